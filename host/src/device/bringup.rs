//! `maobi device check`: the first power-on of a pen, step by step, over the wire protocol.
//!
//! 1. handshake: protocol, firmware, board, capabilities and the stored configuration's state
//!    (a missing or corrupt configuration stops the check unless the builder lets it write
//!    the reference configuration, [`DeviceConfig::DEFAULT`]);
//! 2. live sensor readings ([`Command::StreamSensors`]): the builder moves each joint, every
//!    encoder and gimbal channel must change (PASS with the sign of its largest excursion);
//!    a virtual pen (QEMU, [`Capabilities::VIRTUAL_PEN`]) is moved by this wizard instead,
//!    through a scripted motion of the pose it streams;
//! 3. each motor nudged ([`Command::NudgeMotor`]) after a confirmation, the encoder read
//!    before and after: the joint must move, the way a positive command should turn it; a
//!    reversed motor can have its `motor_sign` flipped in the stored configuration, and is
//!    nudged again to confirm;
//! 4. calibration: the pen in its inkwell, [`Command::Calibrate`], the configuration read back
//!    valid and calibrated (before step 3 when the pen is not calibrated yet: the firmware
//!    keeps the motors off until it is);
//! 5. a summary; any FAIL makes the command's exit code non-zero.
//!
//! A step the device's hello says it does not offer is skipped, with the reason, and is no
//! failure: the sensor stream and the nudges need [`Capabilities::STORED_CONFIG`] (the
//! firmware's boards; not `maobi sim-device` nor `maobi bridge`), the nudges
//! [`Capabilities::FORCE_OUTPUT`], calibration a stored configuration.
//!
//! The terminal is behind [`Operator`], so scripts and tests run it without one ([`Scripted`]:
//! `--yes`).
//!
//! Assumes the board applies the configuration's `motor_sign` to a nudge (a positive nudge
//! is meant to turn the joint the positive way) and that a joint's direction is its encoder
//! count times `encoder_sign`.

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use maobi_shared::protocol::{
    Buttons, Capabilities, Command, CommandError, ConfigRejected, ConfigState, DeviceConfig,
    DeviceInfo, DeviceMsg, Faults, HostMsg, HostRx, Message, Nudge, PoseSample, SensorReport,
};
use maobi_shared::{Pose, Quat, Vec3};

use super::client::HandshakeError;
use super::endpoint::{nothing_to_read_yet, Conn, Endpoint};

/// Sensor reports per second asked for while the check runs.
pub const SENSOR_HZ: u16 = 50;
/// The names of the three motor joints and the three gimbal axes, in channel order.
pub const ARM_JOINTS: [&str; 3] = ["base (yaw)", "shoulder", "elbow"];
pub const GIMBAL_AXES: [&str; 3] = ["gimbal 1", "gimbal 2", "gimbal 3"];

/// What the builder is asked and shown.
pub trait Operator {
    /// A line of output.
    fn say(&mut self, text: &str);
    /// A line redrawn in place (live readings).
    fn live(&mut self, text: &str);
    /// A yes/no question; no unless answered yes.
    fn confirm(&mut self, question: &str) -> bool;
    /// Waits for Enter after `prompt`.
    fn wait_enter(&mut self, prompt: &str);
    /// Whether Enter was pressed since the last call (does not block).
    fn enter_pressed(&mut self) -> bool;
}

/// `--yes`: every question answered yes, nothing waited for; output to stdout.
#[derive(Default)]
pub struct Scripted {
    /// Everything said, for tests.
    pub transcript: Vec<String>,
    pub echo: bool,
}

impl Operator for Scripted {
    fn say(&mut self, text: &str) {
        if self.echo {
            println!("{text}");
        }
        self.transcript.push(text.to_string());
    }
    fn live(&mut self, _text: &str) {}
    fn confirm(&mut self, question: &str) -> bool {
        self.say(&format!("{question} [y/N] y (--yes)"));
        true
    }
    fn wait_enter(&mut self, prompt: &str) {
        self.say(&format!("{prompt} (--yes: not waiting)"));
    }
    fn enter_pressed(&mut self) -> bool {
        false
    }
}

/// The terminal: questions on stdout, answers from stdin lines (read by a thread, so live
/// readings can stop at Enter without blocking).
pub struct Terminal {
    lines: std::sync::mpsc::Receiver<String>,
    live_shown: bool,
}

impl Terminal {
    pub fn new() -> Self {
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let stdin = std::io::stdin();
            let mut line = String::new();
            while stdin.read_line(&mut line).is_ok_and(|n| n > 0) {
                if tx.send(std::mem::take(&mut line)).is_err() {
                    break;
                }
            }
        });
        Terminal {
            lines: rx,
            live_shown: false,
        }
    }
    fn end_live(&mut self) {
        if std::mem::take(&mut self.live_shown) {
            println!();
        }
    }
}

impl Default for Terminal {
    fn default() -> Self {
        Self::new()
    }
}

impl Operator for Terminal {
    fn say(&mut self, text: &str) {
        self.end_live();
        println!("{text}");
    }
    fn live(&mut self, text: &str) {
        use std::io::Write;
        // Clear to the end of the line: the new text may be shorter.
        print!("\r{text}\x1b[K");
        let _ = std::io::stdout().flush();
        self.live_shown = true;
    }
    fn confirm(&mut self, question: &str) -> bool {
        use std::io::Write;
        self.end_live();
        // Answers typed before the question do not count.
        while self.lines.try_recv().is_ok() {}
        print!("{question} [y/N] ");
        let _ = std::io::stdout().flush();
        match self.lines.recv() {
            Ok(a) => matches!(a.trim().to_lowercase().as_str(), "y" | "yes"),
            Err(_) => false,
        }
    }
    fn wait_enter(&mut self, prompt: &str) {
        use std::io::Write;
        self.end_live();
        while self.lines.try_recv().is_ok() {}
        print!("{prompt} ");
        let _ = std::io::stdout().flush();
        let _ = self.lines.recv();
    }
    fn enter_pressed(&mut self) -> bool {
        self.lines.try_recv().is_ok()
    }
}

/// How the check runs.
#[derive(Clone, Debug)]
pub struct CheckOptions {
    pub endpoint: Endpoint,
    /// How long the live readings run (Enter ends them sooner).
    pub sensor_time: Duration,
    /// How long the device may take to answer a command.
    pub reply_timeout: Duration,
    /// The nudge: command (thousandths of full current) and duration.
    pub nudge_permille: i16,
    pub nudge_ms: u16,
    /// Smallest change that counts as a joint having moved: encoder counts, gimbal codes.
    pub min_counts: i64,
    pub min_codes: i32,
    /// What step 1 writes to a pen with a missing or corrupt configuration: the builder's own
    /// (`--config FILE`) or, by default, the reference pen's.
    pub first_config: DeviceConfig,
}

impl CheckOptions {
    pub fn new(endpoint: Endpoint) -> Self {
        CheckOptions {
            endpoint,
            sensor_time: Duration::from_secs(10),
            reply_timeout: Duration::from_secs(3),
            nudge_permille: 80,
            nudge_ms: 150,
            min_counts: 4,
            min_codes: 20,
            first_config: DeviceConfig::DEFAULT,
        }
    }
}

/// A step's verdict.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub enum Outcome {
    Pass,
    Fail,
    /// Not run (declined, or it cannot apply to this device); not a failure.
    Skip,
}

impl std::fmt::Display for Outcome {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        // `pad`: the summary table aligns the column with a width.
        f.pad(match self {
            Outcome::Pass => "PASS",
            Outcome::Fail => "FAIL",
            Outcome::Skip => "SKIP",
        })
    }
}

/// One line of the summary.
#[derive(Clone, Debug)]
pub struct StepReport {
    pub step: String,
    pub outcome: Outcome,
    pub detail: String,
}

/// Every step's verdict, in order.
#[derive(Clone, Debug, Default)]
pub struct CheckReport {
    pub steps: Vec<StepReport>,
    pub info: Option<DeviceInfo>,
}

impl CheckReport {
    pub fn passed(&self) -> bool {
        !self.steps.is_empty() && self.steps.iter().all(|s| s.outcome != Outcome::Fail)
    }
    pub fn outcome(&self, step: &str) -> Option<Outcome> {
        self.steps
            .iter()
            .find(|s| s.step == step)
            .map(|s| s.outcome)
    }
    fn push(&mut self, step: impl Into<String>, outcome: Outcome, detail: impl Into<String>) {
        self.steps.push(StepReport {
            step: step.into(),
            outcome,
            detail: detail.into(),
        });
    }
    /// The summary table.
    pub fn table(&self) -> String {
        let w = self.steps.iter().map(|s| s.step.len()).max().unwrap_or(4);
        let mut s = format!("{:<w$}  result  detail\n", "step");
        for r in &self.steps {
            s.push_str(&format!("{:<w$}  {:<6}  {}\n", r.step, r.outcome, r.detail));
        }
        s.trim_end().to_string()
    }
}

/// A synchronous protocol session for the check.
pub struct Wire {
    conn: Box<dyn Conn>,
    dec: Box<HostRx>,
    buf: Vec<u8>,
    pending: VecDeque<DeviceMsg>,
    pub info: DeviceInfo,
    /// The latest sensor report and the latest brush state's handle pose.
    pub sensors: Option<SensorReport>,
    /// Every sensor report since the last [`Wire::take_sensor_reports`] (at most
    /// [`SENSOR_BACKLOG`]; the oldest are dropped).
    backlog: VecDeque<SensorReport>,
    pub handle: Option<Pose<f64>>,
    /// The faults the latest state frame or event reported (latched ones and
    /// `NOT_CALIBRATED`), and when that message arrived.
    pub faults: Option<(Faults, Instant)>,
    last_sent: Instant,
    ping: u32,
    /// A virtual pen's pose stream, once started.
    pen: Option<VirtualPen>,
}

/// The pose stream of a virtual pen: poses queued to send, then the last one held. Paced
/// by the device: at most [`POSES_AHEAD`] poses beyond the last one a state reported
/// consumed, so a device slower than real time (the firmware in QEMU) is never overrun, and
/// one that runs its clock ahead while idle (QEMU's `-icount sleep=off`) always has a pose
/// to tick on and never sees the host fall silent.
struct VirtualPen {
    queue: VecDeque<Pose<f64>>,
    hold: Pose<f64>,
    next_seq: u32,
    first_seq: u32,
    acked: Option<u32>,
    /// The sequence number of the last queued (not held) pose.
    last_queued: Option<u32>,
}

/// Poses sent ahead of the device's consumption (its queue holds 64).
pub const POSES_AHEAD: u32 = 32;

/// Sensor reports kept for [`Wire::take_sensor_reports`]: a minute at [`SENSOR_HZ`].
const SENSOR_BACKLOG: usize = 3000;
/// How often an otherwise idle wizard pings (so the device does not count the host gone).
const KEEPALIVE: Duration = Duration::from_millis(100);
/// Pause between connection attempts a TCP endpoint turned away (see [`Wire::connect`]).
const RETRY_PAUSE: Duration = Duration::from_millis(100);

impl Wire {
    /// Opens `endpoint` and shakes hands. A TCP endpoint that drops the connection before
    /// answering is tried again (every 100 ms, within `timeout`): QEMU's UART socket serves
    /// one client at a time and turns away one that arrives before it has seen the last
    /// one leave.
    pub fn connect(endpoint: &Endpoint, timeout: Duration) -> Result<Wire, String> {
        let started = Instant::now();
        let mut dec = Box::new(HostRx::new());
        let (conn, info) = loop {
            let mut conn = endpoint
                .open()
                .map_err(|e| format!("cannot open {endpoint}: {e}"))?;
            dec.reset();
            let left = timeout.saturating_sub(started.elapsed());
            match super::client::handshake(&mut *conn, &mut dec, "maobi-check", left, &|| false) {
                Some(Ok(info)) => break (conn, info),
                Some(Err(e))
                    if e.closed
                        && matches!(endpoint, Endpoint::Tcp(_))
                        && started.elapsed() + RETRY_PAUSE < timeout =>
                {
                    conn.shut();
                    std::thread::sleep(RETRY_PAUSE);
                }
                Some(Err(e)) => return Err(no_answer_cause(endpoint, e)),
                None => return Err("stopped".into()),
            }
        };
        Ok(Wire {
            conn,
            dec,
            buf: vec![0; 8192],
            pending: VecDeque::new(),
            info,
            sensors: None,
            backlog: VecDeque::new(),
            handle: None,
            faults: None,
            last_sent: Instant::now(),
            ping: 0,
            pen: None,
        })
    }

    pub fn send(&mut self, m: &HostMsg) -> Result<(), String> {
        let mut b = [0u8; HostMsg::MAX_FRAME];
        let n = m.encode(&mut b).map_err(|e| format!("encoding: {e}"))?;
        self.conn
            .write_all(&b[..n])
            .and_then(|()| self.conn.flush())
            .map_err(|e| format!("writing to the device: {e}"))?;
        self.last_sent = Instant::now();
        Ok(())
    }

    /// One read (at most the endpoint's read poll), decoded into `pending`.
    fn pump(&mut self) -> Result<(), String> {
        self.feed_pen()?;
        if self.last_sent.elapsed() >= KEEPALIVE {
            self.ping = self.ping.wrapping_add(1);
            self.send(&HostMsg::Ping { seq: self.ping })?;
        }
        let n = match self.conn.read(&mut self.buf) {
            Ok(0) => return Err("the device closed the link".into()),
            Ok(n) => n,
            Err(e) if nothing_to_read_yet(&e) => 0,
            Err(e) => return Err(format!("reading from the device: {e}")),
        };
        for m in self.dec.feed(&self.buf[..n]).flatten() {
            match &m {
                DeviceMsg::Sensors(r) => {
                    self.sensors = Some(r.clone());
                    if self.backlog.len() >= SENSOR_BACKLOG {
                        self.backlog.pop_front();
                    }
                    self.backlog.push_back(r.clone());
                }
                DeviceMsg::Event(e) => self.faults = Some((e.faults, Instant::now())),
                DeviceMsg::State(s) => {
                    self.faults = Some((s.faults, Instant::now()));
                    self.handle = Some(s.shape().handle().cast());
                    if let Some(pen) = &mut self.pen {
                        if s.pose_seq.wrapping_sub(pen.first_seq) < 1 << 31
                            && pen.acked.is_none_or(|a| {
                                s.pose_seq.wrapping_sub(a).wrapping_sub(1) < 1 << 31
                            })
                        {
                            pen.acked = Some(s.pose_seq);
                        }
                    }
                }
                _ => {}
            }
            self.pending.push_back(m);
        }
        Ok(())
    }

    /// The faults the device reports in state frames and events arriving after `since`:
    /// the first report `wanted` accepts, else (after `timeout`) the last one that came;
    /// `None` if none came.
    pub fn faults_since(
        &mut self,
        since: Instant,
        timeout: Duration,
        wanted: impl Fn(Faults) -> bool,
    ) -> Result<Option<Faults>, String> {
        let end = Instant::now() + timeout;
        loop {
            let latest = self.faults.filter(|(_, at)| *at > since).map(|(f, _)| f);
            if latest.is_some_and(&wanted) || Instant::now() >= end {
                return Ok(latest);
            }
            self.pump()?;
        }
    }

    /// Waits up to `timeout` for the first message `pick` accepts (others are dropped; the
    /// latest sensors and handle pose are kept as they pass).
    pub fn wait<R>(
        &mut self,
        timeout: Duration,
        mut pick: impl FnMut(&DeviceMsg) -> Option<R>,
    ) -> Result<Option<R>, String> {
        let end = Instant::now() + timeout;
        loop {
            while let Some(m) = self.pending.pop_front() {
                if let Some(r) = pick(&m) {
                    return Ok(Some(r));
                }
            }
            if Instant::now() >= end {
                return Ok(None);
            }
            self.pump()?;
        }
    }

    /// Starts streaming poses for a virtual pen, holding `at`.
    pub fn start_virtual_pen(&mut self, at: Pose<f64>) {
        self.pen = Some(VirtualPen {
            queue: VecDeque::new(),
            hold: at,
            next_seq: 1,
            first_seq: 1,
            acked: None,
            last_queued: None,
        });
    }

    /// Queues `poses` for the virtual pen (then it holds the last).
    pub fn move_virtual_pen(&mut self, poses: &[Pose<f64>]) {
        if let Some(pen) = &mut self.pen {
            pen.queue.extend(poses.iter().copied());
        }
    }

    /// Whether every queued pose has been sent and reported consumed.
    pub fn virtual_pen_arrived(&self) -> bool {
        self.pen.as_ref().is_none_or(|p| {
            p.queue.is_empty()
                && match (p.last_queued, p.acked) {
                    (Some(l), Some(a)) => a.wrapping_sub(l) < 1 << 31,
                    (Some(_), None) => false,
                    (None, _) => true,
                }
        })
    }

    /// Tops up the virtual pen's poses in flight.
    fn feed_pen(&mut self) -> Result<(), String> {
        let Some(pen) = &mut self.pen else {
            return Ok(());
        };
        let consumed_to = pen.acked.unwrap_or(pen.first_seq.wrapping_sub(1));
        let in_flight = pen.next_seq.wrapping_sub(consumed_to).wrapping_sub(1);
        let room = POSES_AHEAD.saturating_sub(in_flight);
        let mut batch = Vec::new();
        let mut frame = [0u8; HostMsg::MAX_FRAME];
        for _ in 0..room {
            let pose = match pen.queue.pop_front() {
                Some(p) => {
                    pen.hold = p;
                    pen.last_queued = Some(pen.next_seq);
                    p
                }
                None => pen.hold,
            };
            let sample = PoseSample::new(pen.next_seq, pose.cast(), Buttons::empty());
            pen.next_seq = pen.next_seq.wrapping_add(1);
            let n = HostMsg::Pose(sample)
                .encode(&mut frame)
                .map_err(|e| format!("encoding: {e}"))?;
            batch.extend_from_slice(&frame[..n]);
        }
        if !batch.is_empty() {
            self.conn
                .write_all(&batch)
                .and_then(|()| self.conn.flush())
                .map_err(|e| format!("writing to the device: {e}"))?;
            self.last_sent = Instant::now();
        }
        Ok(())
    }

    /// The sensor reports received since the last call, in order.
    pub fn take_sensor_reports(&mut self) -> Vec<SensorReport> {
        self.backlog.drain(..).collect()
    }

    /// Reads what arrives for `d`.
    pub fn idle(&mut self, d: Duration) -> Result<(), String> {
        self.wait(d, |_| None::<()>).map(|_| ())
    }

    /// Sends a command and waits for its answer.
    pub fn command(
        &mut self,
        c: Command,
        timeout: Duration,
    ) -> Result<Result<(), CommandError>, String> {
        self.send(&HostMsg::Command(c.clone()))?;
        self.wait(timeout, |m| match m {
            DeviceMsg::CommandDone { command, result } if *command == c => Some(result.clone()),
            _ => None,
        })?
        .ok_or_else(|| format!("no answer to {c:?} within {} s", timeout.as_secs_f64()))
    }

    fn config_reply(
        &mut self,
        timeout: Duration,
    ) -> Result<Result<DeviceConfig, ConfigRejected>, String> {
        self.wait(timeout, |m| match m {
            DeviceMsg::Config(r) => Some(r.clone()),
            _ => None,
        })?
        .ok_or_else(|| {
            format!(
                "no answer about the configuration within {} s",
                timeout.as_secs_f64()
            )
        })
    }

    pub fn get_config(
        &mut self,
        timeout: Duration,
    ) -> Result<Result<DeviceConfig, ConfigRejected>, String> {
        self.send(&HostMsg::GetConfig)?;
        self.config_reply(timeout)
    }

    pub fn set_config(
        &mut self,
        cfg: DeviceConfig,
        timeout: Duration,
    ) -> Result<Result<DeviceConfig, ConfigRejected>, String> {
        self.send(&HostMsg::SetConfig(cfg))?;
        self.config_reply(timeout)
    }

    /// A sensor report newer than the latest one seen (waits for the stream).
    pub fn fresh_sensors(&mut self, timeout: Duration) -> Result<SensorReport, String> {
        let after = self.sensors.as_ref().map(|s| s.tick);
        self.wait(timeout, |m| match m {
            DeviceMsg::Sensors(r) if after.is_none_or(|t| r.tick != t) => Some(r.clone()),
            _ => None,
        })?
        .ok_or_else(|| format!("no sensor report within {} s", timeout.as_secs_f64()))
    }
}

/// One sensor channel's excursion from its first reading.
#[derive(Copy, Clone, Debug, Default)]
struct Excursion {
    first: Option<i64>,
    /// The reading farthest from the first, minus the first.
    largest: i64,
}

impl Excursion {
    fn add(&mut self, v: i64) {
        let first = *self.first.get_or_insert(v);
        let d = v - first;
        if d.abs() > self.largest.abs() {
            self.largest = d;
        }
    }
}

fn sign(v: i64) -> &'static str {
    if v >= 0 {
        "+"
    } else {
        "-"
    }
}

/// The scripted motion a virtual pen is put through in the sensor step: from `start`, each
/// translation axis out 15 mm and back, then a 15 degree turn about each axis and back, in
/// steps well under the device's sensor-jump limit.
pub fn virtual_motion(start: Pose<f64>) -> Vec<Pose<f64>> {
    const STEP_MM: f64 = 0.25;
    const OUT_MM: f64 = 15.0;
    const TURN: f64 = 15.0 * std::f64::consts::PI / 180.0;
    let n = (OUT_MM / STEP_MM) as usize;
    let mut poses = vec![];
    for axis in 0..3 {
        let mut d = [0.0; 3];
        for k in (0..=n).chain((0..n).rev()) {
            d[axis] = k as f64 * STEP_MM;
            poses.push(Pose::new(
                start.pos + Vec3::new(d[0], d[1], d[2]),
                start.rot,
            ));
        }
    }
    for axis in 0..3 {
        let mut a = [0.0; 3];
        a[axis] = 1.0;
        let about = Vec3::new(a[0], a[1], a[2]);
        for k in (0..=n).chain((0..n).rev()) {
            let half = TURN * k as f64 / n as f64 / 2.0;
            let v = about.scale(half.sin());
            let turn = Quat::new(half.cos(), v.x, v.y, v.z);
            poses.push(Pose::new(start.pos, turn.compose(start.rot)));
        }
    }
    poses
}

/// A handshake's failure as `maobi device check` reports it: a serial port that opened and
/// sent back not one byte is named for its usual cause, DTR. The Black Pill's firmware
/// used to send nothing until the host asserted DTR (data terminal ready, CDC-ACM's "a
/// program has the port open"); today's answers whatever DTR says, and this host asserts it
/// when it opens a port (`endpoint::serial_settings`), so a silent port means an older
/// firmware with DTR lost on the way, the firmware not running, or another program on the
/// port.
pub(crate) fn no_answer_cause(endpoint: &Endpoint, e: HandshakeError) -> String {
    match endpoint {
        Endpoint::Serial(_) if e.silent => format!(
            "{}: the port opened but the pen sent nothing. A pen whose firmware predates this \
             host's answers only while the host holds DTR (data terminal ready) asserted; \
             `maobi` asserts it on open, so DTR was lost on the way (a USB hub or adapter, a \
             virtual machine's USB passthrough, another program holding the port) or the \
             firmware is not running: close other programs on the port, replug the pen, \
             update its firmware (it now answers whatever DTR says), and read its log \
             (`probe-rs attach`)",
            e.message
        ),
        _ => e.message,
    }
}

/// Runs the check against `opts.endpoint`.
pub fn run_check(opts: &CheckOptions, op: &mut dyn Operator) -> CheckReport {
    let mut report = CheckReport::default();
    let mut wire = match Wire::connect(&opts.endpoint, opts.reply_timeout) {
        Ok(w) => w,
        Err(e) => {
            report.push(
                "1 handshake",
                Outcome::Fail,
                format!("{e} (is the pen plugged in and flashed? `maobi gui` lists the ports)"),
            );
            return report;
        }
    };
    let info = wire.info.clone();
    report.info = Some(info.clone());
    let virtual_pen = info.capabilities.contains(Capabilities::VIRTUAL_PEN);
    op.say(&format!(
        "device: board {} firmware {} protocol {}, capabilities {}, forces {} N peak / {} N \
         continuous, configuration {}, tick limits {}",
        info.board,
        info.firmware,
        info.protocol_version,
        info.capabilities,
        info.force_peak_n,
        info.force_continuous_n,
        info.config,
        info.limits
    ));
    if virtual_pen {
        op.say(
            "note: this is a virtual pen (the QEMU board or a simulator): its sensor readings are \
             computed from the poses this check sends and its motors do not exist. A run here \
             checks the protocol, the kinematics and this wizard; not wiring, motor direction, \
             sensor noise or calibration on a real arm.",
        );
    }
    if !step_handshake(&mut wire, opts, op, &mut report) {
        return report;
    }
    let bring_up = info.capabilities.contains(Capabilities::STORED_CONFIG);
    let streaming = match no_bring_up(&info) {
        None => step_sensors(&mut wire, opts, op, &mut report, virtual_pen),
        Some(why) => {
            let why = format!("the device streams no raw sensor readings {why}");
            skip(op, &mut report, "2 sensors", why);
            false
        }
    };
    // The firmware keeps the motors off until the pen is calibrated (a configuration just
    // written, never calibrated, or on a pen with incremental encoders not since power-on)
    // and says so with NOT_CALIBRATED: then calibration comes before the nudges. Firmware
    // that does not report it yet is judged by its stored calibration.
    let uncalibrated = no_calibration(&wire.info).is_none()
        && (matches!(
            wire.faults_since(Instant::now(), opts.reply_timeout, |_| true),
            Ok(Some(f)) if f.contains(Faults::NOT_CALIBRATED)
        ) || matches!(wire.get_config(opts.reply_timeout), Ok(Ok(c)) if c.calibration.is_none()));
    if uncalibrated {
        op.say(
            "The pen is not calibrated yet and its firmware keeps the motors off until it is: \
             calibrating (step 4) before the motor nudges.",
        );
        step_calibrate(&mut wire, opts, op, &mut report);
        step_nudges(&mut wire, opts, op, &mut report, virtual_pen, streaming);
    } else {
        step_nudges(&mut wire, opts, op, &mut report, virtual_pen, streaming);
        step_calibrate(&mut wire, opts, op, &mut report);
    }
    if bring_up {
        let _ = wire.command(Command::StreamSensors { rate_hz: 0 }, opts.reply_timeout);
    }
    step_tick(&mut wire, opts, op, &mut report);
    report
}

/// The worst share of the 1 ms tick a pen's core may spend on the tick's work: beyond it,
/// the next interrupt, a longer stroke or a warmer chip overruns.
pub const WORST_TICK_PERCENT: f32 = 90.0;

/// Step 5: the force tick's timing from the device's telemetry (sent once a second): its
/// worst busy time and its overruns since start (skipped for a device that sends none). A pen with sensors of its own fails on
/// any overrun or a worst tick above [`WORST_TICK_PERCENT`]; a virtual pen's clock is
/// emulated or the desktop's, so its figures are shown, not judged.
fn step_tick(
    wire: &mut Wire,
    opts: &CheckOptions,
    op: &mut dyn Operator,
    report: &mut CheckReport,
) {
    const STEP: &str = "5 tick";
    let wait = opts.reply_timeout.max(Duration::from_millis(2500));
    let t = match wire.wait(wait, |m| match m {
        DeviceMsg::Telemetry(t) => Some(t.clone()),
        _ => None,
    }) {
        Ok(Some(t)) => t,
        Ok(None) => {
            // The pen's firmware reports once a second; a device that sends none (a test's
            // fake, a bridge) leaves the tick's timing unknown, which is not a fault of its
            // wiring.
            let why = format!("no telemetry in {wait:?}: the tick's timing is not known");
            skip(op, report, STEP, why);
            return;
        }
        Err(e) => {
            report.push(STEP, Outcome::Fail, e);
            return;
        }
    };
    let what = format!(
        "worst tick busy {} us ({:.1}% of the tick, {} cycles), mean load {}%, overruns {} since start",
        t.tick_busy_max_us,
        t.worst_busy_percent(),
        t.tick_busy_max_cycles,
        t.load_percent,
        t.overruns
    );
    op.say(&format!("{STEP}: {what}"));
    let judged = wire.info.capabilities.contains(Capabilities::REAL_SENSORS);
    let outcome = if !judged || (t.overruns == 0 && t.worst_busy_percent() <= WORST_TICK_PERCENT) {
        Outcome::Pass
    } else {
        Outcome::Fail
    };
    let note = if judged {
        format!("{what} (fails on any overrun or a worst tick above {WORST_TICK_PERCENT}%)")
    } else {
        format!("{what} (a virtual pen: its clock is not the pen's, not judged)")
    };
    report.push(STEP, outcome, note);
}

/// A step the device does not offer: said as it is reached, a SKIP in the summary.
fn skip(op: &mut dyn Operator, report: &mut CheckReport, step: &str, why: String) {
    op.say(&format!("{step}: skipped: {why}"));
    report.push(step, Outcome::Skip, why);
}

/// Why the device answers no bring-up command (sensor stream, motor nudge), from its hello:
/// "(capabilities ...: no STORED_CONFIG ...)". They came with the stored configuration
/// (protocol 3) and the firmware answers them on every board that announces one; a device
/// that keeps none (`maobi sim-device`, `maobi bridge`) answers them `Unsupported`, which is
/// no fault of its wiring.
fn no_bring_up(info: &DeviceInfo) -> Option<String> {
    (!info.capabilities.contains(Capabilities::STORED_CONFIG)).then(|| {
        format!(
            "(capabilities {}: no STORED_CONFIG, which the bring-up commands come with)",
            caps_text(info.capabilities)
        )
    })
}

/// Why step 3 cannot nudge this device's motors, from its hello.
fn no_nudges(info: &DeviceInfo) -> Option<String> {
    if !info.capabilities.contains(Capabilities::FORCE_OUTPUT) {
        return Some(format!(
            "the device has no motors (capabilities {}: no FORCE_OUTPUT)",
            caps_text(info.capabilities)
        ));
    }
    no_bring_up(info).map(|why| format!("the device takes no motor nudge {why}"))
}

/// Why step 4 does not apply to this device: it keeps no configuration to hold a
/// calibration (by its capabilities, or the QEMU board without a store, by its hello's
/// configuration state).
fn no_calibration(info: &DeviceInfo) -> Option<String> {
    let keeps_one = info.capabilities.contains(Capabilities::STORED_CONFIG)
        && info.config != ConfigState::NotApplicable;
    if keeps_one {
        return None;
    }
    Some(
        if info.capabilities.contains(Capabilities::VIRTUAL_PEN) {
            "this device keeps no configuration (a virtual pen needs no calibration: its pose \
             comes from the host)"
        } else {
            "this device keeps no configuration to store a calibration in (a device behind a \
             bridge, such as `maobi bridge`'s Phantom, is calibrated by its own library)"
        }
        .to_string(),
    )
}

/// A capability set as its flags' names ("none" when empty).
fn caps_text(caps: Capabilities) -> String {
    if caps.is_empty() {
        "none".to_string()
    } else {
        caps.to_string()
    }
}

/// Step 1's verdict on the configuration; false: stop here.
fn step_handshake(
    wire: &mut Wire,
    opts: &CheckOptions,
    op: &mut dyn Operator,
    report: &mut CheckReport,
) -> bool {
    let info = wire.info.clone();
    let what = format!(
        "protocol {}, firmware {}, board {}, configuration {}",
        info.protocol_version, info.firmware, info.board, info.config
    );
    match &info.config {
        ConfigState::Valid | ConfigState::NotApplicable => {
            report.push("1 handshake", Outcome::Pass, what);
            true
        }
        ConfigState::Migrated { .. } => {
            // Not the reference configuration over it: that would lose the pen's geometry,
            // limits and calibration, which the migration kept.
            op.say(&format!(
                "The pen's stored {}. Its kinematics and calibration are in force; forces \
                 and motor nudges stay off until then.",
                info.config
            ));
            report.push(
                "1 handshake",
                Outcome::Fail,
                format!(
                    "{what}: stopped. Read the migrated configuration (`maobi device config \
                     get -o pen.toml`), set drive.winding_mohm for each motor, power.supply_v \
                     and power.driver_current_a (0 there: not given) and each drive.max_duty \
                     within the driver's rating, write it (`maobi device config set \
                     pen.toml`), then run the check again"
                ),
            );
            false
        }
        bad @ (ConfigState::Missing | ConfigState::Corrupt(_)) => {
            op.say(&format!(
                "The pen's stored configuration is {bad}: forces and motor nudges stay off \
                 until a valid one is written."
            ));
            let which = if opts.first_config == DeviceConfig::DEFAULT {
                "the reference configuration (link lengths, ratios, signs of the reference \
                 pen, not calibrated)"
            } else {
                "the configuration given with --config"
            };
            let short = which.split(" (").next().unwrap_or(which);
            if !op.confirm(&format!("Write {which} to the pen now?")) {
                report.push(
                    "1 handshake",
                    Outcome::Fail,
                    format!(
                        "{what}: stopped. Write a configuration (`maobi device config set \
                         FILE`, or run `maobi device check` again and let it write one), then \
                         calibrate (step 4)"
                    ),
                );
                return false;
            }
            match wire.set_config(opts.first_config, opts.reply_timeout) {
                Ok(Ok(_)) => {
                    report.push(
                        "1 handshake",
                        Outcome::Pass,
                        format!("{what}; {} was written", short),
                    );
                    true
                }
                Ok(Err(why)) => {
                    report.push(
                        "1 handshake",
                        Outcome::Fail,
                        format!("{what}; writing {} failed: {why}", short),
                    );
                    false
                }
                Err(e) => {
                    report.push("1 handshake", Outcome::Fail, format!("{what}; {e}"));
                    false
                }
            }
        }
    }
}

fn live_line(r: &SensorReport) -> String {
    let mut b = vec![];
    if r.buttons.contains(Buttons::PRIMARY) {
        b.push("1");
    }
    if r.buttons.contains(Buttons::SECONDARY) {
        b.push("2");
    }
    format!(
        "encoders {:>8} {:>8} {:>8} | gimbal {:>5} {:>5} {:>5} | buttons {}",
        r.encoders[0],
        r.encoders[1],
        r.encoders[2],
        r.gimbal[0],
        r.gimbal[1],
        r.gimbal[2],
        if b.is_empty() {
            "-".to_string()
        } else {
            b.join("+")
        }
    )
}

/// Step 2; true when the sensor stream is running.
fn step_sensors(
    wire: &mut Wire,
    opts: &CheckOptions,
    op: &mut dyn Operator,
    report: &mut CheckReport,
    virtual_pen: bool,
) -> bool {
    match wire.command(
        Command::StreamSensors { rate_hz: SENSOR_HZ },
        opts.reply_timeout,
    ) {
        Ok(Ok(())) => {}
        Ok(Err(e)) => {
            report.push(
                "2 sensors",
                Outcome::Fail,
                format!("the device refused to stream its sensors: {e:?}"),
            );
            return false;
        }
        Err(e) => {
            report.push("2 sensors", Outcome::Fail, e);
            return false;
        }
    }
    if virtual_pen {
        // Start where the device's pen is (its first state says), so the first sample is no
        // jump; its states also pace the poses (they say which one it consumed last).
        let _ = wire.wait(Duration::from_secs(2), |m| {
            matches!(m, DeviceMsg::State(_)).then_some(())
        });
        let Some(start) = wire.handle else {
            report.push(
                "2 sensors",
                Outcome::Fail,
                "a virtual pen that sends no brush states cannot be moved (nothing paces the poses)",
            );
            return true;
        };
        let motion = virtual_motion(start);
        wire.start_virtual_pen(start);
        wire.move_virtual_pen(&motion);
        op.say(&format!(
            "Moving the virtual pen through {} poses (each axis 15 mm, each turn 15 degrees) \
             while reading its sensors.",
            motion.len()
        ));
    } else {
        op.say(&format!(
            "Move each joint by hand, one at a time: the base, the shoulder, the elbow, then the \
             three gimbal axes; press the stylus buttons. ({} s, or Enter when done.)",
            opts.sensor_time.as_secs()
        ));
    }
    let mut enc = [Excursion::default(); 3];
    let mut gim = [Excursion::default(); 3];
    let mut buttons = Buttons::empty();
    let mut reports = 0usize;
    let mut synthetic = false;
    let start = Instant::now();
    let mut arrived: Option<Instant> = None;
    loop {
        if let Err(e) = wire.idle(Duration::from_millis(5)) {
            report.push("2 sensors", Outcome::Fail, e);
            return false;
        }
        let fresh = wire.take_sensor_reports();
        for r in &fresh {
            reports += 1;
            synthetic |= r.synthetic;
            for i in 0..3 {
                enc[i].add(r.encoders[i]);
                gim[i].add(i64::from(r.gimbal[i]));
            }
            buttons |= r.buttons;
        }
        if let Some(r) = fresh.last() {
            op.live(&live_line(r));
        }
        let done = if virtual_pen {
            // The whole motion consumed, and a moment for the last readings.
            match arrived {
                None if wire.virtual_pen_arrived() => {
                    arrived = Some(Instant::now());
                    false
                }
                Some(t) => t.elapsed() > Duration::from_millis(300),
                None => false,
            }
        } else {
            start.elapsed() >= opts.sensor_time || op.enter_pressed()
        };
        if done || start.elapsed() > opts.sensor_time.max(Duration::from_secs(60)) {
            break;
        }
    }
    if reports == 0 {
        report.push(
            "2 sensors",
            Outcome::Fail,
            "the device accepted the command but sent no sensor reports",
        );
        return true;
    }
    op.say(&format!(
        "sensor channels ({reports} reports{}):",
        if synthetic { ", synthetic" } else { "" }
    ));
    let mut all = true;
    let mut parts = vec![];
    let mut line = |name: &str, e: &Excursion, min: i64, unit: &str| {
        let moved = e.largest.abs() >= min;
        all &= moved;
        let v = if moved { "PASS" } else { "FAIL" };
        let s = format!("{name}: {v} {}{} {unit}", sign(e.largest), e.largest.abs());
        op.say(&format!("  {s}"));
        parts.push(s);
    };
    for i in 0..3 {
        line(ARM_JOINTS[i], &enc[i], opts.min_counts, "counts");
    }
    for i in 0..3 {
        line(GIMBAL_AXES[i], &gim[i], i64::from(opts.min_codes), "codes");
    }
    op.say(&format!(
        "  buttons seen pressed: {}",
        if buttons.is_empty() {
            "none".to_string()
        } else {
            buttons.to_string()
        }
    ));
    report.push(
        "2 sensors",
        if all { Outcome::Pass } else { Outcome::Fail },
        format!(
            "{}{}",
            parts.join("; "),
            if all {
                ""
            } else {
                " (a channel that did not change: check its wiring, or move that joint further)"
            }
        ),
    );
    true
}

/// The joint's move from a nudge, in joint direction (encoder counts times the encoder
/// sign), or why it could not be measured.
fn nudge_once(
    wire: &mut Wire,
    opts: &CheckOptions,
    channel: usize,
    encoder_sign: i8,
) -> Result<i64, String> {
    let before = wire.fresh_sensors(opts.reply_timeout)?;
    let nudge = Nudge {
        channel: channel as u8,
        command_permille: opts.nudge_permille,
        duration_ms: opts.nudge_ms,
    };
    match wire.command(Command::NudgeMotor(nudge), opts.reply_timeout)? {
        Ok(()) => {}
        Err(e) => return Err(format!("the device refused the nudge: {e:?}")),
    }
    // The motor runs for the nudge's duration; then a moment for the arm to settle.
    wire.idle(Duration::from_millis(u64::from(opts.nudge_ms) + 200))?;
    let after = wire.fresh_sensors(opts.reply_timeout)?;
    let counts = after.encoders[channel] - before.encoders[channel];
    Ok(counts * i64::from(encoder_sign.signum()))
}

fn step_nudges(
    wire: &mut Wire,
    opts: &CheckOptions,
    op: &mut dyn Operator,
    report: &mut CheckReport,
    virtual_pen: bool,
    streaming: bool,
) {
    if let Some(why) = no_nudges(&wire.info) {
        op.say(&format!("3 motors: skipped: {why}"));
        for (ch, joint) in ARM_JOINTS.iter().enumerate() {
            report.push(
                format!("3 motor {ch} ({joint})"),
                Outcome::Skip,
                why.clone(),
            );
        }
        return;
    }
    // Nudges are refused while forces are on (and the arm should be still anyway).
    if streaming {
        let _ = wire.command(Command::DisableForces, opts.reply_timeout);
        // A fault latched meanwhile (a virtual pen's link gap) would refuse the nudges.
        let _ = wire.command(Command::ClearFaults, opts.reply_timeout);
    }
    for (ch, joint) in ARM_JOINTS.iter().enumerate() {
        let step = format!("3 motor {ch} ({joint})");
        if !streaming {
            report.push(step, Outcome::Fail, "no sensor stream to read the encoder");
            continue;
        }
        if !op.confirm(&format!(
            "Nudge motor {ch} ({joint}): {}% of full current for {} ms? Keep hands clear.",
            f64::from(opts.nudge_permille) / 10.0,
            opts.nudge_ms
        )) {
            report.push(step, Outcome::Skip, "declined");
            continue;
        }
        let cfg = match wire.get_config(opts.reply_timeout) {
            Ok(Ok(c)) => Some(c),
            _ => None,
        };
        let encoder_sign = cfg.as_ref().map(|c| c.pen.encoder_sign[ch]).unwrap_or(1);
        let moved = match nudge_once(wire, opts, ch, encoder_sign) {
            Ok(m) => m,
            Err(e) => {
                report.push(step, Outcome::Fail, e);
                continue;
            }
        };
        if moved.abs() < opts.min_counts {
            if virtual_pen {
                report.push(
                    step,
                    Outcome::Skip,
                    format!(
                        "the board accepted the nudge; a virtual pen's joint cannot move \
                         ({moved} counts)"
                    ),
                );
            } else {
                report.push(
                    step,
                    Outcome::Fail,
                    format!(
                        "the joint did not move ({moved} counts): check the driver's enable, \
                         the motor wiring and power, or raise --nudge-permille"
                    ),
                );
            }
            continue;
        }
        if moved > 0 {
            report.push(
                step,
                Outcome::Pass,
                format!("moved {moved:+} counts, the right way"),
            );
            continue;
        }
        op.say(&format!(
            "Motor {ch} turned its joint the wrong way ({moved:+} counts for a positive command)."
        ));
        let Some(mut c) = cfg else {
            report.push(
                step,
                Outcome::Fail,
                format!("reversed ({moved:+} counts) and the configuration cannot be read"),
            );
            continue;
        };
        if !op.confirm(&format!(
            "Flip motor_sign[{ch}] in the pen's configuration (or swap the motor's two wires \
             and run the check again)?"
        )) {
            report.push(
                step,
                Outcome::Fail,
                format!("reversed ({moved:+} counts); not flipped"),
            );
            continue;
        }
        c.pen.motor_sign[ch] = -c.pen.motor_sign[ch];
        match wire.set_config(c, opts.reply_timeout) {
            Ok(Ok(_)) => {}
            Ok(Err(why)) => {
                report.push(
                    step,
                    Outcome::Fail,
                    format!("reversed; flipping failed: {why}"),
                );
                continue;
            }
            Err(e) => {
                report.push(step, Outcome::Fail, format!("reversed; {e}"));
                continue;
            }
        }
        match nudge_once(wire, opts, ch, encoder_sign) {
            Ok(again) if again >= opts.min_counts => report.push(
                step,
                Outcome::Pass,
                format!(
                    "was reversed ({moved:+} counts); motor_sign flipped and stored; nudged \
                     again: {again:+} counts"
                ),
            ),
            Ok(again) => report.push(
                step,
                Outcome::Fail,
                format!(
                    "was reversed ({moved:+} counts); motor_sign flipped, but nudged again it \
                     moved {again:+} counts"
                ),
            ),
            Err(e) => report.push(step, Outcome::Fail, format!("after flipping: {e}")),
        }
    }
}

fn step_calibrate(
    wire: &mut Wire,
    opts: &CheckOptions,
    op: &mut dyn Operator,
    report: &mut CheckReport,
) {
    let step = "4 calibration";
    if let Some(why) = no_calibration(&wire.info) {
        skip(op, report, step, why);
        return;
    }
    op.wait_enter("Put the pen in its inkwell (the calibration pose), hold it still, press Enter.");
    match wire.command(
        Command::Calibrate,
        opts.reply_timeout.max(Duration::from_secs(5)),
    ) {
        Ok(Ok(())) => {}
        Ok(Err(e)) => {
            report.push(step, Outcome::Fail, format!("the device refused: {e:?}"));
            return;
        }
        Err(e) => {
            report.push(step, Outcome::Fail, e);
            return;
        }
    }
    let calibrated_at = Instant::now();
    match wire.get_config(opts.reply_timeout) {
        Ok(Ok(c)) => match (c.validate(), c.calibration) {
            (Ok(()), Some(r)) => {
                // The pen itself must now count as calibrated: the next report after the
                // read-back no longer carries NOT_CALIBRATED.
                // A frame copied just before the calibration may still be on its way:
                // waits for a clear one.
                match wire.faults_since(calibrated_at, opts.reply_timeout, |f| {
                    !f.contains(Faults::NOT_CALIBRATED)
                }) {
                    Ok(Some(f)) if f.contains(Faults::NOT_CALIBRATED) => report.push(
                        step,
                        Outcome::Fail,
                        "stored and read back, but the pen still reports NOT_CALIBRATED",
                    ),
                    Err(e) => report.push(step, Outcome::Fail, e),
                    Ok(_) => report.push(
                        step,
                        Outcome::Pass,
                        format!(
                            "stored and read back valid; inkwell encoders {:?}, gimbal {:?}",
                            r.encoders, r.gimbal
                        ),
                    ),
                }
            }
            (Ok(()), None) => report.push(
                step,
                Outcome::Fail,
                "the configuration read back has no calibration",
            ),
            (Err(e), _) => report.push(
                step,
                Outcome::Fail,
                format!("the configuration read back is invalid: {e}"),
            ),
        },
        Ok(Err(why)) => report.push(
            step,
            Outcome::Fail,
            format!("reading the configuration back: {why}"),
        ),
        Err(e) => report.push(step, Outcome::Fail, e),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A serial port that opens and answers nothing (a pseudo-terminal nobody serves, as a
    /// pen that sends only with DTR asserted looks when DTR is lost): the check names DTR;
    /// a TCP peer that answers nothing is not given that cause.
    #[cfg(unix)]
    #[test]
    fn a_silent_serial_port_is_named_for_dtr() {
        use serialport::SerialPort;
        let (_pen, port) = match serialport::TTYPort::pair() {
            Ok(p) => p,
            Err(e) => {
                maobi_testenv::skip(&format!("no pseudo-terminals here ({e})"));
                return;
            }
        };
        let path = port.name().expect("a pty has a name");
        drop(port);
        let endpoint = Endpoint::Serial(path);
        let e = match Wire::connect(&endpoint, Duration::from_millis(300)) {
            Ok(_) => panic!("nothing answers on {endpoint}"),
            Err(e) => e,
        };
        assert!(e.contains("not one byte came back"), "{e}");
        assert!(e.contains("DTR"), "{e}");

        let quiet = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let endpoint = Endpoint::Tcp(quiet.local_addr().unwrap().to_string());
        let e = match Wire::connect(&endpoint, Duration::from_millis(300)) {
            Ok(_) => panic!("nothing answers on {endpoint}"),
            Err(e) => e,
        };
        assert!(e.contains("not one byte came back"), "{e}");
        assert!(!e.contains("DTR"), "{e}");
    }

    #[test]
    fn only_a_silent_serial_handshake_is_blamed_on_dtr() {
        let silent = HandshakeError {
            message: "no answer".into(),
            closed: false,
            silent: true,
        };
        let noisy = HandshakeError {
            silent: false,
            ..silent.clone()
        };
        let serial = Endpoint::Serial("/dev/ttyACM0".into());
        let tcp = Endpoint::Tcp("127.0.0.1:1".into());
        assert!(no_answer_cause(&serial, silent.clone()).contains("DTR"));
        assert_eq!(no_answer_cause(&serial, noisy), "no answer");
        assert_eq!(no_answer_cause(&tcp, silent), "no answer");
    }

    #[test]
    fn the_virtual_motion_moves_every_axis_in_small_steps_and_comes_back() {
        let start = Pose::new(Vec3::new(10.0, -20.0, 30.0), Quat::IDENTITY);
        let m = virtual_motion(start);
        let mut reach = [0.0f64; 6];
        for w in m.windows(2) {
            // Far below the firmware's 10 mm sensor-jump limit.
            assert!((w[1].pos - w[0].pos).norm() <= 0.25 + 1e-9);
        }
        for p in &m {
            let d = p.pos - start.pos;
            for (i, v) in [d.x, d.y, d.z].into_iter().enumerate() {
                reach[i] = reach[i].max(v);
            }
            // The rotation's vector part is sin(angle / 2) times the axis.
            for (i, v) in [p.rot.x, p.rot.y, p.rot.z].into_iter().enumerate() {
                reach[3 + i] = reach[3 + i].max(v);
            }
        }
        for r in &reach[..3] {
            assert!((r - 15.0).abs() < 1e-9, "{reach:?}");
        }
        for r in &reach[3..] {
            assert!((r - (7.5f64).to_radians().sin()).abs() < 1e-9, "{reach:?}");
        }
        let last = m.last().unwrap();
        assert!((last.pos - start.pos).norm() < 1e-9);
        assert!((last.rot.w - 1.0).abs() < 1e-9);
    }

    #[test]
    fn an_excursion_keeps_the_sign_of_the_largest_move() {
        let mut e = Excursion::default();
        for v in [100, 110, 95, 40, 90] {
            e.add(v);
        }
        assert_eq!(e.largest, -60);
        assert_eq!(sign(e.largest), "-");
    }

    #[test]
    fn the_summary_fails_on_any_fail_and_not_on_skips() {
        let mut r = CheckReport::default();
        assert!(!r.passed(), "an empty check is no pass");
        r.push("1 handshake", Outcome::Pass, "ok");
        r.push("3 motor 0", Outcome::Skip, "declined");
        assert!(r.passed());
        r.push("4 calibration", Outcome::Fail, "refused");
        assert!(!r.passed());
        let t = r.table();
        assert!(
            t.lines().nth(3).unwrap().starts_with("4 calibration  FAIL"),
            "{t}"
        );
    }
}
