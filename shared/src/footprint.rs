//! The footprint (SPEC D): the part of the brush surface within epsilon of the paper, seen
//! orthographically from above, as one convex polygon per band of surface between two
//! neighbouring layer rings.
//!
//! Each band is the convex hull of its two rings (the frustum the hairs fill between layer i
//! and layer i+1). Its part at or below `z = eps` projects onto the paper as the convex hull
//! of: the ring nodes at or below `eps`, and the points where the band's edges (ring edges,
//! and the straight and diagonal edges between the rings) cross `z = eps`. Host and device
//! compute it with this same code, so the ink the GUI paints from a state frame is the ink the
//! device's model made.

use crate::brush::{Brush, Layer};
use crate::params::MAX_RING_NODES;
use crate::scalar::Scalar;
use crate::vec::{Vec2, Vec3};

/// cos and sin of 2 pi j / 32 (printed to full f64 precision by a script, hence the literals) (eq. 3-21's angles for K = 32; other K take every (32/K)-th).
#[allow(clippy::approx_constant)]
const TRIG32: [(f64, f64); 32] = [
    (1.0, 0.0),
    (0.9807852804032304, 0.19509032201612825),
    (0.9238795325112867, 0.3826834323650898),
    (0.8314696123025452, 0.5555702330196022),
    (0.7071067811865476, 0.7071067811865475),
    (0.5555702330196023, 0.8314696123025452),
    (0.38268343236508984, 0.9238795325112867),
    (0.19509032201612833, 0.9807852804032304),
    (6.123233995736766e-17, 1.0),
    (-0.1950903220161282, 0.9807852804032304),
    (-0.3826834323650897, 0.9238795325112867),
    (-0.555570233019602, 0.8314696123025455),
    (-0.7071067811865475, 0.7071067811865476),
    (-0.8314696123025453, 0.5555702330196022),
    (-0.9238795325112867, 0.3826834323650899),
    (-0.9807852804032304, 0.1950903220161286),
    (-1.0, 1.2246467991473532e-16),
    (-0.9807852804032304, -0.19509032201612836),
    (-0.9238795325112868, -0.38268343236508967),
    (-0.8314696123025455, -0.555570233019602),
    (-0.7071067811865477, -0.7071067811865475),
    (-0.5555702330196022, -0.8314696123025452),
    (-0.38268343236509034, -0.9238795325112865),
    (-0.19509032201612866, -0.9807852804032303),
    (-1.8369701987210297e-16, -1.0),
    (0.1950903220161283, -0.9807852804032304),
    (0.38268343236509, -0.9238795325112866),
    (0.5555702330196018, -0.8314696123025455),
    (0.7071067811865474, -0.7071067811865477),
    (0.8314696123025452, -0.5555702330196022),
    (0.9238795325112865, -0.3826834323650904),
    (0.9807852804032303, -0.19509032201612872),
];

/// Most candidate points one band can produce (2K nodes + 4K edge crossings).
pub const MAX_CANDIDATES: usize = 6 * MAX_RING_NODES;

/// Surface node G_{i,j} of eq. 3-21.
#[inline]
pub fn ring_node<S: Scalar>(center: Vec3<S>, layer: &Layer<S>, j: usize, k: usize) -> Vec3<S> {
    let step = MAX_RING_NODES / k.clamp(1, MAX_RING_NODES);
    let (c, s) = TRIG32[(j * step) % MAX_RING_NODES];
    center
        + layer.long_axis.scale(layer.long_radius * S::from_f64(c))
        + layer.short_axis.scale(layer.short_radius * S::from_f64(s))
}

/// The geometry the footprint is computed from: what a brush-state frame carries, so the host
/// can rebuild the footprint from the device's state with this same code.
#[derive(Copy, Clone, Debug)]
pub struct Geometry<'a, S> {
    /// Spine masses S_i (mm), S_0 the ferrule.
    pub spine: &'a [Vec3<S>],
    /// Each layer's ellipse, one per spine mass.
    pub layers: &'a [Layer<S>],
    /// K, nodes per ring (4, 8, 16 or 32).
    pub ring_nodes: usize,
    /// Surface at or below this height leaves ink (mm).
    pub eps: S,
}

impl<'a, S: Scalar> Geometry<'a, S> {
    /// The geometry of a live brush.
    pub fn of(brush: &'a Brush<S>) -> Self {
        Geometry {
            spine: brush.spine(),
            layers: brush.layers(),
            ring_nodes: brush.ring_nodes(),
            eps: S::from_f32(brush.params().footprint_eps_mm),
        }
    }

    /// All K nodes of layer i's ring.
    pub fn ring(&self, i: usize, out: &mut [Vec3<S>; MAX_RING_NODES]) -> usize {
        let k = self.ring_nodes.clamp(1, MAX_RING_NODES);
        let center = self.spine[i];
        let layer = &self.layers[i];
        for (j, o) in out.iter_mut().enumerate().take(k) {
            *o = ring_node(center, layer, j, k);
        }
        k
    }

    /// Calls `f(band, polygon)` for every band with a non-empty footprint, band i lying
    /// between layers i and i+1. Polygons are convex, counter-clockwise, in paper millimetres.
    pub fn for_each_polygon<F: FnMut(usize, &[Vec2<S>])>(&self, mut f: F) {
        let n = self.spine.len().min(self.layers.len());
        if n < 2 {
            return;
        }
        let k = self.ring_nodes.clamp(1, MAX_RING_NODES);
        let eps = self.eps;
        let mut a = [Vec3::ZERO; MAX_RING_NODES];
        let mut b = [Vec3::ZERO; MAX_RING_NODES];
        let mut cand = [Vec2::new(S::ZERO, S::ZERO); MAX_CANDIDATES];
        let mut hull = [Vec2::new(S::ZERO, S::ZERO); MAX_CANDIDATES + 1];
        self.ring(0, &mut a);
        let mut low_a = a[..k].iter().any(|p| p.z <= eps);
        for i in 0..n - 1 {
            self.ring(i + 1, &mut b);
            let low_b = b[..k].iter().any(|p| p.z <= eps);
            if low_a || low_b {
                let m = band_candidates(&a[..k], &b[..k], eps, &mut cand);
                let h = convex_hull(&mut cand[..m], &mut hull);
                if h >= 3 {
                    f(i, &hull[..h]);
                }
            }
            a = b;
            low_a = low_b;
        }
    }
}

/// All K nodes of layer i's ring of a live brush.
pub fn ring<S: Scalar>(brush: &Brush<S>, i: usize, out: &mut [Vec3<S>; MAX_RING_NODES]) -> usize {
    Geometry::of(brush).ring(i, out)
}

/// [`Geometry::for_each_polygon`] for a live brush.
pub fn for_each_polygon<S: Scalar, F: FnMut(usize, &[Vec2<S>])>(brush: &Brush<S>, f: F) {
    Geometry::of(brush).for_each_polygon(f)
}

/// Candidate points of one band's clipped projection; returns how many were written.
fn band_candidates<S: Scalar>(
    a: &[Vec3<S>],
    b: &[Vec3<S>],
    eps: S,
    out: &mut [Vec2<S>; MAX_CANDIDATES],
) -> usize {
    let k = a.len();
    let mut m = 0;
    let mut push = |p: Vec3<S>, m: &mut usize| {
        if *m < MAX_CANDIDATES {
            out[*m] = Vec2::new(p.x, p.y);
            *m += 1;
        }
    };
    for ring in [a, b] {
        for p in ring {
            if p.z <= eps {
                push(*p, &mut m);
            }
        }
    }
    for j in 0..k {
        let jn = (j + 1) % k;
        for (p, q) in [(a[j], a[jn]), (b[j], b[jn]), (a[j], b[j]), (a[j], b[jn])] {
            if (p.z <= eps) != (q.z <= eps) {
                let t = (eps - p.z).div(q.z - p.z);
                push(Vec3::lerp(p, q, t), &mut m);
            }
        }
    }
    m
}

/// Convex hull (Andrew's monotone chain) of `pts` (reordered in place) into `out`,
/// counter-clockwise, without repeated or collinear points. Returns the vertex count; `out`
/// must hold `pts.len() + 1` points (a shorter `out` is a caller bug: it asserts in debug
/// builds and yields an empty hull in release rather than panicking on the device).
pub fn convex_hull<S: Scalar>(pts: &mut [Vec2<S>], out: &mut [Vec2<S>]) -> usize {
    let n = pts.len();
    debug_assert!(
        out.len() > n,
        "convex_hull: `out` must hold pts.len() + 1 points"
    );
    if n < 3 || out.len() < n + 1 {
        return 0;
    }
    pts.sort_unstable_by(|p, q| {
        p.x.partial_cmp(&q.x)
            .unwrap_or(core::cmp::Ordering::Equal)
            .then(p.y.partial_cmp(&q.y).unwrap_or(core::cmp::Ordering::Equal))
    });
    let mut h = 0;
    for &p in pts.iter() {
        while h >= 2 && Vec2::orient(out[h - 2], out[h - 1], p) <= S::ZERO {
            h -= 1;
        }
        out[h] = p;
        h += 1;
    }
    let lower = h + 1;
    for &p in pts.iter().rev().skip(1) {
        while h >= lower && Vec2::orient(out[h - 2], out[h - 1], p) <= S::ZERO {
            h -= 1;
        }
        out[h] = p;
        h += 1;
    }
    // The last point repeats the first.
    h.saturating_sub(1)
}

/// Area of a simple polygon (mm^2, positive when counter-clockwise).
pub fn polygon_area<S: Scalar>(poly: &[Vec2<S>]) -> f64 {
    let n = poly.len();
    let mut a = 0.0;
    for i in 0..n {
        let p = poly[i];
        let q = poly[(i + 1) % n];
        a += p.x.to_f64() * q.y.to_f64() - q.x.to_f64() * p.y.to_f64();
    }
    0.5 * a
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hull_of_square_with_interior_points() {
        let mut pts = [
            Vec2::new(0.0, 0.0),
            Vec2::new(1.0, 0.0),
            Vec2::new(0.5, 0.5),
            Vec2::new(1.0, 1.0),
            Vec2::new(0.0, 1.0),
            Vec2::new(0.5, 0.0),
            Vec2::new(0.25, 0.75),
        ];
        let mut out = [Vec2::new(0.0f64, 0.0); 8];
        let h = convex_hull(&mut pts, &mut out);
        assert_eq!(h, 4);
        assert!((polygon_area(&out[..h]) - 1.0).abs() < 1e-12);
    }

    #[test]
    fn hull_of_degenerate_input_is_empty() {
        let mut pts = [
            Vec2::new(0.0, 0.0),
            Vec2::new(1.0, 1.0),
            Vec2::new(2.0, 2.0),
        ];
        let mut out = [Vec2::new(0.0f64, 0.0); 4];
        assert!(convex_hull(&mut pts, &mut out) < 3);
    }
}
