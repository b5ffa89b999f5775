//! The three hair types a calligrapher picks between (`presets::WOLF`, `GOAT`, `MIXED`)
//! behave as their hair does, measured through the model rather than read off their
//! parameters: the same push across the tip bends goat hair more than mixed and mixed more
//! than wolf, and after the same press and lift wolf hair is back first.
//!
//! `cargo test --release -p maobi-shared --test hair -- --nocapture` prints the figures.

mod common;
use common::AFTER_LIFT_MS;
use maobi_shared::{presets, Brush, BrushParams, BrushScalar, Fx, Pose, Vec3};

/// The hair types, stiffest first.
const HAIRS: [(&str, BrushParams); 3] = [
    ("wolf", presets::WOLF),
    ("mixed", presets::MIXED),
    ("goat", presets::GOAT),
];

/// The handle at (x, 0, z) mm, tilted `tilt_deg` about +y (the tip swings toward -x).
fn pose<S: BrushScalar>(x: f64, z: f64, tilt_deg: f64) -> Pose<S> {
    common::pose_at(x, 0.0, z, tilt_deg)
}

/// The ferrule-to-tip chord's angle from the hanging axis (degrees) after 0.5 s of each of
/// `loads_n` pushing across the tip of the upright brush in turn. At two substeps per tick:
/// the fixed-point step does not hold 2 N on the free tip in one (`Brush::set_tip_load`),
/// and a static bend is the same at any step.
fn bends(params: BrushParams, loads_n: [f64; 3]) -> [f64; 3] {
    let upright = pose::<Fx>(0.0, 60.0, 0.0);
    let params = BrushParams {
        substeps_per_tick: params.substeps_per_tick.max(2),
        ..params
    };
    let mut b = Brush::new(params, upright).unwrap();
    loads_n.map(|f| {
        b.set_tip_load(Vec3::from_f64([f, 0.0, 0.0]));
        for _ in 0..500 {
            b.tick(upright);
        }
        let s = b.spine();
        let chord = (s[s.len() - 1] - s[0]).to_f64();
        chord[0].atan2(-chord[2]).to_degrees()
    })
}

#[test]
fn every_hair_type_bends_nearly_flat_under_one_to_two_newtons() {
    for (name, params) in HAIRS {
        let [a025, a1, a2] = bends(params, [0.25, 1.0, 2.0]);
        println!("{name}: chord bend 0.25 N {a025:.1} deg, 1 N {a1:.1} deg, 2 N {a2:.1} deg");
        let light = if name == "goat" { 60.0 } else { 50.0 };
        assert!(a025 < light, "{name} too soft: {a025}");
        assert!((70.0..90.0).contains(&a1), "{name} 1 N: {a1}");
        assert!((70.0..90.0).contains(&a2), "{name} 2 N: {a2}");
    }
}

/// The same push across the tip bends goat hair most and wolf hair least, at every load.
#[test]
fn the_same_push_bends_goat_more_than_mixed_more_than_wolf() {
    let loads = [0.25, 0.5, 1.0];
    goat_bends_most("Liang", loads, HAIRS.map(|(_, p)| bends(p, loads)), 2.0);
}

/// Checks (and prints) that each load of `loads` bends goat hair more than mixed and mixed
/// more than wolf by more than `margin_deg`; `bends` are the hair types' in [`HAIRS`]' order.
fn goat_bends_most(model: &str, loads: [f64; 3], bends: [[f64; 3]; 3], margin_deg: f64) {
    let [wolf, mixed, goat] = bends;
    for (k, f) in loads.iter().enumerate() {
        println!(
            "{model}, {f} N across the tip: wolf {:.1} deg, mixed {:.1} deg, goat {:.1} deg",
            wolf[k], mixed[k], goat[k]
        );
        assert!(
            wolf[k] + margin_deg < mixed[k] && mixed[k] + margin_deg < goat[k],
            "{model}, {f} N: wolf {}, mixed {}, goat {}",
            wolf[k],
            mixed[k],
            goat[k]
        );
    }
}

/// After the same press and lift, wolf hair is back nearer its rest shape than mixed, and
/// mixed than goat, at every reading; wolf and mixed are within 0.1 mm of rest after 200 ms
/// like the large brush, goat hair, the slowest, within 0.3 mm then and 0.1 mm after 500 ms.
#[test]
fn after_a_press_wolf_hair_springs_back_first() {
    let [wolf, mixed, goat] = HAIRS.map(|(_, p)| common::spring_back::<Fx>(p));
    for (k, at) in AFTER_LIFT_MS.iter().enumerate() {
        println!(
            "{at} ms after the lift, from rest: wolf {:.4} mm, mixed {:.4} mm, goat {:.4} mm",
            wolf[k], mixed[k], goat[k]
        );
    }
    for k in 0..AFTER_LIFT_MS.len() {
        assert!(
            wolf[k] < mixed[k] && mixed[k] < goat[k],
            "{} ms: wolf {}, mixed {}, goat {}",
            AFTER_LIFT_MS[k],
            wolf[k],
            mixed[k],
            goat[k]
        );
    }
    assert!(
        wolf[2] < 0.1 && mixed[2] < 0.1,
        "200 ms: {wolf:?} {mixed:?}"
    );
    assert!(goat[2] < 0.3 && goat[3] < 0.1, "200 and 500 ms: {goat:?}");
}

/// Baxter & Lin's round head of each hair type (`SpineParams::of_hair`): the chord's bend
/// under each of `loads_n` across the tip, as [`bends`] for Liang's.
fn baxter_lin_bends(params: BrushParams, loads_n: [f64; 3]) -> [f64; 3] {
    use maobi_shared::baxter_lin::brush::BaxterLinBrush;
    let upright = pose::<f64>(0.0, 60.0, 0.0);
    let mut b = BaxterLinBrush::of_preset(&params, upright).unwrap();
    loads_n.map(|f| {
        b.set_tip_load(Vec3::new(f, 0.0, 0.0));
        // Each solve is quasi-static: a few settle the joints' friction.
        for _ in 0..50 {
            b.tick(&upright);
        }
        let c = b.centres();
        let chord = c[c.len() - 1] - c[0];
        chord.x.atan2(-chord.z).to_degrees()
    })
}

/// The hair types in Baxter & Lin's model: the same order as in Liang's (goat bends most,
/// wolf least, at every load), and 1-2 N still bends each 70-90 degrees.
#[test]
fn baxter_and_lins_brush_bends_each_hair_type_in_the_same_order() {
    let loads = [0.25, 1.0, 2.0];
    let [wolf, mixed, goat] = HAIRS.map(|(_, p)| baxter_lin_bends(p, loads));
    goat_bends_most("Baxter & Lin", loads, [wolf, mixed, goat], 1.0);
    for (name, b) in [("wolf", wolf), ("mixed", mixed), ("goat", goat)] {
        assert!((70.0..90.0).contains(&b[1]), "{name} 1 N: {}", b[1]);
        assert!((70.0..90.0).contains(&b[2]), "{name} 2 N: {}", b[2]);
    }
}
