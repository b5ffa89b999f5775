//! Wide forms of the brush's flat fixed-point loops for x86-64 hosts: four `I32F32` entries per
//! AVX2 instruction instead of one, giving the scalar loops' bits.
//!
//! Why only here: the device computes one entry at a time (the Cortex-M4 has no wide integer
//! unit that would help), and the host's simulation must give the device's bits, so the host
//! cannot change the arithmetic, only how many entries it does at once. Three loops took
//! most of the host's fixed-point substep (callgrind, `shared/examples/tick_cost`): the
//! segment springs (a root and a spring term per segment), the right-hand sides of the
//! interior rows and the Jacobi sweeps.
//! Here they run four segments or entries at a time (`segments`, `interior_rows`, `jacobi`),
//! and so do smaller pieces of the tick: the surface update's segment roots (`measure`: the
//! float estimate of `Scalar::rsqrt` and its Newton step, four at once, where one at a time
//! waited on a square root and a division; the segment kernel takes the same path where its
//! Newton guess is off), the skeleton's placement (`place_nodes`) and its straight-line steps
//! (`step_nodes`, with their range shown once a tick by `node_steps_fit`), and the
//! integration (`integrate`: one mass per vector, its three components at once, which
//! replaces the scalar loop's nine checked sums and branches by one range test). The brush
//! reaches them through the hooks of `brush::BrushScalar`, which `Fx` implements here. The
//! tip's row and the ties stay scalar.
//!
//! Exactness:
//! * **Products.** The coefficient product `floor(x c / 2^32)` for `0 <= c < 2^32` raw is
//!   `xh c + floor(xl c / 2^32)` with `x = xh 2^32 + xl` (`xh` signed, `xl` unsigned), the
//!   identity the device's own coefficient product uses: `vpmuludq` gives `xl c`, and `xh c`
//!   is `vpmuldq` when `c < 2^31` (a signed word), else `vpmuludq` less `c 2^32` where `xh`
//!   is negative.
//! * **Saturation.** Each kernel first bounds its inputs (for example the spine within
//!   +-2^45 raw for the segments, every input within +-2^58 for the right-hand sides, the
//!   right-hand sides within +-2^60 and the coefficients at most 3/8 for the Jacobi sweeps:
//!   each kernel's comment has the arithmetic), within which none of its sums can overflow,
//!   so the saturating and the wrapping sums agree. Where a bound fails, the scalar loop
//!   runs instead and saturates exactly as on the device.
//! * **Floats.** `measure` converts with the same IEEE single-precision operations as
//!   `Scalar::rsqrt` (integer to `f32` through an exact `f64`, square root, division,
//!   truncation back through another exact `f64`), so its estimates are the same bits.
//!
//! The tests below compare each kernel with its scalar loop over random inputs, saturation
//! included; `brush`'s `wide_kernels_change_no_bit` runs whole strokes both ways. CPUs
//! without AVX2 (detected at run time, once) and every other target run the scalar loops;
//! [`set_enabled`] switches the wide forms off to measure or compare them.
#![allow(unsafe_code)]

use crate::brush::{BrushScalar, Integration, InteriorRows, LayerAxes, Segments};
use crate::params::MAX_LAYERS;
use crate::scalar::Fx;
// The scalar forms the kernels are tested against, and the documentation's links.
#[cfg(target_arch = "x86_64")]
use crate::scalar::Scalar;
use crate::vec::Vec3;
use core::sync::atomic::{AtomicBool, Ordering};

static ENABLED: AtomicBool = AtomicBool::new(true);

/// Lets the wide forms run where the CPU has them (the default), or not: the results are the
/// same bits either way, so this only changes the speed (for benchmarks and tests).
pub fn set_enabled(on: bool) {
    ENABLED.store(on, Ordering::Relaxed);
}

/// Whether the wide forms run on this machine: enabled and the CPU has AVX2.
pub fn active() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        ENABLED.load(Ordering::Relaxed) && x86::avx2()
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// The fixed-point format's wide forms of the brush's loops: the functions below, each of
/// which falls back to the brush's own loop where it does not apply (on every target but
/// x86-64 with AVX2, always).
impl BrushScalar for Fx {
    #[inline]
    fn jacobi_wide(p: &mut [Self], coefs: (Self, Self), n: usize, iterations: usize) -> bool {
        jacobi(p, coefs, n, iterations)
    }
    #[inline]
    fn interior_rows_wide(rows: &InteriorRows<'_, Self>, p: &mut [Self]) -> bool {
        interior_rows(rows, p)
    }
    #[inline]
    fn segments_wide(segments: &mut Segments<'_, Self>) -> u32 {
        self::segments(segments)
    }
    #[inline]
    fn integrate_wide(integration: &mut Integration<'_, Self>) -> usize {
        integrate(integration)
    }
    #[inline]
    fn layer_axes_wide(axes: &mut LayerAxes<'_, Self>) -> u32 {
        layer_axes(axes)
    }
    #[inline]
    fn measure_wide(n: usize, spine: &[Vec3<Self>], len2: &mut [Self], rsqrt: &mut [Self]) -> u32 {
        measure(n, spine, len2, rsqrt)
    }
    #[inline]
    fn node_steps_fit(nodes: &[Vec3<Self>], step: &[Vec3<Self>], substeps: usize) -> bool {
        node_steps_fit(nodes, step, substeps)
    }
    #[inline]
    fn step_nodes_wide(
        nodes: &mut [Vec3<Self>],
        vel: &mut [Vec3<Self>],
        step: &[Vec3<Self>],
    ) -> bool {
        step_nodes(nodes, vel, step)
    }
    #[inline]
    fn place_nodes_wide(
        pos: Vec3<Self>,
        offsets: &[[Self; MAX_LAYERS]; 3],
        m: &[[Self; 3]; 3],
        out: &mut [Vec3<Self>],
    ) -> bool {
        place_nodes(pos, offsets, m, out)
    }
}

/// The brush's Jacobi solve (`brush::jacobi`): from `du = p`, `iterations` sweeps of
/// `du_e = p_e + c (du_{e-3} + du_{e+3})` over the interior masses' entries `3..3(n-1)` and
/// `du_e = p_e + c_tip du_{e-3}` over the tip's three, entries `0..3` (the ferrule's) held at
/// `p`'s; saturating sums, coefficient products, each sweep reading only the one before. Turns
/// `p[..3n]` into `du` in place and returns true, or returns false, with `p` unchanged, where
/// the wide form does not apply (then the caller runs its own sweeps).
#[inline]
pub(crate) fn jacobi(p: &mut [Fx], (c, c_tip): (Fx, Fx), n: usize, iterations: usize) -> bool {
    #[cfg(target_arch = "x86_64")]
    if is_small_coef(c) && is_small_coef(c_tip) && active() {
        return x86::jacobi(p, (c, c_tip), n, iterations);
    }
    let _ = (p, c, c_tip, n, iterations);
    false
}

/// `0 <= c < 1/2`: a coefficient the wide product takes as one signed word.
#[cfg(target_arch = "x86_64")]
fn is_small_coef(c: Fx) -> bool {
    (0..1 << 31).contains(&c.to_bits())
}

/// Writes [`InteriorRows`]' right-hand sides into `p` (flattened: mass i at `3i..3i+3`) and
/// returns true, or returns false having written nothing where the wide form does not apply
/// (then the caller runs its scalar loop).
pub(crate) fn interior_rows(rows: &InteriorRows<'_, Fx>, p: &mut [Fx]) -> bool {
    #[cfg(target_arch = "x86_64")]
    if rows.coefs.iter().all(|c| is_small_coef(*c)) && active() {
        return x86::interior_rows(rows, p);
    }
    let _ = (rows, p);
    false
}

/// [`InteriorRows`]' arrays as flat arrays of components (entry `3i + axis` of mass i).
#[cfg(target_arch = "x86_64")]
#[derive(Copy, Clone)]
struct FlatRows<'a> {
    f: &'a [Fx],
    v: &'a [Fx],
    x: &'a [Fx],
    k: &'a [Fx],
    kv: &'a [Fx],
}

#[cfg(target_arch = "x86_64")]
impl<'a> FlatRows<'a> {
    fn of(rows: &InteriorRows<'a, Fx>) -> Self {
        FlatRows {
            f: flat(rows.seg),
            v: flat(rows.vel),
            x: flat(rows.spine),
            k: flat(rows.skel),
            kv: flat(rows.skel_vel),
        }
    }

    /// Entry `e` of the right-hand sides for a mass of tie weight `w`: the scalar form the
    /// wide one must equal, the same operations in the same order as `Brush`'s rows.
    fn entry(&self, w: Fx, c: [Fx; 4], e: usize) -> Fx {
        let [c_k, c_j, c_t, c_tv] = c;
        let (f, v) = (self.f, self.v);
        let ve = v[e];
        let rel = (v[e - 3] - ve) + (v[e + 3] - ve);
        let mut pi = (f[e + 3] - f[e]).mul_tested_coef(c_k) + rel.mul_tested_coef(c_j);
        if w > Fx::ZERO {
            let tie = (self.k[e] - self.x[e]).mul_tested_coef(c_t)
                + (self.kv[e] - ve).mul_tested_coef(c_tv);
            pi += if w < Fx::ONE {
                tie.mul_tested_coef(w)
            } else {
                tie
            };
        }
        pi
    }
}

/// Measures [`Segments`] and writes their spring terms where the wide form applies, and
/// returns the segments it did as bits (bit j for segment j); the caller does the others
/// (whose inverse lengths are left as they were) with its scalar code.
pub(crate) fn segments(s: &mut Segments<'_, Fx>) -> u32 {
    #[cfg(target_arch = "x86_64")]
    if active() {
        return x86::segments(s);
    }
    let _ = s;
    0
}

/// Integrates masses `1..k` of [`Integration`] where the wide form applies and returns `k`,
/// the first mass left for the caller's scalar loop (1 where none was done, `n` where all
/// were).
pub(crate) fn integrate(s: &mut Integration<'_, Fx>) -> usize {
    #[cfg(target_arch = "x86_64")]
    if active() {
        return x86::integrate(s);
    }
    let _ = s;
    1
}

/// Sets [`LayerAxes`]' axes where the wide form applies and returns the layers it did as
/// bits (bit i for layer i); the others are left as they were for the caller.
pub(crate) fn layer_axes(a: &mut LayerAxes<'_, Fx>) -> u32 {
    #[cfg(target_arch = "x86_64")]
    if active() {
        return x86::layer_axes(a);
    }
    let _ = a;
    0
}

/// `pos + m offset_i` for each node i of `out` (the skeleton placed by a rotation `m` whose
/// entries are coefficients, [`Scalar::is_coef`]), where the wide form applies; false, having
/// written nothing, where not.
pub(crate) fn place_nodes(
    pos: Vec3<Fx>,
    offsets: &[[Fx; MAX_LAYERS]; 3],
    m: &[[Fx; 3]; 3],
    out: &mut [Vec3<Fx>],
) -> bool {
    #[cfg(target_arch = "x86_64")]
    if active() {
        return x86::place_nodes(pos, offsets, m, out);
    }
    let _ = (pos, offsets, m, out);
    false
}

/// Whether `substeps` steps `node += step` from `nodes` (a tick's straight-line node paths)
/// cannot overflow, so that [`step_nodes`] may take them with wrapping sums: every node
/// within +-2^61, every step within +-2^54 and at most 128 substeps keep every node within
/// +-2^62. False where the wide form does not run.
pub(crate) fn node_steps_fit(nodes: &[Vec3<Fx>], step: &[Vec3<Fx>], substeps: usize) -> bool {
    let within = |v: &[Vec3<Fx>], bound: i64| {
        flat(v)
            .iter()
            .all(|c| (-bound..bound).contains(&c.to_bits()))
    };
    active()
        && substeps <= 128
        && nodes.len() >= 2
        && step.len() >= nodes.len()
        && within(nodes, 1 << 61)
        && within(&step[..nodes.len()], 1 << 54)
}

/// `node += step`, `vel = step` for every node of `nodes` (and as many of `vel`, `step`),
/// after [`node_steps_fit`] held at the tick's start; false, having changed nothing, where
/// the wide form does not run.
pub(crate) fn step_nodes(nodes: &mut [Vec3<Fx>], vel: &mut [Vec3<Fx>], step: &[Vec3<Fx>]) -> bool {
    #[cfg(target_arch = "x86_64")]
    if active() && nodes.len() >= 2 && vel.len() >= nodes.len() && step.len() >= nodes.len() {
        let n = nodes.len();
        // SAFETY: AVX2 found by `active`; three slices of 3n >= 6 entries each.
        unsafe { x86::step_nodes_avx2(flat_mut(nodes), flat_mut(&mut vel[..n]), flat(&step[..n])) };
        return true;
    }
    let _ = (nodes, vel, step);
    false
}

/// Each spine segment j in `1..n`: its squared length into `len2[j]` and `len2.rsqrt()`
/// ([`Scalar::rsqrt`], the same bits) into `rsqrt[j]`, where the wide form applies; the
/// segments done as bits (bit j), the others left as they were for the caller to measure.
pub(crate) fn measure(n: usize, spine: &[Vec3<Fx>], len2: &mut [Fx], rsqrt: &mut [Fx]) -> u32 {
    #[cfg(target_arch = "x86_64")]
    if active() {
        return x86::measure(n, spine, len2, rsqrt);
    }
    let _ = (n, spine, len2, rsqrt);
    0
}

/// The components of `v` in order: `Vec3` is `repr(C)` over three scalars.
fn flat(v: &[Vec3<Fx>]) -> &[Fx] {
    // SAFETY: `Vec3<Fx>` is `repr(C)` with three `Fx` fields and no padding (all three have
    // one size and alignment), so `v` is `3 v.len()` consecutive `Fx`, borrowed as long as `v`.
    unsafe { core::slice::from_raw_parts(v.as_ptr().cast::<Fx>(), 3 * v.len()) }
}

/// [`flat`] for writing.
#[cfg(target_arch = "x86_64")]
fn flat_mut(v: &mut [Vec3<Fx>]) -> &mut [Fx] {
    // SAFETY: as for `flat`; the borrow is exclusive as `v`'s was.
    unsafe { core::slice::from_raw_parts_mut(v.as_mut_ptr().cast::<Fx>(), 3 * v.len()) }
}

#[cfg(target_arch = "x86_64")]
mod x86 {
    use super::{flat, flat_mut, FlatRows, Integration, InteriorRows, LayerAxes, Segments};
    use crate::brush::Layer;
    use crate::params::MAX_LAYERS;
    use crate::scalar::{Fx, Scalar};
    use crate::vec::Vec3;
    use core::arch::x86_64::*;
    use core::mem::MaybeUninit;
    use core::sync::atomic::{AtomicU8, Ordering};

    /// Run-time AVX2 detection, cached: 0 not yet asked, 1 absent, 2 present.
    pub(super) fn avx2() -> bool {
        static STATE: AtomicU8 = AtomicU8::new(0);
        match STATE.load(Ordering::Relaxed) {
            1 => false,
            2 => true,
            _ => {
                let present = detect_avx2();
                STATE.store(if present { 2 } else { 1 }, Ordering::Relaxed);
                present
            }
        }
    }

    /// AVX2 in the CPU (CPUID leaf 7) and its registers saved by the operating system (XCR0's
    /// SSE and AVX state bits, readable once CPUID reports OSXSAVE).
    fn detect_avx2() -> bool {
        let leaf1 = __cpuid(1);
        let (osxsave, avx) = (leaf1.ecx & 1 << 27 != 0, leaf1.ecx & 1 << 28 != 0);
        if !(osxsave && avx) || __cpuid(0).eax < 7 {
            return false;
        }
        let avx2 = __cpuid_count(7, 0).ebx & 1 << 5 != 0;
        // SAFETY: CPUID reports OSXSAVE, so XGETBV may be executed.
        let xcr0 = unsafe { xgetbv0() };
        avx2 && xcr0 & 0b110 == 0b110
    }

    #[target_feature(enable = "xsave")]
    unsafe fn xgetbv0() -> u64 {
        _xgetbv(0)
    }

    /// Four entries of a slice from `i` (`i + 4 <= s.len()`, checked by the callers).
    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn load(s: &[Fx], i: usize) -> __m256i {
        _mm256_loadu_si256(s.as_ptr().add(i).cast::<__m256i>())
    }

    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn store(s: &mut [Fx], i: usize, v: __m256i) {
        _mm256_storeu_si256(s.as_mut_ptr().add(i).cast::<__m256i>(), v)
    }

    /// `floor(x c / 2^32)` for `0 <= c < 2^31` in every lane.
    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn mul_small_coef(x: __m256i, c: __m256i) -> __m256i {
        // vpmuldq reads each lane's low word as signed (xh after the shift), vpmuludq as
        // unsigned (xl).
        let high = _mm256_mul_epi32(_mm256_srli_epi64::<32>(x), c);
        let low = _mm256_srli_epi64::<32>(_mm256_mul_epu32(x, c));
        _mm256_add_epi64(high, low)
    }

    /// `floor(x c / 2^32)` for `x >= 0` and `0 <= c < 2^32` in every lane: [`mul_coef`]
    /// without its correction for a negative `x`.
    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn mul_nonnegative(x: __m256i, c: __m256i) -> __m256i {
        let high = _mm256_mul_epu32(_mm256_srli_epi64::<32>(x), c);
        let low = _mm256_srli_epi64::<32>(_mm256_mul_epu32(x, c));
        _mm256_add_epi64(high, low)
    }

    /// `floor(x c / 2^32)` for `0 <= c < 2^32` in every lane.
    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn mul_coef(x: __m256i, c: __m256i) -> __m256i {
        // xh taken unsigned is xh + 2^32 where x < 0: take c 2^32 back there.
        let negative = _mm256_cmpgt_epi64(_mm256_setzero_si256(), x);
        let high = _mm256_sub_epi64(
            _mm256_mul_epu32(_mm256_srli_epi64::<32>(x), c),
            _mm256_and_si256(negative, _mm256_slli_epi64::<32>(c)),
        );
        let low = _mm256_srli_epi64::<32>(_mm256_mul_epu32(x, c));
        _mm256_add_epi64(high, low)
    }

    /// [`super::jacobi`] with AVX2 present and both coefficients below 1/2.
    pub(super) fn jacobi(p: &mut [Fx], coefs: (Fx, Fx), n: usize, iterations: usize) -> bool {
        // At least four interior entries (n >= 4) for the overlapping last vector, and one
        // entry after the tip's three (n < MAX_LAYERS), which the tip's vector reads.
        if !(4..MAX_LAYERS).contains(&n) || p.len() < 3 * n + 1 {
            return false;
        }
        if iterations == 0 {
            return true;
        }
        // SAFETY: AVX2 and the coefficients checked by the caller; `p` holds 3n + 1 entries
        // with 4 <= n < MAX_LAYERS.
        unsafe { jacobi_avx2(&mut p[..3 * n + 1], coefs, iterations) }
    }

    /// The sweeps: the first from `p`, the middle ones between two spare buffers, the last
    /// into `p` itself; false (before any sweep) if an entry of `p` is beyond +-2^60 or a
    /// coefficient above 3/8.
    ///
    /// Within those no sum of any sweep can overflow, so the sweeps need no check: with
    /// `P = max |p| < 2^60` and `D_k` the largest entry after sweep k, `D_0 = P` and
    /// `D_k <= P + 2c D_(k-1) + 1` (the floor of the product adds at most one unit), so every
    /// `D_k <= (P + 1) / (1 - 2c) <= 4 (P + 1) < 2^62` for `2c <= 3/4`: the neighbours' sum
    /// is below 2^63, and so is `p` plus its product. The Jacobi solve runs only for `c_j`
    /// up to `JACOBI_LIMIT` (1/4).
    ///
    /// The spare buffers are not cleared (clearing two of them was a twentieth of the
    /// host's substep): a sweep writes entries `3..3n + 1` of its buffer and entries `0..3`
    /// are copied from `p` first, and a sweep reads only entries below `3n` of the one
    /// before, so nothing unwritten is ever read.
    /// Safety: AVX2 present; `p` holds `3n + 1` entries with `4 <= n < MAX_LAYERS`;
    /// `iterations >= 1`; both coefficients non-negative.
    #[target_feature(enable = "avx2")]
    unsafe fn jacobi_avx2(p: &mut [Fx], (c, c_tip): (Fx, Fx), iterations: usize) -> bool {
        const THREE_EIGHTHS: i64 = 3 << 29;
        if c.to_bits() > THREE_EIGHTHS || c_tip.to_bits() > THREE_EIGHTHS {
            return false;
        }
        // The entries that count, `..3n` (the last one is the unused entry after the tip).
        if !all_within::<60>(&p[..p.len() - 1]) {
            return false;
        }
        let coefs = (
            _mm256_set1_epi64x(c.to_bits()),
            _mm256_set1_epi64x(c_tip.to_bits()),
        );
        let tip = p.len() - 4;
        let mut spare = [MaybeUninit::<[Fx; 3 * MAX_LAYERS]>::uninit(); 2];
        let [a, b] = spare.each_mut().map(|s| s.as_mut_ptr().cast::<Fx>());
        for buffer in [a, b] {
            core::ptr::copy_nonoverlapping(p.as_ptr(), buffer, 3);
        }
        let base = p.as_mut_ptr();
        let (mut src, mut dst) = (a, b);
        sweep(base, base, a, coefs, tip);
        for _ in 2..iterations {
            sweep(src, base, dst, coefs, tip);
            core::mem::swap(&mut src, &mut dst);
        }
        if iterations == 1 {
            core::ptr::copy_nonoverlapping(src.add(3), base.add(3), tip);
        } else {
            last_sweep(src, base, coefs, tip);
        }
        true
    }

    /// One sweep from `src` into `dst` with p at `p` (`src` may be `p`): the interior entries
    /// four at a time (the last four end at the tip, overlapping the previous ones: the same
    /// values written again), then the tip's three and the unused entry after them, which no
    /// sweep reads. Safety: as [`jacobi_avx2`] once it has checked `p` and the coefficients,
    /// with `tip = 3(n - 1)`; each pointer valid for `3n + 1` entries, the first `3n` of
    /// `src` written; `dst` apart from both.
    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn sweep(
        src: *const Fx,
        p: *const Fx,
        dst: *mut Fx,
        (c, c_tip): (__m256i, __m256i),
        tip: usize,
    ) {
        let at = |s: *const Fx, i: usize| _mm256_loadu_si256(s.add(i).cast::<__m256i>());
        let mut next = 3;
        while next < tip {
            let e = next.min(tip - 4);
            next = e + 4;
            let s = _mm256_add_epi64(at(src, e - 3), at(src, e + 3));
            let v = _mm256_add_epi64(at(p, e), mul_small_coef(s, c));
            _mm256_storeu_si256(dst.add(e).cast::<__m256i>(), v);
        }
        let m = mul_small_coef(at(src, tip - 3), c_tip);
        _mm256_storeu_si256(
            dst.add(tip).cast::<__m256i>(),
            _mm256_add_epi64(at(p, tip), m),
        );
    }

    /// The last sweep, from `src` into `p` itself. Each vector reads the p entries it then
    /// replaces, so the overlapping last interior vector, whose first entries the one
    /// before it replaces, is computed first and stored last; the entry after the tip's
    /// three keeps its value. Safety: as [`sweep`], `src` apart from `p`.
    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn last_sweep(src: *const Fx, p: *mut Fx, (c, c_tip): (__m256i, __m256i), tip: usize) {
        let at = |s: *const Fx, i: usize| _mm256_loadu_si256(s.add(i).cast::<__m256i>());
        let entries = |e: usize| {
            let s = _mm256_add_epi64(at(src, e - 3), at(src, e + 3));
            _mm256_add_epi64(at(p, e), mul_small_coef(s, c))
        };
        let last = entries(tip - 4);
        let mut e = 3;
        while e < tip - 4 {
            _mm256_storeu_si256(p.add(e).cast::<__m256i>(), entries(e));
            e += 4;
        }
        _mm256_storeu_si256(p.add(tip - 4).cast::<__m256i>(), last);
        let old = at(p, tip);
        let new = _mm256_add_epi64(old, mul_small_coef(at(src, tip - 3), c_tip));
        let kept = _mm256_blend_epi32::<0b1100_0000>(new, old);
        _mm256_storeu_si256(p.add(tip).cast::<__m256i>(), kept);
    }

    /// [`super::segments`] with AVX2 present.
    pub(super) fn segments(s: &mut Segments<'_, Fx>) -> u32 {
        let n = s.n;
        // At least four segments (n >= 5) for the overlapping last vector; the compression
        // ratio a coefficient of either sign's product below (its only use is on a negative
        // strain: [0, 1)).
        let fits = (5..=MAX_LAYERS).contains(&n)
            && s.spine.len() >= n
            && s.len2.len() >= n
            && s.rsqrt.len() >= n
            && s.seg.len() >= n
            && (0..1 << 32).contains(&s.compression_ratio.to_bits());
        if !fits {
            return 0;
        }
        // SAFETY: AVX2 checked by the caller; 5 <= n <= MAX_LAYERS and every array holds n
        // entries, which is all the kernel reads and writes.
        unsafe { segments_avx2(s) }
    }

    /// Four Vec3s given as their x, y and z lanes, stored as the spine holds them (x y z x,
    /// y z x y, z x y z) at `out[at..at + 12]`. Safety: AVX2 present; `at + 12 <= out.len()`.
    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn store_vec3s(out: &mut [Fx], at: usize, [x, y, z]: [__m256i; 3]) {
        // Each vector: its lanes 0 and 3 from the first permutation, lane 1 (32-bit words 2,
        // 3) from the second, lane 2 (words 4, 5) from the third.
        let parts = [
            [
                _mm256_permute4x64_epi64::<0x40>(x),
                _mm256_permute4x64_epi64::<0x00>(y),
                _mm256_permute4x64_epi64::<0x00>(z),
            ],
            [
                _mm256_permute4x64_epi64::<0x81>(y),
                _mm256_permute4x64_epi64::<0x04>(z),
                _mm256_permute4x64_epi64::<0x20>(x),
            ],
            [
                _mm256_permute4x64_epi64::<0xc2>(z),
                _mm256_permute4x64_epi64::<0x0c>(x),
                _mm256_permute4x64_epi64::<0x30>(y),
            ],
        ];
        for (k, [a, b, c]) in parts.into_iter().enumerate() {
            let v = _mm256_blend_epi32::<0b0011_0000>(_mm256_blend_epi32::<0b0000_1100>(a, b), c);
            store(out, at + 4 * k, v);
        }
    }

    /// [`super::place_nodes`] with AVX2 present.
    pub(super) fn place_nodes(
        pos: Vec3<Fx>,
        offsets: &[[Fx; MAX_LAYERS]; 3],
        m: &[[Fx; 3]; 3],
        out: &mut [Vec3<Fx>],
    ) -> bool {
        let n = out.len();
        let in_range = |v: Fx| (-(1 << 61)..1 << 61).contains(&v.to_bits());
        let coef = |c: &Fx| (-(1 << 32)..=1 << 32).contains(&c.to_bits());
        let fits = (4..=MAX_LAYERS).contains(&n)
            && [pos.x, pos.y, pos.z].into_iter().all(in_range)
            && m.iter().flatten().all(coef);
        // SAFETY: AVX2 checked by the caller; 4 <= n <= MAX_LAYERS, within the offsets and
        // `out`, all the kernel reads and writes.
        fits && unsafe { place_nodes_avx2(pos, offsets, m, flat_mut(out)) }
    }

    /// Four nodes at a time (the last four end at n, overlapping the previous ones: the
    /// same values again); false, having written nothing, if an offset is beyond +-2^59
    /// (within, with the position within +-2^61 and every entry of `m` a coefficient, no sum
    /// can overflow: three products below 2^59 each, plus the position, stay below 2^62).
    /// Safety: AVX2 present; `out` holds `n` Vec3s with `4 <= n <= MAX_LAYERS`; every
    /// entry of `m` within [-1, 1].
    #[target_feature(enable = "avx2")]
    unsafe fn place_nodes_avx2(
        pos: Vec3<Fx>,
        offsets: &[[Fx; MAX_LAYERS]; 3],
        m: &[[Fx; 3]; 3],
        out: &mut [Fx],
    ) -> bool {
        let n = out.len() / 3;
        let bias = _mm256_set1_epi64x(1 << 59);
        let mut range = _mm256_setzero_si256();
        let mut next = 0;
        while next < n {
            let j = next.min(n - 4);
            next = j + 4;
            for o in offsets {
                range = _mm256_or_si256(range, _mm256_add_epi64(load(o, j), bias));
            }
        }
        if _mm256_testz_si256(range, _mm256_set1_epi64x(!((1 << 60) - 1))) == 0 {
            return false;
        }
        // An entry of one (or minus one) is not a coefficient: its product is the offset
        // itself (or its negation, exact within the bound), as the scalar product gives.
        let zero = _mm256_setzero_si256();
        let (mut c, mut one, mut minus_one) = ([[zero; 3]; 3], [[zero; 3]; 3], [[zero; 3]; 3]);
        for r in 0..3 {
            for k in 0..3 {
                let bits = m[r][k].to_bits();
                c[r][k] = _mm256_set1_epi64x(bits);
                one[r][k] = _mm256_set1_epi64x(-i64::from(bits == 1 << 32));
                minus_one[r][k] = _mm256_set1_epi64x(-i64::from(bits == -(1 << 32)));
            }
        }
        let pos = [pos.x, pos.y, pos.z];
        let mut next = 0;
        while next < n {
            let j = next.min(n - 4);
            next = j + 4;
            let offset = [
                load(&offsets[0], j),
                load(&offsets[1], j),
                load(&offsets[2], j),
            ];
            // pos + (x m0 + y m1 + z m2) per axis, the scalar sums' order.
            let mut nodes = [zero; 3];
            for r in 0..3 {
                let mut terms = [zero; 3];
                for k in 0..3 {
                    let v = offset[k];
                    let unit = _mm256_blendv_epi8(v, _mm256_sub_epi64(zero, v), minus_one[r][k]);
                    let either = _mm256_or_si256(one[r][k], minus_one[r][k]);
                    terms[k] = _mm256_blendv_epi8(mul_signed_coef(v, c[r][k]), unit, either);
                }
                let sum = _mm256_add_epi64(_mm256_add_epi64(terms[0], terms[1]), terms[2]);
                nodes[r] = _mm256_add_epi64(_mm256_set1_epi64x(pos[r].to_bits()), sum);
            }
            store_vec3s(out, 3 * j, nodes);
        }
        true
    }

    /// All entries four at a time: the last four (ending at the end) computed first and
    /// stored last, over the same values. Wrapping sums: the caller has shown they cannot
    /// overflow ([`super::node_steps_fit`]). Safety: AVX2 present; `vel` and `step` at least
    /// as long as `nodes`, which holds at least 4 entries.
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn step_nodes_avx2(nodes: &mut [Fx], vel: &mut [Fx], step: &[Fx]) {
        let last = nodes.len() - 4;
        let node_last = _mm256_add_epi64(load(nodes, last), load(step, last));
        let mut e = 0;
        while e < last {
            let st = load(step, e);
            store(nodes, e, _mm256_add_epi64(load(nodes, e), st));
            store(vel, e, st);
            e += 4;
        }
        store(nodes, last, node_last);
        store(vel, last, load(step, last));
    }

    /// Segments j..j+4 of a spine given as its flat coordinates (masses j.. less masses
    /// j-1..): their x, y and z lanes and squared lengths (`Vec3::norm2`, exact for
    /// coordinates within +-2^45, which the callers check). Safety: AVX2 present; `j >= 1`
    /// and masses up to j+3 in `coordinates`.
    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn segment_vectors(coordinates: &[Fx], j: usize) -> ([__m256i; 3], __m256i) {
        // The differences as the spine holds them, x y z x, y z x y, z x y z, then sorted
        // into x, y and z.
        let [a, b, c] = [0, 4, 8].map(|o| {
            let at = 3 * j + o;
            _mm256_sub_epi64(load(coordinates, at), load(coordinates, at - 3))
        });
        let d = [
            // x0 . . .  from a, x3 (lane 1) from c, x2 (lane 2) from b, x1 (lane 3) from a.
            _mm256_permute4x64_epi64::<0b01_10_11_00>(_mm256_blend_epi32::<0b0000_1100>(
                _mm256_blend_epi32::<0b0011_0000>(a, b),
                c,
            )),
            // y1 (lane 0) and y2 (lane 3) from b, y0 (lane 1) from a, y3 (lane 2) from c.
            _mm256_permute4x64_epi64::<0b10_11_00_01>(_mm256_blend_epi32::<0b0011_0000>(
                _mm256_blend_epi32::<0b1100_0011>(a, b),
                c,
            )),
            // z2 (lane 0) and z3 (lane 3) from c, z1 (lane 1) from b, z0 (lane 2) from a.
            _mm256_permute4x64_epi64::<0b11_00_01_10>(_mm256_blend_epi32::<0b1100_0011>(
                _mm256_blend_epi32::<0b0000_1100>(a, b),
                c,
            )),
        ];
        let len2 = _mm256_add_epi64(_mm256_add_epi64(square(d[0]), square(d[1])), square(d[2]));
        (d, len2)
    }

    /// Every entry of `s` within `+-2^BITS` (`-2^BITS <= x < 2^BITS`). Safety: AVX2 present;
    /// at least 4 entries.
    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn all_within<const BITS: u32>(s: &[Fx]) -> bool {
        // x + 2^BITS is below 2^(BITS + 1) (unsigned) exactly when x is within; or-ed over
        // every entry, the same holds of all of them.
        let (bias, end) = (_mm256_set1_epi64x(1 << BITS), s.len());
        let mut range = _mm256_setzero_si256();
        let mut next = 0;
        while next < end {
            let i = next.min(end - 4);
            next = i + 4;
            range = _mm256_or_si256(range, _mm256_add_epi64(load(s, i), bias));
        }
        _mm256_testz_si256(range, _mm256_set1_epi64x(!((1 << (BITS + 1)) - 1))) == 1
    }

    /// The spine's coordinates all within +-2^45 (then differences, squares and their sums
    /// cannot overflow). Safety: AVX2 present; at least 4 coordinates.
    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn spine_in_range(coordinates: &[Fx]) -> bool {
        all_within::<45>(coordinates)
    }

    /// [`super::measure`] with AVX2 present.
    pub(super) fn measure(n: usize, spine: &[Vec3<Fx>], len2: &mut [Fx], rsqrt: &mut [Fx]) -> u32 {
        let fits = (5..=MAX_LAYERS).contains(&n)
            && spine.len() >= n
            && len2.len() >= n
            && rsqrt.len() >= n;
        // SAFETY: AVX2 checked by the caller; 5 <= n <= MAX_LAYERS and the arrays hold n
        // entries, all the kernel reads and writes.
        if !fits || !unsafe { spine_in_range(flat(&spine[..n])) } {
            return 0;
        }
        unsafe { measure_avx2(flat(&spine[..n]), len2, rsqrt) }
    }

    /// Four segments at a time from segment 1 (the last four end at n - 1, overlapping the
    /// previous ones: the same values again), their roots by [`rsqrt_above_one`]. Where a
    /// segment is not done (len2 at most one, or beyond 2^52 raw) nothing of it is written. Safety: AVX2 present; the spine's coordinates within +-2^45; `len2` and
    /// `rsqrt` hold the spine's n masses, `5 <= n`.
    #[target_feature(enable = "avx2")]
    unsafe fn measure_avx2(coordinates: &[Fx], len2_out: &mut [Fx], rsqrt_out: &mut [Fx]) -> u32 {
        let n = coordinates.len() / 3;
        let mut done = 0u32;
        let mut next = 1;
        while next < n {
            let j = next.min(n - 4);
            next = j + 4;
            let (_, len2) = segment_vectors(coordinates, j);
            let (r, ok) = rsqrt_above_one(len2);
            let lanes = _mm256_movemask_pd(_mm256_castsi256_pd(ok)) as u32;
            // Only what is done is written: the others keep their values for the caller.
            store(len2_out, j, _mm256_blendv_epi8(load(len2_out, j), len2, ok));
            store(rsqrt_out, j, _mm256_blendv_epi8(load(rsqrt_out, j), r, ok));
            done |= lanes << j;
        }
        done
    }

    /// `Scalar::rsqrt` of four squared lengths `len2 >= 0` and the lanes where it is that:
    /// its float estimate, lane by lane with the same IEEE operations (the integer to `f32`
    /// conversion through an exact `f64`, the truncation back through another), then its
    /// Newton step for `len2 > 1`. A lane is not done (its root unspecified) where `len2` is
    /// at most one, beyond 2^52 raw, or the estimate or the step leave the range the scalar
    /// code takes as coefficients. Safety: AVX2 present.
    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn rsqrt_above_one(len2: __m256i) -> (__m256i, __m256i) {
        let one = _mm256_set1_epi64x(Fx::ONE.to_bits());
        let three = _mm256_set1_epi64x(3 << 32);
        let limit = _mm256_set1_epi64x(1 << 52);
        // The estimate is below 2^20 for len2 above one, so 2^32 times it below 2^52.
        let y = rsqrt_estimate(len2);
        // x > 1: y < 1 is the coefficient, x y^2 as (x y) y; then y (3 - x y^2) / 2.
        let u = mul_nonnegative(mul_nonnegative(len2, y), y);
        let t = _mm256_sub_epi64(three, u);
        let r = _mm256_srli_epi64::<1>(mul_nonnegative(t, y));
        let ok = _mm256_and_si256(
            _mm256_and_si256(
                _mm256_cmpgt_epi64(len2, one),
                _mm256_cmpgt_epi64(limit, len2),
            ),
            _mm256_and_si256(
                _mm256_cmpgt_epi64(one, y),
                _mm256_cmpgt_epi64(t, _mm256_set1_epi64x(-1)),
            ),
        );
        (r, ok)
    }

    /// `floor(x x / 2^32)` for `|x| < 2^46`: the square from `|x|`'s words, `a = ah 2^32 +
    /// al`: `ah^2 2^32 + 2 ah al + floor(al^2 / 2^32)`, exact (the first two are integers).
    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn square(x: __m256i) -> __m256i {
        let negative = _mm256_cmpgt_epi64(_mm256_setzero_si256(), x);
        let a = _mm256_blendv_epi8(x, _mm256_sub_epi64(_mm256_setzero_si256(), x), negative);
        let ah = _mm256_srli_epi64::<32>(a);
        let hh = _mm256_slli_epi64::<32>(_mm256_mul_epu32(ah, ah));
        let hl = _mm256_slli_epi64::<1>(_mm256_mul_epu32(ah, a));
        let ll = _mm256_srli_epi64::<32>(_mm256_mul_epu32(a, a));
        _mm256_add_epi64(_mm256_add_epi64(hh, hl), ll)
    }

    /// `floor(x c / 2^32)` for `-2^32 < c < 2^32` in every lane: with `c = cl - s 2^32` (`cl`
    /// its low word, `s` 1 where negative), `floor(x cl / 2^32) - s x`.
    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn mul_signed_coef(x: __m256i, c: __m256i) -> __m256i {
        let low_word = _mm256_set1_epi64x(0xffff_ffff);
        let product = mul_coef(x, _mm256_and_si256(c, low_word));
        let c_negative = _mm256_cmpgt_epi64(_mm256_setzero_si256(), c);
        _mm256_sub_epi64(product, _mm256_and_si256(c_negative, x))
    }

    /// Four segments at a time from segment 1 (the last four end at n - 1, overlapping the
    /// previous ones: the same values again); the segments done as bits. Nothing is written
    /// (and 0 returned) if a spine coordinate is beyond +-2^45 (then the squares could
    /// saturate). Where a segment is not done its root is left as it was, and its length and
    /// spring term hold unspecified values for the caller to replace.
    /// Safety: AVX2 present; `5 <= n <= MAX_LAYERS`; `s`'s arrays hold n entries.
    #[target_feature(enable = "avx2")]
    unsafe fn segments_avx2(s: &mut Segments<'_, Fx>) -> u32 {
        let n = s.n;
        let coordinates = flat(s.spine);
        let zero = _mm256_setzero_si256();
        let one = _mm256_set1_epi64x(Fx::ONE.to_bits());
        let three = _mm256_set1_epi64x(3 << 32);
        let band = _mm256_set1_epi64x(1 << 16);
        let segment = _mm256_set1_epi64x(s.segment.to_bits());
        let ratio = _mm256_set1_epi64x(s.compression_ratio.to_bits());
        let tiny2 = _mm256_set1_epi64x(s.tiny2.to_bits());
        if !spine_in_range(&coordinates[..3 * n]) {
            return 0;
        }
        // The roots the Newton steps start from are the ones the blocks replace; the last
        // block overlaps the one before it, so its roots are read before any is replaced.
        let tail = n - 4;
        let tail_near = load(s.rsqrt, tail);
        let mut done = 0u32;
        let mut next = 1;
        while next < n {
            let j = next.min(tail);
            next = j + 4;
            let (d, len2) = segment_vectors(coordinates, j);
            // The Newton step from the last root (`rsqrt_near`), where it applies: len2 > 1,
            // 0 < near < 1 and the guess within 2^-16 (len2 near^2, both products floor'd).
            let near = if j == tail {
                tail_near
            } else {
                load(s.rsqrt, j)
            };
            let e = mul_nonnegative(mul_nonnegative(len2, near), near);
            let off = _mm256_sub_epi64(e, one);
            let stepped = [
                _mm256_cmpgt_epi64(len2, one),
                _mm256_cmpgt_epi64(near, zero),
                _mm256_cmpgt_epi64(one, near),
                _mm256_cmpgt_epi64(off, _mm256_sub_epi64(zero, band)),
                _mm256_cmpgt_epi64(band, off),
            ]
            .iter()
            .fold(_mm256_set1_epi64x(-1), |m, c| _mm256_and_si256(m, *c));
            // 3 - e is about 2 and the product positive: the halving is a logical shift.
            let r = _mm256_srli_epi64::<1>(mul_nonnegative(_mm256_sub_epi64(three, e), near));
            let empty = _mm256_cmpeq_epi64(len2, zero);
            let mut r = _mm256_andnot_si256(empty, r);
            let mut ok = _mm256_or_si256(stepped, empty);
            // A guess too far off: `rsqrt_near` takes `rsqrt` afresh, and so does this lane
            // (a segment whose length changes by more than about 8 ppm in the substep).
            if _mm256_movemask_pd(_mm256_castsi256_pd(ok)) != 0b1111 {
                let (afresh, took) = rsqrt_above_one(len2);
                let took = _mm256_andnot_si256(ok, took);
                r = _mm256_blendv_epi8(r, afresh, took);
                ok = _mm256_or_si256(ok, took);
            }
            // The spring: strain 1 - L r (L r a coefficient product: r < 1), times the ratio
            // where negative; the term is d times the strain, d itself for a strain of one.
            let springy = _mm256_cmpgt_epi64(len2, tiny2);
            let strain = _mm256_sub_epi64(one, mul_nonnegative(segment, r));
            let compressed = _mm256_cmpgt_epi64(zero, strain);
            let strain = _mm256_blendv_epi8(strain, mul_signed_coef(strain, ratio), compressed);
            let unit = _mm256_cmpeq_epi64(strain, one);
            // A strain at or below -1 is not a coefficient: the scalar code's full product.
            let too_short = _mm256_cmpgt_epi64(_mm256_set1_epi64x(-(1 << 32) + 1), strain);
            let r_not_coef = _mm256_cmpgt_epi64(r, _mm256_set1_epi64x((1 << 32) - 1));
            let scalar_only = _mm256_and_si256(springy, _mm256_or_si256(too_short, r_not_coef));
            ok = _mm256_andnot_si256(scalar_only, ok);
            let f = d.map(|dk| {
                let fk = _mm256_blendv_epi8(mul_signed_coef(dk, strain), dk, unit);
                _mm256_and_si256(fk, springy)
            });
            store_vec3s(flat_mut(s.seg), 3 * j, f);
            store(s.len2, j, len2);
            store(s.rsqrt, j, _mm256_blendv_epi8(near, r, ok));
            done |= (_mm256_movemask_pd(_mm256_castsi256_pd(ok)) as u32) << j;
        }
        done
    }

    /// [`super::integrate`] with AVX2 present.
    pub(super) fn integrate(s: &mut Integration<'_, Fx>) -> usize {
        let n = s.n;
        if n < 2
            || [s.spine.len(), s.vel.len(), s.contact.len(), s.ties.len()]
                .iter()
                .any(|&l| l < n)
            || s.du.len() < 3 * n
        {
            return 1;
        }
        // Each mass's three entries are read as four (the fourth is the next mass's x, or
        // whatever follows the last one): the masses whose four stay inside all three arrays.
        let room = (3 * s.spine.len()).min(3 * s.vel.len()).min(s.du.len());
        let end = n.min((room - 1) / 3);
        if end < 2 {
            return 1;
        }
        // SAFETY: AVX2 checked by the caller; entries 3i..3i+4 of the three arrays exist for
        // every mass i below `end`, and `contact`, `ties` hold n >= end entries.
        unsafe { integrate_avx2(s, end) }
    }

    /// Masses `1..end` one at a time, their x, y and z in three lanes of one vector: stops at
    /// (and returns) the first mass with an entry of its position, velocity or velocity
    /// change beyond +-2^61, or a drag factor outside [0, 1], having written nothing of it.
    /// Within those the sums cannot overflow (|u + du| < 2^62, |S + v| < 2^63), so wrapping
    /// and saturating sums agree, and `keep` is a coefficient of the lanes' product (or one,
    /// which leaves v as it is: the scalar full product by one is exact).
    /// Each mass's components are stored as two and one (its loads are of four, the
    /// next mass's x included, which must not be stored over before that mass reads it).
    /// Safety: AVX2 present; `2 <= end <= n`; entries `3i..3i+4` of the flattened spine,
    /// velocities and `du` exist for every `i < end`.
    #[target_feature(enable = "avx2")]
    unsafe fn integrate_avx2(s: &mut Integration<'_, Fx>, end: usize) -> usize {
        let x_at = s.spine.as_mut_ptr().cast::<Fx>();
        let u_at = s.vel.as_mut_ptr().cast::<Fx>();
        let du = s.du.as_ptr();
        let at = |p: *const Fx, i: usize| _mm256_loadu_si256(p.add(3 * i).cast::<__m256i>());
        let bias = _mm256_set1_epi64x(1 << 61);
        // Lanes 0..3 (x, y, z) beyond +-2^61: x + 2^61 at or above 2^62 (unsigned).
        let beyond = _mm256_setr_epi64x(!((1 << 62) - 1), !((1 << 62) - 1), !((1 << 62) - 1), 0);
        let z_lane = _mm256_setr_epi64x(0, 0, -1, 0);
        for i in 1..end {
            let (u, d, x) = (at(u_at, i), at(du, i), at(x_at, i));
            let range = _mm256_or_si256(
                _mm256_or_si256(_mm256_add_epi64(u, bias), _mm256_add_epi64(d, bias)),
                _mm256_add_epi64(x, bias),
            );
            if _mm256_testz_si256(range, beyond) == 0 {
                return i;
            }
            let mut v = _mm256_add_epi64(u, d);
            // Drag in proportion to how much the mass is lying on the paper.
            let on_paper = Fx::ONE - *s.ties.get_unchecked(i);
            if on_paper > Fx::ZERO {
                let keep = Fx::ONE - on_paper.mul_coef(s.drag_loss);
                if keep != Fx::ONE {
                    if !(Fx::ZERO..Fx::ONE).contains(&keep) {
                        return i;
                    }
                    let scaled = mul_coef(v, _mm256_set1_epi64x(keep.to_bits()));
                    v = _mm256_blend_epi32::<0b0000_1111>(v, scaled);
                }
            }
            let mut p = _mm256_add_epi64(x, v);
            // Below the paper: put back onto it, a downward velocity removed.
            let below = _mm256_and_si256(_mm256_cmpgt_epi64(_mm256_setzero_si256(), p), z_lane);
            p = _mm256_andnot_si256(below, p);
            v = _mm256_andnot_si256(
                _mm256_and_si256(below, _mm256_cmpgt_epi64(_mm256_setzero_si256(), v)),
                v,
            );
            let (v_hi, p_hi) = (
                _mm256_extracti128_si256::<1>(v),
                _mm256_extracti128_si256::<1>(p),
            );
            _mm_storeu_si128(u_at.add(3 * i).cast(), _mm256_castsi256_si128(v));
            _mm_storel_epi64(u_at.add(3 * i + 2).cast(), v_hi);
            _mm_storeu_si128(x_at.add(3 * i).cast(), _mm256_castsi256_si128(p));
            _mm_storel_epi64(x_at.add(3 * i + 2).cast(), p_hi);
            let z = Fx::from_bits(_mm_cvtsi128_si64(p_hi));
            *s.contact.get_unchecked_mut(i) = z <= s.contact_tol;
        }
        end
    }

    /// [`super::layer_axes`] with AVX2 present.
    pub(super) fn layer_axes(a: &mut LayerAxes<'_, Fx>) -> u32 {
        let n = a.n;
        let fits = (5..=MAX_LAYERS).contains(&n)
            && [a.spine.len(), a.len2.len(), a.rsqrt.len(), a.layers.len()]
                .iter()
                .all(|&l| l >= n);
        // SAFETY: AVX2 checked by the caller; 5 <= n <= MAX_LAYERS and every array holds n
        // entries, all the kernel reads and writes.
        if !fits || !unsafe { spine_in_range(flat(&a.spine[..n])) } {
            return 0;
        }
        unsafe { layer_axes_avx2(a) }
    }

    /// `-2 <= x < 2` in every lane, as a mask: the factors [`mul_factor`] takes.
    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn factor_mask(x: __m256i) -> __m256i {
        _mm256_andnot_si256(
            _mm256_or_si256(
                _mm256_cmpgt_epi64(_mm256_set1_epi64x(-(1 << 33)), x),
                _mm256_cmpgt_epi64(x, _mm256_set1_epi64x((1 << 33) - 1)),
            ),
            _mm256_set1_epi64x(-1),
        )
    }

    /// `floor(a c / 2^32)` for `-2 <= c < 2` in every lane and `|a| < 2^61`: the value of
    /// the coefficient product where `|c| < 1` and of the full product (unsaturated) where
    /// not, such as a unit vector's component of one or a hair above. With `c = s 2^32 + cl`
    /// (`s` in -2..=1, `cl` its low word), `floor(a cl / 2^32) + s a`.
    #[inline]
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn mul_factor(a: __m256i, c: __m256i) -> __m256i {
        let low = mul_coef(a, _mm256_and_si256(c, _mm256_set1_epi64x(0xffff_ffff)));
        let zero = _mm256_setzero_si256();
        let plus = _mm256_cmpgt_epi64(c, _mm256_set1_epi64x((1 << 32) - 1));
        let minus = _mm256_cmpgt_epi64(zero, c);
        let minus_two = _mm256_cmpgt_epi64(_mm256_set1_epi64x(-(1 << 32)), c);
        let whole = _mm256_sub_epi64(
            _mm256_and_si256(plus, a),
            _mm256_add_epi64(_mm256_and_si256(minus, a), _mm256_and_si256(minus_two, a)),
        );
        _mm256_add_epi64(low, whole)
    }

    /// `floor(a b / 2^32)` for `0 <= a, b < 2^46` in every lane (the full product, exact:
    /// with `a = ah 2^32 + al`, `ah bh 2^32 + ah bl + al bh + floor(al bl / 2^32)`, each
    /// term below 2^60).
    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn mul_small_nonnegative(a: __m256i, b: __m256i) -> __m256i {
        let (ah, bh) = (_mm256_srli_epi64::<32>(a), _mm256_srli_epi64::<32>(b));
        let hh = _mm256_slli_epi64::<32>(_mm256_mul_epu32(ah, bh));
        let cross = _mm256_add_epi64(_mm256_mul_epu32(ah, b), _mm256_mul_epu32(a, bh));
        let ll = _mm256_srli_epi64::<32>(_mm256_mul_epu32(a, b));
        _mm256_add_epi64(_mm256_add_epi64(hh, cross), ll)
    }

    /// `Scalar::rsqrt`'s float estimate of `x` (`x` below 2^52, so exactly an `f64`): the
    /// same IEEE operations, lane by lane (the conversion to `f32` rounded once, the
    /// truncation of `est 2^32` back through an exact `f64`, which needs it below 2^52).
    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn rsqrt_estimate(x: __m256i) -> __m256i {
        // 2^52 as f64 bits: or-ed into a value below 2^52 it makes the f64 2^52 + value.
        let magic = _mm256_set1_epi64x(0x4330_0000_0000_0000);
        let magic_f = _mm256_castsi256_pd(magic);
        let exact = _mm256_sub_pd(_mm256_castsi256_pd(_mm256_or_si256(x, magic)), magic_f);
        let xf = _mm_mul_ps(_mm256_cvtpd_ps(exact), _mm_set1_ps(1.0 / 4_294_967_296.0));
        let est = _mm_div_ps(_mm_set1_ps(1.0), _mm_sqrt_ps(xf));
        let scaled = _mm256_cvtps_pd(_mm_mul_ps(est, _mm_set1_ps(4_294_967_296.0)));
        let whole = _mm256_round_pd::<{ _MM_FROUND_TO_ZERO | _MM_FROUND_NO_EXC }>(scaled);
        _mm256_sub_epi64(_mm256_castpd_si256(_mm256_add_pd(whole, magic_f)), magic)
    }

    /// `Scalar::rsqrt` of four `0 < x <= 1`, and the lanes where it is that: the estimate
    /// `y >= 1`, then `u = (y y) x` (`y y` the full product, `x` its coefficient, or `y y`
    /// itself for `x` of one) and `(3 - u) y / 2` (the full product: `y` is no
    /// coefficient). A lane is not done where `y` is 2^46 raw or more or `3 - u` negative.
    /// Safety: AVX2 present.
    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn rsqrt_at_most_one(x: __m256i) -> (__m256i, __m256i) {
        let one = _mm256_set1_epi64x(Fx::ONE.to_bits());
        let y = rsqrt_estimate(x);
        let yy = square(y);
        let u = _mm256_blendv_epi8(mul_nonnegative(yy, x), yy, _mm256_cmpeq_epi64(x, one));
        let t = _mm256_sub_epi64(_mm256_set1_epi64x(3 << 32), u);
        let r = _mm256_srli_epi64::<1>(mul_small_nonnegative(t, y));
        let ok = _mm256_and_si256(
            _mm256_cmpgt_epi64(_mm256_set1_epi64x(1 << 46), y),
            _mm256_cmpgt_epi64(t, _mm256_set1_epi64x(-1)),
        );
        (r, ok)
    }

    /// The x, y and z of a vector of four layers' short axes from `at`. Safety: layers
    /// `at..at + 4` exist.
    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn short_axes(layers: &[Layer<Fx>], at: usize) -> [__m256i; 3] {
        let l = |k: usize| layers.get_unchecked(at + k).short_axis;
        let lanes = |f: fn(Vec3<Fx>) -> Fx| {
            _mm256_setr_epi64x(
                f(l(0)).to_bits(),
                f(l(1)).to_bits(),
                f(l(2)).to_bits(),
                f(l(3)).to_bits(),
            )
        };
        [lanes(|v| v.x), lanes(|v| v.y), lanes(|v| v.z)]
    }

    /// `a x b` for `b`'s components within [-2, 2), lanes as x, y and z: `Vec3::cross_coef`
    /// (and `Vec3::cross`, the same values, where a component is no coefficient, such as a
    /// unit vector's +-1); `a`'s within +-2^40, so no product or difference saturates.
    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn cross_coef([ax, ay, az]: [__m256i; 3], [bx, by, bz]: [__m256i; 3]) -> [__m256i; 3] {
        let m = |a, c| mul_factor(a, c);
        [
            _mm256_sub_epi64(m(ay, bz), m(az, by)),
            _mm256_sub_epi64(m(az, bx), m(ax, bz)),
            _mm256_sub_epi64(m(ax, by), m(ay, bx)),
        ]
    }

    /// Four layers at a time from layer 1 (the last four end at n - 1, overlapping the ones
    /// before: their short axes are read before any is replaced, and the same values are
    /// written again). A layer is done only where every step takes the path the scalar code
    /// takes with the same products: the segment measured and longer than one and than
    /// `sqrt(min_len2)` (so `dir` is the segment times its root below one), `dir`, the old
    /// short axis's cross product with it and the normalised long axis coefficients, the old
    /// short axis within +-2^40, `|LA|^2` above `min_cross^2` with its root done by
    /// [`rsqrt_above_one`] or [`rsqrt_at_most_one`] (a root below one where the square is
    /// above one). Nothing of a layer not done is written. Safety: AVX2 present; the spine's
    /// coordinates within +-2^45; `5 <= n` and every array holds n entries.
    #[target_feature(enable = "avx2")]
    unsafe fn layer_axes_avx2(a: &mut LayerAxes<'_, Fx>) -> u32 {
        let n = a.n;
        let coordinates = flat(a.spine);
        let one = _mm256_set1_epi64x(Fx::ONE.to_bits());
        let zero = _mm256_setzero_si256();
        let min_len2 = _mm256_set1_epi64x(a.min_len2.to_bits());
        // `Vec3::normalized_or_none_coef`'s threshold, formed as it forms it.
        let min_cross2 = _mm256_set1_epi64x((a.min_cross * a.min_cross).to_bits());
        let lane_bits = _mm256_setr_epi64x(1, 2, 4, 8);
        let sa_bias = _mm256_set1_epi64x(1 << 40);
        let sa_beyond = _mm256_set1_epi64x(!((1 << 41) - 1));
        let tail = n - 4;
        let tail_sa = short_axes(a.layers, tail);
        let mut done = 0u32;
        let mut next = 1;
        while next < n {
            let j = next.min(tail);
            next = j + 4;
            let (d, _) = segment_vectors(coordinates, j);
            let (len2, r) = (load(a.len2, j), load(a.rsqrt, j));
            let bits = _mm256_set1_epi64x(i64::from((a.measured >> j) as u8 & 0xf));
            let measured = _mm256_cmpeq_epi64(_mm256_and_si256(bits, lane_bits), lane_bits);
            let mut ok = [
                measured,
                _mm256_cmpgt_epi64(len2, min_len2),
                _mm256_cmpgt_epi64(len2, one),
                _mm256_cmpgt_epi64(r, _mm256_set1_epi64x(-1)),
                _mm256_cmpgt_epi64(one, r),
            ]
            .iter()
            .fold(_mm256_set1_epi64x(-1), |m, c| _mm256_and_si256(m, *c));
            // The direction: the segment times its root, a coefficient below one.
            let dir = d.map(|dk| mul_coef(dk, r));
            let sa = if j == tail {
                tail_sa
            } else {
                short_axes(a.layers, j)
            };
            let sa_range = sa.iter().fold(zero, |m, c| {
                _mm256_or_si256(m, _mm256_add_epi64(*c, sa_bias))
            });
            ok = _mm256_and_si256(
                ok,
                _mm256_cmpeq_epi64(_mm256_and_si256(sa_range, sa_beyond), zero),
            );
            for c in dir {
                ok = _mm256_and_si256(ok, factor_mask(c));
            }
            let la = cross_coef(sa, dir);
            // |LA|^2: the squares floor(x^2 / 2^32), exact for |x| below 2^42 (sa within
            // +-2^40, dir within [-2, 2)), whether the scalar code takes them as coefficient
            // products or full ones; then its root.
            let n2 = _mm256_add_epi64(
                _mm256_add_epi64(square(la[0]), square(la[1])),
                square(la[2]),
            );
            ok = _mm256_and_si256(ok, _mm256_cmpgt_epi64(n2, min_cross2));
            let above = _mm256_cmpgt_epi64(n2, one);
            let (r_above, ok_above) = rsqrt_above_one(n2);
            let (r_below, ok_below) = rsqrt_at_most_one(n2);
            let root = _mm256_blendv_epi8(r_below, r_above, above);
            ok = _mm256_and_si256(ok, _mm256_blendv_epi8(ok_below, ok_above, above));
            // Normalised: LA times a root below one (a square above one), else the root times
            // LA's components as the factors (about one at most for a square up to one).
            ok = _mm256_andnot_si256(
                _mm256_and_si256(
                    above,
                    _mm256_cmpgt_epi64(root, _mm256_set1_epi64x((1 << 32) - 1)),
                ),
                ok,
            );
            for c in la {
                ok = _mm256_and_si256(ok, _mm256_or_si256(above, factor_mask(c)));
            }
            let unit =
                la.map(|c| _mm256_blendv_epi8(mul_factor(root, c), mul_coef(c, root), above));
            for c in unit {
                ok = _mm256_and_si256(ok, factor_mask(c));
            }
            let short = cross_coef(dir, unit);
            let lanes = _mm256_movemask_pd(_mm256_castsi256_pd(ok)) as u32;
            if lanes != 0 {
                let mut out = [[0i64; 4]; 6];
                for (o, v) in out.iter_mut().zip(unit.iter().chain(&short)) {
                    _mm256_storeu_si256(o.as_mut_ptr().cast(), *v);
                }
                for k in (0..4).filter(|k| lanes >> k & 1 != 0) {
                    let c = |axis: usize| Fx::from_bits(out[axis][k]);
                    let layer = a.layers.get_unchecked_mut(j + k);
                    layer.long_axis = Vec3::new(c(0), c(1), c(2));
                    layer.short_axis = Vec3::new(c(3), c(4), c(5));
                }
            }
            done |= lanes << j;
        }
        done
    }

    /// [`super::interior_rows`] with AVX2 present and the coefficients below 1/2.
    pub(super) fn interior_rows(rows: &InteriorRows<'_, Fx>, p: &mut [Fx]) -> bool {
        let n = rows.n;
        let a = FlatRows::of(rows);
        // Entries 3..3(n-1) are written; they read up to 3n of f and v, 3(n-1) of the rest.
        let fits = (3..=MAX_LAYERS).contains(&n)
            && a.f.len() >= 3 * n
            && a.v.len() >= 3 * n
            && [a.x.len(), a.k.len(), a.kv.len(), p.len()]
                .iter()
                .all(|&l| l >= 3 * (n - 1))
            && rows.ties.len() >= n - 1;
        if !fits {
            return false;
        }
        let end = 3 * (n - 1);
        let c = rows.coefs;
        if end < 3 + 4 {
            // Three layers: one interior mass, three entries.
            for (e, pe) in p.iter_mut().enumerate().take(end).skip(3) {
                *pe = a.entry(rows.ties[e / 3], c, e);
            }
            return true;
        }
        // SAFETY: AVX2 checked by the caller; every index the kernel reads or writes is within
        // the lengths checked above, and `end` is at least 7.
        unsafe { interior_rows_avx2(&a, rows.ties, c, p, end) }
    }

    /// The entries `3..end` four at a time (the last four end at `end`, overlapping the
    /// previous ones: the same values written again); false if an input was beyond +-2^58
    /// (then `p` holds unspecified values).
    /// Safety: AVX2 present; `end >= 7`; `a.f`, `a.v` hold `end + 3` entries, the other
    /// arrays and `p` `end`, `ties` `end / 3`; every coefficient in `[0, 2^31)`.
    #[target_feature(enable = "avx2")]
    unsafe fn interior_rows_avx2(
        a: &FlatRows<'_>,
        ties: &[Fx],
        c: [Fx; 4],
        p: &mut [Fx],
        end: usize,
    ) -> bool {
        let [c_k, c_j, c_t, c_tv] = c.map(|c| _mm256_set1_epi64x(c.to_bits()));
        let one = _mm256_set1_epi64x(Fx::ONE.to_bits());
        // x + 2^58 is below 2^59 (unsigned) exactly when -2^58 <= x < 2^58; or-ed over every
        // input, the same holds of all of them.
        let bias = _mm256_set1_epi64x(1 << 58);
        let mut range = _mm256_setzero_si256();
        let FlatRows { f, v, x, k, kv } = *a;
        let mut next = 3;
        while next < end {
            let e = next.min(end - 4);
            next = e + 4;
            let (f0, f1) = (load(f, e), load(f, e + 3));
            let (vl, ve, vr) = (load(v, e - 3), load(v, e), load(v, e + 3));
            let (xe, ke, kve) = (load(x, e), load(k, e), load(kv, e));
            for input in [f0, f1, vl, ve, vr, xe, ke, kve] {
                range = _mm256_or_si256(range, _mm256_add_epi64(input, bias));
            }
            let spring = _mm256_sub_epi64(f1, f0);
            let rel = _mm256_add_epi64(_mm256_sub_epi64(vl, ve), _mm256_sub_epi64(vr, ve));
            let pi = _mm256_add_epi64(mul_small_coef(spring, c_k), mul_small_coef(rel, c_j));
            let tie = _mm256_add_epi64(
                mul_small_coef(_mm256_sub_epi64(ke, xe), c_t),
                mul_small_coef(_mm256_sub_epi64(kve, ve), c_tv),
            );
            // The tie weight of each entry's mass: the four entries from e belong to masses
            // e / 3 and the next, in a pattern that repeats with e % 3.
            let m = _mm256_castsi128_si256(_mm_loadu_si128(ties.as_ptr().add(e / 3).cast()));
            let we = match e % 3 {
                0 => _mm256_permute4x64_epi64::<0b01_00_00_00>(m),
                1 => _mm256_permute4x64_epi64::<0b01_01_00_00>(m),
                _ => _mm256_permute4x64_epi64::<0b01_01_01_00>(m),
            };
            // Weight one: the tie itself; below one (zero included), its product. Masses in
            // the air all have weight one: then no product at all.
            let is_one = _mm256_cmpeq_epi64(we, one);
            let weighted = if _mm256_movemask_pd(_mm256_castsi256_pd(is_one)) == 0b1111 {
                tie
            } else {
                _mm256_blendv_epi8(mul_coef(tie, we), tie, is_one)
            };
            store(p, e, _mm256_add_epi64(pi, weighted));
        }
        let beyond = _mm256_set1_epi64x(!((1 << 59) - 1));
        _mm256_testz_si256(range, beyond) == 1
    }
}

/// The kernels against their scalar forms, called directly (not through [`set_enabled`],
/// which another test switches).
#[cfg(all(test, target_arch = "x86_64"))]
mod tests {
    extern crate std;
    use super::*;
    use core::arch::x86_64::*;
    use std::{format, vec, vec::Vec};

    /// xorshift64*: a fixed stream of test operands.
    struct Rng(u64);
    impl Rng {
        fn next(&mut self) -> u64 {
            self.0 ^= self.0 >> 12;
            self.0 ^= self.0 << 25;
            self.0 ^= self.0 >> 27;
            self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
        }
        /// Mostly model-sized values (within +-2^40 raw, 256 mm), some anywhere in i64.
        fn value(&mut self) -> Fx {
            let r = self.next();
            Fx::from_bits(match r % 16 {
                0 => self.next() as i64,
                1 => i64::MAX - (self.next() % 8) as i64,
                2 => i64::MIN + (self.next() % 8) as i64,
                _ => (self.next() as i64) >> 24,
            })
        }
        fn coef(&mut self) -> Fx {
            Fx::from_bits((self.next() % (1 << 31)) as i64)
        }
    }

    /// The sweeps as `brush::jacobi` states them, one entry at a time.
    fn jacobi_reference(p: &[Fx], (c, c_tip): (Fx, Fx), n: usize, iterations: usize) -> Vec<Fx> {
        let mut du = p[..3 * n].to_vec();
        for _ in 0..iterations {
            let src = du.clone();
            for e in 3..3 * (n - 1) {
                du[e] = p[e] + (src[e - 3] + src[e + 3]).mul_tested_coef(c);
            }
            for e in 3 * (n - 1)..3 * n {
                du[e] = p[e] + src[e - 3].mul_tested_coef(c_tip);
            }
        }
        du
    }

    #[test]
    fn wide_jacobi_is_the_sweeps() {
        if !x86::avx2() {
            std::println!("no AVX2 on this CPU: nothing to compare");
            return;
        }
        const N: usize = crate::params::MAX_LAYERS;
        let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
        let (mut saturated, mut wide_runs) = (0, 0);
        for round in 0..20_000 {
            let n = 4 + round % (N - 3);
            let iterations = round % 7;
            // One round in four with values anywhere, so sums saturate.
            let p: Vec<Fx> = (0..3 * N)
                .map(|_| {
                    if round % 4 == 0 {
                        rng.value()
                    } else {
                        Fx::from_bits((rng.next() as i64) >> 20)
                    }
                })
                .collect();
            // The Jacobi solve's coefficients are at most 1/4; now and then above the 3/8
            // the wide form takes.
            let mut coef = || match rng.next() % 8 {
                0 => rng.coef(),
                _ => Fx::from_bits((rng.next() % ((1 << 30) + 1)) as i64),
            };
            let coefs = (coef(), coef());
            let want = jacobi_reference(&p, coefs, n, iterations);
            saturated += want
                .iter()
                .filter(|o| **o == Fx::MAX || **o == Fx::MIN)
                .count();
            // In place: p becomes du where the wide form runs, and is left as it was where
            // it declines; the entries after the tip's are p's either way.
            let mut du = p.clone();
            if x86::jacobi(&mut du, coefs, n, iterations) {
                wide_runs += 1;
                assert_eq!(du[..3 * n], want[..], "round {round}, n {n}");
            } else {
                assert_eq!(du[..3 * n], p[..3 * n], "round {round}, n {n}: declined");
            }
            assert_eq!(
                du[3 * n..],
                p[3 * n..],
                "round {round}, n {n}: beyond the tip"
            );
        }
        // At the edge of both bounds: neighbours' sums that saturate after a few sweeps
        // with coefficients near 1/2 (which the wide form declines), none with 3/8.
        let p = vec![Fx::from_bits((1 << 60) - 1); 3 * N];
        for (c, declined) in [(Fx::from_f64(0.49), true), (Fx::from_f64(0.375), false)] {
            let want = jacobi_reference(&p, (c, c), 20, 12);
            let mut du = p.clone();
            let ran = x86::jacobi(&mut du, (c, c), 20, 12);
            assert_eq!(!ran, declined, "{c:?}");
            assert_eq!(&du[..60], if ran { &want[..] } else { &p[..60] }, "{c:?}");
        }
        // The streams reach the saturating cases the wide form leaves to the scalar sweeps,
        // and the wide form ran on most of the others.
        assert!(saturated > 1000, "{saturated}");
        assert!(wide_runs > 12_000, "{wide_runs}");
    }

    /// One segment as `Brush` measures it, with its own functions: length, root (the
    /// Newton step from `near`) and spring term.
    fn segment_reference(d: Vec3<Fx>, near: Fx, s: &Segments<'_, Fx>) -> (Fx, Fx, Vec3<Fx>) {
        let (len2, r) = crate::brush::measure_near(d, near);
        let constants = (s.segment, s.compression_ratio, s.tiny2);
        (len2, r, crate::brush::spring_term(d, len2, r, constants))
    }

    #[test]
    fn wide_segments_are_the_scalar_ones() {
        if !x86::avx2() {
            std::println!("no AVX2 on this CPU: nothing to compare");
            return;
        }
        const N: usize = crate::params::MAX_LAYERS;
        let mut rng = Rng(0x5851_f42d_4c95_7f2d);
        let mm = |v: f64| Fx::from_f64(v);
        let (mut done_total, mut left_total, mut compressed, mut afresh) = (0, 0, 0, 0);
        for round in 0..20_000 {
            let n = 5 + round % (N - 4);
            let segment = mm(1.5 + (rng.next() % 4000) as f64 * 1e-3);
            // Masses along a wobbly line: segments near the rest length, some stretched, some
            // compressed below half of it, some of zero length, now and then one far away.
            let mut spine = vec![Vec3::<Fx>::ZERO; N];
            let mut at = Vec3::new(mm(10.0), mm(-5.0), mm(30.0));
            for m in spine.iter_mut().take(n) {
                *m = at;
                let step = match rng.next() % 10 {
                    0 => 0.0,
                    1 => 0.2,
                    2 | 3 => 0.7,
                    4 => 1.7,
                    _ => 1.0,
                } * segment.to_f64();
                let (a, b) = (
                    (rng.next() % 1000) as f64 * 1e-3,
                    (rng.next() % 1000) as f64 * 1e-3,
                );
                at += Vec3::from_f64([step * a, step * b, -step * (1.0 - a * a).sqrt()]);
                if round % 50 == 0 && rng.next().is_multiple_of(8) {
                    at.x = Fx::from_bits(rng.value().to_bits() >> 2);
                }
            }
            // Last roots: the segment's own (the Newton step applies), a stale one, zero.
            let near: Vec<Fx> = (0..N)
                .map(|j| match rng.next() % 4 {
                    0 => Fx::ZERO,
                    1 => Fx::from_bits((rng.next() % (1 << 32)) as i64),
                    _ if j >= 1 && j < n => {
                        let d = spine[j] - spine[j - 1];
                        let len2 = d.norm2();
                        if len2 > Fx::ZERO {
                            len2.rsqrt()
                        } else {
                            Fx::ZERO
                        }
                    }
                    _ => Fx::ZERO,
                })
                .collect();
            let (mut len2, mut rsqrt) = (vec![Fx::ZERO; N], near.clone());
            let mut seg = vec![Vec3::<Fx>::ZERO; N + 1];
            let mut s = Segments {
                n,
                spine: &spine,
                len2: &mut len2,
                rsqrt: &mut rsqrt,
                seg: &mut seg,
                segment,
                compression_ratio: mm([0.0, 0.1, 0.5, 0.999][round % 4]),
                tiny2: mm(1e-12),
            };
            let done = x86::segments(&mut s);
            for j in 1..n {
                let want = segment_reference(spine[j] - spine[j - 1], near[j], &s);
                if done >> j & 1 != 0 {
                    done_total += 1;
                    compressed += (want.2.dot(spine[j] - spine[j - 1]) < Fx::ZERO) as u32;
                    // A stale or no last root: `rsqrt` afresh.
                    afresh += (near[j] != crate::brush::measure(spine[j] - spine[j - 1]).1) as u32;
                    assert_eq!(
                        (s.len2[j], s.rsqrt[j], s.seg[j]),
                        want,
                        "round {round} j {j}"
                    );
                } else {
                    left_total += 1;
                    // Left for the scalar code with its last root as it was.
                    assert_eq!(s.rsqrt[j], near[j], "round {round} j {j}");
                }
            }
            assert_eq!(done & !((1 << n) - 2), 0, "only segments 1..n: {done:b}");
        }
        // Every kind occurs often: done wide from the last root and afresh (stale or no
        // roots), and left (segments under 1 mm, far masses).
        let counts = format!("{done_total} done ({afresh} afresh), {left_total} left");
        assert!(done_total > 100_000 && left_total > 10_000, "{counts}");
        assert!(afresh > 50_000 && done_total - afresh > 50_000, "{counts}");
        assert!(compressed > 10_000, "{compressed}");
    }

    #[test]
    fn wide_placed_nodes_are_the_scalar_ones() {
        if !x86::avx2() {
            std::println!("no AVX2 on this CPU: nothing to compare");
            return;
        }
        const N: usize = crate::params::MAX_LAYERS;
        let mut rng = Rng(0x1405_7b7e_f767_814f);
        let mut wide_runs = 0;
        for round in 0..20_000 {
            let n = 4 + round % (N - 3);
            let mut value = || {
                if round % 5 == 0 {
                    rng.value()
                } else {
                    Fx::from_bits((rng.next() as i64) >> 20)
                }
            };
            let offsets: [[Fx; N]; 3] = core::array::from_fn(|_| core::array::from_fn(|_| value()));
            let pos = Vec3::new(value(), value(), value());
            // Rotation-like entries: coefficients of either sign, now and then exactly zero.
            let m: [[Fx; 3]; 3] = core::array::from_fn(|_| {
                core::array::from_fn(|_| match rng.next() % 8 {
                    0 => Fx::ZERO,
                    1 => Fx::ONE,
                    2 => -Fx::ONE,
                    _ => Fx::from_bits((rng.next() % (1 << 33)) as i64 - (1 << 32) + 1),
                })
            });
            let mut out = vec![Vec3::<Fx>::ZERO; n];
            if !x86::place_nodes(pos, &offsets, &m, &mut out) {
                continue;
            }
            wide_runs += 1;
            for (i, node) in out.iter().enumerate() {
                let [x, y, z] = [0, 1, 2].map(|k| offsets[k][i]);
                let axis = |row: &[Fx; 3], p: Fx| {
                    p + (x.mul_coef(row[0]) + y.mul_coef(row[1]) + z.mul_coef(row[2]))
                };
                let want = Vec3::new(axis(&m[0], pos.x), axis(&m[1], pos.y), axis(&m[2], pos.z));
                assert_eq!(*node, want, "round {round}, node {i} of {n}");
            }
        }
        // Four rounds in five model-sized: the wide form ran on them.
        assert!(wide_runs > 15_000, "{wide_runs}");
    }

    #[test]
    fn wide_measures_are_the_scalar_ones() {
        if !x86::avx2() {
            std::println!("no AVX2 on this CPU: nothing to compare");
            return;
        }
        const N: usize = crate::params::MAX_LAYERS;
        let mut rng = Rng(0x94d0_49bb_1331_11eb);
        let (mut done_total, mut left_total) = (0, 0);
        for round in 0..20_000 {
            let n = 5 + round % (N - 4);
            // Segments from zero length through under a millimetre (left to the scalar root)
            // to about a metre, now and then one too long to convert exactly.
            let mut spine = vec![Vec3::<Fx>::ZERO; N];
            let mut at = Vec3::<Fx>::ZERO;
            for m in spine.iter_mut().take(n) {
                *m = at;
                let scale = match rng.next() % 8 {
                    0 => 0.0,
                    1 => 0.3,
                    2 => 300.0,
                    // Roots whose f32 estimate, scaled, has a fraction to truncate.
                    3 => 1000.0,
                    4 if round % 16 == 0 => 2e6,
                    _ => 3.0,
                };
                let mut c = || (rng.next() % 2001) as f64 * 1e-3 - 1.0;
                at += Vec3::from_f64([scale * c(), scale * c(), scale * c()]);
            }
            let marker = Fx::from_bits(-12345);
            let (mut len2, mut rsqrt) = (vec![marker; N], vec![marker; N]);
            let done = x86::measure(n, &spine, &mut len2, &mut rsqrt);
            for j in 1..n {
                let d = spine[j] - spine[j - 1];
                let want = d.norm2();
                if done >> j & 1 != 0 {
                    done_total += 1;
                    assert_eq!(
                        (len2[j], rsqrt[j]),
                        (want, want.rsqrt()),
                        "round {round} j {j}"
                    );
                } else {
                    left_total += 1;
                    assert_eq!((len2[j], rsqrt[j]), (marker, marker), "round {round} j {j}");
                }
            }
            assert_eq!(done & !((1 << n) - 2), 0, "only segments 1..n: {done:b}");
        }
        let counts = format!("{done_total} done, {left_total} left");
        assert!(done_total > 150_000 && left_total > 20_000, "{counts}");
    }

    #[test]
    fn wide_integration_is_the_scalar_one() {
        if !x86::avx2() {
            std::println!("no AVX2 on this CPU: nothing to compare");
            return;
        }
        const N: usize = crate::params::MAX_LAYERS;
        let mut rng = Rng(0x2f6b_1d9e_83a4_c5f7);
        let (mut wide_masses, mut stopped, mut dragged, mut projected) = (0, 0, 0, 0);
        for round in 0..20_000 {
            let n = 2 + round % (N - 1);
            // Arrays of exactly n masses now and then (the last masses' four-entry loads
            // would leave them: left to the scalar loop), else of MAX_LAYERS as in `Brush`.
            let len = if round % 5 == 0 { n } else { N };
            let vec3 = |rng: &mut Rng, wild: bool| {
                let mut c = || {
                    if wild {
                        rng.value()
                    } else {
                        Fx::from_bits((rng.next() as i64) >> 26)
                    }
                };
                Vec3::new(c(), c(), c())
            };
            let wild = round % 8 == 0;
            let spine: Vec<Vec3<Fx>> = (0..len).map(|_| vec3(&mut rng, wild)).collect();
            let vel: Vec<Vec3<Fx>> = (0..len).map(|_| vec3(&mut rng, wild)).collect();
            let du: Vec<Fx> = (0..3 * len).map(|_| vec3(&mut rng, wild).x).collect();
            // Tie weights: clear of the paper, lying on it, in between.
            let ties: Vec<Fx> = (0..len)
                .map(|_| match rng.next() % 3 {
                    0 => Fx::ONE,
                    1 => Fx::ZERO,
                    _ => Fx::from_bits((rng.next() % (1 << 32)) as i64),
                })
                .collect();
            // Beyond [0, 1] (which the parameters reject) too: a drag factor outside it.
            let drag_loss = [
                Fx::ZERO,
                Fx::ONE,
                Fx::from_f64(0.3),
                rng.coef(),
                Fx::from_f64(1.7),
                Fx::from_f64(-0.4),
            ][round % 6];
            let tol = Fx::from_bits((rng.next() % (1 << 24)) as i64);
            let (mut want_x, mut want_u) = (spine.clone(), vel.clone());
            let mut want_contact = vec![false; len];
            for i in 1..n {
                let d = Vec3::new(du[3 * i], du[3 * i + 1], du[3 * i + 2]);
                want_contact[i] = crate::brush::integrate_mass(
                    &mut want_x[i],
                    &mut want_u[i],
                    d,
                    ties[i],
                    drag_loss,
                    tol,
                );
            }
            let (mut x, mut u, mut contact) = (spine.clone(), vel.clone(), vec![false; len]);
            let from = x86::integrate(&mut Integration {
                n,
                spine: &mut x,
                vel: &mut u,
                contact: &mut contact,
                du: &du,
                ties: &ties,
                drag_loss,
                contact_tol: tol,
            });
            assert!((1..=n).contains(&from), "round {round}: {from}");
            wide_masses += from - 1;
            stopped += (from < n) as u32;
            for i in 1..from {
                let at = format!("round {round} mass {i}");
                assert_eq!(
                    (x[i], u[i], contact[i]),
                    (want_x[i], want_u[i], want_contact[i]),
                    "{at}"
                );
                dragged += (ties[i] < Fx::ONE && drag_loss > Fx::ZERO) as u32;
                projected += (spine[i].z + vel[i].z + du[3 * i + 2] < Fx::ZERO) as u32;
            }
            // Nothing of the masses left to the scalar loop was written, nor beyond n.
            let left = from.max(1)..len;
            assert_eq!(
                (&x[left.clone()], &u[left.clone()]),
                (&spine[left.clone()], &vel[left.clone()]),
                "round {round}"
            );
            assert!(contact[left].iter().all(|c| !c), "round {round}");
        }
        // The wide form took most masses, stopped at the wild ones, and both drag and the
        // projection onto the paper ran in it.
        let counts = format!(
            "{wide_masses} wide, {stopped} stops, {dragged} dragged, {projected} projected"
        );
        std::println!("{counts}");
        assert!(wide_masses > 100_000 && stopped > 1_000, "{counts}");
        assert!(dragged > 50_000 && projected > 50_000, "{counts}");
    }

    #[test]
    fn wide_factor_products_are_the_full_ones() {
        if !x86::avx2() {
            std::println!("no AVX2 on this CPU: nothing to compare");
            return;
        }
        let mut rng = Rng(0x1b87_3593_cc9e_2d51);
        let edges = [
            -(1 << 33),
            -(1 << 32) - 1,
            -(1 << 32),
            -1,
            0,
            1,
            (1 << 32) - 1,
            1 << 32,
            (1 << 33) - 1,
        ];
        for round in 0..50_000 {
            let a: [i64; 4] = core::array::from_fn(|_| (rng.next() as i64) >> 3);
            let c: [i64; 4] = core::array::from_fn(|k| match rng.next() % 4 {
                0 => edges[(round + k) % edges.len()],
                _ => (rng.next() % (1 << 34)) as i64 - (1 << 33),
            });
            let mut got = [0i64; 4];
            // SAFETY: AVX2 checked above; four lanes in and out.
            unsafe {
                let v = x86::mul_factor(
                    _mm256_loadu_si256(a.as_ptr().cast()),
                    _mm256_loadu_si256(c.as_ptr().cast()),
                );
                _mm256_storeu_si256(got.as_mut_ptr().cast(), v);
            }
            for k in 0..4 {
                let want = Fx::from_bits(a[k]) * Fx::from_bits(c[k]);
                assert_eq!(got[k], want.to_bits(), "{} x {}", a[k], c[k]);
            }
        }
    }

    #[test]
    fn wide_layer_axes_are_the_scalar_ones() {
        if !x86::avx2() {
            std::println!("no AVX2 on this CPU: nothing to compare");
            return;
        }
        use crate::brush::Layer;
        const N: usize = crate::params::MAX_LAYERS;
        let mut rng = Rng(0x7a3c_55e1_09b4_d2f3);
        let mm = |v: f64| Fx::from_f64(v);
        let (mut done_total, mut left_total, mut axis_aligned) = (0, 0, 0);
        for round in 0..20_000 {
            let n = 5 + round % (N - 4);
            // A spine hanging down, bent now and then, with segments along the axes (a
            // brush at rest), of zero length and under 1 mm among them.
            let mut spine = vec![Vec3::<Fx>::ZERO; N];
            let mut at = Vec3::new(mm(3.0), mm(-2.0), mm(40.0));
            for m in spine.iter_mut().take(n) {
                *m = at;
                let step = match rng.next() % 12 {
                    // Length two: the root one half exactly, the direction a unit axis.
                    0 => Vec3::from_f64([0.0, 0.0, -2.0]),
                    1 => Vec3::from_f64([2.0, 0.0, 0.0]),
                    2 => Vec3::ZERO,
                    3 => Vec3::from_f64([0.3, 0.2, -0.4]),
                    _ => {
                        let (a, b) = (
                            (rng.next() % 2000) as f64 * 1e-3 - 1.0,
                            (rng.next() % 2000) as f64 * 1e-3 - 1.0,
                        );
                        Vec3::from_f64([a, b, -2.0])
                    }
                };
                at += step;
            }
            // Short axes: unit vectors along the axes, random ones (the handle's blend),
            // some parallel to a segment (no plane), now and then a wild value.
            let mut layers = vec![
                Layer {
                    short_axis: Vec3::ZERO,
                    long_axis: Vec3::from_f64([0.0, 1.0, 0.0]),
                    long_radius: Fx::ZERO,
                    short_radius: Fx::ZERO,
                    wetness: Fx::ZERO,
                };
                N
            ];
            for (i, l) in layers.iter_mut().enumerate() {
                l.short_axis = match rng.next() % 8 {
                    0 => Vec3::from_f64([1.0, 0.0, 0.0]),
                    1 => Vec3::from_f64([0.0, -1.0, 0.0]),
                    2 if i >= 1 && i < n => spine[i] - spine[i - 1],
                    3 if round % 20 == 0 => Vec3::new(rng.value(), rng.value(), rng.value()),
                    _ => {
                        let t = (rng.next() % 6283) as f64 * 1e-3;
                        Vec3::from_f64([t.cos(), t.sin(), 0.1 * (t * 3.0).sin()])
                            .normalized_or_none(Fx::from_bits(1))
                            .unwrap_or(Vec3::ZERO)
                    }
                };
            }
            let (mut len2, mut rsqrt) = (vec![Fx::ZERO; N], vec![Fx::ZERO; N]);
            let mut measured = 0u32;
            for j in 1..n {
                (len2[j], rsqrt[j]) = crate::brush::measure(spine[j] - spine[j - 1]);
                // Now and then a segment left unmeasured (its values stale).
                if !rng.next().is_multiple_of(16) {
                    measured |= 1 << j;
                } else {
                    (len2[j], rsqrt[j]) = (Fx::ONE, Fx::ONE);
                }
            }
            let tiny = [mm(1e-3), mm(0.05), Fx::from_bits(3)][round % 3];
            let min_len2 = tiny * tiny;
            let before = layers.clone();
            let done = x86::layer_axes(&mut LayerAxes {
                n,
                spine: &spine,
                len2: &len2,
                rsqrt: &rsqrt,
                measured,
                layers: &mut layers,
                min_len2,
                min_cross: tiny,
            });
            assert_eq!(
                done & !((1 << n) - 2) & !measured,
                0,
                "round {round}: {done:b}"
            );
            for i in 1..n {
                let at = format!("round {round} layer {i}");
                if done >> i & 1 == 0 {
                    left_total += 1;
                    assert_eq!(layers[i], before[i], "{at}: not done, changed");
                    continue;
                }
                done_total += 1;
                let v = spine[i] - spine[i - 1];
                assert!(len2[i] > min_len2, "{at}");
                let dir = v.normalized_by(len2[i], rsqrt[i]);
                // The surface update's steps 2-3, with the functions it calls.
                let la = before[i].short_axis.cross_coef(dir);
                let la = la
                    .normalized_or_none_coef(tiny)
                    .expect("a layer done has a plane");
                let want = (la, dir.cross_coef(la));
                assert_eq!((layers[i].long_axis, layers[i].short_axis), want, "{at}");
                let whole = |v: Vec3<Fx>| [v.x, v.y, v.z].iter().any(|c| c.abs() >= Fx::ONE);
                axis_aligned += (whole(dir) || whole(want.0)) as u32;
            }
            assert_eq!(layers[n..], before[n..], "round {round}: beyond n");
        }
        // Done wide most of the time, axis-aligned directions and axes (no coefficients,
        // the scalar code's full products) included; left: unmeasured, short or
        // coincident segments, no plane, wild short axes.
        let counts = format!("{done_total} done ({axis_aligned} axis-aligned), {left_total} left");
        std::println!("{counts}");
        assert!(done_total > 150_000 && axis_aligned > 20_000, "{counts}");
        assert!(left_total > 20_000, "{counts}");
    }

    #[test]
    fn wide_interior_rows_are_the_scalar_entries() {
        if !x86::avx2() {
            std::println!("no AVX2 on this CPU: nothing to compare");
            return;
        }
        const N: usize = crate::params::MAX_LAYERS;
        let mut rng = Rng(0x2545_f491_4f6c_dd1d);
        let mut wide_runs = 0;
        for round in 0..5_000 {
            let n = 3 + round % (N - 2);
            let mut vecs = || -> Vec<Vec3<Fx>> {
                (0..N + 1)
                    .map(|_| {
                        // Some rounds all model-sized, so the wide form runs on them.
                        let mut c = || {
                            if round % 3 == 0 {
                                rng.value()
                            } else {
                                Fx::from_bits((rng.next() as i64) >> 24)
                            }
                        };
                        Vec3::new(c(), c(), c())
                    })
                    .collect()
            };
            let (seg, vel, spine, skel, skel_vel) = (vecs(), vecs(), vecs(), vecs(), vecs());
            // Every third round mostly weight one (a brush in the air: whole blocks of it).
            let ties: Vec<Fx> = (0..N)
                .map(|_| match rng.next() % 4 {
                    _ if round % 3 == 0 && !rng.next().is_multiple_of(8) => Fx::ONE,
                    0 => Fx::ZERO,
                    1 => Fx::ONE,
                    _ => Fx::from_bits((rng.next() % (1 << 32)) as i64),
                })
                .collect();
            let coefs = [rng.coef(), rng.coef(), rng.coef(), rng.coef()];
            let rows = InteriorRows {
                n,
                seg: &seg,
                vel: &vel,
                spine: &spine,
                skel: &skel,
                skel_vel: &skel_vel,
                ties: &ties,
                coefs,
            };
            let mut p = [Fx::ZERO; 3 * N];
            if !x86::interior_rows(&rows, &mut p) {
                continue;
            }
            wide_runs += 1;
            let a = FlatRows::of(&rows);
            for e in 3..3 * (n - 1) {
                let want = a.entry(ties[e / 3], coefs, e);
                assert_eq!(p[e], want, "round {round}, n {n}, entry {e}");
            }
        }
        // Two rounds in three are model-sized; of the others most fall back.
        assert!(wide_runs > 3_000, "{wide_runs}");
    }
}
