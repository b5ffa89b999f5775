//! What the host's tests share: the app in a kittest harness (no window) with fonts of its
//! own, the example files, the guide stroke and a guided run along it, and the stderr of a
//! `maobi` server process.

// Each test binary includes this module and uses a part of it.
#![allow(dead_code)]

use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::ChildStderr;
use std::sync::mpsc::Receiver;
use std::sync::{Arc, Mutex};

use egui_kittest::Harness;
use maobi::device::builtin::{SimClock, SimCore, SimDevice};
use maobi::device::{BrushFrame, Device, DeviceCommand, GuideFrame};
use maobi::gui::app::{Automation, MaobiApp};
use maobi::gui::fonts::{CjkFont, FontSource, CJK_TEXT};
use maobi::gui::{start_hand, GuiOptions};
use maobi::poses::PoseTrack;
use maobi_shared::guide::DEFAULT_GUIDE;

pub mod test_font;

/// The app on the `large` brush's simulator running on `clock`, with a square paper of
/// `paper_mm` at `px_per_mm`, driven by `automation`.
pub fn app(clock: SimClock, paper_mm: f64, px_per_mm: f64, automation: Automation) -> MaobiApp {
    let device = SimDevice::new(clock, "large", start_hand(40.0)).expect("the simulator starts");
    app_over(Box::new(device), paper_mm, px_per_mm, automation)
}

/// The app over `device`, with a square paper of `paper_mm` at `px_per_mm`, driven by
/// `automation`.
pub fn app_over(
    device: Box<dyn Device>,
    paper_mm: f64,
    px_per_mm: f64,
    automation: Automation,
) -> MaobiApp {
    let opts = GuiOptions {
        paper_mm,
        px_per_mm,
        ..GuiOptions::default()
    };
    // The laboratory: these tests drive its controls (the writing view has its own tests).
    let mut app = MaobiApp::new(device, opts.frame(), automation, Default::default());
    app.set_face(maobi::gui::writing::Face::Laboratory);
    app
}

/// `app` in a 1400 x 900 kittest harness.
pub fn harness(app: MaobiApp) -> Harness<'static, MaobiApp> {
    harness_sized(app, 1400.0, 900.0)
}

/// `app` in a kittest harness of `width` x `height`, drawing with [`test_fonts`]. kittest
/// panics on a character no font draws.
pub fn harness_sized(app: MaobiApp, width: f32, height: f32) -> Harness<'static, MaobiApp> {
    let app = app.with_fonts(test_fonts());
    Harness::builder()
        .with_size(egui::vec2(width, height))
        .build_ui_state(|ui, app: &mut MaobiApp| app.frame_ui(ui), app)
}

/// The fonts every test draws with, whatever the machine has: egui's, then a CJK font made
/// here that draws the app's CJK text ([`CJK_TEXT`]) and nothing else (no arrows, no Latin).
pub fn test_fonts() -> FontSource {
    FontSource::Fixed(Some(test_cjk_font()))
}

/// The CJK font of [`test_fonts`].
pub fn test_cjk_font() -> CjkFont {
    CjkFont::from_bytes("test font", test_font::font_for(CJK_TEXT))
        .expect("the test font draws the app's CJK text")
}

/// `examples/poses/NAME`.
pub fn example(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../examples/poses")
        .join(name)
}

/// The guide stroke: a 30 mm line along paper +x in 0.5 s, from `(0, y, z)` (mm).
pub fn guide_line(y: f64, z: f64) -> PoseTrack {
    let csv = format!("t,x,y,z,qw,qx,qy,qz\n0,0,{y},{z},1,0,0,0\n0.5,30,{y},{z},1,0,0,0\n");
    PoseTrack::from_reader("line.csv", csv.as_bytes()).expect("the guide line parses")
}

/// Guided writing on the simulator `core`, forces on: the brush settles 600 ticks, then the
/// guide plays [`guide_line`]`(0, 50)` (the brush in free air) while the hand stays put.
/// Checks what every model's guide must do: the pull within the guide's limit and toward
/// the point running ahead along +x, the fade-in, and the guide letting go once, after the
/// stroke and its fade-out. `each` sees every guided tick's frame and guide for the model's
/// own checks; returns the ticks the guide pulled on.
pub fn guide_along_a_line(
    core: &mut SimCore,
    mut each: impl FnMut(usize, &BrushFrame, &GuideFrame),
) -> usize {
    core.apply(DeviceCommand::EnableForces(true)).unwrap();
    for _ in 0..600 {
        core.step();
    }
    core.apply(DeviceCommand::Guide(Some(Arc::new(guide_line(0.0, 50.0)))))
        .unwrap();
    assert!(core.guiding());
    let (mut pulled, mut last_gain, mut ended_at) = (0, 0.0, None);
    for k in 0..1200 {
        let f = core.step();
        let Some(g) = f.guide else {
            ended_at.get_or_insert(k);
            continue;
        };
        assert!(ended_at.is_none(), "the guide came back at tick {k}");
        let gf = (g.force[0].powi(2) + g.force[1].powi(2) + g.force[2].powi(2)).sqrt();
        assert!(
            gf <= DEFAULT_GUIDE.max_force_n as f64 + 1e-6,
            "tick {k}: {gf} N"
        );
        if g.distance_mm > 1.0 && g.gain > 0.0 {
            assert!(g.force[0] > 0.0, "tick {k}: pulls toward +x: {:?}", g.force);
            pulled += 1;
        }
        if k < 300 {
            assert!(g.gain >= last_gain, "fades in");
        }
        last_gain = g.gain;
        each(k, &f, &g);
    }
    let ended_at = ended_at.expect("the guide lets go after the stroke");
    // 500 ticks of stroke, then the 0.3 s fade-out.
    assert!((750..=850).contains(&ended_at), "ended at tick {ended_at}");
    assert!(!core.guiding());
    pulled
}

/// The last line of a server's log: its stderr has been read to the end.
pub const STDERR_CLOSED: &str = "(stderr closed)\n";

/// Reads a server process's `stderr` on a thread of its own: every line into the log, then
/// [`STDERR_CLOSED`]; the first address `find` picks out of a line goes to the receiver.
pub fn collect_stderr(
    stderr: ChildStderr,
    find: fn(&str) -> Option<String>,
) -> (Arc<Mutex<String>>, Receiver<String>) {
    let log = Arc::new(Mutex::new(String::new()));
    let (tx, rx) = std::sync::mpsc::channel();
    {
        let log = log.clone();
        std::thread::spawn(move || {
            for line in BufReader::new(stderr).lines().map_while(Result::ok) {
                if let Some(a) = find(&line) {
                    let _ = tx.send(a);
                }
                log.lock().unwrap().push_str(&(line + "\n"));
            }
            log.lock().unwrap().push_str(STDERR_CLOSED);
        });
    }
    (log, rx)
}
