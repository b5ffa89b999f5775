//! Property tests over random handle paths: invariants that must hold for every input.

use maobi_shared::energy::energy;
use maobi_shared::{presets, Brush, BrushParams, BrushScalar, Fx, Pose, Quat, Scalar, Vec3};
use proptest::prelude::*;

fn pose<S: BrushScalar>(p: [f64; 3], tilt_deg: f64, azimuth_deg: f64) -> Pose<S> {
    // Tilt about a horizontal axis at `azimuth` from +y.
    let (h, a) = (tilt_deg.to_radians() / 2.0, azimuth_deg.to_radians());
    Pose::new(
        Vec3::from_f64(p),
        Quat::from_f64([h.cos(), h.sin() * a.sin(), h.sin() * a.cos(), 0.0]),
    )
}

/// A waypoint: position (mm), tilt and azimuth (degrees).
fn waypoint() -> impl Strategy<Value = ([f64; 3], f64, f64)> {
    (
        (-30.0..30.0f64, -30.0..30.0f64, -15.0..60.0f64),
        0.0..60.0f64,
        0.0..360.0f64,
    )
        .prop_map(|((x, y, z), t, a)| ([x, y, z], t, a))
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, .. ProptestConfig::default() })]

    /// The handle may be driven anywhere, even into the paper: after every substep no mass
    /// of either preset is below it.
    #[test]
    fn no_mass_ends_a_substep_below_the_paper(
        path in prop::collection::vec(waypoint(), 2..6),
        small in any::<bool>(),
        ms_per_leg in 20usize..120,
    ) {
        let params = if small { presets::SMALL } else { presets::LARGE };
        let (p0, t0, a0) = path[0];
        let mut b = Brush::<Fx>::new(params, pose(p0, t0, a0)).unwrap();
        let zero = <Fx as Scalar>::ZERO;
        for leg in path.windows(2) {
            let ((pa, ta, aa), (pb, tb, ab)) = (leg[0], leg[1]);
            let steps = ms_per_leg * b.substeps_per_tick();
            for s in 1..=steps {
                let f = s as f64 / steps as f64;
                let p = [0, 1, 2].map(|i| pa[i] + (pb[i] - pa[i]) * f);
                b.substep(pose(p, ta + (tb - ta) * f, aa + (ab - aa) * f));
                for (i, m) in b.spine().iter().enumerate() {
                    prop_assert!(m.z >= zero, "mass {} at z = {:?} after substep {}", i, m.z, s);
                }
            }
            b.end_tick();
        }
    }

    /// A fixed-point brush teleported between poses anywhere in its range and beyond (a
    /// hostile or broken pose stream: jumps of up to 10 m, any orientation, any stiffness the
    /// parameters allow, with any mass, tie and damping) never panics, in any build: the 32-bit chain solve's formats hold
    /// or wrap, and the model's sums saturate. What the brush then does is not judged; that
    /// the next tick runs is.
    #[test]
    fn fixed_point_brush_survives_teleports(
        jumps in prop::collection::vec(
            ((-1e4..1e4f64, -1e4..1e4f64, -1e4..1e4f64), 0.0..180.0f64, 0.0..360.0f64),
            2..8,
        ),
        small in any::<bool>(),
        stiffer in prop_oneof![Just(1.0f32), Just(20.0f32), Just(1000.0f32)],
        mass_g in prop_oneof![Just(None), (0.005..50.0f32).prop_map(Some)],
        tie in prop_oneof![Just(None), (0.01..1.0e6f32).prop_map(Some)],
        damping in prop_oneof![Just(None), (0.0..1.0e4f32).prop_map(Some)],
    ) {
        let base = if small { presets::SMALL } else { presets::LARGE };
        let mut params = BrushParams {
            axial_stiffness: base.axial_stiffness * stiffer,
            ..base
        };
        // Any valid values of the parameters that scale the step's matrix, as a buggy host
        // may send them.
        params.mass_g = mass_g.unwrap_or(params.mass_g);
        params.tie_stiffness = tie.unwrap_or(params.tie_stiffness);
        params.axial_damping = damping.unwrap_or(params.axial_damping);
        let ((x, y, z), t, a) = jumps[0];
        // A brush too stiff for the fixed-point step at its substep rate is refused, not run.
        let made = Brush::<Fx>::new(params, pose([x, y, z], t, a));
        prop_assume!(made.is_ok());
        let Ok(mut b) = made else { unreachable!() };
        for &((x, y, z), t, a) in &jumps {
            for _ in 0..20 {
                b.tick(pose([x, y, z], t, a));
            }
        }
        prop_assert_eq!(b.substeps_done(), 20 * jumps.len() as u64);
    }

    /// Every spring 1000x stiffer than the preset, at the largest substep offered (1 ms, one
    /// substep per tick), handle held still after a random jolt, in the air or pressed into
    /// the paper.
    ///
    /// In the air the kinetic and tie energy never rise above the energy just after the jolt,
    /// and the total falls over every [`WINDOW`] substeps. (The thesis's integrator needs the
    /// exact solve that `JACOBI_LIMIT` switches to: four Jacobi iterations alone blow up at
    /// this stiffness.)
    ///
    /// On the paper the claim is stability, not decay. The thesis unties masses lying on the
    /// paper (3.1.2), and the tie fades back in over `TIE_RAMP_MM` as a mass leaves it. That
    /// makes the tie a position-dependent, non-conservative force: a mass rising through the
    /// ramp re-engages a tie to a skeleton node below the paper, and the energy that tie then
    /// holds, up to `press_energy` (every node's tie at full weight from the paper), was paid
    /// for by no force. So a stiff brush pressed into the paper can settle into a bounded
    /// two-substep cycle: masses a fraction of a millimetre up with their ties engaged, then
    /// back on the paper, as seen on the large brush at 37.5 degrees pressed 11.1 mm without a
    /// jolt (where a bound on the energy after the jolt alone fails). The tie's weight is
    /// explicit in the step (its change with height is not in the Jacobian), and backward
    /// Euler damps that cycle less than the thesis's scheme did, so the bound is 200 times the
    /// energy after the jolt plus `press_energy` (the small brush jolted 9 mm sideways onto a
    /// light press, in the regressions file, comes closest); a runaway, like the one four
    /// Jacobi iterations produce here, exceeds it by orders of magnitude.
    #[test]
    fn stiff_brush_at_the_largest_step_never_gains_energy(
        jolt in (-8.0..8.0f64, -8.0..8.0f64, -8.0..8.0f64),
        tilt in 0.0..50.0f64,
        press in prop_oneof![Just(-20.0), 0.0..12.0f64],
        small in any::<bool>(),
    ) {
        let base = if small { presets::SMALL } else { presets::LARGE };
        let params = BrushParams {
            axial_stiffness: base.axial_stiffness * 1000.0,
            tie_stiffness: base.tie_stiffness * 1000.0,
            substeps_per_tick: 1,
            ..base
        };
        let held = jolt_and_hold(params, jolt, tilt, press, 3000);
        let (start_e, worst, end_e, rise) = (held.start, held.worst, held.end, held.rise);
        if press < 0.0 {
            prop_assert!(rise <= 1e-9 * start_e + 1e-15,
                "energy grew by {:e} J over {} substeps", rise, WINDOW);
            // What may rise for a moment is the stretch of the turning segments (see
            // `WINDOW`), nothing else.
            prop_assert!(held.worst_unstretched <= start_e * (1.0 + 1e-9) + 1e-15,
                "kinetic and tie energy rose from {:e} to {:e} J", start_e, held.worst_unstretched);
            prop_assert!(worst <= 3.0 * start_e + 1e-3,
                "energy rose from {:e} to {:e} J", start_e, worst);
        } else {
            let scale = start_e + held.press;
            prop_assert!(worst <= 200.0 * scale,
                "energy rose from {:e} J (with {:e} J of ties at full weight from the paper) to {:e} J",
                start_e, held.press, worst);
        }
        // In the air it dies away; pressed into the paper it settles at the energy of the
        // pressed shape (ties stretched toward skeleton nodes below the paper).
        if press < 0.0 {
            prop_assert!(end_e <= start_e * 1e-3 + 1e-12,
                "energy did not die away: {:e} -> {:e} J", start_e, end_e);
        }
    }

    /// At the presets' own stiffness and rate, in the air, energy falls over every
    /// [`WINDOW`] substeps, and only the axial springs' share ever rises above the energy
    /// just after the jolt.
    #[test]
    fn preset_brush_loses_energy_on_every_substep(
        jolt in (-8.0..8.0f64, -8.0..8.0f64, -8.0..8.0f64),
        tilt in 0.0..50.0f64,
        small in any::<bool>(),
    ) {
        let params = if small { presets::SMALL } else { presets::LARGE };
        let reach = params.length_mm as f64 * tilt.to_radians().cos();
        let hold = [0.0, 0.0, reach + 20.0];
        let start = [jolt.0, jolt.1, reach + 20.0 + jolt.2];
        let mut b = Brush::<f64>::new(params, pose(start, tilt, 0.0)).unwrap();
        b.substep(pose(hold, tilt, 0.0));
        let start_e = energy(&b).total();
        let mut recent = [start_e; WINDOW];
        for s in 0..5000 {
            b.substep(pose(hold, tilt, 0.0));
            let parts = energy(&b);
            let e = parts.total();
            let before = recent[s % WINDOW];
            prop_assert!(s < WINDOW || e <= before * (1.0 + 1e-9) + 1e-15,
                "energy grew over the {} substeps to substep {}: {:e} -> {:e} J", WINDOW, s, before, e);
            // What may rise for a moment is the stretch of the turning segments (see
            // `WINDOW`), nothing else.
            prop_assert!(parts.kinetic + parts.tie <= start_e * (1.0 + 1e-9) + 1e-15,
                "kinetic and tie energy rose above the energy after the jolt at substep {}: {:e} -> {:e} J",
                s, start_e, parts.kinetic + parts.tie);
            recent[s % WINDOW] = e;
        }
    }
}

/// What [`jolt_and_hold`] saw.
struct Held {
    /// Energy just after the jolt (J).
    start: f64,
    /// Largest energy afterwards.
    worst: f64,
    /// Largest kinetic and tie energy afterwards (the total less the axial springs').
    worst_unstretched: f64,
    /// Energy at the end.
    end: f64,
    /// Largest rise over any [`WINDOW`] substeps.
    rise: f64,
    /// [`press_energy`] just after the jolt.
    press: f64,
}

/// Jolts the handle and holds it for `substeps`.
fn jolt_and_hold(
    params: BrushParams,
    jolt: (f64, f64, f64),
    tilt: f64,
    press: f64,
    substeps: usize,
) -> Held {
    let reach = params.length_mm as f64 * tilt.to_radians().cos();
    let hold = [0.0, 0.0, reach - press];
    let start = [jolt.0, jolt.1, reach - press + jolt.2];
    let mut b = Brush::<f64>::new(params, pose(start, tilt, 0.0)).unwrap();
    b.substep(pose(hold, tilt, 0.0));
    let start_e = energy(&b).total();
    let mut held = Held {
        start: start_e,
        worst: 0.0,
        worst_unstretched: 0.0,
        end: start_e,
        rise: 0.0,
        press: press_energy(&b),
    };
    let mut recent = [start_e; WINDOW];
    for s in 0..substeps {
        b.substep(pose(hold, tilt, 0.0));
        let e = energy(&b);
        let next = e.total();
        held.worst_unstretched = held.worst_unstretched.max(e.kinetic + e.tie);
        let slot = &mut recent[s % WINDOW];
        if s >= WINDOW {
            held.rise = held.rise.max(next - *slot);
        }
        *slot = next;
        held.end = next;
        held.worst = held.worst.max(next);
    }
    held
}

/// The energy is compared across this many substeps (10 ms at the presets' one substep per
/// tick). Backward Euler linearises each spring where the substep starts, so a segment that
/// turns in a substep ends it a little longer than the step predicted (by `L theta^2 / 2` for
/// a turn `theta`): a stiff axial spring can hold slightly more energy after a substep than
/// before, which the following substeps take out again (the axial mode is heavily damped by
/// the step). Over a window the energy falls.
const WINDOW: usize = 10;

/// The energy the ties would hold at full weight if every mass lay on the paper straight
/// above its skeleton node (J): what ties re-engaging as masses leave the paper can add.
fn press_energy(b: &Brush<f64>) -> f64 {
    let kt = b.params().tie_stiffness as f64;
    b.skeleton()[1..]
        .iter()
        .map(|node| {
            let depth_m = node.z.min(0.0) * 1e-3;
            0.5 * kt * depth_m * depth_m
        })
        .sum()
}
