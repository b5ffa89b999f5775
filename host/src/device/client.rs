//! [`LinkDevice`]: a device on the other end of a wire-protocol link, behind the
//! [`Device`] trait.
//!
//! Two threads per device, neither ever touched by the UI thread except through a mutex held
//! for a copy:
//! * the **link thread** opens the [`Endpoint`], sends `Hello` and waits for the device's
//!   (a peer of another protocol version is a clear error, not noise), then reads and decodes
//!   frames with [`HostRx`] into [`BrushFrame`]s, answers, counters and status, and calls the
//!   wake callback (the GUI's `request_repaint`) when frames arrive. End of stream, a read
//!   error or more than [`LINK_TIMEOUT`] without a good frame ends the session: the status
//!   says the link is lost and why, the frames already received (the GUI's canvas) stay,
//!   and the thread reconnects with a growing back-off until the peer is back.
//! * the **writer thread** is the virtual pen's 1 kHz clock: for a device with
//!   [`Capabilities::VIRTUAL_PEN`] it moves the hand toward the GUI's target (as fast as a
//!   hand, like the built-in simulator) and sends one [`PoseSample`] per millisecond, or a
//!   replay's poses; for a device with its own sensors it pings. It also turns the GUI's
//!   commands into [`HostMsg`]s.
//! * **Guided writing** ([`DeviceCommand::Guide`]): the writer plays the stroke's moving
//!   point one resampled pose per tick ([`GuidePlay`]), as a [`GuideSample`] sent just
//!   before the pose of the same `seq` (the device applies it at the tick that consumes that
//!   pose); after the stroke's end, or when the GUI stops it, it holds the last point with
//!   `on = false` until the guide has faded out. It mirrors the device's guide (the force
//!   loop's own [`HandGuide`], fed exactly what the device gets), so each received state's frame carries the anchor sent for its tick,
//!   the stylus's distance from it (how far the writer strayed), the fade gain and the
//!   guide's force ([`BrushFrame::guide`]).

use std::collections::VecDeque;
use std::io::Write;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError, Sender};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use maobi_shared::force::OutputState;
use maobi_shared::params::TickLimits;

use super::model::{BrushChoice, ModelKind};
use maobi_shared::force_loop::HandGuide;
use maobi_shared::guide::{GuideForce, GuidePlay, DEFAULT_GUIDE};
use maobi_shared::protocol::{
    bounded_str, param_id, BrushState, Buttons, Capabilities, Command, DeviceInfo, DeviceMsg,
    GuideSample, HostHello, HostMsg, HostRx, Message, PoseSample, PresetRef, ProtocolError,
    Version, DELIMITER,
};
use maobi_shared::{presets, BrushParams, Fx, ParamId, Pose, Quat, Scalar, Vec3};

use super::api::{
    BrushFrame, Device, DeviceCommand, DeviceError, DeviceStatus, GuideFrame, HandInput, LinkReport,
};
use super::builtin::{FRAME_QUEUE, HAND_SPEED_MM_PER_TICK, HAND_TURN_PER_TICK};
use super::endpoint::{nothing_to_read_yet, Conn, Endpoint};

/// No good frame for this long: the link is lost.
pub const LINK_TIMEOUT: Duration = Duration::from_millis(500);
/// How long the device may take to answer `Hello`.
pub const HANDSHAKE_TIMEOUT: Duration = Duration::from_millis(1000);
/// Reconnection back-off: first wait, and the longest.
pub const BACKOFF_MIN: Duration = Duration::from_millis(100);
pub const BACKOFF_MAX: Duration = Duration::from_secs(2);
/// A device without a virtual pen gets a ping this often (so it knows the host is there).
pub const PING_EVERY: Duration = Duration::from_millis(100);
/// How long a new session waits for the device's first state before the virtual pen starts
/// from where the host left it.
pub const SYNC_WAIT: Duration = Duration::from_millis(300);
/// Pose ticks the writer may fall behind the wall clock before it skips ahead.
pub const MAX_BEHIND_TICKS: u64 = 50;
/// At most this many poses in flight: sent but not yet reported consumed (a state's
/// `pose_seq`); the protocol's bound, which every device's pose queue holds. A
/// slower-than-real-time device (the firmware under QEMU) paces the writer instead of
/// overflowing its queue, so no replay pose is lost.
pub const POSES_IN_FLIGHT: u32 = maobi_shared::protocol::POSES_IN_FLIGHT;

/// What the link client says about itself in the handshake.
#[derive(Clone, Debug)]
pub struct LinkOptions {
    pub endpoint: Endpoint,
    /// Program name in our `Hello` ("maobi-gui", "phantom-bridge").
    pub host_name: String,
    /// Where the virtual pen starts.
    pub start_hand: HandInput,
    /// Preset whose parameters the status shows until the device has reported its own.
    pub preset: String,
    /// How long without a good frame ends the session: [`LINK_TIMEOUT`], what a pen on a
    /// cable that comes loose looks like. A test that runs an emulated pen in lock-step
    /// raises it: that pen is silent while the machine that emulates it is busy elsewhere,
    /// which says nothing about the link.
    pub silence_limit: Duration,
}

impl LinkOptions {
    pub fn new(endpoint: Endpoint, start_hand: HandInput) -> LinkOptions {
        LinkOptions {
            endpoint,
            host_name: "maobi-gui".into(),
            start_hand,
            preset: "large".into(),
            silence_limit: LINK_TIMEOUT,
        }
    }
}

/// Our software version, for `Hello`.
pub fn host_version() -> Version {
    let v = |s: &str| s.parse().unwrap_or(0);
    Version {
        major: v(env!("CARGO_PKG_VERSION_MAJOR")),
        minor: v(env!("CARGO_PKG_VERSION_MINOR")),
        patch: v(env!("CARGO_PKG_VERSION_PATCH")),
    }
}

/// A replay's span of pose sequence numbers, as far as it is known.
#[derive(Copy, Clone, Debug, Default)]
struct ReplaySpan {
    first: Option<u32>,
    last: Option<u32>,
}

/// `a` is at or after `b` in wrapping sequence order.
fn seq_at_or_after(a: u32, b: u32) -> bool {
    (a.wrapping_sub(b) as i32) >= 0
}

struct Shared {
    status: DeviceStatus,
    report: LinkReport,
    frames: VecDeque<BrushFrame>,
    queue_dropped: u64,
    device_dropped: u32,
    capabilities: Capabilities,
    replay: Option<ReplaySpan>,
    last_tick: Option<u64>,
    /// The parameters changed wholesale (a preset): read them again.
    refetch_params: bool,
    /// The handle pose of this session's latest state: where the device's pen is.
    device_handle: Option<Pose<f64>>,
    /// The `pose_seq` of this session's latest state: the last pose the device consumed.
    device_pose_seq: Option<u32>,
    /// Guided writing: what the writer sent (and its mirror computed) for recent pose
    /// sequence numbers, for the frames of the states that report them.
    guide_sent: VecDeque<(u32, GuideFrame)>,
}

/// Guide entries kept for states to come (more than the poses in flight).
const GUIDE_SENT_KEPT: usize = 1024;

type Wake = Arc<dyn Fn() + Send + Sync>;

struct Inner {
    shared: Mutex<Shared>,
    /// The writer's handle on the current session's stream (`None` between sessions).
    out: Mutex<Option<Box<dyn Conn>>>,
    stop: AtomicBool,
    /// A write failed: the link thread ends the session.
    write_failed: AtomicBool,
    wake: Mutex<Option<Wake>>,
}

impl Inner {
    fn shared(&self) -> MutexGuard<'_, Shared> {
        self.shared.lock().unwrap_or_else(|p| p.into_inner())
    }
    fn out(&self) -> MutexGuard<'_, Option<Box<dyn Conn>>> {
        self.out.lock().unwrap_or_else(|p| p.into_inner())
    }
    fn wake(&self) {
        let w = self.wake.lock().ok().and_then(|w| w.clone());
        if let Some(w) = w {
            w();
        }
    }
    /// Writes `bytes` on the current session, if any; a failure ends the session.
    fn write(&self, bytes: &[u8]) -> bool {
        let mut out = self.out();
        let Some(conn) = out.as_mut() else {
            return false;
        };
        match conn.write_all(bytes).and_then(|()| conn.flush()) {
            Ok(()) => true,
            Err(e) => {
                conn.shut();
                *out = None;
                drop(out);
                self.write_failed.store(true, Ordering::SeqCst);
                self.shared().report.last_error = Some(format!("write failed: {e}"));
                false
            }
        }
    }
    fn send(&self, msg: &HostMsg) -> bool {
        let mut buf = [0u8; HostMsg::MAX_FRAME];
        match msg.encode(&mut buf) {
            Ok(n) => self.write(&buf[..n]),
            Err(_) => false,
        }
    }
}

struct Running {
    link: JoinHandle<()>,
    writer: JoinHandle<()>,
    cmds: Sender<DeviceCommand>,
}

/// A device over the wire protocol (TCP or serial).
pub struct LinkDevice {
    opts: LinkOptions,
    inner: Arc<Inner>,
    running: Option<Running>,
    /// Parameters as last reported, for validating commands before they are sent.
    params: BrushParams,
    /// The device's tick limits (its handshake's), for the same.
    limits: TickLimits,
}

impl LinkDevice {
    pub fn new(opts: LinkOptions) -> Result<LinkDevice, DeviceError> {
        let params = BrushChoice::liang_params(&opts.preset).map_err(DeviceError::Rejected)?;
        let status = DeviceStatus {
            name: opts.endpoint.to_string(),
            connected: false,
            protocol_version: None,
            firmware_version: None,
            faults: Vec::new(),
            frames_dropped: 0,
            ticks_late: 0,
            tick_period_ms: None,
            params,
            preset: opts.preset.clone(),
            model: ModelKind::Liang,
            forces_enabled: false,
            replaying: false,
            replays_done: 0,
            link: None,
            tick_limits: TickLimits::NONE,
        };
        let report = LinkReport {
            state: "not connected".into(),
            ..LinkReport::default()
        };
        Ok(LinkDevice {
            inner: Arc::new(Inner {
                shared: Mutex::new(Shared {
                    status,
                    report,
                    frames: VecDeque::new(),
                    queue_dropped: 0,
                    device_dropped: 0,
                    capabilities: Capabilities::empty(),
                    replay: None,
                    last_tick: None,
                    refetch_params: false,
                    device_handle: None,
                    device_pose_seq: None,
                    guide_sent: VecDeque::new(),
                }),
                out: Mutex::new(None),
                stop: AtomicBool::new(false),
                write_failed: AtomicBool::new(false),
                wake: Mutex::new(None),
            }),
            opts,
            running: None,
            params,
            limits: TickLimits::NONE,
        })
    }

    /// Calls `wake` from the link thread when frames arrive (e.g. `request_repaint`).
    pub fn on_frames(&mut self, wake: Arc<dyn Fn() + Send + Sync>) {
        if let Ok(mut w) = self.inner.wake.lock() {
            *w = Some(wake);
        }
    }

    pub fn endpoint(&self) -> &Endpoint {
        &self.opts.endpoint
    }

    /// Waits up to `timeout` until the link is connected.
    pub fn wait_connected(&self, timeout: Duration) -> bool {
        let end = Instant::now() + timeout;
        while Instant::now() < end {
            if self.inner.shared().status.connected {
                return true;
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        self.inner.shared().status.connected
    }
}

impl Device for LinkDevice {
    /// Starts the link and waits (at most about two seconds) for the first handshake. On
    /// failure the error says why (refused, no answer, version mismatch) and the link keeps
    /// retrying in the background until [`Device::disconnect`].
    fn connect(&mut self) -> Result<(), DeviceError> {
        if self.running.is_none() {
            self.inner.stop.store(false, Ordering::SeqCst);
            {
                let mut s = self.inner.shared();
                s.report.state = format!("connecting to {}", self.opts.endpoint);
                s.report.attempts = 0;
            }
            let (tx, rx) = mpsc::channel();
            let link = {
                let inner = self.inner.clone();
                let opts = self.opts.clone();
                std::thread::Builder::new()
                    .name("maobi-link".into())
                    .spawn(move || run_link(&inner, &opts))
                    .map_err(|e| DeviceError::Link(format!("cannot start the link thread: {e}")))?
            };
            let writer = {
                let inner = self.inner.clone();
                let hand = self.opts.start_hand;
                std::thread::Builder::new()
                    .name("maobi-link-tx".into())
                    .spawn(move || run_writer(&inner, rx, hand))
                    .map_err(|e| DeviceError::Link(format!("cannot start the writer: {e}")))?
            };
            self.running = Some(Running {
                link,
                writer,
                cmds: tx,
            });
        }
        let end = Instant::now() + HANDSHAKE_TIMEOUT + Duration::from_millis(1200);
        loop {
            {
                let s = self.inner.shared();
                if s.status.connected {
                    return Ok(());
                }
                if s.report.attempts > 0 {
                    let why = s.report.last_error.clone().unwrap_or_default();
                    return Err(DeviceError::Link(format!(
                        "{}: {why} (retrying in the background)",
                        self.opts.endpoint
                    )));
                }
            }
            if Instant::now() > end {
                return Err(DeviceError::Link(format!(
                    "{}: no connection yet (retrying in the background)",
                    self.opts.endpoint
                )));
            }
            std::thread::sleep(Duration::from_millis(5));
        }
    }

    fn disconnect(&mut self) {
        if let Some(r) = self.running.take() {
            self.inner.stop.store(true, Ordering::SeqCst);
            if let Some(c) = self.inner.out().take() {
                c.shut();
            }
            drop(r.cmds);
            let _ = r.writer.join();
            let _ = r.link.join();
        }
        let mut s = self.inner.shared();
        s.status.connected = false;
        s.report.state = "disconnected".into();
        s.replay = None;
        s.status.replaying = false;
    }

    fn status(&self) -> DeviceStatus {
        let s = self.inner.shared();
        let mut st = s.status.clone();
        st.frames_dropped =
            u64::from(s.report.rx.dropped()) + u64::from(s.device_dropped) + s.queue_dropped;
        st.link = Some(s.report.clone());
        st
    }

    fn poll(&mut self, out: &mut Vec<BrushFrame>) {
        let mut s = self.inner.shared();
        out.extend(s.frames.drain(..));
        self.params = s.status.params;
        self.limits = s.status.tick_limits;
    }

    fn send(&mut self, cmd: DeviceCommand) -> Result<(), DeviceError> {
        cmd.validate(&self.params)?;
        cmd.check_tick_limits(&self.params, &self.limits)?;
        if let DeviceCommand::Model(m) = cmd {
            // The pen runs Liang's model: nothing to send.
            return m
                .on_liang_only_device("a pen")
                .map_err(DeviceError::Rejected);
        }
        let Some(r) = &self.running else {
            return Err(DeviceError::NotConnected);
        };
        let connected = self.inner.shared().status.connected;
        if !connected && !matches!(cmd, DeviceCommand::Hand(_)) {
            return Err(DeviceError::NotConnected);
        }
        let virtual_pen = self
            .inner
            .shared()
            .capabilities
            .contains(Capabilities::VIRTUAL_PEN);
        match &cmd {
            DeviceCommand::SetParam(id, v) => {
                let _ = self.params.set(*id, *v);
            }
            DeviceCommand::Replay(track) if track.rows().is_empty() => {
                return Err(DeviceError::Rejected("the pose file is empty".into()));
            }
            DeviceCommand::Replay(_) if !virtual_pen => {
                return Err(DeviceError::Rejected(
                    "this device reads its own sensors: replaying poses needs a virtual-pen \
                     device (the QEMU board, the sim-device, the Phantom bridge)"
                        .into(),
                ));
            }
            DeviceCommand::Replay(_) => {
                let mut s = self.inner.shared();
                s.replay = Some(ReplaySpan::default());
                s.status.replaying = true;
            }
            DeviceCommand::Guide(Some(track)) if track.rows().is_empty() => {
                return Err(DeviceError::Rejected("the stroke is empty".into()));
            }
            DeviceCommand::Lane(Some(_)) | DeviceCommand::Guide(Some(_)) if !virtual_pen => {
                // The moving point (the lane's wall point) rides with the virtual pen's
                // pose samples.
                return Err(DeviceError::Rejected(match cmd {
                    DeviceCommand::Lane(_) => super::api::LANE_NEEDS_THE_POSE.into(),
                    _ => "guided writing over the link needs a virtual-pen device (the QEMU \
                          board, the sim-device); a pen with its own sensors does not take \
                          the moving point yet"
                        .into(),
                }));
            }
            DeviceCommand::Lane(Some((track, _)))
                if super::lane::pieces(track, self.params.length_mm as f64).is_empty() =>
            {
                return Err(DeviceError::Rejected(super::api::LANE_NO_PATH.into()));
            }
            _ => {}
        }
        r.cmds
            .send(cmd)
            .map_err(|_| DeviceError::Link("the writer thread has stopped".into()))
    }
}

impl Drop for LinkDevice {
    fn drop(&mut self) {
        self.disconnect();
    }
}

/// Why a session ended.
enum End {
    /// Asked to stop.
    Stopped,
    /// Never came up (open failed, no handshake, version mismatch).
    Failed(String),
    /// Was up, then lost.
    Lost(String),
}

fn run_link(inner: &Inner, opts: &LinkOptions) {
    let mut dec = Box::new(HostRx::new());
    let mut backoff = BACKOFF_MIN;
    let mut attempt = 0u32;
    while !inner.stop.load(Ordering::SeqCst) {
        attempt += 1;
        let end = session(inner, opts, &mut dec);
        {
            let mut s = inner.shared();
            s.status.connected = false;
            if let Some(c) = inner.out().take() {
                c.shut();
            }
            if s.replay.take().is_some() {
                s.status.replaying = false;
                s.status.replays_done += 1;
                s.report.last_error = Some("the replay was cut short by the link loss".into());
            }
            s.report.rx = dec.stats();
            s.report.attempts = attempt;
            match &end {
                End::Stopped => {}
                End::Failed(why) => {
                    s.report.state = format!(
                        "not connected: {why}; retrying in {:.1} s",
                        backoff.as_secs_f64()
                    );
                    s.report.last_error = Some(why.clone());
                }
                End::Lost(why) => {
                    backoff = BACKOFF_MIN;
                    s.report.lost += 1;
                    s.report.state = format!("link lost: {why}; reconnecting");
                    s.report.last_error = Some(format!("link lost: {why}"));
                }
            }
        }
        inner.wake();
        if matches!(end, End::Stopped) {
            break;
        }
        let until = Instant::now() + backoff;
        while Instant::now() < until && !inner.stop.load(Ordering::SeqCst) {
            std::thread::sleep(Duration::from_millis(10));
        }
        if matches!(end, End::Failed(_)) {
            backoff = (backoff * 2).min(BACKOFF_MAX);
        }
    }
}

/// Reads into `buf`: `Ok(0)` is end of stream, `Ok(None)`-like timeouts come back as
/// `Ok(usize::MAX)`.
fn read_some(conn: &mut dyn Conn, buf: &mut [u8]) -> std::io::Result<Option<usize>> {
    match conn.read(buf) {
        Ok(n) => Ok(Some(n)),
        Err(e) if nothing_to_read_yet(&e) => Ok(None),
        Err(e) => Err(e),
    }
}

/// Sends our `Hello` on `conn` and waits up to `timeout` for the device's; `None` when
/// `stop` said to give up. A version mismatch (in a frame's version byte or in the device's
/// hello) is an error that says so.
/// Why a handshake failed.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(crate) struct HandshakeError {
    pub message: String,
    /// The other end closed or reset the connection before it answered. A TCP server that
    /// serves one client at a time (QEMU's UART socket) does that to a client that arrives
    /// before it has seen the previous one leave: another try soon after can succeed.
    pub closed: bool,
    /// Not one byte came back before the timeout: nothing is listening, or the device
    /// sends nothing to this host (see `bringup`'s `no_answer_cause`).
    pub silent: bool,
}

impl HandshakeError {
    fn other(message: String) -> Self {
        HandshakeError {
            message,
            closed: false,
            silent: false,
        }
    }
}

impl std::fmt::Display for HandshakeError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.message)
    }
}

impl From<HandshakeError> for String {
    fn from(e: HandshakeError) -> String {
        e.message
    }
}

pub(crate) fn handshake(
    conn: &mut dyn Conn,
    dec: &mut HostRx,
    host_name: &str,
    timeout: Duration,
    stop: &dyn Fn() -> bool,
) -> Option<Result<DeviceInfo, HandshakeError>> {
    // A lone delimiter flushes whatever partial frame the device holds, then our hello.
    let hello = HostMsg::Hello(HostHello::new(host_name, host_version()));
    let mut buf = [0u8; HostMsg::MAX_FRAME + 1];
    buf[0] = DELIMITER;
    let n = match hello.encode(&mut buf[1..]) {
        Ok(n) => n,
        Err(e) => {
            return Some(Err(HandshakeError::other(format!(
                "cannot encode the hello: {e}"
            ))))
        }
    };
    if let Err(e) = conn.write_all(&buf[..n + 1]) {
        return Some(Err(HandshakeError {
            closed: is_closed(&e),
            message: format!("cannot write: {e}"),
            silent: false,
        }));
    }
    let started = Instant::now();
    let mut rx = vec![0u8; 8192];
    let mut heard = 0usize;
    loop {
        if stop() {
            return None;
        }
        if started.elapsed() > timeout {
            let ms = timeout.as_millis();
            return Some(Err(if heard == 0 {
                HandshakeError {
                    message: format!(
                        "no answer to the handshake within {ms} ms: not one byte came back"
                    ),
                    closed: false,
                    silent: true,
                }
            } else {
                HandshakeError::other(format!(
                    "no answer to the handshake within {ms} ms ({heard} bytes came back, no \
                     hello among them): is this a Maobi device?"
                ))
            }));
        }
        let n = match read_some(conn, &mut rx) {
            Ok(Some(0)) => {
                return Some(Err(HandshakeError {
                    message: "the device closed the link".into(),
                    closed: true,
                    silent: false,
                }))
            }
            Ok(Some(n)) => {
                heard += n;
                n
            }
            Ok(None) => continue,
            Err(e) => {
                return Some(Err(HandshakeError {
                    closed: is_closed(&e),
                    message: format!("read failed: {e}"),
                    silent: false,
                }))
            }
        };
        let mut mismatch = None;
        let mut got = None;
        for outcome in dec.feed(&rx[..n]) {
            match outcome {
                Ok(DeviceMsg::Hello(info)) => got = Some(info),
                Err(e @ ProtocolError::VersionMismatch { .. }) => mismatch = Some(e),
                _ => {}
            }
        }
        if let Some(e) = mismatch {
            return Some(Err(HandshakeError::other(e.to_string())));
        }
        if let Some(info) = got {
            log::debug!("handshake: the device says {info:?}");
            return Some(
                info.check()
                    .map(|()| info)
                    .map_err(|e| HandshakeError::other(e.to_string())),
            );
        }
    }
}

/// The other end is gone: reset, aborted or closed under us.
fn is_closed(e: &std::io::Error) -> bool {
    use std::io::ErrorKind::*;
    matches!(
        e.kind(),
        ConnectionReset | ConnectionAborted | BrokenPipe | UnexpectedEof
    )
}

/// Whether a Maobi device answers at `endpoint`: opens it, shakes hands, closes it. For
/// finding the pen among the serial ports (see [`probe_serial_ports`]).
pub fn identify(endpoint: &Endpoint, timeout: Duration) -> Result<DeviceInfo, String> {
    let mut conn = endpoint
        .open()
        .map_err(|e| format!("cannot open {endpoint}: {e}"))?;
    let mut dec = Box::new(HostRx::new());
    let r = handshake(&mut *conn, &mut dec, "maobi-probe", timeout, &|| false)
        .unwrap_or_else(|| Err(HandshakeError::other("stopped".into())))
        .map_err(String::from);
    conn.shut();
    r
}

/// Every serial port with what answered there: the board's name, or why not.
pub fn probe_serial_ports(timeout: Duration) -> Vec<(String, Result<String, String>)> {
    super::endpoint::available_serial_ports()
        .into_iter()
        .map(|p| {
            let r = identify(&Endpoint::Serial(p.clone()), timeout)
                .map(|info| format!("{} (firmware {})", info.board, info.firmware));
            (p, r)
        })
        .collect()
}

fn session(inner: &Inner, opts: &LinkOptions, dec: &mut HostRx) -> End {
    let mut conn = match opts.endpoint.open() {
        Ok(c) => c,
        Err(e) => return End::Failed(format!("cannot open {}: {e}", opts.endpoint)),
    };
    dec.reset();
    inner.write_failed.store(false, Ordering::SeqCst);
    let stop = || inner.stop.load(Ordering::SeqCst);
    let outcome = handshake(&mut *conn, dec, &opts.host_name, HANDSHAKE_TIMEOUT, &stop);
    inner.shared().report.rx = dec.stats();
    let info = match outcome {
        None => return End::Stopped,
        Some(Err(e)) => return End::Failed(e.into()),
        Some(Ok(info)) => info,
    };
    let mut rx = vec![0u8; 8192];
    // Up: the writer gets its own handle.
    let out = match conn.try_clone_conn() {
        Ok(c) => c,
        Err(e) => return End::Failed(format!("cannot share the stream: {e}")),
    };
    {
        let mut s = inner.shared();
        s.capabilities = info.capabilities;
        s.status.connected = true;
        s.status.protocol_version = Some(u32::from(info.protocol_version));
        s.status.firmware_version = Some(format!("{} on {}", info.firmware, info.board));
        s.status.name = format!("{} ({})", opts.endpoint, info.board);
        s.report.state = format!("connected to {} ({})", opts.endpoint, info.board);
        s.report.board = Some(info.board.to_string());
        s.report.capabilities = info.capabilities.to_string();
        s.report.config = info.config.to_string();
        s.report.config_allows_forces = info.config.allows_forces();
        s.status.tick_limits = info.limits;
        s.report.sessions += 1;
        s.last_tick = None;
        s.device_handle = None;
        s.device_pose_seq = None;
    }
    *inner.out() = Some(out);
    request_params(inner);
    inner.wake();

    let mut last_good = Instant::now();
    loop {
        if inner.stop.load(Ordering::SeqCst) {
            return End::Stopped;
        }
        if inner.write_failed.load(Ordering::SeqCst) {
            let why = inner.shared().report.last_error.clone().unwrap_or_default();
            return End::Lost(why);
        }
        let n = match read_some(&mut *conn, &mut rx) {
            Ok(Some(0)) => return End::Lost("the device closed the link".into()),
            Ok(Some(n)) => n,
            Ok(None) => 0,
            Err(e) => return End::Lost(format!("read failed: {e}")),
        };
        let mut frames = 0;
        if n > 0 {
            let mut s = inner.shared();
            for msg in dec.feed(&rx[..n]).flatten() {
                last_good = Instant::now();
                if handle(&mut s, msg) {
                    frames += 1;
                }
            }
            s.report.rx = dec.stats();
            let refetch = std::mem::take(&mut s.refetch_params);
            drop(s);
            if refetch {
                request_params(inner);
            }
        }
        if frames > 0 {
            inner.wake();
        }
        if last_good.elapsed() > opts.silence_limit {
            return End::Lost(format!(
                "no data from the device for {} ms",
                opts.silence_limit.as_millis()
            ));
        }
    }
}

/// Asks for every parameter (answers update the status).
fn request_params(inner: &Inner) {
    for id in ParamId::ALL {
        inner.send(&HostMsg::GetParam { id: id as u8 });
    }
}

/// Handles one message; true when it was a brush state. Runs with the shared state locked:
/// it must not write to the link.
fn handle(s: &mut Shared, msg: DeviceMsg) -> bool {
    match msg {
        DeviceMsg::State(state) => {
            let replaying = match &mut s.replay {
                Some(ReplaySpan {
                    first: Some(first), ..
                }) => seq_at_or_after(state.pose_seq, *first),
                _ => false,
            };
            let done = match s.replay {
                Some(ReplaySpan {
                    last: Some(last), ..
                }) => seq_at_or_after(state.pose_seq, last),
                _ => false,
            };
            let tick = match s.last_tick {
                Some(t) => {
                    let d = state.tick.wrapping_sub(t as u32);
                    if d < 1 << 31 {
                        t + u64::from(d)
                    } else {
                        u64::from(state.tick)
                    }
                }
                None => u64::from(state.tick),
            };
            s.last_tick = Some(tick);
            let mut frame = frame_from_state(&state, tick, replaying);
            frame.guide = guide_frame(s, &state, frame.pose);
            s.device_handle = Some(frame.pose);
            s.device_pose_seq = Some(state.pose_seq);
            s.status.forces_enabled = state.haptics.enabled;
            s.status.faults = if state.faults.is_empty() {
                Vec::new()
            } else {
                vec![format!("device faults: {}", state.faults)]
            };
            if s.frames.len() >= FRAME_QUEUE {
                s.frames.pop_front();
                s.queue_dropped += 1;
            }
            s.frames.push_back(frame);
            if done {
                s.replay = None;
                s.status.replaying = false;
                s.status.replays_done += 1;
            }
            s.report.states += 1;
            true
        }
        DeviceMsg::Param(reply) => {
            match (param_id(reply.id), reply.result) {
                (Some(id), Ok(v)) => {
                    let _ = s.status.params.set(id, v);
                }
                (_, Err(rej)) => {
                    s.report.last_error = Some(format!("the device refused: {rej}"));
                }
                (None, Ok(_)) => {}
            }
            false
        }
        DeviceMsg::CommandDone { command, result } => {
            match result {
                Ok(()) => {
                    if let Command::ChoosePreset(PresetRef::Name(n)) = &command {
                        s.status.preset = n.to_string();
                        if let Some(p) = presets::by_name(n) {
                            s.status.params = p;
                        }
                        s.refetch_params = true;
                    }
                }
                Err(e) => {
                    s.report.last_error = Some(format!("the device refused {command:?}: {e}"));
                }
            }
            false
        }
        DeviceMsg::Event(e) => {
            s.report.last_event = Some(format!("tick {}: {:?}", e.tick, e.kind));
            false
        }
        DeviceMsg::Telemetry(t) => {
            s.status.tick_period_ms =
                (t.tick_period_mean_us > 0).then(|| f64::from(t.tick_period_mean_us) * 1e-3);
            s.device_dropped = t.frames_dropped;
            s.report.pose_gaps = t.pose_gaps;
            s.report.device_rx = t.rx;
            false
        }
        DeviceMsg::Hello(info) => {
            s.capabilities = info.capabilities;
            s.report.config = info.config.to_string();
            s.report.config_allows_forces = info.config.allows_forces();
            false
        }
        DeviceMsg::Config(Err(rej)) => {
            s.report.last_error = Some(format!("configuration: {rej}"));
            false
        }
        // Configuration and raw sensor readings are for bring-up tools, not the brush view.
        DeviceMsg::Config(Ok(_)) | DeviceMsg::Sensors(_) => false,
        DeviceMsg::Pong { .. } => false,
    }
}

/// The guide at a received state's tick: the anchor the writer sent with the pose the state
/// reports consumed, the stylus's distance from it, and the mirror's gain and force (none
/// while a fault is latched: the device cuts the guide then).
fn guide_frame(s: &mut Shared, state: &BrushState, handle: Pose<f64>) -> Option<GuideFrame> {
    while s
        .guide_sent
        .front()
        .is_some_and(|(q, _)| *q != state.pose_seq && seq_at_or_after(state.pose_seq, *q))
    {
        s.guide_sent.pop_front();
    }
    let (q, g) = s.guide_sent.front()?;
    if *q != state.pose_seq || !state.faults.is_empty() {
        return None;
    }
    let d = handle.pos.to_f64();
    let dist = (0..3)
        .map(|i| (d[i] - g.anchor[i]).powi(2))
        .sum::<f64>()
        .sqrt();
    Some(GuideFrame {
        distance_mm: dist,
        ..*g
    })
}

/// The GUI's frame for a received state: geometry bit for bit as the device computed it.
/// The wire carries the force on the hand, not its parts: the frame's normal force is the
/// force's z component, and the depth is the lowest skeleton node's depth below the paper
/// (as the force model computes it).
pub fn frame_from_state(state: &BrushState, tick: u64, replaying: bool) -> BrushFrame {
    let shape = state.shape();
    let lowest = shape
        .skeleton()
        .iter()
        .map(|v| v.z.to_f64())
        .fold(f64::INFINITY, f64::min);
    let force = state.haptics.force().to_f64();
    let output = if !state.faults.is_empty() {
        OutputState::Faulted
    } else if state.haptics.enabled {
        OutputState::Active
    } else {
        OutputState::Disabled
    };
    BrushFrame {
        tick,
        pose: shape.handle().cast(),
        spine: shape.spine().to_vec(),
        skeleton: shape.skeleton().to_vec(),
        layers: shape.layers().to_vec(),
        in_contact: (0..state.layers.len())
            .map(|i| state.in_contact(i))
            .collect(),
        ring_nodes: usize::from(state.ring_nodes),
        hairs: Vec::new(),
        eps: Fx::from_bits(state.footprint_eps),
        force_total: force,
        force_normal: [0.0, 0.0, force[2]],
        depth_mm: if lowest.is_finite() {
            (-lowest).max(0.0)
        } else {
            0.0
        },
        command: force,
        output,
        replaying,
        received: std::time::Instant::now(),
        guide: None,
    }
}

/// The virtual pen and what it is doing.
enum Pen {
    /// Following the GUI's hand.
    Hand,
    /// Moving (as a hand would) to a replay's first pose.
    Approach(Vec<Pose<f64>>),
    /// Streaming a replay's poses: the poses and the next one's index.
    Replay(Vec<Pose<f64>>, usize),
}

/// One hand step toward `target`: at most the hand speed; the rotation arrives with the
/// position (or turns a fixed share per tick once there).
fn step_toward(from: Pose<f64>, target: Pose<f64>) -> (Pose<f64>, bool) {
    let d = target.pos - from.pos;
    let n = d.norm();
    if n <= HAND_SPEED_MM_PER_TICK {
        let rot = Quat::nlerp(from.rot, target.rot, HAND_TURN_PER_TICK.max(0.5));
        return (Pose::new(target.pos, rot), true);
    }
    let f = HAND_SPEED_MM_PER_TICK / n;
    let rot = Quat::nlerp(from.rot, target.rot, f.max(HAND_TURN_PER_TICK));
    (Pose::new(from.pos + d.scale(f), rot), false)
}

fn run_writer(inner: &Inner, cmds: Receiver<DeviceCommand>, start: HandInput) {
    let mut target = start;
    let mut hand = start.pose();
    let mut pen = Pen::Hand;
    // Sequence numbers start at 1: a state with `pose_seq` 0 is one from before any pose.
    let mut seq: u32 = 1;
    // The first sequence number of the current session.
    let mut session_first = seq;
    let clock = Instant::now();
    let mut done: u64 = 0;
    let mut last_ping = Instant::now();
    let mut ping_seq = 0u32;
    let mut batch = Vec::with_capacity(64 * HostMsg::MAX_FRAME);
    let mut frame = [0u8; HostMsg::MAX_FRAME];
    let mut was_up = false;
    let mut syncing: Option<Instant> = None;
    // Guided writing: the stroke being played and the device's guide as mirrored here.
    let mut guide: Option<GuidePlay<Vec<Vec3<Fx>>>> = None;
    // "Stay in the lane": its wall point is computed from each pose as it is sent, so the
    // device's guide gets exactly the hand's position inside the tube.
    let mut lane: Option<super::lane::HostLane> = None;
    // The device's guide, fed what the device gets: the samples sent and the poses they ride
    // with (the virtual pen's hand is the pose sent), so its gain and force are the device's.
    // The shared defaults are valid (tested in maobi-shared).
    let mut mirror = HandGuide::<Fx>::new(DEFAULT_GUIDE).expect("the default guide is valid");
    loop {
        if inner.stop.load(Ordering::SeqCst) {
            return;
        }
        // Commands, in order.
        loop {
            let cmd = match cmds.recv_timeout(Duration::from_micros(500)) {
                Ok(c) => c,
                Err(RecvTimeoutError::Timeout) => break,
                Err(RecvTimeoutError::Disconnected) => return,
            };
            let msg = match cmd {
                // Refused in `send`: a pen has one model.
                DeviceCommand::Model(_) => None,
                DeviceCommand::Hand(h) => {
                    target = h;
                    None
                }
                DeviceCommand::EnableForces(true) => Some(HostMsg::Command(Command::EnableForces)),
                DeviceCommand::EnableForces(false) => {
                    Some(HostMsg::Command(Command::DisableForces))
                }
                DeviceCommand::ClearFault => Some(HostMsg::Command(Command::ClearFaults)),
                DeviceCommand::Dip(w) => Some(HostMsg::Command(Command::DipInk {
                    wetness: Fx::from_f32(w.clamp(0.0, 1.0)).to_bits(),
                })),
                DeviceCommand::Preset(name) => Some(HostMsg::Command(Command::ChoosePreset(
                    PresetRef::Name(bounded_str(&name)),
                ))),
                DeviceCommand::SetParam(id, value) => Some(HostMsg::SetParam {
                    id: id as u8,
                    value,
                }),
                DeviceCommand::Replay(track) => {
                    pen = Pen::Approach(track.resample().collect());
                    None
                }
                DeviceCommand::Guide(Some(track)) => {
                    let points: Vec<Vec3<Fx>> =
                        track.resample().map(|p| p.pos.cast::<Fx>()).collect();
                    if !points.is_empty() {
                        guide = Some(GuidePlay::new(points));
                        lane = None;
                    }
                    None
                }
                DeviceCommand::Lane(Some((track, radius_mm))) => {
                    let head = inner.shared().status.params.length_mm as f64;
                    lane = Some(maobi_shared::guide::Lane::new(
                        super::lane::pieces(&track, head),
                        radius_mm,
                    ));
                    guide = None;
                    None
                }
                DeviceCommand::Lane(None) => {
                    if let Some(l) = &mut lane {
                        l.stop();
                    }
                    None
                }
                DeviceCommand::Guide(None) => {
                    // Hold the point reached and fade out.
                    if let Some(g) = &mut guide {
                        g.stop();
                    }
                    None
                }
                DeviceCommand::StopReplay => {
                    let mut s = inner.shared();
                    match (&pen, &mut s.replay) {
                        (Pen::Replay(..), Some(span)) if seq > 0 => {
                            span.last = Some(seq.wrapping_sub(1));
                        }
                        _ => {
                            if s.replay.take().is_some() {
                                s.status.replays_done += 1;
                            }
                            s.status.replaying = false;
                        }
                    }
                    pen = Pen::Hand;
                    None
                }
            };
            if let Some(m) = msg {
                inner.send(&m);
            }
        }
        let (up, virtual_pen) = {
            let s = inner.shared();
            (
                s.status.connected,
                s.capabilities.contains(Capabilities::VIRTUAL_PEN),
            )
        };
        if !up {
            // Hold the pen (and the clock) until the link is back.
            was_up = false;
            if !matches!(pen, Pen::Hand) {
                pen = Pen::Hand;
            }
            std::thread::sleep(Duration::from_millis(1));
            continue;
        }
        let due = clock.elapsed().as_millis() as u64 + 1;
        if !was_up {
            was_up = true;
            done = due - 1;
            session_first = seq;
            syncing = Some(Instant::now());
            // The device restarts its forces (and its guide) at a new session's first pose.
            mirror.restart();
            inner.shared().guide_sent.clear();
        }
        if let Some(since) = syncing {
            // Start the virtual pen where the device's pen is (its first state says), so
            // the first sample of a session is no jump (the firmware latches one of more
            // than 10 mm as a sensor fault); without a state soon, start from ours.
            let at = inner.shared().device_handle;
            if let Some(p) = at {
                hand = p;
                syncing = None;
            } else if since.elapsed() >= SYNC_WAIT {
                syncing = None;
            } else {
                done = due;
                continue;
            }
        }
        if !virtual_pen {
            done = due;
            if last_ping.elapsed() >= PING_EVERY {
                last_ping = Instant::now();
                ping_seq = ping_seq.wrapping_add(1);
                inner.send(&HostMsg::Ping { seq: ping_seq });
            }
            continue;
        }
        if due > done + MAX_BEHIND_TICKS {
            done = due - MAX_BEHIND_TICKS;
        }
        // Poses the device has not reported consumed yet (a pose_seq from before this
        // session counts as none consumed).
        let in_flight = match inner.shared().device_pose_seq {
            Some(a) if seq_at_or_after(a, session_first) => seq.wrapping_sub(a).wrapping_sub(1),
            _ => seq.wrapping_sub(session_first),
        };
        let mut room = POSES_IN_FLIGHT.saturating_sub(in_flight);
        batch.clear();
        while done < due && room > 0 {
            // A replay's brush reset waits until the device has consumed every earlier pose:
            // the device applies a command when it arrives but queues poses, so a reset sent
            // behind queued poses would take effect before them.
            if matches!(pen, Pen::Replay(_, 0)) && room < POSES_IN_FLIGHT {
                break;
            }
            done += 1;
            room -= 1;
            let pose = match &mut pen {
                Pen::Hand => {
                    let (p, _) = step_toward(hand, target.pose());
                    // The hand's own tilt turns gradually, as in the built-in simulator.
                    let rot = Quat::nlerp(hand.rot, target.pose().rot, HAND_TURN_PER_TICK);
                    Pose::new(p.pos, rot)
                }
                Pen::Approach(poses) => {
                    let first = poses[0];
                    let (p, arrived) = step_toward(hand, first);
                    if arrived {
                        // The approach ends exactly at the first pose.
                        pen = Pen::Replay(std::mem::take(poses), 0);
                        first
                    } else {
                        p
                    }
                }
                Pen::Replay(poses, k) => {
                    if *k == 0 {
                        // The brush restarts at rest at the first pose, as the built-in
                        // simulator's replay does; the replay's poses follow.
                        let n = encode(&HostMsg::Command(Command::ResetBrush), &mut frame);
                        batch.extend_from_slice(&frame[..n]);
                        // The device's reset restarts its forces and cuts its guide.
                        mirror.restart();
                        let mut s = inner.shared();
                        if let Some(span) = &mut s.replay {
                            span.first = Some(seq);
                        }
                    }
                    let p = poses[*k];
                    *k += 1;
                    if *k >= poses.len() {
                        let mut s = inner.shared();
                        if let Some(span) = &mut s.replay {
                            span.last = Some(seq);
                        }
                        drop(s);
                        let pp = p.pos.to_f64();
                        target = HandInput {
                            x: pp[0],
                            y: pp[1],
                            z: pp[2],
                            ..target
                        };
                        pen = Pen::Hand;
                    }
                    p
                }
            };
            hand = pose;
            let pos: Vec3<Fx> = pose.pos.cast();
            // The moving point for this tick goes just before its pose.
            let g = match &mut lane {
                Some(l) => l.next_sample(Some(pose.pos.to_f64()), mirror.stream()),
                None => guide.as_mut().and_then(|g| g.next_sample(mirror.stream())),
            };
            if let Some(g) = g {
                let n = encode(
                    &HostMsg::Guide(GuideSample::new(seq, g.anchor, g.on)),
                    &mut frame,
                );
                batch.extend_from_slice(&frame[..n]);
            }
            let (_, force) = mirror.tick(g, pos, true, false);
            if let Some(f) = mirrored_guide_frame(&mirror, &force) {
                let mut s = inner.shared();
                if s.guide_sent.len() >= GUIDE_SENT_KEPT {
                    s.guide_sent.pop_front();
                }
                s.guide_sent.push_back((seq, f));
            }
            if g.is_none() && !mirror.stream().active() {
                guide = None;
            }
            if lane.as_ref().is_some_and(|l| l.done(mirror.stream())) {
                lane = None;
            }
            let sample = PoseSample::new(seq, pose.cast(), Buttons::empty());
            seq = seq.wrapping_add(1);
            let n = encode(&HostMsg::Pose(sample), &mut frame);
            batch.extend_from_slice(&frame[..n]);
        }
        if !batch.is_empty() {
            inner.write(&batch);
        }
    }
}

/// What the GUI shows of the device's guide after a tick with the guide's force `f`, while
/// the guide is active (or its force not yet zero).
fn mirrored_guide_frame(mirror: &HandGuide<Fx>, f: &GuideForce<Fx>) -> Option<GuideFrame> {
    let stream = mirror.stream();
    if stream.active() || f.force != Vec3::ZERO {
        GuideFrame::of(stream, f)
    } else {
        None
    }
}

fn encode(msg: &HostMsg, out: &mut [u8]) -> usize {
    msg.encode(out).unwrap_or(0)
}
