//! The Phantom servo callback's model step, per 1 ms tick, on the hook stroke (the device
//! poses the bridge would read for `examples/poses/hook.csv`, with its default mapping):
//!
//! * `servo_step/fx`: `ServoCore::step` with Liang's brush in `Fx`, what the bridge runs;
//! * `force_loop/f32`: the shared force loop in `f32` on the same poses, for comparison;
//! * `servo_step/baxter_lin`: the step with Baxter & Lin's brush, whose solver is served
//!   (untimed) after every tick, as its own thread keeps up beside the servo loop in real
//!   time: the step only evaluates the solver's last local model.
//!
//! Each iteration is one pass over the whole stroke from a fresh model, so every pass
//! measures the same ticks; the figures are per pass, and per tick as the throughput.
//! The callback shares its millisecond with libHD's own work, so the step should stay well
//! inside it.
//!
//! `cargo bench -p maobi --bench servo`

use std::hint::black_box;
use std::path::Path;
use std::time::{Duration, Instant};

use criterion::{criterion_group, criterion_main, BatchSize, Criterion, Throughput};
use maobi::phantom::servo::{transform_of_pose, Mapping, ServoCore};
use maobi::phantom::solver::{Solver, SolverLink};
use maobi::poses::PoseTrack;
use maobi_shared::baxter_lin::head::HeadShape;
use maobi_shared::baxter_lin::local_force::LocalForceParams;
use maobi_shared::force::{DEFAULT_FORCES, PHANTOM_OMNI};
use maobi_shared::force_loop::{Gate, TickIn};
use maobi_shared::guide::DEFAULT_GUIDE;
use maobi_shared::{presets, ForceLoop, Pose};

/// The hook's paper poses, one per tick, and the device transforms the servo loop reads.
fn hook() -> (Vec<Pose<f64>>, Vec<[f64; 16]>) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/poses/hook.csv");
    let paper: Vec<Pose<f64>> = PoseTrack::from_path(&path)
        .expect("the hook stroke")
        .resample()
        .collect();
    let map = Mapping::default();
    let transforms = paper
        .iter()
        .map(|p| {
            let (pos, rot) = map.to_device(*p);
            transform_of_pose(pos, rot)
        })
        .collect();
    (paper, transforms)
}

fn servo(c: &mut Criterion) {
    let (paper, transforms) = hook();
    let params = presets::LARGE;
    let mut g = c.benchmark_group("servo_step");
    g.throughput(Throughput::Elements(transforms.len() as u64));
    g.sample_size(20);

    g.bench_function("fx/hook", |b| {
        b.iter_batched_ref(
            || ServoCore::new(params, PHANTOM_OMNI, Mapping::default(), true).unwrap(),
            |core| {
                for m in &transforms {
                    black_box(core.step(m, 0));
                }
            },
            BatchSize::PerIteration,
        )
    });

    // Only the steps are timed; the solver's work (on its own core in the bridge) is not.
    let local = LocalForceParams::for_device(&PHANTOM_OMNI);
    g.bench_function("baxter_lin/hook", |b| {
        b.iter_custom(|passes| {
            let mut timed = Duration::ZERO;
            for _ in 0..passes {
                let link = SolverLink::new();
                let mut core = ServoCore::baxter_lin(
                    params,
                    PHANTOM_OMNI,
                    Mapping::default(),
                    true,
                    link.clone(),
                )
                .unwrap();
                let mut solver = Solver::new(link, HeadShape::Round, local);
                for m in &transforms {
                    let t = Instant::now();
                    black_box(core.step(m, 0));
                    timed += t.elapsed();
                    solver.serve();
                }
            }
            timed
        })
    });
    g.finish();

    let mut g = c.benchmark_group("force_loop");
    g.throughput(Throughput::Elements(paper.len() as u64));
    g.sample_size(20);
    let poses: Vec<Pose<f32>> = paper.iter().map(|p| p.cast()).collect();
    let gate = Gate {
        allowed: true,
        faulted: false,
    };
    g.bench_function("f32/hook", |b| {
        b.iter_batched_ref(
            || {
                ForceLoop::<f32>::new(
                    params,
                    poses[0],
                    DEFAULT_FORCES,
                    PHANTOM_OMNI,
                    DEFAULT_GUIDE,
                )
                .unwrap()
            },
            |fl| {
                for p in &poses {
                    black_box(fl.tick(TickIn {
                        pose: Some(*p),
                        guide: None,
                        gate,
                    }));
                }
            },
            BatchSize::PerIteration,
        )
    });
    g.finish();
}

criterion_group!(benches, servo);
criterion_main!(benches);
