//! Orientation interpolation: directions along great circles at constant angular speed
//! (Sheu 1989, §4.4), unit quaternions by slerp and squad (Shoemake 1985) for the full pose,
//! and the handle's tilt and azimuth.
//!
//! Quaternions are `[w, x, y, z]` (Hamilton), as in [`crate::Quat`]; the identity holds the
//! brush straight down.

/// A unit quaternion `[w, x, y, z]`.
pub type Q = [f64; 4];

const EPS: f64 = 1e-12;

fn dot4(a: &Q, b: &Q) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3]
}

/// Scales `q` to unit length (the identity for a zero quaternion).
pub fn normalize(q: Q) -> Q {
    let n = libm::sqrt(dot4(&q, &q));
    if n > 0.0 && n.is_finite() {
        [q[0] / n, q[1] / n, q[2] / n, q[3] / n]
    } else {
        [1.0, 0.0, 0.0, 0.0]
    }
}

/// Hamilton product `a * b`.
pub fn mul(a: Q, b: Q) -> Q {
    [
        a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3],
        a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
        a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1],
        a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0],
    ]
}

/// The conjugate (the inverse of a unit quaternion).
pub fn conj(q: Q) -> Q {
    [q[0], -q[1], -q[2], -q[3]]
}

/// Rotates `v` by the unit quaternion `q`.
pub fn rotate(q: Q, v: [f64; 3]) -> [f64; 3] {
    let p = mul(mul(q, [0.0, v[0], v[1], v[2]]), conj(q));
    [p[1], p[2], p[3]]
}

/// Angle between two orientations (radians, in [0, pi]), `q` and `-q` being the same.
pub fn angle_between(a: Q, b: Q) -> f64 {
    let d = libm::fabs(dot4(&a, &b)).min(1.0);
    2.0 * libm::acos(d)
}

/// Logarithm of a unit quaternion: the pure quaternion `theta/2 * axis`.
fn log(q: Q) -> [f64; 3] {
    let v = libm::sqrt(q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    if v < EPS {
        return [0.0; 3];
    }
    let th = libm::atan2(v, q[0]);
    [q[1] * th / v, q[2] * th / v, q[3] * th / v]
}

/// Exponential of a pure quaternion.
fn exp(v: [f64; 3]) -> Q {
    let th = libm::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    if th < EPS {
        return normalize([1.0, v[0], v[1], v[2]]);
    }
    let s = libm::sin(th) / th;
    [libm::cos(th), v[0] * s, v[1] * s, v[2] * s]
}

/// Spherical linear interpolation from `a` (h = 0) to `b` (h = 1) along the shorter arc, at
/// constant angular speed.
pub fn slerp(a: Q, b: Q, h: f64) -> Q {
    let mut d = dot4(&a, &b);
    let b = if d < 0.0 {
        d = -d;
        [-b[0], -b[1], -b[2], -b[3]]
    } else {
        b
    };
    if d > 1.0 - 1e-12 {
        let q = [
            a[0] + (b[0] - a[0]) * h,
            a[1] + (b[1] - a[1]) * h,
            a[2] + (b[2] - a[2]) * h,
            a[3] + (b[3] - a[3]) * h,
        ];
        return normalize(q);
    }
    let th = libm::acos(d.min(1.0));
    let s = libm::sin(th);
    let wa = libm::sin((1.0 - h) * th) / s;
    let wb = libm::sin(h * th) / s;
    normalize([
        wa * a[0] + wb * b[0],
        wa * a[1] + wb * b[1],
        wa * a[2] + wb * b[2],
        wa * a[3] + wb * b[3],
    ])
}

/// Flips the signs of `qs` in place so each is in the hemisphere of the one before it.
pub fn make_continuous(qs: &mut [Q]) {
    for i in 1..qs.len() {
        if dot4(&qs[i - 1], &qs[i]) < 0.0 {
            qs[i] = qs[i].map(|c| -c);
        }
    }
}

/// Squad's inner control quaternion at key `i` of `qs` (which must be sign-continuous):
/// `s_i = q_i exp(-(log(q_i^-1 q_{i+1}) + log(q_i^-1 q_{i-1})) / 4)`; the end keys use
/// themselves as their missing neighbour.
pub fn squad_control(qs: &[Q], i: usize) -> Q {
    let q = qs[i];
    let prev = if i == 0 { q } else { qs[i - 1] };
    let next = if i + 1 >= qs.len() { q } else { qs[i + 1] };
    let inv = conj(q);
    let l1 = log(mul(inv, next));
    let l0 = log(mul(inv, prev));
    normalize(mul(
        q,
        exp([
            -(l1[0] + l0[0]) / 4.0,
            -(l1[1] + l0[1]) / 4.0,
            -(l1[2] + l0[2]) / 4.0,
        ]),
    ))
}

/// Squad between keys `q0` and `q1` with inner controls `s0`, `s1` at `h` in [0, 1]:
/// `slerp(slerp(q0, q1, h), slerp(s0, s1, h), 2h(1 - h))`. Passes through the keys, C1 across
/// them when the controls come from [`squad_control`].
pub fn squad(q0: Q, q1: Q, s0: Q, s1: Q, h: f64) -> Q {
    slerp(slerp(q0, q1, h), slerp(s0, s1, h), 2.0 * h * (1.0 - h))
}

/// Great-circle interpolation between unit directions `d0` (h = 0) and `d1` (h = 1) at
/// constant angular speed (Sheu §4.4: the point on the chord, pushed out to the sphere, with
/// the chord parameter chosen so that equal steps in `h` sweep equal angles). Antipodal
/// directions have no unique great circle; one through the x-y plane's normal (or x) is taken.
pub fn great_circle(d0: [f64; 3], d1: [f64; 3], h: f64) -> [f64; 3] {
    let c = (d0[0] * d1[0] + d0[1] * d1[1] + d0[2] * d1[2]).clamp(-1.0, 1.0);
    let th = libm::acos(c);
    if th < 1e-9 {
        return d0;
    }
    // The component of d1 orthogonal to d0, normalised.
    let mut w = [d1[0] - c * d0[0], d1[1] - c * d0[1], d1[2] - c * d0[2]];
    let mut wn = libm::sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]);
    if wn < 1e-9 {
        // Antipodal: any perpendicular.
        let axis = if libm::fabs(d0[2]) < 0.9 {
            [0.0, 0.0, 1.0]
        } else {
            [1.0, 0.0, 0.0]
        };
        let k = axis[0] * d0[0] + axis[1] * d0[1] + axis[2] * d0[2];
        w = [
            axis[0] - k * d0[0],
            axis[1] - k * d0[1],
            axis[2] - k * d0[2],
        ];
        wn = libm::sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]);
    }
    let (s, co) = (libm::sin(h * th), libm::cos(h * th));
    [
        co * d0[0] + s * w[0] / wn,
        co * d0[1] + s * w[1] / wn,
        co * d0[2] + s * w[2] / wn,
    ]
}

/// The orientation for a handle tilted `tilt` radians from vertical, its top leaning toward
/// the compass direction `azimuth` (radians counter-clockwise from +x), turned `roll` radians
/// about its own axis: `q = q_tilt * q_roll`. The ferrule then lies above the tip, offset
/// toward `azimuth`.
pub fn from_tilt_azimuth(tilt: f64, azimuth: f64, roll: f64) -> Q {
    let (sh, ch) = (libm::sin(tilt / 2.0), libm::cos(tilt / 2.0));
    // Axis z x h = (-sin az, cos az, 0) takes +z to the handle direction h.
    let qt = [ch, -libm::sin(azimuth) * sh, libm::cos(azimuth) * sh, 0.0];
    let qr = [libm::cos(roll / 2.0), 0.0, 0.0, libm::sin(roll / 2.0)];
    normalize(mul(qt, qr))
}

/// The handle's tilt from vertical and the azimuth its top leans toward (radians), the
/// inverse of [`from_tilt_azimuth`] for the axis (roll is not recovered). Azimuth is 0 for an
/// upright handle.
pub fn tilt_azimuth(q: Q) -> (f64, f64) {
    let h = rotate(q, [0.0, 0.0, 1.0]);
    let tilt = libm::acos(h[2].clamp(-1.0, 1.0));
    let az = if libm::hypot(h[0], h[1]) < 1e-12 {
        0.0
    } else {
        libm::atan2(h[1], h[0])
    };
    (tilt, az)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tilt_azimuth_round_trip_and_convention() {
        // A handle leaning toward -y by 15 degrees is a rotation about +x (the examples' shu).
        let q = from_tilt_azimuth(15f64.to_radians(), -90f64.to_radians(), 0.0);
        assert!((q[0] - 0.991444861).abs() < 1e-8 && (q[1] - 0.130526192).abs() < 1e-8);
        let (t, a) = tilt_azimuth(q);
        assert!((t.to_degrees() - 15.0).abs() < 1e-9 && (a.to_degrees() + 90.0).abs() < 1e-9);
    }

    #[test]
    fn squad_passes_through_keys() {
        let qs = [
            from_tilt_azimuth(0.2, 0.0, 0.0),
            from_tilt_azimuth(0.4, 1.0, 0.1),
            from_tilt_azimuth(0.1, 2.0, -0.2),
        ];
        let s0 = squad_control(&qs, 0);
        let s1 = squad_control(&qs, 1);
        assert!(angle_between(squad(qs[0], qs[1], s0, s1, 0.0), qs[0]) < 1e-9);
        assert!(angle_between(squad(qs[0], qs[1], s0, s1, 1.0), qs[1]) < 1e-9);
    }
}
