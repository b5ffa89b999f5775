//! Baxter & Lin's brush in a haptic device's 1 kHz loop: the brush solved at a lower rate,
//! the local force model between solves ([`LocalForceBrush`]), then the same guide, gate
//! and output stage as Liang's [`crate::ForceLoop`] ([`HandStage`]).
//!
//! What differs from Liang's loop is only the brush and where its force comes from; the
//! sensor-jump check, the guide, the passivity control, the ramps and the limits are the
//! shared ones, so a device running either model protects the hand alike. `f64`: this
//! model runs on the desktop (the app's built-in device, the Phantom bridge), not the pen.

use super::brush::BaxterLinBrush;
use super::local_force::{LocalForceBrush, LocalForceParams};
use crate::force::{DeviceLimits, LimitError, OutputStage, OutputState};
use crate::force_loop::{jumped, HandGuide, HandStage, TickIn, SENSOR_JUMP_MM};
use crate::guide::{GuideForce, GuideParams, GuideStream};
use crate::protocol::Faults;
use crate::quat::Pose;
use crate::vec::Vec3;

/// One tick's output.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct BaxterLinTickOut {
    /// The output stage's command: the force on the hand (N, paper frame).
    pub command: Vec3<f64>,
    /// The brush's force on the handle from the local model (N).
    pub force: Vec3<f64>,
    /// The brush's force plus the guide's, before the output stage (N).
    pub wanted: Vec3<f64>,
    /// The guide's force, distance and source energy this tick.
    pub guide: GuideForce<f64>,
    /// Faults raised this tick (the caller latches them).
    pub faults: Faults,
}

/// Baxter & Lin's brush, its local force model, the guide and the output stage.
#[derive(Clone, Debug)]
pub struct BaxterLinLoop {
    brush: LocalForceBrush,
    stage: HandStage<f64>,
    last_pose: Option<Pose<f64>>,
}

impl BaxterLinLoop {
    /// `brush`, last solved at `pose` (as built), with the local model rebuilt at the rate
    /// and under the stiffness bound of [`LocalForceParams::for_device`] for `limits`, the
    /// output stage for `limits` (disabled until a tick's gate opens) and the guide `guide`.
    pub fn new(
        brush: BaxterLinBrush,
        pose: Pose<f64>,
        limits: DeviceLimits,
        guide: GuideParams,
    ) -> Result<Self, LimitError> {
        let stage = HandStage::new(limits, guide)?;
        Ok(BaxterLinLoop {
            brush: LocalForceBrush::new(brush, &pose, LocalForceParams::for_device(&limits)),
            stage,
            last_pose: None,
        })
    }

    /// One 1 kHz tick, as [`crate::ForceLoop::tick`]: a fresh pose is checked for a jump
    /// and drives the brush (solved on every [`LocalForceParams::rebuild_every`]-th); no
    /// pose holds the brush and the guide. The local model's force at the hand, the guide's
    /// pull and the output stage follow.
    pub fn tick(&mut self, input: TickIn<f64>) -> BaxterLinTickOut {
        let mut raised = Faults::empty();
        let fresh = match input.pose {
            Some(pose) => {
                if let Some(prev) = self.last_pose {
                    if jumped(prev.pos, pose.pos, jump_limit2()) {
                        raised |= Faults::SENSOR_JUMP;
                    }
                }
                self.brush.tick(&pose);
                self.last_pose = Some(pose);
                true
            }
            None => false,
        };
        let hand = self.hand();
        let force = self.brush.model().force(hand);
        let gate = input.gate.with_raised(raised);
        let out = self
            .stage
            .tick_with(force, input.guide, hand, fresh, gate, HandGuide::tick);
        BaxterLinTickOut {
            command: out.command,
            force,
            wanted: out.wanted,
            guide: out.guide,
            faults: raised,
        }
    }

    /// The hand at the last pose (the origin before the first).
    fn hand(&self) -> Vec3<f64> {
        self.last_pose.map_or(Vec3::ZERO, |p| p.pos)
    }

    /// Replaces the brush with `brush`, at rest at `pose`: the local model rebuilt there,
    /// the guide afresh, the next pose not checked for a jump.
    pub fn reset_brush(&mut self, brush: BaxterLinBrush, pose: Pose<f64>) {
        self.brush = LocalForceBrush::new(brush, &pose, *self.brush.params());
        self.stage.restart_guide();
        self.last_pose = None;
    }

    /// The brush as last solved.
    pub fn brush(&self) -> &BaxterLinBrush {
        self.brush.brush()
    }

    /// The brush and its local force model.
    pub fn local(&self) -> &LocalForceBrush {
        &self.brush
    }

    /// Fills every ring to `load` of what it holds: dipping the brush.
    pub fn dip(&mut self, load: f64) {
        self.brush.dip(load);
    }

    /// Forgets the last pose, so the next is not checked for a jump.
    pub fn forget_pose(&mut self) {
        self.last_pose = None;
    }

    pub fn output(&self) -> &OutputStage<f64> {
        self.stage.output()
    }

    pub fn guide(&self) -> &GuideStream<f64> {
        self.stage.guide().stream()
    }

    /// What the output stage is doing under a device's switch `enabled` with `faults`.
    pub fn output_state(&self, enabled: bool, faults: Faults) -> OutputState {
        self.stage.output_state(enabled, faults)
    }

    /// Puts a device's force limits in force (see [`HandStage::set_limits`]).
    pub fn set_limits(&mut self, limits: DeviceLimits) -> Result<(), LimitError> {
        self.stage.set_limits(limits)
    }

    /// Energy the virtual environment stores now, with the hand at the last pose (J): the
    /// brush's springs and the local model's ([`LocalForceBrush::stored_energy`]) and the
    /// guide's spring. The passivity audit's `E`, less the stylus's kinetic energy.
    pub fn stored_energy(&self) -> f64 {
        let hand = self.hand();
        self.brush.stored_energy(hand) * 1e-3 + self.stage.guide_energy(hand)
    }
}

/// [`SENSOR_JUMP_MM`] squared (mm^2).
fn jump_limit2() -> f64 {
    let d = SENSOR_JUMP_MM as f64;
    d * d
}
