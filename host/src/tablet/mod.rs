//! Pen tablets (Wacom, XP-Pen, Huion) as the hand: the stylus's pressure drives the brush's
//! depth and its tilt the brush's tilt; the pointer still comes from the window system, which
//! already moves the cursor with the tablet.
//!
//! The pieces, from the wire inwards:
//! * [`live`] (Linux): the tablet's evdev node (`/dev/input/eventN`) read on a thread through
//!   the `evdev` crate. winit, and so egui, reports neither pressure nor tilt on X11, so the
//!   kernel's own events are the one source that carries both.
//! * [`recording`]: the same events from a file in the format `evemu-record` writes, replayed
//!   along the model's clock (tests, bug reports, and users without a tablet at hand).
//! * [`Decoder`]: evdev's event protocol (frames closed by `SYN_REPORT`; after `SYN_DROPPED`
//!   the next frame discarded and the device's state taken from its [`PenStateSource`])
//!   turned into [`Reading`]s with the axes' ranges applied.
//! * [`PressureCurve`] and [`Reading::hand`]: what a reading does to the hand.
//!
//! Event codes are the kernel's (`linux/input-event-codes.h`), kept as plain numbers here so
//! that decoding, recordings and their tests build on every platform.

pub mod recording;

#[cfg(target_os = "linux")]
pub mod live;

use std::path::Path;
use std::time::Duration;

pub mod decode;
pub mod error;

pub use decode::*;
pub use error::TabletError;
pub use recording::{Recording, RecordingError};

/// The pen tablets this process can open. Devices it may not open (no permission) are left
/// out; [`Tablet::open`] on one says why.
pub fn list() -> Vec<TabletInfo> {
    #[cfg(target_os = "linux")]
    {
        live::list()
    }
    #[cfg(not(target_os = "linux"))]
    {
        Vec::new()
    }
}

/// A tablet in use: a live device or a recording being replayed.
pub enum Tablet {
    #[cfg(target_os = "linux")]
    Live(live::LiveTablet),
    Replay(recording::Replay),
}

impl Tablet {
    /// Opens `path`: an evdev node (`/dev/input/eventN`), or a recording (any other file)
    /// replayed along the model's clock.
    pub fn open(path: &Path) -> Result<Tablet, TabletError> {
        if path.starts_with("/dev") {
            #[cfg(target_os = "linux")]
            {
                return live::LiveTablet::open(path).map(Tablet::Live);
            }
            #[cfg(not(target_os = "linux"))]
            {
                return Err(TabletError::Unsupported {
                    path: path.to_path_buf(),
                });
            }
        }
        let rec = Recording::from_path(path).map_err(TabletError::Recording)?;
        Ok(Tablet::Replay(recording::Replay::new(rec)))
    }

    /// A device, not a recording.
    pub fn is_live(&self) -> bool {
        !matches!(self, Tablet::Replay(_))
    }

    /// Moves a replay on by `model_time` (the model's clock: what the device ran since the
    /// last call) and returns the tablet's state. Live tablets run on their own thread.
    pub fn poll(&mut self, model_time: Duration) -> TabletStatus {
        match self {
            #[cfg(target_os = "linux")]
            Tablet::Live(t) => t.status(),
            Tablet::Replay(r) => {
                r.advance(model_time);
                r.status()
            }
        }
    }
}
