//! The brush in 3D, drawn with egui's painter: a perspective orbit camera, the paper plane
//! with its grid, the contact patch, the hair surface as shaded quads between neighbouring
//! layer rings (sorted back to front), the handle, the spine and the virtual skeleton.

use egui::epaint::{Mesh, Vertex, WHITE_UV};
use egui::{Color32, Pos2, Rect, Sense, Shape, Stroke, Vec2};
use maobi_shared::params::MAX_RING_NODES;
use maobi_shared::{Scalar, Vec3};

use crate::device::BrushFrame;

type V3 = [f64; 3];

fn sub(a: V3, b: V3) -> V3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
fn dot(a: V3, b: V3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn cross(a: V3, b: V3) -> V3 {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}
fn norm(a: V3) -> V3 {
    let n = dot(a, a).sqrt().max(1e-12);
    [a[0] / n, a[1] / n, a[2] / n]
}

/// Colours of the drawing (the screenshot checker looks for the hair colour).
pub const HAIR: Color32 = Color32::from_rgb(196, 150, 82);
pub const BACKGROUND: Color32 = Color32::from_rgb(38, 44, 56);
const PAPER: Color32 = Color32::from_rgb(226, 220, 204);

/// An orbit camera around a point that follows the brush.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct Orbit {
    /// Azimuth and elevation (radians).
    pub yaw: f64,
    pub pitch: f64,
    /// Distance from the target (mm).
    pub dist: f64,
}

impl Default for Orbit {
    fn default() -> Self {
        Orbit {
            yaw: -1.1,
            pitch: 0.35,
            dist: 150.0,
        }
    }
}

struct Camera {
    eye: V3,
    right: V3,
    up: V3,
    fwd: V3,
    focal: f64,
    center: Pos2,
}

impl Camera {
    fn new(o: &Orbit, target: V3, rect: Rect) -> Camera {
        let dir = [
            o.pitch.cos() * o.yaw.cos(),
            o.pitch.cos() * o.yaw.sin(),
            o.pitch.sin(),
        ];
        let eye = [
            target[0] + o.dist * dir[0],
            target[1] + o.dist * dir[1],
            target[2] + o.dist * dir[2],
        ];
        let fwd = norm(sub(target, eye));
        let right = norm(cross(fwd, [0.0, 0.0, 1.0]));
        let up = cross(right, fwd);
        // 40 degree vertical field of view.
        let focal = rect.height() as f64 * 0.5 / (20f64).to_radians().tan();
        Camera {
            eye,
            right,
            up,
            fwd,
            focal,
            center: rect.center(),
        }
    }
    /// Screen position and depth, or `None` behind the camera.
    fn project(&self, p: V3) -> Option<(Pos2, f64)> {
        let d = sub(p, self.eye);
        let z = dot(d, self.fwd);
        if z < 1.0 {
            return None;
        }
        let x = dot(d, self.right) * self.focal / z;
        let y = dot(d, self.up) * self.focal / z;
        Some((
            Pos2::new(self.center.x + x as f32, self.center.y - y as f32),
            z,
        ))
    }
}

fn v(p: Vec3<maobi_shared::Fx>) -> V3 {
    p.to_f64()
}

fn shade(c: Color32, k: f64) -> Color32 {
    let k = k.clamp(0.0, 1.0) as f32;
    Color32::from_rgb(
        (c.r() as f32 * k) as u8,
        (c.g() as f32 * k) as u8,
        (c.b() as f32 * k) as u8,
    )
}

fn lerp_color(a: Color32, b: Color32, t: f32) -> Color32 {
    let t = t.clamp(0.0, 1.0);
    let m = |x: u8, y: u8| (x as f32 + (y as f32 - x as f32) * t) as u8;
    Color32::from_rgb(m(a.r(), b.r()), m(a.g(), b.g()), m(a.b(), b.b()))
}

/// Draws the brush of `frame` in `ui`'s remaining space; drag to orbit, scroll to zoom,
/// double-click to reset the view.
pub fn show(ui: &mut egui::Ui, orbit: &mut Orbit, frame: Option<&BrushFrame>) -> Rect {
    let size = ui.available_size();
    let (rect, resp) = ui.allocate_exact_size(size, Sense::click_and_drag());
    if resp.dragged_by(egui::PointerButton::Primary) {
        let d = resp.drag_delta();
        orbit.yaw -= d.x as f64 * 0.01;
        orbit.pitch = (orbit.pitch + d.y as f64 * 0.01).clamp(-0.15, 1.5);
    }
    if resp.hovered() {
        let s = ui.input(|i| i.smooth_scroll_delta.y);
        if s != 0.0 {
            orbit.dist = (orbit.dist * (1.0 - s as f64 * 0.002)).clamp(30.0, 600.0);
        }
    }
    if resp.double_clicked() {
        *orbit = Orbit::default();
    }
    let painter = ui.painter_at(rect);
    painter.rect_filled(rect, 0.0, BACKGROUND);
    let Some(f) = frame else {
        painter.text(
            rect.center(),
            egui::Align2::CENTER_CENTER,
            "no brush state yet",
            egui::FontId::proportional(14.0),
            Color32::LIGHT_GRAY,
        );
        return rect;
    };
    let ferrule = f.pose.pos.to_f64();
    let target = [ferrule[0], ferrule[1], 18.0];
    let cam = Camera::new(orbit, target, rect);

    // Paper: a square around the ferrule, with a 10 mm grid.
    let (cx, cy) = (
        (ferrule[0] / 10.0).round() * 10.0,
        (ferrule[1] / 10.0).round() * 10.0,
    );
    let half = 60.0;
    let corners = [
        [cx - half, cy - half, 0.0],
        [cx + half, cy - half, 0.0],
        [cx + half, cy + half, 0.0],
        [cx - half, cy + half, 0.0],
    ];
    let pc: Option<Vec<Pos2>> = corners
        .iter()
        .map(|&c| cam.project(c).map(|p| p.0))
        .collect();
    if let Some(pc) = pc {
        painter.add(Shape::convex_polygon(pc, PAPER, Stroke::NONE));
    }
    let grid = Stroke::new(1.0, Color32::from_rgb(200, 192, 176));
    let mut g = -half;
    while g <= half {
        for (a, b) in [
            ([cx + g, cy - half, 0.0], [cx + g, cy + half, 0.0]),
            ([cx - half, cy + g, 0.0], [cx + half, cy + g, 0.0]),
        ] {
            if let (Some(a), Some(b)) = (cam.project(a), cam.project(b)) {
                painter.line_segment([a.0, b.0], grid);
            }
        }
        g += 10.0;
    }

    // Contact patch: this tick's footprint on the paper.
    let geom = f.geometry();
    geom.for_each_polygon(|_, poly| {
        let pts: Option<Vec<Pos2>> = poly
            .iter()
            .map(|p| cam.project([p.x.to_f64(), p.y.to_f64(), 0.0]).map(|q| q.0))
            .collect();
        if let Some(pts) = pts {
            painter.add(Shape::convex_polygon(
                pts,
                Color32::from_rgb(30, 26, 30),
                Stroke::NONE,
            ));
        }
    });

    // Shadow of the spine on the paper, for depth cues.
    let shadow: Vec<Pos2> = f
        .spine
        .iter()
        .filter_map(|p| {
            let p = v(*p);
            cam.project([p[0], p[1], 0.0]).map(|q| q.0)
        })
        .collect();
    painter.add(Shape::line(
        shadow,
        Stroke::new(3.0, Color32::from_black_alpha(60)),
    ));

    // Handle: a cylinder from the ferrule up the brush's axis, drawn as a thick segment.
    let up = {
        let d = f.pose.down().to_f64();
        [-d[0], -d[1], -d[2]]
    };
    let top = [
        ferrule[0] + up[0] * 70.0,
        ferrule[1] + up[1] * 70.0,
        ferrule[2] + up[2] * 70.0,
    ];
    if let (Some(a), Some(b)) = (cam.project(ferrule), cam.project(top)) {
        let r = f
            .layers
            .first()
            .map(|l| l.long_radius.to_f64())
            .unwrap_or(3.0)
            .max(1.0)
            * 1.15;
        let w = (2.0 * r * cam.focal / a.1) as f32;
        painter.line_segment([a.0, b.0], Stroke::new(w, Color32::from_rgb(92, 54, 34)));
        painter.circle_filled(b.0, w * 0.5, Color32::from_rgb(92, 54, 34));
    }

    // Hair surface: quads between rings i and i+1, back to front.
    let n = f.spine.len().min(f.layers.len());
    let k = f.ring_nodes.clamp(1, MAX_RING_NODES);
    let mut rings: Vec<[V3; MAX_RING_NODES]> = Vec::with_capacity(n);
    let mut buf = [Vec3::ZERO; MAX_RING_NODES];
    for i in 0..n {
        geom.ring(i, &mut buf);
        let mut r = [[0.0; 3]; MAX_RING_NODES];
        for j in 0..k {
            r[j] = v(buf[j]);
        }
        rings.push(r);
    }
    let light = norm([0.4, -0.5, 0.8]);
    struct Quad {
        pts: [Pos2; 4],
        depth: f64,
        color: Color32,
    }
    let mut quads = Vec::with_capacity(n * k);
    for i in 0..n.saturating_sub(1) {
        let wet = ((f.layers[i].wetness.to_f64() + f.layers[i + 1].wetness.to_f64()) * 0.5) as f32;
        let base = lerp_color(HAIR, Color32::from_rgb(60, 46, 36), wet * 0.45);
        let base = if f.in_contact[i + 1] {
            lerp_color(base, Color32::from_rgb(25, 20, 20), 0.5)
        } else {
            base
        };
        for j in 0..k {
            let j2 = (j + 1) % k;
            let c = [rings[i][j], rings[i][j2], rings[i + 1][j2], rings[i + 1][j]];
            let pr: Option<Vec<(Pos2, f64)>> = c.iter().map(|&p| cam.project(p)).collect();
            let Some(pr) = pr else { continue };
            let nrm = norm(cross(sub(c[2], c[0]), sub(c[3], c[1])));
            let lit = 0.35 + 0.65 * dot(nrm, light).abs();
            quads.push(Quad {
                pts: [pr[0].0, pr[1].0, pr[2].0, pr[3].0],
                depth: pr.iter().map(|p| p.1).sum::<f64>() * 0.25,
                color: shade(base, lit),
            });
        }
    }
    quads.sort_by(|a, b| b.depth.total_cmp(&a.depth));
    let mut mesh = Mesh::default();
    for q in &quads {
        let i0 = mesh.vertices.len() as u32;
        for p in q.pts {
            mesh.vertices.push(Vertex {
                pos: p,
                uv: WHITE_UV,
                color: q.color,
            });
        }
        mesh.indices
            .extend_from_slice(&[i0, i0 + 1, i0 + 2, i0, i0 + 2, i0 + 3]);
    }
    painter.add(Shape::mesh(mesh));

    // Spine (red) and virtual skeleton (blue), over the surface.
    let line = |pts: &[Vec3<maobi_shared::Fx>], color: Color32| {
        let p: Vec<Pos2> = pts
            .iter()
            .filter_map(|p| cam.project(v(*p)).map(|q| q.0))
            .collect();
        for q in &p {
            painter.circle_filled(*q, 2.0, color);
        }
        painter.add(Shape::line(p, Stroke::new(1.5, color)));
    };
    line(&f.skeleton, Color32::from_rgb(90, 150, 255));
    line(&f.spine, Color32::from_rgb(235, 70, 60));
    // Baxter & Lin's spines (their joints), in the skeleton's blue.
    for hair in &f.hairs {
        let p: Vec<Pos2> = hair
            .iter()
            .filter_map(|p| cam.project(p.to_f64()).map(|q| q.0))
            .collect();
        for q in &p {
            painter.circle_filled(*q, 1.5, Color32::from_rgb(90, 150, 255));
        }
        painter.add(Shape::line(
            p,
            Stroke::new(1.0, Color32::from_rgb(90, 150, 255)),
        ));
    }

    let info = format!(
        "contacts {}  depth {:.2} mm  |F_n| {:.3} N",
        f.contacts(),
        f.depth_mm,
        dot(f.force_normal, f.force_normal).sqrt()
    );
    painter.text(
        rect.left_top() + Vec2::new(6.0, 6.0),
        egui::Align2::LEFT_TOP,
        info,
        egui::FontId::monospace(11.0),
        Color32::from_gray(220),
    );
    painter.text(
        rect.left_bottom() + Vec2::new(6.0, -6.0),
        egui::Align2::LEFT_BOTTOM,
        "drag: orbit  wheel: zoom  double-click: reset",
        egui::FontId::proportional(10.0),
        Color32::from_gray(150),
    );
    rect
}
