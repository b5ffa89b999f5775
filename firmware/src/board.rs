//! What the application needs from a board, as small traits.
//!
//! The application ([`crate::app`], [`crate::link`]) is written against these traits only;
//! a board module implements them and owns every register address, pin, interrupt number
//! and linker-script detail:
//!
//! * `qemu` (feature `board-qemu`): QEMU's mps2-an386, a virtual pen fed by the host;
//! * `blackpill` (feature `board-blackpill`): the STM32F411CE Black Pill driving the real
//!   pen's motors from its encoders and gimbal sensors.
//!
//! What stays on the application's side of the line: the force loop and the order of its
//! tick ([`crate::app::ForceLoop::tick`], run by [`crate::app::run_tick`] from the board's
//! 1 kHz timer interrupt), the pose from raw sensor readings ([`crate::app::SensorPen`]:
//! encoder unwrapping, filtering, calibration, kinematics), the supervisor, and the link
//! protocol. What the board provides: its boot, its interrupts, and these traits.

use maobi_shared::pen_io::DeviceConfig;
use maobi_shared::{Fx, Pose};

/// The three motor channels of the pen.
///
/// Commands are torques in newton-metres, one per channel, already saturated to the
/// channel's limit by the caller. `disable` must take effect at once and must be callable
/// from any context (fault handlers included).
pub trait Motors {
    fn command(&mut self, torque_nm: [Fx; 3]);
    /// All channels off (zero current, drivers disabled).
    fn disable(&mut self);
    /// The last command actually applied (zero while disabled): reported in state frames.
    fn applied(&self) -> [Fx; 3];
    /// Drives one channel at `command` (fraction of full current, within the nudge caps)
    /// and the others not at all: the bring-up's motor check. False if the board has no
    /// motors to nudge.
    fn nudge(&mut self, _channel: usize, _command: Fx) -> bool {
        false
    }
    /// A new stored configuration is in force (torque constants, ratios, drive settings).
    fn configure(&mut self, _cfg: &DeviceConfig) {}
}

/// One raw reading of the pen's joints: encoder counts of the three motor joints and the
/// three gimbal angles, as integers straight from the hardware (the encoders' free-running
/// 16-bit counters, the ADC's 12-bit codes).
#[cfg_attr(feature = "board-qemu", allow(dead_code))] // QEMU's pen is virtual
#[derive(Copy, Clone, Debug, Default, PartialEq, Eq)]
pub struct JointReading {
    pub encoders: [i32; 3],
    pub gimbal: [i32; 3],
    /// The stylus buttons as read now (bit 0 primary, bit 1 secondary; set = pressed),
    /// not debounced.
    pub buttons: u8,
}

/// Joint sensors of a physical pen (read by the force loop once per tick).
#[cfg_attr(feature = "board-qemu", allow(dead_code))] // as JointReading
pub trait JointSensors {
    fn read(&mut self) -> JointReading;
}

/// Where the force loop gets the handle pose each tick.
///
/// A physical pen implements this as [`JointSensors`] plus its forward kinematics; the QEMU
/// board's virtual pen takes poses the host sent ([`crate::qemu`]).
pub trait PoseSource {
    /// The pose for this tick, or `None` when the source has no new reading (the virtual
    /// pen's queue is empty). The force loop then holds the brush and counts the gap.
    fn next_pose(&mut self) -> Option<Pose<Fx>>;
    /// The host's sequence number of the last pose `next_pose` returned (virtual pen; 0
    /// for a pen with its own sensors).
    fn pose_seq(&self) -> u32 {
        0
    }
    /// Maps a force on the handle (newtons, world frame) to the three motor torques (N·m).
    fn torques_for(&self, force_n: [Fx; 3]) -> [Fx; 3];
    /// Whether the motors may be driven at all (a physical pen: a valid configuration and
    /// a calibration). The host's enable and the latched faults gate them as well.
    fn forces_allowed(&self) -> bool {
        true
    }
    /// A new stored configuration is in force (geometry, sensors, and the calibration: the
    /// link task stores the readings at the inkwell in it).
    fn configure(&mut self, _cfg: &DeviceConfig) {}
}

/// A physical pen's configuration store (flash): the link writes a validated
/// configuration through it, only while the forces are off.
pub trait ConfigStore {
    /// Writes `cfg` and reads it back; false if either failed.
    fn store(&mut self, cfg: &DeviceConfig) -> bool;
}

/// The store of a board that keeps no configuration (a virtual pen): writes nothing.
#[cfg_attr(not(feature = "board-qemu"), allow(dead_code))]
pub struct NoConfigStore;

impl ConfigStore for NoConfigStore {
    fn store(&mut self, _cfg: &DeviceConfig) -> bool {
        false
    }
}

/// The byte-stream link to the host, non-blocking on both sides: the force loop never
/// touches it, the link task reads what is there and writes what fits.
pub trait LinkTransport {
    /// Copies received bytes into `buf`; returns how many (0 if none).
    fn read(&mut self, buf: &mut [u8]) -> usize;
    /// Queues bytes for sending; returns how many fitted.
    fn write(&mut self, buf: &[u8]) -> usize;
    /// Free room in the transmit queue (bytes).
    fn tx_space(&self) -> usize;
    /// Waits until at least one received byte is available.
    fn readable(&mut self) -> impl core::future::Future<Output = ()>;
    /// Received bytes dropped because the receive ring was full.
    fn rx_overflows(&self) -> u32;
}

/// A hardware watchdog that turns the motors off when the force loop stops feeding it.
pub trait Watchdog {
    fn feed(&mut self);
}

/// A free-running counter for measuring code, in the board's own unit.
pub trait CycleCounter {
    fn now(&self) -> u32;
    /// What one count is: on QEMU `"timer25mhz"` (40 / 2^shift instructions under
    /// `-icount shift=N`, converted by the host), on hardware `"cycles"` (DWT).
    #[cfg_attr(not(feature = "board-qemu"), allow(dead_code))] // read by QEMU's bench
    const UNIT: &'static str;
}
