//! The brush surface over Baxter & Lin's spines (004 §4), in the form the rest of Maobi
//! already draws and inks: one ellipse ring per layer ([`Layer`]), so the footprint
//! ([`crate::footprint::Geometry`]), the ink per layer and the app's drawing serve both
//! models unchanged.
//!
//! The paper skins its spines with a Catmull-Clark subdivision surface whose control vertices
//! follow the spines by matrix skinning, the weights set up by hand in a modelling tool. Maobi
//! has no modelling tool and needs the surface every tick on the CPU, so the surface is the
//! envelope of the spines' hair instead: each spine carries a bundle of hair (a [`Bundle`],
//! its radius tapering from root to tip), and layer i is the ellipse, in the plane across the
//! head at the same distance along every spine from its root, along the principal axes of
//! the spines' spread, holding the spines and as wide and as thick as their hair. A row of spines (a flat brush) gives a long, thin
//! ellipse across the row; a ring of spines (a round brush) a circle; spines splayed on the
//! paper a ring as wide as the splay. The strips of §4.2.2 (hairs interpolated between the
//! spines, eqs. 16-20) are [`strip_weights`] and [`strip_point`].

use crate::brush::Layer;
use crate::params::head_radius;
use crate::quat::Pose;
use crate::vec::Vec3;

/// Most spines one brush head has (the paper simulates "generally less than ten").
pub const MAX_SPINES: usize = 12;

/// Below this (mm) two points coincide: no direction, no spread.
const TINY_MM: f64 = 1e-9;

/// The radius of the hair bundle a spine carries, along it: `root_mm` at the ferrule,
/// swelling by `belly` and tapering to `tip_mm` ([`head_radius`], the profile of Liang's
/// round head).
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct Bundle {
    pub root_mm: f64,
    pub tip_mm: f64,
    pub belly: f64,
}

impl Bundle {
    /// The bundle's radius at the fraction `t` of the spine's length from its root (mm).
    pub fn radius_at(&self, t: f64) -> f64 {
        head_radius(self.root_mm, self.tip_mm, self.belly, t.clamp(0.0, 1.0))
    }
}

/// One spine as the surface sees it: its joints from the root (on the ferrule) to the tip,
/// world millimetres, and the bundle of hair it carries.
#[derive(Copy, Clone, Debug)]
pub struct SpineCurve<'a> {
    pub joints: &'a [Vec3<f64>],
    pub bundle: Bundle,
}

impl SpineCurve<'_> {
    /// The spine's length (mm): the sum of its segments.
    pub fn length(&self) -> f64 {
        self.joints.windows(2).map(|w| (w[1] - w[0]).norm()).sum()
    }

    /// The point at `distance` (mm) along the spine from its root and the unit tangent
    /// there, or `None` beyond its tip (or for a spine without segments).
    pub fn at_distance(&self, distance: f64) -> Option<(Vec3<f64>, Vec3<f64>)> {
        let mut walked = 0.0;
        let mut last = None;
        for w in self.joints.windows(2) {
            let seg = w[1] - w[0];
            let len = seg.norm();
            if len <= TINY_MM {
                continue;
            }
            let dir = seg.scale(1.0 / len);
            if distance <= walked + len {
                let along = (distance - walked).max(0.0);
                return Some((w[0] + dir.scale(along), dir));
            }
            walked += len;
            last = Some((w[1], dir));
        }
        // Within rounding of the tip: the tip.
        last.filter(|_| distance <= walked + 1e-9 * walked.max(1.0))
    }

    /// The point at the fraction `s` of the spine's length from its root (eq. 16's
    /// `p_i(s)`): the root for `s <= 0`, the tip for `s >= 1`.
    pub fn at_fraction(&self, s: f64) -> Vec3<f64> {
        let len = self.length();
        match self.at_distance(len * s.clamp(0.0, 1.0)) {
            Some((p, _)) => p,
            None => self.joints.last().copied().unwrap_or(Vec3::ZERO),
        }
    }
}

/// Fits the layers' rings to the spines: `centers[i]` and the geometry of `layers[i]` (axes
/// and radii; the ink fields are left as they are) for `n = min(centers.len(),
/// layers.len())` levels, level i at the distance `i / (n - 1)` of the longest spine's length
/// from the roots. A spine shorter than a level's distance has ended there and does not
/// count (a filbert's outer spines end above its middle ones, so its tip rounds). `pose` is
/// the handle's: its axes orient a ring whose spines give no direction (a single spine, or
/// spines gathered to a point). Returns `n` (0 when there are fewer than two levels or no
/// spine with a length).
pub fn skin(
    spines: &[SpineCurve<'_>],
    pose: &Pose<f64>,
    centers: &mut [Vec3<f64>],
    layers: &mut [Layer<f64>],
) -> usize {
    let n = centers.len().min(layers.len());
    let longest = spines.iter().map(SpineCurve::length).fold(0.0, f64::max);
    if n < 2 || longest <= TINY_MM {
        return 0;
    }
    let down = pose.down();
    let across = pose.rot.rotate(Vec3::Y);
    let side = pose.rot.rotate(Vec3::X);
    for (i, (center, layer)) in centers
        .iter_mut()
        .zip(layers.iter_mut())
        .enumerate()
        .take(n)
    {
        let distance = longest * i as f64 / (n - 1) as f64;
        let ring = fit_ring(spines, distance, down, across, side);
        *center = ring.center;
        layer.long_axis = ring.long_axis;
        layer.short_axis = ring.short_axis;
        layer.long_radius = ring.long_radius;
        layer.short_radius = ring.short_radius;
    }
    n
}

/// One layer's ring: an ellipse around `center` in the plane across the head.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct Ring {
    pub center: Vec3<f64>,
    pub long_axis: Vec3<f64>,
    pub short_axis: Vec3<f64>,
    pub long_radius: f64,
    pub short_radius: f64,
}

/// The ring at `distance` along the spines (see [`skin`]); `down`, `across` and `side` are
/// the handle's axes (unit).
pub fn fit_ring(
    spines: &[SpineCurve<'_>],
    distance: f64,
    down: Vec3<f64>,
    across: Vec3<f64>,
    side: Vec3<f64>,
) -> Ring {
    // The spines that reach this level: their points, tangents and bundle radii.
    let mut points = [Vec3::ZERO; MAX_SPINES];
    let mut radii = [0.0; MAX_SPINES];
    let mut m = 0;
    let mut tangent_sum = Vec3::ZERO;
    for spine in spines.iter().take(MAX_SPINES) {
        let len = spine.length();
        if let Some((p, t)) = spine.at_distance(distance) {
            points[m] = p;
            radii[m] = spine.bundle.radius_at(distance / len.max(TINY_MM));
            tangent_sum += t;
            m += 1;
        }
    }
    if m == 0 {
        // No spine reaches this far (only when `distance` exceeds every spine): a point at
        // the longest spine's tip.
        let tip = spines
            .iter()
            .max_by(|a, b| a.length().total_cmp(&b.length()))
            .and_then(|s| s.joints.last().copied())
            .unwrap_or(Vec3::ZERO);
        return Ring {
            center: tip,
            long_axis: across,
            short_axis: side,
            long_radius: 0.0,
            short_radius: 0.0,
        };
    }
    let points = &points[..m];
    let radii = &radii[..m];
    let inv_m = 1.0 / m as f64;
    let center = points
        .iter()
        .fold(Vec3::ZERO, |acc, p| acc + *p)
        .scale(inv_m);
    // The ring's plane is across the spines' mean direction; a basis in it starts from the
    // handle's across axis (a flat brush's width), so a ring keeps its orientation while the
    // spines give it none.
    let axis = tangent_sum.normalized_or_none(TINY_MM).unwrap_or(down);
    let e1 = (across - axis.scale(across.dot(axis)))
        .normalized_or_none(1e-6)
        .or_else(|| (side - axis.scale(side.dot(axis))).normalized_or_none(1e-6))
        .unwrap_or(across);
    let e2 = axis.cross(e1);
    // The spread of the spines across the plane: its principal axes are the ellipse's.
    let (mut cxx, mut cyy, mut cxy) = (0.0, 0.0, 0.0);
    for p in points {
        let d = *p - center;
        let (x, y) = (d.dot(e1), d.dot(e2));
        cxx += x * x;
        cyy += y * y;
        cxy += x * y;
    }
    let angle = 0.5 * libm::atan2(2.0 * cxy, cxx - cyy);
    let (s, c) = (libm::sin(angle), libm::cos(angle));
    let a = e1.scale(c) + e2.scale(s);
    let b = axis.cross(a);
    // An ellipse of the spread's own shape (its radii in the ratio of the spread's
    // deviations along the axes) through each spine's centre line, grown by that spine's
    // bundle; the ring is the largest of them along each axis. For a ring of spines (a round
    // head) that is the circle holding every bundle; for a row (a flat head) the ellipse as
    // long and as thick as the row's hair, which cuts the corners of the row's rounded
    // rectangle, as Liang's rings round any cross-section, and keeps the width and thickness
    // that set a stroke's.
    let (mut su, mut sv) = (0.0, 0.0);
    for p in points {
        let d = *p - center;
        su += d.dot(a) * d.dot(a);
        sv += d.dot(b) * d.dot(b);
    }
    let su = libm::sqrt(su * inv_m).max(TINY_MM);
    let sv = libm::sqrt(sv * inv_m).max(TINY_MM);
    let (mut ra, mut rb) = (0.0f64, 0.0f64);
    for (p, r) in points.iter().zip(radii) {
        let d = *p - center;
        let k = libm::hypot(d.dot(a) / su, d.dot(b) / sv);
        ra = ra.max(k * su + r);
        rb = rb.max(k * sv + r);
    }
    if ra >= rb {
        Ring {
            center,
            long_axis: a,
            short_axis: b,
            long_radius: ra,
            short_radius: rb,
        }
    } else {
        Ring {
            center,
            long_axis: b,
            short_axis: a,
            long_radius: rb,
            short_radius: ra,
        }
    }
}

/// The weights of eqs. 17-20 for a hair strip rooted at `root` among spines rooted at
/// `spine_roots` (all in the ferrule's cross-section, the plane z = 0 of the handle's frame),
/// into `out` (one per spine; the rest zeroed): minimise `sum |root - r_i|^2 w_i^2` subject to
/// `sum w_i = 1`, `w_i >= 0` and `sum w_i r_i = root` (the strip's root where it was placed),
/// so the nearer a spine, the more the strip follows it.
///
/// With the bounds inactive the problem is an equality-constrained quadratic with the closed
/// form `w = D^-1 A^T (A D^-1 A^T)^-1 c` (D the squared distances, A the constraints' rows:
/// ones, and the roots' coordinates along each direction the roots span: one for a row of
/// spines, two otherwise); a negative weight is fixed at zero and the rest solved again
/// (an active set, at most one pass per spine). A strip rooted
/// on a spine's root follows that spine alone; a root the spines cannot reach with
/// non-negative weights (outside their hull) gets the weights without eq. 20, `w_i ~ 1 /
/// |root - r_i|^2`.
pub fn strip_weights(root: Vec3<f64>, spine_roots: &[Vec3<f64>], out: &mut [f64]) {
    out.iter_mut().for_each(|w| *w = 0.0);
    let m = spine_roots.len().min(out.len()).min(MAX_SPINES);
    if m == 0 {
        return;
    }
    let roots = &spine_roots[..m];
    if let Some(on) = roots
        .iter()
        .position(|r| (*r - root).norm2() <= TINY_MM * TINY_MM)
    {
        out[on] = 1.0;
        return;
    }
    // The directions the roots span: the principal axes of their spread in the plane.
    let mean = roots
        .iter()
        .fold(Vec3::ZERO, |a, r| a + *r)
        .scale(1.0 / m as f64);
    let (mut cxx, mut cyy, mut cxy) = (0.0, 0.0, 0.0);
    for r in roots {
        let d = *r - mean;
        cxx += d.x * d.x;
        cyy += d.y * d.y;
        cxy += d.x * d.y;
    }
    let angle = 0.5 * libm::atan2(2.0 * cxy, cxx - cyy);
    let (s, c) = (libm::sin(angle), libm::cos(angle));
    let axes = [Vec3::new(c, s, 0.0), Vec3::new(-s, c, 0.0)];
    let spread = |a: Vec3<f64>| {
        roots
            .iter()
            .map(|r| (*r - mean).dot(a).abs())
            .fold(0.0, f64::max)
    };
    let spanned = axes.iter().filter(|a| spread(**a) > 1e-6).count();
    // Constraint rows: the sum, then the coordinates along the spanned axes.
    let row = |k: usize, i: usize| -> f64 {
        if k == 0 {
            1.0
        } else {
            (roots[i] - mean).dot(axes[k - 1])
        }
    };
    let rows = 1 + spanned;
    let target = [1.0, (root - mean).dot(axes[0]), (root - mean).dot(axes[1])];
    let inv_d: [f64; MAX_SPINES] = core::array::from_fn(|i| {
        if i < m {
            1.0 / (roots[i] - root).norm2()
        } else {
            0.0
        }
    });
    let mut free = [false; MAX_SPINES];
    free[..m].iter_mut().for_each(|f| *f = true);
    for _ in 0..m {
        // (A D^-1 A^T) lambda = c over the free weights, then w = D^-1 A^T lambda.
        let mut g = [[0.0; 3]; 3];
        for (k, gk) in g.iter_mut().enumerate().take(rows) {
            for (l, gkl) in gk.iter_mut().enumerate().take(rows) {
                *gkl = (0..m)
                    .filter(|&i| free[i])
                    .map(|i| row(k, i) * row(l, i) * inv_d[i])
                    .sum();
            }
        }
        let Some(lambda) = solve_small(g, target, rows) else {
            break;
        };
        let mut most_negative = None;
        for i in 0..m {
            out[i] = if free[i] {
                inv_d[i] * (0..rows).map(|k| row(k, i) * lambda[k]).sum::<f64>()
            } else {
                0.0
            };
            if out[i] < -1e-12 && most_negative.is_none_or(|j: usize| out[i] < out[j]) {
                most_negative = Some(i);
            }
        }
        match most_negative {
            None => {
                out[..m].iter_mut().for_each(|w| *w = w.max(0.0));
                return;
            }
            Some(i) => free[i] = false,
        }
    }
    // Unreachable with non-negative weights: eqs. 17-19 alone.
    let total: f64 = inv_d[..m].iter().sum();
    for (w, d) in out.iter_mut().zip(&inv_d[..m]) {
        *w = d / total;
    }
}

/// Solves the `n` x `n` system `a x = b` (n at most 3) by Gaussian elimination with partial
/// pivoting; `None` when it is singular.
fn solve_small(mut a: [[f64; 3]; 3], mut b: [f64; 3], n: usize) -> Option<[f64; 3]> {
    let scale = a.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
    for col in 0..n {
        let pivot = (col..n).max_by(|&i, &j| a[i][col].abs().total_cmp(&a[j][col].abs()))?;
        if a[pivot][col].abs() <= 1e-12 * scale {
            return None;
        }
        a.swap(col, pivot);
        b.swap(col, pivot);
        let (pivot_row, pivot_b) = (a[col], b[col]);
        for (row, rhs) in a.iter_mut().zip(b.iter_mut()).take(n).skip(col + 1) {
            let f = row[col] / pivot_row[col];
            for (x, p) in row.iter_mut().zip(pivot_row).take(n).skip(col) {
                *x -= f * p;
            }
            *rhs -= f * pivot_b;
        }
    }
    let mut x = [0.0; 3];
    for r in (0..n).rev() {
        let tail: f64 = (r + 1..n).map(|c| a[r][c] * x[c]).sum();
        x[r] = (b[r] - tail) / a[r][r];
    }
    Some(x)
}

/// A strip's point at the fraction `s` of its length (eqs. 16, 20): the weighted sum of the
/// spines' points at the same fraction of theirs.
pub fn strip_point(spines: &[SpineCurve<'_>], weights: &[f64], s: f64) -> Vec3<f64> {
    spines
        .iter()
        .zip(weights)
        .filter(|(_, w)| **w > 0.0)
        .fold(Vec3::ZERO, |acc, (spine, w)| {
            acc + spine.at_fraction(s).scale(*w)
        })
}
