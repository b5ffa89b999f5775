//! The built-in simulated device: a brush model in its 1 kHz loop ([`SimModel`]): Liang's
//! in the shared force loop (`ForceLoop<Fx>`, the pen's number type: brush, force model,
//! guide, output stage), or Baxter & Lin's with its local force model, ending in the same
//! guide and output stage.
//!
//! Two clocks:
//! * [`SimClock::RealTime`]: a background thread runs the ticks that are due by the wall
//!   clock, so the UI never waits on the model. If the thread falls more than
//!   [`MAX_BEHIND_TICKS`] behind it skips ahead and counts the ticks as late. Frames go to the
//!   GUI through a bounded queue; when it is full (a stalled UI) live frames are dropped and
//!   counted, but replay frames wait, so a replay's ink is always complete.
//! * [`SimClock::Stepped`]: no thread; each [`Device::poll`] runs a fixed number of ticks.
//!   Deterministic, for tests.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{self, Receiver, Sender, SyncSender, TrySendError};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use maobi_shared::force::PHANTOM_OMNI;
use maobi_shared::force_loop::Gate;
use maobi_shared::guide::DEFAULT_GUIDE;
use maobi_shared::params::TickLimits;
use maobi_shared::protocol::Faults;
use maobi_shared::{BrushParams, Pose, Quat};

use super::api::{BrushFrame, Device, DeviceCommand, DeviceError, DeviceStatus, HandInput};
use super::journal::{Journal, JournalEvent};
use super::model::{BrushChoice, ModelKind};
use super::sim_model::SimModel;

/// Fastest the simulated hand moves toward the pointer (mm per 1 ms tick, i.e. m/s).
pub const HAND_SPEED_MM_PER_TICK: f64 = 0.4;
/// Fraction of the remaining rotation toward the target tilt per tick.
pub const HAND_TURN_PER_TICK: f64 = 0.02;
/// Queue of frames between the model thread and the GUI (4 s at 1 kHz).
pub const FRAME_QUEUE: usize = 4096;
/// Ticks the real-time thread may fall behind before it skips ahead.
pub const MAX_BEHIND_TICKS: u64 = 100;

/// How the simulator keeps time.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub enum SimClock {
    RealTime,
    /// Each poll runs this many ticks.
    Stepped(usize),
}

/// The model and its inputs; no threads, no clock.
pub struct SimCore {
    /// The brush model in its loop: brush, forces, guide, output stage.
    model: Box<SimModel>,
    /// The forces switch, and the faults latched (a sensor jump) until cleared.
    enabled: bool,
    faults: Faults,
    preset: String,
    hand: Pose<f64>,
    target: HandInput,
    replay: Option<(Vec<Pose<f64>>, usize)>,
    replays_done: u64,
    tick: u64,
    /// Every pose and brush command since the start, for saving the session
    /// ([`super::journal`]). Shared so the GUI can read it while the model thread runs.
    journal: Arc<Mutex<Journal>>,
}

impl SimCore {
    /// The brush `preset`, hanging at rest at `hand`.
    pub fn new(preset: &str, hand: HandInput) -> Result<SimCore, DeviceError> {
        SimCore::with_model(ModelKind::Liang, preset, hand)
    }

    /// The brush `brush` of `model`, hanging at rest at `hand`.
    pub fn with_model(
        model: ModelKind,
        brush: &str,
        hand: HandInput,
    ) -> Result<SimCore, DeviceError> {
        let mut core = SimCore::of_model(model, brush, hand.pose())?;
        core.target = hand;
        Ok(core)
    }

    /// The brush `preset` (Liang's model), hanging at rest at `pose`; the hand's target is
    /// that pose.
    pub fn at_pose(preset: &str, pose: Pose<f64>) -> Result<SimCore, DeviceError> {
        SimCore::of_model(ModelKind::Liang, preset, pose)
    }

    /// The brush `brush` of `model`, hanging at rest at `pose`; the hand's target is that
    /// pose.
    pub fn of_model(
        model: ModelKind,
        brush: &str,
        pose: Pose<f64>,
    ) -> Result<SimCore, DeviceError> {
        let choice = BrushChoice::for_model(brush, model).map_err(DeviceError::Rejected)?;
        let params = choice.params;
        let sim = SimModel::new(model, &choice, params, pose, PHANTOM_OMNI, DEFAULT_GUIDE)?;
        let journal = Journal::new(brush, params, pose).with_model(model);
        Ok(SimCore {
            model: Box::new(sim),
            enabled: false,
            faults: Faults::empty(),
            preset: brush.to_string(),
            hand: pose,
            target: hand_at(pose),
            replay: None,
            replays_done: 0,
            tick: 0,
            journal: Arc::new(Mutex::new(journal)),
        })
    }

    /// The brush model this core runs.
    pub fn model(&self) -> ModelKind {
        self.model.kind()
    }

    /// The journal of this model (shared with the thread that runs it).
    pub fn journal(&self) -> Arc<Mutex<Journal>> {
        self.journal.clone()
    }

    /// Continues `journal` (a re-rendered session's) instead of this model's own.
    pub fn resume_journal(&mut self, journal: Journal) {
        if let Ok(mut j) = self.journal.lock() {
            *j = journal;
        }
    }

    fn note(&self, e: JournalEvent) {
        if let Ok(mut j) = self.journal.lock() {
            j.event(e);
        }
    }

    /// Replaces all parameters (validated by the model).
    pub fn set_params(&mut self, p: BrushParams) -> Result<(), DeviceError> {
        self.model.set_params(p, self.hand)
    }

    /// Carries out a journaled event again (re-rendering a session).
    pub fn replay_event(&mut self, e: &JournalEvent) -> Result<(), DeviceError> {
        match e {
            JournalEvent::Dip(w) => self.apply(DeviceCommand::Dip(*w)),
            JournalEvent::Param(id, v) => self.apply(DeviceCommand::SetParam(*id, *v)),
            JournalEvent::Preset(n) => self.apply(DeviceCommand::Preset(n.clone())),
            JournalEvent::Model(m) => self.apply(DeviceCommand::Model(*m)),
            JournalEvent::Reset(p) => {
                self.reset_at(*p);
                Ok(())
            }
        }
    }

    /// The brush at rest at `p`, the forces afresh; the next pose is not checked for a jump
    /// from the last.
    fn reset_at(&mut self, p: Pose<f64>) {
        self.model.reset_at(p);
        self.hand = p;
    }

    pub fn params(&self) -> &BrushParams {
        self.model.params()
    }

    /// The last tick run.
    pub fn tick(&self) -> u64 {
        self.tick
    }

    pub fn replaying(&self) -> bool {
        self.replay.is_some()
    }

    /// Carries out a command. Parameter changes are validated by the model itself; on error
    /// nothing changes.
    pub fn apply(&mut self, cmd: DeviceCommand) -> Result<(), DeviceError> {
        cmd.validate_for(self.model(), &self.preset, self.params())?;
        match cmd {
            DeviceCommand::Hand(h) => self.target = h,
            DeviceCommand::EnableForces(on) => self.enabled = on,
            DeviceCommand::ClearFault => self.faults = Faults::empty(),
            DeviceCommand::Dip(w) => {
                self.model.dip(w);
                self.note(JournalEvent::Dip(w));
            }
            DeviceCommand::Preset(name) => {
                let choice =
                    BrushChoice::for_model(&name, self.model()).map_err(DeviceError::Rejected)?;
                if let SimModel::BaxterLin { brush, .. } = &mut *self.model {
                    *brush = choice.clone();
                }
                self.model.set_params(choice.params, self.hand)?;
                self.note(JournalEvent::Preset(name.clone()));
                self.preset = name;
            }
            DeviceCommand::Model(kind) => {
                if kind != self.model() {
                    let choice = BrushChoice::for_model(&self.preset, kind)
                        .map_err(DeviceError::Rejected)?;
                    // The new model starts from the brush's parameters as they stand.
                    let params = *self.params();
                    *self.model = SimModel::new(
                        kind,
                        &choice,
                        params,
                        self.hand,
                        PHANTOM_OMNI,
                        DEFAULT_GUIDE,
                    )?;
                    self.note(JournalEvent::Model(kind));
                }
            }
            DeviceCommand::SetParam(id, v) => {
                self.model.set_param(id, v, self.hand)?;
                self.note(JournalEvent::Param(id, v));
            }
            DeviceCommand::Replay(track) => {
                let poses: Vec<Pose<f64>> = track.resample().collect();
                self.reset_at(poses[0]);
                self.note(JournalEvent::Reset(poses[0]));
                self.replay = Some((poses, 0));
            }
            DeviceCommand::StopReplay => self.end_replay(),
            DeviceCommand::Guide(Some(track)) => {
                let points: Vec<_> = track.resample().map(|p| p.pos).collect();
                if points.is_empty() {
                    return Err(DeviceError::Rejected("the stroke is empty".into()));
                }
                self.model.guide(points);
            }
            // Hold the point reached and fade out.
            DeviceCommand::Guide(None) => self.model.stop_guide(),
            DeviceCommand::Lane(Some((track, radius_mm))) => {
                let head = self.params().length_mm as f64;
                let pieces = super::lane::pieces(&track, head);
                if pieces.is_empty() {
                    return Err(DeviceError::Rejected(super::api::LANE_NO_PATH.into()));
                }
                self.model
                    .lane(maobi_shared::guide::Lane::new(pieces, radius_mm));
            }
            DeviceCommand::Lane(None) => self.model.stop_guide(),
        }
        Ok(())
    }

    fn end_replay(&mut self) {
        if self.replay.take().is_some() {
            self.replays_done += 1;
            // Hold where the replay left the hand until the GUI says otherwise.
            let p = self.hand.pos.to_f64();
            self.target = HandInput {
                x: p[0],
                y: p[1],
                z: p[2],
                ..self.target
            };
        }
    }

    /// Runs one 1 ms tick and returns the brush state after it.
    pub fn step(&mut self) -> BrushFrame {
        let replaying = self.replay.is_some();
        let pose = if let Some((poses, k)) = &mut self.replay {
            let p = poses[*k];
            *k += 1;
            if *k >= poses.len() {
                self.hand = p;
                self.end_replay();
            }
            p
        } else {
            let t = self.target.pose();
            let d = t.pos - self.hand.pos;
            let n = d.norm();
            let pos = if n > HAND_SPEED_MM_PER_TICK {
                self.hand.pos + d.scale(HAND_SPEED_MM_PER_TICK / n)
            } else {
                t.pos
            };
            let rot = Quat::nlerp(self.hand.rot, t.rot, HAND_TURN_PER_TICK);
            Pose::new(pos, rot)
        };
        self.run_tick(pose, replaying)
    }

    /// Runs one tick with the handle at `pose` (re-rendering a journal).
    pub fn step_at(&mut self, pose: Pose<f64>) -> BrushFrame {
        self.run_tick(pose, false)
    }

    fn run_tick(&mut self, pose: Pose<f64>, replaying: bool) -> BrushFrame {
        self.hand = pose;
        let out = self
            .model
            .tick(Some(pose), Gate::new(self.enabled, self.faults));
        self.faults |= out.faults;
        self.tick += 1;
        if let Ok(mut j) = self.journal.lock() {
            j.tick(self.tick, pose);
        }
        let output = self.model.output_state(self.enabled, self.faults);
        self.model.frame(self.tick, pose, out, output, replaying)
    }

    /// Guided writing is on (or fading out).
    pub fn guiding(&self) -> bool {
        self.model.guiding()
    }

    fn status(&self, name: &str, connected: bool) -> DeviceStatus {
        let faults = self
            .faults
            .iter_names()
            .map(|(n, _)| n.to_string())
            .collect();
        DeviceStatus {
            name: name.to_string(),
            connected,
            protocol_version: None,
            firmware_version: None,
            faults,
            frames_dropped: 0,
            ticks_late: 0,
            tick_period_ms: None,
            params: *self.params(),
            preset: self.preset.clone(),
            model: self.model(),
            forces_enabled: self.enabled,
            replaying: self.replay.is_some(),
            replays_done: self.replays_done,
            link: None,
            // The desktop keeps up with any brush or falls behind and says so (`ticks_late`).
            tick_limits: TickLimits::NONE,
        }
    }
}

/// A hand target at `pose`'s position, held straight (the GUI sends its own at once).
fn hand_at(pose: Pose<f64>) -> HandInput {
    let p = pose.pos.to_f64();
    HandInput {
        x: p[0],
        y: p[1],
        z: p[2],
        tilt_x_deg: 0.0,
        tilt_y_deg: 0.0,
    }
}

const NAME: &str = "built-in simulator";

struct Running {
    thread: JoinHandle<()>,
    stop: Arc<AtomicBool>,
    cmds: Sender<DeviceCommand>,
    frames: Receiver<BrushFrame>,
    status: Arc<Mutex<DeviceStatus>>,
}

/// The built-in simulator as a [`Device`].
pub struct SimDevice {
    clock: SimClock,
    /// The model and brush a new model starts with (as last chosen), and the ones in
    /// force, for validating commands before they are sent.
    model: ModelKind,
    preset: String,
    start_hand: HandInput,
    /// Stepped clock: the model itself. Real-time clock: kept while disconnected, moved
    /// into the thread while connected.
    core: Option<SimCore>,
    running: Option<Running>,
    /// Parameters as last reported, for validating commands before they are sent.
    params: BrushParams,
    /// Called by the model thread when it has new frames (e.g. to wake the UI).
    wake: Option<Arc<dyn Fn() + Send + Sync>>,
    /// The current model's journal (a new model starts a new one).
    journal: Arc<Mutex<Journal>>,
}

impl SimDevice {
    pub fn new(clock: SimClock, preset: &str, hand: HandInput) -> Result<SimDevice, DeviceError> {
        SimDevice::with_model(clock, ModelKind::Liang, preset, hand)
    }

    /// The simulator running the brush `brush` of `model`.
    pub fn with_model(
        clock: SimClock,
        model: ModelKind,
        brush: &str,
        hand: HandInput,
    ) -> Result<SimDevice, DeviceError> {
        let core = SimCore::with_model(model, brush, hand)?;
        Ok(SimDevice::from_core(clock, core))
    }

    /// The simulator continuing from `core` (e.g. a re-rendered session's model).
    pub fn from_core(clock: SimClock, core: SimCore) -> SimDevice {
        SimDevice {
            clock,
            model: core.model(),
            preset: core.preset.clone(),
            start_hand: hand_at(core.hand),
            params: *core.params(),
            journal: core.journal(),
            core: Some(core),
            running: None,
            wake: None,
        }
    }

    /// Calls `wake` from the model thread after each batch of ticks.
    pub fn on_frames(&mut self, wake: Arc<dyn Fn() + Send + Sync>) {
        self.wake = Some(wake);
    }
}

impl Device for SimDevice {
    fn connect(&mut self) -> Result<(), DeviceError> {
        if self.running.is_some() {
            return Ok(());
        }
        let core = match self.core.take() {
            Some(c) => c,
            None => SimCore::with_model(self.model, &self.preset, self.start_hand)?,
        };
        self.journal = core.journal();
        match self.clock {
            SimClock::Stepped(_) => {
                self.core = Some(core);
                // A stepped simulator is "connected" whenever it holds its core.
                self.running = None;
            }
            SimClock::RealTime => {
                let stop = Arc::new(AtomicBool::new(false));
                let (cmd_tx, cmd_rx) = mpsc::channel();
                let (frame_tx, frame_rx) = mpsc::sync_channel(FRAME_QUEUE);
                let status = Arc::new(Mutex::new(core.status(NAME, true)));
                let thread = {
                    let stop = stop.clone();
                    let status = status.clone();
                    let wake = self.wake.clone();
                    std::thread::Builder::new()
                        .name("maobi-sim".into())
                        .spawn(move || run_thread(core, stop, cmd_rx, frame_tx, status, wake))
                        .map_err(|e| {
                            DeviceError::Link(format!("cannot start the model thread: {e}"))
                        })?
                };
                self.running = Some(Running {
                    thread,
                    stop,
                    cmds: cmd_tx,
                    frames: frame_rx,
                    status,
                });
            }
        }
        self.connected_flag(true);
        Ok(())
    }

    fn disconnect(&mut self) {
        if let Some(r) = self.running.take() {
            r.stop.store(true, Ordering::Relaxed);
            // Unblock a thread waiting to hand over a replay frame.
            drop(r.frames);
            let _ = r.thread.join();
        }
        self.core = None;
        self.connected_flag(false);
    }

    fn status(&self) -> DeviceStatus {
        if let Some(r) = &self.running {
            return r
                .status
                .lock()
                .map(|s| s.clone())
                .unwrap_or_else(|p| p.into_inner().clone());
        }
        match &self.core {
            Some(c) => c.status(NAME, true),
            None => {
                let mut s = SimCore::with_model(self.model, &self.preset, self.start_hand)
                    .map(|c| c.status(NAME, false))
                    .expect("the preset was valid at start");
                s.params = self.params;
                s
            }
        }
    }

    fn poll(&mut self, out: &mut Vec<BrushFrame>) {
        if let Some(r) = &self.running {
            out.extend(r.frames.try_iter());
            if let Ok(s) = r.status.lock() {
                self.params = s.params;
            }
        } else if let (Some(core), SimClock::Stepped(n)) = (&mut self.core, self.clock) {
            for _ in 0..n {
                out.push(core.step());
            }
            self.params = *core.params();
        }
    }

    fn journal(&self) -> Option<Journal> {
        let j = self.journal.lock().ok()?;
        Some(j.clone())
    }

    fn send(&mut self, cmd: DeviceCommand) -> Result<(), DeviceError> {
        cmd.validate_for(self.model, &self.preset, &self.params)?;
        // Keep the local copies current so the next validation sees this change (the
        // next model started, on a reconnect, has the model and brush last chosen).
        match &cmd {
            DeviceCommand::Model(m) => self.model = *m,
            DeviceCommand::Preset(name) => {
                self.preset = name.clone();
                if let Ok(b) = BrushChoice::parse(name) {
                    self.params = b.params;
                }
            }
            _ => {}
        }
        if let Some(r) = &self.running {
            if let DeviceCommand::SetParam(id, v) = cmd {
                let _ = self.params.set(id, v);
            }
            r.cmds
                .send(cmd)
                .map_err(|_| DeviceError::Link("the model thread has stopped".into()))
        } else if let Some(core) = &mut self.core {
            let r = core.apply(cmd);
            self.params = *core.params();
            self.model = core.model();
            self.preset = core.preset.clone();
            r
        } else {
            Err(DeviceError::NotConnected)
        }
    }
}

impl SimDevice {
    fn connected_flag(&mut self, _connected: bool) {
        if let Some(c) = &self.core {
            self.params = *c.params();
        }
    }
}

impl Drop for SimDevice {
    fn drop(&mut self) {
        self.disconnect();
    }
}

fn run_thread(
    mut core: SimCore,
    stop: Arc<AtomicBool>,
    cmds: Receiver<DeviceCommand>,
    frames: SyncSender<BrushFrame>,
    status: Arc<Mutex<DeviceStatus>>,
    wake: Option<Arc<dyn Fn() + Send + Sync>>,
) {
    let start = Instant::now();
    let mut done: u64 = 0;
    let mut dropped: u64 = 0;
    let mut late: u64 = 0;
    let mut last_error: Option<String> = None;
    // Tick period: wall time over ticks run, per window of about a second.
    let mut window = (Instant::now(), 0u64);
    let mut period_ms: Option<f64> = None;
    'run: while !stop.load(Ordering::Relaxed) {
        for cmd in cmds.try_iter() {
            if let Err(e) = core.apply(cmd) {
                last_error = Some(e.to_string());
            }
        }
        let due = start.elapsed().as_micros() as u64 / 1000 + 1;
        if due > done + MAX_BEHIND_TICKS {
            late += due - done - MAX_BEHIND_TICKS;
            done = due - MAX_BEHIND_TICKS;
        }
        while done < due {
            let frame = core.step();
            done += 1;
            window.1 += 1;
            if frame.replaying {
                if frames.send(frame).is_err() {
                    break 'run;
                }
            } else {
                match frames.try_send(frame) {
                    Ok(()) => {}
                    Err(TrySendError::Full(_)) => dropped += 1,
                    Err(TrySendError::Disconnected(_)) => break 'run,
                }
            }
            if stop.load(Ordering::Relaxed) {
                break 'run;
            }
        }
        let w = window.0.elapsed();
        if w >= Duration::from_secs(1) {
            period_ms = (window.1 > 0).then(|| w.as_secs_f64() * 1e3 / window.1 as f64);
            window = (Instant::now(), 0);
        }
        if let Ok(mut s) = status.lock() {
            *s = core.status(NAME, true);
            s.frames_dropped = dropped;
            s.ticks_late = late;
            s.tick_period_ms = period_ms;
            if let Some(e) = &last_error {
                s.faults.push(format!("last command failed: {e}"));
            }
        }
        if let Some(w) = &wake {
            w();
        }
        std::thread::sleep(Duration::from_millis(1));
    }
}
