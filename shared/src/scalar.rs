//! The number type the model is written over.
//!
//! Every piece of the model is generic over [`Scalar`], so the device's fixed-point arithmetic
//! ([`Fx`]) and the `f32` / `f64` references run *the same code path*. Only the handful of
//! operations below may differ between implementations, and each one documents its rounding
//! and overflow behaviour.
//!
//! # The fixed-point format: why `I32F32`, millimetres and "per substep" velocities
//!
//! Quantities the model must carry (large brush, N = 16, substep h = 40 us, see
//! `../shared/notes/fixed-point-magnitudes.md` for the derivation):
//!
//! | quantity | smallest that matters | largest |
//! |---|---|---|
//! | position (mm) | 1 um for the rest test, 5 um fixed-vs-f64 | a few hundred mm of canvas |
//! | velocity as displacement per substep (mm) | 0.38 mm/s creep = 1.5e-5 mm | 500 mm/s stroke = 0.02 mm |
//! | coefficient h^2 k / W' (dimensionless) | soft skeleton tie: 1.3e-3, wanted to 1e-4 relative | stiff 1000x springs: ~0.5 |
//!
//! * **Units.** Positions are millimetres. Velocities are stored as the displacement per
//!   substep `u = v h` (mm), so the position update is a plain add `x += u` with no `h`
//!   multiplication. Every spring, damper and friction term enters only through
//!   dimensionless coefficients such as `h^2 k / W'` and `h k_d / W'` that are computed when a
//!   parameter changes (in `f64` on every target, once, off the hot path): `h^2` itself
//!   (1.6e-9 s^2) never appears in fixed point.
//! * **Format.** `I32F32`: 32 integer bits (range +-2.1e9 mm, so no product of positions or
//!   coefficients the model forms can overflow) and 32 fraction bits (resolution 2.3e-10 mm =
//!   0.23 pm, or 5.8 um/s as a velocity at 25 kHz). A soft tie coefficient of 1.3e-3 is held to
//!   1.8e-7 relative. `Q16.16` was rejected: its 1.5e-5 resolution makes the soft tie stall
//!   for displacements under 11 um, more than the 5 um budget.
//! * **Error budget.** Each multiply rounds toward -inf (error <= 2.3e-10 mm); a substep does
//!   about 150 roundings per mass. Even if all accumulated coherently over one simulated
//!   second at 25 kHz that is 150 * 25,000 * 2.3e-10 ~ 0.9 um, and random accumulation gives
//!   about 1e-6 um; what dominates fixed-vs-f64 differences in practice is the contact
//!   decision on masses that sit within a few picometres of the paper. The test
//!   `fixed_matches_f64_on_every_example` measures it (see the README for the figure).
//! * **Overflow.** Explicit and the same in debug and release: add, sub, mul and div
//!   *saturate*; division by zero saturates to the signed maximum (or 0 for 0/0); `sqrt` of a
//!   negative number returns 0. None of these can panic.
//!
//! The cost of 64-bit fixed point on a Cortex-M4 is measured by the firmware issue; the whole
//! model changes format by changing the [`Fx`] alias, and the error analysis above says what a
//! 32-bit format would have to give up.

use core::fmt::Debug;
use core::ops::{Add, AddAssign, Mul, Neg, Sub, SubAssign};

/// The raw fixed-point format behind [`Fx`].
pub type FxRaw = fixed::types::I32F32;

/// The fixed-point number the device runs: [`FxRaw`] with *saturating* operators.
///
/// The `fixed` crate's own `+`, `-` and `*` panic on overflow in debug builds and wrap in
/// release builds; this wrapper makes every operator saturate in both, so overflow is never a
/// matter of build profile.
#[derive(Copy, Clone, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
#[repr(transparent)]
pub struct Fx(pub FxRaw);

impl Fx {
    pub const MAX: Fx = Fx(FxRaw::MAX);
    pub const MIN: Fx = Fx(FxRaw::MIN);
    /// The smallest positive step, 2^-32.
    pub const DELTA: Fx = Fx(FxRaw::DELTA);
    /// The raw two's-complement bits (for the wire format and bit-exact comparisons).
    #[inline]
    pub const fn to_bits(self) -> i64 {
        self.0.to_bits()
    }
    #[inline]
    pub const fn from_bits(bits: i64) -> Fx {
        Fx(FxRaw::from_bits(bits))
    }
}

impl Debug for Fx {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        Debug::fmt(&self.0, f)
    }
}

impl core::fmt::Display for Fx {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        core::fmt::Display::fmt(&self.0, f)
    }
}

impl Add for Fx {
    type Output = Fx;
    #[inline]
    fn add(self, rhs: Fx) -> Fx {
        Fx(self.0.saturating_add(rhs.0))
    }
}
impl Sub for Fx {
    type Output = Fx;
    #[inline]
    fn sub(self, rhs: Fx) -> Fx {
        Fx(self.0.saturating_sub(rhs.0))
    }
}
impl Mul for Fx {
    type Output = Fx;
    #[inline]
    fn mul(self, rhs: Fx) -> Fx {
        // Full 128-bit product, floor-shifted back to 32 fraction bits, clamped: the same
        // result as `saturating_mul`, without its general-purpose overflow bookkeeping.
        let p = (self.0.to_bits() as i128 * rhs.0.to_bits() as i128) >> 32;
        let bits = if p > i64::MAX as i128 {
            i64::MAX
        } else if p < i64::MIN as i128 {
            i64::MIN
        } else {
            p as i64
        };
        Fx(FxRaw::from_bits(bits))
    }
}
impl Neg for Fx {
    type Output = Fx;
    #[inline]
    fn neg(self) -> Fx {
        Fx(self.0.saturating_neg())
    }
}
impl AddAssign for Fx {
    #[inline]
    fn add_assign(&mut self, rhs: Fx) {
        *self = *self + rhs;
    }
}
impl SubAssign for Fx {
    #[inline]
    fn sub_assign(&mut self, rhs: Fx) {
        *self = *self - rhs;
    }
}

/// A real-number type the model can run on: `f32`, `f64` or [`Fx`].
pub trait Scalar:
    Copy
    + Debug
    + PartialOrd
    + PartialEq
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Neg<Output = Self>
    + AddAssign
    + SubAssign
    + Send
    + Sync
    + 'static
{
    const ZERO: Self;
    const ONE: Self;
    /// Short name for reports ("fixed", "f32", "f64").
    const NAME: &'static str;
    /// Conversion from a parameter or input value. Non-finite input becomes zero for fixed
    /// point; callers validate first.
    fn from_f64(v: f64) -> Self;
    fn to_f64(self) -> f64;
    /// Division; see the module docs for the fixed-point behaviour at zero.
    fn div(self, rhs: Self) -> Self;
    /// Square root; 0 for negative input.
    fn sqrt(self) -> Self;
    /// `1 / sqrt(self)`; the largest value for zero or negative input. One call replaces a
    /// square root and a division when normalising.
    fn rsqrt(self) -> Self;
    /// Sine and cosine of an angle in radians.
    fn sin_cos(self) -> (Self, Self);
    /// Angle of the point (x, y) = (`x`, `self`) in (-pi, pi]; 0 for (0, 0).
    fn atan2(self, x: Self) -> Self;
    fn abs(self) -> Self {
        if self < Self::ZERO {
            -self
        } else {
            self
        }
    }
    fn min(self, other: Self) -> Self {
        if other < self {
            other
        } else {
            self
        }
    }
    fn max(self, other: Self) -> Self {
        if other > self {
            other
        } else {
            self
        }
    }
    fn clamp(self, lo: Self, hi: Self) -> Self {
        self.max(lo).min(hi)
    }
    fn from_f32(v: f32) -> Self {
        Self::from_f64(v as f64)
    }
    fn to_f32(self) -> f32 {
        self.to_f64() as f32
    }
    fn from_usize(v: usize) -> Self {
        Self::from_f64(v as f64)
    }
}

/// The float references: IEEE arithmetic, with `libm` for the functions `core` lacks, so the
/// results are the same on every target and in every build configuration.
macro_rules! float_scalar {
    ($t:ty, $name:literal, $sqrt:path, $sincos:path, $atan2:path) => {
        impl Scalar for $t {
            const ZERO: Self = 0.0;
            const ONE: Self = 1.0;
            const NAME: &'static str = $name;
            #[inline]
            fn from_f64(v: f64) -> Self {
                v as $t
            }
            #[inline]
            fn to_f64(self) -> f64 {
                self as f64
            }
            #[inline]
            fn div(self, rhs: Self) -> Self {
                self / rhs
            }
            #[inline]
            fn sqrt(self) -> Self {
                if self > 0.0 {
                    $sqrt(self)
                } else {
                    0.0
                }
            }
            #[inline]
            fn rsqrt(self) -> Self {
                if self > 0.0 {
                    1.0 / $sqrt(self)
                } else {
                    <$t>::MAX
                }
            }
            fn sin_cos(self) -> (Self, Self) {
                $sincos(self)
            }
            fn atan2(self, x: Self) -> Self {
                $atan2(self, x)
            }
        }
    };
}

float_scalar!(f64, "f64", libm::sqrt, libm::sincos, libm::atan2);
float_scalar!(f32, "f32", libm::sqrtf, libm::sincosf, libm::atan2f);

impl Scalar for Fx {
    const ZERO: Self = Fx(FxRaw::ZERO);
    const ONE: Self = Fx(FxRaw::ONE);
    const NAME: &'static str = "fixed";
    /// Rounds to nearest (ties away from zero) and saturates; NaN becomes zero. Rust's
    /// float-to-int `as` cast is defined to saturate and to map NaN to 0 on every target.
    #[inline]
    fn from_f64(v: f64) -> Self {
        let scaled = v * 4_294_967_296.0;
        let rounded = if scaled >= 0.0 {
            scaled + 0.5
        } else {
            scaled - 0.5
        };
        Fx(FxRaw::from_bits(rounded as i64))
    }
    #[inline]
    fn to_f64(self) -> f64 {
        // Exact for |x| < 2^21; correctly rounded above.
        self.0.to_bits() as f64 * (1.0 / 4_294_967_296.0)
    }
    #[inline]
    fn div(self, rhs: Self) -> Self {
        if rhs.0 == FxRaw::ZERO {
            if self.0 > FxRaw::ZERO {
                Fx::MAX
            } else if self.0 < FxRaw::ZERO {
                Fx::MIN
            } else {
                Fx(FxRaw::ZERO)
            }
        } else {
            Fx(self.0.saturating_div(rhs.0))
        }
    }
    /// Correctly rounded IEEE `f64` square root of the exactly converted value, rounded to
    /// the nearest `Fx`. Bit-identical wherever IEEE 754 double arithmetic is (on the
    /// Cortex-M4F through the compiler's soft-float routines), and about 20x faster on the host
    /// than a bit-serial integer root. Values above 2^21 lose fraction bits in the conversion;
    /// the model's square roots are of squared lengths of a few hundred mm^2 at most.
    #[inline]
    fn sqrt(self) -> Self {
        if self.0 > FxRaw::ZERO {
            Fx::from_f64(libm::sqrt(self.to_f64()))
        } else {
            Fx(FxRaw::ZERO)
        }
    }
    #[inline]
    fn rsqrt(self) -> Self {
        if self.0 > FxRaw::ZERO {
            Fx::from_f64(1.0 / libm::sqrt(self.to_f64()))
        } else {
            Fx::MAX
        }
    }
    /// CORDIC (the `cordic` crate, 32 rotations: about 1e-9 rad) after reducing the angle to
    /// [-pi, pi] here, so the crate's own reduction loop runs at most once.
    fn sin_cos(self) -> (Self, Self) {
        let two_pi = FxRaw::TAU;
        let mut a = self.0 % two_pi;
        if a > FxRaw::PI {
            a -= two_pi;
        } else if a < -FxRaw::PI {
            a += two_pi;
        }
        let (s, c) = cordic::sin_cos(a);
        (Fx(s), Fx(c))
    }
    /// CORDIC arc tangent of a ratio kept within [-1, 1] (the crate's `atan2` divides `y / x`
    /// unguarded, which can overflow), with the quadrant restored here.
    fn atan2(self, x: Self) -> Self {
        let (y, x) = (self.0, x.0);
        if x == FxRaw::ZERO && y == FxRaw::ZERO {
            return Fx(FxRaw::ZERO);
        }
        let half_pi = FxRaw::FRAC_PI_2;
        let a = if y.unsigned_abs() <= x.unsigned_abs() {
            // |y / x| <= 1.
            let t = cordic::atan(y / x);
            if x > FxRaw::ZERO {
                t
            } else if y >= FxRaw::ZERO {
                t + FxRaw::PI
            } else {
                t - FxRaw::PI
            }
        } else {
            // |x / y| <= 1: atan2(y, x) = +-pi/2 - atan(x / y).
            let t = cordic::atan(x / y);
            if y > FxRaw::ZERO {
                half_pi - t
            } else {
                -half_pi - t
            }
        };
        Fx(a)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fixed_trigonometry_matches_f64() {
        let mut worst: f64 = 0.0;
        for k in -400..=400 {
            let a = k as f64 * 0.0191;
            let (s, c) = <Fx as Scalar>::from_f64(a).sin_cos();
            worst = worst
                .max((s.to_f64() - a.sin()).abs())
                .max((c.to_f64() - a.cos()).abs());
            for &r in &[0.3, 1.0, 150.0] {
                let (y, x) = (r * a.sin(), r * a.cos());
                let t = Scalar::atan2(<Fx as Scalar>::from_f64(y), <Fx as Scalar>::from_f64(x));
                let d = (t.to_f64() - y.atan2(x)).abs();
                let d = d.min((d - 2.0 * core::f64::consts::PI).abs());
                worst = worst.max(d);
            }
        }
        assert!(worst < 1e-7, "worst trig error {worst}");
        let zero = <Fx as Scalar>::ZERO;
        assert_eq!(Scalar::atan2(zero, zero), zero);
    }

    #[test]
    fn fixed_saturates_instead_of_panicking() {
        let one = <Fx as Scalar>::ONE;
        let zero = <Fx as Scalar>::ZERO;
        assert_eq!(Fx::MAX + Fx::MAX, Fx::MAX);
        assert_eq!(Fx::MIN - Fx::MAX, Fx::MIN);
        assert_eq!(Fx::MAX * Fx::MAX, Fx::MAX);
        assert_eq!(Fx::MAX * -Fx::MAX, Fx::MIN);
        let a = <Fx as Scalar>::from_f64(-3.25);
        let b = <Fx as Scalar>::from_f64(1.5);
        assert_eq!((a * b).0, a.0.saturating_mul(b.0));
        assert_eq!(<Fx as Scalar>::from_f64(-1e30), Fx::MIN);
        assert_eq!(<Fx as Scalar>::from_f64(0.1).0, FxRaw::from_num(0.1));
        assert_eq!(-Fx::MIN, Fx::MAX);
        assert_eq!(Scalar::div(one, zero), Fx::MAX);
        assert_eq!(Scalar::div(-one, zero), Fx::MIN);
        assert_eq!(Scalar::div(zero, zero), zero);
        assert_eq!(Scalar::div(Fx::MAX, Fx::DELTA), Fx::MAX);
        assert_eq!(Scalar::sqrt(-one), zero);
        assert_eq!(<Fx as Scalar>::from_f64(f64::NAN), zero);
        assert_eq!(<Fx as Scalar>::from_f64(1e30), Fx::MAX);
        assert_eq!(Scalar::sqrt(<Fx as Scalar>::from_f64(6.25)).to_f64(), 2.5);
        assert_eq!(Scalar::rsqrt(<Fx as Scalar>::from_f64(0.25)).to_f64(), 2.0);
        assert_eq!(Scalar::rsqrt(zero), Fx::MAX);
    }
}
