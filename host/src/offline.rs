//! Runs the brush model over a resampled pose track, one 1 ms tick at a time, in the shared
//! force loop (`maobi_shared::ForceLoop`) that every device runs.

use std::fmt;

use maobi_shared::force::{Forces, DEFAULT_FORCES, PHANTOM_OMNI};
use maobi_shared::force_loop::{Gate, TickIn};
use maobi_shared::guide::DEFAULT_GUIDE;
use maobi_shared::{Brush, BrushParams, BrushScalar, ForceLoop, Fx, Pose, Scalar};

use crate::poses::PoseTrack;

/// The number type to run the model in.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum ScalarKind {
    /// I32F32 fixed point, as on the device.
    #[default]
    Fixed,
    F32,
    F64,
}

impl ScalarKind {
    pub fn name(self) -> &'static str {
        match self {
            ScalarKind::Fixed => <Fx as Scalar>::NAME,
            ScalarKind::F32 => <f32 as Scalar>::NAME,
            ScalarKind::F64 => <f64 as Scalar>::NAME,
        }
    }
}

impl fmt::Display for ScalarKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// The state after one tick, handed to the caller of [`simulate`].
pub struct Tick<'a, S: Scalar> {
    /// Tick index; 0 is the rest state at the first pose.
    pub k: usize,
    /// Time (s) on the input's clock.
    pub t: f64,
    /// The resampled input pose the handle was driven to.
    pub pose: Pose<f64>,
    pub brush: &'a Brush<S>,
    /// The force model's output for this tick, with the hand's ferrule at `pose` (which may
    /// be below the paper; the brush's own handle is kept on it). Before any device's output
    /// stage: no ramp, clamp or step limit.
    pub forces: Forces<S>,
}

/// Creates the brush at rest at the track's first pose, calls `on_tick` with that state
/// (tick 0), then ticks to each following resampled pose and calls `on_tick` after each.
/// Stops at the first error `on_tick` returns. Returns the number of ticks (tick 0 included).
pub fn simulate<S: BrushScalar>(
    params: BrushParams,
    track: &PoseTrack,
    mut on_tick: impl FnMut(&Tick<'_, S>) -> anyhow::Result<()>,
) -> anyhow::Result<usize> {
    let mut poses = track.resample();
    let first = poses.next().expect("a pose track has at least one tick");
    let mut fl = ForceLoop::<S>::new(
        params,
        first.cast(),
        DEFAULT_FORCES,
        PHANTOM_OMNI,
        DEFAULT_GUIDE,
    )?;
    // Tick 0 places the brush at rest at the first pose; the forces are the model's alone
    // (no guide, the output stage never drives).
    fl.reanchor();
    let gate = Gate {
        allowed: false,
        faulted: false,
    };
    let mut k = 0;
    for pose in std::iter::once(first).chain(poses) {
        let out = fl.tick(TickIn {
            pose: Some(pose.cast()),
            guide: None,
            gate,
        });
        on_tick(&Tick {
            k,
            t: track.tick_time(k),
            pose,
            brush: fl.brush(),
            forces: out.forces,
        })?;
        k += 1;
    }
    Ok(k)
}
