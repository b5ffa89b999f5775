//! The force model and the output stage: what the hand feels, and that it is safe.

use maobi_shared::force::{
    ForceModel, Forces, OutputStage, OutputState, DEFAULT_FORCES, PHANTOM_OMNI,
};
use maobi_shared::hand::{HandParams, Script, SimHand};
use maobi_shared::{presets, Brush, Fx, Pose, Quat, Scalar, Vec3};

fn pose<S: Scalar>(p: [f64; 3], tilt_deg: f64) -> Pose<S> {
    let h = tilt_deg.to_radians() / 2.0;
    Pose::new(
        Vec3::from_f64(p),
        Quat::from_f64([h.cos(), 0.0, h.sin(), 0.0]),
    )
}

/// Runs brush and force model one tick with the hand's ferrule at `p`.
fn step<S: Scalar>(b: &mut Brush<S>, f: &mut ForceModel<S>, p: [f64; 3], tilt: f64) -> Forces<S> {
    let target = pose::<S>(p, tilt);
    b.tick(target);
    f.tick(b, target.pos)
}

#[test]
fn free_air_gives_gravity_only() {
    let mut b = Brush::<Fx>::new(presets::LARGE, pose([0.0, 0.0, 80.0], 10.0)).unwrap();
    let mut f = ForceModel::<Fx>::new(DEFAULT_FORCES).unwrap();
    for k in 0..2000 {
        let t = k as f64 * 1e-3;
        let p = [
            30.0 * (3.0 * t).sin(),
            20.0 * (2.0 * t).cos(),
            60.0 + 10.0 * (5.0 * t).sin(),
        ];
        let out = step(&mut b, &mut f, p, 10.0 + 20.0 * t);
        assert_eq!(out.total, out.gravity, "tick {k}: {out:?}");
        assert!(out.gravity.z.to_f64() < 0.0);
    }
    let g = f.tick(&b, b.handle().pos).gravity.z.to_f64();
    assert!((g + 0.015 * 9.806_65).abs() < 1e-6, "{g}");
}

#[test]
fn contact_pushes_back_along_the_normal() {
    // A stroke: descend, drag, lift, at a slant. Whenever hair lies on the paper the contact
    // terms (normal + constraint) push up.
    let tilt = 20.0;
    let reach = 40.0 * f64::to_radians(tilt).cos();
    let mut b = Brush::<Fx>::new(presets::LARGE, pose([0.0, 0.0, reach + 5.0], tilt)).unwrap();
    let mut f = ForceModel::<Fx>::new(DEFAULT_FORCES).unwrap();
    let mut touching = 0;
    for k in 0..1500 {
        let t = k as f64 * 1e-3;
        let depth = 8.0 * (std::f64::consts::PI * t / 1.5).sin();
        let p = [60.0 * t, 0.0, reach - depth];
        let out = step(&mut b, &mut f, p, tilt);
        if b.contacts() > 0 {
            touching += 1;
            let up = (out.normal + out.constraint).z.to_f64();
            assert!(
                up > 0.0,
                "tick {k}: {} masses on the paper, normal force {up}",
                b.contacts()
            );
        }
    }
    assert!(touching > 500, "only {touching} ticks touching");
}

#[test]
fn straight_press_of_five_mm_gives_between_a_third_and_three_newtons_monotonic_in_depth() {
    let mut b = Brush::<Fx>::new(presets::LARGE, pose([0.0, 0.0, 45.0], 0.0)).unwrap();
    let mut f = ForceModel::<Fx>::new(DEFAULT_FORCES).unwrap();
    let mut last = 0.0;
    for depth in [0.5, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0] {
        let mut out = None;
        for _ in 0..300 {
            out = Some(step(&mut b, &mut f, [0.0, 0.0, 40.0 - depth], 0.0));
        }
        let n = out.unwrap().normal.z.to_f64();
        println!("pressed {depth} mm: normal force {n:.3} N");
        assert!(n > last, "not monotonic at {depth} mm: {n} after {last}");
        if depth == 5.0 {
            assert!((0.3..3.0).contains(&n), "5 mm: {n} N");
        }
        last = n;
    }
}

/// A pressed, dragged, lifted script with the stage enabled part-way, already in the paper.
fn run_stage(limits_ramp_out_s: f32, fault_at: Option<usize>, ticks: usize) -> Vec<[f64; 3]> {
    let mut limits = PHANTOM_OMNI;
    limits.ramp_out_s = limits_ramp_out_s;
    let mut b = Brush::<Fx>::new(presets::LARGE, pose([0.0, 0.0, 45.0], 15.0)).unwrap();
    let mut f = ForceModel::<Fx>::new(DEFAULT_FORCES).unwrap();
    let mut stage = OutputStage::<Fx>::new(limits).unwrap();
    let mut hand = SimHand::new(HandParams::WRITER, [0.0, 0.0, 45.0]);
    let mut script = Script::new(7, [0.0, 0.0, 45.0], (-2.0, 45.0));
    let mut cmd = [0.0; 3];
    let mut out = Vec::new();
    let mut last = Vec3::<Fx>::ZERO;
    for k in 0..ticks {
        let (target, push) = script.tick();
        hand.tick_with_push(target, cmd, push);
        let p = Vec3::<Fx>::from_f64(hand.stylus());
        b.tick(pose(hand.stylus(), 15.0));
        let forces = f.tick(&b, p);
        if k == 300 {
            stage.enable();
        }
        if Some(k) == fault_at {
            stage.fault();
        }
        let c = stage.apply(forces.total, p - last);
        last = p;
        cmd = c.to_f64();
        out.push(cmd);
    }
    out
}

#[test]
fn commanded_force_never_steps_more_than_the_limit_even_when_enabled_in_the_paper() {
    let cmds = run_stage(0.0, None, 6000);
    let max_step = PHANTOM_OMNI.max_step_n as f64;
    let mut worst: f64 = 0.0;
    for w in cmds.windows(2) {
        let d = ((w[1][0] - w[0][0]).powi(2)
            + (w[1][1] - w[0][1]).powi(2)
            + (w[1][2] - w[0][2]).powi(2))
        .sqrt();
        worst = worst.max(d);
    }
    let peak = cmds
        .iter()
        .map(|c| (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt())
        .fold(0.0, f64::max);
    println!("largest step {worst:.4} N (limit {max_step}), largest force {peak:.3} N");
    assert!(worst <= max_step + 1e-6);
    assert!(peak <= PHANTOM_OMNI.peak_n as f64 + 1e-6);
    assert!(peak > 0.3, "the script should make real forces");
}

#[test]
fn a_fault_brings_the_force_to_zero_within_the_ramp_out_time_plus_one_tick() {
    for (ramp_out_s, fault_at) in [(0.0, 700), (0.0, 1234), (0.005, 900), (0.02, 2500)] {
        let cmds = run_stage(ramp_out_s, Some(fault_at), fault_at + 100);
        let allowed = (ramp_out_s as f64 / 1e-3).ceil() as usize;
        let zero_from = fault_at + allowed;
        let before = cmds[fault_at - 1];
        println!("ramp-out {ramp_out_s} s, fault at tick {fault_at}: force before {before:?}");
        for (k, c) in cmds.iter().enumerate().skip(zero_from) {
            assert_eq!(*c, [0.0; 3], "tick {k}: still {c:?}");
        }
    }
}

#[test]
fn output_stage_states() {
    let mut s = OutputStage::<Fx>::new(PHANTOM_OMNI).unwrap();
    assert_eq!(s.state(), OutputState::Disabled);
    let f = Vec3::<Fx>::from_f64([0.0, 0.0, 2.0]);
    assert_eq!(s.apply(f, Vec3::ZERO), Vec3::ZERO, "disabled: no force");
    s.enable();
    let first = s.apply(f, Vec3::ZERO);
    assert!(first.z.to_f64() > 0.0 && first.z.to_f64() <= 0.2 + 1e-9);
    assert_eq!(s.state(), OutputState::RampingIn);
    for _ in 0..2000 {
        s.apply(f, Vec3::ZERO);
    }
    assert_eq!(s.state(), OutputState::Active);
    // 2 N held for 2 s: the thermal limit brings it down to the continuous 0.88 N.
    let held = s.last_command().z.to_f64();
    assert!((held - 0.88).abs() < 0.06, "held {held}");
    s.fault();
    assert_eq!(s.apply(f, Vec3::ZERO), Vec3::ZERO);
    assert_eq!(s.state(), OutputState::Faulted);
    s.clear_fault();
    assert!(s.apply(f, Vec3::ZERO).z.to_f64() > 0.0);
}

/// A model force far beyond fixed point's squares (a hostile host's poses drive the model
/// there): the command still stays within the peak, tick after tick. The norm's square
/// saturated, the clamp came out too weak, and the step limit walked the command past the
/// peak at 0.2 N a tick (found by the pen's fuzz test, `hil/tests/fuzz.rs`).
#[test]
fn a_force_beyond_fixed_points_range_is_still_clamped_to_the_peak() {
    for wanted in [
        [-2.4e6, 0.6, 7.2],
        [5.5e5, -4.0e5, 1.0e5],
        [0.0, 0.0, 2.0e9],
        [3.0e4, 3.0e4, 3.0e4],
    ] {
        let mut s = OutputStage::<Fx>::new(PHANTOM_OMNI).unwrap();
        s.enable();
        let f = Vec3::<Fx>::from_f64(wanted);
        let mut last = 0.0;
        for k in 0..3000 {
            let c = s.apply(f, Vec3::ZERO);
            let n = c.to_f64();
            last = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            assert!(
                last <= f64::from(PHANTOM_OMNI.peak_n) * (1.0 + 1e-6),
                "{wanted:?}, tick {k}: {last} N"
            );
        }
        // Held at the thermal limit by then, pointing along the wanted force.
        assert!(last > 0.5, "{wanted:?}: {last} N");
    }
}

/// The command after the passivity controller's ticks (see the test below), and the energy
/// the observer holds then (J).
fn passivity_run<S: Scalar>(step_mm: f64) -> (f64, f64) {
    let mut s = OutputStage::<S>::new(PHANTOM_OMNI).unwrap();
    s.enable();
    let f = Vec3::<S>::from_f64([0.5, 0.0, 0.0]);
    // Ramped in with the hand still: no work done, 0.5 N held.
    for _ in 0..1000 {
        s.apply(f, Vec3::ZERO);
    }
    assert!((s.last_command().x.to_f64() - 0.5).abs() < 1e-9);
    assert_eq!(s.absorbed_energy(), 0.0);
    let c = s.apply(f, Vec3::<S>::from_f64([step_mm, 0.0, 0.0]));
    (c.x.to_f64(), s.absorbed_energy())
}

#[test]
fn the_passivity_controller_takes_back_what_the_device_put_in() {
    // The hand moves 0.1 mm along the 0.5 N it was held with: the device did 0.05 mJ of
    // work on it. The damper that takes that back within the tick is a = 0.05 mJ / (0.1
    // mm/tick)^2 = 5 N s/m, i.e. -0.5 N: the target falls to zero and the step limit (0.2
    // N, an f32: 0.2 + 3e-9) leaves 0.3 N. Fixed point (energy in mJ, Fx) and f64 agree.
    for (x, absorbed) in [passivity_run::<Fx>(0.1), passivity_run::<f64>(0.1)] {
        assert!((x - 0.3).abs() < 1e-8, "command {x}");
        assert!((absorbed + 0.05e-3).abs() < 1e-12, "absorbed {absorbed}");
    }
    // A slow hand (1e-4 mm/tick): surplus / v^2 is 5e6 N s/m, the damper takes its largest
    // coefficient (peak / 1 mm/s: 0.33 N at this speed) and the quotient never overflows.
    for (x, _) in [passivity_run::<Fx>(1e-4), passivity_run::<f64>(1e-4)] {
        assert!((x - 0.3).abs() < 1e-6, "command {x}");
    }
    // Without the controller the model's force goes through unchanged.
    let mut s = OutputStage::<Fx>::new(PHANTOM_OMNI).unwrap();
    s.set_passivity_control(false);
    s.enable();
    let f = Vec3::<Fx>::from_f64([0.5, 0.0, 0.0]);
    for _ in 0..1000 {
        s.apply(f, Vec3::ZERO);
    }
    let c = s.apply(f, Vec3::<Fx>::from_f64([0.1, 0.0, 0.0]));
    assert!((c.x.to_f64() - 0.5).abs() < 1e-9);
}

#[test]
fn bad_force_parameters_are_rejected() {
    let mut p = DEFAULT_FORCES;
    p.normal_weight = f32::NAN;
    assert!(ForceModel::<Fx>::new(p).is_err());
    let mut m = ForceModel::<Fx>::new(DEFAULT_FORCES).unwrap();
    p = DEFAULT_FORCES;
    p.constraint_stiffness = -1.0;
    let e = m.set_params(p).unwrap_err();
    assert!(e.to_string().contains("constraint_stiffness"), "{e}");
    assert_eq!(*m.params(), DEFAULT_FORCES);
    let mut l = PHANTOM_OMNI;
    l.continuous_n = 5.0; // above the peak
    assert!(OutputStage::<Fx>::new(l).is_err());
}
