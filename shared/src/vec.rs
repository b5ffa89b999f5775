//! Small vectors over a [`Scalar`].

use crate::scalar::Scalar;
use core::ops::{Add, AddAssign, Mul, Neg, Sub, SubAssign};

/// A 3-vector. Model coordinates: millimetres, paper plane z = 0, +z up.
///
/// `repr(C)`: a slice of them is the components in order, which the host's wide kernels
/// (`wide`) read as one flat array.
#[derive(Copy, Clone, Debug, PartialEq, Default)]
#[repr(C)]
pub struct Vec3<S> {
    pub x: S,
    pub y: S,
    pub z: S,
}

impl<S: Scalar> Vec3<S> {
    pub const ZERO: Self = Vec3 {
        x: S::ZERO,
        y: S::ZERO,
        z: S::ZERO,
    };
    pub const X: Self = Vec3 {
        x: S::ONE,
        y: S::ZERO,
        z: S::ZERO,
    };
    pub const Y: Self = Vec3 {
        x: S::ZERO,
        y: S::ONE,
        z: S::ZERO,
    };
    pub const Z: Self = Vec3 {
        x: S::ZERO,
        y: S::ZERO,
        z: S::ONE,
    };

    #[inline]
    pub const fn new(x: S, y: S, z: S) -> Self {
        Vec3 { x, y, z }
    }
    pub fn from_f64(v: [f64; 3]) -> Self {
        Vec3::new(S::from_f64(v[0]), S::from_f64(v[1]), S::from_f64(v[2]))
    }
    pub fn to_f64(self) -> [f64; 3] {
        [self.x.to_f64(), self.y.to_f64(), self.z.to_f64()]
    }
    /// Converts between scalar types (through `f64`).
    pub fn cast<T: Scalar>(self) -> Vec3<T> {
        Vec3::from_f64(self.to_f64())
    }
    #[inline]
    pub fn dot(self, o: Self) -> S {
        self.x * o.x + self.y * o.y + self.z * o.z
    }
    #[inline]
    pub fn cross(self, o: Self) -> Self {
        Vec3::new(
            self.y * o.z - self.z * o.y,
            self.z * o.x - self.x * o.z,
            self.x * o.y - self.y * o.x,
        )
    }
    /// `self.dot(o)` with `o`'s components as the coefficients of [`Scalar::mul_coef`]:
    /// the same value (each product is the product), cheaper in fixed point when `o` is a
    /// unit vector (or any vector of components below one).
    #[inline]
    pub fn dot_coef(self, o: Self) -> S {
        // The three coefficients tested together, then three bare products: the compiler
        // does not merge the tests of separate `mul_coef` calls by itself.
        if o.is_coef() {
            self.x.mul_tested_coef(o.x) + self.y.mul_tested_coef(o.y) + self.z.mul_tested_coef(o.z)
        } else {
            self.dot(o)
        }
    }
    /// Whether every component is a coefficient ([`Scalar::is_coef`]).
    #[inline]
    fn is_coef(self) -> bool {
        self.x.is_coef() && self.y.is_coef() && self.z.is_coef()
    }
    /// `self.cross(o)` with `o`'s components as the coefficients of [`Scalar::mul_coef`]:
    /// the same value, cheaper in fixed point when `o` is a unit vector.
    #[inline]
    pub fn cross_coef(self, o: Self) -> Self {
        if o.is_coef() {
            let m = |a: S, c: S| a.mul_tested_coef(c);
            Vec3::new(
                m(self.y, o.z) - m(self.z, o.y),
                m(self.z, o.x) - m(self.x, o.z),
                m(self.x, o.y) - m(self.y, o.x),
            )
        } else {
            self.cross(o)
        }
    }
    #[inline]
    pub fn scale(self, s: S) -> Self {
        Vec3::new(self.x * s, self.y * s, self.z * s)
    }
    /// `self.scale(c)` for a coefficient `|c| < 1` ([`Scalar::mul_coef`]): the same
    /// value, cheaper in fixed point.
    #[inline]
    pub fn scale_coef(self, c: S) -> Self {
        if c.is_coef() {
            Vec3::new(
                self.x.mul_tested_coef(c),
                self.y.mul_tested_coef(c),
                self.z.mul_tested_coef(c),
            )
        } else {
            self.scale(c)
        }
    }
    #[inline]
    pub fn norm2(self) -> S {
        self.dot(self)
    }
    #[inline]
    pub fn norm(self) -> S {
        self.norm2().sqrt()
    }
    /// The unit vector along `self`, or `None` when its length is at most `min_len`
    /// (a direction that is not defined).
    #[inline]
    pub fn normalized_or_none(self, min_len: S) -> Option<Self> {
        self.normalized_if_longer(self.norm2(), min_len)
    }
    /// [`Self::normalized_or_none`] for a vector whose components are below one in
    /// magnitude, such as the cross product of two unit vectors: the squared length from
    /// coefficient products ([`Self::dot_coef`], which tests that they are), the same value,
    /// cheaper in fixed point.
    #[inline]
    pub fn normalized_or_none_coef(self, min_len: S) -> Option<Self> {
        self.normalized_if_longer(self.dot_coef(self), min_len)
    }
    /// The two above, given the squared length `n2` however it was formed.
    #[inline]
    fn normalized_if_longer(self, n2: S, min_len: S) -> Option<Self> {
        if n2 > min_len * min_len {
            Some(self.normalized_by(n2, n2.rsqrt()))
        } else {
            None
        }
    }
    /// `self` scaled to unit length, given its squared length `n2` and `r = n2.rsqrt()`
    /// (for a caller that has them already): the same value as
    /// [`Self::normalized_or_none`]'s.
    #[inline]
    pub fn normalized_by(self, n2: S, r: S) -> Self {
        // A product's value does not depend on which factor is the coefficient of
        // `mul_coef`: take the one below one, so fixed point skips the overflow test and half
        // the partial products. Longer than one, 1/|v| is below one; shorter, every component
        // is.
        if n2 > S::ONE {
            self.scale_coef(r)
        } else {
            Vec3::new(r.mul_coef(self.x), r.mul_coef(self.y), r.mul_coef(self.z))
        }
    }
    /// The part of `self` in the paper plane (z set to zero).
    #[inline]
    pub fn xy(self) -> Self {
        Vec3::new(self.x, self.y, S::ZERO)
    }
    /// `a + (b - a) t`.
    #[inline]
    pub fn lerp(a: Self, b: Self, t: S) -> Self {
        // Usually t is in [0, 1): the coefficient product (the same value, cheaper in fixed
        // point).
        a + (b - a).scale_coef(t)
    }
}

impl<S: Scalar> Add for Vec3<S> {
    type Output = Self;
    #[inline]
    fn add(self, o: Self) -> Self {
        Vec3::new(self.x + o.x, self.y + o.y, self.z + o.z)
    }
}
impl<S: Scalar> Sub for Vec3<S> {
    type Output = Self;
    #[inline]
    fn sub(self, o: Self) -> Self {
        Vec3::new(self.x - o.x, self.y - o.y, self.z - o.z)
    }
}
impl<S: Scalar> Neg for Vec3<S> {
    type Output = Self;
    #[inline]
    fn neg(self) -> Self {
        Vec3::new(-self.x, -self.y, -self.z)
    }
}
impl<S: Scalar> Mul<S> for Vec3<S> {
    type Output = Self;
    #[inline]
    fn mul(self, s: S) -> Self {
        self.scale(s)
    }
}
impl<S: Scalar> AddAssign for Vec3<S> {
    #[inline]
    fn add_assign(&mut self, o: Self) {
        *self = *self + o;
    }
}
impl<S: Scalar> SubAssign for Vec3<S> {
    #[inline]
    fn sub_assign(&mut self, o: Self) {
        *self = *self - o;
    }
}

/// A point in paper coordinates (mm).
#[derive(Copy, Clone, Debug, PartialEq, Default)]
pub struct Vec2<S> {
    pub x: S,
    pub y: S,
}

impl<S: Scalar> Vec2<S> {
    #[inline]
    pub const fn new(x: S, y: S) -> Self {
        Vec2 { x, y }
    }
    /// z-component of `(b - a) x (c - a)`: positive when a, b, c turn counter-clockwise.
    #[inline]
    pub fn orient(a: Self, b: Self, c: Self) -> S {
        (b.x - a.x) * (c.y - a.y) - (b.y - a.y) * (c.x - a.x)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scalar::Fx;

    /// The coefficient forms give the plain forms' bits, for the unit vectors the surface
    /// feeds them (and the fallback when a component is not a coefficient).
    #[test]
    fn coefficient_forms_are_the_plain_ones() {
        let mut x: u64 = 0x0DDB_1A5E_5BAD_5EED;
        let mut next = || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            (x >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        let tiny = Fx::from_f64(1e-6);
        let mut unit = || loop {
            let v = Vec3::<Fx>::from_f64([next(), next(), next()]);
            if let Some(u) = v.normalized_or_none(tiny) {
                return u;
            }
        };
        for _ in 0..20_000 {
            let (a, b) = (unit(), unit());
            assert_eq!(a.cross_coef(b), a.cross(b));
            assert_eq!(a.dot_coef(b), a.dot(b));
            let la = a.cross_coef(b);
            assert_eq!(
                la.normalized_or_none_coef(tiny),
                la.normalized_or_none(tiny)
            );
        }
        // Components of one or more in magnitude take the plain products.
        let big = Vec3::<Fx>::from_f64([3.0, -4.0, 0.5]);
        assert_eq!(
            big.normalized_or_none_coef(tiny),
            big.normalized_or_none(tiny)
        );
        assert_eq!(Vec3::<Fx>::ZERO.normalized_or_none_coef(tiny), None);
    }
}
