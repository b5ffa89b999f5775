//! The app over the built-in simulator for GUI tests (egui_kittest, no window).

use egui_kittest::Harness;
use maobi::device::builtin::{SimClock, SimDevice};
use maobi::gui::app::{Automation, MaobiApp};
use maobi::gui::{start_hand, GuiOptions};

/// The app on the `large` brush's simulator running on `clock`, with a square paper of
/// `paper_mm` at `px_per_mm`, driven by `automation`.
pub fn app(clock: SimClock, paper_mm: f64, px_per_mm: f64, automation: Automation) -> MaobiApp {
    let opts = GuiOptions {
        paper_mm,
        px_per_mm,
        ..GuiOptions::default()
    };
    let device = SimDevice::new(clock, "large", start_hand(40.0)).expect("the simulator starts");
    MaobiApp::new(
        Box::new(device),
        opts.frame(),
        automation,
        Default::default(),
    )
}

/// `app` in a 1400 x 900 kittest harness.
pub fn harness(app: MaobiApp) -> Harness<'static, MaobiApp> {
    Harness::builder()
        .with_size(egui::vec2(1400.0, 900.0))
        .build_ui_state(|ui, app: &mut MaobiApp| app.frame_ui(ui), app)
}
