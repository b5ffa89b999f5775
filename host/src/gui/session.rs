//! Sessions: everything needed to re-render a sitting at the built-in simulator exactly.
//!
//! A session is not a picture but the inputs that made it: the brush preset and parameters
//! the model started from, the pose it started at rest in, the handle pose of every tick
//! (stored only when it changed), every command that changed the brush (dip, parameter,
//! preset, the reset at the start of a replay) with the tick it took effect before, and the
//! paper's own history: which ticks were inked (live frames a stalled UI dropped were not)
//! and where undo and clear came between them. Replaying those through the same fixed-point
//! model and the same inker ([`super::rerender`]) gives the same canvas, bit for bit, and
//! leaves the model in the state it was in, so writing can go on where it stopped.
//!
//! The journal of poses and commands is kept by the built-in device itself ([`Journal`],
//! written by [`SimCore`](crate::device::builtin::SimCore)), because only it knows at which
//! tick a command took effect; the paper's history is kept by the app ([`InkLog`]).
//!
//! # File format (`.maobi.toml`, version 2)
//!
//! TOML, so it can be read and diffed: `format = "maobi-session"`, `version`, `model` (the
//! [`MODEL_VERSION`] it was recorded with; version 1 files, written before models had
//! versions, have none), the `device` it was recorded on, `preset`, `ticks` (the last tick), `start` (the rest pose before tick
//! 1: `[x, y, z, qw, qx, qy, qz]`, mm and a unit quaternion), `inked` (inclusive tick
//! ranges), a `[paper]` table (the canvas frame, and the paper's `kind`, `"sized"` or
//! `"raw"`, and the `seed` of its fibres: both optional, files written before papers had
//! kinds are sized paper with the default seed), a `[params]` table (every parameter by its
//! `maobi` name), `[[events]]` (`tick` and one of `dip`, `param` + `value`, `preset`,
//! `reset`), `[[canvas]]` (`after_tick` and `op` = `"undo"` or `"clear"`), and `poses`: a
//! CSV text with the header `tick,x,y,z,qw,qx,qy,qz`, one row per tick at which the pose
//! changed; the pose holds until the next row. Numbers are written in Rust's shortest
//! round-trip form, so reading them back gives the same bits.

use std::fmt::Write as _;
use std::path::Path;

use anyhow::{bail, Context as _};
use maobi_shared::{ParamId, Pose, Quat, Vec3};
use serde::{Deserialize, Serialize};

use crate::device::journal::{Journal, JournalEvent, MAX_JOURNAL_POSES};
use crate::device::model::{BrushChoice, ModelKind};
use crate::paper::{PaperKind, PaperSpec, DEFAULT_SEED};
use crate::raster::Frame;

/// The `format` key of a session file.
pub const FORMAT: &str = "maobi-session";
/// The version this build writes. It reads it and version 1 (the same, without `model`).
pub const VERSION: u32 = 2;
/// The most ticks a session may span: a day at 1 kHz.
pub const MAX_TICKS: u64 = 24 * 3600 * 1000;

/// The version of what turns a session's inputs into ink: the brush model, the force loop
/// and the built-in device (`maobi-shared`), and the inker and paper. A session records the
/// version it was written with, and a session opened in a build of another version
/// re-renders with this build's model, so its ink may differ from what was written: the app
/// says so. Raised with every change to the re-rendered result; `tests/model_version.rs`
/// keeps a digest of a reference session's re-render for the current version and fails when
/// the result changes and the version does not.
pub const MODEL_VERSION: u32 = 4;
/// A change to the paper that is not ink.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum CanvasOp {
    Undo,
    Clear,
}

/// The paper's history, kept by the app: which ticks it inked, and undo/clear between them.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct InkLog {
    /// Inclusive ranges of inked ticks, ascending.
    pub inked: Vec<[u64; 2]>,
    /// `(after_tick, op)`: the op came after the paper inked `after_tick` (0: before any).
    pub ops: Vec<(u64, CanvasOp)>,
    /// The paper has ink that is not in this log (from another device's session).
    pub foreign: bool,
}

impl InkLog {
    pub fn inked(&mut self, tick: u64) {
        match self.inked.last_mut() {
            Some(r) if r[1] + 1 == tick => r[1] = tick,
            Some(r) if tick <= r[1] => {} // a tick seen twice; the first inking counts.
            _ => self.inked.push([tick, tick]),
        }
    }
    pub fn op(&mut self, op: CanvasOp) {
        let after = self.inked.last().map_or(0, |r| r[1]);
        self.ops.push((after, op));
    }
    /// The paper inked `tick`.
    pub fn contains(&self, tick: u64) -> bool {
        self.inked.iter().any(|r| (r[0]..=r[1]).contains(&tick))
    }
}

/// A sitting: the simulator's journal, the paper it inked and the paper's history.
#[derive(Clone, Debug)]
pub struct Session {
    /// Who recorded it ("built-in simulator").
    pub device: String,
    pub journal: Journal,
    pub paper: Frame,
    /// The paper's kind and fibres.
    pub paper_spec: PaperSpec,
    pub ink: InkLog,
    /// The [`MODEL_VERSION`] it was recorded with (`None`: before models had versions).
    pub model: Option<u32>,
}

impl Session {
    /// What a re-render in this build changes, if anything: `None` when the session was
    /// recorded with this build's model, else a sentence for the user.
    pub fn model_note(&self) -> Option<String> {
        let recorded = match self.model {
            Some(v) if v == MODEL_VERSION => return None,
            Some(v) => format!("recorded with brush model version {v}"),
            None => "recorded before brush models had versions".to_string(),
        };
        Some(format!(
            "{recorded}, re-rendered with this build's version {MODEL_VERSION}: the ink may \
             differ from what was written (a PNG saved then is the record of it)"
        ))
    }

    /// Checks that the session can be saved: a complete journal, no ink from elsewhere.
    pub fn check_complete(&self) -> anyhow::Result<()> {
        if let Some(t) = self.journal.full_at {
            bail!(
                "the session's journal filled up at tick {t} ({MAX_JOURNAL_POSES} pose changes); \
                 it cannot re-render exactly. Save the PNG, or record poses instead"
            );
        }
        if self.ink.foreign {
            bail!(
                "the paper holds ink from a device used before this one, which is not part of \
                 this session; clear the paper (or save the PNG) first"
            );
        }
        Ok(())
    }

    /// Writes the session file (see the module docs for the format).
    pub fn save(&self, path: &Path) -> anyhow::Result<()> {
        self.check_complete()?;
        let text = self.to_toml()?;
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir)
                .with_context(|| format!("cannot create {}", dir.display()))?;
        }
        std::fs::write(path, text).with_context(|| format!("cannot write {}", path.display()))
    }

    pub fn to_toml(&self) -> anyhow::Result<String> {
        let j = &self.journal;
        let mut poses = format!("{POSES_HEADER}\n");
        for (t, p) in &j.poses {
            let v = pose_values(p);
            let _ = writeln!(
                poses,
                "{t},{},{},{},{},{},{},{}",
                v[0], v[1], v[2], v[3], v[4], v[5], v[6]
            );
        }
        let file = SessionFile {
            format: FORMAT.into(),
            version: VERSION,
            model: Some(self.model.unwrap_or(MODEL_VERSION)),
            brush_model: (j.model != ModelKind::Liang).then(|| j.model.name().to_string()),
            device: self.device.clone(),
            preset: j.preset.clone(),
            ticks: j.ticks,
            start: pose_values(&j.start),
            inked: self.ink.inked.clone(),
            paper: PaperFile {
                x0_mm: self.paper.x0_mm,
                y_top_mm: self.paper.y_top_mm,
                px_per_mm: self.paper.px_per_mm,
                width: self.paper.width as u64,
                height: self.paper.height as u64,
                kind: Some(self.paper_spec.kind.name().to_string()),
                seed: Some(self.paper_spec.seed),
            },
            params: ParamId::ALL
                .iter()
                .map(|&id| (id.name().to_string(), j.params.get(id)))
                .collect(),
            events: j
                .events
                .iter()
                .map(|(tick, e)| {
                    let mut f = EventFile {
                        tick: *tick,
                        ..EventFile::default()
                    };
                    match e {
                        JournalEvent::Dip(w) => f.dip = Some(*w),
                        JournalEvent::Param(id, v) => {
                            f.param = Some(id.name().to_string());
                            f.value = Some(*v);
                        }
                        JournalEvent::Preset(n) => f.preset = Some(n.clone()),
                        JournalEvent::Reset(p) => f.reset = Some(pose_values(p)),
                        JournalEvent::Model(m) => f.brush_model = Some(m.name().to_string()),
                    }
                    f
                })
                .collect(),
            canvas: self
                .ink
                .ops
                .iter()
                .map(|&(after_tick, op)| CanvasFile { after_tick, op })
                .collect(),
            poses,
        };
        toml::to_string(&file).context("cannot write the session as TOML")
    }

    /// Reads and checks a session file; every problem names the file and what is wrong.
    pub fn load(path: &Path) -> anyhow::Result<Session> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read {}", path.display()))?;
        Session::from_toml(&text).with_context(|| format!("{}", path.display()))
    }

    pub fn from_toml(text: &str) -> anyhow::Result<Session> {
        let f: SessionFile = toml::from_str(text).context("not a session file")?;
        if f.format != FORMAT {
            bail!("format is `{}`, expected `{FORMAT}`", f.format);
        }
        match (f.version, f.model) {
            (1, None) | (VERSION, Some(_)) => {}
            (VERSION, None) => bail!("version {VERSION} needs `model`, the brush model's version"),
            (1, Some(_)) => bail!("version 1 has no `model` (it came with version 2)"),
            (v, _) => bail!("session version {v} (this build reads versions 1 and {VERSION})"),
        }
        let brush_model = match &f.brush_model {
            None => ModelKind::Liang,
            Some(m) => ModelKind::from_name(m).map_err(|e| anyhow::anyhow!("brush_model: {e}"))?,
        };
        let preset_params = BrushChoice::for_model(&f.preset, brush_model)
            .map_err(|e| anyhow::anyhow!("preset: {e}"))?
            .params;
        let mut params = preset_params;
        for (name, v) in &f.params {
            let id = ParamId::from_name(name)
                .ok_or_else(|| anyhow::anyhow!("[params]: unknown parameter `{name}`"))?;
            params
                .set(id, *v)
                .map_err(|e| anyhow::anyhow!("[params]: {e}"))?;
        }
        params
            .validate()
            .map_err(|e| anyhow::anyhow!("[params]: {e}"))?;
        let start = pose_from(&f.start).map_err(|e| anyhow::anyhow!("start: {e}"))?;
        let p = &f.paper;
        let bad = |v: f64| !v.is_finite();
        if bad(p.x0_mm) || bad(p.y_top_mm) || !(p.px_per_mm > 0.0 && p.px_per_mm <= 100.0) {
            bail!("[paper]: origin must be finite and px_per_mm in (0, 100]");
        }
        if p.width == 0 || p.height == 0 || p.width * p.height > 64_000_000 {
            bail!(
                "[paper]: {} x {} px is not a paper (1 to 64 Mpx)",
                p.width,
                p.height
            );
        }
        let paper_spec = PaperSpec {
            kind: match &p.kind {
                None => PaperKind::default(),
                Some(k) => PaperKind::from_name(k).map_err(|e| {
                    anyhow::anyhow!("[paper] kind{}: {e}", table_key_line(text, "paper", "kind"))
                })?,
            },
            seed: p.seed.unwrap_or(DEFAULT_SEED),
        };
        let paper = Frame {
            x0_mm: p.x0_mm,
            y_top_mm: p.y_top_mm,
            px_per_mm: p.px_per_mm,
            width: p.width as usize,
            height: p.height as usize,
        };
        // A session is re-run tick by tick: a day of them is hours of simulation already.
        if f.ticks > MAX_TICKS {
            bail!(
                "`ticks = {}`: more than the {MAX_TICKS} (a day at 1 kHz) a session may hold",
                f.ticks
            );
        }
        // File line of the CSV's header, so errors point into the file.
        let header_line = text
            .lines()
            .position(|l| {
                l.trim_start_matches("poses = ")
                    .trim_start_matches(['"', '\''])
                    == POSES_HEADER
            })
            .map_or(1, |i| i + 1);
        let poses = parse_poses(&f.poses, f.ticks, header_line)?;
        let mut events = Vec::with_capacity(f.events.len());
        let mut last = 0;
        for (i, e) in f.events.iter().enumerate() {
            let n = i + 1;
            if e.tick < last || e.tick == 0 || e.tick > f.ticks + 1 {
                bail!(
                    "event {n}: tick {} out of order or outside 1..={}",
                    e.tick,
                    f.ticks + 1
                );
            }
            last = e.tick;
            let kinds = [
                e.dip.is_some(),
                e.param.is_some(),
                e.preset.is_some(),
                e.reset.is_some(),
                e.brush_model.is_some(),
            ];
            if kinds.iter().filter(|&&k| k).count() != 1 {
                bail!("event {n}: needs exactly one of dip, param, preset, reset, brush_model");
            }
            let ev = if let Some(w) = e.dip {
                if !(0.0..=1.0).contains(&w) {
                    bail!("event {n}: dip {w} outside 0..=1");
                }
                JournalEvent::Dip(w)
            } else if let Some(name) = &e.param {
                let id = ParamId::from_name(name)
                    .ok_or_else(|| anyhow::anyhow!("event {n}: unknown parameter `{name}`"))?;
                let v = e
                    .value
                    .ok_or_else(|| anyhow::anyhow!("event {n}: param `{name}` has no value"))?;
                JournalEvent::Param(id, v)
            } else if let Some(name) = &e.preset {
                BrushChoice::parse(name).map_err(|e| anyhow::anyhow!("event {n}: {e}"))?;
                JournalEvent::Preset(name.clone())
            } else if let Some(m) = &e.brush_model {
                JournalEvent::Model(
                    ModelKind::from_name(m).map_err(|e| anyhow::anyhow!("event {n}: {e}"))?,
                )
            } else {
                let v = e.reset.unwrap_or_default();
                JournalEvent::Reset(pose_from(&v).map_err(|e| anyhow::anyhow!("event {n}: {e}"))?)
            };
            events.push((e.tick, ev));
        }
        let mut inked: Vec<[u64; 2]> = Vec::with_capacity(f.inked.len());
        for r in &f.inked {
            if r[0] > r[1] || r[1] > f.ticks || inked.last().is_some_and(|l| l[1] >= r[0]) {
                bail!(
                    "inked: range {r:?} empty, overlapping or past the last tick {}",
                    f.ticks
                );
            }
            inked.push(*r);
        }
        let mut ops = Vec::with_capacity(f.canvas.len());
        let mut last = 0;
        for (i, c) in f.canvas.iter().enumerate() {
            if c.after_tick < last || c.after_tick > f.ticks {
                bail!(
                    "canvas op {}: after_tick {} out of order or past the last tick",
                    i + 1,
                    c.after_tick
                );
            }
            last = c.after_tick;
            ops.push((c.after_tick, c.op));
        }
        Ok(Session {
            device: f.device,
            journal: Journal::restored(&f.preset, params, start, f.ticks, poses, events)
                .with_model(brush_model),
            paper,
            paper_spec,
            ink: InkLog {
                inked,
                ops,
                foreign: false,
            },
            model: f.model,
        })
    }
}

/// `, line N` of `key` in the TOML table `[table]` of `text`, or nothing if not found.
fn table_key_line(text: &str, table: &str, key: &str) -> String {
    let header = format!("[{table}]");
    let mut inside = false;
    for (i, l) in text.lines().enumerate() {
        let l = l.trim_start();
        if l.starts_with('[') {
            inside = l.starts_with(&header);
        } else if inside
            && l.strip_prefix(key)
                .is_some_and(|r| r.trim_start().starts_with('='))
        {
            return format!(", line {}", i + 1);
        }
    }
    String::new()
}

fn pose_values(p: &Pose<f64>) -> [f64; 7] {
    let v = p.pos.to_f64();
    let q = p.rot.to_f64();
    [v[0], v[1], v[2], q[0], q[1], q[2], q[3]]
}

fn pose_from(v: &[f64; 7]) -> Result<Pose<f64>, String> {
    if v.iter().any(|x| !x.is_finite()) {
        return Err(format!("pose {v:?} is not finite"));
    }
    let n = (v[3] * v[3] + v[4] * v[4] + v[5] * v[5] + v[6] * v[6]).sqrt();
    if (n - 1.0).abs() > 1e-3 {
        return Err(format!("quaternion norm {n} is not 1 (within 1e-3)"));
    }
    Ok(Pose::new(
        Vec3::new(v[0], v[1], v[2]),
        Quat::new(v[3], v[4], v[5], v[6]),
    ))
}

const POSES_HEADER: &str = "tick,x,y,z,qw,qx,qy,qz";

/// Parses the `poses` CSV, whose header is on line `header_line` of the file (errors name
/// file lines).
fn parse_poses(
    text: &str,
    ticks: u64,
    header_line: usize,
) -> anyhow::Result<Vec<(u64, Pose<f64>)>> {
    let mut rdr = csv::ReaderBuilder::new()
        .has_headers(false)
        .flexible(true)
        .trim(csv::Trim::All)
        .from_reader(text.as_bytes());
    // The reader counts lines from 1 at the CSV's first; the file's lines start earlier.
    let file_line =
        |r: &csv::StringRecord| header_line - 1 + r.position().map_or(1, |p| p.line() as usize);
    let mut records = rdr.records();
    match records.next() {
        Some(Ok(h)) if h.iter().eq(POSES_HEADER.split(',')) => {}
        other => bail!(
            "poses: the header must be `{POSES_HEADER}`, found `{}`",
            match other {
                Some(Ok(h)) => h.iter().collect::<Vec<_>>().join(","),
                Some(Err(e)) => e.to_string(),
                None => String::new(),
            }
        ),
    }
    let mut out = Vec::new();
    let mut last = 0;
    for record in records {
        let cols = record.map_err(|e| anyhow::anyhow!("poses: {e}"))?;
        let ln = file_line(&cols);
        if cols.len() != 8 {
            bail!("poses, line {ln}: {} columns, expected 8", cols.len());
        }
        let tick: u64 = cols[0]
            .parse()
            .map_err(|_| anyhow::anyhow!("poses, line {ln}, column tick: `{}`", &cols[0]))?;
        if tick <= last || tick > ticks {
            bail!("poses, line {ln}: tick {tick} not after {last} or past the last tick {ticks}");
        }
        last = tick;
        let mut v = [0.0; 7];
        for (k, name) in ["x", "y", "z", "qw", "qx", "qy", "qz"].iter().enumerate() {
            v[k] = cols[k + 1].parse().map_err(|_| {
                anyhow::anyhow!("poses, line {ln}, column {name}: `{}`", &cols[k + 1])
            })?;
        }
        let p = pose_from(&v).map_err(|e| anyhow::anyhow!("poses, line {ln}: {e}"))?;
        out.push((tick, p));
    }
    Ok(out)
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct SessionFile {
    format: String,
    version: u32,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    model: Option<u32>,
    /// The brush model the device started with (`liang`, `baxter-lin`); absent: `liang`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    brush_model: Option<String>,
    device: String,
    preset: String,
    ticks: u64,
    start: [f64; 7],
    inked: Vec<[u64; 2]>,
    poses: String,
    paper: PaperFile,
    params: std::collections::BTreeMap<String, f32>,
    #[serde(default)]
    events: Vec<EventFile>,
    #[serde(default)]
    canvas: Vec<CanvasFile>,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct PaperFile {
    x0_mm: f64,
    y_top_mm: f64,
    px_per_mm: f64,
    width: u64,
    height: u64,
    /// The paper's name; absent in files from before papers had kinds (sized).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    kind: Option<String>,
    /// The seed of the paper's fibres.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    seed: Option<u64>,
}

#[derive(Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
struct EventFile {
    tick: u64,
    #[serde(skip_serializing_if = "Option::is_none")]
    dip: Option<f32>,
    #[serde(skip_serializing_if = "Option::is_none")]
    param: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    value: Option<f32>,
    #[serde(skip_serializing_if = "Option::is_none")]
    preset: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    reset: Option<[f64; 7]>,
    /// Another brush model from here on (`liang`, `baxter-lin`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    brush_model: Option<String>,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct CanvasFile {
    after_tick: u64,
    op: CanvasOp,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ink_log_merges_consecutive_ticks_and_places_ops() {
        let mut l = InkLog::default();
        l.op(CanvasOp::Clear);
        for t in [1, 2, 3, 7, 8] {
            l.inked(t);
        }
        l.op(CanvasOp::Undo);
        assert_eq!(l.inked, vec![[1, 3], [7, 8]]);
        assert_eq!(l.ops, vec![(0, CanvasOp::Clear), (8, CanvasOp::Undo)]);
        assert!(l.contains(2) && !l.contains(5) && l.contains(8));
    }

    fn file(paper: &str) -> String {
        format!(
            "format = \"maobi-session\"\nversion = 1\ndevice = \"built-in simulator\"\n\
             preset = \"large\"\nticks = 2\nstart = [0.0, 0.0, 50.0, 1.0, 0.0, 0.0, 0.0]\n\
             inked = []\nposes = \"tick,x,y,z,qw,qx,qy,qz\"\n\n[paper]\nx0_mm = -10.0\n\
             y_top_mm = 10.0\npx_per_mm = 2.0\nwidth = 40\nheight = 40\n{paper}\n\
             [params]\n"
        )
    }

    #[test]
    fn a_session_records_its_model_and_an_older_one_says_what_a_replay_changes() {
        // Version 1: written before models had versions.
        let old = Session::from_toml(&file("")).unwrap();
        assert_eq!(old.model, None);
        let note = old.model_note().unwrap();
        assert!(note.contains("before brush models had versions"), "{note}");
        assert!(note.contains(&format!("version {MODEL_VERSION}")), "{note}");
        // Written out, it is this format's file, with this build's model: what re-rendering
        // it now gives.
        let text = old.to_toml().unwrap();
        assert!(text.contains("version = 2") && text.contains(&format!("model = {MODEL_VERSION}")));
        let current = Session::from_toml(&text).unwrap();
        assert_eq!(current.model, Some(MODEL_VERSION));
        assert_eq!(current.model_note(), None);
        // Another version's session reads, and says so.
        let other = text.replace(
            &format!("model = {MODEL_VERSION}"),
            &format!("model = {}", MODEL_VERSION + 7),
        );
        let note = Session::from_toml(&other).unwrap().model_note().unwrap();
        assert!(
            note.contains(&format!("version {}", MODEL_VERSION + 7)),
            "{note}"
        );
        // Each version's own fields.
        let bad = |t: &str| format!("{:#}", Session::from_toml(t).unwrap_err());
        assert!(
            bad(&text.replace(&format!("model = {MODEL_VERSION}\n"), "")).contains("needs `model`")
        );
        assert!(
            bad(&file("").replace("version = 1\n", "version = 1\nmodel = 1\n"))
                .contains("version 1 has no `model`")
        );
    }

    #[test]
    fn the_paper_kind_is_optional_and_checked() {
        let old = Session::from_toml(&file("")).unwrap();
        assert_eq!(old.paper_spec, PaperSpec::default());
        let raw = Session::from_toml(&file("kind = \"raw\"\nseed = 9")).unwrap();
        assert_eq!(
            raw.paper_spec,
            PaperSpec {
                kind: PaperKind::Raw,
                seed: 9
            }
        );
        // Saved and read back, the paper comes back.
        let again = Session::from_toml(&raw.to_toml().unwrap()).unwrap();
        assert_eq!(again.paper_spec, raw.paper_spec);
        let e = format!(
            "{:#}",
            Session::from_toml(&file("kind = \"washi\"")).unwrap_err()
        );
        assert!(
            e.contains("[paper] kind, line 16")
                && e.contains("`washi`")
                && e.contains("sized, raw"),
            "{e}"
        );
    }
}
