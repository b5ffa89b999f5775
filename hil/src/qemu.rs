//! Starting `qemu-system-arm` for the firmware, always under a deadline.
//!
//! UART0 on a loopback socket ([`Run::listen_uart`]): this process binds and listens on
//! port 0 and hands QEMU the listening socket itself (`-chardev socket,fd=N,server=on`, the
//! descriptor inherited by QEMU alone), so the port is taken from the moment it is chosen
//! and tests running in parallel can never be given the same one.
//!
//! The firmware's boot arguments ([`Run::args`]) are its semihosting command line,
//! documented in `firmware/src/qemu/boot.rs`: `run` (the device), `tick_us=N`,
//! `state_hz=N`, `telemetry_ticks=N`, and `lockstep`, in which the emulated pen ticks
//! exactly once per pose the host sends and every tick's state reaches the host (for
//! comparisons with the host's simulator that must not depend on machine load; see
//! `firmware/src/qemu/mod.rs`).

use std::io::Read;
use std::net::TcpListener;
use std::os::fd::{AsRawFd, RawFd};
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStderr, Command, ExitStatus, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};

/// The emulator binary (override with `MAOBI_QEMU`).
pub fn qemu_binary() -> PathBuf {
    std::env::var_os("MAOBI_QEMU")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("qemu-system-arm"))
}

/// Whether the emulator can be started at all.
pub fn available() -> bool {
    Command::new(qemu_binary())
        .arg("--version")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .map(|s| s.success())
        .unwrap_or(false)
}

/// How the guest's clock runs.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub enum Clock {
    /// `-icount shift=N,sleep=off`: virtual time from the instruction count only; idle time
    /// is skipped. Deterministic for self-contained runs.
    Deterministic { shift: u32 },
    /// `-icount shift=N,sleep=on`: instruction-counted while running, host time while idle,
    /// so link timeouts are comparable with the host's pace.
    Paced { shift: u32 },
}

/// One emulator run of the firmware image.
#[derive(Clone, Debug)]
pub struct Run {
    pub elf: PathBuf,
    /// Semihosting arguments after the program name (the boot mode).
    pub args: Vec<String>,
    pub clock: Clock,
    /// UART0 as a TCP server on this listening loopback socket (the host connects to its
    /// port; see [`Run::listen_uart`]); `None`: UART0 unused.
    pub uart: Option<UartSocket>,
    /// Hard limit on the emulator's wall-clock time.
    pub timeout: Duration,
    /// Further QEMU arguments (e.g. [`config_loader_args`] to preload a configuration).
    pub qemu_args: Vec<String>,
}

/// Where the QEMU board keeps its configuration image: the firmware's
/// `qemu::config_store::CONFIG_REGION`, the start of the mps2-an386's PSRAM.
pub const CONFIG_REGION: u32 = 0x2100_0000;

/// QEMU arguments that preload the file `image` as the board's stored configuration (QEMU's
/// generic loader writes it to [`CONFIG_REGION`] before the CPU starts).
pub fn config_loader_args(image: &Path) -> Vec<String> {
    vec![
        "-device".into(),
        format!("loader,file={},addr={CONFIG_REGION:#x}", image.display()),
    ]
}

impl Run {
    pub fn new(elf: &Path, args: &[&str], clock: Clock, timeout: Duration) -> Self {
        Run {
            elf: elf.to_path_buf(),
            args: args.iter().map(|s| s.to_string()).collect(),
            clock,
            uart: None,
            timeout,
            qemu_args: Vec::new(),
        }
    }

    /// Puts UART0 on a new listening loopback socket and returns its port, where the host
    /// connects once QEMU runs (connections made before then wait in the socket's backlog).
    pub fn listen_uart(&mut self) -> Result<u16> {
        let socket = UartSocket::bind()?;
        let port = socket.port;
        self.uart = Some(socket);
        Ok(port)
    }

    pub fn command(&self) -> Command {
        let mut c = Command::new(qemu_binary());
        c.args(["-machine", "mps2-an386", "-cpu", "cortex-m4"]);
        c.args(["-display", "none", "-monitor", "none"]);
        let mut semi = String::from("enable=on,target=native,arg=maobi-fw");
        for a in &self.args {
            semi.push_str(",arg=");
            semi.push_str(a);
        }
        c.args(["-semihosting-config", &semi]);
        let icount = match self.clock {
            Clock::Deterministic { shift } => format!("shift={shift},sleep=off"),
            Clock::Paced { shift } => format!("shift={shift},sleep=on"),
        };
        c.args(["-icount", &icount]);
        match &self.uart {
            Some(socket) => {
                let fd = socket.listener.as_raw_fd();
                c.args([
                    "-chardev",
                    &format!("socket,id=u0,fd={fd},server=on,wait=on,nodelay=on"),
                    "-serial",
                    "chardev:u0",
                ]);
                // The listening socket is kept from every other child (std opens it
                // close-on-exec) and passed to this one: cleared in the child only, between
                // fork and exec.
                // SAFETY: the closure only calls fcntl(2), which is async-signal-safe, on a
                // descriptor `socket` keeps open while `c` exists (it holds a clone).
                let keep = socket.clone();
                unsafe {
                    c.pre_exec(move || inherit_fd(keep.listener.as_raw_fd()));
                }
            }
            None => {
                c.args(["-serial", "null"]);
            }
        }
        c.args(&self.qemu_args);
        c.arg("-kernel").arg(&self.elf);
        c
    }

    /// Starts the emulator with stdout captured and stderr (the firmware's defmt frames)
    /// decoded into [`Guest::defmt_log`].
    pub fn spawn(&self) -> Result<Guest> {
        let mut child = self
            .command()
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .with_context(|| {
                format!(
                    "cannot start {} (install it: apt-get install qemu-system-arm)",
                    qemu_binary().display()
                )
            })?;
        let log = DefmtLog::default();
        if let Some(stderr) = child.stderr.take() {
            log.decode_from(&self.elf, stderr);
        }
        Ok(Guest {
            child,
            deadline: Instant::now() + self.timeout,
            timeout: self.timeout,
            log,
        })
    }

    /// Runs to completion and returns the exit status and the semihosting stdout.
    pub fn output(&self) -> Result<(ExitStatus, String)> {
        let mut g = self.spawn()?;
        let status = g.wait()?;
        let mut out = String::new();
        if let Some(mut s) = g.child.stdout.take() {
            s.read_to_string(&mut out)?;
        }
        Ok((status, out))
    }
}

/// The firmware's defmt log as decoded so far, one line a record (`timestamp LEVEL message`).
#[derive(Clone, Debug, Default)]
pub struct DefmtLog(Arc<Mutex<Vec<String>>>);

impl DefmtLog {
    /// Decodes defmt frames from `stderr` on a thread until QEMU closes it, with the string
    /// table of `elf` (the image QEMU runs). An image without a table, or one this decoder
    /// cannot read, leaves a line saying so instead of records.
    fn decode_from(&self, elf: &Path, mut stderr: ChildStderr) {
        let lines = self.0.clone();
        let elf = elf.to_path_buf();
        std::thread::spawn(move || {
            let push = |l: String| {
                if let Ok(mut v) = lines.lock() {
                    v.push(l);
                }
            };
            let table = std::fs::read(&elf)
                .map_err(anyhow::Error::from)
                .and_then(|b| defmt_decoder::Table::parse(&b));
            let table = match table {
                Ok(Some(t)) => t,
                Ok(None) => return push("(the image has no defmt table)".into()),
                Err(e) => return push(format!("(cannot read the image's defmt table: {e})")),
            };
            let mut decoder = table.new_stream_decoder();
            // defmt's encoder opens the stream with a frame separator (so that a decoder can
            // drop what an earlier boot left half-written), which reads as one empty,
            // malformed frame before the first record: not worth a line.
            let mut decoded_any = false;
            let mut buf = [0u8; 4096];
            loop {
                let n = match stderr.read(&mut buf) {
                    Ok(0) | Err(_) => return,
                    Ok(n) => n,
                };
                decoder.received(&buf[..n]);
                loop {
                    match decoder.decode() {
                        Ok(frame) => {
                            decoded_any = true;
                            push(frame.display(false).to_string())
                        }
                        Err(defmt_decoder::DecodeError::UnexpectedEof) => break,
                        Err(defmt_decoder::DecodeError::Malformed) if !decoded_any => {
                            decoded_any = true;
                        }
                        Err(defmt_decoder::DecodeError::Malformed) => {
                            push("(a malformed defmt frame)".into())
                        }
                    }
                }
            }
        });
    }

    /// The records decoded so far.
    pub fn lines(&self) -> Vec<String> {
        self.0.lock().map(|v| v.clone()).unwrap_or_default()
    }
}

/// A running emulator; killed when dropped.
pub struct Guest {
    pub child: Child,
    deadline: Instant,
    timeout: Duration,
    log: DefmtLog,
}

impl Guest {
    /// The firmware's defmt log so far (decoded from QEMU's stderr).
    pub fn defmt_log(&self) -> Vec<String> {
        self.log.lines()
    }

    /// Waits for the emulator to exit; kills it and fails at the deadline.
    pub fn wait(&mut self) -> Result<ExitStatus> {
        loop {
            if let Some(s) = self.child.try_wait()? {
                return Ok(s);
            }
            if Instant::now() >= self.deadline {
                let _ = self.child.kill();
                let _ = self.child.wait();
                bail!("QEMU did not finish within {:?}: killed", self.timeout);
            }
            std::thread::sleep(Duration::from_millis(10));
        }
    }

    pub fn deadline(&self) -> Instant {
        self.deadline
    }

    /// Stops the emulator and returns its stdout, with how it had exited if it had (`None`:
    /// it was still running, as a device should be).
    pub fn stop(&mut self) -> Result<(Option<ExitStatus>, String)> {
        let exited = self.child.try_wait()?;
        if exited.is_none() {
            let _ = self.child.kill();
        }
        let _ = self.child.wait();
        let mut out = String::new();
        if let Some(mut s) = self.child.stdout.take() {
            s.read_to_string(&mut out)?;
        }
        Ok((exited, out))
    }
}

/// The firmware's stack readings in its stdout (`STACK high_water_bytes=N`, printed by the
/// supervisor at each new high-water mark, `firmware/src/app/stack.rs`), deepest first.
pub fn stack_readings(stdout: &str) -> Vec<u64> {
    let mut r: Vec<u64> = stdout
        .lines()
        .filter_map(|l| l.strip_prefix("STACK high_water_bytes="))
        .filter_map(|n| n.trim().parse().ok())
        .collect();
    r.sort_unstable_by(|a, b| b.cmp(a));
    r
}

impl Drop for Guest {
    fn drop(&mut self) {
        if let Ok(None) = self.child.try_wait() {
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}

/// A loopback TCP socket listening on a port of the system's choosing, for QEMU's UART0
/// ([`Run::listen_uart`]). QEMU takes the socket itself, so nothing can bind the port
/// between this process choosing it and QEMU serving it.
#[derive(Clone, Debug)]
pub struct UartSocket {
    listener: Arc<TcpListener>,
    /// Where the host connects.
    pub port: u16,
}

impl UartSocket {
    pub fn bind() -> Result<Self> {
        let listener = TcpListener::bind("127.0.0.1:0").context("cannot listen on loopback")?;
        let port = listener.local_addr()?.port();
        Ok(UartSocket {
            listener: Arc::new(listener),
            port,
        })
    }
}

/// Clears close-on-exec on `fd`, so the program about to be executed inherits it.
pub(crate) fn inherit_fd(fd: RawFd) -> std::io::Result<()> {
    // SAFETY: fcntl on a descriptor number, no pointers.
    let flags = unsafe { libc::fcntl(fd, libc::F_GETFD) };
    if flags < 0 {
        return Err(std::io::Error::last_os_error());
    }
    // SAFETY: as above.
    if unsafe { libc::fcntl(fd, libc::F_SETFD, flags & !libc::FD_CLOEXEC) } < 0 {
        return Err(std::io::Error::last_os_error());
    }
    Ok(())
}
