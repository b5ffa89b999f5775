//! The shared simulator behind the wire protocol, over TCP: `maobi sim-device --listen
//! 127.0.0.1:PORT`, and [`SimDeviceServer`] for tests.
//!
//! It behaves as the QEMU board does, from the link's side: a virtual-pen device
//! ([`Capabilities::VIRTUAL_PEN`]) that answers `Hello`, `Ping`, parameter reads and writes
//! and commands, runs one tick of the shared force loop ([`ForceLoop`]: brush, force model,
//! guide, output stage, sensor-jump check; the firmware's) per [`HostMsg::Pose`] sample, in
//! arrival order, and sends the brush's [`BrushState`] at `state_hz` (120 by default; 1000
//! sends every tick), plus [`Telemetry`] once a second. Guided writing: a [`HostMsg::Guide`]
//! sample rides with the pose of its `seq` into the loop's guide, as the firmware's link task
//! hands it to its force loop.
//! With no pose samples arriving it keeps sending its state at `state_hz`, so the host can tell
//! the link is up. One host at a time; the brush lives on between connections, as a
//! device's would.

use std::io::{ErrorKind, Read, Write};
use std::net::{SocketAddr, TcpListener};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use maobi_shared::force::{DEFAULT_FORCES, PHANTOM_OMNI};
use maobi_shared::force_loop::{Gate, TickIn};
use maobi_shared::guide::{GuideInput, DEFAULT_GUIDE};
use maobi_shared::protocol::{
    param_id, BrushState, Capabilities, Command, CommandError, ConfigRejected, ConfigState,
    DeviceInfo, DeviceMsg, DeviceRx, Event, EventKind, Faults, GuideSample, Haptics, HostMsg,
    Message, ParamReply, PoseSample, Telemetry,
};
use maobi_shared::{presets, BrushParams, ForceLoop, Fx, ParamError, ParamId, Pose, Scalar, Vec3};

use super::client::host_version;
use super::endpoint::{nothing_to_read_yet, Conn};

/// Options of the simulated device.
#[derive(Clone, Debug)]
pub struct SimDeviceOptions {
    /// The brush at start (a preset, or one with parameters changed: `maobi sim-device
    /// --param`); the host can change it over the protocol.
    pub brush: BrushParams,
    /// State frames per second (1 ..= 1000).
    pub state_hz: u32,
    /// Board name in the handshake.
    pub board: String,
}

impl Default for SimDeviceOptions {
    fn default() -> Self {
        SimDeviceOptions {
            brush: presets::LARGE,
            state_hz: 120,
            board: "maobi-sim-device".into(),
        }
    }
}

/// The model the device runs: the shared force loop, with the forces switch and the latched
/// faults that make its gate.
struct Model {
    fl: ForceLoop<Fx>,
    /// The host's switch for the forces (EnableForces / DisableForces).
    enabled: bool,
    /// Brush ticks run (one per pose sample).
    tick: u32,
    pose_seq: u32,
    /// The wanted force of the last tick (the state's `haptics.force_n`).
    force: Vec3<Fx>,
    faults: Faults,
    /// The last guide sample, for the pose of its `seq` (as the firmware's link task keeps
    /// it for its force loop).
    pending_guide: Option<GuideSample>,
}

impl Model {
    fn new(params: BrushParams) -> anyhow::Result<Model> {
        let start = Pose::new(
            Vec3::from_f64([0.0, 0.0, params.length_mm as f64 + 6.0]),
            maobi_shared::Quat::IDENTITY,
        );
        Ok(Model {
            fl: ForceLoop::new(params, start, DEFAULT_FORCES, PHANTOM_OMNI, DEFAULT_GUIDE)
                .map_err(|e| anyhow::anyhow!("{e}"))?,
            enabled: false,
            tick: 0,
            pose_seq: 0,
            force: Vec3::ZERO,
            faults: Faults::empty(),
            pending_guide: None,
        })
    }

    /// The guide sample that rides with the pose `seq`, if the host sent one for it.
    fn take_guide(&mut self, seq: u32) -> Option<GuideInput<Fx>> {
        match self.pending_guide {
            Some(g) if g.seq == seq => {
                self.pending_guide = None;
                Some(GuideInput {
                    anchor: g.anchor(),
                    on: g.on,
                })
            }
            _ => None,
        }
    }

    fn step(&mut self, pose: Pose<Fx>, seq: u32) {
        let guide = self.take_guide(seq);
        let out = self.fl.tick(TickIn {
            pose: Some(pose),
            guide,
            gate: Gate::new(self.enabled, self.faults),
        });
        // A sensor jump latches (forces held at zero until cleared).
        self.faults |= out.faults;
        self.force = out.wanted;
        self.tick = self.tick.wrapping_add(1);
        self.pose_seq = seq;
    }

    fn state(&self) -> BrushState {
        let enabled = self.enabled && self.faults.is_empty();
        BrushState::from_brush(
            self.fl.brush(),
            self.tick,
            self.pose_seq,
            Haptics::new(self.force, [Fx::ZERO; 3], enabled),
            self.faults,
        )
    }

    fn command(&mut self, c: &Command) -> Result<(), CommandError> {
        match c {
            Command::EnableForces if !self.faults.is_empty() => {
                return Err(CommandError::FaultsLatched(self.faults));
            }
            Command::EnableForces => self.enabled = true,
            Command::DisableForces => self.enabled = false,
            Command::Calibrate => return Err(CommandError::Unsupported),
            Command::DipInk { wetness } => {
                let w = Ord::clamp(Fx::from_bits(*wetness), Fx::ZERO, Fx::ONE);
                self.fl.brush_mut().dip(w);
            }
            Command::ChoosePreset(r) => {
                let p = r.resolve().ok_or(CommandError::UnknownPreset)?;
                self.fl
                    .set_params(p)
                    .map_err(|_| CommandError::UnknownPreset)?;
            }
            Command::ClearFaults => self.faults = Faults::empty(),
            Command::ResetBrush => {
                let pose = self.fl.brush().handle();
                self.fl.reset_brush(pose);
            }
            // Test hooks of the firmware (and commands newer than this device).
            #[allow(unreachable_patterns)]
            _ => return Err(CommandError::Unsupported),
        }
        Ok(())
    }
}

/// `EIO`, as Linux and the BSDs number it.
const EIO: i32 = 5;

/// The device behind the wire protocol: the simulated brush here, the Phantom bridge
/// ([`crate::phantom::device::BridgeModel`]) there. The connection loop (handshake, pings,
/// parameters, commands, telemetry, framing) is the same for both.
pub trait ProtocolModel: Send {
    /// Capabilities and force limits (peak, continuous; N) for the handshake.
    fn capabilities(&self) -> (Capabilities, f32, f32);
    /// The device's tick now.
    fn tick(&self) -> u32;
    /// A virtual-pen pose sample from the host; true if it ran a model tick.
    fn pose(&mut self, sample: &PoseSample) -> bool;
    /// Guided writing: the moving point for the pose sample of the same `seq` (sent just
    /// before it). A device without a virtual pen has no such pose to pair it with and
    /// drops it (the host sends guide samples only to virtual-pen devices).
    fn guide(&mut self, _sample: &GuideSample) {}
    /// The state to send now, if any. `due`: the state period has elapsed (or enough pose
    /// samples were consumed); a device with its own clock hands over what it produced.
    fn poll_state(&mut self, due: bool) -> Option<BrushState>;
    fn params(&self) -> BrushParams;
    fn set_param(&mut self, id: ParamId, value: f32) -> Result<(), ParamError>;
    fn command(&mut self, c: &Command) -> Result<(), CommandError>;
    /// The device has stopped for good (the connection and the server end): why.
    fn failed(&self) -> Option<String> {
        None
    }
}

impl ProtocolModel for Model {
    fn capabilities(&self) -> (Capabilities, f32, f32) {
        (
            Capabilities::VIRTUAL_PEN | Capabilities::FORCE_OUTPUT,
            PHANTOM_OMNI.peak_n,
            PHANTOM_OMNI.continuous_n,
        )
    }
    fn tick(&self) -> u32 {
        self.tick
    }
    fn pose(&mut self, sample: &PoseSample) -> bool {
        self.step(sample.pose(), sample.seq);
        true
    }
    fn guide(&mut self, sample: &GuideSample) {
        self.pending_guide = Some(*sample);
    }
    fn poll_state(&mut self, due: bool) -> Option<BrushState> {
        due.then(|| self.state())
    }
    fn params(&self) -> BrushParams {
        *self.fl.brush().params()
    }
    fn set_param(&mut self, id: ParamId, value: f32) -> Result<(), ParamError> {
        self.fl.brush_mut().set_param(id, value)
    }
    fn command(&mut self, c: &Command) -> Result<(), CommandError> {
        Model::command(self, c)
    }
}

/// A running simulated device; stops (closing its socket) when dropped.
pub struct SimDeviceServer {
    addr: SocketAddr,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl SimDeviceServer {
    /// Listens on `addr` (`127.0.0.1:0` picks a free port: see [`SimDeviceServer::addr`]).
    pub fn spawn(addr: &str, opts: SimDeviceOptions) -> anyhow::Result<SimDeviceServer> {
        let model = Model::new(opts.brush)?;
        SimDeviceServer::spawn_model(addr, Box::new(model), opts)
    }

    /// Serves `model` (any [`ProtocolModel`]) on `addr`; `opts.brush` is not used.
    pub fn spawn_model(
        addr: &str,
        mut model: Box<dyn ProtocolModel>,
        opts: SimDeviceOptions,
    ) -> anyhow::Result<SimDeviceServer> {
        if !(1..=1000).contains(&opts.state_hz) {
            anyhow::bail!("--state-hz must be 1 ..= 1000");
        }
        let listener =
            TcpListener::bind(addr).map_err(|e| anyhow::anyhow!("cannot listen on {addr}: {e}"))?;
        listener.set_nonblocking(true)?;
        let addr = listener.local_addr()?;
        let stop = Arc::new(AtomicBool::new(false));
        let thread = {
            let stop = stop.clone();
            std::thread::Builder::new()
                .name("maobi-sim-device".into())
                .spawn(move || serve(listener, &mut *model, opts, &stop))?
        };
        Ok(SimDeviceServer {
            addr,
            stop,
            thread: Some(thread),
        })
    }

    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// Stops serving: closes the connection and the listening socket.
    pub fn stop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }

    /// Serves until the process ends (for `maobi sim-device`).
    pub fn wait(mut self) {
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl Drop for SimDeviceServer {
    fn drop(&mut self) {
        self.stop();
    }
}

fn serve(
    listener: TcpListener,
    model: &mut dyn ProtocolModel,
    opts: SimDeviceOptions,
    stop: &AtomicBool,
) {
    while !stop.load(Ordering::SeqCst) && model.failed().is_none() {
        match listener.accept() {
            Ok((stream, peer)) => {
                log::info!("sim-device: client {peer} connected");
                let setup = || -> std::io::Result<Box<dyn Conn>> {
                    stream.set_nonblocking(false)?;
                    stream.set_nodelay(true)?;
                    stream.set_read_timeout(Some(Duration::from_millis(1)))?;
                    stream.set_write_timeout(Some(Duration::from_millis(500)))?;
                    Ok(Box::new(stream.try_clone()?))
                };
                match setup() {
                    Ok(conn) => match connection(conn, model, &opts, stop) {
                        Ok(()) => log::info!("sim-device: client {peer} left"),
                        Err(e) => log::info!("sim-device: client {peer} dropped: {e}"),
                    },
                    Err(e) => log::warn!("sim-device: cannot set up {peer}'s socket: {e}"),
                }
            }
            Err(e) if e.kind() == ErrorKind::WouldBlock => {
                std::thread::sleep(Duration::from_millis(5));
            }
            Err(_) => std::thread::sleep(Duration::from_millis(50)),
        }
    }
}

/// Serves one host on `conn` (reads should time out after about a millisecond) until it
/// closes the stream or `stop` is set: the same device as [`SimDeviceServer`], over any byte
/// stream (a serial port, a pty in tests).
pub fn serve_stream(
    conn: Box<dyn Conn>,
    opts: &SimDeviceOptions,
    stop: &AtomicBool,
) -> anyhow::Result<()> {
    let mut model = Model::new(opts.brush)?;
    connection(conn, &mut model, opts, stop)?;
    Ok(())
}

struct Tx {
    stream: Box<dyn Conn>,
    buf: Vec<u8>,
    frame: Vec<u8>,
    dropped: u32,
}

impl Tx {
    fn send(&mut self, msg: &DeviceMsg) {
        match msg.encode(&mut self.frame) {
            Ok(n) => self.buf.extend_from_slice(&self.frame[..n]),
            Err(_) => self.dropped = self.dropped.saturating_add(1),
        }
    }
    fn flush(&mut self) -> std::io::Result<()> {
        if !self.buf.is_empty() {
            self.stream.write_all(&self.buf)?;
            self.buf.clear();
        }
        Ok(())
    }
}

fn connection(
    stream: Box<dyn Conn>,
    model: &mut dyn ProtocolModel,
    opts: &SimDeviceOptions,
    stop: &AtomicBool,
) -> std::io::Result<()> {
    let mut rx_stream = stream.try_clone_conn()?;
    let mut tx = Tx {
        stream,
        buf: Vec::new(),
        frame: vec![0u8; DeviceMsg::MAX_FRAME],
        dropped: 0,
    };
    let mut dec = Box::new(DeviceRx::new());
    let mut buf = vec![0u8; 4096];
    let period = Duration::from_micros(1_000_000 / u64::from(opts.state_hz));
    let ticks_per_state = (1000 / opts.state_hz).max(1);
    let mut since_state = 0u32;
    let mut last_state = Instant::now();
    let mut last_telemetry = Instant::now();
    let mut last_loop = Instant::now();
    let mut period_us = (u32::MAX, 0u64, 0u32, 0u32);
    let mut pose_gaps = 0u32;
    let mut brush_ticks = 0u32;
    let mut last_pose = Instant::now();
    let mut greeted = false;
    let started = Instant::now();
    while !stop.load(Ordering::SeqCst) {
        if model.failed().is_some() {
            tx.flush()?;
            return Ok(());
        }
        let n = match rx_stream.read(&mut buf) {
            Ok(0) => return Ok(()),
            Ok(n) => n,
            Err(e) if nothing_to_read_yet(&e) => 0,
            // A pty master whose other end nobody holds open (yet): no host on the line.
            Err(e) if e.raw_os_error() == Some(EIO) => {
                std::thread::sleep(Duration::from_millis(1));
                0
            }
            Err(e) => return Err(e),
        };
        let now = Instant::now();
        let us = now
            .duration_since(last_loop)
            .as_micros()
            .min(u128::from(u32::MAX)) as u32;
        last_loop = now;
        period_us = (
            period_us.0.min(us),
            period_us.1 + u64::from(us),
            period_us.2 + 1,
            period_us.3.max(us),
        );
        for outcome in dec.feed(&buf[..n]) {
            let Ok(msg) = outcome else { continue };
            match msg {
                HostMsg::Hello(h) => {
                    if h.check().is_ok() {
                        let (caps, peak, continuous) = model.capabilities();
                        let info =
                            DeviceInfo::new(&opts.board, host_version(), caps, peak, continuous);
                        tx.send(&DeviceMsg::Hello(info));
                        if !greeted {
                            greeted = true;
                            tx.send(&DeviceMsg::Event(Event {
                                tick: model.tick(),
                                kind: EventKind::LinkConnected,
                                faults: Faults::empty(),
                            }));
                        }
                    }
                }
                HostMsg::Ping { seq } => tx.send(&DeviceMsg::Pong { seq }),
                HostMsg::Guide(g) => model.guide(&g),
                HostMsg::Pose(sample) => {
                    last_pose = now;
                    if model.pose(&sample) {
                        since_state += 1;
                        brush_ticks = brush_ticks.wrapping_add(1);
                    }
                    if since_state >= ticks_per_state {
                        since_state = 0;
                        last_state = now;
                        if let Some(state) = model.poll_state(true) {
                            tx.send(&DeviceMsg::State(state));
                        }
                    }
                }
                HostMsg::GetParam { id } => {
                    tx.send(&DeviceMsg::Param(ParamReply::read(&model.params(), id)))
                }
                HostMsg::SetParam { id, value } => {
                    let reply = match param_id(id) {
                        Some(p) => {
                            let r = model.set_param(p, value);
                            ParamReply::written(id, r, &model.params())
                        }
                        None => ParamReply::read(&model.params(), id),
                    };
                    tx.send(&DeviceMsg::Param(reply));
                }
                HostMsg::Command(c) => {
                    let result = model.command(&c);
                    tx.send(&DeviceMsg::CommandDone { command: c, result });
                }
                // A simulated device keeps no configuration (its handshake says
                // NotApplicable).
                HostMsg::GetConfig | HostMsg::SetConfig(_) => {
                    let reply = Err(ConfigRejected::NotStored(ConfigState::NotApplicable));
                    tx.send(&DeviceMsg::Config(reply));
                }
            }
        }
        // Without pose samples, the clock still runs: count the gaps, keep the state coming.
        if now.duration_since(last_pose) > Duration::from_millis(1) {
            pose_gaps = pose_gaps.saturating_add(1);
        }
        if greeted {
            // A device with its own clock may have several states waiting; a few per pass.
            let mut due = now.duration_since(last_state) >= period;
            for _ in 0..8 {
                let Some(state) = model.poll_state(due) else {
                    break;
                };
                due = false;
                last_state = now;
                since_state = 0;
                tx.send(&DeviceMsg::State(state));
            }
        }
        if now.duration_since(last_telemetry) >= Duration::from_secs(1) {
            last_telemetry = now;
            let (min, sum, count, max) = period_us;
            tx.send(&DeviceMsg::Telemetry(Telemetry {
                tick: started.elapsed().as_millis() as u32,
                tick_period_min_us: if count > 0 { min } else { 0 },
                tick_period_mean_us: sum.checked_div(u64::from(count)).unwrap_or(0) as u32,
                tick_period_max_us: max,
                load_percent: 0,
                frames_dropped: tx.dropped,
                pose_gaps,
                rx: dec.stats(),
                // A simulator on the desktop has no deadline of its own to overrun: it
                // measures no busy time and counts no overrun.
                tick_busy_max_us: 0,
                tick_busy_max_cycles: 0,
                overruns: 0,
                brush_ticks,
            }));
            period_us = (u32::MAX, 0, 0, 0);
        }
        tx.flush()?;
    }
    Ok(())
}
