//! The GUI over a protocol device: the real app (egui_kittest, no window) with the TCP
//! backend to the simulated protocol device. A replay inks the paper from the received
//! geometry; when the device dies the status bar says the link is lost and the paper keeps
//! its ink; when it comes back the app reconnects.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use egui_kittest::kittest::Queryable;
use egui_kittest::Harness;
use maobi::device::{Endpoint, LinkDevice, LinkOptions, SimDeviceOptions, SimDeviceServer};
use maobi::gui::app::{Automation, MaobiApp};
use maobi::gui::{start_hand, GuiOptions};

mod common;

fn harness(endpoint: Endpoint) -> Harness<'static, MaobiApp> {
    let device = LinkDevice::new(LinkOptions::new(endpoint, start_hand(40.0))).unwrap();
    common::harness(common::app_over(
        Box::new(device),
        150.0,
        4.0,
        Automation::default(),
    ))
}

/// Steps the UI (in real time: the device runs on its own clock) until `what` holds.
fn step_until(
    h: &mut Harness<'static, MaobiApp>,
    timeout: Duration,
    what: impl Fn(&MaobiApp) -> bool,
) -> bool {
    let end = Instant::now() + timeout;
    while Instant::now() < end {
        h.run_steps(1);
        if what(h.state()) {
            return true;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    false
}

#[test]
fn the_app_inks_over_tcp_and_keeps_the_paper_when_the_link_drops() {
    let mut srv = SimDeviceServer::spawn("127.0.0.1:0", SimDeviceOptions::default()).unwrap();
    let addr = srv.addr().to_string();
    let mut h = harness(Endpoint::Tcp(addr.clone()));
    h.run_steps(2);
    assert!(h.state().status().connected, "{:?}", h.state().status());
    h.get_by_label_contains("connected to tcp:");
    h.get_by_label("Disconnect");

    let hook = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../examples/poses/hook.csv");
    h.state_mut().start_replay(&hook).unwrap();
    assert!(
        step_until(&mut h, Duration::from_secs(15), |a| {
            a.status().replays_done == 1 && !a.status().replaying
        }),
        "the replay finishes: {:?}",
        h.state().status()
    );
    let ink = h.state().paper().canvas().ink_fraction();
    assert!(ink > 0.001, "the replay inked the paper: {ink}");
    assert!(h.state().replay_frames() > 100);
    // Every frame's ink went up in the first UI frame after it arrived (the reader thread
    // wakes the UI; the UI drains and inks everything it has).
    let lat = h.state().ink_latency();
    println!("arrival to ink: {lat:?}");
    assert!(lat.frames > 0);
    assert_eq!(lat.late, 0, "frames waited more than one UI frame: {lat:?}");
    // The live plots: the device's own tick period (from its telemetry) and our frame rate.
    h.get_by_label("device tick period (ms)");
    h.get_by_label("device frames received (1/s)");
    assert!(
        step_until(&mut h, Duration::from_secs(3), |a| a
            .status()
            .tick_period_ms
            .is_some_and(|p| p > 0.5 && p < 2.0)),
        "telemetry reports the tick period: {:?}",
        h.state().status().tick_period_ms
    );

    srv.stop();
    assert!(
        step_until(&mut h, Duration::from_secs(3), |a| !a.status().connected),
        "the loss shows"
    );
    h.run_steps(2);
    h.get_by_label_contains("link lost");
    assert_eq!(
        h.state().paper().canvas().ink_fraction(),
        ink,
        "the paper keeps its ink"
    );

    let _srv2 = SimDeviceServer::spawn(&addr, SimDeviceOptions::default()).unwrap();
    assert!(
        step_until(&mut h, Duration::from_secs(5), |a| a.status().connected),
        "reconnects"
    );
    h.run_steps(2);
    h.get_by_label_contains("connected to tcp:");
    assert_eq!(h.state().paper().canvas().ink_fraction(), ink);
}

#[test]
fn the_cli_names_the_device_forms() {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_maobi"))
        .args(["gui", "--device", "usb:3"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("expected sim, tcp:HOST:PORT or serial:PATH"),
        "{err}"
    );
}

#[test]
fn maobi_sim_device_serves_the_protocol() {
    use std::io::{BufRead, BufReader};
    use std::process::{Command, Stdio};
    let mut child = Command::new(env!("CARGO_BIN_EXE_maobi"))
        .args(["sim-device", "--listen", "127.0.0.1:0", "--brush", "small"])
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut line = String::new();
    BufReader::new(child.stderr.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    let addr = line
        .split("--device tcp:")
        .nth(1)
        .and_then(|s| s.split('`').next())
        .unwrap_or_else(|| panic!("the address is printed: {line}"))
        .to_string();
    let mut dev = LinkDevice::new(LinkOptions::new(Endpoint::Tcp(addr), start_hand(30.0))).unwrap();
    use maobi::device::Device;
    let r = dev.connect();
    let small = maobi_shared::presets::by_name("small").unwrap();
    let end = Instant::now() + Duration::from_secs(3);
    while dev.status().params != small && Instant::now() < end {
        std::thread::sleep(Duration::from_millis(10));
    }
    let status = dev.status();
    let _ = child.kill();
    let _ = child.wait();
    r.expect("connects to `maobi sim-device`");
    assert_eq!(status.params, small, "the device's parameters were read");
}

/// The device chooser: from the built-in simulator to a TCP device (combo, address field,
/// Use); the paper keeps what the simulator drew.
#[test]
fn the_device_chooser_switches_to_tcp_and_keeps_the_paper() {
    use maobi::device::builtin::{SimClock, SimDevice};
    let srv = SimDeviceServer::spawn("127.0.0.1:0", SimDeviceOptions::default()).unwrap();
    let opts = GuiOptions {
        paper_mm: 150.0,
        px_per_mm: 4.0,
        ..GuiOptions::default()
    };
    let device = SimDevice::new(SimClock::Stepped(50), "large", start_hand(40.0)).unwrap();
    let mut app = MaobiApp::new(
        Box::new(device),
        opts.frame(),
        Automation::default(),
        Default::default(),
    );
    // The device chooser is the laboratory's.
    app.set_face(maobi::gui::writing::Face::Laboratory);
    let mut h = common::harness(app);
    h.run_steps(2);
    let hook = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../examples/poses/hook.csv");
    h.state_mut().start_replay(&hook).unwrap();
    h.run_steps(40);
    let ink = h.state().paper().canvas().ink_fraction();
    assert!(ink > 0.001, "the simulator drew: {ink}");

    h.get_by_role_and_label(egui::accesskit::Role::ComboBox, "device")
        .click();
    h.run_steps(2);
    h.get_by_label("TCP (QEMU board, sim-device, bridge)")
        .click();
    h.run_steps(2);
    h.get_by_role_and_label(egui::accesskit::Role::TextInput, "address")
        .set_text_value_accesskit(&srv.addr().to_string());
    h.run_steps(2);
    h.get_by_label("Use").click();
    assert!(
        step_until(&mut h, Duration::from_secs(5), |a| a.status().connected
            && a.status().link.is_some()),
        "switched and connected: {:?}",
        h.state().status()
    );
    h.run_steps(2);
    // The message and the link's status row.
    assert_eq!(h.get_all_by_label_contains("connected to tcp:").count(), 2);
    assert_eq!(h.state().paper().canvas().ink_fraction(), ink);
}

#[test]
fn the_chooser_offers_the_phantom_and_falls_back_with_the_reason() {
    let mut h = harness(Endpoint::Tcp("127.0.0.1:9".into()));
    h.run_steps(1);
    let missing = std::env::temp_dir().join("maobi-no-such-libHD.so");
    h.state_mut().choose_phantom(Some(&missing));
    h.run_steps(1);
    h.get_by_label("libHD.so");
    let ctx = h.ctx.clone();
    h.state_mut().switch_device(&ctx);
    h.run_steps(2);
    let s = h.state().status();
    assert!(s.connected, "the fallback simulator runs: {s:?}");
    assert!(
        s.name.contains("Phantom unavailable") || s.faults.iter().any(|f| f.contains("Phantom")),
        "the reason shows: {s:?}"
    );
    assert!(
        format!("{s:?}").contains("maobi-no-such-libHD.so"),
        "the path it looked for is named: {s:?}"
    );
}
