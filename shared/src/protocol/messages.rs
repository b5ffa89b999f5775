//! The messages: [`HostMsg`] (host to device) and [`DeviceMsg`] (device to host), and
//! everything they carry except the brush state (see [`super::state`]) and the flag sets
//! (see [`super::flags`]).

use core::fmt;

use heapless::String;
use serde::{Deserialize, Serialize};

use super::flags::{Buttons, Capabilities, Faults};
use super::frame::{
    check_version, encode_as, Message, ProtocolError, DEVICE_TO_HOST, HOST_TO_DEVICE,
    PROTOCOL_VERSION,
};
use super::state::{BrushState, GuideSample, PoseSample};
use crate::params::{BrushParams, ParamError, ParamId, TickLimits};
use crate::pen_io::{ConfigState, DeviceConfig, InvalidField};
use crate::presets;

/// Largest decoded host-to-device frame (header + message + CRC). The biggest host
/// message, a [`HostMsg::SetConfig`] with every value at its longest varint, is a 267-byte
/// frame (a [`PoseSample`]: 85 bytes; test `largest_messages_fit_their_bounds`); the rest
/// is room to grow. The device's receive buffer is this size.
pub const HOST_MSG_MAX: usize = 512;
/// Largest decoded device-to-host frame. A [`BrushState`] of [`crate::params::MAX_LAYERS`]
/// layers with every value at its longest varint (10 bytes per fixed-point value) is a
/// 3786-byte frame (test `largest_messages_fit_their_bounds`), so any brush state the model
/// can reach fits in one frame; the large preset's stay under a kilobyte (test
/// `state_frame_size_and_link_share`).
pub const DEVICE_MSG_MAX: usize = 4096;

/// At most this many [`HostMsg::Pose`] samples a host keeps in flight: sent, but not yet
/// reported consumed by a state's `pose_seq`. A device with a virtual pen queues at least this
/// many, so a host that keeps to it never fills the queue: nothing is lost when the device runs
/// slower than real time (the firmware under QEMU). A device in real time consumes one pose per
/// millisecond and reports at 120 Hz, so 48 leaves it about 40 ms of slack.
pub const POSES_IN_FLIGHT: u32 = 48;

/// Capacity of names on the wire (board, host program, preset).
pub const NAME_LEN: usize = 24;
/// Capacity of a rejected parameter's explanation.
pub const REASON_LEN: usize = 64;

/// Host to device.
///
/// The variant order is the wire tag: any change to it or to a message's fields bumps
/// [`PROTOCOL_VERSION`].
// `SetConfig` makes it ~330 bytes; messages are decoded one at a time into place and there
// is no allocator to box the configuration.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum HostMsg {
    /// Opens a session; the device answers [`DeviceMsg::Hello`].
    Hello(HostHello),
    /// Liveness and round-trip probe; the device answers [`DeviceMsg::Pong`] with the same
    /// `seq`. A host without pose samples to send pings so the device can tell the link is up.
    Ping { seq: u32 },
    /// The virtual pen's pose for one tick (QEMU board, or the Phantom bridge).
    Pose(PoseSample),
    /// Reads a parameter; answered by [`DeviceMsg::Param`].
    GetParam { id: u8 },
    /// Sets a parameter (validated on the device); answered by [`DeviceMsg::Param`].
    SetParam { id: u8, value: f32 },
    /// A command; answered by [`DeviceMsg::CommandDone`].
    Command(Command),
    /// Guided writing: the stroke's moving point for the next [`HostMsg::Pose`] with the
    /// same `seq` (sent just before it, one per tick while guiding). Appended in protocol
    /// version 2: every earlier variant keeps its wire tag.
    Guide(GuideSample),
    // Protocol 3: the stored configuration (appended: earlier variants keep their tags).
    /// Reads the configuration in force; answered by [`DeviceMsg::Config`] (an error when
    /// none is: [`ConfigRejected::NotStored`] with the [`ConfigState`]). A configuration
    /// migrated from an older format ([`ConfigState::Migrated`], protocol 7) is in force for
    /// the kinematics and is answered, what that format lacked at zero.
    GetConfig,
    /// Validates `config`, writes it to the pen's store, reads it back and puts it in force;
    /// answered by [`DeviceMsg::Config`] with the configuration now stored, or why not
    /// ([`ConfigRejected`]: the invalid field, forces enabled, the store failed). Nothing is
    /// written unless the whole configuration is valid, and never while forces are enabled.
    SetConfig(DeviceConfig),
}

/// Device to host.
///
/// The variant order is the wire tag: any change to it or to a message's fields bumps
/// [`PROTOCOL_VERSION`].
// A device message is built in place and encoded at once (no allocator to box the state).
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum DeviceMsg {
    /// The device's identity and limits, in answer to [`HostMsg::Hello`].
    Hello(DeviceInfo),
    /// Answer to [`HostMsg::Ping`].
    Pong { seq: u32 },
    /// The brush (one spine of it) at one tick, streamed at about 120 Hz.
    State(BrushState),
    /// Answer to [`HostMsg::GetParam`] and [`HostMsg::SetParam`].
    Param(ParamReply),
    /// Answer to [`HostMsg::Command`]: the command, echoed, and its outcome.
    CommandDone {
        command: Command,
        result: Result<(), CommandError>,
    },
    /// Something happened (sent when it happens).
    Event(Event),
    /// Loop timing and link health (sent periodically, about once a second).
    Telemetry(Telemetry),
    // Protocol 3 (appended: earlier variants keep their tags).
    /// Answer to [`HostMsg::GetConfig`] and [`HostMsg::SetConfig`].
    Config(Result<DeviceConfig, ConfigRejected>),
    /// Raw sensor readings for bring-up, streamed at the rate [`Command::StreamSensors`]
    /// asked for.
    Sensors(SensorReport),
}

impl Message for HostMsg {
    const DIRECTION: u8 = HOST_TO_DEVICE;
    const MAX_DECODED: usize = HOST_MSG_MAX;
}

impl Message for DeviceMsg {
    const DIRECTION: u8 = DEVICE_TO_HOST;
    const MAX_DECODED: usize = DEVICE_MSG_MAX;
}

/// [`DeviceMsg::State`]'s variant index, its tag on the wire.
const STATE_VARIANT: u32 = 2;

/// A [`DeviceMsg::State`] that borrows its state: serializes exactly as the owned message.
struct StateRef<'a>(&'a BrushState);

impl Serialize for StateRef<'_> {
    fn serialize<Ser: serde::Serializer>(&self, s: Ser) -> Result<Ser::Ok, Ser::Error> {
        s.serialize_newtype_variant("DeviceMsg", STATE_VARIANT, "State", self.0)
    }
}

impl DeviceMsg {
    /// The frame of `DeviceMsg::State(state.clone())`, byte for byte, without the copy: a
    /// device encodes the state (about 3 KB) where it lies instead of moving it onto its
    /// stack (test `borrowed_state_encodes_as_the_message`).
    pub fn encode_state(state: &BrushState, out: &mut [u8]) -> Result<usize, ProtocolError> {
        encode_as::<DeviceMsg, _>(&StateRef(state), out)
    }
}

/// A software version.
#[derive(
    Copy, Clone, Debug, Default, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize,
)]
pub struct Version {
    pub major: u16,
    pub minor: u16,
    pub patch: u16,
}

impl fmt::Display for Version {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}.{}.{}", self.major, self.minor, self.patch)
    }
}

/// The host's side of the handshake.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct HostHello {
    /// The host's [`PROTOCOL_VERSION`].
    pub protocol_version: u8,
    /// The host program's version.
    pub software: Version,
    /// The host program ("maobi-gui", "phantom-bridge", "hil").
    pub name: String<NAME_LEN>,
}

impl HostHello {
    /// Our hello: this build's protocol version, `name` cut to [`NAME_LEN`] bytes.
    pub fn new(name: &str, software: Version) -> Self {
        HostHello {
            protocol_version: PROTOCOL_VERSION,
            software,
            name: bounded_str(name),
        }
    }
    /// On the device: `VersionMismatch` unless the host speaks our version.
    pub fn check(&self) -> Result<(), ProtocolError> {
        check_version(self.protocol_version)
    }
}

/// The device's side of the handshake.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DeviceInfo {
    /// The device's [`PROTOCOL_VERSION`].
    pub protocol_version: u8,
    /// Firmware version.
    pub firmware: Version,
    /// Board name ("maobi-pen-r1", "qemu-mps2-an386").
    pub board: String<NAME_LEN>,
    pub capabilities: Capabilities,
    /// Largest force the motors may exert, briefly (N).
    pub force_peak_n: f32,
    /// Largest force the motors may exert indefinitely (N).
    pub force_continuous_n: f32,
    /// The stored configuration (protocol 3). Forces are refused
    /// ([`CommandError::ConfigNotValid`]) unless it [allows them](ConfigState::allows_forces):
    /// a physical pen needs a valid one; a virtual pen says
    /// [`ConfigState::NotApplicable`].
    pub config: ConfigState,
    /// What the board's core runs within its 1 ms tick (protocol 6): the device refuses a
    /// parameter or preset beyond these caps, and the host can tell before it asks.
    pub limits: TickLimits,
}

impl DeviceInfo {
    /// This build's protocol version, `board` cut to [`NAME_LEN`] bytes, configuration
    /// [`ConfigState::NotApplicable`] (a board with a store sets its state with
    /// [`Self::with_config`]).
    pub fn new(
        board: &str,
        firmware: Version,
        capabilities: Capabilities,
        force_peak_n: f32,
        force_continuous_n: f32,
    ) -> Self {
        DeviceInfo {
            protocol_version: PROTOCOL_VERSION,
            firmware,
            board: bounded_str(board),
            capabilities,
            force_peak_n,
            force_continuous_n,
            config: ConfigState::NotApplicable,
            limits: TickLimits::NONE,
        }
    }
    /// The same, with the board's tick limits.
    pub fn with_limits(mut self, limits: TickLimits) -> Self {
        self.limits = limits;
        self
    }
    /// The same, with the stored configuration's state.
    pub fn with_config(mut self, config: ConfigState) -> Self {
        self.config = config;
        self
    }
    /// On the host: `VersionMismatch` unless the device speaks our version.
    pub fn check(&self) -> Result<(), ProtocolError> {
        check_version(self.protocol_version)
    }
}

/// `s` cut to the longest prefix (on a character boundary) that fits `N` bytes.
pub fn bounded_str<const N: usize>(s: &str) -> String<N> {
    let mut out = String::new();
    for c in s.chars() {
        if out.push(c).is_err() {
            break;
        }
    }
    out
}

/// The [`ParamId`] with wire number `id`, if there is one.
pub fn param_id(id: u8) -> Option<ParamId> {
    ParamId::ALL.into_iter().find(|p| *p as u8 == id)
}

/// Answer to a parameter read or write: the parameter's wire number (as requested) and either
/// the value now in force or why the write (or read) was refused.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ParamReply {
    pub id: u8,
    pub result: Result<f32, ParamRejected>,
}

impl ParamReply {
    /// Answer to [`HostMsg::GetParam`] from the parameters in force.
    pub fn read(params: &BrushParams, id: u8) -> Self {
        let result = match param_id(id) {
            Some(p) => Ok(params.get(p)),
            None => Err(ParamRejected::unknown(id)),
        };
        ParamReply { id, result }
    }

    /// Answer to [`HostMsg::SetParam`]: `outcome` is what the brush's `set_param` returned,
    /// `params` the parameters in force afterwards (the old value stays on error).
    pub fn written(id: u8, outcome: Result<(), ParamError>, params: &BrushParams) -> Self {
        match outcome {
            Ok(()) => ParamReply::read(params, id),
            Err(e) => ParamReply {
                id,
                result: Err(e.into()),
            },
        }
    }
}

/// A refused parameter value: the parameter at fault (which may differ from the one written,
/// for values that are valid alone but not together) and why.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ParamRejected {
    /// Wire number of the parameter at fault.
    pub param: u8,
    pub reason: RejectReason,
}

impl ParamRejected {
    /// A parameter number the device does not know.
    pub fn unknown(id: u8) -> Self {
        ParamRejected {
            param: id,
            reason: RejectReason::UnknownParam,
        }
    }
}

/// [`ParamError`] in a form that crosses the link (plus unknown parameter numbers).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum RejectReason {
    UnknownParam,
    NotFinite,
    OutOfRange {
        value: f32,
        min: f32,
        max: f32,
    },
    NotWholeNumber {
        value: f32,
    },
    Inconsistent {
        why: String<REASON_LEN>,
    },
    RingNodesNotPowerOfTwo {
        value: f32,
    },
    // Protocol 6 (appended).
    /// Valid, but beyond the board's [`TickLimits`](crate::params::TickLimits).
    OverTickLimit {
        value: f32,
        max: f32,
    },
}

impl From<ParamError> for ParamRejected {
    fn from(e: ParamError) -> Self {
        let (param, reason) = match e {
            ParamError::NotFinite { param } => (param, RejectReason::NotFinite),
            ParamError::OutOfRange {
                param,
                value,
                min,
                max,
            } => (param, RejectReason::OutOfRange { value, min, max }),
            ParamError::NotWholeNumber { param, value } => {
                (param, RejectReason::NotWholeNumber { value })
            }
            ParamError::Inconsistent { param, why } => (
                param,
                RejectReason::Inconsistent {
                    why: bounded_str(why),
                },
            ),
            ParamError::RingNodesNotPowerOfTwo { value } => (
                ParamId::RingNodes,
                RejectReason::RingNodesNotPowerOfTwo { value },
            ),
            ParamError::OverTickLimit { param, value, max } => {
                (param, RejectReason::OverTickLimit { value, max })
            }
        };
        ParamRejected {
            param: param as u8,
            reason,
        }
    }
}

impl fmt::Display for ParamRejected {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match param_id(self.param) {
            Some(p) => write!(f, "{p}: ")?,
            None => write!(f, "parameter #{}: ", self.param)?,
        }
        match &self.reason {
            RejectReason::UnknownParam => f.write_str("no such parameter"),
            RejectReason::NotFinite => f.write_str("value is not a finite number"),
            RejectReason::OutOfRange { value, min, max } => {
                write!(f, "{value} is outside the valid range {min} ..= {max}")
            }
            RejectReason::NotWholeNumber { value } => write!(f, "{value} is not a whole number"),
            RejectReason::Inconsistent { why } => f.write_str(why),
            RejectReason::RingNodesNotPowerOfTwo { value } => {
                write!(f, "{value} is not one of 4, 8, 16, 32")
            }
            RejectReason::OverTickLimit { value, max } => write!(
                f,
                "{value} would not fit this pen's 1 ms tick; it allows at most {max}"
            ),
        }
    }
}

/// Commands from the host.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Command {
    EnableForces,
    DisableForces,
    /// Zero the sensors (board held in its rest fixture).
    Calibrate,
    /// Fill every layer with ink to this share of what it holds (`Brush::dip`); `wetness` as
    /// [`crate::Fx`] bits, clamped to [0, 1].
    DipInk {
        wetness: i64,
    },
    /// Replace the brush with a preset (reset at the current pose).
    ChoosePreset(PresetRef),
    /// Clear latched faults whose cause is gone.
    ClearFaults,
    /// Put the brush back at rest at the current pose.
    ResetBrush,
    /// Test hook (HIL): make the next force-loop tick overrun its period, so the device's
    /// overrun path (motors off, [`Faults::LOOP_OVERRUN`] latched) can be exercised. Added
    /// at the end: every earlier variant keeps its wire tag. Only test images offer it (the
    /// firmware's `test-hooks` feature); a pen, and any image built without the feature,
    /// answers [`CommandError::Unsupported`].
    InjectOverrun,
    // Protocol 3: bring-up (appended: earlier variants keep their tags).
    /// Stream [`DeviceMsg::Sensors`] at `rate_hz` (1 ..= [`SENSOR_RATE_MAX_HZ`]); 0 stops.
    /// Refused with [`CommandError::OutOfRange`] above the maximum.
    StreamSensors {
        rate_hz: u16,
    },
    /// Drive one motor gently for a moment, to check its wiring and direction. Refused while
    /// forces are enabled ([`CommandError::ForcesEnabled`]), while the configuration is not
    /// valid ([`CommandError::ConfigNotValid`]), and outside the caps
    /// ([`CommandError::OutOfRange`]); the motors are off again after `duration_ms`.
    NudgeMotor(Nudge),
}

/// Most sensor reports per second [`Command::StreamSensors`] asks for: one per force tick.
pub const SENSOR_RATE_MAX_HZ: u16 = 1000;

/// A gentle, short motor command ([`Command::NudgeMotor`]).
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Nudge {
    /// Motor channel, 0 ..= 2.
    pub channel: u8,
    /// Command in thousandths of full current, signed, at most [`Nudge::MAX_PERMILLE`] in
    /// magnitude.
    pub command_permille: i16,
    /// How long (ms), 1 ..= [`Nudge::MAX_MS`].
    pub duration_ms: u16,
}

impl Nudge {
    /// Largest nudge: 15% of full current, enough to turn a motor against its friction,
    /// too little to throw the arm.
    pub const MAX_PERMILLE: i16 = 150;
    /// Longest nudge (ms): a visible twitch, not a run into a joint limit.
    pub const MAX_MS: u16 = 300;

    /// Whether the nudge is within the caps.
    pub fn is_within_caps(&self) -> bool {
        self.channel < 3
            && self.command_permille.unsigned_abs() <= Self::MAX_PERMILLE.unsigned_abs()
            && (1..=Self::MAX_MS).contains(&self.duration_ms)
    }
}

/// Raw sensor readings ([`DeviceMsg::Sensors`]), for bring-up: what the pen's own sensors
/// say, before calibration and kinematics.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct SensorReport {
    /// Device tick (1 ms) of the reading.
    pub tick: u32,
    /// Encoder counts, unwrapped (`kinematics::EncoderUnwrap`), per motor.
    pub encoders: [i64; 3],
    /// Gimbal ADC codes after the filter (`pen_io::AdcFilter`), 12-bit.
    pub gimbal: [u16; 3],
    pub buttons: Buttons,
    /// The readings are computed, not measured: the QEMU board derives them from the host's
    /// pose through the pen's inverse kinematics.
    pub synthetic: bool,
}

/// Why [`HostMsg::GetConfig`] or [`HostMsg::SetConfig`] was refused.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum ConfigRejected {
    /// No valid configuration in force (answer to `GetConfig`): the stored state.
    NotStored(ConfigState),
    /// A value out of range, by field (`"pen.ratio"`, `"drive[1].deadband"`); nothing was
    /// written.
    Invalid(InvalidField),
    /// Forces are enabled: disable them before writing the configuration.
    ForcesEnabled,
    /// The store failed to write, or the image read back differs.
    StoreFailed,
}

impl fmt::Display for ConfigRejected {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ConfigRejected::NotStored(state) => write!(f, "no configuration in force: {state}"),
            ConfigRejected::Invalid(field) => write!(f, "{field}"),
            ConfigRejected::ForcesEnabled => {
                f.write_str("forces are enabled: disable them before writing the configuration")
            }
            ConfigRejected::StoreFailed => f.write_str("the configuration store failed"),
        }
    }
}

/// A preset, by its index in [`presets::PRESETS`] or by one of the names
/// [`presets::by_name`] accepts.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum PresetRef {
    Index(u8),
    Name(String<NAME_LEN>),
}

impl PresetRef {
    /// The preset's parameters, if it exists.
    pub fn resolve(&self) -> Option<BrushParams> {
        match self {
            PresetRef::Index(i) => presets::PRESETS.get(usize::from(*i)).map(|(_, p)| **p),
            PresetRef::Name(name) => presets::by_name(name),
        }
    }
}

/// Why a command was refused.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum CommandError {
    /// The board lacks the capability (forces on a board without motors, calibration of a
    /// virtual pen).
    Unsupported,
    /// [`PresetRef::resolve`] found nothing.
    UnknownPreset,
    /// Forces stay off while these faults are latched.
    FaultsLatched(Faults),
    // Protocol 3 (appended).
    /// The pen's stored configuration is missing or corrupt (see [`DeviceInfo::config`]),
    /// or not calibrated: forces (and nudges) stay off until a valid one is written.
    ConfigNotValid,
    /// Forces are enabled: the command (nudge, calibration) needs them off.
    ForcesEnabled,
    /// An argument outside its range (a nudge beyond its caps, a sensor rate too high).
    OutOfRange,
    /// The configuration store failed to write (calibration).
    StoreFailed,
    // Protocol 6 (appended).
    /// The preset is more than the board's core runs in its tick
    /// ([`DeviceInfo::limits`]): `param` (a [`ParamId`] number) is `value`, the cap `max`.
    OverTickLimit { param: u8, value: u32, max: u32 },
}

impl fmt::Display for CommandError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            CommandError::Unsupported => f.write_str("this board cannot do that"),
            CommandError::UnknownPreset => f.write_str("no such preset"),
            CommandError::FaultsLatched(faults) => {
                write!(f, "faults are latched ({faults}): clear them first")
            }
            CommandError::ConfigNotValid => {
                f.write_str("the pen's stored configuration is missing, invalid or not calibrated")
            }
            CommandError::ForcesEnabled => f.write_str("forces are on: switch them off first"),
            CommandError::OutOfRange => f.write_str("an argument is outside its range"),
            CommandError::StoreFailed => f.write_str("the configuration store failed to write"),
            CommandError::OverTickLimit { param, value, max } => {
                match param_id(*param) {
                    Some(p) => write!(f, "{p}")?,
                    None => write!(f, "parameter #{param}")?,
                }
                write!(
                    f,
                    " {value} would not fit this pen's 1 ms tick; it allows at most {max}"
                )
            }
        }
    }
}

/// Something that happened on the device, at a tick, with the faults latched after it.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Event {
    /// Device tick (1 ms) at which it happened.
    pub tick: u32,
    pub kind: EventKind,
    /// Faults latched after the event.
    pub faults: Faults,
}

/// What happened.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum EventKind {
    /// These faults were raised (newly latched).
    FaultRaised(Faults),
    /// These faults were cleared.
    FaultCleared(Faults),
    ForcesEnabled,
    ForcesDisabled,
    /// The first host contact since the board started.
    LinkConnected,
    /// The host is back after `silent_ms` of silence ([`Faults::LINK_SILENT`] was raised).
    LinkReconnected {
        silent_ms: u32,
    },
}

/// Loop timing and link health over the last reporting period.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Telemetry {
    /// Device tick (1 ms) at the end of the period.
    pub tick: u32,
    /// Shortest, mean and longest interval between tick starts (us; nominally 1000).
    pub tick_period_min_us: u32,
    pub tick_period_mean_us: u32,
    pub tick_period_max_us: u32,
    /// Time spent in the tick's work as a share of the tick (%), mean over the period.
    pub load_percent: u8,
    /// Device-to-host frames the device dropped (link busy or down), since start.
    pub frames_dropped: u32,
    /// Virtual pen: ticks without a new pose sample (the brush held its last pose), since
    /// start.
    pub pose_gaps: u32,
    /// The device receiver's counters (frames decoded; CRC, framing, oversized, decode and
    /// version errors), since start.
    pub rx: super::frame::LinkStats,
    // Protocol 6 (appended).
    /// The longest time one tick's work took over the period (us).
    pub tick_busy_max_us: u32,
    /// The same in the board's core-clock cycles, as its counter read them: the pen's DWT
    /// cycle counter (`CYCCNT`, 96 MHz), the QEMU board's 25 MHz system timer.
    pub tick_busy_max_cycles: u32,
    /// Ticks that overran (each latched [`Faults::LOOP_OVERRUN`]), since start.
    pub overruns: u32,
    /// Ticks in which the brush took a pose and advanced, since start: every tick but a
    /// pose gap and a tick the brush stood by (after an overrun).
    pub brush_ticks: u32,
}

impl Telemetry {
    /// The worst tick's work as a share of the nominal tick (%).
    pub fn worst_busy_percent(&self) -> f32 {
        self.tick_busy_max_us as f32 * crate::params::TICK_HZ as f32 / 1.0e4
    }
}
