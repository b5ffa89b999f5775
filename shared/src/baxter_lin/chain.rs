//! Spine kinematics (Baxter & Lin eqs. 10-11): the joint positions of a chain of XYZ-Euler
//! joints and their first and second derivatives in the joint angles.
//!
//! Joint `k` (0-based; the paper's joint k + 1) sits at `x[k]` and turns segment `k`, of
//! length `l_k`, by `R(theta_k, phi_k) = Ry(phi_k) Rx(theta_k)` (eq. 10) relative to its
//! parent's frame: the frames are `F_0 = R_handle R_rest`, `F_{k+1} = F_k R(theta_k, phi_k)`,
//! and the segment points along its frame's -z, so `x[k + 1] = x[k] + F_{k+1} (0, 0, -l_k)`
//! (eq. 11). `x[0]` is the root on the ferrule. `R_rest` is the fixed rotation that takes the
//! handle's -z to the spine's rest direction ([`Mat3::rest`]): at rest (all angles 0) the
//! spine points along it, and each joint's bend is measured from it. A spine hanging straight
//! down the handle has `F_0 = R_handle` itself.
//!
//! The variables are ordered as the rotations compose, `[phi_0, theta_0, phi_1, theta_1,
//! ...]`: `phi_k` turns about `F_k`'s y axis and carries `theta_k`'s axis `F_{k+1}`'s x with
//! it. With every variable a revolute joint about a world axis `a_v` through `x[v / 2]`,
//!
//! ```text
//! d x_i / d q_v          = a_v x (x_i - x[v/2])                     (v < 2 i)
//! d^2 x_i / d q_u d q_v  = a_u x (a_v x (x_i - x[v/2]))              (u <= v < 2 i)
//! ```
//!
//! the second because turning about an earlier axis `a_u` carries `a_v`, its pivot and `x_i`
//! rigidly. `x_i` does not depend on the variables of joints at or past it. The axes are
//! those of the frames built from `F_0`, so the derivatives carry the rest rotation with them.

// The second derivatives fill a matrix by its row and column indices.
#![allow(clippy::needless_range_loop)]

use crate::quat::Quat;
use crate::vec::Vec3;

/// Most joints a spine may have.
pub const MAX_JOINTS: usize = 8;
/// Most joint angles (two per joint).
pub(crate) const MAX_VARS: usize = 2 * MAX_JOINTS;

pub(crate) type V3 = Vec3<f64>;

/// A rotation matrix by its columns (the images of x, y, z).
#[derive(Copy, Clone, Debug, PartialEq)]
pub(crate) struct Mat3 {
    pub c: [V3; 3],
}

impl Mat3 {
    pub fn from_quat(q: Quat<f64>) -> Self {
        Mat3 {
            c: [q.rotate(V3::X), q.rotate(V3::Y), q.rotate(V3::Z)],
        }
    }
    #[inline]
    pub fn apply(&self, v: V3) -> V3 {
        self.c[0] * v.x + self.c[1] * v.y + self.c[2] * v.z
    }
    #[inline]
    pub fn then(&self, o: &Mat3) -> Mat3 {
        Mat3 {
            c: [self.apply(o.c[0]), self.apply(o.c[1]), self.apply(o.c[2])],
        }
    }
    /// The shortest-arc rotation taking -z to the unit vector `d` (the spine's rest
    /// direction in the handle frame), for `d.z <= 0`: a turn by `acos(-d.z)` about
    /// `-z x d`. By Rodrigues' formula with `v = -z x d = (d.y, -d.x, 0)` and `c = -d.z`,
    /// `R e = c e + v x e + v (v . e) / (1 + c)`; `1 + c >= 1` on the allowed half-space.
    pub fn rest(d: V3) -> Mat3 {
        let v = V3::new(d.y, -d.x, 0.0);
        let c = -d.z;
        let turn = |e: V3| e * c + v.cross(e) + v * (v.dot(e) / (1.0 + c));
        Mat3 {
            c: [turn(V3::X), turn(V3::Y), turn(V3::Z)],
        }
    }
    /// Eq. 10: `Ry(phi) Rx(theta)`, by columns.
    #[inline]
    pub fn joint(theta: f64, phi: f64) -> Mat3 {
        let (st, ct) = libm::sincos(theta);
        let (sp, cp) = libm::sincos(phi);
        Mat3 {
            c: [
                V3::new(cp, 0.0, -sp),
                V3::new(sp * st, ct, cp * st),
                V3::new(sp * ct, -st, cp * ct),
            ],
        }
    }
}

/// The root frame `F_0 = R_handle R_rest` of the handle's frame and a spine's rest rotation;
/// `None` for a spine hanging straight down the handle, whose root frame is the handle's
/// own (not a product with the identity, which could flip the sign of a zero).
pub fn root_frame(handle: &Mat3, rest: Option<&Mat3>) -> Mat3 {
    match rest {
        Some(r) => handle.then(r),
        None => *handle,
    }
}

/// One evaluation of the chain's forward kinematics.
#[derive(Copy, Clone, Debug)]
pub(crate) struct Chain {
    pub joints: usize,
    /// Joint positions, `x[0]` the root, `x[joints]` the tip (mm, world).
    pub x: [V3; MAX_JOINTS + 1],
    /// World rotation axis of each variable.
    pub axis: [V3; MAX_VARS],
}

impl Chain {
    /// Forward kinematics of angles `q` (variable order of the module docs) from the root
    /// frame `frame`, `F_0 = R_handle R_rest`.
    pub fn new(root: V3, frame: &Mat3, lengths: &[f64], q: &[f64]) -> Chain {
        let joints = lengths.len().min(MAX_JOINTS);
        let mut c = Chain {
            joints,
            x: [V3::ZERO; MAX_JOINTS + 1],
            axis: [V3::ZERO; MAX_VARS],
        };
        c.x[0] = root;
        let mut frame = *frame;
        for k in 0..joints {
            let (phi, theta) = (q[2 * k], q[2 * k + 1]);
            c.axis[2 * k] = frame.c[1];
            frame = frame.then(&Mat3::joint(theta, phi));
            c.axis[2 * k + 1] = frame.c[0];
            c.x[k + 1] = c.x[k] - frame.c[2] * lengths[k];
        }
        c
    }

    /// Number of variables.
    pub fn vars(&self) -> usize {
        2 * self.joints
    }

    /// `d x_i / d q_v` (zero for a variable at or past joint i).
    #[inline]
    pub fn d(&self, i: usize, v: usize) -> V3 {
        if v < 2 * i {
            self.axis[v].cross(self.x[i] - self.x[v / 2])
        } else {
            V3::ZERO
        }
    }

    /// `sum_{u,v} w . d^2 x_i / d q_u d q_v` added into `h` (both triangles): the
    /// curvature of a term whose gradient in `x_i` is `w`.
    pub fn add_curvature(&self, i: usize, w: V3, h: &mut [[f64; MAX_VARS]; MAX_VARS]) {
        let n = (2 * i).min(self.vars());
        for v in 0..n {
            let t = self.axis[v].cross(self.x[i] - self.x[v / 2]);
            for u in 0..=v {
                let e = w.dot(self.axis[u].cross(t));
                h[u][v] += e;
                if u != v {
                    h[v][u] += e;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn handle() -> Mat3 {
        let h = 0.3f64;
        let axis = V3::new(0.3, -0.5, 0.8);
        let axis = axis * (1.0 / axis.norm());
        Mat3::from_quat(Quat::new(
            h.cos(),
            axis.x * h.sin(),
            axis.y * h.sin(),
            axis.z * h.sin(),
        ))
    }

    const L: [f64; 4] = [4.0, 3.0, 2.5, 2.0];
    const Q: [f64; 8] = [0.2, -0.4, 0.7, 0.1, -0.3, 0.5, 0.05, -0.6];

    #[test]
    fn eq10_bends_by_beta() {
        // The segment's axis leans from its parent's by beta = acos(cos theta cos phi) (eq. 12).
        for &(t, p) in &[(0.3, 0.0), (0.0, 0.4), (0.5, -0.7), (-1.2, 0.9)] {
            let r = Mat3::joint(t, p);
            let cosb = r.c[2].z;
            assert!((cosb - libm::cos(t) * libm::cos(p)).abs() < 1e-15);
            // A rotation: orthonormal columns.
            assert!((r.c[0].cross(r.c[1]) - r.c[2]).norm() < 1e-15);
        }
    }

    /// Rest directions in the handle frame: straight down (the handle's own frame), the
    /// fan's outermost spine (35 degrees in the y-z plane), a round head's ring spine, a
    /// skew one, and one lying across the ferrule's plane.
    fn directions() -> [V3; 5] {
        let fan = 35f64.to_radians();
        let skew = V3::new(0.4, -0.3, -0.8);
        [
            -V3::Z,
            V3::new(0.0, libm::sin(fan), -libm::cos(fan)),
            V3::new(-3.0, 0.0, -40.0) * (1.0 / libm::hypot(3.0, 40.0)),
            skew * (1.0 / skew.norm()),
            V3::X,
        ]
    }

    fn frames() -> [Mat3; 5] {
        let h = handle();
        directions().map(|d| {
            if d == -V3::Z {
                root_frame(&h, None)
            } else {
                root_frame(&h, Some(&Mat3::rest(d)))
            }
        })
    }

    #[test]
    fn rest_rotation_takes_down_to_the_direction() {
        for d in directions() {
            let r = Mat3::rest(d);
            let err = (r.apply(-V3::Z) - d).norm();
            // A rotation: orthonormal, right-handed columns.
            let ortho = (r.c[0].cross(r.c[1]) - r.c[2]).norm()
                + (r.c[0].norm() - 1.0).abs()
                + (r.c[1].norm() - 1.0).abs();
            assert!(err < 1e-15 && ortho < 1e-15, "{d:?}: {err} {ortho}");
            // The shortest arc: the turn's axis is perpendicular to both -z and d, so a
            // vector along that axis is left where it is.
            let axis = V3::new(d.y, -d.x, 0.0);
            assert!((r.apply(axis) - axis).norm() < 1e-15);
        }
    }

    #[test]
    fn rest_chain_hangs_along_its_rest_direction() {
        let h = handle();
        for (d, f) in directions().into_iter().zip(frames()) {
            let c = Chain::new(V3::new(1.0, 2.0, 30.0), &f, &L, &[0.0; 8]);
            // The handle's rotation of the rest direction.
            let along = h.apply(d);
            let tip = c.x[4] - c.x[0];
            assert!((tip - along * 11.5).norm() < 1e-12, "{d:?}: {tip:?}");
        }
    }

    #[test]
    fn derivatives_match_finite_differences() {
        for f in frames() {
            derivatives_match_finite_differences_from(&f);
        }
    }

    fn derivatives_match_finite_differences_from(h: &Mat3) {
        let root = V3::new(1.0, 2.0, 30.0);
        let c = Chain::new(root, h, &L, &Q);
        let step = 1e-6;
        for v in 0..8 {
            let mut qp = Q;
            let mut qm = Q;
            qp[v] += step;
            qm[v] -= step;
            let cp = Chain::new(root, h, &L, &qp);
            let cm = Chain::new(root, h, &L, &qm);
            for i in 0..=4 {
                let fd = (cp.x[i] - cm.x[i]) * (0.5 / step);
                let err = (fd - c.d(i, v)).norm();
                assert!(err < 1e-8, "d x_{i} / d q_{v}: {err}");
                // Second derivatives: the curvature of w . x_i against differences of the
                // analytic first derivatives.
                for w in [V3::X, V3::Y, V3::Z] {
                    let mut hh = [[0.0; MAX_VARS]; MAX_VARS];
                    c.add_curvature(i, w, &mut hh);
                    for u in 0..8 {
                        let fd2 = (cp.d(i, u) - cm.d(i, u)).dot(w) * (0.5 / step);
                        assert!(
                            (fd2 - hh[u][v]).abs() < 1e-7,
                            "x_{i} {u} {v}: {fd2} {}",
                            hh[u][v]
                        );
                    }
                }
            }
        }
    }
}
