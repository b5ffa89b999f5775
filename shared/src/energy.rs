//! Mechanical energy of the brush (joules), for the stability and passivity checks.

use crate::brush::Brush;
use crate::scalar::Scalar;

/// The brush's energy split by where it is stored.
#[derive(Copy, Clone, Debug, PartialEq, Default)]
pub struct Energy {
    /// Kinetic energy of the free masses, relative to the handle frame's motion not removed:
    /// in the world frame.
    pub kinetic: f64,
    /// Energy in the stretched or compressed spine springs.
    pub axial: f64,
    /// Energy in the ties between spine masses and skeleton nodes, each weighted as the model
    /// weights it (0 on the paper).
    pub tie: f64,
}

impl Energy {
    pub fn total(&self) -> f64 {
        self.kinetic + self.axial + self.tie
    }
}

/// Computes the energy in `f64` from any scalar type's state.
pub fn energy<S: Scalar>(b: &Brush<S>) -> Energy {
    let p = b.params();
    let n = b.len();
    let h = p.substep_s() as f64;
    let m = p.mass_g as f64 * 1e-3 / (n as f64 - 1.0);
    let ks = p.axial_stiffness as f64;
    let kt = p.tie_stiffness as f64;
    let l = b.segment_mm();
    let spine = b.spine();
    let vel = b.velocities();
    let skel = b.skeleton();
    let mut e = Energy::default();
    for i in 1..n {
        let u = vel[i].to_f64();
        let v2 = (u[0] * u[0] + u[1] * u[1] + u[2] * u[2]) * 1e-6 / (h * h);
        e.kinetic += 0.5 * m * v2;
        let d = (spine[i] - spine[i - 1]).to_f64();
        let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        let stretch = (len - l) * 1e-3;
        let k = if stretch < 0.0 {
            ks * p.compression_ratio as f64
        } else {
            ks
        };
        e.axial += 0.5 * k * stretch * stretch;
        let t = (spine[i] - skel[i]).to_f64();
        let w = b.tie_weight(i).to_f64();
        e.tie += 0.5 * w * kt * (t[0] * t[0] + t[1] * t[1] + t[2] * t[2]) * 1e-6;
    }
    e
}
