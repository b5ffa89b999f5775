//! A pen tablet's evdev node, read on its own thread.
//!
//! The thread waits on the device with `poll(2)` and a short timeout, so that dropping the
//! [`LiveTablet`] stops it promptly, and hands each complete event frame to the [`Decoder`]
//! behind a mutex the app reads once per UI frame. After `SYN_DROPPED` the decoder asks the
//! device for its present keys and axes (`EVIOCGKEY`, `EVIOCGABS`: [`PenStateSource`] for
//! the raw device). An unplugged tablet makes the read fail (`ENODEV`): the thread records
//! why and ends, and the app falls back to the mouse.

use std::os::fd::AsRawFd;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;

use evdev::raw_stream::RawDevice;
use evdev::{AbsoluteAxisCode, KeyCode};

use super::decode::{
    Axes, AxisRange, Decoder, PenState, PenStateSource, TabletInfo, TabletStatus, EV_ABS, EV_KEY,
};
use super::error::TabletError;

/// How long the reader sleeps in `poll` before it looks at the stop flag again.
const POLL_MS: i32 = 100;

fn is_pen(dev: &RawDevice) -> bool {
    let pressure = dev
        .supported_absolute_axes()
        .is_some_and(|a| a.contains(AbsoluteAxisCode::ABS_PRESSURE));
    let pen = dev
        .supported_keys()
        .is_some_and(|k| k.contains(KeyCode::BTN_TOOL_PEN));
    pressure && pen
}

/// The pen tablets under `/dev/input` that this process may open.
pub fn list() -> Vec<TabletInfo> {
    let mut found: Vec<TabletInfo> = evdev::raw_stream::enumerate()
        .filter(|(_, dev)| is_pen(dev))
        .map(|(path, dev)| TabletInfo {
            name: dev.name().unwrap_or("unnamed tablet").to_string(),
            path,
        })
        .collect();
    found.sort_by(|a, b| a.path.cmp(&b.path));
    found
}

fn axes_of(dev: &RawDevice, path: &Path) -> Result<Axes, TabletError> {
    let open_err = |reason: String| TabletError::Open {
        path: path.to_path_buf(),
        reason,
    };
    let info = dev
        .get_absinfo()
        .map_err(|e| open_err(format!("reading its axes: {e}")))?;
    let mut pressure = None;
    let mut tilt_x = None;
    let mut tilt_y = None;
    for (code, abs) in info {
        let range = AxisRange {
            min: abs.minimum(),
            max: abs.maximum(),
            resolution: abs.resolution(),
        };
        match code {
            AbsoluteAxisCode::ABS_PRESSURE => pressure = Some(range),
            AbsoluteAxisCode::ABS_TILT_X => tilt_x = Some(range),
            AbsoluteAxisCode::ABS_TILT_Y => tilt_y = Some(range),
            _ => {}
        }
    }
    match pressure {
        Some(pressure) if is_pen(dev) => Ok(Axes {
            pressure,
            tilt_x,
            tilt_y,
        }),
        _ => Err(TabletError::NotAPen {
            path: path.to_path_buf(),
            name: dev.name().unwrap_or("unnamed").to_string(),
        }),
    }
}

impl PenStateSource for RawDevice {
    type Error = std::io::Error;

    fn current_state(&mut self) -> std::io::Result<PenState> {
        let keys = self.get_key_state()?;
        let axes = self.get_abs_state()?;
        let mut state = PenState::default();
        for code in PenState::KEYS {
            state.apply(EV_KEY, code, keys.contains(KeyCode::new(code)) as i32);
        }
        for code in PenState::AXES {
            state.apply(EV_ABS, code, axes[code as usize].value);
        }
        Ok(state)
    }
}

struct Shared {
    decoder: Decoder,
    error: Option<String>,
}

/// A tablet being read.
pub struct LiveTablet {
    name: String,
    shared: Arc<Mutex<Shared>>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl LiveTablet {
    pub fn open(path: &Path) -> Result<LiveTablet, TabletError> {
        let mut dev = RawDevice::open(path).map_err(|e| TabletError::Open {
            path: path.to_path_buf(),
            reason: if e.kind() == std::io::ErrorKind::PermissionDenied {
                format!(
                    "{e}: add yourself to the `input` group (`sudo usermod -aG input $USER`, then \
                     log in again) or install the udev rule in host/udev/"
                )
            } else {
                e.to_string()
            },
        })?;
        let axes = axes_of(&dev, path)?;
        let name = dev.name().unwrap_or("tablet").to_string();
        let shared = Arc::new(Mutex::new(Shared {
            decoder: Decoder::new(axes),
            error: None,
        }));
        let stop = Arc::new(AtomicBool::new(false));
        let thread = {
            let shared = shared.clone();
            let stop = stop.clone();
            let at: PathBuf = path.to_path_buf();
            std::thread::Builder::new()
                .name("maobi-tablet".into())
                .spawn(move || read_loop(&mut dev, &at, &shared, &stop))
                .map_err(|e| TabletError::Open {
                    path: path.to_path_buf(),
                    reason: format!("starting its reader: {e}"),
                })?
        };
        log::info!("tablet {name} at {}", path.display());
        Ok(LiveTablet {
            name,
            shared,
            stop,
            thread: Some(thread),
        })
    }

    pub fn status(&self) -> TabletStatus {
        match self.shared.lock() {
            Ok(s) => TabletStatus {
                name: self.name.clone(),
                reading: s.decoder.reading(),
                has_tilt: s.decoder.has_tilt(),
                error: s.error.clone(),
                frames: s.decoder.frames,
                dropped_frames: s.decoder.dropped_frames,
            },
            Err(_) => TabletStatus {
                name: self.name.clone(),
                reading: Default::default(),
                has_tilt: false,
                error: Some("the tablet's reader failed".into()),
                frames: 0,
                dropped_frames: 0,
            },
        }
    }
}

fn read_loop(dev: &mut RawDevice, path: &Path, shared: &Mutex<Shared>, stop: &AtomicBool) {
    let fd = dev.as_raw_fd();
    while !stop.load(Ordering::Relaxed) {
        let mut pfd = libc::pollfd {
            fd,
            events: libc::POLLIN,
            revents: 0,
        };
        // SAFETY: one valid pollfd for the device's open descriptor, which `dev` keeps open
        // for the duration of the call.
        let n = unsafe { libc::poll(&mut pfd, 1, POLL_MS) };
        if n < 0 {
            let e = std::io::Error::last_os_error();
            if e.kind() == std::io::ErrorKind::Interrupted {
                continue;
            }
            fail(shared, path, e);
            return;
        }
        if n == 0 {
            continue;
        }
        if pfd.revents & (libc::POLLERR | libc::POLLHUP | libc::POLLNVAL) != 0 {
            fail(
                shared,
                path,
                std::io::Error::from_raw_os_error(libc::ENODEV),
            );
            return;
        }
        // Taken out of the device's buffer first: a resync asks the device itself.
        let events: Vec<(u16, u16, i32)> = match dev.fetch_events() {
            Ok(events) => events
                .map(|e| (e.event_type().0, e.code(), e.value()))
                .collect(),
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => continue,
            Err(e) => {
                fail(shared, path, e);
                return;
            }
        };
        let Ok(mut s) = shared.lock() else { return };
        for (kind, code, value) in events {
            if let Err(e) = s.decoder.feed(dev, kind, code, value) {
                drop(s);
                fail(shared, path, e);
                return;
            }
        }
    }
}

fn fail(shared: &Mutex<Shared>, path: &Path, e: std::io::Error) {
    let msg = if e.raw_os_error() == Some(libc::ENODEV) {
        format!(
            "the tablet at {} was unplugged; the mouse drives the brush",
            path.display()
        )
    } else {
        format!(
            "reading the tablet at {}: {e}; the mouse drives the brush",
            path.display()
        )
    };
    log::warn!("{msg}");
    if let Ok(mut s) = shared.lock() {
        s.error = Some(msg);
    }
}

impl Drop for LiveTablet {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}
