//! Guided writing on the built-in simulator: the moving point walks the stroke in real time,
//! the guide fades in, pulls toward it within its limit, and lets go when the stroke ends.

use maobi::device::builtin::SimCore;
use maobi::gui::start_hand;
use maobi_shared::force::DEFAULT_FORCES;

mod common;

#[test]
fn the_simulator_leads_toward_the_moving_point_and_lets_go() {
    // A 30 mm line in 0.5 s, 10 mm above the paper (no brush forces but gravity).
    let mut core = SimCore::new("large", start_hand(44.0)).unwrap();
    let weight =
        DEFAULT_FORCES.gravity_weight as f64 * DEFAULT_FORCES.brush_mass_g as f64 * 9.80665e-3;
    common::guide_along_a_line(&mut core, |_, f, g| {
        // The guide's force is part of the total the output stage was given.
        assert!((f.force_total[2] - g.force[2] + weight).abs() < 1e-3 || f.depth_mm > 0.0);
    });
}
