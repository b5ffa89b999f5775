//! The ink in the ties (`maobi_shared::brush::ink`, the thesis's 3.1.2 suggestion): a
//! layer's tie softens and its damping rises with the layer's ink, by the factors the
//! parameters give, in the pen's fixed point as in f64, and the handle's reaction stays in
//! step with the ties the model integrates.

use maobi_shared::params::ParamId;
use maobi_shared::{presets, Brush, BrushParams, BrushScalar, Fx, ParamError, Pose, Quat, Vec3};

/// The large brush upright, its ferrule 60 mm above the paper: the hair hangs in the air.
fn upright<S: BrushScalar>() -> Pose<S> {
    Pose::new(Vec3::from_f64([0.0, 0.0, 60.0]), Quat::IDENTITY)
}

/// The large brush with every layer at wetness `wet` and the ink's tie factors given (in
/// percent of the dry tie's).
fn brush<S: BrushScalar>(wet: f64, stiffness_wet_pct: u8, damping_wet_pct: u8) -> Brush<S> {
    let mut p: BrushParams = presets::LARGE;
    p.set(ParamId::TieStiffnessWet, stiffness_wet_pct.into())
        .unwrap();
    p.set(ParamId::TieDampingWet, damping_wet_pct.into())
        .unwrap();
    let mut b = Brush::new(p, upright()).unwrap();
    b.dip(S::from_f64(wet));
    b
}

/// The tip's sideways displacement (mm) from the ferrule's vertical.
fn tip_x<S: BrushScalar>(b: &Brush<S>) -> f64 {
    let s = b.spine();
    (s[s.len() - 1] - s[0]).to_f64()[0]
}

/// A push of `force` newtons across the tip, held `ms` ticks: the tip's sideways
/// displacement then, and the handle's reaction along the push.
fn push<S: BrushScalar>(b: &mut Brush<S>, force: f64, ms: usize) -> (f64, f64) {
    b.set_tip_load(Vec3::from_f64([force, 0.0, 0.0]));
    for _ in 0..ms {
        b.tick(upright());
    }
    (tip_x(b), b.handle_reaction()[0])
}

/// A layer's tie, saturated, is the dry one times the stiffness factor; the ties alone hold
/// the brush's shape against a sideways load (the axial springs keep the hair's length), so
/// pushed with a force F the saturated brush bends as the dry one does under F / factor
/// (the bend is far from linear in the force: the hair buckles along its length), and
/// further than the dry one under F. Half loaded, the factor is halfway (linear in the
/// wetness). The handle feels the push itself either way: its reaction sums the same ties.
fn static_push_follows_the_stiffness_factor<S: BrushScalar>() {
    let force = 0.02;
    let pct = presets::TIE_STIFFNESS_WET_PCT;
    let factor = f64::from(pct) / 100.0;
    let half_factor = 0.5 * (1.0 + factor);
    let (dry, dry_reaction) = push(&mut brush::<S>(0.0, pct, 100), force, 800);
    let (wet, wet_reaction) = push(&mut brush::<S>(1.0, pct, 100), force, 800);
    let (half, _) = push(&mut brush::<S>(0.5, pct, 100), force, 800);
    let dry_f = |f: f64| push(&mut brush::<S>(0.0, pct, 100), f, 800).0;
    let (dry_wet_load, dry_half_load) = (dry_f(force / factor), dry_f(force / half_factor));
    // The same brushes with the ink's law switched off bend alike.
    let (plain_dry, _) = push(&mut brush::<S>(0.0, 100, 100), force, 800);
    let (plain_wet, _) = push(&mut brush::<S>(1.0, 100, 100), force, 800);
    println!(
        "{force} N across the tip: dry {dry:.4} mm, saturated {wet:.4} mm (dry under \
         F/{factor}: {dry_wet_load:.4}), half {half:.4} mm (dry under F/{half_factor}: \
         {dry_half_load:.4}); factor 1: {plain_dry:.4} / {plain_wet:.4} mm; handle reaction \
         {dry_reaction:.4} / {wet_reaction:.4} N"
    );
    assert!(dry > 0.5, "the push must bend the brush: {dry} mm");
    assert!(wet > dry * 1.1, "saturated {wet} mm, dry {dry} mm");
    assert!(
        (wet / dry_wet_load - 1.0).abs() < 0.01,
        "saturated under F: {wet} mm, dry under F/{factor}: {dry_wet_load} mm"
    );
    assert!(
        (half / dry_half_load - 1.0).abs() < 0.01,
        "half loaded under F: {half} mm, dry under F/{half_factor}: {dry_half_load} mm"
    );
    assert!(
        (plain_wet / plain_dry - 1.0).abs() < 1e-6,
        "without the law the ink changed the bend: {plain_dry} / {plain_wet}"
    );
    for r in [dry_reaction, wet_reaction] {
        assert!(
            (r / force - 1.0).abs() < 0.02,
            "handle reaction {r} N against a {force} N push: not the model's ties"
        );
    }
}

#[test]
fn a_pushed_saturated_brush_bends_further_by_the_stiffness_factor_fixed_point() {
    static_push_follows_the_stiffness_factor::<Fx>();
}

#[test]
fn a_pushed_saturated_brush_bends_further_by_the_stiffness_factor_f64() {
    static_push_follows_the_stiffness_factor::<f64>();
}

/// Ticks, after the push across the tip is released, until the tip is back within half of
/// its pushed displacement.
fn ticks_to_half_return<S: BrushScalar>(mut b: Brush<S>) -> usize {
    let (pushed, _) = push(&mut b, 0.02, 800);
    b.set_tip_load(Vec3::ZERO);
    (1..=1000)
        .find(|_| {
            b.tick(upright());
            tip_x(&b) < 0.5 * pushed
        })
        .expect("the tip returns")
}

/// With the stiffness the same wet and dry, a saturated brush returns from a push more
/// slowly than a dry one: the ink's viscosity damps the ties. With the damping the same
/// wet and dry too, the two return alike.
#[test]
fn ink_damps_the_return_from_a_push() {
    let damping_wet = presets::TIE_DAMPING_WET_PCT;
    let dry = ticks_to_half_return(brush::<Fx>(0.0, 100, damping_wet));
    let wet = ticks_to_half_return(brush::<Fx>(1.0, 100, damping_wet));
    let heavy = ticks_to_half_return(brush::<Fx>(1.0, 100, 250));
    let plain = ticks_to_half_return(brush::<Fx>(1.0, 100, 100));
    println!(
        "ms to half return after a push: dry {dry}, saturated {wet} (damping {damping_wet}%), \
         saturated with damping 250% {heavy}, saturated without the law {plain}"
    );
    assert_eq!(plain, dry, "without the law the ink changed the return");
    assert!(
        wet > dry,
        "the ink did not slow the return: {dry} -> {wet} ms"
    );
    assert!(
        heavy > wet,
        "more viscous ink did not slow it more: {wet} -> {heavy} ms"
    );
}

/// The presets' brush, loaded against dry, both effects together: it bends further under
/// the same push and takes longer to come back.
#[test]
fn the_presets_loaded_brush_is_softer_and_slower_than_dry() {
    let (s, d) = (presets::TIE_STIFFNESS_WET_PCT, presets::TIE_DAMPING_WET_PCT);
    let (dry, _) = push(&mut brush::<Fx>(0.0, s, d), 0.02, 800);
    let (wet, _) = push(&mut brush::<Fx>(1.0, s, d), 0.02, 800);
    let (dry_back, wet_back) = (
        ticks_to_half_return(brush::<Fx>(0.0, s, d)),
        ticks_to_half_return(brush::<Fx>(1.0, s, d)),
    );
    println!(
        "presets' law: bend dry {dry:.3} / saturated {wet:.3} mm, half return dry {dry_back} / \
         saturated {wet_back} ms"
    );
    assert!(wet > dry && wet_back > dry_back);
}

/// The factors are parameters like the others: named in the error when out of range (the
/// law's directions: ink never stiffens the spring nor thins the damper), and the brush
/// keeps its old value.
#[test]
fn tie_factors_out_of_range_are_refused_by_name() {
    let mut b = brush::<Fx>(
        1.0,
        presets::TIE_STIFFNESS_WET_PCT,
        presets::TIE_DAMPING_WET_PCT,
    );
    let before = *b.params();
    for (id, v) in [
        (ParamId::TieStiffnessWet, 120.0),
        (ParamId::TieStiffnessWet, 5.0),
        (ParamId::TieStiffnessWet, 70.5),
        (ParamId::TieStiffnessWet, f32::NAN),
        (ParamId::TieDampingWet, 50.0),
        (ParamId::TieDampingWet, 300.0),
    ] {
        let e = b.set_param(id, v).unwrap_err();
        println!("{e}");
        assert!(e.to_string().starts_with(id.name()), "{e}");
        assert!(matches!(
            e,
            ParamError::OutOfRange { param, .. }
                | ParamError::NotFinite { param }
                | ParamError::NotWholeNumber { param, .. } if param == id
        ));
        assert_eq!(*b.params(), before);
    }
    assert_eq!(
        ParamId::from_name("tie_stiffness_wet_pct"),
        Some(ParamId::TieStiffnessWet)
    );
    assert_eq!(
        ParamId::from_name("tie_damping_wet_pct"),
        Some(ParamId::TieDampingWet)
    );
    b.set_param(ParamId::TieDampingWet, 200.0).unwrap();
    assert_eq!(b.params().tie_damping_wet_pct, 200);
    assert_eq!(b.params().tie_damping_wet(), 2.0);
}

/// The tip's sideways path over a push across it (300 ms) and its release (300 ms).
fn push_and_release_path<S: BrushScalar>(mut b: Brush<S>) -> Vec<f64> {
    let mut path = Vec::new();
    for load in [0.02, 0.0] {
        b.set_tip_load(Vec3::from_f64([load, 0.0, 0.0]));
        for _ in 0..300 {
            b.tick(upright());
            path.push(tip_x(&b));
        }
    }
    path
}

/// The factors are what the parameters say, over the whole motion: a layer with wetness W
/// moves as a layer of a brush without the law whose tie stiffness and damping are the dry
/// ones times `1 + W (factor - 1)`, for both integrators, in fixed point and in f64.
fn a_loaded_layer_moves_as_a_dry_one_with_the_factored_ties<S: BrushScalar>() {
    let (s, d) = (presets::TIE_STIFFNESS_WET_PCT, presets::TIE_DAMPING_WET_PCT);
    let (sf, df) = (f32::from(s) / 100.0, f32::from(d) / 100.0);
    for integrator in [
        maobi_shared::params::INTEGRATOR_BACKWARD_EULER,
        maobi_shared::params::INTEGRATOR_KANG_CHO,
    ] {
        for wet in [1.0f32, 0.5] {
            let mut loaded = brush::<S>(wet as f64, s, d);
            loaded
                .set_param(ParamId::Integrator, integrator as f32)
                .unwrap();
            let mut dry = brush::<S>(0.0, 100, 100);
            dry.set_param(ParamId::Integrator, integrator as f32)
                .unwrap();
            let k = presets::LARGE.tie_stiffness * (1.0 + wet * (sf - 1.0));
            let c = presets::LARGE.tie_damping * (1.0 + wet * (df - 1.0));
            dry.set_param(ParamId::TieStiffness, k).unwrap();
            dry.set_param(ParamId::TieDamping, c).unwrap();
            let (a, b) = (push_and_release_path(loaded), push_and_release_path(dry));
            let peak = a.iter().fold(0.0f64, |m, x| m.max(x.abs()));
            let worst = a
                .iter()
                .zip(&b)
                .map(|(x, y)| (x - y).abs())
                .fold(0.0, f64::max);
            println!(
                "integrator {integrator}, wetness {wet}: tip path peak {peak:.3} mm, off the dry \
                 brush with k_t {k:.4} N/m, k_dt {c:.4} N s/m by at most {worst:.2e} mm"
            );
            assert!(peak > 1.0, "the push must bend the brush: {peak} mm");
            assert!(worst < 2e-3 * peak, "{worst} mm off over a {peak} mm path");
        }
    }
}

#[test]
fn a_loaded_layer_moves_as_a_dry_one_with_the_factored_ties_fixed_point() {
    a_loaded_layer_moves_as_a_dry_one_with_the_factored_ties::<Fx>();
}

#[test]
fn a_loaded_layer_moves_as_a_dry_one_with_the_factored_ties_f64() {
    a_loaded_layer_moves_as_a_dry_one_with_the_factored_ties::<f64>();
}
