//! The bridge behind the two ways to run it: the wire protocol over TCP (`maobi bridge`,
//! [`BridgeModel`] in the same connection loop as `maobi sim-device`) and a
//! [`Device`] for the GUI (`maobi --device phantom`, [`PhantomDevice`], with [`gui_device`] falling
//! back to the built-in simulator when there is no library or no device).

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

use maobi_shared::params::TickLimits;
use maobi_shared::protocol::{BrushState, Capabilities, Command, CommandError, Faults, PoseSample};
use maobi_shared::{BrushParams, Fx, ParamError, ParamId, Scalar};

use super::loader::HdLib;
use super::servo::{
    Bridge, BridgeOptions, GuidePoints, HandState, ServoBrush, ServoCommand, ServoShared,
    ServoState,
};
use super::solver::SolverLink;
use crate::device::builtin::{SimClock, SimDevice};
use crate::device::client::frame_from_state;
use crate::device::journal::Journal;
use crate::device::model::{BrushChoice, ModelKind};
use crate::device::sim_model::{fill_baxter_lin, frame_of_tick, ModelTick};
use crate::device::ProtocolModel;
use crate::device::{BrushFrame, Device, DeviceCommand, DeviceError, DeviceStatus, HandInput};

/// The running bridge as a wire-protocol device: real sensors (the stylus), force output,
/// buttons; states come from the servo loop at its own pace.
pub struct BridgeModel {
    bridge: Bridge,
    shared: Arc<ServoShared>,
    params: BrushParams,
}

impl BridgeModel {
    pub fn new(bridge: Bridge) -> BridgeModel {
        BridgeModel {
            shared: bridge.shared(),
            params: *bridge.params(),
            bridge,
        }
    }

    pub fn shared(&self) -> Arc<ServoShared> {
        self.shared.clone()
    }

    fn set_params(&mut self, p: BrushParams) {
        self.params = p;
        self.shared.send(ServoCommand::SetParams(p));
    }
}

impl ProtocolModel for BridgeModel {
    fn capabilities(&self) -> (Capabilities, f32, f32) {
        let l = self.bridge.limits();
        (
            Capabilities::REAL_SENSORS | Capabilities::FORCE_OUTPUT | Capabilities::BUTTONS,
            l.peak_n,
            l.continuous_n,
        )
    }
    fn tick(&self) -> u32 {
        self.shared.ticks()
    }
    /// The stylus is the pen: a host's virtual-pen samples are not used.
    fn pose(&mut self, _sample: &PoseSample) -> bool {
        false
    }
    fn poll_state(&mut self, _due: bool) -> Option<BrushState> {
        self.shared.take_state()
    }
    fn params(&self) -> BrushParams {
        self.params
    }
    fn set_param(&mut self, id: ParamId, value: f32) -> Result<(), ParamError> {
        let mut p = self.params;
        p.set(id, value)?;
        p.validate()?;
        self.set_params(p);
        Ok(())
    }
    fn command(&mut self, c: &Command) -> Result<(), CommandError> {
        let s = &self.shared;
        match c {
            Command::EnableForces => s.send(ServoCommand::EnableForces(true)),
            Command::DisableForces => s.send(ServoCommand::EnableForces(false)),
            Command::Calibrate => s.send(ServoCommand::Calibrate),
            Command::DipInk { wetness } => {
                s.send(ServoCommand::Dip(Fx::from_bits(*wetness).to_f32()));
            }
            Command::ChoosePreset(r) => {
                let p = r.resolve().ok_or(CommandError::UnknownPreset)?;
                self.set_params(p);
            }
            Command::ClearFaults => s.send(ServoCommand::ClearFaults),
            Command::ResetBrush => s.send(ServoCommand::ResetBrush),
            #[allow(unreachable_patterns)]
            _ => return Err(CommandError::Unsupported),
        }
        Ok(())
    }
    fn failed(&self) -> Option<String> {
        self.bridge.stopped().map(|s| s.to_string())
    }
}

/// The Phantom as the GUI's device: the servo loop in this process.
pub struct PhantomDevice {
    hd_lib: Option<PathBuf>,
    /// The faults of the last state polled (for the status' notices).
    last_faults: Faults,
    opts: BridgeOptions,
    bridge: Option<Bridge>,
    model: ModelKind,
    brush: BrushChoice,
    params: BrushParams,
    preset: String,
    last_error: Option<String>,
    wake: Option<Arc<dyn Fn() + Send + Sync>>,
    waker: Option<(Arc<AtomicBool>, std::thread::JoinHandle<()>)>,
}

impl PhantomDevice {
    /// Not yet connected: [`Device::connect`] loads libHD (`hd_lib`, `$MAOBI_HD_LIB`, the
    /// install paths) and starts the servo loop with the brush `preset` (`opts.brush` and
    /// `opts.model` are replaced by it), Liang's model.
    pub fn new(
        hd_lib: Option<PathBuf>,
        preset: &str,
        opts: BridgeOptions,
    ) -> Result<PhantomDevice, DeviceError> {
        PhantomDevice::with_model(hd_lib, ModelKind::Liang, preset, opts)
    }

    /// As [`Self::new`], running `model`: Baxter & Lin's brush (`brush` a preset's round
    /// head, or flat, filbert, fan) is solved on a thread beside the servo loop.
    pub fn with_model(
        hd_lib: Option<PathBuf>,
        model: ModelKind,
        brush: &str,
        opts: BridgeOptions,
    ) -> Result<PhantomDevice, DeviceError> {
        let choice = BrushChoice::for_model(brush, model).map_err(DeviceError::Rejected)?;
        Ok(PhantomDevice {
            hd_lib,
            last_faults: Faults::empty(),
            preset: brush.to_string(),
            opts,
            bridge: None,
            model,
            params: choice.params,
            brush: choice,
            last_error: None,
            wake: None,
            waker: None,
        })
    }

    /// Calls `wake` (about 60 times a second) while connected, so the UI redraws.
    pub fn on_frames(&mut self, wake: Arc<dyn Fn() + Send + Sync>) {
        self.wake = Some(wake);
    }

    /// The servo loop's model for the brush chosen.
    fn servo_brush(&self) -> ServoBrush {
        match self.model {
            ModelKind::Liang => ServoBrush::Liang,
            ModelKind::BaxterLin => ServoBrush::BaxterLin(self.brush.head_shape()),
        }
    }

    /// Starts the servo loop again with the model and brush now chosen (a new model or head
    /// needs a new loop; the brush starts at rest at the next pose), if it was running. The
    /// paper's calibration and the forces switch carry over: forces the user turned off
    /// stay off.
    fn restart(&mut self) -> Result<(), DeviceError> {
        let Some(b) = &self.bridge else {
            return Ok(());
        };
        let shared = b.shared();
        if let Some(h) = shared.paper_height_mm() {
            self.opts.mapping.paper_height_mm = h;
        }
        self.opts.forces_on = shared.forces_on() || shared.awaiting_lift();
        self.disconnect();
        self.connect()
    }

    /// A brush frame of Baxter & Lin's model: the servo loop's side `h` and the brush the
    /// solver last published (`None` before its first solve).
    fn hand_frame(link: &SolverLink, h: &HandState) -> Option<BrushFrame> {
        let brush = link.brush_of(h.generation)?;
        let out = ModelTick::of_baxter_lin(
            maobi_shared::Vec3::from_f64(h.command),
            maobi_shared::Vec3::from_f64(h.force),
            h.faults,
            None,
        );
        let mut frame = frame_of_tick(u64::from(h.tick), h.pose, out, h.output, false);
        fill_baxter_lin(&mut frame, &brush);
        Some(frame)
    }

    fn servo(&self, cmd: ServoCommand) -> Result<(), DeviceError> {
        match &self.bridge {
            Some(b) if b.stopped().is_none() => {
                b.shared().send(cmd);
                Ok(())
            }
            Some(b) => Err(DeviceError::Link(
                b.stopped().map(|s| s.to_string()).unwrap_or_default(),
            )),
            None => Err(DeviceError::NotConnected),
        }
    }
}

impl Device for PhantomDevice {
    fn connect(&mut self) -> Result<(), DeviceError> {
        if self.bridge.is_some() {
            return Ok(());
        }
        // Loaded once per process: connecting again reuses the library (see `loader`).
        let lib = HdLib::find(self.hd_lib.as_deref()).map_err(|e| {
            let e = DeviceError::Link(e.to_string());
            self.last_error = Some(e.to_string());
            e
        })?;
        // The brush as it stands, with any parameter changed since the preset was chosen.
        let mut opts = self.opts.clone();
        opts.brush = self.params;
        opts.model = self.servo_brush();
        let bridge = Bridge::start(lib, &opts).map_err(|e| {
            let e = DeviceError::Link(format!("{e:#}"));
            self.last_error = Some(e.to_string());
            e
        })?;
        self.bridge = Some(bridge);
        if let Some(w) = self.wake.clone() {
            let run = Arc::new(AtomicBool::new(true));
            let r2 = run.clone();
            if let Ok(t) = std::thread::Builder::new()
                .name("maobi-phantom-wake".into())
                .spawn(move || {
                    while r2.load(Ordering::Relaxed) {
                        w();
                        std::thread::sleep(Duration::from_millis(16));
                    }
                })
            {
                self.waker = Some((run, t));
            }
        }
        Ok(())
    }

    fn disconnect(&mut self) {
        if let Some((run, t)) = self.waker.take() {
            run.store(false, Ordering::Relaxed);
            let _ = t.join();
        }
        if let Some(mut b) = self.bridge.take() {
            b.shutdown();
        }
    }

    fn status(&self) -> DeviceStatus {
        let mut faults = Vec::new();
        let (name, connected, forces) = match &self.bridge {
            Some(b) => {
                if let Some(s) = b.stopped() {
                    faults.push(s.to_string());
                } else {
                    faults.extend(b.shared().notices(self.last_faults));
                    if let Some(l) = b.solver_link() {
                        if let Some(why) = l.refusal() {
                            faults.push(format!("the brush could not be built: {why}"));
                        } else if l.stale().0 {
                            faults.push(
                                "the brush's solver has fallen behind the servo loop: no \
                                 brush force until it catches up"
                                    .to_string(),
                            );
                        }
                    }
                }
                (
                    format!("Phantom ({})", b.lib().path().display()),
                    b.stopped().is_none(),
                    b.shared().forces_on(),
                )
            }
            None => ("Phantom (not connected)".to_string(), false, false),
        };
        if let Some(e) = &self.last_error {
            faults.push(e.clone());
        }
        DeviceStatus {
            name,
            connected,
            protocol_version: None,
            firmware_version: None,
            faults,
            frames_dropped: self
                .bridge
                .as_ref()
                .map(|b| b.shared().state_counts().1)
                .unwrap_or(0),
            ticks_late: 0,
            // The servo loop runs on the HD scheduler's clock (1 kHz by hdSetSchedulerRate).
            tick_period_ms: None,
            params: self.params,
            preset: self.preset.clone(),
            model: self.model,
            forces_enabled: forces,
            replaying: false,
            replays_done: 0,
            link: None,
            // The servo loop runs on the desktop, far inside its tick at any brush (its
            // benchmark: `cargo bench --bench servo`).
            tick_limits: TickLimits::NONE,
        }
    }

    fn poll(&mut self, out: &mut Vec<BrushFrame>) {
        if let Some(b) = &self.bridge {
            let shared = b.shared();
            while let Some((s, guide)) = shared.take_state_with_guide() {
                let frame = match s {
                    ServoState::Brush(s) => {
                        self.last_faults = s.faults;
                        Some(frame_from_state(&s, u64::from(s.tick), false))
                    }
                    ServoState::Hand(h) => {
                        self.last_faults = h.faults;
                        b.solver_link().and_then(|l| Self::hand_frame(l, &h))
                    }
                };
                if let Some(mut frame) = frame {
                    frame.guide = guide;
                    out.push(frame);
                }
            }
        }
    }

    fn send(&mut self, cmd: DeviceCommand) -> Result<(), DeviceError> {
        // Checked as the built-in simulator checks it, for the model in force.
        cmd.validate_for(self.model, &self.preset, &self.params)?;
        let rejected = DeviceError::Rejected;
        match cmd {
            // The stylus is the hand.
            DeviceCommand::Hand(_) | DeviceCommand::StopReplay => Ok(()),
            DeviceCommand::Model(m) => {
                if m == self.model {
                    return Ok(());
                }
                // The brush's parameters as they stand (as the built-in simulator does).
                let choice = BrushChoice::for_model(&self.preset, m).map_err(rejected)?;
                self.model = m;
                self.brush = choice;
                self.restart()
            }
            DeviceCommand::EnableForces(on) => self.servo(ServoCommand::EnableForces(on)),
            DeviceCommand::ClearFault => self.servo(ServoCommand::ClearFaults),
            DeviceCommand::Dip(w) => self.servo(ServoCommand::Dip(w)),
            DeviceCommand::Preset(name) => {
                let choice = BrushChoice::for_model(&name, self.model).map_err(rejected)?;
                // Another of Baxter & Lin's heads needs a new loop (its solver is built for
                // one head); otherwise the loop takes the parameters. Disconnected, the
                // next connection starts with them.
                let new_loop = self.model == ModelKind::BaxterLin
                    && choice.head_shape() != self.brush.head_shape();
                if self.bridge.is_some() && !new_loop {
                    self.servo(ServoCommand::SetParams(choice.params))?;
                }
                self.params = choice.params;
                self.preset = name;
                self.brush = choice;
                if new_loop {
                    self.restart()?;
                }
                Ok(())
            }
            DeviceCommand::SetParam(id, v) => {
                let mut p = self.params;
                p.set(id, v).map_err(|e| rejected(e.to_string()))?;
                self.servo(ServoCommand::SetParams(p))?;
                self.params = p;
                Ok(())
            }
            DeviceCommand::Replay(_) => Err(DeviceError::Rejected(
                "the Phantom is driven by its stylus; replay pose files on the built-in simulator"
                    .into(),
            )),
            DeviceCommand::Guide(Some(track)) => {
                // The moving point in the paper frame, one per servo tick (1 kHz).
                let points: GuidePoints = track.resample().map(|p| p.pos.cast::<Fx>()).collect();
                if points.is_empty() {
                    return Err(DeviceError::Rejected("the stroke is empty".into()));
                }
                self.servo(ServoCommand::Guide(Some(points)))
            }
            DeviceCommand::Guide(None) => self.servo(ServoCommand::Guide(None)),
            DeviceCommand::Lane(Some((track, radius_mm))) => {
                crate::device::api::check_lane_radius(radius_mm)?;
                let head = self.params.length_mm as f64;
                let pieces = crate::device::lane::pieces(&track, head);
                if pieces.is_empty() {
                    return Err(rejected(crate::device::api::LANE_NO_PATH.into()));
                }
                let lane = maobi_shared::guide::Lane::new(pieces, radius_mm);
                self.servo(ServoCommand::Lane(Some(Box::new(lane))))
            }
            DeviceCommand::Lane(None) => self.servo(ServoCommand::Lane(None)),
        }
    }
}

impl Drop for PhantomDevice {
    fn drop(&mut self) {
        self.disconnect();
    }
}

/// The built-in simulator standing in for a Phantom that could not be used, saying why in
/// the status bar (its name and its faults).
pub struct FallbackDevice {
    inner: Box<dyn Device>,
    why: String,
}

impl Device for FallbackDevice {
    fn connect(&mut self) -> Result<(), DeviceError> {
        self.inner.connect()
    }
    fn disconnect(&mut self) {
        self.inner.disconnect()
    }
    fn status(&self) -> DeviceStatus {
        let mut s = self.inner.status();
        s.name = format!("{} (Phantom unavailable, see faults)", s.name);
        s.faults.insert(0, self.why.clone());
        s
    }
    fn poll(&mut self, out: &mut Vec<BrushFrame>) {
        self.inner.poll(out)
    }
    fn journal(&self) -> Option<Journal> {
        self.inner.journal()
    }
    fn send(&mut self, cmd: DeviceCommand) -> Result<(), DeviceError> {
        self.inner.send(cmd)
    }
}

/// `maobi --device phantom`: the Phantom, connected; or, when libHD or the device cannot be
/// used, the built-in simulator with the reason in its status (also logged as a warning).
pub fn gui_device(
    hd_lib: Option<PathBuf>,
    model: ModelKind,
    brush: &str,
    hand: HandInput,
    wake: Option<Arc<dyn Fn() + Send + Sync>>,
) -> Result<Box<dyn Device>, DeviceError> {
    let mut d = PhantomDevice::with_model(hd_lib, model, brush, BridgeOptions::default())?;
    if let Some(w) = wake.clone() {
        d.on_frames(w);
    }
    match d.connect() {
        Ok(()) => Ok(Box::new(d)),
        Err(e) => {
            let why = format!("Phantom unavailable, using the built-in simulator: {e}");
            // A warning (shown by default): the app opens on the simulator, and whoever
            // launched it from a shell sees why the Phantom is not the one answering.
            log::warn!("{why}");
            let mut sim = SimDevice::with_model(SimClock::RealTime, model, brush, hand)?;
            if let Some(w) = wake {
                sim.on_frames(w);
            }
            Ok(Box::new(FallbackDevice {
                inner: Box::new(sim),
                why,
            }))
        }
    }
}
