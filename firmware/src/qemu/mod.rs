//! The QEMU board: `qemu-system-arm -machine mps2-an386 -cpu cortex-m4`.
//!
//! | what | where | priority |
//! |---|---|---|
//! | watchdog: TIMER1 counting down [`app::WATCHDOG_MIN_TICKS`] tick periods, reloaded by a force tick after the supervisor has checked in | 0x4000_1000, IRQ 9 | 0 (highest) |
//! | force loop: TIMER0 at 1 kHz | 0x4000_0000, IRQ 8 | 1 |
//! | link: UART0 RX / TX | 0x4000_4000, IRQ 0 / 1 | 2 |
//! | embassy time driver: dual timer | 0x4000_2000, IRQ 10 | 3 |
//! | thread-mode executor (WFI when idle) | | thread |
//! | configuration store: RAM the host preloads ([`config_store`]) | 0x2100_0000, 4 KiB of PSRAM | (used by the link task) |
//!
//! The pen is virtual: its poses come from the host's PoseSamples through a queue
//! ([`VirtualPen`]); the motor commands are not sent anywhere but reported back in the
//! state frames ([`ReportedMotors`]). Its raw sensor readings (bring-up's
//! `StreamSensors`) are synthesised from the latest pose through the reference pen's
//! inverse kinematics ([`VirtualPen`]). The configuration store is a RAM region the host
//! can preload with QEMU's generic loader at [`config_store::CONFIG_REGION`]
//! (`-device loader,file=cfg.bin,addr=0x21000000`; see [`config_store`]).
//!
//! # Lock-step
//!
//! Booted with `lockstep` (see [`boot`]), the force loop ticks exactly once per pose the
//! host sends, and every tick's state reaches the host whole, whatever the pace of QEMU and
//! of the host. TIMER0 still interrupts every `tick_us`, but a tick is taken only when the
//! host's next pose is queued, the state of the previous tick has left the snapshot slot,
//! and the UART's transmit ring is empty (so the link task has room to send that state:
//! two state frames fit the ring); otherwise the tick is held ([`app::ForceLoop::hold`]: the
//! link's commands are applied and the watchdog fed, but the brush, the tick count and the
//! forces wait). Why here: the emulated pen otherwise ticks on QEMU's own clock and, like a
//! real pen, holds its last pose on a tick no pose reached, and drops a state the link task
//! has not taken in time, while the host's in-process simulator ticks once per pose; a
//! comparison of the two then depends on how fast each side ran. The host-side alternative
//! (waiting for every state by sequence number) cannot take back a tick the pen already ran
//! on a held pose, so the pen must wait for the pose. The force loop is the same
//! [`app::ForceLoop`]; only the board decides when to call it, and the Black Pill never
//! holds a tick.
//!
//! What lock-step gives up: the link's silence is counted in force ticks
//! ([`app::LINK_TIMEOUT_TICKS`]), and no tick is taken while the host sends nothing, so a
//! host that goes away leaves the virtual pen as it was (its motors are reported, not
//! driven). Tests of the link timeout run without `lockstep`.
//!
//! Output and exit go through semihosting (enable it
//! with `-semihosting-config enable=on,target=native`): text on the host's stdout, defmt
//! frames on stderr (see [`logger`]), and the exit code becomes QEMU's.

pub mod boot;
pub mod config_store;
pub mod logger;
pub mod regs;
pub mod semihosting;
pub mod time_driver;
pub mod uart;

pub use boot::main;

use core::cell::Cell;
use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};

use critical_section::Mutex;

use cortex_m::peripheral::NVIC;
use maobi_shared::guide::GuideInput;
use maobi_shared::kinematics::{Pen, PenConfig, RawReadings};
use maobi_shared::pen_io::DeviceConfig;
use maobi_shared::protocol::{Buttons, SensorReport};
use maobi_shared::{Fx, Pose, Scalar};

use crate::app::{self, PoseConsumer, PoseProducer, PoseQueue};
use crate::board::{CycleCounter, Motors, PoseSource, Watchdog};
use regs::{rd, timer as t, wr, PCLK_HZ};

/// The watchdog timeout in force, in timer counts: [`app::WATCHDOG_MIN_TICKS`] tick
/// periods, which hold several of the supervisor's check-in periods (set by [`start`]).
static WATCHDOG_RELOAD: AtomicU32 = AtomicU32::new(u32::MAX);

/// Lock-step mode (see the module docs), set by [`start`].
static LOCKSTEP: AtomicBool = AtomicBool::new(false);

/// Cortex-M4 with 3 priority bits on this machine model? The NVIC keeps the top bits; these
/// are spaced so any implemented width orders them the same way.
const PRIO_WATCHDOG: u8 = 0x00;
const PRIO_FORCE: u8 = 0x20;
const PRIO_UART: u8 = 0x40;
const PRIO_TIME: u8 = 0x60;

#[derive(Copy, Clone)]
#[repr(u16)]
pub enum Irq {
    UartRx = regs::uart::IRQ_RX,
    UartTx = regs::uart::IRQ_TX,
    Timer0 = t::IRQ_TIMER0,
    Timer1 = t::IRQ_TIMER1,
    DualTimer = regs::dualtimer::IRQ,
}

// SAFETY: the numbers are the machine's interrupt lines (QEMU hw/arm/mps2.c).
unsafe impl cortex_m::interrupt::InterruptNumber for Irq {
    fn number(self) -> u16 {
        self as u16
    }
}

// ---------------------------------------------------------------------------------------
// The virtual pen

/// The pen of the QEMU board: poses the host sent, one per force tick.
///
/// Its sensor readings are synthesised for bring-up: the latest pose through the stored
/// configuration's kinematics (the reference pen, [`PenConfig::OMNI_LIKE`], until one is
/// configured) back to encoder counts and 12-bit gimbal codes, with the inkwell at the
/// calibration's readings (counts 0, codes 2048 while uncalibrated). A pose outside that
/// pen's workspace has no readings (`None`: no report). Buttons are not passed from the
/// pose samples to the force loop: reported empty.
pub struct VirtualPen {
    rx: PoseConsumer,
    seq: u32,
    guide: Option<GuideInput<Fx>>,
    last: Option<Pose<Fx>>,
    /// The pen whose sensors are synthesised (None only if its config would not validate,
    /// which `configure` never passes).
    synth: Option<Pen<Fx>>,
    /// Boot argument `poses=script`: the pen writes the bench stroke itself, a pose every
    /// tick, instead of taking the host's (see [`ScriptedStroke`]).
    script: Option<ScriptedStroke>,
}

/// The bench stroke ([`app::bench::stroke_pose`]) as a pose source of its own, there and back
/// for ever: a pen with sensors has a new pose on every tick, which a pose streamed over the
/// emulated UART (one byte per interrupt) cannot give at the pen's pace. With it a test can
/// hold the brush to ticking every tick while it works the link: the state frames'
/// `pose_seq` counts the poses the brush took. Built for the tick: the
/// stroke's straight pieces in single precision (the M4F's FPU), its tilt computed once.
struct ScriptedStroke {
    k: u32,
    tilt: maobi_shared::Quat<Fx>,
}

impl ScriptedStroke {
    fn new() -> Self {
        ScriptedStroke {
            k: 0,
            tilt: app::bench::stroke_pose(0).rot,
        }
    }
    fn next(&mut self) -> Pose<Fx> {
        let n = app::bench::STROKE_TICKS;
        self.k = (self.k + 1) % (2 * n);
        // Back along the same path after the lift: the pose never jumps.
        let k = if self.k <= n { self.k } else { 2 * n - self.k };
        let (hang, press) = (44.0f32, 32.0f32);
        let frac = |from: u32, len: u32| (k - from) as f32 / len as f32;
        let (x, z) = match k {
            0..=49 => (0.0, hang),
            50..=199 => (0.0, hang + (press - hang) * frac(50, 150)),
            200..=499 => (60.0 * frac(200, 300), press),
            _ => (60.0, press + (hang - press) * frac(500, 100)),
        };
        Pose::new(
            maobi_shared::Vec3::new(Fx::from_f32(x), Fx::ZERO, Fx::from_f32(z)),
            self.tilt,
        )
    }
}

/// The virtual pen's readings at the inkwell while no calibration is stored.
const UNCALIBRATED_ZERO: RawReadings = RawReadings {
    encoders: [0; 3],
    gimbal: [2048; 3],
};

fn synth_pen(cfg: &PenConfig, zero: Option<RawReadings>) -> Option<Pen<Fx>> {
    let mut pen = Pen::new(*cfg).ok()?;
    pen.calibrate(zero.unwrap_or(UNCALIBRATED_ZERO));
    Some(pen)
}

impl VirtualPen {
    /// The host's next pose is queued.
    fn pose_waiting(&self) -> bool {
        self.rx.ready()
    }
}

impl PoseSource for VirtualPen {
    fn next_pose(&mut self) -> Option<Pose<Fx>> {
        if let Some(script) = self.script.as_mut() {
            let pose = script.next();
            self.seq = self.seq.wrapping_add(1);
            self.last = Some(pose);
            return Some(pose);
        }
        let p = self.rx.dequeue()?;
        self.seq = p.seq;
        self.guide = p.guide;
        self.last = Some(p.pose);
        Some(p.pose)
    }
    /// A host's pose is dropped; the scripted stroke waits instead, so that its sequence
    /// numbers count the brush's ticks.
    fn skip_pose(&mut self) {
        if self.script.is_none() {
            let _ = self.next_pose();
            let _ = self.take_guide();
        }
    }
    fn pose_seq(&self) -> u32 {
        self.seq
    }
    fn take_guide(&mut self) -> Option<GuideInput<Fx>> {
        self.guide.take()
    }
    /// The virtual pen has no linkage: its "motors" are the three Cartesian axes with a unit
    /// lever arm, so the reported torques (N·m) equal the force's components (N).
    fn torques_for(&self, f: [Fx; 3]) -> [Fx; 3] {
        f
    }
    /// Only the synthesised sensors follow the configuration: the virtual pen's forces are
    /// Cartesian whatever the linkage.
    fn configure(&mut self, cfg: &DeviceConfig) {
        self.synth = synth_pen(&cfg.pen, cfg.calibration);
    }
    fn raw_sensors(&mut self, tick: u32) -> Option<SensorReport> {
        let pen = self.synth.as_ref()?;
        let joints = pen.inverse(&self.last?).ok()?;
        let raw = pen.raw_readings(&joints).ok()?;
        Some(SensorReport {
            tick,
            encoders: raw.encoders,
            // A 12-bit converter reads no further than its rails.
            gimbal: raw.gimbal.map(|g| g.clamp(0, 4095) as u16),
            buttons: Buttons::empty(),
            synthetic: true,
        })
    }
}

// ---------------------------------------------------------------------------------------
// Motors

static MOTORS_ON: AtomicBool = AtomicBool::new(false);
static MOTOR_CMD: Mutex<Cell<[i64; 3]>> = Mutex::new(Cell::new([0; 3]));

/// The QEMU board's motors: the commands are kept and reported in state frames.
pub struct ReportedMotors {
    _private: (),
}

impl Motors for ReportedMotors {
    fn command(&mut self, torque: [Fx; 3]) {
        critical_section::with(|cs| MOTOR_CMD.borrow(cs).set(torque.map(Fx::to_bits)));
        MOTORS_ON.store(true, Ordering::SeqCst);
    }
    fn disable(&mut self) {
        motors_off();
    }
    fn applied(&self) -> [Fx; 3] {
        if MOTORS_ON.load(Ordering::SeqCst) {
            critical_section::with(|cs| MOTOR_CMD.borrow(cs).get()).map(Fx::from_bits)
        } else {
            [Fx::from_bits(0); 3]
        }
    }
    /// Reported torques need no drive settings.
    fn configure(&mut self, _cfg: &DeviceConfig) {}
}

/// All motors off; callable from any context (fault handlers included).
pub fn motors_off() {
    MOTORS_ON.store(false, Ordering::SeqCst);
    critical_section::with(|cs| MOTOR_CMD.borrow(cs).set([0; 3]));
}

// ---------------------------------------------------------------------------------------
// Watchdog and force-loop timers

/// TIMER1 as the watchdog: a force tick reloads it once the supervisor has checked in since
/// the last reload (`app::ForceLoop::tick`); if it ever reaches zero (the force loop or
/// thread mode stopped) its interrupt (above the force loop's priority) turns the motors off
/// and stops the machine, as the Black Pill's IWDG resets the chip.
pub struct TimerWatchdog {
    _private: (),
}

impl Watchdog for TimerWatchdog {
    #[inline]
    fn feed(&mut self) {
        wr(
            t::TIMER1 + t::VALUE,
            WATCHDOG_RELOAD.load(Ordering::Relaxed),
        );
    }
}

/// The board's cycle counter: the time driver's free-running 25 MHz count. Under
/// `-icount shift=N` one count is 40 / 2^N instructions.
pub struct IcountCounter;

impl CycleCounter for IcountCounter {
    #[inline(always)]
    fn now(&self) -> u32 {
        time_driver::counts_lo()
    }
    const UNIT: &'static str = "timer25mhz";
}

// ---------------------------------------------------------------------------------------
// The force loop's home

type Loop = app::ForceLoop<VirtualPen, ReportedMotors, TimerWatchdog>;

/// The force loop: written by `start` before TIMER0's interrupt is enabled, then used only
/// by that interrupt's handler.
static LOOP: app::ForceLoopSlot<Loop> = app::ForceLoopSlot::new();

/// Everything `main` gets from the board.
pub struct Parts {
    pub uart: uart::Uart0,
    pub config: config_store::RamConfigStore,
    pub poses: PoseProducer,
    pub cmds: app::CmdProducer,
}

/// Brings the board up: time driver, UART, the force loop around a brush of `params` at rest
/// at `pose`, ticking every `tick_us` (in `lockstep`, taking a tick only on a pose from the
/// host: see the module docs), the watchdog, and the interrupt priorities. Interrupts are
/// enabled on return.
pub fn start(
    params: maobi_shared::BrushParams,
    pose: maobi_shared::Pose<Fx>,
    tick_us: u32,
    lockstep: bool,
    scripted: bool,
) -> Parts {
    LOCKSTEP.store(lockstep, Ordering::Relaxed);
    let tick_counts = PCLK_HZ / 1_000_000 * tick_us;
    let watchdog_counts = tick_counts.saturating_mul(app::WATCHDOG_MIN_TICKS);
    WATCHDOG_RELOAD.store(watchdog_counts, Ordering::Relaxed);
    static mut POSES: PoseQueue = PoseQueue::new();
    static mut CMDS: app::CmdQueue = app::CmdQueue::new();
    // SAFETY: `start` runs once; the queues are split here and never touched otherwise.
    let (pose_tx, pose_rx) = unsafe { (*core::ptr::addr_of_mut!(POSES)).split() };
    let (cmd_tx, cmd_rx) = unsafe { (*core::ptr::addr_of_mut!(CMDS)).split() };

    time_driver::init();
    let uart = uart::Uart0::init();

    // Built in its static, not on the stack (`ForceLoop::new_in`).
    // SAFETY: once, and the TIMER0 interrupt is not enabled yet.
    let built = unsafe {
        LOOP.init_with(|slot| {
            app::ForceLoop::new_in(
                slot,
                params,
                pose,
                VirtualPen {
                    rx: pose_rx,
                    seq: 0,
                    guide: None,
                    last: None,
                    synth: synth_pen(&PenConfig::OMNI_LIKE, None),
                    script: scripted.then(ScriptedStroke::new),
                },
                ReportedMotors { _private: () },
                TimerWatchdog { _private: () },
                cmd_rx,
            )
        })
    };
    if built.is_none() {
        semihosting::fatal(
            "the brush preset or the force model's defaults are invalid",
            5,
        );
    }

    // TIMER1: watchdog; TIMER0: 1 kHz force tick.
    wr(t::TIMER1 + t::CTRL, 0);
    wr(t::TIMER1 + t::RELOAD, watchdog_counts);
    wr(t::TIMER1 + t::VALUE, watchdog_counts);
    wr(t::TIMER1 + t::INTCLEAR, 1);
    wr(t::TIMER0 + t::CTRL, 0);
    wr(t::TIMER0 + t::RELOAD, tick_counts - 1);
    wr(t::TIMER0 + t::VALUE, tick_counts - 1);
    wr(t::TIMER0 + t::INTCLEAR, 1);

    // SAFETY: boot, single context; priorities are set before the lines are unmasked.
    unsafe {
        let mut p = cortex_m::Peripherals::steal();
        p.NVIC.set_priority(Irq::Timer1, PRIO_WATCHDOG);
        p.NVIC.set_priority(Irq::Timer0, PRIO_FORCE);
        p.NVIC.set_priority(Irq::UartRx, PRIO_UART);
        p.NVIC.set_priority(Irq::UartTx, PRIO_UART);
        p.NVIC.set_priority(Irq::DualTimer, PRIO_TIME);
        for irq in [
            Irq::Timer1,
            Irq::Timer0,
            Irq::UartRx,
            Irq::UartTx,
            Irq::DualTimer,
        ] {
            NVIC::unpend(irq);
            NVIC::unmask(irq);
        }
    }
    wr(t::TIMER1 + t::CTRL, t::CTRL_EN | t::CTRL_IRQ_EN);
    wr(t::TIMER0 + t::CTRL, t::CTRL_EN | t::CTRL_IRQ_EN);
    // SAFETY: everything the handlers touch is initialised.
    unsafe { cortex_m::interrupt::enable() };

    Parts {
        uart,
        config: config_store::RamConfigStore::open(),
        poses: pose_tx,
        cmds: cmd_tx,
    }
}

/// TIMER0: one force-loop tick (the application's [`app::run_tick`]); the tick overran if
/// TIMER0's interrupt is pending again when it ends. In lock-step, a tick that may not be
/// taken yet is held instead.
fn on_force_tick() {
    wr(t::TIMER0 + t::INTCLEAR, 1);
    // SAFETY: only this handler uses the slot after `start`; it does not re-enter.
    let Some(fl) = (unsafe { LOOP.get() }) else {
        return;
    };
    if LOCKSTEP.load(Ordering::Relaxed) && !lockstep_tick_ready(fl) {
        fl.hold();
        return;
    }
    app::run_tick(fl, &IcountCounter, PCLK_HZ / 1_000_000, || {
        rd(t::TIMER0 + t::INTCLEAR) & 1 != 0
    });
}

/// Lock-step: the host's next pose is queued, and the last tick's state has gone (out of
/// the snapshot slot, and every byte the link task queued before it out of the transmit
/// ring), so this tick's state will be sent whole, not dropped for want of room.
fn lockstep_tick_ready(fl: &Loop) -> bool {
    fl.pen().pose_waiting() && !app::SNAPSHOT.is_full() && uart::tx_queued() == 0
}

fn on_watchdog() -> ! {
    motors_off();
    app::latch(maobi_shared::protocol::Faults::WATCHDOG);
    // Which context stopped: the force loop ticking on unfed is a starved thread mode; a
    // stopped force loop stops thread mode too (it runs below it). Plain text: no
    // formatting on this path.
    if app::thread_mode_starved_the_watchdog() {
        semihosting::fatal(
            "watchdog: thread mode stopped (the force loop ticked on, no supervisor check-in); motors off",
            3,
        )
    }
    semihosting::fatal("watchdog: the force loop stopped; motors off", 3)
}

/// Device interrupts arrive here (no peripheral-access crate): dispatch by number.
#[cortex_m_rt::exception]
unsafe fn DefaultHandler(irqn: i16) {
    match irqn {
        8 => on_force_tick(),
        9 => on_watchdog(),
        0 => uart::on_rx_interrupt(),
        1 => uart::on_tx_interrupt(),
        10 => time_driver::on_interrupt(),
        // 12: UART overflow (combined); nothing is enabled to raise it.
        n if n >= 0 => {
            NVIC::mask(IrqN(n as u16));
        }
        _ => {
            motors_off();
            semihosting::fatal("unexpected exception", 4)
        }
    }
}

#[derive(Copy, Clone)]
struct IrqN(u16);
// SAFETY: a line number reported by the NVIC itself.
unsafe impl cortex_m::interrupt::InterruptNumber for IrqN {
    fn number(self) -> u16 {
        self.0
    }
}

#[cortex_m_rt::exception]
unsafe fn HardFault(ef: &cortex_m_rt::ExceptionFrame) -> ! {
    motors_off();
    semihosting::fatal_fmt(
        format_args!("HardFault at pc={:#010x}; motors off", ef.pc()),
        2,
    )
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    cortex_m::interrupt::disable();
    motors_off();
    semihosting::fatal_fmt(format_args!("panic: {info}; motors off"), 1)
}
