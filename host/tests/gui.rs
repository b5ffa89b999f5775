//! The GUI without a window: egui_kittest drives the real app over the built-in simulator on
//! a stepped clock (each UI frame runs a fixed number of 1 ms model ticks), so every run is
//! the same.

use egui_kittest::kittest::Queryable;
use egui_kittest::Harness;
use maobi::device::builtin::SimClock;
use maobi::gui::app::{Automation, MaobiApp, Outcome};
use maobi::poses::PoseTrack;

mod common;
use common::example;

/// Model ticks per UI frame.
const TICKS_PER_FRAME: usize = 50;

fn harness() -> Harness<'static, MaobiApp> {
    common::harness(common::app(
        SimClock::Stepped(TICKS_PER_FRAME),
        150.0,
        4.0,
        Automation::default(),
    ))
}

/// Replays a pose file and steps until the device reports it finished.
fn replay(h: &mut Harness<'static, MaobiApp>, name: &str) {
    let path = example(name);
    let ticks = PoseTrack::from_path(&path).unwrap().ticks();
    let done = h.state().status().replays_done;
    h.state_mut().start_replay(&path).unwrap();
    let frames = ticks / TICKS_PER_FRAME + 3;
    h.run_steps(frames);
    assert_eq!(h.state().status().replays_done, done + 1, "{name} finished");
    assert!(!h.state().status().replaying);
}

fn ink(h: &Harness<'static, MaobiApp>) -> f64 {
    h.state().paper().canvas().ink_fraction()
}

#[test]
fn starts_with_the_simulator_connected() {
    let mut h = harness();
    h.run_steps(3);
    let s = h.state().status();
    assert!(s.connected);
    assert_eq!(s.name, "built-in simulator");
    assert!(h.state().latest().is_some(), "frames arrive");
    h.get_by_label_contains("built-in simulator");
    h.get_by_label("connected");
    h.get_by_label("Disconnect");
    assert_eq!(ink(&h), 0.0);
}

#[test]
fn replay_leaves_ink_and_the_brush_state() {
    let mut h = harness();
    h.run_steps(2);
    replay(&mut h, "hook.csv");
    assert!(ink(&h) > 0.0, "ink fraction {}", ink(&h));
    assert_eq!(h.state().paper().strokes(), 1);
    // Every replay tick reached the GUI (tick 0, the rest pose, is the reset itself).
    let ticks = PoseTrack::from_path(&example("hook.csv")).unwrap().ticks() as u64;
    assert_eq!(h.state().replay_frames(), ticks);
    h.get_by_label("replay finished");
}

#[test]
fn a_rejected_parameter_shows_why() {
    let mut h = harness();
    h.run_steps(2);
    let layers = h.state().status().params.layers;
    h.get_by_role_and_label(egui::accesskit::Role::SpinButton, "layers")
        .set_value_accesskit(99.0);
    h.run_steps(2);
    h.get_by_label_contains("layers rejected");
    h.get_by_label_contains("outside the valid range 3 ..= 24");
    assert_eq!(h.state().status().params.layers, layers, "old value kept");

    // A valid value is taken and the message says so.
    h.get_by_role_and_label(egui::accesskit::Role::SpinButton, "plasticity_d")
        .set_value_accesskit(0.01);
    h.run_steps(2);
    h.get_by_label("plasticity_d = 0.01");
    assert_eq!(h.state().status().params.plasticity, 0.01);

    // The panel shows a value as the model holds it, not rounded to the drag's decimals
    // (the goat brush's tie damping is 0.014).
    h.get_by_role_and_label(egui::accesskit::Role::SpinButton, "tie_damping_ns_per_m")
        .set_value_accesskit(0.014);
    h.run_steps(2);
    assert_eq!(h.state().status().params.tie_damping, 0.014);
    let shown = h
        .get_by_role_and_label(egui::accesskit::Role::SpinButton, "tie_damping_ns_per_m")
        .value();
    assert_eq!(shown.as_deref(), Some("0.014"));
}

#[test]
fn undo_takes_back_the_last_stroke_and_clear_is_undoable() {
    let mut h = harness();
    h.run_steps(2);
    replay(&mut h, "hook.csv");
    let first = h.state().paper().canvas().ink().to_vec();
    let after_one = ink(&h);
    assert!(after_one > 0.0);
    replay(&mut h, "shu.csv");
    assert_eq!(h.state().paper().strokes(), 2);
    assert!(ink(&h) > after_one, "the second stroke adds ink");

    h.get_by_label("Undo stroke").click();
    h.run_steps(2);
    assert_eq!(h.state().paper().canvas().ink(), &first[..]);

    h.get_by_label("Clear").click();
    h.run_steps(2);
    assert_eq!(ink(&h), 0.0);
    h.get_by_label("Undo stroke").click();
    h.run_steps(2);
    assert_eq!(h.state().paper().canvas().ink(), &first[..]);
    h.get_by_label("Undo stroke").click();
    h.run_steps(2);
    assert_eq!(ink(&h), 0.0);
    assert_eq!(h.state().paper().undo_depth(), 0);
}

#[test]
fn recording_writes_a_pose_file_that_replays() {
    let dir = std::env::temp_dir().join(format!("maobi-gui-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let rec = dir.join("rec.csv");
    let mut h = harness();
    h.run_steps(2);
    h.state_mut().start_recording(&rec);
    replay(&mut h, "press_lift.csv");
    let n = h.state_mut().stop_recording().unwrap();
    let track = PoseTrack::from_path(&rec).unwrap();
    assert_eq!(track.rows().len(), n);
    let src = PoseTrack::from_path(&example("press_lift.csv")).unwrap();
    assert!(n >= src.ticks(), "{n} poses for {} ticks", src.ticks());
    let ink_before = ink(&h);

    // The recording replays to the same ink on a fresh paper.
    let mut h2 = harness();
    h2.run_steps(2);
    h2.state_mut().start_replay(&rec).unwrap();
    h2.run_steps(n / TICKS_PER_FRAME + 3);
    let ink_after = ink(&h2);
    assert!(
        (ink_after - ink_before).abs() <= 0.02 * ink_before,
        "{ink_before} vs {ink_after}"
    );
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn outcome_defaults_are_empty() {
    let o = Outcome::default();
    assert!(o.error.is_none() && o.summary.is_empty());
}

#[test]
fn dip_ink_loads_the_brush_as_much_as_asked() {
    let mut h = harness();
    h.run_steps(2);
    h.get_by_role_and_label(egui::accesskit::Role::SpinButton, "ink load")
        .set_value_accesskit(0.3);
    h.run_steps(1);
    h.get_by_label("Dip ink").click();
    h.run_steps(2);
    h.get_by_label("dipped: ink load 0.30");
    let f = h.state().latest().expect("frames");
    for l in &f.layers {
        let w = maobi_shared::Scalar::to_f64(l.wetness);
        assert!((w - 0.3).abs() < 0.02, "wetness {w} after a 0.3 dip");
    }
}

#[test]
fn the_model_choice_runs_baxter_and_lins_brush_with_its_heads() {
    use egui_kittest::kittest::NodeT;
    use maobi::device::ModelKind;
    let mut h = harness();
    h.run_steps(2);
    assert_eq!(h.state().status().model, ModelKind::Liang);
    h.get_by_role_and_label(egui::accesskit::Role::ComboBox, "model")
        .click();
    h.run_steps(2);
    h.get_by_label("Baxter & Lin (spines)").click();
    h.run_steps(3);
    assert_eq!(h.state().status().model, ModelKind::BaxterLin);
    h.get_by_label("model: Baxter & Lin (spines)");
    let f = h.state().latest().expect("frames arrive");
    assert_eq!(f.hairs.len(), 7, "the round head's spines are drawn");
    // Its heads join the brush choice.
    h.get_by_role_and_label(egui::accesskit::Role::ComboBox, "brush")
        .click();
    h.run_steps(2);
    h.get_by_label("flat").click();
    h.run_steps(3);
    assert_eq!(h.state().status().preset, "flat");
    // The parameters the flat head does not read are shown but cannot be edited.
    let substeps = h.get_by_role_and_label(egui::accesskit::Role::SpinButton, "substeps_per_tick");
    assert!(substeps.accesskit_node().is_disabled());
    let wetness = h.get_by_role_and_label(egui::accesskit::Role::SpinButton, "wetness");
    assert!(!wetness.accesskit_node().is_disabled());
    // It writes: the hook (posed for the large brush's length) replayed with Baxter &
    // Lin's large round head leaves ink.
    h.get_by_role_and_label(egui::accesskit::Role::ComboBox, "brush")
        .click();
    h.run_steps(2);
    h.get_by_label("large").click();
    h.run_steps(3);
    assert_eq!(h.state().status().model, ModelKind::BaxterLin);
    replay(&mut h, "hook.csv");
    assert!(ink(&h) > 0.0, "ink fraction {}", ink(&h));
}

/// A pose file posed for the large brush, replayed with the small one (18 mm of hair), never
/// reaches the paper: the app says so instead of leaving the page blank without a word.
#[test]
fn a_replay_the_brush_cannot_reach_says_so() {
    let mut h = harness();
    h.run_steps(2);
    h.get_by_role_and_label(egui::accesskit::Role::ComboBox, "brush")
        .click();
    h.run_steps(2);
    h.get_by_label("small").click();
    h.run_steps(3);
    assert_eq!(h.state().status().preset, "small");
    replay(&mut h, "press_lift.csv");
    assert_eq!(ink(&h), 0.0);
    h.get_by_label_contains("the brush never reaches the paper");
    // The large brush reaches it, and nothing is said.
    h.get_by_role_and_label(egui::accesskit::Role::ComboBox, "brush")
        .click();
    h.run_steps(2);
    h.get_by_label("large").click();
    h.run_steps(3);
    replay(&mut h, "press_lift.csv");
    assert!(ink(&h) > 0.0);
    assert!(h
        .query_by_label_contains("the brush never reaches the paper")
        .is_none());
}

/// The About window, on its own (the app's menu opens it): the version, Maobi's licence,
/// the CJK font the fonts' setup installed (here the tests' own), and the bundled fonts'
/// licences; its close button closes it.
#[test]
fn the_about_window_shows_the_version_licences_and_font() {
    use maobi::gui::about::{about_window, BUNDLED, LICENCE, VERSION};
    let mut h = Harness::builder()
        .with_size(egui::vec2(900.0, 700.0))
        .build_ui_state(
            |ui, open: &mut bool| {
                if maobi::gui::fonts::installed(ui.ctx()).is_none() {
                    let _ = maobi::gui::fonts::setup(ui.ctx(), &common::test_fonts());
                }
                about_window(ui.ctx(), open);
            },
            true,
        );
    h.run();
    h.get_by_label(&format!("Maobi {VERSION}"));
    h.get_by_label_contains(&format!("licensed under {LICENCE}"));
    h.get_by_label_contains("CJK text: test font (face 0)");
    for b in BUNDLED {
        h.get_by_label(b.name);
        assert!(
            h.query_all_by_label(b.licence).next().is_some(),
            "{}: {}",
            b.name,
            b.licence
        );
    }
    h.get_by_label("Close window").click();
    h.run();
    assert!(!*h.state(), "the close button closes it");
    assert!(h.query_by_label(&format!("Maobi {VERSION}")).is_none());
}
