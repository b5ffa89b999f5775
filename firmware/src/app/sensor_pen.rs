//! The pose of a pen with its own sensors, from the board's raw readings: the same code on
//! every physical board, so that a board only reads registers.
//!
//! Each tick [`SensorPen::next_pose`] reads the board's [`JointSensors`] once, extends the
//! encoders' 16-bit counts ([`EncoderUnwrap`]), and, once the pen has a valid configuration
//! and a calibration, turns the readings into joint angles and the ferrule's pose
//! ([`Pen::forward`]). The joint angles of that reading map the force on the hand to joint
//! torques ([`Pen::torques`], `tau = J^T F`) for the same tick.

use maobi_shared::kinematics::{EncoderUnwrap, Pen, RawReadings};
use maobi_shared::{Fx, Pose, Scalar, Vec3};

use crate::board::{JointReading, JointSensors, PoseSource};

pub struct SensorPen<J> {
    sensors: J,
    /// `None`: no valid configuration (missing or corrupt): no pose, no forces.
    pen: Option<Pen<Fx>>,
    unwrap: [EncoderUnwrap; 3],
    /// The last reading, encoders unwrapped.
    raw: RawReadings,
    /// The last reading as the board gave it.
    last: JointReading,
    /// Arm joint angles of the last pose (rad), for the torques.
    arm: Option<[Fx; 3]>,
}

impl<J: JointSensors> SensorPen<J> {
    pub fn new(sensors: J, pen: Option<Pen<Fx>>) -> Self {
        SensorPen {
            sensors,
            pen,
            unwrap: [EncoderUnwrap::default(); 3],
            raw: RawReadings::default(),
            last: JointReading::default(),
            arm: None,
        }
    }

    /// The last reading as the board gave it, and with the encoders unwrapped.
    #[allow(dead_code)] // the sensor stream (bring-up) reads it
    pub fn readings(&self) -> (JointReading, RawReadings) {
        (self.last, self.raw)
    }
}

impl<J: JointSensors> PoseSource for SensorPen<J> {
    fn next_pose(&mut self) -> Option<Pose<Fx>> {
        let r = self.sensors.read();
        self.last = r;
        for (j, u) in self.unwrap.iter_mut().enumerate() {
            // The counters are 16 bits wide; the board hands them over as read.
            self.raw.encoders[j] = u.update(r.encoders[j] as u16);
        }
        self.raw.gimbal = r.gimbal;
        let pen = self.pen.as_ref()?;
        match maobi_fast::pen_pose(pen, &self.raw) {
            Ok((pose, arm)) => {
                self.arm = Some(arm);
                Some(pose)
            }
            Err(_) => {
                self.arm = None;
                None
            }
        }
    }

    fn torques_for(&self, f: [Fx; 3]) -> [Fx; 3] {
        match (&self.pen, &self.arm) {
            (Some(pen), Some(q)) => maobi_fast::pen_torques(pen, q, Vec3::new(f[0], f[1], f[2])),
            _ => [Fx::ZERO; 3],
        }
    }

    fn forces_allowed(&self) -> bool {
        self.pen.as_ref().is_some_and(Pen::is_calibrated)
    }

    fn calibrate(&mut self) -> bool {
        match &mut self.pen {
            Some(pen) => {
                pen.calibrate(self.raw);
                true
            }
            None => false,
        }
    }
}
