//! Why a tablet cannot be used, from either source (the live device or a recording).

use std::fmt;
use std::path::PathBuf;

use super::recording::RecordingError;

/// Why a tablet cannot be used.
#[derive(Debug)]
pub enum TabletError {
    /// The path names neither an evdev device nor a readable recording.
    Open {
        path: PathBuf,
        reason: String,
    },
    /// The device has no pressure axis: it is a mouse, a touchpad or a keyboard.
    NotAPen {
        path: PathBuf,
        name: String,
    },
    Recording(RecordingError),
    /// Live tablets are read through Linux's evdev; other platforms give the app pressure
    /// through the window system instead.
    Unsupported {
        path: PathBuf,
    },
}

impl fmt::Display for TabletError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            TabletError::Open { path, reason } => {
                write!(f, "cannot open the tablet {}: {reason}", path.display())
            }
            TabletError::NotAPen { path, name } => write!(
                f,
                "{} ({name}) reports no pen pressure: it is not a pen tablet's stylus (try the \
                 device whose name ends in \"Pen\" or \"Stylus\")",
                path.display()
            ),
            TabletError::Recording(e) => e.fmt(f),
            TabletError::Unsupported { path } => write!(
                f,
                "cannot read {}: live tablets are read through Linux's evdev; on this platform \
                 the app takes pen pressure from the window system",
                path.display()
            ),
        }
    }
}

impl std::error::Error for TabletError {}
