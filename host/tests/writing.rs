//! The writing view (`gui::writing`): the brush's mark over the paper before and while it
//! touches, the view's share of the window, its shortcuts, and the face the app is left in.
//! On the simulator's stepped clock, so every run is the same.

use egui_kittest::kittest::Queryable;
use egui_kittest::Harness;
use maobi::device::builtin::{SimClock, SimDevice};
use maobi::device::{BrushFrame, Device, DeviceCommand, HandInput, ModelKind};
use maobi::gui::app::{Automation, MaobiApp};
use maobi::gui::files::{FileKind, Purpose};
use maobi::gui::writing::{brush_mark, BrushMark, Face, Grid, HOVER_REACH_MM};
use maobi::gui::{start_hand, GuiOptions};

mod common;

/// Model ticks per poll of the simulator.
const TICKS: usize = 200;

/// The simulator's last frame with the ferrule held at `z` mm over the paper's origin.
fn frame_at(dev: &mut SimDevice, z: f64) -> BrushFrame {
    dev.send(DeviceCommand::Hand(HandInput {
        z,
        ..start_hand(0.0)
    }))
    .unwrap();
    let mut frames = Vec::new();
    // Long enough for the brush to come to rest where the hand holds it.
    for _ in 0..3 {
        dev.poll(&mut frames);
    }
    frames.pop().expect("the simulator delivers frames")
}

/// The `large` brush of `model` on the simulator, the hand well above the paper.
fn simulator(model: ModelKind) -> SimDevice {
    let mut dev = SimDevice::new(SimClock::Stepped(TICKS), "large", start_hand(60.0)).unwrap();
    dev.connect().unwrap();
    if model != ModelKind::Liang {
        dev.send(DeviceCommand::Model(model)).unwrap();
    }
    dev
}

/// The ring's radius (mm) as the ferrule comes down from far above to where the tip meets the
/// paper and below, for `model`'s `large` brush: `None` beyond reach, the ring while above,
/// and the footprint's depth while touching.
fn descent(model: ModelKind) -> (f64, Vec<(f64, Option<BrushMark>)>) {
    let mut dev = simulator(model);
    let length = dev.status().params.length_mm as f64;
    let mut out = Vec::new();
    // From beyond reach down to a press of a fifth of the hair's length.
    let mut z = length + HOVER_REACH_MM + 15.0;
    while z > length * 0.8 {
        let f = frame_at(&mut dev, z);
        out.push((z, brush_mark(&f, length)));
        z -= 2.5;
    }
    (length, out)
}

fn check_descent(model: ModelKind) {
    let (length, marks) = descent(model);
    assert!(
        marks[0].1.is_none(),
        "{model:?}: beyond reach there is no mark: {:?}",
        marks[0]
    );
    let rings: Vec<(f64, f64, f64)> = marks
        .iter()
        .filter_map(|(z, m)| match m {
            Some(BrushMark::Above {
                ring_mm, height_mm, ..
            }) => Some((*z, *height_mm, *ring_mm)),
            _ => None,
        })
        .collect();
    assert!(
        rings.len() >= 8,
        "{model:?}: a ring on the way down: {rings:?}"
    );
    for w in rings.windows(2) {
        assert!(
            w[1].2 < w[0].2 && w[1].1 < w[0].1,
            "{model:?}: the ring tightens as the tip descends: {w:?}"
        );
    }
    // Within reach from the first ring on, and the ring reaches the tip's size at the paper.
    assert!(rings[0].1 <= HOVER_REACH_MM);
    let last = rings.last().unwrap();
    // (The descent's step is 2.5 mm.)
    assert!(
        last.1 <= 2.51 && last.2 < 2.0,
        "{model:?}: near the paper {last:?}"
    );
    // Then the footprint, with the press depth growing.
    let touching: Vec<(f64, usize, f64)> = marks
        .iter()
        .filter_map(|(z, m)| match m {
            Some(BrushMark::Touching {
                outlines, depth_mm, ..
            }) => Some((*z, outlines.len(), *depth_mm)),
            _ => None,
        })
        .collect();
    assert!(touching.len() >= 3, "{model:?}: it touched: {touching:?}");
    assert!(
        touching.iter().all(|t| t.1 >= 1),
        "{model:?}: an outline: {touching:?}"
    );
    for w in touching.windows(2) {
        assert!(w[1].2 > w[0].2, "{model:?}: the depth grows: {touching:?}");
    }
    let deepest = touching.last().unwrap();
    assert!(
        deepest.2 > 0.15 * length,
        "{model:?}: pressed: {touching:?}"
    );
    // Lifting it again beyond reach takes the mark away.
    let mut dev = simulator(model);
    assert!(brush_mark(&frame_at(&mut dev, length * 0.9), length).is_some());
    assert!(brush_mark(&frame_at(&mut dev, length + HOVER_REACH_MM + 10.0), length).is_none());
}

#[test]
fn the_ring_tightens_as_the_brush_descends_and_is_gone_beyond_reach() {
    check_descent(ModelKind::Liang);
}

#[test]
fn baxter_and_lins_brush_has_the_same_mark() {
    check_descent(ModelKind::BaxterLin);
}

/// The app as a user's first start shows it: the writing view (no settings).
fn writing_app() -> MaobiApp {
    let device = SimDevice::new(SimClock::Stepped(50), "large", start_hand(40.0)).unwrap();
    let opts = GuiOptions {
        paper_mm: 150.0,
        px_per_mm: 4.0,
        ..GuiOptions::default()
    };
    MaobiApp::new(
        Box::new(device),
        opts.frame(),
        Automation::default(),
        Default::default(),
    )
}

fn key(h: &mut Harness<'static, MaobiApp>, modifiers: egui::Modifiers, key: egui::Key) {
    h.key_press_modifiers(modifiers, key);
    h.run_steps(1);
}

#[test]
fn the_writing_view_gives_the_paper_the_window() {
    let mut h = common::harness_sized(writing_app(), 1600.0, 1000.0);
    h.run_steps(3);
    assert_eq!(h.state().face(), Face::Writing, "a first start writes");
    let view = h.state().paper().view_rect;
    let share = view.area() / (1600.0 * 1000.0);
    eprintln!("paper view {view:?}: {:.1}% of the window", share * 100.0);
    assert!(share >= 0.7, "the paper view has {share:.3} of the window");
    // The laboratory's panels are not there; its switch is.
    assert!(h.query_by_label("device tick period (ms)").is_none());
    h.get_by_label("Laboratory");
}

#[test]
fn shortcuts_write_undo_save_dip_and_switch_faces() {
    let mut h = common::harness_sized(writing_app(), 1600.0, 1000.0);
    h.run_steps(2);
    let hook =
        std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../examples/poses/hook.csv");
    h.state_mut().start_replay(&hook).unwrap();
    h.run_steps(60);
    let inked = h.state().paper().canvas().ink_fraction();
    assert!(inked > 0.001, "the stroke inked: {inked}");
    assert!(h.state().paper().undo_depth() > 0);

    // Ctrl+Z takes the stroke back.
    key(&mut h, egui::Modifiers::COMMAND, egui::Key::Z);
    assert_eq!(h.state().paper().canvas().ink_fraction(), 0.0, "undone");

    // Write again; Ctrl+S saves the picture where it was told to.
    h.state_mut().start_replay(&hook).unwrap();
    h.run_steps(60);
    let dir = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("writing");
    std::fs::create_dir_all(&dir).unwrap();
    let png = dir.join("picture.png");
    let _ = std::fs::remove_file(&png);
    h.state_mut().set_picture_path(&png);
    key(&mut h, egui::Modifiers::COMMAND, egui::Key::S);
    let decoded = png::Decoder::new(std::io::BufReader::new(
        std::fs::File::open(&png).expect("Ctrl+S wrote the picture"),
    ))
    .read_info()
    .unwrap();
    assert_eq!(decoded.info().width, 600, "the whole paper at 4 px/mm");

    // D dips.
    key(&mut h, egui::Modifiers::NONE, egui::Key::D);
    h.get_by_label("dipped: ink load 1.00");

    // G steps through the grids.
    key(&mut h, egui::Modifiers::NONE, egui::Key::G);
    assert_eq!(h.state().settings().grid, Grid::Mi);

    // F2 opens the laboratory, and the settings remember it.
    key(&mut h, egui::Modifiers::NONE, egui::Key::F2);
    h.run_steps(1);
    assert_eq!(h.state().face(), Face::Laboratory);
    h.get_by_label("device tick period (ms)");
    let left = h.state().settings();
    assert_eq!(left.face, Face::Laboratory);

    // The next start comes back in the face it was left in.
    let mut again = writing_app();
    again.restore(&left, false);
    assert_eq!(again.face(), Face::Laboratory);
    assert_eq!(again.settings().grid, Grid::Mi);
}

#[test]
fn a_file_button_asks_for_a_dialog_after_the_frame_and_its_answer_is_acted_on() {
    let mut h = common::harness_sized(writing_app(), 1600.0, 1000.0);
    h.run_steps(2);
    // The "…" beside "Save picture" asks; nothing is shown inside the frame (no window
    // here: the app shows it after the frame, on the window, on a thread of its own).
    h.get_by_label("…").click();
    h.run_steps(1);
    let asked = h
        .state()
        .pending_dialog()
        .cloned()
        .expect("a dialog asked for");
    assert_eq!(asked.purpose, Purpose::Save(FileKind::Png));
    assert_eq!(asked.current, h.state().settings().png_path);
    // Ctrl+Shift+S asks for the same.
    key(
        &mut h,
        egui::Modifiers::COMMAND | egui::Modifiers::SHIFT,
        egui::Key::S,
    );
    assert_eq!(
        h.state().pending_dialog().map(|d| d.purpose),
        Some(Purpose::Save(FileKind::Png))
    );
    // The answer saves the picture there and remembers the path.
    let dir = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("writing");
    std::fs::create_dir_all(&dir).unwrap();
    let png = dir.join("chosen.png");
    let _ = std::fs::remove_file(&png);
    let ctx = h.ctx.clone();
    h.state_mut()
        .file_chosen(Purpose::Save(FileKind::Png), &png, &ctx);
    assert!(png.exists(), "saved where the dialog said");
    assert_eq!(h.state().settings().png_path, png.display().to_string());
}
