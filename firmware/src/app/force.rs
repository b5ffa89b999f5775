//! The force on the hand, once per tick: `maobi_shared::force`'s model (Liang 4.2-4.7) and
//! its output stage (passivity controller, ramps, limits).
//!
//! The supervisor's gate (calibrated, no latched fault) decides whether the motors are
//! driven at all; when it closes, the motors are disabled at once by the force loop and the
//! output stage is told, so that forces ramp in again from zero after the fault is cleared.
//!
//! Guided writing: a [`GuideStream`] adds its pull toward the stroke's moving point to the
//! model's force before the output stage, which is credited with the energy the moving
//! point supplies (`apply_with_source`). A latched fault cuts the guide at once (it fades in
//! again from zero when guide samples come after the fault is cleared); a new stroke
//! ([`HandForces::reset`]) cuts it too, so every stream of guide samples starts from zero
//! gain, as the host's mirror does.

use maobi_shared::force::{DeviceLimits, ForceModel, OutputStage, DEFAULT_FORCES, PHANTOM_OMNI};
use maobi_shared::guide::{GuideInput, GuideStream, DEFAULT_GUIDE};
use maobi_shared::{Brush, Fx, Scalar, Vec3};

pub struct HandForces {
    model: ForceModel<Fx>,
    out: OutputStage<Fx>,
    guide: GuideStream<Fx>,
    last_hand: Option<Vec3<Fx>>,
    /// The model's force plus the guide's, before the output stage (N).
    pub wanted: Vec3<Fx>,
}

impl HandForces {
    /// The default force model with the Phantom Omni's limits (the pen's are alike).
    pub fn new() -> Option<Self> {
        Some(HandForces {
            model: ForceModel::new(DEFAULT_FORCES).ok()?,
            out: OutputStage::new(PHANTOM_OMNI).ok()?,
            guide: GuideStream::new(DEFAULT_GUIDE).ok()?,
            last_hand: None,
            wanted: Vec3::ZERO,
        })
    }

    /// The command for this tick (N, world frame), for the brush after its tick and the
    /// hand's ferrule at `hand` (mm), and this tick's guide sample, if one came. `fresh`: a
    /// new pose came this tick (a virtual pen's tick without one holds the guide: it runs in
    /// pose time, as the host's mirror does). `allowed`: the supervisor's gate; `faulted`: a
    /// fault is latched (cuts the guide).
    pub fn tick(
        &mut self,
        brush: &Brush<Fx>,
        hand: Vec3<Fx>,
        guide: Option<GuideInput<Fx>>,
        fresh: bool,
        allowed: bool,
        faulted: bool,
    ) -> [Fx; 3] {
        let step = match self.last_hand {
            Some(last) => hand - last,
            None => Vec3::ZERO,
        };
        self.last_hand = Some(hand);
        let model = maobi_fast::force_model_tick(&mut self.model, brush, hand).total;
        let source_mj = if faulted {
            self.guide.cut();
            self.wanted = model;
            Fx::ZERO
        } else {
            let g = if fresh {
                self.guide.tick(guide, hand, step)
            } else {
                self.guide.hold()
            };
            self.wanted = model + g.force;
            g.source_mj
        };
        if allowed {
            if self.out.faulted() {
                self.out.clear_fault();
            }
            self.out.enable();
        } else {
            self.out.fault();
        }
        let c = maobi_fast::output_stage_apply(&mut self.out, self.wanted, step, source_mj);
        if allowed {
            [c.x, c.y, c.z]
        } else {
            [Fx::ZERO; 3]
        }
    }

    /// A new stroke: the model's filters and the dragged mass start afresh, the guide
    /// from zero.
    /// Puts a configuration's force limits in force (peak, continuous, slew, ramps). The
    /// output stage starts over disabled, so forces ramp in again from zero; the link task
    /// changes the configuration only while forces are off. Invalid limits (which a
    /// validated configuration never has) are refused and the old ones kept.
    pub fn set_limits(&mut self, limits: DeviceLimits) -> bool {
        if *self.out.limits() == limits {
            return true;
        }
        match OutputStage::new(limits) {
            Ok(out) => {
                self.out = out;
                true
            }
            Err(_) => false,
        }
    }

    pub fn reset(&mut self) {
        self.model.reset();
        self.guide.cut();
        self.last_hand = None;
    }

    /// The guide is leading (or fading out).
    #[cfg_attr(not(feature = "board-qemu"), allow(dead_code))] // read by QEMU's bench
    pub fn guiding(&self) -> bool {
        self.guide.active()
    }
}
