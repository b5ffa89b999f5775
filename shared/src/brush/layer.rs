//! A layer of the brush's surface: the ellipse around one spine mass (Liang 3.2), and the
//! ink it holds. Its own module so that the ink ([`super::ink`]), which every brush model's
//! layers go through, depends on the layer and not on the brush.

use crate::vec::Vec3;

/// The state of one layer's surface ellipse (Liang 3.2).
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct Layer<S> {
    /// Short-axis direction SA_i (unit).
    pub short_axis: Vec3<S>,
    /// Long-axis direction LA_i (unit).
    pub long_axis: Vec3<S>,
    /// Long radius RL_i (mm).
    pub long_radius: S,
    /// Short radius RS_i (mm).
    pub short_radius: S,
    /// Wetness W_i in [0, 1]: the layer's ink load as a share of what it holds ([`super::ink`]).
    pub wetness: S,
    /// Ink the layer has given to the paper since the brush was built or reset (ink units, a
    /// running total: the host lays each increase on the paper under the layer's footprint;
    /// in fixed point it saturates after some two thousand million units).
    pub deposited: S,
}

impl<S: crate::scalar::Scalar> Layer<S> {
    /// The same layer in another number type (a model's `f64` layers drawn by a host that
    /// holds frames in the pen's fixed point).
    pub fn cast<T: crate::scalar::Scalar>(&self) -> Layer<T> {
        Layer {
            short_axis: self.short_axis.cast(),
            long_axis: self.long_axis.cast(),
            long_radius: T::from_f64(self.long_radius.to_f64()),
            short_radius: T::from_f64(self.short_radius.to_f64()),
            wetness: T::from_f64(self.wetness.to_f64()),
            deposited: T::from_f64(self.deposited.to_f64()),
        }
    }
}
