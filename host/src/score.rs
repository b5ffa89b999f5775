//! Scoring a written character against the master's, stroke by stroke, as numbers a teacher
//! would agree with (the learning measures of Xiong et al. 2010 and the thesis's chapter 5):
//! which written stroke is which of the master's, in which order and direction; its shape
//! against the master's outline; where the character sits and how large; and the writing's
//! speed, its time in the air and its press, against the master's own writing of it by the
//! same brush (`maobi stroke from-char`).
//!
//! The written character is a pose track (a recording, a session, or a stroke file sampled)
//! run through the brush: a *written stroke* is a run of ticks in which the brush inks the
//! paper, ended once it has been off the paper for [`GAP_S`]. Each figure is a score in
//! [0, 1] with its measured value beside it; [`WEIGHTS`] states how the total is made.

use crate::hanzi::{self, Hanzi, HanziStroke};
use crate::offline;
use crate::paper::{Canvas, PaperKind, PaperSpec};
use crate::poses::PoseTrack;
use crate::raster::Frame;
use crate::render::Inker;
use crate::strokes::Character;
use maobi_shared::{BrushParams, Fx};

/// Off the paper this long (s), a written stroke has ended: longer than a brush skipping
/// over the paper within a stroke, shorter than a lift between two strokes.
pub const GAP_S: f64 = 0.08;

/// Resolution of the scoring's images (px/mm).
pub const PX_PER_MM: f64 = 5.0;

/// A written stroke matches one of the master's only if their paths lie within this share of
/// the character's size of each other on average.
pub const MATCH_OF_SIZE: f64 = 0.12;

/// Scales of the exponential scores, as shares of the character's size: the distance between
/// a written stroke's path and the master's median, and the character's offset.
pub const MEDIAN_OF_SIZE: f64 = 0.03;
pub const POSITION_OF_SIZE: f64 = 0.1;

/// Press difference (mm, RMS over the stroke's length) at which the press score is 1/e.
pub const PRESS_MM: f64 = 1.0;

/// How the total is made: each figure's weight (they sum to one).
pub const WEIGHTS: [(&str, f64); 7] = [
    ("order", 0.2),
    ("shape", 0.3),
    ("position", 0.1),
    ("size", 0.05),
    ("direction", 0.1),
    ("speed", 0.1),
    ("press", 0.15),
];

/// Points along each path at which two paths and two press profiles are compared.
pub const SAMPLES: usize = 32;

/// Ticks either side over which a written stroke's speed is taken.
const SPEED_SPAN: usize = 5;

/// The eight strokes of 永 as 永字八法 names them, in the five strokes of its writing order
/// (Make Me a Hanzi's): the dot; the horizontal, vertical and hook in one; the rising stroke
/// and the left-falling one in one; the short left-falling; the right-falling.
pub const YONG_EIGHT: [&str; 5] = ["側", "勒 努 趯", "策 掠", "啄", "磔"];

/// One written stroke, from a pose track run through the brush.
#[derive(Clone, Debug)]
pub struct WrittenStroke {
    /// When the brush first and last inked it (s on the track's clock).
    pub start_s: f64,
    pub end_s: f64,
    /// The ferrule's x-y (mm) at each inking tick, and its press there (mm below touching).
    pub path: Vec<[f64; 2]>,
    pub press: Vec<f64>,
    /// Its ink, alone, in the scoring frame.
    pub ink: Vec<bool>,
}

impl WrittenStroke {
    pub fn length_mm(&self) -> f64 {
        self.path.windows(2).map(|w| dist(w[0], w[1])).sum()
    }
    /// Mean speed along the path while inking (mm/s).
    pub fn speed_mm_s(&self) -> f64 {
        self.length_mm() / (self.end_s - self.start_s).max(1e-3)
    }

    /// The speed (mm/s) at each inking tick: over five ticks either side.
    pub fn speeds_mm_s(&self) -> Vec<f64> {
        let n = self.path.len();
        (0..n)
            .map(|i| {
                let (a, b) = (i.saturating_sub(SPEED_SPAN), (i + SPEED_SPAN).min(n - 1));
                if b > a {
                    let len: f64 = self.path[a..=b].windows(2).map(|w| dist(w[0], w[1])).sum();
                    len / ((b - a) as f64 * crate::poses::TICK_S)
                } else {
                    0.0
                }
            })
            .collect()
    }
}

/// Runs `track` through the brush `params` and cuts it into written strokes, each inked alone
/// into `frame`.
pub fn written_strokes(
    track: &PoseTrack,
    params: &BrushParams,
    frame: Frame,
) -> anyhow::Result<Vec<WrittenStroke>> {
    let head = params.length_mm as f64;
    let gap_ticks = (GAP_S / crate::poses::TICK_S).round() as usize;
    let mut inker = Inker::new(frame, params.layers as usize - 1);
    let blank = || Canvas::with_paper(frame.width, frame.height, PaperSpec::new(PaperKind::Sized));
    let mut canvas = blank();
    let mut strokes = Vec::new();
    let mut current: Option<WrittenStroke> = None;
    let mut since_ink = usize::MAX;
    let mut finish = |cur: &mut Option<WrittenStroke>, canvas: &mut Canvas| {
        if let Some(mut st) = cur.take() {
            st.ink = hanzi::ink_mask(&canvas.to_gray8());
            strokes.push(st);
        }
        *canvas = blank();
    };
    offline::simulate::<Fx>(*params, track, |tick| {
        let inked = inker.stamp(tick.brush, &mut canvas);
        if inked {
            let p = tick.pose;
            let [x, y, z] = p.pos.to_f64();
            let q = p.rot;
            // The handle's tilt: touching is at z = head cos(tilt).
            let cos_tilt = 1.0 - 2.0 * (q.x * q.x + q.y * q.y);
            let press = head * cos_tilt - z;
            let st = current.get_or_insert_with(|| WrittenStroke {
                start_s: tick.t,
                end_s: tick.t,
                path: Vec::new(),
                press: Vec::new(),
                ink: Vec::new(),
            });
            st.end_s = tick.t;
            st.path.push([x, y]);
            st.press.push(press);
            since_ink = 0;
        } else {
            since_ink = since_ink.saturating_add(1);
            if since_ink == gap_ticks {
                finish(&mut current, &mut canvas);
            }
        }
        Ok(())
    })?;
    finish(&mut current, &mut canvas);
    Ok(strokes)
}

/// One figure: its score in [0, 1], the measured value it comes from, and what it means.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Figure {
    pub name: &'static str,
    pub score: f64,
    pub value: f64,
    pub unit: &'static str,
    pub meaning: &'static str,
}

/// A model stroke's figures, where a written stroke matched it.
#[derive(Clone, Debug, serde::Serialize)]
pub struct StrokeReport {
    /// The master's stroke (from 1) and its name (永字八法's for 永).
    pub stroke: usize,
    pub name: String,
    /// The written stroke that matched it (from 1), if one did.
    pub written: Option<usize>,
    pub in_order: bool,
    pub backwards: bool,
    /// Intersection over union of the written stroke's ink with the master's outline.
    pub iou: f64,
    /// Mean distance between the written path and the master's median (mm).
    pub median_mm: f64,
    /// Cosine of the angle between the written and the master's start-to-end directions.
    pub direction_cos: f64,
    /// Written speed over the master's.
    pub speed_ratio: f64,
    /// RMS press difference along the stroke (mm).
    pub press_rms_mm: f64,
    /// Along the master's median ([`SAMPLES`] points, start to end): the press (mm) and the
    /// speed (mm/s) where the written stroke passed each point, and the master's own. Empty
    /// where the stroke is missing.
    pub press_mm: Vec<f64>,
    pub master_press_mm: Vec<f64>,
    pub speed_mm_s: Vec<f64>,
    pub master_speed_mm_s: Vec<f64>,
    /// The stroke's score: its shape, direction and press scores' mean (0 where missing).
    pub score: f64,
}

/// The whole report: the character's figures, the total, and each master stroke's figures.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Report {
    pub character: String,
    pub total: f64,
    pub figures: Vec<Figure>,
    pub strokes: Vec<StrokeReport>,
    /// Written strokes that matched none of the master's (from 1).
    pub extra: Vec<usize>,
    /// The character's offset from the master's (mm, x right, y up) and its size over the
    /// master's.
    pub offset_mm: [f64; 2],
    pub size_ratio: f64,
}

impl Report {
    pub fn figure(&self, name: &str) -> Option<&Figure> {
        self.figures.iter().find(|f| f.name == name)
    }

    /// The report as text: one line per figure, one per master stroke.
    pub fn to_text(&self) -> String {
        use std::fmt::Write as _;
        let mut out = format!("{}: total {:.3}\n", self.character, self.total);
        for f in &self.figures {
            let _ = writeln!(
                out,
                "  {:<9} {:.3}  ({:.3} {}: {})",
                f.name, f.score, f.value, f.unit, f.meaning
            );
        }
        for s in &self.strokes {
            match s.written {
                None => {
                    let _ = writeln!(out, "  stroke {} {}: missing", s.stroke, s.name);
                }
                Some(w) => {
                    let mut notes = Vec::new();
                    if !s.in_order {
                        notes.push("written out of order".to_string());
                    }
                    if s.backwards {
                        notes.push("written backwards".to_string());
                    }
                    let _ = writeln!(
                        out,
                        "  stroke {} {}: written {w}, score {:.3}, IoU {:.2}, median {:.1} mm, \
                         direction cos {:.2}, speed x{:.2}, press {:.2} mm{}{}",
                        s.stroke,
                        s.name,
                        s.score,
                        s.iou,
                        s.median_mm,
                        s.direction_cos,
                        s.speed_ratio,
                        s.press_rms_mm,
                        if notes.is_empty() { "" } else { "; " },
                        notes.join(", ")
                    );
                }
            }
        }
        for e in &self.extra {
            let _ = writeln!(
                out,
                "  written stroke {e}: extra (matches none of the master's)"
            );
        }
        out
    }
}

/// The master's side of a comparison: the character's data, its strokes in mm, its own
/// writing by the brush, and the frame every image is taken in.
pub struct Master {
    pub hanzi: Hanzi,
    pub size_mm: f64,
    pub params: BrushParams,
    pub frame: Frame,
    outlines: Vec<HanziStroke>,
    outline_masks: Vec<Vec<bool>>,
    own: Vec<WrittenStroke>,
    text: String,
    track: PoseTrack,
}

impl Master {
    /// `hanzi` written `size_mm` square by the brush `params` (preset `brush`): its stroke
    /// file as `maobi stroke from-char` writes it, run through the brush.
    pub fn new(
        hanzi: Hanzi,
        brush: &str,
        params: BrushParams,
        size_mm: f64,
    ) -> anyhow::Result<Master> {
        let curve = hanzi::WidthCurve::measure(&params)?;
        let text = hanzi::stroke_file(&hanzi, brush, &params, size_mm, &curve)?;
        Master::with_stroke_file(hanzi, params, size_mm, &text)
    }

    /// [`Master::new`] from the master's stroke file text (`stroke_file`'s).
    pub fn with_stroke_file(
        hanzi: Hanzi,
        params: BrushParams,
        size_mm: f64,
        text: &str,
    ) -> anyhow::Result<Master> {
        let half = size_mm;
        let frame = Frame::covering([-half, -half], [half, half], 0.0, PX_PER_MM);
        let outlines = hanzi.to_mm(size_mm);
        let outline_masks = outlines
            .iter()
            .map(|o| hanzi::outline_mask(std::slice::from_ref(o), &frame))
            .collect();
        let track = Character::from_toml("the master's strokes", text)?.track("the master")?;
        let own = written_strokes(&track, &params, frame)?;
        let text = text.to_string();
        if own.len() != outlines.len() {
            anyhow::bail!(
                "the master's own writing of {} came out as {} strokes, not its {}",
                hanzi.ch,
                own.len(),
                outlines.len()
            );
        }
        Ok(Master {
            hanzi,
            size_mm,
            params,
            frame,
            outlines,
            outline_masks,
            own,
            text,
            track,
        })
    }

    /// The master's stroke file (as `maobi stroke from-char` writes it).
    pub fn stroke_text(&self) -> &str {
        &self.text
    }

    /// The master's writing as a pose track: what "Watch" replays and "Guide me" leads along.
    pub fn track(&self) -> &PoseTrack {
        &self.track
    }

    /// The master's strokes in paper millimetres (outlines and medians).
    pub fn outlines(&self) -> &[HanziStroke] {
        &self.outlines
    }

    fn stroke_name(&self, k: usize) -> String {
        if self.hanzi.ch == '永' {
            YONG_EIGHT.get(k).map_or(String::new(), |s| s.to_string())
        } else {
            String::new()
        }
    }

    /// Scores the written pose track `track` against the master.
    pub fn score(&self, track: &PoseTrack) -> anyhow::Result<Report> {
        let written = written_strokes(track, &self.params, self.frame)?;
        if written.is_empty() {
            anyhow::bail!(
                "nothing was written: the brush never inked the paper ({} poses)",
                track.rows().len()
            );
        }
        Ok(self.score_strokes(&written))
    }

    /// Scores written strokes (from [`written_strokes`] in [`Master::frame`]).
    pub fn score_strokes(&self, written: &[WrittenStroke]) -> Report {
        let size = self.size_mm;
        // Where the character sits and how large: the paths its strokes inked along against
        // the master's own, each point weighed by the length it stands for (a slower hand
        // does not move the character).
        let (w_centre, w_spread) = centre_and_spread(written.iter().map(|s| s.path.as_slice()));
        let (m_centre, m_spread) = centre_and_spread(self.own.iter().map(|s| s.path.as_slice()));
        let offset = [w_centre[0] - m_centre[0], w_centre[1] - m_centre[1]];
        let size_ratio = if m_spread > 0.0 {
            w_spread / m_spread
        } else {
            1.0
        };
        // Everything else is compared with the offset taken out.
        let shift_px = [
            (offset[0] * PX_PER_MM).round() as i64,
            (-offset[1] * PX_PER_MM).round() as i64,
        ];
        let back = |p: [f64; 2]| [p[0] - offset[0], p[1] - offset[1]];
        let paths: Vec<Vec<[f64; 2]>> = written
            .iter()
            .map(|s| resample(&s.path.iter().map(|p| back(*p)).collect::<Vec<_>>()))
            .collect();
        let medians: Vec<Vec<[f64; 2]>> =
            self.outlines.iter().map(|o| resample(&o.median)).collect();

        // Which written stroke is which master stroke: the closest pairs first, direction
        // aside (a stroke written backwards is still that stroke).
        let mut pairs = Vec::new();
        for (i, p) in paths.iter().enumerate() {
            for (j, m) in medians.iter().enumerate() {
                pairs.push((path_distance(p, m), i, j));
            }
        }
        pairs.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)).then(a.2.cmp(&b.2)));
        let mut of_master: Vec<Option<usize>> = vec![None; medians.len()];
        let mut of_written: Vec<Option<usize>> = vec![None; paths.len()];
        for (d, i, j) in pairs {
            if d <= MATCH_OF_SIZE * size && of_written[i].is_none() && of_master[j].is_none() {
                of_written[i] = Some(j);
                of_master[j] = Some(i);
            }
        }
        // Order: the longest run of matched strokes written in the master's order keeps its
        // place; the others were written out of order.
        let sequence: Vec<usize> = of_written.iter().flatten().copied().collect();
        let in_order_set = longest_increasing(&sequence);

        let mut reports = Vec::new();
        let (mut shape_sum, mut dir_sum, mut press_sum, mut speed_sum) = (0.0, 0.0, 0.0, 0.0);
        let mut matched = 0usize;
        for (j, m) in medians.iter().enumerate() {
            let name = self.stroke_name(j);
            let Some(i) = of_master[j] else {
                reports.push(StrokeReport {
                    stroke: j + 1,
                    name,
                    written: None,
                    in_order: false,
                    backwards: false,
                    iou: 0.0,
                    median_mm: f64::NAN,
                    direction_cos: f64::NAN,
                    speed_ratio: f64::NAN,
                    press_rms_mm: f64::NAN,
                    press_mm: Vec::new(),
                    master_press_mm: Vec::new(),
                    speed_mm_s: Vec::new(),
                    master_speed_mm_s: Vec::new(),
                    score: 0.0,
                });
                continue;
            };
            matched += 1;
            let w = &written[i];
            let p = &paths[i];
            let ink = shifted(&w.ink, &self.frame, shift_px);
            let iou = hanzi::overlap(&ink, &self.outline_masks[j]);
            let median_mm = path_distance(p, m);
            // The overlap counts in full at what the brush itself reaches writing along the
            // master's median (the master's own writing of this stroke): a brush lays no
            // outline exactly.
            let own_iou = hanzi::overlap(&self.own[j].ink, &self.outline_masks[j]);
            let shape = 0.5 * (iou / own_iou.max(1e-9)).min(1.0)
                + 0.5 * (-median_mm / (MEDIAN_OF_SIZE * size)).exp();
            let along = |a: &[[f64; 2]]| [a[a.len() - 1][0] - a[0][0], a[a.len() - 1][1] - a[0][1]];
            let (wd, md) = (along(p), along(m));
            let norm = (wd[0].hypot(wd[1]) * md[0].hypot(md[1])).max(1e-9);
            let direction_cos = (wd[0] * md[0] + wd[1] * md[1]) / norm;
            // Backwards: its ends lie nearer the master's ends swapped than as they are.
            let (ws, we, ms, me) = (p[0], p[p.len() - 1], m[0], m[m.len() - 1]);
            let backwards = dist(ws, me) + dist(we, ms) < dist(ws, ms) + dist(we, me);
            let own = &self.own[j];
            let speed_ratio = w.speed_mm_s() / own.speed_mm_s().max(1e-9);
            let (wp, mp) = (
                along_median(m, &w.path, &w.press, offset),
                along_median(m, &own.path, &own.press, [0.0, 0.0]),
            );
            let press_rms_mm = (wp
                .iter()
                .zip(&mp)
                .map(|(a, b)| (a - b) * (a - b))
                .sum::<f64>()
                / SAMPLES as f64)
                .sqrt();
            let press = (-press_rms_mm / PRESS_MM).exp();
            let direction = (1.0 + direction_cos) / 2.0;
            let speed = (-speed_ratio.max(1e-9).ln().abs()).exp();
            shape_sum += shape;
            dir_sum += direction;
            press_sum += press;
            speed_sum += speed;
            reports.push(StrokeReport {
                stroke: j + 1,
                name,
                written: Some(i + 1),
                in_order: in_order_set.contains(&j),
                backwards,
                iou,
                median_mm,
                direction_cos,
                speed_ratio,
                press_rms_mm,
                speed_mm_s: along_median(m, &w.path, &w.speeds_mm_s(), offset),
                master_speed_mm_s: along_median(m, &own.path, &own.speeds_mm_s(), [0.0, 0.0]),
                press_mm: wp,
                master_press_mm: mp,
                score: (shape + direction + press) / 3.0,
            });
        }
        let extra: Vec<usize> = of_written
            .iter()
            .enumerate()
            .filter(|(_, m)| m.is_none())
            .map(|(i, _)| i + 1)
            .collect();
        let n_master = medians.len() as f64;
        let per_matched = |sum: f64| {
            if matched > 0 {
                sum / matched as f64
            } else {
                0.0
            }
        };
        // In the air between strokes: the written character's against the master's.
        let in_air = |s: &[WrittenStroke]| -> f64 {
            s.windows(2)
                .map(|w| (w[1].start_s - w[0].end_s).max(0.0))
                .sum()
        };
        let (w_air, m_air) = (in_air(written), in_air(&self.own));
        let air_ratio = if m_air > 0.0 { w_air / m_air } else { 1.0 };
        let air = (-air_ratio.max(1e-9).ln().abs()).exp();
        let speed_score = 0.5 * per_matched(speed_sum) + 0.5 * air;
        let order_value = in_order_set.len() as f64;
        // A per-stroke value's mean over the strokes that were written.
        let mean_matched = |value: fn(&StrokeReport) -> f64| {
            reports
                .iter()
                .filter(|r| r.written.is_some())
                .map(value)
                .sum::<f64>()
                / matched.max(1) as f64
        };
        let figures = vec![
            Figure {
                name: "order",
                score: order_value / (n_master + extra.len() as f64),
                value: order_value,
                unit: "strokes",
                meaning: "master strokes written, in the master's order (over the master's count plus extra strokes)",
            },
            Figure {
                name: "shape",
                score: shape_sum / n_master,
                value: mean_matched(|r| r.iou),
                unit: "IoU",
                meaning: "each stroke's ink against the master's outline (in full at the overlap the brush reaches along the master's median) and its path against the master's median; missing strokes score 0",
            },
            Figure {
                name: "position",
                score: (-offset[0].hypot(offset[1]) / (POSITION_OF_SIZE * size)).exp(),
                value: offset[0].hypot(offset[1]),
                unit: "mm",
                meaning: "how far the character (the paths its strokes inked along) sits from the master's",
            },
            Figure {
                name: "size",
                score: (-size_ratio.max(1e-9).ln().abs() / 0.25f64.ln_1p()).exp(),
                value: size_ratio,
                unit: "x",
                meaning: "the spread of the character's paths over the master's",
            },
            Figure {
                name: "direction",
                score: per_matched(dir_sum),
                value: reports.iter().filter(|r| r.backwards).count() as f64,
                unit: "backwards",
                meaning: "each stroke's start-to-end direction against the master's",
            },
            Figure {
                name: "speed",
                score: speed_score,
                value: mean_matched(|r| r.speed_ratio),
                unit: "x",
                meaning: "writing speed over the master's, and the time in the air between strokes over the master's",
            },
            Figure {
                name: "press",
                score: per_matched(press_sum),
                value: mean_matched(|r| r.press_rms_mm),
                unit: "mm RMS",
                meaning: "where the hand pressed and lifted along each stroke, against the master's",
            },
        ];
        let total = WEIGHTS
            .iter()
            .map(|(name, w)| {
                w * figures
                    .iter()
                    .find(|f| f.name == *name)
                    .map_or(0.0, |f| f.score)
            })
            .sum();
        Report {
            character: self.hanzi.ch.to_string(),
            total,
            figures,
            strokes: reports,
            extra,
            offset_mm: offset,
            size_ratio,
        }
    }
}

fn dist(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

/// `path` at [`SAMPLES`] points evenly spaced along its length.
fn resample(path: &[[f64; 2]]) -> Vec<[f64; 2]> {
    let total: f64 = path.windows(2).map(|w| dist(w[0], w[1])).sum();
    if path.len() < 2 || total <= 0.0 {
        return vec![path.first().copied().unwrap_or([0.0, 0.0]); SAMPLES];
    }
    let mut out = Vec::with_capacity(SAMPLES);
    let (mut seg, mut seg_start) = (0usize, 0.0);
    for k in 0..SAMPLES {
        let want = total * k as f64 / (SAMPLES - 1) as f64;
        while seg + 2 < path.len() && seg_start + dist(path[seg], path[seg + 1]) < want {
            seg_start += dist(path[seg], path[seg + 1]);
            seg += 1;
        }
        let (a, b) = (path[seg], path[seg + 1]);
        let len = dist(a, b);
        let f = if len > 0.0 {
            ((want - seg_start) / len).clamp(0.0, 1.0)
        } else {
            0.0
        };
        out.push([a[0] + (b[0] - a[0]) * f, a[1] + (b[1] - a[1]) * f]);
    }
    out
}

/// A per-tick value (the press, the speed) along the master's resampled median `median`: at
/// each of its points, the value where the stroke's path (moved back by `offset`) came
/// nearest to it. The same poses at any speed give the same press profile.
fn along_median(
    median: &[[f64; 2]],
    path: &[[f64; 2]],
    values: &[f64],
    offset: [f64; 2],
) -> Vec<f64> {
    median
        .iter()
        .map(|m| {
            path.iter()
                .zip(values)
                .map(|(p, d)| (dist([p[0] - offset[0], p[1] - offset[1]], *m), *d))
                .min_by(|a, b| a.0.total_cmp(&b.0))
                .map_or(0.0, |(_, d)| d)
        })
        .collect()
}

/// The mean distance from each of two resampled paths' points to the other path's nearest
/// point, both ways: the same whichever way either was written.
fn path_distance(a: &[[f64; 2]], b: &[[f64; 2]]) -> f64 {
    let one_way = |a: &[[f64; 2]], b: &[[f64; 2]]| {
        a.iter()
            .map(|p| b.iter().map(|q| dist(*p, *q)).fold(f64::INFINITY, f64::min))
            .sum::<f64>()
            / a.len() as f64
    };
    0.5 * (one_way(a, b) + one_way(b, a))
}

/// The centre (mm) of `paths` and their RMS distance from it (mm), each point weighed by half
/// the length of the segments either side of it.
fn centre_and_spread<'a>(paths: impl Iterator<Item = &'a [[f64; 2]]> + Clone) -> ([f64; 2], f64) {
    let weighed = |path: &'a [[f64; 2]]| {
        (0..path.len()).map(move |i| {
            let before = if i > 0 {
                dist(path[i - 1], path[i])
            } else {
                0.0
            };
            let after = if i + 1 < path.len() {
                dist(path[i], path[i + 1])
            } else {
                0.0
            };
            (path[i], 0.5 * (before + after))
        })
    };
    let (mut n, mut sx, mut sy) = (0.0, 0.0, 0.0);
    for (p, w) in paths.clone().flat_map(weighed) {
        n += w;
        sx += w * p[0];
        sy += w * p[1];
    }
    if n <= 0.0 {
        return ([0.0, 0.0], 0.0);
    }
    let c = [sx / n, sy / n];
    let s2: f64 = paths
        .flat_map(weighed)
        .map(|(p, w)| w * ((p[0] - c[0]).powi(2) + (p[1] - c[1]).powi(2)))
        .sum();
    (c, (s2 / n).sqrt())
}

/// `mask` moved back by `shift_px` (the character's offset in pixels: x right, y down).
fn shifted(mask: &[bool], frame: &Frame, shift_px: [i64; 2]) -> Vec<bool> {
    let (w, h) = (frame.width as i64, frame.height as i64);
    let mut out = vec![false; mask.len()];
    for (k, _) in mask.iter().enumerate().filter(|(_, &b)| b) {
        let (x, y) = (k as i64 % w - shift_px[0], k as i64 / w - shift_px[1]);
        if (0..w).contains(&x) && (0..h).contains(&y) {
            out[(y * w + x) as usize] = true;
        }
    }
    out
}

/// The master strokes (indices into `seq`'s values) on a longest strictly increasing run of
/// `seq`: those written in the master's order.
fn longest_increasing(seq: &[usize]) -> Vec<usize> {
    let n = seq.len();
    let mut len = vec![1usize; n];
    let mut prev = vec![usize::MAX; n];
    for i in 0..n {
        for j in 0..i {
            if seq[j] < seq[i] && len[j] + 1 > len[i] {
                len[i] = len[j] + 1;
                prev[i] = j;
            }
        }
    }
    let Some(mut i) = (0..n).max_by_key(|&i| (len[i], usize::MAX - i)) else {
        return Vec::new();
    };
    let mut out = vec![seq[i]];
    while prev[i] != usize::MAX {
        i = prev[i];
        out.push(seq[i]);
    }
    out.reverse();
    out
}

/// A session's journal as a pose track at the model's tick: each tick's pose, the last one
/// the journal noted at or before it.
pub fn journal_track(j: &crate::device::journal::Journal) -> anyhow::Result<PoseTrack> {
    use crate::poses::PoseRow;
    if j.ticks == 0 {
        anyhow::bail!("the session has no ticks: nothing was written");
    }
    let mut rows = Vec::with_capacity(j.ticks as usize);
    let mut next = j.poses.iter().peekable();
    let mut pose = j.start;
    for k in 0..=j.ticks {
        while let Some((_, p)) = next.next_if(|(t, _)| *t <= k) {
            pose = *p;
        }
        let q = pose.rot;
        rows.push(PoseRow {
            t: k as f64 * crate::poses::TICK_S,
            pos: pose.pos.to_f64(),
            rot: [q.w, q.x, q.y, q.z],
        });
    }
    let csv = crate::strokes::rows_to_csv(&rows);
    PoseTrack::from_reader("the session", csv.as_bytes()).map_err(|e| anyhow::anyhow!("{e}"))
}

/// The environment variable that names the score history file.
pub const HISTORY_ENV: &str = "MAOBI_SCORE_HISTORY";

/// The history file: [`HISTORY_ENV`], else `scores.csv` in the platform's data folder for
/// Maobi (where the app keeps its settings).
pub fn history_path() -> anyhow::Result<std::path::PathBuf> {
    if let Some(p) = std::env::var_os(HISTORY_ENV).filter(|v| !v.is_empty()) {
        return Ok(p.into());
    }
    eframe::storage_dir("maobi")
        .map(|d| d.join("scores.csv"))
        .ok_or_else(|| anyhow::anyhow!("no data folder for the score history: set {HISTORY_ENV}"))
}

/// The history's columns: when (UTC, RFC 3339), the character, the writing's source, the
/// total and each figure's score.
pub fn history_header() -> String {
    let mut cols = vec!["date", "character", "source", "total"];
    cols.extend(WEIGHTS.iter().map(|(n, _)| *n));
    cols.join(",")
}

/// Appends one attempt to the history CSV at `path` (created with its header if new).
pub fn append_history(path: &std::path::Path, report: &Report, source: &str) -> anyhow::Result<()> {
    use std::io::Write as _;
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir)
            .map_err(|e| anyhow::anyhow!("cannot create {}: {e}", dir.display()))?;
    }
    let new = !path.exists();
    let mut f = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(path)
        .map_err(|e| anyhow::anyhow!("cannot open {}: {e}", path.display()))?;
    let mut w = csv::Writer::from_writer(Vec::new());
    if new {
        w.write_record(history_header().split(','))?;
    }
    let mut rec = vec![
        jiff::Timestamp::now()
            .round(jiff::Unit::Second)?
            .to_string(),
        report.character.clone(),
        source.to_string(),
        format!("{:.4}", report.total),
    ];
    for (name, _) in WEIGHTS {
        rec.push(format!(
            "{:.4}",
            report.figure(name).map_or(0.0, |f| f.score)
        ));
    }
    w.write_record(&rec)?;
    let bytes = w.into_inner().map_err(|e| anyhow::anyhow!("{e}"))?;
    f.write_all(&bytes)
        .map_err(|e| anyhow::anyhow!("cannot write {}: {e}", path.display()))?;
    Ok(())
}

impl Report {
    /// The report as JSON: `character`, `total`, `figures` by name (each its score, value,
    /// unit and meaning), `strokes`, `extra`, `offset_mm`, `size_ratio`, `weights`.
    pub fn to_json(&self) -> serde_json::Value {
        let figures: serde_json::Map<String, serde_json::Value> = self
            .figures
            .iter()
            .map(|f| {
                (
                    f.name.to_string(),
                    serde_json::json!({
                        "score": f.score, "value": f.value, "unit": f.unit, "meaning": f.meaning
                    }),
                )
            })
            .collect();
        let weights: serde_json::Map<String, serde_json::Value> = WEIGHTS
            .iter()
            .map(|(n, w)| (n.to_string(), serde_json::json!(w)))
            .collect();
        serde_json::json!({
            "character": self.character,
            "total": self.total,
            "figures": figures,
            "weights": weights,
            "strokes": self.strokes,
            "extra": self.extra,
            "offset_mm": self.offset_mm,
            "size_ratio": self.size_ratio,
        })
    }
}
