//! The spine's block-tridiagonal solve ([`super::chain_solve`]) in 32-bit fixed point: the
//! fixed-point brush's kernel, on the pen and on the host alike.
//!
//! The same elimination and back substitution as [`ChainSolve`](super::chain_solve::ChainSolve),
//! with the model's `I32F32` replaced by three 32-bit formats chosen for what each quantity
//! can be:
//!
//! * **blocks** (`G_j`, the diagonal blocks and their Schur complements `D_i`): `Q11.20`,
//!   for diagonals up to [`MAX_DIAGONAL`] (the fixed-point brush refuses a stiffer one at
//!   its substep rate: `BrushScalar::check_params`), and
//!   `P_i = D_{i-1}^-1 G_i` in `Q6.25` ([`P_FRAC`]);
//! * **inverses** (`E_i = D_i^-1`): `Q0.31`. Every `D_i` is at least the identity (see
//!   `chain_solve`), so `E_i <= I` and its entries lie in (-1, 1). They are computed
//!   from exact integer cofactors and determinant ([`QSym::inverse_spd`]);
//! * **vectors** (right-hand sides, eliminated `y_i`, solutions `z_i`: millimetres per
//!   substep): `Q4.27` ([`VEC_FRAC`]), the right-hand sides and `y_i` at that resolution
//!   in 64 bits (they are `D_i` times the solution, beyond 16 mm on a brush with light
//!   masses; [`Y_BITS`]): a chain of segments in different directions
//!   multiplies a vector's rounding by the stiffness, row after row, so they keep more
//!   fractional bits than the blocks; a substep whose vectors leave the range (a pose that
//!   jumped) is reported ([`SpineChain::saturated`]), and the brush restarts at rest.
//!
//! This is the fixed-point brush's only chain solve: the model's general one in `I32F32`
//! would be a second copy of the step in the pen's flash, which has no room for it.
//!
//! A product of two 32-bit numbers is one `SMULL` (and a sum of three one `SMULL` and two
//! `SMLAL`) on the Cortex-M4, where `I32F32`'s is a 64 x 64-bit product of about thirty
//! instructions: the reason this kernel exists. Each sum of products is formed exactly in
//! 64 bits and rounded once, to nearest. The host runs this same code for the fixed-point
//! brush, so the pen and the host compute the same bits (hil's link tests), and
//! `tests/fixed_vs_f64.rs` bounds its distance from the `f64` brush.
//!
//! Where values enter (the model's blocks and vectors) and where the inverse leaves its
//! exact computation they are clamped to their formats' range. Inside, the bounds hold
//! by construction and are not tested again, which would double the kernel's cost: every
//! block is symmetric positive semi-definite with diagonal entries below [`MAX_DIAGONAL`]
//! (the fixed-point brush is refused beyond that bound), so the Schur complements stay
//! below that bound, `P`'s entries below its square root, the inverse's below one, and
//! every sum of three products below `2^63`. Out of those bounds (no brush that takes this
//! solve reaches them) the arithmetic wraps, as `wrapping_*` says, and panics in no build;
//! the vectors stay clamped.

use super::chain_solve::{Segment, SpineChain};
use super::unit_fixed::saturated_word;
use crate::params::MAX_LAYERS;
use crate::scalar::Fx;
use crate::vec::Vec3;

/// Fractional bits of the inverses (`Q0.31`).
const INV_FRAC: u32 = 31;
/// The bound of every block entry where it enters the format: `2^30` units.
const LIMIT: i32 = 1 << 30;
/// Fractional bits of the blocks (`Q11.20`): constant, so that every shift in the kernel
/// is (a variable 64-bit shift is a library call on the Cortex-M4).
const BLOCK_FRAC: u32 = 20;
/// Fractional bits of a segment's unit direction (`Q1.30`), from which its block is built.
const DIR_FRAC: u32 = 30;
/// Fractional bits of `P_i = D_{i-1}^-1 G_i` (`Q6.25`). `P`'s norm is below `sqrt(cond D)`,
/// at most the square root of the diagonal's bound, so half the blocks' integer bits hold
/// it; its precision matters more than theirs, since the next row's Schur complement
/// multiplies it by a stiff segment's block.
const P_FRAC: u32 = (BLOCK_FRAC + 30) / 2;

/// The largest diagonal entry the blocks' format holds with room for rounding: the bound
/// on `1 + c_tv + c_p + 2 (c_k + c_d)` (`BrushParams::backward_euler_diagonal_bound`) below
/// which the fixed-point brush solves its chain; a brush beyond it at its substep rate
/// (several times stiffer than the presets at one substep per tick) is refused in fixed
/// point, and runs in the float formats or at more substeps.
pub const MAX_DIAGONAL: f32 = (LIMIT >> (BLOCK_FRAC + 1)) as f32;

/// `v >> shift` (`shift >= 1`), rounded to nearest (ties up), clamped to `+-limit`: where the
/// model's values enter the formats. Shifting first leaves room for the rounding bit, so no
/// value wraps, except `i64::MAX` at a shift of one (a saturated inverse entry), which
/// becomes `-limit`: never a panic.
#[inline(always)]
fn round_clamp(v: i64, shift: u32, limit: i32) -> i32 {
    saturated_word((v >> (shift - 1)).wrapping_add(1) >> 1).clamp(-limit, limit)
}

/// `v >> shift` rounded to nearest (ties up), for a result the formats' bounds keep within
/// `i32` (see the module docs); out of them it wraps, and panics in no build.
#[inline(always)]
fn round_shift(v: i64, shift: u32) -> i32 {
    (v.wrapping_add(1 << (shift - 1)) >> shift) as i32
}

/// `v >> shift` rounded to nearest (ties up), in 64 bits: the vectors' resolution with
/// more range (the right-hand sides and the eliminated `y_i`).
#[inline(always)]
fn round_shift64(v: i64, shift: u32) -> i64 {
    v.wrapping_add(1 << (shift - 1)) >> shift
}

/// The bound on the eliminated `y_i` in the vectors' resolution: `2^46` units, `2^19` mm per
/// substep.
const Y_BITS: u32 = 46;

/// `sum a_k y_k >> INV_FRAC`, rounded to nearest (ties up), for a row of an inverse (`Q0.31`,
/// entries below `2^31`) and a 64-bit `y` (below `2^Y_BITS`): `y` split at bit 30, two sums
/// of three 32 x 32-bit products, each below `2^63`, and the quotient put together exactly.
/// For `y` within 32 bits the same bits as rounding `dot(a, y)`.
#[inline(always)]
fn dot_wide(a: [i32; 3], y: [i64; 3]) -> i64 {
    let hi = y.map(|e| (e >> 30) as i32);
    let lo = y.map(|e| (e & 0x3fff_ffff) as i32);
    // sum = high 2^30 + low; (sum + 2^30) >> 31 = (high + (low + 2^30) >> 30) >> 1, exactly.
    let high = dot(a, hi);
    let low = dot(a, lo).wrapping_add(1 << 30);
    high.wrapping_add(low >> 30) >> 1
}

/// A sum of three exact products (wrapping only outside the formats' bounds).
#[inline(always)]
fn dot(a: [i32; 3], b: [i32; 3]) -> i64 {
    let p = |k: usize| (a[k] as i64).wrapping_mul(b[k] as i64);
    p(0).wrapping_add(p(1)).wrapping_add(p(2))
}

/// Fractional bits of the vectors (`Q4.27`: right-hand sides, eliminated `y_i`, solutions
/// `z_i`, in millimetres per substep, and the relative velocities the blocks multiply): a
/// brush's motion, even a fast stroke's, stays far inside 16 mm per substep, and 27
/// fractional bits keep the chain's rounding, multiplied by the stiffness row after row,
/// within the model's tolerance at a hundred substeps per tick (26 do not). A substep that
/// leaves the range is [`SpineChain::saturated`], and the brush restarts at rest: a pose
/// that jumps, a hostile stream, or a force on a mass beyond its format (a load on the tip,
/// `Brush::set_tip_load`, of more than about a newton at one substep per tick).
const VEC_FRAC: u32 = 27;

/// `v >> shift` rounded to nearest, in the vectors' format; a value beyond it saturates
/// and sets `saturated`.
#[inline(always)]
fn to_vec_from(v: i64, shift: u32, saturated: &mut bool) -> i32 {
    let r = v.wrapping_add(1 << (shift - 1)) >> shift;
    let word = r as i32;
    if word as i64 == r {
        word
    } else {
        *saturated = true;
        saturated_word(r)
    }
}

/// A model's value in the vectors' format ([`to_vec_from`]).
#[inline(always)]
fn to_vec(v: Vec3<Fx>, saturated: &mut bool) -> [i32; 3] {
    [v.x, v.y, v.z].map(|e| to_vec_from(e.to_bits(), 32 - VEC_FRAC, saturated))
}

/// `a + b` in the vectors' format, saturating and setting `saturated` on overflow.
#[inline(always)]
fn add_vec(a: i32, b: i32, saturated: &mut bool) -> i32 {
    a.checked_add(b).unwrap_or_else(|| {
        *saturated = true;
        if b < 0 {
            -i32::MAX
        } else {
            i32::MAX
        }
    })
}

/// A symmetric 3x3 block in one of the formats: `[xx, yy, zz, xy, xz, yz]`.
#[derive(Copy, Clone, Debug, PartialEq)]
struct QSym([i32; 6]);

impl QSym {
    const ZERO: Self = QSym([0; 6]);

    #[inline(always)]
    fn row(&self, r: usize) -> [i32; 3] {
        let [xx, yy, zz, xy, xz, yz] = self.0;
        match r {
            0 => [xx, xy, xz],
            1 => [xy, yy, yz],
            _ => [xz, yz, zz],
        }
    }

    /// The inverse (`Q0.31`) of a block that is at least the identity, as its adjugate
    /// over its determinant, both exact in integers: the six cofactors of the `Q11.20`
    /// entries are exact in 64 bits, the determinant in 93, and only the quotient is
    /// rounded, with one 64-bit division for the block (the reciprocal of the
    /// determinant's leading 32 bits) instead of a reciprocal per pivot.
    ///
    /// Exactness is the point: a stiff brush's blocks are ill-conditioned (a segment's
    /// axial stiffness against the mass), and an elimination in fixed point loses the soft
    /// directions' pivots to cancellation (with 20 fractional bits in the `L D L^T`
    /// factors, the inverse's error in the stiff direction, magnified by the stiffness
    /// twice in the next row's Schur complement, swamped the soft directions). Exact
    /// cofactors cancel without loss, and the quotient's relative error, a few parts in
    /// `2^31` of entries below one, is the format's own resolution.
    ///
    /// A block that is not at least the identity (only a rounding away from one, for a
    /// brush that takes this solve) has its determinant raised to one's; entries clamp to
    /// the format. Never a panic.
    #[inline(always)]
    fn inverse_spd(&self) -> Self {
        let [a, b, c, d, e, f] = self.0.map(|v| v as i64);
        let m = |x: i64, y: i64| x.wrapping_mul(y);
        // Cofactors in Q22.40: entries below 2^30 in magnitude, each below 2^61.
        let cof = [
            m(b, c).wrapping_sub(m(f, f)),
            m(a, c).wrapping_sub(m(e, e)),
            m(a, b).wrapping_sub(m(d, d)),
            m(e, f).wrapping_sub(m(d, c)),
            m(d, f).wrapping_sub(m(b, e)),
            m(d, e).wrapping_sub(m(a, f)),
        ];
        // det = a C_xx + d C_xy + e C_xz (Q33.60), each cofactor split at bit 31 into a
        // signed high part (below 2^30) and a low part below 2^31, so every sum of three
        // 32 x 32-bit products fits 64 bits; then shifted by 29 bits, which keeps a
        // determinant of at least one (2^60) to 2^-31 relative, and holds up to the
        // diagonal bound cubed (2^58 here).
        let (hi, lo) = (|k: usize| cof[k] >> 31, |k: usize| cof[k] & 0x7fff_ffff);
        let high = m(a, hi(0))
            .wrapping_add(m(d, hi(3)))
            .wrapping_add(m(e, hi(4)));
        let low = m(a, lo(0))
            .wrapping_add(m(d, lo(3)))
            .wrapping_add(m(e, lo(4)));
        let one = 1i64 << (60 - 29);
        let det = high.wrapping_mul(4).wrapping_add(low >> 29).max(one);
        // det = mant 2^(bits - 32), mant in [2^31, 2^32); its reciprocal 2^63 / mant in
        // (2^31, 2^32).
        let bits = 64 - det.leading_zeros();
        let recip = recip_q63((det >> (bits - 32)) as u32);
        // E = C 2^51 / det_60 = C 2^51 / (mant 2^(bits - 3)) = (C >> (bits - 22)) recip >> 31;
        // the cofactor's shift leaves it below 2^31 for |E| <= 1, so the product is below
        // 2^62. Both shifts round to nearest.
        let shift = bits - 22;
        let q31 = |v: i64| {
            let c = (v >> (shift - 1)).wrapping_add(1) >> 1;
            let e = c.wrapping_mul(recip).wrapping_add(1 << 30) >> 31;
            saturated_word(e)
        };
        QSym(cof.map(q31))
    }
}

/// `2^63 / x` for `x` in `[2^31, 2^32)`, to within a few units (of about `2^32`): a
/// 16-bit estimate from the hardware's 32-bit division, then two Newton steps
/// `r += r (2^63 - x r) / 2^63`, each squaring the relative error. The Cortex-M4 has no
/// 64-bit division: the library's takes some hundreds of instructions, this some tens.
#[inline(always)]
fn recip_q63(x: u32) -> i64 {
    let x = x.max(1 << 31);
    // The estimate overshoots by less than 2^-15 relative (the divisor's dropped bits),
    // so x r stays below 2^64, and the residual within +-2^48.
    let mut r = ((u32::MAX / (x >> 16)) as i64) << 15;
    for _ in 0..2 {
        let residual = (1u64 << 63).wrapping_sub((x as u64).wrapping_mul(r as u64)) as i64;
        // r (residual / 2^63), the residual's low 18 bits dropped (2^-13 of a unit of r) so
        // that the product stays within 2^63.
        r = r.wrapping_add(r.wrapping_mul(residual >> 18) >> 45);
    }
    r
}

/// A general 3x3 block by rows, in the blocks' format.
#[derive(Copy, Clone, Debug)]
struct QMat([[i32; 3]; 3]);

/// The fixed-point brush's chain solve: [`ChainSolve`](super::chain_solve::ChainSolve)'s
/// interface, its arithmetic in the formats of the module docs.
pub struct FixedChain {
    /// `P_i` of each row from the second.
    p: [QMat; MAX_LAYERS],
    /// `z_i` in the vectors' format ([`VEC_FRAC`]), the solution after [`Self::solve`].
    z: [[i32; 3]; MAX_LAYERS],
    /// Whether a vector left its format in this substep ([`SpineChain::saturated`]).
    saturated: bool,
    /// The last row's `D^-1` (`Q0.31`).
    inv: QSym,
    /// The last two segments' blocks ([`SpineChain::segment`]), the upper the latest.
    g_below: QSym,
    g_above: QSym,
    /// The same segments' terms `T_j` ([`Segment`]), exact sums of products in
    /// `Q(BLOCK_FRAC + VEC_FRAC)`: a term alone can leave the vectors' range (a stiff
    /// segment's force), where the difference of two, the row's right-hand side, does not.
    t_below: [i64; 3],
    t_above: [i64; 3],
}

impl FixedChain {
    /// A solve before its first segment: a constant, so that a new one is one block copy
    /// (building it field by field, then moving it into [`FxChain`], cost the pen's tick
    /// thousands of instructions).
    const EMPTY: Self = FixedChain {
        p: [QMat([[0; 3]; 3]); MAX_LAYERS],
        z: [[0; 3]; MAX_LAYERS],
        inv: QSym::ZERO,
        g_below: QSym::ZERO,
        g_above: QSym::ZERO,
        t_below: [0; 3],
        t_above: [0; 3],
        saturated: false,
    };
}

impl SpineChain<Fx> for FixedChain {
    fn new() -> Self {
        Self::EMPTY
    }

    /// The block in the blocks' format from its parts (each entered once: `iso` and
    /// `axial` below the diagonal's bound, `dir` a unit vector), then the term
    /// `spring + G rel`, exact.
    #[inline(always)]
    fn segment(&mut self, s: Segment<Fx>) {
        let q = |v: Fx| round_clamp(v.to_bits(), 32 - BLOCK_FRAC, LIMIT);
        let (iso, axial) = (q(s.iso), q(s.axial));
        // The direction in Q1.30: its rounding is multiplied by the axial stiffness.
        let unit = |v: Fx| round_clamp(v.to_bits(), 32 - DIR_FRAC, 1 << DIR_FRAC);
        let d = [unit(s.dir.x), unit(s.dir.y), unit(s.dir.z)];
        let ad = d.map(|e| round_shift(axial as i64 * e as i64, DIR_FRAC));
        let outer = |a: usize, b: usize| round_shift(ad[a] as i64 * d[b] as i64, DIR_FRAC);
        let g = QSym([
            iso.wrapping_add(outer(0, 0)),
            iso.wrapping_add(outer(1, 1)),
            iso.wrapping_add(outer(2, 2)),
            outer(0, 1),
            outer(0, 2),
            outer(1, 2),
        ]);
        self.g_below = self.g_above;
        self.g_above = g;
        let sat = &mut self.saturated;
        let rel = to_vec(s.rel, sat);
        // G rel in Q(BLOCK_FRAC + VEC_FRAC), exact in 64 bits (entries below the diagonal's
        // bound and 2^31), plus the spring force, whose model format (`I32F32`) enters that
        // one exactly: kept, so that the row rounds the difference of two terms once. (A
        // coefficient format for the spring's scale of the segment's vector loses the force
        // at high substep rates, where that scale is a few units of its resolution.)
        let shift = BLOCK_FRAC + VEC_FRAC - 32;
        let spring = [s.spring.x, s.spring.y, s.spring.z];
        let term = [0, 1, 2].map(|r| {
            let force = spring[r].to_bits();
            // A force beyond the terms' range (2^16 mm per substep, never a brush's) is
            // reported as saturated.
            if force.unsigned_abs() >> (63 - shift) != 0 {
                *sat = true;
            }
            dot(g.row(r), rel).wrapping_add(force.wrapping_shl(shift))
        });
        self.t_below = self.t_above;
        self.t_above = term;
    }

    #[inline(always)]
    fn row(&mut self, i: usize, a: Fx, drag: Fx, lift: Fx, own: Vec3<Fx>) {
        let i = i.clamp(1, MAX_LAYERS - 1);
        let f = BLOCK_FRAC;
        let sat = &mut self.saturated;
        // T_{i+1} - T_i + own, exact, then rounded once to the vectors' resolution, kept in
        // 64 bits: the right-hand side and the eliminated y_i = D_i z_i are the explicit
        // velocity change, up to the diagonal (1 + 2 c_k) times the solution, and leave the
        // solution's 16 mm per substep on a brush whose light masses make c_k large (the
        // small brush's tip segment stretching at a fraction of a millimetre per substep).
        let own = to_vec(own, sat);
        let rhs = [0, 1, 2].map(|r| {
            let sum = self.t_above[r]
                .wrapping_sub(self.t_below[r])
                .wrapping_add((own[r] as i64) << BLOCK_FRAC);
            round_shift64(sum, BLOCK_FRAC)
        });
        let (g, g_next) = (self.g_below, self.g_above);
        // a I + c (x x^T + y y^T) + l z z^T + G_i + G_{i+1}, in the blocks' format (each
        // below the diagonal's bound: l is at most c's).
        let a = round_clamp(a.to_bits(), 32 - BLOCK_FRAC, LIMIT);
        let in_plane = a.wrapping_add(round_clamp(drag.to_bits(), 32 - BLOCK_FRAC, LIMIT));
        let vertical = a.wrapping_add(round_clamp(lift.to_bits(), 32 - BLOCK_FRAC, LIMIT));
        let diag = QSym(core::array::from_fn(|k| {
            let sum = g.0[k].wrapping_add(g_next.0[k]);
            match k {
                0 | 1 => sum.wrapping_add(in_plane),
                2 => sum.wrapping_add(vertical),
                _ => sum,
            }
        }));
        let (d, y) = if i == 1 {
            (diag, rhs)
        } else {
            // P = E g: E in Q0.31, g in the blocks' format: a block.
            let cols = [0, 1, 2].map(|c| g.row(c));
            let pf = P_FRAC;
            let p = QMat([0, 1, 2].map(|r| {
                cols.map(|col| round_shift(dot(self.inv.row(r), col), INV_FRAC + f - pf))
            }));
            self.p[i] = p;
            // D = diag - g P (symmetric: six entries), y = rhs + g z_{i-1}.
            let col = |c: usize| [p.0[0][c], p.0[1][c], p.0[2][c]];
            let gp = |r: usize, c: usize| round_shift(dot(g.row(r), col(c)), pf);
            let [xx, yy, zz, xy, xz, yz] = diag.0;
            let sub = |a: i32, b: i32| a.wrapping_sub(b);
            let d = QSym([
                sub(xx, gp(0, 0)),
                sub(yy, gp(1, 1)),
                sub(zz, gp(2, 2)),
                sub(xy, gp(0, 1)),
                sub(xz, gp(0, 2)),
                sub(yz, gp(1, 2)),
            ]);
            let z = self.z[i - 1];
            let y = [0, 1, 2].map(|r| rhs[r].wrapping_add(round_shift64(dot(g.row(r), z), f)));
            (d, y)
        };
        self.inv = d.inverse_spd();
        let inv = self.inv;
        self.z[i] = [0, 1, 2].map(|r| {
            let y = y.map(|e| {
                // Beyond any brush's (D z below 2^19 mm per substep for a diagonal below
                // MAX_DIAGONAL and z in range): saturated, and the split below stays exact.
                if e.unsigned_abs() >> Y_BITS != 0 {
                    *sat = true;
                }
                e.clamp(-(1 << Y_BITS), 1 << Y_BITS)
            });
            let q = dot_wide(inv.row(r), y);
            let word = q as i32;
            if word as i64 == q {
                word
            } else {
                *sat = true;
                saturated_word(q)
            }
        });
    }

    #[inline(always)]
    fn solve(&mut self, n: usize) {
        let n = n.clamp(2, MAX_LAYERS);
        let pf = P_FRAC;
        for i in (1..n - 1).rev() {
            let next = self.z[i + 1];
            let p = &self.p[i + 1].0;
            for r in 0..3 {
                let pz = to_vec_from(dot(p[r], next), pf, &mut self.saturated);
                self.z[i][r] = add_vec(self.z[i][r], pz, &mut self.saturated);
            }
        }
    }

    #[inline(always)]
    fn du(&self, i: usize) -> Vec3<Fx> {
        let [x, y, z] =
            self.z[i.min(MAX_LAYERS - 1)].map(|e| Fx::from_bits((e as i64) << (32 - VEC_FRAC)));
        Vec3::new(x, y, z)
    }
    fn saturated(&self) -> bool {
        self.saturated
    }
}

#[cfg(test)]
mod tests {
    use super::super::chain_solve::{ChainSolve, Segment, Sym3};
    use super::*;
    extern crate std;
    use crate::scalar::Scalar;

    fn fx(v: f64) -> Fx {
        Fx::from_f64(v)
    }

    /// The 32-bit solve is within 8 nm of the `f64` solve of the same system (solutions of
    /// a millimetre or two: the blocks' resolution, 2^-20, relative to them), from soft
    /// brushes to six times the presets' stiffness (near the format's [`MAX_DIAGONAL`]), for systems shaped like a brush's (stiff along
    /// each segment, soft across it, masses tied or free, the segments in any direction) at
    /// the block formats their stiffness calls for.
    #[test]
    fn fixed_chain_matches_the_f64_solve() {
        let mut seed = 0x9e37_79b9_7f4a_7c15u64;
        let mut rnd = || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        let mut rounded = false;
        let mut worst = 0.0f64;
        for trial in 0..200 {
            let n = 3 + trial % 22;
            let c_k = [0.05, 2.0, 32.0, 200.0][trial % 4];
            let c_d = c_k * 0.03;
            // Segments k (e I + (1 - e) d d^T) + c_d I, e a small strain, d in any direction:
            // (iso, axial, d).
            let segments: [(f64, f64, Vec3<f64>); MAX_LAYERS + 1] = core::array::from_fn(|j| {
                if j == 0 || j >= n {
                    return (0.0, 0.0, Vec3::ZERO);
                }
                let v = Vec3::new(rnd(), rnd(), rnd() - 1.5);
                let e = (rnd() * 1e-3).max(0.0);
                (
                    c_k * e + c_d,
                    c_k * (1.0 - e),
                    v.scale(1.0 / v.norm2().sqrt()),
                )
            });
            let block =
                |(iso, axial, d): (f64, f64, Vec3<f64>)| Sym3::iso_plus_outer(iso, axial, d);
            let a: [f64; MAX_LAYERS] = core::array::from_fn(|_| 1.0 + 0.2 * rnd().abs());
            let rhs: [Vec3<f64>; MAX_LAYERS] =
                core::array::from_fn(|_| Vec3::new(rnd(), rnd(), rnd()).scale(2.0));
            // Relative velocities whose damping and stiffness terms stay within the vectors'
            // range, as a brush's do (a stiffer brush's masses move together).
            let rel: [Vec3<f64>; MAX_LAYERS + 1] = core::array::from_fn(|_| {
                Vec3::new(rnd(), rnd(), rnd()).scale(0.1 / c_k.max(1.0).sqrt())
            });
            let to_fx = |s: Sym3<f64>| Sym3 {
                xx: fx(s.xx),
                yy: fx(s.yy),
                zz: fx(s.zz),
                xy: fx(s.xy),
                xz: fx(s.xz),
                yz: fx(s.yz),
            };
            let vfx = |v: Vec3<f64>| Vec3::new(fx(v.x), fx(v.y), fx(v.z));
            let mut exact = ChainSolve::<f64>::new();
            let mut model = ChainSolve::<Fx>::new();
            let mut fixed = FixedChain::new();
            // Each segment's spring force: its term T_j = spring + G_j rel, and the rows'
            // right-hand sides T_{i+1} - T_i + own.
            let springs: [Vec3<f64>; MAX_LAYERS + 1] =
                core::array::from_fn(|_| Vec3::new(rnd(), rnd(), rnd()).scale(c_k * 3e-3));
            let term = |j: usize| {
                if j >= n {
                    return Vec3::ZERO;
                }
                springs[j] + block(segments[j]).mul_vec(rel[j])
            };
            let segment = |fixed: &mut FixedChain, j: usize| {
                let (iso, axial, d) = segments[j];
                let spring = if j < n { springs[j] } else { Vec3::ZERO };
                fixed.segment(Segment {
                    iso: fx(iso),
                    axial: fx(axial),
                    dir: vfx(d),
                    spring: vfx(spring),
                    rel: vfx(rel[j]),
                });
            };
            segment(&mut fixed, 1);
            for i in 1..n {
                segment(&mut fixed, i + 1);
                let (g, g_next) = (block(segments[i]), block(segments[i + 1]));
                let diag = Sym3::iso(a[i]).add(g).add(g_next);
                let full = term(i + 1) - term(i) + rhs[i];
                exact.row(i, diag, &g, full);
                model.row(i, to_fx(diag), &to_fx(g), vfx(full));
                fixed.row(i, fx(a[i]), Fx::ZERO, Fx::ZERO, vfx(rhs[i]));
            }
            let want = *exact.solve(n);
            let own = *model.solve(n);
            fixed.solve(n);
            assert!(
                !fixed.saturated(),
                "trial {trial}: the system left the formats"
            );
            let off = |v: Vec3<Fx>, w: Vec3<f64>| {
                let v = v.to_f64();
                [v[0] - w.x, v[1] - w.y, v[2] - w.z]
                    .iter()
                    .fold(0.0f64, |m, e| m.max(e.abs()))
            };
            for i in 1..n {
                let (d, d_own) = (off(fixed.du(i), want[i]), off(own[i], want[i]));
                rounded |= d > 0.0;
                worst = worst.max(d);
                let limit = 8e-6;
                assert!(
                    d <= limit,
                    "trial {trial} (n {n}, c_k {c_k}) mass {i}: {d:e} mm off, \
                     the I32F32 solve {d_own:e}"
                );
            }
        }
        assert!(rounded, "the comparison saw no rounding at all");
        std::println!("32-bit chain solve against f64: largest difference {worst:e} mm");
    }

    /// The reciprocal is within two units of `2^63 / x` across its domain.
    #[test]
    fn reciprocal_of_a_normalised_word() {
        let mut x = 1u64 << 31;
        while x < 1 << 32 {
            for x in [x, x + 1, x | 0xffff, (x + (x >> 7)).min(u32::MAX as u64)] {
                let want = (1u128 << 63) as f64 / x as f64;
                let got = recip_q63(x as u32) as f64;
                assert!((got - want).abs() <= 2.0, "x {x:#x}: {got} against {want}");
            }
            x += x >> 9;
        }
        let want = (1u128 << 63) as f64 / u32::MAX as f64;
        assert!((recip_q63(u32::MAX) as f64 - want).abs() <= 2.0);
    }

    /// Vectors at the ends of their range (a brush flung by a hostile stream) saturate through
    /// the elimination and the back substitution, no overflow in a build that checks, and
    /// the solve says so (the brush then restarts at rest); a system inside the range does
    /// not.
    #[test]
    fn saturated_vectors_do_not_overflow_and_are_reported() {
        for big in [
            Fx::from_bits(i64::MAX),
            Fx::from_bits(-i64::MAX),
            fx(17.0),
            fx(1.0),
        ] {
            let mut fixed = FixedChain::new();
            let n = 6;
            fixed.segment(Segment {
                iso: fx(1.0),
                axial: fx(30.0),
                dir: Vec3::new(fx(0.0), fx(0.0), fx(1.0)),
                ..Segment::BEYOND_TIP
            });
            for i in 1..n {
                let rel = Vec3::new(big, big, big).scale(fx(0.01));
                let axial = if i + 1 < n { fx(30.0) } else { fx(0.0) };
                fixed.segment(Segment {
                    iso: fx(1.0),
                    axial,
                    dir: Vec3::new(fx(0.6), fx(0.0), fx(0.8)),
                    rel,
                    ..Segment::BEYOND_TIP
                });
                fixed.row(i, fx(1.0), Fx::ZERO, Fx::ZERO, Vec3::new(big, big, big));
            }
            fixed.solve(n);
            let inside = big.to_f64().abs() < 16.0;
            assert_eq!(fixed.saturated(), !inside, "{big:?}");
            for i in 1..n {
                let du = fixed.du(i).to_f64();
                assert!(du.iter().all(|e| e.abs() <= 16.0), "{du:?}");
            }
        }
    }
}
