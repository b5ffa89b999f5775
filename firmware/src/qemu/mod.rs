//! The QEMU board: `qemu-system-arm -machine mps2-an386 -cpu cortex-m4`.
//!
//! | what | where | priority |
//! |---|---|---|
//! | watchdog: TIMER1 counting down 20 ms, reloaded by every force tick | 0x4000_1000, IRQ 9 | 0 (highest) |
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
//! Output and exit go through semihosting (enable it
//! with `-semihosting-config enable=on,target=native`): text on the host's stdout, defmt
//! frames on stderr (see [`logger`]), and the exit code becomes QEMU's.

pub mod config_store;
pub mod executor;
pub mod logger;
pub mod regs;
pub mod semihosting;
pub mod time_driver;
pub mod uart;

use core::cell::Cell;
use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};

use critical_section::Mutex;

use cortex_m::peripheral::NVIC;
use maobi_shared::kinematics::{Pen, PenConfig, RawReadings};
use maobi_shared::pen_io::DeviceConfig;
use maobi_shared::protocol::{Buttons, SensorReport};
use maobi_shared::{Fx, Pose};

use crate::app::{self, fault, POSE_QUEUE};
use crate::board::{CycleCounter, Motors, PoseSource, Watchdog};
use regs::{rd, timer as t, wr, PCLK_HZ};

/// Watchdog timeout in timer counts (20 ms).
pub const WATCHDOG_COUNTS: u32 = PCLK_HZ / 50;

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

/// A pose the host sent, with its sequence number.
pub type PoseQueue = heapless::spsc::Queue<(u32, Pose<Fx>), POSE_QUEUE>;
pub type PoseProducer = heapless::spsc::Producer<'static, (u32, Pose<Fx>)>;

/// The pen of the QEMU board: poses the host sent, one per force tick.
///
/// Its sensor readings are synthesised for bring-up: the latest pose through the stored
/// configuration's kinematics (the reference pen, [`PenConfig::OMNI_LIKE`], until one is
/// configured) back to encoder counts and 12-bit gimbal codes, with the inkwell at the
/// calibration's readings (counts 0, codes 2048 while uncalibrated). A pose outside that
/// pen's workspace has no readings (`None`: no report). Buttons are not passed from the
/// pose samples to the force loop: reported empty.
pub struct VirtualPen {
    rx: heapless::spsc::Consumer<'static, (u32, Pose<Fx>)>,
    seq: u32,
    last: Option<Pose<Fx>>,
    /// The pen whose sensors are synthesised (None only if its config would not validate,
    /// which `configure` never passes).
    synth: Option<Pen<Fx>>,
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

impl PoseSource for VirtualPen {
    fn next_pose(&mut self) -> Option<Pose<Fx>> {
        let (seq, pose) = self.rx.dequeue()?;
        self.seq = seq;
        self.last = Some(pose);
        Some(pose)
    }
    fn pose_seq(&self) -> u32 {
        self.seq
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

/// TIMER1 as the watchdog: the force loop reloads it every tick; if it ever reaches zero its
/// interrupt (above the force loop's priority) turns the motors off and stops the machine.
pub struct TimerWatchdog {
    _private: (),
}

impl Watchdog for TimerWatchdog {
    #[inline]
    fn feed(&mut self) {
        wr(t::TIMER1 + t::VALUE, WATCHDOG_COUNTS);
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

/// Uninitialised storage (in .bss, not copied from flash) until `start` writes it.
struct LoopCell(core::cell::UnsafeCell<core::mem::MaybeUninit<Loop>>);
// SAFETY: written once by `start` (then LOOP_READY is set) before the TIMER0 interrupt is
// enabled, then touched only by the TIMER0 handler, which nothing else preempts except the
// watchdog (which never touches it).
unsafe impl Sync for LoopCell {}
static LOOP: LoopCell = LoopCell(core::cell::UnsafeCell::new(core::mem::MaybeUninit::uninit()));
static LOOP_READY: AtomicBool = AtomicBool::new(false);

static OVERRUNS: AtomicU32 = AtomicU32::new(0);
/// Time-driver count (25 MHz, low word) at the previous tick's start.
static LAST_TICK_START: AtomicU32 = AtomicU32::new(0);

/// Everything `main` gets from the board.
pub struct Parts {
    pub uart: uart::Uart0,
    pub config: config_store::RamConfigStore,
    pub poses: PoseProducer,
    pub cmds: app::CmdProducer,
}

/// Brings the board up: time driver, UART, the force loop around `brush` ticking every
/// `tick_us`, the watchdog, and the interrupt priorities. Interrupts are enabled on return.
pub fn start(brush: maobi_shared::Brush<Fx>, tick_us: u32) -> Parts {
    let tick_counts = PCLK_HZ / 1_000_000 * tick_us;
    static mut POSES: PoseQueue = PoseQueue::new();
    static mut CMDS: app::CmdQueue = app::CmdQueue::new();
    // SAFETY: `start` runs once; the queues are split here and never touched otherwise.
    let (pose_tx, pose_rx) = unsafe { (*core::ptr::addr_of_mut!(POSES)).split() };
    let (cmd_tx, cmd_rx) = unsafe { (*core::ptr::addr_of_mut!(CMDS)).split() };

    time_driver::init();
    let uart = uart::Uart0::init();

    let Some(fl) = app::ForceLoop::new(
        brush,
        VirtualPen {
            rx: pose_rx,
            seq: 0,
            last: None,
            synth: synth_pen(&PenConfig::OMNI_LIKE, None),
        },
        ReportedMotors { _private: () },
        TimerWatchdog { _private: () },
        cmd_rx,
    ) else {
        semihosting::fatal("the force model's defaults are invalid", 5);
    };
    // SAFETY: the TIMER0 interrupt is not enabled yet (see `LoopCell`).
    unsafe { (*LOOP.0.get()).write(fl) };
    LOOP_READY.store(true, Ordering::SeqCst);

    // TIMER1: watchdog; TIMER0: 1 kHz force tick.
    wr(t::TIMER1 + t::CTRL, 0);
    wr(t::TIMER1 + t::RELOAD, WATCHDOG_COUNTS);
    wr(t::TIMER1 + t::VALUE, WATCHDOG_COUNTS);
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
        config: config_store::RamConfigStore::new(),
        poses: pose_tx,
        cmds: cmd_tx,
    }
}

/// Number of ticks that overran (latched as LOOP_OVERRUN too).
pub fn overruns() -> u32 {
    OVERRUNS.load(Ordering::Relaxed)
}

fn on_force_tick() {
    wr(t::TIMER0 + t::INTCLEAR, 1);
    if !LOOP_READY.load(Ordering::Relaxed) {
        return;
    }
    // SAFETY: see `LoopCell`: initialised (LOOP_READY), and only this handler touches it.
    let fl = unsafe { (*LOOP.0.get()).assume_init_mut() };
    let start = time_driver::counts_lo();
    fl.tick();
    let end = time_driver::counts_lo();
    let last = LAST_TICK_START.swap(start, Ordering::Relaxed);
    if last != 0 {
        let per_us = PCLK_HZ / 1_000_000;
        app::timing::record(
            start.wrapping_sub(last) / per_us,
            end.wrapping_sub(start) / per_us,
        );
    }
    if rd(t::TIMER0 + t::INTCLEAR) & 1 != 0 {
        // The next tick fell due while this one ran.
        OVERRUNS.fetch_add(1, Ordering::Relaxed);
        app::latch(fault::LOOP_OVERRUN);
        fl.motors_off();
    }
}

fn on_watchdog() -> ! {
    motors_off();
    app::latch(fault::LOOP_STALLED);
    semihosting::fatal("watchdog: the force loop stopped for 20 ms; motors off", 3)
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
