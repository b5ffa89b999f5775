//! The brush: spine dynamics (SPEC A), virtual skeleton and plasticity (SPEC B) and the
//! surface ellipses (SPEC C), after Liang 2009 chapters 2-4.
//!
//! # One substep
//!
//! 1. **Handle.** The ferrule mass S_0 and the virtual skeleton VS_i move rigidly with the
//!    handle pose (the skeleton's directions are stored in the handle frame, so the skeleton
//!    turns with the handle). The ferrule is kept on or above the paper: like the thesis's
//!    god-object (4.2.3) the drawn brush never enters the paper; how far the *hand* went in is
//!    the force model's business.
//! 2. **Dynamics** (eqs. 2.19-2.33, Kang & Cho). Velocities are kept as displacement per
//!    substep `u = v h` (mm); multiplying eq. 2.33 through by `h` gives, for free mass i,
//!
//!    ```text
//!    p_i   = c_k sum_j [(1 - L/|d_ij|) d_ij + (u_j - u_i)] + c_d sum_j (u_j - u_i)
//!          + t_i [c_t (VS_i - S_i) + (c_t + c_dt) (w_i - u_i)]
//!    du_i(0) = p_i,   du_i(k) = p_i + (c_k + c_d) sum_j du_j(k-1)
//!    ```
//!
//!    with `c_k = h^2 k_s / W'_i`, `c_d = h k_d / W'_i`, `c_t = h^2 k_t / W'_i`,
//!    `c_dt = h k_dt / W'_i`, `W'_i = m + h^2 (n_i k_s + t_i k_t) + h (n_i k_d + t_i k_dt)`,
//!    `t_i` the weight of mass i's tie to the skeleton (0 lying on the paper, 3.1.2, rising
//!    to 1 at [`TIE_RAMP_MM`]; the implicit rows always include the tie, which changes W' by
//!    under 0.01% at the presets' stiffness and keeps the solve independent of contact),
//!    `w_i` the skeleton node's own displacement this substep, and `du_0` the ferrule's
//!    prescribed velocity change. The coefficients are dimensionless and computed in `f64`
//!    when a parameter changes, so `h^2` never meets the fixed-point format.
//!
//!    The iterations are the thesis's method and are used while they converge well; for
//!    stiffer springs or longer substeps the same system is solved exactly in O(N) (see
//!    [`JACOBI_LIMIT`] for the stability analysis behind the switch).
//! 3. **Paper.** Viscous drag (eq. 4.1) on masses lying on the paper, applied implicitly
//!    (`u_par /= 1 + h C_f / m`, stable for any drag). Then `S_i += u_i`, and a mass below the
//!    paper is projected back onto it with its downward velocity removed (Fig. 4-5).
//!
//! Once per 1 ms tick, after the substeps ([`Brush::end_tick`]):
//!
//! 4. **Plasticity** (eqs. 3-1..3-6) when D > 0.
//! 5. **Surface** (eqs. 3-7..3-21): per-layer ellipse axes and radii.
//!
//! # Deviations from the thesis, and why
//!
//! * Eq. 3-3 interpolates with weight i/(N-1), which moves the end direction V_{N-2} it has just
//!   set; we use i/(N-2) so both ends keep their values.
//! * D and SDF are per-step rates in the thesis, which ran them at 25 kHz. They are stated at
//!   that reference rate and converted to the 1 kHz tick at which we run them,
//!   `1 - (1 - D)^(25 kHz / 1 kHz)`, so a brush behaves the same at any substep rate.
//! * Eq. 3-8 interpolates the short axis toward the paper normal but never makes it
//!   perpendicular to the spine segment, so near a vertical brush the "cross-section"
//!   ellipse stands upright. We keep the interpolated direction's intent and use
//!   `SA = V x LA` (the interpolated SA with its component along the segment removed), so
//!   every ellipse is a true cross-section of the hair bundle.
//! * Eq. 3.11's cross product vanishes when a layer's short axis is parallel to its spine
//!   segment (a brush pressed straight down): the previous long axis, made perpendicular to
//!   the segment, is kept instead.

// The solver walks chains of masses touching i-1, i and i+1 of several arrays at once; index
// loops say that more plainly than zipped iterators.
#![allow(clippy::needless_range_loop)]

use crate::params::{BrushParams, ParamError, ParamId, MAX_LAYERS, REFERENCE_SUBSTEP_HZ, TICK_HZ};
use crate::quat::{Pose, Quat};
use crate::scalar::Scalar;
use crate::vec::Vec3;

/// Largest Jacobi off-diagonal weight `c_j = (h^2 k_s + h k_d) / W'` at which the thesis's
/// truncated Jacobi solve is used. Above it the same linear system is solved exactly.
///
/// Why: for the chain's alternating mode the Jacobi iteration matrix has eigenvalue
/// `-2 c_j`, and k = 4 iterations scale the update by `S = (1 + (2c)^5) / (1 + 2c)` instead of
/// the exact `1 / (1 + 2c)`. The step is stable only while `c S <= 1/3`, which fails for
/// `c_j > 0.425` (h^2 k / m > 2.8): a brush 1000x stiffer than the presets blows up at any
/// substep rate. At 0.25 the series has converged to 3% and the margin is wide; the presets
/// sit at 0.05. The exact solve costs about as much as two Jacobi sweeps.
pub const JACOBI_LIMIT: f64 = 0.25;

/// A mass within this height of the paper touches it (mm).
pub const CONTACT_TOLERANCE_MM: f64 = 1e-4;
/// Height over which a mass's tie to the skeleton fades in as it leaves the paper (mm).
///
/// The thesis unties masses lying on the paper (3.1.2) with a switch. A hair grazing the paper
/// then falls into a relay oscillation: untied it drifts up, tied it is pulled back into the
/// paper, projected it is untied again, every few substeps; and the fixed-point and f64 runs
/// switch in different orders (measured 27 um apart at the tip on the 橫 example). With the
/// tie's weight ramping linearly from 0 on the paper to 1 at this height, and the paper drag
/// ramping the other way, the model is continuous and the two runs stay together.
pub const TIE_RAMP_MM: f64 = 0.05;

/// Per-substep coefficients of one mass's row in the implicit solve (see the module docs).
#[derive(Copy, Clone, Debug)]
struct Row<S> {
    c_k: S,
    c_j: S, // c_k + c_d: the Jacobi off-diagonal, also the relative-velocity weight
    c_t: S,
    c_tv: S, // c_t + c_dt
    c_f: S,  // h^2 / W' in mm per newton: an external force's share of the velocity change
}

/// Everything derived from the parameters that the substep needs: recomputed by
/// [`Brush::set_params`], never on the substep path.
#[derive(Copy, Clone, Debug)]
struct Derived<S> {
    n: usize,
    k: usize,
    iterations: usize,
    substeps: usize,
    /// Solve eq. 2.30 exactly instead of by Jacobi iterations (see [`JACOBI_LIMIT`]).
    exact_solve: bool,
    /// [interior or tip][untied or tied]
    rows: [[Row<S>; 2]; 2],
    /// 1 - 1 / (1 + h C_f / m): the share of in-plane velocity the paper's drag takes.
    drag_loss: S,
    segment: S,
    segment_f64: f64,
    compression_ratio: S,
    plasticity: S,
    spread_rate: S,
    spread_tf: S,
    rest_radius: [S; MAX_LAYERS],
    max_radius: [S; MAX_LAYERS],
    /// i / (N - 2) for the skeleton interpolation (eq. 3-3).
    skel_weight: [S; MAX_LAYERS],
    /// i / (N - 1) (eq. 3-17).
    layer_frac: [S; MAX_LAYERS],
    contact_tol: S,
    /// 1 / TIE_RAMP_MM.
    inv_tie_ramp: S,
    inv_substeps: S,
    /// Below this length a direction is treated as undefined (mm).
    tiny: S,
    tiny2: S,
}

/// The state of one layer's surface ellipse (Liang 3.2).
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct Layer<S> {
    /// Short-axis direction SA_i (unit).
    pub short_axis: Vec3<S>,
    /// Long-axis direction LA_i (unit).
    pub long_axis: Vec3<S>,
    /// Long radius RL_i (mm).
    pub long_radius: S,
    /// Short radius RS_i (mm).
    pub short_radius: S,
    /// Wetness W_i in [0, 1].
    pub wetness: S,
}

/// A brush: its parameters and its complete dynamic state.
#[derive(Clone, Debug)]
pub struct Brush<S: Scalar> {
    params: BrushParams,
    d: Derived<S>,
    handle: Pose<S>,
    /// Spine masses S_i (mm); S_0 is the ferrule.
    spine: [Vec3<S>; MAX_LAYERS],
    /// Displacement per substep u_i = v_i h (mm).
    vel: [Vec3<S>; MAX_LAYERS],
    contact: [bool; MAX_LAYERS],
    /// Skeleton segment directions V_i in the handle frame (unit), i in 0..N-1.
    skel_dir: [Vec3<S>; MAX_LAYERS],
    /// Skeleton nodes VS_i in the world (mm).
    skel: [Vec3<S>; MAX_LAYERS],
    /// Skeleton nodes' displacement in the last substep (mm).
    skel_vel: [Vec3<S>; MAX_LAYERS],
    layers: [Layer<S>; MAX_LAYERS],
    /// External force on the tip mass (N), e.g. a finger or a test load.
    tip_load: Vec3<S>,
    /// Cached pivots of the exact solve (`Some(0)` once computed for the current parameters).
    pivots_for: Option<u32>,
    inv_pivot: [S; MAX_LAYERS],
    cprime: [S; MAX_LAYERS],
    substeps_done: u64,
}

impl<S: Scalar> Brush<S> {
    /// A brush at rest, hanging straight along the handle at `pose`.
    pub fn new(params: BrushParams, pose: Pose<S>) -> Result<Self, ParamError> {
        params.validate()?;
        let d = derive::<S>(&params);
        let mut b = Brush {
            params,
            d,
            handle: pose,
            spine: [Vec3::ZERO; MAX_LAYERS],
            vel: [Vec3::ZERO; MAX_LAYERS],
            contact: [false; MAX_LAYERS],
            skel_dir: [-Vec3::Z; MAX_LAYERS],
            skel: [Vec3::ZERO; MAX_LAYERS],
            skel_vel: [Vec3::ZERO; MAX_LAYERS],
            layers: [Layer {
                short_axis: Vec3::X,
                long_axis: Vec3::Y,
                long_radius: S::ZERO,
                short_radius: S::ZERO,
                wetness: S::ONE,
            }; MAX_LAYERS],
            tip_load: Vec3::ZERO,
            pivots_for: None,
            inv_pivot: [S::ZERO; MAX_LAYERS],
            cprime: [S::ZERO; MAX_LAYERS],
            substeps_done: 0,
        };
        b.reset(pose);
        Ok(b)
    }

    /// Puts the brush at rest at `pose`: straight, no velocity, round, wet as configured.
    pub fn reset(&mut self, pose: Pose<S>) {
        let pose = clamp_to_paper(pose);
        self.handle = pose;
        self.skel_dir = [-Vec3::Z; MAX_LAYERS];
        self.rebuild_skeleton(false);
        self.skel_vel = [Vec3::ZERO; MAX_LAYERS];
        let n = self.d.n;
        for i in 0..n {
            self.spine[i] = self.skel[i];
            self.vel[i] = Vec3::ZERO;
            self.contact[i] = false;
        }
        let sa = pose.rot.rotate(Vec3::X);
        let la = pose.rot.rotate(Vec3::Y);
        let w = S::from_f32(self.params.wetness);
        for i in 0..n {
            self.layers[i] = Layer {
                short_axis: sa,
                long_axis: la,
                long_radius: self.d.rest_radius[i],
                short_radius: self.d.rest_radius[i],
                wetness: w,
            };
        }
        // A brush reset into the paper settles onto it on the first substep.
        self.project_onto_paper();
    }

    pub fn params(&self) -> &BrushParams {
        &self.params
    }

    /// Replaces all parameters (validated first; on error nothing changes). The state is
    /// kept when the number of layers is unchanged; otherwise the brush is reset at its
    /// current pose.
    pub fn set_params(&mut self, params: BrushParams) -> Result<(), ParamError> {
        params.validate()?;
        let relayout = params.layers != self.params.layers
            || params.length_mm != self.params.length_mm
            || params.wetness != self.params.wetness;
        self.params = params;
        self.d = derive::<S>(&params);
        self.pivots_for = None;
        if relayout {
            self.reset(self.handle);
        }
        Ok(())
    }

    /// Sets one parameter (validated; on error nothing changes).
    pub fn set_param(&mut self, id: ParamId, value: f32) -> Result<(), ParamError> {
        let mut p = self.params;
        p.set(id, value)?;
        self.set_params(p)
    }

    /// Number of layers N.
    pub fn len(&self) -> usize {
        self.d.n
    }
    pub fn is_empty(&self) -> bool {
        self.d.n == 0
    }
    pub fn handle(&self) -> Pose<S> {
        self.handle
    }
    pub fn spine(&self) -> &[Vec3<S>] {
        &self.spine[..self.d.n]
    }
    /// Displacement of each mass in the last substep (mm).
    pub fn velocities(&self) -> &[Vec3<S>] {
        &self.vel[..self.d.n]
    }
    pub fn skeleton(&self) -> &[Vec3<S>] {
        &self.skel[..self.d.n]
    }
    /// Skeleton segment directions in the handle frame.
    pub fn skeleton_directions(&self) -> &[Vec3<S>] {
        &self.skel_dir[..self.d.n - 1]
    }
    pub fn layers(&self) -> &[Layer<S>] {
        &self.layers[..self.d.n]
    }
    pub fn in_contact(&self) -> &[bool] {
        &self.contact[..self.d.n]
    }
    /// Masses lying on the paper.
    pub fn contacts(&self) -> usize {
        self.in_contact().iter().filter(|&&c| c).count()
    }
    pub fn substeps_done(&self) -> u64 {
        self.substeps_done
    }
    pub fn substeps_per_tick(&self) -> usize {
        self.d.substeps
    }
    /// Rest segment length L (mm).
    pub fn segment_mm(&self) -> f64 {
        self.d.segment_f64
    }
    /// Whether the implicit solve is exact (stiff parameters) rather than Jacobi iterations.
    pub fn solves_exactly(&self) -> bool {
        self.d.exact_solve
    }
    pub fn ring_nodes(&self) -> usize {
        self.d.k
    }

    /// The force the hairs exert on the handle (newtons, world frame): the first segment's
    /// spring-damper pulling on the ferrule plus every tie's spring-damper pulling on the
    /// skeleton, which the handle carries. At rest against the paper this balances the
    /// paper's reaction, so its vertical part is the normal force the brush presses with.
    pub fn handle_reaction(&self) -> [f64; 3] {
        let p = &self.params;
        let h = p.substep_s();
        let (ks, kd) = (p.axial_stiffness as f64, p.axial_damping as f64);
        let (kt, kdt) = (p.tie_stiffness as f64, p.tie_damping as f64);
        let mut f = [0.0; 3];
        let n = self.d.n;
        if n > 1 {
            let d = (self.spine[1] - self.spine[0]).to_f64();
            let dv = (self.vel[1] - self.vel[0]).to_f64();
            let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            if len > 1e-9 {
                let mut s = ks * (len - self.d.segment_f64) / len;
                if s < 0.0 {
                    s *= p.compression_ratio as f64;
                }
                for a in 0..3 {
                    f[a] += (s * d[a] + kd * dv[a] / h) * 1e-3;
                }
            }
        }
        for i in 1..n {
            let w = self.tie_weight(i).to_f64();
            let d = (self.spine[i] - self.skel[i]).to_f64();
            let dv = (self.vel[i] - self.skel_vel[i]).to_f64();
            for a in 0..3 {
                f[a] += w * (kt * d[a] + kdt * dv[a] / h) * 1e-3;
            }
        }
        f
    }

    /// Applies a constant external force (newtons, world frame) to the tip mass until changed.
    pub fn set_tip_load(&mut self, force: Vec3<S>) {
        self.tip_load = force;
    }

    /// Wets every layer to `wetness` (dipping the brush in ink).
    pub fn dip(&mut self, wetness: S) {
        let w = wetness.clamp(S::ZERO, S::ONE);
        for l in self.layers[..self.d.n].iter_mut() {
            l.wetness = w;
        }
    }

    /// Advances one 1 ms tick to the handle pose `target`, moving the handle linearly (and by
    /// nlerp for its orientation) from the previous tick's pose over the substeps.
    pub fn tick(&mut self, target: Pose<S>) {
        let start = self.handle;
        let n = self.d.substeps;
        for s in 1..=n {
            let pose = if s == n {
                target
            } else {
                let t = S::from_usize(s) * self.d.inv_substeps;
                Pose::new(
                    Vec3::lerp(start.pos, target.pos, t),
                    Quat::nlerp(start.rot, target.rot, t),
                )
            };
            self.substep(pose);
        }
        self.end_tick();
    }

    /// The once-per-tick part of the model: plastic flow of the skeleton and the surface.
    /// Neither is read by the substep's dynamics except through the skeleton, which moves by
    /// at most D per reference step, so running them at 1 kHz with their rates converted
    /// changes the result by far less than a micrometre and saves 24 of every 25 evaluations.
    pub fn end_tick(&mut self) {
        if self.d.plasticity > S::ZERO {
            self.plastic_flow();
        }
        self.update_surface();
    }

    /// One substep of length h with the handle at `pose`.
    pub fn substep(&mut self, pose: Pose<S>) {
        self.substep_dynamics(pose);
        self.project_onto_paper();
        self.substeps_done = self.substeps_done.wrapping_add(1);
    }

    /// Everything in a substep but the paper projection.
    fn substep_dynamics(&mut self, pose: Pose<S>) {
        let pose = clamp_to_paper(pose);
        let n = self.d.n;
        let old_ferrule = self.spine[0];
        let old_ferrule_vel = self.vel[0];
        self.handle = pose;
        self.rebuild_skeleton(true);
        // The ferrule moves rigidly: its velocity change is prescribed.
        self.spine[0] = self.skel[0];
        self.vel[0] = self.skel[0] - old_ferrule;
        let du0 = self.vel[0] - old_ferrule_vel;

        // Spring term of each segment j (between masses j-1 and j), computed once and used with
        // opposite signs by both ends: (1 - L/|d|) d with d = S_j - S_{j-1}.
        let mut seg_force = [Vec3::<S>::ZERO; MAX_LAYERS];
        for j in 1..n {
            seg_force[j] = self.spring(self.spine[j] - self.spine[j - 1]);
        }

        // Right-hand side p_i of eq. 2.33 (scaled by h, see the module docs).
        let mut p = [Vec3::<S>::ZERO; MAX_LAYERS];
        let mut rows = [self.d.rows[0][0]; MAX_LAYERS];
        for i in 1..n {
            let tip = usize::from(i == n - 1);
            let row = self.d.rows[tip][1];
            rows[i] = row;
            let xi = self.spine[i];
            let ui = self.vel[i];
            let mut spring = -seg_force[i];
            let mut rel = self.vel[i - 1] - ui;
            if i + 1 < n {
                spring += seg_force[i + 1];
                rel += self.vel[i + 1] - ui;
            }
            let mut pi = spring.scale(row.c_k) + rel.scale(row.c_j);
            let w = self.tie_weight(i);
            if w > S::ZERO {
                pi += ((self.skel[i] - xi).scale(row.c_t)
                    + (self.skel_vel[i] - ui).scale(row.c_tv))
                .scale(w);
            }
            p[i] = pi;
        }
        p[n - 1] += self.tip_load.scale(rows[n - 1].c_f);

        let du = if self.d.exact_solve {
            self.solve_exact(&p, &rows, du0)
        } else {
            // Jacobi iterations (eq. 2.33).
            let mut du = p;
            let mut next = p;
            for _ in 0..self.d.iterations {
                for i in 1..n {
                    let mut sum = if i == 1 { du0 } else { du[i - 1] };
                    if i + 1 < n {
                        sum += du[i + 1];
                    }
                    next[i] = p[i] + sum.scale(rows[i].c_j);
                }
                du[1..n].copy_from_slice(&next[1..n]);
            }
            du
        };

        // Integrate, paper drag, projection.
        for i in 1..n {
            let mut u = self.vel[i] + du[i];
            // Drag in proportion to how much the mass is lying on the paper.
            let on_paper = S::ONE - self.tie_weight(i);
            if on_paper > S::ZERO {
                let keep = S::ONE - on_paper * self.d.drag_loss;
                u.x = u.x * keep;
                u.y = u.y * keep;
            }
            self.vel[i] = u;
            self.spine[i] += u;
        }
    }

    /// Solves eq. 2.30's tridiagonal system `du_i - c_j,i (du_{i-1} + du_{i+1}) = p_i` exactly
    /// (Thomas algorithm; the ferrule's du_0 is known). The pivots depend only on which masses
    /// lie on the paper... and since the tie is weighted on the right-hand side, not at all:
    /// they are computed once per parameter change.
    fn solve_exact(
        &mut self,
        p: &[Vec3<S>; MAX_LAYERS],
        rows: &[Row<S>; MAX_LAYERS],
        du0: Vec3<S>,
    ) -> [Vec3<S>; MAX_LAYERS] {
        let n = self.d.n;
        // The rows no longer depend on contact (the tie is weighted in the right-hand side),
        // so the pivots change only with the parameters.
        let mask = 0;
        if self.pivots_for != Some(mask) {
            // Forward elimination of the coefficients: cp_i = -c_i / m_i, inv_m_i = 1 / m_i
            // with m_i = 1 - c_i * (-cp_{i-1})... written for sub = super = -c_j,i.
            let mut prev_cp = S::ZERO;
            for i in 1..n {
                let c = rows[i].c_j;
                let m = S::ONE - c * prev_cp;
                let inv_m = S::ONE.div(m);
                self.inv_pivot[i] = inv_m;
                prev_cp = if i + 1 < n { c * inv_m } else { S::ZERO };
                self.cprime[i] = prev_cp;
            }
            self.pivots_for = Some(mask);
        }
        let mut d = [Vec3::<S>::ZERO; MAX_LAYERS];
        let mut prev = Vec3::ZERO;
        for i in 1..n {
            let mut rhs = p[i];
            if i == 1 {
                rhs += du0.scale(rows[1].c_j);
            }
            // d'_i = (d_i - a_i d'_{i-1}) / m_i with a_i = -c_j,i.
            prev = (rhs + prev.scale(rows[i].c_j)).scale(self.inv_pivot[i]);
            d[i] = prev;
        }
        let mut du = d;
        for i in (1..n - 1).rev() {
            du[i] = d[i] + du[i + 1].scale(self.cprime[i]);
        }
        du
    }

    /// How strongly mass i is tied to the skeleton: 0 lying on the paper, 1 from
    /// [`TIE_RAMP_MM`] up.
    #[inline]
    pub fn tie_weight(&self, i: usize) -> S {
        (self.spine[i].z * self.d.inv_tie_ramp).clamp(S::ZERO, S::ONE)
    }

    /// `c`-free spring term `(1 - L/|d|) d` for a neighbour offset `d` (mm).
    #[inline]
    fn spring(&self, d: Vec3<S>) -> Vec3<S> {
        let len2 = d.norm2();
        if len2 > self.d.tiny2 {
            let strain = S::ONE - self.d.segment * len2.rsqrt();
            // Negative strain: the segment is compressed and the hairs buckle.
            let strain = if strain < S::ZERO {
                strain * self.d.compression_ratio
            } else {
                strain
            };
            d.scale(strain)
        } else {
            // Coincident masses (piled on the paper): no defined direction, no force.
            Vec3::ZERO
        }
    }

    fn project_onto_paper(&mut self) {
        let tol = self.d.contact_tol;
        for i in 1..self.d.n {
            let s = &mut self.spine[i];
            let u = &mut self.vel[i];
            if s.z < S::ZERO {
                s.z = S::ZERO;
                if u.z < S::ZERO {
                    u.z = S::ZERO;
                }
            }
            self.contact[i] = s.z <= tol;
        }
        self.contact[0] = self.spine[0].z <= tol;
    }

    /// Rebuilds VS_i from the handle (eqs. 3-5, 3-6); records their displacement if `track`.
    fn rebuild_skeleton(&mut self, track: bool) {
        let n = self.d.n;
        let m = RotMat::from_quat(self.handle.rot);
        let mut node = self.handle.pos;
        for i in 0..n {
            if i > 0 {
                node += m.apply(self.skel_dir[i - 1]).scale(self.d.segment);
            }
            if track {
                self.skel_vel[i] = node - self.skel[i];
            }
            self.skel[i] = node;
        }
    }

    /// Bends the skeleton toward the spine's tip direction (eqs. 3-1..3-4).
    fn plastic_flow(&mut self) {
        let n = self.d.n;
        let tip = self.spine[n - 1] - self.spine[n - 2];
        let Some(goal) = tip.normalized_or_none(self.d.tiny) else {
            return;
        };
        let goal_local = self.handle.rot.rotate_inv(goal);
        let dd = self.d.plasticity;
        let end = self.skel_dir[n - 2].scale(S::ONE - dd) + goal_local.scale(dd);
        let Some(end) = end.normalized_or_none(self.d.tiny) else {
            return;
        };
        self.skel_dir[n - 2] = end;
        let first = self.skel_dir[0];
        for i in 1..n - 2 {
            let w = self.d.skel_weight[i];
            let v = first.scale(S::ONE - w) + end.scale(w);
            if let Some(v) = v.normalized_or_none(self.d.tiny) {
                self.skel_dir[i] = v;
            }
        }
    }

    /// Surface ellipses (eqs. 3-7..3-20).
    fn update_surface(&mut self) {
        let n = self.d.n;
        let normal = Vec3::<S>::Z;
        let sa0 = self.handle.rot.rotate(Vec3::X);
        let down = self.handle.down();
        self.layers[0].short_axis = sa0;
        self.layers[0].long_axis = self.handle.rot.rotate(Vec3::Y);

        // Step 1: short axes. First layer lying on the paper, if any.
        let first_contact = (1..n).find(|&i| self.contact[i]);
        match first_contact {
            Some(c) => {
                let inv_c = S::ONE.div(S::from_usize(c));
                for i in 1..n {
                    self.layers[i].short_axis = if i >= c {
                        normal
                    } else {
                        let w = S::from_usize(i) * inv_c;
                        sa0.scale(S::ONE - w) + normal.scale(w)
                    };
                }
            }
            None => {
                let end = self.layers[n - 1].short_axis;
                for i in 1..n - 1 {
                    let w = self.d.layer_frac[i];
                    self.layers[i].short_axis = sa0.scale(S::ONE - w) + end.scale(w);
                }
            }
        }

        // Steps 2-3: long axes from the cross product, both normalised; Step 4: bends.
        let mut seg = [Vec3::<S>::ZERO; MAX_LAYERS];
        for i in 1..n {
            let v = self.spine[i] - self.spine[i - 1];
            // Coincident masses (piled on the paper) have no direction: use the handle's.
            seg[i] = v.normalized_or_none(self.d.tiny).unwrap_or(down);
            let layer = &mut self.layers[i];
            let sa = layer.short_axis;
            let la = sa.cross(seg[i]);
            // |sa x v| below sin(0.5 deg) * |sa|: the ellipse plane is undefined; keep the old
            // long axis, made perpendicular to the segment, and rebuild the short one.
            let min_cross = self.d.tiny;
            match la.normalized_or_none(min_cross) {
                Some(la) => {
                    layer.long_axis = la;
                    // V x LA: the short axis made perpendicular to the segment, so the
                    // ellipse is a true cross-section (unit: V and LA are unit and orthogonal).
                    layer.short_axis = seg[i].cross(la);
                }
                None => {
                    let old = layer.long_axis;
                    let la = old - seg[i].scale(old.dot(seg[i]));
                    if let Some(la) = la.normalized_or_none(self.d.tiny) {
                        layer.long_axis = la;
                        if let Some(sa) = seg[i].cross(la).normalized_or_none(self.d.tiny) {
                            layer.short_axis = sa;
                        }
                    }
                }
            }
        }
        let mut tilt = [S::ZERO; MAX_LAYERS];
        let mut tilt_sum = S::ZERO;
        for i in 1..n - 1 {
            tilt[i] = S::ONE - seg[i + 1].dot(seg[i]);
            tilt_sum += tilt[i];
        }
        tilt[n - 1] = tilt[n - 2];
        let tilt_all = if n > 2 {
            tilt_sum.div(S::from_usize(n - 2))
        } else {
            S::ZERO
        };

        // Steps 5-6: target and relaxed radii, area preserved (eqs. 3-17..3-20).
        let any_contact = first_contact.is_some();
        let rate = self.d.spread_rate;
        for i in 1..n {
            let rest = self.d.rest_radius[i];
            let layer = &mut self.layers[i];
            let rl = layer.long_radius;
            let goal = if any_contact {
                let bend = self.d.spread_tf * tilt[i] + (S::ONE - tilt[i]) * tilt_all;
                rl + (self.d.max_radius[i] - rl)
                    * (S::ONE - layer.wetness)
                    * self.d.layer_frac[i]
                    * bend
            } else {
                rest
            };
            let rl = (rate * goal + (S::ONE - rate) * rl).clamp(rest, self.d.max_radius[i]);
            layer.long_radius = rl;
            layer.short_radius = (rest * rest).div(rl);
        }
    }
}

/// The ferrule cannot enter the paper (the god-object of Liang 4.2.3 keeps the drawn brush on
/// the surface; the force model sees the hand's real penetration).
fn clamp_to_paper<S: Scalar>(mut pose: Pose<S>) -> Pose<S> {
    if pose.pos.z < S::ZERO {
        pose.pos.z = S::ZERO;
    }
    pose
}

/// A rotation matrix from a unit quaternion: 9 multiplies per vector instead of 18.
struct RotMat<S> {
    m: [[S; 3]; 3],
}

impl<S: Scalar> RotMat<S> {
    fn from_quat(q: Quat<S>) -> Self {
        let two = S::ONE + S::ONE;
        let (w, x, y, z) = (q.w, q.x, q.y, q.z);
        let (xx, yy, zz) = (x * x, y * y, z * z);
        let (xy, xz, yz) = (x * y, x * z, y * z);
        let (wx, wy, wz) = (w * x, w * y, w * z);
        RotMat {
            m: [
                [S::ONE - two * (yy + zz), two * (xy - wz), two * (xz + wy)],
                [two * (xy + wz), S::ONE - two * (xx + zz), two * (yz - wx)],
                [two * (xz - wy), two * (yz + wx), S::ONE - two * (xx + yy)],
            ],
        }
    }
    #[inline]
    fn apply(&self, v: Vec3<S>) -> Vec3<S> {
        let m = &self.m;
        Vec3::new(
            m[0][0] * v.x + m[0][1] * v.y + m[0][2] * v.z,
            m[1][0] * v.x + m[1][1] * v.y + m[1][2] * v.z,
            m[2][0] * v.x + m[2][1] * v.y + m[2][2] * v.z,
        )
    }
}

/// `1 - (1 - rate)^(reference / actual)`: a per-step rate stated at 25 kHz, at another rate.
fn per_substep_rate(rate: f64, substep_hz: f64) -> f64 {
    if rate <= 0.0 {
        return 0.0;
    }
    let steps = REFERENCE_SUBSTEP_HZ as f64 / substep_hz;
    1.0 - libm::pow(1.0 - rate, steps)
}

fn derive<S: Scalar>(p: &BrushParams) -> Derived<S> {
    let n = p.layers as usize;
    let h = p.substep_s();
    let m = p.mass_g as f64 * 1e-3 / (n as f64 - 1.0);
    let (ks, kd) = (p.axial_stiffness as f64, p.axial_damping as f64);
    let (kt, kdt) = (p.tie_stiffness as f64, p.tie_damping as f64);
    let row = |neighbours: f64, tied: bool| {
        let t = if tied { 1.0 } else { 0.0 };
        let w = m + h * h * (neighbours * ks + t * kt) + h * (neighbours * kd + t * kdt);
        let c_k = h * h * ks / w;
        let c_d = h * kd / w;
        let c_t = h * h * kt / w;
        let c_dt = h * kdt / w;
        Row {
            c_k: S::from_f64(c_k),
            c_j: S::from_f64(c_k + c_d),
            c_t: S::from_f64(c_t * t),
            c_tv: S::from_f64((c_t + c_dt) * t),
            c_f: S::from_f64(h * h * 1e3 / w),
        }
    };
    let mut rest_radius = [S::ZERO; MAX_LAYERS];
    let mut max_radius = [S::ZERO; MAX_LAYERS];
    let mut skel_weight = [S::ZERO; MAX_LAYERS];
    let mut layer_frac = [S::ZERO; MAX_LAYERS];
    for i in 0..n {
        let r = p.rest_radius_mm(i);
        rest_radius[i] = S::from_f64(r);
        max_radius[i] = S::from_f64(r * p.spread_max as f64);
        skel_weight[i] = S::from_f64(if n > 2 {
            i as f64 / (n as f64 - 2.0)
        } else {
            0.0
        });
        layer_frac[i] = S::from_f64(i as f64 / (n as f64 - 1.0));
    }
    let rows = [
        [row(2.0, false), row(2.0, true)],
        [row(1.0, false), row(1.0, true)],
    ];
    let worst_c_j = rows
        .iter()
        .flatten()
        .map(|r| r.c_j.to_f64())
        .fold(0.0, f64::max);
    Derived {
        exact_solve: worst_c_j > JACOBI_LIMIT,
        n,
        k: p.ring_nodes as usize,
        iterations: p.jacobi_iterations as usize,
        substeps: p.substeps_per_tick as usize,
        rows,
        drag_loss: S::from_f64(1.0 - 1.0 / (1.0 + h * p.paper_drag as f64 / m)),
        segment: S::from_f64(p.segment_mm()),
        segment_f64: p.segment_mm(),
        compression_ratio: S::from_f32(p.compression_ratio),
        plasticity: S::from_f64(per_substep_rate(p.plasticity as f64, TICK_HZ as f64)),
        spread_rate: S::from_f64(per_substep_rate(p.spread_rate as f64, TICK_HZ as f64)),
        spread_tf: S::from_f64(p.spread_tf as f64),
        rest_radius,
        max_radius,
        skel_weight,
        layer_frac,
        contact_tol: S::from_f64(CONTACT_TOLERANCE_MM),
        inv_tie_ramp: S::from_f64(1.0 / TIE_RAMP_MM),
        inv_substeps: S::from_f64(1.0 / p.substeps_per_tick as f64),
        tiny: S::from_f64(1e-6),
        tiny2: S::from_f64(1e-12),
    }
}

/// Rate conversion is exposed for tests and documentation.
pub fn rate_at(rate_at_25khz: f64, substep_hz: f64) -> f64 {
    per_substep_rate(rate_at_25khz, substep_hz)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rates_convert_between_substep_rates() {
        assert!((rate_at(0.01, 25_000.0) - 0.01).abs() < 1e-12);
        // Half the rate: two reference steps per substep.
        assert!((rate_at(0.01, 12_500.0) - (1.0 - 0.99f64 * 0.99)).abs() < 1e-12);
    }
}
