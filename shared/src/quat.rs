//! Unit quaternions (w, x, y, z) for the handle's orientation.

use crate::scalar::Scalar;
use crate::vec::Vec3;

/// A rotation as a unit quaternion, Hamilton convention, `q = w + xi + yj + zk`.
///
/// The identity holds the brush pointing straight down (-z) at the paper.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct Quat<S> {
    pub w: S,
    pub x: S,
    pub y: S,
    pub z: S,
}

impl<S: Scalar> Default for Quat<S> {
    fn default() -> Self {
        Self::IDENTITY
    }
}

impl<S: Scalar> Quat<S> {
    pub const IDENTITY: Self = Quat {
        w: S::ONE,
        x: S::ZERO,
        y: S::ZERO,
        z: S::ZERO,
    };

    pub const fn new(w: S, x: S, y: S, z: S) -> Self {
        Quat { w, x, y, z }
    }
    pub fn from_f64(q: [f64; 4]) -> Self {
        Quat::new(
            S::from_f64(q[0]),
            S::from_f64(q[1]),
            S::from_f64(q[2]),
            S::from_f64(q[3]),
        )
    }
    pub fn to_f64(self) -> [f64; 4] {
        [
            self.w.to_f64(),
            self.x.to_f64(),
            self.y.to_f64(),
            self.z.to_f64(),
        ]
    }
    pub fn norm2(self) -> S {
        self.w * self.w + self.x * self.x + self.y * self.y + self.z * self.z
    }
    /// Rotates `v` by this (unit) quaternion: `v + 2 w (u x v) + 2 u x (u x v)`.
    #[inline]
    pub fn rotate(self, v: Vec3<S>) -> Vec3<S> {
        let u = Vec3::new(self.x, self.y, self.z);
        let t = u.cross(v);
        let t = t + t;
        v + t.scale(self.w) + u.cross(t)
    }
    /// Rotates `v` by the inverse rotation.
    #[inline]
    pub fn rotate_inv(self, v: Vec3<S>) -> Vec3<S> {
        self.conj().rotate(v)
    }
    pub fn conj(self) -> Self {
        Quat::new(self.w, -self.x, -self.y, -self.z)
    }
    /// Hamilton product `self * o` (apply `o`, then `self`).
    pub fn compose(self, o: Self) -> Self {
        Quat::new(
            self.w * o.w - self.x * o.x - self.y * o.y - self.z * o.z,
            self.w * o.x + self.x * o.w + self.y * o.z - self.z * o.y,
            self.w * o.y - self.x * o.z + self.y * o.w + self.z * o.x,
            self.w * o.z + self.x * o.y - self.y * o.x + self.z * o.w,
        )
    }
    /// Where the rotation takes +z (its matrix's third column), from six products: `(2(xz +
    /// wy), 2(yz - wx), 1 - 2(x^2 + y^2))` for a unit quaternion.
    pub fn z_axis(self) -> Vec3<S> {
        let Quat { w, x, y, z } = self;
        let twice = |v: S| v + v;
        Vec3::new(
            twice(x * z + w * y),
            twice(y * z - w * x),
            S::ONE - twice(x * x + y * y),
        )
    }
    /// `self.compose(r)` for `r` the rotation about axis 0 (x), 1 (y) or 2 (z) whose half
    /// angle has cosine `c` and sine `s`: the general product with `r`'s two zero components
    /// left out (8 products instead of 16). The same value, and for [`crate::Fx`] the same
    /// bits: a product with zero is exactly zero and adding it changes nothing.
    pub fn then_about(self, axis: usize, c: S, s: S) -> Self {
        let Quat { w, x, y, z } = self;
        match axis {
            0 => Quat::new(w * c - x * s, w * s + x * c, y * c + z * s, z * c - y * s),
            1 => Quat::new(w * c - y * s, x * c - z * s, w * s + y * c, x * s + z * c),
            _ => Quat::new(w * c - z * s, x * c + y * s, y * c - x * s, w * s + z * c),
        }
    }
    /// Scales to unit length; the identity for a zero quaternion.
    pub fn normalized(self) -> Self {
        let n2 = self.norm2();
        if n2 > S::ZERO {
            // One reciprocal square root instead of a square root and a division (the
            // fixed-point division is the dearer of the two).
            let inv = n2.rsqrt();
            // Near-unit components are the coefficients (the same products).
            Quat::new(
                inv.mul_coef(self.w),
                inv.mul_coef(self.x),
                inv.mul_coef(self.y),
                inv.mul_coef(self.z),
            )
        } else {
            Self::IDENTITY
        }
    }
    /// Normalised linear interpolation along the shorter arc: for the small turns of one
    /// step (a tick, a hand's move), where nlerp equals slerp to far below the format's
    /// resolution.
    pub fn nlerp(a: Self, b: Self, t: S) -> Self {
        // Unit quaternions: components in [-1, 1], coefficient products (the same values).
        let d = a.w.mul_coef(b.w) + a.x.mul_coef(b.x) + a.y.mul_coef(b.y) + a.z.mul_coef(b.z);
        let b = if d < S::ZERO {
            Quat::new(-b.w, -b.x, -b.y, -b.z)
        } else {
            b
        };
        // t is usually in [0, 1): the coefficient product (the same value, cheaper in fixed
        // point).
        Quat::new(
            a.w + (b.w - a.w).mul_coef(t),
            a.x + (b.x - a.x).mul_coef(t),
            a.y + (b.y - a.y).mul_coef(t),
            a.z + (b.z - a.z).mul_coef(t),
        )
        .normalized()
    }
}

/// The handle's pose: the ferrule's position (mm) and orientation.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct Pose<S> {
    pub pos: Vec3<S>,
    pub rot: Quat<S>,
}

impl<S: Scalar> Default for Pose<S> {
    fn default() -> Self {
        Pose::new(Vec3::ZERO, Quat::IDENTITY)
    }
}

impl<S: Scalar> Pose<S> {
    pub fn new(pos: Vec3<S>, rot: Quat<S>) -> Self {
        Pose { pos, rot }
    }
    /// The brush's rest direction in the world: the handle frame's -z.
    pub fn down(&self) -> Vec3<S> {
        self.rot.rotate(-Vec3::Z)
    }
    pub fn cast<T: Scalar>(self) -> Pose<T> {
        Pose {
            pos: self.pos.cast(),
            rot: Quat::from_f64(self.rot.to_f64()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rotation_about_x_tilts_the_brush() {
        let h = core::f64::consts::FRAC_PI_4; // 90 degrees about +y: -z goes to -x
        let q: Quat<f64> = Quat::from_f64([h.cos(), 0.0, h.sin(), 0.0]);
        let d = Pose::new(Vec3::ZERO, q).down();
        assert!((d.x + 1.0).abs() < 1e-12 && d.y.abs() < 1e-12 && d.z.abs() < 1e-12);
        let back = q.rotate_inv(d);
        assert!((back.z + 1.0).abs() < 1e-12);
    }

    /// Unit quaternions from a fixed pseudo-random sequence of axis-angle pairs.
    fn turns() -> impl Iterator<Item = (usize, f64)> {
        let mut seed = 0x2545_F491_4F6C_DD1Du64;
        (0..2000).map(move |_| {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (
                (seed % 3) as usize,
                (seed >> 8) as f64 / (1u64 << 56) as f64 * 12.0 - 6.0,
            )
        })
    }

    fn about<S: Scalar>(axis: usize, angle: f64) -> Quat<S> {
        let (s, c) = (angle / 2.0).sin_cos();
        let mut q = [c, 0.0, 0.0, 0.0];
        q[axis + 1] = s;
        Quat::from_f64(q)
    }

    #[test]
    fn then_about_is_the_composition_bit_for_bit() {
        let mut q = Quat::<crate::Fx>::from_f64([1.0, 0.0, 0.0, 0.0]);
        for (axis, angle) in turns() {
            let r = about::<crate::Fx>(axis, angle);
            let fast = q.then_about(axis, r.w, [r.x, r.y, r.z][axis]);
            assert_eq!(fast, q.compose(r));
            q = fast;
        }
        let mut q = Quat::<f64>::from_f64([1.0, 0.0, 0.0, 0.0]);
        for (axis, angle) in turns() {
            let r = about::<f64>(axis, angle);
            let fast = q.then_about(axis, r.w, [r.x, r.y, r.z][axis]);
            assert_eq!(fast, q.compose(r));
            q = fast;
        }
    }

    #[test]
    fn z_axis_is_the_rotated_z() {
        let mut q = Quat::<f64>::from_f64([1.0, 0.0, 0.0, 0.0]);
        for (axis, angle) in turns() {
            q = q.compose(about(axis, angle)).normalized();
            let d = (q.z_axis() - q.rotate(Vec3::Z)).to_f64();
            assert!(d.iter().all(|e| e.abs() < 1e-12), "{d:?}");
        }
    }
}
