//! Backend `probe-rs`: the firmware flashed onto a board through a debug probe with the
//! `probe-rs` tool, the pose-file checks run over the pen's USB serial port (the `serial`
//! backend's session), and the defmt log read back through RTT checked for the boot line and
//! for panics and faults.
//!
//! `probe-rs run` flashes, resets, and then prints the defmt log while the firmware runs (it
//! needs the ELF for the defmt string table); it is a subprocess here, as QEMU is for the
//! `qemu` backend, so no debug-probe library is linked into the runner. Built and tested
//! against a fake `probe-rs` and a fake pen on a pseudo-terminal (`tests/probe_rs.rs`); not
//! yet run on a board.

use std::io::{BufRead, BufReader, Read};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use maobi::device::{serial_ports, PortInfo};
use maobi::poses::PoseTrack;

use crate::firmware::Board;
use crate::run::{log_checks, render_log, run_session, Check, RunReport};
use crate::session::{Session, StreamOptions};

/// The pen's microcontroller as probe-rs names it (the STM32F411CE "Black Pill").
pub const DEFAULT_CHIP: &str = "STM32F411CEUx";
/// What the pen's firmware logs once it has started: the Black Pill board's boot record
/// (the QEMU image's is `maobi-fw up`).
pub const BOOT_LINE: &str = Board::Blackpill.boot_line();
/// How long the log may lag the link at the end of a run (probe-rs's idle RTT poll is 100 ms).
pub const LOG_SETTLE: Duration = Duration::from_millis(300);
/// How to get the tool, for the error when it is missing.
pub const INSTALL_HINT: &str = "install it with `cargo install probe-rs-tools --locked` \
     (see https://probe.rs/docs/getting-started/installation/), or pass --probe-rs PATH";

/// How to run the backend.
#[derive(Clone, Debug)]
pub struct ProbeRsOptions {
    /// The `probe-rs` executable (`--probe-rs`, else `$MAOBI_PROBE_RS`, else `probe-rs` on
    /// the PATH).
    pub tool: PathBuf,
    /// `--chip` for probe-rs.
    pub chip: String,
    /// `--probe VID:PID[:SERIAL]` for probe-rs, when more than one probe is attached.
    pub probe: Option<String>,
    /// The pen's serial port; `None`: the first port with Maobi's USB IDs.
    pub port: Option<PathBuf>,
    /// How long the pen's port may take to appear after probe-rs starts (flashing included).
    pub port_timeout: Duration,
    /// The defmt line that says the firmware booted.
    pub boot_line: String,
    /// How long probe-rs gets to stop after SIGINT before it is killed.
    pub stop_timeout: Duration,
}

impl ProbeRsOptions {
    pub fn new(tool: Option<PathBuf>) -> Self {
        ProbeRsOptions {
            tool: tool.unwrap_or_else(default_tool),
            chip: DEFAULT_CHIP.into(),
            probe: None,
            port: None,
            port_timeout: Duration::from_secs(30),
            boot_line: BOOT_LINE.into(),
            stop_timeout: Duration::from_secs(5),
        }
    }

    /// The arguments given to probe-rs: `run`, the chip, the probe, the ELF. `--no-location`
    /// keeps each log record on one line (no `└─ module @ file:line` line under it), so the
    /// log checks read messages only.
    pub fn args(&self, elf: &Path) -> Vec<std::ffi::OsString> {
        let mut a: Vec<std::ffi::OsString> =
            vec!["run".into(), "--chip".into(), self.chip.clone().into()];
        if let Some(p) = &self.probe {
            a.push("--probe".into());
            a.push(p.into());
        }
        a.push("--no-location".into());
        a.push(elf.into());
        a
    }
}

/// `$MAOBI_PROBE_RS`, else `probe-rs` (looked up on the PATH).
pub fn default_tool() -> PathBuf {
    std::env::var_os("MAOBI_PROBE_RS")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("probe-rs"))
}

/// Which output of probe-rs a line came from.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub enum Stream {
    /// The defmt log (RTT), and probe-rs's stack trace when the core halts.
    Stdout,
    /// probe-rs's own progress and errors.
    Stderr,
}

/// Lines of a child's output, collected by reader threads as they arrive.
#[derive(Clone, Default)]
pub struct Lines(Arc<Mutex<Vec<(Stream, String)>>>);

impl Lines {
    fn push(&self, s: Stream, line: String) {
        self.0
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .push((s, line));
    }
    pub fn of(&self, s: Stream) -> Vec<String> {
        self.0
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .iter()
            .filter(|(k, _)| *k == s)
            .map(|(_, l)| l.clone())
            .collect()
    }
    /// The last `n` lines of `s`, joined for an error message.
    pub fn tail(&self, s: Stream, n: usize) -> String {
        let v = self.of(s);
        v[v.len().saturating_sub(n)..].join("\n")
    }
}

fn read_lines(r: impl Read + Send + 'static, s: Stream, into: Lines) -> JoinHandle<()> {
    std::thread::spawn(move || {
        // Lossy: a stray byte from the probe must not end the log.
        let mut r = BufReader::new(r);
        let mut buf = Vec::new();
        while let Ok(n) = r.read_until(b'\n', &mut buf) {
            if n == 0 {
                break;
            }
            let line = String::from_utf8_lossy(&buf);
            into.push(s, line.trim_end_matches(['\n', '\r']).to_string());
            buf.clear();
        }
    })
}

/// A running `probe-rs run`; stopped (SIGINT, then killed) when dropped.
pub struct ProbeRun {
    child: Child,
    pub lines: Lines,
    readers: Vec<JoinHandle<()>>,
    stop_timeout: Duration,
    /// The exit status, once it has exited.
    exited: Option<ExitStatus>,
}

impl ProbeRun {
    /// Starts `probe-rs run` on `elf`. A missing tool is an error that says how to install it.
    pub fn start(opts: &ProbeRsOptions, elf: &Path) -> Result<Self> {
        if !elf.is_file() {
            bail!("firmware image {} not found", elf.display());
        }
        let mut child = match Command::new(&opts.tool)
            .args(opts.args(elf))
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
        {
            Ok(c) => c,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => bail!(
                "probe-rs not found (`{}`): {INSTALL_HINT}",
                opts.tool.display()
            ),
            Err(e) => {
                return Err(e).with_context(|| format!("cannot start {}", opts.tool.display()))
            }
        };
        let lines = Lines::default();
        let mut readers = vec![];
        if let Some(o) = child.stdout.take() {
            readers.push(read_lines(o, Stream::Stdout, lines.clone()));
        }
        if let Some(e) = child.stderr.take() {
            readers.push(read_lines(e, Stream::Stderr, lines.clone()));
        }
        Ok(ProbeRun {
            child,
            lines,
            readers,
            stop_timeout: opts.stop_timeout,
            exited: None,
        })
    }

    /// `Some(status)` once probe-rs has exited.
    pub fn exited(&mut self) -> Result<Option<ExitStatus>> {
        if self.exited.is_none() {
            self.exited = self.child.try_wait()?;
        }
        Ok(self.exited)
    }

    /// The error for probe-rs having exited with `status` before the pen came up: no probe,
    /// or a flash (or attach) failure, with probe-rs's own words.
    pub fn failure(&self, status: ExitStatus) -> anyhow::Error {
        // probe-rs's output reaches us through the reader threads; give them a moment.
        std::thread::sleep(Duration::from_millis(50));
        let err = self.lines.tail(Stream::Stderr, 20);
        let lower = err.to_lowercase();
        if lower.contains("no probe") || lower.contains("no connected probe") {
            anyhow::anyhow!(
                "no debug probe found: connect the probe (ST-Link, CMSIS-DAP, J-Link) to the \
                 board's SWD pins and USB, check `probe-rs list` and the udev rule \
                 (firmware/README.md); probe-rs ({status}) said:\n{err}"
            )
        } else {
            anyhow::anyhow!("flashing with probe-rs failed ({status}); probe-rs said:\n{err}")
        }
    }

    /// Stops probe-rs as Ctrl-C would (it detaches from RTT and leaves the core running),
    /// then kills it if it has not exited within the stop timeout; waits for its output.
    pub fn stop(&mut self) -> Option<ExitStatus> {
        if matches!(self.exited(), Ok(None)) {
            interrupt(&self.child);
            let end = Instant::now() + self.stop_timeout;
            while Instant::now() < end {
                if let Ok(Some(_)) = self.exited() {
                    break;
                }
                std::thread::sleep(Duration::from_millis(10));
            }
            if matches!(self.exited(), Ok(None)) {
                let _ = self.child.kill();
                self.exited = self.child.wait().ok();
            }
        }
        for r in self.readers.drain(..) {
            let _ = r.join();
        }
        self.exited
    }
}

impl Drop for ProbeRun {
    fn drop(&mut self) {
        self.stop();
    }
}

#[cfg(unix)]
fn interrupt(child: &Child) {
    if let Ok(pid) = libc::pid_t::try_from(child.id()) {
        // SAFETY: kill(2) on our own child's pid, which has not been reaped yet (we only
        // wait on it afterwards), so the pid cannot have been reused.
        unsafe {
            libc::kill(pid, libc::SIGINT);
        }
    }
}

#[cfg(not(unix))]
fn interrupt(_child: &Child) {
    // No SIGINT: `stop` kills the process after the timeout.
}

/// The first port with Maobi's USB IDs.
pub fn pen_port(ports: &[PortInfo]) -> Option<PathBuf> {
    ports
        .iter()
        .find(|p| p.is_maobi())
        .map(|p| PathBuf::from(&p.name))
}

/// Waits for the pen's port: `given` to exist, or one with Maobi's USB IDs to appear
/// (`ports` lists them). Fails early if probe-rs exits meanwhile (no probe, flashing
/// failed), and at the timeout.
pub fn wait_for_port(
    run: &mut ProbeRun,
    given: Option<&Path>,
    timeout: Duration,
    ports: &dyn Fn() -> Vec<PortInfo>,
) -> Result<PathBuf> {
    let start = Instant::now();
    loop {
        let found = match given {
            Some(p) => p.exists().then(|| p.to_path_buf()),
            None => pen_port(&ports()),
        };
        if let Some(p) = found {
            return Ok(p);
        }
        if let Some(status) = run.exited()? {
            return Err(run.failure(status));
        }
        if start.elapsed() >= timeout {
            let what = match given {
                Some(p) => format!("{} did not appear", p.display()),
                None => format!(
                    "no serial port with Maobi's USB IDs ({:04x}:{:04x}) appeared",
                    maobi_shared::protocol::USB_VID,
                    maobi_shared::protocol::USB_PID
                ),
            };
            bail!(
                "{what} within {} s of starting probe-rs: is the pen's USB cable plugged in \
                 (the probe powers the chip but does not carry the pen's USB), did the \
                 firmware boot (defmt log below)? Give the port with --port PATH if it has \
                 other IDs.\nprobe-rs output:\n{}\n{}",
                timeout.as_secs(),
                run.lines.tail(Stream::Stderr, 10),
                run.lines.tail(Stream::Stdout, 10)
            );
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// The outcome of a probe-rs run: the link session's report (if the pen came up), then the
/// flashing, link and log checks.
pub struct ProbeRsReport {
    pub session: Option<RunReport>,
    pub checks: Vec<Check>,
    /// The defmt log as probe-rs printed it.
    pub log: Vec<String>,
    pub port: Option<PathBuf>,
}

impl ProbeRsReport {
    pub fn passed(&self) -> bool {
        self.checks.iter().all(|c| c.pass) && self.session.as_ref().is_some_and(|s| s.passed())
    }

    pub fn render(&self) -> String {
        use std::fmt::Write;
        let mut s = String::new();
        if let Some(r) = &self.session {
            let _ = writeln!(s, "{}", r.render());
        }
        for c in &self.checks {
            let _ = writeln!(s, "{c}");
        }
        render_log(&mut s, &self.log);
        s.trim_end().to_string()
    }
}

/// `hil run --backend probe-rs POSES.csv`: flash and start `elf` with probe-rs, wait for the
/// pen's port, run the session, stop probe-rs, check its log. An error (not a report) when
/// the run could not start: no tool, no probe, flashing failed, no port.
pub fn run_probe_rs(elf: &Path, poses: &Path, opts: &ProbeRsOptions) -> Result<ProbeRsReport> {
    run_probe_rs_with(elf, poses, opts, &serial_ports)
}

/// [`run_probe_rs`] with the serial port list given (tests).
pub fn run_probe_rs_with(
    elf: &Path,
    poses: &Path,
    opts: &ProbeRsOptions,
    ports: &dyn Fn() -> Vec<PortInfo>,
) -> Result<ProbeRsReport> {
    let track = PoseTrack::from_path(poses).map_err(|e| anyhow::anyhow!("{e}"))?;
    let mut run = ProbeRun::start(opts, elf)?;
    let port = wait_for_port(&mut run, opts.port.as_deref(), opts.port_timeout, ports)?;
    let mut checks = vec![];
    let session = match open_retrying(&port, Duration::from_secs(5)) {
        Ok(io) => {
            let r = Session::new(io)
                .and_then(|mut s| run_session(&mut s, &track, StreamOptions::default()));
            match r {
                Ok(r) => Some(r),
                Err(e) => {
                    checks.push(Check {
                        name: "link session".into(),
                        pass: false,
                        detail: format!("{e:#}"),
                    });
                    None
                }
            }
        }
        Err(e) => {
            checks.push(Check {
                name: "link session".into(),
                pass: false,
                detail: format!("{e:#}"),
            });
            None
        }
    };
    // probe-rs polls RTT every 100 ms while the log is quiet: let the last records arrive.
    std::thread::sleep(LOG_SETTLE);
    // Did the firmware stay under probe-rs until the end? probe-rs exits by itself only when
    // the core halts (a breakpoint, a fault it catches) or it loses the probe.
    let early = run.exited()?;
    run.stop();
    checks.push(Check {
        name: "probe-rs ran to the end".into(),
        pass: early.is_none(),
        detail: match early {
            None => "stopped after the checks".into(),
            Some(st) => format!(
                "probe-rs exited during the run ({st}): {}",
                run.lines.tail(Stream::Stderr, 5)
            ),
        },
    });
    let log = run.lines.of(Stream::Stdout);
    checks.extend(log_checks(&log, &opts.boot_line));
    Ok(ProbeRsReport {
        session,
        checks,
        log,
        port: Some(port),
    })
}

/// Opens the port, retrying while the freshly enumerated device is not ready (udev still
/// setting its permissions, the CDC interface not configured yet).
fn open_retrying(port: &Path, within: Duration) -> Result<serialport::TTYPort> {
    let end = Instant::now() + within;
    loop {
        match crate::serial::open(port) {
            Ok(p) => return Ok(p),
            Err(e) if Instant::now() >= end => return Err(e),
            Err(_) => std::thread::sleep(Duration::from_millis(100)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use maobi::device::UsbIds;

    fn lines(s: &str) -> Vec<String> {
        s.lines().map(String::from).collect()
    }

    #[test]
    fn a_clean_log_passes_and_a_panic_or_restart_fails() {
        let ok = lines("0.000000 INFO  maobi-pen up\n1.2 WARN  uart rx ring overflowed: 3 bytes\n");
        assert!(log_checks(&ok, BOOT_LINE).iter().all(|c| c.pass));

        let panic = lines("0.0 INFO  maobi-pen up\n2.5 ERROR panicked at src/main.rs:3:5: boom\n");
        let c = log_checks(&panic, BOOT_LINE);
        assert!(c[0].pass);
        assert!(!c[1].pass && c[1].detail.contains("boom"), "{}", c[1]);

        let fault = lines("INFO  maobi-pen up\nHardFault at pc=0x08000123; motors off\n");
        assert!(!log_checks(&fault, BOOT_LINE)[1].pass);
        let trace = lines("INFO  maobi-pen up\nFrame 0: HardFault @ 0x08000400\n");
        assert!(!log_checks(&trace, BOOT_LINE)[1].pass);

        let twice = lines("INFO  maobi-pen up\nINFO  maobi-pen up\n");
        let c = log_checks(&twice, BOOT_LINE);
        assert!(!c[0].pass && c[0].detail.contains("2 times"), "{}", c[0]);

        let none = lines("INFO  something else\n");
        assert!(!log_checks(&none, BOOT_LINE)[0].pass);
        // A function named after panics in a location line is not a panic.
        let loc = lines("INFO  maobi-pen up\n└─ maobi_fw::panic_hooks::arm @ src/x.rs:1\n");
        assert!(log_checks(&loc, BOOT_LINE).iter().all(|c| c.pass));
    }

    #[test]
    fn the_pen_port_is_the_first_with_maobis_usb_ids() {
        let port = |name: &str, ids: Option<(u16, u16)>| PortInfo {
            name: name.into(),
            usb: ids.map(|(vid, pid)| UsbIds {
                vid,
                pid,
                product: None,
                serial: None,
            }),
        };
        let ports = vec![
            port("/dev/ttyS0", None),
            port("/dev/ttyACM0", Some((0x0483, 0x374b))), // the ST-Link's own port
            port("/dev/ttyACM1", Some((0x1209, 0x0001))),
        ];
        assert_eq!(pen_port(&ports), Some(PathBuf::from("/dev/ttyACM1")));
        assert_eq!(pen_port(&ports[..2]), None);
    }

    #[test]
    fn probe_rs_gets_chip_probe_and_elf() {
        let mut o = ProbeRsOptions::new(Some("probe-rs".into()));
        o.probe = Some("0483:374b:ABC".into());
        let a: Vec<String> = o
            .args(Path::new("fw.elf"))
            .into_iter()
            .map(|s| s.to_string_lossy().into_owned())
            .collect();
        assert_eq!(
            a,
            [
                "run",
                "--chip",
                "STM32F411CEUx",
                "--probe",
                "0483:374b:ABC",
                "--no-location",
                "fw.elf"
            ]
        );
    }
}
