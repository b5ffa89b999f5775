//! Brush state frames and pose samples: every fixed-point value crosses the link as its exact
//! [`Fx`] bits, so what the host rebuilds is bit-identical to what the device computed.

use heapless::Vec;
use serde::{Deserialize, Serialize};

use super::flags::{Buttons, Faults};
use crate::params::MAX_LAYERS;
use crate::quat::{Pose, Quat};
use crate::scalar::Fx;
use crate::vec::Vec3;

/// A [`Vec3<Fx>`] as the bits of its components.
pub type Vec3Bits = [i64; 3];

/// The bits of `v`'s components.
pub fn vec3_bits(v: Vec3<Fx>) -> Vec3Bits {
    [v.x.to_bits(), v.y.to_bits(), v.z.to_bits()]
}

/// The vector with these component bits.
pub fn vec3_from_bits([x, y, z]: Vec3Bits) -> Vec3<Fx> {
    Vec3::new(Fx::from_bits(x), Fx::from_bits(y), Fx::from_bits(z))
}

/// `a - b` on the raw bits, wrapping: [`add_bits`] undoes it exactly for every input.
pub(crate) fn delta_bits(a: Vec3<Fx>, b: Vec3<Fx>) -> Vec3Bits {
    [
        a.x.to_bits().wrapping_sub(b.x.to_bits()),
        a.y.to_bits().wrapping_sub(b.y.to_bits()),
        a.z.to_bits().wrapping_sub(b.z.to_bits()),
    ]
}

/// `base + d` on the raw bits, wrapping.
pub(crate) fn add_bits(base: Vec3<Fx>, [x, y, z]: Vec3Bits) -> Vec3<Fx> {
    Vec3::new(
        Fx::from_bits(base.x.to_bits().wrapping_add(x)),
        Fx::from_bits(base.y.to_bits().wrapping_add(y)),
        Fx::from_bits(base.z.to_bits().wrapping_add(z)),
    )
}

/// A [`Pose<Fx>`] as bits: position (mm) and orientation quaternion (w, x, y, z).
#[derive(Copy, Clone, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct PoseBits {
    pub pos: Vec3Bits,
    pub rot: [i64; 4],
}

impl From<Pose<Fx>> for PoseBits {
    fn from(p: Pose<Fx>) -> Self {
        let q = p.rot;
        PoseBits {
            pos: vec3_bits(p.pos),
            rot: [q.w.to_bits(), q.x.to_bits(), q.y.to_bits(), q.z.to_bits()],
        }
    }
}

impl PoseBits {
    pub fn pose(&self) -> Pose<Fx> {
        let [w, x, y, z] = self.rot.map(Fx::from_bits);
        Pose::new(vec3_from_bits(self.pos), Quat::new(w, x, y, z))
    }
}

/// One tick of the virtual pen, host to device: exactly the pose the host simulation feeds
/// its own `Brush<Fx>`, so device and host simulate the same brush bit for bit.
#[derive(Copy, Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct PoseSample {
    /// The host's tick number for this pose (one per 1 ms); the device detects lost and
    /// reordered samples by it (wrapping).
    pub seq: u32,
    pub pose: PoseBits,
    pub buttons: Buttons,
}

impl PoseSample {
    pub fn new(seq: u32, pose: Pose<Fx>, buttons: Buttons) -> Self {
        PoseSample {
            seq,
            pose: pose.into(),
            buttons,
        }
    }
    pub fn pose(&self) -> Pose<Fx> {
        self.pose.pose()
    }
}

/// One tick of guided writing, host to device: the stroke's moving point for the pose sample
/// with the same `seq` (sent just before it). The device applies it at the tick that
/// consumes that pose, so the device and the host simulation lead the same hand to the same
/// point at the same tick, bit for bit (`maobi_shared::guide::GuideStream`).
#[derive(Copy, Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct GuideSample {
    /// The [`PoseSample::seq`] of the tick this point belongs to.
    pub seq: u32,
    /// Where the ferrule should be at that tick (mm, paper frame), as [`Fx`] bits.
    pub anchor: Vec3Bits,
    /// Lead the hand (fade in, or stay on); false: fade out, holding this point.
    pub on: bool,
}

impl GuideSample {
    pub fn new(seq: u32, anchor: Vec3<Fx>, on: bool) -> Self {
        GuideSample {
            seq,
            anchor: vec3_bits(anchor),
            on,
        }
    }
    pub fn anchor(&self) -> Vec3<Fx> {
        vec3_from_bits(self.anchor)
    }
}

/// What the force loop did at the state's tick.
#[derive(Copy, Clone, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct Haptics {
    /// Force on the hand, world frame (N), as [`Fx`] bits.
    pub force_n: Vec3Bits,
    /// The three motor commands the board drives (or would drive, with forces off), in
    /// [-1, 1] of full current as `kinematics::Pen::motor_commands` gives them, as [`Fx`] bits.
    pub motors: [i64; 3],
    /// Forces are enabled (the motors are driven).
    pub enabled: bool,
}

impl Haptics {
    pub fn new(force_n: Vec3<Fx>, motors: [Fx; 3], enabled: bool) -> Self {
        Haptics {
            force_n: vec3_bits(force_n),
            motors: motors.map(Fx::to_bits),
            enabled,
        }
    }
    pub fn force(&self) -> Vec3<Fx> {
        vec3_from_bits(self.force_n)
    }
    pub fn motors(&self) -> [Fx; 3] {
        self.motors.map(Fx::from_bits)
    }
}

/// One layer of one spine, [`Fx`] bits. Positions are differences, which are shorter varints
/// than canvas coordinates and exact (wrapping differences of the raw bits).
#[derive(Copy, Clone, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct LayerState {
    /// Spine mass S_i minus S_(i-1) (for S_0: minus the handle position) (mm).
    pub spine: Vec3Bits,
    /// Skeleton node VS_i minus S_i (mm).
    pub skeleton: Vec3Bits,
    /// The ellipse: short- and long-axis directions (unit), radii (mm), wetness [0, 1] (the
    /// layer's ink load as a share of what it holds).
    pub short_axis: Vec3Bits,
    pub long_axis: Vec3Bits,
    pub long_radius: i64,
    pub short_radius: i64,
    pub wetness: i64,
    /// Ink the layer has given to the paper since the brush was built or reset (ink units, a
    /// running total, `crate::brush::ink`): the host inks each increase, so no state frame
    /// needs to be seen for the paper to get all the ink.
    pub deposited: i64,
}

/// The brush at one tick, device to host, one frame per spine.
///
/// A brush of several spines (Baxter & Lin's multi-spine brushes) sends `spine_count` frames
/// per tick with the same `tick`, `spine_index` 0, 1, ...; each frame is complete on its own,
/// so a lost frame costs one spine for one tick. Today's brush has one spine.
///
/// Filled from a brush by [`BrushState::from_brush`] and read back as a brush's shape by
/// [`BrushState::shape`], both in [`crate::brush::state_frame`], beside the brush: the
/// protocol itself is data types and their codec, and knows nothing of the model.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct BrushState {
    /// Device tick (1 ms, wrapping).
    pub tick: u32,
    /// Virtual pen: the `seq` of the last [`PoseSample`] the brush has consumed, so the host
    /// can set this state beside its own simulation at that tick (0 with real sensors).
    pub pose_seq: u32,
    pub spine_index: u8,
    pub spine_count: u8,
    /// The handle (ferrule) pose the model used at this tick.
    pub handle: PoseBits,
    pub haptics: Haptics,
    /// Faults latched at this tick.
    pub faults: Faults,
    /// Bit i set: layer i lies on the paper.
    pub contacts: u32,
    /// K, nodes per ellipse ring.
    pub ring_nodes: u8,
    /// Surface at or below this height leaves ink (mm, [`Fx`] bits).
    pub footprint_eps: i64,
    /// One entry per layer, ferrule first.
    pub layers: Vec<LayerState, MAX_LAYERS>,
}

impl BrushState {
    /// No layers, every field zero: a placeholder to [fill](Self::fill_from_brush). All zero
    /// bytes, so a `static` holding it costs no flash.
    pub const EMPTY: BrushState = BrushState {
        tick: 0,
        pose_seq: 0,
        spine_index: 0,
        spine_count: 0,
        handle: PoseBits {
            pos: [0; 3],
            rot: [0; 4],
        },
        haptics: Haptics {
            force_n: [0; 3],
            motors: [0; 3],
            enabled: false,
        },
        faults: Faults::empty(),
        contacts: 0,
        ring_nodes: 0,
        footprint_eps: 0,
        layers: Vec::new(),
    };

    /// Whether layer `i` lies on the paper.
    pub fn in_contact(&self, i: usize) -> bool {
        u32::try_from(i)
            .ok()
            .and_then(|i| self.contacts.checked_shr(i))
            .is_some_and(|bits| bits & 1 == 1)
    }
}
