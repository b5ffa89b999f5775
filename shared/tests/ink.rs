//! Ink in the brush: what a dip puts in is what the brush holds plus what it gave to the
//! paper (to rounding, in fixed point and in f64), a stroke written without dipping drains
//! the brush and its wetness with it, a dip refills it, and the pen and the desktop formats
//! agree.

use maobi_shared::{presets, Brush, BrushScalar, Fx, Pose, Quat, Scalar, Vec3};

/// The handle at (x, 0, z) mm, tilted 15 degrees about +y (the tip trails toward -x).
fn pose<S: BrushScalar>(x: f64, z: f64) -> Pose<S> {
    let h = 15f64.to_radians() / 2.0;
    Pose::new(
        Vec3::from_f64([x, 0.0, z]),
        Quat::from_f64([h.cos(), 0.0, h.sin(), 0.0]),
    )
}

/// Writes a stroke of `length_mm` at `speed` mm/s, pressed to z = 33 mm, after settling
/// 0.2 s; returns the brush, the ink deposited tick by tick (per tick, summed over layers)
/// in the scalar's own arithmetic, and the load after the dip.
fn write<S: BrushScalar>(speed: f64, length_mm: f64) -> (Brush<S>, Vec<S>, S) {
    let params = presets::by_name("large").unwrap();
    let mut b = Brush::<S>::new(params, pose(0.0, 45.0)).unwrap();
    b.dip(S::from_f64(0.8));
    let dipped = b.ink_load();
    let mut deposits = Vec::new();
    let mut before = S::ZERO;
    let ticks = 200 + (length_mm / speed * 1000.0) as usize;
    for k in 0..ticks {
        let x = ((k as f64 - 200.0) * 1e-3 * speed).clamp(0.0, length_mm);
        b.tick(pose(x, 33.0));
        let total = b.layers().iter().fold(S::ZERO, |a, l| a + l.deposited);
        deposits.push(total - before);
        before = total;
    }
    (b, deposits, dipped)
}

/// In fixed point each update of a layer's wetness rounds at 2^-32 of what it holds (about
/// 3e-8 ink units for the large brush's belly), three a layer a tick: within 1e-7 of the dip
/// over the stroke.
#[test]
fn ink_is_conserved_in_fixed_point_to_rounding() {
    let (b, deposits, dipped) = write::<Fx>(200.0, 150.0);
    let paper = deposits.iter().fold(Fx::ZERO, |a, &d| a + d);
    let err = (paper + b.ink_load() - dipped).to_f64().abs();
    println!(
        "dipped {dipped}, on paper {paper}, in the brush {}, off by {err:.1e} ink units over {} ticks",
        b.ink_load(),
        deposits.len()
    );
    assert!(paper > Fx::from_f64(10.0), "the stroke gave ink: {paper}");
    assert!(err < 1e-7 * dipped.to_f64(), "{err}");
}

#[test]
fn ink_is_conserved_in_f64_to_rounding() {
    let (b, deposits, dipped) = write::<f64>(200.0, 150.0);
    let paper: f64 = deposits.iter().sum();
    let err = (paper + b.ink_load() - dipped).abs() / dipped;
    println!("dipped {dipped}, on paper {paper}, relative error {err:.1e}");
    assert!(paper > 10.0);
    // The amounts are computed in single precision (as on the pen), each layer's capacity's
    // reciprocal too: each update of a wetness is off by its relative rounding, 6e-8.
    assert!(err < 1e-7, "{err}");
    assert!(b.layers().iter().all(|l| (0.0..=1.0).contains(&l.wetness)));
}

/// Written without dipping, the brush gives less ink per tick at the end of a long stroke
/// than at its start, and its layers' wetness falls; a dip fills them again.
#[test]
fn a_long_stroke_drains_the_brush_and_a_dip_refills_it() {
    let (mut b, deposits, dipped) = write::<Fx>(100.0, 250.0);
    let moving = &deposits[200..deposits.len()];
    let q = moving.len() / 4;
    let mean = |s: &[Fx]| s.iter().map(|d| d.to_f64()).sum::<f64>() / s.len() as f64;
    let (first, last) = (mean(&moving[..q]), mean(&moving[3 * q..]));
    let left = b.ink_load().to_f64() / dipped.to_f64();
    println!(
        "ink per tick: first quarter {first:.4}, last {last:.4}; {:.0}% of the dip left",
        left * 100.0
    );
    assert!(last < 0.7 * first, "{first} -> {last}");
    let wet = |b: &Brush<Fx>| b.layers().iter().map(|l| l.wetness.to_f64()).sum::<f64>();
    let dry = wet(&b);
    b.dip(Fx::from_f64(0.8));
    assert!(wet(&b) > dry + 1.0, "{dry} -> {}", wet(&b));
    assert!((b.ink_load() - dipped).to_f64().abs() < 1e-6);
}

/// The pen (fixed point) and the desktop (f64) give the same ink along the same stroke, to
/// the difference of their arithmetic.
#[test]
fn fixed_and_float_brushes_give_the_same_ink() {
    let (_, fx, _) = write::<Fx>(150.0, 60.0);
    let (_, fl, _) = write::<f64>(150.0, 60.0);
    let total = |d: &[f64]| d.iter().sum::<f64>();
    let fx: Vec<f64> = fx.iter().map(|d| d.to_f64()).collect();
    let (a, b) = (total(&fx), total(&fl));
    println!("ink given: fixed {a:.4}, f64 {b:.4}");
    assert!((a - b).abs() < 0.02 * b, "{a} vs {b}");
}
