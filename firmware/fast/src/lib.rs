//! The force loop's hot path, instantiated for the firmware's scalar ([`Fx`]) here.
//!
//! The brush, the force model and the pen's kinematics are generic over the scalar, and a
//! generic function is compiled in the crate that instantiates it. These non-generic entry
//! points instantiate the hot code in this crate, so that it is built for speed while the
//! rest of the image is built for size (`firmware/Cargo.toml`: both images, `release` for
//! QEMU and `pen` for the Black Pill, at `opt-level = "z"`, this crate at 2);
//! `#[inline(never)]` keeps link-time optimisation from pulling them back into the
//! size-optimised callers. The shared force loop's tick ([`force_loop_tick`]: brush, force
//! model, output stage) is one entry point; the guide's tick and the brush's reset come from
//! the caller's size-optimised code ([`TickParts`]), as do the brush's construction and new
//! parameters: built for speed they would cost several times the flash, and the reset runs
//! only in a tick without a brush tick (a re-anchor) or on a command. The brush's parts
//! have their own entry points for the bench's per-part figures.
#![no_std]

use maobi_shared::force_loop::{TickIn, TickOut, TickParts};
use maobi_shared::kinematics::{ArmTrig, Joints, KinematicsError, Pen, RawReadings};
use maobi_shared::{Brush, ForceLoop, Fx, Pose, Scalar, Vec3};

/// `ForceLoop::tick_with`: one 1 ms tick of the shared force loop (pose, brush, forces,
/// guide, output stage, sensor-jump check), with the caller's guide tick and brush reset.
#[inline(never)]
pub fn force_loop_tick(
    fl: &mut ForceLoop<Fx>,
    input: TickIn<Fx>,
    parts: &TickParts<Fx>,
) -> TickOut<Fx> {
    fl.tick_with(input, parts)
}

/// `Brush::tick`: every substep and the surface update of one 1 ms tick.
#[inline(never)]
pub fn brush_tick(brush: &mut Brush<Fx>, pose: Pose<Fx>) {
    brush.tick(pose);
}

/// `Brush::substep`: one substep alone (the bench's per-part figures).
#[inline(never)]
pub fn brush_substep(brush: &mut Brush<Fx>, pose: Pose<Fx>) {
    brush.substep(pose);
}

/// `Brush::end_tick`: the once-per-tick surface update alone (the bench's per-part figures).
#[inline(never)]
pub fn brush_end_tick(brush: &mut Brush<Fx>) {
    brush.end_tick();
}

/// `Pen::joints` and `Pen::forward_with_trig`: the ferrule's pose from raw readings, with
/// the arm's sines and cosines (for the torques of the same tick).
#[inline(never)]
pub fn pen_pose(
    pen: &Pen<Fx>,
    raw: &RawReadings,
) -> Result<(Pose<Fx>, ArmTrig<Fx>), KinematicsError> {
    let joints: Joints<Fx> = pen.joints(raw)?;
    Ok(pen.forward_with_trig(&joints))
}

/// `Pen::torques_at`: joint torques (N m) for force `f` (N) at the wrist, `tau = J^T F`,
/// at the arm angles whose sines and cosines `pen_pose` gave.
#[inline(never)]
pub fn pen_torques(pen: &Pen<Fx>, arm: &ArmTrig<Fx>, f: Vec3<Fx>) -> [Fx; 3] {
    pen.torques_at(arm, f)
}

/// The scalar operations the model is built from (the bench's per-operation figures).
#[derive(Copy, Clone, Debug)]
pub enum ScalarOp {
    Add,
    Mul,
    Div,
    Sqrt,
    Rsqrt,
    FromF64,
}

/// `times` evaluations of `op` on `x` and `y`, summed: compiled here, like the hot path, so
/// that the bench's per-operation counts are those of the code the tick runs.
#[inline(never)]
pub fn repeat_scalar_op(op: ScalarOp, x: Fx, y: Fx, times: u32) -> Fx {
    let mut acc = Fx::ZERO;
    let bb = core::hint::black_box::<Fx>;
    match op {
        ScalarOp::Add => (0..times).for_each(|_| acc += bb(x) + bb(y)),
        ScalarOp::Mul => (0..times).for_each(|_| acc += bb(x) * bb(y)),
        ScalarOp::Div => (0..times).for_each(|_| acc += Scalar::div(bb(x), bb(y))),
        ScalarOp::Sqrt => (0..times).for_each(|_| acc += Scalar::sqrt(bb(x))),
        ScalarOp::Rsqrt => (0..times).for_each(|_| acc += Scalar::rsqrt(bb(x))),
        ScalarOp::FromF64 => (0..times).for_each(|_| acc += Fx::from_f64(bb(x).to_bits() as f64)),
    }
    acc
}
