//! The app's practice panel (`gui::practice`) in a kittest harness on the built-in pen in
//! lock-step: load 永, watch the master write it while "Write" records, score the attempt;
//! the report lists every figure and names 永's strokes; the master's outlines are drawn
//! over the paper. Bad input (a character without data) is a message, not a panic.

use egui_kittest::kittest::Queryable;
use maobi::device::builtin::SimClock;
use maobi::gui::app::{Automation, MaobiApp};
use maobi::gui::writing::Face;

mod common;

/// Model ticks per UI frame.
const TICKS_PER_FRAME: usize = 50;

/// Frames allowed for a thread's result (making the master, scoring) before the test calls it
/// hung; each waits for the result, not for time.
const HANG_FRAMES: usize = 20_000;

fn harness() -> egui_kittest::Harness<'static, MaobiApp> {
    let mut app = common::app(
        SimClock::Stepped(TICKS_PER_FRAME),
        200.0,
        5.0,
        Automation::default(),
    );
    app.set_face(Face::Writing);
    app.practice_mut().open = true;
    let history = std::env::temp_dir().join(format!("maobi-practice-{}.csv", std::process::id()));
    // The history goes to a file of this test's own (read by the app through the env).
    std::env::set_var(maobi::score::HISTORY_ENV, &history);
    common::harness_sized(app, 1600.0, 1000.0)
}

/// Steps until the practice panel has nothing running.
fn settle(h: &mut egui_kittest::Harness<'static, MaobiApp>) {
    for _ in 0..HANG_FRAMES {
        h.step();
        if !h.state().practice().busy() {
            return;
        }
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    panic!("the practice panel's thread did not finish");
}

#[test]
fn practise_yong_watch_it_written_and_score_the_attempt() {
    let mut h = harness();
    h.step();
    h.get_by_label("Load").click();
    h.step();
    settle(&mut h);
    let m = h.state().practice().master().expect("the master is loaded");
    assert_eq!(m.outlines().len(), 5);
    h.get_by_label_contains("5 strokes, from the shipped practice set");

    // The lane around the master's strokes: the device keeps it until it is left.
    h.get_by_label("Stay in the lane").click();
    h.step();
    h.step();
    assert!(h.state().practice().lane_on);
    assert!(
        h.state().latest().is_some_and(|f| f.guide.is_some()),
        "the device keeps the lane"
    );
    h.get_by_label("Leave the lane").click();
    for _ in 0..20 {
        h.step();
    }
    assert!(
        h.state().latest().is_some_and(|f| f.guide.is_none()),
        "and lets go"
    );

    // Write, and let the device write the master's 永 (as a writer's hand would).
    h.get_by_label("Write").click();
    h.step();
    assert!(h.state().practice().is_writing());
    h.get_by_label("Watch").click();
    let mut seen_replay = false;
    for _ in 0..2_000 {
        h.step();
        let replaying = h.state().status().replaying;
        seen_replay |= replaying;
        if seen_replay && !replaying {
            break;
        }
    }
    assert!(
        seen_replay && !h.state().status().replaying,
        "the replay ran and ended"
    );
    h.get_by_label("Score").click();
    h.step();
    settle(&mut h);
    let r = h.state().practice().report.clone().expect("a report");
    println!("{}", r.to_text());
    assert!(r.total >= 0.9, "{}", r.to_text());
    assert!(
        r.strokes.iter().all(|s| s.written.is_some()),
        "{}",
        r.to_text()
    );
    h.get_by_label_contains("永: total");
    for name in [
        "order",
        "shape",
        "position",
        "size",
        "direction",
        "speed",
        "press",
    ] {
        h.get_by_label(name);
    }
    h.get_by_label_contains("4 啄:");
    h.get_by_label("press (mm) along each stroke");
    h.get_by_label("speed (mm/s) along each stroke");
    // The attempt is the master's own writing: its profiles are the master's.
    for s in &r.strokes {
        for (a, b) in s.press_mm.iter().zip(&s.master_press_mm) {
            assert!((a - b).abs() < 1e-9, "{a} {b}");
        }
        assert_eq!(s.speed_mm_s.len(), maobi::score::SAMPLES);
    }
}

#[test]
fn a_character_without_data_is_a_message() {
    let mut h = harness();
    // Not a character of the data (nor one the test's font draws: any other glyph would do).
    h.state_mut().practice_mut().input = "x".into();
    h.step();
    h.get_by_label("Load").click();
    h.step();
    settle(&mut h);
    assert!(h.state().practice().master().is_none());
    h.get_by_label_contains("no stroke data for x (U+0078)");
}
