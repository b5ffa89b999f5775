//! Guided writing against the simulated hand: the device leads a relaxed hand along a
//! stroke, and a hand that resists never gets more than the limits, with the passivity audit
//! of `tests/passivity.rs` extended by the energy the moving point supplies.
//!
//! The loop is the firmware's: the fixed-point brush at the stylus's pose, the force model,
//! the guide toward the stroke's moving point, their sum through the Phantom Omni's output
//! stage (credited with the guide's source energy), held over the tick on the hand.

use maobi_shared::force::{DeviceLimits, ForceModel, OutputStage, DEFAULT_FORCES, PHANTOM_OMNI};
use maobi_shared::force_loop::stored_energy;
use maobi_shared::guide::{Guide, DEFAULT_GUIDE};
use maobi_shared::hand::{HandParams, Script, SimHand};
use maobi_shared::stroke::orient::from_tilt_azimuth;
use maobi_shared::stroke::{Keyframe, Stroke};
use maobi_shared::{presets, Brush, Fx, Pose, Quat, Scalar, Vec3};

/// A pressed horizontal stroke for the large brush (40 mm head, z = 40 touches the paper
/// with the brush straight down): in at 3 mm above, pressed 5 mm along 60 mm, out.
fn stroke() -> Stroke {
    let q = from_tilt_azimuth(0.0, 0.0, 0.0);
    let key = |x: f64, y: f64, z: f64, t: f64| Keyframe {
        pos: [x, y, z],
        rot: q,
        t: Some(t),
    };
    let keys = [
        key(-32.0, 0.0, 43.0, 0.0),
        key(-30.0, 0.0, 36.0, 0.3),
        key(0.0, 1.0, 35.0, 0.8),
        key(28.0, 2.0, 36.0, 1.3),
        key(30.0, 2.0, 43.0, 1.6),
    ];
    Stroke::new(&keys, &[], &[], 60.0).unwrap()
}

struct Run {
    /// Distance from the moving point while the stroke plays at full gain (mm).
    rms_mm: f64,
    max_mm: f64,
    /// The same in the paper plane (the stroke's shape; depth is also the brush pushing back).
    rms_xy_mm: f64,
    max_xy_mm: f64,
    peak_cmd: f64,
    peak_guide: f64,
    worst_violation: f64,
    sourced_j: f64,
}

/// Ticks the loop: `hand_target(k, hand)` gives the hand's own target (and push) each tick;
/// the guide holds the stroke's start for the fade-in, plays it, holds its end and fades out,
/// `cycles` times over.
fn run(
    hand_params: HandParams,
    cycles: usize,
    mut hand_target: impl FnMut(usize, &SimHand) -> ([f64; 3], [f64; 3]),
    limits: DeviceLimits,
) -> Run {
    let s = stroke();
    let (t0, t1) = s.domain();
    let fade = (DEFAULT_GUIDE.fade_s as f64 * 1e3) as usize + 50;
    let play = ((t1 - t0) * 1e3).round() as usize;
    let cycle = fade + play + fade;
    let (p0, q0) = s.pose_at(t0);
    let rot = Quat::from_f64(q0);
    let mut brush = Brush::<Fx>::new(presets::LARGE, Pose::new(Vec3::from_f64(p0), rot)).unwrap();
    let mut model = ForceModel::<Fx>::new(DEFAULT_FORCES).unwrap();
    let mut stage = OutputStage::<Fx>::new(limits).unwrap();
    stage.enable();
    let mut guide = Guide::<Fx>::new(DEFAULT_GUIDE).unwrap();
    let mut hand = SimHand::new(hand_params, p0);

    let mut cmd = [0.0; 3];
    let mut last_hand = Vec3::<Fx>::from_f64(p0);
    let mut last_anchor = Vec3::<Fx>::from_f64(p0);
    let mut sourced = 0.0;
    let mut best = f64::MIN;
    let (mut sum2, mut n, mut max_mm) = (0.0, 0usize, 0.0f64);
    let (mut sum2_xy, mut max_xy) = (0.0, 0.0f64);
    let mut r = Run {
        rms_mm: 0.0,
        max_mm: 0.0,
        rms_xy_mm: 0.0,
        max_xy_mm: 0.0,
        peak_cmd: 0.0,
        peak_guide: 0.0,
        worst_violation: 0.0,
        sourced_j: 0.0,
    };
    for k in 0..cycles * cycle {
        let phase = k % cycle;
        if phase == 0 {
            guide.start();
        }
        if phase == fade + play {
            guide.stop();
        }
        let t = t0 + (phase.saturating_sub(fade)).min(play) as f64 * 1e-3;
        let (a, _) = s.pose_at(t);
        let anchor = Vec3::<Fx>::from_f64(a);

        let (target, push) = hand_target(k, &hand);
        hand.tick_with_push(target, cmd, push);
        let x = hand.stylus();
        let p = Vec3::<Fx>::from_f64(x);
        brush.tick(Pose::new(p, rot));
        let forces = model.tick(&brush, p);
        let g = guide.tick(anchor, anchor - last_anchor, p, p - last_hand);
        let c = stage.apply_with_source(forces.total + g.force, p - last_hand, g.source_mj);
        sourced += g.source_mj.to_f64() * 1e-3;
        last_hand = p;
        last_anchor = anchor;
        cmd = c.to_f64();
        let norm = |v: [f64; 3]| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        r.peak_cmd = r.peak_cmd.max(norm(cmd));
        r.peak_guide = r.peak_guide.max(norm(g.force.to_f64()));
        if phase >= fade && phase < fade + play {
            let d = g.distance_mm.to_f64();
            sum2 += d * d;
            n += 1;
            max_mm = max_mm.max(d);
            let dxy2 = (a[0] - x[0]).powi(2) + (a[1] - x[1]).powi(2);
            sum2_xy += dxy2;
            max_xy = max_xy.max(dxy2.sqrt());
        }

        // The audit: W_in + sourced >= E(t1) - E(t0) - tol over every window.
        let stored = hand.stylus_kinetic_energy()
            + stored_energy(&brush, &model, p)
            + guide.stored_energy(anchor, p);
        if k < 600 {
            continue; // the stage's own ramp-in, as in tests/passivity.rs
        }
        let phi = hand.energy_in() + sourced - stored;
        best = best.max(phi);
        r.worst_violation = r.worst_violation.max(best - phi);
    }
    r.rms_mm = (sum2 / n.max(1) as f64).sqrt();
    r.max_mm = max_mm;
    r.rms_xy_mm = (sum2_xy / n.max(1) as f64).sqrt();
    r.max_xy_mm = max_xy;
    r.sourced_j = sourced;
    r
}

/// The stated guidance error for a relaxed hand, in the paper plane.
const XY_RMS_MM: f64 = 2.5;
const XY_MAX_MM: f64 = 5.0;

/// Same tolerance as the passivity audit of the force path alone.
const TOLERANCE_J: f64 = 2e-3;

#[test]
fn a_relaxed_hand_is_led_along_the_stroke() {
    // The relaxed hand has no will of its own: its muscles only damp (target = itself).
    let r = run(
        HandParams::RELAXED,
        1,
        |_, h| (h.hand(), [0.0; 3]),
        PHANTOM_OMNI,
    );
    println!(
        "relaxed: in the paper plane {:.2} mm RMS, {:.2} mm at most from the moving point; \
         in 3D {:.2} mm RMS, {:.2} mm at most (the brush pushes back on the press); peak \
         command {:.3} N, guide {:.3} N; audit {:.2e} J (tolerance {TOLERANCE_J:e}); the \
         stroke supplied {:.4} J",
        r.rms_xy_mm,
        r.max_xy_mm,
        r.rms_mm,
        r.max_mm,
        r.peak_cmd,
        r.peak_guide,
        r.worst_violation,
        r.sourced_j
    );
    assert!(
        r.rms_xy_mm < XY_RMS_MM,
        "led within {XY_RMS_MM} mm RMS: {:.2}",
        r.rms_xy_mm
    );
    assert!(
        r.max_xy_mm < XY_MAX_MM,
        "and {XY_MAX_MM} mm at most: {:.2}",
        r.max_xy_mm
    );
    assert!(
        r.rms_mm < 5.0 && r.max_mm < 8.0,
        "3D: {:.2} / {:.2}",
        r.rms_mm,
        r.max_mm
    );
    assert!(r.peak_cmd <= PHANTOM_OMNI.peak_n as f64 + 1e-6);
    assert!(
        r.worst_violation <= TOLERANCE_J,
        "{:e} J",
        r.worst_violation
    );
}

#[test]
fn a_resisting_hand_gets_no_more_than_the_limits_and_the_audit_holds() {
    // A writer with a mind of its own: the random presses, drags, lifts and bumps of the
    // passivity audit, around the stroke, while the guide pulls along it. Limits raised as
    // in tests/passivity.rs so the audit's energy describes what the hand felt; the guide's
    // own clamp still holds.
    let start = stroke().pose_at(0.0).0;
    let mut script = Script::new(23, start, (30.0, 48.0));
    script.xy_range = 30.0;
    let big = DeviceLimits {
        peak_n: 20.0,
        continuous_n: 20.0,
        ..PHANTOM_OMNI
    };
    let r = run(HandParams::WRITER, 60, |_, _| script.tick(), big);
    println!(
        "resisting: {:.1} mm RMS from the moving point; peak command {:.3} N, guide {:.3} N; \
         largest energy created over any window {:.2e} J (tolerance {TOLERANCE_J:e})",
        r.rms_mm, r.peak_cmd, r.peak_guide, r.worst_violation
    );
    assert!(r.rms_mm > 3.0, "the hand did resist: {:.1} mm", r.rms_mm);
    assert!(r.peak_guide <= DEFAULT_GUIDE.max_force_n as f64 + 1e-6);
    assert!(
        r.worst_violation <= TOLERANCE_J,
        "{:e} J",
        r.worst_violation
    );

    // With the Omni's real limits, the command never exceeds them.
    let mut script = Script::new(29, start, (30.0, 48.0));
    script.xy_range = 30.0;
    let r = run(HandParams::WRITER, 20, |_, _| script.tick(), PHANTOM_OMNI);
    println!("resisting, Omni limits: peak command {:.3} N", r.peak_cmd);
    assert!(r.peak_cmd <= PHANTOM_OMNI.peak_n as f64 + 1e-6);
}

/// "Stay in the lane" (`guide::Lane`) on the firmware's loop: the stroke's path in the paper
/// plane as the fixture's one piece (every millimetre of it), a writer's random presses,
/// drags and lifts around it. Returns (ticks inside the tube after the fade-in and the
/// largest guide force on them, ticks well outside and the smallest share of the force
/// pointing back toward the path on them, the audit's worst violation, the energy the wall
/// point's motion was credited with). A tick inside counts from the second in a row: on the
/// tick the hand enters, the damper still takes the step it made from the wall.
fn lane_run(seed: u64, radius_mm: f64, ticks: usize) -> (usize, f64, usize, f64, f64, f64) {
    use maobi_shared::guide::{GuideInput, GuideStream, Lane};
    let s = stroke();
    let (t0, t1) = s.domain();
    let path: Vec<[f64; 2]> = (0..=((t1 - t0) * 1e3) as usize)
        .map(|k| s.pose_at(t0 + k as f64 * 1e-3).0)
        .filter(|p| p[2] <= 40.0)
        .map(|p| [p[0], p[1]])
        .collect();
    let mut lane = Lane::new(vec![path], radius_mm);
    let (p0, q0) = s.pose_at(t0);
    let rot = Quat::from_f64(q0);
    let mut brush = Brush::<Fx>::new(presets::LARGE, Pose::new(Vec3::from_f64(p0), rot)).unwrap();
    let mut model = ForceModel::<Fx>::new(DEFAULT_FORCES).unwrap();
    let big = DeviceLimits {
        peak_n: 20.0,
        continuous_n: 20.0,
        ..PHANTOM_OMNI
    };
    let mut stage = OutputStage::<Fx>::new(big).unwrap();
    stage.enable();
    let mut stream = GuideStream::<Fx>::new(DEFAULT_GUIDE).unwrap();
    let mut hand = SimHand::new(HandParams::WRITER, p0);
    let mut script = Script::new(seed, p0, (30.0, 48.0));
    script.xy_range = 20.0;
    let mut cmd = [0.0; 3];
    let mut last_hand = Vec3::<Fx>::from_f64(p0);
    let (mut sourced, mut best, mut worst) = (0.0, f64::MIN, 0.0f64);
    let (mut inside, mut inside_max) = (0usize, 0.0f64);
    let (mut outside, mut outside_min) = (0usize, f64::INFINITY);
    let fade = (DEFAULT_GUIDE.fade_s as f64 * 1e3) as usize;
    let mut was_inside = false;
    for k in 0..ticks {
        let (target, push) = script.tick();
        hand.tick_with_push(target, cmd, push);
        let x = hand.stylus();
        let p = Vec3::<Fx>::from_f64(x);
        brush.tick(Pose::new(p, rot));
        let forces = model.tick(&brush, p);
        let sample: Option<GuideInput<Fx>> = lane.next_sample(Some(x), &stream);
        let g = stream.tick(sample, p, p - last_hand);
        let c = stage.apply_with_source(forces.total + g.force, p - last_hand, g.source_mj);
        sourced += g.source_mj.to_f64() * 1e-3;
        last_hand = p;
        cmd = c.to_f64();
        let f = g.force.to_f64();
        let fn_ = (f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sqrt();
        let (near, d) = lane.nearest([x[0], x[1]]).unwrap();
        let now_inside = d <= radius_mm;
        if k > fade {
            if now_inside && was_inside {
                inside += 1;
                inside_max = inside_max.max(fn_);
            } else if d > radius_mm + 1.0 {
                outside += 1;
                // The share of the force pointing back toward the path, in the paper plane.
                let to = [near[0] - x[0], near[1] - x[1]];
                let back = (f[0] * to[0] + f[1] * to[1]) / (fn_.max(1e-12) * d);
                outside_min = outside_min.min(back);
            }
        }
        was_inside = now_inside;
        let stored = hand.stylus_kinetic_energy()
            + stored_energy(&brush, &model, p)
            + stream
                .guide()
                .stored_energy(stream.anchor().unwrap_or(p), p);
        if k < 600 {
            continue;
        }
        let phi = hand.energy_in() + sourced - stored;
        best = best.max(phi);
        worst = worst.max(best - phi);
    }
    (inside, inside_max, outside, outside_min, worst, sourced)
}

#[test]
fn the_lane_is_force_free_inside_restores_outside_and_passes_the_audit() {
    let radius = 2.0;
    let (inside, inside_max, outside, outside_min, worst, sourced) = lane_run(31, radius, 30_000);
    println!(
        "lane, {radius} mm: {inside} ticks inside the tube, largest guide force there {inside_max:e} N; \
         {outside} ticks more than 1 mm outside, the force's smallest share back toward the path \
         {outside_min:.3}; largest energy created over any window {worst:.2e} J (tolerance \
         {TOLERANCE_J:e}); the wall point credited {sourced:.4} J"
    );
    assert!(inside > 1000 && outside > 1000, "{inside} / {outside}");
    assert_eq!(inside_max, 0.0, "no force at all inside the tube");
    assert!(outside_min > 0.5, "restoring outside: {outside_min}");
    assert!(worst <= TOLERANCE_J, "{worst:e} J");
}
