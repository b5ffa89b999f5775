//! What a physical pen stores in flash, and the image format it is stored in.
//!
//! # The image
//!
//! | bytes | what |
//! |---|---|
//! | 4 | [`CONFIG_MAGIC`], `b"MBCF"` |
//! | 2 | format version, little-endian: [`CONFIG_FORMAT_VERSION`] |
//! | 2 | payload length `n`, little-endian, at most [`CONFIG_PAYLOAD_MAX`] |
//! | n | the [`DeviceConfig`], postcard-encoded |
//! | 4 | CRC-32/ISO-HDLC of the header and the payload, little-endian (the same CRC as the wire protocol's frames: [`crate::protocol::crc32`]) |
//!
//! At most [`CONFIG_IMAGE_MAX`] bytes. [`decode`] checks, in this order, and names the first
//! thing wrong ([`ConfigError`]): blank header (erased flash: never written), magic, version,
//! length, enough bytes, CRC, payload decodes with nothing left over, values valid. A CRC-32
//! catches every error of up to 3 flipped bits and every burst of up to 32 bits in an image
//! this size, and a truncated image is caught by its length field before the CRC is looked
//! at; `shared/tests/pen_io.rs` flips every bit and cuts every length of a real image.
//!
//! An interrupted write leaves the end of the image blank (erased flash reads `0xFF`; the
//! QEMU board's RAM-backed store reads `0x00` where no file was loaded): an image whose
//! length field is blank, or whose CRC does not match and whose last byte is blank, is
//! reported as [`ConfigError::Truncated`] rather than as a CRC mismatch. (This only names the
//! error: such an image is rejected either way. A damaged image whose real CRC happens to end
//! in `0x00` or `0xFF` is reported as truncated too.) An image cut inside its header may
//! also read as a bad magic or a bad length.
//!
//! # Why postcard and a version number
//!
//! postcard is already the wire protocol's encoding (the same serde derives serve
//! [`crate::protocol::HostMsg::SetConfig`]); it is compact and bounded. It has no schema
//! evolution, so any change to [`DeviceConfig`]'s layout increments [`CONFIG_FORMAT_VERSION`].
//! [`load`] reads the older formats it knows and migrates them to this one
//! ([`Loaded::Migrated`]); an image of any other version is reported as
//! [`ConfigError::UnsupportedVersion`]: the pen starts safe (no force) and the builder
//! writes the configuration again. [`decode`] reads this format only (what [`encode`]
//! wrote: the pen reads back every save with it).
//!
//! * 1: the first format: the pen ([`PenConfig`]), three drive channels (PWM frequency,
//!   deadband, duty clamp, zero policy), the force limits, the calibration.
//! * 2: each motor's winding resistance ([`DriveConfig::winding_mohm`]) and the motor supply
//!   and driver rating ([`PowerConfig`]), which bound the duty. A format-1 image is migrated:
//!   everything it has is kept (and validated as format 2 validates it), and what it lacks
//!   is left at zero, "not given" (`winding_mohm` 0, `power.supply_v` and
//!   `power.driver_current_a` 0.0), which [`DeviceConfig::validate`] refuses by name. The
//!   pen puts the migrated configuration in force for its kinematics and calibration (the
//!   brush follows the pen) but gives no force ([`ConfigState::Migrated`], which
//!   [`Readiness`] never lets drive the motors) until a `SetConfig` with the builder's values
//!   writes a format-2 image. No migration could supply those values: they bound the motor
//!   current, and only the builder knows the motors and the supply.

use core::fmt;

use heapless::String;
use serde::{Deserialize, Serialize};

use crate::force::{check, DeviceLimits, LimitError, PHANTOM_OMNI};
use crate::kinematics::{PenConfig, RawReadings};
use crate::protocol::crc32;

use super::drive::DriveConfig;

/// First four bytes of every configuration image.
pub const CONFIG_MAGIC: [u8; 4] = *b"MBCF";
/// Version of the image's payload layout; any change to [`DeviceConfig`] increments it.
pub const CONFIG_FORMAT_VERSION: u16 = 2;
/// Magic, version and length.
pub const IMAGE_HEADER_LEN: usize = 8;
const CRC_LEN: usize = 4;
/// Longest postcard encoding of a [`DeviceConfig`]: 30 `f32` and 9 `i8` in the pen
/// (120 + 9 bytes) and its three `u32` counts (5 bytes each at most); per drive channel a
/// `u32` (5), two `f32` (8), the policy (1) and a `u16` (3); the power's two `f32` (8); 7 `f32` limits
/// (28); the calibration's option tag (1), three `i64` (10 each) and three `i32` (5 each).
/// Test `longest_payload_is_the_bound` encodes a config with every varint at its longest.
pub const CONFIG_PAYLOAD_MAX: usize = 129 + 15 + 3 * 17 + 8 + 28 + 1 + 30 + 15;
/// Longest postcard encoding of a format-1 payload: as [`CONFIG_PAYLOAD_MAX`] without the
/// winding resistances (3 bytes a channel) and the power (8 bytes).
pub const FORMAT_1_PAYLOAD_MAX: usize = CONFIG_PAYLOAD_MAX - 3 * 3 - 8;
/// Longest image: header, payload and CRC. A flash page for the image needs this much.
pub const CONFIG_IMAGE_MAX: usize = IMAGE_HEADER_LEN + CONFIG_PAYLOAD_MAX + CRC_LEN;
/// Capacity of a field's name in [`InvalidField`] (`"drive[2].max_duty"`).
pub const FIELD_LEN: usize = 32;

/// Everything a physical pen keeps across power cycles.
#[derive(Copy, Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DeviceConfig {
    /// Link lengths, encoder counts, ratios, torque constants, signs, joint limits, the
    /// inkwell pose.
    pub pen: PenConfig,
    /// One H-bridge channel per motor.
    pub drive: [DriveConfig; 3],
    /// The motor supply and the driver's current rating: with each channel's winding
    /// resistance they bound its duty.
    pub power: PowerConfig,
    /// The force limits of this pen's motors.
    pub limits: DeviceLimits,
    /// The raw readings with the pen resting in its inkwell ([`crate::kinematics::Pen::calibrate`]);
    /// `None` until [`crate::protocol::Command::Calibrate`] has recorded them.
    pub calibration: Option<RawReadings>,
}

impl DeviceConfig {
    /// The reference pen ([`PenConfig::OMNI_LIKE`]), [`DriveConfig::DEFAULT`] on every
    /// channel, the Phantom Omni's force limits, not calibrated. Its `pen.max_current` is
    /// each motor's stall current at its duty clamp ([`Self::stall_current_a`]), the rule the
    /// builder's guide gives: full command is all the current the clamp lets the motor draw.
    pub const DEFAULT: DeviceConfig = DeviceConfig {
        pen: PenConfig {
            max_current: [PowerConfig::DEFAULT.stall_current_a(
                DriveConfig::DEFAULT.max_duty,
                DriveConfig::DEFAULT.winding_ohm(),
            ); 3],
            ..PenConfig::OMNI_LIKE
        },
        drive: [DriveConfig::DEFAULT; 3],
        power: PowerConfig::DEFAULT,
        limits: PHANTOM_OMNI,
        calibration: None,
    };

    /// Every value within its range; the first one that is not, by name
    /// (`"pen.ratio"`, `"drive[1].deadband"`, `"limits.peak_n"`). A channel whose
    /// `max_duty` would let its stalled motor draw more than the driver's rating
    /// ([`Self::over_current`]) is reported as `drive[j].max_duty` with the largest duty
    /// that does not as the range's top.
    ///
    /// The one validation of a configuration: the pen runs it on every image it loads and
    /// every `SetConfig`, the host on every file before it sends it.
    pub fn validate(&self) -> Result<(), InvalidField> {
        self.pen
            .validate()
            .map_err(|e| InvalidField::new("pen.", None, e))?;
        for (j, d) in self.drive.iter().enumerate() {
            d.validate()
                .map_err(|e| InvalidField::new("drive", Some(j), e))?;
        }
        self.power
            .validate()
            .map_err(|e| InvalidField::new("power.", None, e))?;
        if let Some(over) = self.over_current() {
            let d = self.drive.get(over.channel).copied().unwrap_or_default();
            return Err(InvalidField::new(
                "drive",
                Some(over.channel),
                LimitError {
                    name: "max_duty",
                    value: d.max_duty,
                    min: d.deadband + 0.05,
                    max: over.duty_limit,
                },
            ));
        }
        self.limits
            .validate()
            .map_err(|e| InvalidField::new("limits.", None, e))
    }

    /// [`Self::validate`] of what a format-1 image holds: the pen, each channel's PWM
    /// frequency, deadband and duty clamp, the force limits; not the winding resistances nor
    /// the power, which that format lacks (a migrated configuration has them at zero).
    pub fn validate_migrated(&self) -> Result<(), InvalidField> {
        self.pen
            .validate()
            .map_err(|e| InvalidField::new("pen.", None, e))?;
        for (j, d) in self.drive.iter().enumerate() {
            // The winding's check is the channel's last: a value that passes it skips it.
            DriveConfig {
                winding_mohm: DriveConfig::MIN_WINDING_MOHM,
                ..*d
            }
            .validate()
            .map_err(|e| InvalidField::new("drive", Some(j), e))?;
        }
        self.limits
            .validate()
            .map_err(|e| InvalidField::new("limits.", None, e))
    }

    /// The first channel whose duty clamp lets its motor, stalled, draw more than the
    /// driver's rating: `power.supply_v * max_duty / R > power.driver_current_a`.
    /// A stalled motor is the haptic pen's usual state (the hand holds the stylus against
    /// the force), and with no back-EMF the winding's resistance alone sets the current.
    pub fn over_current(&self) -> Option<OverCurrent> {
        self.drive.iter().enumerate().find_map(|(channel, d)| {
            let duty_limit = self.power.duty_limit(d.winding_ohm());
            // A NaN anywhere compares as nothing: over the limit.
            let within = d
                .max_duty
                .partial_cmp(&duty_limit)
                .is_some_and(core::cmp::Ordering::is_le);
            (!within).then_some(OverCurrent {
                channel,
                max_duty: d.max_duty,
                winding_ohm: d.winding_ohm(),
                supply_v: self.power.supply_v,
                stall_a: self.power.stall_current_a(d.max_duty, d.winding_ohm()),
                rating_a: self.power.driver_current_a,
                duty_limit,
            })
        })
    }

    /// The current channel `channel`'s motor draws stalled at its duty clamp (A):
    /// `power.supply_v * drive[channel].max_duty / its winding's resistance`, the most
    /// `pen.max_current[channel]` can be. 0 for a channel the pen does not have.
    pub fn stall_current_a(&self, channel: usize) -> f32 {
        self.drive.get(channel).map_or(0.0, |d| {
            self.power.stall_current_a(d.max_duty, d.winding_ohm())
        })
    }

    /// Whether forces may be rendered with this configuration: valid and calibrated.
    pub fn ready_for_forces(&self) -> bool {
        self.validate().is_ok() && self.calibration.is_some()
    }
}

/// The motor supply and the H-bridge driver, for every channel.
#[derive(Copy, Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PowerConfig {
    /// The motor supply at the drivers' VM pins (V). At most [`Self::MAX_SUPPLY_V`].
    pub supply_v: f32,
    /// The driver's continuous (average) output current per channel (A): the TB6612's
    /// 1.2 A, not its 3.2 A peak, which holds only for a pulse of milliseconds, while a
    /// haptic pen holds a stall for as long as the hand pushes.
    pub driver_current_a: f32,
}

impl PowerConfig {
    /// A 12 V supply and TB6612 drivers (the bill of materials).
    pub const DEFAULT: PowerConfig = PowerConfig {
        supply_v: 12.0,
        driver_current_a: 1.2,
    };
    /// The TB6612's largest operating motor supply (V). Back-driven motors pump the supply
    /// above its nominal value, so a 12 V supply needs the bulk capacitance and clamp the
    /// builder's guide gives.
    pub const MAX_SUPPLY_V: f32 = 13.5;
    /// Smallest supply accepted (V).
    pub const MIN_SUPPLY_V: f32 = 1.0;
    /// Largest driver rating accepted (A).
    pub const MAX_DRIVER_CURRENT_A: f32 = 10.0;

    pub fn validate(&self) -> Result<(), LimitError> {
        check(
            "supply_v",
            self.supply_v,
            Self::MIN_SUPPLY_V,
            Self::MAX_SUPPLY_V,
        )?;
        check(
            "driver_current_a",
            self.driver_current_a,
            0.01,
            Self::MAX_DRIVER_CURRENT_A,
        )
    }

    /// The largest duty that keeps a stalled motor of `winding_ohm` within the driver's
    /// rating: `driver_current_a * winding_ohm / supply_v`, at most 1.
    pub fn duty_limit(&self, winding_ohm: f32) -> f32 {
        (self.driver_current_a * winding_ohm / self.supply_v).min(1.0)
    }

    /// The current a stalled motor of `winding_ohm` draws at `duty` (A).
    pub const fn stall_current_a(&self, duty: f32, winding_ohm: f32) -> f32 {
        self.supply_v * duty / winding_ohm
    }
}

impl Default for PowerConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// A channel whose duty clamp lets its stalled motor draw more than the driver's rating
/// ([`DeviceConfig::over_current`]), with the figures that say so.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct OverCurrent {
    pub channel: usize,
    pub max_duty: f32,
    pub winding_ohm: f32,
    pub supply_v: f32,
    /// `supply_v * max_duty / winding_ohm` (A).
    pub stall_a: f32,
    /// `power.driver_current_a` (A).
    pub rating_a: f32,
    /// The largest `max_duty` within the rating ([`PowerConfig::duty_limit`]).
    pub duty_limit: f32,
}

impl fmt::Display for OverCurrent {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        // The suggestion rounded down, so that it passes the check it comes from.
        let suggest = libm::floorf(self.duty_limit * 1000.0) / 1000.0;
        write!(
            f,
            "drive[{}].max_duty = {} lets the stalled motor draw {:.2} A ({} V x {} / {} Ohm), \
             more than the driver's rating of {} A (power.driver_current_a); with this motor \
             and supply, max_duty may be at most {}",
            self.channel,
            self.max_duty,
            self.stall_a,
            self.supply_v,
            self.max_duty,
            self.winding_ohm,
            self.rating_a,
            suggest
        )
    }
}

impl Default for DeviceConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// A configuration value out of its range: the field's path, the value and the valid range
/// (a non-finite value is reported as itself).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct InvalidField {
    /// `"pen.upper_arm_mm"`, `"drive[0].pwm_hz"`, `"limits.continuous_n"`.
    pub field: String<FIELD_LEN>,
    pub value: f32,
    pub min: f32,
    pub max: f32,
}

impl InvalidField {
    fn new(prefix: &str, channel: Option<usize>, e: LimitError) -> Self {
        // "{prefix}[{j}].{name}" or "{prefix}{name}", pushed piece by piece rather than with
        // `write!`, so that the pen's image carries no `core::fmt` machinery for it. A piece
        // that does not fit in FIELD_LEN is left out (none is: the longest name is 27 bytes).
        let mut field = String::new();
        let _ = field.push_str(prefix);
        if let Some(j) = channel {
            let _ = field.push('[');
            push_decimal(&mut field, j);
            let _ = field.push_str("].");
        }
        let _ = field.push_str(e.name);
        InvalidField {
            field,
            value: e.value,
            min: e.min,
            max: e.max,
        }
    }
}

/// `n` in decimal at the end of `s` (digits that do not fit are left out): the leading
/// digits first, by recursion (at most 20 deep).
fn push_decimal(s: &mut String<FIELD_LEN>, n: usize) {
    if n >= 10 {
        push_decimal(s, n / 10);
    }
    let _ = s.push(char::from(b'0' + (n % 10) as u8));
}

impl fmt::Display for InvalidField {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.value.is_finite() {
            write!(
                f,
                "{}: {} is outside the valid range {} ..= {}",
                self.field, self.value, self.min, self.max
            )
        } else {
            write!(f, "{}: value is not a finite number", self.field)
        }
    }
}

/// Why an image is not a usable configuration (or could not be written).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum ConfigError {
    /// The header is erased flash (all `0xFF`): nothing was ever written.
    Erased,
    /// The first four bytes are not [`CONFIG_MAGIC`]: not a configuration image.
    BadMagic,
    /// A configuration image of a format version this firmware neither reads nor migrates
    /// (a firmware update changed the layout; format 1 is migrated: [`load`]): write the
    /// configuration again.
    UnsupportedVersion { found: u16 },
    /// The length field exceeds [`CONFIG_PAYLOAD_MAX`].
    BadLength { len: u16 },
    /// The image ends before its length says (or its end is blank: the write was
    /// interrupted).
    Truncated,
    /// The CRC does not match: the image was damaged.
    CrcMismatch { stored: u32, computed: u32 },
    /// Intact image whose payload does not decode as a [`DeviceConfig`] (or has bytes left
    /// over).
    Undecodable,
    /// Intact image with a value out of range.
    Invalid(InvalidField),
    /// Encoding: the buffer cannot hold the image.
    BufferTooSmall,
}

impl fmt::Display for ConfigError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ConfigError::Erased => f.write_str("no configuration stored (erased flash)"),
            ConfigError::BadMagic => f.write_str("not a configuration image (bad magic)"),
            ConfigError::UnsupportedVersion { found } => write!(
                f,
                "configuration format version {found}, this firmware reads {CONFIG_FORMAT_VERSION} \
                 (and migrates 1)"
            ),
            ConfigError::BadLength { len } => write!(
                f,
                "configuration length {len} exceeds the maximum {CONFIG_PAYLOAD_MAX}"
            ),
            ConfigError::Truncated => f.write_str("configuration image truncated"),
            ConfigError::CrcMismatch { stored, computed } => write!(
                f,
                "configuration CRC mismatch (stored {stored:#010x}, computed {computed:#010x})"
            ),
            ConfigError::Undecodable => f.write_str("configuration payload does not decode"),
            ConfigError::Invalid(field) => write!(f, "configuration value invalid: {field}"),
            ConfigError::BufferTooSmall => f.write_str("buffer too small for the image"),
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for ConfigError {}

/// What the pen says about its stored configuration in the handshake
/// ([`crate::protocol::DeviceInfo::config`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum ConfigState {
    /// A valid configuration is in force.
    Valid,
    /// None stored (erased flash): forces are refused until one is written.
    Missing,
    /// The stored image is unusable, and why: forces are refused until a valid one is written.
    Corrupt(ConfigError),
    /// The device has no stored configuration and needs none: a virtual pen (the QEMU board
    /// without a configuration image, a bridge to a commercial device).
    NotApplicable,
    /// The stored image is of an older format (`from`), migrated ([`Loaded::Migrated`]):
    /// the pen's geometry, drive channels, limits and calibration are in force (the brush
    /// follows the pen), forces are refused until a `SetConfig` gives what bounds the motor
    /// current (each winding's resistance, the supply, the driver's rating). `GetConfig`
    /// answers with the migrated configuration, those values at zero.
    Migrated { from: u16 },
}

impl ConfigState {
    /// The state after loading an image: [`decode`]'s result.
    pub fn of(loaded: &Result<DeviceConfig, ConfigError>) -> Self {
        match loaded {
            Ok(_) => ConfigState::Valid,
            Err(ConfigError::Erased) => ConfigState::Missing,
            Err(e) => ConfigState::Corrupt(e.clone()),
        }
    }

    /// The state after loading an image: [`load`]'s result.
    pub fn of_loaded(loaded: &Result<Loaded, ConfigError>) -> Self {
        match loaded {
            Ok(Loaded::Current(_)) => ConfigState::Valid,
            Ok(Loaded::Migrated { from, .. }) => ConfigState::Migrated { from: *from },
            Err(ConfigError::Erased) => ConfigState::Missing,
            Err(e) => ConfigState::Corrupt(e.clone()),
        }
    }

    /// Whether forces may be enabled in this state (valid, or no configuration needed),
    /// calibration aside: [`Readiness`] adds it.
    pub fn allows_forces(&self) -> bool {
        matches!(self, ConfigState::Valid | ConfigState::NotApplicable)
    }
}

/// How long a pen's zeros ([`DeviceConfig::calibration`]) hold.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub enum ZeroHold {
    /// Across power cycles: the sensors read absolute positions (potentiometers, hall
    /// sensors, the QEMU board's readings synthesised from the host's poses), so the stored
    /// calibration stays true.
    Stored,
    /// Until power-off: incremental encoders count from wherever the arm was when the chip
    /// started (a reset clears the timers), so a stored calibration from an earlier power-on
    /// is meaningless. Only the zeros `Calibrate` took since power-on hold (`None` until
    /// then). The boards that announce `Capabilities::NEEDS_CALIBRATION`.
    SincePowerOn(Option<RawReadings>),
}

/// Whether a pen may render forces, and whether it reports
/// [`crate::protocol::Faults::NOT_CALIBRATED`]: the supervisor's "no force before
/// calibration".
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub struct Readiness {
    /// Forces (and bring-up nudges) may be driven: a valid configuration whose zeros hold,
    /// or none needed.
    pub allows_forces: bool,
    /// The pen needs zeros it does not have (no configuration, none calibrated, or zeros
    /// from an earlier power-on): reported until `Calibrate` succeeds.
    pub not_calibrated: bool,
}

impl Readiness {
    /// From the store's state, the configuration in force (`Some` exactly when `state` is
    /// [`ConfigState::Valid`] or [`ConfigState::Migrated`]) and how long this pen's zeros
    /// hold. A migrated configuration never allows forces; its zeros count as they would
    /// in a valid one (its kinematics are in force).
    ///
    /// A pen without a stored configuration that needs none ([`ConfigState::NotApplicable`]:
    /// the QEMU board's virtual pen, whose poses come from the host already in the world
    /// frame) is calibrated by construction.
    pub fn of(state: &ConfigState, config: Option<&DeviceConfig>, zeros: ZeroHold) -> Self {
        let zeros_hold = |cfg: &DeviceConfig| match zeros {
            ZeroHold::Stored => cfg.calibration.is_some(),
            ZeroHold::SincePowerOn(taken) => taken.is_some() && cfg.calibration == taken,
        };
        let (allows_forces, calibrated) = match (state, config) {
            (ConfigState::NotApplicable, _) => (true, true),
            (ConfigState::Valid, Some(cfg)) if cfg.validate().is_ok() => {
                let held = zeros_hold(cfg);
                (held, held)
            }
            // Kinematics and zeros, never force: what bounds the current is not given.
            (ConfigState::Migrated { .. }, Some(cfg)) => (false, zeros_hold(cfg)),
            _ => (false, false),
        };
        Readiness {
            allows_forces,
            not_calibrated: !calibrated,
        }
    }
}

impl fmt::Display for ConfigState {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ConfigState::Valid => f.write_str("valid"),
            ConfigState::Missing => f.write_str("missing (never written)"),
            ConfigState::Corrupt(e) => write!(f, "corrupt: {e}"),
            ConfigState::NotApplicable => f.write_str("not applicable (no stored configuration)"),
            ConfigState::Migrated { from } => write!(
                f,
                "configuration migrated from format {from}: set the motors' winding \
                 resistance, supply voltage and driver rating (drive.winding_mohm, \
                 power.supply_v, power.driver_current_a: `maobi device config get -o pen.toml`, \
                 edit, `maobi device config set pen.toml`) to enable force"
            ),
        }
    }
}

/// Writes `cfg`'s image into `out`; returns its length. Refuses an invalid configuration
/// ([`ConfigError::Invalid`]): an image this function wrote always decodes.
pub fn encode(cfg: &DeviceConfig, out: &mut [u8]) -> Result<usize, ConfigError> {
    cfg.validate().map_err(ConfigError::Invalid)?;
    let (header, rest) = out
        .split_at_mut_checked(IMAGE_HEADER_LEN)
        .ok_or(ConfigError::BufferTooSmall)?;
    let payload_room = rest.len().saturating_sub(CRC_LEN);
    let payload_len = {
        let room = rest
            .get_mut(..payload_room)
            .ok_or(ConfigError::BufferTooSmall)?;
        postcard::to_slice(cfg, room)
            .map_err(|_| ConfigError::BufferTooSmall)?
            .len()
    };
    if rest.len() < payload_len + CRC_LEN {
        return Err(ConfigError::BufferTooSmall);
    }
    let len16 = u16::try_from(payload_len).map_err(|_| ConfigError::BufferTooSmall)?;
    let [m0, m1, m2, m3] = CONFIG_MAGIC;
    let [v0, v1] = CONFIG_FORMAT_VERSION.to_le_bytes();
    let [l0, l1] = len16.to_le_bytes();
    header.copy_from_slice(&[m0, m1, m2, m3, v0, v1, l0, l1]);
    let body_len = IMAGE_HEADER_LEN + payload_len;
    let crc = crc32(out.get(..body_len).ok_or(ConfigError::BufferTooSmall)?);
    out.get_mut(body_len..body_len + CRC_LEN)
        .ok_or(ConfigError::BufferTooSmall)?
        .copy_from_slice(&crc.to_le_bytes());
    Ok(body_len + CRC_LEN)
}

/// What an intact image holds ([`load`]).
#[derive(Copy, Clone, Debug, PartialEq)]
pub enum Loaded {
    /// An image of this format ([`CONFIG_FORMAT_VERSION`]), valid.
    Current(DeviceConfig),
    /// An image of the older format `from`, read into this one: everything it has, valid
    /// ([`DeviceConfig::validate_migrated`]); what it lacks (the winding resistances, the
    /// power) at zero, so that [`DeviceConfig::validate`] refuses it until the builder gives
    /// them. Not for the motors: [`ConfigState::Migrated`].
    Migrated { from: u16, config: DeviceConfig },
}

impl Loaded {
    /// The configuration, current or migrated.
    pub fn config(&self) -> &DeviceConfig {
        match self {
            Loaded::Current(c) | Loaded::Migrated { config: c, .. } => c,
        }
    }
}

/// Reads an image of this format from the start of `image` (bytes after its end are
/// ignored: a flash page is larger than the image) and validates it: what [`encode`] wrote.
/// An older format is [`ConfigError::UnsupportedVersion`] here: [`load`] migrates it.
/// Never panics, whatever the bytes.
pub fn decode(image: &[u8]) -> Result<DeviceConfig, ConfigError> {
    match load(image)? {
        Loaded::Current(cfg) => Ok(cfg),
        Loaded::Migrated { from, .. } => Err(ConfigError::UnsupportedVersion { found: from }),
    }
}

/// Reads an image of this format or an older one from the start of `image` and validates
/// it ([`Loaded`]): what the pen does with its store at start. The same checks, in the same
/// order, for every format (header, length within the format's bound, CRC, payload decodes
/// with nothing left over, values valid). Never panics, whatever the bytes.
pub fn load(image: &[u8]) -> Result<Loaded, ConfigError> {
    let (version, payload) = intact_payload(image)?;
    if version == 1 {
        let cfg = format_1::take(payload)?;
        cfg.validate_migrated().map_err(ConfigError::Invalid)?;
        return Ok(Loaded::Migrated {
            from: 1,
            config: cfg,
        });
    }
    let cfg = match postcard::take_from_bytes::<DeviceConfig>(payload) {
        Ok((cfg, [])) => cfg,
        _ => return Err(ConfigError::Undecodable),
    };
    cfg.validate().map_err(ConfigError::Invalid)?;
    Ok(Loaded::Current(cfg))
}

/// The format version and the payload of an intact image of a format this firmware reads:
/// header, length and CRC checked.
fn intact_payload(image: &[u8]) -> Result<(u16, &[u8]), ConfigError> {
    let header_part = image.get(..IMAGE_HEADER_LEN).unwrap_or(image);
    if !header_part.is_empty() && header_part.iter().all(|&b| b == 0xFF) {
        return Err(ConfigError::Erased);
    }
    let header: &[u8; IMAGE_HEADER_LEN] =
        header_part.try_into().map_err(|_| ConfigError::Truncated)?;
    let [m0, m1, m2, m3, v0, v1, l0, l1] = *header;
    if [m0, m1, m2, m3] != CONFIG_MAGIC {
        return Err(ConfigError::BadMagic);
    }
    if is_blank(&[l0, l1]) {
        // The write stopped before the length (a real payload is never empty nor 64 KiB).
        return Err(ConfigError::Truncated);
    }
    let version = u16::from_le_bytes([v0, v1]);
    let payload_max = match version {
        CONFIG_FORMAT_VERSION => CONFIG_PAYLOAD_MAX,
        1 => FORMAT_1_PAYLOAD_MAX,
        found => return Err(ConfigError::UnsupportedVersion { found }),
    };
    let len = u16::from_le_bytes([l0, l1]);
    if usize::from(len) > payload_max {
        return Err(ConfigError::BadLength { len });
    }
    let body_len = IMAGE_HEADER_LEN + usize::from(len);
    let body = image.get(..body_len).ok_or(ConfigError::Truncated)?;
    let stored: [u8; CRC_LEN] = image
        .get(body_len..body_len + CRC_LEN)
        .and_then(|s| s.try_into().ok())
        .ok_or(ConfigError::Truncated)?;
    let computed = crc32(body);
    if u32::from_le_bytes(stored) != computed {
        let [.., last] = stored;
        if is_blank(&[last]) {
            // The image's last byte was never written.
            return Err(ConfigError::Truncated);
        }
        return Err(ConfigError::CrcMismatch {
            stored: u32::from_le_bytes(stored),
            computed,
        });
    }
    let payload = body.get(IMAGE_HEADER_LEN..).ok_or(ConfigError::Truncated)?;
    Ok((version, payload))
}

/// Format 1's payload, read to migrate it: postcard's encoding of, in this order, the pen
/// ([`PenConfig`], unchanged since), three drive channels of four fields (PWM frequency
/// `u32`, deadband `f32`, duty clamp `f32`, [`crate::pen_io::ZeroPolicy`]: format 2 appended the winding
/// resistance), the force limits ([`DeviceLimits`], unchanged) and the calibration
/// (`Option<RawReadings>`, unchanged); format 2 put the power between the drive channels
/// and the limits. The unchanged parts are read with the deserializers format 2's uses.
mod format_1 {
    use postcard::take_from_bytes;
    use serde::Deserialize;

    use super::{ConfigError, DeviceConfig, PowerConfig};
    use crate::force::DeviceLimits;
    use crate::kinematics::{PenConfig, RawReadings};
    use crate::pen_io::drive::{DriveConfig, ZeroPolicy};

    /// A format-1 drive channel.
    #[derive(Deserialize)]
    struct Drive {
        pwm_hz: u32,
        deadband: f32,
        max_duty: f32,
        zero: ZeroPolicy,
    }

    /// What bounds the motor current, not given: zero, which validation refuses.
    const NOT_GIVEN: PowerConfig = PowerConfig {
        supply_v: 0.0,
        driver_current_a: 0.0,
    };

    /// The configuration a format-1 payload holds, the whole payload (nothing left over),
    /// migrated: the winding resistances and the power at zero.
    pub(super) fn take(payload: &[u8]) -> Result<DeviceConfig, ConfigError> {
        let undecodable = |_| ConfigError::Undecodable;
        let (pen, rest) = take_from_bytes::<PenConfig>(payload).map_err(undecodable)?;
        let (drive, rest) = take_from_bytes::<[Drive; 3]>(rest).map_err(undecodable)?;
        let (limits, rest) = take_from_bytes::<DeviceLimits>(rest).map_err(undecodable)?;
        let (calibration, rest) =
            take_from_bytes::<Option<RawReadings>>(rest).map_err(undecodable)?;
        if !rest.is_empty() {
            return Err(ConfigError::Undecodable);
        }
        Ok(DeviceConfig {
            pen,
            drive: drive.map(|d| DriveConfig {
                pwm_hz: d.pwm_hz,
                deadband: d.deadband,
                max_duty: d.max_duty,
                zero: d.zero,
                winding_mohm: 0,
            }),
            power: NOT_GIVEN,
            limits,
            calibration,
        })
    }
}

/// All erased flash (`0xFF`) or all zero (RAM where nothing was loaded).
fn is_blank(bytes: &[u8]) -> bool {
    bytes.iter().all(|&b| b == 0xFF) || bytes.iter().all(|&b| b == 0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn field_names_carry_the_channel_in_decimal() {
        let e = LimitError {
            name: "pwm_hz",
            value: 1.0,
            min: 2.0,
            max: 3.0,
        };
        for (channel, name) in [
            (Some(0), "drive[0].pwm_hz"),
            (Some(12), "drive[12].pwm_hz"),
            (Some(305), "drive[305].pwm_hz"),
            (None, "drivepwm_hz"),
        ] {
            assert_eq!(InvalidField::new("drive", channel, e).field.as_str(), name);
        }
        let mut s = String::<FIELD_LEN>::new();
        push_decimal(&mut s, 4_294_967_295);
        assert_eq!(s.as_str(), "4294967295");
    }
}
