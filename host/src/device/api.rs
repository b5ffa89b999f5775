//! The device seam: "a device" runs the brush model, takes the hand's pose and commands, and
//! sends back its state.
//!
//! The GUI never touches a [`Brush`](maobi_shared::Brush) directly. It sends the hand's pose
//! and commands through a [`Device`] and draws the [`BrushFrame`]s that come back (one per
//! 1 ms model tick), so a real pen on a serial link and the built-in simulator look the same
//! to it.
//!
//! Devices:
//! * [`super::builtin::SimDevice`]: the built-in simulator (the shared model on the host).
//! * [`super::client::LinkDevice`]: a device speaking `maobi_shared::protocol`, over TCP
//!   (`tcp:HOST:PORT`: the QEMU board, `maobi sim-device`, the Phantom bridge) or a
//!   serial port (`serial:PATH`: the pen on USB).
//! * `crate::phantom::device::PhantomDevice`: the Phantom's servo loop in this process.

use std::fmt;
use std::sync::Arc;

use maobi_shared::footprint::Geometry;
use maobi_shared::force::OutputState;
use maobi_shared::guide::{GuideForce, GuideStream};
use maobi_shared::params::TickLimits;
use maobi_shared::{presets, BrushParams, BrushScalar, Fx, Layer, ParamId, Pose, Scalar, Vec3};

use super::journal::Journal;
use super::model::{BrushChoice, ModelKind};
use crate::poses::PoseTrack;

/// The brush's state after one model tick, as a device reports it.
#[derive(Clone, Debug)]
pub struct BrushFrame {
    /// Model tick number since the device started.
    pub tick: u64,
    /// The handle (ferrule) pose the model was driven to.
    pub pose: Pose<f64>,
    /// Spine masses S_i (mm), S_0 at the ferrule.
    pub spine: Vec<Vec3<Fx>>,
    /// Virtual skeleton nodes VS_i (mm).
    pub skeleton: Vec<Vec3<Fx>>,
    /// Each layer's surface ellipse.
    pub layers: Vec<Layer<Fx>>,
    pub in_contact: Vec<bool>,
    /// K, nodes per surface ring.
    pub ring_nodes: usize,
    /// Surface at or below this height inks (mm).
    pub eps: Fx,
    /// The force model's output (N): total, and its normal part.
    pub force_total: [f64; 3],
    pub force_normal: [f64; 3],
    /// Depth of the virtual skeleton below the paper (mm).
    pub depth_mm: f64,
    /// What the output stage commands the motors (N) after ramp, clamp and passivity control.
    pub command: [f64; 3],
    pub output: OutputState,
    /// The device is driving this tick from a pose file, not from the hand.
    pub replaying: bool,
    /// When the host had this frame (decoded from the link, or made by the simulator): the
    /// start of its latency to the screen.
    pub received: std::time::Instant,
    /// Guided writing, while the guide is active.
    pub guide: Option<GuideFrame>,
    /// Baxter & Lin's brush: each spine's joints from its root to its tip (mm), for the
    /// drawing; empty for Liang's (its spine and skeleton are above).
    pub hairs: Vec<Vec<Vec3<f64>>>,
}

impl BrushFrame {
    /// The geometry the footprint and the drawing are computed from.
    pub fn geometry(&self) -> Geometry<'_, Fx> {
        Geometry {
            spine: &self.spine,
            layers: &self.layers,
            ring_nodes: self.ring_nodes,
            eps: self.eps,
        }
    }

    pub fn contacts(&self) -> usize {
        self.in_contact.iter().filter(|&&c| c).count()
    }
}

/// Where the GUI wants the hand (the ferrule) to be.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct HandInput {
    /// Paper position (mm).
    pub x: f64,
    pub y: f64,
    /// Ferrule height above the paper (mm).
    pub z: f64,
    /// Tilt about the paper's x and y axes (degrees); 0, 0 holds the brush straight down.
    pub tilt_x_deg: f64,
    pub tilt_y_deg: f64,
}

impl HandInput {
    pub fn pose(&self) -> Pose<f64> {
        let (ax, ay) = (
            self.tilt_x_deg.to_radians() * 0.5,
            self.tilt_y_deg.to_radians() * 0.5,
        );
        let qx = maobi_shared::Quat::new(ax.cos(), ax.sin(), 0.0, 0.0);
        let qy = maobi_shared::Quat::new(ay.cos(), 0.0, ay.sin(), 0.0);
        Pose::new(
            Vec3::new(self.x, self.y, self.z),
            qy.compose(qx).normalized(),
        )
    }
}

/// A command to the device.
#[derive(Clone, Debug)]
pub enum DeviceCommand {
    /// Move the hand toward this pose (the device limits the speed as a hand would).
    Hand(HandInput),
    /// Enable or disable the force output (it ramps in and out).
    EnableForces(bool),
    /// Clear a latched output-stage fault.
    ClearFault,
    /// Wet every layer to this wetness in [0, 1].
    Dip(f32),
    /// Replace all parameters with a preset's (by name, see `maobi_shared::presets`; with
    /// Baxter & Lin's model also one of their heads, see [`super::model::BrushChoice`]).
    Preset(String),
    /// Run this brush model from now on, the brush as it stands, at rest where the hand is.
    /// The built-in simulator and the Phantom have the choice; a pen runs Liang's model.
    Model(ModelKind),
    /// Set one parameter; validated before it is sent.
    SetParam(ParamId, f32),
    /// Drive the model from a pose file, tick by tick, then hand control back.
    Replay(Arc<PoseTrack>),
    /// Stop a replay.
    StopReplay,
    /// Guided writing: the device pulls the hand toward the moving point of this pose track
    /// (played in real time from the next tick) with `maobi_shared::guide`'s fading
    /// spring-damper; `None` stops it (fading out).
    Guide(Option<Arc<PoseTrack>>),
    /// Stay in the lane: no force while the ferrule is within the radius (mm) of this pose
    /// track's path on the paper (where it presses), a spring-damper back toward it outside
    /// (`maobi_shared::guide::Lane`, through the guide's stream); `None` lets go (fading
    /// out). Guided writing and the lane replace each other. The built-in pen, the Phantom
    /// and a virtual pen over the link keep it ([`LANE_NEEDS_THE_POSE`]).
    Lane(Option<(Arc<PoseTrack>, f64)>),
}

/// Why a pen refuses [`DeviceCommand::Lane`]: the fixture's wall point is computed from the
/// hand's position every tick, which the host has only where it supplies the poses (a
/// virtual pen) or runs the force loop itself (the built-in pen, the Phantom).
pub const LANE_NEEDS_THE_POSE: &str = "\"Stay in the lane\" over the link needs a virtual-pen \
     device (the QEMU board, the sim-device); a pen with its own sensors cannot take it yet";

/// Why a lane is refused whatever the device: its stroke has no path on the paper.
pub const LANE_NO_PATH: &str = "the stroke never presses the paper: no lane to keep";

/// The tube's radius range for [`DeviceCommand::Lane`] (mm).
pub const LANE_RADIUS_MM: std::ops::RangeInclusive<f64> = 0.5..=20.0;

/// Refuses a lane radius outside [`LANE_RADIUS_MM`] (every device that keeps a lane).
pub fn check_lane_radius(r: f64) -> Result<(), DeviceError> {
    if LANE_RADIUS_MM.contains(&r) {
        Ok(())
    } else {
        Err(DeviceError::Rejected(format!(
            "the lane's radius {r} mm is outside {} ..= {} mm",
            LANE_RADIUS_MM.start(),
            LANE_RADIUS_MM.end()
        )))
    }
}

impl DeviceCommand {
    /// Checks the command against the parameters in force (`params`) with the shared
    /// model's own checks, as every device does before carrying it out or sending it: a
    /// parameter the model would refuse, an unknown preset, a wetness outside 0 ..= 1.
    pub fn validate(&self, params: &BrushParams) -> Result<(), DeviceError> {
        match self {
            DeviceCommand::SetParam(id, v) => {
                // Every device runs Liang's brush in fixed point (the pen, the built-in
                // simulator, the bridge's servo loop by default), whose step refuses a brush
                // too stiff for its formats: refused here, before the panel shows it.
                let mut p = *params;
                p.set(*id, *v)
                    .and_then(|()| p.validate())
                    .and_then(|()| <Fx as BrushScalar>::check_params(&p))
                    .map_err(|e| DeviceError::Rejected(e.to_string()))
            }
            DeviceCommand::Preset(name) => BrushChoice::liang_params(name)
                .map(|_| ())
                .map_err(DeviceError::Rejected),
            DeviceCommand::Dip(w) if !(0.0..=1.0).contains(w) => Err(DeviceError::Rejected(
                format!("wetness {w} is outside 0 ..= 1"),
            )),
            DeviceCommand::Lane(Some((_, r))) => check_lane_radius(*r),
            _ => Ok(()),
        }
    }

    /// Checks the command against a device's tick limits (from its handshake) with the
    /// device's own check ([`TickLimits::check`]): a parameter or a preset that the device
    /// would refuse because its tick cannot run it is refused here, in the same words,
    /// before it is sent. A preset's substep rate is lowered to the device's, as the device
    /// does.
    pub fn check_tick_limits(
        &self,
        params: &BrushParams,
        limits: &TickLimits,
    ) -> Result<(), DeviceError> {
        let brush = match self {
            DeviceCommand::SetParam(id, v) => {
                let mut p = *params;
                p.set(*id, *v)
                    .map_err(|e| DeviceError::Rejected(e.to_string()))?;
                p
            }
            DeviceCommand::Preset(name) => match BrushChoice::liang_params(name) {
                Ok(p) => limits.brush(p),
                Err(why) => return Err(DeviceError::Rejected(why)),
            },
            _ => return Ok(()),
        };
        limits
            .check(&brush)
            .map_err(|e| DeviceError::Rejected(e.to_string()))
    }

    /// Checks the command as a device running `model` with the brush `brush` (parameters
    /// `params`) would take it, before it is queued: the shared checks ([`Self::validate`])
    /// for Liang's brush; for Baxter & Lin's, a brush name may also be one of their heads,
    /// and only the parameters its head reads are taken; a switch to Liang's model needs one
    /// of its presets. The built-in simulator and the Phantom check with this.
    pub fn validate_for(
        &self,
        model: ModelKind,
        brush: &str,
        params: &BrushParams,
    ) -> Result<(), DeviceError> {
        let reject = DeviceError::Rejected;
        match (self, model) {
            (DeviceCommand::Preset(name), m) => {
                BrushChoice::for_model(name, m).map(|_| ()).map_err(reject)
            }
            (DeviceCommand::SetParam(id, v), ModelKind::BaxterLin) => {
                let choice = BrushChoice::parse(brush).map_err(reject)?;
                choice.baxter_lin_reads(*id).map_err(reject)?;
                self.validate(params)?;
                let mut p = *params;
                p.set(*id, *v).map_err(|e| reject(e.to_string()))?;
                choice.baxter_lin_builds(&p).map_err(reject)
            }
            (DeviceCommand::Model(ModelKind::BaxterLin), _) => {
                BrushChoice::for_model(brush, ModelKind::BaxterLin)
                    .and_then(|b| b.baxter_lin_builds(params))
                    .map_err(reject)
            }
            (DeviceCommand::Model(ModelKind::Liang), _) => {
                BrushChoice::for_model(brush, ModelKind::Liang)
                    .map(|_| ())
                    .map_err(|_| {
                        reject(format!(
                            "Liang's model has no {brush} brush: choose one of its presets first"
                        ))
                    })
            }
            _ => self.validate(params),
        }
    }
}

/// Guided writing at one tick, as the device reports it.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct GuideFrame {
    /// The moving point (mm).
    pub anchor: [f64; 3],
    /// The pen's distance from it (mm).
    pub distance_mm: f64,
    /// The guide's fade gain in [0, 1].
    pub gain: f64,
    /// The guide's force on the hand (N), part of `force_total`.
    pub force: [f64; 3],
}

impl GuideFrame {
    /// The frame of a guide `stream` whose tick gave `force`; `None` while it has no moving
    /// point.
    pub fn of<S: Scalar>(stream: &GuideStream<S>, force: &GuideForce<S>) -> Option<GuideFrame> {
        let anchor = stream.anchor()?;
        Some(GuideFrame {
            anchor: anchor.to_f64(),
            distance_mm: force.distance_mm.to_f64(),
            gain: stream.guide().gain().to_f64(),
            force: force.force.to_f64(),
        })
    }
}

/// Why a command was not carried out.
#[derive(Clone, Debug, PartialEq)]
pub enum DeviceError {
    NotConnected,
    /// The device (or the shared validation in front of it) refused the command.
    Rejected(String),
    /// The link failed.
    Link(String),
}

impl fmt::Display for DeviceError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            DeviceError::NotConnected => f.write_str("not connected"),
            DeviceError::Rejected(why) => write!(f, "rejected: {why}"),
            DeviceError::Link(why) => write!(f, "link error: {why}"),
        }
    }
}

impl std::error::Error for DeviceError {}

impl From<presets::UnknownPreset<'_>> for DeviceError {
    fn from(e: presets::UnknownPreset<'_>) -> DeviceError {
        DeviceError::Rejected(e.to_string())
    }
}

/// What the status bar shows.
#[derive(Clone, Debug)]
pub struct DeviceStatus {
    /// Human-readable device name ("built-in simulator", a port name, ...).
    pub name: String,
    pub connected: bool,
    /// Wire protocol version, when the device speaks one.
    pub protocol_version: Option<u32>,
    pub firmware_version: Option<String>,
    /// Faults the device reports (empty when healthy).
    pub faults: Vec<String>,
    /// State frames lost between the device and the GUI.
    pub frames_dropped: u64,
    /// Model ticks the device could not run in real time (it fell behind and skipped).
    pub ticks_late: u64,
    /// The device's measured tick period (ms; mean over its last report), when it has a
    /// clock of its own.
    pub tick_period_ms: Option<f64>,
    /// The parameters in force on the device.
    pub params: BrushParams,
    /// Name of the preset the parameters started from.
    pub preset: String,
    /// The brush model the device runs.
    pub model: ModelKind,
    pub forces_enabled: bool,
    /// A replay is running.
    pub replaying: bool,
    /// Replays finished since connecting.
    pub replays_done: u64,
    /// For a device over the wire protocol: the link's state and counters.
    pub link: Option<LinkReport>,
    /// What the device's tick runs (its handshake's; none for the desktop's own devices).
    pub tick_limits: TickLimits,
}

/// The state of a wire-protocol link ([`super::client::LinkDevice`]).
#[derive(Clone, Debug, Default)]
pub struct LinkReport {
    /// "connected to ...", "link lost: ...; reconnecting", "not connected: ...".
    pub state: String,
    /// The device's board name, from its handshake.
    pub board: Option<String>,
    /// The device's capabilities, from its handshake.
    pub capabilities: String,
    /// The device's stored configuration, from its handshake (protocol 2): "valid",
    /// "missing (never written)", "corrupt: ...", "not applicable ...".
    pub config: String,
    /// Whether that configuration state lets the device render forces.
    pub config_allows_forces: bool,
    /// Our decoder's counters (frames decoded; framing, CRC, oversized, decode and version
    /// errors), over all sessions.
    pub rx: maobi_shared::protocol::LinkStats,
    /// The device's receiver counters, from its telemetry.
    pub device_rx: maobi_shared::protocol::LinkStats,
    /// Ticks the device ran without a pose sample (virtual pen), from its telemetry.
    pub pose_gaps: u32,
    /// State frames received.
    pub states: u64,
    /// Sessions that completed the handshake, and sessions lost after it.
    pub sessions: u32,
    pub lost: u32,
    /// Connection attempts so far.
    pub attempts: u32,
    pub last_error: Option<String>,
    pub last_event: Option<String>,
}

/// A source of brush state that takes commands: the built-in simulator or a real pen.
pub trait Device {
    /// Opens the link (for the simulator: starts the model).
    fn connect(&mut self) -> Result<(), DeviceError>;
    /// Closes the link; the device's output stage fades its forces out.
    fn disconnect(&mut self);
    fn status(&self) -> DeviceStatus;
    /// Appends the frames that arrived since the last call, oldest first.
    fn poll(&mut self, out: &mut Vec<BrushFrame>);
    /// Sends a command. Parameters are validated (with the shared model's own checks) before
    /// anything is sent, so a rejection comes back here.
    fn send(&mut self, cmd: DeviceCommand) -> Result<(), DeviceError>;
    /// Every pose and brush command since the model started, for saving the session
    /// ([`super::journal`]); `None` from devices that keep no journal (a pen on a link).
    fn journal(&self) -> Option<Journal> {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A parameter that makes the brush too stiff for the fixed-point step at its substep
    /// rate is refused before it is queued, naming what to raise; at more substeps it is
    /// taken.
    #[test]
    fn a_brush_too_stiff_for_fixed_point_is_rejected_before_it_is_queued() {
        let stiff = DeviceCommand::SetParam(ParamId::AxialStiffness, 50_000.0);
        match stiff.validate(&presets::LARGE) {
            Err(DeviceError::Rejected(why)) => assert!(why.contains("substeps_per_tick"), "{why}"),
            other => panic!("{other:?}"),
        }
        let finer = BrushParams {
            substeps_per_tick: 5,
            ..presets::LARGE
        };
        assert!(stiff.validate(&finer).is_ok());
    }
}
