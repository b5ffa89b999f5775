//! The paper's friction as `maobi trace` reports it: a brush dragged at constant speed along
//! the paper is held back, against the motion, with a share of its normal force (Coulomb
//! friction, `maobi_shared::force`), which the trace's `fx,fy,fz` columns show.

use std::path::PathBuf;
use std::process::Command;

/// The brush moves at this speed along +x while pressed (mm/s).
const SPEED_MM_S: f64 = 60.0;
/// The pen's tilt about the y axis (degrees).
const TILT_DEG: f64 = 15.0;
/// Timeline (s): lowered into the paper until `PRESSED`, still until `DRAG`, speeding up
/// smoothly to `SPEED_MM_S` over `RAMP_S`, then at constant speed until `END`.
const PRESSED: f64 = 0.3;
const DRAG: f64 = 0.4;
const RAMP_S: f64 = 0.1;
const END: f64 = 1.6;
/// Rows from here on are past the start's transient (the dragged inertia mass settles).
const STEADY_FROM: f64 = 0.9;

/// A pose file: `length_mm`'s brush pressed `press_mm` into the paper at `TILT_DEG` and
/// dragged along +x.
fn drag_poses(length_mm: f64, press_mm: f64) -> String {
    let tilt = TILT_DEG.to_radians();
    let touch = length_mm * tilt.cos();
    let (qw, qy) = ((tilt / 2.0).cos(), (tilt / 2.0).sin());
    let mut csv = String::from("t,x,y,z,qw,qx,qy,qz\n");
    let steps = (END * 100.0).round() as usize;
    for k in 0..=steps {
        let t = k as f64 / 100.0;
        let z = touch + 3.0 - (3.0 + press_mm) * (t / PRESSED).min(1.0);
        // Distance: quadratic while speeding up, then linear.
        let u = (t - DRAG).max(0.0);
        let x = if u < RAMP_S {
            SPEED_MM_S * u * u / (2.0 * RAMP_S)
        } else {
            SPEED_MM_S * (u - RAMP_S / 2.0)
        };
        csv += &format!("{t:.3},{x:.6},0,{z:.6},{qw:.9},0,{qy:.9},0\n");
    }
    csv
}

fn scratch(name: &str) -> PathBuf {
    std::env::temp_dir().join(format!("maobi-friction-{}-{name}", std::process::id()))
}

/// `maobi trace` of `poses` with `brush`: the rows as (t, fx, fy, fz).
fn trace(brush: &str, poses: &str) -> Vec<(f64, f64, f64, f64)> {
    let input = scratch(&format!("{brush}.csv"));
    let output = scratch(&format!("{brush}-trace.csv"));
    std::fs::write(&input, poses).unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_maobi"))
        .args(["trace", "--poses"])
        .arg(&input)
        .args(["--brush", brush, "-o"])
        .arg(&output)
        .output()
        .expect("run maobi");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = std::fs::read_to_string(&output).unwrap();
    let _ = std::fs::remove_file(&input);
    let _ = std::fs::remove_file(&output);
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let col = |name: &str| header.iter().position(|c| *c == name).unwrap();
    let (t, fx, fy, fz) = (col("t"), col("fx"), col("fy"), col("fz"));
    lines
        .map(|l| {
            let r: Vec<f64> = l.split(',').map(|v| v.parse().unwrap()).collect();
            (r[t], r[fx], r[fy], r[fz])
        })
        .collect()
}

#[test]
fn a_steady_drag_on_the_paper_is_held_back_by_friction() {
    for (brush, length_mm, press_mm) in [("large", 40.0, 6.0), ("small", 18.0, 3.0)] {
        let rows = trace(brush, &drag_poses(length_mm, press_mm));
        let steady: Vec<_> = rows.iter().filter(|r| r.0 >= STEADY_FROM).collect();
        assert!(steady.len() > 500, "{brush}: {} steady rows", steady.len());
        let mut least = f64::MAX;
        for &&(t, fx, fy, fz) in &steady {
            assert!(
                fz > 0.2,
                "{brush}, t = {t}: the brush presses with fz = {fz} N"
            );
            // The motion is along +x: friction pulls toward -x, with no sideways part.
            let ratio = -fx / fz;
            least = least.min(ratio);
            assert!(
                ratio >= 0.15,
                "{brush}, t = {t}: fx = {fx} N against fz = {fz} N (ratio {ratio:.3})"
            );
            assert!(fy.abs() < 0.01 * fz, "{brush}, t = {t}: fy = {fy} N");
        }
        let (t, fx, _, fz) = steady[steady.len() / 2];
        println!(
            "{brush}: dragged at {SPEED_MM_S} mm/s, -fx / fz at least {least:.3} from \
             t = {STEADY_FROM} s (at t = {t}: fx = {fx} N, fz = {fz} N)"
        );
    }
}
