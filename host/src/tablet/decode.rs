//! What a pen tablet says: evdev's event codes, the axes' ranges, the [`Decoder`] that turns
//! the kernel's event protocol into [`Reading`]s, and what a reading does to the hand
//! ([`PressureCurve`], [`Reading::hand`]). Both sources of events, the live device and a
//! recording, feed this module; it depends on neither.

use std::path::PathBuf;

/// Event types.
pub const EV_SYN: u16 = 0x00;
pub const EV_KEY: u16 = 0x01;
pub const EV_ABS: u16 = 0x03;
/// `EV_SYN` codes.
pub const SYN_REPORT: u16 = 0;
pub const SYN_DROPPED: u16 = 3;
/// `EV_ABS` codes a pen tablet reports.
pub const ABS_X: u16 = 0x00;
pub const ABS_Y: u16 = 0x01;
pub const ABS_PRESSURE: u16 = 0x18;
pub const ABS_TILT_X: u16 = 0x1a;
pub const ABS_TILT_Y: u16 = 0x1b;
/// `EV_KEY` codes: the tools coming into range, and the tip on the surface.
pub const BTN_TOOL_PEN: u16 = 0x140;
pub const BTN_TOOL_RUBBER: u16 = 0x141;
pub const BTN_TOUCH: u16 = 0x14a;

/// An absolute axis's range, as `EVIOCGABS` (or a recording's `A:` line) gives it.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub struct AxisRange {
    pub min: i32,
    pub max: i32,
    /// Units per millimetre for positions, per radian for tilt; 0 when the driver does not say.
    pub resolution: i32,
}

impl AxisRange {
    /// `value` as a fraction of the range, clamped to [0, 1].
    fn fraction(&self, value: i32) -> f32 {
        let span = self.max as i64 - self.min as i64;
        if span <= 0 {
            return 0.0;
        }
        ((value as i64 - self.min as i64) as f64 / span as f64).clamp(0.0, 1.0) as f32
    }

    /// A tilt value in degrees. The kernel states tilt resolution in units per radian; drivers
    /// that leave it 0 report degrees (Wacom's -64..63 and most others).
    fn degrees(&self, value: i32) -> f32 {
        if self.resolution > 0 {
            (value as f64 / self.resolution as f64).to_degrees() as f32
        } else {
            value as f32
        }
    }
}

/// The axes a device offers that matter here. A device without pressure is not a pen tablet.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub struct Axes {
    pub pressure: AxisRange,
    pub tilt_x: Option<AxisRange>,
    pub tilt_y: Option<AxisRange>,
}

/// The stylus as of the last complete event frame.
#[derive(Copy, Clone, Debug, Default, PartialEq)]
pub struct Reading {
    /// A pen (or its eraser end) is within the tablet's sensing range.
    pub in_range: bool,
    /// The tip is on the surface.
    pub touching: bool,
    /// Tip pressure in [0, 1] of the axis's range.
    pub pressure: f32,
    /// The pen's lean, in degrees: its top toward the tablet's right (+x) and toward the user
    /// (+y, down the tablet); 0, 0 when upright or when the tablet has no tilt.
    pub tilt_x_deg: f32,
    pub tilt_y_deg: f32,
}

/// The largest tilt the app's hand takes (degrees), as with the arrow keys.
pub const MAX_TILT_DEG: f64 = 45.0;

/// What a reading does to the hand: how far the ferrule goes below its touching height (mm),
/// and the hand's tilt about the paper's x and y axes (degrees).
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct HandFromPen {
    /// `None` while the tip is off the surface: the hand hovers.
    pub depth_mm: Option<f64>,
    pub tilt_x_deg: f64,
    pub tilt_y_deg: f64,
}

impl Reading {
    /// The hand for this reading, with full pressure pressing `full_press_mm` deep through
    /// `curve`.
    ///
    /// The tilt mapping follows the hand's rotations (`HandInput::pose`): a positive hand tilt
    /// about y swings the tip toward -x, so the pen's top leans toward +x; one about x swings
    /// the tip toward +y, the top toward -y, which on the paper (y up the screen) is toward
    /// the user. So the pen's x lean is the hand's y tilt and its y lean the hand's x tilt.
    pub fn hand(&self, curve: PressureCurve, full_press_mm: f64) -> HandFromPen {
        let depth_mm = (self.touching && self.in_range)
            .then(|| full_press_mm * curve.apply(self.pressure) as f64);
        HandFromPen {
            depth_mm,
            tilt_x_deg: (self.tilt_y_deg as f64).clamp(-MAX_TILT_DEG, MAX_TILT_DEG),
            tilt_y_deg: (self.tilt_x_deg as f64).clamp(-MAX_TILT_DEG, MAX_TILT_DEG),
        }
    }
}

/// What a [`Decoder`] reads of a device's state, in evdev's raw terms: which of the pen's keys
/// are down and the value of each of its absolute axes, as the kernel holds them for the
/// device (`EVIOCGKEY`, `EVIOCGABS`) and as its events change them.
#[derive(Copy, Clone, Debug, Default, PartialEq, Eq)]
pub struct PenState {
    /// `BTN_TOOL_PEN`: the pen's tip end is in range.
    pub tool_pen: bool,
    /// `BTN_TOOL_RUBBER`: its eraser end is in range.
    pub tool_rubber: bool,
    /// `BTN_TOUCH`: the tip is on the surface.
    pub touch: bool,
    /// `ABS_PRESSURE`, `ABS_TILT_X`, `ABS_TILT_Y` in the device's units.
    pub pressure: i32,
    pub tilt_x: i32,
    pub tilt_y: i32,
}

impl PenState {
    /// The `EV_KEY` codes this state holds.
    pub const KEYS: [u16; 3] = [BTN_TOOL_PEN, BTN_TOOL_RUBBER, BTN_TOUCH];
    /// The `EV_ABS` codes this state holds.
    pub const AXES: [u16; 3] = [ABS_PRESSURE, ABS_TILT_X, ABS_TILT_Y];

    /// Takes one event: a key of [`Self::KEYS`] goes down (any value but 0: pressed or
    /// repeating) or up, an axis of [`Self::AXES`] takes its value; other events change
    /// nothing.
    pub fn apply(&mut self, kind: u16, code: u16, value: i32) {
        match (kind, code) {
            (EV_KEY, BTN_TOOL_PEN) => self.tool_pen = value != 0,
            (EV_KEY, BTN_TOOL_RUBBER) => self.tool_rubber = value != 0,
            (EV_KEY, BTN_TOUCH) => self.touch = value != 0,
            (EV_ABS, ABS_PRESSURE) => self.pressure = value,
            (EV_ABS, ABS_TILT_X) => self.tilt_x = value,
            (EV_ABS, ABS_TILT_Y) => self.tilt_y = value,
            _ => {}
        }
    }
}

/// Where a [`Decoder`]'s events come from, asked for the device's present state when events
/// were lost (`SYN_DROPPED`): the live device answers with evdev's `EVIOCGKEY` and
/// `EVIOCGABS`, a replayed recording with the state its events have built so far.
pub trait PenStateSource {
    type Error;
    fn current_state(&mut self) -> Result<PenState, Self::Error>;
}

/// A state is its own source: what a replay that keeps the device's state answers.
impl PenStateSource for PenState {
    type Error = core::convert::Infallible;
    fn current_state(&mut self) -> Result<PenState, Self::Error> {
        Ok(*self)
    }
}

/// evdev's event stream to [`Reading`]s.
///
/// The kernel sends a device's state changes as a frame of events closed by `SYN_REPORT`; a
/// reader takes the frame as a whole. When the reader's buffer overflowed the kernel sends
/// `SYN_DROPPED`: events were lost, so the state the frames built is wrong (a lost
/// `BTN_TOUCH` release would leave the tip on the paper, a lost pressure change a stale
/// press). Everything up to and including the next `SYN_REPORT` is ignored and the decoder
/// then takes the device's present state from its source instead (the kernel's
/// `Documentation/input/event-codes.rst` asks readers to do exactly this).
#[derive(Clone, Debug)]
pub struct Decoder {
    axes: Axes,
    committed: PenState,
    pending: PenState,
    dropping: bool,
    /// Frames taken, and frames thrown away after `SYN_DROPPED` (each followed by a resync
    /// from the device's state).
    pub frames: u64,
    pub dropped_frames: u64,
}

impl Decoder {
    pub fn new(axes: Axes) -> Decoder {
        Decoder {
            axes,
            committed: PenState::default(),
            pending: PenState::default(),
            dropping: false,
            frames: 0,
            dropped_frames: 0,
        }
    }

    pub fn axes(&self) -> Axes {
        self.axes
    }

    /// The device reports tilt on at least one axis.
    pub fn has_tilt(&self) -> bool {
        self.axes.tilt_x.is_some() || self.axes.tilt_y.is_some()
    }

    /// The stylus as of the last complete frame (or resync).
    pub fn reading(&self) -> Reading {
        self.reading_of(&self.committed)
    }

    /// What `state` says of the stylus, with the axes' ranges applied. Out of range, nothing
    /// the pen last reported holds.
    fn reading_of(&self, state: &PenState) -> Reading {
        if !(state.tool_pen || state.tool_rubber) {
            return Reading::default();
        }
        let degrees = |range: Option<AxisRange>, value| range.map_or(0.0, |r| r.degrees(value));
        Reading {
            in_range: true,
            touching: state.touch,
            pressure: self.axes.pressure.fraction(state.pressure),
            tilt_x_deg: degrees(self.axes.tilt_x, state.tilt_x),
            tilt_y_deg: degrees(self.axes.tilt_y, state.tilt_y),
        }
    }

    /// Makes the pending state the reading; true when that changed the reading.
    fn commit(&mut self) -> bool {
        let before = self.reading();
        self.committed = self.pending;
        self.reading() != before
    }

    /// Takes one event from `source`; returns true when it closed a frame (or ended a drop)
    /// that changed the reading. Fails only when the source cannot say its state after a
    /// drop; the reading is then the last complete frame's.
    pub fn feed<S: PenStateSource>(
        &mut self,
        source: &mut S,
        kind: u16,
        code: u16,
        value: i32,
    ) -> Result<bool, S::Error> {
        match (kind, code) {
            (EV_SYN, SYN_DROPPED) => {
                self.dropping = true;
                Ok(false)
            }
            (EV_SYN, SYN_REPORT) if self.dropping => {
                self.dropping = false;
                self.dropped_frames += 1;
                self.pending = self.committed;
                self.pending = source.current_state()?;
                Ok(self.commit())
            }
            (EV_SYN, SYN_REPORT) => {
                self.frames += 1;
                Ok(self.commit())
            }
            _ if self.dropping => Ok(false),
            _ => {
                self.pending.apply(kind, code, value);
                Ok(false)
            }
        }
    }
}

/// How pressure maps to depth: `p' = ((p - threshold) / (1 - threshold))^exponent`, 0 below
/// the threshold. An exponent above 1 makes light pressure lighter (fine hairlines), below 1
/// makes it heavier (a soft touch presses the belly down); the threshold ignores the tip's
/// resting weight and a tablet's noise floor. Drawing programs offer the same two knobs.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct PressureCurve {
    pub exponent: f32,
    pub threshold: f32,
}

impl Default for PressureCurve {
    fn default() -> Self {
        PressureCurve {
            exponent: 1.0,
            threshold: 0.02,
        }
    }
}

impl PressureCurve {
    /// The ranges the app and the command line accept.
    pub const EXPONENT: std::ops::RangeInclusive<f32> = 0.2..=5.0;
    pub const THRESHOLD: std::ops::RangeInclusive<f32> = 0.0..=0.5;

    /// The curve, if both values are in range.
    pub fn new(exponent: f32, threshold: f32) -> Result<PressureCurve, String> {
        if !Self::EXPONENT.contains(&exponent) {
            return Err(format!(
                "pressure curve exponent {exponent} is outside {}..={}",
                Self::EXPONENT.start(),
                Self::EXPONENT.end()
            ));
        }
        if !Self::THRESHOLD.contains(&threshold) {
            return Err(format!(
                "pressure threshold {threshold} is outside {}..={}",
                Self::THRESHOLD.start(),
                Self::THRESHOLD.end()
            ));
        }
        Ok(PressureCurve {
            exponent,
            threshold,
        })
    }

    pub fn apply(&self, pressure: f32) -> f32 {
        let p = pressure.clamp(0.0, 1.0);
        if p <= self.threshold {
            return 0.0;
        }
        ((p - self.threshold) / (1.0 - self.threshold)).powf(self.exponent)
    }
}

/// A pen tablet found on this machine (its evdev node), for the chooser.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TabletInfo {
    pub path: PathBuf,
    pub name: String,
}

impl TabletInfo {
    pub fn label(&self) -> String {
        format!("{} ({})", self.name, self.path.display())
    }
}

/// What the app shows of a tablet and uses of it.
#[derive(Clone, Debug, PartialEq)]
pub struct TabletStatus {
    pub name: String,
    pub reading: Reading,
    /// The tablet reports tilt (else the keys tilt the hand, as with a mouse).
    pub has_tilt: bool,
    /// Set when the device went away or failed: the app falls back to the mouse.
    pub error: Option<String>,
    pub frames: u64,
    pub dropped_frames: u64,
}
