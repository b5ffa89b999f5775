//! Baxter & Lin's brush (Baxter & Lin 2004, "A Versatile Interactive 3D Brush Model"; SPEC
//! F), the second brush model: spines that find their shape by minimising energy, skinned
//! by the surface the rest of Maobi draws.
//!
//! * [`head`]: brush heads (round, flat, filbert, fan) as sets of spines.
//! * [`skin`]: the surface over the spines as layer rings, and the hair strips between them.
//! * [`Spine`]: one spine and its solver, below.
//! * [`brush`]: the brush as a whole: a head's spines, their surface, their ink.
//! * [`local_force`]: the local force model (eqs. 21-22): the hand's force at 1 kHz from the
//!   brush solved at a lower rate.
//! * [`force_loop`]: that brush in a device's 1 kHz loop, ending in the guide, gate and
//!   output stage Liang's loop ends in.
//!
//! A spine is a chain of J joints hanging from a root on the ferrule. It has no mass: each
//! [`Spine::solve`] carries it rigidly with the new handle pose (§3.1 steps 1-2, the angles
//! kept) and then finds the static equilibrium there as the constrained minimum of its
//! energy (step 3). `f64` throughout (this model runs on the desktop, not on the pen), no
//! heap: fixed arrays of at most [`MAX_JOINTS`] joints.
//!
//! # Kinematics (eqs. 10-11)
//!
//! Joint k turns the segment below it by `Ry(phi_k) Rx(theta_k)` relative to its parent's
//! frame (the XYZ Euler set, the first two angles: eq. 10), the first joint relative to the
//! root frame; each segment, of length `l = length_mm / J`, points down its frame's -z. The
//! root frame is the handle's turned by a fixed rotation, the shortest arc from the handle's
//! -z to the spine's rest direction [`SpineParams::root_direction`] (the handle's own frame
//! for the default, straight down), so at rest (all angles 0) the spine points along its
//! rest direction, carried with the handle, and each bend beta is measured from there. The
//! world positions `x_i` and their first and second derivatives in the angles are analytic
//! (`chain.rs`).
//!
//! # Energy (eqs. 1-4, 13-15)
//!
//! ```text
//! E = sum_k K_k beta_k^2 / 2                                  springs (eq. 2)
//!   + sum_i (1 - eta_i) mu_i |F_n,i| |dx_c,i|                 paper friction (eqs. 3, 13)
//!   + sum_k D |beta_k - beta_k,start|                          joint friction (eqs. 4, 15)
//!   - F_tip . x_J                                              a load on the tip (tests)
//! beta_k = acos(cos theta_k cos phi_k)                         (eq. 12)
//! eta_i  = C_eta max(0, d_p,i . dx_c,i / |dx_c,i|)^k           (eq. 14)
//! subject to z_i >= 0 for every joint i                        (eq. 5, the paper z = 0)
//! ```
//!
//! * `K_k` falls geometrically from [`SpineParams::stiffness_root`] at the root to
//!   [`SpineParams::stiffness_tip`] at the last joint (§3.3: stiffer near the ferrule).
//! * Friction acts on the joints that press on the paper, with a normal force held fixed
//!   through a minimisation (§3.4): first the last solve's, then the solution's own, the
//!   minimisation repeated until they agree within 0.1% (a joint that lands is frictionless
//!   only in the first). `dx_c,i` is the contact's move in the paper's plane from its
//!   anchor: where it stuck (sticking, `mu_s`) or where it was at the last solve (sliding,
//!   `mu_k`). The cone `|dx|` is rounded so the Newton steps have a Hessian (the paper uses
//!   a zero gradient at the apex and BFGS instead): over [`FRICTION_SMOOTHING_MM`] from a
//!   sticking anchor, over [`SLIDING_SMOOTHING_MM_S`] times the time between solves for a
//!   sliding contact, so that a slide's friction is the same however often it is solved.
//! * The preferred direction `d_p,i` is the pull direction: along the hair from the contact
//!   back toward the ferrule (the segment ending at joint i, carried with the handle, in
//!   the paper's plane). A contact dragged behind the handle slides at `(1 - C_eta)` of the
//!   friction; one pushed tip first meets all of it (§3.4.2).
//! * Joint friction `D` (eq. 15) is plasticity: a joint released from a bend stops where its
//!   spring's torque falls to D, at `beta = D / K`. Rounded over
//!   [`PLASTICITY_SMOOTHING_RAD`]; `d beta` is measured from a reference bend that follows
//!   the joint to within three roundings after each solve (the last solve's bend would let
//!   a joint held at its limit creep a little every solve), so a released joint stops
//!   between 95% and 100% of `D / K` and stays.
//!
//! # Stiction (§3.4.1)
//!
//! A contact sticks until a solve moves it more than [`SpineParams::slip_mm`] from its
//! anchor; then it slides and the minimisation runs again with `mu_k` from where it was. A
//! sliding contact that moves slower than [`SpineParams::stick_speed_mm_s`] over a solve
//! ([`Spine::set_solve_interval`]: a speed, so that catching does not depend on the solve
//! rate; the hysteresis) sticks where it is. A contact that lifts off is free; a new one starts
//! sliding and sticks when it stops.
//!
//! # The solver
//!
//! An active-set SQP like the paper's, with analytic derivatives instead of its BFGS
//! Hessian: at each iterate the QP `min g.d + d.H d/2` subject to the linearised
//! constraints `z_i + grad z_i . d >= 0` for every joint, where H is the Lagrangian's
//! Hessian: the springs' and the joint friction's exact 2x2 blocks in each joint's angles
//! (the joint friction cone's curvature left out within a milliradian of rest, where it
//! grows without bound), the paper friction's 2x2 Hessian in the contact's paper
//! coordinates (central differences of its analytic gradient) carried through the chain's
//! Jacobian, and the exact curvature of every point force (friction, load and the
//! constraint multipliers) through the chain's second derivatives. A pressed spine's H is
//! not convex (it would buckle) but in the directions the contacts allow: each pressing
//! contact (one whose last multiplier is positive) adds `rho a_i a_i^T` (`a_i` its
//! constraint's gradient, `rho` H's largest absolute diagonal entry). For a contact that
//! stays pressed this leaves the QP's step alone (it keeps `a_i . d = -z_i`) and is taken
//! out of the multiplier afterwards (`lambda_i - rho a_i . d`); one the step lifts off
//! had its step held toward the paper a little, which the line search judges. Whatever is
//! left non-convex takes the smallest tenfold ridge that factors. (A ridge alone, as large
//! as the buckling needed, shortened every step: the minimisation crawled and 0.3-25% of a
//! stroke's solves stopped short.) The QP is solved through its dual,
//! a bound-constrained QP in the J multipliers (`0 <= lambda_i <= 10^4 N`: the cap is an
//! elastic mode for linearisations that cannot all hold) by a primal active-set method
//! (`dense::box_qp`); the multipliers of the last QP are the contact normal forces. Steps
//! are capped at 0.5 rad in any angle and accepted by an Armijo line search on the l1 merit
//! `E + nu sum max(0, -z_i)` (`nu` twice the largest multiplier), angles clamped to
//! `|theta| <= `[`THETA_LIMIT`], `|phi| <= `[`PHI_LIMIT`]. A step the line search cannot
//! use is solved again with a Levenberg-Marquardt ridge, tenfold each time (from `1e-4` of
//! H's scale to `1e2`), which shortens it and turns it toward the gradient. It stops,
//! converged, when an undamped step is below 1e-8 rad or finds no decrease while below
//! 1e-6 rad; and short of the minimum when a damped step is that short, when the most
//! damped step finds no decrease, or after [`SpineParams::max_iterations`] iterations
//! ([`SolveReport::converged`]); a solve runs at most thirty minimisations
//! (the first, after a slip, and while the normal forces move).
//!
//! Afterwards any joint still below the paper is moved onto it by Gauss-Newton steps on
//! the violated constraints; if the result is not finite or cannot be made feasible the
//! spine falls back to its last angles (carried with the handle and pushed out), and failing
//! that to lying flat from its root, and counts the fallback. A root the pose puts below the
//! paper is lifted onto it first (no shape would keep the joints out otherwise), like
//! Liang's god-object. Every step is a fixed sequence of `f64` operations through `libm`: the
//! same input gives the same bits.
//!
//! # Outputs
//!
//! Joint positions, which joints touch the paper and their normal forces (the multipliers)
//! and friction forces, each contact's stiction state, and the force and torque the spine
//! exerts on the handle: at equilibrium the massless spine passes on exactly what the paper
//! and the load put on it, so that force is their sum and the torque about the root their
//! moment, whose components about the root joint's axes are that joint's spring and
//! friction torques (`tests/baxter_lin.rs` checks this). The local force model of eqs. 21-22
//! ([`local_force`]) is built from these.

pub mod brush;
pub mod force_loop;
pub mod head;
pub mod local_force;
pub mod skin;

mod chain;
mod dense;
mod params;
mod spine;

pub use chain::MAX_JOINTS;
pub use params::{SpineParamError, SpineParams};
pub use spine::{
    bend_angle, ContactState, SolveReport, Spine, DEFAULT_SOLVE_INTERVAL_S, FRICTION_SMOOTHING_MM,
    PENETRATION_TOLERANCE_MM, PHI_LIMIT, PLASTICITY_SMOOTHING_RAD, SLIDING_SMOOTHING_MM_S,
    THETA_LIMIT,
};
