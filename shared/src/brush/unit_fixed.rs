//! The surface update's unit-vector arithmetic for the fixed-point brush in 32-bit words:
//! the layers' axes are unit vectors (components within one), so their cross products and
//! normalisations need neither `I32F32`'s range nor its 64 x 64-bit products.
//!
//! Components enter as `Q1.30` (`i32`); a product of two is one `SMULL` on the Cortex-M4,
//! exact in 64 bits, and a cross product's component (a difference of two) is rounded once
//! back into the model's format. A normalisation takes the squared length exactly in 64
//! bits, its reciprocal root from the hardware's correctly rounded `f32` square root and
//! division of the length's leading 32 bits (IEEE operations: the host computes the same
//! bits, as for [`crate::scalar::Scalar::rsqrt`]'s estimate), and scales in integers. The
//! result is a unit vector to `f32`'s precision, about `1e-7` relative: an ellipse's axis,
//! whose length the footprint and the drawing multiply by a radius of a few millimetres.
//!
//! A segment's direction enters its words once and stays there for the layer's axes and
//! the tilts on either side; the interpolated short axes are formed in words and never
//! enter the model's format.
//!
//! [`super::BrushScalar`] hooks these in for `Fx`; the float formats keep their own
//! arithmetic.

use crate::scalar::{sqrt_f32, Fx, Scalar};
use crate::vec::Vec3;

/// Fractional bits of a unit vector's components (`Q1.30`).
const UNIT_FRAC: u32 = 30;
/// Fractional bits of the reciprocal root's integer form (`Q8.24`): roots of squared
/// lengths down to `2^-16` fit (a normalisation's threshold is far above that).
const ROOT_FRAC: u32 = 24;

/// A component in `Q1.30`, rounded, saturated (a unit vector's are within one; a vector
/// that is not, for a caller's bug, saturates and never wraps).
#[inline(always)]
fn q30(v: Fx) -> i32 {
    let shift = 32 - UNIT_FRAC;
    saturated_word(((v.to_bits() >> (shift - 1)).wrapping_add(1)) >> 1)
}

/// `v` as an `i32`, saturated to `+-i32::MAX` by its sign when it does not fit: one
/// comparison of words (a clamp of a 64-bit value takes four on the Cortex-M4). Every
/// 64-bit result of the brush's 32-bit kernels enters its format through here.
#[inline(always)]
pub(super) fn saturated_word(v: i64) -> i32 {
    let word = v as i32;
    if word as i64 == v {
        word
    } else if v < 0 {
        -i32::MAX
    } else {
        i32::MAX
    }
}

#[inline(always)]
fn q30_vec(v: Vec3<Fx>) -> [i32; 3] {
    [q30(v.x), q30(v.y), q30(v.z)]
}

/// A unit vector's components in `Q1.30` ([`super::BrushScalar::Unit`] for `Fx`).
pub(super) type Unit = [i32; 3];

/// `dir` (a unit vector) as its `Q1.30` words.
#[inline(always)]
pub(super) fn unit(dir: Vec3<Fx>) -> Unit {
    q30_vec(dir)
}

/// The unit vector along `v`, given `len2 = |v|^2` and `r = len2.rsqrt()`, in words:
/// [`Vec3::normalized_by`]'s products (the same bits), each rounded to `Q1.30` as [`unit`]
/// rounds them, without its saturation (a unit vector's components are within one). For a
/// segment longer than a millimetre `r` is the coefficient, tested once, and the products
/// are inline.
#[inline(always)]
pub(super) fn direction(v: Vec3<Fx>, len2: Fx, r: Fx) -> Unit {
    let d = if len2 > Fx::ONE && r.is_coef() {
        Vec3::new(
            v.x.mul_tested_coef(r),
            v.y.mul_tested_coef(r),
            v.z.mul_tested_coef(r),
        )
    } else {
        v.normalized_by(len2, r)
    };
    let shift = 32 - UNIT_FRAC;
    let word = |c: Fx| (c.to_bits().wrapping_add(1 << (shift - 1)) >> shift) as i32;
    [word(d.x), word(d.y), word(d.z)]
}

/// A unit vector's words as a vector: exact.
#[inline(always)]
pub(super) fn from_unit(u: Unit) -> Vec3<Fx> {
    let fx = |w: i32| Fx::from_bits((w as i64) << (32 - UNIT_FRAC));
    Vec3::new(fx(u[0]), fx(u[1]), fx(u[2]))
}

/// `a (1 - w) + Z w` of a unit vector's words, `w` in [0, 1]: each product exact in 64
/// bits and rounded once to `Q1.30`.
#[inline(always)]
pub(super) fn toward_normal(a: Unit, w: Fx) -> Unit {
    let w = q30(w);
    let keep = ((1i64 << UNIT_FRAC) - w as i64) as i32;
    let [x, y, z] = a.map(|c| round_q30(c as i64 * keep as i64));
    [x, y, z.wrapping_add(w)]
}

/// `a + (b - a) w` of two unit vectors' words, `w` in [0, 1]: each product exact in 64 bits
/// and rounded once to `Q1.30`.
#[inline(always)]
pub(super) fn lerp_unit(a: Unit, b: Unit, w: Fx) -> Unit {
    let w = q30(w) as i64;
    let lerp = |k: usize| a[k].wrapping_add(round_q30((b[k] as i64 - a[k] as i64) * w));
    [lerp(0), lerp(1), lerp(2)]
}

/// A `Q2.60` product (below 2^62 in magnitude) rounded to `Q1.30`.
#[inline(always)]
fn round_q30(p: i64) -> i32 {
    (p.wrapping_add(1 << (UNIT_FRAC - 1)) >> UNIT_FRAC) as i32
}

/// `1 - a . b` of two unit vectors' words: the dot product exact in `Q2.60` (within one in
/// magnitude for unit vectors), rounded once into the model's format.
#[inline(always)]
pub(super) fn one_minus_dot(a: Unit, b: Unit) -> Fx {
    let m = |k: usize| a[k] as i64 * b[k] as i64;
    let dot = m(0).wrapping_add(m(1)).wrapping_add(m(2));
    let shift = 2 * UNIT_FRAC - 32;
    Fx::from_bits((1i64 << 32).wrapping_sub(dot.wrapping_add(1 << (shift - 1)) >> shift))
}

/// [`super::BrushScalar::ellipse_axes`] in 32-bit words: the short axis `sa` (`None`: `Z`)
/// and the direction `d` come as words ([`unit`]); the long axis `sa x d` is formed exactly
/// in 64 bits, rounded to `Q1.30`, normalised (its squared length exact, the reciprocal root
/// from `f32`, see the module docs) and the short axis `d x long` taken from the normalised
/// words; each leaves once, rounded into the model's format.
///
/// Every intermediate is a word (`i32`), every product a 32 x 32-bit one (`SMULL`): `sa`
/// within the unit ball and `d` a unit vector (the surface's are, to their rounding), so
/// `sa x d` and the normalised axis lie within one, far inside `Q1.30`'s range of two. A
/// caller's vector that is not wraps (never panics).
#[inline(always)]
pub(super) fn ellipse_axes(sa: Option<Unit>, d: Unit, min_len: Fx) -> Option<(Vec3<Fx>, Vec3<Fx>)> {
    let a = sa.unwrap_or([0, 0, 1 << UNIT_FRAC]);
    // Products in Q2.60 (below 2^62 in magnitude), their difference rounded to Q1.30.
    let long = cross_words(a, d).map(round_q30);
    let unit = normalize_words(long, min_len)?;
    // dir x long in Q2.60, rounded once into the model's format.
    let shift = 2 * UNIT_FRAC - 32;
    let round = |p: i64| Fx::from_bits(p.wrapping_add(1 << (shift - 1)) >> shift);
    let short = cross_words(d, unit);
    Some((
        from_unit(unit),
        Vec3::new(round(short[0]), round(short[1]), round(short[2])),
    ))
}

/// `a x b` of `Q1.30` words, exact in `Q2.60`.
#[inline(always)]
fn cross_words(a: [i32; 3], b: [i32; 3]) -> [i64; 3] {
    let m = |x: i32, y: i32| x as i64 * y as i64;
    [
        m(a[1], b[2]).wrapping_sub(m(a[2], b[1])),
        m(a[2], b[0]).wrapping_sub(m(a[0], b[2])),
        m(a[0], b[1]).wrapping_sub(m(a[1], b[0])),
    ]
}

/// `v / |v|` of `Q1.30` words (magnitudes within one), in `Q1.30`, if `|v| > min_len`: the
/// squared length exact in 64 bits, the reciprocal root from `f32` (see the module docs).
#[inline(always)]
fn normalize_words(q: [i32; 3], min_len: Fx) -> Option<[i32; 3]> {
    // Q2.60, each square at most 2^62: the sum below 2^64 as unsigned.
    let n2 = q
        .iter()
        .fold(0u64, |s, &c| s.wrapping_add((c as i64 * c as i64) as u64));
    let min = q30(min_len) as i64;
    // Below 2^-8 in length the root leaves its format: too short to normalise, whatever
    // the caller's threshold.
    if n2 <= ((min * min) as u64).max(1 << 44) {
        return None;
    }
    // n2 = m 2^(32 - s), m in [2^30, 2^32) its leading bits (s even, so the root's power
    // of two is whole); |v|^-1 = (n2 2^-60)^-1/2 = m^-1/2 2^(14 + s/2).
    let s = n2.leading_zeros() & !1;
    let m = ((n2 << s) >> 32) as u32;
    let root = 1.0 / sqrt_f32(m as f32);
    // Scaled by 2^(14 + s/2 + ROOT_FRAC) (exact: a power of two), then to an integer below
    // 2^32 for a length above 2^-8 (a float-to-u32 conversion is one instruction).
    let scale = f32::from_bits((127 + 14 + ROOT_FRAC + s / 2) << 23);
    let r = (root * scale) as u32 as i64;
    // Q1.30 times Q8.24 (below 2^62: a component is at most the length), rounded back to
    // Q1.30.
    Some(q.map(|c| ((c as i64 * r + (1 << (ROOT_FRAC - 1))) >> ROOT_FRAC) as i32))
}

/// The skeleton's nodes `pos + m offset_i` (`m` a rotation matrix, `offset_i` in the
/// handle's frame) into `out`: [`super::place_skeleton`] for the fixed-point brush. Each
/// rotation entry enters as `Q1.30`; each offset splits into its signed integer word and
/// its fraction's upper 31 bits, so a row's three products are two sums of 32 x 32-bit
/// products, exact in 64 bits, recombined and rounded once (the offsets are validated
/// brush lengths, far below the range where the integer sums could wrap).
#[inline(always)]
pub(super) fn place_nodes(
    pos: Vec3<Fx>,
    offsets: &[[Fx; crate::params::MAX_LAYERS]; 3],
    m: &[[Fx; 3]; 3],
    out: &mut [Vec3<Fx>],
) {
    let rows = m.map(|row| row.map(|e| q30(e) as i64));
    let [ox, oy, oz] = offsets;
    for (node, ((x, y), z)) in out.iter_mut().zip(ox.iter().zip(oy).zip(oz)) {
        let split = |v: &Fx| {
            let b = v.to_bits();
            (b >> 32, ((b as u32) >> 1) as i64)
        };
        let parts = [split(x), split(y), split(z)];
        let row = |r: &[i64; 3]| {
            let high = (r[0].wrapping_mul(parts[0].0))
                .wrapping_add(r[1].wrapping_mul(parts[1].0))
                .wrapping_add(r[2].wrapping_mul(parts[2].0));
            let low = r[0] * parts[0].1 + r[1] * parts[1].1 + r[2] * parts[2].1;
            // high is in Q.30 of the integer words, low in Q.61: to the model's Q.32.
            let low = (low + (1 << 28)) >> 29;
            Fx::from_bits((high << 2).wrapping_add(low))
        };
        *node = Vec3::new(
            pos.x + row(&rows[0]),
            pos.y + row(&rows[1]),
            pos.z + row(&rows[2]),
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn random_unit(next: &mut impl FnMut() -> f64) -> [f64; 3] {
        loop {
            let v = [next(), next(), next()];
            let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            if n > 0.1 && n < 1.0 {
                return v.map(|c| c / n);
            }
        }
    }

    /// The axes of layers with random short axes (within the unit ball, as the surface's
    /// interpolated ones are, or the paper's normal) and unit segment directions: within
    /// `3e-7` of the exact unit vectors; none where `|sa x dir|` is below the threshold.
    #[test]
    fn ellipse_axes_match_f64() {
        let mut seed = 0x2545_f491_4f6c_dd1du64;
        let mut next = || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        let fx = |v: [f64; 3]| Vec3::<Fx>::from_f64(v);
        let cross = |a: [f64; 3], b: [f64; 3]| {
            [
                a[1] * b[2] - a[2] * b[1],
                a[2] * b[0] - a[0] * b[2],
                a[0] * b[1] - a[1] * b[0],
            ]
        };
        let min_len = 0.0087;
        let (mut some, mut none) = (0, 0);
        for k in 0..20_000 {
            let dir = random_unit(&mut next);
            // Every fourth on the paper; some nearly along the segment (no plane).
            let sa = match k % 4 {
                0 => None,
                1 => Some(dir.map(|c| c * 0.9 + next() * 0.004)),
                _ => Some(random_unit(&mut next).map(|c| c * (0.5 + 0.5 * next().abs()))),
            };
            let a = sa.unwrap_or([0.0, 0.0, 1.0]);
            let long = cross(a, dir);
            let len = (long[0] * long[0] + long[1] * long[1] + long[2] * long[2]).sqrt();
            match ellipse_axes(
                sa.map(|v| unit(fx(v))),
                unit(fx(dir)),
                Fx::from_f64(min_len),
            ) {
                Some((l, sh)) => {
                    some += 1;
                    assert!(len > min_len * 0.999, "{len}");
                    let unit = long.map(|c| c / len);
                    let short = cross(dir, unit);
                    let (l, sh) = (l.to_f64(), sh.to_f64());
                    for c in 0..3 {
                        assert!((l[c] - unit[c]).abs() < 3e-7, "{sa:?} {dir:?}: {l:?}");
                        assert!((sh[c] - short[c]).abs() < 3e-7, "{sa:?} {dir:?}: {sh:?}");
                    }
                }
                None => {
                    none += 1;
                    assert!(len <= min_len * 1.001, "{len}");
                }
            }
        }
        assert!(some > 10_000 && none > 100, "{some} {none}");
    }

    /// Skeleton nodes from random rotations and offsets along a bent brush up to 200 mm
    /// long, within half a nanometre of the `f64` placement (the rotation's entries rounded to
    /// 2^-31, times 200 mm, three times).
    #[test]
    fn skeleton_nodes_match_f64() {
        use crate::params::MAX_LAYERS;
        use crate::quat::Quat;
        let mut seed = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        for _ in 0..2_000 {
            let q = [next(), next(), next(), next()];
            let n = q.iter().map(|c| c * c).sum::<f64>().sqrt().max(1e-3);
            let rot = Quat::<f64>::from_f64(q.map(|c| c / n));
            let m64 = super::super::RotMat::from_quat(rot).m;
            let pos = [next() * 300.0, next() * 300.0, next() * 100.0];
            let offsets: [[f64; MAX_LAYERS]; 3] =
                core::array::from_fn(|_| core::array::from_fn(|_| next() * 200.0));
            let mut out = [Vec3::<Fx>::ZERO; MAX_LAYERS];
            place_nodes(
                Vec3::from_f64(pos),
                &offsets.map(|o| o.map(Fx::from_f64)),
                &m64.map(|r| r.map(Fx::from_f64)),
                &mut out,
            );
            for (i, node) in out.iter().enumerate() {
                let o = [offsets[0][i], offsets[1][i], offsets[2][i]];
                let got = node.to_f64();
                for (r, row) in m64.iter().enumerate() {
                    let want = pos[r] + row[0] * o[0] + row[1] * o[1] + row[2] * o[2];
                    assert!((got[r] - want).abs() < 5e-7, "{got:?} row {r}: {want}");
                }
            }
        }
    }
}
