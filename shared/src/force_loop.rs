//! The force loop, once for every device: pose in, brush tick, force model, guide, output
//! stage, sensor-jump check, command out.
//!
//! The pen's firmware, the host's simulators (`maobi sim-device`, the GUI's built-in
//! device, the offline trace), the Phantom bridge's servo loop and the HIL runner's mirror
//! of the firmware all run this [`ForceLoop`], so that the same inputs give the same forces,
//! bit for bit in [`Fx`](crate::Fx), wherever it runs. What stays with each of them is what
//! is theirs: where the poses come from, the clock, the transport, the device's axes, and
//! the latched faults and the forces switch (the [`Gate`] they hand in every tick).
//!
//! `no_std`, no allocation: a loop is kilobytes (its brush most of it), so a device builds it
//! in place in a static's storage ([`ForceLoop::new_in`]).
//!
//! # One tick ([`ForceLoop::tick`])
//! 1. A fresh pose: after [`ForceLoop::reanchor`] the brush is put at rest there and the
//!    forces start afresh (no sensor-jump check); otherwise a step further than
//!    [`SENSOR_JUMP_MM`] from the last pose raises [`Faults::SENSOR_JUMP`] (this tick is
//!    then faulted), and the brush ticks to it. No pose (a virtual pen's host fell behind):
//!    the brush and the guide hold, the force model still ticks at the last hand position.
//! 2. The force model's force for the brush after its tick, with the hand at the last pose.
//! 3. The guide's pull toward this tick's sample ([`GuideStream`], in pose time), added to
//!    the model's force: the *wanted* force, which a state frame reports as
//!    `haptics.force_n`. A latched fault cuts the guide.
//! 4. The output stage (passivity, ramps, limits), credited with the energy the guide's
//!    moving point supplied, turns the wanted force into the command. The gate decides
//!    whether it drives: closed, it ramps out (and in again from zero when it opens).

use crate::brush::{Brush, BrushScalar};
use crate::force::{
    DeviceLimits, ForceModel, ForceParams, Forces, LimitError, OutputStage, OutputState, G,
};
use crate::guide::{GuideForce, GuideInput, GuideParams, GuideStream};
use crate::params::{BrushParams, ParamError};
use crate::protocol::Faults;
use crate::quat::Pose;
use crate::scalar::Scalar;
use crate::vec::Vec3;
use core::fmt;
use core::mem::MaybeUninit;

/// Two consecutive poses further apart than this (mm) are a sensor fault: a 500 mm/s
/// stroke moves 0.5 mm per 1 ms tick.
pub const SENSOR_JUMP_MM: u32 = 10;

/// The supervisor's word on this tick, from what the caller latches and switches.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub struct Gate {
    /// The output stage may drive: forces enabled, no fault latched, nothing else holding
    /// them (a configuration that does not allow forces, a deliberate pause).
    pub allowed: bool,
    /// A fault is latched: the guide is cut.
    pub faulted: bool,
}

impl Gate {
    /// The gate of a device whose switch is `enabled` with `faults` latched.
    pub fn new(enabled: bool, faults: Faults) -> Gate {
        Gate {
            allowed: enabled && faults.is_empty(),
            faulted: !faults.is_empty(),
        }
    }

    /// This gate once the tick has raised `raised`: a fault raised now counts this tick, as
    /// one latched before it would.
    #[inline(always)]
    pub fn with_raised(self, raised: Faults) -> Gate {
        Gate {
            allowed: self.allowed && raised.is_empty(),
            faulted: self.faulted || !raised.is_empty(),
        }
    }
}

/// One tick's input.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct TickIn<S> {
    /// The pen's pose this tick, if a fresh one came.
    pub pose: Option<Pose<S>>,
    /// The guide sample that rides with it, if any.
    pub guide: Option<GuideInput<S>>,
    pub gate: Gate,
}

/// One tick's output.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct TickOut<S> {
    /// The output stage's command: the force on the hand (N, paper frame).
    pub command: Vec3<S>,
    /// The force model's force, by term.
    pub forces: Forces<S>,
    /// The model's force plus the guide's, before the output stage (N): a state frame's
    /// `haptics.force_n`.
    pub wanted: Vec3<S>,
    /// The guide's force, distance and source energy this tick (zero while it is idle).
    pub guide: GuideForce<S>,
    /// Faults raised this tick (the caller latches them).
    pub faults: Faults,
}

/// The guide's tick ([`HandGuide::tick`]) as a function pointer.
pub type GuideTick<S> =
    fn(&mut HandGuide<S>, Option<GuideInput<S>>, Vec3<S>, bool, bool) -> (Vec3<S>, GuideForce<S>);

/// The parts of a tick that the caller supplies, compiled where it names them: the guide's
/// tick and the brush's reset (a re-anchor). A caller that builds the tick for speed and the
/// rest for size (the pen's firmware: its tick in `maobi-fast`) hands in the copies its
/// size-optimised code already has: the reset's, which a re-anchor tick can afford since it
/// runs no brush tick, and the guide's, which at speed would cost more flash than the pen has.
/// [`ForceLoop::tick`] uses its own ([`TickParts::here`]).
#[derive(Copy, Clone)]
pub struct TickParts<S: Scalar> {
    pub guide: GuideTick<S>,
    pub reset: fn(&mut Brush<S>, Pose<S>),
}

impl<S: BrushScalar> TickParts<S> {
    /// The parts, compiled in the crate that calls this.
    pub const fn here() -> Self {
        TickParts {
            guide: HandGuide::tick,
            reset: Brush::reset,
        }
    }
}

/// Why a loop could not be built.
#[derive(Copy, Clone, Debug, PartialEq)]
pub enum LoopError {
    Brush(ParamError),
    Limits(LimitError),
}

impl fmt::Display for LoopError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            LoopError::Brush(e) => write!(f, "{e}"),
            LoopError::Limits(e) => write!(f, "{e}"),
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for LoopError {}

impl From<ParamError> for LoopError {
    fn from(e: ParamError) -> Self {
        LoopError::Brush(e)
    }
}

impl From<LimitError> for LoopError {
    fn from(e: LimitError) -> Self {
        LoopError::Limits(e)
    }
}

/// The device's guide as its force loop runs it: a [`GuideStream`] fed one sample per tick
/// with the hand's step since the last tick, cut while a fault is latched, held on a tick
/// without a pose. The force loop's own, and the host's mirror of a device's guide (what the
/// GUI shows of a device it streams to) runs the same.
#[derive(Clone, Debug)]
pub struct HandGuide<S> {
    stream: GuideStream<S>,
    last_hand: Option<Vec3<S>>,
}

impl<S: Scalar> HandGuide<S> {
    pub fn new(params: GuideParams) -> Result<Self, LimitError> {
        Ok(HandGuide {
            stream: GuideStream::new(params)?,
            last_hand: None,
        })
    }

    pub fn stream(&self) -> &GuideStream<S> {
        &self.stream
    }

    /// Starts afresh: the guide from zero, and no step for the next hand position.
    pub fn restart(&mut self) {
        self.stream.cut();
        self.last_hand = None;
    }

    /// One tick with the hand at `hand`: its step since the last tick, and the guide's
    /// force. `fresh`: a new pose came (else the guide holds its force); `faulted`: the guide
    /// is cut and pulls with nothing. Never inlined: a caller may hand it to a loop's tick
    /// built elsewhere ([`TickParts`]), which must call this copy, not grow its own.
    #[inline(never)]
    pub fn tick(
        &mut self,
        sample: Option<GuideInput<S>>,
        hand: Vec3<S>,
        fresh: bool,
        faulted: bool,
    ) -> (Vec3<S>, GuideForce<S>) {
        let step = match self.last_hand {
            Some(last) => hand - last,
            None => Vec3::ZERO,
        };
        self.last_hand = Some(hand);
        let g = if faulted {
            self.stream.cut();
            GuideForce {
                force: Vec3::ZERO,
                distance_mm: S::ZERO,
                source_mj: S::ZERO,
            }
        } else if fresh {
            self.stream.tick(sample, hand, step)
        } else {
            self.stream.hold()
        };
        (step, g)
    }
}

/// What a tick does after the brush's force, whichever brush model made it: the guide's
/// pull added to it, the gate, and the output stage that turns the wanted force into the
/// command. Liang's [`ForceLoop`] and Baxter & Lin's loop
/// ([`crate::baxter_lin::force_loop`]) both end their ticks here.
#[derive(Clone, Debug)]
pub struct HandStage<S> {
    out: OutputStage<S>,
    guide: HandGuide<S>,
}

/// What [`HandStage::tick_with`] made of a brush's force.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct StageOut<S> {
    /// The output stage's command: the force on the hand (N, paper frame).
    pub command: Vec3<S>,
    /// The brush's force plus the guide's, before the output stage (N).
    pub wanted: Vec3<S>,
    /// The guide's force, distance and source energy this tick (zero while it is idle).
    pub guide: GuideForce<S>,
}

impl<S: Scalar> HandStage<S> {
    /// The output stage for `limits` (disabled until a tick's gate opens) and the guide
    /// `guide`.
    #[inline(always)]
    pub fn new(limits: DeviceLimits, guide: GuideParams) -> Result<Self, LimitError> {
        Ok(HandStage {
            out: OutputStage::new(limits)?,
            guide: HandGuide::new(guide)?,
        })
    }

    #[inline]
    pub fn output(&self) -> &OutputStage<S> {
        &self.out
    }

    #[inline]
    pub fn guide(&self) -> &HandGuide<S> {
        &self.guide
    }

    /// The guide starts afresh ([`HandGuide::restart`]).
    #[inline]
    pub fn restart_guide(&mut self) {
        self.guide.restart();
    }

    /// Puts a device's force limits in force. The output stage starts over disabled, so
    /// forces ramp in again from zero. Invalid limits are refused and the old ones kept.
    #[inline]
    pub fn set_limits(&mut self, limits: DeviceLimits) -> Result<(), LimitError> {
        if *self.out.limits() != limits {
            self.out = OutputStage::new(limits)?;
        }
        Ok(())
    }

    /// What the output stage is doing under a device's switch `enabled` with `faults`
    /// latched (the gate the next tick gets): faulted, disabled, ramping in or active.
    #[inline]
    pub fn output_state(&self, enabled: bool, faults: Faults) -> OutputState {
        if !faults.is_empty() {
            OutputState::Faulted
        } else if !enabled {
            OutputState::Disabled
        } else if self.out.state() == OutputState::Active {
            OutputState::Active
        } else {
            OutputState::RampingIn
        }
    }

    /// The brush's `force` with the hand at `hand` (`fresh`: a new pose came this tick):
    /// the guide's tick (through `guide_tick`, see [`TickParts`]) on `sample`, its pull
    /// added unless `gate` is faulted, and the output stage driving if `gate` allows.
    #[inline(always)]
    pub fn tick_with(
        &mut self,
        force: Vec3<S>,
        sample: Option<GuideInput<S>>,
        hand: Vec3<S>,
        fresh: bool,
        gate: Gate,
        guide_tick: GuideTick<S>,
    ) -> StageOut<S> {
        let (step, guide) = guide_tick(&mut self.guide, sample, hand, fresh, gate.faulted);
        let wanted = if gate.faulted {
            force
        } else {
            force + guide.force
        };
        if gate.allowed {
            if self.out.faulted() {
                self.out.clear_fault();
            }
            self.out.enable();
        } else {
            self.out.fault();
        }
        let command = self.out.apply_with_source(wanted, step, guide.source_mj);
        StageOut {
            command,
            wanted,
            guide,
        }
    }

    /// The energy the guide's spring stores with the hand at `hand` (J).
    pub fn guide_energy(&self, hand: Vec3<S>) -> f64 {
        let stream = self.guide.stream();
        match stream.anchor() {
            Some(a) => stream.guide().stored_energy(a, hand),
            None => 0.0,
        }
    }
}

/// Whether a pose at `pos` after one at `last` is a sensor fault: further apart than
/// `limit2`, the square of [`SENSOR_JUMP_MM`] in the caller's scalar.
#[inline(always)]
pub fn jumped<S: Scalar>(last: Vec3<S>, pos: Vec3<S>, limit2: S) -> bool {
    (pos - last).norm2() > limit2
}

/// The force loop's state: the brush, the force model, the guide and the output stage.
#[derive(Clone, Debug)]
pub struct ForceLoop<S: Scalar> {
    brush: Brush<S>,
    model: ForceModel<S>,
    stage: HandStage<S>,
    last_pose: Option<Pose<S>>,
    /// The next pose places the brush at rest rather than dragging it there.
    reanchor: bool,
    brush_ticks: u32,
    jump2: S,
}

impl<S: BrushScalar> ForceLoop<S> {
    /// The brush `params` at rest at `pose`, the force model `forces`, the output stage for
    /// `limits` (disabled until a tick's gate opens), the guide `guide`. No last pose: the
    /// first is not checked for a jump.
    pub fn new(
        params: BrushParams,
        pose: Pose<S>,
        forces: ForceParams,
        limits: DeviceLimits,
        guide: GuideParams,
    ) -> Result<Self, LoopError> {
        let mut lp = Self::unplaced(params, pose, forces, limits, guide)?;
        lp.brush.place(pose);
        Ok(lp)
    }

    /// [`Self::new`] built where it is to live (a static's storage): the loop is kilobytes,
    /// and a device pays for a copy through the stack at boot in stack it must reserve. The
    /// brush is built in place as [`Brush::new_in`] builds it.
    pub fn new_in(
        slot: &mut MaybeUninit<Self>,
        params: BrushParams,
        pose: Pose<S>,
        forces: ForceParams,
        limits: DeviceLimits,
        guide: GuideParams,
    ) -> Result<&mut Self, LoopError> {
        let lp = slot.write(Self::unplaced(params, pose, forces, limits, guide)?);
        lp.brush.place(pose);
        Ok(lp)
    }

    /// Every part validated and built, the brush not yet placed: inlined into both
    /// constructors so that `new_in` writes the fields straight into its slot.
    #[inline(always)]
    fn unplaced(
        params: BrushParams,
        pose: Pose<S>,
        forces: ForceParams,
        limits: DeviceLimits,
        guide: GuideParams,
    ) -> Result<Self, LoopError> {
        let model = ForceModel::new(forces)?;
        let stage = HandStage::new(limits, guide)?;
        Ok(ForceLoop {
            brush: Brush::unplaced(params, pose)?,
            model,
            stage,
            last_pose: None,
            reanchor: false,
            brush_ticks: 0,
            jump2: S::from_usize((SENSOR_JUMP_MM * SENSOR_JUMP_MM) as usize),
        })
    }

    pub fn brush(&self) -> &Brush<S> {
        &self.brush
    }

    /// The brush, for what does not move it (ink, a parameter that keeps its layout).
    pub fn brush_mut(&mut self) -> &mut Brush<S> {
        &mut self.brush
    }

    pub fn model(&self) -> &ForceModel<S> {
        &self.model
    }

    pub fn output(&self) -> &OutputStage<S> {
        self.stage.output()
    }

    pub fn guide(&self) -> &GuideStream<S> {
        self.stage.guide().stream()
    }

    /// Brush ticks (poses consumed) since the brush was last put at rest.
    pub fn brush_ticks(&self) -> u32 {
        self.brush_ticks
    }

    /// The last pose consumed (none since the loop was built or [`Self::forget_pose`]).
    pub fn last_pose(&self) -> Option<Pose<S>> {
        self.last_pose
    }

    /// The next pose places the brush at rest there, however far it is from the last.
    pub fn reanchor(&mut self) {
        self.reanchor = true;
    }

    /// A re-anchor is pending: the brush waits for a pose to be placed at.
    pub fn reanchoring(&self) -> bool {
        self.reanchor
    }

    /// Forgets the last pose (the pose moved under the hand: new geometry or zeros), so the
    /// next is not checked for a jump; the hand is at the origin until then.
    pub fn forget_pose(&mut self) {
        self.last_pose = None;
    }

    /// The forces start afresh: the model's filters and dragged mass, the guide from zero,
    /// no step for the next hand position.
    pub fn restart_forces(&mut self) {
        self.model.reset();
        self.stage.restart_guide();
    }

    /// The brush at rest at `pose`, the forces afresh, the tick count from zero.
    pub fn reset_brush(&mut self, pose: Pose<S>) {
        self.brush.reset(pose);
        self.restart_forces();
        self.brush_ticks = 0;
    }

    /// Replaces every brush parameter (on error nothing changes) and puts the brush at rest
    /// at its handle, the forces afresh.
    pub fn set_params(&mut self, params: BrushParams) -> Result<(), ParamError> {
        self.brush.set_params(params)?;
        let pose = self.brush.handle();
        self.reset_brush(pose);
        Ok(())
    }

    /// Puts a device's force limits in force. The output stage starts over disabled, so
    /// forces ramp in again from zero. Invalid limits are refused and the old ones kept.
    pub fn set_limits(&mut self, limits: DeviceLimits) -> Result<(), LimitError> {
        self.stage.set_limits(limits)
    }

    /// What the output stage is doing under a device's switch `enabled` with `faults`
    /// latched (the gate the next tick gets): faulted, disabled, ramping in or active.
    pub fn output_state(&self, enabled: bool, faults: Faults) -> OutputState {
        self.stage.output_state(enabled, faults)
    }

    /// One tick (see the module docs).
    pub fn tick(&mut self, input: TickIn<S>) -> TickOut<S> {
        self.tick_with(input, &TickParts::here())
    }

    /// [`Self::tick`] with the guide's tick and the brush's reset that `parts` name.
    pub fn tick_with(&mut self, input: TickIn<S>, parts: &TickParts<S>) -> TickOut<S> {
        let mut raised = Faults::empty();
        let fresh = match input.pose {
            Some(pose) if self.reanchor => {
                self.reanchor = false;
                (parts.reset)(&mut self.brush, pose);
                self.restart_forces();
                self.brush_ticks = 0;
                self.last_pose = Some(pose);
                true
            }
            Some(pose) => {
                if let Some(prev) = self.last_pose {
                    if jumped(prev.pos, pose.pos, self.jump2) {
                        raised |= Faults::SENSOR_JUMP;
                    }
                }
                self.brush.tick(pose);
                self.brush_ticks = self.brush_ticks.wrapping_add(1);
                self.last_pose = Some(pose);
                true
            }
            None => false,
        };
        let gate = input.gate.with_raised(raised);
        let hand = match self.last_pose {
            Some(p) => p.pos,
            None => Vec3::ZERO,
        };
        let forces = self.model.tick(&self.brush, hand);
        let out = self
            .stage
            .tick_with(forces.total, input.guide, hand, fresh, gate, parts.guide);
        TickOut {
            command: out.command,
            forces,
            wanted: out.wanted,
            guide: out.guide,
            faults: raised,
        }
    }

    /// Energy the virtual environment stores now, with the hand at the last pose (J): the
    /// force model's ([`stored_energy`]) and the guide's spring. The passivity audit's `E`,
    /// less the stylus's own kinetic energy.
    pub fn stored_energy(&self) -> f64 {
        let hand = match self.last_pose {
            Some(p) => p.pos,
            None => Vec3::ZERO,
        };
        stored_energy(&self.brush, &self.model, hand) + self.stage.guide_energy(hand)
    }
}

/// Energy the force model's virtual environment stores with the hand's ferrule at `hand`
/// (J), as the passivity audit counts it: the dragged inertia mass and its spring, the
/// friction's bristle, the paper's god-object spring, the normal force as the spring it
/// models (`F_n^2 L_p / (2 w_n)`, with the model's L_p) and gravity's potential of the brush's
/// weight.
pub fn stored_energy<S: Scalar>(brush: &Brush<S>, model: &ForceModel<S>, hand: Vec3<S>) -> f64 {
    let p = model.params();
    let k_c = p.constraint_stiffness as f64;
    let w_n = p.normal_weight as f64;
    let weight = p.gravity_weight as f64 * p.brush_mass_g as f64 * 1e-3 * G;
    let x = hand.to_f64();
    let pen = (-x[2]).max(0.0) * 1e-3;
    let skel = brush.skeleton();
    let lowest = skel.iter().fold(S::from_f64(f64::MAX), |m, v| m.min(v.z));
    let top = skel.first().map_or(S::ZERO, |v| v.z);
    let extent = model.normal_extent(top - lowest).to_f64() * 1e-3;
    let f_n = model.normal_state().to_f64();
    model.inertia_energy(hand)
        + model.friction_energy()
        + 0.5 * k_c * pen * pen
        + if w_n > 0.0 {
            f_n * f_n * extent / (2.0 * w_n)
        } else {
            0.0
        }
        + weight * x[2] * 1e-3
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::force::{DEFAULT_FORCES, PHANTOM_OMNI};
    use crate::guide::DEFAULT_GUIDE;
    use crate::{presets, Fx, Quat};

    fn at(x: f64, z: f64) -> Pose<Fx> {
        Pose::new(Vec3::from_f64([x, 0.0, z]), Quat::IDENTITY)
    }

    fn new_loop() -> ForceLoop<Fx> {
        ForceLoop::new(
            presets::LARGE,
            at(0.0, 45.0),
            DEFAULT_FORCES,
            PHANTOM_OMNI,
            DEFAULT_GUIDE,
        )
        .unwrap()
    }

    const OPEN: Gate = Gate {
        allowed: true,
        faulted: false,
    };

    fn input(pose: Option<Pose<Fx>>, guide: Option<GuideInput<Fx>>) -> TickIn<Fx> {
        TickIn {
            pose,
            guide,
            gate: OPEN,
        }
    }

    #[test]
    fn built_in_place_is_the_same_loop() {
        let mut slot = MaybeUninit::uninit();
        let a = ForceLoop::new_in(
            &mut slot,
            presets::LARGE,
            at(0.0, 45.0),
            DEFAULT_FORCES,
            PHANTOM_OMNI,
            DEFAULT_GUIDE,
        )
        .unwrap();
        let mut b = new_loop();
        for k in 0..50 {
            let i = input(Some(at(0.1 * k as f64, 45.0 - 0.2 * k as f64)), None);
            assert_eq!(a.tick(i), b.tick(i));
        }
        assert_eq!(a.brush().spine(), b.brush().spine());
    }

    #[test]
    fn a_jump_raises_a_fault_holds_the_forces_and_cuts_the_guide_that_tick() {
        let mut fl = new_loop();
        let lead = |x: f64| {
            Some(GuideInput {
                anchor: Vec3::from_f64([x, 3.0, 45.0]),
                on: true,
            })
        };
        for k in 0..400 {
            let out = fl.tick(input(
                Some(at(0.01 * k as f64, 45.0)),
                lead(0.01 * k as f64),
            ));
            assert!(out.faults.is_empty());
        }
        assert!(fl.guide().active());
        assert!(fl.output().last_command() != Vec3::ZERO);
        let out = fl.tick(input(Some(at(20.0, 45.0)), lead(20.0)));
        assert_eq!(out.faults, Faults::SENSOR_JUMP);
        assert!(!fl.guide().active(), "the guide is cut at once");
        assert_eq!(out.guide.force, Vec3::ZERO);
        assert_eq!(out.wanted, out.forces.total);
        assert_eq!(
            out.command,
            Vec3::ZERO,
            "the Omni's stage ramps out at once"
        );
        // The brush did follow the pose (only the forces are held).
        assert_eq!(fl.last_pose(), Some(at(20.0, 45.0)));
        // A step within the limit is no fault.
        let out = fl.tick(input(Some(at(29.9, 45.0)), None));
        assert!(out.faults.is_empty());
    }

    #[test]
    fn a_reanchor_places_the_brush_at_rest_without_a_jump() {
        let mut fl = new_loop();
        for k in 0..100 {
            fl.tick(input(
                Some(at(0.05 * k as f64, 45.0 - 0.1 * k as f64)),
                None,
            ));
        }
        fl.reanchor();
        assert!(fl.reanchoring());
        let far = at(60.0, 50.0);
        let out = fl.tick(input(Some(far), None));
        assert!(out.faults.is_empty());
        assert!(!fl.reanchoring());
        assert_eq!(fl.brush_ticks(), 0);
        let rest = Brush::<Fx>::new(presets::LARGE, far).unwrap();
        assert_eq!(fl.brush().spine(), rest.spine());
    }

    #[test]
    fn a_tick_without_a_pose_holds_the_brush_and_the_guide() {
        let mut fl = new_loop();
        let sample = Some(GuideInput {
            anchor: Vec3::from_f64([5.0, 0.0, 45.0]),
            on: true,
        });
        for k in 0..100 {
            fl.tick(input(Some(at(0.01 * k as f64, 45.0)), sample));
        }
        let spine = fl.brush().spine().to_vec();
        let gain = fl.guide().guide().gain();
        let last = fl.tick(input(Some(at(1.0, 45.0)), sample));
        for _ in 0..3 * crate::guide::GUIDE_TIMEOUT_TICKS {
            let out = fl.tick(input(None, None));
            assert_eq!(out.guide.force, last.guide.force, "the guide's force holds");
            assert_eq!(out.guide.source_mj, Fx::ZERO);
        }
        assert_ne!(
            fl.brush().spine(),
            &spine[..],
            "the pose before did move it"
        );
        let held = fl.brush().spine().to_vec();
        fl.tick(input(None, None));
        assert_eq!(fl.brush().spine(), &held[..], "no pose, no brush tick");
        assert!(fl.guide().guide().gain() >= gain);
    }

    #[test]
    fn the_stored_energy_counts_the_guides_spring() {
        let mut fl = new_loop();
        let sample = Some(GuideInput {
            anchor: Vec3::from_f64([5.0, 0.0, 45.0]),
            on: true,
        });
        let out = fl.tick(input(Some(at(0.0, 45.0)), None));
        assert!(out.faults.is_empty());
        let alone = stored_energy(fl.brush(), fl.model(), Vec3::from_f64([0.0, 0.0, 45.0]));
        assert_eq!(fl.stored_energy(), alone, "no guide, no spring");
        for _ in 0..400 {
            fl.tick(input(Some(at(0.0, 45.0)), sample));
        }
        assert!(fl.stored_energy() > alone + 1e-4, "5 mm of guide spring");
    }
}
