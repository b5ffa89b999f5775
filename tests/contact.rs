//! A mass grazing the paper settles on it instead of hopping: the brush's contact with the
//! paper does not chatter at the rate it is stepped.
//!
//! A hop is a tick whose count of masses on the paper differs from the ticks on either side,
//! which agree with each other (on, off, on). The tie's weight grows with a mass's height
//! near the paper (`brush::TIE_RAMP_MM`); with that weight taken where the substep starts, a
//! light mass on the paper was lifted by its springs while untied, pulled back into the paper
//! once tied, and untied again: the small brush at one substep, the pen's rate, hopped on
//! three ticks in four on the paper. The backward-Euler step now takes the weight's growth
//! where the substep ends (`Brush::backward_euler`).
//!
//! Every preset, every example stroke, at one substep (the Black Pill's) and at its own rate,
//! in `f64` and in fixed point: at most [`HOPS_PER_TOUCHING_TICK`] of the ticks on the paper.
//! `cargo test --release -p maobi-tests --test contact -- --nocapture` prints the counts.

use maobi_shared::params::ParamId;
use maobi_shared::{presets, Brush, BrushParams, BrushScalar, Fx, Pose};
use maobi_tests::example_strokes;

/// The most hops a stroke may have, as a fraction of its ticks on the paper. A stroke's
/// contacts change where its masses land and lift, and a mass that lands and leaves on
/// consecutive ticks (a brush sweeping over its tip) counts; chatter makes it most of them.
const HOPS_PER_TOUCHING_TICK: f64 = 0.02;

/// Ticks on the paper and hops of `params` over `poses` in the scalar `S`.
fn hops<S: BrushScalar>(params: BrushParams, poses: &[Pose<f64>]) -> (usize, usize) {
    let (first, rest) = poses.split_first().expect("a stroke has a first pose");
    let mut brush = Brush::<S>::new(params, first.cast()).expect("a preset is a valid brush");
    let contacts: Vec<usize> = rest
        .iter()
        .map(|pose| {
            brush.tick(pose.cast());
            brush.contacts()
        })
        .collect();
    let touching = contacts.iter().filter(|&&c| c > 0).count();
    let hops = contacts
        .windows(3)
        .filter(|w| w[0] == w[2] && w[0] != w[1])
        .count();
    (touching, hops)
}

#[test]
fn a_mass_grazing_the_paper_settles_instead_of_hopping() {
    let mut failures = Vec::new();
    for (preset, params) in presets::PRESETS {
        let strokes = example_strokes(params.length_mm as f64);
        let mut rates = vec![1, params.substeps_per_tick];
        rates.dedup();
        for rate in rates {
            let mut p = *params;
            p.set(ParamId::SubstepsPerTick, rate as f32).unwrap();
            for stroke in &strokes {
                for (format, (touching, hops)) in [
                    ("f64", hops::<f64>(p, &stroke.poses)),
                    ("fixed", hops::<Fx>(p, &stroke.poses)),
                ] {
                    println!(
                        "{preset:5} {rate} substep(s) {format:5} {:10} {hops:4} hops in {touching:5} ticks on the paper",
                        stroke.name
                    );
                    assert!(touching > 0, "{preset} {}: never on the paper", stroke.name);
                    if hops as f64 > HOPS_PER_TOUCHING_TICK * touching as f64 {
                        failures.push(format!(
                            "{preset} {format} at {rate} substep(s) on {}: {hops} hops in {touching} ticks on the paper",
                            stroke.name
                        ));
                    }
                }
            }
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
