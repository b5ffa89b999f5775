//! `hil run`: a pose file through the device, every state checked against the host
//! simulation bit for bit.

use std::net::TcpStream;
use std::path::Path;
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use maobi::poses::PoseTrack;
use maobi_shared::presets;
use maobi_shared::protocol::Capabilities;

use crate::qemu::{Clock, Guest, Run};
use crate::selftest::EMULATED_TICK_US;
use crate::session::{self, Session, StreamLog, StreamOptions, Transport};

/// The `-icount` shift at which QEMU runs the pen's instruction rate: shift N gives every
/// instruction 2^N ns of virtual time, and the Black Pill's Cortex-M4 at 96 MHz is expected
/// (issue #48; not yet measured on a board) to retire an instruction every 1.4 to 1.8 cycles
/// on this firmware's code (64-bit fixed-point arithmetic: multiplies, loads, taken branches
/// and flash wait states that take more than a cycle), 53 to 69 million a second. Shift 4
/// (16 ns: 62.5 million a second, 96 MHz at 1.54 cycles an instruction) is the only shift in
/// that band: shift 3 would be a core at 0.77 cycles an instruction, faster than any M4,
/// shift 5 one at 3.1. A 1 ms tick then holds 62,500 instructions, and the ~48,000 of the
/// presets' worst tick (`hil bench`) leave about a fifth for the link. Were the pen nearer
/// one cycle an instruction (`docs/firmware-cost.md`'s older estimate), this pace is the
/// stricter one: what fits here fits there.
pub const PEN_ICOUNT_SHIFT: u32 = 4;

/// The pen's force-loop period (us): its real 1 kHz tick, not [`EMULATED_TICK_US`].
pub const PEN_TICK_US: u32 = 1000;

/// A firmware image running in QEMU with UART0 on a loopback socket.
pub struct QemuDevice {
    pub guest: Guest,
    pub port: u16,
}

impl QemuDevice {
    /// Starts QEMU (`-icount shift=0,sleep=off`, the force loop paced at
    /// [`EMULATED_TICK_US`]) with `extra` boot arguments, and connects to its UART0.
    pub fn start(elf: &Path, extra: &[&str], timeout: Duration) -> Result<(Self, TcpStream)> {
        Self::start_with(elf, extra, &[], timeout)
    }

    /// As [`Self::start`], with further QEMU arguments (`qemu_args`, e.g.
    /// [`crate::qemu::config_loader_args`]).
    pub fn start_with(
        elf: &Path,
        extra: &[&str],
        qemu_args: &[String],
        timeout: Duration,
    ) -> Result<(Self, TcpStream)> {
        Self::start_at_shift(elf, 0, extra, qemu_args, timeout)
    }

    /// As [`Self::start_with`] at `-icount shift=SHIFT,sleep=off`: a virtual millisecond
    /// holds 2^SHIFT times fewer instructions, so the force loop is paced 2^SHIFT times
    /// slower ([`EMULATED_TICK_US`] at shift 0) and keeps the same share of each tick.
    pub fn start_at_shift(
        elf: &Path,
        shift: u32,
        extra: &[&str],
        qemu_args: &[String],
        timeout: Duration,
    ) -> Result<(Self, TcpStream)> {
        Self::start_clocked(
            elf,
            shift,
            EMULATED_TICK_US << shift,
            extra,
            qemu_args,
            timeout,
        )
    }

    /// As [`Self::start`] at the pen's own pace: `-icount shift=`[`PEN_ICOUNT_SHIFT`]`,
    /// sleep=off` and the pen's 1 ms tick ([`PEN_TICK_US`]), so that a tick holds as many
    /// instructions as the Black Pill runs in 1 ms and one dearer than that overruns here as
    /// it would there.
    pub fn start_paced_like_the_pen(
        elf: &Path,
        extra: &[&str],
        timeout: Duration,
    ) -> Result<(Self, TcpStream)> {
        Self::start_clocked(elf, PEN_ICOUNT_SHIFT, PEN_TICK_US, extra, &[], timeout)
    }

    /// Starts QEMU at `-icount shift=SHIFT,sleep=off` with the force loop ticking every
    /// `tick_us` of virtual time.
    pub fn start_clocked(
        elf: &Path,
        shift: u32,
        tick_us: u32,
        extra: &[&str],
        qemu_args: &[String],
        timeout: Duration,
    ) -> Result<(Self, TcpStream)> {
        let tick = format!("tick_us={tick_us}");
        let mut args = vec!["run", tick.as_str()];
        args.extend_from_slice(extra);
        let mut run = Run::new(elf, &args, Clock::Deterministic { shift }, timeout);
        let port = run.listen_uart()?;
        run.qemu_args = qemu_args.to_vec();
        let guest = run.spawn()?;
        let mut dev = QemuDevice { guest, port };
        let stream = dev.connect(Duration::from_secs(20))?;
        Ok((dev, stream))
    }

    /// Connects (again) to the UART socket, retrying until QEMU listens.
    pub fn connect(&mut self, within: Duration) -> Result<TcpStream> {
        let end = Instant::now() + within;
        loop {
            match TcpStream::connect(("127.0.0.1", self.port)) {
                Ok(s) => {
                    s.set_nodelay(true)?;
                    return Ok(s);
                }
                Err(e) => {
                    if let Some(st) = self.guest.child.try_wait()? {
                        bail!("QEMU exited ({st}) before the link opened");
                    }
                    if Instant::now() >= end {
                        return Err(e).context("cannot connect to QEMU's UART0 socket");
                    }
                    std::thread::sleep(Duration::from_millis(20));
                }
            }
        }
    }
}

/// One check's outcome.
#[derive(Clone, Debug)]
pub struct Check {
    pub name: String,
    pub pass: bool,
    pub detail: String,
}

impl std::fmt::Display for Check {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let v = if self.pass { "PASS" } else { "FAIL" };
        write!(f, "{v} {}: {}", self.name, self.detail)
    }
}

/// The outcome of a run.
pub struct RunReport {
    /// The firmware's own defmt log, where the backend decodes it (QEMU).
    pub defmt_log: Vec<String>,
    pub checks: Vec<Check>,
    pub figures: session::Figures,
    pub round_trip: Vec<Duration>,
    pub log: StreamLog,
}

impl RunReport {
    pub fn passed(&self) -> bool {
        self.checks.iter().all(|c| c.pass)
    }
    pub fn render(&self) -> String {
        use std::fmt::Write;
        let mut s = String::new();
        if !self.defmt_log.is_empty() {
            render_log(&mut s, &self.defmt_log);
        }
        for c in &self.checks {
            let _ = writeln!(s, "{c}");
        }
        let f = &self.figures;
        let rt: Vec<f64> = self
            .round_trip
            .iter()
            .map(|d| d.as_secs_f64() * 1e3)
            .collect();
        let rt_mean = rt.iter().sum::<f64>() / rt.len().max(1) as f64;
        let rt_max = rt.iter().cloned().fold(0.0, f64::max);
        let _ = write!(
            s,
            "states={} per_s_wall={:.0} per_s_device={:.1} bytes_per_state mean={:.0} max={} \
             link_share_at_120hz_of_1MBps={:.1}% ping_round_trip_ms mean={rt_mean:.2} max={rt_max:.2}",
            f.states,
            f.states_per_s_wall,
            f.states_per_device_s,
            f.state_bytes_mean,
            f.state_bytes_max,
            f.link_share_at_120hz * 100.0
        );
        s
    }
}

/// Handshake, a few pings, the stream, the comparison. `base`: the first pose's seq.
pub fn run_session<T: Transport>(
    s: &mut Session<T>,
    track: &PoseTrack,
    opts: StreamOptions,
) -> Result<RunReport> {
    let poses = session::track_poses(track);
    let sim = session::simulate(presets::LARGE, &poses)?;
    let mut log = StreamLog::default();
    let info = s.handshake(Duration::from_secs(10), &mut log.received)?;
    let mut checks = vec![Check {
        name: "handshake".into(),
        pass: true,
        detail: format!(
            "protocol {} firmware {} board {} capabilities {:?} force peak {} N continuous {} N",
            info.protocol_version,
            info.firmware,
            info.board,
            info.capabilities,
            info.force_peak_n,
            info.force_continuous_n
        ),
    }];
    if !info.capabilities.contains(Capabilities::VIRTUAL_PEN) {
        // A pen that reads its own sensors ignores host poses: the pose file cannot be
        // compared with the simulation; its link and loop are checked instead.
        return sensor_pen_checks(s, checks, log, SENSOR_PEN_LISTEN);
    }
    let mut round_trip = vec![];
    for seq in 0..5 {
        round_trip.push(s.ping(seq, Duration::from_secs(5), &mut log.received)?);
    }
    let base = opts.base;
    session::stream(s, &poses, opts, &mut log)?;
    let cmp = session::compare(&log, base, &sim);
    checks.push(Check {
        name: "states bit-identical to the host simulation".into(),
        pass: cmp.mismatches.is_empty() && cmp.compared > 0,
        detail: format!(
            "{} states over {} of {} ticks compared, {} mismatches{}",
            cmp.compared,
            cmp.ticks,
            sim.len(),
            cmp.mismatches.len(),
            cmp.mismatches
                .first()
                .map(|(k, w)| format!(" (first at tick {k}: {w})"))
                .unwrap_or_default()
        ),
    });
    let last = log.states().last().map(|(_, st)| st.pose_seq);
    checks.push(Check {
        name: "every pose consumed".into(),
        pass: last == Some(base + poses.len() as u32 - 1),
        detail: format!(
            "last state after pose seq {last:?}, {} poses sent",
            log.sent
        ),
    });
    checks.push(Check {
        name: "host decoder clean".into(),
        pass: s.errors.is_empty(),
        detail: format!("{} frames dropped by the host decoder", s.errors.len()),
    });
    Ok(RunReport {
        defmt_log: Vec::new(),
        figures: session::figures(&log),
        checks,
        round_trip,
        log,
    })
}

/// How long a pen with its own sensors is listened to.
pub const SENSOR_PEN_LISTEN: Duration = Duration::from_secs(3);

/// The checks of a pen that reads its own sensors (it takes no poses from the host): pings,
/// then `listen` of its stream: brush states keep coming, a telemetry report says the force
/// loop holds its 1 ms tick (mean within 1%, no tick longer than 1.5 ms, no overrun since
/// start, no tick's work above 90% of it), and both ends' decoders are clean.
pub fn sensor_pen_checks<T: Transport>(
    s: &mut Session<T>,
    mut checks: Vec<Check>,
    mut log: StreamLog,
    listen: Duration,
) -> Result<RunReport> {
    checks.push(Check {
        name: "pose file".into(),
        pass: true,
        detail: "not streamed: this pen reads its own sensors (no VIRTUAL_PEN); its link and \
                 force loop are checked instead"
            .into(),
    });
    let mut round_trip = vec![];
    for seq in 0..5 {
        round_trip.push(s.ping(seq, Duration::from_secs(5), &mut log.received)?);
    }
    log.started = Some(Instant::now());
    let end = Instant::now() + listen;
    while Instant::now() < end {
        if let Some(r) = s.recv(Duration::from_millis(20))? {
            log.received.push(r);
        }
    }
    log.finished = Some(Instant::now());
    let states = log.states().count();
    checks.push(Check {
        name: "brush states stream".into(),
        pass: states > 0,
        detail: format!("{states} states in {:.1} s", listen.as_secs_f64()),
    });
    let t = log.telemetry().last().cloned();
    checks.push(Check {
        name: "force loop holds 1 ms".into(),
        pass: t.as_ref().is_some_and(|t| {
            (990..=1010).contains(&t.tick_period_mean_us) && t.tick_period_max_us <= 1500
        }),
        detail: match &t {
            None => "no telemetry report".into(),
            Some(t) => format!(
                "tick period min/mean/max {}/{}/{} us, load {}%, {} frames dropped",
                t.tick_period_min_us,
                t.tick_period_mean_us,
                t.tick_period_max_us,
                t.load_percent,
                t.frames_dropped
            ),
        },
    });
    let worst = maobi::device::bringup::WORST_TICK_PERCENT;
    checks.push(Check {
        name: "no overrun, worst tick within 90%".into(),
        pass: t
            .as_ref()
            .is_some_and(|t| t.overruns == 0 && t.worst_busy_percent() <= worst),
        detail: match &t {
            None => "no telemetry report".into(),
            Some(t) => format!(
                "worst tick busy {} us ({:.1}%, {} cycles; at most {worst}%), {} overruns since start",
                t.tick_busy_max_us,
                t.worst_busy_percent(),
                t.tick_busy_max_cycles,
                t.overruns
            ),
        },
    });
    let device_rx_clean = t.as_ref().is_some_and(|t| {
        t.rx.crc_errors == 0
            && t.rx.framing_errors == 0
            && t.rx.decode_errors == 0
            && t.rx.version_errors == 0
            && t.rx.oversized_frames == 0
    });
    checks.push(Check {
        name: "decoders clean".into(),
        pass: s.errors.is_empty() && device_rx_clean,
        detail: format!(
            "{} frames dropped by the host decoder; device receiver {}",
            s.errors.len(),
            t.as_ref()
                .map(|t| format!("{:?}", t.rx))
                .unwrap_or_else(|| "not reported".into())
        ),
    });
    Ok(RunReport {
        defmt_log: Vec::new(),
        figures: session::figures(&log),
        checks,
        round_trip,
        log,
    })
}

/// `hil run --backend qemu POSES.csv`.
pub fn run_qemu(elf: &Path, poses: &Path, state_hz: u32, timeout: Duration) -> Result<RunReport> {
    let track = PoseTrack::from_path(poses).map_err(|e| anyhow::anyhow!("{e}"))?;
    let hz = format!("state_hz={state_hz}");
    let (dev, stream) = QemuDevice::start(elf, &[&hz], timeout)?;
    let mut s = Session::new(stream)?;
    let mut r = run_session(&mut s, &track, StreamOptions::default())?;
    // The firmware's log, decoded from QEMU's stderr: booted once, no panic or fault.
    r.defmt_log = dev.guest.defmt_log();
    r.checks.extend(log_checks(
        &r.defmt_log,
        crate::firmware::Board::Qemu.boot_line(),
    ));
    drop(dev);
    Ok(r)
}

/// `hil run --backend serial --port PATH POSES.csv`: the same session over a serial port.
pub fn run_serial(port: &Path, poses: &Path) -> Result<RunReport> {
    let track = PoseTrack::from_path(poses).map_err(|e| anyhow::anyhow!("{e}"))?;
    let io = crate::serial::open(port)?;
    let mut s = Session::new(io)?;
    run_session(&mut s, &track, StreamOptions::default())
}

/// A defmt log's last 20 lines under a heading with the count, for a run's report.
pub fn render_log(s: &mut String, log: &[String]) {
    use std::fmt::Write;
    let shown = log.len().saturating_sub(20);
    let _ = writeln!(
        s,
        "defmt log ({} lines{}):",
        log.len(),
        if shown > 0 { ", the last 20" } else { "" }
    );
    for l in &log[shown..] {
        let _ = writeln!(s, "  {l}");
    }
}

/// The checks of a defmt log (probe-rs's stdout, QEMU's decoded stderr): the boot line exactly once (twice means
/// the pen restarted during the run: watchdog, brown-out, a fault handler's reset), and no
/// panic or fault. Records may carry a timestamp and a level before the message.
pub fn log_checks(lines: &[String], boot_line: &str) -> Vec<Check> {
    // Location lines (`└─ module @ file:line`), if a probe-rs prints them anyway, name
    // functions, not events.
    let records: Vec<&str> = lines
        .iter()
        .map(|l| l.trim())
        .filter(|l| !l.is_empty() && !l.starts_with('└'))
        .collect();
    let boots = records.iter().filter(|l| l.contains(boot_line)).count();
    let boot = Check {
        name: "defmt log: the firmware booted once".into(),
        pass: boots == 1,
        detail: match boots {
            0 => format!(
                "`{boot_line}` not in the {} lines of the log (RTT not found, or the firmware \
                 stopped before it)",
                records.len()
            ),
            1 => format!("`{boot_line}` seen, {} log lines", records.len()),
            n => format!("`{boot_line}` seen {n} times: the pen restarted during the run"),
        },
    };
    let faults: Vec<&str> = records
        .iter()
        .copied()
        .filter(|l| is_fault_line(l))
        .collect();
    let clean = Check {
        name: "defmt log: no panic or fault".into(),
        pass: faults.is_empty(),
        detail: match faults.first() {
            None => "no error-level record, panic, fault or stack trace".into(),
            Some(first) => format!("{} such lines, the first: {first}", faults.len()),
        },
    };
    vec![boot, clean]
}

/// An error-level defmt record, a panic, a fault handler's report, or the stack trace
/// probe-rs prints when the core halts (`Frame 0: ...`).
fn is_fault_line(line: &str) -> bool {
    let lower = line.to_lowercase();
    let level_error = line
        .split_whitespace()
        .take(2)
        .any(|w| w.trim_matches(|c| c == '[' || c == ']') == "ERROR");
    level_error
        || lower.contains("panicked")
        || lower.contains("panic:")
        || lower.contains("hardfault")
        || lower.contains("hard fault")
        || lower.contains("locked up")
        || lower.starts_with("frame 0:")
}
