//! The application: panels, controls, and the per-frame loop (poll the device, ink its
//! frames, draw, send the hand).

use std::collections::VecDeque;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::Context as _;
use egui::{Color32, RichText};
use maobi_shared::force::OutputState;
use maobi_shared::{presets, ParamId};

use super::brush_view::{self, Orbit};
use super::canvas::PaperView;
use super::choice::{make_device, start_hand, DeviceChoice};
use super::files::{DeviceKind, DialogRequest, FileKind, Purpose, Recent, RunningDialog, Settings};
use super::rerender::{rerender, Rerender};
use super::session::{CanvasOp, InkLog, Session};
use super::timeline::{Timeline, TimelineAction};
use super::writing::{brush_mark, draw_grid, draw_mark, BrushMark, Face, Grid};
use crate::device::model::HEAD_NAMES;
use crate::device::{
    serial_ports, BrushChoice, BrushFrame, Device, DeviceCommand, DeviceStatus, Endpoint,
    HandInput, ModelKind, PortInfo, SimClock, SimDevice,
};
use crate::paper::{PaperKind, PaperSpec};
use crate::poses::PoseTrack;
use crate::raster::Frame;
use crate::render::write_png;
use crate::tablet::{PressureCurve, Tablet, TabletInfo, TabletStatus};

/// Seconds of history in the live plots.
const PLOT_SECONDS: f64 = 5.0;
/// Side of the writing view's brush view (points).
const BRUSH_VIEW_PT: f32 = 240.0;
/// Ferrule height above the brush length while the pen is up (mm).
const HOVER_MM: f64 = 6.0;

/// What the automation (`--replay`, `--screenshot`) should do.
#[derive(Clone, Debug, Default)]
pub struct Automation {
    /// Replay this pose file at start.
    pub replay: Option<PathBuf>,
    /// After the replay (or the first frames, without one), save a screenshot here and exit.
    pub screenshot: Option<PathBuf>,
    /// Open this session at start (the screenshot waits for its re-render).
    pub session: Option<PathBuf>,
    /// Practise this character at start: the panel open, the master loaded; the replay (if
    /// any) starts once it is, recorded as the attempt and scored; the screenshot waits for
    /// the score.
    pub practice: Option<String>,
    /// Keep the views' rectangles and the face in this file, rewritten when they change
    /// ([`LAYOUT_ENV`]): how a driver of the real window (xdotool in CI) finds the paper and
    /// the controls. It drives nothing itself, so it does not make the run an automated one.
    pub layout: Option<PathBuf>,
}

/// Environment variable naming the file [`Automation::layout`] keeps.
pub const LAYOUT_ENV: &str = "MAOBI_LAYOUT";

impl Automation {
    /// Something at start drives the app (a replay, a screenshot, a session).
    pub fn is_active(&self) -> bool {
        self.replay.is_some() || self.screenshot.is_some() || self.session.is_some()
    }
}

/// How the run ended, for the process's exit code and the summary on stderr.
#[derive(Clone, Debug, Default)]
pub struct Outcome {
    pub error: Option<String>,
    pub summary: Vec<String>,
}

#[derive(Debug)]
enum Shot {
    /// Waiting for the replay to finish (counts frames since it did).
    Waiting(u32),
    Requested(Arc<Mutex<Option<Arc<egui::ColorImage>>>>, Instant),
    Done,
}

/// Frame-time samples (ms).
#[derive(Default)]
struct FrameTimes {
    last: Option<Instant>,
    /// Interval between frames while the brush was drawing from a replay.
    replay_interval: Vec<f64>,
    /// Time spent in `ui` (inking, uploading and building the UI) during the replay.
    replay_ui: Vec<f64>,
    recent: VecDeque<[f64; 2]>,
    /// Start of the UI frame before this one.
    prev_begin: Option<Instant>,
    /// Per UI frame that inked: age (ms) of its oldest frame when its ink was uploaded.
    ink_latency: Vec<f64>,
    /// Oldest frame inked in this UI frame (its arrival on the host).
    oldest_inked: Option<Instant>,
    /// Frames that had arrived before the previous UI frame began, i.e. waited more than
    /// one frame for their ink.
    late_inks: u64,
}

/// Latency from a frame's arrival on the host to its ink uploaded for the screen.
#[derive(Clone, Debug, Default)]
pub struct InkLatency {
    /// UI frames that inked something.
    pub frames: usize,
    pub median_ms: f64,
    pub p99_ms: f64,
    pub max_ms: f64,
    /// Device frames that waited past the next UI frame (the goal: none).
    pub late: u64,
}

fn percentile(v: &[f64], p: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let i = ((s.len() - 1) as f64 * p).round() as usize;
    s[i]
}

/// Recording of the pose stream, in the `maobi trace` pose CSV format.
struct Recorder {
    path: PathBuf,
    first_tick: u64,
    rows: Vec<(u64, maobi_shared::Pose<f64>)>,
}

pub struct MaobiApp {
    device: Box<dyn Device>,
    status: DeviceStatus,
    paper: PaperView,
    orbit: Orbit,
    scratch: Vec<BrushFrame>,
    latest: Option<BrushFrame>,
    started: Instant,
    /// Hand control.
    hand: HandInput,
    /// How far the ferrule goes below the brush length when the pen is pressed (mm).
    press_mm: f64,
    pen_down: bool,
    /// Pen pressure in [0, 1] from a touch/pen device, when it reports one.
    pressure: Option<f32>,
    /// A pen tablet in use (its pressure and tilt drive the hand), what it last reported,
    /// and the curve from its pressure to the brush's depth.
    tablet: Option<Tablet>,
    tablet_status: Option<TabletStatus>,
    pressure_curve: PressureCurve,
    /// Pen tablets found on this machine, and the path in the chooser's field.
    tablets: Vec<TabletInfo>,
    tablet_path: String,
    /// Model ticks the device delivered this UI frame: the clock a tablet recording plays on.
    frame_ticks: usize,
    /// Files recently opened and saved, per kind.
    recent: Recent,
    /// Live plot data: [t s, value].
    normal_n: VecDeque<[f64; 2]>,
    depth_mm: VecDeque<[f64; 2]>,
    tick_period_ms: VecDeque<[f64; 2]>,
    /// Device frames received per second, and the window being counted (start s, frames).
    frame_rate: VecDeque<[f64; 2]>,
    rate_window: (f64, u64),
    times: FrameTimes,
    /// The values shown in the parameter editors.
    param_edit: Vec<f32>,
    /// Last parameter change's result: (message, is an error).
    param_msg: Option<(String, bool)>,
    /// Last general message.
    message: Option<(String, bool)>,
    save_path: String,
    record_path: String,
    replay_path: String,
    recorder: Option<Recorder>,
    automation: Automation,
    shot: Option<Shot>,
    replay_started: bool,
    /// Whether the automation's practice character was loaded.
    practice_started: bool,
    outcome: Arc<Mutex<Outcome>>,
    /// Frames seen from replays.
    replay_frames: u64,
    /// Screen rectangle of the brush view in the last frame.
    brush_rect: egui::Rect,
    /// Device chooser: the kind (built-in simulator, TCP, serial) and the address.
    device_kind: DeviceKind,
    device_addr: String,
    /// Serial ports found, Maobi's USB IDs first.
    serial_ports: Vec<PortInfo>,
    /// A running search for the pen among the serial ports (handshake on each).
    probe: Option<Arc<Mutex<Option<ProbeResults>>>>,
    /// Preset a newly chosen device starts with.
    /// Why the replay under way leaves no ink, if it cannot ([`Self::start_replay`]).
    replay_warning: Option<String>,
    brush_name: String,
    /// The model a newly chosen built-in simulator runs (as last chosen).
    model_choice: ModelKind,
    /// Wetness a dip leaves the brush with (0..=1).
    ink_load: f32,
    /// The stroke editor (keyframed strokes on a timeline) and whether it is shown.
    timeline: Timeline,
    show_timeline: bool,
    /// Copying a master's character: the panel, the master, the attempt and its score.
    practice: super::practice::Practice,
    /// Where the fonts come from, and the outcome of setting them up (on the first frame,
    /// when there is a context).
    font_source: super::fonts::FontSource,
    fonts: Option<Result<(), String>>,
    /// The paper's history for the session file (inked ticks, undo, clear).
    ink_log: InkLog,
    session_path: String,
    /// A session being re-rendered in the background: its path and the result slot.
    opening: Option<(PathBuf, RerenderSlot)>,
    /// The clock of the simulator an opened session continues on.
    session_clock: SimClock,
    /// Which face the app shows, the writing view's grid, and whether it shows the brush.
    face: Face,
    grid: Grid,
    show_brush_view: bool,
    /// What the paper view drew for the brush in the last frame.
    mark: Option<BrushMark>,
    /// Screen rectangle of the first parameter's editor in the last frame (the laboratory).
    param_rect: egui::Rect,
    /// The layout last written to [`Automation::layout`].
    layout_written: String,
    /// The About window is open.
    show_about: bool,
    /// A file dialog this frame asked for, and the one on screen ([`super::files`]).
    dialog_request: Option<DialogRequest>,
    dialog: Option<RunningDialog>,
}

/// Where a background re-render leaves its result.
type RerenderSlot = Arc<Mutex<Option<anyhow::Result<Rerender>>>>;

/// Serial ports and what answered on each (the board, or why not).
type ProbeResults = Vec<(String, Result<String, String>)>;

impl MaobiApp {
    /// The app over `device` (connected here), with a paper of `paper` mapped by `frame`.
    pub fn new(
        mut device: Box<dyn Device>,
        frame: Frame,
        automation: Automation,
        outcome: Arc<Mutex<Outcome>>,
    ) -> MaobiApp {
        let connect_msg = device
            .connect()
            .err()
            .map(|e| (format!("cannot connect: {e}"), true));
        let status = device.status();
        let len = status.params.length_mm as f64;
        let cx = frame.x0_mm + frame.width as f64 / frame.px_per_mm * 0.5;
        let cy = frame.y_top_mm - frame.height as f64 / frame.px_per_mm * 0.5;
        let param_edit = ParamId::ALL.iter().map(|&p| status.params.get(p)).collect();
        let shot = automation.screenshot.as_ref().map(|_| Shot::Waiting(0));
        MaobiApp {
            device,
            paper: PaperView::new(frame, PaperSpec::default()),
            orbit: Orbit::default(),
            scratch: Vec::new(),
            latest: None,
            started: Instant::now(),
            hand: HandInput {
                x: cx,
                y: cy,
                z: len + HOVER_MM,
                tilt_x_deg: 0.0,
                tilt_y_deg: 0.0,
            },
            press_mm: (len * 0.25).clamp(1.0, 20.0),
            pen_down: false,
            pressure: None,
            tablet: None,
            tablet_status: None,
            pressure_curve: PressureCurve::default(),
            tablets: Vec::new(),
            tablet_path: String::new(),
            frame_ticks: 0,
            recent: Recent::default(),
            normal_n: VecDeque::new(),
            depth_mm: VecDeque::new(),
            tick_period_ms: VecDeque::new(),
            frame_rate: VecDeque::new(),
            rate_window: (0.0, 0),
            times: FrameTimes::default(),
            param_edit,
            param_msg: None,
            message: connect_msg,
            save_path: "out/maobi-canvas.png".into(),
            record_path: "out/maobi-recording.csv".into(),
            replay_path: automation
                .replay
                .as_ref()
                .map(|p| p.display().to_string())
                .unwrap_or_else(|| "examples/poses/hook.csv".into()),
            recorder: None,
            shot,
            automation,
            replay_started: false,
            practice_started: false,
            outcome,
            status,
            replay_frames: 0,
            brush_rect: egui::Rect::NOTHING,
            device_kind: DeviceKind::Sim,
            device_addr: "127.0.0.1:7878".into(),
            serial_ports: Vec::new(),
            probe: None,
            replay_warning: None,
            brush_name: "large".into(),
            model_choice: ModelKind::Liang,
            ink_load: 1.0,
            timeline: Timeline::default(),
            show_timeline: false,
            practice: Default::default(),
            font_source: Default::default(),
            fonts: None,
            ink_log: InkLog::default(),
            session_path: "out/maobi-session.maobi.toml".into(),
            opening: None,
            session_clock: SimClock::RealTime,
            face: Face::default(),
            grid: Grid::default(),
            show_brush_view: true,
            mark: None,
            param_rect: egui::Rect::NOTHING,
            layout_written: String::new(),
            show_about: false,
            dialog_request: None,
            dialog: None,
        }
    }

    /// Which face the app shows.
    pub fn face(&self) -> Face {
        self.face
    }

    /// Shows `face` (the laboratory or the writing view).
    pub fn set_face(&mut self, face: Face) {
        self.face = face;
    }

    /// The grid drawn over the paper.
    pub fn set_grid(&mut self, grid: Grid) {
        self.grid = grid;
    }

    /// What the paper view drew for the brush in the last frame: its hover ring or its
    /// footprint (see [`super::writing`]).
    pub fn brush_mark(&self) -> Option<&BrushMark> {
        self.mark.as_ref()
    }

    /// Where Ctrl+S saves the picture.
    pub fn set_picture_path(&mut self, path: &Path) {
        self.save_path = path.display().to_string();
    }

    /// The app drawing its text with the fonts of `source` (tests fix them, so that the
    /// glyphs do not depend on the machine).
    pub fn with_fonts(mut self, source: super::fonts::FontSource) -> MaobiApp {
        self.font_source = source;
        self.fonts = None;
        self
    }

    /// The clock of the simulator an opened session continues on (tests use a stepped one).
    pub fn set_session_clock(&mut self, clock: SimClock) {
        self.session_clock = clock;
    }

    /// A new device (or a new model on the same one) starts a new journal: ink already on
    /// the paper is not part of the new session.
    fn restart_ink_log(&mut self) {
        self.ink_log = InkLog {
            foreign: self.paper.canvas().ink_area_px() > 0.0 || self.paper.undo_depth() > 0,
            ..InkLog::default()
        };
    }

    /// The session so far: the device's journal and the paper's history.
    pub fn session(&self) -> anyhow::Result<Session> {
        let journal = self.device.journal().ok_or_else(|| {
            anyhow::anyhow!(
                "{} keeps no session journal (only the built-in simulator does); \
                 use Record poses to keep its pose stream",
                self.status.name
            )
        })?;
        Ok(Session {
            device: self.status.name.clone(),
            journal,
            paper: *self.paper.frame(),
            paper_spec: self.paper.paper(),
            ink: self.ink_log.clone(),
            model: Some(super::session::MODEL_VERSION),
        })
    }

    /// Saves the session (see [`super::session`] for the format); returns its ticks.
    pub fn save_session(&mut self, path: &Path) -> anyhow::Result<u64> {
        let s = self.session()?;
        s.save(path)?;
        Ok(s.journal.ticks)
    }

    /// Starts re-rendering a session file in the background; [`Self::opening_session`]
    /// says whether it is still running. When it is done the paper shows the session and
    /// the built-in simulator continues from where it ended.
    pub fn open_session(&mut self, path: &Path, ctx: Option<&egui::Context>) {
        let slot = Arc::new(Mutex::new(None));
        let s2 = slot.clone();
        let p = path.to_path_buf();
        let ctx = ctx.cloned();
        let spawned = std::thread::Builder::new()
            .name("maobi-session".into())
            .spawn(move || {
                let r = Session::load(&p).and_then(|s| rerender(&s, |_| {}));
                if let Ok(mut s) = s2.lock() {
                    *s = Some(r);
                }
                if let Some(c) = ctx {
                    c.request_repaint();
                }
            });
        match spawned {
            Ok(_) => {
                self.message = Some((format!("opening {}", path.display()), false));
                self.opening = Some((path.to_path_buf(), slot));
            }
            Err(e) => self.message = Some((format!("cannot start the re-render: {e}"), true)),
        }
    }

    pub fn opening_session(&self) -> bool {
        self.opening.is_some()
    }

    /// Takes an opened session in when its re-render is done.
    fn finish_open(&mut self, ctx: &egui::Context) {
        let Some((path, slot)) = &self.opening else {
            return;
        };
        let done = slot.lock().ok().and_then(|mut s| s.take());
        let Some(result) = done else {
            ctx.request_repaint_after(Duration::from_millis(50));
            return;
        };
        let path = path.clone();
        self.opening = None;
        match result {
            Err(e) => {
                let msg = format!("cannot open {}: {e:#}", path.display());
                if self.automation.screenshot.is_some() {
                    // Unattended: the run fails rather than screenshot the wrong paper.
                    self.fail(ctx, msg.clone());
                }
                self.message = Some((msg, true));
            }
            Ok(r) => {
                let ticks = r.core.tick();
                let mut d = SimDevice::from_core(self.session_clock, r.core);
                let c2 = ctx.clone();
                d.on_frames(Arc::new(move || c2.request_repaint()));
                self.device.disconnect();
                let connected = d.connect();
                self.device = Box::new(d);
                self.status = self.device.status();
                self.latest = None;
                self.device_kind = DeviceKind::Sim;
                self.paper = r.paper;
                self.ink_log = r.ink;
                self.param_edit = ParamId::ALL
                    .iter()
                    .map(|&p| self.status.params.get(p))
                    .collect();
                let note = r
                    .model_note
                    .map_or(String::new(), |n| format!(". Note: {n}"));
                self.message = Some(match connected {
                    Ok(()) => (
                        format!(
                            "opened {}: {ticks} ticks re-rendered; the built-in simulator goes on from there{note}",
                            path.display()
                        ),
                        false,
                    ),
                    Err(e) => (format!("opened {}, but: {e}", path.display()), true),
                });
            }
        }
    }

    /// Shows `choice` in the device chooser; `brush` is the preset a newly chosen device
    /// starts with, `model` the model a newly chosen simulator runs.
    pub fn set_device_choice(&mut self, choice: &DeviceChoice, brush: &str, model: ModelKind) {
        self.brush_name = brush.to_string();
        self.model_choice = model;
        match choice {
            DeviceChoice::Sim => self.device_kind = DeviceKind::Sim,
            DeviceChoice::Link(Endpoint::Tcp(a)) => {
                self.device_kind = DeviceKind::Tcp;
                self.device_addr = a.clone();
            }
            DeviceChoice::Link(Endpoint::Serial(p)) => {
                self.device_kind = DeviceKind::Serial;
                self.device_addr = p.clone();
            }
        }
    }

    /// Shows the Phantom in the device chooser (`maobi --device phantom`); `hd_lib` is the
    /// library given on the command line, if any.
    pub fn choose_phantom(&mut self, hd_lib: Option<&Path>) {
        self.device_kind = DeviceKind::Phantom;
        self.device_addr = hd_lib.map(|p| p.display().to_string()).unwrap_or_default();
    }

    /// Replaces the device with the chooser's choice and connects it; the paper is kept.
    pub fn switch_device(&mut self, ctx: &egui::Context) {
        if self.device_kind == DeviceKind::Phantom {
            let c2 = ctx.clone();
            let wake: Arc<dyn Fn() + Send + Sync> = Arc::new(move || c2.request_repaint());
            let lib = self.device_addr.trim();
            let lib = (!lib.is_empty()).then(|| PathBuf::from(lib));
            let len = crate::device::BrushChoice::parse(&self.brush_name)
                .map_or(50.0, |b| b.params.length_mm as f64);
            // Connects, or falls back to the simulator with the reason in the status.
            match crate::phantom::device::gui_device(
                lib,
                self.model_choice,
                &self.brush_name,
                start_hand(len),
                Some(wake),
            ) {
                Ok(d) => {
                    self.device.disconnect();
                    self.device = d;
                    self.status = self.device.status();
                    self.message = Some((format!("device: {}", self.status.name), false));
                    self.latest = None;
                    self.restart_ink_log();
                }
                Err(e) => self.message = Some((format!("cannot use the Phantom: {e}"), true)),
            }
            return;
        }
        let choice = match self.device_kind {
            // (The Phantom returned above.)
            DeviceKind::Sim | DeviceKind::Phantom => Ok(DeviceChoice::Sim),
            DeviceKind::Tcp => format!("tcp:{}", self.device_addr.trim()).parse(),
            DeviceKind::Serial => format!("serial:{}", self.device_addr.trim()).parse(),
        };
        let choice = match choice {
            Ok(c) => c,
            Err(e) => {
                self.message = Some((e, true));
                return;
            }
        };
        let c2 = ctx.clone();
        let wake: Arc<dyn Fn() + Send + Sync> = Arc::new(move || c2.request_repaint());
        match make_device(&choice, &self.brush_name, self.model_choice, Some(wake)) {
            Ok(mut d) => {
                self.device.disconnect();
                self.message = Some(match d.connect() {
                    Ok(()) => (format!("connected to {choice}"), false),
                    Err(e) => (format!("cannot connect: {e}"), true),
                });
                self.device = d;
                self.status = self.device.status();
                self.latest = None;
                self.restart_ink_log();
            }
            Err(e) => self.message = Some((format!("cannot use {choice}: {e}"), true)),
        }
    }

    pub fn paper(&self) -> &PaperView {
        &self.paper
    }
    pub fn status(&self) -> &DeviceStatus {
        &self.status
    }
    pub fn latest(&self) -> Option<&BrushFrame> {
        self.latest.as_ref()
    }
    pub fn replay_frames(&self) -> u64 {
        self.replay_frames
    }

    pub fn timeline(&self) -> &Timeline {
        &self.timeline
    }
    pub fn timeline_mut(&mut self) -> &mut Timeline {
        &mut self.timeline
    }
    /// Shows or hides the stroke editor.
    pub fn show_timeline(&mut self, on: bool) {
        self.show_timeline = on;
    }

    /// Carries out what the stroke editor asked for.
    pub fn timeline_action(&mut self, a: TimelineAction) {
        if let TimelineAction::ChooseFile { save, current } = &a {
            let purpose = if *save {
                Purpose::Save(FileKind::Stroke)
            } else {
                Purpose::Open(FileKind::Stroke)
            };
            self.ask_file(purpose, current);
            return;
        }
        if let TimelineAction::Play(t) | TimelineAction::Guide(t) = &a {
            if let Some(mut w) = self.never_reaches_paper(t) {
                if let Some(c) = self.timeline.character() {
                    w += &format!("; {}", c.placement_note());
                }
                self.timeline.message = Some((w, true));
            }
        }
        let (cmd, what) = match a {
            TimelineAction::Play(t) => (DeviceCommand::Replay(Arc::new(t)), "play"),
            TimelineAction::Pause => (DeviceCommand::StopReplay, "pause"),
            TimelineAction::Guide(t) => (DeviceCommand::Guide(Some(Arc::new(t))), "guide"),
            TimelineAction::StopGuide => (DeviceCommand::Guide(None), "stop guiding"),
            TimelineAction::ChooseFile { .. } => return,
        };
        if let Err(e) = self.device.send(cmd) {
            self.timeline.message = Some((format!("cannot {what}: {e}"), true));
        }
    }

    /// The practice panel's state.
    pub fn practice(&self) -> &super::practice::Practice {
        &self.practice
    }

    pub fn practice_mut(&mut self) -> &mut super::practice::Practice {
        &mut self.practice
    }

    /// Carries out what the practice panel asked of the device.
    pub fn practice_action(&mut self, a: super::practice::PracticeAction) {
        use super::practice::PracticeAction as A;
        let (cmd, what) = match a {
            A::Watch(t) => (DeviceCommand::Replay(t), "watch"),
            A::Guide(t) => (DeviceCommand::Guide(Some(t)), "guide"),
            A::StopGuide => (DeviceCommand::Guide(None), "stop guiding"),
            A::Lane(t, r) => (DeviceCommand::Lane(Some((t, r))), "keep the lane"),
            A::StopLane => (DeviceCommand::Lane(None), "leave the lane"),
            A::Clear => {
                self.clear();
                return;
            }
        };
        if let Err(e) = self.device.send(cmd) {
            self.practice.lane_on = false;
            self.practice.message = Some((format!("cannot {what}: {e}"), true));
        }
    }

    /// Arrival-to-ink latency so far.
    pub fn ink_latency(&self) -> InkLatency {
        let v = &self.times.ink_latency;
        InkLatency {
            frames: v.len(),
            median_ms: percentile(v, 0.5),
            p99_ms: percentile(v, 0.99),
            max_ms: v.iter().copied().fold(0.0, f64::max),
            late: self.times.late_inks,
        }
    }

    /// Starts replaying a pose file through the device.
    pub fn start_replay(&mut self, path: &Path) -> anyhow::Result<()> {
        let track = PoseTrack::from_path(path)?;
        let warning = self.never_reaches_paper(&track);
        self.device
            .send(DeviceCommand::Replay(Arc::new(track)))
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        self.message = Some(match &warning {
            Some(w) => (format!("replaying {}: {w}", path.display()), true),
            None => (format!("replaying {}", path.display()), false),
        });
        // Said again when the replay ends, over the "replay finished" that replaces this.
        self.replay_warning = warning;
        Ok(())
    }

    /// [`PoseTrack::never_reaches_paper`] for the brush the device runs now.
    fn never_reaches_paper(&self, track: &PoseTrack) -> Option<String> {
        let choice = crate::device::BrushChoice::parse(&self.status.preset).ok()?;
        let hair = choice.hair_length_mm(self.status.model, &self.status.params);
        track.never_reaches_paper(hair, &self.status.preset)
    }

    /// Sets a parameter on the device; the message shows what happened.
    pub fn set_param(&mut self, id: ParamId, value: f32) {
        match self.device.send(DeviceCommand::SetParam(id, value)) {
            Ok(()) => self.param_msg = Some((format!("{} = {value}", id.name()), false)),
            Err(e) => {
                self.param_msg = Some((format!("{} rejected: {e}", id.name()), true));
            }
        }
    }

    /// Starts recording the pose stream to `path` (written by [`Self::stop_recording`]).
    pub fn start_recording(&mut self, path: &Path) {
        self.recorder = Some(Recorder {
            path: path.to_path_buf(),
            first_tick: 0,
            rows: Vec::new(),
        });
    }

    /// Writes the recording; returns the number of poses.
    pub fn stop_recording(&mut self) -> anyhow::Result<usize> {
        let r = self
            .recorder
            .take()
            .ok_or_else(|| anyhow::anyhow!("not recording"))?;
        write_recording(&r)
    }

    pub fn undo(&mut self) -> bool {
        let undone = self.paper.undo();
        if undone {
            self.ink_log.op(CanvasOp::Undo);
        }
        undone
    }
    pub fn clear(&mut self) {
        self.paper.clear();
        self.ink_log.op(CanvasOp::Clear);
    }

    /// A fresh sheet of `kind`, blank and with nothing to undo. The paper's history starts
    /// again with it (a session holds one paper), while the device's journal goes on.
    pub fn set_paper(&mut self, kind: PaperKind) {
        if kind == self.paper.paper().kind {
            return;
        }
        self.paper.set_paper(PaperSpec::new(kind));
        self.restart_ink_log();
        self.message = Some((format!("paper: {kind} (a fresh sheet)"), false));
    }

    /// Polls the device and inks what arrived.
    fn pump(&mut self) {
        let mut frames = std::mem::take(&mut self.scratch);
        frames.clear();
        self.device.poll(&mut frames);
        self.frame_ticks = frames.len();
        let was_replaying = self.status.replaying;
        self.status = self.device.status();
        let t_now = self.started.elapsed().as_secs_f64();
        let n = frames.len().max(1) as f64;
        self.times.oldest_inked = frames.iter().map(|f| f.received).min();
        if let Some(prev) = self.times.prev_begin {
            self.times.late_inks += frames.iter().filter(|f| f.received < prev).count() as u64;
        }
        self.rate_window.1 += frames.len() as u64;
        if t_now - self.rate_window.0 >= 0.5 {
            let rate = self.rate_window.1 as f64 / (t_now - self.rate_window.0);
            push(&mut self.frame_rate, [t_now, rate]);
            self.rate_window = (t_now, 0);
        }
        if let Some(p) = self.status.tick_period_ms {
            push(&mut self.tick_period_ms, [t_now, p]);
        }
        for (i, f) in frames.iter().enumerate() {
            self.paper.ink(f);
            self.practice.frame(f.tick, f.pose);
            self.ink_log.inked(f.tick);
            if f.replaying {
                self.replay_frames += 1;
            }
            if let Some(r) = &mut self.recorder {
                if r.rows.is_empty() {
                    r.first_tick = f.tick;
                }
                r.rows.push((f.tick, f.pose));
            }
            // Frames of this UI frame spread over its interval, for the plots.
            let t = t_now - (n - 1.0 - i as f64) * 1e-3;
            if i % 4 == 0 {
                let fn_ = f.force_normal;
                push(
                    &mut self.normal_n,
                    [
                        t,
                        (fn_[0] * fn_[0] + fn_[1] * fn_[1] + fn_[2] * fn_[2]).sqrt(),
                    ],
                );
                push(&mut self.depth_mm, [t, f.depth_mm]);
            }
        }
        self.timeline
            .follow(&frames, self.replay_frames, self.status.replaying);
        if let Some(f) = frames.pop() {
            self.latest = Some(f);
        }
        self.scratch = frames;
        if was_replaying && !self.status.replaying {
            // Hand control back where the replay left the brush, lifted.
            if let Some(f) = &self.latest {
                let p = f.pose.pos.to_f64();
                self.hand.x = p[0];
                self.hand.y = p[1];
            }
            self.message = Some(match self.replay_warning.take() {
                Some(w) => (format!("replay finished: {w}"), true),
                None => ("replay finished".into(), false),
            });
        }
    }

    fn automation(&mut self, ctx: &egui::Context) {
        if !self.practice_started {
            self.practice_started = true;
            if let Some(ch) = self.automation.practice.clone() {
                self.face = Face::Writing;
                self.practice.open = true;
                self.practice.input = ch.clone();
                let (preset, params) = (self.status.preset.clone(), self.status.params);
                self.practice.load(&ch, &preset, params);
            }
        }
        let practising = self.automation.practice.is_some();
        if practising && !self.replay_started {
            if self.practice.busy() {
                return;
            }
            if self.practice.master().is_none() {
                let msg = self
                    .practice
                    .message
                    .clone()
                    .map(|m| m.0)
                    .unwrap_or_default();
                self.replay_started = true;
                self.fail(ctx, format!("--practice: {msg}"));
                return;
            }
            if self.automation.replay.is_some() {
                self.practice.start_writing();
            }
        }
        if !self.replay_started {
            self.replay_started = true;
            if let Some(p) = self.automation.session.clone() {
                self.open_session(&p, Some(ctx));
            }
            if let Some(p) = self.automation.replay.clone() {
                if let Err(e) = self.start_replay(&p) {
                    self.fail(ctx, format!("cannot replay {}: {e:#}", p.display()));
                    return;
                }
            }
        }
        let mut replay_done = (self.automation.replay.is_none()
            || (self.status.replays_done > 0 && !self.status.replaying))
            && self.opening.is_none();
        if practising && replay_done && self.automation.replay.is_some() {
            // The replay was the attempt: score it, and wait for the score.
            if self.practice.is_writing() {
                self.practice.score();
            }
            replay_done = !self.practice.busy();
        }
        let Some(shot) = self.shot.take() else { return };
        self.shot = Some(match shot {
            Shot::Waiting(k) if !replay_done => Shot::Waiting(k),
            // A few frames after the replay: the queue is drained and the last ink shown.
            Shot::Waiting(k) if k < 5 => Shot::Waiting(k + 1),
            Shot::Waiting(_) => {
                let slot = Arc::new(Mutex::new(None));
                let s2 = slot.clone();
                ctx.request_screenshot(move |img| {
                    if let Ok(mut s) = s2.lock() {
                        *s = Some(img);
                    }
                });
                Shot::Requested(slot, Instant::now())
            }
            Shot::Requested(slot, since) => {
                let img = slot.lock().ok().and_then(|mut s| s.take());
                match img {
                    Some(img) => {
                        let path = self.automation.screenshot.clone().unwrap_or_default();
                        match self.save_screenshot(ctx, &img, &path) {
                            Ok(()) => {
                                self.finish_summary();
                                ctx.send_viewport_cmd(egui::ViewportCommand::Close);
                            }
                            Err(e) => self.fail(ctx, format!("{e:#}")),
                        }
                        Shot::Done
                    }
                    None if since.elapsed() > Duration::from_secs(20) => {
                        self.fail(ctx, "the screenshot never arrived (20 s)".into());
                        Shot::Done
                    }
                    None => Shot::Requested(slot, since),
                }
            }
            Shot::Done => Shot::Done,
        });
    }

    fn fail(&mut self, ctx: &egui::Context, msg: String) {
        if let Ok(mut o) = self.outcome.lock() {
            o.error = Some(msg);
        }
        self.finish_summary();
        ctx.send_viewport_cmd(egui::ViewportCommand::Close);
    }

    /// Writes the frame-time and ink summary into the outcome (printed at exit).
    fn finish_summary(&mut self) {
        let c = self.paper.canvas();
        let t = &self.times;
        let mut lines = vec![format!(
            "maobi gui: canvas {} x {} px, ink {:.2}%, {} strokes, {} replay ticks, {} frames dropped, {} ticks late",
            c.width(),
            c.height(),
            c.ink_fraction() * 100.0,
            self.paper.strokes(),
            self.replay_frames,
            self.status.frames_dropped,
            self.status.ticks_late
        )];
        if !t.replay_interval.is_empty() {
            lines.push(format!(
                "maobi gui: frame time while drawing ({} frames): median {:.1} ms, p99 {:.1} ms; ui+ink+upload median {:.2} ms, p99 {:.2} ms",
                t.replay_interval.len(),
                percentile(&t.replay_interval, 0.5),
                percentile(&t.replay_interval, 0.99),
                percentile(&t.replay_ui, 0.5),
                percentile(&t.replay_ui, 0.99),
            ));
        }
        let l = self.ink_latency();
        if l.frames > 0 {
            lines.push(format!(
                "maobi gui: device frame arrival to ink uploaded ({} UI frames): median {:.2} ms, p99 {:.2} ms, max {:.2} ms; frames that waited past the next UI frame: {}",
                l.frames, l.median_ms, l.p99_ms, l.max_ms, l.late
            ));
        }
        if let Ok(mut o) = self.outcome.lock() {
            o.summary = lines;
        }
    }

    fn save_screenshot(
        &self,
        ctx: &egui::Context,
        img: &egui::ColorImage,
        path: &Path,
    ) -> anyhow::Result<()> {
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir)
                .with_context(|| format!("cannot create {}", dir.display()))?;
        }
        let [w, h] = img.size;
        let mut bytes = Vec::with_capacity(w * h * 4);
        for p in &img.pixels {
            bytes.extend_from_slice(&p.to_array());
        }
        let file = std::fs::File::create(path)
            .with_context(|| format!("cannot create {}", path.display()))?;
        let mut enc = png::Encoder::new(std::io::BufWriter::new(file), w as u32, h as u32);
        enc.set_color(png::ColorType::Rgba);
        enc.set_depth(png::BitDepth::Eight);
        let mut wr = enc.write_header()?;
        wr.write_image_data(&bytes)?;
        wr.finish()?;
        // Where the views are, in the screenshot's pixels, for the checker.
        let lpath = layout_path(path);
        std::fs::write(&lpath, self.layout(ctx))
            .with_context(|| format!("cannot write {}", lpath.display()))?;
        Ok(())
    }

    /// Where the views are, in the window's pixels, a line each (`name x0 y0 x1 y1`), and
    /// the face shown (`face writing` or `face laboratory`).
    pub fn layout(&self, ctx: &egui::Context) -> String {
        let ppp = ctx.pixels_per_point();
        let r = |r: egui::Rect| {
            if !r.is_positive() {
                return "none".to_string();
            }
            format!(
                "{} {} {} {}",
                (r.min.x * ppp).round(),
                (r.min.y * ppp).round(),
                (r.max.x * ppp).round(),
                (r.max.y * ppp).round()
            )
        };
        let laboratory = self.face == Face::Laboratory;
        let f = self.paper.frame();
        let practice = if self.practice.open && !laboratory {
            self.practice.layout(r)
        } else {
            String::new()
        };
        // Where the hand is (the last frame's ferrule, mm) and whether the brush touches.
        let hand = self.latest.as_ref().map_or("none".to_string(), |f| {
            let p = f.pose.pos.to_f64();
            format!("{:.3} {:.3} {:.3}", p[0], p[1], p[2])
        });
        let mark = match &self.mark {
            Some(BrushMark::Touching { .. }) => "touching",
            Some(BrushMark::Above { .. }) => "above",
            None => "none",
        };
        format!(
            "face {}\ncanvas {}\nbrush {}\nsheet {}\nwindow {}\nparam {}\npaper_mm {} {} {} {}\nhand {hand}\nmark {mark}\n{practice}",
            if laboratory { "laboratory" } else { "writing" },
            r(self.paper.view_rect),
            r(self.brush_rect),
            r(self.paper.sheet_rect()),
            r(ctx.viewport_rect()),
            r(if laboratory {
                self.param_rect
            } else {
                egui::Rect::NOTHING
            }),
            f.x0_mm,
            f.y_top_mm,
            f.x0_mm + f.width as f64 / f.px_per_mm,
            f.y_top_mm - f.height as f64 / f.px_per_mm,
        )
    }

    /// Rewrites [`Automation::layout`]'s file when the layout changed.
    fn keep_layout(&mut self, ctx: &egui::Context) {
        let Some(path) = self.automation.layout.clone() else {
            return;
        };
        let text = self.layout(ctx);
        if text == self.layout_written {
            return;
        }
        // Whole or not at all: write beside it and rename, so a reader never sees half.
        let mut tmp = path.clone().into_os_string();
        tmp.push(".new");
        let done = std::fs::write(&tmp, &text).and_then(|()| std::fs::rename(&tmp, &path));
        match done {
            Ok(()) => self.layout_written = text,
            Err(e) => {
                log::warn!("cannot keep the layout in {}: {e}", path.display());
                self.automation.layout = None;
            }
        }
    }
}

/// Where `--screenshot OUT.png` writes the views' rectangles: `OUT.png.layout`.
pub fn layout_path(png: &Path) -> PathBuf {
    let mut s = png.as_os_str().to_owned();
    s.push(".layout");
    PathBuf::from(s)
}

fn push(q: &mut VecDeque<[f64; 2]>, p: [f64; 2]) {
    q.push_back(p);
    while q.front().is_some_and(|f| f[0] < p[0] - PLOT_SECONDS) {
        q.pop_front();
    }
}

fn output_label(s: OutputState) -> (&'static str, Color32) {
    match s {
        OutputState::Disabled => ("forces off", Color32::GRAY),
        OutputState::RampingIn => ("forces ramping in", Color32::from_rgb(220, 180, 60)),
        OutputState::Active => ("forces active", Color32::from_rgb(80, 200, 100)),
        OutputState::Faulted => ("FAULT: forces held at zero", Color32::from_rgb(230, 70, 60)),
    }
}

impl MaobiApp {
    fn device_chooser(&mut self, ui: &mut egui::Ui) {
        let before = self.device_kind;
        egui::ComboBox::from_label("device")
            .selected_text(self.device_kind.label())
            .show_ui(ui, |ui| {
                for k in [
                    DeviceKind::Sim,
                    DeviceKind::Tcp,
                    DeviceKind::Serial,
                    DeviceKind::Phantom,
                ] {
                    ui.selectable_value(&mut self.device_kind, k, k.label());
                }
            });
        if self.device_kind != before {
            match self.device_kind {
                DeviceKind::Serial => {
                    self.serial_ports = serial_ports();
                    self.device_addr = self
                        .serial_ports
                        .first()
                        .map(|p| p.name.clone())
                        .unwrap_or_default();
                }
                DeviceKind::Tcp => self.device_addr = "127.0.0.1:7878".into(),
                DeviceKind::Phantom => self.device_addr.clear(),
                DeviceKind::Sim => {}
            }
        }
        if self.device_kind != DeviceKind::Sim {
            let (hint, what) = match self.device_kind {
                DeviceKind::Tcp => ("HOST:PORT", "address"),
                DeviceKind::Phantom => ("empty: $MAOBI_HD_LIB, install paths", "libHD.so"),
                _ => ("/dev/ttyACM0", "address"),
            };
            let l = ui.label(what);
            ui.add(
                egui::TextEdit::singleline(&mut self.device_addr)
                    .hint_text(hint)
                    .desired_width(150.0),
            )
            .labelled_by(l.id);
        }
        if self.device_kind == DeviceKind::Serial {
            egui::ComboBox::from_label("ports")
                .selected_text(format!(
                    "{} found, {} with Maobi's USB IDs",
                    self.serial_ports.len(),
                    self.serial_ports.iter().filter(|p| p.is_maobi()).count()
                ))
                .show_ui(ui, |ui| {
                    for p in self.serial_ports.clone() {
                        ui.selectable_value(&mut self.device_addr, p.name.clone(), p.label());
                    }
                });
            if ui.button("Rescan").clicked() {
                self.serial_ports = serial_ports();
            }
            self.find_pen(ui);
        }
        if ui
            .button("Use")
            .on_hover_text("Switch to this device (the paper is kept)")
            .clicked()
        {
            let ctx = ui.ctx().clone();
            self.switch_device(&ctx);
        }
    }

    /// "Find the pen": shakes hands on every serial port in the background and picks the
    /// first that answers.
    fn find_pen(&mut self, ui: &mut egui::Ui) {
        if let Some(slot) = &self.probe {
            let done = slot.lock().ok().and_then(|mut s| s.take());
            match done {
                Some(found) => {
                    self.probe = None;
                    self.serial_ports = serial_ports();
                    let pens: Vec<String> = found
                        .iter()
                        .filter_map(|(p, r)| r.as_ref().ok().map(|b| format!("{p}: {b}")))
                        .collect();
                    if let Some((p, _)) = found.iter().find(|(_, r)| r.is_ok()) {
                        self.device_addr = p.clone();
                    }
                    self.message = Some(if pens.is_empty() {
                        (
                            format!("no Maobi device answered on {} ports", found.len()),
                            true,
                        )
                    } else {
                        (format!("found {}", pens.join(", ")), false)
                    });
                }
                None => {
                    ui.spinner();
                    ui.ctx().request_repaint_after(Duration::from_millis(100));
                }
            }
        } else if ui
            .button("Find the pen")
            .on_hover_text("Shake hands on every serial port")
            .clicked()
        {
            let slot = Arc::new(Mutex::new(None));
            let s2 = slot.clone();
            let ctx = ui.ctx().clone();
            std::thread::spawn(move || {
                let found = crate::device::probe_serial_ports(Duration::from_millis(400));
                if let Ok(mut s) = s2.lock() {
                    *s = Some(found);
                }
                ctx.request_repaint();
            });
            self.probe = Some(slot);
        }
    }

    fn toolbar(&mut self, ui: &mut egui::Ui) {
        ui.horizontal_wrapped(|ui| {
            self.device_chooser(ui);
            ui.separator();
            self.tablet_chooser(ui);
            ui.separator();
            if self.status.connected {
                if ui.button("Disconnect").clicked() {
                    self.device.disconnect();
                }
            } else if ui.button("Connect").clicked() {
                if let Err(e) = self.device.connect() {
                    self.message = Some((format!("cannot connect: {e}"), true));
                }
                // The simulator starts a new model (and journal) on connect.
                self.restart_ink_log();
            }
            ui.separator();
            self.brush_controls(ui);
            self.paper_controls(ui);
            self.dip_controls(ui);
            let enabled = self.status.forces_enabled;
            let out = self.latest.as_ref().map(|f| f.output);
            if ui
                .selectable_label(enabled, "Forces")
                .on_hover_text("Enable the force output (it ramps in)")
                .clicked()
            {
                let _ = self.device.send(DeviceCommand::EnableForces(!enabled));
            }
            if let Some(o) = out {
                let (t, c) = output_label(o);
                ui.label(RichText::new(t).color(c));
                if o == OutputState::Faulted && ui.button("Clear fault").clicked() {
                    let _ = self.device.send(DeviceCommand::ClearFault);
                }
            }
            ui.separator();
            self.edit_buttons(ui);
            ui.toggle_value(&mut self.show_timeline, "Strokes")
                .on_hover_text("The stroke editor: keyframes, timeline, play, guided writing");
            if ui.button("1:1").clicked() {
                self.paper.actual_size(ui.ctx());
            }
            ui.separator();
            if ui
                .button("Writing view")
                .on_hover_text("The paper first, the tools in one row (F2)")
                .clicked()
            {
                self.face = Face::Writing;
            }
            ui.toggle_value(&mut self.show_about, "About")
                .on_hover_text("The version, the licences and the fonts (F1)");
        });
        ui.horizontal_wrapped(|ui| {
            self.recent_menu(ui);
            ui.separator();
            let l = ui.label("PNG file");
            ui.add(egui::TextEdit::singleline(&mut self.save_path).desired_width(180.0))
                .labelled_by(l.id);
            if ui.button("Save PNG").clicked() {
                let path = PathBuf::from(&self.save_path);
                self.file_action(FileKind::Png, &path, &ui.ctx().clone());
            }
            let current = self.save_path.clone();
            self.browse_save(ui, FileKind::Png, &current);
            ui.separator();
            let l = ui.label("pose recording");
            ui.add(egui::TextEdit::singleline(&mut self.record_path).desired_width(180.0))
                .labelled_by(l.id);
            if self.recorder.is_some() {
                if ui.button("Stop recording").clicked() {
                    let path = self.record_path.clone();
                    self.message = Some(match self.stop_recording() {
                        Ok(n) => (format!("recorded {n} poses to {path}"), false),
                        Err(e) => (format!("{e:#}"), true),
                    });
                }
            } else {
                if ui.button("Record poses").clicked() {
                    let p = PathBuf::from(&self.record_path);
                    self.start_recording(&p);
                }
                let current = self.record_path.clone();
                self.browse_save(ui, FileKind::Poses, &current);
            }
            ui.separator();
            let l = ui.label("pose file");
            ui.add(egui::TextEdit::singleline(&mut self.replay_path).desired_width(180.0))
                .labelled_by(l.id);
            if self.status.replaying {
                if ui.button("Stop replay").clicked() {
                    let _ = self.device.send(DeviceCommand::StopReplay);
                }
            } else {
                if ui.button("Replay").clicked() {
                    let p = PathBuf::from(&self.replay_path);
                    self.file_action(FileKind::Poses, &p, &ui.ctx().clone());
                }
                let current = self.replay_path.clone();
                self.browse_open(ui, FileKind::Poses, &current);
            }
            ui.separator();
            let l = ui.label("session file");
            ui.add(egui::TextEdit::singleline(&mut self.session_path).desired_width(200.0))
                .labelled_by(l.id);
            if ui
                .button("Save session")
                .on_hover_text("The poses, commands and parameters since the simulator started, so the session re-renders exactly")
                .clicked()
            {
                let p = PathBuf::from(&self.session_path);
                self.save_session_reporting(&p);
            }
            let current = self.session_path.clone();
            self.browse_save(ui, FileKind::Session, &current);
            if self.opening.is_some() {
                ui.spinner();
            } else if ui
                .button("Open session")
                .on_hover_text("Re-render a saved session and go on writing from where it ended")
                .clicked()
            {
                let p = PathBuf::from(&self.session_path);
                self.file_action(FileKind::Session, &p, &ui.ctx().clone());
            }
            if self.opening.is_none() {
                let current = self.session_path.clone();
                self.browse_open(ui, FileKind::Session, &current);
            }
        });
        self.message_line(ui);
    }

    /// The last general message under the toolbar (errors in red): both faces.
    fn message_line(&self, ui: &mut egui::Ui) {
        super::message::label(ui, &self.message);
    }

    /// The brush model and the preset (or Baxter & Lin's head): both faces' toolbars.
    fn brush_controls(&mut self, ui: &mut egui::Ui) {
        let mut model = self.status.model;
        egui::ComboBox::from_label("model")
            .selected_text(model.label())
            .show_ui(ui, |ui| {
                for m in ModelKind::ALL {
                    ui.selectable_value(&mut model, m, m.label());
                }
            })
            .response
            .on_hover_text(
                "Liang: the pen's mass-spring brush. Baxter & Lin: spines that find their \
                 shape by minimising energy, with stiction and the flat, filbert and fan \
                 heads (desktop only: the built-in simulator)",
            );
        if model != self.status.model {
            match self.device.send(DeviceCommand::Model(model)) {
                Ok(()) => {
                    self.model_choice = model;
                    self.message = Some((format!("model: {}", model.label()), false));
                }
                Err(e) => self.message = Some((e.to_string(), true)),
            }
        }
        let mut preset = self.status.preset.clone();
        egui::ComboBox::from_label("brush")
            .selected_text(preset.clone())
            .show_ui(ui, |ui| {
                for (name, _) in presets::PRESETS {
                    ui.selectable_value(&mut preset, name.to_string(), name);
                }
                if self.status.model == ModelKind::BaxterLin {
                    for name in HEAD_NAMES {
                        ui.selectable_value(&mut preset, name.to_string(), name);
                    }
                }
            });
        if preset != self.status.preset {
            match self.device.send(DeviceCommand::Preset(preset.clone())) {
                Ok(()) => {
                    if let Ok(b) = BrushChoice::parse(&preset) {
                        self.param_edit = ParamId::ALL.iter().map(|&i| b.params.get(i)).collect();
                    }
                    self.message = Some((format!("brush: {preset}"), false));
                }
                Err(e) => self.message = Some((e.to_string(), true)),
            }
        }
    }

    /// The paper's kind (sized or raw): both faces' toolbars.
    fn paper_controls(&mut self, ui: &mut egui::Ui) {
        let mut paper = self.paper.paper().kind;
        egui::ComboBox::from_label("paper")
            .selected_text(paper.name())
            .show_ui(ui, |ui| {
                for k in PaperKind::ALL {
                    ui.selectable_value(&mut paper, k, k.name());
                }
            })
            .response
            .on_hover_text(
                "sized (熟宣): the ink stays where it fell; raw (生宣): it wicks outward \
                 along the fibres. Changing it starts a fresh sheet",
            );
        self.set_paper(paper);
    }

    /// The ink load and the dip (D): both faces' toolbars.
    fn dip_controls(&mut self, ui: &mut egui::Ui) {
        let l = ui.label("ink load");
        ui.add(
            egui::DragValue::new(&mut self.ink_load)
                .range(0.0..=1.0)
                .speed(0.01)
                .fixed_decimals(2),
        )
        .labelled_by(l.id)
        .on_hover_text("How wet a dip leaves the brush (0: dry, 1: fully loaded)");
        if ui
            .button("Dip ink")
            .on_hover_text("Load the brush with ink (D)")
            .clicked()
        {
            self.dip();
        }
    }

    /// Dips the brush to the ink load set.
    pub fn dip(&mut self) {
        let load = self.ink_load;
        self.message = Some(match self.device.send(DeviceCommand::Dip(load)) {
            Ok(()) => (format!("dipped: ink load {load:.2}"), false),
            Err(e) => (format!("cannot dip: {e}"), true),
        });
    }

    /// Undo (Ctrl+Z), clear (Ctrl+N) and fit (F): both faces' toolbars.
    fn edit_buttons(&mut self, ui: &mut egui::Ui) {
        if ui
            .add_enabled(
                self.paper.undo_depth() > 0,
                egui::Button::new("Undo stroke"),
            )
            .on_hover_text("Ctrl+Z")
            .clicked()
        {
            self.undo();
        }
        if ui
            .button("Clear")
            .on_hover_text("A fresh sheet (Ctrl+N)")
            .clicked()
        {
            self.clear();
        }
        if ui
            .button("Fit")
            .on_hover_text("The whole paper in the view (F)")
            .clicked()
        {
            self.paper.fit();
        }
    }

    fn params_panel(&mut self, ui: &mut egui::Ui) {
        ui.heading("Parameters");
        ui.label(
            RichText::new(
                "Checked by the model before they apply; a rejected value keeps the old one.",
            )
            .small(),
        );
        if let Some((m, err)) = &self.param_msg {
            let c = if *err {
                Color32::from_rgb(230, 80, 70)
            } else {
                Color32::from_rgb(90, 190, 110)
            };
            ui.label(RichText::new(m).color(c));
        }
        let mut changed = None;
        // Baxter & Lin's brush reads only its head's profile and its ink: the rest are
        // Liang's model's own, shown but not editable.
        let brush = BrushChoice::parse(&self.status.preset).ok();
        let reads = |id: ParamId| match (self.status.model, &brush) {
            (ModelKind::BaxterLin, Some(b)) => b.baxter_lin_reads(id).is_ok(),
            (ModelKind::BaxterLin, None) => false,
            (ModelKind::Liang, _) => true,
        };
        egui::ScrollArea::vertical().show(ui, |ui| {
            egui::Grid::new("params")
                .num_columns(2)
                .striped(true)
                .show(ui, |ui| {
                    for (i, &id) in ParamId::ALL.iter().enumerate() {
                        let (lo, hi, whole) = id.range();
                        let label = ui.label(id.name()).on_hover_text(format!("{lo} ..= {hi}"));
                        let speed = ((hi - lo) as f64 / 500.0).min(1.0);
                        let mut dv = egui::DragValue::new(&mut self.param_edit[i]).speed(speed);
                        dv = if whole {
                            dv.fixed_decimals(0)
                        } else {
                            // The value as the model holds it (f32, shortest form): the
                            // decimals egui derives from the drag speed would round a goat
                            // brush's tie damping of 0.014 to "0.01".
                            dv.custom_formatter(|v, _| format!("{}", v as f32))
                        };
                        let r = ui.add_enabled(reads(id), dv).labelled_by(label.id);
                        if i == 0 {
                            self.param_rect = r.rect;
                        }
                        if r.changed() {
                            changed = Some((id, self.param_edit[i]));
                        }
                        ui.end_row();
                    }
                });
        });
        if let Some((id, v)) = changed {
            self.set_param(id, v);
        }
    }

    fn plots(&mut self, ui: &mut egui::Ui) {
        use egui_plot::{Line, Plot};
        let h = ((ui.available_height() - 100.0) / 5.0).max(40.0);
        let now = self.started.elapsed().as_secs_f64();
        let x0 = now - PLOT_SECONDS;
        let series = [
            (
                "normal force (N)",
                &self.normal_n,
                Color32::from_rgb(240, 120, 80),
            ),
            (
                "depth (mm)",
                &self.depth_mm,
                Color32::from_rgb(90, 160, 255),
            ),
            (
                "device tick period (ms)",
                &self.tick_period_ms,
                Color32::from_rgb(200, 160, 240),
            ),
            (
                "device frames received (1/s)",
                &self.frame_rate,
                Color32::from_rgb(240, 200, 90),
            ),
            (
                "UI frame time (ms)",
                &self.times.recent,
                Color32::from_rgb(120, 220, 120),
            ),
        ];
        for (name, data, color) in series {
            ui.label(name);
            Plot::new(name)
                .height(h)
                .include_x(x0)
                .include_x(now)
                .include_y(0.0)
                .allow_drag(false)
                .allow_zoom(false)
                .allow_scroll(false)
                .show_x(false)
                .show(ui, |p| {
                    let pts: Vec<[f64; 2]> = data.iter().copied().collect();
                    p.line(Line::new(name, pts).color(color));
                });
        }
    }

    fn status_bar(&mut self, ui: &mut egui::Ui) {
        let s = &self.status;
        ui.horizontal(|ui| {
            let (dot, c) = if s.connected {
                ("connected", Color32::from_rgb(80, 200, 100))
            } else {
                ("disconnected", Color32::from_rgb(230, 80, 70))
            };
            ui.label(RichText::new(s.name.clone()).strong());
            ui.label(RichText::new(dot).color(c));
            ui.separator();
            ui.label(format!(
                "protocol {}  firmware {}",
                s.protocol_version.map_or("-".into(), |v| v.to_string()),
                s.firmware_version.as_deref().unwrap_or("-")
            ));
            ui.separator();
            if s.faults.is_empty() {
                ui.label("no faults");
            } else {
                ui.label(RichText::new(s.faults.join("; ")).color(Color32::from_rgb(230, 80, 70)));
            }
            ui.separator();
            ui.label(format!("frames dropped {}  ticks late {}", s.frames_dropped, s.ticks_late));
            ui.separator();
            if let Some(f) = &self.latest {
                let p = f.pose.pos.to_f64();
                ui.label(format!(
                    "tick {}  ferrule ({:.1}, {:.1}, {:.1}) mm  tilt ({:.0}, {:.0})°  press {:.1} mm{}",
                    f.tick,
                    p[0],
                    p[1],
                    p[2],
                    self.hand.tilt_x_deg,
                    self.hand.tilt_y_deg,
                    self.press_mm,
                    if s.replaying { "  REPLAY" } else { "" }
                ));
            }
            if let Some(t) = &self.tablet_status {
                ui.separator();
                let r = t.reading;
                ui.label(format!(
                    "{}: {}  pressure {:.2}  tilt ({:.0}, {:.0})°",
                    t.name,
                    match (r.in_range, r.touching) {
                        (false, _) => "out of range",
                        (true, false) => "hovering",
                        (true, true) => "touching",
                    },
                    r.pressure,
                    r.tilt_x_deg,
                    r.tilt_y_deg
                ));
            }
            ui.separator();
            ui.label(format!(
                "canvas {}x{}  upload {} px  undo {}",
                self.paper.frame().width,
                self.paper.frame().height,
                self.paper.uploaded_px,
                self.paper.undo_depth()
            ));
            if self.recorder.is_some() {
                ui.label(RichText::new("REC").color(Color32::from_rgb(230, 60, 60)));
            }
            if let Some(Err(m)) = &self.fonts {
                ui.label(RichText::new("no CJK font").color(Color32::from_rgb(220, 180, 60)))
                    .on_hover_text(m);
            }
        });
        // A protocol device's link: its state and our receiver's counters.
        if let Some(l) = &s.link {
            ui.horizontal(|ui| {
                let c = if s.connected {
                    ui.visuals().text_color()
                } else {
                    Color32::from_rgb(230, 80, 70)
                };
                ui.label(RichText::new(&l.state).color(c));
                if s.connected && !l.config_allows_forces {
                    // A physical pen without a valid stored configuration refuses forces.
                    ui.label(
                        RichText::new(format!("configuration {}: no forces", l.config))
                            .color(Color32::from_rgb(230, 80, 70)),
                    );
                }
                ui.label(format!(
                    "rx ok {}  crc {}  framing {}  oversized {}  decode {}  version {}  lost {}",
                    l.rx.frames_ok,
                    l.rx.crc_errors,
                    l.rx.framing_errors,
                    l.rx.oversized_frames,
                    l.rx.decode_errors,
                    l.rx.version_errors,
                    l.lost
                ))
                .on_hover_text(format!(
                    "device: {} pose gaps, its receiver {:?}; last error: {}",
                    l.pose_gaps,
                    l.device_rx,
                    l.last_error.as_deref().unwrap_or("none")
                ));
            });
        }
    }

    /// Keys, pointer and tablet to the hand: pointer x/y on the paper; press with the primary
    /// button (depth from pen pressure when reported, else W/S or the wheel), tilt with the
    /// arrows. A pen tablet in range takes over the press (its tip and pressure, through the
    /// pressure curve) and the tilt (its own, when it reports one).
    fn hand_input(&mut self, ctx: &egui::Context, over_paper: super::canvas::PaperPointer) {
        if !ctx.egui_wants_keyboard_input() {
            ctx.input(|i| {
                let dt = i.stable_dt.min(0.1) as f64;
                if i.key_down(egui::Key::W) {
                    self.press_mm += 8.0 * dt;
                }
                if i.key_down(egui::Key::S) {
                    self.press_mm -= 8.0 * dt;
                }
                let rate = 30.0 * dt;
                if i.key_down(egui::Key::ArrowUp) {
                    self.hand.tilt_x_deg -= rate;
                }
                if i.key_down(egui::Key::ArrowDown) {
                    self.hand.tilt_x_deg += rate;
                }
                if i.key_down(egui::Key::ArrowLeft) {
                    self.hand.tilt_y_deg -= rate;
                }
                if i.key_down(egui::Key::ArrowRight) {
                    self.hand.tilt_y_deg += rate;
                }
                if i.key_pressed(egui::Key::R) {
                    self.hand.tilt_x_deg = 0.0;
                    self.hand.tilt_y_deg = 0.0;
                }
            });
        }
        let len = self.status.params.length_mm as f64;
        self.pressure = ctx.input(|i| {
            i.events.iter().rev().find_map(|e| match e {
                egui::Event::Touch {
                    force,
                    phase: egui::TouchPhase::Start | egui::TouchPhase::Move,
                    ..
                } => *force,
                _ => None,
            })
        });
        if let Some(mm) = over_paper.mm {
            let wheel = ctx.input(|i| {
                if i.modifiers.command {
                    0.0
                } else {
                    i.smooth_scroll_delta.y
                }
            });
            self.press_mm += wheel as f64 * 0.02;
            self.hand.x = mm[0];
            self.hand.y = mm[1];
        }
        self.press_mm = self.press_mm.clamp(0.0, len * 0.8);
        let pen = self.poll_tablet();
        let depth = match pen {
            Some(pen) => {
                let tilt = self.tablet_status.as_ref().is_some_and(|s| s.has_tilt);
                if tilt {
                    self.hand.tilt_x_deg = pen.tilt_x_deg;
                    self.hand.tilt_y_deg = pen.tilt_y_deg;
                }
                self.pen_down = pen.depth_mm.is_some() && over_paper.mm.is_some();
                match pen.depth_mm {
                    Some(d) if self.pen_down => d,
                    _ => -HOVER_MM,
                }
            }
            None => {
                self.pen_down = over_paper.pressed;
                match (self.pen_down, self.pressure) {
                    (true, Some(p)) => self.press_mm * (p as f64 * 1.5).min(1.5),
                    (true, None) => self.press_mm,
                    (false, _) => -HOVER_MM,
                }
            }
        };
        self.hand.tilt_x_deg = self.hand.tilt_x_deg.clamp(-45.0, 45.0);
        self.hand.tilt_y_deg = self.hand.tilt_y_deg.clamp(-45.0, 45.0);
        self.hand.z = len - depth;
        if !self.status.replaying {
            let _ = self.device.send(DeviceCommand::Hand(self.hand));
        }
    }

    /// Saves the session to `p` and says how it went.
    fn save_session_reporting(&mut self, p: &Path) {
        self.message = Some(match self.save_session(p) {
            Ok(t) => {
                self.recent.add(FileKind::Session, p);
                (
                    format!("saved the session ({t} ticks) to {}", p.display()),
                    false,
                )
            }
            Err(e) => (format!("cannot save the session: {e:#}"), true),
        });
    }

    /// Reads the tablet, if one is in use; what its pen does to the hand while it is in range
    /// and working. A tablet that failed (unplugged) is dropped with its reason shown, and the
    /// mouse takes over.
    fn poll_tablet(&mut self) -> Option<crate::tablet::HandFromPen> {
        let tablet = self.tablet.as_mut()?;
        let status = tablet.poll(Duration::from_millis(self.frame_ticks as u64));
        let pen = status.reading.hand(self.pressure_curve, self.press_mm);
        let usable = status.error.is_none() && status.reading.in_range;
        if let Some(e) = &status.error {
            self.message = Some((e.clone(), true));
            self.tablet = None;
        }
        self.tablet_status = Some(status);
        usable.then_some(pen)
    }

    /// Uses the pen tablet (or tablet recording) at `path`; an empty path goes back to the
    /// mouse.
    pub fn use_tablet(&mut self, path: &Path) -> Result<(), crate::tablet::TabletError> {
        self.tablet = None;
        self.tablet_status = None;
        if path.as_os_str().is_empty() {
            return Ok(());
        }
        self.set_tablet(Tablet::open(path)?, path);
        Ok(())
    }

    /// Uses a tablet already opened from `path` (remembered for the next run if it is a
    /// device).
    pub fn set_tablet(&mut self, t: Tablet, path: &Path) {
        self.tablet_status = None;
        self.tablet = Some(t);
        self.tablet_path = path.display().to_string();
    }

    /// The tablet's state as of the last UI frame.
    pub fn tablet_status(&self) -> Option<&TabletStatus> {
        self.tablet_status.as_ref()
    }

    pub fn set_pressure_curve(&mut self, c: PressureCurve) {
        self.pressure_curve = c;
    }

    /// Takes what the last run left (see [`Settings`]): the device chooser, the brush's name
    /// for the next device, the file fields and recent files; the tablet and its curve unless
    /// the command line chose them (`keep_tablet`). A remembered tablet that is gone is
    /// reported, not an error.
    pub fn restore(&mut self, s: &Settings, keep_tablet: bool) {
        self.device_kind = s.device_kind;
        self.device_addr = s.device_addr.clone();
        if BrushChoice::for_model(&s.brush, s.model).is_ok() {
            self.brush_name = s.brush.clone();
            self.model_choice = s.model;
        }
        self.save_path = s.png_path.clone();
        self.record_path = s.record_path.clone();
        self.replay_path = s.replay_path.clone();
        self.session_path = s.session_path.clone();
        self.recent = s.recent.clone();
        self.recent.prune_missing();
        self.face = s.face;
        self.grid = s.grid;
        self.show_brush_view = s.show_brush_view;
        if keep_tablet {
            return;
        }
        if let Ok(c) = PressureCurve::new(s.pressure_exponent, s.pressure_threshold) {
            self.pressure_curve = c;
        }
        if let Some(t) = &s.tablet {
            if let Err(e) = self.use_tablet(t) {
                self.message = Some((format!("the last tablet: {e}"), true));
            }
        }
    }

    /// What this run leaves for the next.
    pub fn settings(&self) -> Settings {
        Settings {
            device_kind: self.device_kind,
            device_addr: self.device_addr.clone(),
            brush: self.status.preset.clone(),
            model: self.status.model,
            tablet: self
                .tablet
                .as_ref()
                .filter(|t| t.is_live())
                .map(|_| PathBuf::from(&self.tablet_path)),
            pressure_exponent: self.pressure_curve.exponent,
            pressure_threshold: self.pressure_curve.threshold,
            // The paper is a square centred on the origin (`gui::paper_frame`).
            paper_mm: -2.0 * self.paper.frame().x0_mm,
            px_per_mm: self.paper.frame().px_per_mm,
            png_path: self.save_path.clone(),
            record_path: self.record_path.clone(),
            replay_path: self.replay_path.clone(),
            session_path: self.session_path.clone(),
            recent: self.recent.clone(),
            face: self.face,
            grid: self.grid,
            show_brush_view: self.show_brush_view,
        }
    }

    /// The recent files of each kind.
    pub fn recent(&self) -> &Recent {
        &self.recent
    }

    /// Runs the action on a file of `kind` that the user picked (a dialog, the recent menu)
    /// or typed: fills the kind's field and opens, replays or saves, as its button does.
    pub fn file_action(&mut self, kind: FileKind, path: &Path, ctx: &egui::Context) {
        let shown = path.display().to_string();
        match kind {
            FileKind::Png => {
                self.save_path = shown;
                self.message = Some(match write_png(self.paper.canvas(), path) {
                    Ok(()) => (format!("saved {}", path.display()), false),
                    Err(e) => (format!("{e:#}"), true),
                });
            }
            FileKind::Poses => {
                self.replay_path = shown;
                if let Err(e) = self.start_replay(path) {
                    self.message = Some((format!("cannot replay: {e:#}"), true));
                    return;
                }
            }
            FileKind::Session => {
                self.session_path = shown;
                self.open_session(path, Some(ctx));
            }
            FileKind::Stroke => {
                self.show_timeline = true;
                if let Err(e) = self.timeline.open(path) {
                    self.message = Some((format!("{e:#}"), true));
                    return;
                }
            }
            FileKind::TabletRecording => {
                if let Err(e) = self.use_tablet(path) {
                    self.message = Some((e.to_string(), true));
                    return;
                }
            }
        }
        self.recent.add(kind, path);
    }

    /// A "…" button that asks the platform's dialog for a file of `kind` to open.
    fn browse_open(&mut self, ui: &mut egui::Ui, kind: FileKind, current: &str) {
        if ui
            .button("…")
            .on_hover_text(format!("Choose a {} to open", kind.label()))
            .clicked()
        {
            self.ask_file(Purpose::Open(kind), current);
        }
    }

    /// A "…" button that asks the platform's dialog where to save a file of `kind`, starting
    /// from `current`.
    fn browse_save(&mut self, ui: &mut egui::Ui, kind: FileKind, current: &str) {
        if ui
            .button("…")
            .on_hover_text(format!("Choose where to save the {}", kind.label()))
            .clicked()
        {
            self.ask_file(Purpose::Save(kind), current);
        }
    }

    /// Asks for a file dialog, shown after this frame ([`Self::show_file_dialog`]).
    fn ask_file(&mut self, purpose: Purpose, current: &str) {
        if self.dialog.is_some() {
            self.message = Some(("a file dialog is already open".into(), true));
            return;
        }
        self.dialog_request = Some(DialogRequest {
            purpose,
            current: current.to_string(),
        });
    }

    /// The file dialog asked for in the frame just drawn, if any, on its own thread and on
    /// `parent` (the window; none in tests without one), so that the window keeps drawing.
    pub fn show_file_dialog(&mut self, ctx: &egui::Context, parent: Option<&eframe::Frame>) {
        let Some(req) = self.dialog_request.take() else {
            return;
        };
        match req.show(parent, ctx.clone()) {
            Ok(d) => self.dialog = Some(d),
            Err(e) => self.message = Some((format!("cannot open a file dialog: {e}"), true)),
        }
    }

    /// What a file dialog asked for: the file it is for, once answered.
    pub fn pending_dialog(&self) -> Option<&DialogRequest> {
        self.dialog_request.as_ref()
    }

    /// Acts on the file dialog's answer once it has one.
    fn take_dialog_answer(&mut self, ctx: &egui::Context) {
        let Some(answer) = self.dialog.as_ref().and_then(RunningDialog::answered) else {
            return;
        };
        let Some(d) = self.dialog.take() else { return };
        if let Some(path) = answer {
            self.file_chosen(d.purpose, &path, ctx);
        }
    }

    /// A file chosen (in a dialog) for `purpose`.
    pub fn file_chosen(&mut self, purpose: Purpose, path: &Path, ctx: &egui::Context) {
        match purpose {
            Purpose::Open(kind) | Purpose::Save(kind @ FileKind::Png) => {
                self.file_action(kind, path, ctx)
            }
            Purpose::Save(FileKind::Poses) => {
                self.record_path = path.display().to_string();
                self.start_recording(path);
            }
            Purpose::Save(FileKind::Session) => {
                self.session_path = path.display().to_string();
                self.save_session_reporting(path);
            }
            Purpose::Save(FileKind::Stroke) => self.timeline.save_to(path),
            // Nothing saves a tablet recording.
            Purpose::Save(FileKind::TabletRecording) => {}
        }
    }

    /// The "Recent" menu: the files of each kind used lately, to open again.
    fn recent_menu(&mut self, ui: &mut egui::Ui) {
        let mut picked = None;
        ui.menu_button("Recent", |ui| {
            let mut any = false;
            for kind in [
                FileKind::Session,
                FileKind::Stroke,
                FileKind::Poses,
                FileKind::TabletRecording,
            ] {
                let files: Vec<PathBuf> = self.recent.of(kind).map(Path::to_path_buf).collect();
                if files.is_empty() {
                    continue;
                }
                any = true;
                ui.label(RichText::new(kind.label()).strong());
                for f in files {
                    if ui.button(f.display().to_string()).clicked() {
                        picked = Some((kind, f));
                        ui.close();
                    }
                }
            }
            if !any {
                ui.label("nothing yet");
            }
        });
        if let Some((kind, f)) = picked {
            let ctx = ui.ctx().clone();
            self.file_action(kind, &f, &ctx);
        }
    }

    /// How deep a press goes (mm): the primary button's depth, a tablet's at full pressure.
    pub fn set_press_mm(&mut self, mm: f64) {
        self.press_mm = mm;
    }

    /// The hand the app drives the device with.
    pub fn hand(&self) -> HandInput {
        self.hand
    }

    /// The hand's input: the mouse, or a pen tablet (with its pressure curve).
    fn tablet_chooser(&mut self, ui: &mut egui::Ui) {
        let current = match &self.tablet_status {
            Some(s) if self.tablet.is_some() => s.name.clone(),
            _ => "mouse / window pen".to_string(),
        };
        let mut picked: Option<String> = None;
        egui::ComboBox::from_label("hand")
            .selected_text(current)
            .show_ui(ui, |ui| {
                if ui
                    .selectable_label(self.tablet.is_none(), "mouse / window pen")
                    .clicked()
                {
                    picked = Some(String::new());
                }
                for t in self.tablets.clone() {
                    if ui.selectable_label(false, t.label()).clicked() {
                        picked = Some(t.path.display().to_string());
                    }
                }
            })
            .response
            .on_hover_text("Pen tablets: pressure presses the brush, tilt tilts it");
        if ui
            .button("Find tablets")
            .on_hover_text("List the pen tablets this machine has (Linux evdev)")
            .clicked()
        {
            self.tablets = crate::tablet::list();
            self.message = Some((
                if self.tablets.is_empty() {
                    "no pen tablet found (on Linux, is your user in the `input` group?)".into()
                } else {
                    format!("{} pen tablet(s) found", self.tablets.len())
                },
                self.tablets.is_empty(),
            ));
        }
        if let Some(path) = picked {
            if let Err(e) = self.use_tablet(Path::new(&path)) {
                self.message = Some((e.to_string(), true));
            }
        }
        let current = self.tablet_path.clone();
        self.browse_open(ui, FileKind::TabletRecording, &current);
        if self.tablet.is_some() {
            let mut c = self.pressure_curve;
            ui.add(
                egui::Slider::new(&mut c.exponent, PressureCurve::EXPONENT)
                    .logarithmic(true)
                    .text("pressure curve"),
            )
            .on_hover_text("Above 1: light pressure lighter; below 1: heavier");
            ui.add(
                egui::Slider::new(&mut c.threshold, PressureCurve::THRESHOLD)
                    .text("pressure threshold"),
            );
            self.pressure_curve = c;
        }
    }

    /// Draws the brush's position on the paper view.
    fn overlay(&self, ui: &egui::Ui) {
        let Some(f) = &self.latest else { return };
        let p = f.pose.pos.to_f64();
        let at = self.paper.mm_to_screen(p[0], p[1]);
        let painter = ui.painter_at(self.paper.view_rect);
        let c = if f.contacts() > 0 {
            Color32::from_rgb(220, 60, 50)
        } else {
            Color32::from_rgb(60, 110, 220)
        };
        painter.circle_stroke(at, 6.0, egui::Stroke::new(1.5, c));
        painter.line_segment(
            [at - egui::vec2(10.0, 0.0), at + egui::vec2(10.0, 0.0)],
            (1.0, c),
        );
        painter.line_segment(
            [at - egui::vec2(0.0, 10.0), at + egui::vec2(0.0, 10.0)],
            (1.0, c),
        );
    }
}

impl MaobiApp {
    /// One frame of the whole UI into `ui` (the root).
    pub fn frame_ui(&mut self, ui: &mut egui::Ui) {
        let begin = Instant::now();
        let ctx = ui.ctx().clone();
        if self.fonts.is_none() {
            self.fonts = Some(super::fonts::setup(&ctx, &self.font_source));
        }
        let interval = self.times.last.map(|l| (begin - l).as_secs_f64() * 1e3);
        self.times.prev_begin = self.times.last;
        self.times.last = Some(begin);
        self.pump();
        self.practice.poll();
        let drawing = self.status.replaying || self.latest.as_ref().is_some_and(|f| f.replaying);

        self.take_dialog_answer(&ctx);
        self.shortcuts(&ctx);
        let pointer = match self.face {
            Face::Laboratory => self.laboratory(ui),
            Face::Writing => self.writing(ui),
        };
        super::about::about_window(&ctx, &mut self.show_about);
        self.hand_input(&ctx, pointer);
        self.finish_open(&ctx);
        self.automation(&ctx);
        self.keep_layout(&ctx);
        if self.practice.busy() {
            ctx.request_repaint_after(Duration::from_millis(50));
        }

        let ui_ms = begin.elapsed().as_secs_f64() * 1e3;
        // The ink of this frame's device frames has been uploaded (in `paper.show`): how
        // long the oldest of them waited since it arrived.
        if let Some(o) = self.times.oldest_inked.take() {
            self.times.ink_latency.push(o.elapsed().as_secs_f64() * 1e3);
        }
        if let Some(iv) = interval {
            push(
                &mut self.times.recent,
                [self.started.elapsed().as_secs_f64(), iv],
            );
            if drawing {
                self.times.replay_interval.push(iv);
                self.times.replay_ui.push(ui_ms);
            }
        }
        // A live view: ~60 frames per second while connected.
        ctx.request_repaint_after(Duration::from_millis(15));
    }
    /// The laboratory: devices, parameters, plots, file fields, the stroke editor, the
    /// paper in the middle. The paper's pointer this frame.
    fn laboratory(&mut self, ui: &mut egui::Ui) -> super::canvas::PaperPointer {
        egui::Panel::top("toolbar").show(ui, |ui| self.toolbar(ui));
        egui::Panel::bottom("status").show(ui, |ui| self.status_bar(ui));
        if self.show_timeline {
            let mut action = None;
            egui::Panel::bottom("timeline")
                .resizable(true)
                .default_size(230.0)
                .show(ui, |ui| {
                    action = self
                        .timeline
                        .ui(ui, self.replay_frames, self.latest.as_ref());
                });
            if let Some(a) = action {
                self.timeline_action(a);
            }
        }
        egui::Panel::left("params")
            .resizable(true)
            .default_size(260.0)
            .show(ui, |ui| self.params_panel(ui));
        egui::Panel::right("views")
            .resizable(true)
            .default_size(380.0)
            .show(ui, |ui| {
                let h = ui.available_height() * 0.55;
                ui.allocate_ui(egui::vec2(ui.available_width(), h), |ui| {
                    self.brush_rect = brush_view::show(ui, &mut self.orbit, self.latest.as_ref());
                });
                self.plots(ui);
            });
        let mut pointer = super::canvas::PaperPointer::default();
        egui::CentralPanel::default().show(ui, |ui| {
            let (_, p) = self.paper.show(ui);
            pointer = p;
            self.overlay(ui);
            self.paper_marks(ui);
            if self.show_timeline {
                let anchor = self.latest.as_ref().and_then(|f| f.guide.map(|g| g.anchor));
                if self
                    .timeline
                    .paper_overlay(ui, &self.paper, p.mm, p.pressed, anchor)
                {
                    // Editing keyframes: the pen stays up.
                    pointer.pressed = false;
                }
            }
        });
        pointer
    }

    /// The writing view: the paper as large as the window allows, one row of tools, a
    /// compact status line and a small brush view over the paper's corner.
    fn writing(&mut self, ui: &mut egui::Ui) -> super::canvas::PaperPointer {
        egui::Panel::top("toolbar").show(ui, |ui| self.writing_toolbar(ui));
        egui::Panel::bottom("status").show(ui, |ui| self.writing_status(ui));
        if self.practice.open {
            let guiding = self.latest.as_ref().is_some_and(|f| f.guide.is_some());
            let (preset, params) = (self.status.preset.clone(), self.status.params);
            let mut action = None;
            egui::Panel::right("practice")
                .resizable(true)
                .default_size(300.0)
                .show(ui, |ui| {
                    egui::ScrollArea::vertical().show(ui, |ui| {
                        action = self.practice.ui(ui, &preset, params, guiding);
                    });
                });
            if let Some(a) = action {
                self.practice_action(a);
            }
        }
        let mut pointer = super::canvas::PaperPointer::default();
        egui::CentralPanel::default()
            .frame(egui::Frame::NONE)
            .show(ui, |ui| {
                let (_, p) = self.paper.show(ui);
                pointer = p;
                self.paper_marks(ui);
            });
        self.brush_rect = egui::Rect::NOTHING;
        if self.show_brush_view {
            let view = self.paper.view_rect;
            egui::Area::new(egui::Id::unique("brush view"))
                .fixed_pos(view.right_top() + egui::vec2(-BRUSH_VIEW_PT - 28.0, 12.0))
                .order(egui::Order::Foreground)
                .show(ui.ctx(), |ui| {
                    egui::Frame::popup(ui.style()).show(ui, |ui| {
                        ui.set_max_size(egui::vec2(BRUSH_VIEW_PT, BRUSH_VIEW_PT));
                        ui.allocate_ui(egui::vec2(BRUSH_VIEW_PT, BRUSH_VIEW_PT), |ui| {
                            self.brush_rect =
                                brush_view::show(ui, &mut self.orbit, self.latest.as_ref());
                        });
                    });
                });
        }
        pointer
    }

    /// The grid and the brush's mark over the paper (both faces).
    fn paper_marks(&mut self, ui: &egui::Ui) {
        let painter = ui.painter_at(self.paper.view_rect);
        draw_grid(&painter, &self.paper, self.grid);
        super::practice::draw(&painter, &self.paper, &self.practice);
        let length = self.status.params.length_mm as f64;
        self.mark = self.latest.as_ref().and_then(|f| brush_mark(f, length));
        if let Some(m) = &self.mark {
            draw_mark(&painter, &self.paper, m, length);
        }
    }

    /// The writing view's one row: the face switch, brush, ink, paper, grid, edits, picture.
    fn writing_toolbar(&mut self, ui: &mut egui::Ui) {
        ui.horizontal_wrapped(|ui| {
            if ui
                .button("Laboratory")
                .on_hover_text("Devices, parameters, plots, files, recordings, sessions, the stroke editor (F2)")
                .clicked()
            {
                self.face = Face::Laboratory;
            }
            ui.separator();
            self.brush_controls(ui);
            ui.separator();
            self.dip_controls(ui);
            ui.separator();
            self.paper_controls(ui);
            egui::ComboBox::from_label("grid")
                .selected_text(self.grid.label())
                .show_ui(ui, |ui| {
                    for g in Grid::ALL {
                        ui.selectable_value(&mut self.grid, g, g.label());
                    }
                })
                .response
                .on_hover_text("A practice grid over the paper, not in the picture (G)");
            ui.separator();
            self.edit_buttons(ui);
            if ui
                .button("Save picture")
                .on_hover_text(format!("The paper as a PNG to {} (Ctrl+S)", self.save_path))
                .clicked()
            {
                self.save_picture(ui.ctx());
            }
            let current = self.save_path.clone();
            self.browse_save(ui, FileKind::Png, &current);
            ui.separator();
            ui.toggle_value(&mut self.practice.open, "Practice")
                .on_hover_text("Copy a master's character: trace or copy it, watch it, be guided, write, score (P)");
            ui.toggle_value(&mut self.show_brush_view, "Brush view")
                .on_hover_text("The brush in 3D over the paper's corner (B)");
        });
        self.message_line(ui);
    }

    /// The writing view's status line: the device, and only what needs the writer's eye
    /// (faults, a recording, a missing font).
    fn writing_status(&mut self, ui: &mut egui::Ui) {
        let s = &self.status;
        ui.horizontal(|ui| {
            ui.label(RichText::new(s.name.clone()).strong());
            if !s.connected {
                ui.label(RichText::new("disconnected").color(Color32::from_rgb(230, 80, 70)));
            }
            if !s.faults.is_empty() {
                ui.label(RichText::new(s.faults.join("; ")).color(Color32::from_rgb(230, 80, 70)));
            }
            if s.replaying {
                ui.label("replaying");
            }
            if self.recorder.is_some() {
                ui.label(RichText::new("REC").color(Color32::from_rgb(230, 60, 60)));
            }
            if let Some(Err(m)) = &self.fonts {
                ui.label(RichText::new("no CJK font").color(Color32::from_rgb(220, 180, 60)))
                    .on_hover_text(m);
            }
            ui.with_layout(egui::Layout::right_to_left(egui::Align::Center), |ui| {
                ui.toggle_value(&mut self.show_about, "About")
                    .on_hover_text("The version, the licences and the fonts (F1)");
            });
        });
    }

    /// Saves the paper to the picture path (Ctrl+S, "Save picture").
    pub fn save_picture(&mut self, ctx: &egui::Context) {
        let path = PathBuf::from(&self.save_path);
        self.file_action(FileKind::Png, &path, ctx);
    }

    /// The keyboard shortcuts of both faces, unless a text field has the keyboard.
    fn shortcuts(&mut self, ctx: &egui::Context) {
        use egui::{Key, KeyboardShortcut, Modifiers};
        if ctx.egui_wants_keyboard_input() {
            return;
        }
        let ctrl = |k| KeyboardShortcut::new(Modifiers::COMMAND, k);
        let plain = |k| KeyboardShortcut::new(Modifiers::NONE, k);
        let fired = |s: KeyboardShortcut| ctx.input_mut(|i| i.consume_shortcut(&s));
        if fired(ctrl(Key::Z)) {
            self.undo();
        }
        if fired(KeyboardShortcut::new(
            Modifiers::COMMAND | Modifiers::SHIFT,
            Key::S,
        )) {
            let current = self.save_path.clone();
            self.ask_file(Purpose::Save(FileKind::Png), &current);
        }
        if fired(ctrl(Key::S)) {
            self.save_picture(ctx);
        }
        if fired(ctrl(Key::N)) {
            self.clear();
        }
        if fired(ctrl(Key::Q)) {
            // eframe keeps the settings and runs `on_exit` on the way out.
            ctx.send_viewport_cmd(egui::ViewportCommand::Close);
        }
        if fired(plain(Key::F1)) {
            self.show_about = !self.show_about;
        }
        if fired(plain(Key::F2)) {
            self.face = self.face.other();
        }
        if fired(plain(Key::D)) {
            self.dip();
        }
        if fired(plain(Key::F)) {
            self.paper.fit();
        }
        if fired(plain(Key::B)) {
            self.show_brush_view = !self.show_brush_view;
        }
        if fired(plain(Key::P)) {
            // The practice panel lives in the writing view.
            self.practice.open = self.face == Face::Laboratory || !self.practice.open;
            self.face = Face::Writing;
        }
        if fired(plain(Key::G)) {
            let i = Grid::ALL.iter().position(|g| *g == self.grid).unwrap_or(0);
            self.grid = Grid::ALL[(i + 1) % Grid::ALL.len()];
        }
    }
}

impl eframe::App for MaobiApp {
    fn ui(&mut self, ui: &mut egui::Ui, frame: &mut eframe::Frame) {
        self.frame_ui(ui);
        let ctx = ui.ctx().clone();
        self.show_file_dialog(&ctx, Some(frame));
    }

    /// Keeps the settings for the next run, except from automated runs (`--replay`,
    /// `--screenshot`, `--session`), which must not change what a user's next start shows.
    fn save(&mut self, storage: &mut dyn eframe::Storage) {
        if !self.automation.is_active() {
            eframe::set_value(storage, super::files::SETTINGS_KEY, &self.settings());
        }
    }

    fn on_exit(&mut self, _gl: Option<&eframe::glow::Context>) {
        if self
            .outcome
            .lock()
            .map(|o| o.summary.is_empty())
            .unwrap_or(false)
        {
            self.finish_summary();
        }
        self.device.disconnect();
    }
}

fn write_recording(r: &Recorder) -> anyhow::Result<usize> {
    if let Some(dir) = r.path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir)?;
    }
    let file = std::fs::File::create(&r.path)
        .with_context(|| format!("cannot create {}", r.path.display()))?;
    let mut w = std::io::BufWriter::new(file);
    writeln!(w, "t,x,y,z,qw,qx,qy,qz")?;
    for (tick, pose) in &r.rows {
        let t = (tick - r.first_tick) as f64 * 1e-3;
        let p = pose.pos.to_f64();
        let q = pose.rot.to_f64();
        writeln!(
            w,
            "{t:.3},{:.4},{:.4},{:.4},{:.9},{:.9},{:.9},{:.9}",
            p[0], p[1], p[2], q[0], q[1], q[2], q[3]
        )?;
    }
    w.flush()
        .with_context(|| format!("cannot write {}", r.path.display()))?;
    Ok(r.rows.len())
}

/// Records the frames' poses as a pose CSV (for tests and scripting).
pub fn record_frames(path: &Path, frames: &[BrushFrame]) -> anyhow::Result<usize> {
    let r = Recorder {
        path: path.to_path_buf(),
        first_tick: frames.first().map_or(0, |f| f.tick),
        rows: frames.iter().map(|f| (f.tick, f.pose)).collect(),
    };
    write_recording(&r)
}
