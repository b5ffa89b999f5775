//! The link task: the wire protocol (`maobi_shared::protocol`) over the board's byte link
//! (QEMU's UART, the Black Pill's USB CDC-ACM), the same on every board: a board calls
//! [`run`] from its own task with its [`LinkTransport`] and its [`BoardInfo`].
//!
//! * On start it writes one `0x00` so the host's decoder drops any partial frame.
//! * `Hello` is answered with the device's [`DeviceInfo`] and arms the link supervision
//!   (the force loop latches `LINK_SILENT` after [`app::LINK_TIMEOUT_TICKS`] ticks without
//!   a valid frame and turns the motors off). The first pose sample after a hello places the
//!   brush at rest there: a stream starts at rest at its first pose, as the host simulation
//!   does.
//! * `Pose` samples go into the virtual pen's queue (the force loop takes one per tick and
//!   never waits for the link). When the queue is full the task stops reading until it has
//!   room, so the host's window, not a dropped sample, absorbs the difference.
//! * `State` frames: the force loop copies the brush into the snapshot slot when one is due
//!   ([`app::STATE_HZ`] per 1000 ticks, 120 by default); this task builds
//!   [`BrushState::from_brush`] from it and encodes it here, in thread mode. A state that
//!   finds the transmit ring full is dropped and counted (`Telemetry::frames_dropped`).
//! * Commands and parameters are validated here and handed to the force loop as
//!   [`app::Command`]s; every one is answered.
//! * Events: faults raised and cleared, forces enabled and disabled, link connected and
//!   reconnected (with the silence and the faults latched meanwhile, re-sent because the
//!   originals went nowhere). Telemetry every `telemetry_ticks` ticks.

use core::future::{poll_fn, Future};
use core::pin::pin;
use core::sync::atomic::Ordering;
use core::task::Poll;

use embassy_time::{Duration, Timer};
use maobi_shared::kinematics::RawReadings;
use maobi_shared::pen_io::{ConfigState, DeviceConfig};
use maobi_shared::protocol::{
    param_id, BrushState, Buttons, Capabilities, Command as Wire, CommandError, ConfigRejected,
    DeviceInfo, DeviceMsg, DeviceRx, Event, EventKind, Faults, Haptics, HostMsg, Message, Nudge,
    ParamRejected, ParamReply, SensorReport, Telemetry, Version, SENSOR_RATE_MAX_HZ,
};
use maobi_shared::{BrushParams, Fx, Pose, Scalar, Vec3};

use crate::app::{self, Command, FAULTS, FORCES_ENABLED, SNAPSHOT, TICKS};
use crate::board::{ConfigStore, LinkTransport};

/// What the link says about the board and lets the host do with it.
pub struct BoardInfo {
    /// The board's name in the handshake.
    pub name: &'static str,
    pub capabilities: Capabilities,
    /// Force limits in the handshake (N).
    pub force_peak_n: f32,
    pub force_continuous_n: f32,
    /// `Calibrate` stores the readings at the inkwell in the configuration (else answered
    /// `Unsupported`).
    pub can_calibrate: bool,
}

/// What the link task drives.
pub struct LinkParts<T, S> {
    pub transport: T,
    /// The virtual pen's pose queue (`None` on a board with its own sensors: pose samples
    /// from the host are then ignored).
    pub poses: Option<app::PoseProducer>,
    pub cmds: app::CmdProducer,
    /// The configuration store (a board with `Capabilities::STORED_CONFIG`).
    pub store: S,
    /// The stored configuration's state at boot, and the configuration if it is valid.
    pub config_state: ConfigState,
    pub config: Option<DeviceConfig>,
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
    /// Sensor reports per second (0: none) and the tick the next one is due.
    sensor_rate_hz: u16,
    next_sensor_tick: u32,
    board: &'static BoardInfo,
    cfg: LinkConfig,
    rx: DeviceRx,
    /// Bytes read from the UART but not yet fed to the decoder (a pose is waiting for room).
    inbuf: [u8; 64],
    in_start: usize,
    in_end: usize,
    pending_pose: Option<(u32, Pose<Fx>)>,
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
}

/// The link task's body (each board wraps it in its own `#[embassy_executor::task]`, since
/// tasks cannot be generic over the transport).
pub async fn run<T: LinkTransport, S: ConfigStore>(
    parts: LinkParts<T, S>,
    board: &'static BoardInfo,
    params: BrushParams,
    cfg: LinkConfig,
) -> ! {
    let mut link = Link {
        parts,
        sensor_rate_hz: 0,
        next_sensor_tick: 0,
        board,
        cfg,
        rx: DeviceRx::new(),
        inbuf: [0; 64],
        in_start: 0,
        in_end: 0,
        pending_pose: None,
        params,
        frames_dropped: 0,
        pose_gaps: 0,
        reported_faults: 0,
        reported_enabled: false,
        connected_once: false,
        silence_reported: false,
        next_telemetry: cfg.telemetry_ticks,
        cmds_sent: 0,
    };
    link.parts
        .transport
        .write(&[maobi_shared::protocol::DELIMITER]);
    loop {
        link.receive().await;
        link.send_state();
        link.events().await;
        link.telemetry().await;
        link.sensors().await;
        link.wait().await;
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
            if SNAPSHOT.is_full() {
                return Poll::Ready(());
            }
            if !blocked && readable.as_mut().poll(cx).is_ready() {
                return Poll::Ready(());
            }
            timer.as_mut().poll(cx)
        })
        .await
    }

    /// Reads and handles what the host sent, until the UART is empty or the pose queue full.
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
            }
        }
    }

    /// A valid frame: the link is alive; report a reconnection after a silence.
    async fn heard(&mut self) {
        let now = TICKS.load(Ordering::Relaxed);
        let faults = FAULTS.load(Ordering::SeqCst);
        if faults & app::fault::LINK_SILENT != 0 && !self.silence_reported {
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
                let mut info = DeviceInfo::new(
                    self.board.name,
                    firmware_version(),
                    self.board.capabilities,
                    self.board.force_peak_n,
                    self.board.force_continuous_n,
                );
                if self.stores_config() {
                    info = info.with_config(self.parts.config_state.clone());
                }
                self.send(&DeviceMsg::Hello(info)).await;
                self.command(Command::Reanchor).await;
                app::LINK_ARMED.store(true, Ordering::SeqCst);
                if !self.connected_once {
                    self.connected_once = true;
                    let now = TICKS.load(Ordering::Relaxed);
                    self.event(now, EventKind::LinkConnected).await;
                }
            }
            HostMsg::Ping { seq } => self.send(&DeviceMsg::Pong { seq }).await,
            HostMsg::Pose(s) => {
                // A pen with its own sensors has no use for the host's poses: ignored.
                if let Some(poses) = self.parts.poses.as_mut() {
                    let p = (s.seq, s.pose());
                    if poses.enqueue(p).is_err() {
                        self.pending_pose = Some(p);
                    }
                }
            }
            HostMsg::GetParam { id } => {
                let r = ParamReply::read(&self.params, id);
                self.send(&DeviceMsg::Param(r)).await;
            }
            HostMsg::SetParam { id, value } => {
                let reply = match param_id(id) {
                    None => ParamReply {
                        id,
                        result: Err(ParamRejected::unknown(id)),
                    },
                    Some(p) => {
                        let mut candidate = self.params;
                        let outcome = candidate.set(p, value).and_then(|()| candidate.validate());
                        if outcome.is_ok() {
                            self.params = candidate;
                            self.command(Command::SetParam(p, value)).await;
                        }
                        ParamReply::written(id, outcome, &self.params)
                    }
                };
                self.send(&DeviceMsg::Param(reply)).await;
            }
            HostMsg::GetConfig => {
                let reply = match self.parts.config {
                    Some(c) if self.stores_config() => Ok(c),
                    _ if self.stores_config() => Err(ConfigRejected::NotStored(
                        self.parts.config_state.clone(),
                    )),
                    _ => Err(ConfigRejected::NotStored(ConfigState::NotApplicable)),
                };
                self.send(&DeviceMsg::Config(reply)).await;
            }
            HostMsg::SetConfig(cfg) => {
                let reply = self.set_config(cfg).await;
                self.send(&DeviceMsg::Config(reply)).await;
            }
            HostMsg::Command(c) => {
                let result = self.wire_command(&c).await;
                self.send(&DeviceMsg::CommandDone { command: c, result })
                    .await;
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
            // A pen with no valid configuration, or not calibrated: forces stay off.
            Wire::EnableForces if app::PEN_NOT_READY.load(Ordering::SeqCst) != 0 => {
                return Err(CommandError::ConfigNotValid)
            }
            Wire::EnableForces => Command::EnableForces,
            Wire::DisableForces => Command::DisableForces,
            Wire::Calibrate if self.board.can_calibrate => return self.calibrate().await,
            // The virtual pen has no sensors to zero.
            Wire::Calibrate => return Err(CommandError::Unsupported),
            Wire::DipInk { wetness } => Command::Dip(Fx::from_bits(*wetness)),
            Wire::ChoosePreset(p) => {
                let params = p.resolve().ok_or(CommandError::UnknownPreset)?;
                self.params = params;
                Command::SetParams(params)
            }
            Wire::ClearFaults => Command::ClearFaults,
            Wire::ResetBrush => Command::ResetBrush,
            Wire::InjectOverrun => Command::InjectOverrun,
            Wire::StreamSensors { rate_hz } if *rate_hz > SENSOR_RATE_MAX_HZ => {
                return Err(CommandError::OutOfRange)
            }
            Wire::StreamSensors { rate_hz } if self.has_sensors() => {
                self.sensor_rate_hz = *rate_hz;
                self.next_sensor_tick = TICKS.load(Ordering::Relaxed);
                return Ok(());
            }
            // No sensors on the virtual pen.
            Wire::StreamSensors { .. } => return Err(CommandError::Unsupported),
            Wire::NudgeMotor(n) => self.nudge(n)?,
        };
        self.command(cmd).await;
        Ok(())
    }

    fn stores_config(&self) -> bool {
        self.board
            .capabilities
            .contains(Capabilities::STORED_CONFIG)
    }

    fn has_sensors(&self) -> bool {
        self.board.capabilities.contains(Capabilities::REAL_SENSORS)
    }

    /// `SetConfig`: validated whole, written only with the forces off, read back by the
    /// store, then put in force (the force loop takes it up at its next tick).
    async fn set_config(&mut self, cfg: DeviceConfig) -> Result<DeviceConfig, ConfigRejected> {
        if !self.stores_config() {
            return Err(ConfigRejected::NotStored(ConfigState::NotApplicable));
        }
        self.settle().await;
        if FORCES_ENABLED.load(Ordering::SeqCst) {
            return Err(ConfigRejected::ForcesEnabled);
        }
        cfg.validate().map_err(ConfigRejected::Invalid)?;
        if !self.parts.store.store(&cfg) {
            return Err(ConfigRejected::StoreFailed);
        }
        self.put_in_force(cfg).await;
        Ok(cfg)
    }

    /// A stored configuration replaces the one in force.
    async fn put_in_force(&mut self, cfg: DeviceConfig) {
        self.parts.config = Some(cfg);
        self.parts.config_state = ConfigState::Valid;
        app::CONFIG_VALID.store(true, Ordering::SeqCst);
        critical_section::with(|cs| app::NEW_CONFIG.borrow(cs).set(Some(cfg)));
        self.command(Command::Reconfigure).await;
        self.settle().await;
    }

    /// `Calibrate` on a pen with sensors: the readings now (the pen resting in its inkwell)
    /// become the stored calibration, in force at once.
    async fn calibrate(&mut self) -> Result<(), CommandError> {
        self.settle().await;
        if FORCES_ENABLED.load(Ordering::SeqCst) {
            return Err(CommandError::ForcesEnabled);
        }
        let Some(mut cfg) = self.parts.config else {
            return Err(CommandError::ConfigNotValid);
        };
        // A fresh reading: wait for the force loop's next tick.
        let seen = critical_section::with(|cs| app::SENSORS.borrow(cs).get()).tick;
        while critical_section::with(|cs| app::SENSORS.borrow(cs).get()).tick == seen {
            Timer::after_micros(u64::from(self.cfg.tick_us / 2).max(100)).await;
        }
        let s = critical_section::with(|cs| app::SENSORS.borrow(cs).get());
        cfg.calibration = Some(RawReadings {
            encoders: s.encoders,
            gimbal: s.gimbal.map(i32::from),
        });
        if cfg.validate().is_err() || !self.parts.store.store(&cfg) {
            return Err(CommandError::StoreFailed);
        }
        self.put_in_force(cfg).await;
        Ok(())
    }

    /// `NudgeMotor`: within the caps, forces off, a valid configuration.
    fn nudge(&mut self, n: &Nudge) -> Result<Command, CommandError> {
        if !self.has_sensors() {
            return Err(CommandError::Unsupported);
        }
        if !n.is_within_caps() {
            return Err(CommandError::OutOfRange);
        }
        if FORCES_ENABLED.load(Ordering::SeqCst) {
            return Err(CommandError::ForcesEnabled);
        }
        if self.parts.config.is_none() {
            return Err(CommandError::ConfigNotValid);
        }
        let ticks = (u32::from(n.duration_ms) * 1000 / self.cfg.tick_us.max(1)).max(1);
        Ok(Command::Nudge {
            channel: n.channel,
            command: Fx::from_f64(f64::from(n.command_permille) / 1000.0),
            ticks: u16::try_from(ticks).unwrap_or(u16::MAX),
        })
    }

    /// The bring-up's sensor stream, at the rate the host asked for.
    async fn sensors(&mut self) {
        if self.sensor_rate_hz == 0 {
            return;
        }
        let now = TICKS.load(Ordering::Relaxed);
        if (now.wrapping_sub(self.next_sensor_tick) as i32) < 0 {
            return;
        }
        let ticks_per_report = (1000 / u32::from(self.sensor_rate_hz)).max(1);
        self.next_sensor_tick = now.wrapping_add(ticks_per_report);
        let s = critical_section::with(|cs| app::SENSORS.borrow(cs).get());
        let report = SensorReport {
            tick: s.tick,
            encoders: s.encoders,
            gimbal: s.gimbal,
            buttons: Buttons::from_bits_retain(s.buttons),
            synthetic: false,
        };
        // Like a state frame: dropped (and counted) when the transmit queue is full.
        if !self.try_send(&DeviceMsg::Sensors(report)) {
            self.frames_dropped = self.frames_dropped.saturating_add(1);
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

    /// A state frame from the snapshot, if the force loop left one.
    fn send_state(&mut self) {
        let Some(Some(state)) = SNAPSHOT.take(|s| {
            self.pose_gaps = s.pose_gaps;
            let brush = s.brush.as_ref()?;
            let haptics = Haptics::new(
                Vec3::new(s.force[0], s.force[1], s.force[2]),
                s.motors,
                s.enabled,
            );
            Some(BrushState::from_brush(
                brush,
                s.tick,
                s.pose_seq,
                haptics,
                faults_of(s.faults),
            ))
        }) else {
            return;
        };
        if !self.try_send(&DeviceMsg::State(state)) {
            self.frames_dropped = self.frames_dropped.saturating_add(1);
        }
    }

    async fn events(&mut self) {
        let now = TICKS.load(Ordering::Relaxed);
        let faults = FAULTS.load(Ordering::SeqCst);
        if faults & app::fault::LINK_SILENT == 0 {
            self.silence_reported = false;
        }
        let raised = faults & !self.reported_faults;
        // While the link is silent nothing can be delivered: report on reconnection.
        if raised != 0 && faults & app::fault::LINK_SILENT == 0 {
            let t = (0..app::fault::COUNT)
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
        let (min, mean, max, load) = app::timing::take();
        let overflows = self.parts.transport.rx_overflows();
        if overflows != 0 {
            // Bytes lost to a full receive ring show up as framing / CRC errors too.
            defmt::warn!("link rx ring overflowed: {} bytes dropped", overflows);
        }
        let t = Telemetry {
            tick: now,
            tick_period_min_us: min,
            tick_period_mean_us: mean,
            tick_period_max_us: max,
            load_percent: load,
            frames_dropped: self
                .frames_dropped
                .saturating_add(app::STATES_MISSED.load(Ordering::Relaxed)),
            pose_gaps: self.pose_gaps,
            rx: self.rx.stats(),
        };
        self.send(&DeviceMsg::Telemetry(t)).await;
    }

    async fn event(&mut self, tick: u32, kind: EventKind) {
        let faults = faults_of(FAULTS.load(Ordering::SeqCst));
        self.send(&DeviceMsg::Event(Event { tick, kind, faults }))
            .await;
    }

    /// Sends a message that must not be lost, waiting for room in the transmit ring.
    async fn send(&mut self, m: &DeviceMsg) {
        while !self.try_send(m) {
            Timer::after_micros(u64::from(self.cfg.tick_us / 4).max(100)).await;
        }
    }

    /// Encodes `m` and queues it whole, or not at all (false: no room now).
    fn try_send(&mut self, m: &DeviceMsg) -> bool {
        // SAFETY: only the link task uses the buffer, and not re-entrantly (no await here).
        let buf = unsafe { &mut *TX_BUF.0.get() };
        let Ok(n) = m.encode(buf) else {
            // Cannot happen for messages within the bound; drop rather than stall.
            return true;
        };
        if self.parts.transport.tx_space() < n {
            return false;
        }
        self.parts.transport.write(&buf[..n]);
        true
    }
}

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
