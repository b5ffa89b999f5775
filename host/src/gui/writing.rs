//! The writing face of the app and what it draws over the paper.
//!
//! The app has two faces over one device and one paper ([`Face`]): the writing view a
//! calligrapher opens (the paper as large as the window allows, a one-row toolbar, keyboard
//! shortcuts, a small brush view) and the laboratory (devices, parameters, plots, file fields,
//! recordings, sessions, the stroke editor). Both draw the same paper; switching keeps
//! everything.
//!
//! Over the paper the writing view shows where the brush is before it touches
//! ([`BrushMark`]): Liang's writers found it hard to tell when the brush meets the paper
//! (thesis 5.2), which made the dot and the last stroke of 永 hard. Above the paper a ring
//! around the point the lowest hair would touch, tightening as the tip descends and gone
//! beyond [`HOVER_REACH_MM`]; on the paper the footprint's outline, and the press depth as a
//! number and a bar beside it.

use egui::{Color32, Pos2, Stroke};
use serde::{Deserialize, Serialize};

use maobi_shared::footprint::convex_hull;
use maobi_shared::vec::Vec2;
use maobi_shared::Scalar;

use super::canvas::PaperView;
use crate::device::BrushFrame;

/// Which face the app shows.
#[derive(Copy, Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum Face {
    /// The paper first: a compact toolbar, shortcuts, a small brush view.
    #[default]
    Writing,
    /// Devices, parameters, plots, files, recordings, sessions, the stroke editor.
    Laboratory,
}

impl Face {
    /// The other face (the toggle's target).
    pub fn other(self) -> Face {
        match self {
            Face::Writing => Face::Laboratory,
            Face::Laboratory => Face::Writing,
        }
    }
}

/// The practice grid drawn over the paper (not into the ink: a saved picture has none).
#[derive(Copy, Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum Grid {
    #[default]
    None,
    /// 米字格: the cell's cross and both diagonals.
    Mi,
    /// 田字格: the cell's cross.
    Tian,
    /// 九宫格: the cell in thirds each way.
    Jiugong,
}

impl Grid {
    pub const ALL: [Grid; 4] = [Grid::None, Grid::Mi, Grid::Tian, Grid::Jiugong];

    /// What the chooser shows (the name calligraphers use, and its reading).
    pub fn label(self) -> &'static str {
        match self {
            Grid::None => "no grid",
            Grid::Mi => "米字格 (mi)",
            Grid::Tian => "田字格 (tian)",
            Grid::Jiugong => "九宫格 (jiugong)",
        }
    }
}

/// Side of one grid cell (mm): a character of the size a learner copies with a large brush.
pub const GRID_CELL_MM: f64 = 100.0;

/// Height of the brush's lowest point above the paper (mm) beyond which no mark is drawn: a
/// hand that far up is not about to write.
pub const HOVER_REACH_MM: f64 = 30.0;

/// Radius of the hover ring (mm) when the tip is at the paper: about a fine tip's footprint.
pub const HOVER_RING_MIN_MM: f64 = 0.5;

/// How much the hover ring widens per mm of height: the ring is the section of a cone of
/// this half-angle's tangent standing on the point the tip would touch.
pub const HOVER_SPREAD: f64 = 0.5;

/// What the writing view draws for the brush this frame.
#[derive(Clone, Debug, PartialEq)]
pub enum BrushMark {
    /// The brush is above the paper, within reach.
    Above {
        /// Where its lowest point would touch (paper mm).
        at_mm: [f64; 2],
        /// How high that point is (mm).
        height_mm: f64,
        /// The ring's radius (mm): tightens as the brush descends.
        ring_mm: f64,
    },
    /// The brush touches the paper.
    Touching {
        /// Each band's footprint outline (paper mm, convex, counter-clockwise).
        outlines: Vec<Vec<[f64; 2]>>,
        /// Where the depth label goes: the footprint's rightmost point (paper mm).
        label_at_mm: [f64; 2],
        /// How far the handle is pressed ([`press_depth_mm`]).
        depth_mm: f64,
    },
}

/// The mark for `frame` of a brush whose hair is `length_mm` long: `None` when the brush is
/// beyond [`HOVER_REACH_MM`] or the frame has no geometry.
pub fn brush_mark(frame: &BrushFrame, length_mm: f64) -> Option<BrushMark> {
    let eps = frame.eps.to_f64();
    // Every surface point the frame carries: the layer rings of Liang's brush, the hair
    // joints of Baxter & Lin's.
    let mut points: Vec<[f64; 3]> = Vec::new();
    let g = frame.geometry();
    let n = frame.spine.len().min(frame.layers.len());
    let mut ring = [maobi_shared::vec::Vec3::ZERO; maobi_shared::params::MAX_RING_NODES];
    for i in 0..n {
        points.push(frame.spine[i].to_f64());
        let k = g.ring(i, &mut ring);
        points.extend(ring[..k].iter().map(|p| p.to_f64()));
    }
    points.extend(frame.hairs.iter().flatten().map(|p| [p.x, p.y, p.z]));
    let lowest = points
        .iter()
        .copied()
        .filter(|p| p.iter().all(|v| v.is_finite()))
        .min_by(|a, b| a[2].total_cmp(&b[2]))?;

    let mut outlines: Vec<Vec<[f64; 2]>> = Vec::new();
    if n >= 2 {
        g.for_each_polygon(|_, poly| {
            outlines.push(poly.iter().map(|p| [p.x.to_f64(), p.y.to_f64()]).collect());
        });
    } else {
        // Baxter & Lin's brush: the hull of the joints at or below the inking height.
        let mut low: Vec<Vec2<f64>> = points
            .iter()
            .filter(|p| p[2] <= eps)
            .map(|p| Vec2::new(p[0], p[1]))
            .collect();
        if low.len() >= 3 {
            let mut hull = vec![Vec2::new(0.0, 0.0); low.len() + 1];
            let h = convex_hull(&mut low, &mut hull);
            if h >= 3 {
                outlines.push(hull[..h].iter().map(|p| [p.x, p.y]).collect());
            }
        }
    }
    if !outlines.is_empty() || lowest[2] <= eps {
        let label_at_mm = outlines
            .iter()
            .flatten()
            .copied()
            .max_by(|a, b| a[0].total_cmp(&b[0]))
            .unwrap_or([lowest[0], lowest[1]]);
        return Some(BrushMark::Touching {
            outlines,
            label_at_mm,
            depth_mm: press_depth_mm(frame, length_mm),
        });
    }
    let height_mm = lowest[2].max(0.0);
    if height_mm > HOVER_REACH_MM {
        return None;
    }
    Some(BrushMark::Above {
        at_mm: [lowest[0], lowest[1]],
        height_mm,
        ring_mm: HOVER_RING_MIN_MM + HOVER_SPREAD * height_mm,
    })
}

/// How far the handle is pressed (mm): how far below the paper the tip of the brush would be
/// if it hung straight from the ferrule, as it does at rest. The same for every brush model,
/// and what a writer means by pressing 3 mm.
pub fn press_depth_mm(frame: &BrushFrame, length_mm: f64) -> f64 {
    let down = frame.pose.down().to_f64();
    let tip_z = frame.pose.pos.to_f64()[2] + down[2] * length_mm;
    (-tip_z).max(0.0)
}

/// Draws `mark` over the paper view. `full_depth_mm` is the depth at which the bar is full
/// (the hair's length: a brush cannot be pressed further).
pub fn draw_mark(painter: &egui::Painter, paper: &PaperView, mark: &BrushMark, full_depth_mm: f64) {
    let to = |p: [f64; 2]| paper.mm_to_screen(p[0], p[1]);
    // Screen points per paper mm at the current zoom.
    let per_mm = (to([1.0, 0.0]).x - to([0.0, 0.0]).x).abs();
    match mark {
        BrushMark::Above {
            at_mm,
            height_mm,
            ring_mm,
        } => {
            let fade = (1.0 - height_mm / HOVER_REACH_MM).clamp(0.0, 1.0);
            let alpha = (60.0 + 170.0 * fade) as u8;
            let c = Color32::from_rgba_unmultiplied(40, 90, 200, alpha);
            let at = to(*at_mm);
            painter.circle_stroke(at, (*ring_mm as f32 * per_mm).max(3.0), Stroke::new(1.5, c));
            painter.circle_filled(at, 1.5, c);
        }
        BrushMark::Touching {
            outlines,
            label_at_mm,
            depth_mm,
        } => {
            let c = Color32::from_rgb(200, 50, 40);
            for o in outlines {
                let pts: Vec<Pos2> = o.iter().map(|p| to(*p)).collect();
                painter.add(egui::Shape::closed_line(pts, Stroke::new(1.0, c)));
            }
            // The depth: a number and a bar beside the footprint.
            let at = to(*label_at_mm) + egui::vec2(12.0, 0.0);
            let bar_h = 40.0;
            let full = full_depth_mm.max(1e-3);
            let share = (depth_mm / full).clamp(0.0, 1.0) as f32;
            let frame =
                egui::Rect::from_min_size(at + egui::vec2(0.0, -bar_h), egui::vec2(6.0, bar_h));
            painter.rect_stroke(frame, 0.0, Stroke::new(1.0, c), egui::StrokeKind::Outside);
            let fill = egui::Rect::from_min_max(
                egui::pos2(frame.min.x, frame.max.y - bar_h * share),
                frame.max,
            );
            painter.rect_filled(fill, 0.0, c);
            painter.text(
                at + egui::vec2(10.0, -bar_h / 2.0),
                egui::Align2::LEFT_CENTER,
                format!("{depth_mm:.1} mm"),
                egui::FontId::proportional(13.0),
                c,
            );
        }
    }
}

/// Draws `grid` over the paper view: the cells of [`GRID_CELL_MM`] that lie wholly on the
/// paper, one centred on its middle (where the hand starts) and the rest tiled from it.
pub fn draw_grid(painter: &egui::Painter, paper: &PaperView, grid: Grid) {
    if grid == Grid::None {
        return;
    }
    let f = paper.frame();
    let (x0, y1) = (f.x0_mm, f.y_top_mm);
    let (x1, y0) = (
        x0 + f.width as f64 / f.px_per_mm,
        y1 - f.height as f64 / f.px_per_mm,
    );
    let (cx, cy) = ((x0 + x1) / 2.0, (y0 + y1) / 2.0);
    let s = GRID_CELL_MM;
    // Cells whose centres are this many cells from the middle still fit.
    let nx = (((x1 - x0) / s - 1.0) / 2.0).floor() as i64;
    let ny = (((y1 - y0) / s - 1.0) / 2.0).floor() as i64;
    let outer = Stroke::new(1.2, Color32::from_rgba_unmultiplied(190, 40, 30, 150));
    let inner = Stroke::new(1.0, Color32::from_rgba_unmultiplied(190, 40, 30, 70));
    let line = |a: [f64; 2], b: [f64; 2], s: Stroke| {
        painter.line_segment(
            [
                paper.mm_to_screen(a[0], a[1]),
                paper.mm_to_screen(b[0], b[1]),
            ],
            s,
        );
    };
    for i in -nx..=nx {
        for j in -ny..=ny {
            let (ax, ay) = (cx + i as f64 * s - s / 2.0, cy + j as f64 * s - s / 2.0);
            let (bx, by) = (ax + s, ay + s);
            line([ax, ay], [bx, ay], outer);
            line([bx, ay], [bx, by], outer);
            line([bx, by], [ax, by], outer);
            line([ax, by], [ax, ay], outer);
            let (mx, my) = ((ax + bx) / 2.0, (ay + by) / 2.0);
            match grid {
                Grid::Mi | Grid::Tian => {
                    line([mx, ay], [mx, by], inner);
                    line([ax, my], [bx, my], inner);
                    if grid == Grid::Mi {
                        line([ax, ay], [bx, by], inner);
                        line([ax, by], [bx, ay], inner);
                    }
                }
                Grid::Jiugong => {
                    for t in [1.0 / 3.0, 2.0 / 3.0] {
                        line([ax + s * t, ay], [ax + s * t, by], inner);
                        line([ax, ay + s * t], [bx, ay + s * t], inner);
                    }
                }
                Grid::None => {}
            }
        }
    }
}
