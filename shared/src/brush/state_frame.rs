//! The brush's side of the link's state frame: a [`Brush`]'s state as a [`BrushState`] (the
//! device's force loop fills one every tick), and a received state back as a [`BrushShape`]
//! (the host's view of the device's brush). The protocol carries the bits and knows nothing
//! of the brush; what the bits mean for a brush lives here, beside it. The methods are
//! `BrushState`'s own (`BrushState::from_brush`, `fill_from_brush`, `shape`), so that callers
//! read as before.

use crate::brush::{Brush, Layer};
use crate::footprint::Geometry;
use crate::params::MAX_LAYERS;
use crate::protocol::{
    add_bits, delta_bits, vec3_bits, vec3_from_bits, BrushState, Faults, Haptics, LayerState,
};
use crate::quat::Pose;
use crate::scalar::{Fx, Scalar};
use crate::vec::Vec3;

impl BrushState {
    /// The state of a (single-spine) brush at device tick `tick`, after the pose sample
    /// `pose_seq`.
    pub fn from_brush(
        brush: &Brush<Fx>,
        tick: u32,
        pose_seq: u32,
        haptics: Haptics,
        faults: Faults,
    ) -> Self {
        let mut state = BrushState::EMPTY;
        state.fill_from_brush(brush, tick, pose_seq, haptics, faults);
        state
    }

    /// [`Self::from_brush`] written over `self` in place: the device's force loop fills the
    /// state slot it shares with the link task this way, with no 3 KB temporary on its
    /// (interrupt) stack.
    pub fn fill_from_brush(
        &mut self,
        brush: &Brush<Fx>,
        tick: u32,
        pose_seq: u32,
        haptics: Haptics,
        faults: Faults,
    ) {
        let handle = brush.handle();
        let geometry = Geometry::of(brush);
        self.layers.clear();
        let mut contacts = 0u32;
        let mut prev = handle.pos;
        let per_layer = geometry
            .spine
            .iter()
            .zip(brush.skeleton())
            .zip(geometry.layers)
            .zip(brush.in_contact());
        for (i, (((&s, &k), l), &touching)) in per_layer.enumerate() {
            if touching {
                contacts |= u32::try_from(i)
                    .ok()
                    .and_then(|i| 1u32.checked_shl(i))
                    .unwrap_or(0);
            }
            // A brush has at most MAX_LAYERS layers: the push cannot fail.
            let _ = self.layers.push(LayerState {
                spine: delta_bits(s, prev),
                skeleton: delta_bits(k, s),
                short_axis: vec3_bits(l.short_axis),
                long_axis: vec3_bits(l.long_axis),
                long_radius: l.long_radius.to_bits(),
                short_radius: l.short_radius.to_bits(),
                wetness: l.wetness.to_bits(),
                deposited: l.deposited.to_bits(),
            });
            prev = s;
        }
        self.tick = tick;
        self.pose_seq = pose_seq;
        self.spine_index = 0;
        self.spine_count = 1;
        self.handle = handle.into();
        self.haptics = haptics;
        self.faults = faults;
        self.contacts = contacts;
        self.ring_nodes = u8::try_from(geometry.ring_nodes).unwrap_or(u8::MAX);
        self.footprint_eps = geometry.eps.to_bits();
    }

    /// The spine's positions and ellipses, decoded (host side): build the footprint from
    /// [`BrushShape::geometry`] with the same code the device runs.
    pub fn shape(&self) -> BrushShape {
        let handle = self.handle.pose();
        let mut shape = BrushShape {
            handle,
            spine: [Vec3::ZERO; MAX_LAYERS],
            skeleton: [Vec3::ZERO; MAX_LAYERS],
            layers: [NO_LAYER; MAX_LAYERS],
            len: self.layers.len(),
            ring_nodes: usize::from(self.ring_nodes),
            eps: Fx::from_bits(self.footprint_eps),
        };
        let mut prev = handle.pos;
        let slots = shape
            .spine
            .iter_mut()
            .zip(shape.skeleton.iter_mut())
            .zip(shape.layers.iter_mut());
        for (w, ((s, k), l)) in self.layers.iter().zip(slots) {
            *s = add_bits(prev, w.spine);
            *k = add_bits(*s, w.skeleton);
            *l = Layer {
                short_axis: vec3_from_bits(w.short_axis),
                long_axis: vec3_from_bits(w.long_axis),
                long_radius: Fx::from_bits(w.long_radius),
                short_radius: Fx::from_bits(w.short_radius),
                wetness: Fx::from_bits(w.wetness),
                deposited: Fx::from_bits(w.deposited),
            };
            prev = *s;
        }
        shape
    }
}

const NO_LAYER: Layer<Fx> = Layer {
    short_axis: Vec3::ZERO,
    long_axis: Vec3::ZERO,
    long_radius: Fx::ZERO,
    short_radius: Fx::ZERO,
    wetness: Fx::ZERO,
    deposited: Fx::ZERO,
};

/// One spine of a [`BrushState`], decoded into the model's own types.
#[derive(Clone, Debug, PartialEq)]
pub struct BrushShape {
    handle: Pose<Fx>,
    spine: [Vec3<Fx>; MAX_LAYERS],
    skeleton: [Vec3<Fx>; MAX_LAYERS],
    layers: [Layer<Fx>; MAX_LAYERS],
    len: usize,
    ring_nodes: usize,
    eps: Fx,
}

impl BrushShape {
    pub fn handle(&self) -> Pose<Fx> {
        self.handle
    }
    /// Spine masses S_i (mm), the ferrule's first.
    pub fn spine(&self) -> &[Vec3<Fx>] {
        self.spine.get(..self.len).unwrap_or(&[])
    }
    /// Skeleton nodes VS_i (mm).
    pub fn skeleton(&self) -> &[Vec3<Fx>] {
        self.skeleton.get(..self.len).unwrap_or(&[])
    }
    /// Each layer's ellipse.
    pub fn layers(&self) -> &[Layer<Fx>] {
        self.layers.get(..self.len).unwrap_or(&[])
    }
    /// What the footprint is computed from: `shape.geometry().for_each_polygon(..)` gives the
    /// device's polygons, bit for bit.
    pub fn geometry(&self) -> Geometry<'_, Fx> {
        Geometry {
            spine: self.spine(),
            layers: self.layers(),
            ring_nodes: self.ring_nodes,
            eps: self.eps,
        }
    }
}
