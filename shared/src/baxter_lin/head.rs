//! Brush heads as sets of spines (004 §3, §4.2): where each spine is rooted in the ferrule,
//! which way it points at rest, how long it is and what bundle of hair it carries. Baxter &
//! Lin model a brush's shape by its spines, "generally less than ten", and name the shapes a
//! painter picks between; [`HeadShape`] holds the round brush of Chinese calligraphy and the
//! paper's flat, filbert and fan.
//!
//! Frame: the handle's (the ferrule's centre at the origin, the brush pointing along -z at
//! rest, a flat brush's width along y: the axis the app and the footprint call the ferrule's
//! long axis). Millimetres.
//!
//! Sizes (typical catalogue sizes; the round head's are the `large` preset's):
//! * round (大楷): 40 mm of hair, 6 mm in radius at the ferrule, tapering to a point;
//! * flat (a size-12 flat): 18 mm of hair, 12 mm wide and 3 mm thick at the ferrule, square
//!   ended, its chisel edge a little thinner than the ferrule;
//! * filbert (a size-12 filbert): the flat's size with an oval end, its outer hairs shorter;
//! * fan (a size-6 fan): 22 mm of hair from a 10 mm ferrule, spread to about 35 degrees on
//!   either side, 1.2 mm thick.

use core::fmt;

use super::params::SpineParams;
use super::skin::{Bundle, MAX_SPINES};
use crate::vec::Vec3;

/// A brush head's shape.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub enum HeadShape {
    /// The calligraphy brush: a cone of hair to a point (a centre spine and a ring of six).
    Round,
    /// Hair in a row across the ferrule, square ended: a wide stroke across its flat side, a
    /// thin one along it.
    Flat,
    /// A flat with an oval end: its outer spines are shorter.
    Filbert,
    /// A thin row of hair spread like a fan.
    Fan,
}

/// Every shape by its name, as `--brush` and error messages spell them.
pub const SHAPES: [(&str, HeadShape); 4] = [
    ("round", HeadShape::Round),
    ("flat", HeadShape::Flat),
    ("filbert", HeadShape::Filbert),
    ("fan", HeadShape::Fan),
];

impl HeadShape {
    /// The shape called `name`, or the error that lists the names.
    pub fn from_name(name: &str) -> Result<HeadShape, UnknownShape<'_>> {
        SHAPES
            .iter()
            .find(|(n, _)| *n == name)
            .map(|(_, s)| *s)
            .ok_or(UnknownShape(name))
    }

    /// The shape's name.
    pub fn name(self) -> &'static str {
        SHAPES
            .iter()
            .find(|(_, s)| *s == self)
            .map_or("round", |(n, _)| n)
    }

    /// The shape's head at its catalogue size (see the module docs).
    pub fn head(self) -> Head {
        match self {
            HeadShape::Round => Head::round(40.0, 6.0, 0.15, 0.5),
            HeadShape::Flat => Head::flat(12.0, 3.0, 18.0, 1.0),
            HeadShape::Filbert => Head::flat(12.0, 3.0, 18.0, 0.7),
            HeadShape::Fan => Head::fan(10.0, 1.2, 22.0, 35.0),
        }
    }
}

/// A shape name that is none of [`SHAPES`] (it displays the valid names).
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub struct UnknownShape<'a>(pub &'a str);

impl fmt::Display for UnknownShape<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "unknown brush shape `{}`; valid shapes: ", self.0)?;
        for (i, (name, _)) in SHAPES.iter().enumerate() {
            if i > 0 {
                f.write_str(", ")?;
            }
            f.write_str(name)?;
        }
        Ok(())
    }
}

impl core::error::Error for UnknownShape<'_> {}

/// One spine of a head, at rest in the handle's frame.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct SpineRoot {
    /// Where it leaves the ferrule (mm; z = 0, the ferrule's mouth).
    pub position: Vec3<f64>,
    /// Which way it points at rest (unit; about -z).
    pub direction: Vec3<f64>,
    /// Its length (mm).
    pub length_mm: f64,
    /// The hair it carries.
    pub bundle: Bundle,
    /// Its share of the head's hair, by the bundle's cross-section at the ferrule (the shares
    /// sum to one): a spine's stiffness and the ink it holds are this share of the head's.
    pub share: f64,
}

impl SpineRoot {
    /// The [`SpineParams`] of this spine: `base` with this spine's root, rest direction and
    /// length, and its stiffnesses scaled by its [`share`](SpineRoot::share) of the hair.
    /// `base` describes the whole head's hair: its spines bend side by side, in parallel,
    /// so their springs add up to the base's. The joint friction, a torque of the same hair,
    /// is shared the same way, so each spine keeps the base's set (`D / K`). Friction
    /// coefficients, the solver's settings and the joint count are the base's.
    pub fn spine_params(&self, base: &SpineParams) -> SpineParams {
        SpineParams {
            length_mm: self.length_mm,
            root_mm: [self.position.x, self.position.y, self.position.z],
            root_direction: [self.direction.x, self.direction.y, self.direction.z],
            stiffness_root: base.stiffness_root * self.share,
            stiffness_tip: base.stiffness_tip * self.share,
            joint_friction: base.joint_friction * self.share,
            ..*base
        }
    }
}

/// A brush head: its spines.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct Head {
    spines: [SpineRoot; MAX_SPINES],
    count: usize,
}

impl Head {
    /// The head's spines.
    pub fn spines(&self) -> &[SpineRoot] {
        &self.spines[..self.count.min(MAX_SPINES)]
    }

    /// The longest spine's length (mm).
    pub fn length_mm(&self) -> f64 {
        self.spines()
            .iter()
            .map(|s| s.length_mm)
            .fold(0.0, f64::max)
    }

    /// A head of the given spines, their shares set from their bundles (at most
    /// [`MAX_SPINES`]; more are dropped).
    fn of(spines: &[SpineRoot]) -> Head {
        let placeholder = SpineRoot {
            position: Vec3::ZERO,
            direction: -Vec3::Z,
            length_mm: 0.0,
            bundle: Bundle {
                root_mm: 0.0,
                tip_mm: 0.0,
                belly: 0.0,
            },
            share: 0.0,
        };
        let mut head = Head {
            spines: [placeholder; MAX_SPINES],
            count: spines.len().min(MAX_SPINES),
        };
        head.spines[..head.count].copy_from_slice(&spines[..head.count]);
        let area: f64 = head
            .spines()
            .iter()
            .map(|s| s.bundle.root_mm * s.bundle.root_mm)
            .sum();
        for s in &mut head.spines[..head.count] {
            s.share = if area > 0.0 {
                s.bundle.root_mm * s.bundle.root_mm / area
            } else {
                1.0 / head.count as f64
            };
        }
        head
    }

    /// A round head `length` long, `radius` at the ferrule, `tip` at the point, swelling by
    /// `belly` (Liang's profile): a centre spine and six on a ring at half the radius, each
    /// carrying a bundle half the head's radius, so their envelope is the head. The ring's
    /// spines lean in to meet the centre's at the point, as a round brush's hairs gather to
    /// its tip.
    pub fn round(length: f64, radius: f64, tip: f64, belly: f64) -> Head {
        let bundle = Bundle {
            root_mm: radius / 2.0,
            tip_mm: tip,
            belly,
        };
        let point = Vec3::new(0.0, 0.0, -length);
        let mut spines = [SpineRoot {
            position: Vec3::ZERO,
            direction: -Vec3::Z,
            length_mm: length,
            bundle,
            share: 0.0,
        }; 7];
        for (k, s) in spines[1..].iter_mut().enumerate() {
            let angle = core::f64::consts::TAU * k as f64 / 6.0;
            let root = Vec3::new(libm::cos(angle), libm::sin(angle), 0.0).scale(radius / 2.0);
            let to_point = point - root;
            s.position = root;
            s.length_mm = to_point.norm();
            s.direction = to_point.scale(1.0 / s.length_mm);
        }
        Head::of(&spines)
    }

    /// A flat head `width` across (y) and `thickness` through (x) at the ferrule, `length`
    /// long: five spines in a row, each a bundle as thick as the head. `end` is the length of
    /// the outermost spines as a fraction of the middle one's along an oval: 1 for a
    /// square-ended flat, below one for a filbert's rounded end.
    pub fn flat(width: f64, thickness: f64, length: f64, end: f64) -> Head {
        // The chisel edge: a little thinner than the ferrule.
        Head::row::<5>(width, thickness, 0.6, |u, s| {
            // An oval end: the length falls from the middle's to `end` of it at the edges.
            s.length_mm = length * (end + (1.0 - end) * libm::sqrt(1.0 - u * u));
        })
    }

    /// A fan `ferrule` wide at the ferrule (y), `thickness` through, `length` long, its seven
    /// spines spread evenly to `spread_deg` on either side.
    pub fn fan(ferrule: f64, thickness: f64, length: f64, spread_deg: f64) -> Head {
        Head::row::<7>(ferrule, thickness, 0.5, |u, s| {
            let angle = (u * spread_deg).to_radians();
            s.length_mm = length;
            s.direction = Vec3::new(0.0, libm::sin(angle), -libm::cos(angle));
        })
    }

    /// `N` spines in a row across the ferrule's `width` (y), each a bundle as thick as the
    /// head (`thickness`, x) tapering to `tip_ratio` of it, the outer bundles' edges on the
    /// ferrule's edges, pointing down; `shape(u, spine)` then sets each spine's length and
    /// direction from its place `u` in [-1, 1] across the row.
    fn row<const N: usize>(
        width: f64,
        thickness: f64,
        tip_ratio: f64,
        shape: impl Fn(f64, &mut SpineRoot),
    ) -> Head {
        let half = thickness / 2.0;
        let reach = width / 2.0 - half;
        let mut spines = [SpineRoot {
            position: Vec3::ZERO,
            direction: -Vec3::Z,
            length_mm: 0.0,
            bundle: Bundle {
                root_mm: half,
                tip_mm: half * tip_ratio,
                belly: 0.0,
            },
            share: 0.0,
        }; N];
        for (k, s) in spines.iter_mut().enumerate() {
            let u = 2.0 * k as f64 / (N - 1) as f64 - 1.0;
            s.position = Vec3::new(0.0, u * reach, 0.0);
            shape(u, s);
        }
        Head::of(&spines)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::baxter_lin::Spine;
    use crate::{Pose, Quat};

    #[test]
    fn round_spines_hang_along_their_rest_directions_and_share_the_stiffness() {
        let base = SpineParams::DEFAULT;
        let head = HeadShape::Round.head();
        assert_eq!(head.spines().len(), 7);
        let (mut k_root, mut k_tip, mut d) = (0.0, 0.0, 0.0);
        for (n, root) in head.spines().iter().enumerate() {
            let p = root.spine_params(&base);
            assert_eq!(p.validate(), Ok(()));
            k_root += p.stiffness_root;
            k_tip += p.stiffness_tip;
            d += p.joint_friction;
            for tilt in [0.0f64, 30.0] {
                let h = tilt.to_radians() / 2.0;
                let rot = Quat::new(libm::cos(h), 0.0, libm::sin(h), 0.0);
                let pose = Pose::new(Vec3::new(2.0, -1.0, 80.0), rot);
                let s = Spine::new(p, pose).unwrap();
                let ferrule = pose.pos + rot.rotate(root.position);
                let tip = ferrule + rot.rotate(root.direction).scale(root.length_mm);
                let root_err = (s.position(0) - ferrule).norm();
                let tip_err = (s.position(s.joints()) - tip).norm();
                let bends: f64 = (0..s.joints()).map(|k| s.bend(k)).sum();
                assert!(
                    root_err < 1e-9 && tip_err < 1e-9 && bends == 0.0,
                    "spine {n} at {tilt} deg: root {root_err:e} tip {tip_err:e} mm, bends {bends}"
                );
            }
        }
        assert!((k_root - base.stiffness_root).abs() < 1e-12, "{k_root}");
        assert!((k_tip - base.stiffness_tip).abs() < 1e-12, "{k_tip}");
        assert!((d - base.joint_friction).abs() < 1e-15, "{d}");
    }
}
