//! Characters with their stroke order, from Make Me a Hanzi's data as the npm package
//! `hanzi-writer-data` publishes it: one `<character>.json` per character, each with its
//! strokes in writing order, every stroke an outline (an SVG path) and a median (the
//! polyline down its middle), in a 1024-unit box with +y up (the box's top at y = 900, its
//! bottom at -124), Kai style, under the Arphic Public License.
//!
//! Where the data comes from, in order: the folder [`DATA_ENV`] names (a folder of the
//! package's own files, as `npm pack` unpacks them); else [`default_dir`], where
//! `scripts/install-hanzi-data` installs all 9,574 characters; else the practice set shipped
//! in the binary ([`SHIPPED`]: 永 and the hundred most common characters, `host/data/hanzi/`,
//! with the licence beside them).
//!
//! [`stroke_file`] turns a character into a keyframed stroke file (`crate::strokes`' format)
//! for a brush, its press at each point chosen from the brush's measured stroke width
//! ([`WidthCurve`]) so that the stroke is as wide as the outline around its median.

use crate::paper::{PaperKind, PaperSpec};
use crate::raster::Frame;
use crate::render;
use crate::strokes::Character;
use anyhow::Context as _;
use kurbo::{BezPath, PathEl, Point, Shape as _};
use maobi_shared::BrushParams;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// The environment variable that names a folder of `hanzi-writer-data`'s files.
pub const DATA_ENV: &str = "MAOBI_HANZI_DATA";

/// The npm package (and version) the shipped set was taken from and the install script
/// installs.
pub const PACKAGE: &str = "hanzi-writer-data@2.0.1";

/// The data's box: 1024 units, +y up, its top at y = 900.
const BOX_UNITS: f64 = 1024.0;
const BOX_CENTRE: [f64; 2] = [512.0, 388.0];

/// The practice set compiled in: 永 and the hundred most common characters of modern Chinese
/// (Jun Da's character frequency list), each the package's own file.
macro_rules! shipped {
    ($($c:literal)*) => {
        &[$(($c, include_str!(concat!("../data/hanzi/", $c, ".json")))),*]
    };
}
pub const SHIPPED: &[(&str, &str)] = shipped!(
    "的" "一" "是" "不" "了" "在" "人" "有" "我" "他" "这" "个" "们" "中" "来" "上" "大" "为" "和"
    "国" "地" "到" "以" "说" "时" "要" "就" "出" "会" "可" "也" "你" "对" "生" "能" "而" "子" "那"
    "得" "于" "着" "下" "自" "之" "年" "过" "发" "后" "作" "里" "用" "道" "行" "所" "然" "家" "种"
    "事" "成" "方" "多" "经" "么" "去" "法" "学" "如" "都" "同" "现" "当" "没" "动" "面" "起" "看"
    "定" "天" "分" "还" "进" "好" "小" "部" "其" "些" "主" "样" "理" "心" "她" "本" "前" "开" "但"
    "因" "只" "从" "想" "实" "永"
);

/// Why a character's data could not be had. Each names the character and, where there is
/// one, the file.
#[derive(Debug, thiserror::Error)]
pub enum HanziError {
    #[error("{0:?} is not one character: give one, e.g. 永")]
    NotOneCharacter(String),
    #[error(
        "no stroke data for {ch} (U+{code:04X}): {looked}; `bash scripts/install-hanzi-data` \
         installs all 9,574 characters of {PACKAGE}"
    )]
    Missing { ch: char, code: u32, looked: String },
    #[error("{path}: the stroke data for {ch} is damaged: {why}")]
    Damaged { ch: char, path: String, why: String },
    #[error("{DATA_ENV}={path}: {why}")]
    BadFolder { path: String, why: String },
}

/// One stroke: its outline (mm, +y up) and its median (mm), in writing order.
#[derive(Clone, Debug)]
pub struct HanziStroke {
    pub outline: BezPath,
    pub median: Vec<[f64; 2]>,
}

/// A character's strokes in writing order, in the data's units (see [`Hanzi::to_mm`]).
#[derive(Clone, Debug)]
pub struct Hanzi {
    pub ch: char,
    /// Where it was read: a file, or the shipped set.
    pub source: String,
    strokes: Vec<HanziStroke>,
}

#[derive(serde::Deserialize)]
struct RawHanzi {
    strokes: Vec<String>,
    medians: Vec<Vec<[f64; 2]>>,
}

impl Hanzi {
    /// Parses a character's file (`text`, read from `source`).
    pub fn parse(ch: char, source: &str, text: &str) -> Result<Hanzi, HanziError> {
        let damaged = |why: String| HanziError::Damaged {
            ch,
            path: source.to_string(),
            why,
        };
        let raw: RawHanzi = serde_json::from_str(text).map_err(|e| damaged(e.to_string()))?;
        if raw.strokes.is_empty() {
            return Err(damaged("it has no strokes".into()));
        }
        if raw.strokes.len() != raw.medians.len() {
            return Err(damaged(format!(
                "{} outlines but {} medians",
                raw.strokes.len(),
                raw.medians.len()
            )));
        }
        let in_box = |p: &[f64; 2]| {
            p.iter()
                .all(|v| v.is_finite() && (-512.0..=1536.0).contains(v))
        };
        let mut strokes = Vec::with_capacity(raw.strokes.len());
        for (k, (svg, median)) in raw.strokes.iter().zip(raw.medians).enumerate() {
            let n = k + 1;
            let outline = BezPath::from_svg(svg)
                .map_err(|e| damaged(format!("stroke {n}'s outline: {e}")))?;
            if outline.elements().is_empty() {
                return Err(damaged(format!("stroke {n}'s outline is empty")));
            }
            let bad_point = outline.elements().iter().any(|el| {
                let pts: [Option<Point>; 3] = match *el {
                    PathEl::MoveTo(p) | PathEl::LineTo(p) => [Some(p), None, None],
                    PathEl::QuadTo(a, b) => [Some(a), Some(b), None],
                    PathEl::CurveTo(a, b, c) => [Some(a), Some(b), Some(c)],
                    PathEl::ClosePath => [None; 3],
                };
                pts.iter().flatten().any(|p| !in_box(&[p.x, p.y]))
            });
            if bad_point {
                return Err(damaged(format!(
                    "stroke {n}'s outline leaves the character's box"
                )));
            }
            if median.len() < 2 {
                return Err(damaged(format!(
                    "stroke {n}'s median has {} point(s)",
                    median.len()
                )));
            }
            if let Some(p) = median.iter().find(|p| !in_box(p)) {
                return Err(damaged(format!(
                    "stroke {n}'s median point {p:?} is outside the box"
                )));
            }
            strokes.push(HanziStroke { outline, median });
        }
        Ok(Hanzi {
            ch,
            source: source.to_string(),
            strokes,
        })
    }

    /// The strokes in the data's units.
    pub fn strokes(&self) -> &[HanziStroke] {
        &self.strokes
    }

    /// The strokes in paper millimetres for a character `size_mm` square centred on the
    /// origin (+y up the paper): the data's box scaled to `size_mm`.
    pub fn to_mm(&self, size_mm: f64) -> Vec<HanziStroke> {
        let s = size_mm / BOX_UNITS;
        let map = |p: Point| Point::new((p.x - BOX_CENTRE[0]) * s, (p.y - BOX_CENTRE[1]) * s);
        self.strokes
            .iter()
            .map(|st| {
                let mut outline = st.outline.clone();
                outline.apply_affine(kurbo::Affine::new([
                    s,
                    0.0,
                    0.0,
                    s,
                    -BOX_CENTRE[0] * s,
                    -BOX_CENTRE[1] * s,
                ]));
                let median = st
                    .median
                    .iter()
                    .map(|p| {
                        let q = map(Point::new(p[0], p[1]));
                        [q.x, q.y]
                    })
                    .collect();
                HanziStroke { outline, median }
            })
            .collect()
    }
}

/// The folder [`load`] reads before the shipped set when [`DATA_ENV`] is unset: `hanzi-writer-data`
/// in the platform's data folder for Maobi (`~/.local/share/maobi/` on Linux, `%APPDATA%\maobi\data\`
/// on Windows, `~/Library/Application Support/maobi/` on macOS).
pub fn default_dir() -> Option<PathBuf> {
    eframe::storage_dir("maobi").map(|d| d.join("hanzi-writer-data"))
}

/// `ch`'s data: from the folder [`DATA_ENV`] names (an error if it is no folder), else from
/// [`default_dir`] where it has the file, else from the shipped set.
pub fn load(ch: &str) -> Result<Hanzi, HanziError> {
    match std::env::var_os(DATA_ENV).filter(|v| !v.is_empty()) {
        Some(dir) => {
            let dir = PathBuf::from(dir);
            if !dir.is_dir() {
                return Err(HanziError::BadFolder {
                    path: dir.display().to_string(),
                    why: "no such folder (it names a folder of hanzi-writer-data's files, \
                          `永.json` and the others)"
                        .into(),
                });
            }
            load_from(Some(&dir), ch)
        }
        None => load_from(default_dir().as_deref(), ch),
    }
}

/// `ch`'s data from `dir` (where it holds `<ch>.json`), else from the shipped set.
pub fn load_from(dir: Option<&Path>, ch: &str) -> Result<Hanzi, HanziError> {
    let mut chars = ch.chars();
    let (Some(c), None) = (chars.next(), chars.next()) else {
        return Err(HanziError::NotOneCharacter(ch.to_string()));
    };
    if let Some(dir) = dir {
        let path = dir.join(format!("{c}.json"));
        match std::fs::read(&path) {
            Ok(bytes) => {
                let shown = path.display().to_string();
                let text = String::from_utf8(bytes).map_err(|_| HanziError::Damaged {
                    ch: c,
                    path: shown.clone(),
                    why: "it is not UTF-8 text".into(),
                })?;
                return Hanzi::parse(c, &shown, &text);
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => {
                return Err(HanziError::Damaged {
                    ch: c,
                    path: path.display().to_string(),
                    why: e.to_string(),
                })
            }
        }
    }
    if let Some((_, text)) = SHIPPED.iter().find(|(name, _)| name.chars().eq([c])) {
        return Hanzi::parse(
            c,
            &format!("the shipped practice set (host/data/hanzi/{c}.json)"),
            text,
        );
    }
    let looked = match dir {
        Some(d) => format!(
            "not in {} nor in the shipped practice set of {} characters",
            d.display(),
            SHIPPED.len()
        ),
        None => format!(
            "not in the shipped practice set of {} characters",
            SHIPPED.len()
        ),
    };
    Err(HanziError::Missing {
        ch: c,
        code: c as u32,
        looked,
    })
}

/// Darkness (1 - reflectance) from which a pixel counts as ink: in the brush's width measure
/// ([`WidthCurve`]) and in [`overlap`].
pub const INK_DARKNESS: f64 = 0.2;

/// Resolution (px/mm) of the width measure's renders.
const WIDTH_PX_PER_MM: f64 = 8.0;

/// Depths (fractions of the head's length) at which [`WidthCurve::measure`] presses the brush.
const DEPTH_FRACTIONS: [f64; 12] = [
    0.005, 0.01, 0.02, 0.04, 0.06, 0.08, 0.10, 0.13, 0.16, 0.20, 0.25, 0.30,
];

/// A brush's stroke width (mm) against its press (mm below touching), measured: a straight
/// 40 mm stroke at 60 mm/s at each depth, upright, rendered on sized paper, its ink band's
/// width (pixels at least [`INK_DARKNESS`] dark) taken across its middle 16 mm. Widths are
/// made non-decreasing with depth (a deeper press never asks for a narrower stroke).
#[derive(Clone, Debug)]
pub struct WidthCurve {
    points: Vec<(f64, f64)>,
}

impl WidthCurve {
    pub fn measure(params: &BrushParams) -> anyhow::Result<WidthCurve> {
        let head = params.length_mm as f64;
        let mut points = Vec::with_capacity(DEPTH_FRACTIONS.len());
        let mut widest: f64 = 0.0;
        for f in DEPTH_FRACTIONS {
            let depth = f * head;
            let text = format!(
                "format = \"maobi-stroke\"\nversion = 1\nhead_mm = {head}\nspeed_mm_s = 60.0\n\
                 [[stroke]]\nkeys = [\n  {{ at = [-25.0, 0.0], lift = 1.0 }},\n  \
                 {{ at = [-20.0, 0.0], depth = {depth} }},\n  {{ at = [20.0, 0.0], depth = {depth} }},\n  \
                 {{ at = [25.0, 0.0], lift = 1.0 }},\n]\n"
            );
            let track = Character::from_toml("width measure", &text)?.track("width measure")?;
            let frame = render::paper_frame(&track, params, WIDTH_PX_PER_MM)?;
            let (canvas, _) = render::render::<maobi_shared::Fx>(
                *params,
                &track,
                frame,
                PaperSpec::new(PaperKind::Sized),
            )
            .with_context(|| format!("measuring the brush's width at {depth:.2} mm"))?;
            let ink = ink_mask(&canvas.to_gray8());
            let mut widths: Vec<f64> = (-8..=8)
                .map(|x_mm| {
                    let [px, _] = frame.to_px(x_mm as f64, 0.0);
                    let col = (px as usize).min(frame.width - 1);
                    let n = (0..frame.height)
                        .filter(|&row| ink[row * frame.width + col])
                        .count();
                    n as f64 / WIDTH_PX_PER_MM
                })
                .collect();
            widths.sort_by(f64::total_cmp);
            widest = widest.max(widths[widths.len() / 2]);
            points.push((depth, widest));
        }
        Ok(WidthCurve { points })
    }

    /// (depth, width) pairs in mm, by depth.
    pub fn points(&self) -> &[(f64, f64)] {
        &self.points
    }

    /// The depth that lays a stroke `width` mm wide: interpolated between the measured
    /// points, the shallowest for a width at or below its width, the deepest above its.
    pub fn depth_for(&self, width: f64) -> f64 {
        let first = self.points[0];
        if width <= first.1 {
            return first.0;
        }
        for pair in self.points.windows(2) {
            let ((d0, w0), (d1, w1)) = (pair[0], pair[1]);
            if width <= w1 {
                return if w1 > w0 {
                    d0 + (d1 - d0) * (width - w0) / (w1 - w0)
                } else {
                    d0
                };
            }
        }
        self.points[self.points.len() - 1].0
    }
}

/// Which pixels of a grey image (255 = paper) are ink: at least [`INK_DARKNESS`] dark.
pub fn ink_mask(gray: &[u8]) -> Vec<bool> {
    let limit = ((1.0 - INK_DARKNESS) * 255.0).round() as u8;
    gray.iter().map(|&g| g <= limit).collect()
}

/// Which pixels of `frame` the character's outlines (mm) cover, by each pixel's centre.
pub fn outline_mask(strokes: &[HanziStroke], frame: &Frame) -> Vec<bool> {
    let mut mask = vec![false; frame.width * frame.height];
    for st in strokes {
        let b = st.outline.bounding_box();
        let [x0, y0] = frame.to_px(b.x0, b.y1);
        let [x1, y1] = frame.to_px(b.x1, b.y0);
        let cols = (x0.floor().max(0.0) as usize)..(x1.ceil().max(0.0) as usize).min(frame.width);
        let rows = (y0.floor().max(0.0) as usize)..(y1.ceil().max(0.0) as usize).min(frame.height);
        for row in rows {
            for col in cols.clone() {
                let x = frame.x0_mm + (col as f64 + 0.5) / frame.px_per_mm;
                let y = frame.y_top_mm - (row as f64 + 0.5) / frame.px_per_mm;
                if st.outline.contains(Point::new(x, y)) {
                    mask[row * frame.width + col] = true;
                }
            }
        }
    }
    mask
}

/// Intersection over union of two masks of one frame.
pub fn overlap(a: &[bool], b: &[bool]) -> f64 {
    let (mut both, mut either) = (0usize, 0usize);
    for (&x, &y) in a.iter().zip(b) {
        both += usize::from(x && y);
        either += usize::from(x || y);
    }
    if either == 0 {
        0.0
    } else {
        both as f64 / either as f64
    }
}

/// Half the width of the outline at `p` (inside it): the distance to its nearest edge.
fn half_width(outline: &BezPath, p: Point) -> f64 {
    let mut nearest = f64::INFINITY;
    let mut last = Point::ZERO;
    let mut start = Point::ZERO;
    let mut edge = |a: Point, b: Point| {
        let ab = b - a;
        let len2 = ab.hypot2();
        let t = if len2 > 0.0 {
            ((p - a).dot(ab) / len2).clamp(0.0, 1.0)
        } else {
            0.0
        };
        nearest = nearest.min((a + ab * t - p).hypot());
    };
    kurbo::flatten(outline.elements().iter().copied(), 0.01, |el| match el {
        PathEl::MoveTo(a) => {
            (last, start) = (a, a);
        }
        PathEl::LineTo(b) => {
            edge(last, b);
            last = b;
        }
        PathEl::ClosePath => {
            edge(last, start);
            last = start;
        }
        _ => {}
    });
    nearest
}

/// Writing speeds (mm/s) of [`stroke_file`]'s profile: the body (行筆), the slow entry and
/// blunt ending, and a tapering ending's flick out (出鋒).
const BODY_MM_S: f64 = 60.0;
const SLOW_MM_S: f64 = 35.0;
const FLICK_MM_S: f64 = 110.0;
/// The press-and-turn at a stroke's entry (頓筆, s) and the pause before a blunt ending's lift
/// (回鋒, s).
const ENTRY_S: f64 = 0.12;
const BLUNT_PAUSE_S: f64 = 0.08;
/// Longest gap between two keyframes along a median (mm): the press follows the outline's
/// width at least this often.
const KEY_SPACING_MM: f64 = 4.0;
/// A stroke whose last width is below this share of its widest tapers out (撇, 鉤): it is
/// flicked out fast, not paused and lifted.
const TAPER: f64 = 0.5;

/// Rounds of [`stroke_file`]'s press fit: each renders every stroke and corrects each
/// keyframe's depth by the ratio of the outline's width to the ink's there.
const FIT_ROUNDS: usize = 4;

/// One stroke's plan: its keyframes' points along the median, the outline's width at each,
/// their depths and times.
struct Plan {
    path: Vec<[f64; 2]>,
    widths: Vec<f64>,
    depths: Vec<f64>,
    tapers: bool,
}

impl Plan {
    /// The stroke's `[[stroke]]` table: entered from just above the paper with a press and a
    /// pause (起筆), written at an even pace (行筆), ended by a pause and a lift where it is
    /// blunt or a faster flick where it tapers (收筆).
    fn toml(&self, name: &str) -> String {
        let path = &self.path;
        let mut out = String::new();
        let _ = writeln!(out, "\n[[stroke]]\nname = \"{name}\"\nkeys = [");
        let start = path[0];
        let _ = writeln!(
            out,
            "  {{ at = [{:.2}, {:.2}], lift = 1.0, t = 0.0 }},",
            start[0], start[1]
        );
        let mut t = ENTRY_S;
        for (i, (p, depth)) in path.iter().zip(&self.depths).enumerate() {
            if i > 0 {
                let last_stretch = i + 2 >= path.len();
                let speed = if i == 1 {
                    SLOW_MM_S
                } else if last_stretch && self.tapers {
                    FLICK_MM_S
                } else if last_stretch {
                    SLOW_MM_S
                } else {
                    BODY_MM_S
                };
                t += dist(path[i - 1], *p) / speed;
            }
            let _ = writeln!(
                out,
                "  {{ at = [{:.2}, {:.2}], depth = {depth:.2}, t = {t:.3} }},",
                p[0], p[1]
            );
        }
        // A tapering stroke leaves along its direction, a blunt one pauses and lifts where it is.
        let (end, before) = (path[path.len() - 1], path[path.len() - 2]);
        let len = dist(before, end).max(1e-9);
        let (carry, lift_s) = if self.tapers {
            (1.5, 0.03)
        } else {
            (0.3, 0.1 + BLUNT_PAUSE_S)
        };
        let away = [
            end[0] + (end[0] - before[0]) / len * carry,
            end[1] + (end[1] - before[1]) / len * carry,
        ];
        let _ = writeln!(
            out,
            "  {{ at = [{:.2}, {:.2}], lift = 1.5, t = {:.3} }},",
            away[0],
            away[1],
            t + lift_s
        );
        out.push_str("]\n");
        out
    }
}

/// `hanzi` as a stroke file (`crate::strokes`' format) for the brush `params` (preset `brush`)
/// written `size_mm` square, centred on the origin: each stroke's path along its median,
/// upright (中鋒): entered from just above the paper with a press and a pause (起筆), written
/// at an even pace (行筆), ended by a pause and a lift where it is blunt or a faster flick
/// where it tapers (收筆). Each keyframe's press starts where `curve` (the brush's steady
/// width against its press) lays the outline's width there; then four rounds render each
/// stroke, measure the ink's width across the path at
/// each keyframe and correct the press by the ratio (a brush opens over time: a short stroke
/// needs more press than a long one for the same width).
pub fn stroke_file(
    hanzi: &Hanzi,
    brush: &str,
    params: &BrushParams,
    size_mm: f64,
    curve: &WidthCurve,
) -> anyhow::Result<String> {
    let head = params.length_mm as f64;
    let mut header = String::new();
    let _ = writeln!(
        header,
        "# {} written {size_mm} mm square for the {brush} brush (head {head} mm), from the median of each\n\
         # stroke of Make Me a Hanzi's data ({PACKAGE}, Arphic Public License), by\n\
         # `maobi stroke from-char {} --size-mm {size_mm} --brush {brush}`. Depths fitted to the\n\
         # outline's width with the brush itself; times from the profile of 起筆, 行筆, 收筆.",
        hanzi.ch, hanzi.ch
    );
    let _ = writeln!(
        header,
        "format = \"maobi-stroke\"\nversion = 1\nname = \"{}\"\nhead_mm = {head:.1}\nlift_mm = 10.0\n\
         travel_speed_mm_s = 150.0\npause_s = 0.15\nspeed_mm_s = {BODY_MM_S:.1}\ntilt_deg = 0.0\nazimuth_deg = 0.0",
        hanzi.ch
    );
    let deepest = DEPTH_FRACTIONS[DEPTH_FRACTIONS.len() - 1] * head;
    let mut out = header.clone();
    for (k, st) in hanzi.to_mm(size_mm).iter().enumerate() {
        let path = resample(&st.median);
        let widths: Vec<f64> = path
            .iter()
            .map(|p| 2.0 * half_width(&st.outline, Point::new(p[0], p[1])))
            .collect();
        let widest = widths.iter().copied().fold(0.0, f64::max);
        let mut plan = Plan {
            depths: widths.iter().map(|w| curve.depth_for(*w)).collect(),
            tapers: widths[widths.len() - 1] < TAPER * widest,
            path,
            widths,
        };
        let name = format!("stroke {}", k + 1);
        for _ in 0..FIT_ROUNDS {
            let text = format!("{header}{}", plan.toml(&name));
            let track = Character::from_toml(&name, &text)?.track(&name)?;
            let frame = render::paper_frame(&track, params, WIDTH_PX_PER_MM)?;
            let (canvas, _) = render::render::<maobi_shared::Fx>(
                *params,
                &track,
                frame,
                PaperSpec::new(PaperKind::Sized),
            )?;
            let ink = ink_mask(&canvas.to_gray8());
            for i in 0..plan.path.len() {
                let got = ink_width_across(&ink, &frame, &plan.path, i);
                let want = plan.widths[i];
                let ratio = if got > 0.0 { want / got } else { 2.0 };
                plan.depths[i] = (plan.depths[i] * ratio.clamp(0.5, 2.0)).clamp(0.05, deepest);
            }
        }
        out += &plan.toml(&name);
    }
    Ok(out)
}

/// The ink's width (mm) across the path at its point `i`: the run of ink pixels along the
/// normal to the path there that holds the point (or the nearest run within a millimetre).
fn ink_width_across(ink: &[bool], frame: &Frame, path: &[[f64; 2]], i: usize) -> f64 {
    let (a, b) = (path[i.saturating_sub(1)], path[(i + 1).min(path.len() - 1)]);
    let len = dist(a, b).max(1e-9);
    let normal = [-(b[1] - a[1]) / len, (b[0] - a[0]) / len];
    let p = path[i];
    let step = 1.0 / WIDTH_PX_PER_MM;
    let at = |s: f64| {
        let [x, y] = frame.to_px(p[0] + normal[0] * s, p[1] + normal[1] * s);
        if x < 0.0 || y < 0.0 || x >= frame.width as f64 || y >= frame.height as f64 {
            return false;
        }
        ink[y as usize * frame.width + x as usize]
    };
    // The run's seed: the point itself, or the nearest ink within a millimetre of it.
    let seed = (0..=(1.0 / step) as i32)
        .flat_map(|j| [j, -j])
        .map(|j| j as f64 * step)
        .find(|&s| at(s));
    let Some(seed) = seed else {
        return 0.0;
    };
    let reach = 30.0;
    let mut hi = seed;
    while hi < reach && at(hi + step) {
        hi += step;
    }
    let mut lo = seed;
    while lo > -reach && at(lo - step) {
        lo -= step;
    }
    hi - lo + step
}

fn dist(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

/// The median's points, with points added along any gap longer than [`KEY_SPACING_MM`], and
/// points closer than a tenth of a millimetre to the last one dropped.
fn resample(median: &[[f64; 2]]) -> Vec<[f64; 2]> {
    let mut out: Vec<[f64; 2]> = vec![median[0]];
    for &p in &median[1..] {
        let a = out[out.len() - 1];
        let d = dist(a, p);
        if d < 0.1 {
            continue;
        }
        let parts = (d / KEY_SPACING_MM).ceil() as usize;
        for j in 1..=parts {
            let f = j as f64 / parts as f64;
            out.push([a[0] + (p[0] - a[0]) * f, a[1] + (p[1] - a[1]) * f]);
        }
    }
    if out.len() < 2 {
        // A median shorter than a tenth of a millimetre: a dot, written as a press in place.
        let a = out[0];
        out.push([a[0] + 0.1, a[1]]);
    }
    out
}
