//! The brush: spine dynamics (SPEC A), virtual skeleton and plasticity (SPEC B) and the
//! surface ellipses (SPEC C), after Liang 2009 chapters 2-4.
//!
//! # One substep
//!
//! 1. **Handle.** The ferrule mass S_0 and the virtual skeleton VS_i move rigidly with the
//!    handle pose (the skeleton's directions are stored in the handle frame, so the skeleton
//!    turns with the handle). The ferrule is kept on or above the paper: like the thesis's
//!    god-object (4.2.3) the drawn brush never enters the paper; how far the *hand* went in is
//!    the force model's business.
//! 2. **Dynamics.** Velocities are kept as displacement per substep `u = v h` (mm). Two
//!    integrators, chosen by the `integrator` parameter:
//!
//!    **Backward Euler** (the default, `Brush::backward_euler`). The forces are linearised
//!    where the substep starts, each spring with its own Jacobian: for a segment d = S_j -
//!    S_{j-1} with strain e = 1 - L/|d| and unit direction d^, `k_s (e I + (1 - e) d^ d^T)`
//!    (the thesis's eq. 2.21 uses `k_s I` in every direction, which acts as a neighbour damper
//!    of `h k_s` across the chain and makes the brush's response depend on h). In units of
//!    the mass, per free mass i,
//!
//!    ```text
//!    (1 + t_i c_tv + (1 - t_i) c_p P + l_i z z^T) du_i + sum_j G_j (du_i - du_j)
//!        = sum_j [c_k f_j + G_j (u_j - u_i)] + t_i [c_t (VS^t_i - S_i) + c_tv (w_i - u_i)]
//!          - (1 - t_i) c_p P u_i - l_i u_i,z z
//!    G_j = c_k (e+ I + (1 - e+) d^ d^T) + c_d I
//!    ```
//!
//!    over its one or two segments j, with `c_k = h^2 k_s / m`, `c_d = h k_d / m`, `c_t = h^2
//!    k_t,i / m`, `c_tv = c_t + h k_dt,i / m` (layer i's tie for its ink, [`ink`]'s law),
//!    `f_j` the spring term `(1 - L/|d|) d` with the mass's sign, `e+ = max(e, 0)`:
//!    compressed, the negative transverse stiffness (buckling) stays in the force but not in
//!    the matrix, which keeps the system positive definite and the step stable, and the
//!    axial stiffness is the compression's (blended with the
//!    stretch's across [`STIFFNESS_BLEND_STRAIN`] of the rest length, so the step is
//!    continuous in the state). `VS^t_i` is the skeleton node where the substep started and
//!    `w_i` its displacement in it; the ferrule's prescribed displacement `u_0` enters as
//!    the neighbour velocity of mass 1. `c_p = h C_f / m` is the paper's viscous drag (eq.
//!    4.1) on a mass as far as it lies on the paper (`1 - t_i`), `P` the projection onto the
//!    paper's plane: in the system, not applied after it, because a drag that stops a mass
//!    in about a millisecond split from the springs it holds back makes the step's result
//!    depend on the step (`tests/convergence.rs` checks the spring-back of each preset that
//!    runs one substep per tick within 5% of the converged brush there, which the split
//!    drag missed). `l_i` is the tie's weight taken where the substep ends near the paper:
//!    `t_i` grows by `1 / TIE_RAMP_MM` a millimetre of height there, so a tie pulling the
//!    mass down by `T_z` (its term's vertical part) is a vertical stiffness `l_i = -T_z /
//!    TIE_RAMP_MM` on the heights `u_z + du_z` the substep adds (zero clear of the ramp,
//!    and where the tie pulls up; capped where the block would leave the fixed-point
//!    chain's bound); left where the substep starts, a light mass grazing the paper hops
//!    on and off it every other substep ([`TIE_RAMP_MM`]). The prescribed
//!    motion so enters once, and a spine
//!    moving steadily with its skeleton stays where it hangs. The system is block-tridiagonal
//!    with symmetric 3x3 blocks, solved exactly in O(N) (`brush/chain_solve.rs`; the
//!    fixed-point brush in 32-bit formats, `brush/chain_fixed.rs`, chosen by its
//!    [`BrushScalar`]). One substep per tick gives the converged brush within 10%
//!    (`tests/convergence.rs`).
//!
//!    **Kang & Cho** (eqs. 2.19-2.33, the thesis's, `Brush::kang_cho`). Multiplying eq. 2.33
//!    through by `h` gives, for free mass i,
//!
//!    ```text
//!    p_i   = c_k sum_j [(1 - L/|d_ij|) d_ij + (u_j - u_i)] + c_d sum_j (u_j - u_i)
//!          + t_i [c_t (VS^t_i - S_i) + (c_t + c_dt) (w_i - u_i)]
//!    du_i(0) = p_i,   du_i(k) = p_i + (c_k + c_d) sum_j du_j(k-1)
//!    ```
//!
//!    with `c_k = h^2 k_s / W'_i`, `c_d = h k_d / W'_i`, `c_t = h^2 k_t / W'_i`,
//!    `c_dt = h k_dt / W'_i`, `W'_i = m + h^2 (n_i k_s + t_i k_t) + h (n_i k_d + t_i k_dt)`
//!    (in p_i, c_t and c_dt are layer i's for its ink, [`ink`]'s law; W' keeps the dry tie),
//!    `t_i` the weight of mass i's tie to the skeleton (0 lying on the paper, 3.1.2, rising
//!    to 1 at [`TIE_RAMP_MM`]; the implicit rows always include the tie, which changes W' by
//!    under 0.01% at the presets' stiffness and keeps the solve independent of contact),
//!    and `du_0` the ferrule's prescribed velocity change.
//!
//!    The iterations are the thesis's method and are used while they converge well; for
//!    stiffer springs or longer substeps the same system is solved exactly in O(N) (see
//!    [`JACOBI_LIMIT`] for the stability analysis behind the switch).
//!
//!    In both, the coefficients are dimensionless and computed when a parameter changes, so
//!    `h^2` never meets the fixed-point format.
//! 3. **Paper.** The thesis's step then applies the viscous drag (eq. 4.1) on masses lying
//!    on the paper, implicitly (`u_par /= 1 + h C_f / m`, stable for any drag; backward Euler
//!    has it in its system). Then `S_i += u_i`, and a mass below the paper is projected back
//!    onto it with its downward velocity removed (Fig. 4-5).
//!
//! Once per 1 ms tick, after the substeps ([`Brush::end_tick`]):
//!
//! 4. **Plasticity** (eqs. 3-1..3-6) when D > 0.
//! 5. **Surface** (eqs. 3-7..3-21): per-layer ellipse axes and radii.
//! 6. **Ink** ([`ink`]): what each layer gives to the paper, and wicking between layers.
//!
//! # Deviations from the thesis, and why
//!
//! * Eq. 3-3 interpolates with weight i/(N-1), which moves the end direction V_{N-2} it has just
//!   set; we use i/(N-2) so both ends keep their values.
//! * D and SDF are per-step rates in the thesis, which ran them at 25 kHz. They are stated at
//!   that reference rate and converted to the 1 kHz tick at which we run them,
//!   `1 - (1 - D)^(25 kHz / 1 kHz)`, so a brush behaves the same at any substep rate.
//! * Eq. 3-8 interpolates the short axis toward the paper normal but never makes it
//!   perpendicular to the spine segment, so near a vertical brush the "cross-section"
//!   ellipse stands upright. We keep the interpolated direction's intent and use
//!   `SA = V x LA` (the interpolated SA with its component along the segment removed), so
//!   every ellipse is a true cross-section of the hair bundle.
//! * Eq. 3.11's cross product vanishes when a layer's short axis is parallel to its spine
//!   segment (a brush pressed straight down): the previous long axis, made perpendicular to
//!   the segment, is kept instead.

// The solver walks chains of masses touching i-1, i and i+1 of several arrays at once; index
// loops say that more plainly than zipped iterators.
#![allow(clippy::needless_range_loop)]
// A build without the thesis's step (the Black Pill's image) leaves its solves, rows and
// coefficients unread; they are compiled out as dead code there.
#![cfg_attr(not(feature = "kang-cho"), allow(dead_code))]

use core::mem::MaybeUninit;

#[cfg(feature = "backward-euler")]
use crate::params::INTEGRATOR_BACKWARD_EULER;
use crate::params::{BrushParams, ParamError, ParamId, MAX_LAYERS, REFERENCE_SUBSTEP_HZ, TICK_HZ};
use crate::quat::{Pose, Quat};
use crate::scalar::Scalar;
use crate::vec::Vec3;

#[cfg(feature = "backward-euler")]
mod chain_fixed;
#[cfg(feature = "backward-euler")]
mod chain_solve;
pub mod ink;
mod layer;
pub use layer::Layer;
pub mod state_frame;
mod unit_fixed;

#[cfg(feature = "backward-euler")]
pub use chain_fixed::MAX_DIAGONAL;
#[cfg(feature = "backward-euler")]
use chain_solve::{ChainSolve, Segment, SpineChain};

use crate::scalar::Fx;

/// A number format the brush runs in: a [`Scalar`], and how the backward-Euler step solves
/// its spine's chain in it. The float formats solve in their own arithmetic; the fixed-point
/// format (`Fx`, the pen's) in 32-bit fixed point (`brush/chain_fixed.rs`: its own 64-bit
/// products cost the pen's tick several times as much), which bounds the brushes it takes
/// ([`Self::check_params`]). Implemented for `f32`, `f64` and `Fx`; sealed (its solver trait
/// is private to the brush).
pub trait BrushScalar: Scalar {
    #[cfg(feature = "backward-euler")]
    #[doc(hidden)]
    type Chain: SpineChain<Self>;
    /// Whether the format can run a brush of `params` (validated): the float formats run
    /// every brush; fixed point refuses one whose backward-Euler step's blocks leave its
    /// chain's formats at the brush's substep rate ([`MAX_DIAGONAL`]).
    #[inline]
    fn check_params(params: &BrushParams) -> Result<(), ParamError> {
        let _ = params;
        Ok(())
    }
    /// A unit vector (a segment's direction) in the form the surface's products take it in
    /// ([`Self::unit`]).
    #[doc(hidden)]
    type Unit: Copy;
    /// `dir` (unit) as a [`Self::Unit`]: the float formats keep it as it is.
    #[doc(hidden)]
    fn unit(dir: Vec3<Self>) -> Self::Unit;
    /// The unit vector along `v`, given `len2 = |v|^2` and `r = len2.rsqrt()`, as a
    /// [`Self::Unit`]: [`Vec3::normalized_by`]'s.
    #[doc(hidden)]
    fn direction(v: Vec3<Self>, len2: Self, r: Self) -> Self::Unit;
    /// `1 - a . b` of two unit vectors: a layer's tilt (the surface update's step 5).
    #[doc(hidden)]
    fn one_minus_dot(a: Self::Unit, b: Self::Unit) -> Self;
    /// A [`Self::Unit`] as a vector.
    #[doc(hidden)]
    fn from_unit(u: Self::Unit) -> Vec3<Self>;
    /// `a (1 - w) + Z w` for `w` in [0, 1]: a short axis between `a` and the paper's normal.
    #[doc(hidden)]
    fn toward_normal(a: Self::Unit, w: Self) -> Self::Unit;
    /// `a + (b - a) w` for `w` in [0, 1]: a short axis between `a` and `b`.
    #[doc(hidden)]
    fn lerp_unit(a: Self::Unit, b: Self::Unit, w: Self) -> Self::Unit;
    /// A layer's ellipse axes from its short axis `sa` (components within one; `None`: the
    /// paper's normal) and its segment's unit direction `dir` ([`Self::unit`]): the long axis
    /// `sa x dir` normalised, if longer than `min_len`, and the short axis `dir x long`
    /// (unit).
    #[doc(hidden)]
    fn ellipse_axes(
        sa: Option<Self::Unit>,
        dir: Self::Unit,
        min_len: Self,
    ) -> Option<(Vec3<Self>, Vec3<Self>)>;
    /// The skeleton's nodes `pos + m offset_i` into `out` by the format's own means, if it
    /// has them (`true`); else [`place_skeleton`]'s generic products.
    #[doc(hidden)]
    #[inline(always)]
    fn place_nodes(
        pos: Vec3<Self>,
        offsets: &Offsets<Self>,
        m: &[[Self; 3]; 3],
        out: &mut [Vec3<Self>],
    ) -> bool {
        let _ = (pos, offsets, m, out);
        false
    }
    /// The tick's ink transfer (`Brush::transfer_ink`, [`ink`]), compiled where the format
    /// wants it: the pen's in the shared crate, built for size.
    #[doc(hidden)]
    #[inline(always)]
    fn transfer_ink(brush: &mut Brush<Self>) {
        brush.transfer_ink();
    }
    /// A layer's short radius `area / long` from its rest area and its long radius (at least
    /// the rest radius, so positive): eq. 3-20's area preserved.
    #[doc(hidden)]
    #[inline(always)]
    fn short_radius(area: Self, long: Self) -> Self {
        // rl is at least the rest radius and the area its square: the reciprocal's product
        // is within about r0^2 (1 + 1/r0) units of the format's resolution of the quotient
        // ([`Scalar::recip`]). The reciprocal is below one for a long radius above a
        // millimetre: the coefficient product then (the same value).
        area.mul_coef(long.recip())
    }
}

/// [`BrushScalar`]'s surface products in the format's own arithmetic (the float formats').
macro_rules! float_surface {
    () => {
        type Unit = Vec3<Self>;
        #[inline(always)]
        fn unit(dir: Vec3<Self>) -> Vec3<Self> {
            dir
        }
        #[inline(always)]
        fn direction(v: Vec3<Self>, len2: Self, r: Self) -> Vec3<Self> {
            v.normalized_by(len2, r)
        }
        #[inline(always)]
        fn one_minus_dot(a: Vec3<Self>, b: Vec3<Self>) -> Self {
            1.0 - a.dot_coef(b)
        }
        #[inline(always)]
        fn from_unit(u: Vec3<Self>) -> Vec3<Self> {
            u
        }
        #[inline(always)]
        fn toward_normal(a: Vec3<Self>, w: Self) -> Vec3<Self> {
            // Z's products are exact (zero and w), so only the z sum is left of them.
            let sa = a.scale_coef(1.0 - w);
            Vec3::new(sa.x, sa.y, sa.z + w)
        }
        #[inline(always)]
        fn lerp_unit(a: Vec3<Self>, b: Vec3<Self>, w: Self) -> Vec3<Self> {
            // Three products instead of the six of a (1 - w) + b w.
            a + (b - a).scale_coef(w)
        }
        #[inline(always)]
        fn ellipse_axes(
            sa: Option<Vec3<Self>>,
            dir: Vec3<Self>,
            min_len: Self,
        ) -> Option<(Vec3<Self>, Vec3<Self>)> {
            let la = match sa {
                // Z x V: the value of the general product (its factors zero and one give
                // exact products), without its six products.
                None => Vec3::new(0.0 - dir.y, dir.x, 0.0),
                Some(sa) => sa.cross_coef(dir),
            };
            let la = la.normalized_or_none_coef(min_len)?;
            Some((la, dir.cross_coef(la)))
        }
    };
}

impl BrushScalar for f64 {
    #[cfg(feature = "backward-euler")]
    type Chain = ChainSolve<f64>;
    float_surface!();
}

impl BrushScalar for f32 {
    #[cfg(feature = "backward-euler")]
    type Chain = ChainSolve<f32>;
    float_surface!();
}

impl BrushScalar for Fx {
    #[cfg(feature = "backward-euler")]
    type Chain = chain_fixed::FixedChain;
    #[cfg(feature = "backward-euler")]
    fn check_params(params: &BrushParams) -> Result<(), ParamError> {
        // One chain solve for the format, the 32-bit one (the pen's flash holds no second):
        // a brush stiffer than its blocks hold, at its substep rate, is refused.
        if params.integrator == crate::params::INTEGRATOR_BACKWARD_EULER
            && params.backward_euler_diagonal_bound() >= MAX_DIAGONAL
        {
            return Err(ParamError::Inconsistent {
                param: ParamId::SubstepsPerTick,
                why: "too stiff for the fixed-point step: raise it or soften the hair",
            });
        }
        Ok(())
    }
    // In 32-bit words (`brush/unit_fixed.rs`): a surface update's worth of 64-bit products
    // saved on the pen's every tick. A direction enters its words once, for the layer's
    // axes and for the tilts on either side.
    type Unit = unit_fixed::Unit;
    #[inline(always)]
    fn unit(dir: Vec3<Fx>) -> unit_fixed::Unit {
        unit_fixed::unit(dir)
    }
    #[inline(always)]
    fn direction(v: Vec3<Fx>, len2: Fx, r: Fx) -> unit_fixed::Unit {
        unit_fixed::direction(v, len2, r)
    }
    #[inline(always)]
    fn one_minus_dot(a: unit_fixed::Unit, b: unit_fixed::Unit) -> Fx {
        unit_fixed::one_minus_dot(a, b)
    }
    #[inline(always)]
    fn from_unit(u: unit_fixed::Unit) -> Vec3<Fx> {
        unit_fixed::from_unit(u)
    }
    #[inline(always)]
    fn toward_normal(a: unit_fixed::Unit, w: Fx) -> unit_fixed::Unit {
        unit_fixed::toward_normal(a, w)
    }
    #[inline(always)]
    fn lerp_unit(a: unit_fixed::Unit, b: unit_fixed::Unit, w: Fx) -> unit_fixed::Unit {
        unit_fixed::lerp_unit(a, b, w)
    }
    #[inline(always)]
    fn ellipse_axes(
        sa: Option<unit_fixed::Unit>,
        dir: unit_fixed::Unit,
        min_len: Fx,
    ) -> Option<(Vec3<Fx>, Vec3<Fx>)> {
        unit_fixed::ellipse_axes(sa, dir, min_len)
    }
    #[inline(always)]
    fn place_nodes(
        pos: Vec3<Fx>,
        offsets: &Offsets<Fx>,
        m: &[[Fx; 3]; 3],
        out: &mut [Vec3<Fx>],
    ) -> bool {
        unit_fixed::place_nodes(pos, offsets, m, out);
        true
    }
    fn transfer_ink(brush: &mut Brush<Fx>) {
        transfer_ink_fx(brush);
    }
    // In `f32` (a tenth of a nanometre for the presets' radii): every layer's short radius
    // is a division on the pen's every tick.
    #[inline(always)]
    fn short_radius(area: Fx, long: Fx) -> Fx {
        crate::scalar::quotient_f32(area, long)
    }
}

/// Largest Jacobi off-diagonal weight `c_j = (h^2 k_s + h k_d) / W'` at which the thesis's
/// truncated Jacobi solve is used. Above it the same linear system is solved exactly.
///
/// Why: for the chain's alternating mode the Jacobi iteration matrix has eigenvalue
/// `-2 c_j`, and k = 4 iterations scale the update by `S = (1 + (2c)^5) / (1 + 2c)` instead of
/// the exact `1 / (1 + 2c)`. The step is stable only while `c S <= 1/3`, which fails for
/// `c_j > 0.425` (h^2 k / m > 2.8): a brush 1000x stiffer than the presets blows up at any
/// substep rate. At 0.25 the series has converged to 3% and the margin is wide; the presets
/// sit at 0.05. The exact solve costs about as much as two Jacobi sweeps.
pub const JACOBI_LIMIT: f64 = 0.25;

/// A mass within this height of the paper touches it (mm).
pub const CONTACT_TOLERANCE_MM: f64 = 1e-4;
/// Height over which a mass's tie to the skeleton fades in as it leaves the paper (mm).
///
/// The thesis unties masses lying on the paper (3.1.2) with a switch. A hair grazing the paper
/// then falls into a relay oscillation: untied it drifts up, tied it is pulled back into the
/// paper, projected it is untied again, every few substeps; and the fixed-point and f64 runs
/// switch in different orders (far apart at the tip on the 橫 example, against a budget of
/// a few micrometres). With the
/// tie's weight ramping linearly from 0 on the paper to 1 at this height, and the paper drag
/// ramping the other way, the model is continuous and the two runs stay together. The
/// backward-Euler step takes the weight's growth with the height where the substep ends
/// (`Brush::backward_euler`): taken where it starts, the ramp is steep enough for a light
/// mass to hop on and off the paper every other substep (`tests/contact.rs`).
pub const TIE_RAMP_MM: f64 = 0.05;

/// Per-substep coefficients of one mass's row in the implicit solve (see the module docs).
#[derive(Copy, Clone, Debug)]
struct Row<S> {
    c_k: S,
    c_j: S, // c_k + c_d: the Jacobi off-diagonal, also the relative-velocity weight
    tie: Tie<S>,
    c_f: S, // h^2 / W' in mm per newton: an external force's share of the velocity change
}

/// A tie's per-substep coefficients, `c_t` and `c_tv = c_t + c_dt` of a dry layer (see the
/// module docs), and what a saturated layer's ink adds to each ([`ink`]'s law).
#[derive(Copy, Clone, Debug)]
struct Tie<S> {
    c_t: S,
    c_tv: S,
    c_t_ink: S,
    c_tv_ink: S,
}

impl<S: Scalar> Tie<S> {
    /// The coefficients `(c_t, c_tv)` of a layer with wetness `wet`: linear in it, one
    /// product each, by `mul` (a coefficient product: `c_t_ink` and `c_tv_ink` are the
    /// coefficients).
    #[inline(always)]
    fn at(&self, wet: S, mul: impl Fn(S, S) -> S) -> (S, S) {
        (
            self.c_t + mul(wet, self.c_t_ink),
            self.c_tv + mul(wet, self.c_tv_ink),
        )
    }
}

/// Half the band of strain across which the backward-Euler step's axial stiffness goes from
/// the compression's to the stretch's (see `Brush::backward_euler`).
#[cfg(feature = "backward-euler")]
pub const STIFFNESS_BLEND_STRAIN: f64 = 1e-4;

/// Per-substep coefficients of the backward-Euler step (see the module docs), each in units
/// of the mass it moves: `h^2 k / m` and `h c / m`.
#[cfg(feature = "backward-euler")]
#[derive(Copy, Clone, Debug)]
struct Implicit<S> {
    /// h^2 k_s / m.
    c_k: S,
    /// The same in compression (times the compression ratio).
    c_k_compressed: S,
    /// `c_k - c_k_compressed`: the axial stiffness's step at the rest length.
    c_k_stretch_step: S,
    /// [`STIFFNESS_BLEND_STRAIN`], and one over twice it.
    blend_strain: S,
    inv_blend_width: S,
    /// h k_d / m.
    c_d: S,
    /// h^2 k_t / m and (h^2 k_t + h k_dt) / m, and the ink's change to them.
    tie: Tie<S>,
    /// h^2 / m in mm per newton: an external force's displacement.
    c_f: S,
    /// h C_f / m: the paper's drag on a mass lying on it, in the paper's plane.
    c_drag: S,
    /// The largest vertical stiffness of a tie's weight near the paper: what the diagonal
    /// block's vertical entry has left below [`MAX_DIAGONAL`] after the mass, its tie and
    /// its two segments.
    lift_max: S,
}

/// Everything derived from the parameters that the substep needs: recomputed by
/// [`Brush::set_params`], never on the substep path.
#[derive(Copy, Clone, Debug)]
struct Derived<S> {
    /// Layers (masses): read through [`Derived::n`].
    layers: usize,
    k: usize,
    iterations: usize,
    substeps: usize,
    /// Backward Euler (else the thesis's Kang & Cho scheme).
    #[cfg(feature = "backward-euler")]
    backward_euler: bool,
    /// Solve eq. 2.30 exactly instead of by Jacobi iterations (see [`JACOBI_LIMIT`]).
    exact_solve: bool,
    /// Whether every coefficient the interior rows multiply by is a coefficient in the
    /// sense of [`Scalar::is_coef`] (so the thesis's step may take `mul_tested_coef`):
    /// decided with the parameters, not on every substep.
    interior_coefs: bool,
    #[cfg(feature = "backward-euler")]
    implicit: Implicit<S>,
    /// [interior, tip]. Every row includes the tie (see the module docs).
    rows: [Row<S>; 2],
    /// 1 - 1 / (1 + h C_f / m): the share of in-plane velocity the paper's drag takes.
    drag_loss: S,
    segment: S,
    compression_ratio: S,
    plasticity: S,
    spread_rate: S,
    spread_tf: S,
    rest_radius: [S; MAX_LAYERS],
    /// `rest_radius` squared (the same product): the area-preserving short radius
    /// divides it by the long radius every tick.
    rest_area: [S; MAX_LAYERS],
    max_radius: [S; MAX_LAYERS],
    /// i / (N - 2) for the skeleton interpolation (eq. 3-3).
    skel_weight: [S; MAX_LAYERS],
    /// i / (N - 1) (eq. 3-17).
    layer_frac: [S; MAX_LAYERS],
    /// 1 / k for k in 1..N (entry 0 unused): the surface update's divisions by a count of
    /// layers, as `S::ONE.div` computes them, taken once per parameter change instead of
    /// once per tick.
    inv_count: [S; MAX_LAYERS],
    /// The spread rate times i / (N - 1): the share of the way to the widest radius a
    /// layer's long radius spreads in a tick (eqs. 3-17..3-19).
    spread_weight: [S; MAX_LAYERS],
    contact_tol: S,
    /// 1 / TIE_RAMP_MM.
    inv_tie_ramp: S,
    /// 2 TIE_RAMP_MM: from this height up the tie weight is one.
    tie_clear: S,
    inv_substeps: S,
    /// Below this length a direction is treated as undefined (mm).
    tiny: S,
    tiny2: S,
}

impl<S> Derived<S> {
    /// The number of layers, which validation keeps within `3..=MAX_LAYERS`: clamped here
    /// as well, so that the compiler knows every `[..n]`, `[1..n]` and `[n - 1]` of the
    /// model's `MAX_LAYERS` arrays is in bounds and leaves out the panicking checks (the
    /// force path must not hold any; the clamp is two instructions).
    #[inline(always)]
    fn n(&self) -> usize {
        self.layers.clamp(2, MAX_LAYERS)
    }
}

/// A brush: its parameters and its complete dynamic state.
#[derive(Clone, Debug)]
pub struct Brush<S> {
    params: BrushParams,
    d: Derived<S>,
    handle: Pose<S>,
    /// Spine masses S_i (mm); S_0 is the ferrule.
    spine: [Vec3<S>; MAX_LAYERS],
    /// Displacement per substep u_i = v_i h (mm).
    vel: [Vec3<S>; MAX_LAYERS],
    contact: [bool; MAX_LAYERS],
    /// Skeleton segment directions V_i in the handle frame (unit), i in 0..N-1.
    skel_dir: [Vec3<S>; MAX_LAYERS],
    /// Skeleton nodes VS_i in the world (mm).
    skel: [Vec3<S>; MAX_LAYERS],
    /// Skeleton nodes' displacement in the last substep (mm).
    skel_vel: [Vec3<S>; MAX_LAYERS],
    layers: [Layer<S>; MAX_LAYERS],
    ink_coefs: ink::InkCoefs,
    /// Which pairs of layers wick this tick ([`ink`]): the even and the odd in turn.
    ink_phase: bool,
    /// External force on the tip mass (N), e.g. a finger or a test load.
    tip_load: Vec3<S>,
    /// The exact solve's pivots ([`Self::prepare_pivots`]), computed with the parameters.
    inv_pivot: [S; MAX_LAYERS],
    cprime: [S; MAX_LAYERS],
    /// Squared length and its `rsqrt` of each spine segment i (masses i-1 to i) as last
    /// measured. Exact for the spine as it is while `segments_cached`: the surface update
    /// measured them, and the next substep's springs need the same two numbers for every
    /// segment but the first (only the ferrule moves before they are computed), which at
    /// one substep per tick saves a fifth of the device's square roots. Set by
    /// [`Self::measure_segments`] (the surface update and [`Self::reset`]); every substep
    /// then measures again, each `rsqrt` from the last ([`Scalar::rsqrt_near`]), and clears
    /// `segments_cached`.
    seg_len2: [S; MAX_LAYERS],
    seg_rsqrt: [S; MAX_LAYERS],
    segments_cached: bool,
    substeps_done: u64,
    /// Substeps the fixed-point solve could not hold, each a restart at rest.
    restarts: u32,
}

impl<S: BrushScalar> Brush<S> {
    /// A brush at rest, hanging straight along the handle at `pose`.
    pub fn new(params: BrushParams, pose: Pose<S>) -> Result<Self, ParamError> {
        let mut b = Self::unplaced(params, pose)?;
        b.place(pose);
        Ok(b)
    }

    /// [`Self::new`] built where it is to live (a `static`'s storage, say): a brush is
    /// kilobytes of arrays sized for `MAX_LAYERS`, and `new` returns it through two or three
    /// copies on the stack, which a microcontroller pays for at boot in stack it must
    /// reserve. The same brush, bit for bit (test `brush_built_in_place_is_the_same`).
    pub fn new_in(
        slot: &mut MaybeUninit<Self>,
        params: BrushParams,
        pose: Pose<S>,
    ) -> Result<&mut Self, ParamError> {
        let b = slot.write(Self::unplaced(params, pose)?);
        b.place(pose);
        Ok(b)
    }

    /// Places a brush from [`Self::unplaced`] at rest at `pose`.
    pub(crate) fn place(&mut self, pose: Pose<S>) {
        self.prepare_pivots();
        self.reset(pose);
    }

    /// The validated parameters and their derived coefficients, everything else zero:
    /// [`Self::reset`] places it. Inlined into both constructors so that `new_in` writes
    /// the fields straight into its slot.
    #[inline(always)]
    pub(crate) fn unplaced(params: BrushParams, pose: Pose<S>) -> Result<Self, ParamError> {
        params.validate()?;
        S::check_params(&params)?;
        Ok(Brush {
            params,
            d: derive::<S>(&params),
            handle: pose,
            spine: [Vec3::ZERO; MAX_LAYERS],
            vel: [Vec3::ZERO; MAX_LAYERS],
            contact: [false; MAX_LAYERS],
            skel_dir: [-Vec3::Z; MAX_LAYERS],
            skel: [Vec3::ZERO; MAX_LAYERS],
            skel_vel: [Vec3::ZERO; MAX_LAYERS],
            layers: [Layer {
                short_axis: Vec3::X,
                long_axis: Vec3::Y,
                long_radius: S::ZERO,
                short_radius: S::ZERO,
                wetness: S::ONE,
                deposited: S::ZERO,
            }; MAX_LAYERS],
            ink_coefs: ink::InkCoefs::new(&params),
            ink_phase: false,
            tip_load: Vec3::ZERO,
            inv_pivot: [S::ZERO; MAX_LAYERS],
            cprime: [S::ZERO; MAX_LAYERS],
            seg_len2: [S::ZERO; MAX_LAYERS],
            seg_rsqrt: [S::ZERO; MAX_LAYERS],
            segments_cached: false,
            substeps_done: 0,
            restarts: 0,
        })
    }

    /// Puts the brush at rest at `pose`: straight, no velocity, round, wet as configured.
    pub fn reset(&mut self, pose: Pose<S>) {
        let pose = clamp_to_paper(pose);
        self.handle = pose;
        self.skel_dir = [-Vec3::Z; MAX_LAYERS];
        let offsets = self.skeleton_offsets();
        place_skeleton(pose, &offsets, &mut self.skel[..self.d.n()]);
        self.skel_vel = [Vec3::ZERO; MAX_LAYERS];
        let n = self.d.n();
        for i in 0..n {
            self.spine[i] = self.skel[i];
            self.vel[i] = Vec3::ZERO;
            self.contact[i] = false;
        }
        let sa = pose.rot.rotate(Vec3::X);
        let la = pose.rot.rotate(Vec3::Y);
        let w = S::from_f32(self.params.wetness);
        // The wicking's alternation starts again with the ink, as in a new brush (a host
        // that mirrors a reset pen builds one).
        self.ink_phase = false;
        for i in 0..n {
            self.layers[i] = Layer {
                short_axis: sa,
                long_axis: la,
                long_radius: self.d.rest_radius[i],
                short_radius: self.d.rest_radius[i],
                wetness: w,
                deposited: S::ZERO,
            };
        }
        // A brush reset into the paper settles onto it on the first substep.
        self.project_onto_paper();
        // What the first substep's springs need, as the surface update would leave it.
        self.measure_segments();
    }

    /// Replaces all parameters (validated first; on error nothing changes). The state is
    /// kept when the number of layers is unchanged; otherwise the brush is reset at its
    /// current pose.
    pub fn set_params(&mut self, params: BrushParams) -> Result<(), ParamError> {
        params.validate()?;
        S::check_params(&params)?;
        let relayout = params.layers != self.params.layers
            || params.length_mm != self.params.length_mm
            || params.wetness != self.params.wetness;
        self.params = params;
        self.d = derive::<S>(&params);
        self.ink_coefs = ink::InkCoefs::new(&params);
        self.prepare_pivots();
        if relayout {
            self.reset(self.handle);
        }
        Ok(())
    }

    /// Sets one parameter (validated; on error nothing changes).
    pub fn set_param(&mut self, id: ParamId, value: f32) -> Result<(), ParamError> {
        let mut p = self.params;
        p.set(id, value)?;
        self.set_params(p)
    }
}

/// What reads the brush, or changes it without running the model: for any [`Scalar`].
impl<S: Scalar> Brush<S> {
    pub fn params(&self) -> &BrushParams {
        &self.params
    }

    /// Number of layers N.
    pub fn len(&self) -> usize {
        self.d.n()
    }
    pub fn is_empty(&self) -> bool {
        self.d.n() == 0
    }
    pub fn handle(&self) -> Pose<S> {
        self.handle
    }
    pub fn spine(&self) -> &[Vec3<S>] {
        &self.spine[..self.d.n()]
    }
    /// Displacement of each mass in the last substep (mm).
    pub fn velocities(&self) -> &[Vec3<S>] {
        &self.vel[..self.d.n()]
    }
    pub fn skeleton(&self) -> &[Vec3<S>] {
        &self.skel[..self.d.n()]
    }
    /// Skeleton segment directions in the handle frame.
    pub fn skeleton_directions(&self) -> &[Vec3<S>] {
        &self.skel_dir[..self.d.n() - 1]
    }
    pub fn layers(&self) -> &[Layer<S>] {
        &self.layers[..self.d.n()]
    }
    pub fn in_contact(&self) -> &[bool] {
        &self.contact[..self.d.n()]
    }
    /// Masses lying on the paper.
    pub fn contacts(&self) -> usize {
        self.in_contact().iter().filter(|&&c| c).count()
    }
    pub fn substeps_done(&self) -> u64 {
        self.substeps_done
    }
    /// Substeps whose motion the fixed-point solve could not hold (a pose that jumped), after
    /// each of which the brush restarted at rest on its skeleton; zero in the float formats.
    pub fn restarts(&self) -> u32 {
        self.restarts
    }
    pub fn substeps_per_tick(&self) -> usize {
        self.d.substeps
    }
    /// Rest segment length L (mm).
    pub fn segment_mm(&self) -> f64 {
        self.d.segment.to_f64()
    }
    /// Whether the implicit solve is exact (stiff parameters) rather than Jacobi iterations.
    pub fn solves_exactly(&self) -> bool {
        self.d.exact_solve
    }
    pub fn ring_nodes(&self) -> usize {
        self.d.k
    }

    /// The force the hairs exert on the handle (newtons, world frame): the first segment's
    /// spring-damper pulling on the ferrule plus every tie's spring-damper pulling on the
    /// skeleton, which the handle carries. At rest against the paper this balances the
    /// paper's reaction, so its vertical part is the normal force the brush presses with.
    pub fn handle_reaction(&self) -> [f64; 3] {
        let p = &self.params;
        let h = p.substep_s() as f64;
        let (ks, kd) = (p.axial_stiffness as f64, p.axial_damping as f64);
        let mut f = [0.0; 3];
        let n = self.d.n();
        if n > 1 {
            let d = (self.spine[1] - self.spine[0]).to_f64();
            let dv = (self.vel[1] - self.vel[0]).to_f64();
            let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            if len > 1e-9 {
                let mut s = ks * (len - self.segment_mm()) / len;
                if s < 0.0 {
                    s *= p.compression_ratio as f64;
                }
                for a in 0..3 {
                    f[a] += (s * d[a] + kd * dv[a] / h) * 1e-3;
                }
            }
        }
        for i in 1..n {
            let (kt, kdt) = ink::tie_at(p, self.layers[i].wetness.to_f64());
            let w = self.tie_weight(i).to_f64();
            let d = (self.spine[i] - self.skel[i]).to_f64();
            let dv = (self.vel[i] - self.skel_vel[i]).to_f64();
            for a in 0..3 {
                f[a] += w * (kt * d[a] + kdt * dv[a] / h) * 1e-3;
            }
        }
        f
    }

    /// Applies a constant external force (newtons, world frame) to the tip mass until changed.
    /// In fixed point, a load that moves the free tip further in one substep than the step's
    /// format holds (about a newton on the large brush at one substep per tick) restarts
    /// the brush every substep ([`Self::restarts`]): the static-bend experiment, whose
    /// equilibrium does not depend on the step, takes two substeps there.
    pub fn set_tip_load(&mut self, force: Vec3<S>) {
        self.tip_load = force;
    }

    /// How strongly mass i is tied to the skeleton: 0 lying on the paper, 1 from
    /// [`TIE_RAMP_MM`] up.
    #[inline]
    pub fn tie_weight(&self, i: usize) -> S {
        tie_weight_at(&self.d, self.spine[i].z)
    }
}

impl<S: BrushScalar> Brush<S> {
    /// Advances one 1 ms tick to the handle pose `target`. Over the tick's substeps each
    /// skeleton node (the ferrule, node 0, with them) moves in equal steps along the straight
    /// line from where the previous tick's pose placed it to where `target` places it; the
    /// last substep places the skeleton from `target` itself.
    pub fn tick(&mut self, target: Pose<S>) {
        let n = self.d.substeps;
        // The skeleton's shape in the handle frame changes only in `end_tick` (plastic flow),
        // so its node offsets are summed once here for all the tick's substeps.
        let offsets = self.skeleton_offsets();
        let target = clamp_to_paper(target);
        if n > 1 {
            // The poses come one per tick, so the handle's path between two is ours to
            // choose. Straight node paths differ from placing the skeleton rigidly at an
            // interpolated pose by r dθ^2 / 8 for a node r from the ferrule and a turn dθ in
            // the tick (0.5 um at 40 mm for a turn of 10 rad/s), and spare every substep but
            // the last the rotation of every node: a fifth of the host's tick, a seventh of
            // the device's at 25 substeps. (The last substep places the nodes again, in
            // place: at one substep per tick, the board's rate, that is the only placement.)
            let mut end = [Vec3::<S>::ZERO; MAX_LAYERS];
            place_skeleton(target, &offsets, &mut end[..self.d.n()]);
            let mut step = [Vec3::<S>::ZERO; MAX_LAYERS];
            for ((st, e), now) in step.iter_mut().zip(&end).zip(&self.skel) {
                *st = (*e - *now).scale_coef(self.d.inv_substeps);
            }
            for _ in 1..n {
                self.substep_by(|b| {
                    let n = b.d.n();
                    for ((node, vel), st) in b.skel[..n].iter_mut().zip(&mut b.skel_vel).zip(&step)
                    {
                        *node += *st;
                        *vel = *st;
                    }
                    // The orientation stays the tick's start until its last substep.
                    b.handle.pos = b.skel[0];
                });
            }
        }
        self.substep_by(|b| b.place_at(target, &offsets));
        self.end_tick();
    }

    /// The once-per-tick part of the model: plastic flow of the skeleton, the surface, and the
    /// ink the layers give and wick ([`ink`]).
    /// Neither is read by the substep's dynamics except through the skeleton, which moves by
    /// at most D per reference step, so running them at 1 kHz with their rates converted
    /// changes the result by far less than a micrometre and saves 24 of every 25 evaluations.
    pub fn end_tick(&mut self) {
        if self.d.plasticity > S::ZERO {
            self.plastic_flow();
        }
        self.update_surface();
        S::transfer_ink(self);
    }

    /// One substep of length h with the handle at `pose`.
    pub fn substep(&mut self, pose: Pose<S>) {
        let offsets = self.skeleton_offsets();
        self.substep_by(|b| b.place_at(clamp_to_paper(pose), &offsets));
    }

    /// One substep (steps 1-3): `place` puts the handle and the skeleton where the substep
    /// has them, then the dynamics, integration, drag and paper projection.
    #[inline(always)]
    fn substep_by(&mut self, place: impl FnOnce(&mut Self)) {
        let old_ferrule = self.spine[0];
        let old_ferrule_vel = self.vel[0];
        place(self);
        self.dynamics(old_ferrule, old_ferrule_vel);
        self.contact[0] = self.spine[0].z <= self.d.contact_tol;
        self.substeps_done = self.substeps_done.wrapping_add(1);
    }

    /// Puts the handle at `pose` and the skeleton nodes where it places them, recording
    /// their displacement.
    fn place_at(&mut self, pose: Pose<S>, offsets: &Offsets<S>) {
        self.handle = pose;
        let n = self.d.n();
        // The new nodes go into the displacement slots first, then swap in: no copy of the
        // whole skeleton on the 1 kHz path.
        place_skeleton(pose, offsets, &mut self.skel_vel[..n]);
        for (node, vel) in self.skel[..n].iter_mut().zip(&mut self.skel_vel[..n]) {
            let next = *vel;
            *vel = next - *node;
            *node = next;
        }
    }

    /// The substep's dynamics, integration and paper projection (steps 2-3) once the
    /// skeleton is where the substep puts it; the ferrule was at `old_ferrule` moving by
    /// `old_ferrule_vel`. Out of line: [`Self::substep_by`] is inlined where a tick or
    /// [`Self::substep`] moves the skeleton, and one copy of the largest function of the
    /// model is worth more flash than a call costs (one per substep).
    #[inline(never)]
    fn dynamics(&mut self, old_ferrule: Vec3<S>, old_ferrule_vel: Vec3<S>) {
        let n = self.d.n();
        // The ferrule moves rigidly: its displacement this substep is prescribed. The springs
        // and the ties are evaluated where the substep starts (the spine, ferrule included,
        // where it was; the skeleton where it was, `VS - w`), and the prescribed motion
        // enters once, through the implicit terms.
        let u0 = self.skel[0] - old_ferrule;
        // The tie weight of each mass, once: the tie and the paper drag both read it, and both
        // read it before the mass moves.
        let mut ties = [S::ZERO; MAX_LAYERS];
        for (t, x) in ties[1..n].iter_mut().zip(&self.spine[1..n]) {
            *t = tie_weight_at(&self.d, x.z);
        }
        // A build with one step has only it in `integrator`'s range (see
        // `params::DEFAULT_INTEGRATOR`): without the thesis's, backward Euler is taken
        // unconditionally, so the thesis's code is not in the build at all.
        #[cfg(feature = "backward-euler")]
        if cfg!(not(feature = "kang-cho")) || self.d.backward_euler {
            let mut solve = S::Chain::new();
            self.backward_euler(u0, &ties, &mut solve);
            if solve.saturated() {
                // The substep's motion left the fixed-point solve's formats: a pose that
                // jumped (a tracker's glitch, a hostile stream) further in one substep than
                // a hand moves. Nothing physical happened, and no solution is to be had in
                // the format: the brush restarts at rest on its skeleton, its ink kept.
                self.restart_on_skeleton();
                return;
            }
            self.integrate(u0, &ties, S::ZERO, (1..n).map(|i| solve.du(i)));
            return;
        }
        // The ferrule's last displacement is the thesis's step's alone.
        #[cfg(not(feature = "kang-cho"))]
        let _ = old_ferrule_vel;
        #[cfg(feature = "kang-cho")]
        {
            let p = self.kang_cho(u0 - old_ferrule_vel, &ties);
            self.integrate(
                u0,
                &ties,
                self.d.drag_loss,
                p[3..3 * n]
                    .chunks_exact(3)
                    .map(|e| Vec3::new(e[0], e[1], e[2])),
            );
        }
    }

    /// The spine put back on its skeleton at rest, where the substep placed the skeleton, the
    /// layers (their ink) kept: what a substep the fixed-point solve cannot hold leaves.
    /// Counted ([`Self::restarts`]).
    #[cfg(feature = "backward-euler")]
    #[inline(never)]
    fn restart_on_skeleton(&mut self) {
        let n = self.d.n();
        for ((s, u), node) in self.spine[..n]
            .iter_mut()
            .zip(&mut self.vel[..n])
            .zip(&self.skel[..n])
        {
            *s = *node;
            *u = Vec3::ZERO;
        }
        // Its segments are measured again where they are next needed (the step left them
        // unmeasured: `segments_cached` is false).
        self.project_onto_paper();
        self.restarts = self.restarts.wrapping_add(1);
    }

    /// The substep's end, once the velocity change `du` of each free mass (from mass 1 on) is
    /// known: the ferrule moved by `u0`; integration, paper drag and projection (Fig. 4-5), per
    /// mass, with the tie weights `ties`. The thesis's step takes the paper's drag here, as
    /// `drag_loss` (after its solve); backward Euler has it in its system, and gives zero.
    #[inline(always)]
    fn integrate(
        &mut self,
        u0: Vec3<S>,
        ties: &[S; MAX_LAYERS],
        drag_loss: S,
        du: impl Iterator<Item = Vec3<S>>,
    ) {
        let n = self.d.n();
        self.spine[0] = self.skel[0];
        self.vel[0] = u0;
        let tol = self.d.contact_tol;
        for ((((x, u), du), w), touching) in self.spine[1..n]
            .iter_mut()
            .zip(&mut self.vel[1..n])
            .zip(du)
            .zip(&ties[1..n])
            .zip(&mut self.contact[1..n])
        {
            *touching = integrate_mass(x, u, du, *w, drag_loss, tol);
        }
    }

    /// The thesis's step (eqs. 2.19-2.33, Kang & Cho; see the module docs): the velocity
    /// change of each free mass, flattened (mass i at `3i..3i + 3`), given the ferrule's
    /// `du0` and the tie weights.
    #[cfg(feature = "kang-cho")]
    #[inline(always)]
    fn kang_cho(&mut self, du0: Vec3<S>, ties: &[S; MAX_LAYERS]) -> [S; FLAT] {
        let n = self.d.n();
        let d = &self.d;
        // Every row includes the tie (see the module docs), so only two rows occur: the
        // interior masses 1..n-1 share one, the tip has its own.
        let [inner, tip] = d.rows;

        // Spring term of each segment j (between masses j-1 and j), computed once and used with
        // opposite signs by both ends: (1 - L/|d|) d with d = S_j - S_{j-1}. `seg[n]` stays
        // zero: the tip has no outer segment, so its row needs no special case here.
        let mut seg = [Vec3::<S>::ZERO; MAX_LAYERS + 1];
        // Segments 2.. have not moved since the surface update measured them (if it did).
        let first_cached = if self.segments_cached { 2 } else { usize::MAX };
        self.segments_cached = false;
        // Each starts its inverse square root from the segment's last one, which is kept for
        // the next substep.
        for (j, ((f, pair), (len2, r))) in (1..).zip(
            seg[1..n].iter_mut().zip(self.spine[..n].windows(2)).zip(
                self.seg_len2[1..n]
                    .iter_mut()
                    .zip(&mut self.seg_rsqrt[1..n]),
            ),
        ) {
            let v = pair[1] - pair[0];
            if j < first_cached {
                (*len2, *r) = measure_near(v, *r);
            }
            *f = spring_with(d, v, *len2, *r);
        }

        // p is kept flattened (x_0, y_0, z_0, x_1, ...) for the solve, see [`jacobi`].
        let last = n - 1;
        let mut p = [S::ZERO; FLAT];
        // Entry 0 (the ferrule has no row) holds du_0 for the solve.
        p[..3].copy_from_slice(&[du0.x, du0.y, du0.z]);
        // The interior rows share their coefficients (in [0, 1): fractions of the mass's
        // W'): tested once for the whole loop instead of on each product.
        if d.interior_coefs {
            self.interior_rhs(&inner, &seg, ties, &mut p, S::mul_tested_coef);
        } else {
            self.interior_rhs(&inner, &seg, ties, &mut p, S::mul_coef);
        }
        let r = self.row_rhs(
            &tip,
            last,
            -seg[last],
            self.vel[last - 1] - self.vel[last],
            ties[last],
            S::mul_coef,
        ) + self.tip_load.scale_coef(tip.c_f);
        p[3 * last..3 * n].copy_from_slice(&[r.x, r.y, r.z]);

        // Both solves turn p into du in place.
        if d.exact_solve {
            self.solve_exact(&mut p, du0);
        } else {
            jacobi(&mut p, inner.c_j, tip.c_j, n, d.iterations);
        }
        p
    }

    #[cfg(feature = "backward-euler")]
    /// Backward Euler (see the module docs): linearised about the substep's start with each
    /// segment's own Jacobian, the spine's block-tridiagonal system solved exactly by
    /// `solve` (which then holds the velocity change of each free mass), given the
    /// ferrule's displacement `u0` in this substep and the tie weights.
    #[inline(always)]
    fn backward_euler(&mut self, u0: Vec3<S>, ties: &[S; MAX_LAYERS], solve: &mut S::Chain) {
        let n = self.d.n();
        let c = self.d.implicit;
        // Segments 2.. have not moved since the surface update measured them (if it did).
        let first_cached = if self.segments_cached { 2 } else { usize::MAX };
        self.segments_cached = false;
        // Segment j's Jacobian block G_j and its term T_j = c_k f_j + G_j (u_j - u_{j-1}) in
        // the rows of its two masses (+ in row j-1, - in row j), linearised where the substep
        // starts; u_0 is the ferrule's new displacement, so its prescribed motion enters
        // here, once. The chain forms the blocks and terms in its own format
        // ([`Segment`]): the brush hands it each segment's parts, its block's isotropic
        // stiffness `iso` and axial stiffness `axial` along the unit direction `dir`, its
        // spring term c_k f_j, and the relative velocity of its masses.
        let segment = |this: &mut Self, j: usize| -> Segment<S> {
            let j = j.clamp(1, MAX_LAYERS - 1);
            let v = this.spine[j] - this.spine[j - 1];
            if j < first_cached {
                (this.seg_len2[j], this.seg_rsqrt[j]) = measure_near(v, this.seg_rsqrt[j]);
            }
            let rel = this.vel[j] - if j == 1 { u0 } else { this.vel[j - 1] };
            let (len2, r) = (this.seg_len2[j], this.seg_rsqrt[j]);
            if len2 > this.d.tiny2 {
                // The Jacobian k (e I + (1 - e) d d^T), e = 1 - L/|d| the strain, d the unit
                // direction. Compressed (e < 0) the transverse term k e (I - d d^T) is
                // negative (the hairs buckle): left out, so the matrix stays positive
                // definite and the step stable (the force itself keeps it), and the axial
                // stiffness is the compression's. The axial stiffness steps from k c_r to k
                // at the rest length, where a brush at rest sits: blended across a band of
                // +-STIFFNESS_BLEND_STRAIN so that the step is a continuous function of the
                // state, and a rounding of the strain across zero (fixed point against f64)
                // changes it by a rounding, not by the step.
                // The factors in [0, 1] (the stretch, the blend, 1/|d| for a segment over a
                // millimetre) are the coefficients of `mul_coef`: the same products, cheaper
                // in fixed point.
                let strain = S::ONE - this.d.segment.mul_coef(r);
                let stretched = strain.max(S::ZERO);
                let blend = ((strain + c.blend_strain) * c.inv_blend_width).clamp(S::ZERO, S::ONE);
                let axial = c.c_k_compressed + c.c_k_stretch_step.mul_coef(blend);
                // The spring term c_k f_j = c_k (1 - L/|d|) d (`spring_term`'s strain, the
                // compression's ratio applied when compressed), as one scale of d.
                let spring_strain = if strain < S::ZERO {
                    strain.mul_coef(this.d.compression_ratio)
                } else {
                    strain
                };
                Segment {
                    iso: c.c_k.mul_coef(stretched) + c.c_d,
                    axial: axial.mul_coef(S::ONE - stretched),
                    dir: v.scale_coef(r),
                    // c_k times a strain is small (a coefficient) but for a segment
                    // stretched far: `scale_coef` tests it.
                    spring: v.scale_coef(c.c_k.mul_coef(spring_strain)),
                    rel,
                }
            } else {
                // Coincident masses (piled on the paper): no direction, no spring force.
                Segment {
                    iso: c.c_d,
                    rel,
                    ..Segment::BEYOND_TIP
                }
            }
        };
        // One call site for the segments, so that their parts are formed in line: segment
        // j, then row j - 1, whose blocks are the last two segments given.
        for j in 1..=n {
            solve.segment(if j < n {
                segment(self, j)
            } else {
                Segment::BEYOND_TIP
            });
            if j == 1 {
                continue;
            }
            // Row j - 1 (within the arrays: the force path has no panicking index).
            let i = (j - 1).min(MAX_LAYERS - 1);
            let w = ties[i];
            let mut own = Vec3::ZERO;
            let mut diag = S::ONE;
            let mut lift = S::ZERO;
            // The tie in the thesis's form, c_t (VS^t - S) + c_tv (w - u), VS^t the node
            // where the substep started, its coefficients the layer's for its ink: for a
            // mass lying on the paper too (weight zero), for its weight's growth below.
            let (c_t, tv) = c.tie.at(self.layers[i].wetness, S::mul_coef);
            let tie = ((self.skel[i] - self.skel_vel[i]) - self.spine[i]).scale_coef(c_t)
                + (self.skel_vel[i] - self.vel[i]).scale_coef(tv);
            if w >= S::ONE {
                (own, diag) = (tie, diag + tv);
            } else {
                if w > S::ZERO {
                    (own, diag) = (tie.scale_coef(w), diag + tv.mul_coef(w));
                }
                // Near the paper the tie's weight grows with the height, 1 / TIE_RAMP_MM a
                // millimetre, and where the tie pulls the mass down that is a vertical
                // stiffness: taken in the system at the height where the substep ends,
                // w + (u_z + du_z) / ramp, as backward Euler takes every force. Left where
                // the substep starts, a light mass grazing the paper hops: untied on the
                // paper the springs lift it, tied it is pulled back into the paper and
                // untied again, every other substep. Capped where the block's vertical entry
                // would leave the fixed-point chain's bound (far above what a preset's tie
                // reaches); a tie pulling up (the brush leaving the paper) only hastens its
                // own release and stays where the substep starts.
                let pull = tie.z * self.d.inv_tie_ramp;
                if pull < S::ZERO {
                    lift = (S::ZERO - pull).min(c.lift_max);
                    own.z -= self.vel[i].z * lift;
                }
            }
            if i + 1 == n {
                own += self.tip_load.scale(c.c_f);
            }
            // The paper's drag on a mass lying on it (by how much it lies there, `1 - w`),
            // in the paper's plane: implicit like the rest, -c (u + du), so that the drag
            // and the springs it holds back are one step, whatever its length.
            let on_paper = S::ONE - w;
            let mut drag = S::ZERO;
            if on_paper > S::ZERO {
                drag = c.c_drag.mul_coef(on_paper);
                let u = self.vel[i];
                own.x -= u.x.mul_coef(drag);
                own.y -= u.y.mul_coef(drag);
            }
            solve.row(i, diag, drag, lift, own);
        }
        solve.solve(n);
    }

    /// Right-hand side p_i of eq. 2.33 (scaled by h, see the module docs) for mass `i` with tie
    /// weight `w`, the row's coefficients multiplied by `mul` (a coefficient product).
    #[inline(always)]
    fn row_rhs(
        &self,
        row: &Row<S>,
        i: usize,
        spring: Vec3<S>,
        rel: Vec3<S>,
        w: S,
        mul: impl Fn(S, S) -> S + Copy,
    ) -> Vec3<S> {
        let scale = |v: Vec3<S>, c: S| Vec3::new(mul(v.x, c), mul(v.y, c), mul(v.z, c));
        let mut pi = scale(spring, row.c_k) + scale(rel, row.c_j);
        if w > S::ZERO {
            // The skeleton where the substep started (VS^t): its motion in the substep, w,
            // enters through c_tv alone. The coefficients are the layer's for its ink,
            // evaluated here rather than with the weights: only for a tied mass, and with
            // the row's tested products.
            let (c_t, c_tv) = row.tie.at(self.layers[i].wetness, mul);
            let tie = scale((self.skel[i] - self.skel_vel[i]) - self.spine[i], c_t)
                + scale(self.skel_vel[i] - self.vel[i], c_tv);
            // A mass clear of the paper has weight exactly one, and scaling by one is exact in
            // every scalar type: skip those three multiplies. A weight below one is a
            // coefficient.
            pi += if w < S::ONE { tie.scale_coef(w) } else { tie };
        }
        pi
    }

    /// [`Self::row_rhs`] of the interior masses 1..n-1 into `p` (flattened, see [`jacobi`]).
    #[inline(always)]
    fn interior_rhs(
        &self,
        inner: &Row<S>,
        seg: &[Vec3<S>; MAX_LAYERS + 1],
        ties: &[S; MAX_LAYERS],
        p: &mut [S; FLAT],
        mul: impl Fn(S, S) -> S + Copy,
    ) {
        let n = self.d.n();
        for (i, (pi, (v, s))) in p[3..3 * (n - 1)]
            .chunks_exact_mut(3)
            .zip(self.vel[..n].windows(3).zip(seg[1..n].windows(2)))
            .enumerate()
        {
            let ui = v[1];
            let rel = (v[0] - ui) + (v[2] - ui);
            let r = self.row_rhs(inner, i + 1, s[1] - s[0], rel, ties[i + 1], mul);
            pi.copy_from_slice(&[r.x, r.y, r.z]);
        }
    }

    /// Solves eq. 2.30's tridiagonal system `du_i - c_j,i (du_{i-1} + du_{i+1}) = p_i` exactly
    /// (Thomas algorithm; the ferrule's du_0 is known), in place: `p` (flattened, entries
    /// 1..n) becomes `du`. The pivots depend only on which masses lie on the paper... and
    /// since the tie is weighted on the right-hand side, not at all: they are computed once
    /// per parameter change.
    fn solve_exact(&self, p: &mut [S; FLAT], du0: Vec3<S>) {
        let n = self.d.n();
        // The pivots: set by `prepare_pivots` with the parameters (the rows do not depend on
        // contact: the tie is weighted in the right-hand side).
        let c_j = |i: usize| self.d.rows[usize::from(i == n - 1)].c_j;
        let get = |e: &[S]| Vec3::new(e[0], e[1], e[2]);
        let mut prev = Vec3::<S>::ZERO;
        for (i, e) in (1..n).zip(p[3..].chunks_exact_mut(3)) {
            let mut rhs = get(e);
            if i == 1 {
                rhs += du0.scale_coef(c_j(1));
            }
            // d'_i = (d_i - a_i d'_{i-1}) / m_i with a_i = -c_j,i.
            prev = (rhs + prev.scale_coef(c_j(i))).scale(self.inv_pivot[i]);
            e.copy_from_slice(&[prev.x, prev.y, prev.z]);
        }
        // Back substitution: `next` is already du_{i+1} when entry i becomes du_i.
        let mut next = prev;
        for (i, e) in (1..n - 1)
            .rev()
            .zip(p[3..3 * (n - 1)].chunks_exact_mut(3).rev())
        {
            next = get(e) + next.scale_coef(self.cprime[i]);
            e.copy_from_slice(&[next.x, next.y, next.z]);
        }
    }

    /// The exact solve's pivots ([`Self::solve_exact`]): forward elimination of the
    /// coefficients, `cp_i = -c_i / m_i`, `inv_m_i = 1 / m_i` with `m_i = 1 - c_i (-cp_{i-1})`,
    /// written for sub = super = `-c_j,i`. They depend on the parameters only, so they are
    /// computed where the parameters change (fifteen divisions, which would otherwise land
    /// on the next force-loop tick).
    fn prepare_pivots(&mut self) {
        let n = self.d.n();
        let mut prev_cp = S::ZERO;
        for i in 1..n {
            let c = self.d.rows[usize::from(i == n - 1)].c_j;
            let m = S::ONE - c * prev_cp;
            let inv_m = S::ONE.div(m);
            self.inv_pivot[i] = inv_m;
            prev_cp = if i + 1 < n { c * inv_m } else { S::ZERO };
            self.cprime[i] = prev_cp;
        }
    }

    /// Measures every spine segment for the next substep's springs and the surface
    /// ([`Self::seg_len2`]): squared length, and its `rsqrt` when positive (both users test
    /// their own threshold on the same numbers, so they get exactly what they would compute).
    fn measure_segments(&mut self) {
        for i in 1..self.d.n() {
            (self.seg_len2[i], self.seg_rsqrt[i]) = measure(self.spine[i] - self.spine[i - 1]);
        }
        self.segments_cached = true;
    }

    fn project_onto_paper(&mut self) {
        let tol = self.d.contact_tol;
        for i in 1..self.d.n() {
            let s = &mut self.spine[i];
            let u = &mut self.vel[i];
            if s.z < S::ZERO {
                s.z = S::ZERO;
                if u.z < S::ZERO {
                    u.z = S::ZERO;
                }
            }
            self.contact[i] = s.z <= tol;
        }
        self.contact[0] = self.spine[0].z <= tol;
    }

    /// The skeleton nodes relative to VS_0 in the handle frame, `sum_{j<i} V_j L` (eq. 3-6
    /// unrolled), one array per component. They change only when the directions do (plastic
    /// flow, once per tick), so a tick sums them once and each substep only rotates and
    /// translates them: node i then costs one rotation, not a rotation and a serial chain of
    /// sums, and the nodes are independent of each other.
    fn skeleton_offsets(&self) -> Offsets<S> {
        let n = self.d.n();
        let mut out = [[S::ZERO; MAX_LAYERS]; 3];
        let [ox, oy, oz] = &mut out;
        let mut acc = Vec3::ZERO;
        for (((x, y), z), dir) in ox[1..n]
            .iter_mut()
            .zip(&mut oy[1..n])
            .zip(&mut oz[1..n])
            .zip(&self.skel_dir[..n - 1])
        {
            // A unit direction's components are the coefficients (the same products).
            let seg = self.d.segment;
            acc += Vec3::new(
                seg.mul_coef(dir.x),
                seg.mul_coef(dir.y),
                seg.mul_coef(dir.z),
            );
            (*x, *y, *z) = (acc.x, acc.y, acc.z);
        }
        out
    }

    /// Bends the skeleton toward the spine's tip direction (eqs. 3-1..3-4).
    fn plastic_flow(&mut self) {
        let n = self.d.n();
        let tip = self.spine[n - 1] - self.spine[n - 2];
        let Some(goal) = tip.normalized_or_none(self.d.tiny) else {
            return;
        };
        let goal_local = self.handle.rot.rotate_inv(goal);
        let dd = self.d.plasticity;
        // Interpolation weights in [0, 1]: coefficient products (the same values).
        let end = self.skel_dir[n - 2].scale_coef(S::ONE - dd) + goal_local.scale_coef(dd);
        let Some(end) = end.normalized_or_none(self.d.tiny) else {
            return;
        };
        self.skel_dir[n - 2] = end;
        let first = self.skel_dir[0];
        for i in 1..n - 2 {
            let w = self.d.skel_weight[i];
            let v = first.scale_coef(S::ONE - w) + end.scale_coef(w);
            if let Some(v) = v.normalized_or_none(self.d.tiny) {
                self.skel_dir[i] = v;
            }
        }
    }

    /// Surface ellipses (eqs. 3-7..3-20).
    fn update_surface(&mut self) {
        let n = self.d.n();
        let normal = Vec3::<S>::Z;
        // The handle's x, y and -z axes are columns of its rotation matrix: one matrix for
        // the three, instead of three quaternion rotations of basis vectors.
        let m = RotMat::from_quat(self.handle.rot).m;
        let sa0 = Vec3::new(m[0][0], m[1][0], m[2][0]);
        let down = -Vec3::new(m[0][2], m[1][2], m[2][2]);
        self.layers[0].short_axis = sa0;
        self.layers[0].long_axis = Vec3::new(m[0][1], m[1][1], m[2][1]);

        // Step 1: short axes. First layer lying on the paper, if any. The layers from there
        // on have the paper's normal for their short axis; those above it interpolate
        // between the handle's short axis and the paper's normal (by i / c) or, with no
        // layer on the paper, the tip layer's short axis of the last tick (by i / (N - 1)).
        // Each is formed where the layer's axes are, below, in the surface's unit form.
        let first_contact = (1..n).find(|&i| self.contact[i]);
        let on_paper_from = first_contact.unwrap_or(n);
        // c < n: the entry exists (`get` only spares the force path a panic).
        let inv_c = first_contact.map(|c| self.d.inv_count.get(c).copied().unwrap_or(S::ONE));
        let sa0_unit = S::unit(sa0);
        let end_unit = S::unit(self.layers[n - 1].short_axis);
        let short_axis = |i: usize| match inv_c {
            // i < c: the weight is below one, and 1/c too unless c is one.
            Some(inv_c) => S::toward_normal(sa0_unit, S::from_usize(i).mul_coef(inv_c)),
            None if i + 1 < n => S::lerp_unit(sa0_unit, end_unit, self.d.layer_frac[i]),
            None => end_unit,
        };

        // Steps 2-3: long axes from the cross product, both normalised; Step 4: bends.
        // A segment shorter than `tiny` has no direction (`Vec3::normalized_or_none`'s test).
        let min_len2 = self.d.tiny * self.d.tiny;
        // Each layer's tilt (step 5) is 1 - cos of the angle between its segment and the
        // next: summed here as each segment follows the last, so no array of segments (the
        // pen would pay for zeroing that array in every tick).
        let mut tilt = [S::ZERO; MAX_LAYERS];
        let mut tilt_sum = S::ZERO;
        let mut prev_dir = S::unit(Vec3::ZERO);
        // |sa x v| below sin(0.5 deg) * |sa|: the ellipse plane is undefined (see below).
        let min_cross = self.d.tiny;
        for i in 1..n {
            let v = self.spine[i] - self.spine[i - 1];
            // Kept for the next substep's springs too (as `measure_segments` does, inline
            // here so the loop reads each segment once).
            let (len2, r) = measure(v);
            (self.seg_len2[i], self.seg_rsqrt[i]) = (len2, r);
            // Coincident masses (piled on the paper) have no direction: use the handle's.
            let unit = if len2 > min_len2 {
                S::direction(v, len2, r)
            } else {
                S::unit(down)
            };
            if i >= 2 {
                tilt[i - 1] = S::one_minus_dot(unit, prev_dir);
                tilt_sum += tilt[i - 1];
            }
            prev_dir = unit;
            // The short axis is the paper's normal from the first layer on it (step 1).
            let sa = (i < on_paper_from).then(|| short_axis(i));
            let layer = &mut self.layers[i];
            match S::ellipse_axes(sa, unit, min_cross) {
                Some((la, sa)) => {
                    layer.long_axis = la;
                    // V x LA: the short axis made perpendicular to the segment, so the
                    // ellipse is a true cross-section (unit: V and LA are unit and orthogonal).
                    layer.short_axis = sa;
                }
                // The ellipse plane undefined: keep the old long axis, made perpendicular to
                // the segment, and rebuild the short one.
                None => {
                    layer.short_axis = sa.map_or(normal, S::from_unit);
                    let dir = S::from_unit(unit);
                    let old = layer.long_axis;
                    let la = old - dir.scale(old.dot(dir));
                    if let Some(la) = la.normalized_or_none(self.d.tiny) {
                        layer.long_axis = la;
                        if let Some(sa) = dir.cross(la).normalized_or_none(self.d.tiny) {
                            layer.short_axis = sa;
                        }
                    }
                }
            }
        }
        tilt[n - 1] = tilt[n - 2];
        self.segments_cached = true;
        let tilt_all = if n > 2 {
            // 1 / (N - 2) is below one for N > 3 (a coefficient), one for N = 3.
            tilt_sum.mul_coef(self.d.inv_count[n - 2])
        } else {
            S::ZERO
        };

        // Steps 5-6: target and relaxed radii, area preserved (eqs. 3-17..3-20).
        // The relaxation `goal rate + RL (1 - rate)` is taken as `RL + (goal - RL) rate`, and
        // the contact goal's spread is `RL + (max - RL) (1 - W) (i / (N - 1)) bend`: the rate
        // joins the layer's fraction in `spread_weight` (once per parameter change), one
        // product a layer instead of three. The bend, `tf tilt + tilt_all (1 - tilt)`, is
        // `tilt_all + (tf - tilt_all) tilt`: one product.
        let any_contact = first_contact.is_some();
        let rate = self.d.spread_rate;
        let bend_slope = self.d.spread_tf - tilt_all;
        for i in 1..n {
            let rest = self.d.rest_radius[i];
            let max = self.d.max_radius[i];
            let layer = &mut self.layers[i];
            let rl = layer.long_radius;
            // The factors in [0, 1] (tilts, dryness, weights, rates) are the coefficients of
            // `mul_coef`: the same products, cheaper in fixed point.
            let step = if any_contact {
                let bend = tilt_all + bend_slope.mul_coef(tilt[i]);
                (max - rl)
                    .mul_coef(S::ONE - layer.wetness)
                    .mul_coef(self.d.spread_weight[i])
                    .mul_coef(bend)
            } else {
                (rest - rl).mul_coef(rate)
            };
            let rl = (rl + step).clamp(rest, max);
            layer.long_radius = rl;
            // Not a 64-bit division, which the Cortex-M4 does in software.
            layer.short_radius = S::short_radius(self.d.rest_area[i], rl);
        }
    }
}

/// Ink in the brush (the model in [`ink`]): the dip, the loads, and the tick's transfer.
impl<S: Scalar> Brush<S> {
    /// Fills every layer to `load` of what it holds (clamped to [0, 1]): dipping the brush.
    pub fn dip(&mut self, load: S) {
        let w = load.clamp(S::ZERO, S::ONE);
        let n = self.d.n();
        for l in self.layers[..n].iter_mut() {
            l.wetness = w;
        }
    }

    /// Ink held by the whole brush (ink units).
    pub fn ink_load(&self) -> S {
        (0..self.d.n()).fold(S::ZERO, |a, i| a + self.ink_held(i))
    }

    /// Ink layer i holds (ink units).
    pub fn ink_held(&self, i: usize) -> S {
        self.layers
            .get(i)
            .map_or(S::ZERO, |l| l.wetness * self.ink_capacity(i))
    }

    /// What layer i holds when saturated (ink units).
    pub fn ink_capacity(&self, i: usize) -> S {
        match self.ink_coefs.inv_capacity.get(i) {
            Some(&inv) if inv > 0.0 => S::from_f32(1.0 / inv),
            _ => S::ZERO,
        }
    }

    /// The tick's ink transfer ([`ink::transfer`]): deposits and wicking. Runs after the
    /// surface update, whose radii and axes it reads.
    #[inline(always)]
    pub(crate) fn transfer_ink(&mut self) {
        let n = self.d.n();
        ink::transfer(
            &mut self.layers[..n],
            &self.spine[..n],
            &self.vel[..n],
            &self.d.max_radius[..n],
            &self.ink_coefs,
            &mut self.ink_phase,
        );
    }
}

/// [`Brush::transfer_ink`] for the pen's format, compiled in this crate: not generic,
/// it is built with this crate's code generation (in the firmware, for size) rather than the
/// hot path's (`firmware/fast`, for speed), where its fixed-point products, inlined, would
/// cost the Black Pill's flash more than it has; out of line, they cost a call each.
#[inline(never)]
pub(crate) fn transfer_ink_fx(brush: &mut Brush<Fx>) {
    brush.transfer_ink();
}

/// Skeleton node offsets in the handle frame, per component ([`Brush::skeleton_offsets`]).
type Offsets<S> = [[S; MAX_LAYERS]; 3];

/// Entries of a flattened [`Vec3`] array: `x_0, y_0, z_0, x_1, ...`.
const FLAT: usize = 3 * MAX_LAYERS;

/// `iterations` Jacobi sweeps of eq. 2.33, `du_i <- p_i + c_j,i (du_{i-1} + du_{i+1})`, from
/// `du = p`, with the ferrule's prescribed `du_0` and `du_n = 0` beyond the tip, in place: `p`
/// becomes `du`. `p` is a flattened [`Vec3`] array (x_0, y_0, z_0, x_1, ...); its entry 0
/// holds `du_0`, which the sweeps read as mass 1's inner neighbour.
///
/// The sweeps run over the three components as one flat array: an interior row multiplies
/// all three components of both neighbours by the same `c_j`, so component k of mass i reads
/// entries `3i + k - 3` and `3i + k + 3`, one stride for the whole chain. That loop has no
/// per-mass branch or struct shuffling, and for the float types it vectorises. Each entry is
/// computed with the same operations in the same order as per [`Vec3`], so the results are
/// the same bits.
fn jacobi<S: Scalar>(p: &mut [S; FLAT], c: S, c_tip: S, n: usize, iterations: usize) {
    // The two coefficients are the same for every sweep: tested once (the presets' are in
    // (-1, 1)), not on each of the sweeps' products; the same values either way. One copy of
    // the sweeps, the product chosen at run time: the thesis's sweeps run only at several
    // substeps per tick, which the pen's tick cannot afford, and its flash is short.
    let mul: fn(S, S) -> S = if c.is_coef() && c_tip.is_coef() {
        S::mul_tested_coef
    } else {
        S::mul_coef
    };
    jacobi_with(p, c, c_tip, n, iterations, mul);
}

/// [`jacobi`] with the product by a coefficient `mul`.
#[inline(always)]
fn jacobi_with<S: Scalar>(
    p: &mut [S; FLAT],
    c: S,
    c_tip: S,
    n: usize,
    iterations: usize,
    mul: impl Fn(S, S) -> S + Copy,
) {
    // Components of the interior masses 1..n-1 (from LO), and of the tip. `n` clamped as
    // `Derived::n` does, so that the compiler sees every range below within FLAT and leaves
    // out the panicking checks.
    const LO: usize = 3;
    let tip = (3 * n.max(1) - 3).clamp(LO, FLAT - 3);
    // A sweep from `src` into `dst`, which starts as p's entries (`dst_e = p_e + product`).
    let sweep = |src: &[S; FLAT], p: &[S; FLAT], dst: &mut [S; FLAT]| {
        // Clamped again inside (compiled on its own, a closure sees only the captured value).
        let tip = tip.clamp(LO, FLAT - 3);
        for (((o, pk), left), right) in dst[LO..tip]
            .iter_mut()
            .zip(&p[LO..tip])
            .zip(&src[LO - 3..tip - 3])
            .zip(&src[LO + 3..tip + 3])
        {
            *o = *pk + mul(*left + *right, c);
        }
        for ((o, pk), left) in dst[tip..tip + 3]
            .iter_mut()
            .zip(&p[tip..tip + 3])
            .zip(&src[tip - 3..tip])
        {
            *o = *pk + mul(*left, c_tip);
        }
    };
    // The last sweep, into p itself: each entry reads its own p_e just before it is
    // replaced, and its neighbours from `src`.
    let last_sweep = |src: &[S; FLAT], p: &mut [S; FLAT]| {
        let tip = tip.clamp(LO, FLAT - 3);
        for ((o, left), right) in p[LO..tip]
            .iter_mut()
            .zip(&src[LO - 3..tip - 3])
            .zip(&src[LO + 3..tip + 3])
        {
            *o += mul(*left + *right, c);
        }
        for (o, left) in p[tip..tip + 3].iter_mut().zip(&src[tip - 3..tip]) {
            *o += mul(*left, c_tip);
        }
    };
    if iterations == 0 {
        // (Not a valid parameter; kept total.) No sweep: du = p.
        return;
    }
    // The first sweep reads p itself (du starts at p), the middle ones alternate between two
    // buffers, the last writes p: nothing is copied. Entries 0..3 (the ferrule's du_0) are
    // p's in every buffer.
    let (mut a, mut b) = ([S::ZERO; FLAT], [S::ZERO; FLAT]);
    a[..3].copy_from_slice(&p[..3]);
    b[..3].copy_from_slice(&p[..3]);
    let (mut src, mut dst) = (&mut a, &mut b);
    sweep(p, p, src);
    for _ in 2..iterations {
        sweep(src, p, dst);
        core::mem::swap(&mut src, &mut dst);
    }
    if iterations == 1 {
        *p = *src;
    } else {
        last_sweep(src, p);
    }
}

/// Where the handle at `pose` places the skeleton nodes VS_i (eqs. 3-5, 3-6), from the node
/// offsets ([`Brush::skeleton_offsets`]), into `out` (one per node).
fn place_skeleton<S: BrushScalar>(pose: Pose<S>, offsets: &Offsets<S>, out: &mut [Vec3<S>]) {
    let m = RotMat::from_quat(pose.rot).m;
    if S::place_nodes(pose.pos, offsets, &m, out) {
        return;
    }
    // A rotation's entries are in [-1, 1]: coefficient products (the same values), the
    // nine entries tested once for all nodes rather than on each product.
    if m.iter().flatten().all(|c| c.is_coef()) {
        place_nodes(pose.pos, offsets, &m, out, S::mul_tested_coef);
    } else {
        place_nodes(pose.pos, offsets, &m, out, S::mul_coef);
    }
}

/// The skeleton nodes `pos + m offset_i` into `out` (node 0 is the handle itself: offset
/// zero), products by the rotation's entries by `mul`.
#[inline(always)]
fn place_nodes<S: Scalar>(
    pos: Vec3<S>,
    offsets: &Offsets<S>,
    m: &[[S; 3]; 3],
    out: &mut [Vec3<S>],
    mul: impl Fn(S, S) -> S,
) {
    let [ox, oy, oz] = offsets;
    for (node, ((&x, &y), &z)) in out.iter_mut().zip(ox.iter().zip(oy).zip(oz)) {
        *node = Vec3::new(
            pos.x + (mul(x, m[0][0]) + mul(y, m[0][1]) + mul(z, m[0][2])),
            pos.y + (mul(x, m[1][0]) + mul(y, m[1][1]) + mul(z, m[1][2])),
            pos.z + (mul(x, m[2][0]) + mul(y, m[2][1]) + mul(z, m[2][2])),
        );
    }
}

/// How strongly a mass at height `z` is tied to the skeleton (see [`Brush::tie_weight`]).
#[inline]
fn tie_weight_at<S: Scalar>(d: &Derived<S>, z: S) -> S {
    // Twice the ramp up, z / ramp is at least 2 whatever the rounding: weight one, without
    // the multiply (most masses are in the air).
    if z >= d.tie_clear {
        S::ONE
    } else {
        (z * d.inv_tie_ramp).clamp(S::ZERO, S::ONE)
    }
}

/// One mass's integration, paper drag and projection (Fig. 4-5): velocity `u` plus its
/// change `du`, dragged in proportion to how much the mass lies on the paper (tie weight
/// `w`), added to the position `x`; whether the mass then touches the paper (z at most
/// `tol`).
#[inline(always)]
pub(crate) fn integrate_mass<S: Scalar>(
    x: &mut Vec3<S>,
    u: &mut Vec3<S>,
    du: Vec3<S>,
    w: S,
    drag_loss: S,
    tol: S,
) -> bool {
    let mut v = *u + du;
    // Drag in proportion to how much the mass is lying on the paper.
    let on_paper = S::ONE - w;
    if on_paper > S::ZERO && drag_loss > S::ZERO {
        // drag_loss and on_paper are in [0, 1], so keep is too.
        let keep = S::ONE - on_paper.mul_coef(drag_loss);
        v.x = v.x.mul_coef(keep);
        v.y = v.y.mul_coef(keep);
    }
    let mut s = *x + v;
    // A mass below the paper is put back onto it with its downward velocity removed.
    if s.z < S::ZERO {
        s.z = S::ZERO;
        if v.z < S::ZERO {
            v.z = S::ZERO;
        }
    }
    *u = v;
    *x = s;
    s.z <= tol
}

/// A segment's squared length and, when positive, its `rsqrt` (else zero): see
/// [`Brush::measure_segments`].
#[inline]
pub(crate) fn measure<S: Scalar>(v: Vec3<S>) -> (S, S) {
    let len2 = squared_length(v);
    let r = if len2 > S::ZERO {
        len2.rsqrt()
    } else {
        S::ZERO
    };
    (len2, r)
}

/// A segment's squared length: [`Vec3::norm2`]'s sum (the same bits), written out for the
/// surface's measurements so that each square is compiled as one (its two cross terms are
/// one product, its range test one word) rather than as a call to the general dot product
/// (in [`measure_near`], on the substep's path, it measured no cheaper).
#[inline(always)]
fn squared_length<S: Scalar>(v: Vec3<S>) -> S {
    v.x * v.x + v.y * v.y + v.z * v.z
}

/// [`measure`] with the segment's last `rsqrt` as the guess for [`Scalar::rsqrt_near`].
#[inline]
pub(crate) fn measure_near<S: Scalar>(v: Vec3<S>, last: S) -> (S, S) {
    let len2 = v.norm2();
    let r = if len2 > S::ZERO {
        len2.rsqrt_near(last)
    } else {
        S::ZERO
    };
    (len2, r)
}

/// `c`-free spring term `(1 - L/|d|) d` for a neighbour offset `d` (mm), given `len2 =
/// |d|^2` and, if `len2 > tiny2`, `inv_len = len2.rsqrt()`.
#[inline]
fn spring_with<S: Scalar>(dv: &Derived<S>, d: Vec3<S>, len2: S, inv_len: S) -> Vec3<S> {
    spring_term(
        d,
        len2,
        inv_len,
        (dv.segment, dv.compression_ratio, dv.tiny2),
    )
}

/// [`spring_with`] with the rest length, compression ratio and `tiny2` given.
#[inline]
pub(crate) fn spring_term<S: Scalar>(
    d: Vec3<S>,
    len2: S,
    inv_len: S,
    (segment, compression_ratio, tiny2): (S, S, S),
) -> Vec3<S> {
    if len2 > tiny2 {
        // 1/|d| is below one for segments longer than 1 mm: the coefficient.
        let strain = S::ONE - segment.mul_coef(inv_len);
        // Negative strain: the segment is compressed and the hairs buckle.
        // A compression ratio is in [0, 1], and so is a stretched segment's strain.
        let strain = if strain < S::ZERO {
            strain.mul_coef(compression_ratio)
        } else {
            strain
        };
        d.scale_coef(strain)
    } else {
        // Coincident masses (piled on the paper): no defined direction, no force.
        Vec3::ZERO
    }
}

/// The ferrule cannot enter the paper (the god-object of Liang 4.2.3 keeps the drawn brush on
/// the surface; the force model sees the hand's real penetration).
fn clamp_to_paper<S: Scalar>(mut pose: Pose<S>) -> Pose<S> {
    if pose.pos.z < S::ZERO {
        pose.pos.z = S::ZERO;
    }
    pose
}

/// A rotation matrix from a unit quaternion: 9 multiplies per rotated vector instead of 18.
struct RotMat<S> {
    m: [[S; 3]; 3],
}

impl<S: Scalar> RotMat<S> {
    fn from_quat(q: Quat<S>) -> Self {
        // 2a as a + a: the same value in every scalar type (saturating alike), no multiply.
        let two = |a: S| a + a;
        let (w, x, y, z) = (q.w, q.x, q.y, q.z);
        // A unit quaternion's components are in [-1, 1]: coefficient products.
        let (xx, yy, zz) = (x.mul_coef(x), y.mul_coef(y), z.mul_coef(z));
        let (xy, xz, yz) = (x.mul_coef(y), x.mul_coef(z), y.mul_coef(z));
        let (wx, wy, wz) = (w.mul_coef(x), w.mul_coef(y), w.mul_coef(z));
        RotMat {
            m: [
                [S::ONE - two(yy + zz), two(xy - wz), two(xz + wy)],
                [two(xy + wz), S::ONE - two(xx + zz), two(yz - wx)],
                [two(xz - wy), two(yz + wx), S::ONE - two(xx + yy)],
            ],
        }
    }
}

/// `1 - (1 - rate)^(reference / actual)`: a per-step rate stated at 25 kHz, at another rate,
/// as `-expm1(steps ln(1 - rate))` so that a small rate keeps its significant bits (`1 -
/// rate` in single precision would round a rate of 1e-4 by 0.06%).
fn per_substep_rate(rate: f32, substep_hz: f32) -> f32 {
    if rate <= 0.0 {
        return 0.0;
    }
    if rate >= 1.0 {
        return 1.0;
    }
    let steps = REFERENCE_SUBSTEP_HZ as f32 / substep_hz;
    -libm::expm1f(steps * libm::log1pf(-rate))
}

/// The per-substep coefficients, in single precision like the parameters they come from
/// (see [`BrushParams::substep_s`]): the pen derives them with its FPU's hardware operations
/// on every parameter change, and they are the same bits on the host. Single precision's
/// relative 6e-8 is far below anything physical in a stiffness or a mass.
fn derive<S: Scalar>(p: &BrushParams) -> Derived<S> {
    // Validated to 3..=MAX_LAYERS; clamped as `Derived::n` reads it.
    let n = (p.layers as usize).clamp(2, MAX_LAYERS);
    let h = p.substep_s();
    let m = p.mass_g * 1e-3 / (n as f32 - 1.0);
    let (ks, kd) = (p.axial_stiffness, p.axial_damping);
    let (kt, kdt) = (p.tie_stiffness, p.tie_damping);
    // The tie's change from a dry to a saturated layer ([`ink`]'s law), per unit wetness.
    let (kt_ink, kdt_ink) = ink::tie_change(p);
    // Each row's Jacobi coefficient, c_j, as computed: the largest picks the solve.
    let mut worst_c_j = 0.0f32;
    // Every row includes the dry tie (see the module docs): the ink's change to it, like
    // the tie's weight, enters the right-hand side only.
    let mut row = |neighbours: f32| {
        let w = m + h * h * (neighbours * ks + kt) + h * (neighbours * kd + kdt);
        let c_k = h * h * ks / w;
        let c_d = h * kd / w;
        let c_t = h * h * kt / w;
        let c_dt = h * kdt / w;
        let c_t_ink = h * h * kt_ink / w;
        let c_j = c_k + c_d;
        worst_c_j = worst_c_j.max(c_j);
        Row {
            c_k: S::from_f32(c_k),
            c_j: S::from_f32(c_j),
            tie: Tie {
                c_t: S::from_f32(c_t),
                c_tv: S::from_f32(c_t + c_dt),
                c_t_ink: S::from_f32(c_t_ink),
                c_tv_ink: S::from_f32(c_t_ink + h * kdt_ink / w),
            },
            c_f: S::from_f32(h * h * 1e3 / w),
        }
    };
    let mut rest_radius = [S::ZERO; MAX_LAYERS];
    let mut rest_area = [S::ZERO; MAX_LAYERS];
    let mut max_radius = [S::ZERO; MAX_LAYERS];
    let mut skel_weight = [S::ZERO; MAX_LAYERS];
    let mut layer_frac = [S::ZERO; MAX_LAYERS];
    let mut inv_count = [S::ZERO; MAX_LAYERS];
    let mut spread_weight = [S::ZERO; MAX_LAYERS];
    let spread_rate = S::from_f32(per_substep_rate(p.spread_rate, TICK_HZ as f32));
    for i in 0..n {
        let r = p.rest_radius_mm(i);
        rest_radius[i] = S::from_f32(r);
        rest_area[i] = rest_radius[i] * rest_radius[i];
        max_radius[i] = S::from_f32(r * p.spread_max);
        skel_weight[i] = S::from_f32(if n > 2 {
            i as f32 / (n as f32 - 2.0)
        } else {
            0.0
        });
        layer_frac[i] = S::from_f32(i as f32 / (n as f32 - 1.0));
        spread_weight[i] = spread_rate.mul_coef(layer_frac[i]);
        if i > 0 {
            inv_count[i] = S::ONE.div(S::from_usize(i));
        }
    }
    let rows = [row(2.0), row(1.0)];
    // The interior rows' coefficients, tested once here for the substeps' products. A
    // layer's tie coefficients lie between the dry's and the saturated's: c_tv's ends are
    // tested, c_t's saturated end lies between zero and its dry one (the stiffness factor
    // is a tenth to one).
    let [inner, _] = rows;
    let t = inner.tie;
    let interior_coefs = [
        inner.c_k,
        inner.c_j,
        t.c_t,
        t.c_tv,
        t.c_t_ink,
        t.c_tv_ink,
        t.c_tv + t.c_tv_ink,
    ]
    .iter()
    .all(|c| c.is_coef());
    #[cfg(feature = "backward-euler")]
    let implicit = Implicit {
        c_k: S::from_f32(h * h * ks / m),
        c_k_compressed: S::from_f32(h * h * ks * p.compression_ratio / m),
        c_k_stretch_step: S::from_f32(h * h * ks * (1.0 - p.compression_ratio) / m),
        blend_strain: S::from_f32(STIFFNESS_BLEND_STRAIN as f32),
        inv_blend_width: S::from_f32((0.5 / STIFFNESS_BLEND_STRAIN) as f32),
        c_d: S::from_f32(h * kd / m),
        tie: Tie {
            c_t: S::from_f32(h * h * kt / m),
            c_tv: S::from_f32((h * h * kt + h * kdt) / m),
            c_t_ink: S::from_f32(h * h * kt_ink / m),
            c_tv_ink: S::from_f32((h * h * kt_ink + h * kdt_ink) / m),
        },
        c_f: S::from_f32(h * h * 1e3 / m),
        c_drag: S::from_f32(h * p.paper_drag / m),
        lift_max: S::from_f32(
            (MAX_DIAGONAL - (p.backward_euler_diagonal_bound() - h * p.paper_drag / m)).max(0.0),
        ),
    };
    Derived {
        #[cfg(feature = "backward-euler")]
        backward_euler: p.integrator == INTEGRATOR_BACKWARD_EULER,
        exact_solve: worst_c_j as f64 > JACOBI_LIMIT,
        interior_coefs,
        #[cfg(feature = "backward-euler")]
        implicit,
        layers: n,
        k: p.ring_nodes as usize,
        iterations: p.jacobi_iterations as usize,
        substeps: p.substeps_per_tick as usize,
        rows,
        drag_loss: S::from_f32(1.0 - 1.0 / (1.0 + h * p.paper_drag / m)),
        segment: S::from_f32(p.segment_mm()),
        compression_ratio: S::from_f32(p.compression_ratio),
        plasticity: S::from_f32(per_substep_rate(p.plasticity, TICK_HZ as f32)),
        spread_rate,
        spread_tf: S::from_f32(p.spread_tf),
        rest_radius,
        rest_area,
        max_radius,
        skel_weight,
        layer_frac,
        inv_count,
        spread_weight,
        contact_tol: S::from_f32(CONTACT_TOLERANCE_MM as f32),
        inv_tie_ramp: S::from_f32((1.0 / TIE_RAMP_MM) as f32),
        tie_clear: S::from_f32((2.0 * TIE_RAMP_MM) as f32),
        inv_substeps: S::from_f32(1.0 / p.substeps_per_tick as f32),
        tiny: S::from_f32(1e-6),
        tiny2: S::from_f32(1e-12),
    }
}

/// Rate conversion is exposed for tests and documentation.
pub fn rate_at(rate_at_25khz: f32, substep_hz: f32) -> f32 {
    per_substep_rate(rate_at_25khz, substep_hz)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rates_convert_between_substep_rates() {
        // Within a few units of single precision's last place (6e-8 relative).
        let close = |a: f32, b: f64| (a as f64 - b).abs() < 2e-7 * b;
        assert!(close(rate_at(0.01, 25_000.0), 0.01));
        // Half the rate: two reference steps per substep.
        assert!(close(rate_at(0.01, 12_500.0), 1.0 - 0.99f64 * 0.99));
        // A small rate keeps its significant bits; 1 kHz is 25 reference steps.
        assert!(close(
            rate_at(1e-5, 1_000.0),
            1.0 - (1.0 - 1e-5f64).powi(25)
        ));
        assert_eq!(rate_at(0.0, 1_000.0), 0.0);
        assert_eq!(rate_at(1.0, 1_000.0), 1.0);
    }

    /// Tick k of a stroke tilted 15 degrees: pressed down over 100 ticks, drawn along x,
    /// lifted from tick 250.
    fn pressed_stroke<S: Scalar>(k: u32) -> Pose<S> {
        let z = if k < 100 {
            44.0 - 0.12 * k as f64
        } else {
            32.0
        };
        let x = if k < 100 { 0.0 } else { 0.2 * (k - 100) as f64 };
        let z = if k > 250 {
            z + 0.1 * (k - 250) as f64
        } else {
            z
        };
        Pose::new(
            Vec3::<S>::from_f64([x, 0.0, z]),
            Quat::from_f64([0.991_444_861_373_810_4, 0.0, 0.130_526_192_220_051_6, 0.0]),
        )
    }

    /// The fixed-point brush solves its chain in 32 bits and stays within a micrometre of
    /// the `f64` brush over a pressed, dragged and lifted stroke. A brush too stiff for the
    /// chain's formats at its substep rate is refused in fixed point (it runs in `f64`, and
    /// in fixed point at a substep rate where it fits).
    #[cfg(feature = "backward-euler")]
    #[test]
    fn the_fixed_point_brush_runs_what_its_chain_holds() {
        use crate::presets::{LARGE, SMALL};
        // Without the ink's law in the ties (`ink`): this brush, pressed, leaves layers
        // where the ink's deposit starts (a step, `ink::PRESS_FLOOR`), and the rounding
        // that puts a layer on the other side of it in one format but not the other gives
        // the two different wetness, which the ties turn into tens of micrometres; the
        // solve, which this tests, is the same either way.
        let stiff = BrushParams {
            axial_stiffness: LARGE.axial_stiffness * 20.0,
            tie_stiffness_wet_pct: 100,
            tie_damping_wet_pct: 100,
            ..LARGE
        };
        assert!(stiff.backward_euler_diagonal_bound() >= MAX_DIAGONAL);
        let refused = |r: Result<(), ParamError>| {
            matches!(
                r,
                Err(ParamError::Inconsistent {
                    param: ParamId::SubstepsPerTick,
                    ..
                })
            )
        };
        assert!(refused(
            Brush::<Fx>::new(stiff, pressed_stroke(0)).map(|_| ())
        ));
        assert!(Brush::<f64>::new(stiff, pressed_stroke(0)).is_ok());
        let mut b = Brush::<Fx>::new(LARGE, pressed_stroke(0)).unwrap();
        assert!(refused(b.set_params(stiff)));
        assert_eq!(b.params(), &LARGE, "a refused brush changes nothing");
        let finer = (2..=100)
            .map(|s| BrushParams {
                substeps_per_tick: s,
                ..stiff
            })
            .find(|p| p.backward_euler_diagonal_bound() < MAX_DIAGONAL)
            .unwrap();
        for params in [LARGE, SMALL, finer] {
            let mut fixed = Brush::<Fx>::new(params, pressed_stroke(0)).unwrap();
            let mut float = Brush::<f64>::new(params, pressed_stroke(0)).unwrap();
            let mut worst = 0.0f64;
            for k in 1..400 {
                fixed.tick(pressed_stroke(k));
                float.tick(pressed_stroke(k));
                for (a, b) in fixed.spine().iter().zip(float.spine()) {
                    let (a, b) = (a.to_f64(), b.to_f64());
                    for c in 0..3 {
                        worst = worst.max((a[c] - b[c]).abs());
                    }
                }
            }
            assert_eq!(fixed.restarts(), 0);
            assert!(
                worst < 1e-3,
                "{} substeps: {worst} mm from f64",
                params.substeps_per_tick
            );
        }
    }

    /// A pose that jumps (the hand's first reading far from where the brush was made, a
    /// tracker's glitch) moves the brush further in one substep than the 32-bit solve's
    /// vectors hold: that substep restarts the fixed-point brush at rest on its skeleton,
    /// counted, and the stroke goes on from there as for a brush made at rest where the jump
    /// put it, with no other restart and no mass below the paper. The `f64` brush solves
    /// the jump.
    #[cfg(feature = "backward-euler")]
    #[test]
    fn a_jump_beyond_the_fixed_point_range_restarts_the_brush_at_rest() {
        let at = |k: u32, jump: [f64; 3]| -> [f64; 3] {
            let p = pressed_stroke::<f64>(k).pos;
            [p.x + jump[0], p.y + jump[1], p.z + jump[2]]
        };
        let rot = pressed_stroke::<f64>(0).rot.to_f64();
        fn pose<S: Scalar>(p: [f64; 3], rot: [f64; 4]) -> Pose<S> {
            Pose::new(Vec3::from_f64(p), Quat::from_f64(rot))
        }
        for jump in [[100.0, 0.0, 0.0], [0.0, -80.0, 60.0], [-120.0, 120.0, -5.0]] {
            let mut fixed = Brush::<Fx>::new(crate::presets::LARGE, pressed_stroke(0)).unwrap();
            let mut float = Brush::<f64>::new(crate::presets::LARGE, pressed_stroke(0)).unwrap();
            fixed.tick(pose(at(1, jump), rot));
            float.tick(pose(at(1, jump), rot));
            assert_eq!((fixed.restarts(), float.restarts()), (1, 0), "{jump:?}");
            for (s, node) in fixed.spine().iter().zip(fixed.skeleton()) {
                let (s, node) = (s.to_f64(), node.to_f64());
                assert_eq!([s[0], s[1], s[2]], [node[0], node[1], node[2].max(0.0)]);
            }
            // From there on it is a brush made at rest where the jump put it.
            let mut fresh =
                Brush::<Fx>::new(crate::presets::LARGE, pose(at(1, jump), rot)).unwrap();
            let mut worst = 0.0f64;
            for k in 2..300 {
                fixed.tick(pose(at(k, jump), rot));
                fresh.tick(pose(at(k, jump), rot));
                assert!(fixed.spine().iter().all(|s| s.z >= Fx::ZERO));
                for (a, b) in fixed.spine().iter().zip(fresh.spine()) {
                    worst = worst.max((a.cast::<f64>() - b.cast::<f64>()).norm());
                }
            }
            assert_eq!(fixed.restarts(), 1, "{jump:?}: restarted again");
            assert!(worst < 1e-3, "{jump:?}: {worst} mm from a brush made there");
        }
    }

    /// The segment lengths the surface update leaves for the next substep's springs change
    /// nothing: a brush that never uses them (the cache dropped before every tick) ends a
    /// pressed, dragged and lifted stroke with the same bits, at one substep per tick and
    /// at the presets' 25, in fixed point and in f64.
    #[test]
    fn cached_segment_lengths_change_no_bit() {
        fn run<S: BrushScalar>(substeps: f32) {
            let pose = pressed_stroke::<S>;
            let mut cached = Brush::<S>::new(crate::presets::LARGE, pose(0)).unwrap();
            cached
                .set_param(ParamId::SubstepsPerTick, substeps)
                .unwrap();
            let mut fresh = cached.clone();
            let mut used = 0;
            let mut touched = 0;
            for k in 1..=300 {
                used += cached.segments_cached as u32;
                cached.tick(pose(k));
                // Forget what the surface update measured of the segments the cache serves,
                // so that they are measured from scratch (no guess for their roots either).
                fresh.segments_cached = false;
                fresh.seg_rsqrt[2..].fill(S::ZERO);
                fresh.tick(pose(k));
                touched = touched.max(cached.contacts());
                assert_eq!(cached.spine, fresh.spine, "{} tick {k}", S::NAME);
                assert_eq!(cached.vel, fresh.vel, "{} tick {k}", S::NAME);
                assert_eq!(cached.layers, fresh.layers, "{} tick {k}", S::NAME);
            }
            // The cache was there to use on every tick, and the stroke reached the paper.
            assert_eq!(used, 300);
            assert!(touched > 0, "{touched}");
        }
        for substeps in [1.0, 25.0] {
            run::<crate::scalar::Fx>(substeps);
            run::<f64>(substeps);
        }
    }
}
