//! The reference pen's kinematics against hand-computed poses, finite differences and itself.

use maobi_shared::kinematics::{
    EncoderUnwrap, Joints, KinematicsError, Pen, PenConfig, RawReadings,
};
use maobi_shared::{Fx, Scalar, Vec3};
use std::f64::consts::FRAC_PI_2;

fn pen<S: Scalar>() -> Pen<S> {
    Pen::new(PenConfig::OMNI_LIKE).unwrap()
}

fn close(a: [f64; 3], b: [f64; 3], tol: f64) -> bool {
    (0..3).all(|i| (a[i] - b[i]).abs() <= tol)
}

#[test]
fn forward_kinematics_matches_hand_computed_poses() {
    let p = pen::<f64>();
    let (l1, l2) = (133.35f32 as f64, 133.35f32 as f64);
    let b = PenConfig::OMNI_LIKE.base_mm.map(|v| v as f64);
    let cases = [
        ([0.0, 0.0, 0.0], [b[0], b[1] + l1 + l2, b[2]]),
        ([FRAC_PI_2, 0.0, 0.0], [b[0] - (l1 + l2), b[1], b[2]]),
        ([0.0, FRAC_PI_2, -FRAC_PI_2], [b[0], b[1] + l2, b[2] + l1]),
        ([0.0, 0.0, -FRAC_PI_2], [b[0], b[1] + l1, b[2] - l2]),
    ];
    for (q, want) in cases {
        let got = p.wrist(&q).to_f64();
        assert!(close(got, want, 1e-9), "q = {q:?}: {got:?} != {want:?}");
    }
    // All angles zero but the elbow: the brush points straight down after the forearm's
    // elevation is undone by the gimbal pitch.
    let j = Joints {
        arm: [0.3, 0.2, -0.9],
        gimbal: [0.0, 0.7, 0.0],
    };
    let down = p.forward(&j).down().to_f64();
    assert!(close(down, [0.0, 0.0, -1.0], 1e-12), "{down:?}");
}

#[test]
fn forward_and_inverse_agree_to_a_micrometre_inside_the_workspace() {
    let fixed = pen::<Fx>();
    let reference = pen::<f64>();
    let mut checked = 0;
    let mut worst: f64 = 0.0;
    for x in (-120..=120).step_by(20) {
        for y in (-20..=120).step_by(20) {
            for z in (-20..=120).step_by(20) {
                let target = [x as f64, y as f64, z as f64];
                let Ok(q) = reference.inverse_wrist(Vec3::from_f64(target)) else {
                    continue;
                };
                let back = reference.wrist(&q).to_f64();
                assert!(
                    close(back, target, 1e-9),
                    "f64 round trip {target:?} -> {back:?}"
                );
                let qf = fixed
                    .inverse_wrist(Vec3::from_f64(target))
                    .expect("fixed point reaches it too");
                let backf = fixed.wrist(&qf).to_f64();
                for i in 0..3 {
                    worst = worst.max((backf[i] - target[i]).abs());
                }
                checked += 1;
            }
        }
    }
    println!(
        "{checked} workspace points; worst fixed-point forward(inverse(p)) error {:.3} um",
        worst * 1e3
    );
    assert!(checked > 100);
    assert!(worst < 1e-3, "{worst} mm");
}

#[test]
fn unreachable_and_out_of_limit_poses_are_refused() {
    let p = pen::<f64>();
    let b = PenConfig::OMNI_LIKE.base_mm.map(|v| v as f64);
    assert_eq!(
        p.inverse_wrist(Vec3::from_f64([b[0], b[1] + 400.0, b[2]])),
        Err(KinematicsError::Unreachable)
    );
    assert!(matches!(
        p.inverse_wrist(Vec3::from_f64([b[0], b[1] - 200.0, b[2]])),
        Err(KinematicsError::JointLimit { .. })
    ));
    assert!(!p.in_workspace(Vec3::from_f64([b[0] + 250.0, b[1] - 10.0, b[2]])));
}

#[test]
fn jacobian_transpose_matches_finite_differences() {
    let p = pen::<f64>();
    let f = Vec3::from_f64([0.4, -1.1, 2.3]); // N
    for q in [[0.1, 0.3, -1.0], [-0.6, 1.1, -0.4], [0.8, -0.2, -2.0]] {
        let tau = p.torques(&q, f);
        for j in 0..3 {
            // tau_j = F . d(wrist)/dq_j, the derivative by central differences (mm -> m).
            let h = 1e-6;
            let mut qp = q;
            let mut qm = q;
            qp[j] += h;
            qm[j] -= h;
            let d = (p.wrist(&qp) - p.wrist(&qm)).scale(1.0 / (2.0 * h));
            let fd = f.dot(d) * 1e-3;
            assert!(
                (tau[j] - fd).abs() < 1e-7,
                "q = {q:?} joint {j}: {} vs {fd}",
                tau[j]
            );
        }
    }
}

#[test]
fn encoder_counts_wrap_and_signs_are_honoured() {
    let mut e = EncoderUnwrap::default();
    assert_eq!(e.update(65_530), 65_530);
    assert_eq!(e.update(4), 65_540, "forward across the wrap");
    assert_eq!(e.update(65_000), 65_000 - 65_536 + 65_536, "back across it");
    assert_eq!(e.update(65_000), 65_000);
    let mut cfg = PenConfig::OMNI_LIKE;
    let mut p = Pen::<f64>::new(cfg).unwrap();
    let zero = RawReadings {
        encoders: [1000, -5, 70_000],
        gimbal: [2048, 100, 4000],
    };
    assert_eq!(p.joints(&zero), Err(KinematicsError::NotCalibrated));
    p.calibrate(zero);
    let at_inkwell = p.joints(&zero).unwrap();
    let ink = cfg.inkwell_joints.map(|v| v as f64);
    assert!(
        close(at_inkwell.arm, ink, 1e-12),
        "calibration pose reads the inkwell angles"
    );
    // One joint revolution of counts turns joint 0 by 2 pi; flipping its sign reverses it.
    // (The scale is derived in single precision, like the configuration, in this order.)
    let rad_per_count = (core::f32::consts::TAU / (2048.0 * 13.2f32)) as f64;
    let mut moved = zero;
    moved.encoders[0] += 5000;
    let q = p.joints(&moved).unwrap().arm[0];
    assert!((q - (ink[0] + 5000.0 * rad_per_count)).abs() < 1e-12, "{q}");
    cfg.encoder_sign[0] = -1;
    let mut flipped = Pen::<f64>::new(cfg).unwrap();
    flipped.calibrate(zero);
    assert!((flipped.joints(&moved).unwrap().arm[0] - (2.0 * ink[0] - q)).abs() < 1e-12);
    // Gimbal codes: 4096 codes over a turn.
    let mut g = zero;
    g.gimbal[1] += 1024;
    let pitch = p.joints(&g).unwrap().gimbal[1];
    assert!((pitch - 1024.0 * 0.001_534).abs() < 1e-6, "{pitch}");
}

#[test]
fn motor_commands_follow_ratio_torque_constant_and_clamp() {
    let p = pen::<f64>();
    // N m at the joint for full current, derived in single precision like the configuration.
    let full = (13.2f32 * 0.025f32 * 2.0f32) as f64;
    let c = p.motor_commands(&[full / 2.0, -full / 4.0, 3.0 * full]);
    assert!(close(c, [0.5, -0.25, 1.0], 1e-12), "{c:?}");
    let mut cfg = PenConfig::OMNI_LIKE;
    cfg.motor_sign[1] = -1;
    let p2 = Pen::<f64>::new(cfg).unwrap();
    assert!((p2.motor_commands(&[0.0, full / 4.0, 0.0])[1] + 0.25).abs() < 1e-12);
    let mut bad = PenConfig::OMNI_LIKE;
    bad.ratio[2] = f32::NAN;
    assert!(Pen::<f64>::new(bad).is_err());
}

/// Whole-pen inverse kinematics and synthesised readings (the QEMU board's virtual pen
/// reports these for bring-up): forward(inverse(pose)) is the pose, and the readings that
/// `raw_readings` makes give the same joints back through `joints`.
#[test]
fn inverse_and_raw_readings_round_trip() {
    let mut cfg = PenConfig::OMNI_LIKE;
    cfg.stylus_mm = 40.0;
    cfg.encoder_sign = [1, -1, 1];
    cfg.gimbal_sign = [-1, 1, 1];
    let mut p = Pen::<f64>::new(cfg).unwrap();
    let zero = RawReadings {
        encoders: [100, -2000, 70_000],
        gimbal: [2048, 1900, 2100],
    };
    assert_eq!(
        p.raw_readings(&Joints {
            arm: [0.0; 3],
            gimbal: [0.0; 3]
        }),
        Err(KinematicsError::NotCalibrated)
    );
    p.calibrate(zero);
    let mut checked = 0;
    for (arm, gimbal) in [
        ([0.0, 0.2, -1.2], [0.0, 0.0, 0.0]),
        ([0.3, 0.5, -1.0], [0.4, -0.3, 0.2]),
        ([-0.7, 1.0, -2.0], [-1.2, 0.9, -0.6]),
        ([0.9, -0.2, -0.4], [2.5, -1.1, 1.4]),
    ] {
        let j = Joints { arm, gimbal };
        let pose = p.forward(&j);
        let back = p.inverse(&pose).expect("reachable");
        for k in 0..3 {
            assert!(
                (back.arm[k] - arm[k]).abs() < 1e-9,
                "{arm:?} -> {:?}",
                back.arm
            );
            assert!(
                (back.gimbal[k] - gimbal[k]).abs() < 1e-9,
                "{gimbal:?} -> {:?}",
                back.gimbal
            );
        }
        let raw = p.raw_readings(&back).unwrap();
        let again = p.joints(&raw).unwrap();
        // Whole counts: within half a count (2 pi / (2048 * 13.2) / 2 = 0.12 mrad) and half
        // a code (0.77 mrad).
        for k in 0..3 {
            assert!((again.arm[k] - arm[k]).abs() <= 0.5 * 2.33e-4, "{k}");
            assert!((again.gimbal[k] - gimbal[k]).abs() <= 0.5 * 1.534e-3, "{k}");
        }
        checked += 1;
    }
    // At the inkwell, the readings are the calibration's.
    let ink = Joints {
        arm: cfg.inkwell_joints.map(f64::from),
        gimbal: cfg.inkwell_gimbal.map(f64::from),
    };
    assert_eq!(p.raw_readings(&ink), Ok(zero));
    // Fixed point agrees with f64 to a count.
    let mut pf = Pen::<Fx>::new(cfg).unwrap();
    pf.calibrate(zero);
    let j = Joints {
        arm: [0.3, 0.5, -1.0],
        gimbal: [0.4, -0.3, 0.2],
    };
    let rf = pf.inverse(&pf.forward(&Joints {
        arm: j.arm.map(Fx::from_f64),
        gimbal: j.gimbal.map(Fx::from_f64),
    }));
    let rf = pf.raw_readings(&rf.unwrap()).unwrap();
    let rd = p.raw_readings(&j).unwrap();
    for k in 0..3 {
        assert!((rf.encoders[k] - rd.encoders[k]).abs() <= 1);
        assert!((rf.gimbal[k] - rd.gimbal[k]).abs() <= 1);
    }
    assert_eq!(checked, 4);
}
