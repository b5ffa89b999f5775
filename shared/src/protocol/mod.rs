//! # The device wire protocol
//!
//! One definition of everything that crosses the serial link between the pen's firmware and
//! the host (GUI, Phantom bridge, HIL runner, tests). `no_std`, no allocator; the device path
//! (encoding and [`FrameDecoder`]) never panics on any input: the module denies indexing,
//! `unwrap` and `expect` to keep it so.
//!
//! ## Frames
//!
//! | bytes on the wire | what |
//! |---|---|
//! | COBS( | consistent-overhead byte stuffing of everything up to the delimiter: no `0x00` inside |
//! | &nbsp;&nbsp;1 byte | [`PROTOCOL_VERSION`] |
//! | &nbsp;&nbsp;1 byte | direction: [`HOST_TO_DEVICE`] (`'H'`) or [`DEVICE_TO_HOST`] (`'D'`) |
//! | &nbsp;&nbsp;n bytes | the message, postcard-encoded ([`HostMsg`] or [`DeviceMsg`]) |
//! | &nbsp;&nbsp;4 bytes | CRC-32/ISO-HDLC of the header and the message, little-endian |
//! | ) | one code byte, plus one per 254 bytes |
//! | `0x00` | [`DELIMITER`] |
//!
//! The decoded content (header + message + CRC) is bounded per direction: [`HOST_MSG_MAX`]
//! = 512 bytes host to device, [`DEVICE_MSG_MAX`] = 4096 bytes device to host; on the wire
//! that is at most [`max_frame_len`] of it ([`Message::MAX_FRAME`]: 516 and 4114 bytes).
//! Encoding ([`Message::encode`]) streams postcard's output through the CRC and its COBS
//! flavour straight into the caller's buffer: no scratch buffer, no allocation.
//!
//! Receiving: [`FrameDecoder`] ([`DeviceRx`] on the device, [`HostRx`] on the host) takes the
//! byte stream in chunks of any size, undoes COBS byte by byte into a bounded buffer, and at
//! each delimiter checks, in this order: COBS valid and at least 6 bytes (else *framing
//! error*), CRC (else *CRC error*), version byte (else *version error*, reported as
//! [`ProtocolError::VersionMismatch`]), direction byte (else *decode error*, reported as
//! [`ProtocolError::WrongDirection`]: the link echoes), postcard decode with no bytes left
//! over (else *decode error*). Content beyond the buffer is skipped to the next delimiter (*oversized frame*).
//! Each dropped frame is returned once as an `Err` and counted in [`LinkStats`]; whatever the
//! garbage, the decoder is back in sync at the next `0x00`. Empty frames (`0x00 0x00`) are
//! ignored, so a sender may write a lone delimiter when the link opens to flush the peer.
//!
//! ## Messages
//!
//! | Host to device ([`HostMsg`]) | Device to host ([`DeviceMsg`]) |
//! |---|---|
//! | `Hello(`[`HostHello`]`)`: protocol version, host program and version | `Hello(`[`DeviceInfo`]`)`: protocol version, firmware version, board name, [`Capabilities`], force limits (peak, continuous, N) |
//! | `Ping { seq }` | `Pong { seq }` |
//! | `Pose(`[`PoseSample`]`)`: the virtual pen, each 1 ms tick | `State(`[`BrushState`]`)`: the brush, about 120 Hz |
//! | `Guide(`[`GuideSample`]`)`: guided writing's moving point for the pose of the same `seq` (version 2) | |
//! | `GetParam { id }`, `SetParam { id, value }` | `Param(`[`ParamReply`]`)`: the value in force, or [`ParamRejected`] |
//! | `Command(`[`Command`]`)`: enable / disable forces, calibrate, dip ink, choose preset, clear faults, reset brush, stream sensors, nudge a motor | `CommandDone { command, result }` |
//! | | `Event(`[`Event`]`)`: fault raised / cleared, forces enabled / disabled, link (re)connected, with the latched [`Faults`] |
//! | | `Telemetry(`[`Telemetry`]`)`: tick period min / mean / max (us), load (%), frames dropped, virtual-pen pose gaps, the device receiver's [`LinkStats`] |
//! | `GetConfig`, `SetConfig(`[`DeviceConfig`]`)` (protocol 3) | `Config(Result<`[`DeviceConfig`]`, `[`ConfigRejected`]`>)`: the configuration in force, or why not (the invalid field by name, forces enabled, store failed, none stored) |
//! | `Command(StreamSensors { rate_hz })`, `Command(NudgeMotor(`[`Nudge`]`))` (protocol 3) | `Sensors(`[`SensorReport`]`)`: unwrapped encoder counts, filtered gimbal codes, buttons, at the rate asked |
//!
//! ## The stored configuration and bring-up (protocol 3)
//!
//! [`DeviceInfo::config`] says what the pen knows about its stored configuration
//! ([`ConfigState`]): `Valid`, `Missing` (erased flash), `Corrupt(`[`ConfigError`]`)` (bad
//! magic, another format version, truncated, CRC mismatch, undecodable, a value out of
//! range: see [`crate::pen_io::config`] for the image), `NotApplicable` (a virtual pen
//! needs none), or `Migrated { from }` (protocol 7: an image of an older format, read into
//! this one; the kinematics and calibration are in force, forces are not until a
//! `SetConfig` gives each motor's winding resistance, the supply and the driver's rating).
//! While the state does not [allow forces](ConfigState::allows_forces),
//! `EnableForces` and `NudgeMotor` are refused with [`CommandError::ConfigNotValid`] and
//! the motors stay off. `SetConfig` validates the whole configuration before it writes
//! anything and is refused while forces are enabled; a valid write puts the configuration in
//! force and the state becomes `Valid`. `Calibrate` (physical pen) records the raw readings
//! at the inkwell into the configuration and stores it.
//!
//! Bring-up: `StreamSensors { rate_hz }` starts (0 stops) [`DeviceMsg::Sensors`];
//! `NudgeMotor` drives one motor at most 15% of full current for at most 300 ms
//! ([`Nudge::MAX_PERMILLE`], [`Nudge::MAX_MS`]), only with forces off and a valid
//! configuration, and the motor is off again afterwards.
//!
//! Two enums, one per direction, so each end can only decode what the other may send; the
//! direction byte makes an echoed frame an error rather than a message (without it an
//! echoed `Pong { seq }` would read as `Ping { seq }`, whose answer would echo forever). The
//! handshake: the host sends `Hello`, the device answers with its own; each side calls
//! [`HostHello::check`] / [`DeviceInfo::check`]. A peer of another version is caught even
//! before that: every frame carries the version byte, so its frames, the hello included,
//! come out of the decoder as `Err(VersionMismatch { ours, theirs })`.
//!
//! ## Error counters ([`LinkStats`])
//!
//! `frames_ok`, `framing_errors`, `crc_errors`, `oversized_frames`, `decode_errors`,
//! `version_errors`: per receiver, saturating. The device reports its own in [`Telemetry`]
//! with `frames_dropped` (frames it could not send); the host keeps its decoder's.
//!
//! ## Why these encodings
//!
//! * **postcard**: compact (varints, no field names, no padding), serde-derived from the
//!   types below, `no_std` without allocation, decoding bounded by the target types.
//! * **COBS + `0x00`**: constant worst-case overhead (1 byte per 254) and trivial
//!   resynchronisation: a zero byte always ends a frame.
//! * **CRC-32/ISO-HDLC** rather than a CRC-16: state frames are 0.6-3.8 KB, where CRC-32
//!   still detects every error of up to 3 flipped bits and every burst up to 32 bits, and
//!   lets one in 4e9 random corruptions through instead of one in 65,536. Frames carry
//!   commands that switch motors on; two more bytes per frame (0.2% of a state frame) are
//!   cheap. It is the zlib / Ethernet CRC, so any tool can check a captured frame.
//! * **Version byte outside postcard**, first in every frame in every version, so a peer of
//!   another version is recognised from any frame, not mistaken for corruption.
//! * **Direction byte**: costs one byte, turns an echoing link from a silent feedback loop
//!   into a counted, named error.
//! * **Fixed-point values as their `Fx` (`I32F32`) bits in `i64`**: exact by construction.
//!   The host can rebuild the device's footprint polygons bit for bit, and the virtual pen's
//!   [`PoseSample`] is exactly the pose the host simulation feeds its own `Brush<Fx>`, with no
//!   conversion on either side. A micrometre `i32` would be smaller but would quantise the
//!   pose (the model carries 0.23 pm) and need both sides to convert identically. Postcard's
//!   zigzag varints keep the cost near the information: 5 bytes for a unit vector component
//!   or a distance under 4 mm, 6 for canvas coordinates.
//! * **Differences for positions in [`BrushState`]**: each spine mass relative to the previous
//!   one (the first to the handle), each skeleton node relative to its spine mass. Short
//!   distances are shorter varints (the large brush's state frame is about a third
//!   shorter than with absolute positions); wrapping differences of the raw bits are
//!   exact.
//! * **`f32` for parameters and force limits**: that is how [`crate::BrushParams`] stores them.
//! * **Flags** ([`Capabilities`], [`Faults`], [`Buttons`]): integers that keep bits a newer
//!   peer defines.
//!
//! ## Sizes
//!
//! The bytes each frame takes on the wire, and its share of a 1 MB/s USB full-speed CDC
//! link at its rate, are in docs/figures.md (tests `state_frame_size_and_link_share` and
//! `largest_messages_fit_their_bounds` print and bound them). A state of the large preset
//! stays under a kilobyte, an eighth of the link at 120 Hz (asserted); a state of
//! [`crate::params::MAX_LAYERS`] layers with every value at its longest varint, and the
//! longest host message, fit [`DEVICE_MSG_MAX`] and [`HOST_MSG_MAX`] (asserted).
//!
//! A 512-byte frame limit would not hold one exact state of the large brush (every
//! fixed-point value costs 5-6 bytes: 32 fraction bits of live data), hence the per-direction
//! bounds above; the host-to-device bound keeps the device's receive buffer at 512 bytes.

// The device path must not panic on any input: no indexing, no unwrap.
#![deny(
    clippy::indexing_slicing,
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic
)]

mod flags;
mod frame;
#[cfg(feature = "fuzz")]
pub mod fuzz;
mod messages;
mod state;

pub use crate::pen_io::{ConfigError, ConfigState, DeviceConfig, InvalidField};
pub use flags::{Buttons, Capabilities, Faults};
pub use frame::{
    check_version, crc32, encode_raw, max_frame_len, Feed, FrameDecoder, LinkStats, Message,
    ProtocolError, CRC_LEN, DELIMITER, DEVICE_TO_HOST, HEADER_LEN, HOST_TO_DEVICE,
    PROTOCOL_VERSION,
};
pub use messages::{
    bounded_str, param_id, Command, CommandError, ConfigRejected, DeviceInfo, DeviceMsg, Event,
    EventKind, HostHello, HostMsg, Nudge, ParamRejected, ParamReply, PresetRef, RejectReason,
    SensorReport, Telemetry, Version, DEVICE_MSG_MAX, HOST_MSG_MAX, NAME_LEN, POSES_IN_FLIGHT,
    REASON_LEN, SENSOR_RATE_MAX_HZ,
};
pub(crate) use state::{add_bits, delta_bits};
pub use state::{
    vec3_bits, vec3_from_bits, BrushState, GuideSample, Haptics, LayerState, PoseBits, PoseSample,
    Vec3Bits,
};

/// The device's receiver: decodes host messages.
pub type DeviceRx = FrameDecoder<HostMsg, HOST_MSG_MAX>;
/// The host's receiver: decodes device messages.
pub type HostRx = FrameDecoder<DeviceMsg, DEVICE_MSG_MAX>;

/// USB vendor ID the pen's firmware enumerates with (CDC-ACM): pid.codes, the open-hardware
/// vendor ID.
pub const USB_VID: u16 = 0x1209;
/// USB product ID: pid.codes' test PID, until Maobi's own PID is allocated there. It only
/// narrows the search: the handshake ([`DeviceInfo`]) is what identifies a Maobi device, so a
/// board with another PID is still found by trying its port.
pub const USB_PID: u16 = 0x0001;
/// The product string the firmware reports.
pub const USB_PRODUCT: &str = "Maobi pen";
