//! Brush parameters: every one can change at run time and is validated before it is stored.
//!
//! Units are the ones a user thinks in: millimetres, grams, newtons per metre, seconds. The
//! model turns them into dimensionless per-substep coefficients (see [`crate::brush`]) when a
//! parameter changes; nothing here is on the substep path.

use crate::scalar::Scalar;
use core::fmt;

/// Most layers (spine masses, including the ferrule mass S_0) a brush may have.
pub const MAX_LAYERS: usize = 24;
/// Most surface nodes per layer ring.
pub const MAX_RING_NODES: usize = 32;
/// The force loop's tick: the model always advances in 1 ms ticks, split into substeps.
pub const TICK_HZ: u32 = 1000;
/// Rate at which the thesis states its per-step rates D and SDF (25 kHz, Liang 2009 4.2.1).
pub const REFERENCE_SUBSTEP_HZ: u32 = 25_000;

/// Names of the run-time parameters, for `set` / `get` and error messages.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum ParamId {
    Layers = 0,
    RingNodes,
    LengthMm,
    RadiusMm,
    TipRadiusMm,
    Belly,
    MassG,
    AxialStiffness,
    AxialDamping,
    CompressionRatio,
    TieStiffness,
    TieDamping,
    PaperDrag,
    Plasticity,
    JacobiIterations,
    SubstepsPerTick,
    SpreadTf,
    SpreadRate,
    SpreadMax,
    Wetness,
    FootprintEpsMm,
    Integrator,
    InkCapacity,
    TieStiffnessWet,
    TieDampingWet,
}

impl ParamId {
    pub const ALL: [ParamId; 25] = [
        ParamId::Layers,
        ParamId::RingNodes,
        ParamId::LengthMm,
        ParamId::RadiusMm,
        ParamId::TipRadiusMm,
        ParamId::Belly,
        ParamId::MassG,
        ParamId::AxialStiffness,
        ParamId::AxialDamping,
        ParamId::CompressionRatio,
        ParamId::TieStiffness,
        ParamId::TieDamping,
        ParamId::PaperDrag,
        ParamId::Plasticity,
        ParamId::JacobiIterations,
        ParamId::SubstepsPerTick,
        ParamId::SpreadTf,
        ParamId::SpreadRate,
        ParamId::SpreadMax,
        ParamId::Wetness,
        ParamId::FootprintEpsMm,
        ParamId::Integrator,
        ParamId::InkCapacity,
        ParamId::TieStiffnessWet,
        ParamId::TieDampingWet,
    ];

    /// The parameter's name as the CLI, the GUI and the wire protocol spell it.
    pub const fn name(self) -> &'static str {
        match self {
            ParamId::Layers => "layers",
            ParamId::RingNodes => "ring_nodes",
            ParamId::LengthMm => "length_mm",
            ParamId::RadiusMm => "radius_mm",
            ParamId::TipRadiusMm => "tip_radius_mm",
            ParamId::Belly => "belly",
            ParamId::MassG => "mass_g",
            ParamId::AxialStiffness => "axial_stiffness_n_per_m",
            ParamId::AxialDamping => "axial_damping_ns_per_m",
            ParamId::CompressionRatio => "axial_compression_ratio",
            ParamId::TieStiffness => "tie_stiffness_n_per_m",
            ParamId::TieDamping => "tie_damping_ns_per_m",
            ParamId::PaperDrag => "paper_drag_ns_per_m",
            ParamId::Plasticity => "plasticity_d",
            ParamId::JacobiIterations => "jacobi_iterations",
            ParamId::SubstepsPerTick => "substeps_per_tick",
            ParamId::SpreadTf => "spread_tf",
            ParamId::SpreadRate => "spread_sdf",
            ParamId::SpreadMax => "spread_max",
            ParamId::Wetness => "wetness",
            ParamId::FootprintEpsMm => "footprint_eps_mm",
            ParamId::Integrator => "integrator",
            ParamId::InkCapacity => "ink_capacity",
            ParamId::TieStiffnessWet => "tie_stiffness_wet_pct",
            ParamId::TieDampingWet => "tie_damping_wet_pct",
        }
    }

    pub fn from_name(name: &str) -> Option<ParamId> {
        ParamId::ALL.into_iter().find(|p| p.name() == name)
    }

    /// Valid range (inclusive) and whether the value must be a whole number.
    pub const fn range(self) -> (f32, f32, bool) {
        match self {
            ParamId::Layers => (3.0, MAX_LAYERS as f32, true),
            ParamId::RingNodes => (4.0, MAX_RING_NODES as f32, true),
            ParamId::LengthMm => (2.0, 120.0, false),
            ParamId::RadiusMm => (0.2, 30.0, false),
            ParamId::TipRadiusMm => (0.01, 5.0, false),
            ParamId::Belly => (0.0, 2.0, false),
            ParamId::MassG => (0.005, 50.0, false),
            ParamId::AxialStiffness => (1.0, 1.0e7, false),
            ParamId::AxialDamping => (0.0, 1.0e4, false),
            ParamId::CompressionRatio => (0.0, 1.0, false),
            ParamId::TieStiffness => (0.01, 1.0e6, false),
            ParamId::TieDamping => (0.0, 1.0e4, false),
            ParamId::PaperDrag => (0.0, 100.0, false),
            ParamId::Plasticity => (0.0, 0.5, false),
            ParamId::JacobiIterations => (1.0, 16.0, true),
            ParamId::SubstepsPerTick => (1.0, 100.0, true),
            ParamId::SpreadTf => (0.0, 10.0, false),
            ParamId::SpreadRate => (0.0, 0.5, false),
            ParamId::SpreadMax => (1.0, 4.0, false),
            ParamId::Wetness => (0.0, 1.0, false),
            ParamId::FootprintEpsMm => (0.001, 2.0, false),
            ParamId::Integrator => (INTEGRATORS.0 as f32, INTEGRATORS.1 as f32, true),
            ParamId::InkCapacity => (0.01, 100.0, false),
            // Percent of the dry tie's, in the directions of `crate::brush::ink`'s law: ink
            // softens the hair and adds viscosity, never the reverse. Whole percent, each kept
            // in a byte (every copy of the parameters, a command queue's too, stays its
            // size); two and a half times the dry damping is past critical for either preset.
            ParamId::TieStiffnessWet => (10.0, 100.0, true),
            ParamId::TieDampingWet => (100.0, 250.0, true),
        }
    }
}

impl fmt::Display for ParamId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// Why a parameter value was rejected. The old value stays in force.
#[derive(Copy, Clone, Debug, PartialEq)]
pub enum ParamError {
    NotFinite {
        param: ParamId,
    },
    OutOfRange {
        param: ParamId,
        value: f32,
        min: f32,
        max: f32,
    },
    NotWholeNumber {
        param: ParamId,
        value: f32,
    },
    /// Values that are each valid but not together (e.g. a tip wider than the root).
    Inconsistent {
        param: ParamId,
        why: &'static str,
    },
    /// `ring_nodes` must divide the 32-entry trigonometric table.
    RingNodesNotPowerOfTwo {
        value: f32,
    },
    /// Valid for the model, but more than the board's core runs in its 1 ms tick
    /// ([`TickLimits`]).
    OverTickLimit {
        param: ParamId,
        value: f32,
        max: f32,
    },
}

impl fmt::Display for ParamError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            ParamError::NotFinite { param } => write!(f, "{param}: value is not a finite number"),
            ParamError::OutOfRange {
                param,
                value,
                min,
                max,
            } => write!(
                f,
                "{param}: {value} is outside the valid range {min} ..= {max}"
            ),
            ParamError::NotWholeNumber { param, value } => {
                write!(f, "{param}: {value} is not a whole number")
            }
            ParamError::Inconsistent { param, why } => write!(f, "{param}: {why}"),
            ParamError::RingNodesNotPowerOfTwo { value } => {
                write!(f, "ring_nodes: {value} is not one of 4, 8, 16, 32")
            }
            ParamError::OverTickLimit { param, value, max } => write!(
                f,
                "{param}: {value} would not fit this pen's 1 ms tick; it allows at most {max}"
            ),
        }
    }
}

/// The most a board's core runs within its 1 ms force tick: a cap on each parameter whose
/// cost grows with its value. A brush within every cap fits the tick (the board states caps
/// whose most expensive combination it has measured to fit); one beyond any cap is refused
/// by [`TickLimits::check`], on the device and, since the handshake carries the caps, on the
/// host before it asks. Parameters without a cap here cost the same at any valid value.
#[derive(Copy, Clone, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct TickLimits {
    pub substeps_per_tick: u8,
    pub layers: u8,
    pub ring_nodes: u8,
    pub jacobi_iterations: u8,
}

impl fmt::Display for TickLimits {
    /// "substeps_per_tick <= 1, layers <= 12, ...", or "none" without a cap below the
    /// parameters' ranges.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if *self == TickLimits::NONE {
            return f.write_str("none");
        }
        for (i, (param, max)) in self.caps().into_iter().enumerate() {
            if i > 0 {
                f.write_str(", ")?;
            }
            write!(f, "{param} <= {max}")?;
        }
        Ok(())
    }
}

impl Default for TickLimits {
    fn default() -> Self {
        TickLimits::NONE
    }
}

impl TickLimits {
    /// No cap below the parameters' own ranges ([`ParamId::range`]): a board without a
    /// deadline (a simulator that may run slower than real time).
    pub const NONE: TickLimits = TickLimits {
        substeps_per_tick: ParamId::SubstepsPerTick.range().1 as u8,
        layers: MAX_LAYERS as u8,
        ring_nodes: MAX_RING_NODES as u8,
        jacobi_iterations: ParamId::JacobiIterations.range().1 as u8,
    };

    /// Each capped parameter with its cap.
    pub const fn caps(&self) -> [(ParamId, u8); 4] {
        [
            (ParamId::SubstepsPerTick, self.substeps_per_tick),
            (ParamId::Layers, self.layers),
            (ParamId::RingNodes, self.ring_nodes),
            (ParamId::JacobiIterations, self.jacobi_iterations),
        ]
    }

    /// The cap on `id`, if it has one.
    pub fn cap(&self, id: ParamId) -> Option<u8> {
        self.caps()
            .into_iter()
            .find_map(|(p, max)| (p == id).then_some(max))
    }

    /// `Ok` if `params` fits the tick; else the first parameter over its cap.
    pub fn check(&self, params: &BrushParams) -> Result<(), ParamError> {
        for (param, max) in self.caps() {
            let value = params.get(param);
            if value > f32::from(max) {
                return Err(ParamError::OverTickLimit {
                    param,
                    value,
                    max: f32::from(max),
                });
            }
        }
        Ok(())
    }

    /// `preset` as a board with these caps runs it: the substep rate lowered to the cap (a
    /// preset whose hair asks for more substeps is written at the board's rate, its own
    /// convergence bound then applies), the other parameters as they are, for
    /// [`Self::check`] to judge.
    pub const fn brush(&self, preset: BrushParams) -> BrushParams {
        let mut p = preset;
        if p.substeps_per_tick > self.substeps_per_tick {
            p.substeps_per_tick = self.substeps_per_tick;
        }
        p
    }
}

/// Everything that defines a brush. Construct from a [`crate::presets`] entry and change
/// with [`BrushParams::set`], which validates.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct BrushParams {
    /// N: spine masses including the ferrule mass S_0.
    pub layers: u8,
    /// K: surface nodes around each layer's ellipse.
    pub ring_nodes: u8,
    /// Length of the hair from the ferrule to the tip.
    pub length_mm: f32,
    /// Radius of the hair bundle where it leaves the ferrule.
    pub radius_mm: f32,
    /// Radius of the last layer (the tip).
    pub tip_radius_mm: f32,
    /// How much the bundle swells below the ferrule before it tapers (0: a straight cone).
    pub belly: f32,
    /// Mass of the wet hair, spread evenly over the N - 1 free masses.
    pub mass_g: f32,
    /// k_s between neighbouring spine masses (eq. 2.1).
    pub axial_stiffness: f32,
    /// k_d between neighbouring spine masses (eq. 2.27).
    pub axial_damping: f32,
    /// Stiffness in compression as a fraction of `axial_stiffness`. A bundle of hair cannot
    /// carry much compression (each hair buckles), so a brush pressed straight down settles
    /// onto the paper instead of standing on its tip like a column.
    pub compression_ratio: f32,
    /// Zero-length spring from S_i to the virtual skeleton node VS_i (Liang 3.1.2), of a
    /// layer with no ink in it (wetness 0); see `tie_stiffness_wet`.
    pub tie_stiffness: f32,
    /// Damper in parallel with the tie, of a layer with no ink in it; see `tie_damping_wet`.
    pub tie_damping: f32,
    /// C_f of the viscous paper drag on masses lying on the paper (eq. 4.1).
    pub paper_drag: f32,
    /// D of eq. 3-2, per step at the reference 25 kHz (0: perfectly elastic).
    pub plasticity: f32,
    /// k: Jacobi iterations of the thesis's implicit solve (eq. 2.33), when `integrator` is
    /// [`INTEGRATOR_KANG_CHO`].
    pub jacobi_iterations: u8,
    /// Substeps in each 1 ms tick (25 = the thesis's 25 kHz).
    pub substeps_per_tick: u8,
    /// TF of eq. 3-17: weight of a layer's own bend in its spread.
    pub spread_tf: f32,
    /// SDF of eq. 3-19, per step at the reference 25 kHz.
    pub spread_rate: f32,
    /// RL_max,i / RL_initial,i.
    pub spread_max: f32,
    /// Initial ink load of every layer, as a fraction of what it holds (1: saturated); the
    /// wetness W_i of eq. 3-17 is the load's fraction from then on, as the brush writes.
    pub wetness: f32,
    /// Surface within this height of the paper leaves ink (SPEC D).
    pub footprint_eps_mm: f32,
    /// How the spine is integrated: [`INTEGRATOR_BACKWARD_EULER`] (the default, whose
    /// results converge in the substep) or [`INTEGRATOR_KANG_CHO`] (the thesis's, for
    /// comparison with the paper). See [`crate::brush`].
    pub integrator: u8,
    /// Ink a layer holds when saturated, per mm^3 of its hair at rest (the volume of its
    /// rest ellipse over one segment), in ink units (optical depth times mm^2: one unit
    /// darkens 1 mm^2 of paper to optical depth 1). See `crate::brush::ink`.
    pub ink_capacity: f32,
    /// The tie's stiffness of a saturated layer (wetness 1) in percent of `tie_stiffness`:
    /// wet keratin is softer than dry. In between it follows the layer's wetness linearly
    /// (see `crate::brush::ink`, the thesis's 3.1.2 suggestion).
    pub tie_stiffness_wet_pct: u8,
    /// The tie's damping of a saturated layer in percent of `tie_damping`: the ink between
    /// the hairs is viscous. Linear in the wetness, like `tie_stiffness_wet_pct`.
    pub tie_damping_wet_pct: u8,
}

/// `integrator` 0: backward Euler with each spring's own Jacobian, solved exactly.
pub const INTEGRATOR_BACKWARD_EULER: u8 = 0;
/// `integrator` 1: the thesis's approximate implicit scheme (Kang & Cho, eqs. 2.19-2.33).
pub const INTEGRATOR_KANG_CHO: u8 = 1;

/// The integrators this build has, lowest and highest, and the presets' choice: all of them
/// and backward Euler, unless the build leaves one out (`maobi-shared`'s `backward-euler`
/// and `kang-cho` features; the Black Pill's image has backward Euler alone), where
/// `integrator`'s valid range is the one it has and the presets use that.
#[cfg(all(feature = "backward-euler", feature = "kang-cho"))]
const INTEGRATORS: (u8, u8) = (INTEGRATOR_BACKWARD_EULER, INTEGRATOR_KANG_CHO);
#[cfg(all(feature = "backward-euler", not(feature = "kang-cho")))]
const INTEGRATORS: (u8, u8) = (INTEGRATOR_BACKWARD_EULER, INTEGRATOR_BACKWARD_EULER);
#[cfg(all(not(feature = "backward-euler"), feature = "kang-cho"))]
const INTEGRATORS: (u8, u8) = (INTEGRATOR_KANG_CHO, INTEGRATOR_KANG_CHO);
#[cfg(not(any(feature = "backward-euler", feature = "kang-cho")))]
compile_error!("maobi-shared needs an integrator: enable `backward-euler` or `kang-cho`");
/// The presets' integrator: the lowest this build has (see `INTEGRATORS`).
pub const DEFAULT_INTEGRATOR: u8 = INTEGRATORS.0;

impl BrushParams {
    /// Reads one parameter as `f32`.
    pub fn get(&self, id: ParamId) -> f32 {
        match id {
            ParamId::Layers => self.layers as f32,
            ParamId::RingNodes => self.ring_nodes as f32,
            ParamId::LengthMm => self.length_mm,
            ParamId::RadiusMm => self.radius_mm,
            ParamId::TipRadiusMm => self.tip_radius_mm,
            ParamId::Belly => self.belly,
            ParamId::MassG => self.mass_g,
            ParamId::AxialStiffness => self.axial_stiffness,
            ParamId::AxialDamping => self.axial_damping,
            ParamId::CompressionRatio => self.compression_ratio,
            ParamId::TieStiffness => self.tie_stiffness,
            ParamId::TieDamping => self.tie_damping,
            ParamId::PaperDrag => self.paper_drag,
            ParamId::Plasticity => self.plasticity,
            ParamId::JacobiIterations => self.jacobi_iterations as f32,
            ParamId::SubstepsPerTick => self.substeps_per_tick as f32,
            ParamId::SpreadTf => self.spread_tf,
            ParamId::SpreadRate => self.spread_rate,
            ParamId::SpreadMax => self.spread_max,
            ParamId::Wetness => self.wetness,
            ParamId::FootprintEpsMm => self.footprint_eps_mm,
            ParamId::Integrator => self.integrator as f32,
            ParamId::InkCapacity => self.ink_capacity,
            ParamId::TieStiffnessWet => self.tie_stiffness_wet_pct as f32,
            ParamId::TieDampingWet => self.tie_damping_wet_pct as f32,
        }
    }

    /// Sets one parameter after validating it; on error nothing changes.
    pub fn set(&mut self, id: ParamId, value: f32) -> Result<(), ParamError> {
        let mut next = *self;
        next.store_unchecked(id, check_value(id, value)?);
        next.validate()?;
        *self = next;
        Ok(())
    }

    fn store_unchecked(&mut self, id: ParamId, v: f32) {
        match id {
            ParamId::Layers => self.layers = v as u8,
            ParamId::RingNodes => self.ring_nodes = v as u8,
            ParamId::LengthMm => self.length_mm = v,
            ParamId::RadiusMm => self.radius_mm = v,
            ParamId::TipRadiusMm => self.tip_radius_mm = v,
            ParamId::Belly => self.belly = v,
            ParamId::MassG => self.mass_g = v,
            ParamId::AxialStiffness => self.axial_stiffness = v,
            ParamId::AxialDamping => self.axial_damping = v,
            ParamId::CompressionRatio => self.compression_ratio = v,
            ParamId::TieStiffness => self.tie_stiffness = v,
            ParamId::TieDamping => self.tie_damping = v,
            ParamId::PaperDrag => self.paper_drag = v,
            ParamId::Plasticity => self.plasticity = v,
            ParamId::JacobiIterations => self.jacobi_iterations = v as u8,
            ParamId::SubstepsPerTick => self.substeps_per_tick = v as u8,
            ParamId::SpreadTf => self.spread_tf = v,
            ParamId::SpreadRate => self.spread_rate = v,
            ParamId::SpreadMax => self.spread_max = v,
            ParamId::Wetness => self.wetness = v,
            ParamId::FootprintEpsMm => self.footprint_eps_mm = v,
            ParamId::Integrator => self.integrator = v as u8,
            ParamId::InkCapacity => self.ink_capacity = v,
            ParamId::TieStiffnessWet => self.tie_stiffness_wet_pct = v as u8,
            ParamId::TieDampingWet => self.tie_damping_wet_pct = v as u8,
        }
    }

    /// Checks every field and the relations between them.
    pub fn validate(&self) -> Result<(), ParamError> {
        for id in ParamId::ALL {
            check_value(id, self.get(id))?;
        }
        if self.tip_radius_mm > self.radius_mm {
            return Err(ParamError::Inconsistent {
                param: ParamId::TipRadiusMm,
                why: "the tip cannot be wider than the root",
            });
        }
        Ok(())
    }

    // The derived quantities are `f32`, like the parameters: the pen derives them (on every
    // parameter change) with its single-precision FPU, where `f64` would be software, and
    // the host derives the same bits (IEEE single precision is the same on every target).

    /// Substep length in seconds.
    pub fn substep_s(&self) -> f32 {
        1.0 / (TICK_HZ as f32 * self.substeps_per_tick as f32)
    }

    /// The largest entry a diagonal block of the backward-Euler step's system can reach, in
    /// units of the mass: `1 + c_tv + 2 (c_k + c_d)` (the mass, its tie at its strongest over
    /// the layer's wetness, and two segments' stiffness and damping at the substep; see
    /// `crate::brush`). It decides whether the fixed-point brush solves its chain in 32 bits
    /// (`brush::MAX_DIAGONAL`).
    #[cfg(feature = "backward-euler")]
    pub fn backward_euler_diagonal_bound(&self) -> f32 {
        let h = self.substep_s();
        let m = self.mass_g * 1e-3 / (self.layers as f32 - 1.0);
        let c_k = h * h * self.axial_stiffness / m;
        let c_d = h * self.axial_damping / m;
        // The tie at its strongest over the wetness: the law's factors are validated to
        // soften the spring (at most one) and stiffen the damper (at least one) with ink,
        // so the dry spring and the saturated damper.
        let c_tv = (h * h * self.tie_stiffness + h * self.tie_damping * self.tie_damping_wet()) / m;
        // The paper's drag on a mass lying on it (in the paper's plane).
        let c_drag = h * self.paper_drag / m;
        1.0 + c_tv + c_drag + 2.0 * (c_k + c_d)
    }

    /// The tie's stiffness of a saturated layer as a fraction of the dry's
    /// (`tie_stiffness_wet_pct`).
    pub fn tie_stiffness_wet(&self) -> f32 {
        self.tie_stiffness_wet_pct as f32 / 100.0
    }

    /// The tie's damping of a saturated layer as a multiple of the dry's
    /// (`tie_damping_wet_pct`).
    pub fn tie_damping_wet(&self) -> f32 {
        self.tie_damping_wet_pct as f32 / 100.0
    }

    /// Resting length of one spine segment (mm).
    pub fn segment_mm(&self) -> f32 {
        self.length_mm / (self.layers as f32 - 1.0)
    }

    /// Long-axis radius RL_initial,i of layer i at rest: swells by `belly` and tapers to the
    /// tip radius. `t = i / (N-1)` runs from the ferrule (0) to the tip (1).
    pub fn rest_radius_mm(&self, i: usize) -> f32 {
        let t = i as f32 / (self.layers as f32 - 1.0);
        head_radius(self.radius_mm, self.tip_radius_mm, self.belly, t)
    }
}

/// A brush head's radius at the fraction `t` of its length from the ferrule (0) to the tip
/// (1): `r0` at the ferrule, swelling by `(1 + belly t)` below it and tapering as `(1 - t^2)`
/// to `rt` at the tip. With a belly around 0.5 the widest part sits about a third of the way
/// down, as on a calligraphy brush. Liang's layers ([`BrushParams::rest_radius_mm`]) and
/// Baxter & Lin's bundles (`baxter_lin::skin::Bundle`) both take their profile from here.
pub fn head_radius<S: Scalar>(r0: S, rt: S, belly: S, t: S) -> S {
    rt + (r0 - rt) * (S::ONE + belly * t) * (S::ONE - t * t)
}

fn check_value(id: ParamId, value: f32) -> Result<f32, ParamError> {
    if !value.is_finite() {
        return Err(ParamError::NotFinite { param: id });
    }
    let (min, max, whole) = id.range();
    if value < min || value > max {
        return Err(ParamError::OutOfRange {
            param: id,
            value,
            min,
            max,
        });
    }
    if whole && value != (value as u32) as f32 {
        return Err(ParamError::NotWholeNumber { param: id, value });
    }
    if id == ParamId::RingNodes && !(value as u32).is_power_of_two() {
        return Err(ParamError::RingNodesNotPowerOfTwo { value });
    }
    Ok(value)
}

#[cfg(feature = "std")]
impl std::error::Error for ParamError {}
