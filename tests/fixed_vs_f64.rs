//! The device's fixed-point model against the f64 reference on every example stroke and on
//! the stroke file's 永, at the presets' rate (one substep per tick, what the pen runs): every
//! spine mass stays within 5 um of the f64 run at every 1 ms tick of the whole stroke.

use maobi::poses::PoseTrack;
use maobi::strokes::Character;
use maobi_shared::{presets, Brush, Fx};
use maobi_tests::{example_pose_files, workspace_root};

const TOLERANCE_MM: f64 = 5e-3;

#[test]
fn fixed_matches_f64_on_every_example() {
    let files = example_pose_files();
    assert!(
        files.len() >= 4,
        "expected the example strokes, found {files:?}"
    );
    let mut overall = 0.0f64;
    // The example strokes are written for the large brush's 40 mm head (the small one would
    // not reach the paper on them).
    for (name, params) in [("large", &presets::LARGE)] {
        let yong = workspace_root().join("examples/strokes/yong.toml");
        let tracks = files
            .iter()
            .map(|f| PoseTrack::from_path(f).unwrap_or_else(|e| panic!("{e}")))
            .chain([Character::from_path(&yong)
                .and_then(|c| c.track("yong"))
                .unwrap_or_else(|e| panic!("{}: {e}", yong.display()))]);
        for (k_file, track) in tracks.enumerate() {
            let file = files.get(k_file).cloned().unwrap_or_else(|| yong.clone());
            let mut poses = track.resample();
            let first = poses.next().expect("a track has a first pose");
            let mut fixed = Brush::<Fx>::new(*params, first.cast()).unwrap();
            let mut reference = Brush::<f64>::new(*params, first.cast()).unwrap();
            let (mut worst, mut worst_tick, mut worst_mass, mut contact_ticks) = (0.0f64, 0, 0, 0);
            for (k, pose) in poses.enumerate() {
                fixed.tick(pose.cast());
                reference.tick(pose);
                if reference.contacts() > 0 {
                    contact_ticks += 1;
                }
                for (i, (a, b)) in fixed.spine().iter().zip(reference.spine()).enumerate() {
                    let d = (a.cast::<f64>() - *b).norm();
                    if d > worst {
                        (worst, worst_tick, worst_mass) = (d, k + 1, i);
                    }
                }
            }
            let stem = file.file_stem().unwrap().to_string_lossy().into_owned();
            println!(
                "{name:5} {stem:12} {} ticks ({contact_ticks} touching the paper): largest |fixed - f64| = {:.3} um (mass {worst_mass}, tick {worst_tick})",
                track.ticks(),
                worst * 1e3
            );
            assert!(
                contact_ticks > 0,
                "{stem} never touches the paper with {name}"
            );
            assert!(
                worst < TOLERANCE_MM,
                "{name} on {stem}: fixed point is {worst} mm from f64 at tick {worst_tick}, mass {worst_mass}"
            );
            overall = overall.max(worst);
        }
    }
    println!(
        "largest deviation over all strokes and presets: {:.3} um (budget 5 um)",
        overall * 1e3
    );
}
