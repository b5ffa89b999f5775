//! The STM32F411CE "Black Pill" (WeAct v3.0, 25 MHz crystal) in the real pen.
//!
//! | what | where | priority |
//! |---|---|---|
//! | force loop: TIM9 update at 1 kHz | `TIM1_BRK_TIM9` | P1 (highest used) |
//! | link: USB OTG_FS, CDC-ACM (PA11/PA12) | `OTG_FS` | P3 |
//! | embassy time driver | TIM5 | P4 |
//! | thread-mode executor: link, USB, supervisor, LED tasks | | thread |
//! | hardware watchdog (IWDG, fed by the force loop once the supervisor has checked in) | resets the chip | |
//!
//! The force loop reads the sensors and writes the motors inside `ForceLoop::tick` exactly
//! as on QEMU (`app::run_tick` from the timer interrupt): the board only provides the trait
//! implementations ([`sensors`], [`motors`], [`watchdog`], [`usb`]) and its boot (`main`).
//!
//! Clocks: HSE 25 MHz / 25 x 192 = 192 MHz VCO; SYSCLK 96 MHz (P / 2), USB 48 MHz (Q / 4);
//! APB1 48 MHz (its timers 96 MHz), APB2 96 MHz (TIM1 and TIM9 at 96 MHz, ADC 24 MHz).

pub mod config;
pub mod motors;
pub mod pins;
pub mod sensors;
pub mod usb;
pub mod watchdog;

use core::sync::atomic::{AtomicBool, Ordering};

use cortex_m::peripheral::DWT;
use defmt_rtt as _;
use embassy_executor::Spawner;
use embassy_stm32::adc::{Adc, AdcChannel};
use embassy_stm32::flash::Flash;
use embassy_stm32::gpio::{Input, Level, Output, Pull, Speed};
use embassy_stm32::interrupt::{InterruptExt, Priority};
use embassy_stm32::pac::adc::vals::Exten;
use embassy_stm32::time::Hertz;
use embassy_stm32::timer::low_level::{CountingMode, RoundTo, Timer as LlTimer};
use embassy_stm32::timer::qei::{self, Qei};
use embassy_stm32::timer::simple_pwm::{PwmPin, SimplePwm};
use embassy_stm32::wdg::IndependentWatchdog;
use embassy_stm32::{bind_interrupts, pac, peripherals};
use embassy_time::{Duration, Ticker};
use maobi_shared::pen_io::DriveConfig;
use maobi_shared::protocol::Capabilities;
use maobi_shared::{presets, Fx, Pose, Quat, Scalar, Vec3};

use crate::app::{self, SensorPen};
use crate::board::CycleCounter;
use crate::host_link::{self, BoardInfo, LinkParts};

/// SYSCLK, the DWT cycle counter's rate.
pub const SYSCLK_HZ: u32 = 96_000_000;
/// The force loop's period.
pub const TICK_US: u32 = 1000;

// The watchdog's timeout at the fastest LSI still holds the supervisor's check-in margin
// (`app::WATCHDOG_MIN_TICKS` of these ticks): a live but busy thread mode never trips it.
const _: () = assert!(
    watchdog::TIMEOUT_US / watchdog::LSI_FASTEST_KHZ * 32 >= app::WATCHDOG_MIN_TICKS * TICK_US,
    "the watchdog must allow the supervisor's check-in margin at the fastest LSI"
);

/// Lights the fault LED from any context (PC13 low).
pub fn led_on() {
    pins::LED.set_low();
}

/// Puts the fault LED out from any context (PC13 high).
fn led_off() {
    pins::LED.set_high();
}

/// Why the last run ended, kept across the reset in RAM the startup code leaves alone
/// (`.uninit`): the fault paths (panic, HardFault) turn the motors off and spin until the
/// watchdog resets the chip, and without this the next boot could only blame a stalled
/// force loop. A magic word and the reason; anything else (a power-on's random RAM) is no
/// reason.
#[link_section = ".uninit.maobi_reset_reason"]
static mut RESET_REASON: core::mem::MaybeUninit<[u32; 2]> = core::mem::MaybeUninit::uninit();
const REASON_MAGIC: u32 = 0x4D42_5252;
const REASON_PANIC: u32 = 1;
const REASON_HARDFAULT: u32 = 2;

/// Records why this run is about to end (from a fault path, any context).
fn keep_reset_reason(reason: u32) {
    // SAFETY: a plain word pair in RAM, written whole; only the fault paths and `start`
    // touch it, never at once (the fault paths do not return).
    unsafe {
        core::ptr::write_volatile(
            core::ptr::addr_of_mut!(RESET_REASON).cast::<[u32; 2]>(),
            [REASON_MAGIC, reason],
        )
    }
}

/// The reason the last run recorded, if any, forgotten once read.
fn take_reset_reason() -> Option<u32> {
    let at = core::ptr::addr_of_mut!(RESET_REASON).cast::<[u32; 2]>();
    // SAFETY: as in `keep_reset_reason`; any bit pattern is a valid `[u32; 2]`.
    let [magic, reason] = unsafe { core::ptr::read_volatile(at) };
    // SAFETY: as above.
    unsafe { core::ptr::write_volatile(at, [0, 0]) };
    (magic == REASON_MAGIC && matches!(reason, REASON_PANIC | REASON_HARDFAULT)).then_some(reason)
}

bind_interrupts!(struct Irqs {
    OTG_FS => embassy_stm32::usb::InterruptHandler<peripherals::USB_OTG_FS>;
});

/// What the link says about this board (the handshake adds the stored configuration's
/// state).
static BOARD: BoardInfo = BoardInfo {
    name: "maobi-pen-blackpill",
    capabilities: Capabilities::FORCE_OUTPUT
        .union(Capabilities::REAL_SENSORS)
        .union(Capabilities::NEEDS_CALIBRATION)
        .union(Capabilities::BUTTONS)
        .union(Capabilities::STORED_CONFIG),
    force_peak_n: maobi_shared::force::PHANTOM_OMNI.peak_n,
    force_continuous_n: maobi_shared::force::PHANTOM_OMNI.continuous_n,
    // A preset that asks for more substeps than the pen's one (the springy wolf hair's two)
    // runs at one here, springing back slower than at its own rate
    // (`shared/tests/convergence.rs` holds it to its own bound). The image is built with the
    // presets' backward-Euler step only (`maobi-shared`'s `kang-cho` feature left out).
    limits: crate::board::PEN_TICK_LIMITS,
};

/// The force tick's interrupt is enabled: from here a panic ends in the watchdog's reset
/// (the loop stops; the next boot reports it), before it in [`fatal`]'s halt.
static LOOP_STARTED: AtomicBool = AtomicBool::new(false);

type Loop = app::ForceLoop<SensorPen<sensors::PenSensors>, motors::PenMotors, watchdog::Iwdg>;

/// The force loop: written by `main` before TIM9's interrupt is enabled, then used only
/// by that interrupt's handler.
static LOOP: app::ForceLoopSlot<Loop> = app::ForceLoopSlot::new();

/// The Cortex-M4's cycle counter (DWT CYCCNT, 96 MHz).
pub struct Cycles;

impl CycleCounter for Cycles {
    #[inline(always)]
    fn now(&self) -> u32 {
        DWT::cycle_count()
    }
    const UNIT: &'static str = "cycles";
}

/// TIM9's update interrupt: one force-loop tick. It overran if the next update is already
/// pending when it ends.
#[interrupt]
fn TIM1_BRK_TIM9() {
    let tim = pac::TIM9;
    tim.sr().modify(|w| w.set_uif(false));
    // SAFETY: only this handler uses the slot after `main` stored it; it does not re-enter.
    let Some(fl) = (unsafe { LOOP.get() }) else {
        return;
    };
    app::run_tick(fl, &Cycles, SYSCLK_HZ / 1_000_000, || tim.sr().read().uif());
}

// The interrupt attribute of the device crate (embassy-stm32's PAC, `rt` feature); the
// interrupt lines' priorities and enables go through embassy's `InterruptExt`.
use embassy_stm32::interrupt as irq;
use embassy_stm32::pac::interrupt;

/// The board's `main`, called by the entry point of the bin `maobi-pen`: the board brought
/// up, then the tasks, for ever.
pub fn main() -> ! {
    // Everything built at boot is built in `start`'s frame, which is gone before the executor
    // runs: `main` never returns, so what its own frame held (the peripherals' drivers and
    // the USB builder, kilobytes) would sit under the tasks' and the interrupts' stack for
    // good.
    let (usb_parts, link_parts, led) = start();
    crate::executor::run(move |spawner: Spawner| {
        spawner.spawn(
            app::supervisor(TICK_US, motors::motors_off, report_stack, report_feed_gap)
                .expect("one supervisor"),
        );
        spawner.spawn(usb_task(usb_parts).expect("one USB task"));
        spawner.spawn(link_task(link_parts).expect("one link task"));
        spawner.spawn(led_task(led).expect("one LED task"));
    })
}

/// The board brought up: clocks, motors off, sensors, the force loop built and ticking, USB;
/// what the tasks take (see `main` for why not inline).
#[inline(never)]
fn start() -> (
    usb::UsbParts,
    LinkParts<usb::UsbSerial, config::FlashConfig>,
    Output<'static>,
) {
    // Whatever state the pins come up in, the bridges are off before anything else runs.
    motors::motors_off();
    let mut config = embassy_stm32::Config::default();
    {
        use embassy_stm32::rcc::*;
        config.rcc.hse = Some(Hse {
            freq: Hertz(25_000_000),
            mode: HseMode::Oscillator,
        });
        config.rcc.pll_src = PllSource::HSE;
        config.rcc.pll = Some(Pll {
            prediv: PllPreDiv::DIV25,
            mul: PllMul::MUL192,
            divp: Some(PllPDiv::DIV2),
            divq: Some(PllQDiv::DIV4),
            divr: None,
        });
        config.rcc.sys = Sysclk::PLL1_P;
        config.rcc.ahb_pre = AHBPrescaler::DIV1;
        config.rcc.apb1_pre = APBPrescaler::DIV2;
        config.rcc.apb2_pre = APBPrescaler::DIV1;
    }
    let p = embassy_stm32::init(config);
    // embassy's clock setup wrote the flash latency alone, which turned prefetch and the
    // caches off: on again before anything is timed.
    config::restart_flash_caches();
    let reset_by_watchdog = pac::RCC.csr().read().wdgrstf();
    pac::RCC.csr().modify(|w| w.set_rmvf(true));
    watchdog::freeze_in_debug();

    let pins = pins::take(p);

    // The motor bridges first, off: standby low, inputs low, duty zero.
    let pins::MotorPins {
        pwm_timer,
        pwm1,
        pwm2,
        pwm3,
        dir,
        stby,
    } = pins.motors;
    let off = |pin| Output::new(pin, Level::Low, Speed::Low);
    let stby = stby.map(off);
    let dir = dir.map(|d| d.map(off));
    let led = Output::new(pins.led, Level::High, Speed::Low);

    // The configuration log (sectors 6 and 7). The link task loads and decodes the newest image when it
    // starts and puts it in force (`app::Command::Configure`); until then the pen has no
    // kinematics, `app::CONFIG_OK` is off and the motors stay off.
    let mut store = config::FlashConfig::open(Flash::new_blocking(pins.flash));

    let drive = [DriveConfig::DEFAULT; 3];
    let mut pwm = SimplePwm::new(
        pwm_timer,
        Some(PwmPin::new(pwm1, embassy_stm32::gpio::OutputType::PushPull)),
        Some(PwmPin::new(pwm2, embassy_stm32::gpio::OutputType::PushPull)),
        Some(PwmPin::new(pwm3, embassy_stm32::gpio::OutputType::PushPull)),
        None,
        Hertz(drive[0].pwm_hz),
        CountingMode::EdgeAlignedUp,
    );
    let period = u16::try_from(pwm.max_duty_cycle()).unwrap_or(u16::MAX);
    for ch in [
        embassy_stm32::timer::Channel::Ch1,
        embassy_stm32::timer::Channel::Ch2,
        embassy_stm32::timer::Channel::Ch3,
    ] {
        let mut c = pwm.channel(ch);
        c.set_duty_cycle(0);
        c.enable();
    }
    motors::configure_debug_halt();
    let motors = motors::PenMotors {
        pwm,
        dir,
        stby,
        pen: None,
        drive,
        period,
        applied: [Fx::ZERO; 3],
    };

    // Sensors (the pins in `pins`): the encoders' pull-ups on for open-collector outputs, the
    // buttons' too (they switch to ground).
    let qei_cfg = qei::Config {
        ch1_pull: Pull::Up,
        ch2_pull: Pull::Up,
        ..Default::default()
    };
    let sensors = sensors::PenSensors {
        enc1: Qei::new(pins.enc1.timer, pins.enc1.a, pins.enc1.b, qei_cfg),
        enc2: Qei::new(pins.enc2.timer, pins.enc2.a, pins.enc2.b, qei_cfg),
        enc3: Qei::new(pins.enc3.timer, pins.enc3.a, pins.enc3.b, qei_cfg),
        // Switched on once here (its power-up wait paid once); each tick starts one scan.
        gimbal: Adc::new(pins.gimbal.adc).setup_injected_conversions(
            [
                (pins.gimbal.g1.degrade_adc(), sensors::GIMBAL_SAMPLE),
                (pins.gimbal.g2.degrade_adc(), sensors::GIMBAL_SAMPLE),
                (pins.gimbal.g3.degrade_adc(), sensors::GIMBAL_SAMPLE),
            ],
            sensors::SoftwareStart,
            Exten::DISABLED,
            false,
        ),
        buttons: pins.buttons.map(|pin| Input::new(pin, Pull::Up)),
    };

    // The brush starts at rest wherever the first sensor pose puts it.
    let start = Pose::new(
        Vec3::new(Fx::ZERO, Fx::ZERO, Fx::from_usize(44)),
        Quat::IDENTITY,
    );
    static mut CMDS: app::CmdQueue = app::CmdQueue::new();
    // SAFETY: `main` runs once; the queue is split here and never touched otherwise.
    let (cmd_tx, cmd_rx) = unsafe { (*core::ptr::addr_of_mut!(CMDS)).split() };

    let mut iwdg = IndependentWatchdog::new(pins.iwdg, watchdog::TIMEOUT_US);
    iwdg.unleash();
    // Another firmware's data in the configuration sectors (a new board's demo) is erased
    // now, with the motors off and nothing timed yet, rather than on the first save, while
    // the host waits. Once the watchdog runs: the erase stretches it.
    store.reclaim();
    // Built in its static, not on the stack (`ForceLoop::new_in`).
    // SAFETY: once, and TIM9's interrupt is not enabled yet.
    let built = unsafe {
        LOOP.init_with(|slot| {
            app::ForceLoop::new_in(
                slot,
                BOARD.brush(presets::LARGE),
                start,
                SensorPen::new(sensors, None),
                motors,
                watchdog::Iwdg(iwdg),
                cmd_rx,
            )
        })
    };
    let Some(fl) = built else {
        fatal("the brush preset or the force model's defaults are invalid");
    };
    fl.reanchor();
    let kept = take_reset_reason();
    if reset_by_watchdog {
        // The force loop stopped either way; the log says why, as far as it is known.
        match kept {
            Some(REASON_PANIC) => defmt::error!("reset by the watchdog after a panic"),
            Some(REASON_HARDFAULT) => defmt::error!("reset by the watchdog after a HardFault"),
            _ => defmt::error!("reset by the watchdog: the force loop or thread mode had stopped"),
        }
        app::latch(maobi_shared::protocol::Faults::WATCHDOG);
    }

    // The cycle counter for the tick timing.
    // SAFETY: boot, single context.
    let mut core = unsafe { cortex_m::Peripherals::steal() };
    core.DCB.enable_trace();
    core.DWT.enable_cycle_counter();

    // Priorities: the force loop above USB above the time driver.
    irq::TIM1_BRK_TIM9.set_priority(Priority::P1);
    irq::OTG_FS.set_priority(Priority::P3);
    irq::TIM5.set_priority(Priority::P4);

    // USB.
    static EP_OUT: static_cell::StaticCell<[u8; 256]> = static_cell::StaticCell::new();
    let mut usb_cfg = embassy_stm32::usb::Config::default();
    // Bus-powered: VBUS is always there while the chip runs (and PA9 is a PWM output).
    usb_cfg.vbus_detection = false;
    let driver = embassy_stm32::usb::Driver::new_fs(
        pins.usb.otg,
        Irqs,
        pins.usb.dp,
        pins.usb.dm,
        EP_OUT.init([0; 256]),
        usb_cfg,
    );
    let usb_parts = usb::build(driver, embassy_stm32::uid::uid_hex());

    // The force tick: TIM9 at 1 kHz.
    let tick = LlTimer::new(pins.tick_timer);
    tick.set_frequency(Hertz(1_000_000 / TICK_US), RoundTo::Slower);
    tick.enable_update_interrupt(true);
    tick.start();
    // The timer lives for the program (dropping the driver would stop its clock).
    core::mem::forget(tick);
    irq::TIM1_BRK_TIM9.unpend();
    // SAFETY: the handler's state (LOOP) is initialised.
    unsafe { irq::TIM1_BRK_TIM9.enable() };
    LOOP_STARTED.store(true, Ordering::Relaxed);
    // The boot record the HIL runner waits for (`hil::probe_rs::BOOT_LINE`).
    defmt::info!("maobi-pen up");

    let link_parts = LinkParts {
        transport: usb::UsbSerial::new(),
        poses: None,
        cmds: cmd_tx,
        store,
    };
    (usb_parts, link_parts, led)
}

#[embassy_executor::task]
async fn usb_task(parts: usb::UsbParts) {
    usb::run(parts).await
}

#[embassy_executor::task]
async fn link_task(parts: LinkParts<usb::UsbSerial, config::FlashConfig>) {
    let cfg = host_link::LinkConfig {
        tick_us: TICK_US,
        telemetry_ticks: 1000,
    };
    host_link::run(parts, &BOARD, BOARD.brush(presets::LARGE), cfg).await
}

/// A new deepest stack reading (`app::stack`), in the defmt log: the figure the RAM budget's
/// stack reserve must be checked against on the board (it has not run on one yet).
fn report_stack(used: usize) {
    defmt::info!("stack high-water mark: {=usize} bytes", used);
}

/// A new longest gap between two watchdog feeds (`app::FEED_GAP_MAX_TICKS`), in the defmt
/// log: the figure `watchdog::TIMEOUT_US` must stay well above on the board.
fn report_feed_gap(ticks: u32) {
    defmt::info!("longest gap between watchdog feeds: {=u32} ticks", ticks);
}

/// The fault LED: steady while a fault is latched; fast blink (5 Hz) without a valid
/// configuration; slow blink (1 Hz) while not calibrated; a short flash every 2 s when all
/// is well (the board is alive).
#[embassy_executor::task]
async fn led_task(mut led: Output<'static>) {
    let mut ticker = Ticker::every(Duration::from_millis(100));
    let mut phase: u32 = 0;
    loop {
        ticker.next().await;
        phase = phase.wrapping_add(1);
        let faults = app::FAULTS.load(Ordering::Relaxed);
        let on = if faults != 0 {
            true
        } else if !app::CONFIG_VALID.load(Ordering::Relaxed) {
            phase.is_multiple_of(2)
        } else if !app::CONFIG_OK.load(Ordering::Relaxed) {
            phase % 10 < 5
        } else {
            phase.is_multiple_of(20)
        };
        // Active low.
        led.set_level(Level::from(!on));
    }
}

/// The fault LED's pattern after a fatal boot error, in steps of [`FATAL_STEP_MS`]: three
/// short flashes and a pause, unlike every pattern of [`led_task`].
const FATAL_BLINK: [(bool, u32); 6] = [
    (true, 15),
    (false, 15),
    (true, 15),
    (false, 15),
    (true, 15),
    (false, 120),
];
/// Well inside the watchdog's timeout, which the loop feeds between steps.
const FATAL_STEP_MS: u32 = 10;

/// A boot failure, for good: the motors off, the LED blinking [`FATAL_BLINK`] and the
/// reason in the defmt log again on every round (a probe attached later still sees it),
/// until the power goes.
///
/// The watchdog is already running when the boot can fail and the IWDG cannot be stopped
/// once started. Left alone, it would reset the chip within its timeout, the boot would fail
/// the same way, and the chip would loop through resets, each boot reporting a watchdog
/// reset (a stalled force loop) that never happened. So this loop feeds it: with the
/// interrupts off nothing else runs, so there is no force loop whose stall the feeding could
/// hide, and the motors are switched off again on every round.
fn fatal(what: &str) -> ! {
    halt_for_good(|| {
        defmt::error!(
            "FATAL {=str}; motors off, halted (power-cycle to retry)",
            what
        )
    })
}

/// [`fatal`]'s loop, with `say` logging the reason on every round.
fn halt_for_good(say: impl Fn()) -> ! {
    cortex_m::interrupt::disable();
    loop {
        motors::motors_off();
        say();
        for (on, steps) in FATAL_BLINK {
            if on {
                led_on();
            } else {
                led_off();
            }
            for _ in 0..steps {
                watchdog::feed_now();
                cortex_m::asm::delay(SYSCLK_HZ / 1000 * FATAL_STEP_MS);
            }
        }
    }
}

#[cortex_m_rt::exception]
unsafe fn HardFault(ef: &cortex_m_rt::ExceptionFrame) -> ! {
    motors::motors_off();
    led_on();
    keep_reset_reason(REASON_HARDFAULT);
    defmt::error!("FATAL HardFault at pc={=u32:#010x}; motors off", ef.pc());
    // Spin: the watchdog resets the chip and the next boot reports it.
    loop {
        core::hint::spin_loop();
    }
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    cortex_m::interrupt::disable();
    motors::motors_off();
    led_on();
    keep_reset_reason(REASON_PANIC);
    let (file, line) = info.location().map_or(("?", 0), |l| (l.file(), l.line()));
    let message = defmt::Display2Format(&info.message());
    // Before the force loop runs, a reset would only panic again: the same end as a fatal
    // boot error (motors off, the LED's pattern, the reason repeated), no reset loop.
    if !LOOP_STARTED.load(Ordering::Relaxed) {
        halt_for_good(|| {
            defmt::error!(
                "FATAL panic at boot, at {=str}:{=u32}: {}; motors off, halted (power-cycle to retry)",
                file,
                line,
                message
            )
        });
    }
    defmt::error!(
        "FATAL panic at {=str}:{=u32}: {}; motors off",
        file,
        line,
        message
    );
    // With a debugger attached (probe-rs run), stop here so it shows where; without one the
    // watchdog resets the chip and the next boot reports it.
    // SAFETY: reads the debug halting control register.
    let debugger = unsafe { (*cortex_m::peripheral::DCB::PTR).dhcsr.read() } & 1 != 0;
    if debugger {
        cortex_m::asm::bkpt();
    }
    loop {
        core::hint::spin_loop();
    }
}
