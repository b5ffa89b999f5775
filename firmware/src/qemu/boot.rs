//! The QEMU board's boot: the mode from the semihosting command line
//! (`-semihosting-config enable=on,target=native,arg=maobi-fw,arg=MODE,...`):
//!
//! * `run` (default): the device. The force loop ticks at 1 kHz; the link task talks to the
//!   host over UART0.
//! * `selftest [TICKS]`: no link; the pen follows the built-in bench stroke through the real
//!   force loop, timer interrupt and executor, then prints a summary and exits 0.
//! * `tick_us=N` anywhere on the line: a force-loop period other than 1000 us. The brush
//!   still advances 1 ms of model time per tick; this only paces it, for emulated runs
//!   where a tick costs more instructions than a virtual millisecond holds (see the README).
//! * `state_hz=N` (1..=1000): state frames per 1000 force-loop ticks (default 120; 1000 sends
//!   every tick's state, for the bit-exact HIL checks).
//! * `telemetry_ticks=N`: telemetry every N force-loop ticks (default 1000).
//! * `lockstep` anywhere on the line: the force loop ticks exactly once per pose the host
//!   sends, and holds (no tick, no state, not an overrun, not a stall) until the next pose
//!   is queued and the last state is on its way, so that every tick's state reaches the host
//!   (see [`crate::qemu`]'s "Lock-step"). For comparisons with the host's simulator that
//!   must not depend on how fast QEMU or the host runs. A link timeout is counted in ticks,
//!   so it cannot fall due while the host is silent: not for the link-cut tests.
//! * `bench SHIFT [profile|cycles]`: measures the force loop with interrupts masked and
//!   prints `BENCH` lines (see [`crate::app::bench`]); `SHIFT` is QEMU's `-icount` shift.
//!   `profile` and `cycles` run the presets' brush alone, short enough to log every
//!   executed instruction (`cycles` brackets each tick and a state fill with trace markers).
//! * `arith`: checks the fixed-point operators' inline assembly against their portable
//!   references on this core, prints `ARITH` lines (see [`crate::app::arith`]) and exits 0
//!   when every case agrees, 1 otherwise.
//! * `crash panic|hardfault|stall|starve`: test hooks for the fault paths, only in images
//!   built with the `test-hooks` feature (`maobi-fw-hooks`); without it the line boots as
//!   `run`. `stall`: the force loop never returns from a tick; `starve`: a thread-mode task
//!   never yields (the interrupts, the force tick among them, run on; the supervisor never
//!   checks in again).

use core::fmt::Write;
use core::sync::atomic::Ordering;

use embassy_executor::Spawner;
use embassy_time::Timer;
use maobi_shared::{presets, Fx};

use maobi_shared::force::PHANTOM_OMNI;
use maobi_shared::params::TickLimits;
use maobi_shared::protocol::Capabilities;

use crate::app::{self, bench, Command, SNAPSHOT};
use crate::host_link::{self, BoardInfo, LinkParts};
use crate::qemu::{self, semihosting, semihosting::Stdout};

/// What the link says about this board.
static BOARD: BoardInfo = BoardInfo {
    name: "qemu-mps2-an386",
    // Forces are computed and reported in state frames; the QEMU board drives no motor.
    // Its configuration store is RAM the host can preload (`qemu::config_store`).
    capabilities: Capabilities::VIRTUAL_PEN
        .union(Capabilities::FORCE_OUTPUT)
        .union(Capabilities::STORED_CONFIG),
    force_peak_n: PHANTOM_OMNI.peak_n,
    force_continuous_n: PHANTOM_OMNI.continuous_n,
    // The presets' rate: CI checks it bit for bit against the host simulation, and QEMU has
    // no real-time deadline.
    limits: TickLimits::NONE,
};

/// The same board standing in for the pen (boot argument `limits=pen`): the pen's tick
/// limits, so that a host or a test meets the refusals the pen gives.
static BOARD_AS_PEN: BoardInfo = BoardInfo {
    limits: crate::board::PEN_TICK_LIMITS,
    ..BOARD
};

enum Mode {
    Run,
    Selftest(u32),
    /// `bench SHIFT [profile|cycles]`.
    Bench(u32, bench::BenchScope),
    Arith,
    /// Test hooks: `crash panic|hardfault|stall|starve` after the force loop has started.
    #[cfg(feature = "test-hooks")]
    Crash(&'static str),
}

/// Force-loop period: 1000 us (1 kHz) unless the command line says `tick_us=N`.
fn tick_us() -> u32 {
    let mut buf = [0u8; 128];
    let line = semihosting::cmdline(&mut buf);
    line.split_ascii_whitespace()
        .find_map(|w| w.strip_prefix("tick_us=")?.parse().ok())
        .filter(|&us| (100..=100_000).contains(&us))
        .unwrap_or(1000)
}

/// Whether the word `flag` stands on its own on the command line.
fn arg_flag(flag: &str) -> bool {
    let mut buf = [0u8; 128];
    let line = semihosting::cmdline(&mut buf);
    line.split_ascii_whitespace().skip(1).any(|w| w == flag)
}

/// `KEY=WORD` from the command line: `Some(WORD)` if it is one of `words`.
fn arg_word(key: &str) -> Option<&'static str> {
    const WORDS: [&str; 2] = ["script", "pen"];
    let mut buf = [0u8; 128];
    let line = semihosting::cmdline(&mut buf);
    let value = line
        .split_ascii_whitespace()
        .find_map(|w| w.strip_prefix(key)?.strip_prefix('='))?;
    WORDS.into_iter().find(|&w| w == value)
}

/// `KEY=N` from the command line, if present and within `range`.
fn arg_num(key: &str, range: core::ops::RangeInclusive<u32>) -> Option<u32> {
    let mut buf = [0u8; 128];
    let line = semihosting::cmdline(&mut buf);
    line.split_ascii_whitespace()
        .find_map(|w| w.strip_prefix(key)?.strip_prefix('=')?.parse().ok())
        .filter(|v| range.contains(v))
}

fn boot_mode() -> Mode {
    let mut buf = [0u8; 128];
    let line = semihosting::cmdline(&mut buf);
    let mut words = line.split_ascii_whitespace().skip(1);
    let num = |w: Option<&str>, d: u32| w.and_then(|s| s.parse().ok()).unwrap_or(d);
    match words.next() {
        Some("bench") => {
            let shift = num(words.next(), 0);
            let scope = match words.next() {
                Some("profile") => bench::BenchScope::Profile,
                Some("cycles") => bench::BenchScope::Cycles,
                _ => bench::BenchScope::Full,
            };
            Mode::Bench(shift, scope)
        }
        Some("arith") => Mode::Arith,
        Some("selftest") => Mode::Selftest(num(words.next(), bench::STROKE_TICKS)),
        #[cfg(feature = "test-hooks")]
        Some("crash") => Mode::Crash(match words.next() {
            Some("hardfault") => "hardfault",
            Some("stall") => "stall",
            Some("starve") => "starve",
            _ => "panic",
        }),
        _ => Mode::Run,
    }
}

/// The board's `main`, called by the entry point of the bins `maobi-fw` and `maobi-fw-hooks`:
/// the boot mode from the command line, then the force loop and the tasks, for ever.
pub fn main() -> ! {
    let mode = boot_mode();
    if let Mode::Bench(shift, scope) = mode {
        run_bench(shift, scope);
    }
    if let Mode::Arith = mode {
        let mismatches = app::arith::run(&mut Stdout);
        semihosting::exit(u32::from(mismatches != 0));
    }
    // Everything built at boot is built in `start`'s frame, which is gone before the executor
    // runs: `main` never returns, so what its own frame held would sit under the tasks' and
    // the interrupts' stack for good (the brush and the force loop are kilobytes each).
    let (parts, tick_us, link_cfg) = start();

    crate::executor::run(move |spawner: Spawner| {
        spawner.spawn(
            app::supervisor(tick_us, qemu::motors_off, report_stack, report_feed_gap)
                .expect("one supervisor"),
        );
        match mode {
            #[cfg(feature = "test-hooks")]
            Mode::Crash(how) => spawner.spawn(crash(parts, how).expect("one crash task")),
            Mode::Selftest(ticks) => {
                spawner.spawn(selftest(parts, ticks).expect("one selftest"));
            }
            _ => {
                spawner.spawn(link_task(parts, link_cfg).expect("one link task"));
            }
        }
    })
}

/// `bench SHIFT [profile|cycles]`: the per-tick counts, interrupts masked, then exit.
#[inline(never)]
fn run_bench(shift: u32, scope: bench::BenchScope) -> ! {
    let clk = qemu::IcountCounter;
    let _ = writeln!(Stdout, "BENCH icount_shift={shift}");
    qemu::time_driver::init();
    cortex_m::interrupt::free(|_| bench::run(&clk, &mut Stdout, scope));
    let _ = writeln!(Stdout, "BENCH done");
    semihosting::exit(0);
}

/// The brush, the force loop and the board, from the command line's settings (see `main`
/// for why not inline).
#[inline(never)]
fn start() -> (qemu::Parts, u32, host_link::LinkConfig) {
    let tick_us = tick_us();
    if let Some(hz) = arg_num("state_hz", 1..=1000) {
        app::STATE_HZ.store(hz, Ordering::Relaxed);
    }
    let link_cfg = host_link::LinkConfig {
        tick_us,
        telemetry_ticks: arg_num("telemetry_ticks", 10..=100_000).unwrap_or(1000),
    };
    let parts = qemu::start(
        presets::LARGE,
        bench::stroke_pose(0),
        tick_us,
        arg_flag("lockstep"),
        arg_word("poses") == Some("script"),
    );
    defmt::info!("maobi-fw up");
    (parts, tick_us, link_cfg)
}

#[embassy_executor::task]
async fn link_task(parts: qemu::Parts, cfg: host_link::LinkConfig) {
    let parts = LinkParts {
        transport: parts.uart,
        poses: Some(parts.poses),
        cmds: parts.cmds,
        store: parts.config,
    };
    let board = if arg_word("limits") == Some("pen") {
        &BOARD_AS_PEN
    } else {
        &BOARD
    };
    host_link::run(parts, board, board.brush(presets::LARGE), cfg).await
}

/// Test hooks for the fault paths: motors on, then a panic, a HardFault, a force loop that
/// never returns, or a thread mode that never yields (the watchdog's two cases).
#[cfg(feature = "test-hooks")]
#[embassy_executor::task]
async fn crash(mut parts: qemu::Parts, how: &'static str) {
    let _ = parts.cmds.enqueue(Command::EnableForces);
    Timer::after_millis(20).await;
    match how {
        "hardfault" => {
            // An undefined instruction: UsageFault, escalated to HardFault (not enabled).
            // SAFETY: deliberately faults.
            unsafe { core::arch::asm!("udf #0") };
        }
        "stall" => {
            let _ = parts.cmds.enqueue(Command::Stall);
        }
        "starve" => loop {
            // Thread mode taken for good: this task never yields, so the executor never
            // polls the supervisor again, while every interrupt still runs.
            core::hint::spin_loop();
        },
        _ => panic!("crash test"),
    }
    Timer::after_millis(1000).await;
    let _ = writeln!(Stdout, "crash {how}: still running");
    semihosting::exit(0);
}

/// Boot test without a link: the bench stroke through the real force loop.
#[embassy_executor::task]
async fn selftest(mut parts: qemu::Parts, ticks: u32) {
    let _ = parts.cmds.enqueue(Command::EnableForces);
    let mut k = 1;
    let mut done = 0;
    let mut snap_tick = 0;
    let mut tip = [0i64; 3];
    let mut contacts = 0;
    let start = embassy_time::Instant::now();
    while done < ticks {
        while k <= ticks && parts.poses.ready() {
            let _ = parts.poses.enqueue(app::PoseIn {
                seq: k,
                pose: bench::stroke_pose(k),
                guide: None,
            });
            k += 1;
        }
        SNAPSHOT.request();
        Timer::after_millis(5).await;
        if let Some(Some((b, t, c, tk))) = SNAPSHOT.take(|s| {
            // The spine rebuilt from the state frame, bit for bit as the host rebuilds it.
            let shape = s.state.shape();
            let spine = shape.spine();
            let tip = spine.last()?;
            Some((
                s.brush_tick,
                [um(tip.x), um(tip.y), um(tip.z)],
                spine.iter().filter(|p| p.z.to_bits() <= 429_497).count(),
                s.state.tick,
            ))
        }) {
            done = b;
            tip = t;
            contacts = contacts.max(c);
            snap_tick = tk;
        }
    }
    let _ = writeln!(
        Stdout,
        "selftest: brush_ticks={done} force_ticks={snap_tick} elapsed_us={} tip_um=({}, {}, {}) max_masses_on_paper={contacts} faults={:#x} overruns={}",
        start.elapsed().as_micros(),
        tip[0],
        tip[1],
        tip[2],
        app::FAULTS.load(Ordering::SeqCst),
        app::OVERRUNS.load(Ordering::Relaxed),
    );
    semihosting::exit(0);
}

/// A new deepest stack reading (`app::stack`), as plain text on stdout for the host
/// (`hil`'s stack test) and in the log.
fn report_stack(used: usize) {
    let _ = writeln!(Stdout, "STACK high_water_bytes={used}");
    defmt::info!("stack high-water mark: {=usize} bytes", used);
}

/// A new longest gap between two watchdog feeds (`app::FEED_GAP_MAX_TICKS`), as plain text
/// on stdout for the host (`hil`'s watchdog tests) and in the log.
fn report_feed_gap(ticks: u32) {
    let _ = writeln!(Stdout, "WATCHDOG feed_gap_max_ticks={ticks}");
    defmt::info!("longest gap between watchdog feeds: {=u32} ticks", ticks);
}

/// Micrometres, rounded toward -inf (integer output keeps float formatting out of the image).
fn um(v: Fx) -> i64 {
    ((v.to_bits() as i128 * 1000) >> 32) as i64
}
