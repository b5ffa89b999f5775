//! The desktop GUI (eframe over glow) with two faces: the writing view (the paper first) and
//! the laboratory (the paper with the brush in 3D, live plots, controls and a status bar), over a [`Device`](crate::device::Device) (the built-in
//! simulator, a device over the wire protocol or the Phantom: see [`crate::device`]).
//!
//! * [`choice`]: which device the GUI opens ([`DeviceChoice`]) and opening it.
//! * [`canvas`]: the paper view (ink, partial texture uploads, zoom, pan, undo).
//! * [`brush_view`]: the brush in 3D.
//! * [`app`]: the application and its automation (`--replay`, `--screenshot`).
//! * [`files`]: file dialogs, recent files and the settings kept between runs.
//! * [`writing`]: the writing view's faces, grid and the brush's mark over the paper.
//! * [`timeline`]: the stroke editor (keyframed strokes on a timeline, guided writing).
//! * [`session`]: session files (`.maobi.toml`): the device's journal and the paper's history.
//! * [`rerender`]: a session run again through the built-in device onto a fresh paper.
//! * [`icon`]: the window's icon, drawn in code.
//! * [`about`]: the About window: the version, the build, and the licences.

pub mod about;
pub mod app;
pub mod brush_view;
pub mod canvas;
pub mod choice;
pub mod files;
pub mod fonts;
pub mod icon;
pub mod message;
pub mod practice;
pub mod rerender;
pub mod session;
pub mod timeline;
pub mod writing;

use std::path::PathBuf;
use std::sync::{Arc, Mutex};

use anyhow::bail;

use crate::raster::Frame;
use app::{Automation, MaobiApp, Outcome};
pub use choice::{make_device, start_hand, DeviceChoice};

/// What the headless commands are, for the error when there is no display.
pub const HEADLESS_HINT: &str = "without a display, use the headless commands: \
`maobi render --poses FILE.csv -o OUT.png` (ink to PNG) or `maobi trace --poses FILE.csv -o TRACE.csv`; \
or run the GUI under a virtual display: `xvfb-run -a maobi gui ...`";

/// `--device phantom`: where libHD is (`None`: `$MAOBI_HD_LIB`, the install paths).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PhantomChoice {
    pub hd_lib: Option<PathBuf>,
}

/// Options of `maobi gui`.
#[derive(Clone, Debug)]
pub struct GuiOptions {
    /// The device to connect to at start.
    pub device: DeviceChoice,
    /// A Phantom instead of `device` (falling back to the built-in simulator, with the reason
    /// in the status bar, when it cannot be used).
    pub phantom: Option<PhantomChoice>,
    /// Brush preset name (with Baxter & Lin's model also one of their heads).
    pub brush: String,
    /// The brush model the built-in simulator runs.
    pub model: crate::device::ModelKind,
    pub replay: Option<PathBuf>,
    pub screenshot: Option<PathBuf>,
    /// A session file to open at start.
    pub session: Option<PathBuf>,
    /// Where "Save picture" (Ctrl+S) writes (`None`: as last used).
    pub picture: Option<PathBuf>,
    /// The face to open with (`None`: the one left open last, else the writing view).
    pub face: Option<writing::Face>,
    /// Practise this character at start (`maobi gui --practice`).
    pub practice: Option<String>,
    /// The paper's kind at start.
    pub paper_kind: crate::paper::PaperKind,
    /// Paper size (mm, square, centred on the origin) and resolution.
    pub paper_mm: f64,
    pub px_per_mm: f64,
    /// A pen tablet (evdev node or recording) for the hand.
    pub tablet: Option<PathBuf>,
    /// The tablet's pressure curve: exponent and threshold.
    pub pressure_curve: (f32, f32),
    /// Which of these the user gave (on the command line): those win over what the last run
    /// left; the rest start as it left them.
    pub given: Given,
}

/// Options the user set for this run, as opposed to defaults.
#[derive(Copy, Clone, Debug, Default, PartialEq, Eq)]
pub struct Given {
    pub device: bool,
    /// The brush, or its model.
    pub brush: bool,
    /// The tablet or its pressure curve.
    pub tablet: bool,
    /// The paper's size or resolution.
    pub paper: bool,
}

impl Default for GuiOptions {
    fn default() -> Self {
        GuiOptions {
            device: DeviceChoice::Sim,
            phantom: None,
            brush: "large".into(),
            model: crate::device::ModelKind::Liang,
            paper_kind: crate::paper::PaperKind::Sized,
            replay: None,
            screenshot: None,
            session: None,
            picture: None,
            face: None,
            practice: None,
            paper_mm: 200.0,
            px_per_mm: 10.0,
            tablet: None,
            pressure_curve: (1.0, 0.02),
            given: Given::default(),
        }
    }
}

impl GuiOptions {
    /// The paper's frame: `paper_mm` square centred on the origin.
    pub fn frame(&self) -> Frame {
        paper_frame(self.paper_mm, self.px_per_mm)
    }
}

/// The paper's frame: `paper_mm` square centred on the origin at `px_per_mm`.
pub fn paper_frame(paper_mm: f64, px_per_mm: f64) -> Frame {
    let h = paper_mm / 2.0;
    Frame::covering([-h, -h], [h, h], 0.0, px_per_mm)
}

/// The paper the GUI can show: positive sizes, at most 8192 px a side.
pub fn check_paper(paper_mm: f64, px_per_mm: f64) -> anyhow::Result<Frame> {
    if !(px_per_mm.is_finite() && px_per_mm > 0.0) {
        bail!("--px-per-mm must be a positive number");
    }
    if !(paper_mm.is_finite() && paper_mm > 0.0) {
        bail!("--paper-mm must be a positive number");
    }
    let frame = paper_frame(paper_mm, px_per_mm);
    if frame.width > 8192 || frame.height > 8192 {
        bail!(
            "the paper would be {} x {} px; the GUI shows at most 8192 x 8192: use a smaller --paper-mm or --px-per-mm",
            frame.width,
            frame.height
        );
    }
    Ok(frame)
}

/// Whether there is a display to open a window on.
pub fn have_display() -> bool {
    if cfg!(any(target_os = "windows", target_os = "macos")) {
        return true;
    }
    ["DISPLAY", "WAYLAND_DISPLAY"]
        .iter()
        .any(|v| std::env::var_os(v).is_some_and(|s| !s.is_empty()))
}

/// Opens the GUI and runs it until the window closes (or the automation finishes).
pub fn run(opts: GuiOptions) -> anyhow::Result<()> {
    let frame = check_paper(opts.paper_mm, opts.px_per_mm)?;
    // Check the inputs before opening a window.
    if let Some(p) = &opts.replay {
        crate::poses::PoseTrack::from_path(p)?;
    }
    crate::device::BrushChoice::for_model(&opts.brush, opts.model)
        .map_err(|e| anyhow::anyhow!("--brush: {e}"))?;
    let curve = crate::tablet::PressureCurve::new(opts.pressure_curve.0, opts.pressure_curve.1)
        .map_err(|e| anyhow::anyhow!("--pressure-curve / --pressure-threshold: {e}"))?;
    // A tablet that cannot be opened is an error before any window opens.
    let tablet_path = opts.tablet.clone();
    let tablet = opts
        .tablet
        .as_deref()
        .map(crate::tablet::Tablet::open)
        .transpose()?;
    if !have_display() {
        bail!("no display: neither DISPLAY nor WAYLAND_DISPLAY is set; {HEADLESS_HINT}");
    }
    let choice = opts.device.clone();
    let phantom = opts.phantom.clone();
    let brush = opts.brush.clone();
    let model = opts.model;
    let paper_kind = opts.paper_kind;
    let picture = opts.picture.clone();
    let face = opts.face;
    let outcome = Arc::new(Mutex::new(Outcome::default()));
    let automation = Automation {
        replay: opts.replay.clone(),
        screenshot: opts.screenshot.clone(),
        session: opts.session.clone(),
        practice: opts.practice.clone(),
        layout: std::env::var_os(app::LAYOUT_ENV)
            .filter(|v| !v.is_empty())
            .map(PathBuf::from),
    };
    let automated = automation.is_active();
    let given = Given {
        tablet: opts.given.tablet || opts.tablet.is_some(),
        device: opts.given.device || phantom.is_some(),
        ..opts.given
    };
    let native = eframe::NativeOptions {
        renderer: eframe::Renderer::Glow,
        viewport: egui::ViewportBuilder::default()
            .with_title("Maobi")
            .with_icon(icon::icon())
            .with_inner_size([1400.0, 900.0]),
        // An automated run (CI's screenshots) starts and ends the same everywhere.
        persist_window: !automated,
        ..Default::default()
    };
    let out2 = outcome.clone();
    let result = eframe::run_native(
        "maobi",
        native,
        Box::new(move |cc| {
            let saved: Option<files::Settings> = if automated {
                None
            } else {
                cc.storage
                    .and_then(|s| eframe::get_value(s, files::SETTINGS_KEY))
            };
            let (brush, model) = match &saved {
                Some(s)
                    if !given.brush
                        && crate::device::BrushChoice::for_model(&s.brush, s.model).is_ok() =>
                {
                    (s.brush.clone(), s.model)
                }
                _ => (brush, model),
            };
            let ctx = cc.egui_ctx.clone();
            let wake: Arc<dyn Fn() + Send + Sync> = Arc::new(move || ctx.request_repaint());
            let device = match &phantom {
                Some(p) => {
                    let length = crate::device::BrushChoice::parse(&brush)
                        .map(|b| b.params.length_mm as f64)
                        .unwrap_or(50.0);
                    crate::phantom::device::gui_device(
                        p.hd_lib.clone(),
                        model,
                        &brush,
                        start_hand(length),
                        Some(wake),
                    )?
                }
                None => make_device(&choice, &brush, model, Some(wake))?,
            };
            // The last run's paper, unless the command line gave one (a remembered paper that
            // no longer passes the checks is ignored).
            let frame = match &saved {
                Some(s) if !given.paper => check_paper(s.paper_mm, s.px_per_mm).unwrap_or(frame),
                _ => frame,
            };
            let mut app = MaobiApp::new(device, frame, automation, out2);
            app.set_paper(paper_kind);
            app.set_device_choice(&choice, &brush, model);
            if let Some(s) = &saved {
                app.restore(s, given.tablet);
                if given.device {
                    app.set_device_choice(&choice, &brush, model);
                }
            }
            if saved.is_none() || given.tablet {
                app.set_pressure_curve(curve);
            }
            if let (Some(t), Some(path)) = (tablet, &tablet_path) {
                app.set_tablet(t, path);
            }
            if let Some(p) = &phantom {
                app.choose_phantom(p.hd_lib.as_deref());
            }
            if let Some(p) = &picture {
                app.set_picture_path(p);
            }
            if let Some(f) = face {
                app.set_face(f);
            }
            Ok(Box::new(app))
        }),
    );
    let outcome = outcome.lock().map(|o| o.clone()).unwrap_or_default();
    for line in &outcome.summary {
        eprintln!("{line}");
    }
    if let Err(e) = result {
        bail!("cannot open the GUI window: {e}; {HEADLESS_HINT}");
    }
    if let Some(e) = outcome.error {
        bail!("{e}");
    }
    Ok(())
}
