//! Baxter & Lin's brush in a haptic device's 1 kHz loop: the brush solved at a lower rate,
//! the local force model between solves ([`LocalForceBrush`]), then the same guide, gate
//! and output stage as Liang's [`crate::ForceLoop`] ([`HandStage`]).
//!
//! What differs from Liang's loop is only the brush and where its force comes from; the
//! sensor-jump check, the guide, the passivity control, the ramps and the limits are the
//! shared ones, so a device running either model protects the hand alike. `f64`: this
//! model runs on the desktop (the app's built-in device, the Phantom bridge), not the pen.

use super::brush::BaxterLinBrush;
use super::local_force::{LocalForceBrush, LocalForceModel, LocalForceParams};
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

/// The 1 kHz half of the loop: the sensor-jump check, the force of the local model in
/// force at the hand, then the guide, gate and output stage. A device that solves the brush
/// on another thread (the Phantom bridge) runs only this in its servo callback, with the
/// last model that thread published; [`BaxterLinLoop`] runs it after its own solve.
#[derive(Clone, Debug)]
pub struct BaxterLinHand {
    stage: HandStage<f64>,
    last_pose: Option<Pose<f64>>,
}

impl BaxterLinHand {
    /// The output stage for `limits` (disabled until a tick's gate opens) and the guide
    /// `guide`.
    pub fn new(limits: DeviceLimits, guide: GuideParams) -> Result<Self, LimitError> {
        Ok(BaxterLinHand {
            stage: HandStage::new(limits, guide)?,
            last_pose: None,
        })
    }

    /// One 1 kHz tick with the brush's force from `model`: a fresh pose is checked for a
    /// jump from the last; no pose holds the hand and the guide where they were.
    pub fn tick(&mut self, input: TickIn<f64>, model: &LocalForceModel) -> BaxterLinTickOut {
        let mut raised = Faults::empty();
        let fresh = match input.pose {
            Some(pose) => {
                if let Some(prev) = self.last_pose {
                    if jumped(prev.pos, pose.pos, jump_limit2()) {
                        raised |= Faults::SENSOR_JUMP;
                    }
                }
                self.last_pose = Some(pose);
                true
            }
            None => false,
        };
        let hand = self.hand();
        let force = model.force(hand);
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
    pub fn hand(&self) -> Vec3<f64> {
        self.last_pose.map_or(Vec3::ZERO, |p| p.pos)
    }

    /// Forgets the last pose, so the next is not checked for a jump.
    pub fn forget_pose(&mut self) {
        self.last_pose = None;
    }

    /// A new brush: the guide afresh, the next pose not checked for a jump.
    pub fn restart(&mut self) {
        self.stage.restart_guide();
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

    /// The guide's spring energy with the hand at the last pose (J).
    pub fn guide_energy(&self) -> f64 {
        self.stage.guide_energy(self.hand())
    }
}

/// Baxter & Lin's brush, its local force model, the guide and the output stage, in one
/// thread: the brush solved inside every [`LocalForceParams::rebuild_every`]-th tick.
#[derive(Clone, Debug)]
pub struct BaxterLinLoop {
    brush: LocalForceBrush,
    hand: BaxterLinHand,
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
        let hand = BaxterLinHand::new(limits, guide)?;
        Ok(BaxterLinLoop {
            brush: LocalForceBrush::new(brush, &pose, LocalForceParams::for_device(&limits)),
            hand,
        })
    }

    /// One 1 kHz tick, as [`crate::ForceLoop::tick`]: a fresh pose drives the brush (solved
    /// on every [`LocalForceParams::rebuild_every`]-th); then [`BaxterLinHand::tick`] with
    /// the model as it stands.
    pub fn tick(&mut self, input: TickIn<f64>) -> BaxterLinTickOut {
        if let Some(pose) = &input.pose {
            self.brush.tick(pose);
        }
        self.hand.tick(input, self.brush.model())
    }

    /// Replaces the brush with `brush`, at rest at `pose`: the local model rebuilt there,
    /// the guide afresh, the next pose not checked for a jump.
    pub fn reset_brush(&mut self, brush: BaxterLinBrush, pose: Pose<f64>) {
        self.brush = LocalForceBrush::new(brush, &pose, *self.brush.params());
        self.hand.restart();
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
        self.hand.forget_pose();
    }

    pub fn output(&self) -> &OutputStage<f64> {
        self.hand.output()
    }

    pub fn guide(&self) -> &GuideStream<f64> {
        self.hand.guide()
    }

    /// What the output stage is doing under a device's switch `enabled` with `faults`.
    pub fn output_state(&self, enabled: bool, faults: Faults) -> OutputState {
        self.hand.output_state(enabled, faults)
    }

    /// Puts a device's force limits in force (see [`HandStage::set_limits`]).
    pub fn set_limits(&mut self, limits: DeviceLimits) -> Result<(), LimitError> {
        self.hand.set_limits(limits)
    }

    /// Energy the virtual environment stores now, with the hand at the last pose (J): the
    /// brush's springs and the local model's ([`LocalForceBrush::stored_energy`]) and the
    /// guide's spring. The passivity audit's `E`, less the stylus's kinetic energy.
    pub fn stored_energy(&self) -> f64 {
        self.brush.stored_energy(self.hand.hand()) * 1e-3 + self.hand.guide_energy()
    }
}

/// [`SENSOR_JUMP_MM`] squared (mm^2).
fn jump_limit2() -> f64 {
    let d = SENSOR_JUMP_MM as f64;
    d * d
}
