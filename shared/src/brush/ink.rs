//! Ink in the brush (issue 23, item 1): a finite load per layer, filled by a dip, drained
//! onto the paper by contact, pressure and travel, and wicking between neighbouring layers.
//!
//! Units: an *ink unit* darkens 1 mm^2 of paper to optical depth 1 (the paper's unit times
//! its area). Layer i holds at most `capacity_i = ink_capacity x pi r_i^2 L` (its rest
//! ellipse over one segment: the belly holds most), and holds `W_i capacity_i`: its wetness
//! W_i (eq. 3-17) is its load's share, the state itself, so the 3-17 splay follows the brush
//! as it dries. Once per tick, after the surface update (`Brush::transfer_ink`):
//!
//! 1. **Deposit.** A layer whose ellipse reaches within `footprint_eps_mm` of the paper gives
//!    `W_i x TRANSFER x 2 RL_i x (travel_i + DWELL_MM) x press_i`, at most what it holds: ink
//!    in proportion to its wetness (so the tone decays along a stroke written without
//!    dipping), to its width across the stroke, to how far it moved this tick (plus a dwell,
//!    so a brush held still keeps giving ink and a slow stroke gives more per mm than a fast
//!    one), and to how far it is pressed in (`press_i` from [`PRESS_FLOOR`] at the threshold
//!    to one at [`PRESS_FULL_MM`]). The lowest point of the ellipse is taken as
//!    `z - max(|RL LA_z|, |RS SA_z|)` (within a factor sqrt 2 of the true one, and no square
//!    root on the pen).
//! 2. **Wicking.** Ink moves from layer i-1 to i by `WICK x (W_(i-1) - W_i) x min(capacity)`
//!    a tick on average (every other tick at twice that, the even and odd pairs in turn),
//!    at most what the giving layer holds: the belly refills the tip as it writes.
//!
//! What a layer gives is added to its `deposited`, the running total it has given to the
//! paper, which the state frames carry: the host lays the increase since the last frame it
//! saw under the layer's footprint, so a state sent every few ticks, or lost, loses no ink.
//! The amounts are computed in IEEE single precision (the same bits on every target; on the
//! pen's FPU an instruction each, where the fixed-point products are library calls in the
//! size-built code) and rounded into the brush's format once; the wetness is updated in
//! the brush's format by exactly the amounts it gave or took. Ink in the brush plus ink
//! deposited equals ink dipped, to the rounding of those updates (`shared/tests/ink.rs`). The wetness is the state, not the amount, so a layer
//! costs the pen's RAM one number more (its running total), not two; each layer's
//! capacity's reciprocal is kept in single precision.
//!
//! # The ink in the ties
//!
//! The thesis (3.1.2) has the tie between a mass and its skeleton node stand for the hair's
//! elasticity (its spring, k_t) and the ink's viscosity (its damper, k_dt), and suggests
//! making both functions of the ink content. Layer i's tie is
//!
//! ```text
//! k_t,i  = k_t  (1 + W_i (tie_stiffness_wet_pct / 100 - 1))
//! k_dt,i = k_dt (1 + W_i (tie_damping_wet_pct / 100 - 1))
//! ```
//!
//! `k_t`, `k_dt` the dry layer's (`tie_stiffness_n_per_m`, `tie_damping_ns_per_m`), W_i its
//! wetness. The directions are the physics': water plasticises keratin's amorphous matrix
//! (Feughelman's two-phase model, Textile Research Journal 29, 1959), so a dry hair's
//! Young's modulus is two to three times a wet one's (J. Cosmet. Sci. 72, special edition,
//! "The matrix revisited"), and the spring softens with ink (factor at most one); the ink
//! between the hairs is a viscous liquid that binds them and has to be sheared when they
//! move against each other, so the damper stiffens with ink (factor at least one). Linear
//! in W: the thesis gives no form, the wetness is itself the load's share, and a linear law
//! costs the substep one product per coefficient (`c_t + W c_t_ink`, `c_tv + W c_tv_ink`,
//! the saturated layer's changes derived with the other coefficients), evaluated where the
//! tie is, so the brush keeps no per-layer array for it. The presets' factors
//! ([`crate::presets::TIE_STIFFNESS_WET_PCT`], [`crate::presets::TIE_DAMPING_WET_PCT`])
//! are milder than soaked against dry hair: a brush that writes itself dry of ink is still
//! damp. The implicit rows of the thesis's integrator keep the dry tie in W' and take the
//! ink's change on the right-hand side, as they take the tie's weight.

use super::layer::Layer;
use crate::params::{BrushParams, MAX_LAYERS};
use crate::scalar::Scalar;
use crate::vec::Vec3;

/// Ink units a layer gives per mm^2 it sweeps at full load and full press: the optical depth
/// one layer leaves on the paper it passes over.
pub const TRANSFER: f32 = 1.0;

/// Travel (mm) a layer in contact counts per tick on top of its motion: a brush held still
/// keeps giving ink, and a slow stroke gives more per mm than a fast one (as if every
/// stroke moved 30 mm/s faster).
pub const DWELL_MM: f32 = 0.03;

/// Share of the full transfer a layer gives when it only just reaches the paper.
pub const PRESS_FLOOR: f32 = 0.4;

/// Press (mm below the footprint threshold) from which a layer gives its full transfer: one
/// millimetre, so that the press in mm is its share of the way with no product.
pub const PRESS_FULL_MM: f32 = 1.0;

/// Share of the difference in wetness between neighbouring layers that wicks across per
/// tick, of the smaller layer's capacity (explicit, stable up to one half).
pub const WICK: f32 = 0.25;

/// Differences in wetness below this do not wick: a brush fresh from a dip, or in the air,
/// spends no products on wicking.
pub const WICK_MIN: f32 = 1.0 / 65536.0;

/// The ink model's coefficients, derived from the parameters. Single precision: the transfer
/// computes its amounts in IEEE `f32` (the same bits on every target; the pen's FPU does each
/// operation in one instruction), and keeps the wetness and the running totals in the
/// brush's format.
#[derive(Copy, Clone)]
pub(crate) struct InkCoefs {
    /// One over what each layer holds (its capacity is taken as the reciprocal of this, so
    /// the two agree).
    pub(crate) inv_capacity: [f32; MAX_LAYERS],
    /// `DWELL_MM / substeps`, added to the last substep's travel.
    pub(super) dwell: f32,
    pub(super) eps: f32,
    /// The press factor at the threshold and its rise to full press, both times
    /// `2 TRANSFER substeps`: times the wetness, the long radius and the last substep's travel
    /// (plus `dwell`), the ink a layer gives in a tick.
    pub(super) press_floor: f32,
    pub(super) press_slope: f32,
}

/// Without its numbers: formatting an `f32` would bring the float formatting code into the
/// pen's image for a brush's `Debug`, which the image never prints.
impl core::fmt::Debug for InkCoefs {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("InkCoefs").finish_non_exhaustive()
    }
}

impl InkCoefs {
    /// The coefficients of rings that hold `capacity[i]` ink units each when saturated (the
    /// rest hold none), stepped `substeps` times a tick, inking below `eps` mm: a brush
    /// whose layers are not Liang's rest rings (Baxter & Lin's).
    pub(crate) fn for_rings(capacity: &[f32], substeps: u8, eps: f32) -> Self {
        let mut inv_capacity = [0.0; MAX_LAYERS];
        for (inv, c) in inv_capacity.iter_mut().zip(capacity) {
            *inv = if *c > 0.0 { 1.0 / c } else { 0.0 };
        }
        Self::with(inv_capacity, substeps.max(1) as f32, eps)
    }

    pub(crate) fn new(p: &BrushParams) -> Self {
        let per_area = p.ink_capacity * core::f32::consts::PI * p.segment_mm();
        let n = (p.layers as usize).clamp(2, MAX_LAYERS);
        let mut inv_capacity = [0.0; MAX_LAYERS];
        for (i, inv) in inv_capacity[..n].iter_mut().enumerate() {
            let r = p.rest_radius_mm(i);
            *inv = 1.0 / (per_area * r * r);
        }
        Self::with(inv_capacity, p.substeps_per_tick as f32, p.footprint_eps_mm)
    }

    /// The law's coefficients for layers of the given capacities, `substeps` (at least
    /// one) a tick.
    #[inline(always)]
    fn with(inv_capacity: [f32; MAX_LAYERS], substeps: f32, eps: f32) -> Self {
        let gain = 2.0 * TRANSFER * substeps;
        InkCoefs {
            inv_capacity,
            dwell: DWELL_MM / substeps,
            eps,
            press_floor: gain * PRESS_FLOOR,
            press_slope: gain * (1.0 - PRESS_FLOOR),
        }
    }
}

/// The law's one statement: what a saturated layer's ink adds to its tie stiffness (N/m)
/// and damping (N s/m), per unit wetness (see the module docs); the tie at wetness W is the
/// dry tie plus W times this. The brush's coefficients and the handle's reaction both take
/// it from here.
pub fn tie_change(p: &BrushParams) -> (f32, f32) {
    (
        p.tie_stiffness * (p.tie_stiffness_wet() - 1.0),
        p.tie_damping * (p.tie_damping_wet() - 1.0),
    )
}

/// Layer tie stiffness (N/m) and damping (N s/m) at wetness `wet` ([`tie_change`]), in
/// double precision: the handle's reaction ([`super::Brush::handle_reaction`]) sums them.
pub fn tie_at(p: &BrushParams, wet: f64) -> (f64, f64) {
    let (kt_ink, kdt_ink) = tie_change(p);
    (
        p.tie_stiffness as f64 + wet * kt_ink as f64,
        p.tie_damping as f64 + wet * kdt_ink as f64,
    )
}

/// The tick's ink transfer (see the module): deposits, then wicking, for a brush's layers:
/// `centres[i]` is layer i's centre (mm), `steps[i]` how far it moved in the last substep
/// (mm), `max_radius[i]` the widest its ring gets (mm); `phase` picks the wicking pairs and
/// turns on every tick that wicked. Every brush model inks its layers here.
#[inline(always)]
pub(crate) fn transfer<S: Scalar>(
    layers: &mut [Layer<S>],
    centres: &[Vec3<S>],
    steps: &[Vec3<S>],
    max_radius: &[S],
    c: &InkCoefs,
    phase: &mut bool,
) {
    let n = layers.len();
    let eps = S::from_f32(c.eps);
    // Zipped, not indexed: the force path holds no panicking index.
    let each = layers
        .iter_mut()
        .zip(centres)
        .zip(steps)
        .zip(max_radius)
        .zip(&c.inv_capacity);
    for ((((l, x), u), &max_radius), &inv_cap) in each {
        // No radius exceeds the widest: a layer higher than that above the threshold
        // cannot reach the paper, and its lowest point is not needed.
        if x.z > eps + max_radius {
            continue;
        }
        let drop = (l.long_radius * l.long_axis.z)
            .abs()
            .max((l.short_radius * l.short_axis.z).abs());
        let press = (eps - (x.z - drop)).to_f32();
        if press > 0.0 {
            let cap = if inv_cap > 0.0 { 1.0 / inv_cap } else { 0.0 };
            let w = l.wetness.to_f32();
            // PRESS_FULL_MM is one millimetre: the press in mm is its share of the way.
            let press = c.press_floor + c.press_slope * press.min(1.0);
            // |u_xy| within 3% by the octagon, max + 3/8 min: no square root.
            let (ux, uy) = (u.x.to_f32().abs(), u.y.to_f32().abs());
            let travel = ux.max(uy) + 0.375 * ux.min(uy);
            let give = (w * l.long_radius.to_f32() * (travel + c.dwell) * press).min(w * cap);
            let give = S::from_f32(give);
            l.wetness = (l.wetness - give * S::from_f32(inv_cap)).max(S::ZERO);
            l.deposited += give;
        }
    }
    // Wicking, after the deposits: the pairs (i-1, i) with i of this tick's parity, so
    // that each layer takes part in one exchange a tick, at twice the rate, the even
    // and odd pairs in turn: the same diffusion as every pair at WICK each tick, half
    // the work, and (each exchange moving at most half the difference, by WICK <= 1/4)
    // no layer can overshoot its neighbour.
    // The phase turns only on a tick that wicked: a brush at rest in the air, evenly wet,
    // is unchanged by any number of ticks (a device that idles longer than its host's
    // copy still agrees with it).
    let first = if *phase { 2 } else { 1 };
    let mut wicked = false;
    let wick_min = S::from_f32(WICK_MIN);
    for i in (first..n).step_by(2) {
        // Checked, not `split_at_mut`: the force path holds no panic (i < n always).
        let Some((lo, hi)) = layers.split_at_mut_checked(i) else {
            continue;
        };
        let (Some(giver), Some(taker)) = (lo.last_mut(), hi.first_mut()) else {
            continue;
        };
        // None across a difference below WICK_MIN (a brush fresh from a dip, or in the
        // air, costs no products).
        if (giver.wetness - taker.wetness).abs() <= wick_min {
            continue;
        }
        let (Some(&inv_g), Some(&inv_t)) = (c.inv_capacity.get(i - 1), c.inv_capacity.get(i))
        else {
            continue;
        };
        if inv_g <= 0.0 || inv_t <= 0.0 {
            continue;
        }
        // Ink units per unit of wetness difference. At a rate of at most one half of the
        // smaller capacity the flow is within what the giver holds and what the taker
        // can take (each wetness within [0, 1]); the clamps below keep the rounding in.
        let rate = S::from_f32((2.0 * WICK) * (1.0 / inv_g).min(1.0 / inv_t));
        let flow = (giver.wetness - taker.wetness) * rate;
        giver.wetness = (giver.wetness - flow * S::from_f32(inv_g)).clamp(S::ZERO, S::ONE);
        taker.wetness = (taker.wetness + flow * S::from_f32(inv_t)).clamp(S::ZERO, S::ONE);
        wicked = true;
    }
    if wicked {
        *phase = !*phase;
    }
}
