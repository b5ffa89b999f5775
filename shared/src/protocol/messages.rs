//! The messages: [`HostMsg`] (host to device) and [`DeviceMsg`] (device to host), and
//! everything they carry except the brush state (see [`super::state`]).

use core::fmt;

use heapless::String;
use serde::{Deserialize, Serialize};

use super::frame::{
    check_version, Message, ProtocolError, DEVICE_TO_HOST, HOST_TO_DEVICE, PROTOCOL_VERSION,
};
use super::state::{BrushState, GuideSample, PoseSample};
use crate::params::{BrushParams, ParamError, ParamId};
use crate::presets;

/// Largest decoded host-to-device frame (header + message + CRC). The biggest host
/// message, a [`PoseSample`] with every value at its longest varint, is an 85-byte frame
/// (test `largest_messages_fit_their_bounds`); the rest is room to grow. The device's
/// receive buffer is this size.
pub const HOST_MSG_MAX: usize = 256;
/// Largest decoded device-to-host frame. A [`BrushState`] of [`crate::params::MAX_LAYERS`]
/// layers with every value at its longest varint (10 bytes per fixed-point value) is a
/// 3786-byte frame (test `largest_messages_fit_their_bounds`), so any brush state the model
/// can reach fits in one frame; the large preset's is 0.85-0.93 KB.
pub const DEVICE_MSG_MAX: usize = 4096;

/// Capacity of names on the wire (board, host program, preset).
pub const NAME_LEN: usize = 24;
/// Capacity of a rejected parameter's explanation.
pub const REASON_LEN: usize = 64;

/// Host to device.
///
/// The variant order is the wire tag: any change to it or to a message's fields bumps
/// [`PROTOCOL_VERSION`].
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
}

impl Message for HostMsg {
    const DIRECTION: u8 = HOST_TO_DEVICE;
    const MAX_DECODED: usize = HOST_MSG_MAX;
}

impl Message for DeviceMsg {
    const DIRECTION: u8 = DEVICE_TO_HOST;
    const MAX_DECODED: usize = DEVICE_MSG_MAX;
}

/// `Debug` as `Faults(0x5: SENSOR_JUMP | LINK_SILENT)` and `Display` as `SENSOR_JUMP |
/// LINK_SILENT` for a flag set (bits without a name print in hex).
macro_rules! flag_fmt {
    ($name:ident) => {
        impl fmt::Debug for $name {
            fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                write!(f, "{}({:#x}: ", stringify!($name), self.bits())?;
                bitflags::parser::to_writer(self, &mut *f)?;
                f.write_str(")")
            }
        }

        impl fmt::Display for $name {
            fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                bitflags::parser::to_writer(self, f)
            }
        }
    };
}

// Flag sets travel as plain integers (serde-transparent), so bits a newer peer defines are
// kept, not lost.

/// What a board can do, announced in [`DeviceInfo`].
#[derive(Copy, Clone, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(transparent)]
pub struct Capabilities(u32);

bitflags::bitflags! {
    impl Capabilities: u32 {
        /// Motors: the board can push back on the hand.
        const FORCE_OUTPUT = 1 << 0;
        /// The pen's pose comes from the board's own sensors.
        const REAL_SENSORS = 1 << 1;
        /// The pen's pose comes from the host as [`HostMsg::Pose`] (QEMU board, Phantom bridge).
        const VIRTUAL_PEN = 1 << 2;
        /// The sensors need [`Command::Calibrate`] before forces may be enabled.
        const NEEDS_CALIBRATION = 1 << 3;
        /// The pen has buttons (for a virtual pen: reported in [`PoseSample::buttons`]).
        const BUTTONS = 1 << 4;
    }
}
flag_fmt!(Capabilities);

/// Latched faults. A fault stays set until [`Command::ClearFaults`] and its cause is gone;
/// forces stay off while any is set.
#[derive(Copy, Clone, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(transparent)]
pub struct Faults(u16);

bitflags::bitflags! {
    impl Faults: u16 {
        /// Consecutive sensor readings (or pose samples) further apart than the pen can move.
        const SENSOR_JUMP = 1 << 0;
        /// A 1 ms tick did not finish in time.
        const LOOP_OVERRUN = 1 << 1;
        /// Nothing from the host for longer than the link timeout (forces faded out).
        const LINK_SILENT = 1 << 2;
        /// A parameter write was rejected.
        const PARAM_REJECTED = 1 << 3;
        /// The watchdog reset the board.
        const WATCHDOG = 1 << 4;
        /// The sensors are not calibrated.
        const NOT_CALIBRATED = 1 << 5;
    }
}
flag_fmt!(Faults);

/// The pen's buttons, pressed = set.
#[derive(Copy, Clone, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(transparent)]
pub struct Buttons(u8);

bitflags::bitflags! {
    impl Buttons: u8 {
        const PRIMARY = 1 << 0;
        const SECONDARY = 1 << 1;
    }
}
flag_fmt!(Buttons);

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
}

impl DeviceInfo {
    /// This build's protocol version, `board` cut to [`NAME_LEN`] bytes.
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
        }
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
    OutOfRange { value: f32, min: f32, max: f32 },
    NotWholeNumber { value: f32 },
    Inconsistent { why: String<REASON_LEN> },
    RingNodesNotPowerOfTwo { value: f32 },
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
    /// Wet every layer (`Brush::dip`); `wetness` as [`crate::Fx`] bits, clamped to [0, 1].
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
    /// at the end: every earlier variant keeps its wire tag. Boards that do not offer the
    /// hook answer [`CommandError::Unsupported`].
    InjectOverrun,
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
}
