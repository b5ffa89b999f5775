//! Guided writing on the built-in simulator: the moving point walks the stroke in real time,
//! the guide fades in, pulls toward it within its limit, and lets go when the stroke ends.

use std::sync::Arc;

use maobi::device::builtin::SimCore;
use maobi::device::DeviceCommand;
use maobi::gui::start_hand;
use maobi_shared::force::DEFAULT_FORCES;
use maobi_shared::guide::DEFAULT_GUIDE;

mod common;

#[test]
fn the_simulator_leads_toward_the_moving_point_and_lets_go() {
    // A 30 mm line in 0.5 s, 10 mm above the paper (no brush forces but gravity).
    let track = common::guide_line(0.0, 50.0);
    let mut core = SimCore::new("large", start_hand(44.0)).unwrap();
    core.apply(DeviceCommand::EnableForces(true)).unwrap();
    for _ in 0..600 {
        core.step();
    }
    core.apply(DeviceCommand::Guide(Some(Arc::new(track))))
        .unwrap();
    let weight =
        DEFAULT_FORCES.gravity_weight as f64 * DEFAULT_FORCES.brush_mass_g as f64 * 9.80665e-3;
    let mut last_gain = 0.0;
    let mut ended_at = None;
    for k in 0..1200 {
        let f = core.step();
        let Some(g) = f.guide else {
            ended_at.get_or_insert(k);
            continue;
        };
        assert!(ended_at.is_none(), "the guide came back at tick {k}");
        // The hand stays where it is (the GUI's pointer does not move): the point pulls away.
        let gf = (g.force[0].powi(2) + g.force[1].powi(2) + g.force[2].powi(2)).sqrt();
        assert!(
            gf <= DEFAULT_GUIDE.max_force_n as f64 + 1e-6,
            "tick {k}: {gf} N"
        );
        if g.distance_mm > 1.0 && g.gain > 0.0 {
            assert!(g.force[0] > 0.0, "tick {k}: pulls toward +x: {:?}", g.force);
        }
        if k < 300 {
            assert!(g.gain >= last_gain, "fades in");
        }
        last_gain = g.gain;
        // The guide's force is part of the total the output stage was given.
        assert!((f.force_total[2] - g.force[2] + weight).abs() < 1e-3 || f.depth_mm > 0.0);
    }
    let ended_at = ended_at.expect("the guide lets go after the stroke");
    // 500 ticks of stroke, then the 0.3 s fade-out.
    assert!((750..=850).contains(&ended_at), "ended at tick {ended_at}");
    assert!(!core.guiding());
}
