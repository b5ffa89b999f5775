//! What several of the model's tests measure the same way: the press and lift the model
//! tests use for spring-back, and the brush's distance from its hanging shape.
#![allow(dead_code)] // each test binary uses its own part

use maobi_shared::{Brush, BrushParams, BrushScalar, Pose, Quat, Vec3};

/// Milliseconds after the lift at which the spring-back is read.
pub const AFTER_LIFT_MS: [usize; 4] = [50, 100, 200, 500];

/// The handle at (x, y, z) mm, tilted `tilt_deg` about +y (the tip swings toward -x).
pub fn pose_at<S: BrushScalar>(x: f64, y: f64, z: f64, tilt_deg: f64) -> Pose<S> {
    let h = tilt_deg.to_radians() / 2.0;
    Pose::new(
        Vec3::from_f64([x, y, z]),
        Quat::from_f64([h.cos(), 0.0, h.sin(), 0.0]),
    )
}

/// Each mass's distance (mm) from where the hanging shape puts it for the current handle.
pub fn offsets<S: BrushScalar>(b: &Brush<S>) -> impl Iterator<Item = f64> + '_ {
    let h = b.handle().cast::<f64>();
    let seg = b.segment_mm();
    b.spine()
        .iter()
        .enumerate()
        .map(move |(i, s)| (s.cast::<f64>() - (h.pos + h.down().scale(seg * i as f64))).norm())
}

/// The largest of [`offsets`] (mm).
pub fn deviation_from_rest<S: BrushScalar>(b: &Brush<S>) -> f64 {
    offsets(b).fold(0.0, f64::max)
}

/// The model tests' press and lift: slanted 20 degrees, down over 200 ms until the hanging
/// tip would be 10 mm below the paper, held 500 ms, lifted over 100 ms to 5 mm above; then
/// the brush's distance from its hanging shape ([`deviation_from_rest`]) at each of
/// [`AFTER_LIFT_MS`].
pub fn spring_back<S: BrushScalar>(params: BrushParams) -> [f64; 4] {
    let tilt = 20.0f64;
    let reach = params.length_mm as f64 * tilt.to_radians().cos();
    let at = |z: f64| pose_at::<S>(0.0, 0.0, z, tilt);
    let above = at(reach + 5.0);
    let mut b = Brush::new(params, above).unwrap();
    let mut most = 0;
    for k in 1..=200 {
        b.tick(at(reach + 5.0 - 15.0 * k as f64 / 200.0));
        most = most.max(b.contacts());
    }
    for _ in 0..500 {
        b.tick(at(reach - 10.0));
        most = most.max(b.contacts());
    }
    assert!(most >= 3, "the press must put hair on the paper");
    for k in 1..=100 {
        b.tick(at(reach - 10.0 + 15.0 * k as f64 / 100.0));
    }
    let mut t = 0;
    AFTER_LIFT_MS.map(|ms| {
        while t < ms {
            b.tick(above);
            t += 1;
        }
        deviation_from_rest(&b)
    })
}
