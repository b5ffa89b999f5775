//! # maobi-shared: the Maobi brush model
//!
//! A virtual Chinese-calligraphy brush (Liang 2009, "A Calligraphy Writing System Based on
//! Using a Force-Reflection Joystick"), written once over a [`Scalar`] type so that the pen's
//! microcontroller (fixed point, [`Fx`]), the host simulation and the tests (`f32`, `f64`) run
//! the same code. `no_std`, no allocator, no panics on the substep path.
//!
//! * [`scalar`]: the number types and the fixed-point format's error budget.
//! * [`vec`](mod@vec), [`quat`]: vectors, unit quaternions, the handle [`Pose`].
//! * [`params`], [`presets`]: validated run-time parameters and the brush presets.
//! * [`brush`]: spine dynamics, virtual skeleton, plasticity, surface.
//! * [`footprint`]: the part of the surface that touches the paper, as convex polygons.
//! * [`energy`]: the brush's mechanical energy, for stability checks.
//! * [`force`]: the forces for the hand (Liang 4.2.3) and the output stage that keeps them safe.
//! * [`force_loop`]: the force loop every device runs: pose, brush, force model, guide,
//!   output stage and the sensor-jump check, one tick at a time.
//! * [`kinematics`]: the reference pen's arm and gimbal, from raw sensor readings to the pose
//!   and from forces to motor commands.
//! * [`pen_io`]: the physical pen's board logic without the hardware: H-bridge duty from a
//!   motor command, the gimbal sensors' filter, the stored configuration and its flash image.
//! * [`hand`]: a simulated hand holding the stylus, for tests of the force loop.
//! * [`baxter_lin`]: Baxter & Lin's brush (the second model: its spines, heads and surface,
//!   `f64`, desktop only).
//!
//! Coordinates: millimetres, the paper is the plane z = 0 with +z up, the pose is the
//! ferrule's, and the identity orientation holds the brush pointing straight down.
#![cfg_attr(not(feature = "std"), no_std)]
// Denied rather than forbidden so that one place (and nothing else) may opt out, with
// `#[allow(unsafe_code)]` and SAFETY notes: the Cortex-M4F's `asm!` blocks in `scalar.rs`,
// the one-instruction square root (`sqrt_f32`), which `core` does not offer on stable Rust,
// and the fixed-point add, subtract and coefficient multiply (`scalar::raw`), whose compiled
// forms cost half again as many instructions. All are register arithmetic; the firmware
// checks them on the device against their portable references. Anything else unsafe here
// is still an error.
#![deny(unsafe_code)]

pub mod baxter_lin;
pub mod brush;
pub mod energy;
pub mod footprint;
pub mod force;
pub mod force_loop;
pub mod guide;
pub mod hand;
pub mod kinematics;
pub mod params;
pub mod pen_io;
pub mod presets;
pub mod protocol;
pub mod quat;
pub mod scalar;
pub mod stroke;
pub mod vec;

pub use brush::{Brush, BrushScalar, Layer};
pub use force_loop::ForceLoop;
pub use params::{BrushParams, ParamError, ParamId};
pub use quat::{Pose, Quat};
pub use scalar::{Fx, Scalar};
pub use vec::{Vec2, Vec3};
