//! One spine: its state between solves, the energy of one solve and the constrained
//! minimisation (see the module docs of [`crate::baxter_lin`] for the equations).

// The solver indexes the joints, variables and constraints of several fixed-size arrays
// together.
#![allow(clippy::needless_range_loop)]

use super::chain::{root_frame, Chain, Mat3, MAX_JOINTS, MAX_VARS, V3};
use super::dense;
use super::params::{SpineParamError, SpineParams};
use crate::quat::{Pose, Quat};
use crate::vec::Vec3;

/// A sticking contact's friction cone has its apex rounded over this distance (mm): `|dx|`
/// from the anchor becomes `sqrt(|dx|^2 + eps^2) - eps`, so the energy has a Hessian for
/// the Newton steps. A contact under a tangential force T below the limit `mu F_n` creeps
/// by about `eps T / sqrt((mu F_n)^2 - T^2)` from its anchor: far below
/// [`SpineParams::slip_mm`] until T is within a hair of the limit, and the same however
/// often the spine is solved (the anchor stays put).
pub const FRICTION_SMOOTHING_MM: f64 = 1e-4;

/// A sliding contact's cone is rounded the same way, but its `dx` is its move over one
/// solve, so the rounding is a speed (mm/s) times the time between solves: friction
/// below this speed is viscous rather than Coulomb's. As a fixed distance it made the
/// slow slides' friction depend on the solve rate (a contact that moves about the rounding
/// in a solve feels a fraction of its friction, and a slow creep does when solved often
/// enough), and the brush did not converge as the solves grew finer.
pub const SLIDING_SMOOTHING_MM_S: f64 = 0.1;

/// A spine is solved once a 1 kHz tick unless told otherwise ([`Spine::set_solve_interval`]).
pub const DEFAULT_SOLVE_INTERVAL_S: f64 = crate::force::TICK_S;
/// The joint friction's `|d beta|` is rounded the same way over this angle (rad).
pub const PLASTICITY_SMOOTHING_RAD: f64 = 1e-4;
/// A joint's friction is measured from a reference bend that follows the joint only as far
/// as needed to stay within this many roundings of it (after each solve). Measured from the
/// last solve's bend instead, a joint held at its friction limit would creep down the
/// rounded cone's wall a little every solve without end (a set would fade within a
/// second at 1 kHz); held like this, a released joint stops between 95% and 100% of
/// `D / K` and stays there.
const PLASTIC_REFERENCE_SPAN: f64 = 3.0;
/// Bound on each theta (rad): the XYZ set's singularity is at theta = 90 degrees (§3.2).
pub const THETA_LIMIT: f64 = 1.45;
/// Bound on each phi (rad). Past 90 degrees so that a spine whose root is on the paper can
/// still lie flat on it whichever way the handle leans; below 180 degrees, where the bend
/// angle's derivative is singular.
pub const PHI_LIMIT: f64 = 2.0;
/// The non-penetration every solve guarantees: no joint lower than this below the paper
/// (mm).
pub const PENETRATION_TOLERANCE_MM: f64 = 1e-6;
/// A joint whose constraint multiplier is above this (N) touches the paper.
const CONTACT_FORCE_N: f64 = 1e-9;
/// Cap on a constraint multiplier in the QP (N): the elastic mode that keeps a QP whose
/// linearised constraints cannot all hold from producing infinite forces.
const MAX_NORMAL_FORCE_N: f64 = 1e4;
/// Longest step of one SQP iteration in any angle (rad): a trust region for the
/// linearisation.
const MAX_STEP_RAD: f64 = 0.5;
/// An SQP step this small in every angle (rad) ends the iterations.
const STEP_TOLERANCE_RAD: f64 = 1e-8;
/// Most minimisations of one solve: the first, a re-solve after a contact slips (§3.4.1),
/// and re-solves until the normal forces the friction uses are the solution's own
/// (within [`NORMAL_FORCE_TOLERANCE`]); a few suffice but where a head lands.
const MAX_PASSES: usize = 30;
/// The friction of a minimisation uses a normal force held fixed (§3.4); the solve repeats
/// it until the solution's normal forces are within this share of those used (plus
/// [`MIN_NORMAL_FORCE_CHANGE_N`]). Held at the last solve's instead, the friction lags the
/// press by a solve, and a landing head, whose normal forces grow several-fold a solve,
/// slid through its press or caught depending on how often it was solved.
const NORMAL_FORCE_TOLERANCE: f64 = 1e-3;
/// The absolute part of the normal force's tolerance (N).
const MIN_NORMAL_FORCE_CHANGE_N: f64 = 1e-6;
/// The largest Levenberg-Marquardt ridge (a share of the Hessian's scale) a minimisation
/// tries before it stops where it is.
const MAX_DAMPING: f64 = 1e2;
/// Most halvings of a step in the line search.
const MAX_HALVINGS: usize = 16;

/// Whether a joint touches the paper and, if so, whether it sticks (§3.4.1).
#[derive(Copy, Clone, Debug, PartialEq)]
pub enum ContactState {
    /// Not touching the paper.
    Free,
    /// Held where it stuck (paper coordinates, mm): the next solve's friction is static and
    /// measured from there.
    Sticking { anchor: [f64; 2] },
    /// Sliding: the next solve's friction is kinetic, measured from where it is now.
    Sliding,
}

/// What one [`Spine::solve`] did.
#[derive(Copy, Clone, Debug, PartialEq, Default)]
pub struct SolveReport {
    /// SQP iterations over all passes.
    pub iterations: u32,
    /// Minimisations run (1 to 3: the first, after a slip, after the normal forces moved).
    pub passes: u8,
    /// The last minimisation met its step tolerance with an undamped step (otherwise it ran
    /// out of iterations, its line search stalled, or only a damped step was that short, and
    /// the state is the best point found, still feasible).
    pub converged: bool,
    /// The result was unusable (not finite, or infeasible after restoration) and the spine
    /// fell back to its last angles or, failing that, to lying flat from its root.
    pub fell_back: bool,
    /// How far the root was lifted to the paper (mm): the handle pose put it below.
    pub root_lifted_mm: f64,
}

/// A point's friction: the energy's factor `mu |F_n|`, where the contact is measured from
/// and its preferred direction (zero: isotropic).
#[derive(Copy, Clone, Debug, Default)]
struct Friction {
    mu_fn: f64,
    /// The cone's rounding (mm): [`FRICTION_SMOOTHING_MM`] sticking, the
    /// [`SLIDING_SMOOTHING_MM_S`] over a solve sliding.
    eps: f64,
    anchor: [f64; 2],
    dir: [f64; 2],
}

/// Everything one minimisation holds fixed.
#[derive(Copy, Clone, Debug)]
struct Problem {
    joints: usize,
    root: V3,
    /// The root frame `F_0`: the handle's, turned to the spine's rest direction.
    frame: Mat3,
    lengths: [f64; MAX_JOINTS],
    stiffness: [f64; MAX_JOINTS],
    joint_friction: f64,
    /// Each joint's reference bend for eq. 4's `d beta` (see `PLASTIC_REFERENCE_SPAN`).
    beta_start: [f64; MAX_JOINTS],
    /// Indexed by point (1..=joints; 0, the root, never touches).
    friction: [Friction; MAX_JOINTS + 1],
    anisotropy: f64,
    anisotropy_exponent: f64,
    load: V3,
}

/// The energy and its derivatives at one point.
struct Eval {
    chain: Chain,
    energy: f64,
    grad: [f64; MAX_VARS],
    /// The Lagrangian's Hessian (energy and the constraints' curvature at the given
    /// multipliers; the friction's Hessian in the paper plane by differences of its gradient).
    hess: [[f64; MAX_VARS]; MAX_VARS],
}

/// The bend of one joint (eq. 12) and its derivatives in (phi, theta).
struct Bend {
    beta: f64,
    /// `d (beta^2 / 2)`: smooth through the rest position.
    half_sq_grad: [f64; 2],
    /// `d beta`, zero at the rest position where it is not defined (the paper's choice at
    /// the friction cone's apex, §3.4).
    grad: [f64; 2],
    /// `d^2 (beta^2 / 2)`.
    half_sq_hess: [[f64; 2]; 2],
    /// `d^2 beta`, zero within a milliradian of the rest position, where it grows as
    /// `1 / beta` (the cone's apex).
    hess: [[f64; 2]; 2],
}

fn bend(phi: f64, theta: f64) -> Bend {
    let (st, ct) = libm::sincos(theta);
    let (sp, cp) = libm::sincos(phi);
    // sin(beta) without the cancellation of sqrt(1 - cos^2): 1 - ct^2 cp^2 = st^2 + ct^2 sp^2.
    let s = libm::sqrt(st * st + ct * ct * sp * sp);
    let beta = libm::atan2(s, ct * cp);
    let g = if beta < 1e-4 {
        1.0 + beta * beta / 6.0
    } else {
        beta / s
    };
    // w = d cos(beta) negated, and its derivative dw (symmetric).
    let w = [ct * sp, st * cp];
    let c = ct * cp;
    let dw = [[c, -st * sp], [-st * sp, c]];
    let grad = if s > 1e-12 {
        [w[0] / s, w[1] / s]
    } else {
        [0.0; 2]
    };
    // d^2 (beta^2 / 2) = (g'(beta) / sin beta) w w^T + g dw, with
    // g' / sin beta = (sin beta - beta cos beta) / sin^3 beta -> 1/3 at rest.
    let gp = if beta < 1e-3 {
        1.0 / 3.0 + beta * beta / 15.0
    } else {
        (s - beta * c) / (s * s * s)
    };
    // d^2 beta = dw / sin beta - cos beta w w^T / sin^3 beta.
    let near_rest = s < 1e-3;
    let mut half_sq_hess = [[0.0; 2]; 2];
    let mut hess = [[0.0; 2]; 2];
    for a in 0..2 {
        for b in 0..2 {
            half_sq_hess[a][b] = gp * w[a] * w[b] + g * dw[a][b];
            if !near_rest {
                hess[a][b] = dw[a][b] / s - c * w[a] * w[b] / (s * s * s);
            }
        }
    }
    Bend {
        beta,
        half_sq_grad: [g * w[0], g * w[1]],
        grad,
        half_sq_hess,
        hess,
    }
}

/// The bend angle beta (eq. 12) of a joint at (theta, phi).
pub fn bend_angle(theta: f64, phi: f64) -> f64 {
    bend(phi, theta).beta
}

/// Handle positions are clamped to this box (mm).
const MAX_COORDINATE_MM: f64 = 1e6;
/// Tip loads are clamped to this many newtons per component.
const MAX_LOAD_N: f64 = 1e4;

fn clamp_vec(v: V3, limit: f64) -> V3 {
    V3::new(
        v.x.clamp(-limit, limit),
        v.y.clamp(-limit, limit),
        v.z.clamp(-limit, limit),
    )
}

fn clamp_angles(q: &mut [f64; MAX_VARS], n: usize) {
    for v in 0..n {
        let lim = if v % 2 == 0 { PHI_LIMIT } else { THETA_LIMIT };
        q[v] = q[v].clamp(-lim, lim);
    }
}

impl Problem {
    fn chain(&self, q: &[f64; MAX_VARS]) -> Chain {
        Chain::new(self.root, &self.frame, &self.lengths[..self.joints], q)
    }

    /// A contact's friction energy (eqs. 3, 13, 14), its gradient in the point's paper
    /// coordinates and its Hessian there: by central differences of the analytic gradient,
    /// over a thousandth of the rounded distance from the anchor (the scale on which the
    /// cone's curvature changes), accurate to about a millionth.
    fn friction(&self, f: &Friction, x: V3) -> (f64, [f64; 2], [[f64; 2]; 2]) {
        let (e, g) = self.friction_gradient(f, [x.x, x.y]);
        let dx = [x.x - f.anchor[0], x.y - f.anchor[1]];
        let eps = f.eps;
        let step = 1e-3 * libm::sqrt(dx[0] * dx[0] + dx[1] * dx[1] + eps * eps);
        let mut h = [[0.0; 2]; 2];
        for a in 0..2 {
            let mut xp = [x.x, x.y];
            let mut xm = xp;
            xp[a] += step;
            xm[a] -= step;
            let (_, gp) = self.friction_gradient(f, xp);
            let (_, gm) = self.friction_gradient(f, xm);
            for b in 0..2 {
                h[b][a] = (gp[b] - gm[b]) / (2.0 * step);
            }
        }
        let off = 0.5 * (h[0][1] + h[1][0]);
        h[0][1] = off;
        h[1][0] = off;
        (e, g, h)
    }

    /// The friction energy and its gradient at the paper point `x`.
    fn friction_gradient(&self, f: &Friction, x: [f64; 2]) -> (f64, [f64; 2]) {
        let eps = f.eps;
        let dx = [x[0] - f.anchor[0], x[1] - f.anchor[1]];
        let rho = libm::sqrt(dx[0] * dx[0] + dx[1] * dx[1] + eps * eps);
        let s = rho - eps;
        let along = f.dir[0] * dx[0] + f.dir[1] * dx[1];
        let (mut eta, mut geta) = (0.0, [0.0; 2]);
        if self.anisotropy > 0.0 && along > 0.0 {
            // eta = C max(0, d . dx^)^k with dx^ = dx / rho (the rounded unit vector).
            let u = along / rho;
            let uk1 = libm::pow(u, self.anisotropy_exponent - 1.0);
            eta = self.anisotropy * uk1 * u;
            let c = self.anisotropy * self.anisotropy_exponent * uk1 / rho;
            let r2 = rho * rho;
            geta = [
                c * (f.dir[0] - along * dx[0] / r2),
                c * (f.dir[1] - along * dx[1] / r2),
            ];
        }
        let m = f.mu_fn;
        let e = m * (1.0 - eta) * s;
        let g = [
            m * ((1.0 - eta) * dx[0] / rho - s * geta[0]),
            m * ((1.0 - eta) * dx[1] / rho - s * geta[1]),
        ];
        (e, g)
    }

    /// The joints' spring and friction energy (eqs. 2, 4), into `grad` and `hess` if given.
    fn joint_terms(
        &self,
        q: &[f64; MAX_VARS],
        mut derivs: Option<(&mut [f64; MAX_VARS], &mut [[f64; MAX_VARS]; MAX_VARS])>,
    ) -> f64 {
        let eps = PLASTICITY_SMOOTHING_RAD;
        let mut e = 0.0;
        for k in 0..self.joints {
            let b = bend(q[2 * k], q[2 * k + 1]);
            let kk = self.stiffness[k];
            e += 0.5 * kk * b.beta * b.beta;
            let d = self.joint_friction;
            let delta = b.beta - self.beta_start[k];
            let rho = libm::sqrt(delta * delta + eps * eps);
            e += d * (rho - eps);
            if let Some((grad, hess)) = derivs.as_mut() {
                let r = rho * rho * rho;
                for a in 0..2 {
                    grad[2 * k + a] += kk * b.half_sq_grad[a] + d * delta / rho * b.grad[a];
                    for c in 0..2 {
                        hess[2 * k + a][2 * k + c] += kk * b.half_sq_hess[a][c]
                            + d * eps * eps / r * b.grad[a] * b.grad[c]
                            + d * delta / rho * b.hess[a][c];
                    }
                }
            }
        }
        e
    }

    /// The energy E (eq. 1 with the friction of eq. 13 and the tip load's potential) at `q`.
    fn energy(&self, q: &[f64; MAX_VARS], chain: &Chain) -> f64 {
        let mut e = self.joint_terms(q, None);
        for i in 1..=self.joints {
            if self.friction[i].mu_fn > 0.0 {
                let x = chain.x[i];
                e += self.friction_gradient(&self.friction[i], [x.x, x.y]).0;
            }
        }
        e - self.load.dot(chain.x[self.joints])
    }

    /// Each point's energy gradient in world coordinates (friction and load): the negated
    /// force the paper and the load put on it, besides the normal force.
    fn point_gradients(&self, chain: &Chain) -> [V3; MAX_JOINTS + 1] {
        let mut w = [V3::ZERO; MAX_JOINTS + 1];
        for i in 1..=self.joints {
            if self.friction[i].mu_fn > 0.0 {
                let x = chain.x[i];
                let (_, g) = self.friction_gradient(&self.friction[i], [x.x, x.y]);
                w[i] = V3::new(g[0], g[1], 0.0);
            }
        }
        w[self.joints] -= self.load;
        w
    }

    fn evaluate(&self, q: &[f64; MAX_VARS], lam: &[f64; MAX_JOINTS + 1]) -> Eval {
        let chain = self.chain(q);
        let n = chain.vars();
        let mut grad = [0.0; MAX_VARS];
        let mut hess = [[0.0; MAX_VARS]; MAX_VARS];
        let mut energy = self.joint_terms(q, Some((&mut grad, &mut hess)));
        energy -= self.load.dot(chain.x[self.joints]);
        let mut w = [V3::ZERO; MAX_JOINTS + 1];
        for i in 1..=self.joints {
            let mut jac = [V3::ZERO; MAX_VARS];
            for v in 0..n {
                jac[v] = chain.d(i, v);
            }
            if self.friction[i].mu_fn > 0.0 {
                let (e, g, h) = self.friction(&self.friction[i], chain.x[i]);
                energy += e;
                w[i] = V3::new(g[0], g[1], 0.0);
                for u in 0..2 * i {
                    let a = [jac[u].x, jac[u].y];
                    let ha = [
                        h[0][0] * a[0] + h[0][1] * a[1],
                        h[1][0] * a[0] + h[1][1] * a[1],
                    ];
                    for v in 0..2 * i {
                        hess[u][v] += ha[0] * jac[v].x + ha[1] * jac[v].y;
                    }
                }
            }
            if i == self.joints {
                w[i] -= self.load;
            }
            for v in 0..2 * i {
                grad[v] += w[i].dot(jac[v]);
            }
            chain.add_curvature(i, w[i] - V3::Z * lam[i], &mut hess);
        }
        Eval {
            chain,
            energy,
            grad,
            hess,
        }
    }
}

/// The outcome of one minimisation.
struct Minimum {
    q: [f64; MAX_VARS],
    lam: [f64; MAX_JOINTS + 1],
    iterations: u32,
    converged: bool,
}

/// The SQP step at `q`: the QP `min g^T d + d^T H d / 2` subject to `z_i + a_i . d >= 0`,
/// solved through its dual (the multipliers are the only unknowns with bounds; see the
/// module docs), with a ridge of `damping` times H's scale. `augment` makes H convex across
/// the pressing contacts (always, but for the test that checks it leaves the step alone).
/// `None` if no positive definite model of H was found.
fn sqp_step(
    p: &Problem,
    q: &[f64; MAX_VARS],
    lam: &[f64; MAX_JOINTS + 1],
    damping: f64,
    augment: bool,
) -> Option<(Eval, [f64; MAX_VARS], [f64; MAX_JOINTS + 1])> {
    let ev = p.evaluate(q, lam);
    let n = ev.chain.vars();
    let m = p.joints;
    let mut biggest = 0.0f64;
    for v in 0..n {
        biggest = biggest.max(ev.hess[v][v].abs());
    }
    // The contacts' constraints hold the spine where its own Hessian is not convex (pressed,
    // it would buckle): the Hessian is convex only along the paper. Adding rho a a^T for
    // each pressing contact makes it convex across too, and leaves the step alone for a
    // contact that stays pressed, since the step keeps a . d = -z there (its multiplier then
    // carries rho (a . d), taken out below). A ridge alone, large enough to factor, shortens
    // every step and the minimisation crawls. (rho is a number on H's scale, not a
    // stiffness. Scaled per contact by 1 / |a|^2 the term was weaker, the solves converged
    // as often, and a spine pressed straight down buckled onto other branches: the upright
    // press's chaos, docs/models.md.)
    let mut hm = ev.hess;
    let rho = biggest.max(1e-6);
    let mut augmented = [false; MAX_JOINTS + 1];
    for i in 1..=m {
        if augment && lam[i] > CONTACT_FORCE_N {
            augmented[i] = true;
            for u in 0..n {
                let au = ev.chain.d(i, u).z;
                for v in 0..n {
                    hm[u][v] += rho * au * ev.chain.d(i, v).z;
                }
            }
        }
    }
    // Then made positive definite by the smallest ridge tau that factors (tenfold steps),
    // at least the minimisation's damping.
    let mut tau = damping * rho;
    let mut l = hm;
    let mut factored = false;
    for _ in 0..40 {
        l = hm;
        for v in 0..n {
            l[v][v] += tau;
        }
        if dense::cholesky(&mut l, n) {
            factored = true;
            break;
        }
        tau = if tau == 0.0 {
            1e-8 * biggest.max(1e-6)
        } else {
            tau * 10.0
        };
    }
    if !factored {
        return None;
    }
    // s = H^-1 g; y_i = L^-1 a_i; the dual's M = A H^-1 A^T = Y^T Y and h = z - A s.
    let mut s = ev.grad;
    dense::solve(&l, n, &mut s);
    let mut y = [[0.0; MAX_VARS]; MAX_JOINTS];
    let mut a = [[0.0; MAX_VARS]; MAX_JOINTS];
    let mut h = [0.0; MAX_JOINTS];
    for i in 0..m {
        for v in 0..n {
            a[i][v] = ev.chain.d(i + 1, v).z;
        }
        y[i] = a[i];
        dense::forward(&l, n, &mut y[i]);
        let mut as_ = 0.0;
        for v in 0..n {
            as_ += a[i][v] * s[v];
        }
        h[i] = ev.chain.x[i + 1].z - as_;
    }
    let mut mm = [[0.0; MAX_JOINTS]; MAX_JOINTS];
    for i in 0..m {
        for j in 0..=i {
            let mut d = 0.0;
            for v in 0..n {
                d += y[i][v] * y[j][v];
            }
            mm[i][j] = d;
            mm[j][i] = d;
        }
    }
    let mut mu = [0.0; MAX_JOINTS];
    // A QP the active set did not finish still gives a feasible multiplier and a step the
    // line search judges.
    let _ = dense::box_qp(m, &mm, &h, MAX_NORMAL_FORCE_N, &mut mu);
    // d = H^-1 A^T mu - s.
    let mut d = [0.0; MAX_VARS];
    for v in 0..n {
        for i in 0..m {
            d[v] += a[i][v] * mu[i];
        }
    }
    dense::solve(&l, n, &mut d);
    for v in 0..n {
        d[v] -= s[v];
    }
    let mut lam_new = [0.0; MAX_JOINTS + 1];
    for i in 1..=m {
        lam_new[i] = if augmented[i] && mu[i - 1] > 0.0 {
            let ad: f64 = (0..n).map(|v| a[i - 1][v] * d[v]).sum();
            (mu[i - 1] - rho * ad).clamp(0.0, MAX_NORMAL_FORCE_N)
        } else {
            mu[i - 1]
        };
    }
    Some((ev, d, lam_new))
}

fn violation(chain: &Chain) -> f64 {
    let mut v = 0.0;
    for i in 1..=chain.joints {
        v += (-chain.x[i].z).max(0.0);
    }
    v
}

/// Active-set SQP from `q` (module docs): QP step, l1 merit line search.
fn minimise(
    p: &Problem,
    q0: &[f64; MAX_VARS],
    lam0: &[f64; MAX_JOINTS + 1],
    max_iterations: u32,
) -> Minimum {
    let n = 2 * p.joints;
    let mut q = *q0;
    let mut lam = *lam0;
    let mut nu = 1.0f64;
    let mut iterations = 0;
    let mut converged = false;
    // Levenberg-Marquardt: a step the line search cannot use is tried again shorter and
    // turned toward the gradient, by a ridge of this much of the Hessian's scale.
    let mut damping = 0.0f64;
    while iterations < max_iterations {
        let Some((ev, mut d, lam_qp)) = sqp_step(p, &q, &lam, damping, true) else {
            break;
        };
        iterations += 1;
        lam = lam_qp;
        let mut big = 0.0f64;
        for v in 0..n {
            big = big.max(d[v].abs());
        }
        if !big.is_finite() {
            break;
        }
        if big < STEP_TOLERANCE_RAD {
            // A damped step may be short only because it is damped.
            converged = damping == 0.0;
            break;
        }
        if big > MAX_STEP_RAD {
            let f = MAX_STEP_RAD / big;
            for v in 0..n {
                d[v] *= f;
            }
        }
        // l1 merit E + nu sum max(0, -z_i), nu above every multiplier.
        let mut lmax = 0.0f64;
        for &l in &lam[1..=p.joints] {
            lmax = lmax.max(l);
        }
        nu = nu.max(2.0 * lmax + 1e-3);
        let viol0 = violation(&ev.chain);
        let merit0 = ev.energy + nu * viol0;
        let mut slope = -nu * viol0;
        for v in 0..n {
            slope += ev.grad[v] * d[v];
        }
        let slope = slope.min(0.0);
        let mut alpha = 1.0;
        let mut accepted = false;
        for _ in 0..MAX_HALVINGS {
            let mut qt = q;
            for v in 0..n {
                qt[v] += alpha * d[v];
            }
            clamp_angles(&mut qt, n);
            let ct = p.chain(&qt);
            let merit = p.energy(&qt, &ct) + nu * violation(&ct);
            if merit <= merit0 + 1e-4 * alpha * slope {
                q = qt;
                accepted = true;
                break;
            }
            alpha *= 0.5;
        }
        if !accepted {
            // No decrease along the step: as close to the minimum as the merit resolves,
            // or a Hessian model the step cannot trust.
            if big < 1e-6 || damping >= MAX_DAMPING {
                converged = big < 1e-6 && damping == 0.0;
                break;
            }
            damping = if damping == 0.0 { 1e-4 } else { damping * 10.0 };
            continue;
        }
        damping = if damping > 1e-4 { damping * 0.1 } else { 0.0 };
    }
    Minimum {
        q,
        lam,
        iterations,
        converged,
    }
}

/// Gauss-Newton steps onto the paper for the joints below it (minimum-norm corrections of
/// the violated constraints). `true` when every joint ends within the tolerance.
fn restore(p: &Problem, q: &mut [f64; MAX_VARS]) -> bool {
    let n = 2 * p.joints;
    for _ in 0..20 {
        let c = p.chain(q);
        let mut rows = [0usize; MAX_JOINTS];
        let mut nv = 0;
        for i in 1..=p.joints {
            if c.x[i].z < 0.0 {
                rows[nv] = i;
                nv += 1;
            }
        }
        if nv == 0 {
            return true;
        }
        let mut a = [[0.0; MAX_VARS]; MAX_JOINTS];
        for r in 0..nv {
            for v in 0..n {
                a[r][v] = c.d(rows[r], v).z;
            }
        }
        let mut g = [[0.0; MAX_JOINTS]; MAX_JOINTS];
        let mut scale = 0.0f64;
        for r in 0..nv {
            for s in 0..nv {
                g[r][s] = (0..n).map(|v| a[r][v] * a[s][v]).sum();
            }
            scale = scale.max(g[r][r]);
        }
        for r in 0..nv {
            g[r][r] += 1e-10 * scale.max(1e-12);
        }
        if !dense::cholesky(&mut g, nv) {
            return false;
        }
        // Aim a little above the paper so the linearisation's error does not leave it below.
        let mut y = [0.0; MAX_JOINTS];
        for r in 0..nv {
            y[r] = -c.x[rows[r]].z + 1e-9;
        }
        dense::solve(&g, nv, &mut y);
        for v in 0..n {
            for r in 0..nv {
                q[v] += a[r][v] * y[r];
            }
        }
        clamp_angles(q, n);
        if !q[..n].iter().all(|v| v.is_finite()) {
            return false;
        }
    }
    let c = p.chain(q);
    (1..=p.joints).all(|i| c.x[i].z >= -PENETRATION_TOLERANCE_MM)
}

/// Angles that lay the spine flat from its root along the paper: always feasible once the
/// root is on or above the paper. The first joint turns the segment into the horizontal
/// direction perpendicular to the root frame's y axis (so theta is 0), on the side that
/// needs the smaller phi; the others stay straight.
fn flat_angles(frame: &Mat3, joints: usize) -> [f64; MAX_VARS] {
    let mut q = [0.0; MAX_VARS];
    let y = frame.c[1];
    let h = V3::Z.cross(y);
    let h = match h.normalized_or_none(1e-9) {
        Some(h) => h,
        // The root frame's y axis is vertical: any horizontal direction is perpendicular to it.
        None => (frame.c[0] - V3::Z * frame.c[0].z)
            .normalized_or_none(1e-9)
            .unwrap_or(V3::X),
    };
    // The direction in the root frame, v = F_0^T h; the segment is -(sp ct, -st, cp ct).
    let v = V3::new(h.dot(frame.c[0]), h.dot(frame.c[1]), h.dot(frame.c[2]));
    let phi = libm::atan2(-v.x, -v.z);
    let phi = if phi.abs() > core::f64::consts::FRAC_PI_2 {
        libm::atan2(v.x, v.z)
    } else {
        phi
    };
    if joints > 0 {
        q[0] = phi;
    }
    q
}

/// A spine of Baxter & Lin's brush: a chain of joints minimising its energy against the
/// paper, one [`Spine::solve`] per handle pose.
#[derive(Clone, Debug)]
pub struct Spine {
    params: SpineParams,
    /// The rotation from the handle's -z to the rest direction; `None` hanging straight down.
    rest: Option<Mat3>,
    lengths: [f64; MAX_JOINTS],
    stiffness: [f64; MAX_JOINTS],
    /// Angles in the chain's variable order (phi, theta per joint).
    q: [f64; MAX_VARS],
    /// Each joint's friction reference bend (`PLASTIC_REFERENCE_SPAN`).
    plastic_ref: [f64; MAX_JOINTS],
    x: [V3; MAX_JOINTS + 1],
    normal: [f64; MAX_JOINTS + 1],
    friction: [V3; MAX_JOINTS + 1],
    state: [ContactState; MAX_JOINTS + 1],
    handle_force: V3,
    handle_torque: V3,
    pose: Pose<f64>,
    /// The time between solves (s): a sliding contact catches below
    /// [`SpineParams::stick_speed_mm_s`] over it.
    interval_s: f64,
    solves: u64,
    fallbacks: u64,
    unconverged: u64,
    bad_inputs: u64,
}

impl Spine {
    /// A spine at rest (every angle zero) on the handle at `pose`, solved once there (a pose
    /// that puts it into the paper bends it onto the paper).
    pub fn new(params: SpineParams, pose: Pose<f64>) -> Result<Self, SpineParamError> {
        params.validate()?;
        let mut s = Spine {
            params,
            rest: None,
            lengths: [0.0; MAX_JOINTS],
            stiffness: [0.0; MAX_JOINTS],
            q: [0.0; MAX_VARS],
            plastic_ref: [0.0; MAX_JOINTS],
            x: [V3::ZERO; MAX_JOINTS + 1],
            normal: [0.0; MAX_JOINTS + 1],
            friction: [V3::ZERO; MAX_JOINTS + 1],
            state: [ContactState::Free; MAX_JOINTS + 1],
            handle_force: V3::ZERO,
            handle_torque: V3::ZERO,
            pose: Pose::default(),
            interval_s: DEFAULT_SOLVE_INTERVAL_S,
            solves: 0,
            fallbacks: 0,
            unconverged: 0,
            bad_inputs: 0,
        };
        s.derive();
        s.solve(&pose, V3::ZERO);
        Ok(s)
    }

    /// The time between this spine's solves (s; [`DEFAULT_SOLVE_INTERVAL_S`] unless set):
    /// what turns the stick speed into a distance per solve. Not finite or not positive
    /// keeps the interval it had.
    pub fn set_solve_interval(&mut self, interval_s: f64) {
        if interval_s.is_finite() && interval_s > 0.0 {
            self.interval_s = interval_s;
        }
    }

    /// The time between this spine's solves (s).
    pub fn solve_interval(&self) -> f64 {
        self.interval_s
    }

    fn derive(&mut self) {
        self.rest = match self.params.rest_direction() {
            Some(d) if d != -V3::Z => Some(Mat3::rest(d)),
            _ => None,
        };
        for k in 0..self.joints() {
            self.lengths[k] = self.params.segment_mm();
            self.stiffness[k] = self.params.stiffness(k);
        }
    }

    /// Replaces the parameters after validating them (nothing changes on error). A change of
    /// `joints` puts the spine back at rest; the next solve places it. A changed
    /// `root_direction` keeps the angles, now measured from the new rest direction.
    pub fn set_params(&mut self, params: SpineParams) -> Result<(), SpineParamError> {
        params.validate()?;
        if params.joints != self.params.joints {
            self.q = [0.0; MAX_VARS];
            self.plastic_ref = [0.0; MAX_JOINTS];
            self.normal = [0.0; MAX_JOINTS + 1];
            self.state = [ContactState::Free; MAX_JOINTS + 1];
        }
        self.params = params;
        self.derive();
        Ok(())
    }

    pub fn params(&self) -> &SpineParams {
        &self.params
    }

    /// J, the number of joints.
    pub fn joints(&self) -> usize {
        self.params.joints as usize
    }

    /// Point `i` in world coordinates (mm): 0 the root on the ferrule, 1..=J the joints'
    /// segment ends, J the tip.
    pub fn position(&self, i: usize) -> Vec3<f64> {
        self.x[i.min(self.joints())]
    }

    /// The root and every joint, root first.
    pub fn positions(&self) -> &[Vec3<f64>] {
        &self.x[..=self.joints()]
    }

    /// Joint `k`'s angles (theta, phi) in the XYZ Euler set (rad; k from 0 at the root), the
    /// root joint's relative to the rest direction's frame.
    pub fn angles(&self, k: usize) -> (f64, f64) {
        let k = k.min(self.joints() - 1);
        (self.q[2 * k + 1], self.q[2 * k])
    }

    /// Joint `k`'s bend beta (eq. 12, rad).
    pub fn bend(&self, k: usize) -> f64 {
        let (t, p) = self.angles(k);
        bend_angle(t, p)
    }

    /// Whether point `i` (1..=J) presses on the paper (its constraint is active).
    pub fn in_contact(&self, i: usize) -> bool {
        self.normal_force(i) > CONTACT_FORCE_N
    }

    /// The paper's normal force on point `i` (N, along +z): the Lagrange multiplier of its
    /// non-penetration constraint.
    pub fn normal_force(&self, i: usize) -> f64 {
        if (1..=self.joints()).contains(&i) {
            self.normal[i]
        } else {
            0.0
        }
    }

    /// The paper's friction force on point `i` (N, in the paper's plane): minus the friction
    /// energy's gradient at the solution.
    pub fn friction_force(&self, i: usize) -> Vec3<f64> {
        if (1..=self.joints()).contains(&i) {
            self.friction[i]
        } else {
            V3::ZERO
        }
    }

    /// Point `i`'s stiction state (§3.4.1).
    pub fn contact_state(&self, i: usize) -> ContactState {
        if (1..=self.joints()).contains(&i) {
            self.state[i]
        } else {
            ContactState::Free
        }
    }

    /// The force the spine exerts on the handle (N): what the paper and the load put on it,
    /// passed on through the massless spine to its root.
    pub fn handle_force(&self) -> Vec3<f64> {
        self.handle_force
    }

    /// The torque the spine exerts on the handle about its root (N mm): the root joint's
    /// spring and friction torque about its two axes, and the twist the chain cannot take
    /// (carried by the ferrule) about the third.
    pub fn handle_torque(&self) -> Vec3<f64> {
        self.handle_torque
    }

    /// The handle pose of the last solve, the ferrule lifted to the paper if it was below.
    pub fn pose(&self) -> Pose<f64> {
        self.pose
    }

    /// Solves so far, and of them: those that fell back ([`SolveReport::fell_back`]), those
    /// whose minimisation did not converge, and those whose input was not finite (the last
    /// pose was kept).
    pub fn counts(&self) -> (u64, u64, u64, u64) {
        (
            self.solves,
            self.fallbacks,
            self.unconverged,
            self.bad_inputs,
        )
    }

    /// The spring energy sum K_i beta_i^2 / 2 (N mm, eq. 2).
    pub fn spring_energy(&self) -> f64 {
        (0..self.joints())
            .map(|k| 0.5 * self.stiffness[k] * self.bend(k) * self.bend(k))
            .sum()
    }

    /// Moves the spine with the handle to `pose` (steps 1-2 of §3.1: carried rigidly, the
    /// angles kept) and finds its shape there (step 3): the minimum of E (eq. 1) subject to
    /// non-penetration (eq. 5), with friction from where each contact was, stiction
    /// (§3.4.1), anisotropy (eqs. 13-14), joint friction (eq. 15), and a force `tip_load`
    /// (N) on the tip. Warm-started from the last angles. Never panics; a pose or load that
    /// is not finite keeps the last one.
    pub fn solve(&mut self, pose: &Pose<f64>, tip_load: Vec3<f64>) -> SolveReport {
        self.solves += 1;
        let mut report = SolveReport::default();
        let finite = |v: &[f64]| v.iter().all(|x| x.is_finite());
        let pose = if finite(&pose.pos.to_f64()) && finite(&pose.rot.to_f64()) {
            let rot = pose.rot.normalized();
            if rot.norm2() > 0.5 {
                Pose::new(pose.pos, rot)
            } else {
                Pose::new(pose.pos, Quat::IDENTITY)
            }
        } else {
            self.bad_inputs += 1;
            self.pose
        };
        // Finite but absurd inputs are clamped to a range no brush meets, where every product
        // of the energy stays finite.
        let pose = Pose::new(clamp_vec(pose.pos, MAX_COORDINATE_MM), pose.rot);
        let load = if finite(&tip_load.to_f64()) {
            clamp_vec(tip_load, MAX_LOAD_N)
        } else {
            self.bad_inputs += 1;
            V3::ZERO
        };
        let n = 2 * self.joints();
        let j = self.joints();
        let handle = Mat3::from_quat(pose.rot);
        let frame = root_frame(&handle, self.rest.as_ref());
        let r = self.params.root_mm;
        let mut root = pose.pos + handle.apply(V3::new(r[0], r[1], r[2]));
        // Like Liang's god-object the drawn ferrule stays out of the paper: a spine whose
        // root is below it has no shape that keeps its joints above.
        let mut pose = pose;
        if root.z < 0.0 {
            report.root_lifted_mm = -root.z;
            pose.pos.z -= root.z;
            root.z = 0.0;
        }
        self.pose = pose;

        let mut p = Problem {
            joints: j,
            root,
            frame,
            lengths: self.lengths,
            stiffness: self.stiffness,
            joint_friction: self.params.joint_friction,
            beta_start: [0.0; MAX_JOINTS],
            friction: [Friction::default(); MAX_JOINTS + 1],
            anisotropy: self.params.anisotropy,
            anisotropy_exponent: self.params.anisotropy_exponent,
            load,
        };
        p.beta_start = self.plastic_ref;
        // Where each point was, and the hair's direction at the contact once carried with
        // the handle: the preferred (pulling) direction points from the contact back
        // toward the ferrule along the segment that ends there, in the paper's plane.
        let carried = p.chain(&self.q);
        let sliding_eps = SLIDING_SMOOTHING_MM_S * self.interval_s;
        let mut sticking = [false; MAX_JOINTS + 1];
        let mut fn_used = [0.0; MAX_JOINTS + 1];
        for i in 1..=j {
            let back = carried.x[i - 1] - carried.x[i];
            let back = V3::new(back.x, back.y, 0.0);
            p.friction[i].dir = match back.normalized_or_none(1e-9) {
                Some(d) => [d.x, d.y],
                None => [0.0; 2],
            };
            p.friction[i].anchor = [self.x[i].x, self.x[i].y];
            p.friction[i].eps = sliding_eps;
            if self.normal[i] > CONTACT_FORCE_N {
                fn_used[i] = self.normal[i];
                let mu = match self.state[i] {
                    ContactState::Sticking { anchor } => {
                        sticking[i] = true;
                        p.friction[i].anchor = anchor;
                        p.friction[i].eps = FRICTION_SMOOTHING_MM;
                        self.params.friction_static
                    }
                    _ => self.params.friction_kinetic,
                };
                p.friction[i].mu_fn = mu * fn_used[i];
            }
        }

        let mut q = self.q;
        // A straight spine pressed along its axis (a vertical handle straight down) gives its
        // tip a constraint with no gradient: no step of the angles moves it up to first
        // order, and the QP cannot choose a side to buckle to. Bend it a little (the same way
        // every time) so it can.
        for i in 1..=j {
            let grad2: f64 = (0..n).map(|v| carried.d(i, v).z * carried.d(i, v).z).sum();
            if carried.x[i].z < 0.0 && grad2 < 1e-6 * self.params.length_mm * self.params.length_mm
            {
                for k in 0..j {
                    q[2 * k] += 1e-2;
                }
                break;
            }
        }
        let mut lam = self.normal;
        let mut converged = false;
        for _ in 0..MAX_PASSES {
            let found = minimise(&p, &q, &lam, self.params.max_iterations as u32);
            report.passes += 1;
            report.iterations += found.iterations;
            converged = found.converged;
            q = found.q;
            lam = found.lam;
            if !q[..n].iter().all(|v| v.is_finite()) || !lam.iter().all(|v| v.is_finite()) {
                break;
            }
            let c = p.chain(&q);
            let mut again = false;
            for i in 1..=j {
                // A sticking contact that moved past the slip distance slides: re-solve
                // with kinetic friction from where it was (§3.4.1).
                if sticking[i] {
                    let a = p.friction[i].anchor;
                    let moved = libm::hypot(c.x[i].x - a[0], c.x[i].y - a[1]);
                    if moved > self.params.slip_mm {
                        sticking[i] = false;
                        p.friction[i].anchor = [self.x[i].x, self.x[i].y];
                        p.friction[i].mu_fn = self.params.friction_kinetic * fn_used[i];
                        p.friction[i].eps = sliding_eps;
                        again = true;
                    }
                }
                // The friction's normal force is held through a minimisation (§3.4); when
                // the solution's differs, solve again with it.
                let fresh = if lam[i] > CONTACT_FORCE_N {
                    lam[i]
                } else {
                    0.0
                };
                if (fresh - fn_used[i]).abs()
                    > NORMAL_FORCE_TOLERANCE * fn_used[i] + MIN_NORMAL_FORCE_CHANGE_N
                {
                    fn_used[i] = fresh;
                    let mu = if sticking[i] {
                        self.params.friction_static
                    } else {
                        self.params.friction_kinetic
                    };
                    p.friction[i].mu_fn = mu * fresh;
                    again = true;
                }
            }
            if !again {
                break;
            }
        }

        let usable = q[..n].iter().all(|v| v.is_finite()) && lam.iter().all(|v| v.is_finite());
        let mut ok = usable && restore(&p, &mut q);
        if !ok {
            // The last angles carried with the handle, pushed out of the paper; failing
            // that, the spine lying flat from its root.
            report.fell_back = true;
            self.fallbacks += 1;
            q = self.q;
            lam = [0.0; MAX_JOINTS + 1];
            ok = restore(&p, &mut q);
            if !ok {
                q = flat_angles(&frame, j);
            }
        }
        report.converged = converged && !report.fell_back;
        if !report.converged {
            self.unconverged += 1;
        }

        // The final state, its friction forces and what the handle feels.
        let c = p.chain(&q);
        let w = p.point_gradients(&c);
        let mut force = load;
        let mut torque = (c.x[j] - c.x[0]).cross(load);
        for i in 1..=j {
            let fn_i = if lam[i] > CONTACT_FORCE_N && lam[i].is_finite() {
                lam[i]
            } else {
                0.0
            };
            let mut fr = V3::new(-w[i].x, -w[i].y, 0.0);
            if i == j {
                fr = V3::new(-(w[i].x + load.x), -(w[i].y + load.y), 0.0);
            }
            let on_point = V3::Z * fn_i + fr;
            force += on_point;
            torque += (c.x[i] - c.x[0]).cross(on_point);
            self.state[i] = if fn_i == 0.0 {
                ContactState::Free
            } else if sticking[i] {
                ContactState::Sticking {
                    anchor: p.friction[i].anchor,
                }
            } else {
                let moved = libm::hypot(c.x[i].x - self.x[i].x, c.x[i].y - self.x[i].y);
                if moved < self.params.stick_speed_mm_s * self.interval_s
                    && p.friction[i].mu_fn > 0.0
                {
                    ContactState::Sticking {
                        anchor: [c.x[i].x, c.x[i].y],
                    }
                } else {
                    ContactState::Sliding
                }
            };
            self.normal[i] = fn_i;
            self.friction[i] = fr;
        }
        let span = PLASTIC_REFERENCE_SPAN * PLASTICITY_SMOOTHING_RAD;
        for k in 0..j {
            let beta = bend(q[2 * k], q[2 * k + 1]).beta;
            self.plastic_ref[k] = beta - (beta - self.plastic_ref[k]).clamp(-span, span);
        }
        self.q = q;
        self.x = c.x;
        self.handle_force = force;
        self.handle_torque = torque;
        report
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A problem with every term switched on: friction (one contact moving in its easy
    /// direction, one against it), joint friction from a bent start, a tip load; the spine's
    /// rest direction `rest` in the handle frame.
    fn problem(rest: V3) -> Problem {
        let h = 0.2f64;
        let handle = Mat3::from_quat(Quat::new(libm::cos(h), 0.0, libm::sin(h), 0.0));
        let rest = (rest != -V3::Z).then(|| Mat3::rest(rest));
        let mut p = Problem {
            joints: 3,
            root: V3::new(0.0, 0.0, 20.0),
            frame: root_frame(&handle, rest.as_ref()),
            lengths: [10.0; MAX_JOINTS],
            stiffness: [10.0, 7.0, 5.0, 0.0, 0.0, 0.0, 0.0, 0.0],
            joint_friction: 0.3,
            beta_start: [0.2, 0.1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
            friction: [Friction::default(); MAX_JOINTS + 1],
            anisotropy: 0.6,
            anisotropy_exponent: 3.0,
            load: V3::new(0.3, -0.2, 0.1),
        };
        p.friction[2] = Friction {
            mu_fn: 0.4,
            eps: FRICTION_SMOOTHING_MM,
            anchor: [1.0, 2.0],
            dir: [0.6, 0.8],
        };
        p.friction[3] = Friction {
            mu_fn: 0.7,
            eps: FRICTION_SMOOTHING_MM,
            anchor: [9.0, -1.0],
            dir: [-1.0, 0.0],
        };
        p
    }

    /// The term that makes H convex across a pressing contact changes neither the step nor
    /// the contact's multiplier where the contact stays pressed (the tip 1 mm below the
    /// paper, the QP puts it back on it).
    #[test]
    fn the_contacts_convex_term_leaves_the_step_and_the_normal_force_alone() {
        for rest in [-V3::Z, V3::new(0.4, -0.3, -0.8) * (1.0 / 0.9434)] {
            // The springs alone (a convex H without the ridge, so that both steps are the
            // QP's own), the tip pressed.
            let mut p = problem(rest);
            p.friction = [Friction::default(); MAX_JOINTS + 1];
            p.joint_friction = 0.0;
            p.load = V3::ZERO;
            let q = [
                0.3, -0.2, 0.25, 0.4, -0.5, 0.1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
            ];
            p.root.z -= p.chain(&q).x[3].z + 1.0;
            let mut lam = [0.0; MAX_JOINTS + 1];
            lam[3] = 0.05;
            let (plain_ev, plain_d, plain_lam) =
                sqp_step(&p, &q, &lam, 0.0, false).expect("a step");
            let (_, convex_d, convex_lam) = sqp_step(&p, &q, &lam, 0.0, true).expect("a step");
            let tip: f64 = (0..6)
                .map(|v| plain_ev.chain.d(3, v).z * plain_d[v])
                .sum::<f64>()
                + plain_ev.chain.x[3].z;
            assert!(tip.abs() < 1e-9, "{rest:?}: the QP left the tip at {tip}");
            assert!(plain_lam[3] > 0.0, "{rest:?}: the tip not pressing");
            for v in 0..6 {
                assert!(
                    (plain_d[v] - convex_d[v]).abs() < 1e-9,
                    "{rest:?}: step {v}: {} against {}",
                    plain_d[v],
                    convex_d[v]
                );
            }
            assert!(
                (plain_lam[3] - convex_lam[3]).abs() < 1e-9 * plain_lam[3].max(1.0),
                "{rest:?}: normal force {} against {}",
                plain_lam[3],
                convex_lam[3]
            );
        }
    }

    #[test]
    fn gradient_matches_finite_differences() {
        let fan = 35f64.to_radians();
        let skew = V3::new(0.4, -0.3, -0.8);
        for rest in [
            -V3::Z,
            V3::new(0.0, libm::sin(fan), -libm::cos(fan)),
            skew * (1.0 / skew.norm()),
        ] {
            gradient_matches_finite_differences_for(rest);
        }
    }

    fn gradient_matches_finite_differences_for(rest: V3) {
        let p = problem(rest);
        let q = [
            0.3, -0.2, 0.25, 0.4, -0.5, 0.1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
        ];
        let ev = p.evaluate(&q, &[0.0; MAX_JOINTS + 1]);
        let step = 1e-6;
        for v in 0..6 {
            let mut qp = q;
            let mut qm = q;
            qp[v] += step;
            qm[v] -= step;
            let fd = (p.energy(&qp, &p.chain(&qp)) - p.energy(&qm, &p.chain(&qm))) / (2.0 * step);
            assert!(
                (fd - ev.grad[v]).abs() < 1e-6 * (1.0 + fd.abs()),
                "rest {rest:?}: dE/dq_{v}: {fd} vs {}",
                ev.grad[v]
            );
        }
        assert!((ev.energy - p.energy(&q, &ev.chain)).abs() < 1e-12);
    }

    #[test]
    fn flat_angles_lie_on_the_paper_for_any_handle() {
        let mut seed = 0x1234_5678_9ABC_DEF1u64;
        let mut rnd = || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        for _ in 0..2000 {
            let q = Quat::new(rnd(), rnd(), rnd(), rnd()).normalized();
            let handle = Mat3::from_quat(q);
            let a = flat_angles(&handle, 3);
            assert!(a[0].abs() <= core::f64::consts::FRAC_PI_2 + 1e-12);
            let c = Chain::new(V3::ZERO, &handle, &[5.0; 3], &a);
            for i in 1..=3 {
                assert!(c.x[i].z.abs() < 1e-9, "{:?}", c.x[i]);
            }
        }
    }
}
