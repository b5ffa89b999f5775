//! Baxter & Lin's brush as a whole: a head of spines ([`super::head`]), each solved against
//! the paper every tick ([`super::Spine`]), skinned into layer rings ([`super::skin`]) that
//! the footprint, the ink and the app read as they read Liang's brush's, and inked through
//! the same law ([`crate::brush::ink`]).
//!
//! The spines carry the head's hair in parallel, so each takes its share of the head's
//! stiffness: the head bends under a load as one spine of the base stiffness would.

use super::head::{Head, HeadShape};
use super::skin::{self, SpineCurve, MAX_SPINES};
use super::{Spine, SpineParamError, SpineParams, MAX_JOINTS};
use crate::brush::ink::{self, InkCoefs};
use crate::brush::Layer;
use crate::footprint::Geometry;
use crate::params::{BrushParams, ParamId};
use crate::quat::{Pose, Quat};
use crate::vec::Vec3;

/// Layer rings of the surface, from the ferrule to the tip.
pub const LEVELS: usize = 16;

/// Nodes per ring of the surface (as Liang's presets).
pub const RING_NODES: usize = 16;

/// The longest time between two solves of the spines (s). A tick that covers more (the
/// local force model's 10 ms, a solver thread's) solves them along the handle's path,
/// its position and rotation interpolated from the last tick's to the new one, in as many
/// equal substeps as keep each this short. Stiction makes the brush follow the path it
/// was solved along: solved this often or more it converges, where coarser solves let
/// landing spines slip that finer ones hold (`shared/tests/baxter_lin_rate.rs` measures
/// both).
pub const MAX_SOLVE_INTERVAL_S: f64 = 0.25e-3;

/// Most substeps one tick solves: a tick longer than this many
/// [`MAX_SOLVE_INTERVAL_S`] (10 ms) is solved in coarser steps instead, so that a solver
/// thread that fell behind does not fall further behind solving the gap.
pub const MAX_SUBSTEPS: u32 = 40;

/// What the brush needs besides its head and its spines' mechanics: the ink it holds and
/// the footprint's threshold, as Liang's brush takes them from its parameters.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct InkParams {
    /// Ink a saturated ring holds per mm^3 of its volume.
    pub capacity: f32,
    /// The load a dip leaves, in [0, 1].
    pub wetness: f32,
    /// Surface at or below this height touches the paper (mm).
    pub footprint_eps_mm: f32,
}

impl InkParams {
    /// The ink and footprint threshold of Liang's preset `p`, so both models hold and lay
    /// the same ink.
    pub fn of_preset(p: &BrushParams) -> InkParams {
        InkParams {
            capacity: p.ink_capacity,
            wetness: p.wetness,
            footprint_eps_mm: p.footprint_eps_mm,
        }
    }
}

/// Baxter & Lin's brush: its spines, its surface and its ink.
#[derive(Clone, Debug)]
pub struct BaxterLinBrush {
    head: Head,
    spines: heapless::Vec<Spine, MAX_SPINES>,
    centres: [Vec3<f64>; LEVELS],
    /// Each ring's move over the last tick (mm), the ink's travel.
    steps: [Vec3<f64>; LEVELS],
    layers: [Layer<f64>; LEVELS],
    /// A bound on each ring's radius (the longest spine and the thickest bundle): the ink
    /// skips a ring higher than that above the paper.
    max_radius: [f64; LEVELS],
    ink: InkCoefs,
    ink_phase: bool,
    eps: f64,
    /// A constant force on the head's tip (N, world frame), as Liang's brush's
    /// `set_tip_load`: the static-bend experiment of §5.
    tip_load: Vec3<f64>,
    /// The handle's pose at the last tick: where the next tick's path starts.
    pose: Pose<f64>,
    /// The substeps each tick is solved in ([`Self::set_solve_interval`]).
    substeps: u32,
}

impl BaxterLinBrush {
    /// The brush of `head`, its spines built from `base` ([`super::head::SpineRoot::spine_params`]),
    /// hanging at rest
    /// from the handle at `pose`, dipped to `ink.wetness`.
    pub fn new(
        head: Head,
        base: SpineParams,
        ink_params: InkParams,
        pose: Pose<f64>,
    ) -> Result<Self, SpineParamError> {
        let mut spines = heapless::Vec::new();
        for root in head.spines() {
            // At most MAX_SPINES roots: the head holds no more.
            let _ = spines.push(Spine::new(root.spine_params(&base), pose)?);
        }
        let blank = Layer {
            short_axis: Vec3::X,
            long_axis: Vec3::Y,
            long_radius: 0.0,
            short_radius: 0.0,
            wetness: 0.0,
            deposited: 0.0,
        };
        let reach = head.length_mm()
            + head
                .spines()
                .iter()
                .map(|s| s.bundle.root_mm.max(s.bundle.tip_mm))
                .fold(0.0, f64::max);
        let mut brush = BaxterLinBrush {
            head,
            spines,
            centres: [Vec3::ZERO; LEVELS],
            steps: [Vec3::ZERO; LEVELS],
            layers: [blank; LEVELS],
            max_radius: [reach; LEVELS],
            ink: InkCoefs::for_rings(&[0.0; LEVELS], 1, ink_params.footprint_eps_mm),
            ink_phase: false,
            eps: ink_params.footprint_eps_mm as f64,
            tip_load: Vec3::ZERO,
            pose,
            substeps: 1,
        };
        brush.set_solve_interval(super::DEFAULT_SOLVE_INTERVAL_S);
        brush.skin(&pose);
        // What each ring holds: its volume at rest (the ring's ellipse over the spacing
        // between rings) times the capacity per mm^3.
        let spacing = brush.head.length_mm() / (LEVELS - 1) as f64;
        let mut capacity = [0.0f32; LEVELS];
        for (c, l) in capacity.iter_mut().zip(&brush.layers) {
            let area = core::f64::consts::PI * l.long_radius * l.short_radius;
            *c = (ink_params.capacity as f64 * area * spacing) as f32;
        }
        brush.ink = InkCoefs::for_rings(&capacity, 1, ink_params.footprint_eps_mm);
        brush.dip(ink_params.wetness as f64);
        Ok(brush)
    }

    /// The parameters of Liang's presets that [`Self::of_shape`] reads for a head of
    /// `shape`: the ink and the hair's stiffness ([`SpineParams::of_hair`]), and the round
    /// head's profile (the other shapes have their catalogue size). The rest are Liang's
    /// model's own.
    pub fn preset_params(shape: HeadShape) -> &'static [ParamId] {
        const ALL: [ParamId; 8] = [
            ParamId::InkCapacity,
            ParamId::Wetness,
            ParamId::FootprintEpsMm,
            ParamId::TieStiffness,
            ParamId::LengthMm,
            ParamId::RadiusMm,
            ParamId::TipRadiusMm,
            ParamId::Belly,
        ];
        match shape {
            HeadShape::Round => &ALL,
            _ => &ALL[..4],
        }
    }

    /// The round head with the profile of Liang's preset `p` (its length, radius at the
    /// ferrule, tip and belly) and its ink, its spines the paper's ([`SpineParams::DEFAULT`]:
    /// three joints, the stiffness of §5): Baxter & Lin's brush for a preset, wherever a
    /// preset names the brush.
    pub fn of_preset(p: &BrushParams, pose: Pose<f64>) -> Result<Self, SpineParamError> {
        Self::of_shape(HeadShape::Round, p, pose)
    }

    /// [`Self::of_preset`] with the head of `shape`: the round one has the preset's
    /// profile, the others their catalogue size ([`HeadShape::head`]); the ink and the
    /// hair's stiffness ([`SpineParams::of_hair`]) are the preset's either way.
    pub fn of_shape(
        shape: HeadShape,
        p: &BrushParams,
        pose: Pose<f64>,
    ) -> Result<Self, SpineParamError> {
        let head = match shape {
            HeadShape::Round => Head::round(
                p.length_mm as f64,
                p.radius_mm as f64,
                p.tip_radius_mm as f64,
                p.belly as f64,
            ),
            other => other.head(),
        };
        BaxterLinBrush::new(head, SpineParams::of_hair(p), InkParams::of_preset(p), pose)
    }

    /// How far from the ferrule's centre the head's hair can reach (mm): its longest spine
    /// from its farthest root, and that spine's bundle around it, however the spines splay.
    pub fn reach_mm(&self) -> f64 {
        self.head.length_mm()
            + self
                .head
                .spines()
                .iter()
                .map(|s| s.position.norm() + s.bundle.root_mm.max(s.bundle.tip_mm))
                .fold(0.0, f64::max)
    }

    /// One tick: every spine solved along the handle's path from the last tick's pose to
    /// `pose` ([`MAX_SOLVE_INTERVAL_S`]), the surface over them, the ink. A pose that is not
    /// finite is refused by every spine (each keeps its last, [`Spine::solve`]) and starts
    /// no path.
    pub fn tick(&mut self, pose: &Pose<f64>) {
        let finite = pose.pos.to_f64().iter().all(|v| v.is_finite())
            && pose.rot.to_f64().iter().all(|v| v.is_finite());
        let (from, steps) = if finite {
            (self.pose, self.substeps)
        } else {
            (*pose, 1)
        };
        for k in 1..=steps {
            let t = k as f64 / steps as f64;
            let at = if k == steps {
                *pose
            } else {
                Pose::new(
                    from.pos + (pose.pos - from.pos).scale(t),
                    Quat::nlerp(from.rot, pose.rot, t),
                )
            };
            // Each spine carries its share of the load, as it carries its share of the
            // stiffness: every spine then bends as the whole head does.
            for (spine, root) in self.spines.iter_mut().zip(self.head.spines()) {
                spine.solve(&at, self.tip_load.scale(root.share));
            }
        }
        if finite {
            self.pose = *pose;
        }
        let last = self.centres;
        self.skin(pose);
        for ((step, now), then) in self.steps.iter_mut().zip(&self.centres).zip(&last) {
            *step = *now - *then;
        }
        ink::transfer(
            &mut self.layers,
            &self.centres,
            &self.steps,
            &self.max_radius,
            &self.ink,
            &mut self.ink_phase,
        );
    }

    fn skin(&mut self, pose: &Pose<f64>) {
        let mut joints = [[Vec3::ZERO; MAX_JOINTS + 1]; MAX_SPINES];
        let mut curves: heapless::Vec<SpineCurve<'_>, MAX_SPINES> = heapless::Vec::new();
        for ((spine, root), js) in self
            .spines
            .iter()
            .zip(self.head.spines())
            .zip(joints.iter_mut())
        {
            let p = spine.positions();
            let n = p.len().min(js.len());
            js[..n].copy_from_slice(&p[..n]);
            let _ = curves.push(SpineCurve {
                joints: &js[..n],
                bundle: root.bundle,
            });
        }
        skin::skin(&curves, pose, &mut self.centres, &mut self.layers);
    }

    /// The time between this brush's ticks (s; a 1 kHz tick unless set): each tick is solved
    /// in the fewest equal substeps no longer than [`MAX_SOLVE_INTERVAL_S`] (at most
    /// [`MAX_SUBSTEPS`]), every spine's [`Spine::set_solve_interval`] the substep's. An
    /// interval that is not positive and finite keeps the last.
    pub fn set_solve_interval(&mut self, interval_s: f64) {
        if !(interval_s.is_finite() && interval_s > 0.0) {
            return;
        }
        let steps = libm::ceil(interval_s / MAX_SOLVE_INTERVAL_S * (1.0 - 1e-9));
        self.substeps = steps.clamp(1.0, MAX_SUBSTEPS as f64) as u32;
        let step_s = interval_s / self.substeps as f64;
        for s in &mut self.spines {
            s.set_solve_interval(step_s);
        }
    }

    /// Applies a constant force (N, world frame) to the head's tip until changed, shared
    /// between the spines' tips as their stiffness is.
    pub fn set_tip_load(&mut self, force: Vec3<f64>) {
        self.tip_load = force;
    }

    /// Fills every ring to `load` of what it holds (clamped to [0, 1]): dipping the brush.
    pub fn dip(&mut self, load: f64) {
        for l in &mut self.layers {
            l.wetness = load.clamp(0.0, 1.0);
        }
    }

    /// The surface as the footprint reads it.
    pub fn geometry(&self) -> Geometry<'_, f64> {
        Geometry {
            spine: &self.centres,
            layers: &self.layers,
            ring_nodes: RING_NODES,
            eps: self.eps,
        }
    }

    /// The rings' centres (the ferrule's first), world mm.
    pub fn centres(&self) -> &[Vec3<f64>] {
        &self.centres
    }

    /// The rings.
    pub fn layers(&self) -> &[Layer<f64>] {
        &self.layers
    }

    /// The spines.
    pub fn spines(&self) -> &[Spine] {
        &self.spines
    }

    /// The head.
    pub fn head(&self) -> &Head {
        &self.head
    }

    /// The force the spines put on the handle (N): the paper's push on the hair.
    pub fn handle_force(&self) -> Vec3<f64> {
        self.spines
            .iter()
            .fold(Vec3::ZERO, |acc, s| acc + s.handle_force())
    }

    /// Ink the brush holds (ink units).
    pub fn ink_load(&self) -> f64 {
        self.layers
            .iter()
            .zip(&self.ink.inv_capacity)
            .map(|(l, inv)| {
                if *inv > 0.0 {
                    l.wetness / *inv as f64
                } else {
                    0.0
                }
            })
            .sum()
    }

    /// Ink the brush has given the paper (ink units).
    pub fn ink_given(&self) -> f64 {
        self.layers.iter().map(|l| l.deposited).sum()
    }
}
