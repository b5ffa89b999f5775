//! The force on the hand, once per tick: `maobi_shared::force`'s model (Liang 4.2-4.7) and
//! its output stage (passivity controller, ramps, limits).
//!
//! The supervisor's gate (calibrated, no latched fault) decides whether the motors are
//! driven at all; when it closes, the motors are disabled at once by the force loop and the
//! output stage is told, so that forces ramp in again from zero after the fault is cleared.

use maobi_shared::force::{ForceModel, OutputStage, DEFAULT_FORCES, PHANTOM_OMNI};
use maobi_shared::{Brush, Fx, Scalar, Vec3};

pub struct HandForces {
    model: ForceModel<Fx>,
    out: OutputStage<Fx>,
    last_hand: Option<Vec3<Fx>>,
    /// The model's force before the output stage (N).
    pub wanted: Vec3<Fx>,
}

impl HandForces {
    /// The default force model with the Phantom Omni's limits (the pen's are alike).
    pub fn new() -> Option<Self> {
        Some(HandForces {
            model: ForceModel::new(DEFAULT_FORCES).ok()?,
            out: OutputStage::new(PHANTOM_OMNI).ok()?,
            last_hand: None,
            wanted: Vec3::ZERO,
        })
    }

    /// The command for this tick (N, world frame), for the brush after its tick and the
    /// hand's ferrule at `hand` (mm). `allowed`: the supervisor's gate.
    pub fn tick(&mut self, brush: &Brush<Fx>, hand: Vec3<Fx>, allowed: bool) -> [Fx; 3] {
        let step = match self.last_hand {
            Some(last) => hand - last,
            None => Vec3::ZERO,
        };
        self.last_hand = Some(hand);
        self.wanted = maobi_fast::force_model_tick(&mut self.model, brush, hand).total;
        if allowed {
            if self.out.faulted() {
                self.out.clear_fault();
            }
            self.out.enable();
        } else {
            self.out.fault();
        }
        let c = maobi_fast::output_stage_apply(&mut self.out, self.wanted, step);
        if allowed {
            [c.x, c.y, c.z]
        } else {
            [Fx::ZERO; 3]
        }
    }

    /// A new stroke: the model's filters and the dragged mass start afresh.
    pub fn reset(&mut self) {
        self.model.reset();
        self.last_hand = None;
    }
}
