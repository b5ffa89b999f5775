//! Sessions: saved from the app, opened in another, the canvas must come back bit for bit,
//! and the simulator must go on from the same state.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use egui_kittest::kittest::Queryable;
use egui_kittest::Harness;
use maobi::device::builtin::{SimClock, SimDevice};
use maobi::gui::app::{Automation, MaobiApp};
use maobi::gui::session::Session;
use maobi::gui::{start_hand, GuiOptions};
use maobi::paper::PaperKind;
use maobi_shared::ParamId;

mod common;
use common::example;

const TICKS_PER_FRAME: usize = 50;

fn tmp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("maobi-session-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

fn harness(clock: SimClock) -> Harness<'static, MaobiApp> {
    let mut app = common::app(clock, 150.0, 4.0, Automation::default());
    app.set_session_clock(clock);
    common::harness(app)
}

/// Steps the UI until `done`, for at most `limit` (real-time devices need real time).
fn run_until(
    h: &mut Harness<'static, MaobiApp>,
    limit: Duration,
    done: impl Fn(&MaobiApp) -> bool,
) {
    let t0 = Instant::now();
    while !done(h.state()) {
        assert!(t0.elapsed() < limit, "timed out after {limit:?}");
        h.run_steps(1);
        std::thread::sleep(Duration::from_millis(2));
    }
}

fn replay(h: &mut Harness<'static, MaobiApp>, name: &str) {
    let done = h.state().status().replays_done;
    h.state_mut().start_replay(&example(name)).unwrap();
    run_until(h, Duration::from_secs(60), |a| {
        a.status().replays_done > done && !a.status().replaying
    });
    // A few more frames: a real-time device's last frames arrive after its status.
    h.run_steps(3);
}

/// Draws a short stroke with the pointer (the live hand, not a replay).
fn draw_with_pointer(h: &mut Harness<'static, MaobiApp>, from_px: [f32; 2], to_px: [f32; 2]) {
    let r = h.state().paper().view_rect;
    let at = |f: f32| {
        egui::pos2(
            r.center().x + from_px[0] + (to_px[0] - from_px[0]) * f,
            r.center().y + from_px[1] + (to_px[1] - from_px[1]) * f,
        )
    };
    h.event(egui::Event::PointerMoved(at(0.0)));
    h.run_steps(4);
    h.event(egui::Event::PointerButton {
        pos: at(0.0),
        button: egui::PointerButton::Primary,
        pressed: true,
        modifiers: egui::Modifiers::NONE,
    });
    for k in 0..=20 {
        h.event(egui::Event::PointerMoved(at(k as f32 / 20.0)));
        h.run_steps(2);
    }
    h.event(egui::Event::PointerButton {
        pos: at(1.0),
        button: egui::PointerButton::Primary,
        pressed: false,
        modifiers: egui::Modifiers::NONE,
    });
    h.run_steps(6);
}

fn open(path: &Path, clock: SimClock) -> Harness<'static, MaobiApp> {
    let mut h = harness(clock);
    h.run_steps(1);
    h.state_mut().open_session(path, None);
    run_until(&mut h, Duration::from_secs(120), |a| !a.opening_session());
    h.run_steps(1);
    h
}

fn coverage(h: &Harness<'static, MaobiApp>) -> Vec<f32> {
    h.state().paper().canvas().ink().to_vec()
}

/// Replays, dips, changes a parameter, draws with the pointer, undoes, clears and undoes
/// the clear: the session file brings the same canvas back, and the model goes on the same.
#[test]
fn a_saved_session_reopens_to_the_same_canvas_and_goes_on_the_same() {
    let clock = SimClock::Stepped(TICKS_PER_FRAME);
    let mut h = harness(clock);
    h.run_steps(2);
    replay(&mut h, "hook.csv");
    h.state_mut().set_param(ParamId::Plasticity, 0.02);
    h.state_mut().set_param(ParamId::Wetness, 0.6);
    replay(&mut h, "heng.csv");
    draw_with_pointer(&mut h, [-60.0, 40.0], [80.0, 60.0]);
    assert!(h.state_mut().undo(), "the pointer stroke inked");
    draw_with_pointer(&mut h, [-40.0, -80.0], [40.0, -70.0]);
    h.state_mut().clear();
    assert!(h.state_mut().undo());
    let before = coverage(&h);
    let strokes = h.state().paper().strokes();
    assert!(strokes >= 3, "{strokes} strokes");
    assert!(h.state().paper().canvas().ink_fraction() > 0.001);

    let path = tmp("stepped.maobi.toml");
    let ticks = h.state_mut().save_session(&path).unwrap();
    let text = std::fs::read_to_string(&path).unwrap();
    println!(
        "session: {ticks} ticks, {} bytes, {} pose rows",
        text.len(),
        text.lines()
            .filter(|l| l.starts_with(char::is_numeric))
            .count()
    );

    let mut h2 = open(&path, clock);
    let after = coverage(&h2);
    let differ = before.iter().zip(&after).filter(|(a, b)| a != b).count();
    assert_eq!(differ, 0, "{differ} pixels differ after re-rendering");
    assert_eq!(h2.state().paper().strokes(), strokes);
    assert_eq!(
        h2.state().paper().undo_depth(),
        h.state().paper().undo_depth()
    );
    assert_eq!(h2.state().status().params.wetness, 0.6);
    h2.get_by_label_contains("ticks re-rendered");

    // Both go on with the same stroke: the re-rendered model is in the same state.
    replay(&mut h, "shu.csv");
    replay(&mut h2, "shu.csv");
    assert_eq!(coverage(&h), coverage(&h2), "the next stroke inks the same");

    // Saving the opened session again gives the same file plus what was added.
    let again = tmp("again.maobi.toml");
    h2.state_mut().save_session(&again).unwrap();
    let h3 = open(&again, clock);
    assert_eq!(coverage(&h3), coverage(&h2));
}

/// The model runs on its own thread in real time: the journal still knows the exact tick
/// each command and pose took effect.
#[test]
fn a_real_time_session_reopens_to_the_same_canvas() {
    let mut h = harness(SimClock::RealTime);
    run_until(&mut h, Duration::from_secs(10), |a| a.latest().is_some());
    replay(&mut h, "press_lift.csv");
    h.state_mut().set_param(ParamId::Plasticity, 0.03);
    h.get_by_label("Dip ink").click();
    h.run_steps(2);
    replay(&mut h, "hook.csv");
    let before = coverage(&h);
    assert!(h.state().paper().canvas().ink_fraction() > 0.0);
    let path = tmp("realtime.maobi.toml");
    h.state_mut().save_session(&path).unwrap();

    let h2 = open(&path, SimClock::Stepped(TICKS_PER_FRAME));
    let differ = before
        .iter()
        .zip(coverage(&h2))
        .filter(|(a, b)| **a != *b)
        .count();
    assert_eq!(differ, 0, "{differ} pixels differ");
}

#[test]
fn bad_session_files_say_what_is_wrong() {
    let mut h = harness(SimClock::Stepped(TICKS_PER_FRAME));
    h.run_steps(2);
    replay(&mut h, "press_lift.csv");
    let good = h.state().session().unwrap().to_toml().unwrap();
    Session::from_toml(&good).expect("the app's own file reads back");

    let (row_index, first_row) = good
        .lines()
        .enumerate()
        .find(|(_, l)| l.starts_with(char::is_numeric))
        .unwrap();
    let first_row = first_row.to_string();
    let bad_x = format!("poses, line {}, column x", row_index + 1);
    let cases: Vec<(String, &str)> = vec![
        (good.replace("maobi-session", "something"), "format"),
        (good.replace("version = 2", "version = 7"), "version 7"),
        (good.replace("model = ", "# model = "), "needs `model`"),
        (
            good.replace("preset = \"large\"", "preset = \"huge\""),
            "unknown brush `huge`",
        ),
        (
            good.replacen(&first_row, &first_row.replacen(',', ",abc", 1), 1),
            &bad_x,
        ),
        (
            good.replacen("tick,x,y,z,qw,qx,qy,qz", "t,x,y,z", 1),
            "header",
        ),
        (good.replace("wetness = ", "wetness = -"), "wetness"),
        (String::from("not toml ["), "not a session file"),
    ];
    for (text, want) in cases {
        let e = Session::from_toml(&text).expect_err(want);
        let msg = format!("{e:#}");
        assert!(msg.contains(want), "`{want}` not in `{msg}`");
    }

    // A missing file names the path; the app shows the error and keeps its paper.
    let missing = tmp("nope.maobi.toml");
    let ink = h.state().paper().canvas().ink_fraction();
    h.state_mut().open_session(&missing, None);
    run_until(&mut h, Duration::from_secs(10), |a| !a.opening_session());
    h.run_steps(1);
    h.get_by_label_contains("cannot open");
    h.get_by_label_contains("nope.maobi.toml");
    assert_eq!(h.state().paper().canvas().ink_fraction(), ink);
}

/// `maobi render --session` re-renders a saved session headless: the PNG is the app's paper,
/// here raw paper, whose ink the app spread live while the strokes were written.
#[test]
fn maobi_render_session_writes_the_apps_paper() {
    let mut h = harness(SimClock::Stepped(TICKS_PER_FRAME));
    h.run_steps(2);
    h.state_mut().set_paper(PaperKind::Raw);
    replay(&mut h, "hook.csv");
    h.state_mut().set_param(ParamId::Wetness, 0.5);
    replay(&mut h, "shu.csv");
    let path = tmp("cli.maobi.toml");
    h.state_mut().save_session(&path).unwrap();
    let text = std::fs::read_to_string(&path).unwrap();
    assert!(text.contains("kind = \"raw\""), "{text}");
    let png = tmp("cli.png");
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_maobi"))
        .args(["render", "--session"])
        .arg(&path)
        .arg("-o")
        .arg(&png)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    println!("{err}");
    assert!(out.status.success(), "{err}");
    assert!(err.contains("2 strokes"), "{err}");
    // stderr is a pipe here: no progress bar, the summary line alone.
    assert_eq!(err.lines().count(), 1, "{err:?}");
    assert!(!err.contains('\r') && !err.contains("ETA"), "{err:?}");
    let want = h.state().paper().canvas().to_gray8();
    let dec = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&png).unwrap()));
    let mut r = dec.read_info().unwrap();
    let mut buf = vec![0; r.output_buffer_size().unwrap()];
    let info = r.next_frame(&mut buf).unwrap();
    assert_eq!(
        (info.width as usize, info.height as usize),
        (
            h.state().paper().frame().width,
            h.state().paper().frame().height
        )
    );
    assert_eq!(info.color_type, png::ColorType::Grayscale);
    assert_eq!(
        &buf[..info.buffer_size()],
        &want[..],
        "the PNG is the app's paper"
    );
    assert!(!err.contains("warning"), "{err}");

    // The same session as a file from before models had versions: it renders, and says
    // that this build's model may ink it differently.
    let model_line = text.lines().find(|l| l.starts_with("model = ")).unwrap();
    let old = text
        .replace("version = 2", "version = 1")
        .replace(&format!("{model_line}\n"), "");
    std::fs::write(&path, old).unwrap();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_maobi"))
        .args(["render", "--session"])
        .arg(&path)
        .arg("-o")
        .arg(&png)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(
        err.contains("warning") && err.contains("before brush models had versions"),
        "{err}"
    );

    // A broken session: a clear error and a non-zero exit, no PNG.
    std::fs::write(&path, "format = \"maobi-session\"\nversion = 1\n").unwrap();
    let bad = tmp("bad.png");
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_maobi"))
        .args(["render", "--session"])
        .arg(&path)
        .arg("-o")
        .arg(&bad)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        err.contains("cli.maobi.toml") && err.contains("missing field"),
        "{err}"
    );
    assert!(!bad.exists());
}

/// `maobi gui --session FILE` opens the session at start (the automation path).
#[test]
fn the_gui_opens_a_session_given_at_start() {
    let clock = SimClock::Stepped(TICKS_PER_FRAME);
    let mut h = harness(clock);
    h.run_steps(2);
    replay(&mut h, "heng.csv");
    let path = tmp("start.maobi.toml");
    h.state_mut().save_session(&path).unwrap();

    let opts = GuiOptions {
        paper_mm: 150.0,
        px_per_mm: 4.0,
        ..GuiOptions::default()
    };
    let device = SimDevice::new(clock, "small", start_hand(20.0)).unwrap();
    let automation = Automation {
        session: Some(path.clone()),
        ..Automation::default()
    };
    let mut app = MaobiApp::new(
        Box::new(device),
        opts.frame(),
        automation,
        Default::default(),
    );
    app.set_session_clock(clock);
    let mut h2 = common::harness(app);
    h2.run_steps(1);
    run_until(&mut h2, Duration::from_secs(60), |a| !a.opening_session());
    h2.run_steps(1);
    assert_eq!(coverage(&h2), coverage(&h));
    assert_eq!(h2.state().status().preset, "large", "the session's brush");
}
