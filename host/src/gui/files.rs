//! The app's files: the platform's own file dialogs (through `rfd`: the XDG desktop portal or
//! zenity on Linux, the system dialogs on Windows and macOS), the recent files of each kind,
//! and the settings the app keeps between runs.
//!
//! The text fields beside each button stay: they are what automation and tests type into,
//! and what a user without a dialog service (a bare X server, a remote shell) still has.
//!
//! A dialog never freezes the window: a frame asks for one ([`DialogRequest`]), the app shows
//! it after the frame with its window as the dialog's parent (so it sits on the window), on
//! a thread of its own ([`RunningDialog`]), and a later frame takes the answer.

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use serde::{Deserialize, Serialize};

use crate::device::ModelKind;

/// The kinds of file the app opens and saves.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum FileKind {
    /// The paper as an image.
    Png,
    /// A pose recording or a pose file to replay (`t,x,y,z,qw,qx,qy,qz`).
    Poses,
    /// A session (`*.maobi.toml`).
    Session,
    /// A keyframed stroke file (TOML).
    Stroke,
    /// A tablet recording (`evemu-record`'s format).
    TabletRecording,
}

impl FileKind {
    pub const ALL: [FileKind; 5] = [
        FileKind::Png,
        FileKind::Poses,
        FileKind::Session,
        FileKind::Stroke,
        FileKind::TabletRecording,
    ];

    pub fn label(self) -> &'static str {
        match self {
            FileKind::Png => "PNG image",
            FileKind::Poses => "pose file",
            FileKind::Session => "session",
            FileKind::Stroke => "stroke file",
            FileKind::TabletRecording => "tablet recording",
        }
    }

    /// The dialog's filter: its name and extensions.
    fn filter(self) -> (&'static str, &'static [&'static str]) {
        match self {
            FileKind::Png => ("PNG image", &["png"]),
            FileKind::Poses => ("Pose CSV", &["csv"]),
            // `*.maobi.toml` is a TOML file to the dialogs, which match the last extension.
            FileKind::Session => ("Maobi session", &["toml"]),
            FileKind::Stroke => ("Stroke file", &["toml"]),
            FileKind::TabletRecording => ("evemu recording", &["evemu", "txt"]),
        }
    }

    fn dialog(self, current: &str) -> rfd::FileDialog {
        let (name, ext) = self.filter();
        let mut d = rfd::FileDialog::new()
            .set_title(format!("Maobi: {}", self.label()))
            .add_filter(name, ext)
            .add_filter("All files", &["*"]);
        let current = Path::new(current.trim());
        let dir = if current.is_dir() {
            Some(current)
        } else {
            current.parent().filter(|p| p.is_dir())
        };
        if let Some(dir) = dir {
            d = d.set_directory(dir);
        }
        if let Some(name) = current.file_name() {
            d = d.set_file_name(name.to_string_lossy());
        }
        d
    }
}

/// What a file chosen in a dialog is for.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub enum Purpose {
    /// To open as its kind.
    Open(FileKind),
    /// To save the paper, a recording, the session or the strokes to.
    Save(FileKind),
}

/// A file dialog a frame asked for: shown after the frame, when the window is at hand.
#[derive(Clone, Debug, PartialEq)]
pub struct DialogRequest {
    pub purpose: Purpose,
    /// The file field's text: where the dialog starts.
    pub current: String,
}

impl DialogRequest {
    /// Shows the platform's dialog on its own thread, modal to `parent` when there is one;
    /// `ctx` is woken when it is answered. An error if no thread could be started.
    pub fn show(
        self,
        parent: Option<&eframe::Frame>,
        ctx: egui::Context,
    ) -> std::io::Result<RunningDialog> {
        let kind = match self.purpose {
            Purpose::Open(k) | Purpose::Save(k) => k,
        };
        let mut dialog = kind.dialog(&self.current);
        if let Some(w) = parent {
            dialog = dialog.set_parent(w);
        }
        let answer = Arc::new(Mutex::new(None));
        let slot = answer.clone();
        let save = matches!(self.purpose, Purpose::Save(_));
        std::thread::Builder::new()
            .name("file dialog".into())
            .spawn(move || {
                let path = if save {
                    dialog.save_file()
                } else {
                    dialog.pick_file()
                };
                if let Ok(mut s) = slot.lock() {
                    *s = Some(path);
                }
                ctx.request_repaint();
            })?;
        Ok(RunningDialog {
            purpose: self.purpose,
            answer,
        })
    }
}

/// A file dialog on screen, the window drawing on meanwhile.
#[derive(Debug)]
pub struct RunningDialog {
    pub purpose: Purpose,
    /// `Some(path)` once answered (`None` inside: cancelled, or no dialog service).
    answer: Arc<Mutex<Option<Option<PathBuf>>>>,
}

impl RunningDialog {
    /// The answer, once the dialog has closed.
    pub fn answered(&self) -> Option<Option<PathBuf>> {
        self.answer.lock().ok().and_then(|mut a| a.take())
    }
}

/// How many recent files of each kind are kept.
pub const RECENT_PER_KIND: usize = 8;

/// Recently used files, newest first, per kind.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Recent {
    entries: Vec<(FileKind, PathBuf)>,
}

impl Recent {
    /// Puts `path` first among its kind's (once), dropping the oldest past the limit.
    pub fn add(&mut self, kind: FileKind, path: &Path) {
        let path = std::fs::canonicalize(path).unwrap_or_else(|_| path.to_path_buf());
        self.entries.retain(|(k, p)| !(*k == kind && *p == path));
        self.entries.insert(0, (kind, path));
        let mut seen = 0;
        self.entries.retain(|(k, _)| {
            if *k == kind {
                seen += 1;
                seen <= RECENT_PER_KIND
            } else {
                true
            }
        });
    }

    /// `kind`'s recent files, newest first.
    pub fn of(&self, kind: FileKind) -> impl Iterator<Item = &Path> {
        self.entries
            .iter()
            .filter(move |(k, _)| *k == kind)
            .map(|(_, p)| p.as_path())
    }

    /// Forgets files that are gone (shown greyed out would only invite an error).
    pub fn prune_missing(&mut self) {
        self.entries.retain(|(_, p)| p.exists());
    }
}

/// The kinds of device the chooser offers (kept between runs).
#[derive(Copy, Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum DeviceKind {
    Sim,
    Tcp,
    Serial,
    /// A Phantom Omni / Geomagic Touch through OpenHaptics' libHD, in this process.
    Phantom,
}

impl DeviceKind {
    /// What the chooser calls it.
    pub fn label(self) -> &'static str {
        match self {
            DeviceKind::Sim => "built-in simulator",
            DeviceKind::Tcp => "TCP (QEMU board, sim-device, bridge)",
            DeviceKind::Serial => "serial (the pen on USB)",
            DeviceKind::Phantom => "Phantom (OpenHaptics libHD)",
        }
    }
}

/// What the app remembers between runs (eframe's storage; the window's size and place are
/// eframe's own). Fields missing from an older file take their defaults; a file that does not
/// parse at all (edited by hand, say) is ignored and the app starts with the defaults, never
/// an error at start.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Settings {
    /// The device chooser's last choice and its address (HOST:PORT, the serial port, libHD's
    /// path). The app starts on the built-in simulator whatever it was: a force device is
    /// connected by a click, not by a start.
    pub device_kind: DeviceKind,
    pub device_addr: String,
    /// The brush preset (or Baxter & Lin's head).
    pub brush: String,
    /// The brush model the built-in simulator runs.
    pub model: ModelKind,
    /// The pen tablet in use (its evdev node), if any.
    pub tablet: Option<PathBuf>,
    pub pressure_exponent: f32,
    pub pressure_threshold: f32,
    /// The paper's size (mm, square) and resolution (px/mm).
    pub paper_mm: f64,
    pub px_per_mm: f64,
    /// The file fields as last used.
    pub png_path: String,
    pub record_path: String,
    pub replay_path: String,
    pub session_path: String,
    pub recent: Recent,
    /// The face the app was left in (the writing view or the laboratory), the writing view's
    /// grid, and whether it showed the brush.
    pub face: crate::gui::writing::Face,
    pub grid: crate::gui::writing::Grid,
    pub show_brush_view: bool,
}

impl Default for Settings {
    fn default() -> Self {
        Settings {
            device_kind: DeviceKind::Sim,
            device_addr: String::new(),
            brush: "large".into(),
            model: ModelKind::Liang,
            tablet: None,
            pressure_exponent: 1.0,
            pressure_threshold: 0.02,
            paper_mm: 200.0,
            px_per_mm: 10.0,
            png_path: "out/maobi-canvas.png".into(),
            record_path: "out/maobi-recording.csv".into(),
            replay_path: "examples/poses/hook.csv".into(),
            session_path: "out/maobi-session.maobi.toml".into(),
            recent: Recent::default(),
            face: Default::default(),
            grid: Default::default(),
            show_brush_view: true,
        }
    }
}

/// The key the settings are stored under in eframe's storage.
pub const SETTINGS_KEY: &str = "maobi-settings";
