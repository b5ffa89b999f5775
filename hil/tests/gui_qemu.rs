//! The desktop app connected over TCP to the firmware in QEMU: a replay of an example stroke
//! leaves the same canvas, pixel for pixel, as the app's built-in simulator.
//!
//! This is the real `MaobiApp` (egui_kittest, no window) with the TCP device backend
//! (`maobi --device tcp:127.0.0.1:PORT`) connected to QEMU's UART0 socket; the firmware sends
//! every tick's state (`state_hz=1000`, as the built-in simulator hands the paper every
//! tick). The firmware runs slower than real time under emulation; the link's writer paces
//! the replay by the `pose_seq` the device reports, so no pose is lost.
//!
//! Needs `qemu-system-arm` (skipped with a message without it, unless `MAOBI_REQUIRE_QEMU`
//! is set, as in CI).

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use egui_kittest::Harness;
use hil::firmware;
use hil::qemu::{self, free_port, Clock, Run};
use hil::selftest::EMULATED_TICK_US;
use maobi::device::{Endpoint, LinkDevice, LinkOptions};
use maobi::gui::app::{Automation, MaobiApp};
use maobi::gui::device::Device;
use maobi::gui::sim::{SimClock, SimDevice};
use maobi::gui::{start_hand, GuiOptions};
use maobi_shared::presets;

fn image() -> Option<PathBuf> {
    if !qemu::available() {
        assert!(
            std::env::var_os("MAOBI_REQUIRE_QEMU").is_none(),
            "qemu-system-arm is missing (apt-get install qemu-system-arm)"
        );
        eprintln!("SKIPPED: qemu-system-arm is not installed");
        return None;
    }
    Some(firmware::build().expect("firmware builds"))
}

fn app(device: Box<dyn Device>) -> Harness<'static, MaobiApp> {
    let opts = GuiOptions {
        paper_mm: 150.0,
        px_per_mm: 4.0,
        ..GuiOptions::default()
    };
    let app = MaobiApp::new(
        device,
        opts.frame(),
        Automation::default(),
        Default::default(),
    );
    Harness::builder()
        .with_size(egui::vec2(1400.0, 900.0))
        .build_ui_state(|ui, app: &mut MaobiApp| app.frame_ui(ui), app)
}

/// Replays `poses` in the app and steps the UI until the replay is done and inked.
fn replay(h: &mut Harness<'static, MaobiApp>, poses: &Path, within: Duration) {
    h.state_mut()
        .start_replay(poses)
        .expect("the replay starts");
    let end = Instant::now() + within;
    loop {
        h.run_steps(1);
        let s = h.state().status();
        if s.replays_done == 1 && !s.replaying {
            break;
        }
        assert!(
            Instant::now() < end,
            "the replay did not finish within {within:?}: {s:?}"
        );
        std::thread::sleep(Duration::from_millis(2));
    }
    // The frames of the replay's last ticks are inked on the next UI frames.
    h.run_steps(3);
}

#[test]
fn the_app_over_tcp_to_the_qemu_firmware_inks_like_the_built_in_simulator() {
    let Some(elf) = image() else { return };
    let hook = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/poses/hook.csv");
    let length = f64::from(presets::LARGE.length_mm);

    // The built-in simulator (the same fixed-point model, in process).
    let sim = SimDevice::new(SimClock::Stepped(20), "large", start_hand(length)).unwrap();
    let mut local = app(Box::new(sim));
    local.run_steps(2);
    replay(&mut local, &hook, Duration::from_secs(120));

    // The firmware under QEMU, every tick's state on its UART0 socket.
    let port = free_port().unwrap();
    let tick = format!("tick_us={EMULATED_TICK_US}");
    let mut run = Run::new(
        &elf,
        &["run", &tick, "state_hz=1000"],
        Clock::Deterministic { shift: 0 },
        Duration::from_secs(600),
    );
    run.uart_port = Some(port);
    let mut guest = run.spawn().expect("QEMU starts");
    let device = LinkDevice::new(LinkOptions::new(
        Endpoint::Tcp(format!("127.0.0.1:{port}")),
        start_hand(length),
    ))
    .unwrap();
    let mut remote = app(Box::new(device));
    let end = Instant::now() + Duration::from_secs(30);
    while !remote.state().status().connected {
        assert!(Instant::now() < end, "connects to QEMU's UART0 socket");
        if let Ok(Some(st)) = guest.child.try_wait() {
            panic!("QEMU exited ({st}) before the link opened");
        }
        remote.run_steps(1);
        std::thread::sleep(Duration::from_millis(20));
    }
    let status = remote.state().status().clone();
    assert!(
        status
            .firmware_version
            .as_deref()
            .is_some_and(|v| v.contains("qemu")),
        "the handshake names the QEMU board: {status:?}"
    );
    replay(&mut remote, &hook, Duration::from_secs(300));

    let (a, b) = (
        remote.state().paper().canvas().coverage(),
        local.state().paper().canvas().coverage(),
    );
    assert_eq!(a.len(), b.len(), "same paper");
    let ink = local.state().paper().canvas().ink_fraction();
    assert!(ink > 0.001, "the hook inks the paper: {ink}");
    let differ = a.iter().zip(b).filter(|(x, y)| x != y).count();
    eprintln!(
        "hook over QEMU: {} px of ink-carrying paper, {differ} px differ; {} states, {} replay frames",
        a.iter().filter(|&&c| c > 0.0).count(),
        remote.state().status().link.as_ref().map_or(0, |l| l.states),
        remote.state().replay_frames()
    );
    assert_eq!(differ, 0, "the canvases are the same, pixel for pixel");
}
