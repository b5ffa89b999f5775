//! Baxter & Lin's local force model (§5, eqs. 21-22): the hand's force at 1 kHz from a brush
//! solved at a lower rate.
//!
//! The full solve ([`super::Spine::solve`]) is too slow for every haptic tick on a brush of
//! several spines, so [`LocalForceBrush`] ticks the brush every N-th tick (N = 10: 100 Hz;
//! the tick solves it along the handle's path since the last in substeps,
//! [`BaxterLinBrush::tick`], so it is the brush a 1 kHz tick would give) and between its
//! ticks evaluates a first-order model of the handle force built at the last pose `p0`:
//!
//! ```text
//! F(p0 + dp) = F0 + F~(dp),   F~(dp) = F~compress(dp) + F~bend(dp) = -K dp       (eqs. 21-22)
//! ```
//!
//! `F0` is the solved handle force, the sum over the spines (each spine carries its share of
//! the head's hair in parallel: [`BaxterLinBrush::handle_force`] is the head's total, so the
//! felt force is the sum of the spines' local models, not their mean).
//!
//! # Where K comes from
//!
//! At a solved pose the spine is at the constrained minimum `q*(p)` of its energy
//! `E(q; p)`, and the force on the handle is what the paper puts on the hair, passed on by
//! the massless chain. Moving the handle by `dp` changes it in two ways, the paper's two
//! terms:
//!
//! * **compression**: a contact held by its constraint `z_i >= 0` cannot move down, so a
//!   handle pushed toward the paper along the chord from the root to the contact shortens the
//!   bend and the multiplier (the normal force) grows stiffly along that chord;
//! * **bending**: every other direction bends the joints, and the handle feels their springs
//!   through the chain, `K_bend = (J K_joint^-1 J^T)^-1` on the directions the contacts leave
//!   free (J the chain's Jacobian from the angles to the handle-relative contact point).
//!
//! Both are the derivative `dF/dp` of the solution map, which is the KKT system's
//! sensitivity as long as the active set and every contact's stiction state stay as they
//! were. Over one rebuild interval they do not: a 30 mm/s stroke moves the handle 0.3 mm in
//! 10 ms, thirty times the distance at which a sticking contact slips
//! ([`super::SpineParams::slip_mm`]). A contact pushed from rest first holds, its spine
//! bending stiffly, then slips within about 0.1 mm and its force falls back to the sliding
//! friction `mu_k F_n`, which does not grow with `dp` however far the handle goes; and a
//! reversal turns the friction round, a jump of `2 mu F_n` that no stiffness describes. The
//! exact linearisation at `p0` (the stuck contact's stiffness) would promise a force the
//! solve never gives. So K is the **secant** of the solver itself: one-sided differences of
//! warm-started solves of copies of the spines (the real ones untouched) at `p0` moved along
//! each axis by the handle's move over the last interval, which it is taken to repeat, at
//! least [`LocalForceParams::min_probe_mm`]; an axis the handle hardly moved along is probed
//! both ways and the softer side kept (the stiffer one is mostly the friction's reversal),
//! and of that only its own stiffness: made symmetric, its cross terms would act on the
//! axes the hand does move along, a guess from a move it did not make (on a press, a
//! sideways force and a stiffer push than the brush gives). That includes the compression
//! and the bending terms, the contacts that land or lift within the step, and the friction's saturation: a contact that slides contributes its
//! friction's change through `F_n` only. It costs three to six solves a spine a rebuild, the
//! cheapest honest route (the KKT route needs the solver's internals and would still miss
//! the stiction switches).
//!
//! What this buys depends on the hair. On elastic spines (no paper or joint friction) the
//! force is eq. 22's bending and compression and the model follows the full solve at 1 kHz
//! several times closer than holding `F0` for the interval. With the paper's friction the
//! force is mostly friction, which holding `F0` already gets right along a slide, and
//! stick-slip within an interval no first-order model follows: the model is closer than the
//! hold, by less (the workspace's `tests/baxter_lin_local_force.rs` prints both).
//!
//! # Passivity
//!
//! The model is rendered by a device sampled at 1 kHz with the force held over each tick, so
//! its stiffness must stay within the Colgate-Brown budget
//! [`DeviceLimits::max_stable_stiffness`]. And only a symmetric stiffness is a spring: an
//! antisymmetric part `K_a` gives a force field with a curl, around whose loops the device
//! does work on the hand every cycle. So the difference matrix `D = dF/dp` is replaced by
//! `K = clamp(-(D + D^T) / 2)`: its eigenvalues clamped to `[0, k_max]` (a negative stiffness
//! is an unstable spring the hand would have to hold; above `k_max` the sampled loop is
//! active). The antisymmetric part, mostly the friction's dependence on the normal force, is
//! dropped; [`LocalForceModel::dropped_asymmetry`] reports how much.
//!
//! # What is left out
//!
//! The handle's rotation: the model is linear in the handle's position only and uses the
//! rotation of its last solve, and the torque the spines put on the handle is not modelled
//! (the devices render a force). `tests/baxter_lin_local_force.rs` in the workspace's
//! `tests/` measures what this costs on the example strokes.

use super::brush::BaxterLinBrush;
use super::Spine;
use crate::force::{DeviceLimits, TICK_S};
use crate::quat::Pose;
use crate::vec::Vec3;

/// A 3x3 matrix in rows, N/mm when a stiffness.
pub type Mat3x3 = [[f64; 3]; 3];

/// How the local model is built and run.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct LocalForceParams {
    /// The brush is solved every this many ticks (10 at 1 kHz: 100 Hz), at least 1.
    pub rebuild_every: u32,
    /// The smallest step of the differences (mm): a handle that moved less than this along an
    /// axis over the last interval is probed this far along it.
    pub min_probe_mm: f64,
    /// The largest eigenvalue the model's stiffness may have (N/mm).
    pub max_stiffness_n_per_mm: f64,
}

/// The safety factor on the Colgate-Brown budget, as the budget test of Liang's force model
/// (`force.rs`) keeps it.
pub const BUDGET_MARGIN: f64 = 1.5;

impl LocalForceParams {
    /// 100 Hz rebuilds, a 0.2 mm smallest probe (beyond the stick-slip cycle of a contact
    /// pushed from rest, whose force peaks within 0.1 mm and falls back as it slips, so the
    /// secant sees the sliding force a moving hand meets), and the
    /// stiffness `device` renders passively with no virtual damping, over [`BUDGET_MARGIN`].
    pub fn for_device(device: &DeviceLimits) -> Self {
        LocalForceParams {
            rebuild_every: 10,
            min_probe_mm: 0.2,
            max_stiffness_n_per_mm: device.max_stable_stiffness(0.0) * 1e-3 / BUDGET_MARGIN,
        }
    }
}

impl LocalForceParams {
    /// How long a model may be felt, in ticks after the pose it was solved at: one and a
    /// half rebuild intervals. A model is a force field valid about that pose; felt later, by
    /// a device whose solver runs elsewhere and fell behind, it is extrapolated from a hand
    /// that has moved on, and the passivity audit (`shared/tests/passivity.rs`, models felt
    /// late) finds the energy it creates past its tolerance once it is felt longer than
    /// this: a head that lands catches on the paper within a fraction of a millimetre, and a
    /// model that arrives half an interval after it did steps to the whole landing force.
    pub fn stale_after_ticks(&self) -> u32 {
        let every = self.rebuild_every.max(1);
        every + every / 2
    }
}

/// The first-order model of the handle force around one solved pose.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct LocalForceModel {
    p0: Vec3<f64>,
    f0: Vec3<f64>,
    /// The stiffness the hand feels: symmetric, eigenvalues in [0, k_max].
    k: Mat3x3,
    /// The secant `dF/dp` as probed.
    probed: Mat3x3,
}

impl LocalForceModel {
    /// No force anywhere: what a servo loop feels before its solver's first model.
    pub const NONE: LocalForceModel = LocalForceModel {
        p0: Vec3::ZERO,
        f0: Vec3::ZERO,
        k: [[0.0; 3]; 3],
        probed: [[0.0; 3]; 3],
    };

    /// The model of `spines`, solved at `pose`, from one-sided differences of copies of them
    /// solved at `pose` moved along each axis by `motion`'s component there (the handle's move
    /// over the last rebuild interval, which it is taken to repeat), at least `min_probe_mm`
    /// (a smaller component is probed both ways and the softer side kept); clamped to
    /// `max_stiffness` (N/mm).
    pub fn build(
        spines: &[Spine],
        pose: &Pose<f64>,
        motion: Vec3<f64>,
        min_probe_mm: f64,
        max_stiffness: f64,
    ) -> Self {
        let min_probe = if min_probe_mm.is_finite() && min_probe_mm > 0.0 {
            min_probe_mm
        } else {
            0.1
        };
        let f0 = spines
            .iter()
            .fold(Vec3::ZERO, |acc, s| acc + s.handle_force());
        // The brush's force with every spine copied and solved at `pose` moved by `step`.
        let probe = |step: Vec3<f64>| {
            let at = Pose::new(pose.pos + step, pose.rot);
            spines.iter().fold(Vec3::ZERO, |acc, s| {
                let mut copy = s.clone();
                copy.solve(&at, Vec3::ZERO);
                acc + copy.handle_force()
            })
        };
        let mut d = [[0.0; 3]; 3];
        let along = motion.to_f64();
        for (a, axis) in [Vec3::X, Vec3::Y, Vec3::Z].into_iter().enumerate() {
            let m = if along[a].is_finite() { along[a] } else { 0.0 };
            let slope = |h: f64| (probe(axis.scale(h)) - f0).scale(1.0 / h);
            let column = if m.abs() >= min_probe {
                slope(m)
            } else {
                // No motion to go by: of the two ways, the softer. Across a reversal of the
                // friction the stiffer side's secant is mostly the friction's jump, which a
                // hand that stays put never feels.
                let (up, down) = (slope(min_probe), slope(-min_probe));
                let softer = if up.norm2() <= down.norm2() { up } else { down };
                // Only its own stiffness: made symmetric, its cross terms would act on the
                // axes the hand does move along, a guess from a move the hand did not make
                // (on a press, how a sideways probe changes the push: felt as a sideways
                // force and a stiffer press than the brush gives).
                let mut own = [0.0; 3];
                own[a] = softer.to_f64()[a];
                Vec3::from_f64(own)
            };
            for (row, v) in d.iter_mut().zip(column.to_f64()) {
                row[a] = v;
            }
        }
        Self::from_parts(pose.pos, f0, d, max_stiffness)
    }

    /// The model with force `f0` at `p0` and the secant `d = dF/dp` (N/mm), made passive.
    pub fn from_parts(p0: Vec3<f64>, f0: Vec3<f64>, d: Mat3x3, max_stiffness: f64) -> Self {
        let mut sym = [[0.0; 3]; 3];
        for (i, row) in sym.iter_mut().enumerate() {
            for (j, v) in row.iter_mut().enumerate() {
                *v = -0.5 * (d[i][j] + d[j][i]);
            }
        }
        let k_max = if max_stiffness.is_finite() {
            max_stiffness.max(0.0)
        } else {
            0.0
        };
        let k = if sym.iter().flatten().all(|v| v.is_finite()) {
            clamp_eigenvalues(sym, 0.0, k_max)
        } else {
            [[0.0; 3]; 3]
        };
        LocalForceModel {
            p0,
            f0,
            k,
            probed: d,
        }
    }

    /// The felt force at handle position `pos` (N): `F0 - K (pos - p0)`.
    pub fn force(&self, pos: Vec3<f64>) -> Vec3<f64> {
        let dp = (pos - self.p0).to_f64();
        let mut f = self.f0.to_f64();
        for (fi, row) in f.iter_mut().zip(&self.k) {
            *fi -= row[0] * dp[0] + row[1] * dp[1] + row[2] * dp[2];
        }
        Vec3::from_f64(f)
    }

    /// The energy the model's spring holds at `pos` relative to `p0` (N mm = mJ): the
    /// potential of the field [`Self::force`], `-F0 . dp + dp . K dp / 2`.
    pub fn potential(&self, pos: Vec3<f64>) -> f64 {
        let dp = (pos - self.p0).to_f64();
        let mut e = -self.f0.dot(pos - self.p0);
        for i in 0..3 {
            for j in 0..3 {
                e += 0.5 * dp[i] * self.k[i][j] * dp[j];
            }
        }
        e
    }

    /// Where the model was built (mm).
    pub fn origin(&self) -> Vec3<f64> {
        self.p0
    }

    /// The solved force there (N).
    pub fn base_force(&self) -> Vec3<f64> {
        self.f0
    }

    /// The rendered stiffness (N/mm): symmetric, eigenvalues within the budget.
    pub fn stiffness(&self) -> Mat3x3 {
        self.k
    }

    /// The probed secant `dF/dp` before it was made passive (N/mm).
    pub fn probed(&self) -> Mat3x3 {
        self.probed
    }

    /// The Frobenius norm of the probed secant's antisymmetric part, which the model drops
    /// (N/mm).
    pub fn dropped_asymmetry(&self) -> f64 {
        let d = &self.probed;
        let mut s = 0.0;
        for (i, row) in d.iter().enumerate() {
            for (j, v) in row.iter().enumerate() {
                let a = 0.5 * (v - d[j][i]);
                s += a * a;
            }
        }
        libm::sqrt(s)
    }
}

/// `m`'s eigenvalues clamped to `[lo, hi]`, the eigenvectors kept (cyclic Jacobi rotations;
/// `m` symmetric).
pub fn clamp_eigenvalues(m: Mat3x3, lo: f64, hi: f64) -> Mat3x3 {
    let (values, vectors) = symmetric_eigen(m);
    let mut out = [[0.0; 3]; 3];
    for (k, lambda) in values.iter().enumerate() {
        let l = lambda.clamp(lo, hi);
        for (i, row) in out.iter_mut().enumerate() {
            for (j, v) in row.iter_mut().enumerate() {
                *v += l * vectors[i][k] * vectors[j][k];
            }
        }
    }
    out
}

/// Eigenvalues and eigenvectors (the columns of the second) of the symmetric `m`, by cyclic
/// Jacobi rotations: a fixed number of sweeps, far more than a 3x3 needs to reach rounding.
pub fn symmetric_eigen(m: Mat3x3) -> ([f64; 3], Mat3x3) {
    let mut a = m;
    let mut v = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    for _ in 0..12 {
        for (p, q) in [(0, 1), (0, 2), (1, 2)] {
            let apq = a[p][q];
            if apq == 0.0 {
                continue;
            }
            // The rotation that zeroes a[p][q] (Golub & Van Loan's symmetric Schur step).
            let tau = (a[q][q] - a[p][p]) / (2.0 * apq);
            let t = if tau >= 0.0 {
                1.0 / (tau + libm::sqrt(1.0 + tau * tau))
            } else {
                -1.0 / (-tau + libm::sqrt(1.0 + tau * tau))
            };
            let c = 1.0 / libm::sqrt(1.0 + t * t);
            let s = t * c;
            for row in a.iter_mut() {
                let (x, y) = (row[p], row[q]);
                row[p] = c * x - s * y;
                row[q] = s * x + c * y;
            }
            let (row_p, row_q) = (a[p], a[q]);
            for (k, (x, y)) in row_p.into_iter().zip(row_q).enumerate() {
                a[p][k] = c * x - s * y;
                a[q][k] = s * x + c * y;
            }
            for row in v.iter_mut() {
                let (x, y) = (row[p], row[q]);
                row[p] = c * x - s * y;
                row[q] = s * x + c * y;
            }
        }
    }
    ([a[0][0], a[1][1], a[2][2]], v)
}

/// Baxter & Lin's brush for a 1 kHz haptic loop: the brush solved every
/// [`LocalForceParams::rebuild_every`] ticks, the [`LocalForceModel`] rebuilt there and
/// evaluated at every tick.
///
/// The solve runs inside the tick that rebuilds (synchronously): an app that solves on
/// another thread feeds that thread's brush here in the same order, one rebuild later.
#[derive(Clone, Debug)]
pub struct LocalForceBrush {
    brush: BaxterLinBrush,
    params: LocalForceParams,
    model: LocalForceModel,
    ticks: u64,
}

impl LocalForceBrush {
    /// Runs `brush`, which was last solved at `pose` (as [`BaxterLinBrush::new`] leaves it),
    /// with the model built there. `rebuild_every` below 1 counts as 1.
    pub fn new(brush: BaxterLinBrush, pose: &Pose<f64>, params: LocalForceParams) -> Self {
        let params = LocalForceParams {
            rebuild_every: params.rebuild_every.max(1),
            ..params
        };
        let mut brush = brush;
        brush.set_solve_interval(params.rebuild_every as f64 * TICK_S);
        let model = LocalForceModel::build(
            brush.spines(),
            pose,
            Vec3::ZERO,
            params.min_probe_mm,
            params.max_stiffness_n_per_mm,
        );
        LocalForceBrush {
            brush,
            params,
            model,
            ticks: 0,
        }
    }

    /// One 1 kHz tick: every [`LocalForceParams::rebuild_every`]-th the brush is solved at
    /// `pose` and the model rebuilt there; the force on the handle (N) from the model.
    pub fn tick(&mut self, pose: &Pose<f64>) -> Vec3<f64> {
        self.ticks += 1;
        if self.ticks.is_multiple_of(self.params.rebuild_every as u64) {
            self.solve(pose);
        }
        self.model.force(pose.pos)
    }

    /// Solves the brush at `pose` now and rebuilds the model there: what [`Self::tick`] does
    /// every [`LocalForceParams::rebuild_every`]-th tick, and what a solver thread does when
    /// the servo loop asks. The spines' friction takes the time since the last solve from
    /// [`Self::set_solve_interval`].
    pub fn solve(&mut self, pose: &Pose<f64>) {
        self.brush.tick(pose);
        let motion = pose.pos - self.model.origin();
        self.model = LocalForceModel::build(
            self.brush.spines(),
            pose,
            motion,
            self.params.min_probe_mm,
            self.params.max_stiffness_n_per_mm,
        );
    }

    /// The time the next [`Self::solve`] covers (s): a solver thread's solves are as far
    /// apart as the servo ticks between the poses it was given, not a fixed count.
    pub fn set_solve_interval(&mut self, interval_s: f64) {
        self.brush.set_solve_interval(interval_s);
    }

    /// Whether the last [`Self::tick`] solved the brush.
    pub fn rebuilt(&self) -> bool {
        self.ticks > 0 && self.ticks.is_multiple_of(self.params.rebuild_every as u64)
    }

    /// The brush as last solved.
    pub fn brush(&self) -> &BaxterLinBrush {
        &self.brush
    }

    /// Fills every ring to `load` of what it holds ([`BaxterLinBrush::dip`]); the hair's
    /// shape, and so the model, does not change.
    pub fn dip(&mut self, load: f64) {
        self.brush.dip(load);
    }

    /// The current model.
    pub fn model(&self) -> &LocalForceModel {
        &self.model
    }

    pub fn params(&self) -> &LocalForceParams {
        &self.params
    }

    /// The energy the virtual brush stores at handle position `pos` (N mm = mJ): the spines'
    /// springs as last solved plus the model's spring since ([`LocalForceModel::potential`]).
    /// The passivity audits compare the work the hand does with its rise.
    pub fn stored_energy(&self, pos: Vec3<f64>) -> f64 {
        let springs: f64 = self.brush.spines().iter().map(Spine::spring_energy).sum();
        springs + self.model.potential(pos)
    }
}

#[cfg(test)]
// Matrix entries read clearest by their indices.
#[allow(clippy::needless_range_loop)]
mod tests {
    use super::*;
    use crate::baxter_lin::SpineParams;
    use crate::force::PHANTOM_OMNI;
    use crate::quat::Quat;

    fn mul(a: &Mat3x3, b: &Mat3x3) -> Mat3x3 {
        let mut c = [[0.0; 3]; 3];
        for i in 0..3 {
            for j in 0..3 {
                c[i][j] = (0..3).map(|k| a[i][k] * b[k][j]).sum();
            }
        }
        c
    }

    #[test]
    fn jacobi_reconstructs_a_symmetric_matrix_and_clamps_its_eigenvalues() {
        let m = [[4.0, 1.0, -2.0], [1.0, -3.0, 0.5], [-2.0, 0.5, 1.0]];
        let (l, v) = symmetric_eigen(m);
        let mut vl = v;
        for row in vl.iter_mut() {
            for (k, x) in row.iter_mut().enumerate() {
                *x *= l[k];
            }
        }
        let mut vt = [[0.0; 3]; 3];
        for i in 0..3 {
            for j in 0..3 {
                vt[i][j] = v[j][i];
            }
        }
        let back = mul(&vl, &vt);
        for i in 0..3 {
            for j in 0..3 {
                assert!((back[i][j] - m[i][j]).abs() < 1e-12, "{back:?}");
            }
        }
        let c = clamp_eigenvalues(m, 0.0, 2.0);
        let (lc, _) = symmetric_eigen(c);
        for x in lc {
            assert!((-1e-12..=2.0 + 1e-12).contains(&x), "{lc:?}");
        }
        assert!(l.iter().any(|x| *x < 0.0) && l.iter().any(|x| *x > 2.0));
    }

    #[test]
    fn the_model_is_symmetric_and_within_the_budget() {
        // A secant with an antisymmetric part (a curl) and a stiffness far over the budget.
        let d = [[-50.0, 3.0, 0.0], [-3.0, -0.2, 0.0], [0.0, 0.0, 0.4]];
        let k_max = LocalForceParams::for_device(&PHANTOM_OMNI).max_stiffness_n_per_mm;
        let m = LocalForceModel::from_parts(Vec3::ZERO, Vec3::Z, d, k_max);
        let k = m.stiffness();
        for i in 0..3 {
            for j in 0..3 {
                assert_eq!(k[i][j], k[j][i]);
            }
        }
        let (l, _) = symmetric_eigen(k);
        for x in l {
            assert!(
                x >= -1e-12 && x <= k_max * (1.0 + 1e-12),
                "{l:?} vs {k_max}"
            );
        }
        assert!((m.dropped_asymmetry() - 3.0 * 2f64.sqrt()).abs() < 1e-12);
        // The field is the potential's: F = -grad U, checked by differences.
        let p = Vec3::new(0.3, -0.2, 0.1);
        for axis in [Vec3::X, Vec3::Y, Vec3::Z] {
            let h = 1e-5;
            let g = (m.potential(p + axis.scale(h)) - m.potential(p - axis.scale(h))) / (2.0 * h);
            assert!((g + m.force(p).dot(axis)).abs() < 1e-6);
        }
    }

    #[test]
    fn a_pressed_spine_pushes_back_and_its_model_predicts_a_small_press() {
        let tilt = 20f64.to_radians() / 2.0;
        let rot = Quat::new(libm::cos(tilt), 0.0, libm::sin(tilt), 0.0);
        let at = |z: f64| Pose::new(Vec3::new(0.0, 0.0, z), rot);
        let mut s = Spine::new(SpineParams::DEFAULT, at(32.0)).unwrap();
        for k in 0..200 {
            s.solve(&at(32.0 - 0.05 * k as f64), Vec3::ZERO);
        }
        let p0 = at(22.05);
        s.solve(&p0, Vec3::ZERO);
        let m = LocalForceModel::build(
            core::slice::from_ref(&s),
            &p0,
            Vec3::new(0.0, 0.0, -0.2),
            0.2,
            100.0,
        );
        // Pressing down stiffens the push up.
        assert!(m.stiffness()[2][2] > 0.0, "{:?}", m.stiffness());
        let mut pressed = s.clone();
        let p1 = at(21.9);
        pressed.solve(&p1, Vec3::ZERO);
        let (exact, f0) = (pressed.handle_force(), m.base_force());
        let err = (m.force(p1.pos) - exact).norm();
        let hold = (f0 - exact).norm();
        assert!(err < 0.5 * hold, "model {err} N off, hold {hold} N off");
    }
}
