//! Tablet event recordings in the format `evemu-record` writes (the tool every Linux input
//! bug report uses), and their replay.
//!
//! ```text
//! # EVEMU 1.3
//! N: Wacom Intuos Pro M Pen
//! A: 18 0 8191 0 0 0          # axis (hex code) min max fuzz flat resolution
//! A: 1a -64 63 0 0 57
//! E: 0.000000 0001 0140 0001  # time (s) type code (hex) value (decimal)
//! E: 0.000000 0000 0000 0000
//! ```
//!
//! `N:` names the device and `A:` gives each absolute axis's range; `I:`, `P:`, `B:`, `L:`
//! and `S:` lines (ids, properties, bit masks, LEDs, switches) carry nothing this reader uses
//! and are skipped, as are comments after `#`. Record a tablet with
//! `sudo evemu-record /dev/input/eventN > pen.evemu` (package `evemu-tools`).

use std::fmt;
use std::path::{Path, PathBuf};
use std::time::Duration;

use super::decode::{
    Axes, AxisRange, Decoder, PenState, TabletStatus, ABS_PRESSURE, ABS_TILT_X, ABS_TILT_Y,
};

/// One event of a recording.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct Event {
    /// Seconds from the recording's first event.
    pub time_s: f64,
    pub kind: u16,
    pub code: u16,
    pub value: i32,
}

/// A parsed recording: the device's name and axes, and its events in time order.
#[derive(Clone, Debug)]
pub struct Recording {
    pub name: String,
    pub axes: Axes,
    pub events: Vec<Event>,
}

/// A recording that cannot be used, with the line at fault.
#[derive(Debug)]
pub enum RecordingError {
    Io {
        path: PathBuf,
        error: std::io::Error,
    },
    Line {
        path: PathBuf,
        line: usize,
        message: String,
    },
    NoPressure {
        path: PathBuf,
    },
}

impl fmt::Display for RecordingError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            RecordingError::Io { path, error } => {
                write!(
                    f,
                    "cannot read the tablet recording {}: {error}",
                    path.display()
                )
            }
            RecordingError::Line {
                path,
                line,
                message,
            } => write!(f, "{}:{line}: {message}", path.display()),
            RecordingError::NoPressure { path } => write!(
                f,
                "{}: the recording has no pressure axis (no `A: 18 ...` line): it is not a pen \
                 tablet's",
                path.display()
            ),
        }
    }
}

impl std::error::Error for RecordingError {}

fn hex_u16(s: &str, what: &str) -> Result<u16, String> {
    u16::from_str_radix(s, 16).map_err(|_| format!("{what} `{s}` is not a hexadecimal number"))
}

fn int(s: &str, what: &str) -> Result<i32, String> {
    s.parse()
        .map_err(|_| format!("{what} `{s}` is not a whole number"))
}

impl Recording {
    pub fn from_path(path: &Path) -> Result<Recording, RecordingError> {
        let text = std::fs::read_to_string(path).map_err(|error| RecordingError::Io {
            path: path.to_path_buf(),
            error,
        })?;
        Recording::parse(&text, path)
    }

    /// Parses a recording's text; `path` names it in errors.
    pub fn parse(text: &str, path: &Path) -> Result<Recording, RecordingError> {
        let mut name = String::new();
        let mut ranges: Vec<(u16, AxisRange)> = Vec::new();
        let mut events = Vec::new();
        let mut first_time: Option<f64> = None;
        let mut last_time = 0.0;
        for (i, raw) in text.lines().enumerate() {
            let at = |message: String| RecordingError::Line {
                path: path.to_path_buf(),
                line: i + 1,
                message,
            };
            let line = raw.split('#').next().unwrap_or("").trim();
            if line.is_empty() {
                continue;
            }
            let Some((tag, rest)) = line.split_once(':') else {
                return Err(at(format!("`{line}` is not an evemu line (`X: ...`)")));
            };
            let fields: Vec<&str> = rest.split_whitespace().collect();
            match tag {
                "N" => name = rest.trim().to_string(),
                "A" => {
                    if fields.len() < 5 {
                        return Err(at(format!(
                            "an axis line needs code, min, max, fuzz, flat (and resolution); got `{}`",
                            rest.trim()
                        )));
                    }
                    let code = hex_u16(fields[0], "axis code").map_err(at)?;
                    let min = int(fields[1], "minimum").map_err(at)?;
                    let max = int(fields[2], "maximum").map_err(at)?;
                    let resolution = match fields.get(5) {
                        Some(r) => int(r, "resolution").map_err(at)?,
                        None => 0,
                    };
                    if max < min {
                        return Err(at(format!(
                            "axis {code:#04x}: maximum {max} below minimum {min}"
                        )));
                    }
                    ranges.push((
                        code,
                        AxisRange {
                            min,
                            max,
                            resolution,
                        },
                    ));
                }
                "E" => {
                    if fields.len() != 4 {
                        return Err(at(format!(
                            "an event line needs time, type, code and value; got `{}`",
                            rest.trim()
                        )));
                    }
                    let t: f64 = fields[0]
                        .parse()
                        .ok()
                        .filter(|t: &f64| t.is_finite() && *t >= 0.0)
                        .ok_or_else(|| {
                            at(format!("time `{}` is not a time in seconds", fields[0]))
                        })?;
                    let t0 = *first_time.get_or_insert(t);
                    let time_s = t - t0;
                    if time_s < last_time {
                        return Err(at(format!(
                            "time {t} goes back (events must be in time order)"
                        )));
                    }
                    last_time = time_s;
                    events.push(Event {
                        time_s,
                        kind: hex_u16(fields[1], "event type").map_err(at)?,
                        code: hex_u16(fields[2], "event code").map_err(at)?,
                        value: int(fields[3], "value").map_err(at)?,
                    });
                }
                "I" | "P" | "B" | "L" | "S" => {}
                other => return Err(at(format!("unknown evemu line kind `{other}:`"))),
            }
        }
        let axis = |code: u16| ranges.iter().find(|(c, _)| *c == code).map(|(_, r)| *r);
        let pressure = axis(ABS_PRESSURE).ok_or_else(|| RecordingError::NoPressure {
            path: path.to_path_buf(),
        })?;
        Ok(Recording {
            name: if name.is_empty() {
                path.display().to_string()
            } else {
                name
            },
            axes: Axes {
                pressure,
                tilt_x: axis(ABS_TILT_X),
                tilt_y: axis(ABS_TILT_Y),
            },
            events,
        })
    }

    /// How long the recording runs.
    pub fn duration(&self) -> Duration {
        Duration::from_secs_f64(self.events.last().map_or(0.0, |e| e.time_s))
    }
}

/// A recording played through a [`Decoder`] along a clock the caller advances.
///
/// The recording stands for the device: every event in it changes the device's state, also
/// those a `SYN_DROPPED` in it marks as lost to the reader, so the decoder resynchronises
/// after a drop to the state all events so far have built, as a live device's would.
pub struct Replay {
    recording: Recording,
    decoder: Decoder,
    device: PenState,
    next: usize,
    at: Duration,
}

impl Replay {
    pub fn new(recording: Recording) -> Replay {
        Replay {
            decoder: Decoder::new(recording.axes),
            device: PenState::default(),
            recording,
            next: 0,
            at: Duration::ZERO,
        }
    }

    /// Plays the events of the next `dt`.
    pub fn advance(&mut self, dt: Duration) {
        self.at += dt;
        let now = self.at.as_secs_f64();
        while let Some(e) = self.recording.events.get(self.next) {
            if e.time_s > now {
                break;
            }
            self.device.apply(e.kind, e.code, e.value);
            let Ok(_) = self.decoder.feed(&mut self.device, e.kind, e.code, e.value);
            self.next += 1;
        }
    }

    pub fn finished(&self) -> bool {
        self.next >= self.recording.events.len()
    }

    pub fn status(&self) -> TabletStatus {
        TabletStatus {
            name: format!("{} (recording)", self.recording.name),
            reading: self.decoder.reading(),
            has_tilt: self.decoder.has_tilt(),
            error: None,
            frames: self.decoder.frames,
            dropped_frames: self.decoder.dropped_frames,
        }
    }
}
