//! Pen tablets: a recorded event stream (evemu-record's format) decoded and replayed through
//! the app's input path moves the brush: pressure presses it through the pressure curve,
//! tilt tilts it, lifting the pen lifts the brush; events lost to an overflow (`SYN_DROPPED`)
//! are made good from the device's state. Bad recordings and devices are refused with a
//! message that says which and why.

use std::path::{Path, PathBuf};
use std::time::Duration;

mod common;

use egui_kittest::Harness;
use maobi::device::builtin::SimClock;
use maobi::gui::app::{Automation, MaobiApp};
use maobi::gui::start_hand;
use maobi::tablet::recording::Replay;
use maobi::tablet::{
    Axes, AxisRange, Decoder, PenState, PenStateSource, PressureCurve, Reading, Recording, Tablet,
    ABS_PRESSURE, ABS_TILT_X, BTN_TOOL_PEN, BTN_TOUCH, EV_ABS, EV_KEY, EV_SYN, SYN_DROPPED,
    SYN_REPORT,
};

/// Model ticks (ms) per UI frame: the recording advances by as much each frame.
const TICKS_PER_FRAME: usize = 10;

fn recording() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../examples/tablet/press-and-tilt.evemu")
}

fn axes() -> Axes {
    Axes {
        pressure: AxisRange {
            min: 0,
            max: 1000,
            resolution: 0,
        },
        tilt_x: Some(AxisRange {
            min: -64,
            max: 63,
            resolution: 57,
        }),
        tilt_y: None,
    }
}

#[test]
fn the_recording_parses_with_its_axes() {
    let r = Recording::from_path(&recording()).unwrap();
    assert_eq!(r.name, "Wacom Intuos Pro M Pen");
    assert_eq!(r.axes.pressure.max, 8191);
    assert_eq!(r.axes.tilt_x.unwrap().resolution, 57);
    assert!(r.axes.tilt_y.is_some());
    let d = r.duration().as_secs_f64();
    assert!((1.5..1.7).contains(&d), "{d}");
    assert!(r.events.len() > 1000);
}

/// The device a decoder's events come from, as a recording of everything it did: every event
/// changes its state, also those its reader loses to an overflow, and it counts how often the
/// decoder asks for that state.
#[derive(Default)]
struct RecordedDevice {
    state: PenState,
    asked: usize,
}

impl PenStateSource for RecordedDevice {
    type Error = std::convert::Infallible;
    fn current_state(&mut self) -> Result<PenState, Self::Error> {
        self.asked += 1;
        Ok(self.state)
    }
}

impl RecordedDevice {
    /// An event the device sends and the decoder reads; true when it changed the reading.
    fn deliver(&mut self, d: &mut Decoder, kind: u16, code: u16, value: i32) -> bool {
        self.state.apply(kind, code, value);
        let Ok(changed) = d.feed(self, kind, code, value);
        changed
    }

    /// An event the device sends and the reader never sees (its buffer overflowed).
    fn lose(&mut self, kind: u16, code: u16, value: i32) {
        self.state.apply(kind, code, value);
    }
}

#[test]
fn the_decoder_takes_whole_frames() {
    let mut d = Decoder::new(axes());
    let mut dev = RecordedDevice::default();
    dev.deliver(&mut d, EV_KEY, BTN_TOOL_PEN, 1);
    dev.deliver(&mut d, EV_KEY, BTN_TOUCH, 1);
    dev.deliver(&mut d, EV_ABS, ABS_PRESSURE, 500);
    // Nothing counts until the frame closes.
    assert_eq!(d.reading(), Reading::default());
    assert!(dev.deliver(&mut d, EV_SYN, SYN_REPORT, 0));
    let r = d.reading();
    assert!(r.in_range && r.touching);
    assert!((r.pressure - 0.5).abs() < 1e-6);

    // Tilt in units per radian: 57 units is one radian.
    dev.deliver(&mut d, EV_ABS, ABS_TILT_X, 57);
    dev.deliver(&mut d, EV_SYN, SYN_REPORT, 0);
    assert!((d.reading().tilt_x_deg - 57.29578).abs() < 1e-3);

    // Out of range clears everything the pen said.
    dev.deliver(&mut d, EV_KEY, BTN_TOOL_PEN, 0);
    dev.deliver(&mut d, EV_SYN, SYN_REPORT, 0);
    assert_eq!(d.reading(), Reading::default());
    assert_eq!((d.frames, d.dropped_frames), (3, 0));
    assert_eq!(dev.asked, 0, "without a drop the events say it all");
}

/// A pen pressing at half pressure and leaning a radian, read whole by the decoder.
fn pressing() -> (Decoder, RecordedDevice) {
    let mut d = Decoder::new(axes());
    let mut dev = RecordedDevice::default();
    for (kind, code, value) in [
        (EV_KEY, BTN_TOOL_PEN, 1),
        (EV_KEY, BTN_TOUCH, 1),
        (EV_ABS, ABS_PRESSURE, 500),
        (EV_ABS, ABS_TILT_X, 57),
        (EV_SYN, SYN_REPORT, 0),
    ] {
        dev.deliver(&mut d, kind, code, value);
    }
    assert!(d.reading().touching);
    (d, dev)
}

#[test]
fn after_syn_dropped_a_lost_touch_release_resyncs_to_not_touching() {
    let (mut d, mut dev) = pressing();
    // The reader falls behind: the frame that lifts the tip is lost, the kernel says so
    // with SYN_DROPPED, and the frame after it (the hovering pen leaning back) is
    // incomplete and not to be read.
    dev.lose(EV_ABS, ABS_PRESSURE, 0);
    dev.lose(EV_KEY, BTN_TOUCH, 0);
    dev.lose(EV_SYN, SYN_REPORT, 0);
    dev.deliver(&mut d, EV_SYN, SYN_DROPPED, 0);
    dev.deliver(&mut d, EV_ABS, ABS_TILT_X, 0);
    assert_eq!(dev.asked, 0, "the state is asked for once the drop ends");
    assert!(dev.deliver(&mut d, EV_SYN, SYN_REPORT, 0));
    assert_eq!(dev.asked, 1);
    assert_eq!(
        d.reading(),
        Reading {
            in_range: true,
            touching: false,
            pressure: 0.0,
            tilt_x_deg: 0.0,
            tilt_y_deg: 0.0,
        },
        "the device's state, not the last frame read"
    );
    assert_eq!((d.frames, d.dropped_frames), (1, 1));

    // Reading goes on from there, frame by frame.
    dev.deliver(&mut d, EV_KEY, BTN_TOOL_PEN, 0);
    dev.deliver(&mut d, EV_SYN, SYN_REPORT, 0);
    assert_eq!(d.reading(), Reading::default());
    assert_eq!(dev.asked, 1);
}

#[test]
fn after_syn_dropped_a_lost_pressure_change_resyncs_to_the_present_pressure() {
    let (mut d, mut dev) = pressing();
    // Pressed harder in the lost frames; the frame the drop cuts short would have taken it
    // a little further.
    for pressure in [600, 700, 800] {
        dev.lose(EV_ABS, ABS_PRESSURE, pressure);
        dev.lose(EV_SYN, SYN_REPORT, 0);
    }
    dev.deliver(&mut d, EV_SYN, SYN_DROPPED, 0);
    dev.deliver(&mut d, EV_ABS, ABS_PRESSURE, 900);
    assert!(dev.deliver(&mut d, EV_SYN, SYN_REPORT, 0));
    let r = d.reading();
    assert!(r.in_range && r.touching, "{r:?}");
    assert!((r.pressure - 0.9).abs() < 1e-6, "{r:?}");
    assert!((r.tilt_x_deg - 57.29578).abs() < 1e-3, "{r:?}");
    assert_eq!((d.frames, d.dropped_frames, dev.asked), (1, 1, 1));
}

/// A recording (evemu-record's format) in which the reader's buffer overflowed as the pen
/// lifted: the release is in the frame after `SYN_DROPPED`, which a reader discards.
const DROPPED_RELEASE: &str = "\
N: Test Pen
A: 18 0 1000 0 0 0
E: 0.000000 0001 0140 1
E: 0.000000 0001 014a 1
E: 0.000000 0003 0018 500
E: 0.000000 0000 0000 0
E: 0.010000 0000 0003 0
E: 0.010000 0003 0018 0
E: 0.010000 0001 014a 0
E: 0.010000 0000 0000 0
E: 0.020000 0003 0000 100
E: 0.020000 0000 0000 0
";

#[test]
fn a_replayed_recording_that_drops_the_touch_release_lifts_the_pen() {
    let rec = Recording::parse(DROPPED_RELEASE, Path::new("dropped-release.evemu")).unwrap();
    let mut replay = Replay::new(rec);
    replay.advance(Duration::from_millis(5));
    let s = replay.status();
    assert!(s.reading.touching && s.reading.pressure == 0.5, "{s:?}");
    replay.advance(Duration::from_millis(20));
    let s = replay.status();
    assert!(replay.finished());
    assert!(
        s.reading.in_range && !s.reading.touching && s.reading.pressure == 0.0,
        "no stuck touch, no stale pressure: {s:?}"
    );
    assert_eq!((s.frames, s.dropped_frames), (2, 1));
}

#[test]
fn the_pressure_curve_shapes_the_press() {
    let linear = PressureCurve::new(1.0, 0.0).unwrap();
    assert_eq!(linear.apply(0.5), 0.5);
    let light = PressureCurve::new(2.0, 0.0).unwrap();
    assert!((light.apply(0.5) - 0.25).abs() < 1e-6);
    let heavy = PressureCurve::new(0.5, 0.0).unwrap();
    assert!((heavy.apply(0.25) - 0.5).abs() < 1e-6);
    let gated = PressureCurve::new(1.0, 0.2).unwrap();
    assert_eq!(gated.apply(0.1), 0.0);
    assert!((gated.apply(0.6) - 0.5).abs() < 1e-6);
    assert_eq!(gated.apply(1.0), 1.0);
    assert!(PressureCurve::new(0.0, 0.0)
        .unwrap_err()
        .contains("exponent"));
    assert!(PressureCurve::new(1.0, 0.9)
        .unwrap_err()
        .contains("threshold"));

    // What a reading does to the hand: full pressure presses the full depth; the pen's lean
    // to the right is the hand's tilt about y, toward the user its tilt about x; off the
    // surface the hand hovers.
    let r = Reading {
        in_range: true,
        touching: true,
        pressure: 1.0,
        tilt_x_deg: 30.0,
        tilt_y_deg: 60.0,
    };
    let h = r.hand(linear, 8.0);
    assert_eq!(h.depth_mm, Some(8.0));
    assert_eq!(h.tilt_y_deg, 30.0);
    assert_eq!(h.tilt_x_deg, 45.0, "clamped to the hand's range");
    let up = Reading {
        touching: false,
        ..r
    };
    assert_eq!(up.hand(linear, 8.0).depth_mm, None);
}

#[test]
fn the_tilt_mapping_leans_the_brush_as_the_pen_leans() {
    // Where the brush's tip lies from the ferrule (unit vector) for a pen leaning so.
    let tip = |tilt_x_deg: f32, tilt_y_deg: f32| {
        let r = Reading {
            in_range: true,
            touching: false,
            pressure: 0.0,
            tilt_x_deg,
            tilt_y_deg,
        };
        let h = r.hand(PressureCurve::default(), 5.0);
        let mut hand = start_hand(40.0);
        hand.tilt_x_deg = h.tilt_x_deg;
        hand.tilt_y_deg = h.tilt_y_deg;
        hand.pose()
            .rot
            .rotate(maobi_shared::Vec3::new(0.0, 0.0, -1.0))
    };
    // The pen's top toward +x (tablet tilt x > 0) leans the ferrule's axis toward +x: the
    // brush's tip, below the ferrule, then lies toward -x.
    let t = tip(30.0, 0.0);
    assert!(t.x < -0.45 && t.y.abs() < 1e-9, "{t:?}");
    // Toward the user (+y down the tablet, -y on the paper): the tip lies toward +y.
    let t = tip(0.0, 30.0);
    assert!(t.y > 0.45 && t.x.abs() < 1e-9, "{t:?}");
}

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

#[test]
fn bad_recordings_and_devices_are_refused_with_the_reason() {
    let dir = std::env::temp_dir().join(format!("maobi-tablet-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let err = |p: &Path| match Tablet::open(p) {
        Ok(_) => panic!("{} opened", p.display()),
        Err(e) => e.to_string(),
    };

    let p = write(
        &dir,
        "bad-event.evemu",
        "A: 18 0 100 0 0 0\nE: 0.0 0003 0018\n",
    );
    let e = err(&p);
    assert!(
        e.contains("bad-event.evemu:2:") && e.contains("time, type, code and value"),
        "{e}"
    );

    let p = write(
        &dir,
        "bad-hex.evemu",
        "A: 18 0 100 0 0 0\nE: 0.0 0003 zz 5\n",
    );
    let e = err(&p);
    assert!(e.contains(":2:") && e.contains("`zz`"), "{e}");

    let p = write(
        &dir,
        "backwards.evemu",
        "A: 18 0 100 0 0 0\nE: 1.0 0000 0000 0\nE: 0.5 0000 0000 0\n",
    );
    assert!(err(&p).contains(":3: time 0.5 goes back"));

    let p = write(&dir, "mouse.evemu", "N: A Mouse\nA: 00 0 100 0 0 0\n");
    assert!(err(&p).contains("no pressure axis"));

    let p = write(&dir, "garbage.evemu", "\u{0}\u{1}binary\n");
    assert!(err(&p).contains("garbage.evemu:1:"));

    let e = err(&dir.join("missing.evemu"));
    assert!(e.contains("cannot read the tablet recording"), "{e}");

    // A device node that is not there (or, on other platforms, not readable at all).
    let e = err(Path::new("/dev/input/event-maobi-test"));
    assert!(e.contains("/dev/input/event-maobi-test"), "{e}");
    let _ = std::fs::remove_dir_all(&dir);
}

fn harness() -> Harness<'static, MaobiApp> {
    common::harness(common::app(
        SimClock::Stepped(TICKS_PER_FRAME),
        150.0,
        4.0,
        Automation::default(),
    ))
}

/// Steps the app until the recording has played to `t_s` seconds.
fn play_to(h: &mut Harness<'static, MaobiApp>, played: &mut f64, t_s: f64) {
    while *played < t_s {
        h.run_steps(1);
        *played += TICKS_PER_FRAME as f64 * 1e-3;
    }
}

#[test]
fn a_recorded_tablet_stroke_presses_tilts_and_lifts_the_brush() {
    let mut h = harness();
    h.run_steps(2);
    let r = h.state().paper().view_rect;
    h.event(egui::Event::PointerMoved(r.center()));
    h.run_steps(2);
    h.state_mut().use_tablet(&recording()).unwrap();
    h.state_mut()
        .set_pressure_curve(PressureCurve::new(1.0, 0.0).unwrap());
    let full = 8.0;
    // The app's press depth (W/S, wheel) is what full pressure presses.
    h.state_mut().set_press_mm(full);
    let mut played = 0.0;

    // Hovering in range: no contact, no ink.
    play_to(&mut h, &mut played, 0.08);
    let s = h
        .state()
        .tablet_status()
        .cloned()
        .expect("the tablet reports");
    assert!(s.reading.in_range && !s.reading.touching, "{s:?}");
    assert_eq!(h.state().latest().unwrap().contacts(), 0);
    assert_eq!(h.state().paper().canvas().ink_fraction(), 0.0);

    // Held at full pressure, leaning 30 degrees right and 15 toward the user.
    play_to(&mut h, &mut played, 0.95);
    let s = h.state().tablet_status().cloned().unwrap();
    assert!(s.reading.touching && s.reading.pressure == 1.0, "{s:?}");
    let hand = h.state().hand();
    assert!((hand.tilt_y_deg - 30.0).abs() < 0.6, "{hand:?}");
    assert!((hand.tilt_x_deg - 15.0).abs() < 0.6, "{hand:?}");
    let len = 40.0;
    assert!(
        (hand.z - (len - full)).abs() < 1e-9,
        "full pressure, full press: {hand:?}"
    );
    let f = h.state().latest().unwrap().clone();
    assert!(
        (f.pose.pos.z - hand.z).abs() < 0.05,
        "the device follows: {:?}",
        f.pose
    );
    let tip = f
        .spine
        .last()
        .map(|s| maobi_shared::Scalar::to_f64(s.z))
        .unwrap();
    assert!(tip < 0.05, "the tip is on the paper: {tip} mm");
    assert!(h.state().paper().canvas().ink_fraction() > 0.0, "it inks");

    // Eased off to a quarter of the range: a quarter of the press.
    play_to(&mut h, &mut played, 1.45);
    let hand = h.state().hand();
    let quarter = full * (2048.0 / 8191.0);
    assert!((hand.z - (len - quarter)).abs() < 1e-6, "{hand:?}");
    let f = h.state().latest().unwrap().clone();
    assert!((f.pose.pos.z - hand.z).abs() < 0.05, "{:?}", f.pose);

    // Lifted and out of range: the brush leaves the paper and the mouse has the hand again.
    play_to(&mut h, &mut played, 1.75);
    h.run_steps(20);
    let s = h.state().tablet_status().cloned().unwrap();
    assert!(!s.reading.in_range, "{s:?}");
    let f = h.state().latest().unwrap().clone();
    assert_eq!(f.contacts(), 0);
    assert!(
        f.depth_mm <= 0.0 && f.pose.pos.z > len,
        "hovering: {:?}",
        f.pose
    );
    assert!(s.frames > 300 && s.dropped_frames == 0, "{s:?}");
}
