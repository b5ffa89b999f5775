//! The servo loop: the shared brush and force model inside OpenHaptics' 1 kHz scheduler.
//!
//! [`ServoCore`] is the loop's arithmetic with no HD calls (unit-testable): the device pose
//! (HD_CURRENT_TRANSFORM) mapped to the paper by a [`Mapping`], one `Brush<Fx>` tick, the
//! force model and the output stage (limits from the device's own HD_NOMINAL_MAX_FORCE and
//! HD_NOMINAL_MAX_CONTINUOUS_FORCE, ramp-in on enable), the command mapped back to device
//! axes. [`Bridge`] runs it in an `hdScheduleAsynchronous` callback.
//!
//! With Baxter & Lin's brush ([`ServoBrush::BaxterLin`]) the callback runs only the loop's
//! 1 kHz half, their local force model and the same guide, gate and output stage; the brush
//! itself is solved on a thread of its own ([`super::solver`]).
//!
//! # One frame per tick, the force decided inside it
//! libHD allows one `hdBeginFrame`/`hdEndFrame` pair per servo tick (a second is refused with
//! HD_ILLEGAL_BEGIN, and its force never reaches the motors). So each callback opens exactly
//! one frame, reads the pose and the whole HD error stack, decides the force (zero on any
//! fault: an error, a stop, the tick limit, a panic in the model, which is caught inside the
//! frame) and commits it with the frame's end. Errors are sorted as the SDK's `hduError`
//! helpers sort them ([`super::hd::classify`]): a device warning (force, force impulse,
//! velocity, warm motors) zeroes the force, restarts the brush at rest and latches
//! [`Faults::DEVICE_WARNING`] until the user clears it, and the loop goes on; anything else
//! (communication, configuration, timer, scheduler errors; device faults; a misused call)
//! stops it, reported with `hdGetErrorString`'s text.
//!
//! # Calibration and the safe start
//! `hdCheckCalibration` runs at the first tick, when the user calibrates, and periodically;
//! when the library can update the calibration the callback does (`hdUpdateCalibration`, in
//! its frame), and the jump of the pose that follows is no sensor jump: the brush starts
//! afresh at the new pose. While the library asks for the inkwell, [`Faults::NOT_CALIBRATED`]
//! is reported and forces are held. Forces asked for at start wait until the stylus has been
//! seen with the brush clear above the paper (a stylus resting in the inkwell is below it),
//! unless the user enables them.
//!
//! # Why `Fx` and not `f32`
//! Measured by `cargo bench -p maobi --bench servo` (`host/benches/servo.rs`): see
//! docs/phantom.md for the numbers. Both are far inside the 1 ms budget, so the cost does
//! not decide it; what does is that the wire protocol's
//! [`BrushState`] carries `Fx` bits, so with `Fx` the bridge's brush is bit for bit the
//! brush the pen's firmware and `maobi sim-device` would compute for the same poses, and the
//! GUI draws it with the same code.
//!
//! # The handoff to the GUI / TCP side never blocks the callback
//! States (at `state_hz`, 120 by default) go into a bounded queue ([`STATE_QUEUE`] states,
//! its memory reserved up front) that the callback only ever `try_lock`s: if the reader
//! holds the lock at that instant the state is skipped and counted, never waited for; if the
//! reader has fallen [`STATE_QUEUE`] states behind, the oldest is dropped and counted. A
//! queue rather than a single slot, so a reader that wakes late (a loaded machine) still
//! forwards every state. Commands come the other way through a `try_lock`ed queue (a busy
//! queue is read the next tick). No allocation happens in the callback (the brush and
//! `BrushState` are fixed-size; neither queue grows past its reserved capacity there).

use std::collections::VecDeque;
use std::ffi::{c_int, c_void};
use std::panic::AssertUnwindSafe;
use std::sync::atomic::{AtomicBool, AtomicI32, AtomicU32, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use crate::device::lane::HostLane;
use maobi_shared::baxter_lin::force_loop::BaxterLinHand;
use maobi_shared::baxter_lin::head::HeadShape;
use maobi_shared::baxter_lin::local_force::{LocalForceModel, LocalForceParams};
use maobi_shared::force::DEFAULT_FORCES;
use maobi_shared::force::{DeviceLimits, OutputState, PHANTOM_OMNI};
use maobi_shared::force_loop::{Gate, TickIn};
use maobi_shared::guide::{GuidePlay, DEFAULT_GUIDE};
use maobi_shared::protocol::{BrushState, Faults, Haptics};
use maobi_shared::{presets, BrushParams, ForceLoop, Fx, Pose, Quat, Scalar, Vec3};

use super::hd::*;
use super::loader::{HdFns, HdLib};
use super::solver::{SolveRequest, SolverLink, SolverThread};
use crate::device::GuideFrame;

/// States the handoff queue holds (half a second at 120 Hz).
pub const STATE_QUEUE: usize = 64;

/// Device positions beyond this (mm) are garbage, not a pose (the Omni's workspace is about
/// 160 x 120 x 70 mm).
pub const MAX_DEVICE_MM: f64 = 2000.0;

/// The bridge's default paper height: the device height (mm) of the ferrule at the paper.
/// It must sit above where a Touch's stylus reads when it rests in the inkwell (about
/// y = -65.6 mm), so that the stylus in the inkwell is below the paper and the safe start
/// holds forces until the stylus has been lifted above it; and low enough that the large
/// brush (40 mm) has room above the paper in the workspace. `maobi bridge --paper-height`
/// and the GUI's `--device phantom` start from it; the model itself has no paper height.
pub const DEFAULT_PAPER_HEIGHT_MM: f64 = -60.0;

/// Servo ticks between two calibration checks (`hdCheckCalibration`) while the device is
/// calibrated, as the SDK's Calibration example checks once a second.
pub const CAL_CHECK_TICKS: u32 = 1000;
/// The same while it is not: the inkwell is noticed within this many ticks.
pub const CAL_CHECK_WAITING_TICKS: u32 = 100;
/// At most this many errors are read off the HD error stack in one tick (a library that
/// never returns HD_SUCCESS must not hold the callback).
pub const MAX_ERRORS_PER_TICK: usize = 64;

/// How the Phantom's workspace maps to the paper.
///
/// Device frame (OpenHaptics): +x to the user's right, +y up, +z toward the user, mm. Paper
/// frame (the model): +x right, +y away from the user, +z up, the paper at z = 0. So
/// `paper = scale * (dx - ox, -(dz - oz), dy - paper_height)`. Orientation: the paper frame's
/// rotation is the device rotation seen in paper axes, assuming the stylus points along its
/// own -z (away from the user when the gimbal reads identity), so that holding the stylus
/// upright, tip down, is the model's identity (brush hanging straight down). That stylus
/// convention is from the OpenHaptics programmer's guide's description of the gimbal and has
/// not been checked on a device (see docs/phantom.md).
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct Mapping {
    /// Device (x, z) above the paper's centre (mm).
    pub origin_mm: [f64; 2],
    /// Device y of the ferrule when it is at the paper (mm): the paper's height.
    pub paper_height_mm: f64,
    /// Paper millimetres per device millimetre. Forces are not scaled: the device feels
    /// `scale` times the model's stiffness (keep it near 1 for the passivity budget).
    pub scale: f64,
}

impl Default for Mapping {
    /// The Omni's and the Touch's workspace centre is near the device origin; a paper 60 mm
    /// below it leaves the large brush (40 mm) room above the paper.
    fn default() -> Self {
        Mapping {
            origin_mm: [0.0, 0.0],
            paper_height_mm: DEFAULT_PAPER_HEIGHT_MM,
            scale: 1.0,
        }
    }
}

/// The device-to-paper axis change, `R_x(+90 degrees)` (w, x, y, z).
fn axes_quat() -> Quat<f64> {
    let h = std::f64::consts::FRAC_1_SQRT_2;
    Quat::new(h, h, 0.0, 0.0)
}

impl Mapping {
    /// Checks the numbers (finite, a positive scale).
    pub fn validate(&self) -> Result<(), String> {
        let all = [
            self.origin_mm[0],
            self.origin_mm[1],
            self.paper_height_mm,
            self.scale,
        ];
        if all.iter().any(|v| !v.is_finite()) {
            return Err("the workspace mapping has a non-finite number".into());
        }
        if !(1e-3..=1e3).contains(&self.scale) {
            return Err(format!("--scale {} is outside 0.001 ..= 1000", self.scale));
        }
        Ok(())
    }

    /// The paper pose of a device pose (position mm, unit quaternion w, x, y, z).
    pub fn to_paper(&self, pos: [f64; 3], rot: Quat<f64>) -> Pose<f64> {
        let s = self.scale;
        let p = Vec3::new(
            s * (pos[0] - self.origin_mm[0]),
            -s * (pos[2] - self.origin_mm[1]),
            s * (pos[1] - self.paper_height_mm),
        );
        Pose::new(p, axes_quat().compose(rot).normalized())
    }

    /// The device pose of a paper pose (the inverse of [`Mapping::to_paper`]).
    pub fn to_device(&self, pose: Pose<f64>) -> ([f64; 3], Quat<f64>) {
        let s = self.scale;
        let p = pose.pos.to_f64();
        let pos = [
            p[0] / s + self.origin_mm[0],
            p[2] / s + self.paper_height_mm,
            -p[1] / s + self.origin_mm[1],
        ];
        (pos, axes_quat().conj().compose(pose.rot).normalized())
    }

    /// A paper-frame force in device axes (not scaled, see [`Mapping::scale`]).
    pub fn force_to_device(f: [f64; 3]) -> [f64; 3] {
        [f[0], f[2], -f[1]]
    }

    /// Calibration: the device's current height becomes "the brush tip just touches the
    /// paper" for a brush of `length_mm` hanging straight down.
    pub fn calibrate(&mut self, device_y_mm: f64, length_mm: f64) {
        self.paper_height_mm = device_y_mm - length_mm / self.scale;
    }
}

/// Position (mm) and rotation of a column-major 4x4 transform; `None` if it is not finite or
/// not a rotation (a garbage read).
pub fn pose_of_transform(m: &[f64; 16]) -> Option<([f64; 3], Quat<f64>)> {
    if m.iter().any(|v| !v.is_finite()) {
        return None;
    }
    // Column-major: element (row i, column j) is m[4 j + i].
    let r = |i: usize, j: usize| m[4 * j + i];
    let pos = [m[12], m[13], m[14]];
    if pos.iter().any(|v| v.abs() > MAX_DEVICE_MM) {
        return None;
    }
    // Shepperd's method: pick the largest of w, x, y, z to divide by.
    let tr = r(0, 0) + r(1, 1) + r(2, 2);
    let (w, x, y, z);
    if tr > 0.0 {
        let s = (tr + 1.0).sqrt() * 2.0;
        w = 0.25 * s;
        x = (r(2, 1) - r(1, 2)) / s;
        y = (r(0, 2) - r(2, 0)) / s;
        z = (r(1, 0) - r(0, 1)) / s;
    } else if r(0, 0) > r(1, 1) && r(0, 0) > r(2, 2) {
        let s = (1.0 + r(0, 0) - r(1, 1) - r(2, 2)).max(0.0).sqrt() * 2.0;
        w = (r(2, 1) - r(1, 2)) / s;
        x = 0.25 * s;
        y = (r(0, 1) + r(1, 0)) / s;
        z = (r(0, 2) + r(2, 0)) / s;
    } else if r(1, 1) > r(2, 2) {
        let s = (1.0 + r(1, 1) - r(0, 0) - r(2, 2)).max(0.0).sqrt() * 2.0;
        w = (r(0, 2) - r(2, 0)) / s;
        x = (r(0, 1) + r(1, 0)) / s;
        y = 0.25 * s;
        z = (r(1, 2) + r(2, 1)) / s;
    } else {
        let s = (1.0 + r(2, 2) - r(0, 0) - r(1, 1)).max(0.0).sqrt() * 2.0;
        w = (r(1, 0) - r(0, 1)) / s;
        x = (r(0, 2) + r(2, 0)) / s;
        y = (r(1, 2) + r(2, 1)) / s;
        z = 0.25 * s;
    }
    let n = (w * w + x * x + y * y + z * z).sqrt();
    // A rotation's quaternion has norm 1; far from it the matrix was not a rotation.
    if !n.is_finite() || (n - 1.0).abs() > 0.1 {
        return None;
    }
    Some((pos, Quat::new(w / n, x / n, y / n, z / n)))
}

/// The column-major transform of a position and rotation (the stand-in's and the tests'
/// side of [`pose_of_transform`]).
pub fn transform_of_pose(pos: [f64; 3], q: Quat<f64>) -> [f64; 16] {
    let (w, x, y, z) = (q.w, q.x, q.y, q.z);
    let r = [
        [
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y - w * z),
            2.0 * (x * z + w * y),
        ],
        [
            2.0 * (x * y + w * z),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z - w * x),
        ],
        [
            2.0 * (x * z - w * y),
            2.0 * (y * z + w * x),
            1.0 - 2.0 * (x * x + y * y),
        ],
    ];
    let mut m = [0.0; 16];
    for j in 0..3 {
        for i in 0..3 {
            m[4 * j + i] = r[i][j];
        }
    }
    m[12] = pos[0];
    m[13] = pos[1];
    m[14] = pos[2];
    m[15] = 1.0;
    m
}

/// What the stylus buttons ask for, decided when the buttons are released (so a chord is
/// not first taken for its single buttons).
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub enum ButtonAction {
    /// Button 1 alone: dip the brush in ink.
    Dip,
    /// Button 2 alone: forces on or off.
    ToggleForces,
    /// Both together (acted on as soon as both are down): calibrate the paper height.
    Calibrate,
}

/// Turns the raw HD_CURRENT_BUTTONS mask into [`ButtonAction`]s.
#[derive(Copy, Clone, Debug, Default)]
pub struct Buttons {
    /// Buttons seen down since all were last up.
    pressed: c_int,
    chord_done: bool,
}

impl Buttons {
    pub fn update(&mut self, mask: c_int) -> Option<ButtonAction> {
        let both = HD_DEVICE_BUTTON_1 | HD_DEVICE_BUTTON_2;
        let mask = mask & both;
        if mask != 0 {
            self.pressed |= mask;
            if self.pressed == both && !self.chord_done {
                self.chord_done = true;
                return Some(ButtonAction::Calibrate);
            }
            return None;
        }
        let was = std::mem::take(&mut self.pressed);
        let chord = std::mem::take(&mut self.chord_done);
        match was {
            _ if chord => None,
            HD_DEVICE_BUTTON_1 => Some(ButtonAction::Dip),
            HD_DEVICE_BUTTON_2 => Some(ButtonAction::ToggleForces),
            _ => None,
        }
    }
}

/// A command from the GUI or the TCP host to the servo loop.
#[derive(Clone, Debug, PartialEq)]
pub enum ServoCommand {
    EnableForces(bool),
    ClearFaults,
    /// Wet every layer to this wetness (clamped to [0, 1]).
    Dip(f32),
    /// Calibrate: check the device's own calibration (`hdCheckCalibration`, updated if the
    /// library can), then record the height of the stylus as the paper (see
    /// [`Mapping::calibrate`]) from the next pose.
    Calibrate,
    /// Replace the brush parameters (already validated); the brush is reset.
    SetParams(BrushParams),
    ResetBrush,
    /// Guided writing: the stroke's moving point, one position per servo tick (paper frame,
    /// mm, the pose track resampled at 1 kHz), played from the next tick; the shared
    /// force loop's guide pulls the stylus toward it inside the output stage. `None` stops it:
    /// the point reached is held while the guide fades out.
    Guide(Option<GuidePoints>),
    /// Stay in the lane around a stroke's path ([`crate::device::lane`]), replacing guided
    /// writing; `None` lets go (the guide fades out).
    Lane(Option<Box<HostLane>>),
}

/// A guide stroke's moving point, one per servo tick, in the paper frame (mm).
pub type GuidePoints = Arc<[Vec3<Fx>]>;

/// The brush model the servo loop runs.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Default)]
pub enum ServoBrush {
    /// Liang's brush in the pen's own loop and number type, inside the callback.
    #[default]
    Liang,
    /// Baxter & Lin's brush of this head, solved on a thread of its own
    /// ([`super::solver`]); the callback runs its local force model.
    BaxterLin(HeadShape),
}

/// What the servo loop hands over for the GUI at a state's tick.
// Not boxed: the callback hands states over into a queue whose room is reserved up front, and
// a box would be an allocation in the callback.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Debug, PartialEq)]
pub enum ServoState {
    /// Liang's brush: the wire protocol's state, the pen's own.
    Brush(BrushState),
    /// Baxter & Lin's brush: the hand's side only (the brush's shape comes from the solver
    /// thread, [`SolverLink::brush`]).
    Hand(HandState),
}

/// The servo loop's side of a Baxter & Lin state.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct HandState {
    pub tick: u32,
    /// The brush's generation (see [`super::solver`]): the solver's brush of the same one
    /// is drawn with it.
    pub generation: u32,
    /// The handle, paper frame (mm).
    pub pose: Pose<f64>,
    /// The brush's force from the local model, and the output stage's command (N, paper
    /// frame).
    pub force: [f64; 3],
    pub command: [f64; 3],
    pub output: OutputState,
    pub faults: Faults,
}

/// Baxter & Lin's brush in the servo callback: the hand's half of the loop, the last model
/// the solver thread published, and what the next request to it carries.
struct BaxterLinServo {
    hand: BaxterLinHand,
    model: LocalForceModel,
    params: BrushParams,
    link: Arc<SolverLink>,
    /// The brush's generation (see [`super::solver`]); a restart starts the next at the next
    /// pose.
    generation: u32,
    restart: bool,
    /// The servo tick this generation began at, of its last request, and of the pose the
    /// model felt was solved at.
    began: u32,
    last_request: Option<u32>,
    solved_at: Option<u32>,
    rebuild_every: u32,
    /// A model felt this many ticks after its pose is stale
    /// ([`LocalForceParams::stale_after_ticks`]).
    stale_after: u32,
    /// The last pose and the brush's force there.
    pose: Option<Pose<f64>>,
    force: Vec3<f64>,
}

/// The model inside the servo loop.
// One per bridge, boxed inside the callback's context.
#[allow(clippy::large_enum_variant)]
enum ServoModel {
    /// Re-anchored until the first valid pose (the brush starts at rest where the hand is),
    /// and again after every restart of the brush.
    Liang(ForceLoop<Fx>),
    BaxterLin(BaxterLinServo),
}

/// The servo loop's model, with no HD calls: the shared force loop (or Baxter & Lin's hand
/// stage and its solver's models), with the forces switch, the safe start and the latched
/// faults that make its gate.
pub struct ServoCore {
    model: ServoModel,
    mapping: Mapping,
    buttons: Buttons,
    /// The forces switch (the user's, or the safe start's).
    enabled: bool,
    /// Latched faults (cleared by [`ServoCommand::ClearFaults`]).
    faults: Faults,
    /// The safe start: forces are asked for but held until the stylus has been seen with the
    /// brush clear above the paper (or the user enables them).
    await_lift: bool,
    /// The HD library wants the stylus in the inkwell (HD_CALIBRATION_NEEDS_MANUAL_INPUT):
    /// reported as [`Faults::NOT_CALIBRATED`], forces held.
    uncalibrated: bool,
    /// A paper calibration to do at the next pose, and a device calibration check asked for.
    paper_cal_pending: bool,
    device_cal_requested: bool,
    tick: u32,
    /// The output stage's last command (N, paper frame).
    command: Vec3<f64>,
    /// Guided writing: the stroke being played into the loop's guide, and this tick's
    /// figures for the state.
    guide_play: Option<GuidePlay<GuidePoints>>,
    /// "Stay in the lane", while it is on (or its guide fades out).
    lane: Option<Box<HostLane>>,
    guide_frame: Option<GuideFrame>,
}

impl ServoCore {
    /// `limits`: the device's (from HD_NOMINAL_MAX_*). With `forces_on`, forces ramp in from
    /// the first tick at which the brush hangs clear above the paper (the safe start: the
    /// stylus may rest in the inkwell, below the paper).
    pub fn new(
        params: BrushParams,
        limits: DeviceLimits,
        mapping: Mapping,
        forces_on: bool,
    ) -> Result<ServoCore, String> {
        // Placed at the first valid pose.
        let nowhere = Pose::new(Vec3::ZERO, Quat::IDENTITY);
        let mut fl = ForceLoop::new(params, nowhere, DEFAULT_FORCES, limits, DEFAULT_GUIDE)
            .map_err(|e| e.to_string())?;
        fl.reanchor();
        Self::with_model(ServoModel::Liang(fl), mapping, forces_on)
    }

    /// As [`Self::new`], with Baxter & Lin's brush: `params` (validated, and read as
    /// [`crate::device::BrushChoice::baxter_lin_reads`] says) go to the solver serving
    /// `link` with each new brush; the callback's local model is rebuilt at the rate
    /// [`LocalForceParams::for_device`] gives for `limits`.
    pub fn baxter_lin(
        params: BrushParams,
        limits: DeviceLimits,
        mapping: Mapping,
        forces_on: bool,
        link: Arc<SolverLink>,
    ) -> Result<ServoCore, String> {
        let hand = BaxterLinHand::new(limits, DEFAULT_GUIDE).map_err(|e| e.to_string())?;
        let local = LocalForceParams::for_device(&limits);
        let servo = BaxterLinServo {
            hand,
            model: LocalForceModel::NONE,
            params,
            link,
            generation: 0,
            restart: true,
            began: 0,
            last_request: None,
            solved_at: None,
            rebuild_every: local.rebuild_every.max(1),
            stale_after: local.stale_after_ticks(),
            pose: None,
            force: Vec3::ZERO,
        };
        Self::with_model(ServoModel::BaxterLin(servo), mapping, forces_on)
    }

    fn with_model(
        model: ServoModel,
        mapping: Mapping,
        forces_on: bool,
    ) -> Result<ServoCore, String> {
        mapping.validate()?;
        Ok(ServoCore {
            model,
            mapping,
            buttons: Buttons::default(),
            enabled: false,
            faults: Faults::empty(),
            await_lift: forces_on,
            uncalibrated: false,
            paper_cal_pending: false,
            device_cal_requested: false,
            tick: 0,
            command: Vec3::ZERO,
            guide_play: None,
            lane: None,
            guide_frame: None,
        })
    }

    pub fn tick(&self) -> u32 {
        self.tick
    }
    pub fn mapping(&self) -> Mapping {
        self.mapping
    }
    pub fn params(&self) -> &BrushParams {
        match &self.model {
            ServoModel::Liang(fl) => fl.brush().params(),
            ServoModel::BaxterLin(b) => &b.params,
        }
    }
    pub fn output_state(&self) -> OutputState {
        match &self.model {
            ServoModel::Liang(fl) => fl.output_state(self.enabled, self.faults),
            ServoModel::BaxterLin(b) => b.hand.output_state(self.enabled, self.faults),
        }
    }
    /// The faults to report: the latched ones, and [`Faults::NOT_CALIBRATED`] while the
    /// library asks for the inkwell.
    pub fn faults(&self) -> Faults {
        if self.uncalibrated {
            self.faults | Faults::NOT_CALIBRATED
        } else {
            self.faults
        }
    }
    /// Forces are asked for but wait for the stylus above the paper (or for calibration).
    pub fn awaiting_lift(&self) -> bool {
        self.await_lift
    }
    pub fn forces_enabled(&self) -> bool {
        self.enabled && self.faults.is_empty()
    }

    pub fn apply(&mut self, cmd: ServoCommand) {
        match cmd {
            // The user's explicit enable skips the wait for the stylus above the paper; while
            // the library asks for the inkwell, forces wait for the calibration (and then for
            // the stylus out of the inkwell, above the paper).
            ServoCommand::EnableForces(true) if self.faults.is_empty() => {
                if self.uncalibrated {
                    self.await_lift = true;
                } else {
                    self.await_lift = false;
                    self.enabled = true;
                }
            }
            // With faults latched, enabling waits for ClearFaults (as the firmware does).
            ServoCommand::EnableForces(true) => {}
            ServoCommand::EnableForces(false) => {
                self.await_lift = false;
                self.enabled = false;
            }
            ServoCommand::ClearFaults => self.faults = Faults::empty(),
            ServoCommand::Dip(w) => {
                // (A brush waiting for its first pose is placed wet as configured.)
                let w = if w.is_finite() {
                    w.clamp(0.0, 1.0)
                } else {
                    0.0
                };
                match &mut self.model {
                    ServoModel::Liang(fl) => fl.brush_mut().dip(Fx::from_f32(w)),
                    // At the solver's next solve.
                    ServoModel::BaxterLin(b) => b.link.dip(w),
                }
            }
            ServoCommand::Calibrate => {
                // The device's calibration is checked first (by the servo callback, before
                // the next step), so the paper height is taken from a calibrated pose.
                self.paper_cal_pending = true;
                self.device_cal_requested = true;
            }
            ServoCommand::SetParams(p) => {
                let taken = match &mut self.model {
                    ServoModel::Liang(fl) => fl.brush_mut().set_params(p).is_ok(),
                    // Checked by the sender; the solver builds the next brush with them.
                    ServoModel::BaxterLin(b) => {
                        b.params = p;
                        true
                    }
                };
                if taken {
                    self.restart_brush();
                }
            }
            ServoCommand::ResetBrush => self.restart_brush(),
            ServoCommand::Guide(Some(points)) => {
                if !points.is_empty() {
                    self.guide_play = Some(GuidePlay::new(points));
                    self.lane = None;
                }
            }
            ServoCommand::Guide(None) => {
                if let Some(play) = &mut self.guide_play {
                    play.stop();
                }
            }
            ServoCommand::Lane(Some(lane)) => {
                self.guide_play = None;
                self.lane = Some(lane);
            }
            ServoCommand::Lane(None) => {
                if let Some(l) = &mut self.lane {
                    l.stop();
                }
            }
        }
    }

    /// The brush starts afresh, at rest, at the next pose (no sensor-jump check), the forces
    /// from zero, the guide cut.
    fn restart_brush(&mut self) {
        match &mut self.model {
            ServoModel::Liang(fl) => {
                fl.reanchor();
                fl.restart_forces();
            }
            ServoModel::BaxterLin(b) => {
                // No force until the new brush's first model: none of the old brush's is
                // felt at the new pose.
                b.restart = true;
                b.model = LocalForceModel::NONE;
                b.hand.restart();
            }
        }
        self.cut_guide();
    }

    /// Drops the guidance at once (faults, a new brush): no guide force from this tick.
    fn cut_guide(&mut self) {
        self.guide_play = None;
        self.lane = None;
        self.guide_frame = None;
    }

    /// Guided writing is on (or fading out).
    pub fn guiding(&self) -> bool {
        self.guide_play.is_some() || self.lane.is_some()
    }

    /// Guided writing at the last tick, while it is on.
    pub fn guide_frame(&self) -> Option<GuideFrame> {
        self.guide_frame
    }

    /// A device calibration check was asked for (by [`ServoCommand::Calibrate`]) since the
    /// last call.
    pub fn take_device_cal_request(&mut self) -> bool {
        std::mem::take(&mut self.device_cal_requested)
    }

    /// What `hdCheckCalibration` says: `true` while the library wants the stylus in the
    /// inkwell. Forces asked for then wait for the calibration and the stylus above the paper.
    pub fn set_uncalibrated(&mut self, uncalibrated: bool) {
        if uncalibrated && !self.uncalibrated && self.forces_enabled() {
            self.enabled = false;
            self.await_lift = true;
        }
        self.uncalibrated = uncalibrated;
    }

    /// The library's calibration was just updated (`hdUpdateCalibration`): from the next
    /// reading the pose is the calibrated one, however far that is from the last. That is
    /// no sensor jump: the brush starts afresh, at rest, at the next pose, and forces asked
    /// for wait again for the stylus above the paper (an Omni is calibrated in its inkwell).
    pub fn device_recalibrated(&mut self) {
        self.uncalibrated = false;
        if self.forces_enabled() {
            self.enabled = false;
            self.await_lift = true;
        }
        self.restart_brush();
    }

    /// A device warning from the library (see [`ErrorClass::Warning`]): zero force, the
    /// brush at rest (started afresh at the next pose), a fault latched until cleared.
    pub fn device_warning(&mut self) {
        self.faults |= Faults::DEVICE_WARNING;
        self.restart_brush();
        self.command = self.tick_without_pose();
    }

    /// A tick without a usable reading (the one in which the calibration was updated): the
    /// tick counts, the force is zero, the brush is not moved.
    pub fn hold_tick(&mut self) -> [f64; 3] {
        self.tick = self.tick.wrapping_add(1);
        self.command = Vec3::ZERO;
        [0.0; 3]
    }

    /// One 1 ms tick: the device transform and buttons in, the force to command (N, device
    /// axes) out. Never panics; a garbage pose latches a sensor fault (zero force).
    pub fn step(&mut self, transform: &[f64; 16], buttons: c_int) -> [f64; 3] {
        self.tick = self.tick.wrapping_add(1);
        // A calibration asked for by an earlier tick (after the device's own check).
        let paper_cal = std::mem::take(&mut self.paper_cal_pending);
        match self.buttons.update(buttons) {
            Some(ButtonAction::Dip) => self.apply(ServoCommand::Dip(1.0)),
            Some(ButtonAction::ToggleForces) => {
                if self.forces_enabled() {
                    self.apply(ServoCommand::EnableForces(false));
                } else {
                    // The user asks for forces explicitly: clear a latched fault too.
                    self.apply(ServoCommand::ClearFaults);
                    self.apply(ServoCommand::EnableForces(true));
                }
            }
            Some(ButtonAction::Calibrate) => self.apply(ServoCommand::Calibrate),
            None => {}
        }
        let Some((pos, rot)) = pose_of_transform(transform) else {
            return self.fault();
        };
        if paper_cal {
            let length = self.params().length_mm as f64;
            self.mapping.calibrate(pos[1], length);
            // The paper moved under the hand: start the brush afresh where it now is.
            self.restart_brush();
        }
        let paper = self.mapping.to_paper(pos, rot);
        let pose: Pose<Fx> = paper.cast();
        // The safe start: the brush (hanging at most its length below the ferrule) clear of
        // the paper, the device calibrated, no fault.
        if self.await_lift
            && !self.uncalibrated
            && self.faults.is_empty()
            && pose.pos.z.to_f64() > self.params().length_mm as f64
        {
            self.await_lift = false;
            self.enabled = true;
        }
        // A fault latched cuts the guide (as the firmware does).
        if !self.faults.is_empty() {
            self.cut_guide();
        }
        let gate = Gate::new(self.enabled, self.faults);
        let tick = self.tick;
        let (faults, guide_frame, command) = match &mut self.model {
            ServoModel::Liang(fl) => {
                let guide = match &mut self.lane {
                    Some(l) => l.next_sample(Some(paper.pos.to_f64()), fl.guide()),
                    None => GuidePlay::next_sample_of(&mut self.guide_play, fl.guide()),
                };
                let out = fl.tick(TickIn {
                    pose: Some(pose),
                    guide,
                    gate,
                });
                let frame = (self.guide_play.is_some() || self.lane.is_some())
                    .then(|| GuideFrame::of(fl.guide(), &out.guide))
                    .flatten();
                if self.lane.as_ref().is_some_and(|l| l.done(fl.guide())) {
                    self.lane = None;
                }
                (out.faults, frame, out.command.to_f64())
            }
            ServoModel::BaxterLin(b) => {
                // Baxter & Lin's model runs in f64: the device's pose as mapped, unrounded.
                let pose = paper;
                // A stale model is not let through: the output stage ramps out, as for a
                // stalled loop, and back in with a fresh one (not latched).
                let gate = if b.exchange(tick, pose) {
                    Gate {
                        allowed: false,
                        ..gate
                    }
                } else {
                    gate
                };
                let guide = match &mut self.lane {
                    Some(l) => l.next_sample(Some(pose.pos.to_f64()), b.hand.guide()),
                    None => GuidePlay::next_sample_of_as(
                        &mut self.guide_play,
                        b.hand.guide(),
                        Vec3::cast::<f64>,
                    ),
                };
                let out = b.hand.tick(
                    TickIn {
                        pose: Some(pose),
                        guide,
                        gate,
                    },
                    &b.model,
                );
                b.pose = Some(pose);
                b.force = out.force;
                let frame = (self.guide_play.is_some() || self.lane.is_some())
                    .then(|| GuideFrame::of(b.hand.guide(), &out.guide))
                    .flatten();
                if self.lane.as_ref().is_some_and(|l| l.done(b.hand.guide())) {
                    self.lane = None;
                }
                (out.faults, frame, out.command.to_f64())
            }
        };
        // A sensor jump latches (the loop held the forces this tick already).
        self.faults |= faults;
        self.guide_frame = guide_frame;
        self.command = Vec3::from_f64(command);
        self.device_force()
    }

    /// A garbage pose: a sensor fault latched, the guide cut, the command ramped out.
    fn fault(&mut self) -> [f64; 3] {
        self.faults |= Faults::SENSOR_JUMP;
        self.cut_guide();
        self.command = self.tick_without_pose();
        self.device_force()
    }

    /// A tick of the loop without a pose, under the gate in force (held while a fault is
    /// latched): the brush holds, the output stage ramps out.
    fn tick_without_pose(&mut self) -> Vec3<f64> {
        let gate = Gate::new(self.enabled, self.faults);
        match &mut self.model {
            ServoModel::Liang(fl) => fl
                .tick(TickIn {
                    pose: None,
                    guide: None,
                    gate,
                })
                .command
                .cast(),
            ServoModel::BaxterLin(b) => {
                let input = TickIn {
                    pose: None,
                    guide: None,
                    gate,
                };
                b.hand.tick(input, &b.model).command
            }
        }
    }

    /// The stage's command in device axes, guarded once more against the peak force: the
    /// stage clamps in fixed point, and a last-bit rounding above the device's nominal
    /// maximum must not reach the motors.
    fn device_force(&self) -> [f64; 3] {
        let f = self.command.to_f64();
        let peak = match &self.model {
            ServoModel::Liang(fl) => fl.output().limits().peak_n,
            ServoModel::BaxterLin(b) => b.hand.output().limits().peak_n,
        } as f64;
        let n = (f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sqrt();
        let f = if n.is_finite() && n <= peak {
            f
        } else if n.is_finite() {
            let k = peak * (1.0 - 1e-9) / n;
            [f[0] * k, f[1] * k, f[2] * k]
        } else {
            [0.0; 3]
        };
        Mapping::force_to_device(f)
    }

    /// The wire-protocol state of the brush now (`None` before the first valid pose, and
    /// after a restart of the brush until the next).
    pub fn state(&self) -> Option<BrushState> {
        match self.servo_state()? {
            ServoState::Brush(s) => Some(s),
            ServoState::Hand(_) => None,
        }
    }

    /// What the loop hands over for the GUI now: Liang's brush as the wire protocol's
    /// state, Baxter & Lin's as the hand's side (`None` before the first valid pose, and
    /// after a restart of the brush until the next).
    pub fn servo_state(&self) -> Option<ServoState> {
        match &self.model {
            ServoModel::Liang(fl) => {
                if fl.reanchoring() {
                    return None;
                }
                Some(ServoState::Brush(BrushState::from_brush(
                    fl.brush(),
                    self.tick,
                    0,
                    Haptics::new(self.command.cast(), [Fx::ZERO; 3], self.forces_enabled()),
                    self.faults(),
                )))
            }
            ServoModel::BaxterLin(b) => {
                if b.restart {
                    return None;
                }
                Some(ServoState::Hand(HandState {
                    tick: self.tick,
                    generation: b.generation,
                    pose: b.pose?,
                    force: b.force.to_f64(),
                    command: self.command.to_f64(),
                    output: self.output_state(),
                    faults: self.faults(),
                }))
            }
        }
    }
}

impl BaxterLinServo {
    /// The callback's side of the exchange with the solver at servo tick `tick`, the handle
    /// at `pose`: a restart begins the next generation here; a request is left every
    /// `rebuild_every` ticks (at once for a new generation, and retried the next tick if
    /// the slot was busy); the newest model of this generation is taken. Returns whether
    /// the model is stale: the caller closes the output stage's gate then.
    fn exchange(&mut self, tick: u32, pose: Pose<f64>) -> bool {
        if self.restart {
            self.restart = false;
            self.generation = self.generation.wrapping_add(1);
            self.began = tick;
            self.last_request = None;
            self.solved_at = None;
            self.model = LocalForceModel::NONE;
        }
        let due = self
            .last_request
            .is_none_or(|t| tick.wrapping_sub(t) >= self.rebuild_every);
        if due {
            let req = SolveRequest {
                generation: self.generation,
                tick,
                pose,
                params: self.params,
            };
            if self.link.request(req) {
                self.last_request = Some(tick);
            }
        }
        if let Some(p) = self.link.take_published() {
            if p.generation == self.generation {
                self.model = p.model;
                self.solved_at = Some(p.tick);
            }
        }
        // (A generation whose first model has not come is as late as a stale model.)
        let since = self.solved_at.unwrap_or(self.began);
        let stale = tick.wrapping_sub(since) >= self.stale_after;
        self.link.set_stale(stale);
        stale
    }
}

/// Options of the bridge.
#[derive(Clone, Debug)]
pub struct BridgeOptions {
    /// The brush at start (a preset, or one with parameters changed: `maobi bridge --param`);
    /// the host can change it over the protocol.
    pub brush: BrushParams,
    /// The brush model (Liang's by default; Baxter & Lin's is solved on a thread of its own).
    pub model: ServoBrush,
    pub mapping: Mapping,
    /// States per second to the GUI / TCP side (1 ..= 1000).
    pub state_hz: u32,
    /// Forces ramp in at start (otherwise button 2 or a command enables them).
    pub forces_on: bool,
    /// Stop by itself after this many servo ticks (scripted runs and tests).
    pub stop_after_ticks: Option<u32>,
    /// Fault injection for the tests of the recovery path: the model's step panics at this
    /// servo tick, as a bug in it would.
    pub panic_at_tick: Option<u32>,
}

impl Default for BridgeOptions {
    fn default() -> Self {
        BridgeOptions {
            brush: presets::LARGE,
            model: ServoBrush::Liang,
            mapping: Mapping::default(),
            state_hz: 120,
            forces_on: true,
            stop_after_ticks: None,
            panic_at_tick: None,
        }
    }
}

/// Why the servo loop stopped.
#[derive(Clone, Debug, PartialEq)]
pub enum Stopped {
    /// `stop_after_ticks` reached.
    TickLimit(u32),
    /// An HD error: the servo tick it was seen at, the error, and `hdGetErrorString`'s text.
    HdError {
        tick: u32,
        info: HdErrorInfo,
        text: String,
    },
    /// The callback panicked (a bug); forces were zeroed.
    Panicked(u32),
}

impl std::fmt::Display for Stopped {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Stopped::TickLimit(n) => write!(f, "stopped after {n} servo ticks as asked"),
            Stopped::HdError { tick, info, text } => write!(
                f,
                "HD error {} (0x{:04x}, device code {}) at servo tick {tick}: {text}; the force \
                 was set to zero in that tick and the servo loop stopped",
                error_name(info.error_code),
                info.error_code,
                info.internal_error_code
            ),
            Stopped::Panicked(t) => write!(
                f,
                "the servo callback failed at tick {t} (a bug); forces were set to zero"
            ),
        }
    }
}

/// What the callback shares with the rest of the program. Everything the callback touches
/// is an atomic or a `try_lock`.
pub struct ServoShared {
    /// States with the guide's figures at their tick.
    states_q: Mutex<VecDeque<(ServoState, Option<GuideFrame>)>>,
    commands: Mutex<VecDeque<ServoCommand>>,
    /// Every guide stroke handed to the servo loop, kept alive here until the loop has let go
    /// of it. When a stroke ends or is replaced the callback only drops *a* reference: the
    /// last one, and with it the free (an allocator call, with a lock inside, in a 1 kHz
    /// real-time callback), is always dropped on this side, by [`Self::release_played_guides`].
    guides: Mutex<Vec<GuidePoints>>,
    stop: AtomicBool,
    /// The callback has returned HD_CALLBACK_DONE (and will not run again).
    done: AtomicBool,
    /// 0 running, 1 tick limit, 2 HD error, 3 panic.
    why: AtomicU32,
    error_code: AtomicU32,
    internal_code: AtomicI32,
    error_hhd: AtomicU32,
    stop_tick: AtomicU32,
    tick: AtomicU32,
    states: AtomicU64,
    states_skipped: AtomicU64,
    cost_ns_total: AtomicU64,
    cost_ns_max: AtomicU64,
    forces_on: AtomicBool,
    /// The safe start is holding forces (see [`ServoCore::awaiting_lift`]).
    awaiting_lift: AtomicBool,
    /// The mapping's paper height as the loop last had it (`f64` bits; a calibration moves
    /// it), so a loop started again keeps it. NaN before the first tick.
    paper_height_bits: AtomicU64,
    /// Device warnings seen, and the last one (code, internal code, tick).
    warnings: AtomicU64,
    warning_code: AtomicU32,
    warning_internal: AtomicI32,
    warning_tick: AtomicU32,
    /// The last hdCheckCalibration result (0 before the first check), the updates done, and
    /// the last error an update raised (HD_SUCCESS if none).
    calibration: AtomicU32,
    calibration_updates: AtomicU32,
    calibration_error: AtomicU32,
}

impl ServoShared {
    fn new() -> ServoShared {
        ServoShared {
            states_q: Mutex::new(VecDeque::with_capacity(STATE_QUEUE)),
            commands: Mutex::new(VecDeque::new()),
            guides: Mutex::new(Vec::new()),
            stop: AtomicBool::new(false),
            done: AtomicBool::new(false),
            why: AtomicU32::new(0),
            error_code: AtomicU32::new(0),
            internal_code: AtomicI32::new(0),
            error_hhd: AtomicU32::new(0),
            stop_tick: AtomicU32::new(0),
            tick: AtomicU32::new(0),
            states: AtomicU64::new(0),
            states_skipped: AtomicU64::new(0),
            cost_ns_total: AtomicU64::new(0),
            cost_ns_max: AtomicU64::new(0),
            forces_on: AtomicBool::new(false),
            awaiting_lift: AtomicBool::new(false),
            paper_height_bits: AtomicU64::new(f64::NAN.to_bits()),
            warnings: AtomicU64::new(0),
            warning_code: AtomicU32::new(0),
            warning_internal: AtomicI32::new(0),
            warning_tick: AtomicU32::new(0),
            calibration: AtomicU32::new(0),
            calibration_updates: AtomicU32::new(0),
            calibration_error: AtomicU32::new(HD_SUCCESS),
        }
    }

    /// Forces are asked for but held until the stylus is above the paper (the safe start).
    pub fn awaiting_lift(&self) -> bool {
        self.awaiting_lift.load(Ordering::Relaxed)
    }

    /// Device warnings seen so far, and the last one with the servo tick it was read at.
    pub fn warnings(&self) -> (u64, Option<(HdErrorInfo, u32)>) {
        let n = self.warnings.load(Ordering::Acquire);
        let last = (n > 0).then(|| {
            (
                HdErrorInfo {
                    error_code: self.warning_code.load(Ordering::Acquire),
                    internal_error_code: self.warning_internal.load(Ordering::Acquire),
                    h_hd: 0,
                },
                self.warning_tick.load(Ordering::Acquire),
            )
        });
        (n, last)
    }

    /// The last `hdCheckCalibration` result (`None` before the first check), the
    /// calibration updates done, and the error the last failed update raised.
    pub fn calibration(&self) -> (Option<HdEnum>, u32, Option<HdError>) {
        let status = self.calibration.load(Ordering::Acquire);
        let err = self.calibration_error.load(Ordering::Acquire);
        (
            (status != 0).then_some(status),
            self.calibration_updates.load(Ordering::Acquire),
            (err != HD_SUCCESS).then_some(err),
        )
    }

    /// What the user should know about the device now, one sentence each: a calibration the
    /// library asks for, forces waiting for the stylus, the last device warning while its
    /// fault is latched (`faults` is what the last state reported).
    pub fn notices(&self, faults: Faults) -> Vec<String> {
        let mut out = Vec::new();
        let (status, _, cal_err) = self.calibration();
        if status == Some(HD_CALIBRATION_NEEDS_MANUAL_INPUT) {
            out.push(
                "the device is not calibrated: put the stylus in its inkwell (forces stay off \
                 until it is)"
                    .to_string(),
            );
        } else if status == Some(HD_CALIBRATION_NEEDS_UPDATE) {
            out.push(
                "the device's calibration needs an update: hold the stylus at its reset \
                 position and calibrate"
                    .to_string(),
            );
        }
        if let Some(e) = cal_err {
            out.push(format!(
                "the last calibration update failed: {}",
                error_name(e)
            ));
        }
        if self.awaiting_lift() && status != Some(HD_CALIBRATION_NEEDS_MANUAL_INPUT) {
            out.push(
                "forces start once the brush is lifted clear above the paper (or enable them)"
                    .to_string(),
            );
        }
        if faults.contains(Faults::DEVICE_WARNING) {
            if let (_, Some((e, tick))) = self.warnings() {
                out.push(format!(
                    "device warning {} at servo tick {tick}: forces off and the brush at rest \
                     until the fault is cleared",
                    error_name(e.error_code)
                ));
            }
        }
        out
    }

    /// The paper height the loop has now (a calibration moves it); `None` before its first
    /// tick.
    pub fn paper_height_mm(&self) -> Option<f64> {
        let h = f64::from_bits(self.paper_height_bits.load(Ordering::Relaxed));
        h.is_finite().then_some(h)
    }

    /// Servo ticks run so far.
    pub fn ticks(&self) -> u32 {
        self.tick.load(Ordering::Acquire)
    }

    /// The callback has stopped for good (error, tick limit, or asked to).
    pub fn done(&self) -> bool {
        self.done.load(Ordering::Acquire)
    }

    pub fn forces_on(&self) -> bool {
        self.forces_on.load(Ordering::Relaxed)
    }

    /// The oldest wire-protocol state (Liang's brush) the callback handed over that was not
    /// taken yet; Baxter & Lin's hand states before it are passed over.
    pub fn take_state(&self) -> Option<BrushState> {
        loop {
            match self.take_state_with_guide()?.0 {
                ServoState::Brush(s) => return Some(s),
                ServoState::Hand(_) => continue,
            }
        }
    }

    /// The oldest state the callback handed over that was not taken yet, with guided
    /// writing's figures at its tick. (The reader calls this all the time, so it also frees
    /// the strokes the servo loop has finished with.)
    pub fn take_state_with_guide(&self) -> Option<(ServoState, Option<GuideFrame>)> {
        self.release_played_guides();
        self.states_q.lock().ok()?.pop_front()
    }

    /// Queues a command for the next servo tick.
    pub fn send(&self, cmd: ServoCommand) {
        self.release_played_guides();
        if let ServoCommand::Guide(Some(points)) = &cmd {
            if let Ok(mut g) = self.guides.lock() {
                g.push(points.clone());
            }
        }
        if let Ok(mut q) = self.commands.lock() {
            // A stalled servo must not grow this without bound.
            if q.len() < 64 {
                q.push_back(cmd);
            }
        }
    }

    /// Frees the guide strokes nobody but this list holds any more (the servo loop has played
    /// or dropped them, and no queued command carries them). A count read while the callback
    /// drops its reference is at worst one too high: that stroke goes at the next call.
    pub fn release_played_guides(&self) {
        if let Ok(mut g) = self.guides.lock() {
            g.retain(|points| Arc::strong_count(points) > 1);
        }
    }

    /// Guide strokes still held for the servo loop (tests and diagnostics).
    pub fn guides_held(&self) -> usize {
        self.guides.lock().map(|g| g.len()).unwrap_or(0)
    }

    /// Applies the queued commands to `core`, as the callback does at the start of a tick; if
    /// the sender holds the queue right now, they wait for the next tick.
    fn apply_pending(&self, core: &mut ServoCore) {
        if let Ok(mut q) = self.commands.try_lock() {
            while let Some(c) = q.pop_front() {
                core.apply(c);
            }
        }
    }

    /// (mean, max) cost of one callback (microseconds).
    pub fn callback_cost_us(&self) -> (f64, f64) {
        let n = self.ticks().max(1) as f64;
        (
            self.cost_ns_total.load(Ordering::Relaxed) as f64 / n / 1e3,
            self.cost_ns_max.load(Ordering::Relaxed) as f64 / 1e3,
        )
    }

    /// States the servo loop produced, and of them the ones lost (the reader held the queue
    /// at that instant, or fell [`STATE_QUEUE`] behind): a reader that drains the queue after
    /// the loop stops has read exactly the difference.
    pub fn state_counts(&self) -> (u64, u64) {
        (
            self.states.load(Ordering::Relaxed),
            self.states_skipped.load(Ordering::Relaxed),
        )
    }

    /// Why the servo loop stopped, if it has (`lib` gives the error text).
    pub fn stopped(&self, lib: &HdLib) -> Option<Stopped> {
        let (why, tick, info) = self.stopped_raw()?;
        Some(match why {
            1 => Stopped::TickLimit(tick),
            2 => Stopped::HdError {
                tick,
                info,
                text: lib.error_string(info.error_code),
            },
            3 => Stopped::Panicked(tick),
            _ => return None,
        })
    }

    fn stopped_raw(&self) -> Option<(u32, u32, HdErrorInfo)> {
        if !self.done() {
            return None;
        }
        Some((
            self.why.load(Ordering::Acquire),
            self.stop_tick.load(Ordering::Acquire),
            HdErrorInfo {
                error_code: self.error_code.load(Ordering::Acquire),
                internal_error_code: self.internal_code.load(Ordering::Acquire),
                h_hd: self.error_hhd.load(Ordering::Acquire),
            },
        ))
    }
}

/// What the callback owns: the model, the HD functions and the shared side.
struct ServoCtx {
    fns: HdFns,
    hhd: Hhd,
    core: ServoCore,
    shared: Arc<ServoShared>,
    state_hz: u32,
    stop_after: Option<u32>,
    panic_at: Option<u32>,
    /// The style `hdUpdateCalibration` is called with (`None`: the device reports none).
    cal_style: Option<HdEnum>,
    /// Whether the bridge updates the calibration by itself when the library says it can
    /// (not for encoder-reset devices, where the user must hold the arm at its reset
    /// position: only when asked).
    cal_auto: bool,
    /// The servo tick of the next calibration check (the first tick checks it).
    next_cal_check: u32,
    /// A frame of this callback is open (between hdBeginFrame and hdEndFrame).
    frame_open: bool,
}

/// How a servo tick ends.
enum Outcome {
    Continue,
    /// Stop: why (see [`ServoShared::stopped`]) and the error behind it.
    Stop(u32, HdErrorInfo),
}

impl ServoCtx {
    /// One scheduler tick: exactly one frame. The force it commits is decided inside it,
    /// from everything the tick learned (errors, a stop, a panic in the step): zero on any
    /// fault. Returns the callback code.
    fn frame(&mut self) -> HdCallbackCode {
        let started = Instant::now();
        let f = self.fns;
        let tick = self.core.tick().wrapping_add(1);
        let mut m = [0.0f64; 16];
        let mut buttons: c_int = 0;
        // SAFETY: the HD functions are called from the scheduler thread, with buffers of the
        // sizes hdDefines.h documents (16 doubles for the transform, one int for the buttons).
        unsafe {
            (f.begin_frame)(self.hhd);
            self.frame_open = true;
            (f.get_doublev)(HD_CURRENT_TRANSFORM, m.as_mut_ptr());
            (f.get_integerv)(HD_CURRENT_BUTTONS, &mut buttons);
        }
        // Everything raised since the last tick read the stack: the last frame's end, this
        // frame's begin and reads.
        let (fatal, warning) = self.drain_errors();
        let mut force = [0.0f64; 3];
        let mut stepped = false;
        let mut outcome = Outcome::Continue;
        if let Some(err) = fatal {
            outcome = Outcome::Stop(2, err);
        } else if self.shared.stop.load(Ordering::Acquire) {
            outcome = Outcome::Stop(0, HdErrorInfo::none());
        } else {
            // A panic in the model (a bug) must not unwind into the library, nor leave this
            // frame open: it is caught here, and the frame commits zero below.
            match std::panic::catch_unwind(AssertUnwindSafe(|| {
                self.decide(tick, &m, buttons, warning)
            })) {
                Ok(Ok((f, s))) => {
                    force = f;
                    stepped = s;
                }
                Ok(Err(err)) => outcome = Outcome::Stop(2, err),
                Err(_) => outcome = Outcome::Stop(3, HdErrorInfo::none()),
            }
            if matches!(outcome, Outcome::Continue) && self.stop_after.is_some_and(|n| tick >= n) {
                outcome = Outcome::Stop(1, HdErrorInfo::none());
            }
        }
        if !matches!(outcome, Outcome::Continue) {
            force = [0.0; 3];
        }
        // SAFETY: as above; three doubles for the force, inside this tick's one frame.
        unsafe {
            (f.set_doublev)(HD_CURRENT_FORCE, force.as_ptr());
            (f.end_frame)(self.hhd);
        }
        self.frame_open = false;
        self.shared.tick.store(tick, Ordering::Release);
        self.shared
            .forces_on
            .store(self.core.forces_enabled(), Ordering::Relaxed);
        self.shared
            .awaiting_lift
            .store(self.core.awaiting_lift(), Ordering::Relaxed);
        self.shared.paper_height_bits.store(
            self.core.mapping().paper_height_mm.to_bits(),
            Ordering::Relaxed,
        );
        if stepped {
            self.hand_over_state(tick);
        }
        let ns = started.elapsed().as_nanos().min(u128::from(u64::MAX)) as u64;
        self.shared.cost_ns_total.fetch_add(ns, Ordering::Relaxed);
        self.shared.cost_ns_max.fetch_max(ns, Ordering::Relaxed);
        match outcome {
            Outcome::Continue => HD_CALLBACK_CONTINUE,
            Outcome::Stop(why, err) => self.finish(why, tick, err),
        }
    }

    /// Reads the HD error stack to the end: the first scheduler-class (fatal) error and the
    /// first device warning on it.
    fn drain_errors(&mut self) -> (Option<HdErrorInfo>, Option<HdErrorInfo>) {
        let (mut fatal, mut warning) = (None, None);
        for _ in 0..MAX_ERRORS_PER_TICK {
            // SAFETY: a plain HD call on the scheduler thread.
            let e = unsafe { (self.fns.get_error)() };
            if !e.is_error() {
                break;
            }
            match classify(e.error_code) {
                ErrorClass::Fatal => {
                    fatal.get_or_insert(e);
                }
                ErrorClass::Warning => {
                    warning.get_or_insert(e);
                }
            }
        }
        (fatal, warning)
    }

    /// The model's part of the tick: commands, a device warning, the calibration, the step.
    /// Returns the force and whether the model stepped (a state to hand over), or the fatal
    /// error a calibration update raised.
    fn decide(
        &mut self,
        tick: u32,
        m: &[f64; 16],
        buttons: c_int,
        warning: Option<HdErrorInfo>,
    ) -> Result<([f64; 3], bool), HdErrorInfo> {
        if self.panic_at == Some(tick) {
            panic!("injected fault: the servo step panics at tick {tick}");
        }
        self.shared.apply_pending(&mut self.core);
        if let Some(w) = warning {
            self.core.device_warning();
            let s = &self.shared;
            s.warning_code.store(w.error_code, Ordering::Release);
            s.warning_internal
                .store(w.internal_error_code, Ordering::Release);
            s.warning_tick.store(tick, Ordering::Release);
            s.warnings.fetch_add(1, Ordering::AcqRel);
        }
        let asked = self.core.take_device_cal_request();
        if (asked || tick >= self.next_cal_check) && self.check_calibration(tick, asked)? {
            // This tick's reading predates the update: do not use it.
            return Ok((self.core.hold_tick(), false));
        }
        Ok((self.core.step(m, buttons), true))
    }

    /// `hdCheckCalibration`, and `hdUpdateCalibration` when the library says it needs one
    /// and the bridge may do it. Returns whether the calibration was updated.
    fn check_calibration(&mut self, tick: u32, asked: bool) -> Result<bool, HdErrorInfo> {
        let f = self.fns;
        // SAFETY: plain HD calls inside this tick's frame, as the SDK's example makes them.
        let status = unsafe { (f.check_calibration)() };
        self.shared.calibration.store(status, Ordering::Release);
        self.next_cal_check = tick.wrapping_add(if status == HD_CALIBRATION_OK {
            CAL_CHECK_TICKS
        } else {
            CAL_CHECK_WAITING_TICKS
        });
        match status {
            HD_CALIBRATION_OK => self.core.set_uncalibrated(false),
            HD_CALIBRATION_NEEDS_MANUAL_INPUT => self.core.set_uncalibrated(true),
            HD_CALIBRATION_NEEDS_UPDATE => match self.cal_style {
                Some(style) if self.cal_auto || asked => {
                    // SAFETY: as above.
                    unsafe { (f.update_calibration)(style) };
                    let (fatal, warning) = self.drain_errors();
                    if let Some(e) = fatal {
                        self.shared
                            .calibration_error
                            .store(e.error_code, Ordering::Release);
                        // A communication or scheduler error ends the loop; a refused update
                        // is reported and the device treated as uncalibrated.
                        if matches!(
                            e.error_code,
                            HD_COMM_ERROR
                                | HD_COMM_CONFIG_ERROR
                                | HD_TIMER_ERROR
                                | HD_INVALID_PRIORITY
                                | HD_SCHEDULER_FULL
                                | HD_DEVICE_FAULT
                        ) {
                            return Err(e);
                        }
                        self.core.set_uncalibrated(true);
                        return Ok(false);
                    }
                    if warning.is_some() {
                        self.core.device_warning();
                    }
                    self.shared
                        .calibration_error
                        .store(HD_SUCCESS, Ordering::Release);
                    self.shared
                        .calibration_updates
                        .fetch_add(1, Ordering::AcqRel);
                    self.core.device_recalibrated();
                    return Ok(true);
                }
                // An encoder-reset device: the user must hold the arm at its reset position
                // and ask (Calibrate); until then it is not calibrated.
                _ => self.core.set_uncalibrated(true),
            },
            // A status this bridge does not know: leave things as they are.
            _ => {}
        }
        Ok(false)
    }

    /// A state whenever tick * state_hz / 1000 steps: deterministic in the tick number, so
    /// two runs of the same poses hand over states of the same ticks.
    fn hand_over_state(&mut self, tick: u32) {
        let hz = u64::from(self.state_hz);
        if (u64::from(tick) * hz) / 1000 == (u64::from(tick.wrapping_sub(1)) * hz) / 1000 {
            return;
        }
        let Some(state) = self.core.servo_state() else {
            return;
        };
        // Counted before the handoff, so every state is either read or counted as lost.
        self.shared.states.fetch_add(1, Ordering::Relaxed);
        match self.shared.states_q.try_lock() {
            Ok(mut q) => {
                if q.len() >= STATE_QUEUE {
                    q.pop_front();
                    self.shared.states_skipped.fetch_add(1, Ordering::Relaxed);
                }
                // Within the reserved capacity: no allocation.
                q.push_back((state, self.core.guide_frame()));
            }
            Err(_) => {
                self.shared.states_skipped.fetch_add(1, Ordering::Relaxed);
            }
        }
    }

    fn finish(&mut self, why: u32, tick: u32, err: HdErrorInfo) -> HdCallbackCode {
        let s = &self.shared;
        s.error_code.store(err.error_code, Ordering::Release);
        s.internal_code
            .store(err.internal_error_code, Ordering::Release);
        s.error_hhd.store(err.h_hd, Ordering::Release);
        s.stop_tick.store(tick, Ordering::Release);
        s.why.store(why, Ordering::Release);
        s.forces_on.store(false, Ordering::Relaxed);
        s.done.store(true, Ordering::Release);
        HD_CALLBACK_DONE
    }
}

impl HdErrorInfo {
    fn none() -> HdErrorInfo {
        HdErrorInfo {
            error_code: HD_SUCCESS,
            internal_error_code: 0,
            h_hd: 0,
        }
    }
}

/// The scheduler callback: one servo tick ([`ServoCtx::frame`], which catches a panic in the
/// model itself). Should anything else in it panic, the panic must not unwind into C either:
/// it is caught, a frame still open commits zero and is closed (no second frame is begun in
/// the tick), and the callback unschedules itself.
unsafe extern "system" fn servo_callback(user_data: *mut c_void) -> HdCallbackCode {
    if user_data.is_null() {
        return HD_CALLBACK_DONE;
    }
    // SAFETY: `user_data` is the `ServoCtx` that `Bridge::start` boxed and keeps alive until
    // the scheduler is stopped and this callback unscheduled; only this thread uses it.
    let ctx = unsafe { &mut *user_data.cast::<ServoCtx>() };
    match std::panic::catch_unwind(AssertUnwindSafe(|| ctx.frame())) {
        Ok(code) => code,
        Err(_) => {
            if ctx.frame_open {
                let zero = [0.0f64; 3];
                // SAFETY: as in `ServoCtx::frame`, inside the frame it opened.
                unsafe {
                    (ctx.fns.set_doublev)(HD_CURRENT_FORCE, zero.as_ptr());
                    (ctx.fns.end_frame)(ctx.hhd);
                }
                ctx.frame_open = false;
            }
            let tick = ctx.core.tick();
            ctx.finish(3, tick, HdErrorInfo::none())
        }
    }
}

/// The device limits the library reports, checked.
pub fn device_limits(peak_n: f64, continuous_n: f64) -> Result<DeviceLimits, String> {
    let limits = DeviceLimits {
        peak_n: peak_n as f32,
        continuous_n: continuous_n as f32,
        ..PHANTOM_OMNI
    };
    limits.validate().map_err(|e| {
        format!(
            "the device reports unusable force limits (HD_NOMINAL_MAX_FORCE {peak_n} N, \
             HD_NOMINAL_MAX_CONTINUOUS_FORCE {continuous_n} N): {e}"
        )
    })?;
    if peak_n <= 0.0 {
        return Err(format!(
            "the device reports HD_NOMINAL_MAX_FORCE {peak_n} N"
        ));
    }
    Ok(limits)
}

/// The calibration style to update with, from HD_CALIBRATION_STYLE's mask, preferring what
/// needs no help from the user, as the SDK's Calibration example does: auto, then inkwell,
/// then encoder reset. `None` if the mask names none.
pub fn calibration_style(mask: c_int) -> Option<HdEnum> {
    [
        HD_CALIBRATION_AUTO,
        HD_CALIBRATION_INKWELL,
        HD_CALIBRATION_ENCODER_RESET,
    ]
    .into_iter()
    .find(|s| mask & s != 0)
    .map(|s| s as HdEnum)
}

/// The running servo loop on a device.
pub struct Bridge {
    lib: Arc<HdLib>,
    hhd: Hhd,
    /// The servo callback's handle, once scheduled.
    handle: Option<HdSchedulerHandle>,
    /// hdStartScheduler has succeeded.
    started: bool,
    /// HD_FORCE_OUTPUT has been enabled.
    force_output: bool,
    ctx: *mut ServoCtx,
    shared: Arc<ServoShared>,
    limits: DeviceLimits,
    params: BrushParams,
    /// Baxter & Lin's solver thread, when the servo loop runs their brush.
    solver: Option<SolverThread>,
    shut: bool,
}

// SAFETY: `ctx` is only dereferenced by the scheduler thread while scheduled and freed by
// `shutdown` after the scheduler has stopped; the rest is `Send`.
unsafe impl Send for Bridge {}

impl Bridge {
    /// Initialises the default device, reads its force limits and calibration style,
    /// enables force output and schedules the servo callback at 1 kHz. The HD error stack is
    /// read after every setup call, so a failure is reported by the call that failed (and the
    /// device released) before the servo loop runs.
    pub fn start(lib: Arc<HdLib>, opts: &BridgeOptions) -> anyhow::Result<Bridge> {
        let params = opts.brush;
        params
            .validate()
            .map_err(|e| anyhow::anyhow!("the brush: {e}"))?;
        if !(1..=1000).contains(&opts.state_hz) {
            anyhow::bail!("--state-hz must be 1 ..= 1000");
        }
        opts.mapping.validate().map_err(anyhow::Error::msg)?;
        let f = lib.fns();
        let hd_err = |what: &str, e: HdErrorInfo| {
            anyhow::anyhow!(
                "{what}: {} (0x{:04x}, device code {}): {}",
                error_name(e.error_code),
                e.error_code,
                e.internal_error_code,
                lib.error_string(e.error_code)
            )
        };
        // The first error a setup call left on the stack, with the rest read off.
        let take_error = || -> Option<HdErrorInfo> {
            let mut first = None;
            for _ in 0..MAX_ERRORS_PER_TICK {
                // SAFETY: a plain HD call, before the scheduler runs.
                let e = unsafe { (f.get_error)() };
                if !e.is_error() {
                    break;
                }
                first.get_or_insert(e);
            }
            first
        };
        // Errors left by an earlier session in this process are not this start's.
        let _ = take_error();
        // SAFETY (this and the HD calls below): plain calls of the HD API from one thread,
        // before the scheduler runs, with the buffer sizes hdDefines.h documents.
        let hhd = unsafe { (f.init_device)(HD_DEFAULT_DEVICE) };
        if let Some(e) = take_error() {
            return Err(hd_err(
                "hdInitDevice: cannot initialise the default haptic device",
                e,
            ));
        }
        if hhd == HD_INVALID_HANDLE {
            anyhow::bail!("hdInitDevice: cannot initialise the default haptic device");
        }
        // From here on a failure releases the device: `bridge` is dropped (shut down).
        let mut bridge = Bridge {
            lib: lib.clone(),
            hhd,
            handle: None,
            started: false,
            force_output: false,
            ctx: std::ptr::null_mut(),
            shared: Arc::new(ServoShared::new()),
            limits: PHANTOM_OMNI,
            params,
            solver: None,
            shut: false,
        };
        let mut peak = 0.0f64;
        let mut cont = 0.0f64;
        unsafe {
            (f.get_doublev)(HD_NOMINAL_MAX_FORCE, &mut peak);
            (f.get_doublev)(HD_NOMINAL_MAX_CONTINUOUS_FORCE, &mut cont);
        }
        if let Some(e) = take_error() {
            return Err(hd_err(
                "hdGetDoublev(HD_NOMINAL_MAX_FORCE): cannot read the device's force limits",
                e,
            ));
        }
        bridge.limits = device_limits(peak, cont).map_err(anyhow::Error::msg)?;
        let mut style_mask: c_int = 0;
        unsafe { (f.get_integerv)(HD_CALIBRATION_STYLE, &mut style_mask) };
        match take_error() {
            None => {}
            // A library that does not know the query: no calibration to manage.
            Some(e) if e.error_code == HD_INVALID_ENUM => style_mask = 0,
            Some(e) => {
                return Err(hd_err(
                    "hdGetIntegerv(HD_CALIBRATION_STYLE): cannot read the calibration style",
                    e,
                ))
            }
        }
        let cal_style = calibration_style(style_mask);
        let core = match opts.model {
            ServoBrush::Liang => {
                ServoCore::new(params, bridge.limits, opts.mapping, opts.forces_on)
            }
            ServoBrush::BaxterLin(shape) => {
                // The solver runs before the callback first asks it for anything.
                let link = SolverLink::new();
                let local = LocalForceParams::for_device(&bridge.limits);
                bridge.solver = Some(
                    SolverThread::spawn(link.clone(), shape, local)
                        .map_err(|e| anyhow::anyhow!("cannot start the brush's solver: {e}"))?,
                );
                ServoCore::baxter_lin(params, bridge.limits, opts.mapping, opts.forces_on, link)
            }
        }
        .map_err(anyhow::Error::msg)?;
        bridge.ctx = Box::into_raw(Box::new(ServoCtx {
            fns: f,
            hhd,
            core,
            shared: bridge.shared.clone(),
            state_hz: opts.state_hz,
            stop_after: opts.stop_after_ticks,
            panic_at: opts.panic_at_tick,
            cal_style,
            cal_auto: cal_style.is_some_and(|s| s != HD_CALIBRATION_ENCODER_RESET as HdEnum),
            next_cal_check: 1,
            frame_open: false,
        }));
        unsafe { (f.enable)(HD_FORCE_OUTPUT) };
        bridge.force_output = true;
        if let Some(e) = take_error() {
            return Err(hd_err("hdEnable(HD_FORCE_OUTPUT) failed", e));
        }
        // The library's own clamp as a second line behind the output stage's.
        unsafe { (f.enable)(HD_MAX_FORCE_CLAMPING) };
        if let Some(e) = take_error() {
            return Err(hd_err("hdEnable(HD_MAX_FORCE_CLAMPING) failed", e));
        }
        unsafe { (f.set_scheduler_rate)(1000) };
        if let Some(e) = take_error() {
            return Err(hd_err("hdSetSchedulerRate(1000) failed", e));
        }
        // SAFETY: `ctx` stays valid until `shutdown`, after hdStopScheduler.
        let handle = unsafe {
            (f.schedule_asynchronous)(servo_callback, bridge.ctx.cast(), HD_MAX_SCHEDULER_PRIORITY)
        };
        if let Some(e) = take_error() {
            return Err(hd_err("hdScheduleAsynchronous failed", e));
        }
        bridge.handle = Some(handle);
        unsafe { (f.start_scheduler)() };
        // Even if it reports an error, the scheduler may have begun: the teardown stops it
        // before the callback's context is freed.
        bridge.started = true;
        if let Some(e) = take_error() {
            return Err(hd_err("hdStartScheduler: cannot start the servo loop", e));
        }
        Ok(bridge)
    }

    /// The side shared with the callback (states, commands, counters).
    pub fn shared(&self) -> Arc<ServoShared> {
        self.shared.clone()
    }

    /// The limits read from the device.
    pub fn limits(&self) -> DeviceLimits {
        self.limits
    }

    pub fn params(&self) -> &BrushParams {
        &self.params
    }

    pub fn lib(&self) -> &HdLib {
        &self.lib
    }

    /// What the servo loop shares with Baxter & Lin's solver thread, when it runs their
    /// brush.
    pub fn solver_link(&self) -> Option<&Arc<SolverLink>> {
        self.solver.as_ref().map(SolverThread::link)
    }

    /// Why the servo loop stopped, if it has.
    pub fn stopped(&self) -> Option<Stopped> {
        self.shared.stopped(&self.lib)
    }

    /// Stops the servo loop (the callback's last frame commands zero force), the scheduler,
    /// and releases the device. Idempotent; also undoes a start that failed half-way.
    pub fn shutdown(&mut self) {
        if self.shut {
            return;
        }
        self.shut = true;
        let f = self.lib.fns();
        if self.started {
            self.shared.stop.store(true, Ordering::Release);
            // Let the callback see the stop and command zero itself (a few frames at most).
            let deadline = Instant::now() + Duration::from_millis(200);
            while !self.shared.done() && Instant::now() < deadline {
                std::thread::sleep(Duration::from_millis(1));
            }
        }
        // SAFETY: plain HD calls; after hdStopScheduler returns the callback no longer runs,
        // so `ctx` can be freed.
        unsafe {
            if self.started {
                (f.stop_scheduler)();
            }
            if let Some(h) = self.handle {
                if !self.shared.done() {
                    (f.unschedule)(h);
                }
            }
            if self.force_output {
                (f.disable)(HD_FORCE_OUTPUT);
            }
            (f.disable_device)(self.hhd);
            // Errors of the teardown itself are of no use any more; drain them.
            for _ in 0..MAX_ERRORS_PER_TICK {
                if !(f.get_error)().is_error() {
                    break;
                }
            }
            if !self.ctx.is_null() {
                drop(Box::from_raw(self.ctx));
            }
        }
        self.ctx = std::ptr::null_mut();
        // The callback is gone: nothing asks the solver for more.
        if let Some(mut solver) = self.solver.take() {
            solver.stop();
        }
    }
}

impl Drop for Bridge {
    fn drop(&mut self) {
        self.shutdown();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn transform_round_trip() {
        let q = Quat::new(0.9, 0.1, -0.3, 0.2).normalized();
        let m = transform_of_pose([1.0, -2.0, 3.5], q);
        let (p, q2) = pose_of_transform(&m).unwrap();
        assert_eq!(p, [1.0, -2.0, 3.5]);
        let d = (q.w - q2.w).abs() + (q.x - q2.x).abs() + (q.y - q2.y).abs() + (q.z - q2.z).abs();
        assert!(d < 1e-12, "{q:?} {q2:?}");
        // Rotations of every branch of Shepperd's method.
        for q in [
            Quat::new(0.0, 1.0, 0.0, 0.0),
            Quat::new(0.0, 0.0, 1.0, 0.0),
            Quat::new(0.0, 0.0, 0.0, 1.0),
            Quat::new(0.1, 0.7, 0.7, 0.1).normalized(),
        ] {
            let (_, q2) = pose_of_transform(&transform_of_pose([0.0; 3], q)).unwrap();
            let dot = q.w * q2.w + q.x * q2.x + q.y * q2.y + q.z * q2.z;
            assert!((dot.abs() - 1.0).abs() < 1e-12, "{q:?} {q2:?}");
        }
    }

    #[test]
    fn garbage_transforms_are_no_pose() {
        let mut m = transform_of_pose([0.0; 3], Quat::IDENTITY);
        m[5] = f64::NAN;
        assert!(pose_of_transform(&m).is_none());
        assert!(pose_of_transform(&[0.0; 16]).is_none());
        let far = transform_of_pose([1e9, 0.0, 0.0], Quat::IDENTITY);
        assert!(pose_of_transform(&far).is_none());
    }

    #[test]
    fn mapping_axes_and_inverse() {
        let m = Mapping {
            origin_mm: [10.0, 5.0],
            paper_height_mm: -50.0,
            scale: 2.0,
        };
        // Up on the device is up on the paper; toward the user is -y on the paper.
        let p = m.to_paper([10.0, -40.0, 6.0], Quat::<f64>::IDENTITY);
        let v = p.pos.to_f64();
        assert_eq!(v, [0.0, -2.0, 20.0]);
        let (back, _) = m.to_device(p);
        assert_eq!(back, [10.0, -40.0, 6.0]);
        // The stylus held upright, tip down (device rotation R_x(-90)) is the brush hanging
        // straight down (identity).
        let h = std::f64::consts::FRAC_1_SQRT_2;
        let upright = m.to_paper([0.0; 3], Quat::new(h, -h, 0.0, 0.0));
        assert!(
            (upright.rot.w.abs() - 1.0).abs() < 1e-12,
            "{:?}",
            upright.rot
        );
        // A force up on the paper pushes up on the device.
        assert_eq!(Mapping::force_to_device([0.0, 0.0, 1.0]), [0.0, 1.0, 0.0]);
        assert_eq!(Mapping::force_to_device([0.0, 1.0, 0.0]), [0.0, 0.0, -1.0]);
    }

    #[test]
    fn calibration_puts_the_tip_on_the_paper() {
        let mut m = Mapping::default();
        m.calibrate(-20.0, 40.0);
        let p = m.to_paper([0.0, -20.0, 0.0], Quat::<f64>::IDENTITY);
        assert!((p.pos.to_f64()[2] - 40.0).abs() < 1e-12);
    }

    #[test]
    fn buttons_act_on_release_and_chords_calibrate_once() {
        let mut b = Buttons::default();
        assert_eq!(b.update(1), None);
        assert_eq!(b.update(1), None);
        assert_eq!(b.update(0), Some(ButtonAction::Dip));
        assert_eq!(b.update(2), None);
        assert_eq!(b.update(0), Some(ButtonAction::ToggleForces));
        assert_eq!(b.update(1), None);
        assert_eq!(b.update(3), Some(ButtonAction::Calibrate));
        assert_eq!(b.update(3), None);
        assert_eq!(b.update(2), None);
        assert_eq!(b.update(0), None);
        assert_eq!(b.update(0), None);
    }

    /// The servo loop plays a stroke to its end and a second one is replaced mid-way, yet the
    /// last reference to each (and so the free) stays on the non-real-time side.
    #[test]
    fn the_servo_loop_never_frees_a_guide_stroke() {
        let params = presets::by_name("large").unwrap();
        let mut core = ServoCore::new(params, PHANTOM_OMNI, Mapping::default(), true).unwrap();
        let shared = ServoShared::new();
        let q = Quat::new(
            std::f64::consts::FRAC_1_SQRT_2,
            -std::f64::consts::FRAC_1_SQRT_2,
            0.0,
            0.0,
        );
        let m = transform_of_pose([0.0, -10.0, 0.0], q);
        let stroke = |n: usize| -> GuidePoints {
            (0..n)
                .map(|i| Vec3::from_f64([i as f64 * 0.05, 0.0, 1.0]))
                .collect()
        };
        let (first, second) = (stroke(200), stroke(5000));
        let (first_w, second_w) = (Arc::downgrade(&first), Arc::downgrade(&second));
        shared.send(ServoCommand::Guide(Some(first)));
        let mut ticks = 0;
        loop {
            shared.apply_pending(&mut core);
            core.step(&m, 0);
            ticks += 1;
            if !core.guiding() || ticks > 5000 {
                break;
            }
        }
        assert!(!core.guiding(), "the stroke did not end in {ticks} ticks");
        assert!(ticks > 200, "the stroke ended after {ticks} ticks");
        assert!(
            first_w.upgrade().is_some(),
            "the servo side freed the stroke"
        );
        // Replaced mid-way by a new one: the old one's last reference is still not the servo's.
        shared.send(ServoCommand::Guide(Some(second)));
        for _ in 0..100 {
            shared.apply_pending(&mut core);
            core.step(&m, 0);
        }
        assert!(core.guiding());
        assert!(
            first_w.upgrade().is_none(),
            "a played stroke was not released"
        );
        shared.send(ServoCommand::ResetBrush);
        shared.apply_pending(&mut core);
        assert!(!core.guiding());
        assert!(
            second_w.upgrade().is_some(),
            "the servo side freed the stroke"
        );
        assert_eq!(shared.guides_held(), 1);
        shared.release_played_guides();
        assert!(second_w.upgrade().is_none());
        assert_eq!(shared.guides_held(), 0);
    }

    #[test]
    fn garbage_pose_latches_a_fault_and_zero_force() {
        let params = presets::by_name("large").unwrap();
        let mut core = ServoCore::new(params, PHANTOM_OMNI, Mapping::default(), true).unwrap();
        let q = Quat::new(
            std::f64::consts::FRAC_1_SQRT_2,
            -std::f64::consts::FRAC_1_SQRT_2,
            0.0,
            0.0,
        );
        let m = transform_of_pose([0.0, -10.0, 0.0], q);
        for _ in 0..700 {
            core.step(&m, 0);
        }
        assert!(core.forces_enabled());
        let f = core.step(&[f64::NAN; 16], 0);
        assert_eq!(f, [0.0; 3]);
        assert!(!core.faults().is_empty());
        // Stays at zero until cleared, whatever the pose.
        assert_eq!(core.step(&m, 0), [0.0; 3]);
    }

    /// The stylus held upright at device height `y` (mm), as a transform.
    fn upright_at(y: f64) -> [f64; 16] {
        let h = std::f64::consts::FRAC_1_SQRT_2;
        transform_of_pose([0.0, y, 0.0], Quat::new(h, -h, 0.0, 0.0))
    }

    #[test]
    fn the_safe_start_waits_for_the_brush_above_the_paper() {
        let params = presets::by_name("large").unwrap();
        let mut core = ServoCore::new(params, PHANTOM_OMNI, Mapping::default(), true).unwrap();
        // In the inkwell, below the paper: held, whatever the model would push.
        for _ in 0..600 {
            assert_eq!(core.step(&upright_at(-65.6), 0), [0.0; 3]);
        }
        assert!(core.awaiting_lift() && !core.forces_enabled());
        // Lifted (as a hand does, no sensor jump) until the ferrule is just under a brush
        // length above the paper: still held.
        let paper = Mapping::default().paper_height_mm;
        let below = paper + params.length_mm as f64 - 0.5;
        let mut y = -65.6;
        while y < below {
            y = (y + 0.1).min(below);
            assert_eq!(core.step(&upright_at(y), 0), [0.0; 3]);
        }
        assert!(core.awaiting_lift() && core.faults().is_empty());
        core.step(&upright_at(paper + params.length_mm as f64 + 0.5), 0);
        assert!(!core.awaiting_lift() && core.forces_enabled());
        // The user's explicit enable skips the wait.
        let mut core = ServoCore::new(params, PHANTOM_OMNI, Mapping::default(), true).unwrap();
        core.step(&upright_at(-65.6), 0);
        core.apply(ServoCommand::EnableForces(true));
        core.step(&upright_at(-65.6), 0);
        assert!(core.forces_enabled());
        // Asked for no forces: none, wherever the stylus goes.
        let mut core = ServoCore::new(params, PHANTOM_OMNI, Mapping::default(), false).unwrap();
        core.step(&upright_at(0.0), 0);
        assert!(!core.awaiting_lift() && !core.forces_enabled());
    }

    #[test]
    fn calibration_holds_forces_and_an_update_is_no_jump() {
        let params = presets::by_name("large").unwrap();
        let mut core = ServoCore::new(params, PHANTOM_OMNI, Mapping::default(), true).unwrap();
        core.set_uncalibrated(true);
        for _ in 0..10 {
            core.step(&upright_at(20.0), 0);
        }
        assert_eq!(core.faults(), Faults::NOT_CALIBRATED);
        assert!(!core.forces_enabled(), "held while the inkwell is wanted");
        core.device_recalibrated();
        assert_eq!(core.hold_tick(), [0.0; 3]);
        // 30 mm lower at once: the calibrated pose, no sensor jump.
        core.step(&upright_at(-10.0), 0);
        assert!(core.faults().is_empty(), "{:?}", core.faults());
        assert!(core.forces_enabled());
        let z = core.state().unwrap().handle.pose().pos.z.to_f64();
        assert!((z - 50.0).abs() < 1e-6, "{z}");
        // The same jump without the update is one.
        core.step(&upright_at(20.0), 0);
        assert!(core.faults().contains(Faults::SENSOR_JUMP));
    }

    #[test]
    fn a_device_warning_latches_until_cleared() {
        let params = presets::by_name("large").unwrap();
        let mut core = ServoCore::new(params, PHANTOM_OMNI, Mapping::default(), true).unwrap();
        for _ in 0..10 {
            core.step(&upright_at(-10.0), 0);
        }
        core.device_warning();
        assert_eq!(core.step(&upright_at(-30.0), 0), [0.0; 3]);
        assert_eq!(core.faults(), Faults::DEVICE_WARNING);
        core.apply(ServoCommand::EnableForces(true));
        assert!(!core.forces_enabled(), "enabling waits for the clear");
        core.apply(ServoCommand::ClearFaults);
        core.step(&upright_at(-30.0), 0);
        assert!(core.faults().is_empty() && core.forces_enabled());
    }

    #[test]
    fn the_calibration_style_prefers_what_needs_no_help() {
        assert_eq!(calibration_style(0), None);
        assert_eq!(
            calibration_style(HD_CALIBRATION_ENCODER_RESET | HD_CALIBRATION_INKWELL),
            Some(HD_CALIBRATION_INKWELL as HdEnum)
        );
        assert_eq!(calibration_style(7), Some(HD_CALIBRATION_AUTO as HdEnum));
        assert_eq!(
            calibration_style(HD_CALIBRATION_ENCODER_RESET),
            Some(HD_CALIBRATION_ENCODER_RESET as HdEnum)
        );
    }

    #[test]
    fn unusable_limits_are_refused() {
        assert!(device_limits(3.3, 0.88).is_ok());
        assert!(device_limits(f64::NAN, 0.88).is_err());
        assert!(device_limits(0.0, 0.0).is_err());
        assert!(device_limits(1.0, 2.0).is_err());
        assert!(device_limits(1e6, 1.0).is_err());
    }
}
