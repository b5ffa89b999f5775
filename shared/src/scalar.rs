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
//! The cost of 64-bit fixed point on a Cortex-M4 is measured by `hil bench` (docs/figures.md);
//! the whole model changes format by changing the [`Fx`] alias, and the error analysis above
//! says what a 32-bit format would have to give up.

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

// Saturating add and subtract on the raw bits: see [`raw::add`] and [`raw::sub`].
impl Add for Fx {
    type Output = Fx;
    #[inline]
    fn add(self, rhs: Fx) -> Fx {
        Fx::from_bits(raw::add(self.to_bits(), rhs.to_bits()))
    }
}
impl Sub for Fx {
    type Output = Fx;
    #[inline]
    fn sub(self, rhs: Fx) -> Fx {
        Fx::from_bits(raw::sub(self.to_bits(), rhs.to_bits()))
    }
}

impl Mul for Fx {
    type Output = Fx;
    #[inline]
    fn mul(self, rhs: Fx) -> Fx {
        Fx(FxRaw::from_bits(mul_bits(
            self.0.to_bits(),
            rhs.0.to_bits(),
        )))
    }
}
/// `floor(a * b / 2^32)` clamped to `i64`: the saturating `I32F32` product, exactly.
///
/// On 64-bit hosts one 128-bit multiply. On 32-bit targets (the Cortex-M4) a 128-bit multiply
/// is a library call; four 32 x 32 -> 64 partial products (single
/// `SMULL`/`UMULL`-class instructions) give the same bits for much less. `mul_paths_agree`
/// tests the two against each other.
#[inline]
fn mul_bits(a: i64, b: i64) -> i64 {
    #[cfg(target_pointer_width = "64")]
    {
        narrow(mul_wide(a, b))
    }
    #[cfg(not(target_pointer_width = "64"))]
    {
        mul_floor_partial(a, b)
    }
}

#[inline]
#[allow(dead_code)]
fn mul_wide(a: i64, b: i64) -> i128 {
    a as i128 * b as i128
}

/// `floor(a c / 2^32)` for a raw coefficient `|c| < 2^32` (`|c| < 1` as a number): the product
/// then has magnitude below `|a|`, so it cannot overflow and needs no saturation test.
///
/// On 64-bit hosts one 128-bit multiply and a shift, no range test. On 32-bit targets write
/// `c` as `cl - s 2^32` with `cl` its low word (a `u32`) and `s` 1 for negative `c`, else 0, and
/// `a = ah 2^32 + al` (`ah` signed, `al` unsigned). Then `floor(a c / 2^32) = ah cl +
/// floor(al cl / 2^32) - s a` exactly (the other terms are multiples of 2^32). `|ah cl| <
/// 2^63` and `al cl < 2^64`; the first two terms sum to `floor(a cl / 2^32)`, of magnitude at
/// most `|a|`, and the whole to the true product: no step can overflow, and it takes two
/// 32 x 32 -> 64 multiplies (one `SMULL`, one `UMULL` on the Cortex-M4) instead of four and
/// 128-bit sums. `mul_coef_is_the_product` tests both forms against the saturating product.
#[inline]
fn mul_coef_bits(a: i64, c: i64) -> i64 {
    #[cfg(target_pointer_width = "64")]
    {
        // |a c| < 2^63 2^32: the shifted product fits i64, the cast drops only sign bits.
        (mul_wide(a, c) >> 32) as i64
    }
    #[cfg(all(not(target_pointer_width = "64"), not(arm_asm)))]
    {
        mul_coef_partial(a, c)
    }
    #[cfg(arm_asm)]
    {
        raw::mul_coef_arm(a, c)
    }
}

/// The 32-bit targets' form of [`mul_coef_bits`] (tested on every target).
#[inline]
#[allow(dead_code)]
fn mul_coef_partial(a: i64, c: i64) -> i64 {
    let cl = c as u32 as u64;
    let high = (a >> 32).wrapping_mul(cl as i64);
    let low = (((a as u32) as u64 * cl) >> 32) as i64;
    // c >> 63 is all ones for a negative c: subtract a, else nothing. Wrapping operations
    // (none wraps for |c| < 1), so that a caller's broken promise gives a wrong value, not a
    // panic in a build with overflow checks.
    high.wrapping_add(low).wrapping_sub(a & (c >> 63))
}

/// `floor(a b / 2^32)` clamped to `i64`, from 32-bit halves: a = ah 2^32 + al with ah signed,
/// al unsigned. The product is hh 2^64 + (hl + lh) 2^32 + ll and only ll has bits below 2^32,
/// so the quotient is exactly hh 2^32 + hl + lh + floor(ll / 2^32): the low word of ll is
/// never needed and nothing is shifted right in 128 bits.
///
/// Usually |hh| < 2^31 and the sum fits `i64` step by step: two checked 64-bit adds. Only when
/// a step overflows (a product at or near the format's range, or intermediate sums that
/// cancel) is the sum formed in 128 bits and clamped, so the result is exact either way.
#[inline]
#[allow(dead_code)]
fn mul_floor_partial(a: i64, b: i64) -> i64 {
    let (ah, bh) = ((a >> 32) as i32, (b >> 32) as i32);
    // The model's values have integer parts far below 2^15 (mm, coefficients, radians): then
    // |hh| <= 2^30 is one 32-bit multiply, |hl|, |lh| < 2^47 and the whole sum is below
    // 2^62 + 2^48 + 2^32 < 2^63, so it needs no overflow test at all.
    // Both high words in [-2^15, 2^15): one unsigned compare of the two biased words OR-ed
    // (either above 2^16 sets a bit at or above 16).
    if ((ah as u32).wrapping_add(1 << 15) | (bh as u32).wrapping_add(1 << 15)) < 1 << 16 {
        let (al, bl) = (a as u32, b as u32);
        let hh = (ah * bh) as i64;
        let hl = ah as i64 * bl as i64;
        let lh = al as i64 * bh as i64;
        let ll = ((al as u64 * bl as u64) >> 32) as i64;
        return (hh << 32) + hl + lh + ll;
    }
    mul_floor_large(a, b)
}

/// [`mul_floor_partial`] for operands with an integer part beyond +-2^15: out of line, since
/// the model never forms them on its hot path and every product site inlines the fast path.
#[inline(never)]
#[allow(dead_code)]
fn mul_floor_large(a: i64, b: i64) -> i64 {
    let (ah, al) = ((a >> 32) as i32, a as u32);
    let (bh, bl) = ((b >> 32) as i32, b as u32);
    let hh = ah as i64 * bh as i64; // signed x signed
    let hl = ah as i64 * bl as i64; // signed x unsigned: |.| < 2^63
    let lh = al as i64 * bh as i64;
    let ll = al as u64 * bl as u64; // unsigned x unsigned

    // hl + floor(ll / 2^32) cannot overflow: |hl| <= 2^31 (2^32 - 1) and the other < 2^32.
    let mid = hl + (ll >> 32) as i64;
    if let Ok(hh32) = i32::try_from(hh) {
        let step = ((hh32 as i64) << 32).checked_add(mid);
        if let Some(q) = step.and_then(|s| s.checked_add(lh)) {
            return q;
        }
    }
    mul_floor_slow(hh, mid, lh)
}

/// The overflowing case of [`mul_floor_partial`]: `hh 2^32 + mid + lh` in 128 bits, clamped.
#[cold]
#[inline(never)]
#[allow(dead_code)]
fn mul_floor_slow(hh: i64, mid: i64, lh: i64) -> i64 {
    let q = ((hh as i128) << 32) + mid as i128 + lh as i128;
    let (hi, lo) = ((q >> 64) as i64, q as i64);
    if hi == lo >> 63 {
        lo
    } else if hi < 0 {
        i64::MIN
    } else {
        i64::MAX
    }
}

/// `floor(p / 2^32)` clamped to `i64`, for a full 128-bit product `p`. The quotient fits in
/// `i64` exactly when `p`'s upper 64 bits lie in `[-2^31, 2^31)`, i.e. are the sign extension
/// of their low 32 bits: one 64-bit test instead of two 128-bit comparisons after the shift
/// (the comparisons were a quarter of the host's fixed-point tick). `narrow_matches_clamp`
/// tests it against the plain clamp.
#[inline]
#[allow(dead_code)]
fn narrow(p: i128) -> i64 {
    let hi = (p >> 64) as i64;
    if hi == (hi as i32) as i64 {
        (p >> 32) as i64
    } else if hi < 0 {
        i64::MIN
    } else {
        i64::MAX
    }
}

/// `p` clamped to `i64`: the references' saturation (see [`raw`]).
#[allow(dead_code)]
fn clamp_i128(p: i128) -> i64 {
    if p > i64::MAX as i128 {
        i64::MAX
    } else if p < i64::MIN as i128 {
        i64::MIN
    } else {
        p as i64
    }
}

/// [`Fx`]'s saturating add, subtract and multiply and its coefficient multiply on the raw
/// bits: what `+`, `-`, `*` and [`Scalar::mul_tested_coef`] run on this target, beside the
/// portable reference each must equal bit for bit.
///
/// On the pen (`cfg(arm_asm)`, see `build.rs`) all but the multiply are a few lines of
/// inline assembly each, because the compiler's own code for them is what the force loop
/// spends most of its instructions on (measured with `hil bench`, QEMU `-icount`):
///
/// * **add / subtract.** LLVM tests a 64-bit overflow with two exclusive-ors, a bit clear and
///   a branch on the sign after `adds`/`adc`, six instructions for every sum; the hardware
///   already has the answer in the V flag of `adcs`/`sbcs`, so the usual path is three
///   (`adds`, `adcs`, `bvc`), and only an overflow runs the clamp. The force loop
///   does a great many sums, so the saving shows in every tick.
/// * **coefficient multiply** `floor(a c / 2^32)` for `|c| < 2^32`: with `c = ch 2^32 + cl`
///   (`ch` 0 or -1, `cl` unsigned) and `a = ah 2^32 + al` (`ah` signed), the product is
///   `ah cl + hi(al cl) + ch a`. One `umull`, one `umlal` (which takes `ah` unsigned; the
///   `ah < 0` correction subtracts `cl` from the high word) and a masked 64-bit subtract of
///   `a` when `c < 0`: nine instructions, no branch, against about fourteen.
/// * **multiply** `floor(a b / 2^32)`, saturating, stays the compiler's
///   (`mul_floor_partial`): the same identity as the coefficient product's with
///   both operands split is nine instructions of assembly against eleven, and measured
///   a little faster, but LLVM takes an `asm!` block for cheap and inlined and unrolled
///   more around it: kilobytes more flash on both images, enough to push the QEMU image
///   past its 128 KiB budget (docs/firmware-cost.md). It is still checked on the core like
///   the others, as the 32-bit path.
///
/// No host test can execute the assembly, so the firmware checks it on the device against
/// the references here: `maobi-fw arith` under QEMU (`hil` test
/// `qemu::fixed_point_assembly_matches_its_reference_on_the_core`) runs every operator
/// over edge cases and a million pseudo-random operands, and the `hil` link tests compare
/// every tick of every example stroke with the host simulation bit for bit.
pub mod raw {
    /// The saturating sum `a + b` of two raw [`super::Fx`] values.
    #[inline]
    pub fn add(a: i64, b: i64) -> i64 {
        #[cfg(arm_asm)]
        {
            add_arm(a, b)
        }
        #[cfg(not(arm_asm))]
        {
            add_reference(a, b)
        }
    }

    /// The saturating difference `a - b` of two raw [`super::Fx`] values.
    #[inline]
    pub fn sub(a: i64, b: i64) -> i64 {
        #[cfg(arm_asm)]
        {
            sub_arm(a, b)
        }
        #[cfg(not(arm_asm))]
        {
            sub_reference(a, b)
        }
    }

    /// `floor(a c / 2^32)` for a raw coefficient `-2^32 < c < 2^32` (the product of an
    /// [`super::Fx`] and a number of magnitude below one, which cannot overflow). Other `c`
    /// give a wrong value (never a panic): callers test [`super::Scalar::is_coef`] first.
    #[inline]
    pub fn mul_coef(a: i64, c: i64) -> i64 {
        super::mul_coef_bits(a, c)
    }

    /// The saturating product `floor(a b / 2^32)` of two raw [`super::Fx`] values: what `*`
    /// runs on this target.
    #[inline]
    pub fn mul(a: i64, b: i64) -> i64 {
        super::mul_bits(a, b)
    }

    /// The reference for [`mul`]: the exact product in 128 bits, shifted (floor) and clamped.
    pub fn mul_reference(a: i64, b: i64) -> i64 {
        super::clamp_i128((a as i128 * b as i128) >> 32)
    }

    /// The reference for [`add`]: Rust's checked sum, clamped toward the sign of `b`.
    #[inline]
    pub fn add_reference(a: i64, b: i64) -> i64 {
        // The clamp on a cold path: the usual case is the add and a branch on the overflow
        // flag that is never taken, not a branch-free select computed on every call (about
        // a third of the host's fixed-point tick).
        match a.checked_add(b) {
            Some(v) => v,
            None => saturated(b > 0),
        }
    }

    /// The reference for [`sub`]: Rust's checked difference, clamped away from the sign of
    /// `b`.
    #[inline]
    pub fn sub_reference(a: i64, b: i64) -> i64 {
        match a.checked_sub(b) {
            Some(v) => v,
            None => saturated(b < 0),
        }
    }

    /// The reference for [`mul_coef`]: the exact product in 128 bits, shifted (floor).
    pub fn mul_coef_reference(a: i64, c: i64) -> i64 {
        ((a as i128 * c as i128) >> 32) as i64
    }

    /// The bound an overflowing sum or difference saturates to.
    #[cold]
    #[inline(never)]
    fn saturated(up: bool) -> i64 {
        if up {
            i64::MAX
        } else {
            i64::MIN
        }
    }

    /// An `i64`'s low and high 32-bit words: the assembly works on the halves, the low word
    /// first, as AAPCS holds an i64.
    #[cfg(arm_asm)]
    #[inline(always)]
    fn words(x: i64) -> (u32, u32) {
        (x as u32, (x >> 32) as u32)
    }

    /// The `i64` with low word `lo` and high word `hi`.
    #[cfg(arm_asm)]
    #[inline(always)]
    fn from_words(lo: u32, hi: u32) -> i64 {
        ((hi as u64) << 32 | lo as u64) as i64
    }

    #[cfg(arm_asm)]
    #[inline]
    fn add_arm(a: i64, b: i64) -> i64 {
        let (mut lo, mut hi) = words(a);
        let (b_lo, b_hi) = words(b);
        // SAFETY: register arithmetic only: no memory, no stack; the flags are clobbered
        // (not `preserves_flags`).
        #[allow(unsafe_code)] // audited, see lib.rs
        unsafe {
            core::arch::asm!(
                "adds {lo}, {lo}, {b_lo}",
                "adcs {hi}, {hi}, {b_hi}",
                "bvc 2f",
                // Signed overflow: the true sum has b's sign. MAX = (0x7fffffff, 0xffffffff)
                // for b > 0, MIN = (0x80000000, 0) for b < 0: lo = !(b_hi >> 31 arithmetic),
                // hi = lo ^ 0x80000000.
                "asrs {lo}, {b_hi}, #31",
                "mvns {lo}, {lo}",
                "eor {hi}, {lo}, #0x80000000",
                "2:",
                lo = inout(reg) lo,
                hi = inout(reg) hi,
                b_lo = in(reg) b_lo,
                b_hi = in(reg) b_hi,
                options(pure, nomem, nostack),
            );
        }
        from_words(lo, hi)
    }

    #[cfg(arm_asm)]
    #[inline]
    fn sub_arm(a: i64, b: i64) -> i64 {
        let (mut lo, mut hi) = words(a);
        let (b_lo, b_hi) = words(b);
        // SAFETY: as in `add_arm`.
        #[allow(unsafe_code)] // audited, see lib.rs
        unsafe {
            core::arch::asm!(
                "subs {lo}, {lo}, {b_lo}",
                "sbcs {hi}, {hi}, {b_hi}",
                "bvc 2f",
                // Signed overflow: the true difference has the sign opposite to b's: MAX for
                // b < 0 (lo = b_hi >> 31 = all ones), MIN for b > 0 (lo = 0).
                "asrs {lo}, {b_hi}, #31",
                "eor {hi}, {lo}, #0x80000000",
                "2:",
                lo = inout(reg) lo,
                hi = inout(reg) hi,
                b_lo = in(reg) b_lo,
                b_hi = in(reg) b_hi,
                options(pure, nomem, nostack),
            );
        }
        from_words(lo, hi)
    }

    /// [`mul_coef`] on the Cortex-M4: see the module docs for the identity.
    #[cfg(arm_asm)]
    #[inline]
    pub(super) fn mul_coef_arm(a: i64, c: i64) -> i64 {
        let (a_lo, a_hi) = words(a);
        let (c_lo, c_hi) = words(c);
        let (lo, hi): (u32, u32);
        // SAFETY: register arithmetic only: no memory, no stack; the flags are clobbered.
        #[allow(unsafe_code)] // audited, see lib.rs
        unsafe {
            core::arch::asm!(
                // hi:lo = hi(a_lo c_lo) + a_hi c_lo, a_hi taken unsigned by umlal.
                "umull {t}, {lo}, {a_lo}, {c_lo}",
                "movs {hi}, #0",
                "umlal {lo}, {hi}, {a_hi}, {c_lo}",
                // a_hi < 0: umlal added 2^32 c_lo too many to the high word.
                "and {t}, {c_lo}, {a_hi}, asr #31",
                "subs {hi}, {hi}, {t}",
                // c < 0 (c_hi all ones): subtract a. `and` without `s` leaves the borrow of
                // `subs` for `sbcs`.
                "and {t}, {a_lo}, {c_hi}",
                "subs {lo}, {lo}, {t}",
                "and {t}, {a_hi}, {c_hi}",
                "sbcs {hi}, {hi}, {t}",
                a_lo = in(reg) a_lo,
                a_hi = in(reg) a_hi,
                c_lo = in(reg) c_lo,
                c_hi = in(reg) c_hi,
                t = out(reg) _,
                lo = out(reg) lo,
                hi = out(reg) hi,
                options(pure, nomem, nostack),
            );
        }
        from_words(lo, hi)
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
    /// `1 / self`. In fixed point the reciprocal is within about `1 + |1 / self|` units of
    /// the format's resolution, so `a * b.recip()` is within about `|a| (1 + |1 / b|)` units
    /// of the quotient (the test `recip_products_are_within_the_stated_bound_of_the_quotient`),
    /// where [`Scalar::div`] is within one: a few tens of units (1e-8) for the surface's
    /// radii, `r0^2` over a long radius of at least `r0`, for one multiply instead of
    /// `div`'s three and its residual. Zero
    /// gives the largest value.
    #[inline]
    fn recip(self) -> Self {
        Self::ONE.div(self)
    }
    /// Square root; 0 for negative input.
    fn sqrt(self) -> Self;
    /// `1 / sqrt(self)`; the largest value for zero or negative input. One call replaces a
    /// square root and a division when normalising.
    fn rsqrt(self) -> Self;
    /// [`Scalar::rsqrt`] given `near`, a close guess at it (the same quantity's root one
    /// substep ago), which an implementation may refine instead of starting afresh: the
    /// fixed-point format takes one Newton step from it when it is within 2^-17 of the root
    /// (relative error then below 1e-10), and the float types ignore it (their hardware
    /// root is cheaper than the step).
    #[inline]
    fn rsqrt_near(self, near: Self) -> Self {
        let _ = near;
        self.rsqrt()
    }
    /// `self * c`, the same value in every implementation, for the model's coefficients: a
    /// `c` with `|c| < 1` (the implicit solve's `c_k`, `c_j`, `c_t`, tie weights, drag
    /// factors, rotation matrix entries) cannot make the product overflow, so the fixed-point
    /// format skips the overflow check and half of the partial products. Any other `c` takes
    /// the ordinary product.
    #[inline]
    fn mul_coef(self, c: Self) -> Self {
        self * c
    }
    /// Whether [`Scalar::mul_tested_coef`] may take `self` as its coefficient: `|self| < 1` in
    /// fixed point, always for the float types. A loop that multiplies by the same
    /// coefficients many times tests them once with this instead of on every product.
    #[inline]
    fn is_coef(self) -> bool {
        true
    }
    /// `self * c` for a `c` whose [`Scalar::is_coef`] holds (the caller tested it), the same
    /// value as [`Scalar::mul_coef`] without its test. For any other `c` the fixed-point
    /// result is wrong (never a panic): call it only behind the test.
    #[inline]
    fn mul_tested_coef(self, c: Self) -> Self {
        self * c
    }
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
    /// A count (encoder counts, ADC codes): the conversion through `f64`, which an
    /// implementation may do exactly without it.
    fn from_i64(v: i64) -> Self {
        Self::from_f64(v as f64)
    }
    /// `self * 0.5`, which an implementation may compute without a multiply.
    fn halve(self) -> Self {
        self * Self::from_f64(0.5)
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
float_scalar!(f32, "f32", sqrt_f32, libm::sincosf, libm::atan2f);

/// The IEEE `f32` square root, correctly rounded (round to nearest, ties to even).
///
/// Every VFP unit has it as one instruction (`vsqrt.f32`; 14 cycles on the Cortex-M4F), and
/// a hard-float ABI (`eabihf`) means there is one; `core` has no `f32::sqrt` and `libm`
/// falls back to its software routine on Arm (a loop of integer steps). IEEE 754 defines the
/// square root as correctly rounded, and `libm::sqrtf` is (`libm_sqrtf_is_correctly_rounded`
/// checks it against the `f64` root), so both give the same bits: the device and the host
/// simulation stay bit-identical (which the `hil` tests check end to end). The default
/// FPSCR (round to nearest, no flush-to-zero) is what cortex-m-rt leaves, and nothing here
/// changes it.
#[inline]
pub(crate) fn sqrt_f32(x: f32) -> f32 {
    #[cfg(arm_asm)]
    {
        let root: u32;
        // The value goes through a core register and s15 (caller-saved, declared clobbered):
        // stable Rust accepts an `s` register operand only with the `vfp2` feature, which
        // the single-precision FPU of the Cortex-M4F does not have.
        // SAFETY: register-to-register moves and one FPU instruction: no memory, no stack.
        // Not `preserves_flags`: vsqrt sets the FPSCR's sticky exception bits (inexact),
        // which Rust's asm rules count among the flags on Arm.
        #[allow(unsafe_code)] // audited, see lib.rs
        unsafe {
            core::arch::asm!(
                "vmov s15, {x}",
                "vsqrt.f32 s15, s15",
                "vmov {root}, s15",
                x = in(reg) x.to_bits(),
                root = lateout(reg) root,
                out("s15") _,
                options(pure, nomem, nostack),
            );
        }
        f32::from_bits(root)
    }
    #[cfg(not(arm_asm))]
    {
        libm::sqrtf(x)
    }
}

/// `1 / b` for `b != 0`: an IEEE `f32` estimate refined by one Newton step in fixed point,
/// `y (2 - b y)` (relative error about 1e-14; identical on every IEEE target). Replaces a
/// 128-bit software division (a long library routine on the Cortex-M4).
#[inline]
fn recip_nonzero(b: Fx) -> Fx {
    let est = 1.0 / to_f32_fast(b);
    let y = from_f32_fast(est);
    let two = Fx(FxRaw::from_bits(2 << 32));
    y * (two - b * y)
}

/// `±2^31 / n` rounded to nearest (the sign of `n`), in `Q0.31`: the Taylor coefficients
/// below.
const fn q31_inverse_of(n: i64) -> i32 {
    let m = n.unsigned_abs() as i64;
    let q = ((1 << 31) + m / 2) / m;
    (if n < 0 { -q } else { q }) as i32
}

/// The Taylor coefficients of sin r / r and cos r in z = r^2, highest first:
/// `(-1)^k / (2k+1)!` for k = 5..1 and `(-1)^k / (2k)!` for k = 5..1 (the constant terms,
/// one, are added last). Computed at compile time.
const SIN_SERIES: [i32; 5] = [
    q31_inverse_of(-39_916_800),
    q31_inverse_of(362_880),
    q31_inverse_of(-5_040),
    q31_inverse_of(120),
    q31_inverse_of(-6),
];
const COS_SERIES: [i32; 5] = [
    q31_inverse_of(-3_628_800),
    q31_inverse_of(40_320),
    q31_inverse_of(-720),
    q31_inverse_of(24),
    q31_inverse_of(-2),
];

/// `a b` of two `Q0.31` values, rounded to nearest, in `Q0.31`: one `SMULL` and a shift on the
/// Cortex-M4 (its magnitude below one, as its factors' are).
#[inline(always)]
fn q31_mul(a: i32, b: i32) -> i32 {
    ((a as i64 * b as i64 + (1 << 30)) >> 31) as i32
}

/// sin and cos of `r`, |r| <= pi/4 (a little more is harmless), by their Taylor series to
/// r^11 and r^10 (truncation below 2e-11 and 2e-10 there) in Horner form in `z = r^2`:
/// `1 + z (c1 + z (c2 + ...))`. Every partial sum, `z <= 0.62` and `r` lie within one, so
/// the series runs in 32-bit `Q0.31` words (a product is one `SMULL`, where an `I32F32`
/// product takes a dozen instructions and its saturating sum as many): the kinematics take
/// six of these in every force-loop tick. Each product rounds to nearest (under 2^-32),
/// later products shrink what earlier ones lost, and the last terms (`1 +`, `r +`) are added
/// exactly in the model's format: within 1e-9 in all.
#[inline]
fn sin_cos_near_zero(r: Fx) -> (Fx, Fx) {
    // |r| < 1: Q0.31 rounded (its last bit is the model's).
    let r_bits = r.to_bits();
    let r31 = ((r_bits + 1) >> 1).clamp(-(i32::MAX as i64), i32::MAX as i64) as i32;
    let z = q31_mul(r31, r31);
    let horner = |c: &[i32; 5]| c[1..].iter().fold(c[0], |acc, &k| k + q31_mul(acc, z));
    // sin r = r + r z h_s and cos r = 1 + z h_c: the last products taken to 62 fractional
    // bits and rounded once into the model's 32.
    let tail = |h: i32, f: i32| (h as i64 * f as i64 + (1 << 29)) >> 30;
    let zs = q31_mul(horner(&SIN_SERIES), z);
    let sin = r_bits + tail(zs, r31);
    let cos = (1i64 << 32) + ((horner(&COS_SERIES) as i64 * z as i64 + (1 << 29)) >> 30);
    (Fx::from_bits(sin), Fx::from_bits(cos))
}

/// `x / 2` rounded toward -inf: the same bits as `x * 0.5` (the product `floor(x 2^31 / 2^32)`
/// is `floor(x / 2)`, an arithmetic shift, and cannot overflow) without a multiply.
#[inline]
fn half(x: Fx) -> Fx {
    Fx(FxRaw::from_bits(x.0.to_bits() >> 1))
}

/// An `f32`'s bits to `I32F32` bits: `v * 2^32` rounded to nearest with ties away from zero,
/// saturated to `i64`, NaN to zero (what `from_f64` does to the widened value). The value is
/// `m 2^(e - 150)` with the 24-bit significand `m`, so the scaled one is `m 2^(e - 118)`: a
/// left shift (saturating from 2^63 up), or a right shift that adds half of the last place
/// dropped first.
const fn f32_bits_to_raw(bits: u32) -> i64 {
    let negative = bits >> 31 != 0;
    let biased = ((bits >> 23) & 0xff) as i32;
    let frac = (bits & 0x7f_ffff) as u64;
    if biased == 0xff {
        return if frac != 0 {
            0
        } else if negative {
            i64::MIN
        } else {
            i64::MAX
        };
    }
    // Subnormals have no implicit bit and the exponent of the smallest normals.
    let (m, e) = if biased == 0 {
        (frac, 1)
    } else {
        (frac | 0x80_0000, biased)
    };
    let shift = e - 118;
    let magnitude = if shift >= 40 {
        // m >= 2^23 here: at least 2^63, beyond the format.
        return if negative { i64::MIN } else { i64::MAX };
    } else if shift >= 0 {
        m << shift
    } else if shift > -40 {
        let k = -shift as u32;
        (m + (1 << (k - 1))) >> k
    } else {
        // Below 2^-40 of a unit in the last place: rounds to zero.
        0
    };
    // magnitude < 2^63: the negation cannot overflow.
    if negative {
        -(magnitude as i64)
    } else {
        magnitude as i64
    }
}

/// `Fx` to `f32`, rounded to nearest (exact integer-to-float conversion, then a power of two).
#[inline]
fn to_f32_fast(x: Fx) -> f32 {
    #[cfg(target_pointer_width = "64")]
    {
        x.0.to_bits() as f32 * (1.0 / 4_294_967_296.0)
    }
    #[cfg(not(target_pointer_width = "64"))]
    {
        to_f32_split(x)
    }
}

/// [`to_f32_fast`] without a 64-bit integer-to-float conversion, which the Cortex-M4 does in
/// software (`__aeabi_l2f`): the magnitude normalised so its top 32 bits hold the significand,
/// with a sticky bit for anything below them (so round-to-nearest-even still sees whether the
/// dropped part is exactly half), one hardware `u32` to `f32` conversion (correctly rounded),
/// and an exact power-of-two scale. The same bits as [`to_f32_fast`]; `conversions_agree`
/// tests it.
#[inline]
#[allow(dead_code)]
fn to_f32_split(x: Fx) -> f32 {
    let v = x.0.to_bits();
    let m = v.unsigned_abs();
    if m == 0 {
        return 0.0;
    }
    let lz = m.leading_zeros(); // 0..=63
    let t = m << lz;
    let top = (t >> 32) as u32 | u32::from(t as u32 != 0);
    // m / 2^32 = top 2^(32 - lz) / 2^32 = top 2^-lz, and 2^-lz is a normal f32.
    let f = top as f32 * f32::from_bits((127 - lz) << 23);
    if v < 0 {
        -f
    } else {
        f
    }
}

/// `a / b` for positive `a` and `b`, in `f32`: each operand from its two words (the integer
/// word exact below 2^24, the fraction's word rounded once; their sum rounded once), the
/// quotient correctly rounded, truncated back into the format. IEEE operations, so the
/// host computes the same bits; within a few `f32` roundings of the quotient (`4e-7`
/// relative and one unit of the format, `quotient_f32_is_within_4e_7_of_the_quotient`),
/// for two hardware conversions a word and one division where [`Scalar::recip`]'s estimate
/// and Newton step take two normalisations and two 64-bit products.
#[inline(always)]
pub(crate) fn quotient_f32(a: Fx, b: Fx) -> Fx {
    let words = |x: Fx| {
        let bits = x.0.to_bits();
        (bits >> 32) as i32 as f32 + (bits as u32 as f32) * (1.0 / 4_294_967_296.0)
    };
    from_f32_fast(words(a) / words(b))
}

/// `f32` to `Fx`, truncating toward zero and saturating (Rust's `as` cast): used only for
/// estimates that a Newton step then refines, and [`quotient_f32`].
#[inline]
fn from_f32_fast(v: f32) -> Fx {
    #[cfg(target_pointer_width = "64")]
    {
        Fx(FxRaw::from_bits((v * 4_294_967_296.0) as i64))
    }
    #[cfg(not(target_pointer_width = "64"))]
    {
        from_f32_split(v)
    }
}

/// [`from_f32_fast`] without a software `f32` to 64-bit conversion (`__aeabi_f2lz` on the
/// Cortex-M4) for magnitudes below 2^31: the integer part and the fraction (exact in `f32`:
/// both are bits of `v`) each converted by hardware, the fraction scaled by 2^32 (exact) and
/// truncated, so the result is `trunc(v 2^32)` as before. Other values (and NaN) take the
/// plain cast. The same bits as [`from_f32_fast`]; `conversions_agree` tests it.
#[inline]
#[allow(dead_code)]
fn from_f32_split(v: f32) -> Fx {
    let a = v.abs();
    if a < 2_147_483_648.0 {
        let whole = a as u32; // truncated; a < 2^31
        let frac = ((a - whole as f32) * 4_294_967_296.0) as u32; // in [0, 2^32)
        let bits = ((whole as i64) << 32) | frac as i64;
        Fx(FxRaw::from_bits(if v < 0.0 { -bits } else { bits }))
    } else {
        Fx(FxRaw::from_bits((v * 4_294_967_296.0) as i64))
    }
}

impl Scalar for Fx {
    const ZERO: Self = Fx(FxRaw::ZERO);
    const ONE: Self = Fx(FxRaw::ONE);
    const NAME: &'static str = "fixed";
    /// The same value as `from_f64(v as f64)` (rounded to nearest, ties away from zero,
    /// saturated, NaN zero), from the float's bits: no `f64` arithmetic, which the
    /// Cortex-M4F does in software (the parameters and configuration the pen converts are
    /// `f32`). `from_f32_is_from_f64_of_the_widened_value` tests every exponent.
    #[inline]
    fn from_f32(v: f32) -> Self {
        Fx::from_bits(f32_bits_to_raw(v.to_bits()))
    }
    /// Rounded to nearest once (`to_f32_fast`), without the `f64` in between.
    #[inline]
    fn to_f32(self) -> f32 {
        to_f32_fast(self)
    }
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
    /// The integer shifted into place: the same value as `from_f64(v as f64)` (exact below
    /// 2^31, saturated above) without the software `f64` conversion (a library call on the
    /// Cortex-M4, which has no double precision, and `tick` converts a substep index every
    /// substep).
    #[inline]
    fn from_usize(v: usize) -> Self {
        if v < 1 << 31 {
            Fx::from_bits((v as i64) << 32)
        } else {
            Fx::MAX
        }
    }
    /// An arithmetic shift: the same bits as `self * 0.5` (`half`).
    #[inline]
    fn halve(self) -> Self {
        half(self)
    }
    /// The integer shifted into place: the same value as `from_f64(v as f64)` (exact within
    /// +-2^31, saturated beyond) without two software `f64` conversions and a multiply (the
    /// pen's six joint readings are converted every force-loop tick).
    #[inline]
    fn from_i64(v: i64) -> Self {
        if v >= 1 << 31 {
            Fx::MAX
        } else if v < -(1 << 31) {
            Fx::MIN
        } else {
            Fx::from_bits(v << 32)
        }
    }
    /// `self * c` without the overflow test for `|c| < 1` (see `mul_coef_bits`).
    #[inline]
    fn mul_coef(self, c: Self) -> Self {
        if c.is_coef() {
            self.mul_tested_coef(c)
        } else {
            self * c
        }
    }
    /// -2^32 < bits < 2^32: the high word is 0, or -1 with a non-zero low word. Tested on
    /// the 32-bit words (a compare with zero each on the Cortex-M4) rather than as one
    /// 64-bit range comparison, which took more instructions there.
    #[inline]
    fn is_coef(self) -> bool {
        let bits = self.0.to_bits();
        let high = (bits >> 32) as i32;
        high == 0 || (high == -1 && bits as u32 != 0)
    }
    #[inline]
    fn mul_tested_coef(self, c: Self) -> Self {
        Fx(FxRaw::from_bits(mul_coef_bits(
            self.0.to_bits(),
            c.0.to_bits(),
        )))
    }
    #[inline]
    fn recip(self) -> Self {
        if self.0 == FxRaw::ZERO {
            Fx::MAX
        } else {
            recip_nonzero(self)
        }
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
            // Quotient from the reciprocal, then one residual correction so that large
            // divisors (whose reciprocals have few significant bits) lose nothing.
            let r = recip_nonzero(rhs);
            let q = self * r;
            q + (self - rhs * q) * r
        }
    }
    /// `x rsqrt(x)`, then for x > 1 one Newton correction `s + r (x - s^2) / 2` so that large
    /// arguments (whose reciprocal roots have few significant bits) lose nothing.
    #[inline]
    fn sqrt(self) -> Self {
        if self.0 > FxRaw::ZERO {
            let r = self.rsqrt();
            // r < 1 for x > 1: the coefficient product (the same bits) where it applies.
            let s = self.mul_coef(r);
            if self.0 > FxRaw::ONE {
                s + half((self - s * s).mul_coef(r))
            } else {
                // r > 1 would scale the residual's rounding up: x r is already accurate.
                s
            }
        } else {
            Fx(FxRaw::ZERO)
        }
    }
    /// An IEEE `f32` estimate (the Cortex-M4F's hardware square root and division; exact
    /// and identical on every IEEE target) refined by one Newton step in fixed point,
    /// `y (3 - x y^2) / 2`: relative error about 1e-14, far below the format's resolution for
    /// the model's values, and the same bits on the device and the host.
    #[inline]
    fn rsqrt(self) -> Self {
        if self.0 > FxRaw::ZERO {
            let est = 1.0 / sqrt_f32(to_f32_fast(self));
            let y = from_f32_fast(est);
            let three = Fx(FxRaw::from_bits(3 << 32));
            // x y^2 grouped to keep significant bits: (x y) y for large x (y^2 is tiny),
            // x (y y) for small x (x y is tiny).
            // The factor below one (y for x > 1, x itself otherwise) goes in as the coefficient
            // of `mul_coef`: the same bits as the plain product, cheaper.
            let u = if self.0 > FxRaw::ONE {
                self.mul_coef(y).mul_coef(y)
            } else {
                (y * y).mul_coef(self)
            };
            half((three - u).mul_coef(y))
        } else {
            Fx::MAX
        }
    }
    /// One Newton step `y (3 - x y^2) / 2` from `near` when `x > 1`, `0 < near < 1` and
    /// `|x near^2 - 1| < 2^-16` (`near` within about 2^-17 of the root): the step's error,
    /// 1.5 times the square of the guess's, is then below 1e-10 relative, under half the
    /// format's resolution for a root below one (the test
    /// `rsqrt_near_is_rsqrt_to_the_format_resolution`: within one unit in the last place of
    /// `rsqrt`), and both products are coefficient products: three of them, no float
    /// conversions, no hardware root and division. Anything else, a guess too far off
    /// included, takes `rsqrt` after the test (the test's cost on top).
    /// The springs' roots take this path: their last root is usually close, so the mean
    /// tick gets cheaper on the host and on the pen, while the worst tick, where most
    /// guesses miss, pays the test on top of `rsqrt`.
    #[inline]
    fn rsqrt_near(self, near: Self) -> Self {
        if self.0 > FxRaw::ONE && near.0 > FxRaw::ZERO && near.0 < FxRaw::ONE {
            let e = self.mul_tested_coef(near).mul_tested_coef(near);
            let off = (e.0 - FxRaw::ONE).to_bits();
            if off.unsigned_abs() < 1 << 16 {
                let three = Fx(FxRaw::from_bits(3 << 32));
                return half((three - e).mul_tested_coef(near));
            }
        }
        self.rsqrt()
    }
    /// The angle reduced to [-pi, pi] (the remainder of 2 pi, skipped when already there),
    /// then to `r` within pi/4 of the nearest multiple of pi/2, and `sin_cos_near_zero`
    /// of `r`, swapped and negated into the quadrant. About 1e-9 from the exact values.
    ///
    /// It replaced the `cordic` crate's `sin_cos`, which runs its 32 rotations twice (once
    /// for the gain) and divides in 64 bits: many times this series' cost on the Cortex-M4, and the
    /// kinematics take sines and cosines in every force-loop tick.
    fn sin_cos(self) -> (Self, Self) {
        let (pi, half_pi, quarter_pi) = (FxRaw::PI, FxRaw::FRAC_PI_2, FxRaw::FRAC_PI_4);
        let mut a = self.0;
        if a > pi || a < -pi {
            a %= FxRaw::TAU;
            if a > pi {
                a -= FxRaw::TAU;
            } else if a < -pi {
                a += FxRaw::TAU;
            }
        }
        let three_quarters_pi = half_pi + quarter_pi;
        if a > quarter_pi {
            if a > three_quarters_pi {
                let (s, c) = sin_cos_near_zero(Fx(a - pi));
                (-s, -c)
            } else {
                let (s, c) = sin_cos_near_zero(Fx(a - half_pi));
                (c, -s)
            }
        } else if a < -quarter_pi {
            if a < -three_quarters_pi {
                let (s, c) = sin_cos_near_zero(Fx(a + pi));
                (-s, -c)
            } else {
                let (s, c) = sin_cos_near_zero(Fx(a + half_pi));
                (-c, s)
            }
        } else {
            sin_cos_near_zero(Fx(a))
        }
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
    extern crate std;
    use std::println;

    /// Densely over several turns, at and around the quadrant boundaries where the reduction
    /// switches, and at angles that need the remainder of 2 pi.
    #[test]
    fn fixed_sin_cos_is_within_2e_9() {
        let q = core::f64::consts::FRAC_PI_4;
        let boundaries = (-8..=8).flat_map(|k| {
            let b = <Fx as Scalar>::from_f64(k as f64 * q).to_bits();
            (-3..=3).map(move |d| b + d)
        });
        let sweep = (-200_000..=200_000).map(|k| (k as f64 * 1.37e-4 * 4_294_967_296.0) as i64);
        let far =
            [1e3, -1e3, 12345.678, -2e6, 2.1e9, -2.1e9].map(|a: f64| (a * 4_294_967_296.0) as i64);
        let mut worst: f64 = 0.0;
        for bits in boundaries.chain(sweep).chain(far) {
            let x = Fx::from_bits(bits);
            let (s, c) = x.sin_cos();
            let a = x.to_f64();
            // Far out, the remainder of a rounded 2 pi shifts the angle by about a * 2^-35.
            let slack = (a.abs() / core::f64::consts::TAU).floor() * 2.0f64.powi(-33);
            let err = (s.to_f64() - a.sin())
                .abs()
                .max((c.to_f64() - a.cos()).abs())
                - slack;
            assert!(err < 2e-9, "sin_cos({a}) off by {err:e}");
            worst = worst.max(err);
        }
        println!("worst sin_cos error {worst:e}");
    }

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
    fn mul_paths_agree() {
        // The 32-bit target's partial-product multiply against the 128-bit one.
        let mut x: u64 = 0x2545_F491_4F6C_DD1D;
        let mut next = || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x as i64
        };
        let edges = [
            0,
            1,
            -1,
            i64::MAX,
            i64::MIN,
            1 << 32,
            -(1 << 32),
            i64::MAX - 1,
            3 << 31,
            (1 << 31) << 32,
            -(1 << 31) << 32,
            ((1 << 31) - 1) << 32,
            (((1 << 31) - 1) << 32) | 0xFFFF_FFFF,
            0xFFFF_FFFF,
            -0xFFFF_FFFF,
            1 << 47,
            -(1 << 47),
            (1 << 47) + 12345,
            // The small-operand fast path's bounds: integer parts -2^15 and 2^15 - 1 (in),
            // -2^15 - 1 and 2^15 (out).
            (1 << 47) - 1,
            -(1 << 47) - 1,
            -(1 << 47) + 1,
            ((1 << 15) - 1) << 32,
            (-(1 << 15)) << 32,
        ];
        let want = |a: i64, b: i64| clamp_i128(mul_wide(a, b) >> 32);
        for &a in &edges {
            for &b in &edges {
                assert_eq!(mul_floor_partial(a, b), want(a, b), "{a} * {b}");
            }
        }
        for _ in 0..200_000 {
            let (a, b) = (next() >> (next() & 63), next() >> (next() & 63));
            assert_eq!(mul_floor_partial(a, b), want(a, b), "{a} * {b}");
        }
    }

    #[test]
    fn from_f32_is_from_f64_of_the_widened_value() {
        let mut x: u64 = 0x3C6E_F372_FE94_F82B;
        let mut next = || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x
        };
        let check = |bits: u32| {
            let v = f32::from_bits(bits);
            assert_eq!(Fx::from_f32(v), Fx::from_f64(v as f64), "{v:e} ({bits:#x})");
        };
        // Every exponent and sign, with the significands at the ends, at the rounding
        // boundaries (the last kept bit, exactly half, half plus and minus one) and random.
        for sign in [0u32, 1 << 31] {
            for biased in 0..=255u32 {
                let base = sign | biased << 23;
                for frac in [
                    0, 1, 2, 0x40_0000, 0x3f_ffff, 0x40_0001, 0x7f_ffff, 0x7f_fffe,
                ] {
                    check(base | frac);
                }
                for k in 0..23 {
                    for frac in [1u32 << k, (1 << k) - 1, (1 << k) + 1, (3 << k) & 0x7f_ffff] {
                        check(base | (frac & 0x7f_ffff));
                    }
                }
                for _ in 0..2_000 {
                    check(base | (next() as u32 & 0x7f_ffff));
                }
            }
        }
        // The format's ends: 2^31 saturates, the largest f32 below it does not.
        assert_eq!(Fx::from_f32(2_147_483_648.0), Fx::MAX);
        assert_eq!(Fx::from_f32(-2_147_483_648.0), Fx::MIN);
        assert_eq!(Fx::from_f32(f32::NAN), Fx::ZERO);
        assert_eq!(Fx::from_f32(0.5).to_bits(), 1 << 31);
    }

    #[test]
    fn conversions_agree() {
        let mut x: u64 = 0x1234_5678_9ABC_DEF1;
        let mut next = || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x as i64
        };
        let plain_to = |x: Fx| x.0.to_bits() as f32 * (1.0 / 4_294_967_296.0);
        let plain_from = |v: f32| Fx(FxRaw::from_bits((v * 4_294_967_296.0) as i64));
        let edges = [
            0,
            1,
            -1,
            i64::MAX,
            i64::MIN,
            1 << 32,
            (1 << 56) + 1,
            0x80_0000_8000,
        ];
        for &b in &edges {
            let x = Fx::from_bits(b);
            assert_eq!(to_f32_split(x).to_bits(), plain_to(x).to_bits(), "{b}");
        }
        let floats = [
            0.0,
            -0.0,
            1.0,
            -1.5,
            2_147_483_520.0,
            2_147_483_648.0,
            -2_147_483_648.0,
            1e12,
            -1e12,
            1e-12,
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
        ];
        for &v in &floats {
            assert_eq!(from_f32_split(v), plain_from(v), "{v}");
        }
        for _ in 0..200_000 {
            let x = Fx::from_bits(next() >> (next() & 63));
            assert_eq!(to_f32_split(x).to_bits(), plain_to(x).to_bits(), "{x:?}");
            let v = f32::from_bits(next() as u32);
            assert_eq!(from_f32_split(v), plain_from(v), "{v}");
            let v = plain_to(x);
            assert_eq!(from_f32_split(v), plain_from(v), "{v}");
        }
    }

    /// `sqrt_f32` is `vsqrt.f32` on the device and `libm::sqrtf` elsewhere: they agree
    /// exactly when `libm::sqrtf` is correctly rounded, which this checks against the `f64`
    /// root rounded to `f32` (exact: a 53-bit root of a 24-bit argument rounds to 24 bits
    /// without double-rounding error, since 53 >= 2 * 24 + 2).
    #[test]
    fn libm_sqrtf_is_correctly_rounded() {
        let mut x: u64 = 0x5DEE_CE66_D1CE_4E5B;
        let mut next = || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x
        };
        let check = |v: f32| {
            let want = (v as f64).sqrt() as f32;
            assert_eq!(libm::sqrtf(v).to_bits(), want.to_bits(), "sqrt({v:e})");
            assert_eq!(sqrt_f32(v).to_bits(), want.to_bits(), "sqrt({v:e})");
        };
        for v in [
            0.0,
            1.0,
            2.0,
            3.0,
            f32::MIN_POSITIVE,
            f32::MAX,
            2.3e-10,
            7.111,
            1e12,
        ] {
            check(v);
        }
        // Every exponent the model's values reach and beyond, random significands; and
        // runs of consecutive floats, where rounding ties would show.
        for _ in 0..1_000_000 {
            let bits = (next() as u32) & 0x7F7F_FFFF;
            check(f32::from_bits(bits));
        }
        for start in [1.0f32, 2.0, 4.2e-10, 7.25, 1.0e6] {
            let b = start.to_bits();
            for k in 0..20_000 {
                check(f32::from_bits(b + k));
            }
        }
    }

    #[test]
    fn from_usize_is_the_conversion_through_f64() {
        for v in [0, 1, 2, 25, 99, 1 << 20, (1 << 31) - 1, 1 << 31, usize::MAX] {
            assert_eq!(
                <Fx as Scalar>::from_usize(v),
                <Fx as Scalar>::from_f64(v as f64)
            );
        }
    }

    #[test]
    fn from_i64_is_the_conversion_through_f64() {
        let edges = [
            0,
            1,
            -1,
            4096,
            -70_000,
            (1 << 31) - 1,
            1 << 31,
            (1 << 31) + 1,
            -(1 << 31) + 1,
            -(1 << 31),
            -(1 << 31) - 1,
            1 << 53,
            (1 << 53) + 1,
            i64::MAX,
            i64::MIN,
            i64::MIN + 1,
        ];
        let mut rng = 0x9E37_79B9_7F4A_7C15u64;
        let random = (0..100_000).map(|_| {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            // Mostly within the exact range, some beyond it.
            (rng as i64) >> (rng % 40)
        });
        for v in edges.into_iter().chain(random) {
            assert_eq!(
                <Fx as Scalar>::from_i64(v),
                <Fx as Scalar>::from_f64(v as f64),
                "{v}"
            );
        }
    }

    #[test]
    fn add_sub_saturate() {
        let edges = [
            0,
            1,
            -1,
            2,
            -2,
            i64::MAX,
            i64::MIN,
            i64::MAX - 1,
            i64::MIN + 1,
            1 << 62,
            -(1 << 62),
            1 << 32,
        ];
        for &a in &edges {
            for &b in &edges {
                let (x, y) = (Fx::from_bits(a), Fx::from_bits(b));
                assert_eq!((x + y).to_bits(), a.saturating_add(b), "{a} + {b}");
                assert_eq!((x - y).to_bits(), a.saturating_sub(b), "{a} - {b}");
            }
        }
    }

    #[test]
    fn quotient_f32_is_within_4e_7_of_the_quotient() {
        // The surface's short radii: areas from 1e-4 to 1e4 mm^2 over radii from 0.01 to
        // 300 mm (the parameters' ranges), log-uniform.
        let mut x: u64 = 0x9E37_79B9_7F4A_7C15;
        let mut next = || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            (x >> 11) as f64 / (1u64 << 53) as f64
        };
        let lsb = 1.0 / 4_294_967_296.0;
        let mut worst = 0.0f64;
        for _ in 0..200_000 {
            let a = Fx::from_f64(libm::exp2(26.6 * next() - 13.3));
            let b = Fx::from_f64(libm::exp2(14.9 * next() - 6.65));
            let exact = a.to_f64() / b.to_f64();
            let q = quotient_f32(a, b).to_f64();
            // Three roundings to f32 (each operand's sum, the quotient) and the truncation.
            let err = (q - exact).abs();
            let bound = 4e-7 * exact + lsb;
            assert!(err <= bound, "{a:?} / {b:?}: {q} vs {exact}");
            worst = worst.max(err / bound);
        }
        println!("quotient_f32: worst error {worst:.3} of the bound");
        assert_eq!(quotient_f32(Fx::ONE, Fx::from_f64(4.0)), Fx::from_f64(0.25));
    }

    #[test]
    fn recip_products_are_within_the_stated_bound_of_the_quotient() {
        // Divisors of either sign from 1/64 to 64 (the surface's radii are 0.05 to 8 mm),
        // dividends up to 16 (its areas, mm^2).
        let mut x: u64 = 0x2545_F491_4F6C_DD1D;
        let mut next = || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x
        };
        let unit = |v: u64| (v >> 11) as f64 / (1u64 << 53) as f64;
        let lsb = 1.0 / 4_294_967_296.0;
        let mut worst = 0.0f64;
        for _ in 0..200_000 {
            let sign = if next() & 1 == 0 { 1.0 } else { -1.0 };
            let b = Fx::from_f64(sign * libm::exp2(12.0 * unit(next()) - 6.0));
            let a = Fx::from_f64(32.0 * unit(next()) - 16.0);
            let exact = a.to_f64() / b.to_f64();
            let by_recip = (a * b.recip()).to_f64();
            // The Newton step's products round to the format's unit, and the step scales
            // that by 1/b: the reciprocal is within about 1 + |1/b| units (absolute: a large
            // divisor's reciprocal has few significant bits), and the product scales that
            // by |a|.
            let err = (by_recip - exact).abs() / lsb;
            let bound = a.to_f64().abs() * (1.0 + 1.0 / b.to_f64().abs()) + 2.0;
            assert!(err <= bound, "{a:?} / {b:?}: {by_recip} vs {exact}");
            worst = worst.max(err / bound);
        }
        println!("recip: worst error {worst:.3} of the bound");
        assert_eq!(Fx::ZERO.recip(), Fx::MAX);
        assert_eq!(Fx::ONE.recip(), Fx::ONE);
        assert_eq!(Fx::from_f64(4.0).recip(), Fx::from_f64(0.25));
    }

    #[test]
    fn rsqrt_near_is_rsqrt_to_the_format_resolution() {
        // Squared segment lengths from 1 to 100 mm^2, guesses off by up to 2^-16 relative
        // (inside and outside the step's reach) and plainly wrong ones.
        let mut x: u64 = 0x9E37_79B9_7F4A_7C15;
        let mut next = || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x
        };
        let (mut differs, mut worst) = (0, 0i64);
        for _ in 0..200_000 {
            let len2 = Fx(FxRaw::from_bits((1 << 32) + (next() % (99 << 32)) as i64));
            let root = len2.rsqrt();
            // Relative offset in [-2^-16, 2^-16].
            let off = (next() % (1 << 18)) as i64 - (1 << 17);
            let guess = Fx(FxRaw::from_bits(
                root.0.to_bits() + ((root.0.to_bits() as i128 * off as i128) >> 33) as i64,
            ));
            let near = len2.rsqrt_near(guess);
            let d = (near.0.to_bits() - root.0.to_bits()).abs();
            worst = worst.max(d);
            // Only the step can differ from rsqrt (a fallback is rsqrt itself).
            differs += (d != 0) as u32;
            let exact = 1.0 / len2.to_f64().sqrt();
            // The format's resolution, 2^-32, plus the step's own error.
            let lsb = 1.0 / 4_294_967_296.0;
            assert!(
                (near.to_f64() - exact).abs() < lsb + 1e-10 * exact,
                "{len2:?} {guess:?}"
            );
        }
        // Within one unit in the last place of the full computation, and the step was taken
        // (about half the guesses are within its reach).
        assert!(worst <= 1, "worst {worst}");
        assert!(differs > 1_000, "{differs}");
        // A guess that is no guess falls back to rsqrt, bit for bit.
        let five = <Fx as Scalar>::from_f64(5.0);
        for bad in [0.0, -0.3, 0.2, 0.9, 1.5] {
            let g = <Fx as Scalar>::from_f64(bad);
            assert_eq!(five.rsqrt_near(g), five.rsqrt(), "guess {bad}");
        }
        let small = <Fx as Scalar>::from_f64(0.5);
        assert_eq!(small.rsqrt_near(small.rsqrt()), small.rsqrt());
        assert_eq!(Fx(FxRaw::ZERO).rsqrt_near(five), Fx::MAX);
        // The float types ignore the guess.
        assert_eq!(5.0f64.rsqrt_near(0.1), 5.0f64.rsqrt());
    }

    #[test]
    fn half_is_the_product_with_one_half() {
        let one_half = Fx(FxRaw::from_bits(1 << 31));
        for &bits in &[0, 1, -1, 3, -3, i64::MAX, i64::MIN, 1 << 40, -(1 << 40) - 7] {
            let x = Fx::from_bits(bits);
            assert_eq!(half(x), x * one_half, "{bits}");
        }
    }

    /// The 32-bit form of the coefficient product, wherever it applies.
    fn check_partial(a: Fx, c: Fx) {
        if c.to_bits().unsigned_abs() < 1 << 32 {
            let got = mul_coef_partial(a.to_bits(), c.to_bits());
            assert_eq!(Fx::from_bits(got), a * c, "{a:?} * {c:?}");
        }
    }

    #[test]
    fn mul_coef_is_the_product() {
        let mut x: u64 = 0xD1B5_4A32_D192_ED03;
        let mut next = || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x as i64
        };
        let values = [
            0,
            1,
            -1,
            i64::MAX,
            i64::MIN,
            1 << 32,
            -(1 << 32),
            3 << 31,
            -7,
        ];
        let coefs = [
            0,
            1,
            (1 << 32) - 1,
            1 << 31,
            1 << 32,
            -1,
            -(1 << 31),
            1 - (1 << 32),
            -(1 << 32),
            i64::MAX,
            i64::MIN,
            5 << 32,
        ];
        for &a in &values {
            for &c in &coefs {
                let (a, c) = (Fx::from_bits(a), Fx::from_bits(c));
                assert_eq!(a.mul_coef(c), a * c, "{a:?} * {c:?}");
                check_partial(a, c);
                // is_coef is exactly -1 < c < 1, and behind it the untested product is the
                // product.
                let raw = c.to_bits();
                assert_eq!(c.is_coef(), raw > -(1 << 32) && raw < 1 << 32, "{c:?}");
                if c.is_coef() {
                    assert_eq!(a.mul_tested_coef(c), a * c, "{a:?} * {c:?}");
                }
            }
        }
        for _ in 0..200_000 {
            let a = Fx::from_bits(next() >> (next() & 63));
            // Mostly coefficients in (-1, 1), some outside.
            let c = Fx::from_bits(next() >> (28 + (next() & 7)));
            assert_eq!(a.mul_coef(c), a * c, "{a:?} * {c:?}");
            check_partial(a, c);
            if c.is_coef() {
                assert_eq!(a.mul_tested_coef(c), a * c, "{a:?} * {c:?}");
            }
        }
    }

    #[test]
    fn narrow_matches_clamp() {
        let mut x: u64 = 0x9E37_79B9_7F4A_7C15;
        let mut next = || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x as i64
        };
        let edges = [
            0,
            1,
            -1,
            i64::MAX,
            i64::MIN,
            1 << 31,
            -(1 << 31),
            (1 << 31) - 1,
            1 << 32,
            -(1 << 32),
            3 << 31,
        ];
        for &a in &edges {
            for &b in &edges {
                let p = mul_wide(a, b);
                assert_eq!(narrow(p), clamp_i128(p >> 32), "{a} * {b}");
            }
        }
        for _ in 0..200_000 {
            let (a, b) = (next() >> (next() & 63), next() >> (next() & 63));
            let p = mul_wide(a, b);
            assert_eq!(narrow(p), clamp_i128(p >> 32), "{a} * {b}");
        }
    }

    #[test]
    fn fixed_division_and_roots_are_accurate() {
        // Against the exact result for the (already quantised) inputs: within 4 LSB plus
        // 1e-10 relative (a small divisor's large reciprocal scales the residual's LSB).
        let f = <Fx as Scalar>::from_f64;
        let lsb = 1.0 / 4_294_967_296.0;
        let mut worst: f64 = 0.0;
        let mut check = |got: f64, want: f64| {
            let e = (got - want).abs() / (lsb + 1e-10 * want.abs());
            if e > 4.0 {
                println!("got {got} want {want}: {e} LSB");
            }
            worst = worst.max(e);
        };
        let pairs = [
            (1.0, 3.0),
            (-7.25, 0.001),
            (1e-6, 123.456),
            (2.5, -2.5),
            (40.0, 0.37),
        ];
        let more = [
            (30_000.0, 35_565.0),
            (-1e6, 777.0),
            (0.4, 1e5),
            (123.0, -0.0625),
        ];
        for &(a, b) in pairs.iter().chain(more.iter()) {
            let (a, b) = (f(a), f(b));
            check(Scalar::div(a, b).to_f64(), a.to_f64() / b.to_f64());
        }
        for &v in &[1e-6, 0.001, 0.5, 2.0, 6.25, 7.1111, 1600.0, 1e5, 4e6] {
            let x = f(v).to_f64();
            check(Scalar::rsqrt(f(v)).to_f64(), 1.0 / x.sqrt());
            check(Scalar::sqrt(f(v)).to_f64(), x.sqrt());
        }
        println!("worst error {worst:.2} LSB");
        assert!(worst <= 4.0, "worst error {worst} LSB");
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
        assert_eq!(Scalar::div(Fx::MIN, Fx::DELTA), Fx::MIN);
        assert_eq!(Scalar::sqrt(-one), zero);
        assert_eq!(<Fx as Scalar>::from_f64(f64::NAN), zero);
        assert_eq!(<Fx as Scalar>::from_f64(1e30), Fx::MAX);
        assert!((Scalar::sqrt(<Fx as Scalar>::from_f64(6.25)).to_f64() - 2.5).abs() < 1e-9);
        assert!((Scalar::rsqrt(<Fx as Scalar>::from_f64(0.25)).to_f64() - 2.0).abs() < 1e-9);
        assert_eq!(Scalar::rsqrt(zero), Fx::MAX);
    }
}
