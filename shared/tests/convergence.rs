//! The brush's results do not depend on its substep: a sweep of the substep rate in `f64` and in
//! fixed point, against the finest `f64` run, for the default integrator (backward Euler),
//! with the thesis's integrator's table beside it to show what the default changed. Each
//! preset is held to it from its own substep rate up (the springy wolf hair takes two).
//!
//! `cargo test --release -p maobi-shared --test convergence -- --nocapture` prints the tables.

mod common;
use common::AFTER_LIFT_MS;
use maobi_shared::params::{ParamId, INTEGRATOR_BACKWARD_EULER, INTEGRATOR_KANG_CHO};
use maobi_shared::{presets, Brush, BrushParams, BrushScalar, Fx, Pose};

const RATES: [u8; 5] = [1, 2, 5, 25, 100];

/// The handle at (x, 0, z) mm, tilted `tilt_deg` about +y.
fn pose<S: BrushScalar>(x: f64, z: f64, tilt_deg: f64) -> Pose<S> {
    common::pose_at(x, 0.0, z, tilt_deg)
}

/// What one run measures: the largest distance of any mass from the hanging shape at each of
/// [`AFTER_LIFT_MS`] after a 10 mm press and lift (mm), and the tip's distance from it in
/// steady free-air motion at 100 mm/s (mm).
#[derive(Copy, Clone, Debug)]
struct Figures {
    spring_back: [f64; 4],
    moving_tip: f64,
}

fn measure<S: BrushScalar>(params: BrushParams) -> Figures {
    let spring_back = common::spring_back::<S>(params);

    // Free air, upright: the handle speeds up smoothly to 100 mm/s over 100 ms (a half
    // cosine of acceleration), then moves steadily for 900 ms.
    let mut b = Brush::new(params, pose::<S>(0.0, 60.0, 0.0)).unwrap();
    let (ramp, v) = (0.1f64, 100.0f64);
    let x_at = |t: f64| {
        if t < ramp {
            v * (t / 2.0
                - ramp / (2.0 * std::f64::consts::PI) * (std::f64::consts::PI * t / ramp).sin())
        } else {
            v * (t - ramp / 2.0)
        }
    };
    for k in 1..=1000 {
        b.tick(pose(x_at(k as f64 * 1e-3), 60.0, 0.0));
    }
    let moving_tip = common::offsets(&b).last().unwrap_or(0.0);
    Figures {
        spring_back,
        moving_tip,
    }
}

fn with(params: BrushParams, integrator: u8, substeps: u8) -> BrushParams {
    let mut p = params;
    p.set(ParamId::Integrator, integrator as f32).unwrap();
    p.set(ParamId::SubstepsPerTick, substeps as f32).unwrap();
    p
}

/// Prints one integrator's table for `params` and returns its figures by rate, `f64` and
/// fixed point, and the reference (the finest `f64` run).
fn table(
    name: &str,
    params: BrushParams,
    integrator: u8,
) -> (Vec<(u8, Figures, Figures)>, Figures) {
    let rows: Vec<_> = RATES
        .iter()
        .map(|&r| {
            let p = with(params, integrator, r);
            (r, measure::<f64>(p), measure::<Fx>(p))
        })
        .collect();
    let reference = rows.last().map(|r| r.1).expect("rates");
    let label = if integrator == INTEGRATOR_BACKWARD_EULER {
        "backward Euler (default)"
    } else {
        "Kang & Cho (thesis)"
    };
    println!("\n{name}, {label}: distance from the hanging shape (mm)");
    println!(
        "{:>9} {:>6} {:>9} {:>9} {:>9} {:>9} {:>14}",
        "substeps", "format", "50 ms", "100 ms", "200 ms", "500 ms", "tip @100mm/s"
    );
    for (rate, f, x) in &rows {
        for (format, fig) in [("f64", f), ("fixed", x)] {
            println!(
                "{rate:>9} {format:>6} {:>9.4} {:>9.4} {:>9.4} {:>9.4} {:>14.6}",
                fig.spring_back[0],
                fig.spring_back[1],
                fig.spring_back[2],
                fig.spring_back[3],
                fig.moving_tip
            );
        }
    }
    (rows, reference)
}

/// Within 10% or 5 um (whichever is larger) of the reference.
fn close(got: f64, want: f64) -> bool {
    (got - want).abs() <= (0.1 * want.abs()).max(5e-3)
}

/// Within 5% or 1 um of the reference: what backward Euler reaches at one substep per tick
/// (the pen's rate) for a preset that runs at it, with every force of its system in the
/// step, the paper's drag included.
/// The drag taken after the solve instead (as the thesis's step takes it) put the large
/// brush beyond it: a stiff damper split from the springs it holds back.
fn tight(got: f64, want: f64) -> bool {
    (got - want).abs() <= (0.05 * want.abs()).max(1e-3)
}

#[test]
fn backward_euler_converges_in_the_substep_and_the_thesis_scheme_does_not() {
    for (name, params) in presets::PRESETS {
        let (rows, reference) = table(name, *params, INTEGRATOR_BACKWARD_EULER);
        for (rate, f, x) in rows.iter().filter(|r| r.0 >= params.substeps_per_tick) {
            for (format, fig) in [("f64", f), ("fixed", x)] {
                for (k, (&got, &want)) in fig
                    .spring_back
                    .iter()
                    .zip(&reference.spring_back)
                    .enumerate()
                {
                    assert!(
                        close(got, want),
                        "{name} {format} at {rate} substeps, {} ms after the lift: {got} mm \
                         against {want} mm at 100 substeps in f64",
                        AFTER_LIFT_MS[k]
                    );
                    assert!(
                        *rate != 1 || tight(got, want),
                        "{name} {format} at {rate} substeps, {} ms after the lift: {got} mm \
                         against {want} mm at 100 substeps in f64, beyond 5% (is a force \
                         left out of the implicit step?)",
                        AFTER_LIFT_MS[k]
                    );
                }
                assert!(
                    fig.moving_tip <= 5e-3,
                    "{name} {format} at {rate} substeps: the moving tip is {} mm off",
                    fig.moving_tip
                );
            }
        }
        // The thesis's scheme, for comparison: its spring-back depends on the substep.
        let (kc, kc_reference) = table(name, *params, INTEGRATOR_KANG_CHO);
        let one = kc[0].1;
        assert!(
            !close(one.spring_back[0], kc_reference.spring_back[0]),
            "{name}: the thesis's scheme converged at one substep ({} against {})",
            one.spring_back[0],
            kc_reference.spring_back[0]
        );
    }
}
