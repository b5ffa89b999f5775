//! The linear algebra of the backward-Euler substep (see [`super`]): symmetric 3x3 blocks
//! and the exact O(N) solve of the spine's block-tridiagonal system.
//!
//! The system, one block row per free mass i in `1..n` (the ferrule, mass 0, is prescribed):
//!
//! ```text
//! (a_i I + G_i + G_{i+1}) du_i - G_i du_{i-1} - G_{i+1} du_{i+1} = r_i
//! ```
//!
//! with `G_j` the symmetric positive semi-definite block of segment j (masses j-1 and j),
//! `G_n = 0` beyond the tip, `du_0` known (its term is in `r_1`) and `a_i >= 1` (the mass, in
//! units of itself, plus the tie). The matrix is symmetric and at least the identity, so
//! block elimination without pivoting is stable: every Schur complement `D_i` is at least the
//! identity too (the Schur complement is monotone), so the three pivots of each `D_i`'s
//! `L D L^T` lie in `[1, max diagonal]`, where a reciprocal keeps its relative precision in
//! fixed point.
//!
//! The elimination streams: row i needs `G_i`, `G_{i+1}` and the previous row's results, so
//! the caller hands the rows in one at a time ([`ChainSolve::row`]) and only what the back
//! substitution needs, `P_i = D_{i-1}^-1 G_i` and `z_i = D_i^-1 y_i`, is kept.

use crate::params::MAX_LAYERS;
use crate::scalar::Scalar;
use crate::vec::Vec3;

/// A symmetric 3x3 matrix: its six distinct entries.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct Sym3<S> {
    pub xx: S,
    pub yy: S,
    pub zz: S,
    pub xy: S,
    pub xz: S,
    pub yz: S,
}

impl<S: Scalar> Sym3<S> {
    pub const ZERO: Self = Sym3 {
        xx: S::ZERO,
        yy: S::ZERO,
        zz: S::ZERO,
        xy: S::ZERO,
        xz: S::ZERO,
        yz: S::ZERO,
    };

    /// `a I + b v v^T`: a spring's Jacobian block, isotropic part plus its axial part.
    #[inline]
    pub fn iso_plus_outer(a: S, b: S, v: Vec3<S>) -> Self {
        let bv = v.scale(b);
        Sym3 {
            xx: a + bv.x * v.x,
            yy: a + bv.y * v.y,
            zz: a + bv.z * v.z,
            xy: bv.x * v.y,
            xz: bv.x * v.z,
            yz: bv.y * v.z,
        }
    }

    /// `a I`.
    #[inline]
    pub fn iso(a: S) -> Self {
        Sym3 {
            xx: a,
            yy: a,
            zz: a,
            ..Self::ZERO
        }
    }

    #[inline]
    pub fn add(self, o: Self) -> Self {
        Sym3 {
            xx: self.xx + o.xx,
            yy: self.yy + o.yy,
            zz: self.zz + o.zz,
            xy: self.xy + o.xy,
            xz: self.xz + o.xz,
            yz: self.yz + o.yz,
        }
    }

    #[inline]
    pub fn mul_vec(&self, v: Vec3<S>) -> Vec3<S> {
        Vec3::new(
            self.xx * v.x + self.xy * v.y + self.xz * v.z,
            self.xy * v.x + self.yy * v.y + self.yz * v.z,
            self.xz * v.x + self.yz * v.y + self.zz * v.z,
        )
    }

    /// `self * g` for another symmetric `g`: a general matrix (rows).
    #[inline]
    fn mul_sym(&self, g: &Self) -> Mat3<S> {
        let rows = [
            Vec3::new(self.xx, self.xy, self.xz),
            Vec3::new(self.xy, self.yy, self.yz),
            Vec3::new(self.xz, self.yz, self.zz),
        ];
        Mat3(rows.map(|r| g.mul_vec(r)))
    }

    /// `self * p` where the product is known to be symmetric (`p = E self`, `E` symmetric):
    /// only its six distinct entries are computed.
    #[inline]
    fn mul_to_sym(&self, p: &Mat3<S>) -> Self {
        let [a, b, c] = p.0;
        let c0 = Vec3::new(a.x, b.x, c.x);
        let c1 = Vec3::new(a.y, b.y, c.y);
        let c2 = Vec3::new(a.z, b.z, c.z);
        let r0 = Vec3::new(self.xx, self.xy, self.xz);
        let r1 = Vec3::new(self.xy, self.yy, self.yz);
        let r2 = Vec3::new(self.xz, self.yz, self.zz);
        Sym3 {
            xx: r0.dot(c0),
            yy: r1.dot(c1),
            zz: r2.dot(c2),
            xy: r0.dot(c1),
            xz: r0.dot(c2),
            yz: r1.dot(c2),
        }
    }

    #[inline]
    fn sub(self, o: Self) -> Self {
        Sym3 {
            xx: self.xx - o.xx,
            yy: self.yy - o.yy,
            zz: self.zz - o.zz,
            xy: self.xy - o.xy,
            xz: self.xz - o.xz,
            yz: self.yz - o.yz,
        }
    }

    /// The inverse of a symmetric matrix that is at least the identity, by its `L D L^T`
    /// factors: three reciprocals of pivots in `[1, max diagonal]` (see the module docs for
    /// why not the adjugate over the determinant: in fixed point the reciprocal of a large
    /// determinant keeps few significant bits).
    #[inline]
    pub(super) fn inverse_spd(&self) -> Self {
        let r1 = self.xx.recip();
        let l21 = self.xy * r1;
        let l31 = self.xz * r1;
        let p2 = self.yy - self.xy * l21;
        let e2 = self.yz - self.xz * l21;
        let p3 = self.zz - self.xz * l31;
        let r2 = p2.recip();
        let l32 = e2 * r2;
        let r3 = (p3 - e2 * l32).recip();
        // L^-1 = [[1, 0, 0], [-l21, 1, 0], [m31, -l32, 1]], inverse = L^-T diag(r) L^-1.
        let m31 = l21 * l32 - l31;
        let (r2l21, r3m31, r3l32) = (r2 * l21, r3 * m31, r3 * l32);
        Sym3 {
            xx: r1 + r2l21 * l21 + r3m31 * m31,
            yy: r2 + r3l32 * l32,
            zz: r3,
            xy: -r2l21 - r3l32 * m31,
            xz: r3m31,
            yz: -r3l32,
        }
    }
}

/// A general 3x3 matrix by rows.
#[derive(Copy, Clone, Debug)]
struct Mat3<S>([Vec3<S>; 3]);

impl<S: Scalar> Mat3<S> {
    const ZERO: Self = Mat3([Vec3::ZERO; 3]);

    #[inline]
    fn mul_vec(&self, v: Vec3<S>) -> Vec3<S> {
        Vec3::new(self.0[0].dot(v), self.0[1].dot(v), self.0[2].dot(v))
    }
}

/// One segment's part of the backward-Euler system, as the brush hands it to the chain
/// ([`SpineChain::segment`]): its Jacobian block `iso I + axial dir dir^T` (`dir` a unit
/// vector, or zero with `axial`), and the parts of its term `T_j = spring + G_j rel`: the
/// spring force `spring` (in units of the mass at the substep) and the masses' relative
/// velocity `rel`, whose damping and stiffness the block gives. The chain forms the term in
/// its own format, so a compact format keeps the products exact until their one rounding.
#[derive(Copy, Clone, Debug)]
pub struct Segment<S> {
    pub iso: S,
    pub axial: S,
    pub dir: Vec3<S>,
    pub spring: Vec3<S>,
    pub rel: Vec3<S>,
}

impl<S: Scalar> Segment<S> {
    /// Beyond the tip: no segment, a zero block and a zero term.
    pub const BEYOND_TIP: Self = Segment {
        iso: S::ZERO,
        axial: S::ZERO,
        dir: Vec3::ZERO,
        spring: Vec3::ZERO,
        rel: Vec3::ZERO,
    };
}

/// How a number format solves one substep's chain: the elimination row by row
/// ([`SpineChain::row`]), then the back substitution ([`SpineChain::solve`]). The float
/// formats use [`ChainSolve`] in their own arithmetic; the fixed-point brush uses
/// [`FixedChain`](super::chain_fixed::FixedChain), in 32-bit formats, where the brush's
/// blocks fit them. Chosen by the brush's
/// number format ([`BrushScalar`](super::BrushScalar)).
pub trait SpineChain<S> {
    /// A solve for one substep; `compact`: whether the brush's blocks fit the format's
    /// compact solve, if it has one (the fixed-point format's, see
    /// [`super::chain_fixed::MAX_DIAGONAL`]).
    fn new() -> Self;
    /// The next segment (in order from the first, then [`Segment::BEYOND_TIP`]): its
    /// Jacobian block `G_j = iso I + axial dir dir^T`, kept for the rows on either side of
    /// it, and its term `T_j = spring + G_j rel`, kept for their right-hand sides.
    fn segment(&mut self, segment: Segment<S>);
    /// Eliminates row `i` (from 1 up, in order, each after the segment above it), given
    /// `a_i` (the mass and its tie, in units of the mass) and the row's own part of its
    /// right-hand side (tie, load); the chain adds the segments' terms `T_{i+1} - T_i`. Its
    /// blocks are the last two segments given: `G_i` (the coupling to the row before; for
    /// row 1, to the prescribed ferrule, whose term is in `T_1`) and `G_{i+1}`; the
    /// diagonal block is `a_i I + c_i (x x^T + y y^T) + l_i z z^T + G_i + G_{i+1}`, `c_i`
    /// the paper's drag on the mass (in the paper's plane only), `l_i` the vertical
    /// stiffness of its tie's weight near the paper (`Brush::backward_euler`), at most
    /// `c_i`'s bound.
    fn row(&mut self, i: usize, a: S, drag: S, lift: S, own: Vec3<S>);
    /// The back substitution after rows `1..n` were eliminated.
    fn solve(&mut self, n: usize);
    /// Then: `du_i` of free mass `i` (`1..n`).
    fn du(&self, i: usize) -> Vec3<S>;
    /// Whether a value left the solve's formats in this substep (a compact format's range,
    /// under a pose that flings the brush): its `du` is then not the system's solution, and
    /// the brush restarts at rest instead (`Brush::restart_on_skeleton`).
    fn saturated(&self) -> bool {
        false
    }
}

impl<S: Scalar> SpineChain<S> for ChainSolve<S> {
    fn new() -> Self {
        ChainSolve::new()
    }
    #[inline(always)]
    fn segment(&mut self, s: Segment<S>) {
        self.g_below = self.g_above;
        self.g_above = Sym3::iso_plus_outer(s.iso, s.axial, s.dir);
        self.t_below = self.t_above;
        self.t_above = s.spring + self.g_above.mul_vec(s.rel);
    }
    #[inline(always)]
    fn row(&mut self, i: usize, a: S, drag: S, lift: S, own: Vec3<S>) {
        let (g, g_next) = (self.g_below, self.g_above);
        let rhs = (self.t_above - self.t_below) + own;
        let mut diag = Sym3::iso(a);
        diag.xx += drag;
        diag.yy += drag;
        diag.zz += lift;
        ChainSolve::row(self, i, diag.add(g).add(g_next), &g, rhs)
    }
    #[inline(always)]
    fn solve(&mut self, n: usize) {
        ChainSolve::solve(self, n);
    }
    #[inline(always)]
    fn du(&self, i: usize) -> Vec3<S> {
        self.z[i.min(MAX_LAYERS - 1)]
    }
}

/// The block elimination of one substep's system, row by row, then its back substitution.
pub struct ChainSolve<S> {
    /// `P_i = D_{i-1}^-1 G_i` of each row from the second.
    p: [Mat3<S>; MAX_LAYERS],
    /// `z_i = D_i^-1 y_i`, `y_i` the eliminated right-hand side; the solution after
    /// [`Self::solve`].
    z: [Vec3<S>; MAX_LAYERS],
    /// The last row's `D^-1`.
    inv: Sym3<S>,
    /// The last two segments' blocks ([`SpineChain::segment`]), the upper the latest.
    g_below: Sym3<S>,
    g_above: Sym3<S>,
    /// The same segments' terms `T_j` ([`Segment`]).
    t_below: Vec3<S>,
    t_above: Vec3<S>,
}

impl<S: Scalar> ChainSolve<S> {
    pub fn new() -> Self {
        ChainSolve {
            p: [Mat3::ZERO; MAX_LAYERS],
            z: [Vec3::ZERO; MAX_LAYERS],
            inv: Sym3::ZERO,
            g_below: Sym3::ZERO,
            g_above: Sym3::ZERO,
            t_below: Vec3::ZERO,
            t_above: Vec3::ZERO,
        }
    }

    /// Eliminates row `i` (from 1 up, in order): its diagonal block `diag` (`a_i I + G_i +
    /// G_{i+1}`), the coupling `g` to the row before (`G_i`; not read for row 1, whose
    /// coupling to the prescribed ferrule is in its right-hand side) and its right-hand side.
    #[inline]
    pub fn row(&mut self, i: usize, diag: Sym3<S>, g: &Sym3<S>, rhs: Vec3<S>) {
        let i = i.clamp(1, MAX_LAYERS - 1);
        let (d, y) = if i == 1 {
            (diag, rhs)
        } else {
            let p = self.inv.mul_sym(g);
            self.p[i] = p;
            (diag.sub(g.mul_to_sym(&p)), rhs + g.mul_vec(self.z[i - 1]))
        };
        self.inv = d.inverse_spd();
        self.z[i] = self.inv.mul_vec(y);
    }

    /// The back substitution after rows `1..n` were eliminated: `du_i` of each free mass,
    /// at `i` (entry 0 untouched).
    #[inline]
    pub fn solve(&mut self, n: usize) -> &[Vec3<S>; MAX_LAYERS] {
        let n = n.clamp(2, MAX_LAYERS);
        for i in (1..n - 1).rev() {
            let next = self.p[i + 1].mul_vec(self.z[i + 1]);
            self.z[i] += next;
        }
        &self.z
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(v: Vec3<f64>, k: usize) -> f64 {
        [v.x, v.y, v.z][k]
    }

    fn dense_solve(a: &mut [[f64; 64]; 64], b: &mut [f64; 64], m: usize) {
        for k in 0..m {
            let piv = a[k][k];
            for r in k + 1..m {
                let f = a[r][k] / piv;
                for c in k..m {
                    a[r][c] -= f * a[k][c];
                }
                b[r] -= f * b[k];
            }
        }
        for k in (0..m).rev() {
            let mut s = b[k];
            for c in k + 1..m {
                s -= a[k][c] * b[c];
            }
            b[k] = s / a[k][k];
        }
    }

    /// The streamed block elimination solves the same system as dense Gaussian elimination,
    /// for stiff, soft, stretched and slack segments in every direction.
    #[test]
    fn chain_solve_matches_a_dense_solve() {
        let mut seed = 0x2545_f491_4f6c_dd1du64;
        let mut rnd = || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        for trial in 0..50 {
            let n = 3 + trial % 18;
            let scale = [0.01, 1.0, 30.0, 500.0][trial % 4];
            let mut g = [Sym3::<f64>::ZERO; MAX_LAYERS + 1];
            for gj in g.iter_mut().take(n).skip(1) {
                let v = Vec3::new(rnd(), rnd(), rnd());
                *gj = Sym3::iso_plus_outer(scale * rnd().abs() * 0.1, scale * rnd().abs(), v);
            }
            let a: [f64; MAX_LAYERS] = core::array::from_fn(|_| 1.0 + rnd().abs());
            let rhs: [Vec3<f64>; MAX_LAYERS] =
                core::array::from_fn(|_| Vec3::new(rnd(), rnd(), rnd()));
            let mut s = ChainSolve::new();
            for i in 1..n {
                let diag = Sym3::iso(a[i]).add(g[i]).add(g[i + 1]);
                s.row(i, diag, &g[i], rhs[i]);
            }
            let du = *s.solve(n);
            // Dense: unknowns 3(i-1)+k.
            let m = 3 * (n - 1);
            let mut dense = [[0.0; 64]; 64];
            let mut b = [0.0; 64];
            let ent = |s: &Sym3<f64>, r: usize, c: usize| match (r.min(c), r.max(c)) {
                (0, 0) => s.xx,
                (1, 1) => s.yy,
                (2, 2) => s.zz,
                (0, 1) => s.xy,
                (0, 2) => s.xz,
                _ => s.yz,
            };
            for i in 1..n {
                let diag = Sym3::iso(a[i]).add(g[i]).add(g[i + 1]);
                for r in 0..3 {
                    b[3 * (i - 1) + r] = at(rhs[i], r);
                    for c in 0..3 {
                        dense[3 * (i - 1) + r][3 * (i - 1) + c] = ent(&diag, r, c);
                        if i > 1 {
                            dense[3 * (i - 1) + r][3 * (i - 2) + c] = -ent(&g[i], r, c);
                        }
                        if i + 1 < n {
                            dense[3 * (i - 1) + r][3 * i + c] = -ent(&g[i + 1], r, c);
                        }
                    }
                }
            }
            dense_solve(&mut dense, &mut b, m);
            for i in 1..n {
                for k in 0..3 {
                    let (got, want) = (at(du[i], k), b[3 * (i - 1) + k]);
                    assert!(
                        (got - want).abs() <= 1e-9 * (1.0 + want.abs()),
                        "trial {trial} n {n} mass {i}: {got} vs {want}"
                    );
                }
            }
        }
    }

    /// The inverse by `L D L^T` factors is the inverse.
    #[test]
    fn spd_inverse_is_the_inverse() {
        let m = Sym3::iso_plus_outer(1.5, 40.0, Vec3::new(0.3, -0.8, 0.5))
            .add(Sym3::iso_plus_outer(0.2, 7.0, Vec3::new(-0.6, 0.1, 0.7)));
        let inv = m.inverse_spd();
        for v in [Vec3::X, Vec3::Y, Vec3::Z, Vec3::new(0.2, -1.0, 3.0)] {
            let back = m.mul_vec(inv.mul_vec(v));
            assert!((back - v).norm2() < 1e-20, "{back:?} vs {v:?}");
        }
    }
}
