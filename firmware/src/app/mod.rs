//! The application, independent of any board: the 1 kHz force loop, the supervisor's
//! latched faults, the hand-off between the force loop and the link task, and the bench.
//!
//! # Contexts
//!
//! * The **force loop** ([`ForceLoop::tick`]) runs in the board's 1 kHz timer interrupt at
//!   the highest priority. It owns the brush. It reads commands and poses from lock-free
//!   queues, never waits for anything and never touches the link.
//! * The **link task** (thread-mode embassy executor) decodes frames from the host and
//!   pushes poses and commands into the queues; the force loop offers it a [`Snapshot`]
//!   through a one-slot [`Mailbox`] whenever a state frame is due ([`STATE_HZ`]), and the
//!   link task encodes and sends it.
//!
//! # Faults
//!
//! Faults are latched bits in [`FAULTS`]; any latched fault turns the motors off and
//! switches the host's force enable off. Only an explicit [`Command::ClearFaults`] clears
//! them; the host then enables the forces again.

/// `maobi-fw arith`: the fixed-point operators' assembly against their references.
#[cfg(feature = "board-qemu")]
pub mod arith;
#[cfg(feature = "board-qemu")]
pub mod bench;
pub mod mailbox;
// The pose of a pen with its own sensors: compiled (and checked) for every board, used by
// the physical ones.
#[cfg_attr(feature = "board-qemu", allow(dead_code, unused_imports))]
pub mod sensor_pen;
pub mod slot;
pub mod stack;

use core::mem::MaybeUninit;
use core::ptr::addr_of_mut;
use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};

use embassy_sync::waitqueue::AtomicWaker;
use maobi_shared::force::{DEFAULT_FORCES, PHANTOM_OMNI};
use maobi_shared::force_loop::{Gate, TickIn, TickParts};
use maobi_shared::guide::{GuideInput, DEFAULT_GUIDE};
use maobi_shared::pen_io::DeviceConfig;
use maobi_shared::protocol::{BrushState, Faults, Haptics, SensorReport};
use maobi_shared::{BrushParams, Fx, ParamId, Pose, Scalar, Vec3};

use crate::board::{CycleCounter, Motors, PoseSource, Watchdog};
pub use mailbox::Mailbox;
#[cfg_attr(feature = "board-qemu", allow(unused_imports))]
pub use sensor_pen::SensorPen;
pub use slot::ForceLoopSlot;

/// The link is declared silent after this many ticks without a valid frame (100 ms of
/// model time).
pub const LINK_TIMEOUT_TICKS: u32 = 100;

/// Latched faults (bits of the protocol's [`Faults`], all but [`Faults::NOT_CALIBRATED`],
/// which is not latched). Set by anyone, cleared only by the force loop on
/// [`Command::ClearFaults`].
pub static FAULTS: AtomicU32 = AtomicU32::new(0);
/// Number of latched fault bits: the protocol's [`Faults`] up to [`Faults::WATCHDOG`]
/// (the bit above, [`Faults::NOT_CALIBRATED`], is reported, not latched).
pub const LATCHED_FAULTS: usize = Faults::WATCHDOG.bits().trailing_zeros() as usize + 1;
/// The tick at which each fault bit was last raised (for the events the link task sends).
pub static FAULT_TICKS: [AtomicU32; LATCHED_FAULTS] = [const { AtomicU32::new(0) }; LATCHED_FAULTS];
/// Force-loop ticks since boot (the supervisor watches it advance).
pub static TICKS: AtomicU32 = AtomicU32::new(0);
/// Force ticks the board held on purpose ([`ForceLoop::hold`]: a lock-step board waiting for
/// the host's next pose). The loop is alive through them, so the supervisor counts them
/// with [`TICKS`]. Always 0 on a board that never holds a tick.
pub static HELD_TICKS: AtomicU32 = AtomicU32::new(0);
/// Force ticks between two looks of the [`supervisor`]: its check-in period.
pub const SUPERVISOR_TICKS: u32 = 10;
/// The shortest watchdog timeout a board may set, in force ticks: five of the supervisor's
/// check-in periods ([`SUPERVISOR_TICKS`]). The force tick feeds the watchdog only after
/// the supervisor has checked in (`SUPERVISOR_CHECKED_IN`), so two feeds can lie a whole
/// check-in period apart, plus however long thread mode keeps the supervisor waiting: behind
/// the link task's turn (the executor is cooperative) and behind every interrupt (the
/// force tick itself, the link's). The four further periods are that margin, so that a
/// busy but live thread mode never trips the watchdog; only one that stops running does.
pub const WATCHDOG_MIN_TICKS: u32 = 5 * SUPERVISOR_TICKS;
/// Set by the [`supervisor`] (thread mode) each time it runs, taken by the force tick
/// ([`ForceLoop::tick`], an interrupt), which feeds the watchdog only when it finds it set:
/// so the watchdog resets the pen when either context stops, the force loop (no tick feeds
/// it) or thread mode (starved by interrupts, or a task that never yields: no check-in). Set
/// at boot: the first feed is the boot's, before the executor has run the supervisor.
static SUPERVISOR_CHECKED_IN: AtomicBool = AtomicBool::new(true);
/// The most force ticks (taken or held) between two watchdog feeds so far, which
/// [`WATCHDOG_MIN_TICKS`] must exceed with room to spare (the supervisor reports each new
/// maximum to its board).
pub static FEED_GAP_MAX_TICKS: AtomicU32 = AtomicU32::new(0);

/// The supervisor checks in (thread mode): the next force tick may feed the watchdog.
fn supervisor_checks_in() {
    SUPERVISOR_CHECKED_IN.store(true, Ordering::Release);
}

/// Force ticks (taken or held) since the watchdog was last fed: for a board's watchdog
/// handler to tell which context stopped. About the whole timeout ([`WATCHDOG_MIN_TICKS`])
/// when the watchdog fires: the force loop ticked on while thread mode never checked in;
/// far less: the force loop itself stopped (which stops thread mode too, below it).
static TICKS_UNFED: AtomicU32 = AtomicU32::new(0);

/// Whether the watchdog, firing now, was starved by thread mode rather than by the force
/// loop: the force loop ticked on unfed for more than half the timeout (`TICKS_UNFED`).
#[cfg_attr(not(feature = "board-qemu"), allow(dead_code))] // QEMU's watchdog handler
pub fn thread_mode_starved_the_watchdog() -> bool {
    TICKS_UNFED.load(Ordering::Relaxed) > WATCHDOG_MIN_TICKS / 2
}

/// The tick at which the link task last received a valid frame.
pub static LAST_RX_TICK: AtomicU32 = AtomicU32::new(0);
/// The link is supervised (after the host's handshake).
pub static LINK_ARMED: AtomicBool = AtomicBool::new(false);
/// The host's switch for the motors (off at boot, and after any fault latches).
pub static FORCES_ENABLED: AtomicBool = AtomicBool::new(false);
/// Commands the force loop has applied (the link task waits for its own to be applied).
pub static CMDS_APPLIED: AtomicU32 = AtomicU32::new(0);
/// State snapshots that fell due while the previous one was still with the link task.
pub static STATES_MISSED: AtomicU32 = AtomicU32::new(0);
/// State frames are due at this rate of force-loop ticks (1000: every tick).
pub static STATE_HZ: AtomicU32 = AtomicU32::new(120);
/// A valid configuration is in force, calibrated or not (set by the link task with
/// [`CONFIG_OK`]; the Black Pill's fault LED tells "no configuration" from "not calibrated"
/// by it).
#[cfg_attr(feature = "board-qemu", allow(dead_code))] // read by the Black Pill's LED
pub static CONFIG_VALID: AtomicBool = AtomicBool::new(false);

/// The board is stalling the force loop on purpose, with the motors off (writing its
/// configuration to flash, which the core cannot read meanwhile): the supervisor and the
/// overrun check do not count the pause, and the motors stay off until it ends.
pub static MAINTENANCE: AtomicBool = AtomicBool::new(false);

/// A deliberate pause of the force loop ([`MAINTENANCE`]) for as long as the value lives.
#[cfg_attr(feature = "board-qemu", allow(dead_code))] // boards with a flash store
pub struct Maintenance(());

#[cfg_attr(feature = "board-qemu", allow(dead_code))]
impl Maintenance {
    /// Turns the motors off (`motors_off`, the board's any-context switch) and marks the
    /// pause until the returned value is dropped.
    pub fn begin(motors_off: fn()) -> Self {
        MAINTENANCE.store(true, Ordering::SeqCst);
        motors_off();
        Maintenance(())
    }
}

impl Drop for Maintenance {
    fn drop(&mut self) {
        // The ticks that fell due meanwhile ran late once; the supervisor starts afresh.
        MAINTENANCE.store(false, Ordering::SeqCst);
    }
}

/// Woken by the force loop when it has filled the snapshot slot.
pub static SNAPSHOT_WAKER: AtomicWaker = AtomicWaker::new();
/// The stored configuration lets the motors be driven (set by the link task: a valid
/// configuration whose zeros hold, or none needed; `pen_io::Readiness::allows_forces`). Off
/// at boot until the link task has loaded the store: the pen starts safe. The force loop
/// drives the motors only while it is set.
pub static CONFIG_OK: AtomicBool = AtomicBool::new(false);
/// The configuration in force, for [`Command::Configure`]: written by the link task before
/// it sends the command, read by the force loop when it applies it.
pub static CONFIG: critical_section::Mutex<core::cell::Cell<DeviceConfig>> =
    critical_section::Mutex::new(core::cell::Cell::new(DeviceConfig::DEFAULT));
/// Raw sensor readings for bring-up: the link task requests, the force loop fills it at the
/// next tick from [`PoseSource::raw_sensors`] (`None`: the board cannot tell).
pub static SENSORS: Mailbox<Option<SensorReport>> = Mailbox::new(None);

/// The pen lacks zeros that hold (`pen_io::Readiness::not_calibrated`, set by the link task
/// with [`CONFIG_OK`]): no configuration, none calibrated, or (incremental encoders) not
/// calibrated since power-on. Set at boot until the link task has loaded the store.
/// Reported as [`Faults::NOT_CALIBRATED`] until `Calibrate` succeeds; `ClearFaults` does not
/// clear it (its cause is not gone). [`CONFIG_OK`], not this flag, keeps the motors off.
pub static NOT_CALIBRATED: AtomicBool = AtomicBool::new(true);

/// The fault bits the host is told about: the latched [`FAULTS`] and, while it lasts,
/// [`Faults::NOT_CALIBRATED`].
pub fn reported_faults() -> u32 {
    let not_calibrated = if NOT_CALIBRATED.load(Ordering::SeqCst) {
        u32::from(Faults::NOT_CALIBRATED.bits())
    } else {
        0
    };
    FAULTS.load(Ordering::SeqCst) | not_calibrated
}

/// Latches faults (any context) and notes the tick of the newly raised ones.
pub fn latch(faults: Faults) {
    let bits = u32::from(faults.bits());
    let old = FAULTS.fetch_or(bits, Ordering::SeqCst);
    let new = bits & !old;
    let now = TICKS.load(Ordering::Relaxed);
    for (i, t) in FAULT_TICKS.iter().enumerate() {
        if new & (1 << i) != 0 {
            t.store(now, Ordering::Relaxed);
        }
    }
}

/// Records a valid frame from the host (link task).
pub fn link_heard() {
    LAST_RX_TICK.store(TICKS.load(Ordering::Relaxed), Ordering::Relaxed);
}

/// Force-loop timing, kept by the board around each tick (us) and read out by the link
/// task for telemetry.
pub mod timing {
    use core::sync::atomic::{AtomicU32, Ordering};

    static MIN: AtomicU32 = AtomicU32::new(u32::MAX);
    static MAX: AtomicU32 = AtomicU32::new(0);
    static SUM: AtomicU32 = AtomicU32::new(0);
    static BUSY: AtomicU32 = AtomicU32::new(0);
    static BUSY_MAX_US: AtomicU32 = AtomicU32::new(0);
    static BUSY_MAX_COUNTS: AtomicU32 = AtomicU32::new(0);
    static COUNT: AtomicU32 = AtomicU32::new(0);

    /// One tick: `period_us` since the previous tick's start, `busy_us` spent in it
    /// (`busy_counts` in the board's counter).
    pub fn record(period_us: u32, busy_us: u32, busy_counts: u32) {
        MIN.fetch_min(period_us, Ordering::Relaxed);
        MAX.fetch_max(period_us, Ordering::Relaxed);
        SUM.fetch_add(period_us, Ordering::Relaxed);
        BUSY.fetch_add(busy_us, Ordering::Relaxed);
        BUSY_MAX_US.fetch_max(busy_us, Ordering::Relaxed);
        BUSY_MAX_COUNTS.fetch_max(busy_counts, Ordering::Relaxed);
        COUNT.fetch_add(1, Ordering::Relaxed);
    }

    /// The ticks since the last [`take`].
    #[derive(Copy, Clone, Debug, Default)]
    pub struct Period {
        pub min_us: u32,
        pub mean_us: u32,
        pub max_us: u32,
        /// Work over time (%).
        pub load_percent: u8,
        pub busy_max_us: u32,
        pub busy_max_counts: u32,
    }

    /// What was recorded since the last call, and restarts.
    pub fn take() -> Period {
        let (min, max, sum, busy, busy_max_us, busy_max_counts, n) = critical_section::with(|_| {
            (
                MIN.swap(u32::MAX, Ordering::Relaxed),
                MAX.swap(0, Ordering::Relaxed),
                SUM.swap(0, Ordering::Relaxed),
                BUSY.swap(0, Ordering::Relaxed),
                BUSY_MAX_US.swap(0, Ordering::Relaxed),
                BUSY_MAX_COUNTS.swap(0, Ordering::Relaxed),
                COUNT.swap(0, Ordering::Relaxed),
            )
        });
        if n == 0 || sum == 0 {
            return Period::default();
        }
        Period {
            min_us: min,
            mean_us: sum / n,
            max_us: max,
            load_percent: (u64::from(busy) * 100 / u64::from(sum)).min(100) as u8,
            busy_max_us,
            busy_max_counts,
        }
    }
}

/// What the link task asks of the force loop.
#[allow(clippy::large_enum_variant)] // a few of them in a queue; no allocator to box
#[derive(Copy, Clone, Debug)]
pub enum Command {
    /// Put the brush at rest at its current pose (the protocol's `ResetBrush`); the next pose
    /// sample ticks it from there, as the host's simulators tick the first pose after their
    /// reset. (A new stream after a hello is [`Command::Reanchor`]'s.)
    ResetBrush,
    /// The next pose sample places the brush at rest there instead of dragging it (sent by
    /// the link task after a handshake).
    Reanchor,
    /// The host's switch: motors may be driven (while no fault is latched).
    EnableForces,
    DisableForces,
    /// Clear every latched fault (re-arms the link timer).
    ClearFaults,
    /// Test hook: the next tick runs on until the following one falls due (by the board's
    /// own tick timer), one overrun.
    #[cfg(feature = "test-hooks")]
    InjectOverrun,
    /// Test hook: the force loop never returns from its next tick (for the watchdog).
    #[cfg(feature = "test-hooks")]
    #[cfg_attr(not(feature = "board-qemu"), allow(dead_code))] // QEMU's crash test
    Stall,
    /// Set a brush parameter (validated by the link task; a rejection here latches
    /// PARAM_REJECTED).
    SetParam(ParamId, f32),
    /// Replace every parameter (a preset) and put the brush at rest at its current pose.
    SetParams(BrushParams),
    /// Wet every layer (`Brush::dip`).
    Dip(Fx),
    /// A new stored configuration is in force: the pen and the motors take it from
    /// [`CONFIG`] (sent by the link task at boot and after a write, with forces off). The
    /// configuration travels through that slot, not in the command, so that every queued
    /// command does not grow to the size of a whole `DeviceConfig`.
    Configure,
    /// Drive one motor with `torque_nm` for `ticks` ticks while forces are off (bring-up);
    /// the motors are off again afterwards. Checked by the link task (caps, forces off,
    /// configuration); cancelled by `EnableForces` and by any fault.
    Nudge {
        channel: usize,
        torque_nm: Fx,
        ticks: u32,
    },
}

/// A pose sample as the link task queues it for the virtual pen, with the guide sample the
/// host sent for the same tick (guided writing), if any.
#[cfg_attr(not(feature = "board-qemu"), allow(dead_code))] // the virtual pen's
#[derive(Copy, Clone, Debug)]
pub struct PoseIn {
    pub seq: u32,
    pub pose: Pose<Fx>,
    pub guide: Option<GuideInput<Fx>>,
}

/// Length of the virtual pen's pose queue and of the command queue (`heapless::spsc`
/// queues hold one fewer than their length). The pose queue holds the protocol's
/// [`POSES_IN_FLIGHT`](maobi_shared::protocol::POSES_IN_FLIGHT), all a host may send ahead,
/// and no more: each slot is 96 bytes of RAM.
#[cfg_attr(not(feature = "board-qemu"), allow(dead_code))] // the virtual pen's
pub const POSE_QUEUE: usize = maobi_shared::protocol::POSES_IN_FLIGHT as usize + 1;
pub const CMD_QUEUE: usize = 8;

pub type CmdQueue = heapless::spsc::Queue<Command, CMD_QUEUE>;
pub type CmdConsumer = heapless::spsc::Consumer<'static, Command>;
pub type CmdProducer = heapless::spsc::Producer<'static, Command>;

/// The poses (and guide samples) the host sent for a virtual pen.
#[cfg_attr(not(feature = "board-qemu"), allow(dead_code))]
pub type PoseQueue = heapless::spsc::Queue<PoseIn, POSE_QUEUE>;
pub type PoseProducer = heapless::spsc::Producer<'static, PoseIn>;
#[cfg_attr(not(feature = "board-qemu"), allow(dead_code))]
pub type PoseConsumer = heapless::spsc::Consumer<'static, PoseIn>;

/// The state the link task reports, built by the force loop when a state frame is due (or
/// when the link task asks).
///
/// It holds the frame's [`BrushState`], not a copy of the brush (about twice its size): the
/// state is what the frame carries, so the link task encodes it as it is. Building it costs
/// the force loop about what copying the brush did (`BrushState::from_brush` reads the
/// brush's positions and ellipses, computes nothing).
#[derive(Clone, Debug)]
pub struct Snapshot {
    /// Brush ticks since the last reset (poses consumed).
    pub brush_tick: u32,
    /// Ticks without a new pose (the virtual pen's queue was empty).
    pub pose_gaps: u32,
    /// The state frame of this tick: force-loop tick, the `seq` of the last pose sample the
    /// brush consumed (0 with real sensors), haptics (the force model's force before the
    /// output stage and the gate, the torques applied, 0 when off; whether the motors were
    /// driven), latched faults, and the brush.
    pub state: BrushState,
}

impl Snapshot {
    /// All zero bytes, so the slot lives in `.bss` and costs no flash. Never sent: the slot
    /// is read only after the force loop has filled it.
    pub const EMPTY: Snapshot = Snapshot {
        brush_tick: 0,
        pose_gaps: 0,
        state: BrushState::EMPTY,
    };
}

/// The snapshot slot shared by the force loop and the link task.
pub static SNAPSHOT: Mailbox<Snapshot> = Mailbox::new(Snapshot::EMPTY);

/// Whether a state frame falls due at tick `now` at `hz` per 1000 ticks.
pub fn state_due(now: u32, hz: u32) -> bool {
    let hz = u64::from(hz.clamp(1, 1000));
    let n = u64::from(now);
    n * hz / 1000 != n.wrapping_sub(1) * hz / 1000 || n == 0
}

/// The parts of the shared loop's tick built here, for size ([`TickParts`]): the guide's
/// tick and the brush's reset, the same copies the commands use.
const PARTS: TickParts<Fx> = TickParts::here();

/// The force loop's state. Owned by the highest-priority context.
///
/// The brush, the force model, the guide, the output stage and the sensor-jump check are
/// the shared [`maobi_shared::ForceLoop`] (`core`), the same loop the host's simulators and
/// its mirror of this firmware run; what is the board's and the executor's is here: the pen,
/// the motors, the watchdog, the command queue, the latched faults and the forces switch it
/// turns into the core's gate, the snapshot, a bring-up nudge.
pub struct ForceLoop<P, M, W> {
    pub core: maobi_shared::ForceLoop<Fx>,
    pen: P,
    motors: M,
    watchdog: W,
    cmds: CmdConsumer,
    pose_gaps: u32,
    /// [`Command::InjectOverrun`] arrived: [`run_tick`] overruns this tick.
    #[cfg(feature = "test-hooks")]
    inject_overrun: bool,
    /// The wanted force of the last tick (the state frame's `haptics.force_n`).
    force: [Fx; 3],
    enabled: bool,
    /// A bring-up nudge in progress: the torques and the ticks left.
    nudge: Option<([Fx; 3], u32)>,
    /// The last tick stood by ([`Self::stand_by`]): the brush did not follow the pen.
    stood_by: bool,
}

impl<P: PoseSource, M: Motors, W: Watchdog> ForceLoop<P, M, W> {
    /// None if the parameters or the shared force model's defaults are invalid (they are
    /// tested not to be). The boards build theirs in place ([`Self::new_in`]); the bench
    /// builds one here.
    #[cfg_attr(not(feature = "board-qemu"), allow(dead_code))]
    pub fn new(
        params: BrushParams,
        pose: Pose<Fx>,
        pen: P,
        motors: M,
        watchdog: W,
        cmds: CmdConsumer,
    ) -> Option<Self> {
        let mut slot = MaybeUninit::<Self>::uninit();
        Self::new_in(&mut slot, params, pose, pen, motors, watchdog, cmds)?;
        // SAFETY: `new_in` returned `Some`, so it initialised the whole slot.
        Some(unsafe { slot.assume_init() })
    }

    /// [`Self::new`] with the brush built from `params` at `pose`, all of it built in `slot`
    /// (a static's storage): the force loop is kilobytes (its brush most of it), and moving
    /// it through the stack costs the board at boot in stack it must reserve. None if the
    /// parameters or the force model's defaults are invalid.
    pub fn new_in(
        slot: &mut MaybeUninit<Self>,
        params: BrushParams,
        pose: Pose<Fx>,
        pen: P,
        motors: M,
        watchdog: W,
        cmds: CmdConsumer,
    ) -> Option<&mut Self> {
        let p = slot.as_mut_ptr();
        // SAFETY: the `core` field of the slot's storage, seen as the uninitialised loop it
        // is (`MaybeUninit<T>` has `T`'s layout); `init_rest` writes all the other fields, so
        // the whole slot is initialised when it is assumed to be.
        unsafe {
            let core =
                &mut *addr_of_mut!((*p).core).cast::<MaybeUninit<maobi_shared::ForceLoop<Fx>>>();
            maobi_shared::ForceLoop::new_in(
                core,
                params,
                pose,
                DEFAULT_FORCES,
                PHANTOM_OMNI,
                DEFAULT_GUIDE,
            )
            .ok()?;
            Self::init_rest(p, pen, motors, watchdog, cmds);
            Some(slot.assume_init_mut())
        }
    }

    /// Writes every field but the core, the motors disabled.
    ///
    /// # Safety
    /// `p` points to storage for a force loop, valid for writes.
    unsafe fn init_rest(p: *mut Self, pen: P, mut motors: M, watchdog: W, cmds: CmdConsumer) {
        motors.disable();
        // SAFETY: fields of the storage the caller vouches for.
        unsafe {
            addr_of_mut!((*p).pen).write(pen);
            addr_of_mut!((*p).motors).write(motors);
            addr_of_mut!((*p).watchdog).write(watchdog);
            addr_of_mut!((*p).cmds).write(cmds);
            addr_of_mut!((*p).pose_gaps).write(0);
            #[cfg(feature = "test-hooks")]
            addr_of_mut!((*p).inject_overrun).write(false);
            addr_of_mut!((*p).force).write([Fx::ZERO; 3]);
            addr_of_mut!((*p).enabled).write(false);
            addr_of_mut!((*p).nudge).write(None);
            addr_of_mut!((*p).stood_by).write(false);
        }
        // The list above is complete: this pattern names every field (no `..`), so a field
        // added to `ForceLoop` does not compile until it is written here too.
        #[allow(clippy::no_effect_underscore_binding)]
        let _every_field = |f: Self| {
            let ForceLoop {
                core: _,
                pen: _,
                motors: _,
                watchdog: _,
                cmds: _,
                pose_gaps: _,
                #[cfg(feature = "test-hooks")]
                    inject_overrun: _,
                force: _,
                enabled: _,
                nudge: _,
                stood_by: _,
            } = f;
        };
    }

    /// The pen the loop reads (a board's lock-step check looks whether a pose is waiting).
    #[cfg_attr(not(feature = "board-qemu"), allow(dead_code))] // QEMU's lock-step mode
    pub fn pen(&self) -> &P {
        &self.pen
    }

    /// The next pose places the brush at rest there (a board whose sensors start the pen
    /// somewhere unknown asks for this at boot).
    #[cfg_attr(feature = "board-qemu", allow(dead_code))] // physical boards
    pub fn reanchor(&mut self) {
        self.core.reanchor();
    }

    /// One 1 ms tick, in this order on every board: feed the watchdog, apply the link's
    /// commands, **read the sensors** (`PoseSource::next_pose`), run the shared loop's tick
    /// (brush, forces, guide, output stage), **write the motors** (`Motors::command` or
    /// `disable`), offer the snapshot.
    pub fn tick(&mut self) {
        self.feed_watchdog();
        let now = TICKS.load(Ordering::Relaxed).wrapping_add(1);
        TICKS.store(now, Ordering::Relaxed);

        let rebuilt = self.apply_commands();
        if LINK_ARMED.load(Ordering::Relaxed)
            && now.wrapping_sub(LAST_RX_TICK.load(Ordering::Relaxed)) > LINK_TIMEOUT_TICKS
        {
            latch(Faults::LINK_SILENT);
        }
        if FAULTS.load(Ordering::SeqCst) & u32::from(Faults::LOOP_OVERRUN.bits()) != 0 {
            self.stand_by(now);
            return;
        }
        if core::mem::take(&mut self.stood_by) {
            // The pen moved on while the brush stood: it starts again at rest where the pen
            // is now, not dragged across the gap (which would read as a sensor jump).
            self.core.reanchor();
        }

        // A tick that rebuilt the brush from new parameters takes no pose: rebuilding costs
        // about a brush step, and both in one tick would overrun it. The pen's pose waits
        // for the next tick (a virtual pen's stays queued), where the brush steps to it.
        let pose = if rebuilt { None } else { self.pen.next_pose() };
        if pose.is_some() {
            BRUSH_TICKS.fetch_add(1, Ordering::Relaxed);
        } else if !rebuilt {
            self.pose_gaps = self.pose_gaps.wrapping_add(1);
        }

        // The gate: the host's switch, no latched fault, a configuration that allows forces,
        // no deliberate pause (a flash write). A fault the core raises this tick (a sensor
        // jump) closes it for this tick too, and latches below.
        let faulted = FAULTS.load(Ordering::SeqCst) != 0;
        let gate = Gate {
            allowed: FORCES_ENABLED.load(Ordering::SeqCst)
                && !faulted
                && CONFIG_OK.load(Ordering::SeqCst)
                && !MAINTENANCE.load(Ordering::SeqCst),
            faulted,
        };
        // The guide sample that came with this tick's pose (none on a gap tick).
        let guide = self.pen.take_guide();
        let out = maobi_fast::force_loop_tick(&mut self.core, TickIn { pose, guide, gate }, &PARTS);
        if !out.faults.is_empty() {
            latch(out.faults);
        }

        // Any latched fault switches the forces off (and ends a nudge): the host must clear
        // it and enable again. So does a configuration that does not allow forces (missing,
        // invalid, not calibrated): a nudge that was running when such a configuration came
        // into force ends too, since nothing else ends it on a board whose store writes
        // without a pause.
        if FAULTS.load(Ordering::SeqCst) != 0 || !CONFIG_OK.load(Ordering::SeqCst) {
            FORCES_ENABLED.store(false, Ordering::SeqCst);
            self.nudge = None;
        }
        let allowed = gate.allowed && out.faults.is_empty();
        let w = out.wanted;
        self.force = [w.x, w.y, w.z];
        let c = out.command;
        self.apply_outputs(allowed, [c.x, c.y, c.z]);
        self.enabled = allowed;

        self.offer_readings(now);
    }

    /// A tick while an overrun is latched: the brush does not tick (the work that overran),
    /// the motors are off and stay off, and everything else goes on: the watchdog, the link
    /// task's commands (a `ClearFaults` ends the stand-by at the next tick), the sensor
    /// readings and the state frames that report the fault. So an overrun costs the brush,
    /// never the link: the pen is never left unreachable by the work it was asked to do.
    fn stand_by(&mut self, now: u32) {
        self.pen.skip_pose();
        self.stood_by = true;
        FORCES_ENABLED.store(false, Ordering::SeqCst);
        self.nudge = None;
        self.motors.disable();
        self.enabled = false;
        self.force = [Fx::ZERO; 3];
        self.offer_readings(now);
    }

    /// The tick's sensor reading and, when one falls due, its state, for the link task.
    fn offer_readings(&mut self, now: u32) {
        if SENSORS.offer(false, |s| *s = self.pen.raw_sensors(now)) {
            SNAPSHOT_WAKER.wake();
        }

        let due = state_due(now, STATE_HZ.load(Ordering::Relaxed));
        if SNAPSHOT.offer(due, |s| self.snapshot(now, s)) {
            SNAPSHOT_WAKER.wake();
        } else if due {
            STATES_MISSED.fetch_add(1, Ordering::Relaxed);
        }
    }

    /// A tick the board does not take (a lock-step board whose host has not sent the next
    /// pose yet, `crate::qemu`): the loop stays alive (the watchdog fed, the hold counted in
    /// [`HELD_TICKS`] for the supervisor) and serves the link task (its commands applied,
    /// a requested sensor reading given), but the tick counter, the brush, the forces and the
    /// motors stay as the last tick left them, and no state falls due. So a command never
    /// waits for a pose, and the brush advances exactly once per pose.
    #[cfg_attr(not(feature = "board-qemu"), allow(dead_code))] // QEMU's lock-step mode
    pub fn hold(&mut self) {
        self.feed_watchdog();
        HELD_TICKS.fetch_add(1, Ordering::Relaxed);
        self.apply_commands();
        let now = TICKS.load(Ordering::Relaxed);
        if SENSORS.offer(false, |s| *s = self.pen.raw_sensors(now)) {
            SNAPSHOT_WAKER.wake();
        }
    }

    /// Feeds the watchdog if the supervisor has checked in since the last feed, and takes the
    /// check-in: every board's only path to its watchdog, so that a stopped thread mode
    /// resets the pen as a stopped force loop does.
    fn feed_watchdog(&mut self) {
        // Only this context writes it: a load and a store, no read-modify-write needed.
        let unfed = TICKS_UNFED.load(Ordering::Relaxed).saturating_add(1);
        if SUPERVISOR_CHECKED_IN.swap(false, Ordering::AcqRel) {
            self.watchdog.feed();
            FEED_GAP_MAX_TICKS.fetch_max(unfed, Ordering::Relaxed);
            TICKS_UNFED.store(0, Ordering::Relaxed);
        } else {
            TICKS_UNFED.store(unfed, Ordering::Relaxed);
        }
    }

    /// Applies every command the link task has queued, in order.
    /// Returns whether one of them rebuilt the brush (new parameters): that work takes the
    /// place of the brush's step in this tick (see [`Self::tick`]).
    fn apply_commands(&mut self) -> bool {
        let mut rebuilt = false;
        while let Some(cmd) = self.cmds.dequeue() {
            rebuilt |= matches!(cmd, Command::SetParam(..) | Command::SetParams(_));
            self.apply(cmd);
            CMDS_APPLIED.fetch_add(1, Ordering::Release);
        }
        rebuilt
    }

    /// Motors on only while the host has enabled them and no fault is latched, or for a
    /// bring-up nudge (forces off) until it runs out; a deliberate pause
    /// ([`MAINTENANCE`]) ends a nudge too.
    fn apply_outputs(&mut self, allowed: bool, cmd: [Fx; 3]) {
        if MAINTENANCE.load(Ordering::SeqCst) {
            self.nudge = None;
        }
        if allowed {
            self.nudge = None;
            let t = self.pen.torques_for(cmd);
            self.motors.command(t);
        } else if let Some((torque, left)) = self.nudge {
            self.motors.command(torque);
            self.nudge = left.checked_sub(1).filter(|&l| l > 0).map(|l| (torque, l));
        } else {
            self.motors.disable();
        }
    }

    /// Turns the motors off now (called by the board when it detects an overrun).
    pub fn motors_off(&mut self) {
        self.nudge = None;
        self.motors.disable();
        FORCES_ENABLED.store(false, Ordering::SeqCst);
    }

    fn apply(&mut self, cmd: Command) {
        match cmd {
            Command::ResetBrush => {
                let pose = match self.core.last_pose() {
                    Some(p) => p,
                    None => self.core.brush().handle(),
                };
                self.core.reset_brush(pose);
            }
            Command::Reanchor => self.core.reanchor(),
            Command::EnableForces => {
                if FAULTS.load(Ordering::SeqCst) == 0 && CONFIG_OK.load(Ordering::SeqCst) {
                    FORCES_ENABLED.store(true, Ordering::SeqCst);
                }
            }
            Command::DisableForces => FORCES_ENABLED.store(false, Ordering::SeqCst),
            Command::ClearFaults => {
                LAST_RX_TICK.store(TICKS.load(Ordering::Relaxed), Ordering::Relaxed);
                FAULTS.store(0, Ordering::SeqCst);
            }
            #[cfg(feature = "test-hooks")]
            Command::InjectOverrun => self.inject_overrun = true,
            #[cfg(feature = "test-hooks")]
            Command::Stall => loop {
                core::hint::spin_loop();
            },
            Command::SetParam(id, v) => {
                if self.core.brush_mut().set_param(id, v).is_err() {
                    latch(Faults::PARAM_REJECTED);
                }
            }
            Command::SetParams(p) => {
                if self.core.set_params(p).is_err() {
                    latch(Faults::PARAM_REJECTED);
                }
            }
            Command::Dip(w) => self.core.brush_mut().dip(w),
            Command::Configure => {
                let cfg = critical_section::with(|cs| CONFIG.borrow(cs).get());
                self.motors.disable();
                self.pen.configure(&cfg);
                self.motors.configure(&cfg);
                // The link task validated the whole configuration before storing it, so
                // its limits are accepted; if not, the old ones stay and nothing is driven
                // beyond them.
                let _ = self.core.set_limits(cfg.limits);
                if P::POSES_FOLLOW_CONFIG {
                    // New geometry or zeros move the pose at once: not a sensor jump, and
                    // the brush starts at rest where the pen now says it is.
                    self.core.reanchor();
                    self.core.forget_pose();
                }
            }
            Command::Nudge {
                channel,
                torque_nm,
                ticks,
            } => {
                let mut torque = [Fx::ZERO; 3];
                if let Some(t) = torque.get_mut(channel) {
                    *t = torque_nm;
                }
                if !FORCES_ENABLED.load(Ordering::SeqCst) && ticks > 0 {
                    self.nudge = Some((torque, ticks));
                }
            }
        }
    }

    fn snapshot(&self, now: u32, s: &mut Snapshot) {
        s.brush_tick = self.core.brush_ticks();
        s.pose_gaps = self.pose_gaps;
        let f = self.force;
        let haptics = Haptics::new(
            Vec3::new(f[0], f[1], f[2]),
            self.motors.applied(),
            self.enabled,
        );
        let faults = Faults::from_bits_retain(reported_faults() as u16);
        // In place: the slot is a static, so a `BrushState` built and then moved there would
        // be a temporary of the state's whole size on the force-tick interrupt's stack.
        s.state
            .fill_from_brush(self.core.brush(), now, self.pen.pose_seq(), haptics, faults);
    }
}

/// The board's force-tick interrupt, the same on every board: runs one [`ForceLoop::tick`],
/// records its period and busy time with the board's counter (`counts_per_us` counts per
/// microsecond), and if `overran()` says the next tick fell due meanwhile, counts the
/// overrun, latches [`Faults::LOOP_OVERRUN`] and turns the motors off.
pub fn run_tick<P: PoseSource, M: Motors, W: Watchdog, C: CycleCounter>(
    fl: &mut ForceLoop<P, M, W>,
    clock: &C,
    counts_per_us: u32,
    overran: impl Fn() -> bool,
) {
    static LAST_TICK_START: AtomicU32 = AtomicU32::new(0);
    let start = clock.now();
    fl.tick();
    // An injected overrun runs on until the board's own tick timer says the next tick is
    // due, and no further: one overrun whatever the clock (any `-icount` shift, any core
    // clock), never long enough to look like a stopped loop to the watchdog. The timer runs
    // on its own, so this ends; were it ever to stop, the watchdog is what catches that.
    #[cfg(feature = "test-hooks")]
    if core::mem::take(&mut fl.inject_overrun) {
        while !overran() {
            core::hint::spin_loop();
        }
    }
    let end = clock.now();
    let last = LAST_TICK_START.swap(start, Ordering::Relaxed);
    if last != 0 {
        let busy = end.wrapping_sub(start);
        timing::record(
            start.wrapping_sub(last) / counts_per_us,
            busy / counts_per_us,
            busy,
        );
    }
    // A pause the board made on purpose (motors off) is not an overrun.
    if overran() && !MAINTENANCE.load(Ordering::SeqCst) {
        OVERRUNS.fetch_add(1, Ordering::Relaxed);
        latch(Faults::LOOP_OVERRUN);
        fl.motors_off();
    }
}

/// Force-loop ticks that overran (each also latched [`Faults::LOOP_OVERRUN`]).
pub static OVERRUNS: AtomicU32 = AtomicU32::new(0);

/// Force-loop ticks in which the brush took a pose (telemetry's `brush_ticks`).
pub static BRUSH_TICKS: AtomicU32 = AtomicU32::new(0);

/// Watches the force loop from below: if its tick count (ticks taken, and ticks held on
/// purpose: [`HELD_TICKS`]) stops advancing (its timer stopped,
/// or it never returns while the watchdog is somehow not firing), `motors_off` runs and the
/// fault latches. Spawned by every board with its own `motors_off`.
///
/// It is also thread mode's proof of life: every time it runs it checks in
/// (`SUPERVISOR_CHECKED_IN`), and the force tick feeds the watchdog only after a check-in.
/// A thread mode that stops running (a task that never yields, interrupts that leave it no
/// time) stops the feeding, and the watchdog resets the pen into its safe state.
///
/// It looks every [`SUPERVISOR_TICKS`] ticks (10 ms at 1 kHz; longer when the loop is paced
/// slower under emulation, so that one deliberately overrun tick reads as an overrun, not a
/// stall). Every 100 looks it also reads the stack's high-water mark ([`stack`]) and hands
/// each new maximum to the board's `report_stack`, and hands each new longest gap between
/// two watchdog feeds ([`FEED_GAP_MAX_TICKS`], in ticks) to `report_feed_gap`.
#[embassy_executor::task]
pub async fn supervisor(
    tick_us: u32,
    motors_off: fn(),
    report_stack: fn(usize),
    report_feed_gap: fn(u32),
) {
    supervisor_checks_in();
    let period =
        embassy_time::Duration::from_micros(u64::from(tick_us) * u64::from(SUPERVISOR_TICKS));
    let mut last = TICKS
        .load(Ordering::Relaxed)
        .wrapping_add(HELD_TICKS.load(Ordering::Relaxed));
    let mut ticker = embassy_time::Ticker::every(period);
    let mut last_look = embassy_time::Instant::now();
    let mut looks: u32 = 0;
    let mut feed_gap_reported = 0;
    loop {
        ticker.next().await;
        // Thread mode runs: the force tick may feed the watchdog again.
        supervisor_checks_in();
        // After the executor was held up (a flash write), the ticker fires its missed
        // periods back to back: judge once per real period, not on each catch-up.
        let t = embassy_time::Instant::now();
        if t - last_look < period / 2 {
            continue;
        }
        last_look = t;
        // A tick the board held on purpose (lock-step) is a live loop too.
        let now = TICKS
            .load(Ordering::Relaxed)
            .wrapping_add(HELD_TICKS.load(Ordering::Relaxed));
        if now == last && !MAINTENANCE.load(Ordering::SeqCst) {
            motors_off();
            latch(Faults::WATCHDOG);
        }
        last = now;
        looks = looks.wrapping_add(1);
        if looks % 100 == 1 {
            if let Some(used) = stack::new_high_water() {
                report_stack(used);
            }
            let gap = FEED_GAP_MAX_TICKS.load(Ordering::Relaxed);
            if gap > feed_gap_reported {
                feed_gap_reported = gap;
                report_feed_gap(gap);
            }
        }
    }
}
