//! The pen's end of the link to the host: the link task, the wire protocol
//! (`maobi_shared::protocol`) over the board's byte link (QEMU's UART, the Black Pill's USB
//! CDC-ACM), the same on every board: a board calls [`run`] from its own task with its
//! [`LinkTransport`], its [`ConfigStore`] and its [`BoardInfo`]. The other ends are the
//! host's protocol client (`host/src/device/client.rs`) and hil's session
//! (`hil/src/session.rs`).
//!
//! * On start it writes one `0x00` so the host's decoder drops any partial frame.
//! * `Hello` is answered with the device's [`DeviceInfo`] and arms the link supervision
//!   (the force loop latches `LINK_SILENT` after [`app::LINK_TIMEOUT_TICKS`] ticks without
//!   a valid frame and turns the motors off). The first pose sample after a hello places the
//!   brush at rest there: a stream starts at rest at its first pose, as the host simulation
//!   does.
//! * `Pose` samples go into the virtual pen's queue (the force loop takes one per tick and
//!   never waits for the link). When the queue is full the task stops reading until it has
//!   room, so the host's window, not a dropped sample, absorbs the difference. A pen with
//!   its own sensors has no queue: poses (and guide samples) from the host are ignored.
//! * `State` frames: the force loop fills the snapshot slot with the frame's
//!   [`maobi_shared::protocol::BrushState`] when one is due ([`app::STATE_HZ`] per 1000 ticks,
//!   120 by default); this task encodes it where it lies, in thread mode. A state that
//!   finds the transmit ring full is dropped and counted (`Telemetry::frames_dropped`).
//! * Commands and parameters are validated here and handed to the force loop as
//!   [`app::Command`]s; every one is answered.
//! * The stored configuration ([`ConfigStore`]): loaded and decoded when the task starts;
//!   the handshake reports its [`ConfigState`]. Until it allows forces
//!   ([`pen_io::Readiness`]: valid with zeros that hold, or none needed: QEMU without an
//!   image) [`app::CONFIG_OK`] stays off, so the force loop never drives the motors,
//!   `EnableForces` / `NudgeMotor` are refused with `ConfigNotValid`, and state frames and
//!   events carry `Faults::NOT_CALIBRATED`. Zeros hold when stored, except on a board
//!   announcing `NEEDS_CALIBRATION` (incremental encoders, the Black Pill): there only a
//!   `Calibrate` since power-on counts. `SetConfig` is refused while forces are enabled,
//!   validated whole before anything is written, written, read back and decoded, and only then put in
//!   force (`app::Command::Configure`). `Calibrate` records one raw reading (the pen resting
//!   in its inkwell) into the configuration and stores it the same way.
//! * An image of an older format is migrated (`pen_io::load`, in the shared crate): its
//!   geometry, drive channels, limits and calibration go in force (the brush follows the
//!   pen), the handshake says `ConfigState::Migrated`, and [`app::CONFIG_OK`] stays off, so
//!   no force and no nudge, until a `SetConfig` gives what bounds the motor current (each
//!   winding's resistance, the supply, the driver's rating) and writes a current image.
//!   `Calibrate` then puts its zeros in force without storing them (the image cannot be
//!   written without those values); the completing `SetConfig` stores them.
//! * Bring-up: `StreamSensors` asks the force loop for raw readings
//!   ([`app::SENSORS`]) every `1000 / rate_hz` ticks and sends them as `Sensors` (dropped and
//!   counted when the link is busy); `NudgeMotor` hands the force loop a capped torque for a
//!   number of ticks ([`app::Command::Nudge`]), shown in the state frames' applied motor
//!   commands, motors off afterwards.
//! * Events: faults raised and cleared, forces enabled and disabled, link connected and
//!   reconnected (with the silence and the faults latched meanwhile, re-sent because the
//!   originals went nowhere). Telemetry every `telemetry_ticks` ticks.

use core::future::{poll_fn, Future};
use core::pin::pin;
use core::sync::atomic::Ordering;
use core::task::Poll;

use embassy_time::{Duration, Timer};
use maobi_shared::guide::GuideInput;
use maobi_shared::kinematics::RawReadings;
use maobi_shared::params::{ParamError, TickLimits};
use maobi_shared::pen_io::{self, DeviceConfig, Readiness, ZeroHold, CONFIG_IMAGE_MAX};
use maobi_shared::protocol::{
    param_id, Capabilities, Command as Wire, CommandError, ConfigRejected, ConfigState, DeviceInfo,
    DeviceMsg, DeviceRx, Event, EventKind, Faults, GuideSample, HostMsg, Message, Nudge,
    ParamRejected, ParamReply, SensorReport, Telemetry, Version, SENSOR_RATE_MAX_HZ,
};
use maobi_shared::{BrushParams, Fx};

use crate::app::{self, Command, CONFIG_OK, FAULTS, FORCES_ENABLED, SENSORS, SNAPSHOT, TICKS};
use crate::board::{ConfigStore, LinkTransport};

/// What the link says about the board in the handshake.
pub struct BoardInfo {
    /// The board's name.
    pub name: &'static str,
    pub capabilities: Capabilities,
    /// Force limits (N) without a stored configuration; with one, the handshake reports
    /// the configuration's (`DeviceConfig::limits`, what the force loop applies).
    pub force_peak_n: f32,
    pub force_continuous_n: f32,
    /// What this board's core runs within its 1 kHz tick, announced in the handshake. A
    /// preset's substep rate is lowered to it ([`TickLimits::brush`]); a parameter or a
    /// preset beyond any cap is refused with the reason, so no command the link accepts can
    /// make the tick overrun.
    pub limits: TickLimits,
}

impl BoardInfo {
    /// `preset` as this board runs it.
    pub const fn brush(&self, preset: BrushParams) -> BrushParams {
        self.limits.brush(preset)
    }
}

/// What the link task drives.
pub struct LinkParts<T, S> {
    pub transport: T,
    /// The virtual pen's pose queue (`None` on a board with its own sensors: pose samples
    /// from the host are then ignored).
    pub poses: Option<app::PoseProducer>,
    pub cmds: app::CmdProducer,
    /// Where the configuration is kept (loaded when the task starts).
    pub store: S,
}

/// Link settings from the boot command line.
#[derive(Copy, Clone, Debug)]
pub struct LinkConfig {
    /// Force-loop period (us): the task's idle poll interval is half of it.
    pub tick_us: u32,
    /// Telemetry every this many force-loop ticks.
    pub telemetry_ticks: u32,
}

/// Transmit buffer: one frame of the largest device message.
struct TxBuf(core::cell::UnsafeCell<[u8; DeviceMsg::MAX_FRAME]>);
// SAFETY: used only by the link task (one instance, thread mode).
unsafe impl Sync for TxBuf {}
static TX_BUF: TxBuf = TxBuf(core::cell::UnsafeCell::new([0; DeviceMsg::MAX_FRAME]));

struct Link<T, S> {
    parts: LinkParts<T, S>,
    board: &'static BoardInfo,
    cfg: LinkConfig,
    rx: DeviceRx,
    /// Bytes read from the transport but not yet fed to the decoder (a pose is waiting for room).
    inbuf: [u8; 64],
    in_start: usize,
    in_end: usize,
    pending_pose: Option<app::PoseIn>,
    /// The last guide sample, waiting for the pose of its `seq`.
    guide: Option<GuideSample>,
    /// The parameters in force (mirror of the force loop's brush), for validation.
    params: BrushParams,
    frames_dropped: u32,
    pose_gaps: u32,
    reported_faults: u32,
    reported_enabled: bool,
    connected_once: bool,
    /// LINK_SILENT latched and the host not heard since.
    silence_reported: bool,
    next_telemetry: u32,
    /// Commands queued for the force loop so far.
    cmds_sent: u32,
    /// What the store held at start, or the last write.
    config_state: ConfigState,
    /// The configuration in force (`Valid` only).
    config: Option<DeviceConfig>,
    /// The zeros `Calibrate` took since power-on (what counts on a board whose encoders
    /// restart at every power-on).
    zeros_since_power_on: Option<RawReadings>,
    /// Sensor reports every this many ticks (0: not streaming), next at `next_sensors`.
    sensors_every: u32,
    next_sensors: u32,
}

/// The link task's body (each board wraps it in its own `#[embassy_executor::task]`, since
/// a task cannot be generic over the transport).
pub async fn run<T: LinkTransport, S: ConfigStore>(
    parts: LinkParts<T, S>,
    board: &'static BoardInfo,
    params: BrushParams,
    cfg: LinkConfig,
) -> ! {
    let mut link = Link {
        parts,
        board,
        cfg,
        rx: DeviceRx::new(),
        inbuf: [0; 64],
        in_start: 0,
        in_end: 0,
        pending_pose: None,
        guide: None,
        params,
        frames_dropped: 0,
        pose_gaps: 0,
        reported_faults: 0,
        reported_enabled: false,
        connected_once: false,
        silence_reported: false,
        next_telemetry: cfg.telemetry_ticks,
        cmds_sent: 0,
        config_state: ConfigState::NotApplicable,
        config: None,
        zeros_since_power_on: None,
        sensors_every: 0,
        next_sensors: 0,
    };
    link.load_config().await;
    link.parts
        .transport
        .write(&[maobi_shared::protocol::DELIMITER]);
    loop {
        link.receive().await;
        link.send_state();
        // Every other task's turn after each state frame and once a pass. `wait` does not
        // wait when work is already there (a state due, bytes received), and when thread
        // mode runs slower than the states fall due (a busy pen's thread mode gets what the
        // force tick and the link's interrupts leave) that is every pass: without these the
        // link task would never hand the executor back, the supervisor would never check in,
        // and the watchdog would reset a pen whose link is merely busy. So the supervisor
        // waits for one piece of the link's work at most (a message, a state frame), never
        // for as long as work keeps coming.
        embassy_futures::yield_now().await;
        link.sensors();
        link.events().await;
        link.telemetry().await;
        link.wait().await;
        embassy_futures::yield_now().await;
    }
}

impl<T: LinkTransport, S: ConfigStore> Link<T, S> {
    /// Waits for received bytes, a filled snapshot or half a tick, whichever comes first.
    async fn wait(&mut self) {
        let period = Duration::from_micros(u64::from(self.cfg.tick_us / 2).max(100));
        let mut timer = pin!(Timer::after(period));
        let blocked = self.pending_pose.is_some() || self.in_start < self.in_end;
        let mut readable = pin!(self.parts.transport.readable());
        poll_fn(|cx| {
            app::SNAPSHOT_WAKER.register(cx.waker());
            if SNAPSHOT.is_full() || SENSORS.is_full() {
                return Poll::Ready(());
            }
            if !blocked && readable.as_mut().poll(cx).is_ready() {
                return Poll::Ready(());
            }
            timer.as_mut().poll(cx)
        })
        .await
    }

    /// Reads and handles what the host sent, until the transport is empty or the pose queue full.
    async fn receive(&mut self) {
        loop {
            if let (Some(p), Some(poses)) = (self.pending_pose, self.parts.poses.as_mut()) {
                if poses.enqueue(p).is_err() {
                    return;
                }
                self.pending_pose = None;
            }
            if self.in_start == self.in_end {
                self.in_start = 0;
                self.in_end = self.parts.transport.read(&mut self.inbuf);
                if self.in_end == 0 {
                    return;
                }
            }
            // Feed until a frame completes (handled below) or the chunk is used up.
            let mut msg = None;
            {
                let chunk = &self.inbuf[self.in_start..self.in_end];
                let mut feed = self.rx.feed(chunk);
                let outcome = feed.next();
                let used = chunk.len() - feed.remaining().len();
                self.in_start += used;
                if let Some(Ok(m)) = outcome {
                    msg = Some(m);
                }
            }
            if let Some(m) = msg {
                self.heard().await;
                self.handle(m).await;
                // Every other task's turn between two messages: a host that never stops
                // sending (a flood of pings) must not keep the supervisor from checking
                // in, or the watchdog resets the pen.
                embassy_futures::yield_now().await;
            }
        }
    }

    /// A valid frame: the link is alive; report a reconnection after a silence.
    async fn heard(&mut self) {
        let now = TICKS.load(Ordering::Relaxed);
        let faults = app::reported_faults();
        if faults & LINK_SILENT != 0 && !self.silence_reported {
            self.silence_reported = true;
            let last = app::LAST_RX_TICK.load(Ordering::Relaxed);
            let silent_ms = now.wrapping_sub(last);
            self.event(now, EventKind::LinkReconnected { silent_ms })
                .await;
            // The events sent during the silence went nowhere: report the faults again,
            // at the tick LINK_SILENT was raised.
            let t = app::FAULT_TICKS[2].load(Ordering::Relaxed);
            self.event(t, EventKind::FaultRaised(faults_of(faults)))
                .await;
            self.reported_faults = faults;
        }
        app::link_heard();
    }

    async fn handle(&mut self, m: HostMsg) {
        match m {
            HostMsg::Hello(_) => {
                let (peak, continuous) = match &self.config {
                    Some(c) => (c.limits.peak_n, c.limits.continuous_n),
                    None => (self.board.force_peak_n, self.board.force_continuous_n),
                };
                let info = DeviceInfo::new(
                    self.board.name,
                    firmware_version(),
                    self.board.capabilities,
                    peak,
                    continuous,
                )
                .with_config(self.config_state.clone())
                .with_limits(self.board.limits);
                let n = self.stage(&DeviceMsg::Hello(info));
                self.send_staged(n).await;
                self.command(Command::Reanchor).await;
                app::LINK_ARMED.store(true, Ordering::SeqCst);
                if !self.connected_once {
                    self.connected_once = true;
                    let now = TICKS.load(Ordering::Relaxed);
                    self.event(now, EventKind::LinkConnected).await;
                }
            }
            HostMsg::Ping { seq } => {
                let n = self.stage(&DeviceMsg::Pong { seq });
                self.send_staged(n).await;
            }
            HostMsg::Pose(s) => {
                // The guide sample sent for this tick rides with its pose, so the force loop
                // applies it at the tick that consumes the pose (as the host's mirror does).
                let guide = match self.guide {
                    Some(g) if g.seq == s.seq => {
                        self.guide = None;
                        Some(GuideInput {
                            anchor: g.anchor(),
                            on: g.on,
                        })
                    }
                    _ => None,
                };
                let p = app::PoseIn {
                    seq: s.seq,
                    pose: s.pose(),
                    guide,
                };
                // A pen with its own sensors has no use for the host's poses: ignored.
                if let Some(poses) = self.parts.poses.as_mut() {
                    if poses.enqueue(p).is_err() {
                        self.pending_pose = Some(p);
                    }
                }
            }
            HostMsg::Guide(g) => self.guide = Some(g),
            HostMsg::GetParam { id } => {
                let r = ParamReply::read(&self.params, id);
                let n = self.stage(&DeviceMsg::Param(r));
                self.send_staged(n).await;
            }
            HostMsg::SetParam { id, value } => {
                let reply = match param_id(id) {
                    None => ParamReply {
                        id,
                        result: Err(ParamRejected::unknown(id)),
                    },
                    Some(p) => {
                        let mut candidate = self.params;
                        let outcome = candidate
                            .set(p, value)
                            .and_then(|()| candidate.validate())
                            .and_then(|()| self.board.limits.check(&candidate));
                        if outcome.is_ok() {
                            self.params = candidate;
                            self.command(Command::SetParam(p, value)).await;
                        }
                        ParamReply::written(id, outcome, &self.params)
                    }
                };
                let n = self.stage(&DeviceMsg::Param(reply));
                self.send_staged(n).await;
            }
            HostMsg::Command(c) => {
                let result = self.wire_command(&c).await;
                let n = self.stage(&DeviceMsg::CommandDone { command: c, result });
                self.send_staged(n).await;
            }
            HostMsg::GetConfig => {
                let reply = self
                    .config
                    .ok_or_else(|| ConfigRejected::NotStored(self.config_state.clone()));
                let n = self.stage(&DeviceMsg::Config(reply));
                self.send_staged(n).await;
            }
            HostMsg::SetConfig(cfg) => {
                let reply = self.set_config(cfg).await;
                let n = self.stage(&DeviceMsg::Config(reply));
                self.send_staged(n).await;
            }
        }
    }

    async fn wire_command(&mut self, c: &Wire) -> Result<(), CommandError> {
        // Decide on the state after every earlier command (a ClearFaults just before an
        // EnableForces, say).
        self.settle().await;
        let faults = FAULTS.load(Ordering::SeqCst);
        let cmd = match c {
            Wire::EnableForces if faults != 0 => {
                return Err(CommandError::FaultsLatched(faults_of(faults)))
            }
            Wire::EnableForces if !self.config_allows_forces() => {
                return Err(CommandError::ConfigNotValid)
            }
            Wire::EnableForces => Command::EnableForces,
            Wire::DisableForces => Command::DisableForces,
            Wire::Calibrate => return self.calibrate().await,
            Wire::DipInk { wetness } => Command::Dip(Fx::from_bits(*wetness)),
            Wire::ChoosePreset(p) => {
                let params = self
                    .board
                    .brush(p.resolve().ok_or(CommandError::UnknownPreset)?);
                if let Err(ParamError::OverTickLimit { param, value, max }) =
                    self.board.limits.check(&params)
                {
                    return Err(CommandError::OverTickLimit {
                        param: param as u8,
                        value: value as u32,
                        max: max as u32,
                    });
                }
                self.params = params;
                Command::SetParams(params)
            }
            Wire::ClearFaults => Command::ClearFaults,
            Wire::ResetBrush => Command::ResetBrush,
            #[cfg(feature = "test-hooks")]
            Wire::InjectOverrun => Command::InjectOverrun,
            // A test hook: only test builds of the firmware offer it.
            #[cfg(not(feature = "test-hooks"))]
            Wire::InjectOverrun => return Err(CommandError::Unsupported),
            Wire::StreamSensors { rate_hz } => {
                if *rate_hz > SENSOR_RATE_MAX_HZ {
                    return Err(CommandError::OutOfRange);
                }
                self.sensors_every = match *rate_hz {
                    0 => 0,
                    hz => (1000 / u32::from(hz)).max(1),
                };
                self.next_sensors = TICKS.load(Ordering::Relaxed);
                return Ok(());
            }
            Wire::NudgeMotor(n) => self.nudge(n, faults)?,
        };
        self.command(cmd).await;
        Ok(())
    }

    /// Reads the store and puts what it holds in force (at start). An image of an older
    /// format is migrated (`pen_io::load`): its kinematics and calibration are in force, its
    /// state (`ConfigState::Migrated`) keeps the motors off until a `SetConfig`.
    async fn load_config(&mut self) {
        if !self.parts.store.needs_config() {
            self.config_state = ConfigState::NotApplicable;
            self.config = None;
        } else {
            let loaded = self.read_store();
            self.config_state = ConfigState::of_loaded(&loaded);
            self.config = loaded.ok().map(|l| *l.config());
            match &self.config_state {
                ConfigState::Valid => defmt::info!("configuration valid"),
                ConfigState::Migrated { from } => defmt::warn!(
                    "configuration migrated from format {=u16}: forces refused until SetConfig gives the winding resistances, supply and driver rating",
                    from
                ),
                _ => defmt::warn!("no valid configuration: forces refused"),
            }
        }
        if let Some(c) = self.config {
            critical_section::with(|cs| app::CONFIG.borrow(cs).set(c));
            self.command(Command::Configure).await;
        }
        self.publish_readiness();
    }

    /// The store's image, read (an older format migrated). Not async: the buffer lives on
    /// the stack for the call, not in the task's future for its lifetime.
    fn read_store(&mut self) -> Result<pen_io::Loaded, pen_io::ConfigError> {
        let mut buf = [0u8; CONFIG_IMAGE_MAX];
        let n = self.parts.store.load(&mut buf);
        pen_io::load(buf.get(..n).unwrap_or(&[]))
    }

    /// Encodes `cfg` and writes it to the store (as `read_store`, not async).
    fn write_store(
        &mut self,
        cfg: &DeviceConfig,
    ) -> Result<Result<(), crate::board::StoreError>, ConfigRejected> {
        let mut buf = [0u8; CONFIG_IMAGE_MAX];
        let n = pen_io::encode(cfg, &mut buf).map_err(|e| match e {
            pen_io::ConfigError::Invalid(field) => ConfigRejected::Invalid(field),
            _ => ConfigRejected::StoreFailed,
        })?;
        Ok(self.parts.store.store(buf.get(..n).unwrap_or(&[])))
    }

    /// Whether forces may be rendered and whether the pen is calibrated, from the
    /// configuration in force and how long this board's zeros hold.
    fn readiness(&self) -> Readiness {
        let zeros = if self
            .board
            .capabilities
            .contains(Capabilities::NEEDS_CALIBRATION)
        {
            ZeroHold::SincePowerOn(self.zeros_since_power_on)
        } else {
            // Absolute readings: the QEMU board's are synthesised from the host's poses.
            ZeroHold::Stored
        };
        Readiness::of(&self.config_state, self.config.as_ref(), zeros)
    }

    fn config_allows_forces(&self) -> bool {
        self.readiness().allows_forces
    }

    /// Tells the force loop (motor gate), the fault report and the LED.
    fn publish_readiness(&self) {
        let r = self.readiness();
        CONFIG_OK.store(r.allows_forces, Ordering::SeqCst);
        app::NOT_CALIBRATED.store(r.not_calibrated, Ordering::SeqCst);
        // A migrated configuration is in force for the kinematics, but not valid.
        let valid = self.config.is_some() && self.config_state == ConfigState::Valid;
        app::CONFIG_VALID.store(valid, Ordering::SeqCst);
    }

    /// `SetConfig`: refuse while forces are on, validate all of it, then write.
    async fn set_config(&mut self, cfg: DeviceConfig) -> Result<DeviceConfig, ConfigRejected> {
        self.settle().await;
        if FORCES_ENABLED.load(Ordering::SeqCst) {
            return Err(ConfigRejected::ForcesEnabled);
        }
        cfg.validate().map_err(ConfigRejected::Invalid)?;
        self.write_config(cfg).await?;
        Ok(cfg)
    }

    /// Encodes, stores, reads back and decodes `cfg`, then puts it in force. On a failure
    /// the state says what the store now holds.
    async fn write_config(&mut self, cfg: DeviceConfig) -> Result<(), ConfigRejected> {
        let stored = self.write_store(&cfg)?;
        let loaded = self.read_store();
        let ok = stored.is_ok() && loaded == Ok(pen_io::Loaded::Current(cfg));
        self.config_state = ConfigState::of_loaded(&loaded);
        self.config = loaded.ok().map(|l| *l.config());
        if let Some(c) = self.config {
            critical_section::with(|cs| app::CONFIG.borrow(cs).set(c));
            self.command(Command::Configure).await;
        }
        self.publish_readiness();
        if ok {
            Ok(())
        } else {
            defmt::error!("configuration store failed");
            Err(ConfigRejected::StoreFailed)
        }
    }

    /// `Calibrate`: the pen rests in its inkwell; its raw readings become the stored zeros.
    async fn calibrate(&mut self) -> Result<(), CommandError> {
        if !self.parts.store.needs_config() {
            // A virtual pen without a stored configuration has nothing to calibrate.
            return Err(CommandError::Unsupported);
        }
        if FORCES_ENABLED.load(Ordering::SeqCst) {
            return Err(CommandError::ForcesEnabled);
        }
        let Some(mut cfg) = self.config else {
            return Err(CommandError::ConfigNotValid);
        };
        // No reading: the virtual pen's pose is outside the configured pen's workspace.
        let r = self
            .sample_sensors()
            .await
            .ok_or(CommandError::OutOfRange)?;
        let zeros = RawReadings {
            encoders: r.encoders,
            gimbal: r.gimbal.map(i32::from),
        };
        cfg.calibration = Some(zeros);
        // Taken now: they hold until power-off whatever a board's encoders do (in force
        // once the configuration carrying them is).
        self.zeros_since_power_on = Some(zeros);
        if matches!(self.config_state, ConfigState::Migrated { .. }) {
            // A migrated configuration cannot be stored (it lacks what bounds the current):
            // the zeros go in force with it, for the kinematics, and are stored by the
            // `SetConfig` that completes it (the host keeps the pen's calibration).
            self.config = Some(cfg);
            critical_section::with(|cs| app::CONFIG.borrow(cs).set(cfg));
            self.command(Command::Configure).await;
            self.publish_readiness();
            return Ok(());
        }
        self.write_config(cfg)
            .await
            .map_err(|_| CommandError::StoreFailed)
    }

    /// One raw reading from the force loop (within 100 ticks), if the board can tell.
    async fn sample_sensors(&mut self) -> Option<SensorReport> {
        let _ = SENSORS.take(|_| ()); // a stale stream report
        SENSORS.request();
        for _ in 0..200 {
            if let Some(r) = SENSORS.take(|s| s.clone()) {
                return r;
            }
            Timer::after_micros(u64::from(self.cfg.tick_us / 2).max(100)).await;
        }
        None
    }

    /// `NudgeMotor`: checked against the caps and the pen's state, as a torque for the
    /// force loop (the fraction of the channel's full torque, ratio x k_t x I_max).
    fn nudge(&self, n: &Nudge, faults: u32) -> Result<Command, CommandError> {
        if !n.is_within_caps() {
            return Err(CommandError::OutOfRange);
        }
        if FORCES_ENABLED.load(Ordering::SeqCst) {
            return Err(CommandError::ForcesEnabled);
        }
        if faults != 0 {
            return Err(CommandError::FaultsLatched(faults_of(faults)));
        }
        if !self.config_allows_forces() {
            return Err(CommandError::ConfigNotValid);
        }
        let pen = self.config.unwrap_or(DeviceConfig::DEFAULT).pen;
        let channel = usize::from(n.channel);
        let full = [0, 1, 2].map(|j| pen.ratio[j] * pen.torque_constant[j] * pen.max_current[j]);
        let full = full.get(channel).copied().unwrap_or(0.0);
        let torque = f32::from(n.command_permille) / 1000.0 * full;
        Ok(Command::Nudge {
            channel,
            torque_nm: <Fx as maobi_shared::Scalar>::from_f32(torque),
            ticks: u32::from(n.duration_ms),
        })
    }

    /// A sensor report from the force loop, if one is waiting; asks for the next when due.
    fn sensors(&mut self) {
        if let Some(Some(report)) = SENSORS.take(|s| s.clone()) {
            if !self.try_send(&DeviceMsg::Sensors(report)) {
                self.frames_dropped = self.frames_dropped.saturating_add(1);
            }
        }
        if self.sensors_every == 0 {
            return;
        }
        let now = TICKS.load(Ordering::Relaxed);
        if (now.wrapping_sub(self.next_sensors) as i32) >= 0 && SENSORS.request() {
            self.next_sensors = now.wrapping_add(self.sensors_every);
        }
    }

    /// Queues a command for the force loop, waiting for room.
    async fn command(&mut self, c: Command) {
        while self.parts.cmds.enqueue(c).is_err() {
            Timer::after_micros(u64::from(self.cfg.tick_us)).await;
        }
        self.cmds_sent = self.cmds_sent.wrapping_add(1);
    }

    /// Waits until the force loop has applied every command queued so far (at most a tick).
    async fn settle(&mut self) {
        while app::CMDS_APPLIED.load(Ordering::Acquire) != self.cmds_sent {
            Timer::after_micros(u64::from(self.cfg.tick_us / 4).max(100)).await;
        }
    }

    /// A state frame from the snapshot, if the force loop left one, encoded where the state
    /// lies (no copy of it on the stack).
    fn send_state(&mut self) {
        let Some(n) = SNAPSHOT.take(|s| {
            self.pose_gaps = s.pose_gaps;
            // SAFETY: only the link task uses the buffer, and not re-entrantly (no await).
            let buf = unsafe { &mut *TX_BUF.0.get() };
            // As in `stage`: 0 (nothing sent) cannot happen within the bound.
            DeviceMsg::encode_state(&s.state, buf).unwrap_or(0)
        }) else {
            return;
        };
        if !self.write_staged(n) {
            self.frames_dropped = self.frames_dropped.saturating_add(1);
        }
    }

    async fn events(&mut self) {
        let now = TICKS.load(Ordering::Relaxed);
        // NOT_CALIBRATED included: raised at start, cleared by a successful calibration.
        let faults = app::reported_faults();
        if faults & LINK_SILENT == 0 {
            self.silence_reported = false;
        }
        let raised = faults & !self.reported_faults;
        // While the link is silent nothing can be delivered: report on reconnection.
        if raised != 0 && faults & LINK_SILENT == 0 {
            let t = (0..app::LATCHED_FAULTS)
                .filter(|i| raised & (1 << i) != 0)
                .map(|i| app::FAULT_TICKS[i].load(Ordering::Relaxed))
                .max()
                .unwrap_or(now);
            self.event(t, EventKind::FaultRaised(faults_of(raised)))
                .await;
            self.reported_faults |= raised;
        }
        let cleared = self.reported_faults & !faults;
        if cleared != 0 {
            self.event(now, EventKind::FaultCleared(faults_of(cleared)))
                .await;
            self.reported_faults = faults;
        }
        let enabled = FORCES_ENABLED.load(Ordering::SeqCst);
        if enabled != self.reported_enabled {
            self.reported_enabled = enabled;
            let kind = if enabled {
                EventKind::ForcesEnabled
            } else {
                EventKind::ForcesDisabled
            };
            self.event(now, kind).await;
        }
    }

    async fn telemetry(&mut self) {
        let now = TICKS.load(Ordering::Relaxed);
        if (now.wrapping_sub(self.next_telemetry) as i32) < 0 {
            return;
        }
        self.next_telemetry = now.wrapping_add(self.cfg.telemetry_ticks);
        let period = app::timing::take();
        let overflows = self.parts.transport.rx_overflows();
        if overflows != 0 {
            // Bytes lost to a full receive ring show up as framing / CRC errors too.
            defmt::warn!("link rx ring overflowed: {} bytes dropped", overflows);
        }
        let t = Telemetry {
            tick: now,
            tick_period_min_us: period.min_us,
            tick_period_mean_us: period.mean_us,
            tick_period_max_us: period.max_us,
            load_percent: period.load_percent,
            frames_dropped: self
                .frames_dropped
                .saturating_add(app::STATES_MISSED.load(Ordering::Relaxed)),
            pose_gaps: self.pose_gaps,
            rx: self.rx.stats(),
            tick_busy_max_us: period.busy_max_us,
            tick_busy_max_cycles: period.busy_max_counts,
            overruns: app::OVERRUNS.load(Ordering::Relaxed),
            brush_ticks: app::BRUSH_TICKS.load(Ordering::Relaxed),
        };
        let n = self.stage(&DeviceMsg::Telemetry(t));
        self.send_staged(n).await;
    }

    async fn event(&mut self, tick: u32, kind: EventKind) {
        let faults = faults_of(app::reported_faults());
        let n = self.stage(&DeviceMsg::Event(Event { tick, kind, faults }));
        self.send_staged(n).await;
    }

    /// Encodes `m` into the transmit buffer and returns the frame's length, for
    /// [`Self::send_staged`]. Not async, and the call sites build the message in its argument,
    /// so a message (as large as the largest, a state frame: kilobytes) lives on the stack
    /// for this call only, never in the task's future while it waits for room.
    fn stage(&mut self, m: &DeviceMsg) -> usize {
        // SAFETY: only the link task uses the buffer, and not re-entrantly (no await here).
        let buf = unsafe { &mut *TX_BUF.0.get() };
        // An error cannot happen for messages within the bound; 0 sends nothing rather than
        // stalling.
        m.encode(buf).unwrap_or(0)
    }

    /// Queues the frame [`Self::stage`] left in the transmit buffer (a message that must not
    /// be lost), waiting for room in the transmit ring. Nothing else stages meanwhile: the
    /// link task is the buffer's only user and does one thing at a time.
    async fn send_staged(&mut self, n: usize) {
        while !self.write_staged(n) {
            Timer::after_micros(u64::from(self.cfg.tick_us / 4).max(100)).await;
        }
    }

    /// Encodes `m` and queues it whole, or not at all (false: no room now).
    fn try_send(&mut self, m: &DeviceMsg) -> bool {
        let n = self.stage(m);
        self.write_staged(n)
    }

    /// Queues the first `n` bytes of the transmit buffer whole, or not at all.
    fn write_staged(&mut self, n: usize) -> bool {
        if self.parts.transport.tx_space() < n {
            return false;
        }
        // SAFETY: as in `stage`: the link task's own buffer, no await in between.
        let buf = unsafe { &*TX_BUF.0.get() };
        self.parts.transport.write(buf.get(..n).unwrap_or(&[]));
        true
    }
}

/// The link's own fault bit, as the latched bits ([`app::FAULTS`]) hold it.
const LINK_SILENT: u32 = Faults::LINK_SILENT.bits() as u32;

fn faults_of(bits: u32) -> Faults {
    Faults::from_bits_retain(bits as u16)
}

fn firmware_version() -> Version {
    let n = |s: &str| s.parse().unwrap_or(0);
    Version {
        major: n(env!("CARGO_PKG_VERSION_MAJOR")),
        minor: n(env!("CARGO_PKG_VERSION_MINOR")),
        patch: n(env!("CARGO_PKG_VERSION_PATCH")),
    }
}
