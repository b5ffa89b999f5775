//! Writes the example pose files in `examples/poses/` at the workspace root.
//!
//! `cargo run -p maobi --example make_poses`
//!
//! Every file samples the handle at 100 Hz from t = 0. Positions are the ferrule's (mm), the
//! large brush (40 mm head) touches the paper with its ferrule at z = 40 cos(tilt). Motions are
//! eased with smoothstep so the hand has no velocity jumps except where a file says so.
//! "Tilt" leans the brush so its tip trails the motion, as a dragged brush does: the handle's
//! top leans toward the direction of travel.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Rows per second.
const RATE_HZ: f64 = 100.0;
/// Head length of the large brush (mm).
const HEAD_MM: f64 = 40.0;

/// One sample: time, ferrule position, unit quaternion (w, x, y, z).
struct Sample {
    t: f64,
    pos: [f64; 3],
    rot: [f64; 4],
}

/// The orientation that leans the brush by `tilt_deg` so that its tip points toward the
/// paper direction `toward` (x, y; need not be unit). Identity = straight down.
fn lean(tilt_deg: f64, toward: [f64; 2]) -> [f64; 4] {
    let n = (toward[0] * toward[0] + toward[1] * toward[1]).sqrt();
    if tilt_deg == 0.0 || n == 0.0 {
        return [1.0, 0.0, 0.0, 0.0];
    }
    let (dx, dy) = (toward[0] / n, toward[1] / n);
    let half = tilt_deg.to_radians() / 2.0;
    // Rotating -z about the paper axis (dy, -dx) by the tilt swings the tip toward (dx, dy).
    [half.cos(), half.sin() * dy, -half.sin() * dx, 0.0]
}

/// Ferrule height for the tip to be pressed `depth` mm into the paper (negative: above it)
/// with the brush leaning by `tilt_deg`.
fn z_for_depth(depth: f64, tilt_deg: f64) -> f64 {
    HEAD_MM * tilt_deg.to_radians().cos() - depth
}

fn smoothstep(u: f64) -> f64 {
    let u = u.clamp(0.0, 1.0);
    u * u * (3.0 - 2.0 * u)
}

fn lerp(a: f64, b: f64, u: f64) -> f64 {
    a + (b - a) * u
}

/// Samples `f(t)` at 100 Hz over `[0, duration]`.
fn sample(duration: f64, f: impl Fn(f64) -> ([f64; 3], [f64; 4])) -> Vec<Sample> {
    let n = (duration * RATE_HZ).round() as usize;
    (0..=n)
        .map(|i| {
            let t = i as f64 / RATE_HZ;
            let (pos, rot) = f(t);
            Sample { t, pos, rot }
        })
        .collect()
}

/// Distance covered at time `t` by a motion that accelerates uniformly from rest to `v` in
/// `ramp` seconds, cruises, and decelerates to rest in `ramp` seconds, covering `dist` in all.
/// Returns (distance, total duration).
fn trapezoid(dist: f64, v: f64, ramp: f64, t: f64) -> (f64, f64) {
    let cruise = (dist - v * ramp) / v;
    assert!(cruise >= 0.0, "ramps longer than the move");
    let total = 2.0 * ramp + cruise;
    let a = v / ramp;
    let s = if t <= 0.0 {
        0.0
    } else if t < ramp {
        0.5 * a * t * t
    } else if t < ramp + cruise {
        0.5 * v * ramp + v * (t - ramp)
    } else if t < total {
        let r = total - t;
        dist - 0.5 * a * r * r
    } else {
        dist
    };
    (s, total)
}

/// Press and lift on one spot, leaning 5 degrees about y.
fn press_lift() -> Vec<Sample> {
    let rot = lean(5.0, [-1.0, 0.0]);
    sample(1.0, |t| {
        let z = if t < 0.4 {
            lerp(45.0, 30.0, smoothstep(t / 0.4))
        } else if t < 0.6 {
            30.0
        } else {
            lerp(30.0, 45.0, smoothstep((t - 0.6) / 0.4))
        };
        ([0.0, 0.0, z], rot)
    })
}

/// A straight stroke of `length` mm along `dir` at `speed` mm/s, pressed `depth` mm, leaning
/// `tilt` degrees with the tip trailing. Enter (0.3 s), move, lift (0.3 s).
fn straight_stroke(dir: [f64; 2], length: f64, speed: f64, depth: f64, tilt: f64) -> Vec<Sample> {
    let rot = lean(tilt, [-dir[0], -dir[1]]);
    let above = z_for_depth(-5.0, tilt);
    let pressed = z_for_depth(depth, tilt);
    let (enter, ramp, lift) = (0.3, 0.1, 0.3);
    let (_, moving) = trapezoid(length, speed, ramp, 0.0);
    let total = enter + moving + lift;
    sample((total * RATE_HZ).ceil() / RATE_HZ, |t| {
        let (s, _) = trapezoid(length, speed, ramp, t - enter);
        let z = if t < enter {
            lerp(above, pressed, smoothstep(t / enter))
        } else if t < enter + moving {
            pressed
        } else {
            lerp(pressed, above, smoothstep((t - enter - moving) / lift))
        };
        ([dir[0] * s, dir[1] * s, z], rot)
    })
}

/// 趯 (hook): a short vertical stroke down, a pause pressing in while the brush turns to lean
/// its tip toward the lower right, then a flick up and to the left that leaves the paper at
/// 500 mm/s.
fn hook() -> Vec<Sample> {
    let tilt = 10.0;
    let rot_down = lean(tilt, [0.0, 1.0]);
    let above = z_for_depth(-5.0, tilt);
    let pressed = z_for_depth(5.0, tilt);
    // The flick goes up-left; the tip trails it, toward the lower right.
    let dir = [-(0.5f64.sqrt()), 0.5f64.sqrt()];
    let flick_tilt = 15.0;
    let rot_flick = lean(flick_tilt, [-dir[0], -dir[1]]);
    let pause_depth_mm = 8.0;
    // The ferrule rises with the distance flicked: the tip reaches the paper's surface (as
    // if the brush were straight) after `lift_off_mm`.
    let lift_off_mm = 30.0;
    // Phases (s).
    let enter = 0.25;
    let (stroke_len, stroke_v, stroke_ramp) = (40.0, 80.0, 0.1);
    let (_, stroke) = trapezoid(stroke_len, stroke_v, stroke_ramp, 0.0);
    let pause = 0.15;
    // The flick: accelerate from rest at 16,700 mm/s^2 to 500 mm/s (0.03 s, 7.5 mm), keep
    // 500 mm/s for 0.07 s (35 mm), then decelerate in the air over 0.05 s (12.5 mm).
    let (acc_t, cruise_t, stop_t, v) = (0.03, 0.07, 0.05, 500.0);
    let flick = acc_t + cruise_t + stop_t;
    let t_stroke = enter;
    let t_pause = t_stroke + stroke;
    let t_flick = t_pause + pause;
    let total = t_flick + flick + 0.1;
    let bottom = -stroke_len;
    sample((total * RATE_HZ).ceil() / RATE_HZ, |t| {
        if t < t_stroke {
            let z = lerp(above, pressed, smoothstep(t / enter));
            ([0.0, 0.0, z], rot_down)
        } else if t < t_pause {
            let (s, _) = trapezoid(stroke_len, stroke_v, stroke_ramp, t - t_stroke);
            ([0.0, -s, pressed], rot_down)
        } else if t < t_flick {
            // Press in and turn the brush for the flick.
            let u = smoothstep((t - t_pause) / pause);
            let rot = nlerp(rot_down, rot_flick, u);
            let z = lerp(pressed, z_for_depth(pause_depth_mm, flick_tilt), u);
            ([0.0, bottom, z], rot)
        } else {
            let tf = t - t_flick;
            let s = if tf < acc_t {
                0.5 * (v / acc_t) * tf * tf
            } else if tf < acc_t + cruise_t {
                0.5 * v * acc_t + v * (tf - acc_t)
            } else {
                let ts = (tf - acc_t - cruise_t).min(stop_t);
                0.5 * v * acc_t + v * cruise_t + v * ts - 0.5 * (v / stop_t) * ts * ts
            };
            let depth = pause_depth_mm * (1.0 - s / lift_off_mm);
            let z = z_for_depth(depth, flick_tilt);
            ([dir[0] * s, bottom + dir[1] * s, z], rot_flick)
        }
    })
}

/// Normalised interpolation between two close orientations (the tool itself slerps between
/// rows; this only shapes the example).
fn nlerp(a: [f64; 4], b: [f64; 4], u: f64) -> [f64; 4] {
    let q = [0, 1, 2, 3].map(|i| lerp(a[i], b[i], u));
    let n = q.iter().map(|c| c * c).sum::<f64>().sqrt();
    q.map(|c| c / n)
}

fn write(dir: &Path, name: &str, rows: &[Sample]) {
    let mut s = String::from("t,x,y,z,qw,qx,qy,qz\n");
    for r in rows {
        let _ = write!(s, "{:.3}", r.t);
        for v in r.pos {
            let _ = write!(s, ",{}", clean(v, 4));
        }
        for v in r.rot {
            let _ = write!(s, ",{}", clean(v, 9));
        }
        s.push('\n');
    }
    let path = dir.join(name);
    std::fs::write(&path, s).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    println!("wrote {} ({} rows)", path.display(), rows.len());
}

/// `v` with `decimals` digits, without a negative zero.
fn clean(v: f64, decimals: usize) -> String {
    let s = format!("{v:.decimals$}");
    if s.starts_with('-') && s[1..].bytes().all(|b| b == b'0' || b == b'.') {
        s[1..].to_string()
    } else {
        s
    }
}

fn main() {
    let dir: PathBuf = Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("host/ lies in the workspace")
        .join("examples/poses");
    std::fs::create_dir_all(&dir).expect("create examples/poses");
    write(&dir, "press_lift.csv", &press_lift());
    // 橫: left to right, 80 mm at 100 mm/s, 6 mm deep, leaning 15 degrees.
    write(
        &dir,
        "heng.csv",
        &straight_stroke([1.0, 0.0], 80.0, 100.0, 6.0, 15.0),
    );
    // 豎: top to bottom (-y), the same.
    write(
        &dir,
        "shu.csv",
        &straight_stroke([0.0, -1.0], 80.0, 100.0, 6.0, 15.0),
    );
    write(&dir, "hook.csv", &hook());
}
