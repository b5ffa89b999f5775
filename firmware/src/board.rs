//! What the application needs from a board, as small traits.
//!
//! The application ([`crate::app`], [`crate::host_link`]) is written against these traits
//! only; a board module implements them and owns every register address, pin, interrupt
//! number and linker-script detail:
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

use maobi_shared::guide::GuideInput;
use maobi_shared::params::TickLimits;
use maobi_shared::pen_io::DeviceConfig;
use maobi_shared::protocol::SensorReport;
use maobi_shared::{Fx, Pose};

/// What the pen's core (the Black Pill's Cortex-M4F at 96 MHz) runs within its 1 ms tick:
/// the default brush's rate and resolution, which every preset shares (one substep; 12
/// layers of 16 ring nodes; 4 Jacobi sweeps). Each cap is the preset's value, not more: the
/// tick of the default brush is already most of the budget (`hil bench`, docs/figures.md),
/// a second substep or four more layers alone overrun it. The hil test
/// `limits::the_most_expensive_valid_brush_ticks_every_tick` holds the caps together to the
/// tick under QEMU paced like the pen. The QEMU board announces them too when it stands in
/// for the pen (boot argument `limits=pen`).
pub const PEN_TICK_LIMITS: TickLimits = TickLimits {
    substeps_per_tick: 1,
    layers: 12,
    ring_nodes: 16,
    jacobi_iterations: 4,
};

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
    /// A new stored configuration is in force (at boot and after `SetConfig` / `Calibrate`,
    /// always with the motors disabled): a physical board takes its drive settings
    /// (`DeviceConfig::drive`) and the torque-to-command scale (`DeviceConfig::pen`) from it.
    fn configure(&mut self, cfg: &DeviceConfig);
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
    /// This tick's reading, or `None` when the hardware did not deliver one in time (the
    /// Black Pill's ADC scan not ending): the tick then takes no pose, like a virtual pen
    /// with an empty queue, and the force loop counts the gap.
    fn read(&mut self) -> Option<JointReading>;
}

/// Where the force loop gets the handle pose each tick.
///
/// A physical pen implements this as [`JointSensors`] plus its forward kinematics; the QEMU
/// board's virtual pen takes poses the host sent (`crate::qemu`).
pub trait PoseSource {
    /// The pose for this tick, or `None` when the source has no new reading (the virtual
    /// pen's queue is empty). The force loop then holds the brush and counts the gap.
    fn next_pose(&mut self) -> Option<Pose<Fx>>;
    /// A tick whose pose the brush does not take (it stands by after an overrun): the
    /// reading is taken and dropped, so that a virtual pen's queue keeps moving and the
    /// brush, when it starts again, starts from the latest pose.
    fn skip_pose(&mut self) {
        let _ = self.next_pose();
        let _ = self.take_guide();
    }
    /// The host's sequence number of the last pose `next_pose` returned (virtual pen; 0
    /// for a pen with its own sensors).
    fn pose_seq(&self) -> u32 {
        0
    }
    /// The guide sample that came with the pose `next_pose` just returned, once (guided
    /// writing; the virtual pen gets it from the host with the pose of the same `seq`).
    fn take_guide(&mut self) -> Option<GuideInput<Fx>> {
        None
    }
    /// Maps a force on the handle (newtons, world frame) to the three motor torques (N·m).
    fn torques_for(&self, force_n: [Fx; 3]) -> [Fx; 3];
    /// Whether a new configuration moves the poses `next_pose` reports (a pen with its own
    /// sensors: new geometry or calibration zeros). The force loop then puts the brush at
    /// rest at the next pose instead of reading the step as a sensor jump. The virtual
    /// pen's poses come from the host, whatever the configuration.
    const POSES_FOLLOW_CONFIG: bool = false;
    /// A new stored configuration is in force (geometry, calibration): a physical pen
    /// rebuilds its kinematics from it. Called by the force loop between ticks.
    fn configure(&mut self, cfg: &DeviceConfig);
    /// The raw readings behind the latest pose, for bring-up ([`SensorReport`]: unwrapped
    /// encoder counts, filtered gimbal codes, buttons), at force-loop tick `tick`. Called by
    /// the force loop only when the link task asked for one; `None` when the board cannot
    /// tell.
    fn raw_sensors(&mut self, tick: u32) -> Option<SensorReport>;
}

/// Why the configuration could not be stored.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub enum StoreError {
    /// The image does not fit the store.
    TooLarge,
    /// Erasing or programming failed (flash; the QEMU board's RAM cannot fail to write).
    #[cfg_attr(feature = "board-qemu", allow(dead_code))] // constructed by flash-backed boards
    Write,
    /// What reads back differs from what was written.
    Verify,
}

/// Where the pen keeps its configuration image (`maobi_shared::pen_io::encode` /
/// `decode`): a flash page on a physical board, a RAM region the host preloads under QEMU.
/// Used by the link task only (thread mode), never by the force loop.
pub trait ConfigStore {
    /// Copies the stored bytes (at most `buf.len()`) into `buf`; returns how many. Erased
    /// flash is copied as it is (`0xFF`): `decode` tells.
    fn load(&mut self, buf: &mut [u8]) -> usize;
    /// Replaces the stored image with `image` (erase, program, verify).
    fn store(&mut self, image: &[u8]) -> Result<(), StoreError>;
    /// Whether this pen needs a valid configuration to render forces. A physical pen always
    /// does; the QEMU board's virtual pen only once an image was loaded into (or written to)
    /// its store, so that a run without one behaves as before
    /// (`ConfigState::NotApplicable`).
    fn needs_config(&self) -> bool {
        true
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
