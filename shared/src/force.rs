//! Forces for the hand (Liang 2009 4.2.3, eqs. 4.2-4.7) and the output stage that makes them
//! safe to put in a person's hand.
//!
//! # The force model, once per 1 ms tick
//!
//! | term | equation | here |
//! |---|---|---|
//! | constraint (god-object) | 4.2 `F_c = -[k_s |dx| + k_d |dv_perp|] N_p` | the hand's ferrule below the paper pushes it back out: spring on the penetration, damper on the entering speed only, never pulling |
//! | gravity | 4.3 `F_g = -w_g m g N_p` | constant |
//! | normal | 4.4 `F_n = w_n (D_p / L_p) N_p` | D_p: depth of the virtual skeleton below the paper; L_p: its extent along the normal; first-order low-pass |
//! | friction | 4.5 `F_f = -w_f (n / N) V_par` | n: how many masses lie on the paper, counted continuously (each mass by how far its skeleton tie has faded, see `brush::TIE_RAMP_MM`), so the force has no steps |
//! | inertia | 4.6-4.7 `m = m_i + n m_mp` | a point mass dragged in the paper plane on a spring-damper from the handle, while the brush touches the paper; semi-implicit Euler; when m changes its kinetic energy never grows |
//!
//! A handy fact for the units: a displacement of 1 mm per 1 ms tick is a velocity of exactly
//! 1 m/s, so hand velocities need no scaling.
//!
//! # Defaults, and why (large brush)
//!
//! * `w_n = 6 N`: pressing the large brush 5 mm straight down (D_p / L_p = 5/40) gives 0.75 N;
//!   laying it nearly flat (D_p / L_p about 0.3) gives about 1.8 N, Baxter & Lin's "1-2 N
//!   bends a brush nearly 90 degrees".
//! * `k_s = 800 N/m`, `k_d = 0.2 N s/m` for the god-object: firm enough that the paper feels
//!   like a surface under the soft brush.
//! * Inertia: `m_i = 8 g`, `m_mp = 1.5 g` per mass on the paper, 150 N/m: about 30 g of drag
//!   when a third of the large brush lies on the paper, natural frequency under 20 Hz.
//! * Gravity: the brush's 15 g at w_g = 1: 0.15 N.
//!
//! **Passivity budget.** At 1 kHz with a zero-order hold and backward-difference velocities,
//! a virtual spring K with virtual damping B is passive on a device with physical damping b
//! only if `b > K T / 2 + |B|` (Colgate & Brown 1994): virtual damping *spends* the device's
//! damping instead of adding to it. A first-order low-pass of corner `1/(2 pi tau)` on a
//! spring K acts like a negative damper of up to `K tau`. With b = 1 N s/m (our assumption for
//! the Omni, see [`PHANTOM_OMNI`]) the defaults spend, per axis:
//!
//! | axis | terms | K T / 2 + B |
//! |---|---|---|
//! | normal, ferrule in the paper | god-object 800 N/m, 0.2 N s/m (the normal force saturates there) | 0.60 |
//! | normal, brush in the paper | w_n / L_p = 150 N/m, low-pass at 100 Hz (K tau = 0.24) | 0.32 |
//! | in the paper plane | inertia spring 150 N/m, 0.15 N s/m, friction w_f = 0.4 N s/m | 0.63 |
//!
//! hence a 100 Hz normal-force filter (the thesis filters to hide jumps of D_p / L_p; ours is
//! continuous, so a light filter does) and light viscous terms: the dragged brush at 100 mm/s
//! with a third of it on the paper resists with 0.013 N of friction plus the inertia's pull.
//! The test `colgate_brown_budget_of_the_defaults` keeps this table true; the passivity
//! audit in `tests/passivity.rs` checks the whole path against a simulated hand.
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
    /// Corner frequency of the normal force's low-pass (Hz).
    pub normal_cutoff_hz: f32,
    /// w_f of eq. 4.5 (N s/m).
    pub friction_weight: f32,
    /// m_i of eq. 4.6 (g).
    pub inertia_mass_g: f32,
    /// m_mp of eq. 4.6 (g per mass on the paper).
    pub inertia_per_contact_g: f32,
    /// Spring from the handle to the dragged mass (N/m).
    pub inertia_stiffness: f32,
    /// Damper from the handle to the dragged mass (N s/m).
    pub inertia_damping: f32,
}

/// The large brush's feel (see the module docs for why).
pub const DEFAULT_FORCES: ForceParams = ForceParams {
    constraint_stiffness: 800.0,
    constraint_damping: 0.2,
    gravity_weight: 1.0,
    brush_mass_g: 15.0,
    normal_weight: 6.0,
    normal_cutoff_hz: 100.0,
    friction_weight: 0.4,
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
    /// Every field with its name and valid range.
    pub fn fields(&self) -> [(&'static str, f32, f32, f32); 11] {
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
            ("normal_cutoff_hz", self.normal_cutoff_hz, 0.5, 400.0),
            ("friction_weight_ns_per_m", self.friction_weight, 0.0, 50.0),
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
    normal_alpha: S,
    w_f: S,
    m_i: S, // kg
    m_mp: S,
    k_i: S, // N per mm
    b_i: S,
    normal: S,
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
            normal_alpha: S::ZERO,
            w_f: S::ZERO,
            m_i: S::ZERO,
            m_mp: S::ZERO,
            k_i: S::ZERO,
            b_i: S::ZERO,
            normal: S::ZERO,
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
        // First-order low-pass by the matched pole: alpha = 1 - exp(-2 pi f T) (as -expm1, so
        // a low cutoff keeps its significant bits).
        let x = -2.0 * core::f32::consts::PI * p.normal_cutoff_hz * TICK_S as f32;
        self.normal_alpha = S::from_f32(-libm::expm1f(x));
        self.w_f = S::from_f32(p.friction_weight);
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
        self.last_hand = None;
        self.point_vel = Vec3::ZERO;
        self.point_mass = self.m_i;
    }

    /// The low-passed normal force's state (N), for the energy audit.
    pub fn normal_state(&self) -> S {
        self.normal
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
        let share = on_paper.div(S::from_usize(n_layers));

        // Normal (4.4): skeleton depth over its extent along the normal, low-passed.
        let skel = brush.skeleton();
        let mut lowest = skel[0].z;
        for s in skel {
            lowest = lowest.min(s.z);
        }
        let depth = if lowest < S::ZERO { -lowest } else { S::ZERO };
        let extent = (skel[0].z - lowest).max(S::from_f32(1e-3));
        let target = if depth > S::ZERO {
            self.w_n * depth.div(extent)
        } else {
            S::ZERO
        };
        self.normal += (target - self.normal) * self.normal_alpha;
        let normal = Vec3::new(S::ZERO, S::ZERO, self.normal);

        // Friction (4.5) in the paper plane.
        let friction = v.xy().scale(-(self.w_f * share));

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

    #[test]
    fn colgate_brown_budget_of_the_defaults() {
        let p = DEFAULT_FORCES;
        let b = PHANTOM_OMNI.damping_ns_per_m as f64;
        let half_t = TICK_S / 2.0;
        let tau = 1.0 / (2.0 * core::f64::consts::PI * p.normal_cutoff_hz as f64);
        let k_normal = p.normal_weight as f64 / 0.04; // large brush, L_p = 40 mm
        let budgets = [
            (
                "god-object",
                p.constraint_stiffness as f64 * half_t + p.constraint_damping as f64,
            ),
            ("normal force", k_normal * half_t + k_normal * tau),
            (
                "paper plane",
                p.inertia_stiffness as f64 * half_t
                    + p.inertia_damping as f64
                    + p.friction_weight as f64,
            ),
        ];
        for (axis, spent) in budgets {
            assert!(spent * 1.5 < b, "{axis}: spends {spent} of {b} N s/m");
        }
        assert!(PHANTOM_OMNI.max_stable_stiffness(p.constraint_damping as f64) > 1.5 * 800.0);
    }
}
