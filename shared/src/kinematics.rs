//! The reference pen's kinematics: a serial arm shaped like the Phantom Omni (base yaw,
//! shoulder, elbow, driven by three motors through capstan or gear ratios) with a three-axis
//! gimbal at the wrist read by three angle sensors.
//!
//! # Conventions
//!
//! Paper frame: millimetres, the paper is z = 0, +z up. The arm's base sits at `base_mm`.
//!
//! * q1, base yaw about +z: 0 points the arm along +y.
//! * q2, shoulder: elevation of the upper arm above the horizontal.
//! * q3, elbow: angle of the forearm relative to the upper arm (0 = straight; the elbow
//!   bends downward, q3 < 0).
//!
//! With `u = (-sin q1, cos q1, 0)`, `r = l1 cos q2 + l2 cos(q2 + q3)` and
//! `h = l1 sin q2 + l2 sin(q2 + q3)`, the wrist (the gimbal's centre) is `base + r u + h z`.
//!
//! Orientation: the forearm frame is `Rz(q1) Rx(q2 + q3)`, the gimbal adds yaw, pitch and roll
//! `Rz(g1) Rx(g2) Ry(g3)`, and the pen points along the resulting frame's -z, so all angles zero
//! hold the brush straight down. The ferrule sits `stylus_mm` from the wrist along the pen.
//!
//! Forces act at the wrist: the three motors cannot put a torque on the unactuated gimbal, so
//! the force felt is the force at the ferrule carried to the wrist (`tau = J^T F`).
//!
//! # From raw readings
//!
//! Encoders arrive as free-running 16-bit counts ([`EncoderUnwrap`] extends them), gimbal
//! sensors as ADC codes. The pen resting in its inkwell defines the zeros: [`Pen::calibrate`]
//! records the raw readings there, and from then on
//! `q_j = inkwell_j + sign_j (counts_j - zero_j) 2 pi / (counts_per_rev_j ratio_j)`.

use serde::{Deserialize, Serialize};

use crate::force::{check, LimitError};
use crate::quat::{Pose, Quat};
use crate::scalar::Scalar;
use crate::vec::Vec3;

/// Geometry, transmission and sensors of a pen. Defaults: [`PenConfig::OMNI_LIKE`].
/// Serialisable: it is part of the configuration the pen stores ([`crate::pen_io::DeviceConfig`]).
#[derive(Copy, Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PenConfig {
    /// Shoulder to elbow (mm).
    pub upper_arm_mm: f32,
    /// Elbow to wrist (mm).
    pub forearm_mm: f32,
    /// Wrist (gimbal centre) to ferrule along the pen (mm).
    pub stylus_mm: f32,
    /// The shoulder's position in the paper frame (mm).
    pub base_mm: [f32; 3],
    /// Encoder counts per motor revolution (after quadrature decoding).
    pub counts_per_rev: [u32; 3],
    /// Motor revolutions per joint revolution (capstan or gear ratio).
    pub ratio: [f32; 3],
    /// +1 or -1: how a rising count turns the joint.
    pub encoder_sign: [i8; 3],
    /// Motor torque constant (N m / A).
    pub torque_constant: [f32; 3],
    /// Current at full command (A).
    pub max_current: [f32; 3],
    /// +1 or -1: which way a positive command turns the joint.
    pub motor_sign: [i8; 3],
    /// Joint limits (rad).
    pub joint_min: [f32; 3],
    pub joint_max: [f32; 3],
    /// Gimbal sensor scale (rad per ADC code) and sign.
    pub gimbal_rad_per_code: [f32; 3],
    pub gimbal_sign: [i8; 3],
    /// Joint and gimbal angles of the inkwell (calibration) pose (rad).
    pub inkwell_joints: [f32; 3],
    pub inkwell_gimbal: [f32; 3],
}

impl PenConfig {
    /// The Phantom Omni's link lengths (133.35 mm each, SensAble) and plausible parts for a
    /// home-built pen: 2048-count encoders, 13.2:1 capstans, 25 mN m/A motors at 2 A.
    pub const OMNI_LIKE: PenConfig = PenConfig {
        upper_arm_mm: 133.35,
        forearm_mm: 133.35,
        stylus_mm: 0.0,
        base_mm: [0.0, -180.0, 110.0],
        counts_per_rev: [2048; 3],
        ratio: [13.2; 3],
        encoder_sign: [1, 1, 1],
        torque_constant: [0.025; 3],
        max_current: [2.0; 3],
        motor_sign: [1, 1, 1],
        joint_min: [-1.0, -0.3, -2.6],
        joint_max: [1.0, 1.6, -0.15],
        gimbal_rad_per_code: [0.001_534; 3], // 12-bit ADC over 360 degrees
        gimbal_sign: [1, 1, 1],
        inkwell_joints: [0.0, 0.2, -1.2],
        inkwell_gimbal: [0.0, 0.0, 0.0],
    };

    pub fn validate(&self) -> Result<(), LimitError> {
        check("upper_arm_mm", self.upper_arm_mm, 10.0, 1000.0)?;
        check("forearm_mm", self.forearm_mm, 10.0, 1000.0)?;
        check("stylus_mm", self.stylus_mm, 0.0, 300.0)?;
        for j in 0..3 {
            check("base_mm", self.base_mm[j], -2000.0, 2000.0)?;
            check("counts_per_rev", self.counts_per_rev[j] as f32, 4.0, 1.0e7)?;
            check("ratio", self.ratio[j], 0.01, 1000.0)?;
            check("torque_constant", self.torque_constant[j], 1e-5, 10.0)?;
            check("max_current", self.max_current[j], 1e-3, 100.0)?;
            check("joint_min", self.joint_min[j], -7.0, self.joint_max[j])?;
            check("joint_max", self.joint_max[j], self.joint_min[j], 7.0)?;
            check(
                "gimbal_rad_per_code",
                self.gimbal_rad_per_code[j].abs(),
                1e-7,
                1.0,
            )?;
            check(
                "inkwell_joints",
                self.inkwell_joints[j],
                self.joint_min[j],
                self.joint_max[j],
            )?;
            check("inkwell_gimbal", self.inkwell_gimbal[j], -7.0, 7.0)?;
            for (name, s) in [
                ("encoder_sign", self.encoder_sign[j]),
                ("motor_sign", self.motor_sign[j]),
                ("gimbal_sign", self.gimbal_sign[j]),
            ] {
                if s != 1 && s != -1 {
                    return Err(LimitError {
                        name,
                        value: s as f32,
                        min: -1.0,
                        max: 1.0,
                    });
                }
            }
        }
        Ok(())
    }
}

/// Extends a free-running 16-bit encoder count into an unbounded one. Correct as long as the
/// count moves by less than half its range (32,768) between two reads.
#[derive(Copy, Clone, Debug, Default, PartialEq, Eq)]
pub struct EncoderUnwrap {
    last: Option<u16>,
    total: i64,
}

impl EncoderUnwrap {
    pub fn update(&mut self, raw: u16) -> i64 {
        if let Some(last) = self.last {
            self.total += raw.wrapping_sub(last) as i16 as i64;
        } else {
            self.total = raw as i64;
        }
        self.last = Some(raw);
        self.total
    }
    pub fn total(&self) -> i64 {
        self.total
    }
}

/// Raw sensor readings: unwrapped encoder counts and gimbal ADC codes. Serialisable: the
/// readings at the inkwell are the stored calibration ([`crate::pen_io::DeviceConfig`]).
#[derive(Copy, Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct RawReadings {
    pub encoders: [i64; 3],
    pub gimbal: [i32; 3],
}

/// Joint angles of the arm and the gimbal (rad).
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct Joints<S> {
    pub arm: [S; 3],
    pub gimbal: [S; 3],
}

/// Why a pose or reading cannot be turned into joint angles.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub enum KinematicsError {
    /// No calibration yet: the pen does not know its zeros.
    NotCalibrated,
    /// The wrist position is farther than the arm can reach, or too close.
    Unreachable,
    /// Reachable only with joint `joint` outside its limits.
    JointLimit { joint: usize },
}

/// A calibrated pen: configuration plus the raw readings at the inkwell.
#[derive(Clone, Debug)]
pub struct Pen<S> {
    cfg: PenConfig,
    zero: Option<RawReadings>,
    l1: S,
    l2: S,
    base: Vec3<S>,
    rad_per_count: [S; 3],
    rad_per_code: [S; 3],
    torque_per_command: [S; 3],
    /// `cfg`'s inkwell angles and stylus length as scalars, converted once: the force loop
    /// reads them every tick.
    inkwell: Joints<S>,
    stylus: S,
}

impl<S: Scalar> Pen<S> {
    pub fn new(cfg: PenConfig) -> Result<Self, LimitError> {
        cfg.validate()?;
        // Single precision, like the configuration (the pen has no double-precision
        // hardware): a count's angle to 6e-8 relative, far finer than the format keeps it.
        let tau = core::f32::consts::TAU;
        Ok(Pen {
            cfg,
            zero: None,
            l1: S::from_f32(cfg.upper_arm_mm),
            l2: S::from_f32(cfg.forearm_mm),
            base: Vec3::new(
                S::from_f32(cfg.base_mm[0]),
                S::from_f32(cfg.base_mm[1]),
                S::from_f32(cfg.base_mm[2]),
            ),
            rad_per_count: core::array::from_fn(|j| {
                S::from_f32(
                    cfg.encoder_sign[j] as f32 * tau
                        / (cfg.counts_per_rev[j] as f32 * cfg.ratio[j]),
                )
            }),
            rad_per_code: core::array::from_fn(|j| {
                S::from_f32(cfg.gimbal_sign[j] as f32 * cfg.gimbal_rad_per_code[j])
            }),
            // Joint torque at full command: ratio * k_t * I_max (N m).
            torque_per_command: core::array::from_fn(|j| {
                S::from_f32(cfg.ratio[j] * cfg.torque_constant[j] * cfg.max_current[j])
            }),
            inkwell: Joints {
                arm: cfg.inkwell_joints.map(S::from_f32),
                gimbal: cfg.inkwell_gimbal.map(S::from_f32),
            },
            stylus: S::from_f32(cfg.stylus_mm),
        })
    }

    pub fn config(&self) -> &PenConfig {
        &self.cfg
    }

    /// The pen rests in its inkwell: these readings are the known inkwell angles.
    pub fn calibrate(&mut self, at_inkwell: RawReadings) {
        self.zero = Some(at_inkwell);
    }
    pub fn is_calibrated(&self) -> bool {
        self.zero.is_some()
    }

    /// Joint angles from raw readings.
    pub fn joints(&self, raw: &RawReadings) -> Result<Joints<S>, KinematicsError> {
        let zero = self.zero.ok_or(KinematicsError::NotCalibrated)?;
        // `from_fn` hands each closure an index the compiler knows is below 3: no bounds
        // checks on the force path.
        let arm = core::array::from_fn(|j| {
            // Counts since calibration as a scalar: exact for any realistic travel.
            let d = S::from_i64(raw.encoders[j].wrapping_sub(zero.encoders[j]));
            self.inkwell.arm[j] + d * self.rad_per_count[j]
        });
        let gimbal = core::array::from_fn(|j| {
            // In i64: two codes a whole i32 range apart do not overflow.
            let d = S::from_i64(i64::from(raw.gimbal[j]) - i64::from(zero.gimbal[j]));
            self.inkwell.gimbal[j] + d * self.rad_per_code[j]
        });
        Ok(Joints { arm, gimbal })
    }

    /// The wrist (gimbal centre) in the paper frame (mm).
    pub fn wrist(&self, q: &[S; 3]) -> Vec3<S> {
        self.wrist_at(&ArmTrig::of(q))
    }

    /// [`Self::wrist`] from the arm's sines and cosines.
    pub fn wrist_at(&self, t: &ArmTrig<S>) -> Vec3<S> {
        let r = self.l1 * t.c2 + self.l2 * t.c23;
        let h = self.l1 * t.s2 + self.l2 * t.s23;
        self.base + Vec3::new(-r * t.s1, r * t.c1, h)
    }

    /// Forward kinematics: the ferrule's pose.
    pub fn forward(&self, j: &Joints<S>) -> Pose<S> {
        self.forward_with_trig(j).0
    }

    /// [`Self::forward`], with the arm's sines and cosines for the torques of the same
    /// reading ([`Self::torques_at`]). The rotation is `Rz(q1) Rx(q2 + q3) Rz(g1) Rx(g2)
    /// Ry(g3)`, built one axis at a time ([`Quat::then_about`]: half the products of a
    /// general composition); the wrist's sines and cosines of `q1` and `q2 + q3` are the
    /// double angles of the first two half-angle rotations (two products each instead of
    /// a sine and cosine).
    pub fn forward_with_trig(&self, j: &Joints<S>) -> (Pose<S>, ArmTrig<S>) {
        let (h1s, h1c) = half_angle(j.arm[0]).sin_cos();
        let (h23s, h23c) = half_angle(j.arm[1] + j.arm[2]).sin_cos();
        let (s2, c2) = j.arm[1].sin_cos();
        let twice = |v: S| v + v;
        let trig = ArmTrig {
            s1: twice(h1s * h1c),
            c1: h1c * h1c - h1s * h1s,
            s2,
            c2,
            s23: twice(h23s * h23c),
            c23: h23c * h23c - h23s * h23s,
        };
        let about = |q: Quat<S>, axis: usize, angle: S| {
            let (s, c) = half_angle(angle).sin_cos();
            q.then_about(axis, c, s)
        };
        let rot = Quat::new(h1c, S::ZERO, S::ZERO, h1s).then_about(0, h23c, h23s);
        let rot = about(rot, 2, j.gimbal[0]);
        let rot = about(rot, 0, j.gimbal[1]);
        let rot = about(rot, 1, j.gimbal[2]);
        // The stylus runs from the wrist along the pen's -z axis: the rotation's third column
        // (six products; a general rotation of -z takes fifteen).
        let pos = self.wrist_at(&trig) - rot.z_axis().scale(self.stylus);
        (Pose::new(pos, rot), trig)
    }

    /// Inverse kinematics of the arm: the joint angles that put the wrist at `p` (elbow bent
    /// downward), checked against the joint limits.
    pub fn inverse_wrist(&self, p: Vec3<S>) -> Result<[S; 3], KinematicsError> {
        let d = p - self.base;
        let q1 = (-d.x).atan2(d.y);
        let r = (d.x * d.x + d.y * d.y).sqrt();
        let h = d.z;
        let (l1, l2) = (self.l1, self.l2);
        let two = S::ONE + S::ONE;
        let c3 = (r * r + h * h - l1 * l1 - l2 * l2).div(two * l1 * l2);
        if c3 > S::ONE || c3 < -S::ONE {
            return Err(KinematicsError::Unreachable);
        }
        let s3 = -(S::ONE - c3 * c3).max(S::ZERO).sqrt();
        let q3 = s3.atan2(c3);
        let q2 = h.atan2(r) - (l2 * s3).atan2(l1 + l2 * c3);
        let q = [q1, q2, q3];
        for (j, &qj) in q.iter().enumerate() {
            if qj < S::from_f32(self.cfg.joint_min[j]) || qj > S::from_f32(self.cfg.joint_max[j]) {
                return Err(KinematicsError::JointLimit { joint: j });
            }
        }
        Ok(q)
    }

    /// Inverse kinematics of the whole pen: the arm and gimbal angles that put the ferrule at
    /// `pose` (the arm through [`Self::inverse_wrist`], the gimbal by splitting the rotation
    /// left after the arm's `Rz(q1) Rx(q2 + q3)` into `Rz(g1) Rx(g2) Ry(g3)`). With
    /// [`Self::raw_readings`] it synthesises what a pen's sensors would read at a pose (the
    /// QEMU board's virtual pen, for bring-up tests).
    pub fn inverse(&self, pose: &Pose<S>) -> Result<Joints<S>, KinematicsError> {
        let wrist = pose.pos + pose.rot.rotate(Vec3::Z).scale(self.stylus);
        let arm = self.inverse_wrist(wrist)?;
        let forearm = axis_quat(2, arm[0]).compose(axis_quat(0, arm[1] + arm[2]));
        let g = forearm.conj().compose(pose.rot);
        // Columns of Rz(a) Rx(b) Ry(c): e_y -> (-sin a cos b, cos a cos b, sin b), and the z
        // row is (-sin c cos b, sin b, cos c cos b).
        let ey = g.rotate(Vec3::new(S::ZERO, S::ONE, S::ZERO));
        let ex = g.rotate(Vec3::new(S::ONE, S::ZERO, S::ZERO));
        let ez = g.rotate(Vec3::Z);
        let g1 = (-ey.x).atan2(ey.y);
        let g2 = ey.z.atan2((ey.x * ey.x + ey.y * ey.y).sqrt());
        let g3 = (-ex.z).atan2(ez.z);
        Ok(Joints {
            arm,
            gimbal: [g1, g2, g3],
        })
    }

    /// The raw readings at joint angles `j`: the inverse of [`Self::joints`], rounded to
    /// whole counts and codes.
    pub fn raw_readings(&self, j: &Joints<S>) -> Result<RawReadings, KinematicsError> {
        let zero = self.zero.ok_or(KinematicsError::NotCalibrated)?;
        let steps = |angle: S, at_zero: f32, per_step: S| -> i64 {
            let d = (angle - S::from_f32(at_zero)).div(per_step).to_f64();
            // Saturating: a reading beyond i64 cannot come from a joint within its limits.
            libm::round(d) as i64
        };
        let mut raw = zero;
        for k in 0..3 {
            raw.encoders[k] = zero.encoders[k].saturating_add(steps(
                j.arm[k],
                self.cfg.inkwell_joints[k],
                self.rad_per_count[k],
            ));
            let code = steps(
                j.gimbal[k],
                self.cfg.inkwell_gimbal[k],
                self.rad_per_code[k],
            );
            raw.gimbal[k] = (i64::from(zero.gimbal[k]) + code)
                .clamp(i64::from(i32::MIN), i64::from(i32::MAX)) as i32;
        }
        Ok(raw)
    }

    /// Whether the wrist position `p` is inside the workspace (reachable within limits).
    pub fn in_workspace(&self, p: Vec3<S>) -> bool {
        self.inverse_wrist(p).is_ok()
    }

    /// Jacobian of the wrist position (mm per rad), columns = joints.
    pub fn jacobian(&self, q: &[S; 3]) -> [Vec3<S>; 3] {
        self.jacobian_at(&ArmTrig::of(q))
    }

    /// [`Self::jacobian`] from the arm's sines and cosines.
    pub fn jacobian_at(&self, t: &ArmTrig<S>) -> [Vec3<S>; 3] {
        let (s1, c1) = (t.s1, t.c1);
        let r = self.l1 * t.c2 + self.l2 * t.c23;
        let dr2 = -(self.l1 * t.s2 + self.l2 * t.s23);
        let dh2 = r;
        let dr3 = -(self.l2 * t.s23);
        let dh3 = self.l2 * t.c23;
        // Joint 1 turns the arm about z: d/dq1 = r (-cos q1, -sin q1, 0). Joints 2 and 3 move
        // the wrist in the arm's vertical plane, along u = (-sin q1, cos q1, 0) and z. Written
        // out, without the products with the zero and unit components (the same values).
        [
            Vec3::new(-c1 * r, -s1 * r, S::ZERO),
            Vec3::new(-s1 * dr2, c1 * dr2, dh2),
            Vec3::new(-s1 * dr3, c1 * dr3, dh3),
        ]
    }

    /// Joint torques (N m) that produce force `f` (N) at the wrist: `tau = J^T F`.
    pub fn torques(&self, q: &[S; 3], f: Vec3<S>) -> [S; 3] {
        self.torques_at(&ArmTrig::of(q), f)
    }

    /// [`Self::torques`] from the arm's sines and cosines ([`Self::forward_with_trig`]).
    pub fn torques_at(&self, t: &ArmTrig<S>, f: Vec3<S>) -> [S; 3] {
        let j = self.jacobian_at(t);
        let mm = S::from_f64(1e-3);
        [j[0].dot(f) * mm, j[1].dot(f) * mm, j[2].dot(f) * mm]
    }

    /// Motor commands in [-1, 1] (full current) for joint torques `tau` (N m): through the
    /// ratio and the torque constant, clamped.
    pub fn motor_commands(&self, tau: &[S; 3]) -> [S; 3] {
        core::array::from_fn(|j| {
            let c = tau[j].div(self.torque_per_command[j]);
            let c = if self.cfg.motor_sign[j] < 0 { -c } else { c };
            c.clamp(-S::ONE, S::ONE)
        })
    }
}

/// Sines and cosines of the arm's joint angles `q1`, `q2` and `q2 + q3`: what the wrist
/// position ([`Pen::wrist_at`]) and its Jacobian ([`Pen::jacobian_at`]) are made of,
/// computed once per reading and shared by the pose and the torques of a tick.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct ArmTrig<S> {
    pub s1: S,
    pub c1: S,
    pub s2: S,
    pub c2: S,
    pub s23: S,
    pub c23: S,
}

impl<S: Scalar> ArmTrig<S> {
    pub fn of(q: &[S; 3]) -> Self {
        let (s1, c1) = q[0].sin_cos();
        let (s2, c2) = q[1].sin_cos();
        let (s23, c23) = (q[1] + q[2]).sin_cos();
        ArmTrig {
            s1,
            c1,
            s2,
            c2,
            s23,
            c23,
        }
    }
}

fn half_angle<S: Scalar>(angle: S) -> S {
    angle.halve()
}

/// Rotation by `angle` about axis 0 (x), 1 (y) or 2 (z).
fn axis_quat<S: Scalar>(axis: usize, angle: S) -> Quat<S> {
    let (s, c) = half_angle(angle).sin_cos();
    match axis {
        0 => Quat::new(c, s, S::ZERO, S::ZERO),
        1 => Quat::new(c, S::ZERO, s, S::ZERO),
        _ => Quat::new(c, S::ZERO, S::ZERO, s),
    }
}
