//! The force model and the output stage: what the hand feels, and that it is safe.

use maobi_shared::force::{
    ForceModel, Forces, FrictionLaw, OutputStage, OutputState, DEFAULT_FORCES, PHANTOM_OMNI,
};
use maobi_shared::hand::{HandParams, Script, SimHand};
use maobi_shared::{presets, Brush, BrushScalar, Fx, Pose, Quat, Scalar, Vec3};

fn pose<S: BrushScalar>(p: [f64; 3], tilt_deg: f64) -> Pose<S> {
    let h = tilt_deg.to_radians() / 2.0;
    Pose::new(
        Vec3::from_f64(p),
        Quat::from_f64([h.cos(), 0.0, h.sin(), 0.0]),
    )
}

/// Runs brush and force model one tick with the hand's ferrule at `p`.
fn step<S: BrushScalar>(
    b: &mut Brush<S>,
    f: &mut ForceModel<S>,
    p: [f64; 3],
    tilt: f64,
) -> Forces<S> {
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

/// The large brush upright with its tip `depth` mm into the paper, held until the normal
/// force's low-pass has settled: the brush, the model and the ferrule's position.
fn pressed<S: BrushScalar>(depth: f64) -> (Brush<S>, ForceModel<S>, [f64; 3]) {
    let at = [0.0, 0.0, 40.0 - depth];
    let mut b = Brush::<S>::new(presets::LARGE, pose(at, 0.0)).unwrap();
    let mut f = ForceModel::<S>::new(DEFAULT_FORCES).unwrap();
    for _ in 0..300 {
        step(&mut b, &mut f, at, 0.0);
    }
    (b, f, at)
}

#[test]
fn friction_holds_until_mu_s_then_slides_at_mu_k_against_the_motion() {
    for scalar in ["fixed", "f64"] {
        let run = |b: &mut dyn FnMut([f64; 3]) -> (f64, f64)| {
            // Pulled along +x at 10 mm/s for 0.2 s, held still, then pushed back along -x.
            let mut x = 0.0;
            let mut trace = Vec::new();
            for k in 0..600 {
                x += match k {
                    0..200 => 0.01,
                    200..300 => 0.0,
                    _ => -0.01,
                };
                trace.push(b([x, 0.0, 35.0]));
            }
            trace
        };
        let trace = match scalar {
            "fixed" => {
                let (mut b, mut f, _) = pressed::<Fx>(5.0);
                run(&mut |p| {
                    let out = step(&mut b, &mut f, p, 0.0);
                    (out.friction.x.to_f64(), out.normal.z.to_f64())
                })
            }
            _ => {
                let (mut b, mut f, _) = pressed::<f64>(5.0);
                run(&mut |p| {
                    let out = step(&mut b, &mut f, p, 0.0);
                    (out.friction.x, out.normal.z)
                })
            }
        };
        let (mu_s, mu_k) = (
            DEFAULT_FORCES.static_friction as f64,
            DEFAULT_FORCES.kinetic_friction as f64,
        );
        let k_b = DEFAULT_FORCES.bristle_stiffness as f64 * 1e-3; // N per mm
        let n = trace[0].1;
        assert!(n > 0.5, "{scalar}: pressed 5 mm, normal force {n} N");
        // Sticking: the bristle's spring, k_b per mm of the hand's travel, against it.
        assert!(
            (trace[0].0 + k_b * 0.01).abs() < 1e-9,
            "{scalar}: {:?}",
            trace[0]
        );
        let peak = trace[..200].iter().map(|t| -t.0).fold(0.0, f64::max);
        assert!(
            peak <= mu_s * n + 1e-9 && peak > mu_s * n - k_b * 0.01,
            "{scalar}: breaks away at {peak} N, mu_s F_n = {} N",
            mu_s * n
        );
        // Sliding: mu_k F_n against the motion, then held there while the hand rests.
        for (k, t) in trace.iter().enumerate().take(300).skip(150) {
            assert!(
                (t.0 + mu_k * t.1).abs() < 1e-7,
                "{scalar}, tick {k}: {} N at F_n = {} N",
                t.0,
                t.1
            );
        }
        // Pushed back: the bristle unloads and loads the other way, held by mu_s, then
        // slides at mu_k.
        let back = &trace[300..];
        let most = back.iter().map(|t| t.0).fold(f64::MIN, f64::max);
        assert!(
            most <= mu_s * n + 1e-9 && most > mu_s * n - k_b * 0.01,
            "{scalar}: {most}"
        );
        let last = back[back.len() - 1];
        assert!((last.0 - mu_k * last.1).abs() < 1e-7, "{scalar}: {last:?}");
        println!(
            "{scalar}: F_n {n:.4} N, breakaway {peak:.4} N, sliding {:.4} N",
            -trace[250].0
        );
    }
}

/// The derivation in `force.rs`: over every tick, the bristle's energy rises by at most the
/// work the hand did against the friction held over the tick plus the zero-order hold's
/// `k_b |dx|^2 / 2`, whatever the hand and the normal force do.
#[test]
fn the_bristle_never_returns_more_than_the_hand_put_in() {
    fn check<S: BrushScalar>() -> usize {
        let k_b = DEFAULT_FORCES.bristle_stiffness as f64 * 1e-3; // N per mm
        let mut b = Brush::<S>::new(presets::LARGE, pose([0.0, 0.0, 42.0], 20.0)).unwrap();
        let mut f = ForceModel::<S>::new(DEFAULT_FORCES).unwrap();
        let mut state = 0x2545_f491_4f6c_dd1d_u64;
        let mut rand = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let (mut p, mut v) = ([0.0, 0.0, 38.0], [0.0; 3]);
        let mut held = [0.0; 2];
        let mut energy_mj = 0.0;
        let mut slips = 0;
        for k in 0..20_000 {
            // A wandering hand: jerky steps in the plane, the press changing.
            for c in &mut v {
                *c = 0.9 * *c + 0.05 * rand();
            }
            let before = p;
            p = [p[0] + v[0], p[1] + v[1], (p[2] + v[2]).clamp(30.0, 40.0)];
            let out = step(&mut b, &mut f, p, 20.0);
            let dx = [p[0] - before[0], p[1] - before[1]];
            let work_mj = -(held[0] * dx[0] + held[1] * dx[1]);
            let hold_mj = 0.5 * k_b * (dx[0] * dx[0] + dx[1] * dx[1]);
            let now_mj = f.friction_energy() * 1e3;
            assert!(
                now_mj <= energy_mj + work_mj + hold_mj + 1e-9,
                "{}, tick {k}: {now_mj} mJ after {energy_mj} mJ, work {work_mj}, hold {hold_mj}",
                S::NAME
            );
            // A slip is where the bristle lost energy to the paper.
            if now_mj < energy_mj + work_mj + hold_mj - 1e-6 {
                slips += 1;
            }
            let fr = out.friction.to_f64();
            energy_mj = now_mj;
            held = [fr[0], fr[1]];
        }
        slips
    }
    for slips in [check::<Fx>(), check::<f64>()] {
        assert!(
            slips > 2_000,
            "the hand made the brush slide on {slips} ticks only"
        );
    }
}

#[test]
fn the_viscous_law_is_the_theses_drag() {
    let mut params = DEFAULT_FORCES;
    params.friction = FrictionLaw::Viscous;
    let mut b = Brush::<f64>::new(presets::LARGE, pose([0.0, 0.0, 35.0], 0.0)).unwrap();
    let mut f = ForceModel::<f64>::new(params).unwrap();
    let mut moved = 0;
    for k in 0..400 {
        let p = [0.05 * k as f64, -0.02 * k as f64, 35.0];
        let out = step(&mut b, &mut f, p, 0.0);
        if k == 0 {
            continue;
        }
        // -w_f (n / N) v, with v in mm per tick = m/s.
        let drag = params.friction_weight as f64 * out.on_paper / b.len() as f64;
        let want = [-drag * 0.05, drag * 0.02];
        assert!(
            (out.friction.x - want[0]).abs() < 1e-12,
            "tick {k}: {out:?}"
        );
        assert!(
            (out.friction.y - want[1]).abs() < 1e-12,
            "tick {k}: {out:?}"
        );
        if drag > 0.0 {
            moved += 1;
        }
    }
    assert!(moved > 300, "{moved} ticks with the brush on the paper");
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
fn passivity_run<S: BrushScalar>(step_mm: f64) -> (f64, f64) {
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
