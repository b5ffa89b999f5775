//! "Stay in the lane" on the built-in pen (`DeviceCommand::Lane`, `guide::Lane` in the device's
//! force loop): no guide force while the ferrule is inside the tube around the stroke's path,
//! a force back toward it outside, in the paper plane; it lets go with a fade; bad input is
//! refused with the reason. The passivity audit of the fixture is `shared/tests/guide.rs`.

use std::sync::Arc;

use maobi::device::builtin::SimCore;
use maobi::device::{BrushFrame, DeviceCommand};
use maobi::gui::start_hand;
use maobi::poses::PoseTrack;
use maobi_shared::guide::DEFAULT_GUIDE;
use maobi_shared::{Pose, Quat, Vec3};

/// A stroke pressed 3 mm along paper x from -20 to 20 mm at y = 0 (the large brush upright:
/// it touches at z = 40).
fn pressed_line() -> PoseTrack {
    let csv = "t,x,y,z,qw,qx,qy,qz\n0,-20,0,37,1,0,0,0\n1,20,0,37,1,0,0,0\n";
    PoseTrack::from_reader("line.csv", csv.as_bytes()).unwrap()
}

fn at(x: f64, y: f64, z: f64) -> Pose<f64> {
    Pose::new(Vec3::new(x, y, z), Quat::IDENTITY)
}

/// Ticks with the hand moving in a straight line from `from` to `to` over `ticks` ticks, then
/// held there `hold` ticks; the frames.
fn walk(
    core: &mut SimCore,
    from: [f64; 3],
    to: [f64; 3],
    ticks: usize,
    hold: usize,
) -> Vec<BrushFrame> {
    let mut out = Vec::new();
    for k in 1..=ticks + hold {
        let f = (k.min(ticks)) as f64 / ticks.max(1) as f64;
        let p = [0, 1, 2].map(|i| from[i] + (to[i] - from[i]) * f);
        out.push(core.step_at(at(p[0], p[1], p[2])));
    }
    out
}

#[test]
fn no_force_inside_the_lane_a_pull_back_outside_and_a_fade_when_let_go() {
    let mut core = SimCore::new("large", start_hand(50.0)).unwrap();
    core.apply(DeviceCommand::EnableForces(true)).unwrap();
    core.step_at(at(0.0, 1.0, 50.0));
    core.apply(DeviceCommand::Lane(Some((Arc::new(pressed_line()), 2.0))))
        .unwrap();
    assert!(core.guiding());

    // Inside (1 mm off the path, in free air above it), through the fade-in and a walk along.
    let inside = walk(&mut core, [0.0, 1.0, 50.0], [10.0, -1.5, 50.0], 600, 100);
    let largest = inside
        .iter()
        .map(|f| f.guide.expect("the lane's guide reports").force)
        .map(|g| g[0].abs().max(g[1].abs()).max(g[2].abs()))
        .fold(0.0, f64::max);
    let gain = inside.last().unwrap().guide.unwrap().gain;
    println!("inside the 2 mm lane: largest guide force {largest:e} N over 700 ticks, gain {gain}");
    assert_eq!(largest, 0.0);
    assert_eq!(gain, 1.0);

    // Out to 6 mm on the +y side: pulled back toward -y, k (6 - 2) mm at rest there.
    let out = walk(&mut core, [10.0, -1.5, 50.0], [10.0, 6.0, 50.0], 200, 100);
    let held = out.last().unwrap().guide.unwrap().force;
    let k_n_per_mm = DEFAULT_GUIDE.stiffness_n_per_m as f64 * 1e-3;
    println!(
        "held 6 mm off the path: guide force {held:?} N (k (d - r) = {} N)",
        k_n_per_mm * 4.0
    );
    assert!((held[1] + k_n_per_mm * 4.0).abs() < 1e-3, "{held:?}");
    assert!(
        held[0].abs() < 1e-6 && held[2].abs() < 1e-9,
        "in the paper plane only: {held:?}"
    );
    for f in &out {
        let g = f.guide.unwrap();
        let y = f.pose.pos.y;
        if y > 2.5 {
            assert!(g.force[1] < 0.0, "at y = {y}: {:?}", g.force);
        }
    }

    // And from the -y side, past the path's end (the pull is toward its nearest point).
    let other = walk(&mut core, [10.0, 6.0, 50.0], [25.0, -5.0, 50.0], 300, 100);
    let held = other.last().unwrap().guide.unwrap().force;
    println!("held at (25, -5), beyond the end at (20, 0): {held:?} N");
    let want = k_n_per_mm * (50f64.sqrt() - 2.0) / 2f64.sqrt();
    assert!(
        (held[0] + want).abs() < 1e-6 && (held[1] - want).abs() < 1e-6,
        "{held:?}"
    );

    // Back inside: nothing from the second tick in.
    let back = walk(&mut core, [25.0, -5.0, 50.0], [5.0, 0.5, 50.0], 300, 50);
    let entered = back
        .iter()
        .position(|f| {
            f.pose.pos.y.abs() <= 2.0 && f.pose.pos.x <= 20.0 && f.guide.unwrap().distance_mm == 0.0
        })
        .expect("the hand comes back inside");
    assert!(back[entered + 1..]
        .iter()
        .all(|f| f.guide.unwrap().force == [0.0; 3]));

    // Let go: it fades out and ends.
    core.apply(DeviceCommand::Lane(None)).unwrap();
    let out = walk(&mut core, [5.0, 0.5, 50.0], [5.0, 8.0, 50.0], 100, 400);
    let ended = out
        .iter()
        .position(|f| f.guide.is_none())
        .expect("the lane lets go");
    println!("let go: the guide ended after {ended} ticks");
    assert!((250..=350).contains(&ended), "{ended}");
    assert!(!core.guiding());
}

#[test]
fn a_lane_is_refused_with_the_reason() {
    let mut core = SimCore::new("large", start_hand(50.0)).unwrap();
    let e = core
        .apply(DeviceCommand::Lane(Some((Arc::new(pressed_line()), 0.1))))
        .unwrap_err()
        .to_string();
    assert!(e.contains("radius 0.1 mm is outside 0.5 ..= 20 mm"), "{e}");
    let lifted = PoseTrack::from_reader(
        "lifted.csv",
        "t,x,y,z,qw,qx,qy,qz\n0,0,0,45,1,0,0,0\n1,20,0,45,1,0,0,0\n".as_bytes(),
    )
    .unwrap();
    let e = core
        .apply(DeviceCommand::Lane(Some((Arc::new(lifted), 2.0))))
        .unwrap_err()
        .to_string();
    assert!(e.contains("never presses the paper"), "{e}");
    assert!(!core.guiding());
}
