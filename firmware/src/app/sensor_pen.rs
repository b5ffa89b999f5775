//! The pose of a pen with its own sensors, from the board's raw readings: the same code on
//! every physical board, so that a board only reads registers.
//!
//! Each tick [`SensorPen::next_pose`] reads the board's [`JointSensors`] once, extends the
//! encoders' 16-bit counts ([`EncoderUnwrap`]), filters the gimbal's ADC codes
//! ([`AdcFilter`]: median of three, then a 21 Hz low-pass), debounces the buttons, keeps the
//! reading for bring-up ([`SensorPen::raw_sensors`], which the force loop hands the link
//! through [`super::SENSORS`] when asked), and, once the pen has a valid configuration,
//! turns the readings into joint angles and the ferrule's pose ([`Pen::forward_with_trig`]).
//! The sines and cosines of that reading's arm angles map the force on the hand to joint
//! torques ([`Pen::torques_at`], `tau = J^T F`) for the same tick.

use maobi_shared::kinematics::{ArmTrig, EncoderUnwrap, Pen, RawReadings};
use maobi_shared::pen_io::{AdcFilter, DeviceConfig};
use maobi_shared::protocol::{Buttons, SensorReport};
use maobi_shared::{Fx, Pose, Scalar, Vec3};

use crate::board::{JointReading, JointSensors, PoseSource};

/// A button's new state is taken after this many consecutive equal readings (ticks: 5 ms,
/// longer than a switch's bounce, shorter than a deliberate click).
pub const DEBOUNCE_TICKS: u8 = 5;

/// One debounced button.
#[derive(Copy, Clone, Debug, Default)]
struct Debounce {
    state: bool,
    /// Consecutive readings that differ from `state`.
    run: u8,
}

impl Debounce {
    fn update(&mut self, reading: bool) -> bool {
        if reading == self.state {
            self.run = 0;
        } else {
            self.run += 1;
            if self.run >= DEBOUNCE_TICKS {
                self.state = reading;
                self.run = 0;
            }
        }
        self.state
    }
}

pub struct SensorPen<J> {
    sensors: J,
    /// `None`: no valid configuration (missing or corrupt): no pose, no forces.
    pen: Option<Pen<Fx>>,
    unwrap: [EncoderUnwrap; 3],
    filters: [AdcFilter; 3],
    buttons: [Debounce; 2],
    /// The last reading, encoders unwrapped, gimbal filtered.
    raw: RawReadings,
    /// The last debounced buttons (bit 0 primary, bit 1 secondary).
    buttons_now: u8,
    /// The last reading as the board gave it.
    last: JointReading,
    /// Sines and cosines of the last pose's arm angles, for the torques.
    arm_trig: Option<ArmTrig<Fx>>,
}

impl<J: JointSensors> SensorPen<J> {
    pub fn new(sensors: J, pen: Option<Pen<Fx>>) -> Self {
        SensorPen {
            sensors,
            pen,
            unwrap: [EncoderUnwrap::default(); 3],
            filters: [AdcFilter::new(); 3],
            buttons: [Debounce::default(); 2],
            raw: RawReadings::default(),
            buttons_now: 0,
            last: JointReading::default(),
            arm_trig: None,
        }
    }

    /// The board's sensors (the bench scripts their readings).
    #[allow(dead_code)] // used by the bench, which only the QEMU image has
    pub fn sensors_mut(&mut self) -> &mut J {
        &mut self.sensors
    }

    /// The last reading as the board gave it.
    #[allow(dead_code)] // for a debugger's eyes; the link gets `raw_sensors`
    pub fn last_reading(&self) -> JointReading {
        self.last
    }
}

impl<J: JointSensors> PoseSource for SensorPen<J> {
    fn next_pose(&mut self) -> Option<Pose<Fx>> {
        let r = self.sensors.read()?;
        self.last = r;
        for (j, u) in self.unwrap.iter_mut().enumerate() {
            // The counters are 16 bits wide; the board hands them over as read.
            self.raw.encoders[j] = u.update(r.encoders[j] as u16);
        }
        for (j, f) in self.filters.iter_mut().enumerate() {
            // 12-bit codes; anything else is clamped into range rather than wrapped.
            self.raw.gimbal[j] = i32::from(f.update(r.gimbal[j].clamp(0, 4095) as u16));
        }
        self.buttons_now = u8::from(self.buttons[0].update(r.buttons & 1 != 0))
            | u8::from(self.buttons[1].update(r.buttons & 2 != 0)) << 1;
        let pen = self.pen.as_ref()?;
        match maobi_fast::pen_pose(pen, &self.raw) {
            Ok((pose, arm)) => {
                self.arm_trig = Some(arm);
                Some(pose)
            }
            Err(_) => {
                self.arm_trig = None;
                None
            }
        }
    }

    fn torques_for(&self, f: [Fx; 3]) -> [Fx; 3] {
        match (&self.pen, &self.arm_trig) {
            (Some(pen), Some(q)) => maobi_fast::pen_torques(pen, q, Vec3::new(f[0], f[1], f[2])),
            _ => [Fx::ZERO; 3],
        }
    }

    const POSES_FOLLOW_CONFIG: bool = true;

    fn configure(&mut self, cfg: &DeviceConfig) {
        self.pen = Pen::new(cfg.pen).ok().map(|mut pen| {
            if let Some(zero) = cfg.calibration {
                pen.calibrate(zero);
            }
            pen
        });
        self.arm_trig = None;
    }

    /// This tick's reading (read by `next_pose` just before): real sensors, never
    /// synthesised.
    fn raw_sensors(&mut self, tick: u32) -> Option<SensorReport> {
        Some(SensorReport {
            tick,
            encoders: self.raw.encoders,
            // Filtered codes are 12-bit (clamped before the filter).
            gimbal: self.raw.gimbal.map(|g| g.clamp(0, 4095) as u16),
            buttons: Buttons::from_bits_retain(self.buttons_now),
            synthetic: false,
        })
    }
}
