//! The watchdog at the pen's pace: fed by the force tick only after the thread-mode
//! supervisor has checked in (`firmware/src/app/mod.rs`, the same code on both boards), it
//! must never fire on a live pen, quiet link or busy, and must fire when thread mode stops.
//!
//! QEMU runs the pen's pace deterministically ([`QemuDevice::start_paced_like_the_pen`]:
//! `-icount shift=4,sleep=off`, the 1 ms tick), so virtual time comes from the instruction
//! count alone and a host that is slow or busy cannot make it jump. The QEMU board's
//! watchdog is TIMER1 (`firmware/src/qemu/mod.rs`): when it fires, the firmware turns the
//! motors off, prints `FATAL watchdog: ...` and QEMU exits with status 3, where the Black
//! Pill's IWDG resets the chip.
//!
//! Nothing is timed by the wall clock: the pen's ticks are counted from its telemetry, and
//! every wait is for a message, under a hang guard only.

use std::net::TcpStream;
use std::time::Duration;

use hil::firmware;
use hil::qemu::{Clock, Run};
use hil::run::{QemuDevice, PEN_ICOUNT_SHIFT, PEN_TICK_US};
use hil::session::Session;
use maobi_shared::protocol::{DeviceMsg, Faults, Telemetry};

const TIMEOUT: Duration = Duration::from_secs(900);
/// Only a guard against a hang, far longer than any message takes on a loaded machine.
const HANG_GUARD: Duration = Duration::from_secs(120);
/// Pen ticks each live run lasts (virtual time: 20 s at 1 kHz).
const RUN_TICKS: u32 = 20_000;
/// The firmware's `app::WATCHDOG_MIN_TICKS`: the watchdog's timeout in ticks on the QEMU
/// board (five of the supervisor's 10-tick check-in periods).
const WATCHDOG_TICKS: u64 = 50;

/// What one live run saw.
struct Seen {
    ticks: u32,
    telemetry: usize,
    states: usize,
    pongs: u32,
    faults: Faults,
    /// The longest gap between two feeds the firmware reported (ticks).
    feed_gap_max: u64,
}

/// Runs the production image at the pen's pace with `args` for [`RUN_TICKS`] pen ticks
/// after the handshake, pinging back to back when `busy` (each ping sent as the last one's
/// pong arrives); then checks that QEMU is still running and never printed a FATAL.
fn live_run(args: &[&str], busy: bool) -> Option<Seen> {
    let elf = firmware::qemu_test_image()?;
    let (mut dev, stream) = QemuDevice::start_paced_like_the_pen(&elf, args, TIMEOUT).unwrap();
    let mut s: Session<TcpStream> = Session::new(stream).unwrap();
    s.handshake(HANG_GUARD, &mut vec![]).unwrap();
    let mut seen = Seen {
        ticks: 0,
        telemetry: 0,
        states: 0,
        pongs: 0,
        faults: Faults::empty(),
        feed_gap_max: 0,
    };
    let mut first: Option<u32> = None;
    let mut ping = 0u32;
    if busy {
        ping += 1;
        s.send(&maobi_shared::protocol::HostMsg::Ping { seq: ping })
            .unwrap();
    }
    while seen.ticks < RUN_TICKS {
        let Ok(Some(r)) = s.recv(HANG_GUARD) else {
            let (st, out) = dev.guest.stop().unwrap();
            panic!(
                "the pen fell silent after {} ticks ({st:?}): {out}",
                seen.ticks
            );
        };
        match r.msg {
            DeviceMsg::Telemetry(Telemetry { tick, .. }) => {
                seen.telemetry += 1;
                seen.ticks = tick.wrapping_sub(*first.get_or_insert(tick));
            }
            DeviceMsg::State(st) => {
                seen.states += 1;
                seen.faults |= st.faults;
            }
            DeviceMsg::Event(e) => seen.faults |= e.faults,
            DeviceMsg::Pong { seq } if busy && seq == ping => {
                seen.pongs += 1;
                ping += 1;
                s.send(&maobi_shared::protocol::HostMsg::Ping { seq: ping })
                    .unwrap();
            }
            _ => {}
        }
    }
    let (exited, out) = dev.guest.stop().unwrap();
    assert_eq!(exited, None, "QEMU exited during the run: {out}");
    assert!(!out.contains("FATAL"), "{out}");
    seen.feed_gap_max = out
        .lines()
        .filter_map(|l| l.strip_prefix("WATCHDOG feed_gap_max_ticks="))
        .filter_map(|n| n.trim().parse().ok())
        .max()
        .unwrap_or(0);
    // The supervisor reports each new maximum once a second (so a maximum in the run's last
    // second may go unreported); at least the boot's first gap was reported.
    assert!(seen.feed_gap_max > 0, "no feed gap reported: {out}");
    Some(seen)
}

/// Checks common to the live runs: many seconds of virtual time, the watchdog never fired
/// (neither the hardware's reset nor the supervisor's latched fault), and the longest gap
/// between two feeds well inside the timeout.
fn check_live(what: &str, seen: &Seen) {
    println!(
        "WATCHDOG {what}: {} pen ticks, {} telemetry, {} states, {} pongs, faults {:?}, \
         longest gap between feeds {} ticks of the {WATCHDOG_TICKS}-tick timeout",
        seen.ticks, seen.telemetry, seen.states, seen.pongs, seen.faults, seen.feed_gap_max
    );
    assert!(seen.ticks >= RUN_TICKS);
    assert!(!seen.faults.contains(Faults::WATCHDOG), "{:?}", seen.faults);
    // Most of the margin the timeout was chosen for stays unspent (a live thread mode keeps
    // the supervisor waiting about one check-in period at most, beside its own).
    assert!(
        seen.feed_gap_max <= WATCHDOG_TICKS * 3 / 5,
        "{what}: feeds {} ticks apart",
        seen.feed_gap_max
    );
}

/// A quiet link: after the handshake the host sends nothing, and the pen one state and one
/// telemetry a second, so thread mode sleeps nearly all the time and the supervisor must be
/// woken by its own timer (the time driver's alarm) to check in.
#[test]
fn a_quiet_link_at_the_pens_pace_never_trips_the_watchdog() {
    let Some(seen) = live_run(&["state_hz=1", "telemetry_ticks=1000"], false) else {
        return;
    };
    check_live("quiet link", &seen);
}

/// A quiet host at a busy pen: the pen writes the bench stroke itself (a pose every tick,
/// the brush ticking every tick as with its own sensors) and sends its states at the default
/// rate, and the host sends nothing after the handshake. Thread mode then runs slower than
/// the states fall due, so the link task always has work: it must still hand the executor
/// back to the supervisor (it once did so only after a message from the host, and this run
/// ended in the watchdog within a tenth of a second).
#[test]
fn a_quiet_host_at_a_busy_pen_never_trips_the_watchdog() {
    let Some(seen) = live_run(&["poses=script", "telemetry_ticks=1000"], false) else {
        return;
    };
    check_live("quiet host, busy pen", &seen);
}

/// A busy link: as [`a_quiet_host_at_a_busy_pen_never_trips_the_watchdog`], with telemetry
/// four times a second, and the host pinging back to back (each ping sent as the last one's
/// pong arrives).
#[test]
fn a_busy_link_at_the_pens_pace_never_trips_the_watchdog() {
    let Some(seen) = live_run(&["poses=script", "telemetry_ticks=250"], true) else {
        return;
    };
    check_live("busy link", &seen);
    assert!(seen.pongs > 100, "{} pongs", seen.pongs);
}

/// The two ways the watchdog fires, at the pen's pace, through the test hooks (the hooks
/// image only): a thread-mode task that never yields (`crash starve`: the force tick runs
/// on, the supervisor never checks in again) and a force tick that never returns
/// (`crash stall`). Each ends with the motors off and the watchdog named, the cause told
/// apart.
#[test]
fn a_starved_thread_mode_or_a_stalled_force_loop_fires_the_watchdog() {
    let Some(elf) = firmware::qemu_test_hooks_image() else {
        return;
    };
    let tick = format!("tick_us={PEN_TICK_US}");
    for (how, cause) in [
        ("starve", "thread mode stopped"),
        ("stall", "the force loop stopped"),
    ] {
        let (status, out) = Run::new(
            &elf,
            &["crash", how, &tick],
            Clock::Deterministic {
                shift: PEN_ICOUNT_SHIFT,
            },
            Duration::from_secs(120),
        )
        .output()
        .unwrap();
        println!("WATCHDOG crash {how}: {status}: {}", out.trim());
        assert_eq!(status.code(), Some(3), "{how}: {out}");
        assert!(
            out.contains(&format!("FATAL watchdog: {cause}")) && out.contains("motors off"),
            "{how}: {out}"
        );
        assert!(!out.contains("still running"), "{how}: {out}");
    }
}
