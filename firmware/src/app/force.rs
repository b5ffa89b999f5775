//! The force on the hand, evaluated once per tick.
//!
//! PLACEHOLDER until `maobi_shared::force` (the haptic force model and output safety,
//! written by the force-model engineer) lands: this returns zero, so the motor path, the
//! gating and the reporting are exercised end to end with no force. Replace the body with
//! the shared model's call; keep the signature (brush after its tick -> newtons, world).

use maobi_shared::{Brush, Fx, Scalar};

/// Force on the handle (N, world frame) after the brush's tick.
#[inline]
pub fn handle_force(_brush: &Brush<Fx>) -> [Fx; 3] {
    // PLACEHOLDER: no force model yet (see the module docs).
    [Fx::ZERO; 3]
}
