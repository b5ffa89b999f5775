//! The spine's parameters, in the units the paper states them (Baxter & Lin §5): millimetres,
//! newtons, N mm/rad for the joint springs, N mm for the joint friction.

use core::fmt;

use super::chain::MAX_JOINTS;
use crate::vec::Vec3;

/// Everything that defines one spine. [`SpineParams::DEFAULT`] is the paper's scale;
/// [`SpineParams::validate`] names the first bad field.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct SpineParams {
    /// J: joints in the chain (the paper's spines have 3), each bending the segment below it.
    pub joints: u8,
    /// Length from the root to the tip, split into J equal segments (mm).
    pub length_mm: f64,
    /// The root on the ferrule in the handle frame (mm; the ferrule's centre is the origin,
    /// the hair leaves along -z). A brush of several spines gives each its own root.
    pub root_mm: [f64; 3],
    /// Which way the spine points at rest, in the handle frame: `[0, 0, -1]` hangs it
    /// straight down the handle; a head's spines lean (the round head's ring toward its
    /// point, the fan's outward). Only its direction counts: any finite, non-zero vector
    /// not pointing up into the handle (z at most 0) is accepted and normalised
    /// ([`SpineParams::rest_direction`]). Each joint's bend is measured from the frame the
    /// shortest-arc rotation from -z to this direction turns the handle's into, so a spine in
    /// free air points along it.
    pub root_direction: [f64; 3],
    /// K_1, the spring of the joint at the root (N mm/rad). The joints' springs fall
    /// geometrically from it to `stiffness_tip`: the hair is thicker and packed tighter near
    /// the ferrule (§3.3).
    pub stiffness_root: f64,
    /// K_J, the spring of the last joint (N mm/rad), at most `stiffness_root`.
    pub stiffness_tip: f64,
    /// D of eq. 15, every joint's friction torque (N mm): plasticity. 0 is a perfectly
    /// elastic spine; a joint released from a bend stops where its spring's torque `K beta`
    /// falls to D.
    pub joint_friction: f64,
    /// mu_s: the paper's friction coefficient while a contact sticks (§3.4.1).
    pub friction_static: f64,
    /// mu_k: the coefficient while it slides, at most `friction_static`.
    pub friction_kinetic: f64,
    /// C_eta of eq. 14: how much of the friction a contact loses when it moves in the hair's
    /// preferred direction (0 isotropic, 1 frictionless that way).
    pub anisotropy: f64,
    /// k of eq. 14: how narrowly the easy direction is focused (at least 2, so the
    /// friction energy stays continuously differentiable).
    pub anisotropy_exponent: f64,
    /// A sticking contact slips when a solve moves it farther than this from where it stuck
    /// (mm).
    pub slip_mm: f64,
    /// A sliding contact sticks again when it moves slower than this over a solve (mm/s):
    /// the hysteresis of §3.4.1. A speed, not a distance per solve, so that whether a
    /// contact catches does not depend on how often the spine is solved.
    pub stick_speed_mm_s: f64,
    /// Most SQP iterations of one minimisation.
    pub max_iterations: u8,
}

impl SpineParams {
    /// The paper's scale (§5): K of 5-10 N mm/rad, mu 0.3-0.5, D of 0.01 N mm, on a 3-joint
    /// spine 30 mm long that 1-2 N across its tip bends 70-90 degrees
    /// (`tests/baxter_lin.rs`).
    pub const DEFAULT: SpineParams = SpineParams {
        joints: 3,
        length_mm: 30.0,
        root_mm: [0.0; 3],
        root_direction: [0.0, 0.0, -1.0],
        stiffness_root: 10.0,
        stiffness_tip: 5.0,
        joint_friction: 0.01,
        friction_static: 0.5,
        friction_kinetic: 0.3,
        anisotropy: 0.5,
        anisotropy_exponent: 4.0,
        slip_mm: 0.01,
        stick_speed_mm_s: 2.0,
        max_iterations: 30,
    };

    /// The paper's spine ([`Self::DEFAULT`]) with the hair of Liang's preset `p`: its
    /// joints' springs scaled by `p`'s bending stiffness (its ties to the skeleton,
    /// `tie_stiffness`) over the `large` preset's, whose head the paper's K (§5) is taken
    /// for. So wolf hair (狼毫) is stiffer and goat hair (羊毫) softer in either model, in
    /// the same proportion. (Their spring, Liang's damping, has no counterpart here: each
    /// solve is quasi-static.)
    pub fn of_hair(p: &crate::params::BrushParams) -> SpineParams {
        let scale = p.tie_stiffness as f64 / crate::presets::LARGE.tie_stiffness as f64;
        let scale = if scale.is_finite() && scale > 0.0 {
            scale
        } else {
            1.0
        };
        SpineParams {
            stiffness_root: Self::DEFAULT.stiffness_root * scale,
            stiffness_tip: Self::DEFAULT.stiffness_tip * scale,
            ..Self::DEFAULT
        }
    }

    /// The spring constant K_i of joint `i` (0-based, N mm/rad).
    pub fn stiffness(&self, i: usize) -> f64 {
        let j = self.joints.max(1) as usize;
        if j == 1 {
            return self.stiffness_root;
        }
        let t = i.min(j - 1) as f64 / (j - 1) as f64;
        self.stiffness_root * libm::pow(self.stiffness_tip / self.stiffness_root, t)
    }

    /// Length of one segment (mm).
    pub fn segment_mm(&self) -> f64 {
        self.length_mm / self.joints.max(1) as f64
    }

    /// [`SpineParams::root_direction`] as a unit vector, or `None` if it has no direction
    /// (zero or not finite). Scaled by its largest component first, so no finite vector
    /// overflows or underflows on the way; `[0, 0, -1]` comes back exactly.
    pub fn rest_direction(&self) -> Option<Vec3<f64>> {
        let [x, y, z] = self.root_direction;
        let m = x.abs().max(y.abs()).max(z.abs());
        // `max` passes over a NaN, so every component is checked.
        if !(x.is_finite() && y.is_finite() && z.is_finite() && m > 0.0) {
            return None;
        }
        let d = Vec3::new(x / m, y / m, z / m);
        Some(d * (1.0 / d.norm()))
    }

    /// Checks every field and the relations between them; the error names the first bad one.
    pub fn validate(&self) -> Result<(), SpineParamError> {
        range("joints", self.joints as f64, 1.0, MAX_JOINTS as f64)?;
        range("length_mm", self.length_mm, 1.0, 200.0)?;
        for v in self.root_mm {
            range("root_mm", v, -50.0, 50.0)?;
        }
        for v in self.root_direction {
            if !v.is_finite() {
                return Err(SpineParamError::NotFinite {
                    field: "root_direction",
                });
            }
        }
        match self.rest_direction() {
            None => {
                return Err(SpineParamError::Inconsistent {
                    field: "root_direction",
                    why: "has zero length: it must give a direction",
                })
            }
            Some(d) if d.z > 0.0 => {
                return Err(SpineParamError::Inconsistent {
                    field: "root_direction",
                    why: "points up into the handle (z above 0)",
                })
            }
            Some(_) => {}
        }
        range("stiffness_root", self.stiffness_root, 0.01, 1.0e4)?;
        range("stiffness_tip", self.stiffness_tip, 0.01, 1.0e4)?;
        range("joint_friction", self.joint_friction, 0.0, 100.0)?;
        range("friction_static", self.friction_static, 0.0, 5.0)?;
        range("friction_kinetic", self.friction_kinetic, 0.0, 5.0)?;
        range("anisotropy", self.anisotropy, 0.0, 1.0)?;
        range("anisotropy_exponent", self.anisotropy_exponent, 2.0, 256.0)?;
        range("slip_mm", self.slip_mm, 1e-4, 10.0)?;
        range("stick_speed_mm_s", self.stick_speed_mm_s, 1e-3, 100.0)?;
        range("max_iterations", self.max_iterations as f64, 1.0, 200.0)?;
        if self.stiffness_tip > self.stiffness_root {
            return Err(SpineParamError::Inconsistent {
                field: "stiffness_tip",
                why: "the tip cannot be stiffer than the root",
            });
        }
        if self.friction_kinetic > self.friction_static {
            return Err(SpineParamError::Inconsistent {
                field: "friction_kinetic",
                why: "sliding friction cannot exceed the static friction",
            });
        }
        Ok(())
    }
}

impl Default for SpineParams {
    fn default() -> Self {
        Self::DEFAULT
    }
}

fn range(field: &'static str, value: f64, min: f64, max: f64) -> Result<(), SpineParamError> {
    if !value.is_finite() {
        return Err(SpineParamError::NotFinite { field });
    }
    if value < min || value > max {
        return Err(SpineParamError::OutOfRange {
            field,
            value,
            min,
            max,
        });
    }
    Ok(())
}

/// Why a [`SpineParams`] was rejected, naming the field.
#[derive(Copy, Clone, Debug, PartialEq)]
pub enum SpineParamError {
    NotFinite {
        field: &'static str,
    },
    OutOfRange {
        field: &'static str,
        value: f64,
        min: f64,
        max: f64,
    },
    /// Values that are each valid but not together.
    Inconsistent {
        field: &'static str,
        why: &'static str,
    },
}

impl SpineParamError {
    /// The field at fault.
    pub fn field(&self) -> &'static str {
        match *self {
            SpineParamError::NotFinite { field }
            | SpineParamError::OutOfRange { field, .. }
            | SpineParamError::Inconsistent { field, .. } => field,
        }
    }
}

impl fmt::Display for SpineParamError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            SpineParamError::NotFinite { field } => {
                write!(f, "{field}: value is not a finite number")
            }
            SpineParamError::OutOfRange {
                field,
                value,
                min,
                max,
            } => write!(
                f,
                "{field}: {value} is outside the valid range {min} ..= {max}"
            ),
            SpineParamError::Inconsistent { field, why } => write!(f, "{field}: {why}"),
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for SpineParamError {}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_is_valid_and_stiffer_at_the_root() {
        let p = SpineParams::DEFAULT;
        assert_eq!(p.validate(), Ok(()));
        assert!((p.stiffness(0) - 10.0).abs() < 1e-12);
        assert!((p.stiffness(2) - 5.0).abs() < 1e-12);
        assert!(p.stiffness(1) < p.stiffness(0) && p.stiffness(1) > p.stiffness(2));
    }

    #[test]
    fn errors_name_the_field() {
        let mut p = SpineParams::DEFAULT;
        p.joints = 9;
        assert_eq!(p.validate().unwrap_err().field(), "joints");
        let mut p = SpineParams::DEFAULT;
        p.friction_kinetic = 0.6;
        assert_eq!(p.validate().unwrap_err().field(), "friction_kinetic");
        let mut p = SpineParams::DEFAULT;
        p.length_mm = f64::NAN;
        assert_eq!(
            p.validate(),
            Err(SpineParamError::NotFinite { field: "length_mm" })
        );
        let mut p = SpineParams::DEFAULT;
        p.stiffness_tip = 20.0;
        assert_eq!(p.validate().unwrap_err().field(), "stiffness_tip");
        let mut p = SpineParams::DEFAULT;
        p.stick_speed_mm_s = 0.0;
        assert_eq!(p.validate().unwrap_err().field(), "stick_speed_mm_s");
        for bad in [
            [0.0; 3],
            [0.0, f64::NAN, -1.0],
            [0.0, 0.0, f64::INFINITY],
            [0.1, 0.0, 0.5],
        ] {
            let mut p = SpineParams::DEFAULT;
            p.root_direction = bad;
            assert_eq!(
                p.validate().unwrap_err().field(),
                "root_direction",
                "{bad:?}"
            );
        }
    }

    #[test]
    fn rest_direction_is_normalised_and_the_default_exact() {
        let mut p = SpineParams::DEFAULT;
        assert_eq!(p.rest_direction(), Some(-Vec3::Z));
        p.root_direction = [0.0, 0.0, -1e-300];
        assert_eq!(p.rest_direction(), Some(-Vec3::Z));
        p.root_direction = [3e300, 0.0, -4e300];
        let d = p.rest_direction().unwrap();
        assert!((d - Vec3::new(0.6, 0.0, -0.8)).norm() < 1e-15, "{d:?}");
        // Lying across the ferrule's plane is allowed; pointing into the handle is not.
        p.root_direction = [1.0, 0.0, 0.0];
        assert_eq!(p.validate(), Ok(()));
    }
}
