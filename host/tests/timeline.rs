//! The stroke editor in the app (egui_kittest, stepped simulator): open 永, retime along the
//! kinetic curve without changing the path, drag a keyframe on the paper, save and reopen,
//! play from the playhead, and guided writing with how far the pen strayed.

use std::path::PathBuf;

use egui_kittest::kittest::Queryable;
use egui_kittest::Harness;
use maobi::device::builtin::SimClock;
use maobi::gui::app::{Automation, MaobiApp};

mod common;

const TICKS_PER_FRAME: usize = 50;

fn yong() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../examples/strokes/yong.toml")
}

fn harness() -> Harness<'static, MaobiApp> {
    let mut app = common::app(
        SimClock::Stepped(TICKS_PER_FRAME),
        150.0,
        4.0,
        Automation::default(),
    );
    app.show_timeline(true);
    app.timeline_mut().open(&yong()).unwrap();
    let mut h = common::harness_sized(app, 1400.0, 1000.0);
    h.run_steps(2);
    h
}

/// The stroke's path sampled by path parameter (independent of timing).
fn path_of(h: &Harness<'static, MaobiApp>, i: usize) -> Vec<[f64; 3]> {
    let c = h.state().timeline().character().unwrap();
    let seg = c.segments.iter().find(|s| s.from == Some(i)).unwrap();
    let (u0, u1) = seg.stroke.path().domain();
    (0..=400)
        .map(|k| seg.stroke.path().eval(u0 + (u1 - u0) * k as f64 / 400.0))
        .collect()
}

#[test]
fn the_editor_shows_the_strokes_and_retimes_without_changing_the_path() {
    let mut h = harness();
    h.get_by_label_contains("8 strokes");
    h.get_by_label("Play");
    h.get_by_label("Guide me");
    h.get_by_label_contains("kinetic curve");

    let before = path_of(&h, 1);
    let dur = h.state().timeline().duration();
    let (t2, _) = h.state().timeline().key(1, 2).unwrap();
    let (t3, _) = h.state().timeline().key(1, 3).unwrap();
    let new_t = t2 + 0.3 * (t3 - t2);
    assert!(h.state_mut().timeline_mut().retime_key(1, 2, new_t));
    h.run_steps(1);
    h.get_by_label_contains("retimed");
    let after = path_of(&h, 1);
    let worst = before
        .iter()
        .zip(&after)
        .map(|(a, b)| {
            ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
        })
        .fold(0.0, f64::max);
    assert!(worst < 1e-3 * 1e-3, "the path moved by {worst} mm");
    let (t2b, _) = h.state().timeline().key(1, 2).unwrap();
    // Edited times are written to the millisecond (the tick).
    assert!((t2b - new_t).abs() <= 0.5e-3 + 1e-9, "{t2b} vs {new_t}");
    assert!(
        (h.state().timeline().duration() - dur).abs() < 1e-6,
        "later keys keep their times"
    );
    assert!(h.state().timeline().dirty);

    // A keyframe cannot pass the next one: refused, shown, nothing changed.
    let file_before = toml::to_string(h.state().timeline().file().unwrap()).unwrap();
    assert!(!h.state_mut().timeline_mut().retime_key(1, 2, t3 + 0.2));
    h.run_steps(1);
    h.get_by_label_contains("refused");
    assert_eq!(
        toml::to_string(h.state().timeline().file().unwrap()).unwrap(),
        file_before
    );
}

#[test]
fn dragging_a_keyframe_on_the_paper_moves_it_and_the_file_saves_and_reopens() {
    let mut h = harness();
    h.state_mut().timeline_mut().edit_on_paper = true;
    h.run_steps(2);
    let (_, p) = h.state().timeline().key(0, 2).unwrap();
    let from = h.state().paper().mm_to_screen(p[0], p[1]);
    let to = h.state().paper().mm_to_screen(p[0] + 4.0, p[1] - 3.0);
    let ink0 = h.state().paper().canvas().ink_fraction();
    h.event(egui::Event::PointerMoved(from));
    h.run_steps(2);
    h.event(egui::Event::PointerButton {
        pos: from,
        button: egui::PointerButton::Primary,
        pressed: true,
        modifiers: egui::Modifiers::NONE,
    });
    h.run_steps(1);
    for k in 1..=10 {
        h.event(egui::Event::PointerMoved(
            from + (to - from) * (k as f32 / 10.0),
        ));
        h.run_steps(1);
    }
    h.event(egui::Event::PointerButton {
        pos: to,
        button: egui::PointerButton::Primary,
        pressed: false,
        modifiers: egui::Modifiers::NONE,
    });
    h.run_steps(2);
    let (_, q) = h.state().timeline().key(0, 2).unwrap();
    // One screen pixel is a quarter millimetre here.
    assert!(
        (q[0] - (p[0] + 4.0)).abs() < 0.3 && (q[1] - (p[1] - 3.0)).abs() < 0.3,
        "{q:?}"
    );
    assert!((q[2] - p[2]).abs() < 1e-9, "the height is kept");
    assert_eq!(
        h.state().paper().canvas().ink_fraction(),
        ink0,
        "editing does not write"
    );

    let dir = std::env::temp_dir().join(format!("maobi-timeline-{}", std::process::id()));
    let out = dir.join("edited.toml");
    h.state_mut().timeline_mut().save(&out).unwrap();
    assert!(!h.state().timeline().dirty);
    let mut h2 = harness();
    h2.state_mut().timeline_mut().open(&out).unwrap();
    let (_, r) = h2.state().timeline().key(0, 2).unwrap();
    assert!((r[0] - q[0]).abs() < 1e-9 && (r[1] - q[1]).abs() < 1e-9);
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn play_replays_from_the_playhead_and_guide_me_reports_the_stray() {
    let mut h = harness();
    // From the fourth stroke on.
    let c = h.state().timeline().character().unwrap();
    let (t3, _) = c.stroke_times[3];
    let dur = c.duration();
    h.state_mut().timeline_mut().playhead = t3;
    h.get_by_label("Play").click();
    h.run_steps(2);
    assert!(h.state().timeline().playing());
    let frames = ((dur - t3) * 1e3) as usize / TICKS_PER_FRAME + 5;
    h.run_steps(frames);
    assert!(!h.state().timeline().playing(), "played to the end");
    assert!((h.state().timeline().playhead - dur).abs() < 0.01);
    assert_eq!(h.state().status().replays_done, 1);
    assert!(
        h.state().paper().strokes() >= 4,
        "{} strokes",
        h.state().paper().strokes()
    );

    // Guided writing from the start of the last stroke: the virtual pen stays where the
    // replay left it, so the moving point pulls away from it and the panel says how far.
    let (t7, _) = h.state().timeline().character().unwrap().stroke_times[7];
    h.state_mut().timeline_mut().playhead = t7;
    h.get_by_label("Guide me").click();
    h.run_steps(3);
    assert!(h.state().timeline().guiding());
    assert!(h.state().latest().unwrap().guide.is_some());
    h.get_by_label_contains("strayed:");
    h.run_steps(((dur - t7) * 1e3) as usize / TICKS_PER_FRAME + 12);
    assert!(!h.state().timeline().guiding());
    h.get_by_label_contains("guided writing done: strayed");
    let s = &h.state().timeline().stray;
    assert!(s.ticks > 100 && s.max_mm > 1.0, "{s:?}");
}
