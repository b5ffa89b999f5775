//! The device's fixed-point model against the f64 reference: every preset of
//! `presets::PRESETS`, on every example stroke (the pose files of `examples/poses` and the
//! stroke files of `examples/strokes`), at every substep rate from one per tick (the Black
//! Pill's, whatever the preset asks) up to the preset's own (the QEMU board's and the
//! desktop's): every spine mass stays within [`TOLERANCE_MM`] of the f64 run at every 1 ms
//! tick of the whole stroke, and every stroke puts the brush on the paper. The exceptions,
//! where fixed point departs from `f64` by millimetres, are listed in [`KNOWN_DEPARTURES`].
//!
//! The examples are written for the large brush's head. A preset with another head length
//! writes them with its tip where the large brush's tip would be: the pose files' handle is
//! moved along its own axis by the difference, and the stroke files place their depths for
//! the preset's head (their `head_mm`).
//!
//! `cargo test --release -p maobi-tests --test fixed_vs_f64 -- --nocapture` prints the largest
//! deviation of each preset, rate and stroke.

use maobi_shared::params::ParamId;
use maobi_shared::{presets, Brush, BrushParams, Fx, Pose};
use maobi_tests::example_strokes;

/// The largest distance of any fixed-point spine mass from its f64 twin, for every preset:
/// the fixed-point format's error budget for the spine (docs/figures.md has the measured).
const TOLERANCE_MM: f64 = 5e-3;

/// Preset and stroke where fixed point departs from `f64` by millimetres today: the small
/// brush on `speeds`, a stroke exactly in the plane y = 0. Its tip segment, pressed to about
/// half its rest length on the paper, buckles sideways (a pitchfork: the brush is symmetric
/// about that plane), and which side it takes and when is decided by rounding: both runs'
/// masses leave the plane from about tick 3900, e-folding in about 20 ticks, the `f64` one
/// as far from itself when its handle is turned by 1e-7 rad. A property of the model and
/// the stroke's exact symmetry, not of the format. Held to still depart, so that this list
/// shrinks when it is mended.
const KNOWN_DEPARTURES: [(&str, &str); 1] = [("small", "speeds")];

/// What one run of a stroke measures.
struct Deviation {
    /// The largest |fixed - f64| of any mass at any tick (mm), its tick and mass.
    worst_mm: f64,
    tick: usize,
    mass: usize,
    /// Ticks on which the f64 brush touched the paper.
    contact_ticks: usize,
    /// Substeps the fixed-point solve could not hold (each a restart at rest).
    restarts: u32,
}

fn run(params: BrushParams, poses: &[Pose<f64>]) -> Deviation {
    let (first, rest) = poses.split_first().expect("a stroke has a first pose");
    let mut fixed = Brush::<Fx>::new(params, first.cast()).unwrap();
    let mut reference = Brush::<f64>::new(params, *first).unwrap();
    let mut d = Deviation {
        worst_mm: 0.0,
        tick: 0,
        mass: 0,
        contact_ticks: 0,
        restarts: 0,
    };
    for (k, pose) in rest.iter().enumerate() {
        fixed.tick(pose.cast());
        reference.tick(*pose);
        if reference.contacts() > 0 {
            d.contact_ticks += 1;
        }
        for (i, (a, b)) in fixed.spine().iter().zip(reference.spine()).enumerate() {
            let off = (a.cast::<f64>() - *b).norm();
            if off > d.worst_mm {
                (d.worst_mm, d.tick, d.mass) = (off, k + 1, i);
            }
        }
    }
    d.restarts = fixed.restarts();
    d
}

#[test]
fn fixed_matches_f64_for_every_preset_on_every_example() {
    let mut failures = Vec::new();
    for (preset, params) in presets::PRESETS {
        let strokes = example_strokes(params.length_mm as f64);
        let mut worst_of_preset = 0.0f64;
        for substeps in 1..=params.substeps_per_tick {
            let mut p = *params;
            p.set(ParamId::SubstepsPerTick, substeps as f32).unwrap();
            for stroke in &strokes {
                let d = run(p, &stroke.poses);
                println!(
                    "{preset:5} {substeps} substep(s) {:12} {} ticks ({} touching): largest |fixed - f64| = {:.4} um (mass {}, tick {}), {} restart(s)",
                    stroke.name,
                    stroke.poses.len(),
                    d.contact_ticks,
                    d.worst_mm * 1e3,
                    d.mass,
                    d.tick,
                    d.restarts
                );
                if d.contact_ticks == 0 {
                    failures.push(format!(
                        "{preset} at {substeps} substep(s): {} never touches the paper",
                        stroke.name
                    ));
                }
                let known = KNOWN_DEPARTURES.contains(&(preset, stroke.name.as_str()));
                if known && d.worst_mm < TOLERANCE_MM {
                    failures.push(format!(
                        "{preset} on {} is within {TOLERANCE_MM} mm now: take it off \
                         KNOWN_DEPARTURES",
                        stroke.name
                    ));
                }
                if !known && d.worst_mm >= TOLERANCE_MM {
                    failures.push(format!(
                        "{preset} at {substeps} substep(s) on {}: fixed point is {} mm from f64 \
                         at tick {}, mass {}",
                        stroke.name, d.worst_mm, d.tick, d.mass
                    ));
                }
                if !known {
                    worst_of_preset = worst_of_preset.max(d.worst_mm);
                }
            }
        }
        println!(
            "{preset}: largest deviation over its strokes and rates (known departures aside) {:.4} um (budget {} um)",
            worst_of_preset * 1e3,
            TOLERANCE_MM * 1e3
        );
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
