//! Forces for the hand (Liang 2009 4.2.3, eqs. 4.2-4.7) and the output stage that makes them
//! safe to put in a person's hand.
//!
//! # The force model, once per 1 ms tick
//!
//! | term | equation | here |
//! |---|---|---|
//! | constraint (god-object) | 4.2 `F_c = -[k_s |dx| + k_d |dv_perp|] N_p` | the hand's ferrule below the paper pushes it back out: spring on the penetration, damper on the entering speed only, never pulling |
//! | gravity | 4.3 `F_g = -w_g m g N_p` | constant |
//! | normal | 4.4 `F_n = w_n (D_p / L_p) N_p` | D_p: depth of the virtual skeleton below the paper; L_p: its extent along the normal, at least `w_n / K_max` (see the budget below); first-order low-pass |
//! | friction | Coulomb with stiction (default, [`FrictionLaw::Coulomb`]), or 4.5 `F_f = -w_f (n / N) V_par` ([`FrictionLaw::Viscous`]) | see *Friction* below; for 4.5, n: how many masses lie on the paper, counted continuously (each mass by how far its skeleton tie has faded, see `brush::TIE_RAMP_MM`), so the force has no steps |
//! | inertia | 4.6-4.7 `m = m_i + n m_mp` | a point mass dragged in the paper plane on a spring-damper from the handle, while the brush touches the paper; semi-implicit Euler; when m changes its kinetic energy never grows |
//!
//! A handy fact for the units: a displacement of 1 mm per 1 ms tick is a velocity of exactly
//! 1 m/s, so hand velocities need no scaling.
//!
//! # Friction
//!
//! The thesis's drag (4.5) is viscous, and a viscous term spends the device's damping (see the
//! budget below): the budget starved it to 0.4 N s/m, a few millinewtons at writing speeds,
//! and the hand felt no paper. Hair on paper is dry friction: while the brush slides the
//! paper holds it back with `mu_k F_n`, against the motion, and a resting brush needs
//! `mu_s F_n` to start. Baxter & Lin 2004 (section 5) find bristle-on-surface coefficients
//! "about 0.3-0.5" right for haptic painting (dry bristles on a canvas), and model stiction
//! (their 3.4.1) with a static coefficient above the kinetic one. A calligraphy brush slides
//! wet, its ink a lubricant between hair and paper, so the defaults sit just below that
//! range: `mu_k = 0.25` and `mu_s = 0.35`, the sliding brush held back with a quarter of the
//! normal force. (At 0.3 the guided-writing stroke, whose guide spring must stretch to
//! overcome the paper, lagged past its stated 2.5 mm RMS.)
//!
//! It reaches the hand through a bristle, the presliding element of Dahl's model and of
//! Hayward & Armstrong 2000 ("A new computational model of friction applied to haptic
//! rendering"): the ferrule is tied to an adhesion point on the paper by a spring of stiffness
//! `k_b` (the hairs' compliance before their tips slip), and the adhesion point slips when the
//! spring's force exceeds the friction bound. The model keeps the spring's force `f` (N, paper
//! plane, on the hand) as its state. Each tick the hand's step `dx` stretches it,
//! `f' = f - k_b dx`; if `|f'|` exceeds `mu F_n` (`mu_s` while sticking, `mu_k` while
//! sliding) the adhesion point slips along `f'` until `|f| = mu_k F_n`, and the brush is
//! sliding; otherwise it sticks. (Hysteresis as Baxter & Lin suggest: a breakaway at
//! `mu_s F_n` drops to `mu_k F_n`, and the brush sticks again once the hand stops pulling
//! the bristle further.) No division and no square root but the slip's one reciprocal root.
//!
//! **Passive by construction.** The bristle stores `E = |f|^2 / (2 k_b)`. Over a tick in which
//! the device held `f` and the hand moved `dx`, the hand did `W = -f . dx` on it, and the
//! stretched spring stores `|f - k_b dx|^2 / (2 k_b) = E + W + k_b |dx|^2 / 2`. The slip
//! multiplies `f'` by a factor `s` in `[0, 1]`, so the energy by `s^2 <= 1`: whatever the slip
//! rule decides (the coefficients, the switch between them, a normal force that changes under
//! the bristle), the bristle never returns more than the hand put in, but for the zero-order
//! hold's `k_b |dx|^2 / 2` of a spring, which the device's damping absorbs when
//! `b > k_b T / 2` (Colgate & Brown's condition with no virtual damping). So friction spends
//! only its spring's `k_b T / 2` of the device's damping, however hard it holds. The normal
//! force moves only the bound, never the stiffness: a stiffness that followed `F_n` would
//! pump energy (stretched at a light load, released at a heavy one).
//!
//! **Not scaled by n / N.** Coulomb friction follows the load, not the contact area
//! (Amontons), and `F_n` already grows with how much of the brush is pressed into the paper;
//! scaling by `n / N` as well would count the contact twice and let a lightly touching tip
//! slide almost freely (the thesis needs `n / N` because its viscous drag has no load). The
//! load is the brush's normal force only: the god-object (4.2) is the thesis's limit of the
//! workspace, not a force the hairs carry. When the brush leaves the paper `F_n` fades with
//! its filter and the bound with it, so the bristle relaxes to zero and contact starts afresh.
//!
//! # Defaults, and why (large brush)
//!
//! * `w_n = 6 N`: pressing the large brush 5 mm straight down (D_p / L_p = 5/40) gives 0.75 N;
//!   laying it nearly flat (D_p / L_p about 0.3) gives about 1.8 N, Baxter & Lin's "1-2 N
//!   bends a brush nearly 90 degrees".
//! * `K_max = 200 N/m`, the normal force's stiffness bound (below).
//! * `k_s = 800 N/m`, `k_d = 0.2 N s/m` for the god-object: firm enough that the paper feels
//!   like a surface under the soft brush.
//! * Friction: `mu_k = 0.25`, `mu_s = 0.35` (above), bristle `k_b = 500 N/m`: with the large
//!   brush pressed 5 mm the bristle stretches 0.5 mm before it breaks away and 0.4 mm while
//!   it slides, and it costs a quarter of the device's damping. The thesis's `w_f = 0.4 N s/m` is kept for [`FrictionLaw::Viscous`].
//! * Inertia: `m_i = 8 g`, `m_mp = 1.5 g` per mass on the paper, 150 N/m: about 30 g of drag
//!   when a third of the large brush lies on the paper, natural frequency under 20 Hz.
//! * Gravity: the brush's 15 g at w_g = 1: 0.15 N.
//!
//! **Passivity budget.** At 1 kHz with a zero-order hold and backward-difference velocities,
//! a virtual spring K with virtual damping B is passive on a device with physical damping b
//! only if `b > K T / 2 + |B|` (Colgate & Brown 1994): virtual damping *spends* the device's
//! damping instead of adding to it. A first-order low-pass of corner `1/(2 pi tau)` on a
//! spring K acts like a negative damper of up to `K tau`.
//!
//! The normal force's stiffness is `w_n / L_p`, and `L_p` is about `L cos(tilt)`: it grows
//! with the tilt and for a short brush, and one set of forces serves every brush. Unbounded,
//! a long brush steeply tilted, or a short one moderately, spent all of the device's damping.
//! So `L_p` is taken as at least `w_n / K_max`: the stiffness never exceeds `K_max`,
//! for any brush and pose (past it, the force grows with the depth at `K_max` and saturates
//! lower, at `K_max L_p` when the ferrule reaches the paper). With b = 1 N s/m (our assumption
//! for the Omni, see [`PHANTOM_OMNI`]) the defaults spend, per axis, at most:
//!
//! | axis | terms | K T / 2 + B |
//! |---|---|---|
//! | normal, ferrule in the paper | god-object 800 N/m, 0.2 N s/m (the normal force saturates there) | 0.60 |
//! | normal, brush in the paper | `w_n / L_p` at most K_max = 200 N/m, low-pass at 100 Hz (K tau = 0.32) | 0.42 |
//! | in the paper plane, Coulomb friction (default) | inertia spring 150 N/m, 0.15 N s/m; bristle 500 N/m | 0.48 |
//! | in the paper plane, viscous friction (4.5) | inertia spring 150 N/m, 0.15 N s/m; w_f = 0.4 N s/m | 0.63 |
//!
//! hence a 100 Hz normal-force filter (the thesis filters to hide jumps of D_p / L_p; ours is
//! continuous, so a light filter does) and light viscous terms. The test
//! `colgate_brown_budget_of_every_preset_at_every_tilt` keeps this table true, with the normal
//! force's stiffness measured from the model for each preset over the pen's tilts (0-75
//! degrees); the passivity audit in `tests/passivity.rs` checks the whole path, friction
//! included, against a simulated hand for each preset at four tilts.
//!
//! # The output stage (same for every device)
//!
//! [`OutputStage::apply`] turns the model's force into the command: passivity controller (the
//! observer of Hannaford & Ryu 2002: the energy the device has put into the hand, and a damping
//! force that takes back any surplus the next tick; the energy is kept in mJ in the model's
//! scalar, so the 1 kHz loop does no double-precision arithmetic, which the Cortex-M4F has
//! only as library calls), ramp-in after enabling, clamp to the peak
//! force and, when the thermal average says so, to the continuous force, a limit on the step
//! between ticks, and on a fault a ramp-out that bypasses the step limit and reaches zero within
//! the ramp-out time.

use crate::brush::Brush;
use crate::scalar::Scalar;
use crate::vec::Vec3;
use core::fmt;

/// Standard gravity (m/s^2).
pub const G: f64 = 9.806_65;
/// The force loop's period (s).
pub const TICK_S: f64 = 1e-3;

/// Which friction the hand feels in the paper plane (see the module docs).
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub enum FrictionLaw {
    /// Coulomb friction with stiction through a bristle (presliding) spring: passive by
    /// construction, `mu_k F_n` against a sliding brush.
    Coulomb,
    /// The thesis's viscous drag, eq. 4.5: `-w_f (n / N) V_par`, for comparison with the
    /// paper. It spends `w_f` of the device's damping.
    Viscous,
}

/// Weights and constants of the force model. Validated by [`ForceParams::validate`].
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct ForceParams {
    /// k_s of eq. 4.2 (N/m).
    pub constraint_stiffness: f32,
    /// k_d of eq. 4.2 (N s/m).
    pub constraint_damping: f32,
    /// w_g of eq. 4.3.
    pub gravity_weight: f32,
    /// m of eq. 4.3 (g).
    pub brush_mass_g: f32,
    /// w_n of eq. 4.4 (N).
    pub normal_weight: f32,
    /// K_max: the normal force's largest stiffness, `w_n / L_p` with L_p no shorter than
    /// `w_n / K_max` (N/m), so that it stays within the device's passivity budget for every
    /// brush and tilt.
    pub normal_stiffness_max: f32,
    /// Corner frequency of the normal force's low-pass (Hz).
    pub normal_cutoff_hz: f32,
    /// The friction in the paper plane.
    pub friction: FrictionLaw,
    /// w_f of eq. 4.5 (N s/m), for [`FrictionLaw::Viscous`].
    pub friction_weight: f32,
    /// mu_k: the sliding brush's friction over its normal force, for [`FrictionLaw::Coulomb`].
    pub kinetic_friction: f32,
    /// mu_s: the friction over the normal force that starts a sticking brush sliding, at
    /// least mu_k.
    pub static_friction: f32,
    /// k_b: the bristle's stiffness, from the ferrule to where the brush adheres (N/m).
    pub bristle_stiffness: f32,
    /// m_i of eq. 4.6 (g).
    pub inertia_mass_g: f32,
    /// m_mp of eq. 4.6 (g per mass on the paper).
    pub inertia_per_contact_g: f32,
    /// Spring from the handle to the dragged mass (N/m).
    pub inertia_stiffness: f32,
    /// Damper from the handle to the dragged mass (N s/m).
    pub inertia_damping: f32,
}

/// The large brush's feel, which serves every brush (see the module docs for why).
pub const DEFAULT_FORCES: ForceParams = ForceParams {
    constraint_stiffness: 800.0,
    constraint_damping: 0.2,
    gravity_weight: 1.0,
    brush_mass_g: 15.0,
    normal_weight: 6.0,
    normal_stiffness_max: 200.0,
    normal_cutoff_hz: 100.0,
    friction: FrictionLaw::Coulomb,
    friction_weight: 0.4,
    kinetic_friction: 0.25,
    static_friction: 0.35,
    bristle_stiffness: 500.0,
    inertia_mass_g: 8.0,
    inertia_per_contact_g: 1.5,
    inertia_stiffness: 150.0,
    inertia_damping: 0.15,
};

/// A rejected force or device parameter: its name, the value and the valid range.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct LimitError {
    pub name: &'static str,
    pub value: f32,
    pub min: f32,
    pub max: f32,
}

impl fmt::Display for LimitError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.value.is_finite() {
            write!(
                f,
                "{}: {} is outside the valid range {} ..= {}",
                self.name, self.value, self.min, self.max
            )
        } else {
            write!(f, "{}: value is not a finite number", self.name)
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for LimitError {}

/// Whether `value` is finite and within `[min, max]`, else the error naming it. Out of line:
/// the configurations call it for every field, and one copy of the test and the error's
/// construction is smaller in the pen's flash than one per field.
#[inline(never)]
pub(crate) fn check(name: &'static str, value: f32, min: f32, max: f32) -> Result<(), LimitError> {
    if value.is_finite() && value >= min && value <= max {
        Ok(())
    } else {
        Err(LimitError {
            name,
            value,
            min,
            max,
        })
    }
}

impl ForceParams {
    /// Every numeric field with its name and valid range (mu_s's lower end is mu_k).
    pub fn fields(&self) -> [(&'static str, f32, f32, f32); 15] {
        [
            (
                "constraint_stiffness_n_per_m",
                self.constraint_stiffness,
                0.0,
                5000.0,
            ),
            (
                "constraint_damping_ns_per_m",
                self.constraint_damping,
                0.0,
                20.0,
            ),
            ("gravity_weight", self.gravity_weight, 0.0, 2.0),
            ("brush_mass_g", self.brush_mass_g, 0.0, 200.0),
            ("normal_weight_n", self.normal_weight, 0.0, 50.0),
            (
                "normal_stiffness_max_n_per_m",
                self.normal_stiffness_max,
                1.0,
                5000.0,
            ),
            ("normal_cutoff_hz", self.normal_cutoff_hz, 0.5, 400.0),
            ("friction_weight_ns_per_m", self.friction_weight, 0.0, 50.0),
            ("kinetic_friction", self.kinetic_friction, 0.0, 2.0),
            (
                "static_friction",
                self.static_friction,
                self.kinetic_friction,
                2.0,
            ),
            (
                "bristle_stiffness_n_per_m",
                self.bristle_stiffness,
                1.0,
                5000.0,
            ),
            ("inertia_mass_g", self.inertia_mass_g, 0.5, 500.0),
            (
                "inertia_per_contact_g",
                self.inertia_per_contact_g,
                0.0,
                100.0,
            ),
            (
                "inertia_stiffness_n_per_m",
                self.inertia_stiffness,
                0.0,
                2000.0,
            ),
            ("inertia_damping_ns_per_m", self.inertia_damping, 0.0, 20.0),
        ]
    }

    pub fn validate(&self) -> Result<(), LimitError> {
        for (name, v, lo, hi) in self.fields() {
            check(name, v, lo, hi)?;
        }
        Ok(())
    }
}

/// What a device can and may do with a force (newtons, seconds). Serialisable: a physical
/// pen stores its own in its configuration ([`crate::pen_io::DeviceConfig`]).
#[derive(Copy, Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct DeviceLimits {
    /// Largest force, briefly.
    pub peak_n: f32,
    /// Largest force, indefinitely (motor heating).
    pub continuous_n: f32,
    /// Time constant of the thermal average of |F|^2.
    pub thermal_time_s: f32,
    /// Largest change of the commanded force between two ticks (N).
    pub max_step_n: f32,
    /// Forces fade in over this time after enabling.
    pub ramp_in_s: f32,
    /// On a fault or disable, forces fade out over this time (0: the next tick is zero).
    pub ramp_out_s: f32,
    /// The device's physical damping at the handle (N s/m): motors' back-EMF, friction.
    pub damping_ns_per_m: f32,
}

/// Phantom Omni: 3.3 N peak, 0.88 N continuous (SensAble's data sheet, Liang 2009 table 4-1).
/// Its physical damping is not published; the data sheet's rated stiffness (1.02-2.31 N/mm)
/// implies at least 0.5-1.2 N s/m by `b > K T / 2` at 1 kHz, and we assume 1.0.
pub const PHANTOM_OMNI: DeviceLimits = DeviceLimits {
    peak_n: 3.3,
    continuous_n: 0.88,
    thermal_time_s: 2.0,
    max_step_n: 0.2,
    ramp_in_s: 0.5,
    ramp_out_s: 0.0,
    damping_ns_per_m: 1.0,
};

impl DeviceLimits {
    pub fn validate(&self) -> Result<(), LimitError> {
        check("peak_n", self.peak_n, 0.0, 50.0)?;
        check("continuous_n", self.continuous_n, 0.0, self.peak_n)?;
        check("thermal_time_s", self.thermal_time_s, 0.01, 600.0)?;
        check("max_step_n", self.max_step_n, 1e-4, 50.0)?;
        check("ramp_in_s", self.ramp_in_s, 0.0, 10.0)?;
        check("ramp_out_s", self.ramp_out_s, 0.0, 1.0)?;
        check("damping_ns_per_m", self.damping_ns_per_m, 0.0, 100.0)
    }

    /// Largest virtual stiffness the device renders passively at 1 kHz by Colgate & Brown's
    /// condition `b > K T / 2 + B`, with B the virtual damping in parallel (N/m).
    pub fn max_stable_stiffness(&self, virtual_damping: f64) -> f64 {
        (2.0 * (self.damping_ns_per_m as f64 - virtual_damping) / TICK_S).max(0.0)
    }
}

/// The model's force for one tick, split by term (newtons, paper frame).
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct Forces<S> {
    pub total: Vec3<S>,
    pub constraint: Vec3<S>,
    pub gravity: Vec3<S>,
    pub normal: Vec3<S>,
    pub friction: Vec3<S>,
    pub inertia: Vec3<S>,
    /// D_p: depth of the virtual skeleton below the paper (mm).
    pub depth_mm: S,
    /// n: masses lying on the paper, counted continuously.
    pub on_paper: S,
}

/// The force model's state and its per-tick coefficients.
#[derive(Clone, Debug)]
pub struct ForceModel<S> {
    params: ForceParams,
    k_c: S, // N per mm
    b_c: S, // N per (m/s)
    gravity: S,
    w_n: S,
    /// L_p's floor, w_n / K_max (mm).
    extent_floor: S,
    normal_alpha: S,
    w_f: S,
    mu_k: S,
    mu_s: S,
    k_b: S, // N per mm
    m_i: S, // kg
    m_mp: S,
    k_i: S, // N per mm
    b_i: S,
    normal: S,
    /// The bristle's force on the hand (N, paper plane): its stretch times k_b.
    bristle_x: S,
    bristle_y: S,
    /// The brush slid last tick (its friction bound is mu_k, else mu_s).
    sliding: bool,
    point: Vec3<S>,     // mm
    point_vel: Vec3<S>, // m/s
    point_mass: S,      // kg
    last_hand: Option<Vec3<S>>,
}

impl<S: Scalar> ForceModel<S> {
    pub fn new(params: ForceParams) -> Result<Self, LimitError> {
        params.validate()?;
        let mut m = ForceModel {
            params,
            k_c: S::ZERO,
            b_c: S::ZERO,
            gravity: S::ZERO,
            w_n: S::ZERO,
            extent_floor: S::ZERO,
            normal_alpha: S::ZERO,
            w_f: S::ZERO,
            mu_k: S::ZERO,
            mu_s: S::ZERO,
            k_b: S::ZERO,
            m_i: S::ZERO,
            m_mp: S::ZERO,
            k_i: S::ZERO,
            b_i: S::ZERO,
            normal: S::ZERO,
            bristle_x: S::ZERO,
            bristle_y: S::ZERO,
            sliding: false,
            point: Vec3::ZERO,
            point_vel: Vec3::ZERO,
            point_mass: S::ZERO,
            last_hand: None,
        };
        m.derive();
        Ok(m)
    }

    pub fn params(&self) -> &ForceParams {
        &self.params
    }

    /// Replaces the parameters (validated; on error nothing changes). The state is kept.
    pub fn set_params(&mut self, params: ForceParams) -> Result<(), LimitError> {
        params.validate()?;
        self.params = params;
        self.derive();
        Ok(())
    }

    fn derive(&mut self) {
        let p = &self.params;
        // In single precision, like the parameters: the pen derives these with its FPU, where
        // `f64` would be software (see `BrushParams::substep_s`).
        self.k_c = S::from_f32(p.constraint_stiffness * 1e-3);
        self.b_c = S::from_f32(p.constraint_damping);
        self.gravity = S::from_f32(-p.gravity_weight * p.brush_mass_g * 1e-3 * G as f32);
        self.w_n = S::from_f32(p.normal_weight);
        self.extent_floor = S::from_f32(p.normal_weight / p.normal_stiffness_max * 1e3);
        // First-order low-pass by the matched pole: alpha = 1 - exp(-2 pi f T) (as -expm1, so
        // a low cutoff keeps its significant bits).
        let x = -2.0 * core::f32::consts::PI * p.normal_cutoff_hz * TICK_S as f32;
        self.normal_alpha = S::from_f32(-libm::expm1f(x));
        self.w_f = S::from_f32(p.friction_weight);
        self.mu_k = S::from_f32(p.kinetic_friction);
        self.mu_s = S::from_f32(p.static_friction);
        self.k_b = S::from_f32(p.bristle_stiffness * 1e-3);
        self.m_i = S::from_f32(p.inertia_mass_g * 1e-3);
        self.m_mp = S::from_f32(p.inertia_per_contact_g * 1e-3);
        self.k_i = S::from_f32(p.inertia_stiffness * 1e-3);
        self.b_i = S::from_f32(p.inertia_damping);
        if self.point_mass == S::ZERO {
            self.point_mass = self.m_i;
        }
    }

    /// Forgets the motion history (after a reset or a reconnect): the next tick sees the hand
    /// at rest and the filters start from zero.
    pub fn reset(&mut self) {
        self.normal = S::ZERO;
        self.bristle_x = S::ZERO;
        self.bristle_y = S::ZERO;
        self.sliding = false;
        self.last_hand = None;
        self.point_vel = Vec3::ZERO;
        self.point_mass = self.m_i;
    }

    /// The low-passed normal force's state (N), for the energy audit.
    pub fn normal_state(&self) -> S {
        self.normal
    }

    /// Energy stored in the friction's bristle (J), for the energy audit: `|f|^2 / (2 k_b)`.
    pub fn friction_energy(&self) -> f64 {
        let (x, y) = (self.bristle_x.to_f64(), self.bristle_y.to_f64());
        (x * x + y * y) / (2.0 * self.params.bristle_stiffness as f64)
    }

    /// The normal force's L_p for a skeleton that reaches `extent_mm` along the normal (mm):
    /// no shorter than w_n / K_max, so the force's stiffness `w_n / L_p` is at most K_max.
    pub fn normal_extent(&self, extent_mm: S) -> S {
        extent_mm.max(self.extent_floor)
    }

    /// Energy stored in the dragged point mass and its spring (J), for the energy audit.
    pub fn inertia_energy(&self, hand: Vec3<S>) -> f64 {
        let d = (hand - self.point).xy().to_f64();
        let v = self.point_vel.to_f64();
        let m = self.point_mass.to_f64();
        0.5 * m * (v[0] * v[0] + v[1] * v[1])
            + 0.5 * self.params.inertia_stiffness as f64 * (d[0] * d[0] + d[1] * d[1]) * 1e-6
    }

    /// One tick: the force on the hand (N) for the brush's state after this tick's substeps,
    /// with the hand's ferrule at `hand` (mm; it may be below the paper, where the brush
    /// model's handle was kept on it).
    pub fn tick(&mut self, brush: &Brush<S>, hand: Vec3<S>) -> Forces<S> {
        let v = match self.last_hand {
            Some(last) => hand - last,
            None => Vec3::ZERO,
        };
        self.last_hand = Some(hand);

        // Constraint (4.2): penetration spring, entering-speed damper; pushes only.
        let mut constraint = Vec3::ZERO;
        if hand.z < S::ZERO {
            let entering = if v.z < S::ZERO { -v.z } else { S::ZERO };
            let push = self.k_c * (-hand.z) + self.b_c * entering;
            constraint.z = push.max(S::ZERO);
        }

        let gravity = Vec3::new(S::ZERO, S::ZERO, self.gravity);

        // How much of the brush lies on the paper: n, continuously.
        let n_layers = brush.len();
        let mut on_paper = S::ZERO;
        for i in 1..n_layers {
            on_paper += S::ONE - brush.tie_weight(i);
        }

        // Normal (4.4): skeleton depth over its extent along the normal (bounded below, see
        // the budget in the module docs), low-passed.
        let skel = brush.skeleton();
        let mut lowest = skel[0].z;
        for s in skel {
            lowest = lowest.min(s.z);
        }
        let depth = if lowest < S::ZERO { -lowest } else { S::ZERO };
        let target = if depth > S::ZERO {
            self.w_n * depth.div(self.normal_extent(skel[0].z - lowest))
        } else {
            S::ZERO
        };
        self.normal += (target - self.normal) * self.normal_alpha;
        let normal = Vec3::new(S::ZERO, S::ZERO, self.normal);

        // Friction in the paper plane.
        let friction = match self.params.friction {
            FrictionLaw::Coulomb => {
                let (x, y) = self.bristle(v);
                Vec3::new(x, y, S::ZERO)
            }
            FrictionLaw::Viscous => {
                // 4.5, with n / N.
                let drag = -(self.w_f * on_paper.div(S::from_usize(n_layers)));
                Vec3::new(v.x * drag, v.y * drag, S::ZERO)
            }
        };

        // Inertia (4.6-4.7) in the paper plane, engaged in proportion to contact (up to one
        // mass's worth), so it fades in and out without steps.
        let engage = on_paper.min(S::ONE);
        let mass = self.m_i + self.m_mp * on_paper;
        if mass > self.point_mass {
            // Heavier: keep momentum, so kinetic energy falls.
            self.point_vel = self.point_vel.scale(self.point_mass.div(mass));
        } // Lighter: keep velocity, so kinetic energy falls too.
        self.point_mass = mass;
        let inertia;
        if engage > S::ZERO {
            let pull = (hand - self.point).xy().scale(self.k_i)
                + (v - self.point_vel).xy().scale(self.b_i);
            inertia = -pull.scale(engage);
            let dt_over_m = S::from_f32(TICK_S as f32).div(mass);
            self.point_vel += pull.scale(dt_over_m);
            self.point += self.point_vel; // 1 m/s = 1 mm per tick
            self.point.z = hand.z;
        } else {
            // Not touching: the point rides with the hand, so contact starts without a jerk.
            inertia = Vec3::ZERO;
            self.point = hand;
            self.point_vel = v;
        }

        let total = constraint + gravity + normal + friction + inertia;
        Forces {
            total,
            constraint,
            gravity,
            normal,
            friction,
            inertia,
            depth_mm: depth,
            on_paper,
        }
    }

    /// Coulomb friction with stiction: the bristle stretched by the hand's step `v` (mm),
    /// slipping to the kinetic bound when it exceeds the bound of its state, and the force it
    /// puts on the hand (N, paper plane). See the module docs for the model and its passivity.
    #[inline]
    fn bristle(&mut self, v: Vec3<S>) -> (S, S) {
        let x = self.bristle_x - self.k_b * v.x;
        let y = self.bristle_y - self.k_b * v.y;
        let f2 = x * x + y * y;
        let kinetic = self.mu_k * self.normal;
        let bound = if self.sliding {
            kinetic
        } else {
            self.mu_s * self.normal
        };
        // The normal force is never negative, so the bound is not, and comparing squares
        // compares the lengths.
        let (x, y) = if f2 > bound * bound {
            // Slips along itself to the kinetic bound: a factor in [0, 1], which is what keeps
            // it passive (hence the clamp: a rounding must not make it exceed one). Below one
            // it is a coefficient (the cheaper product); at one there is nothing to scale.
            let s = (kinetic * f2.rsqrt()).min(S::ONE);
            self.sliding = true;
            if s.is_coef() {
                (x.mul_tested_coef(s), y.mul_tested_coef(s))
            } else {
                (x, y)
            }
        } else {
            self.sliding = false;
            (x, y)
        };
        self.bristle_x = x;
        self.bristle_y = y;
        (x, y)
    }
}

/// Why the output stage is holding the force at zero, if it is.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub enum OutputState {
    /// Forces disabled (at start, or by command).
    Disabled,
    /// Fading in after enabling.
    RampingIn,
    /// Rendering forces.
    Active,
    /// A fault latched; fading out or at zero until cleared.
    Faulted,
}

/// Turns the model's force into a safe command (see the module docs).
#[derive(Clone, Debug)]
pub struct OutputStage<S> {
    limits: DeviceLimits,
    peak: S,
    continuous: S,
    thermal_alpha: S,
    max_step: S,
    ramp_in_step: S,
    ramp_out_step: S,
    enabled: bool,
    fault: bool,
    gain: S,
    last: Vec3<S>,
    thermal: S,
    /// Energy the device has absorbed from the hand so far (mJ, N mm); negative means it has
    /// put energy in. The resolution of [`crate::Fx`] (2^-32 mJ) makes each tick's rounding
    /// about 2e-13 J: a day at 1 kHz sums below 2e-5 J, and the range (2^31 mJ, 2 MJ) far
    /// exceeds anything a pen absorbs.
    absorbed_mj: S,
    /// The passivity damper's largest coefficient (N s/m, i.e. N per mm/tick): the one that
    /// reaches the peak force at 1 mm/s.
    damper_max: S,
    passivity_control: bool,
}

impl<S: Scalar> OutputStage<S> {
    pub fn new(limits: DeviceLimits) -> Result<Self, LimitError> {
        limits.validate()?;
        let step = |s: f32| {
            if s > 0.0 {
                S::from_f32((TICK_S as f32 / s).min(1.0))
            } else {
                S::ONE
            }
        };
        Ok(OutputStage {
            limits,
            peak: S::from_f32(limits.peak_n),
            continuous: S::from_f32(limits.continuous_n),
            thermal_alpha: S::from_f32(-libm::expm1f(-(TICK_S as f32) / limits.thermal_time_s)),
            max_step: S::from_f32(limits.max_step_n),
            ramp_in_step: step(limits.ramp_in_s),
            ramp_out_step: step(limits.ramp_out_s),
            enabled: false,
            fault: false,
            gain: S::ZERO,
            last: Vec3::ZERO,
            thermal: S::ZERO,
            absorbed_mj: S::ZERO,
            damper_max: S::from_f32(limits.peak_n * 1e3),
            passivity_control: true,
        })
    }

    pub fn limits(&self) -> &DeviceLimits {
        &self.limits
    }

    /// Forces fade in from zero, whatever the pen is touching.
    pub fn enable(&mut self) {
        self.enabled = true;
    }
    pub fn disable(&mut self) {
        self.enabled = false;
    }
    /// Latches a fault: forces fade out and stay at zero until [`OutputStage::clear_fault`].
    pub fn fault(&mut self) {
        self.fault = true;
    }
    pub fn clear_fault(&mut self) {
        self.fault = false;
    }
    pub fn faulted(&self) -> bool {
        self.fault
    }
    /// Turns the passivity controller off (for tests that audit the raw model).
    pub fn set_passivity_control(&mut self, on: bool) {
        self.passivity_control = on;
    }
    /// Energy the device has absorbed from the hand (J; negative: it has given energy).
    pub fn absorbed_energy(&self) -> f64 {
        self.absorbed_mj.to_f64() * 1e-3
    }
    pub fn last_command(&self) -> Vec3<S> {
        self.last
    }

    pub fn state(&self) -> OutputState {
        if self.fault {
            OutputState::Faulted
        } else if !self.enabled {
            OutputState::Disabled
        } else if self.gain < S::ONE {
            OutputState::RampingIn
        } else {
            OutputState::Active
        }
    }

    /// The command for this tick. `hand_step` is the hand's displacement since the last tick
    /// (mm, i.e. its velocity in m/s), over which the last command was applied.
    pub fn apply(&mut self, wanted: Vec3<S>, hand_step: Vec3<S>) -> Vec3<S> {
        self.apply_with_source(wanted, hand_step, S::ZERO)
    }

    /// As [`OutputStage::apply`], for a force that includes an intended source of energy:
    /// `source_mj`, what a guide's moving point supplied this tick (mJ,
    /// [`crate::guide::GuideForce::source_mj`]), is credited to the passivity observer so
    /// the controller does not take back energy that was meant to lead the hand.
    pub fn apply_with_source(
        &mut self,
        wanted: Vec3<S>,
        hand_step: Vec3<S>,
        source_mj: S,
    ) -> Vec3<S> {
        // Passivity observer: the work the last command did on the hand (N x mm = mJ).
        let work_mj = self.last.dot(hand_step);
        self.absorbed_mj += source_mj - work_mj;

        let holding = self.fault || !self.enabled;
        if holding {
            // Ramp out along the last command, bypassing the step limit.
            let old = self.gain;
            self.gain = (self.gain - self.ramp_out_step).max(S::ZERO);
            self.last = if old > S::ZERO {
                self.last.scale(self.gain.div(old))
            } else {
                Vec3::ZERO
            };
            return self.last;
        }
        self.gain = (self.gain + self.ramp_in_step).min(S::ONE);

        let mut target = wanted;
        // Passivity controller: if the device has put net energy into the hand, add a damper
        // that takes it back over this tick: F = -a v with a |v|^2 T = surplus.
        // With v in mm per tick (m/s) and T = 1 ms, a = surplus_J / (|v|^2 T) is the surplus
        // in mJ over |v|^2, at most `damper_max` (the comparison before the division keeps the
        // quotient in range when |v| is tiny).
        if self.passivity_control && self.absorbed_mj < S::ZERO {
            let v2 = hand_step.norm2();
            if v2 > S::ZERO {
                let surplus_mj = -self.absorbed_mj;
                let a = if surplus_mj < self.damper_max * v2 {
                    surplus_mj.div(v2)
                } else {
                    self.damper_max
                };
                target -= hand_step.scale(a);
            }
        }
        target = target.scale(self.gain);

        // Thermal limit: above the continuous force's square on average, clamp to it.
        let limit = if self.thermal > self.continuous * self.continuous {
            self.continuous
        } else {
            self.peak
        };
        target = clamp_norm(target, limit);

        // Step limit.
        let step = target - self.last;
        let cmd = self.last + clamp_norm(step, self.max_step);
        self.thermal += (cmd.norm2() - self.thermal) * self.thermal_alpha;
        self.last = cmd;
        cmd
    }
}

/// Squares above this (N^2) may have saturated in fixed point (`Fx`'s range ends at 2^31),
/// so the norm from them is too short and a clamp by it too weak.
const SQUARE_MAY_SATURATE: f32 = 1.0e9;

/// `v` scaled down to length `max` if it is longer.
fn clamp_norm<S: Scalar>(v: Vec3<S>, max: S) -> Vec3<S> {
    let n2 = v.norm2();
    if n2 > max * max {
        if n2 > S::from_f32(SQUARE_MAY_SATURATE) {
            // A force from a model pushed far outside its range (a hostile host's poses):
            // measure it scaled by its longest component, whose square cannot saturate.
            let big = v.x.abs().max(v.y.abs()).max(v.z.abs());
            let u = v.scale(big.recip());
            return u.scale(max * u.norm2().rsqrt());
        }
        v.scale(max * n2.rsqrt())
    } else {
        v
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::{presets, Pose, Quat};
    extern crate std;
    use std::{format, string::ToString, vec};

    /// The normal force's stiffness (N/m) on `params`'s brush at `tilt_deg`, measured from
    /// the model: the settled force at two depths of the skeleton's tip, a quarter and half of
    /// its extent, differenced.
    fn normal_stiffness(params: crate::BrushParams, tilt_deg: f64) -> f64 {
        let h = tilt_deg.to_radians() / 2.0;
        let rot = Quat::from_f64([h.cos(), 0.0, h.sin(), 0.0]);
        let at = |z: f64| Pose::new(Vec3::from_f64([0.0, 0.0, z]), rot);
        let air = Brush::<f64>::new(params, at(100.0)).unwrap();
        let skel = air.skeleton();
        let extent = skel[0].z - skel.iter().map(|s| s.z).fold(f64::MAX, f64::min);
        // The ferrule `extent - depth` above the paper puts the skeleton's lowest point
        // `depth` into it; the hand holds still there while the low-pass settles.
        let settled = |depth: f64| {
            let brush = Brush::<f64>::new(params, at(extent - depth)).unwrap();
            let mut model = ForceModel::<f64>::new(DEFAULT_FORCES).unwrap();
            let mut f = 0.0;
            for _ in 0..400 {
                f = model.tick(&brush, brush.handle().pos).normal.z;
            }
            f
        };
        let (d1, d2) = (0.25 * extent, 0.5 * extent);
        (settled(d2) - settled(d1)) / (d2 - d1) * 1e3
    }

    #[test]
    fn colgate_brown_budget_of_every_preset_at_every_tilt() {
        let p = DEFAULT_FORCES;
        let b = PHANTOM_OMNI.damping_ns_per_m as f64;
        let half_t = TICK_S / 2.0;
        let tau = 1.0 / (2.0 * core::f64::consts::PI * p.normal_cutoff_hz as f64);
        let margin = 1.5;
        let mut fixed = vec![
            (
                "god-object".to_string(),
                p.constraint_stiffness as f64 * half_t + p.constraint_damping as f64,
            ),
            (
                "paper plane, Coulomb friction".to_string(),
                (p.inertia_stiffness + p.bristle_stiffness) as f64 * half_t
                    + p.inertia_damping as f64,
            ),
            (
                "paper plane, viscous friction".to_string(),
                p.inertia_stiffness as f64 * half_t
                    + p.inertia_damping as f64
                    + p.friction_weight as f64,
            ),
        ];
        let mut stiffest = 0.0f64;
        for (name, params) in presets::PRESETS {
            for tilt in 0..=75 {
                let k = normal_stiffness(*params, tilt as f64);
                stiffest = stiffest.max(k);
                fixed.push((
                    format!("normal force, {name} brush at {tilt} degrees ({k:.0} N/m)"),
                    k * half_t + k * tau,
                ));
            }
        }
        for (axis, spent) in fixed {
            assert!(spent * margin < b, "{axis}: spends {spent} of {b} N s/m");
        }
        // The bound is what holds it: within the stiffness's rounding of K_max.
        assert!(
            stiffest <= p.normal_stiffness_max as f64 * (1.0 + 1e-6),
            "{stiffest}"
        );
        assert!(PHANTOM_OMNI.max_stable_stiffness(p.constraint_damping as f64) > 1.5 * 800.0);
    }
}
