//! Ink in the brush (issue 23, item 1): a finite load per layer, filled by a dip, drained
//! onto the paper by contact, pressure and travel, and wicking between neighbouring layers.
//!
//! Units: an *ink unit* darkens 1 mm^2 of paper to optical depth 1 (the paper's unit times
//! its area). Layer i holds at most `capacity_i = ink_capacity x pi r_i^2 L` (its rest
//! ellipse over one segment: the belly holds most). Once per tick, after the surface update
//! ([`Brush::transfer_ink`]):
//!
//! 1. **Deposit.** A layer whose ellipse reaches within `footprint_eps_mm` of the paper gives
//!    `ink_i x min(1, TRANSFER x 2 RL_i x (travel_i + DWELL_MM) x press_i / capacity_i)`:
//!    ink in proportion to what it holds (so W_i, and with it the tone, decays along a stroke
//!    written without dipping), to its width across the stroke, to how far it moved this tick
//!    (plus a dwell, so a brush held still keeps giving ink and a slow stroke gives more per
//!    mm than a fast one), and to how far it is pressed in (`press_i` from [`PRESS_FLOOR`]
//!    at the threshold to one at [`PRESS_FULL_MM`]). The lowest point of the ellipse is
//!    taken as `z - max(|RL LA_z|, |RS SA_z|)` (within a factor sqrt 2 of the true one, and
//!    no square root on the pen).
//! 2. **Wicking.** Ink moves from layer i-1 to i by `WICK x (W_(i-1) - W_i) x min(capacity)`,
//!    at most what the giving layer holds: the belly refills the tip as it writes.
//! 3. **Wetness** W_i = ink_i / capacity_i (the 3-17 splay follows the brush as it dries).
//!
//! Every amount moved is subtracted from one place and added to another (a layer's
//! `deposited`, the running total it has given to the paper, which the state frames carry:
//! the host lays the increase since the last frame it saw under the layer's footprint, so a
//! state sent every few ticks, or lost, loses no ink), so ink in the brush plus ink
//! deposited equals ink dipped: exactly in fixed point, to rounding in floating point
//! (`shared/tests/ink.rs`). A few products per layer per tick, no division.

use super::Brush;
use crate::params::{BrushParams, MAX_LAYERS};
use crate::scalar::Scalar;

/// Ink units a layer gives per mm^2 it sweeps at full load and full press: the optical depth
/// one layer leaves on the paper it passes over.
pub const TRANSFER: f32 = 1.0;

/// Travel (mm) a layer in contact counts per tick on top of its motion: a brush held still
/// keeps giving ink, and a slow stroke gives more per mm than a fast one (as if every
/// stroke moved 30 mm/s faster).
pub const DWELL_MM: f32 = 0.03;

/// Share of the full transfer a layer gives when it only just reaches the paper.
pub const PRESS_FLOOR: f32 = 0.4;

/// Press (mm below the footprint threshold) from which a layer gives its full transfer.
pub const PRESS_FULL_MM: f32 = 1.0;

/// Share of the difference in wetness between neighbouring layers that wicks across per
/// tick, of the smaller layer's capacity (explicit, stable up to one half).
pub const WICK: f32 = 0.25;

/// The ink model's per-layer coefficients, derived from the parameters.
#[derive(Copy, Clone, Debug)]
pub(crate) struct InkCoefs<S> {
    /// What each layer holds when saturated (ink units).
    capacity: [S; MAX_LAYERS],
    inv_capacity: [S; MAX_LAYERS],
    /// `TRANSFER x 2 / capacity_i`: multiplied by the long radius, the travel and the press,
    /// the share of its load a layer gives.
    rate: [S; MAX_LAYERS],
    /// `WICK x min(capacity_(i-1), capacity_i)`: ink moved per unit difference in wetness
    /// from layer i-1 to i (entry 0 unused).
    wick: [S; MAX_LAYERS],
    dwell: S,
    /// Substeps per tick: the last substep's displacement times this is the tick's travel.
    substeps: S,
    eps: S,
    inv_press_full: S,
    press_floor: S,
    press_slope: S,
    /// 3/8, of the octagon's estimate of a length.
    octagon: S,
}

impl<S: Scalar> InkCoefs<S> {
    pub(crate) fn new(p: &BrushParams) -> Self {
        let n = (p.layers as usize).clamp(2, MAX_LAYERS);
        let seg = p.segment_mm();
        let mut capacity = [S::ZERO; MAX_LAYERS];
        let mut inv_capacity = [S::ZERO; MAX_LAYERS];
        let mut rate = [S::ZERO; MAX_LAYERS];
        let mut wick = [S::ZERO; MAX_LAYERS];
        let mut prev = 0.0f32;
        for i in 0..n {
            let r = p.rest_radius_mm(i);
            let cap = (p.ink_capacity * core::f32::consts::PI * r * r * seg).max(f32::MIN_POSITIVE);
            capacity[i] = S::from_f32(cap);
            inv_capacity[i] = S::from_f32(1.0 / cap);
            rate[i] = S::from_f32(2.0 * TRANSFER / cap);
            if i > 0 {
                wick[i] = S::from_f32(WICK * prev.min(cap));
            }
            prev = cap;
        }
        InkCoefs {
            capacity,
            inv_capacity,
            rate,
            wick,
            dwell: S::from_f32(DWELL_MM),
            substeps: S::from_usize(p.substeps_per_tick as usize),
            eps: S::from_f32(p.footprint_eps_mm),
            inv_press_full: S::from_f32(1.0 / PRESS_FULL_MM),
            press_floor: S::from_f32(PRESS_FLOOR),
            press_slope: S::from_f32(1.0 - PRESS_FLOOR),
            octagon: S::from_f32(0.375),
        }
    }
}

impl<S: Scalar> Brush<S> {
    /// Fills every layer to `load` of what it holds (clamped to [0, 1]): dipping the brush.
    pub fn dip(&mut self, load: S) {
        let w = load.clamp(S::ZERO, S::ONE);
        let n = self.d.n();
        for (l, cap) in self.layers[..n].iter_mut().zip(&self.ink_coefs.capacity) {
            l.ink = cap.mul_coef(w);
            l.wetness = w;
        }
    }

    /// Ink held by the whole brush (ink units).
    pub fn ink_load(&self) -> S {
        self.layers().iter().fold(S::ZERO, |a, l| a + l.ink)
    }

    /// What layer i holds when saturated (ink units).
    pub fn ink_capacity(&self, i: usize) -> S {
        self.ink_coefs.capacity.get(i).copied().unwrap_or(S::ZERO)
    }

    /// The tick's ink transfer (see the module): deposits, wicking, wetness. Runs after the
    /// surface update, whose radii and axes it reads.
    pub(crate) fn transfer_ink(&mut self) {
        let n = self.d.n();
        let c = &self.ink_coefs;
        let one = S::ONE;
        for (((l, x), u), rate) in self.layers[..n]
            .iter_mut()
            .zip(&self.spine)
            .zip(&self.vel)
            .zip(&c.rate)
        {
            let drop = (l.long_radius * l.long_axis.z)
                .abs()
                .max((l.short_radius * l.short_axis.z).abs());
            let press = c.eps - (x.z - drop);
            let give = if press > S::ZERO {
                let press =
                    c.press_floor + c.press_slope.mul_coef((press * c.inv_press_full).min(one));
                // |u_xy| within 3% by the octagon max + 3/8 min: no square root.
                let (ax, ay) = (u.x.abs(), u.y.abs());
                let (hi, lo) = (ax.max(ay), ax.min(ay));
                let travel = (hi + lo.mul_coef(c.octagon)) * c.substeps;
                let share = (l.long_radius * *rate * (travel + c.dwell))
                    .mul_coef(press)
                    .min(one);
                l.ink.mul_coef(share)
            } else {
                S::ZERO
            };
            l.ink -= give;
            l.deposited += give;
        }
        let layers = &mut self.layers;
        for i in 1..n {
            let (giver, taker) = (layers[i - 1], layers[i]);
            let flow =
                ((giver.wetness - taker.wetness) * c.wick[i]).clamp(S::ZERO - taker.ink, giver.ink);
            layers[i - 1].ink -= flow;
            layers[i].ink += flow;
        }
        for (l, inv) in self.layers[..n].iter_mut().zip(&c.inv_capacity) {
            l.wetness = (l.ink * *inv).clamp(S::ZERO, one);
        }
    }
}
