//! Keyframed stroke files: a character as a list of strokes, each a list of keyframes, in
//! TOML (see also `examples/strokes/README.md`).
//!
//! # Format (version 1)
//!
//! ```toml
//! format = "maobi-stroke"     # required
//! version = 1                 # required
//! name = "永"                 # optional
//! head_mm = 40.0              # brush head length: depth 0 touches the paper (default 40;
//!                             # `--head-mm` on render and trace overrides it)
//! lift_mm = 10.0              # travel height above touching between strokes (default 10)
//! travel_speed_mm_s = 150.0   # speed of the travel between strokes (default 150)
//! pause_s = 0.15              # hover before each travel (default 0.15)
//! speed_mm_s = 60.0           # speed for keyframes without a time (default 60)
//! tilt_deg = 10.0             # default handle tilt from vertical (default 0)
//! azimuth_deg = -90.0         # default direction the handle top leans, CCW from +x (default 0)
//! paper = "raw"               # the paper `maobi render` inks: "sized" or "raw" (optional;
//!                             # `--paper` overrides it)
//!
//! [[stroke]]
//! name = "horizontal"         # optional, used in messages
//! travel = true               # lift and travel from the previous stroke (default true);
//!                             # false: continue from its last pose, which must be this
//!                             # stroke's first
//! keys = [
//!   { at = [0, 0], lift = 3 },                # 3 mm above touching
//!   { at = [2, 0], depth = 5, t = 0.25 },     # pressed 5 mm, at 0.25 s
//!   { at = [40, 0, 35.2], tilt = 15, azimuth = 180 },   # explicit ferrule z
//!   { at = [42, 1], depth = 2, quat = [1, 0, 0, 0] },   # orientation as a quaternion
//! ]
//! stops = [{ key = 1, s = 0.1 }]              # stand still at keyframe 1 for 0.1 s
//! moving = [{ t = 0.4, at = 1.5 }]           # at 0.4 s be halfway from keyframe 1 to 2
//! ```
//!
//! * `at`: the ferrule's x, y in mm (+x right, +y up the paper) and optionally z. Without z,
//!   give `depth` (how far the brush is pressed below touching) or `lift` (how far above):
//!   z = head_mm * cos(tilt) - depth.
//! * Orientation: `tilt`/`azimuth` in degrees (defaults from the top), or `quat` [w, x, y, z]
//!   (identity = brush straight down), not both.
//! * `t`: seconds from the stroke's start (the first keyframe defaults to 0); keyframes
//!   without a time are placed by chord length between timed ones or at `speed_mm_s`.
//!   Times must increase.
//! * Every stroke needs at least 2 keyframes.
//!
//! Errors name the file, the stroke (number from 1 and name) and the keyframe (from 1).
//!
//! # Timeline
//!
//! Strokes are played in order. Between two strokes the brush hovers `pause_s`, rises to
//! `lift_mm` above touching, travels to above the next stroke's first keyframe and comes down
//! to it; this travel is itself a keyframed stroke at `travel_speed_mm_s`. The path of each
//! stroke is the cubic B-spline through its keyframes and its timing the kinetic curve through
//! its times ([`maobi_shared::stroke`]).

use std::fmt::Write as _;
use std::path::Path;

use anyhow::{anyhow, bail, Context};
use maobi_shared::stroke::fit::{fit, Fit, FitError, Sample};
use maobi_shared::stroke::kinetic::MAX_PIECES;
use maobi_shared::stroke::orient::{self, Q};
use maobi_shared::stroke::{KeyMovingPoint, Keyframe, Stop, Stroke, MAX_KEYS};
use serde::{Deserialize, Serialize};

use crate::paper::PaperKind;
use crate::poses::{PoseRow, PoseTrack};

pub const FORMAT: &str = "maobi-stroke";
/// Keyframes lie within this distance of the origin along each axis (mm): ten metres, far
/// beyond any paper, and short of the numbers that would make the sampled track absurd.
pub const MAX_COORDINATE_MM: f64 = 10_000.0;
/// The longest a stroke file may last (s), the same bound as a pose file's.
pub const MAX_SPAN_S: f64 = crate::poses::MAX_SPAN_S;
pub const VERSION: i64 = 1;

/// The file as written.
#[derive(Clone, Debug, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct StrokeFile {
    pub format: Option<String>,
    pub version: Option<i64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub name: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub head_mm: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lift_mm: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub travel_speed_mm_s: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub pause_s: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub speed_mm_s: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tilt_deg: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub azimuth_deg: Option<f64>,
    /// The paper's name ([`PaperKind`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub paper: Option<String>,
    #[serde(default)]
    pub stroke: Vec<StrokeSpec>,
}

#[derive(Clone, Debug, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct StrokeSpec {
    #[serde(skip_serializing_if = "Option::is_none")]
    pub name: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub travel: Option<bool>,
    #[serde(default)]
    pub keys: Vec<KeySpec>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub stops: Vec<StopSpec>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub moving: Vec<MovingSpec>,
}

#[derive(Clone, Debug, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct KeySpec {
    pub at: Option<Vec<f64>>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub depth: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lift: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tilt: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub azimuth: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub quat: Option<[f64; 4]>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub t: Option<f64>,
}

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct StopSpec {
    /// Keyframe number (from 1).
    pub key: usize,
    pub s: f64,
}

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct MovingSpec {
    pub t: f64,
    /// Fractional keyframe number (from 1).
    pub at: f64,
}

/// One segment of the timeline: a stroke (or travel) starting at `start` seconds.
#[derive(Clone, Debug)]
pub struct Segment {
    pub start: f64,
    pub stroke: Stroke,
    /// Index of the file's stroke, or `None` for a travel.
    pub from: Option<usize>,
}

/// A character: the validated strokes and the travel between them, on one clock.
#[derive(Clone, Debug)]
pub struct Character {
    pub name: Option<String>,
    /// The head length the keyframes' depths are placed for (mm): the file's `head_mm`, or
    /// the one [`Character::from_path_for_head`] was given.
    pub head_mm: f64,
    /// Whether that head length came from the caller rather than the file.
    pub head_given: bool,
    /// Whether any keyframe is placed by `depth` or `lift` (the head length moves it) rather
    /// than by its z.
    pub relative_heights: bool,
    /// The paper the file asks for, if it names one.
    pub paper: Option<PaperKind>,
    pub segments: Vec<Segment>,
    /// (start, end) time of each of the file's strokes.
    pub stroke_times: Vec<(f64, f64)>,
}

struct Settings {
    head: f64,
    lift: f64,
    travel_speed: f64,
    pause: f64,
    speed: f64,
    tilt: f64,
    azimuth: f64,
}

fn finite_pos(v: Option<f64>, default: f64, what: &str) -> anyhow::Result<f64> {
    match v {
        None => Ok(default),
        Some(x) if x.is_finite() && x > 0.0 => Ok(x),
        Some(x) => bail!("`{what}` must be a positive number, not {x}"),
    }
}

impl Character {
    /// Reads and validates a stroke file.
    pub fn from_path(path: &Path) -> anyhow::Result<Character> {
        let name = path.display().to_string();
        let text = std::fs::read_to_string(path).with_context(|| format!("cannot read {name}"))?;
        Self::from_toml(&name, &text)
    }

    /// Reads a stroke file and places its depths for a head `head_mm` long instead of the
    /// file's `head_mm` (if given): `depth` is then how far that head is pressed below
    /// touching.
    pub fn from_path_for_head(path: &Path, head_mm: Option<f64>) -> anyhow::Result<Character> {
        let name = path.display().to_string();
        let text = std::fs::read_to_string(path).with_context(|| format!("cannot read {name}"))?;
        Self::from_toml_for_head(&name, &text, head_mm)
    }

    /// Parses and validates stroke TOML; `file` names it in errors.
    pub fn from_toml(file: &str, text: &str) -> anyhow::Result<Character> {
        Self::from_toml_for_head(file, text, None)
    }

    /// [`Character::from_toml`], its depths placed for a head `head_mm` long if given.
    pub fn from_toml_for_head(
        file: &str,
        text: &str,
        head_mm: Option<f64>,
    ) -> anyhow::Result<Character> {
        let mut f: StrokeFile = toml::from_str(text).map_err(|e| anyhow!("{file}: {e}"))?;
        let head_given = head_mm.is_some();
        if head_given {
            f.head_mm = head_mm;
        }
        let paper = match &f.paper {
            None => None,
            Some(name) => Some(PaperKind::from_name(name).map_err(|e| {
                // The top-level key's line (before the first table), so the error points at it.
                let line = text
                    .lines()
                    .take_while(|l| !l.trim_start().starts_with('['))
                    .position(|l| {
                        l.trim_start()
                            .strip_prefix("paper")
                            .is_some_and(|r| r.trim_start().starts_with('='))
                    })
                    .map_or(String::new(), |i| format!(", line {}", i + 1));
                anyhow!("{file}{line}: `paper`: {e}")
            })?),
        };
        let mut c = Self::from_file(&f).map_err(|e| anyhow!("{file}: {e:#}"))?;
        c.paper = paper;
        c.head_given = head_given;
        Ok(c)
    }

    fn from_file(f: &StrokeFile) -> anyhow::Result<Character> {
        match f.format.as_deref() {
            Some(FORMAT) => {}
            Some(other) => bail!("`format` is `{other}`, expected `{FORMAT}`"),
            None => bail!("missing `format = \"{FORMAT}\"`"),
        }
        match f.version {
            Some(VERSION) => {}
            Some(v) => bail!("`version` {v} is not supported (this is version {VERSION})"),
            None => bail!("missing `version = {VERSION}`"),
        }
        let deg = |v: Option<f64>, what: &str| -> anyhow::Result<f64> {
            match v {
                None => Ok(0.0),
                Some(x) if x.is_finite() => Ok(x.to_radians()),
                Some(x) => bail!("`{what}` is not finite: {x}"),
            }
        };
        let s = Settings {
            head: finite_pos(f.head_mm, 40.0, "head_mm")?,
            lift: finite_pos(f.lift_mm, 10.0, "lift_mm")?,
            travel_speed: finite_pos(f.travel_speed_mm_s, 150.0, "travel_speed_mm_s")?,
            pause: match f.pause_s {
                None => 0.15,
                Some(x) if x.is_finite() && x >= 0.0 => x,
                Some(x) => bail!("`pause_s` must be zero or positive, not {x}"),
            },
            speed: finite_pos(f.speed_mm_s, 60.0, "speed_mm_s")?,
            tilt: deg(f.tilt_deg, "tilt_deg")?,
            azimuth: deg(f.azimuth_deg, "azimuth_deg")?,
        };
        if f.stroke.is_empty() {
            bail!("no strokes: add at least one [[stroke]]");
        }
        let mut segments = Vec::new();
        let mut stroke_times = Vec::new();
        let mut clock = 0.0;
        let mut last: Option<([f64; 3], Q)> = None;
        for (i, spec) in f.stroke.iter().enumerate() {
            let label = match &spec.name {
                Some(n) => format!("stroke {} ({n})", i + 1),
                None => format!("stroke {}", i + 1),
            };
            let stroke = build_stroke(spec, &s).with_context(|| label.clone())?;
            let first = stroke.key(0);
            if let Some(prev) = last {
                if spec.travel.unwrap_or(true) {
                    let travel = travel(prev, first, &s)
                        .with_context(|| format!("{label}: the travel to it"))?;
                    let (t0, t1) = travel.domain();
                    segments.push(Segment {
                        start: clock - t0,
                        stroke: travel,
                        from: None,
                    });
                    clock += t1 - t0;
                } else {
                    let gap = dist(prev.0, first.0);
                    let turn = orient::angle_between(prev.1, first.1).to_degrees();
                    if gap > 0.01 || turn > 0.1 {
                        bail!(
                            "{label}: `travel = false` but its keyframe 1 is {gap:.3} mm and \
                             {turn:.2} degrees from where the previous stroke ended"
                        );
                    }
                }
            }
            let (t0, t1) = stroke.domain();
            stroke_times.push((clock, clock + t1 - t0));
            last = Some(stroke.key(stroke.len() - 1));
            segments.push(Segment {
                start: clock - t0,
                stroke,
                from: Some(i),
            });
            clock += t1 - t0;
        }
        if clock.is_nan() || clock > MAX_SPAN_S {
            bail!(
                "the strokes last {clock:.0} s with the travel between them, more than the \
                 {MAX_SPAN_S} s (4 hours) a stroke file may: check the keyframes' times and \
                 the speeds"
            );
        }
        let relative_heights = f
            .stroke
            .iter()
            .flat_map(|st| &st.keys)
            .any(|k| k.depth.is_some() || k.lift.is_some());
        Ok(Character {
            name: f.name.clone(),
            head_mm: s.head,
            head_given: false,
            relative_heights,
            paper: None,
            segments,
            stroke_times,
        })
    }

    /// Why a brush may not reach the paper on this file, for a warning: the head its
    /// depths are placed for, or that its keyframes give the ferrule's height outright.
    pub fn placement_note(&self) -> String {
        if self.relative_heights {
            let from = if self.head_given {
                "as asked"
            } else {
                "its `head_mm`"
            };
            format!(
                "the stroke file's depths are placed for a {:.1} mm head ({from})",
                self.head_mm
            )
        } else {
            "the stroke file's keyframes give the ferrule's height (`at = [x, y, z]`), which \
             no head length moves: it is written for a longer brush"
                .to_string()
        }
    }

    /// Total duration (s).
    pub fn duration(&self) -> f64 {
        self.segments
            .last()
            .map_or(0.0, |s| s.start + s.stroke.domain().1)
    }

    /// The pose at time `t` (s) on the character's clock.
    pub fn pose_at(&self, t: f64) -> ([f64; 3], Q) {
        let mut seg = &self.segments[0];
        for s in &self.segments {
            if t >= s.start + s.stroke.domain().0 {
                seg = s;
            } else {
                break;
            }
        }
        seg.stroke.pose_at(t - seg.start)
    }

    /// Poses every `dt` seconds from 0 through the end.
    pub fn sample(&self, dt: f64) -> Vec<PoseRow> {
        let n = (self.duration() / dt + 1e-9).floor() as usize;
        (0..=n)
            .map(|k| {
                let t = k as f64 * dt;
                let (pos, rot) = self.pose_at(t);
                PoseRow { t, pos, rot }
            })
            .collect()
    }

    /// The sampled poses as pose CSV text (`t,x,y,z,qw,qx,qy,qz`).
    pub fn to_csv(&self, dt: f64) -> String {
        rows_to_csv(&self.sample(dt))
    }

    /// The sampled poses (1 ms) as a validated pose track, for `trace` and `render`.
    pub fn track(&self, name: &str) -> anyhow::Result<PoseTrack> {
        let csv = self.to_csv(crate::poses::TICK_S);
        PoseTrack::from_reader(name, csv.as_bytes()).map_err(|e| anyhow!("{e}"))
    }
}

/// Pose rows as CSV text with a header.
pub fn rows_to_csv(rows: &[PoseRow]) -> String {
    let mut out = String::from("t,x,y,z,qw,qx,qy,qz\n");
    for r in rows {
        let _ = writeln!(
            out,
            "{:.6},{:.6},{:.6},{:.6},{:.9},{:.9},{:.9},{:.9}",
            r.t, r.pos[0], r.pos[1], r.pos[2], r.rot[0], r.rot[1], r.rot[2], r.rot[3]
        );
    }
    out
}

fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

fn build_stroke(spec: &StrokeSpec, s: &Settings) -> anyhow::Result<Stroke> {
    if spec.keys.len() < 2 {
        bail!(
            "needs at least 2 keyframes in `keys`, found {}",
            spec.keys.len()
        );
    }
    let mut keys = Vec::with_capacity(spec.keys.len());
    for (k, ks) in spec.keys.iter().enumerate() {
        keys.push(keyframe(ks, s).with_context(|| format!("keyframe {}", k + 1))?);
    }
    let mut stops = Vec::new();
    for (i, st) in spec.stops.iter().enumerate() {
        if st.key < 1 || st.key > keys.len() || !(st.s.is_finite() && st.s > 0.0) {
            bail!(
                "stop {}: `key` must name a keyframe (1..={}) and `s` be a positive number of \
                 seconds",
                i + 1,
                keys.len()
            );
        }
        stops.push(Stop {
            key: st.key - 1,
            dur: st.s,
        });
    }
    let moving: Vec<KeyMovingPoint> = spec
        .moving
        .iter()
        .map(|m| KeyMovingPoint {
            t: m.t,
            at: m.at - 1.0,
        })
        .collect();
    Stroke::new(&keys, &stops, &moving, s.speed).map_err(|e| anyhow!("{}", renumber(&e)))
}

/// The shared crate numbers keyframes, stops and moving points from 0; files from 1.
fn renumber(e: &maobi_shared::stroke::StrokeError) -> String {
    use maobi_shared::stroke::{Source, StrokeError as E};
    match *e {
        E::NotFinite { key } => format!("keyframe {}: a value is not finite", key + 1),
        E::Repeated { key } => format!(
            "keyframe {}: same pose as keyframe {} (to pause, use a stop)",
            key + 1,
            key
        ),
        E::TimeBackwards { key, t, prev } => format!(
            "keyframe {}: time {t} s is not after the previous keyframe's {prev} s (times must \
             increase)",
            key + 1
        ),
        E::BadStop { index } => format!("stop {}: no such keyframe or bad duration", index + 1),
        E::BadMovingPoint { index } => {
            format!(
                "moving point {}: not finite or outside the keyframes",
                index + 1
            )
        }
        E::Timing { at, err } => {
            let at = match at {
                Source::Key(k) => format!("keyframe {}", k + 1),
                Source::MovingPoint(i) => format!("moving point {}", i + 1),
            };
            format!("{at}: timing: {err}")
        }
        ref other => other.to_string(),
    }
}

fn keyframe(ks: &KeySpec, s: &Settings) -> anyhow::Result<Keyframe> {
    let at = ks
        .at
        .as_ref()
        .ok_or_else(|| anyhow!("missing `at = [x, y]` (mm)"))?;
    if !(at.len() == 2 || at.len() == 3) {
        bail!(
            "`at` must be [x, y] or [x, y, z], found {} numbers",
            at.len()
        );
    }
    let check = |v: Option<f64>, what: &str| -> anyhow::Result<()> {
        match v {
            Some(x) if !x.is_finite() => bail!("`{what}` is not finite: {x}"),
            _ => Ok(()),
        }
    };
    for (c, name) in at.iter().zip(["x", "y", "z"]) {
        check(Some(*c), &format!("at.{name}"))?;
    }
    for (v, what) in [
        (ks.depth, "depth"),
        (ks.lift, "lift"),
        (ks.tilt, "tilt"),
        (ks.azimuth, "azimuth"),
        (ks.t, "t"),
    ] {
        check(v, what)?;
    }
    if let Some(t) = ks.t {
        if !(0.0..=MAX_SPAN_S).contains(&t) {
            bail!(
                "`t` is {t} s: a keyframe's time must be within 0..={MAX_SPAN_S} s (4 hours) of \
                 its stroke's start"
            );
        }
    }
    // The keyframe's own tilt, else the file's `tilt_deg`.
    let tilt = ks.tilt.map_or(s.tilt, f64::to_radians);
    if ks.quat.is_none() && tilt.abs() >= core::f64::consts::FRAC_PI_2 {
        let what = if ks.tilt.is_some() {
            "tilt"
        } else {
            "tilt_deg"
        };
        bail!(
            "`{what}` is {:.1} degrees: the handle's tilt from upright must be within -90..90 \
             (leaning the other way is `azimuth` + 180)",
            tilt.to_degrees()
        );
    }
    let rot = match ks.quat {
        Some(q) => {
            if ks.tilt.is_some() || ks.azimuth.is_some() {
                bail!("give `quat` or `tilt`/`azimuth`, not both");
            }
            if q.iter().any(|c| !c.is_finite()) {
                bail!("`quat` is not finite");
            }
            let n = q.iter().map(|c| c * c).sum::<f64>().sqrt();
            if (n - 1.0).abs() > 1e-3 {
                bail!("`quat` has norm {n}, not 1");
            }
            orient::normalize(q)
        }
        None => orient::from_tilt_azimuth(
            ks.tilt.map_or(s.tilt, f64::to_radians),
            ks.azimuth.map_or(s.azimuth, f64::to_radians),
            0.0,
        ),
    };
    let (tilt, _) = orient::tilt_azimuth(rot);
    if tilt >= core::f64::consts::FRAC_PI_2 {
        bail!(
            "`quat` tilts the handle {:.1} degrees from upright: a brush writes with its \
             hair below the ferrule (less than 90)",
            tilt.to_degrees()
        );
    }
    let touch = s.head * tilt.cos();
    let z = match (at.get(2), ks.depth, ks.lift) {
        (Some(&z), None, None) => z,
        (None, Some(d), None) => touch - d,
        (None, None, Some(l)) => touch + l,
        (None, None, None) => bail!("no height: give `at = [x, y, z]`, `depth` or `lift`"),
        _ => bail!("give only one of a z in `at`, `depth` and `lift`"),
    };
    let pos = [at[0], at[1], z];
    if let Some((c, name)) = pos
        .iter()
        .zip(["x", "y", "z"])
        .find(|(c, _)| c.abs() > MAX_COORDINATE_MM)
    {
        bail!(
            "the ferrule's {name} is {c} mm: keyframes must lie within {MAX_COORDINATE_MM} mm \
             of the origin"
        );
    }
    Ok(Keyframe { pos, rot, t: ks.t })
}

/// Hover, rise to the lift height, travel, come down.
fn travel(from: ([f64; 3], Q), to: ([f64; 3], Q), s: &Settings) -> anyhow::Result<Stroke> {
    let up = |p: [f64; 3], q: Q| {
        let touch = s.head * orient::tilt_azimuth(q).0.cos();
        [p[0], p[1], p[2].max(touch + s.lift)]
    };
    let pts = [
        (from.0, from.1),
        (up(from.0, from.1), from.1),
        (up(to.0, to.1), to.1),
        (to.0, to.1),
    ];
    let mut keys: Vec<Keyframe> = Vec::new();
    for (p, q) in pts {
        if let Some(last) = keys.last() {
            if dist(last.pos, p) < 0.5 {
                continue;
            }
        }
        keys.push(Keyframe {
            pos: p,
            rot: q,
            t: None,
        });
    }
    // The end keyframe must be exactly the next stroke's start.
    let last = keys.len() - 1;
    keys[last].pos = to.0;
    keys[last].rot = to.1;
    if keys.len() < 2 {
        keys.insert(
            0,
            Keyframe {
                pos: from.0,
                rot: from.1,
                t: None,
            },
        );
    }
    let stops = if s.pause > 0.0 {
        vec![Stop {
            key: 0,
            dur: s.pause,
        }]
    } else {
        vec![]
    };
    Stroke::new(&keys, &stops, &[], s.travel_speed).map_err(|e| anyhow!("{e}"))
}

/// Fits a pose track with keyframed strokes within the tolerances; the stroke file's text.
/// The track is split into pieces at its slowest moments when one stroke's keyframes are not
/// enough; a piece where the pen rests becomes a stop of the stroke next to it. Returns the
/// TOML and the largest errors of the written file (mm, degrees). A tolerance tighter than a
/// stroke file can follow the recording is refused, naming the smallest that works.
pub fn fit_track(
    track: &PoseTrack,
    tol_mm: f64,
    tol_deg: f64,
) -> anyhow::Result<(String, f64, f64)> {
    let samples: Vec<Sample> = track
        .rows()
        .iter()
        .map(|r| Sample {
            t: r.t,
            pos: r.pos,
            rot: r.rot,
        })
        .collect();
    // Repeated times (allowed in pose files) would stop the fit: keep the later row.
    let mut dedup: Vec<Sample> = Vec::with_capacity(samples.len());
    for s in samples {
        if let Some(l) = dedup.last_mut() {
            if s.t <= l.t {
                *l = s;
                continue;
            }
        }
        dedup.push(s);
    }
    let (text, mm, deg) = fit_samples(&dedup, tol_mm, tol_deg)?;
    if mm <= tol_mm && deg <= tol_deg {
        return Ok((text, mm, deg));
    }
    // Split finely enough, every sample is a keyframe, and still the file can be off: its
    // keyframes are rounded (to 1 nm, 1e-9 and 1 us), and poses closer than the fit tells
    // apart become stops. Look for the smallest tolerances that hold, starting from the
    // errors reached, so the message can name one that was seen to work.
    let mut want = (tol_mm, tol_deg);
    let mut got = (mm, deg);
    let mut works = None;
    for attempt in 0..8 {
        let next = |tol: f64, err: f64| {
            if err <= tol {
                tol
            } else if attempt == 0 {
                round_up_2(err)
            } else {
                round_up_2(err.max(2.0 * tol))
            }
        };
        want = (next(want.0, got.0), next(want.1, got.1));
        let (_, mm, deg) = fit_samples(&dedup, want.0, want.1)?;
        got = (mm, deg);
        if mm <= want.0 && deg <= want.1 {
            works = Some(want);
            break;
        }
    }
    let mut why = Vec::new();
    let mut advice = Vec::new();
    for (opt, unit, tol, err, works) in [
        ("--tol-mm", "mm", tol_mm, mm, works.map(|w| w.0)),
        ("--tol-deg", "degrees", tol_deg, deg, works.map(|w| w.1)),
    ] {
        if err > tol {
            why.push(format!(
                "{opt} {tol} is too tight: the closest the fit gets is {} {unit}",
                round_up_2(err)
            ));
            advice.push(match works {
                Some(w) => format!("{opt} {w}"),
                None => format!("{opt} {} or more", round_up_2(err)),
            });
        }
    }
    bail!(
        "{} (a stroke file rounds positions to 0.000001 mm, quaternions to 1e-9 and times \
         to 0.000001 s, and the fit takes poses closer than 0.0001 mm for the same); the \
         smallest tolerance that works is {}",
        why.join("; "),
        advice.join(" ")
    )
}

/// [`fit_track`] on deduplicated samples, without refusing a tolerance it does not hold.
fn fit_samples(dedup: &[Sample], tol_mm: f64, tol_deg: f64) -> anyhow::Result<(String, f64, f64)> {
    let mut pieces = Vec::new();
    fit_pieces(dedup, tol_mm, tol_deg, 0, &mut pieces)?;
    if !pieces.iter().any(|p| matches!(p, Piece::Moving(..))) {
        bail!(
            "{}: all its poses are the same, and a stroke needs the pen to move between two \
             of them (record the pen while it writes)",
            FitError::Static
        );
    }
    let mut file = StrokeFile {
        format: Some(FORMAT.into()),
        version: Some(VERSION),
        ..Default::default()
    };
    let t_start = dedup[0].t;
    // Times are rounded on the file's clock (from the first sample), and each stroke's
    // keyframe times and stops are differences of those: rounding then never adds up over
    // the pieces, which follow one another.
    let at = |t: f64| round(t - t_start, 6);
    let since = |t: f64, from: f64| round(at(t) - at(from), 6);
    // Where the rest not yet written began: it becomes a stop at the next stroke's first
    // keyframe, or at the last stroke's last keyframe when the recording ends at rest.
    let mut rest_from: Option<f64> = None;
    for piece in &pieces {
        let (range, f) = match piece {
            Piece::Rest((a, _)) => {
                rest_from.get_or_insert(dedup[*a].t);
                continue;
            }
            Piece::Moving(range, f) => (range, f),
        };
        let part = &dedup[range.0..range.1];
        let mut spec = StrokeSpec {
            name: Some(format!("piece {}", file.stroke.len() + 1)),
            travel: Some(false),
            ..Default::default()
        };
        if file.stroke.is_empty() && t_start.abs() > 1e-9 {
            spec.name = Some(format!("piece 1 (recorded from {t_start} s)"));
        }
        // A rest before this piece: the stroke starts with it, standing still at its first
        // keyframe (at time 0); the keyframes after it come that much later.
        let start = rest_from.take().unwrap_or(part[0].t);
        for (j, &k) in f.keys[..f.n].iter().enumerate() {
            let smp = part[k];
            spec.keys.push(KeySpec {
                at: Some(smp.pos.iter().map(|c| round(*c, 6)).collect()),
                quat: Some(smp.rot.map(|c| round(c, 9))),
                t: Some(if j == 0 { 0.0 } else { since(smp.t, start) }),
                ..Default::default()
            });
        }
        for st in &f.stops[..f.n_stops] {
            let from = part[f.keys[st.key]].t;
            spec.stops.push(StopSpec {
                key: st.key + 1,
                s: since(from + st.dur, from),
            });
        }
        if start < part[0].t {
            add_stop(&mut spec, 1, since(part[0].t, start));
        }
        file.stroke.push(spec);
    }
    if let (Some(from), Some(last)) = (rest_from, file.stroke.last_mut()) {
        let key = last.keys.len();
        add_stop(last, key, since(dedup[dedup.len() - 1].t, from));
    }
    let text = toml::to_string(&file).context("cannot write the stroke TOML")?;
    // The errors are those of the file as written (rounded), not of the fit before it.
    let fitted = Character::from_toml("the fitted file", &text).map_err(|e| {
        anyhow!("the fitted keyframes are not a valid stroke file (a bug in the fit): {e:#}")
    })?;
    let (max_mm, max_deg) = file_errors(&fitted, dedup);
    let header = format!(
        "# Fitted by `maobi stroke fit` within {tol_mm} mm and {tol_deg} degrees \
         (largest errors {} mm, {} degrees).\n",
        show_error(max_mm),
        show_error(max_deg)
    );
    Ok((header + &text, max_mm, max_deg))
}

/// The largest distance (mm) and turn (degrees) between a character's poses and the
/// samples, its time 0 at the first sample's. Walks the segments along with the samples
/// (both in time order) rather than searching them for each sample.
fn file_errors(ch: &Character, samples: &[Sample]) -> (f64, f64) {
    let begins = |s: &Segment| s.start + s.stroke.domain().0;
    let (mut mm, mut deg) = (0.0f64, 0.0f64);
    let mut seg = 0;
    for s in samples {
        let t = s.t - samples[0].t;
        // The segment `Character::pose_at` picks: the last one begun by `t`.
        while seg + 1 < ch.segments.len() && t >= begins(&ch.segments[seg + 1]) {
            seg += 1;
        }
        let sg = &ch.segments[seg];
        let (p, q) = sg.stroke.pose_at(t - sg.start);
        mm = mm.max(dist(p, s.pos));
        deg = deg.max(orient::angle_between(q, s.rot).to_degrees());
    }
    (mm, deg)
}

/// A fit's error for people: 4 decimals, or as many as show two significant digits of a
/// smaller one (a fit within 0.00001 mm is not "0.0000 mm" off).
pub fn show_error(x: f64) -> String {
    let decimals = if (1e-9..1e-3).contains(&x) {
        (1 - x.log10().floor() as i32).clamp(4, 10) as usize
    } else {
        4
    };
    format!("{x:.decimals$}")
}

/// `x` rounded up to two significant digits (a tolerance to suggest).
fn round_up_2(x: f64) -> f64 {
    if !(x.is_finite() && x > 0.0) {
        return x;
    }
    let e = 10f64.powi(x.log10().floor() as i32 - 1);
    // Printed with the digits it has, then read back: the value suggested is the one tried.
    let decimals = (-(x.log10().floor() as i32 - 1)).max(0) as usize;
    format!("{:.*}", decimals, (x / e).ceil() * e)
        .parse()
        .unwrap_or(x)
}

/// Adds `dur` seconds of standing still at keyframe `key` (from 1), to its stop if it has one.
fn add_stop(spec: &mut StrokeSpec, key: usize, dur: f64) {
    match spec.stops.iter_mut().find(|s| s.key == key) {
        Some(s) => s.s = round(s.s + dur, 6),
        None => {
            spec.stops.push(StopSpec { key, s: dur });
            spec.stops.sort_by_key(|s| s.key);
        }
    }
}

fn round(x: f64, decimals: i32) -> f64 {
    let s = 10f64.powi(decimals);
    (x * s).round() / s
}

/// A piece of a split recording: samples `range` (end exclusive; neighbours share their
/// boundary sample).
enum Piece {
    /// Keyframes fitted to the samples (boxed: a fit holds whole stroke arrays).
    Moving((usize, usize), Box<Fit>),
    /// The pen stands still: a stroke needs two different poses, so this is written as a stop
    /// of the stroke next to it.
    Rest((usize, usize)),
}

/// Whether a fitted piece can take a stop at each end (for a rest next to it) and still be a
/// stroke: a stroke's timing holds [`MAX_KEYS`] moving points (one per keyframe and one per
/// stop's end) and [`MAX_PIECES`] parts (each stop and each motion between stops).
fn room_for_end_stops(f: &Fit) -> bool {
    let stops = f.n_stops + 2;
    f.n + stops <= MAX_KEYS && 2 * stops - 1 <= MAX_PIECES
}

fn fit_pieces(
    samples: &[Sample],
    tol_mm: f64,
    tol_deg: f64,
    offset: usize,
    out: &mut Vec<Piece>,
) -> anyhow::Result<()> {
    let range = (offset, offset + samples.len());
    let m = samples.len();
    match fit(samples, tol_mm, tol_deg) {
        Ok(f) if (f.within && room_for_end_stops(&f)) || m < 8 => {
            out.push(Piece::Moving(range, Box::new(f)));
            return Ok(());
        }
        // Not within the tolerances, or no room for a rest's stop: split below.
        Ok(_) => {}
        // The pen rests over this whole piece (the whole recording standing still is refused
        // by `fit_track`).
        Err(FitError::Static) => {
            out.push(Piece::Rest(range));
            return Ok(());
        }
        // The keyframes the fit chose are not a stroke (more stops than one stroke's timing
        // holds): smaller pieces have fewer. (From 4 samples on, the split below leaves two
        // smaller pieces of at least 2.)
        Err(FitError::Stroke(_)) if m >= 4 => {}
        Err(e) => bail!("{e}"),
    }
    // Split at the slowest sample in the middle half (a rest point, if there is one); the
    // pieces share that sample so they join exactly.
    let speed = |i: usize| dist(samples[i + 1].pos, samples[i - 1].pos);
    let split = (m / 4..3 * m / 4)
        .min_by(|&a, &b| speed(a).total_cmp(&speed(b)))
        .unwrap_or(m / 2);
    fit_pieces(&samples[..=split], tol_mm, tol_deg, offset, out)?;
    fit_pieces(&samples[split..], tol_mm, tol_deg, offset + split, out)
}
