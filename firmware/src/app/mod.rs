//! The application, independent of any board: the 1 kHz force loop, the supervisor's
//! latched faults, the hand-off between the force loop and the link task, and the bench.
//!
//! # Contexts
//!
//! * The **force loop** ([`ForceLoop::tick`]) runs in the board's 1 kHz timer interrupt at
//!   the highest priority. It owns the brush. It reads commands and poses from lock-free
//!   queues, never waits for anything and never touches the link.
//! * The **link task** (thread-mode embassy executor) decodes frames from the host and
//!   pushes poses and commands into the queues; it asks the force loop for a [`Snapshot`]
//!   through a one-slot [`Mailbox`] and sends it as a state frame.
//!
//! # Faults
//!
//! Faults are latched bits in [`FAULTS`]; any latched fault (and a pen not yet calibrated)
//! keeps the motors off. Only an explicit [`Command::ClearFaults`] clears them.

pub mod bench;
pub mod force;
pub mod mailbox;

use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};

use maobi_shared::params::MAX_LAYERS;
use maobi_shared::{Brush, Fx, Layer, ParamId, Pose, Quat, Scalar, Vec3};

use crate::board::{Motors, PoseSource, Watchdog};
pub use mailbox::Mailbox;

/// Latched fault bits.
pub mod fault {
    /// Two consecutive pen poses further apart than [`super::SENSOR_JUMP_MM`].
    pub const SENSOR_JUMP: u32 = 1 << 0;
    /// A force-loop tick did not finish before the next one was due.
    pub const LOOP_OVERRUN: u32 = 1 << 1;
    /// No valid frame from the host for [`super::LINK_TIMEOUT_TICKS`] ticks.
    pub const LINK_SILENT: u32 = 1 << 2;
    /// The host set a parameter to a value the brush rejected.
    pub const PARAM_REJECTED: u32 = 1 << 3;
    /// The force loop stopped (caught by the watchdog or the supervisor task).
    pub const LOOP_STALLED: u32 = 1 << 4;
}

/// A pose step larger than this between two ticks is a sensor fault (mm). A 500 mm/s stroke
/// moves 0.5 mm per tick.
pub const SENSOR_JUMP_MM: f64 = 10.0;
/// The link is declared silent after this many ticks without a valid frame.
pub const LINK_TIMEOUT_TICKS: u32 = 100;

/// Latched faults (bits of [`fault`]). Set by anyone, cleared only by the force loop on
/// [`Command::ClearFaults`].
pub static FAULTS: AtomicU32 = AtomicU32::new(0);
/// Force-loop ticks since boot (the supervisor watches it advance).
pub static TICKS: AtomicU32 = AtomicU32::new(0);
/// The tick at which the link task last received a valid frame.
pub static LAST_RX_TICK: AtomicU32 = AtomicU32::new(0);
/// The link is supervised (after the host's handshake).
pub static LINK_ARMED: AtomicBool = AtomicBool::new(false);

/// Latches fault bits (any context).
pub fn latch(bits: u32) {
    FAULTS.fetch_or(bits, Ordering::SeqCst);
}

/// Records a valid frame from the host (link task).
#[allow(dead_code)] // TEMPORARY: the protocol link task uses it (next commit)
pub fn link_heard() {
    LAST_RX_TICK.store(TICKS.load(Ordering::Relaxed), Ordering::Relaxed);
}

/// What the link task asks of the force loop.
#[allow(dead_code)] // TEMPORARY: the protocol link task sends them (next commit)
#[derive(Copy, Clone, Debug)]
pub enum Command {
    /// Put the brush at rest at this pose and drop queued poses (start of a stroke stream).
    ResetBrush(Pose<Fx>),
    /// The pen's zero position is known: forces may be applied.
    Calibrated,
    /// Clear every latched fault (re-arms the link timer).
    ClearFaults,
    /// Test hook: burn more than one tick's time in the next tick.
    InjectOverrun,
    /// Test hook: the force loop never returns from its next tick (for the watchdog).
    Stall,
    /// Set a brush parameter (validated; a rejected value latches PARAM_REJECTED).
    SetParam(ParamId, f32),
}

/// Capacity of the virtual pen's pose queue and of the command queue.
pub const POSE_QUEUE: usize = 64;
pub const CMD_QUEUE: usize = 8;

pub type CmdQueue = heapless::spsc::Queue<Command, CMD_QUEUE>;
pub type CmdConsumer = heapless::spsc::Consumer<'static, Command>;
pub type CmdProducer = heapless::spsc::Producer<'static, Command>;

/// The state the link task reports, copied out of the force loop on request.
#[derive(Copy, Clone, Debug)]
pub struct Snapshot {
    /// Force-loop ticks since boot.
    pub tick: u32,
    /// Brush ticks since the last reset (poses consumed): tick k of the host simulation.
    pub brush_tick: u32,
    /// Ticks without a new pose (the virtual pen's queue was empty).
    pub pose_gaps: u32,
    pub faults: u32,
    pub calibrated: bool,
    /// The force model's force on the hand (N) before the output stage and the gate, and
    /// the torques applied (N·m; 0 when off).
    pub force: [Fx; 3],
    pub motors: [Fx; 3],
    pub handle: Pose<Fx>,
    pub layers_n: u8,
    pub spine: [Vec3<Fx>; MAX_LAYERS],
    pub layers: [Layer<Fx>; MAX_LAYERS],
}

impl Snapshot {
    pub const ZERO: Snapshot = Snapshot {
        tick: 0,
        brush_tick: 0,
        pose_gaps: 0,
        faults: 0,
        calibrated: false,
        force: [<Fx as Scalar>::ZERO; 3],
        motors: [<Fx as Scalar>::ZERO; 3],
        // All-zero (not the identity rotation) so the slot lives in .bss, not in flash.
        handle: Pose {
            pos: Vec3::ZERO,
            rot: Quat {
                w: <Fx as Scalar>::ZERO,
                x: <Fx as Scalar>::ZERO,
                y: <Fx as Scalar>::ZERO,
                z: <Fx as Scalar>::ZERO,
            },
        },
        layers_n: 0,
        spine: [Vec3::ZERO; MAX_LAYERS],
        layers: [Layer {
            short_axis: Vec3::ZERO,
            long_axis: Vec3::ZERO,
            long_radius: <Fx as Scalar>::ZERO,
            short_radius: <Fx as Scalar>::ZERO,
            wetness: <Fx as Scalar>::ZERO,
        }; MAX_LAYERS],
    };
}

/// The snapshot slot shared by the force loop and the link task.
pub static SNAPSHOT: Mailbox<Snapshot> = Mailbox::new(Snapshot::ZERO);

/// The force loop's state. Owned by the highest-priority context.
pub struct ForceLoop<P, M, W> {
    pub brush: Brush<Fx>,
    pen: P,
    motors: M,
    watchdog: W,
    cmds: CmdConsumer,
    brush_tick: u32,
    pose_gaps: u32,
    last_pose: Option<Pose<Fx>>,
    calibrated: bool,
    inject_overrun: bool,
    forces: force::HandForces,
    force: [Fx; 3],
    jump2: Fx,
}

impl<P: PoseSource, M: Motors, W: Watchdog> ForceLoop<P, M, W> {
    /// None if the shared force model's defaults are invalid (they are tested not to be).
    pub fn new(
        brush: Brush<Fx>,
        pen: P,
        mut motors: M,
        watchdog: W,
        cmds: CmdConsumer,
    ) -> Option<Self> {
        motors.disable();
        Some(ForceLoop {
            brush,
            pen,
            motors,
            watchdog,
            cmds,
            brush_tick: 0,
            pose_gaps: 0,
            last_pose: None,
            calibrated: false,
            inject_overrun: false,
            forces: force::HandForces::new()?,
            force: [Fx::ZERO; 3],
            jump2: Fx::from_f64(SENSOR_JUMP_MM * SENSOR_JUMP_MM),
        })
    }

    /// One 1 ms tick: commands, sensors, brush, forces, motors, snapshot.
    pub fn tick(&mut self) {
        self.watchdog.feed();
        let now = TICKS.load(Ordering::Relaxed).wrapping_add(1);
        TICKS.store(now, Ordering::Relaxed);

        while let Some(cmd) = self.cmds.dequeue() {
            self.apply(cmd);
        }
        if self.inject_overrun {
            self.inject_overrun = false;
            // Several million instructions: more than a millisecond at any -icount shift
            // the runner uses, and on any real clock.
            cortex_m::asm::delay(8_000_000);
        }

        match self.pen.next_pose() {
            Some(pose) => {
                if let Some(prev) = self.last_pose {
                    if (pose.pos - prev.pos).norm2() > self.jump2 {
                        latch(fault::SENSOR_JUMP);
                    }
                }
                self.brush.tick(pose);
                self.brush_tick = self.brush_tick.wrapping_add(1);
                self.last_pose = Some(pose);
            }
            None => self.pose_gaps = self.pose_gaps.wrapping_add(1),
        }

        if LINK_ARMED.load(Ordering::Relaxed)
            && now.wrapping_sub(LAST_RX_TICK.load(Ordering::Relaxed)) > LINK_TIMEOUT_TICKS
        {
            latch(fault::LINK_SILENT);
        }

        let allowed = self.calibrated && FAULTS.load(Ordering::SeqCst) == 0;
        let hand = self.last_pose.map(|p| p.pos).unwrap_or(Vec3::ZERO);
        let cmd = self.forces.tick(&self.brush, hand, allowed);
        let w = self.forces.wanted;
        self.force = [w.x, w.y, w.z];
        self.apply_outputs(allowed, cmd);

        SNAPSHOT.fill_if_requested(|s| self.snapshot(now, s));
    }

    /// Motors on only with a calibrated pen and no latched fault.
    fn apply_outputs(&mut self, allowed: bool, cmd: [Fx; 3]) {
        if allowed {
            let t = self.pen.torques_for(cmd);
            self.motors.command(t);
        } else {
            self.motors.disable();
        }
    }

    /// Turns the motors off now (called by the board when it detects an overrun).
    pub fn motors_off(&mut self) {
        self.motors.disable();
    }

    fn apply(&mut self, cmd: Command) {
        match cmd {
            Command::ResetBrush(pose) => {
                self.brush.reset(pose);
                self.forces.reset();
                self.brush_tick = 0;
                self.last_pose = Some(pose);
                while self.pen.next_pose().is_some() {}
            }
            Command::Calibrated => self.calibrated = true,
            Command::ClearFaults => {
                LAST_RX_TICK.store(TICKS.load(Ordering::Relaxed), Ordering::Relaxed);
                FAULTS.store(0, Ordering::SeqCst);
            }
            Command::InjectOverrun => self.inject_overrun = true,
            Command::Stall => loop {
                core::hint::spin_loop();
            },
            Command::SetParam(id, v) => {
                if self.brush.set_param(id, v).is_err() {
                    latch(fault::PARAM_REJECTED);
                }
            }
        }
    }

    fn snapshot(&self, now: u32, s: &mut Snapshot) {
        let n = self.brush.len();
        s.tick = now;
        s.brush_tick = self.brush_tick;
        s.pose_gaps = self.pose_gaps;
        s.faults = FAULTS.load(Ordering::Relaxed);
        s.calibrated = self.calibrated;
        s.force = self.force;
        s.motors = self.motors.applied();
        s.handle = self.brush.handle();
        s.layers_n = n as u8;
        s.spine[..n].copy_from_slice(self.brush.spine());
        s.layers[..n].copy_from_slice(self.brush.layers());
    }
}
