//! Baxter & Lin's brush heads and the surface over their spines
//! (`maobi_shared::baxter_lin::{head, skin}`): each shape's rings at rest, the envelope
//! holding every spine's hair, a flat brush's footprint wide across and thin along, and the
//! hair strips' weights (eqs. 16-20).
//!
//! `cargo test -p maobi-shared --test brush_heads -- --nocapture` prints the figures.

use maobi_shared::baxter_lin::head::{Head, HeadShape, SHAPES};
use maobi_shared::baxter_lin::skin::{self, SpineCurve, MAX_SPINES};
use maobi_shared::footprint::Geometry;
use maobi_shared::{Layer, Pose, Quat, Vec3};

const JOINTS: usize = 6;

/// A layer before the skin sets its ring (the ink fields stay as they are).
const BLANK: Layer<f64> = Layer {
    short_axis: Vec3::new(1.0, 0.0, 0.0),
    long_axis: Vec3::new(0.0, 1.0, 0.0),
    long_radius: 0.0,
    short_radius: 0.0,
    wetness: 0.0,
    deposited: 0.0,
};
const LEVELS: usize = 16;

/// Each spine of `head` straight along its rest direction, carried by the handle at `pose`:
/// `JOINTS` joints from root to tip, world mm.
fn rest_spines(head: &Head, pose: &Pose<f64>) -> Vec<[Vec3<f64>; JOINTS]> {
    head.spines()
        .iter()
        .map(|s| {
            core::array::from_fn(|j| {
                let local = s.position
                    + s.direction
                        .scale(s.length_mm * j as f64 / (JOINTS - 1) as f64);
                pose.pos + pose.rot.rotate(local)
            })
        })
        .collect()
}

fn curves<'a>(head: &Head, joints: &'a [[Vec3<f64>; JOINTS]]) -> Vec<SpineCurve<'a>> {
    head.spines()
        .iter()
        .zip(joints)
        .map(|(s, j)| SpineCurve {
            joints: j,
            bundle: s.bundle,
        })
        .collect()
}

fn skinned(head: &Head, pose: &Pose<f64>) -> (Vec<Vec3<f64>>, Vec<Layer<f64>>) {
    let joints = rest_spines(head, pose);
    let spines = curves(head, &joints);
    let mut centers = vec![Vec3::ZERO; LEVELS];
    let mut layers = vec![BLANK; LEVELS];
    assert_eq!(skin::skin(&spines, pose, &mut centers, &mut layers), LEVELS);
    (centers, layers)
}

/// The handle tilted by `deg` about its x axis, ferrule at `pos`.
fn tilted(deg: f64, pos: Vec3<f64>) -> Pose<f64> {
    let h = deg.to_radians() / 2.0;
    Pose::new(pos, Quat::from_f64([h.cos(), h.sin(), 0.0, 0.0]))
}

#[test]
fn every_ring_spans_every_spine_s_hair() {
    // Upright, tilted, and with the spines bent (a tilted handle with spines kept straight
    // down in the world stands for a bend).
    for (name, shape) in SHAPES {
        let head = shape.head();
        for pose in [
            tilted(0.0, Vec3::ZERO),
            tilted(35.0, Vec3::new(3.0, -2.0, 50.0)),
        ] {
            let joints = rest_spines(&head, &pose);
            let spines = curves(&head, &joints);
            let mut centers = [Vec3::ZERO; LEVELS];
            let mut layers = [BLANK; LEVELS];
            skin::skin(&spines, &pose, &mut centers, &mut layers);
            let (mut worst, mut widest) = (0.0f64, 0.0f64);
            for (i, (c, l)) in centers.iter().zip(&layers).enumerate() {
                let mut ring_reach = [0.0f64; 2];
                // Orthonormal axes, across the head.
                assert!((l.long_axis.norm() - 1.0).abs() < 1e-9, "{name} ring {i}");
                assert!((l.short_axis.norm() - 1.0).abs() < 1e-9, "{name} ring {i}");
                assert!(
                    l.long_axis.dot(l.short_axis).abs() < 1e-9,
                    "{name} ring {i}"
                );
                assert!(l.long_radius >= l.short_radius && l.short_radius >= 0.0);
                let distance = head.length_mm() * i as f64 / (LEVELS - 1) as f64;
                for s in &spines {
                    let Some((p, _)) = s.at_distance(distance) else {
                        continue;
                    };
                    let r = s.bundle.radius_at(distance / s.length());
                    // The bundle's section in the ring's plane (what the ring stands for): a
                    // circle of radius r around the spine; its points measured in the ring.
                    let (e1, e2) = (l.long_axis, l.short_axis);
                    let mut reach = [0.0f64; 2];
                    for k in 0..720 {
                        let a = std::f64::consts::TAU * k as f64 / 720.0;
                        let q = p + e1.scale(r * a.cos()) + e2.scale(r * a.sin()) - *c;
                        let u = q.dot(l.long_axis) / l.long_radius.max(1e-12);
                        let v = q.dot(l.short_axis) / l.short_radius.max(1e-12);
                        reach = [reach[0].max(u.abs()), reach[1].max(v.abs())];
                        // A round head's ring holds its bundles whole.
                        if shape == HeadShape::Round {
                            worst = worst.max((u * u + v * v).sqrt());
                        }
                    }
                    // No hair beyond the ring along either axis.
                    widest = widest.max(reach[0]).max(reach[1]);
                    ring_reach[0] = ring_reach[0].max(reach[0]);
                    ring_reach[1] = ring_reach[1].max(reach[1]);
                }
                // A row's hair reaches the ring along each axis: the ring is as wide and as
                // thick as the hair, no more. A round head's ring is the circle its bundles
                // touch (below).
                if shape != HeadShape::Round {
                    assert!(
                        ring_reach[0] > 0.9999 && ring_reach[1] > 0.9999,
                        "{name} ring {i}: {ring_reach:?}"
                    );
                }
            }
            let tilt = 2.0 * pose.rot.to_f64()[0].acos().to_degrees();
            println!(
                "{name:8} tilt {tilt:>4.1}: hair reaches {widest:.4} of its ring along an axis"
            );
            if shape == HeadShape::Round {
                println!(
                    "{name:8} tilt {tilt:>4.1}: the farthest hair point at {worst:.4} of its ring"
                );
            }
            // The round head's ring spines lean in, so a spine's point at a level's distance
            // lies a little off the ring's plane: a thousandth of slack.
            assert!(widest <= 1.001, "{name}: hair beyond its ring ({widest})");
            assert!(worst <= 1.001, "{name}: hair outside its ring ({worst})");
            if shape == HeadShape::Round {
                assert!(
                    worst >= 0.999,
                    "{name}: no hair touches its rings ({worst})"
                );
            }
        }
    }
}

#[test]
fn each_shape_has_its_cross_section() {
    let upright = tilted(0.0, Vec3::new(0.0, 0.0, 60.0));
    println!("shape    level  long mm  short mm  long axis");
    let mut table = Vec::new();
    for (name, shape) in SHAPES {
        let head = shape.head();
        let (centers, layers) = skinned(&head, &upright);
        for i in [0, LEVELS / 3, 2 * LEVELS / 3, LEVELS - 1] {
            let l = &layers[i];
            println!(
                "{name:8} {i:>5}  {:>7.3}  {:>8.3}  ({:+.2}, {:+.2}, {:+.2})",
                l.long_radius, l.short_radius, l.long_axis.x, l.long_axis.y, l.long_axis.z
            );
            // Every ring is centred on the handle's axis (the heads are symmetric).
            assert!(
                centers[i].x.abs() < 1e-9 && centers[i].y.abs() < 1e-9,
                "{name} {i}"
            );
        }
        table.push((shape, layers));
    }
    let ratio = |l: &Layer<f64>| l.long_radius / l.short_radius;
    for (shape, layers) in &table {
        match shape {
            HeadShape::Round => {
                // A circle as wide as the head, down to its point.
                assert!((layers[0].long_radius - 6.0).abs() < 1e-6);
                for l in layers.iter() {
                    assert!(
                        ratio(l) < 1.12,
                        "round ring {} x {}",
                        l.long_radius,
                        l.short_radius
                    );
                }
                assert!(layers[LEVELS - 1].long_radius < 0.2);
            }
            HeadShape::Flat => {
                // 12 x 3 mm at the ferrule, its width along the handle's y axis, to the end.
                assert!((layers[0].long_radius - 6.0).abs() < 1e-6);
                assert!((layers[0].short_radius - 1.5).abs() < 1e-6);
                for l in layers.iter() {
                    assert!(l.long_axis.y.abs() > 0.999);
                    assert!(ratio(l) > 3.9);
                }
            }
            HeadShape::Filbert => {
                // Its end narrower than the flat's: the oval.
                let flat_end = table
                    .iter()
                    .find(|(s, _)| *s == HeadShape::Flat)
                    .map(|(_, l)| l[LEVELS - 1].long_radius)
                    .unwrap();
                assert!(layers[LEVELS - 1].long_radius < 0.5 * flat_end);
            }
            HeadShape::Fan => {
                // Wider with every level as the hair spreads.
                for w in layers.windows(2) {
                    assert!(w[1].long_radius > w[0].long_radius);
                }
                assert!(layers[LEVELS - 1].long_radius > 15.0);
            }
        }
    }
}

/// The footprint's extent along x and along y (mm) of the head lowered onto the paper until
/// its longest spine's tip is `press` below the paper's surface.
fn footprint_extent(head: &Head, yaw_deg: f64, press: f64) -> (f64, f64) {
    let h = yaw_deg.to_radians() / 2.0;
    let pose = Pose::new(
        Vec3::new(0.0, 0.0, head.length_mm() - press),
        Quat::from_f64([h.cos(), 0.0, 0.0, h.sin()]),
    );
    let (centers, layers) = skinned(head, &pose);
    let geometry = Geometry {
        spine: &centers,
        layers: &layers,
        ring_nodes: 16,
        eps: 0.1,
    };
    let (mut lo, mut hi) = ([f64::MAX; 2], [f64::MIN; 2]);
    geometry.for_each_polygon(|_, poly| {
        for p in poly {
            lo = [lo[0].min(p.x), lo[1].min(p.y)];
            hi = [hi[0].max(p.x), hi[1].max(p.y)];
        }
    });
    (hi[0] - lo[0], hi[1] - lo[1])
}

#[test]
fn a_flat_brush_s_footprint_is_wide_across_and_thin_along() {
    // The straight head stood on the paper 2 mm deep (the shape the spine solver will bend
    // is the next step; this is the skin's part): the footprint is the cut through the
    // rings near the paper.
    let flat = HeadShape::Flat.head();
    let (x, y) = footprint_extent(&flat, 0.0, 2.0);
    let (xr, yr) = footprint_extent(&flat, 90.0, 2.0);
    let round = HeadShape::Round.head();
    let (rx, ry) = footprint_extent(&round, 0.0, 2.0);
    println!("flat: {x:.2} mm along x, {y:.2} mm along y; turned 90 degrees: {xr:.2} x {yr:.2}");
    println!("round: {rx:.2} x {ry:.2} mm");
    assert!(y / x > 3.0, "flat {x} x {y}");
    assert!(xr / yr > 3.0, "turned flat {xr} x {yr}");
    assert!((rx / ry - 1.0).abs() < 0.1, "round {rx} x {ry}");
}

#[test]
fn strip_weights_follow_eqs_17_to_20() {
    for (name, shape) in SHAPES {
        let head = shape.head();
        let roots: Vec<Vec3<f64>> = head.spines().iter().map(|s| s.position).collect();
        // Strip roots inside the spines' hull: a deterministic scatter.
        let mut seed = 0x9e37_79b9_7f4a_7c15_u64;
        let mut next = || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut checked = 0;
        for _ in 0..500 {
            // A convex combination of two or three spine roots: inside the hull.
            let (a, b, c) = (next(), next(), next());
            let k = roots.len();
            let pick = |u: f64| roots[((u * k as f64) as usize).min(k - 1)];
            let (wa, wb) = (next(), next());
            let (wa, wb) = if wa + wb > 1.0 {
                (1.0 - wa, 1.0 - wb)
            } else {
                (wa, wb)
            };
            let root = pick(a).scale(wa) + pick(b).scale(wb) + pick(c).scale(1.0 - wa - wb);
            let mut w = [0.0; MAX_SPINES];
            skin::strip_weights(root, &roots, &mut w);
            let sum: f64 = w.iter().sum();
            assert!((sum - 1.0).abs() < 1e-9, "{name}: weights sum to {sum}");
            assert!(w.iter().all(|w| *w >= 0.0), "{name}: {w:?}");
            let at = roots
                .iter()
                .zip(&w)
                .fold(Vec3::ZERO, |acc, (r, w)| acc + r.scale(*w));
            assert!(
                (at - root).norm() < 1e-6,
                "{name}: root {root:?} interpolated at {at:?}"
            );
            // The nearest spine weighs at least as much as the farthest.
            let d = |i: usize| (roots[i] - root).norm();
            let near = (0..k).min_by(|&i, &j| d(i).total_cmp(&d(j))).unwrap();
            let far = (0..k).max_by(|&i, &j| d(i).total_cmp(&d(j))).unwrap();
            assert!(w[near] >= w[far], "{name}: {w:?}");
            checked += 1;
        }
        // On a spine's root: that spine alone.
        let mut w = [0.0; MAX_SPINES];
        skin::strip_weights(roots[1], &roots, &mut w);
        assert_eq!(w[1], 1.0);
        println!("{name}: {checked} strip roots, weights non-negative, summing to one, each root reproduced");
    }
}

#[test]
fn a_strip_between_two_spines_runs_between_them() {
    // Two parallel spines 4 mm apart; a strip rooted a quarter of the way follows them at a
    // quarter of the way, from root to tip (eq. 16).
    let a = [Vec3::new(0.0, 0.0, 0.0), Vec3::new(0.0, 0.0, -10.0)];
    let b = [Vec3::new(0.0, 4.0, 0.0), Vec3::new(0.0, 4.0, -10.0)];
    let bundle = HeadShape::Flat.head().spines()[0].bundle;
    let spines = [
        SpineCurve { joints: &a, bundle },
        SpineCurve { joints: &b, bundle },
    ];
    let mut w = [0.0; 2];
    skin::strip_weights(Vec3::new(0.0, 1.0, 0.0), &[a[0], b[0]], &mut w);
    for s in [0.0, 0.5, 1.0] {
        let p = skin::strip_point(&spines, &w, s);
        assert!(
            (p - Vec3::new(0.0, 1.0, -10.0 * s)).norm() < 1e-9,
            "{p:?} at {s}"
        );
    }
}

#[test]
fn an_unknown_shape_lists_the_shapes() {
    let err = HeadShape::from_name("mop").unwrap_err();
    assert_eq!(
        err.to_string(),
        "unknown brush shape `mop`; valid shapes: round, flat, filbert, fan"
    );
    for (name, shape) in SHAPES {
        assert_eq!(HeadShape::from_name(name), Ok(shape));
        assert_eq!(shape.name(), name);
    }
}
