//! Runs the large brush along a pressed stroke for a given number of ticks: a fixed workload
//! for `valgrind --tool=callgrind` (instruction counts per function, repeatable on a busy
//! machine), as `cargo bench` measures time.
//!
//! `cargo run --release -p maobi-shared --example tick_cost -- f32 2000`
//!
//! `valgrind --tool=callgrind target/release/examples/tick_cost fixed 1000`, then
//! `callgrind_annotate --auto=yes callgrind.out.<pid>` for the per-line picture (the substep is
//! inlined into `Brush::tick`). With `DUMP=1` it prints the final spine, layer radii and
//! axes, to compare two builds' results.
use maobi_shared::{presets, Brush, BrushScalar, Fx, Pose, Quat, Vec3};
use std::hint::black_box;

fn stroke_pose<S: BrushScalar>(k: usize) -> Pose<S> {
    let t = (k % 2000) as f64 * 1e-3;
    let x = 80.0 * (t * 0.5 * std::f64::consts::PI).sin();
    let h = 15f64.to_radians() / 2.0;
    Pose::new(
        Vec3::from_f64([x, 0.0, 34.0]),
        Quat::from_f64([h.cos(), 0.0, h.sin(), 0.0]),
    )
}

fn run<S: BrushScalar>(ticks: usize) {
    let mut b = Brush::<S>::new(presets::LARGE, stroke_pose(0)).unwrap();
    let poses: Vec<Pose<S>> = (0..ticks).map(stroke_pose).collect();
    let start = std::time::Instant::now();
    for pose in poses {
        b.tick(black_box(pose));
    }
    let elapsed = start.elapsed();
    if std::env::var_os("DUMP").is_some() {
        for m in b.spine() {
            println!("{:?}", m.to_f64());
        }
        for l in b.layers() {
            println!("{:?} {:?}", l.long_radius.to_f64(), l.short_radius.to_f64());
            println!("{:?} {:?}", l.long_axis.to_f64(), l.short_axis.to_f64());
        }
    }
    black_box(b.spine());
    // Wall time is only indicative (use `cargo bench` for timings); under callgrind it is
    // meaningless, the instruction counts are what to read there.
    println!(
        "{}: {ticks} ticks, {:.2} us per tick",
        S::NAME,
        elapsed.as_secs_f64() * 1e6 / ticks.max(1) as f64
    );
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let ticks = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(2000);
    match args.get(1).map(String::as_str) {
        Some("fixed") | None => run::<Fx>(ticks),
        Some("f32") => run::<f32>(ticks),
        Some("f64") => run::<f64>(ticks),
        Some(other) => {
            eprintln!("unknown scalar {other}: fixed, f32 or f64");
            std::process::exit(2);
        }
    }
}
