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
use hil::qemu::{free_port, Clock, Run};
use hil::selftest::EMULATED_TICK_US;
use maobi::device::builtin::{SimClock, SimDevice};
use maobi::device::Device;
use maobi::device::{Endpoint, LinkDevice, LinkOptions};
use maobi::gui::app::{Automation, MaobiApp};
use maobi::gui::{start_hand, GuiOptions};
use maobi_shared::{presets, ParamId};

/// Substeps per tick that make the emulated pen's tick cost about 900,000 instructions,
/// slower under QEMU than the app's stream (see the test). The count follows the brush's
/// cost: 25 did it at 16 layers; at 12, whose substep is cheaper, a CI run at 25 received
/// 653 of the replay's 1,251 states and the canvases differed.
const PACED_SUBSTEPS: u8 = 35;

fn image() -> Option<PathBuf> {
    firmware::qemu_test_image()
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
    // The emulated pen ticks as fast as QEMU runs it (deterministic time, idle skipped) and,
    // like a pen, holds its last pose on a tick that none reached; the in-process simulator
    // ticks once per pose. So that both see every pose on its own tick, the pen must not
    // outrun the app's stream: `PACED_SUBSTEPS` per tick (on both) slow its ticks below the
    // stream's pace under QEMU.
    let paced = |h: &mut Harness<'static, MaobiApp>| {
        h.state_mut()
            .set_param(ParamId::SubstepsPerTick, f32::from(PACED_SUBSTEPS));
        let end = Instant::now() + Duration::from_secs(30);
        while h.state().status().params.substeps_per_tick != PACED_SUBSTEPS {
            assert!(Instant::now() < end, "the device took the rate");
            h.run_steps(1);
            std::thread::sleep(Duration::from_millis(5));
        }
    };
    paced(&mut local);
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
    paced(&mut remote);
    replay(&mut remote, &hook, Duration::from_secs(300));

    let (a, b) = (
        remote.state().paper().canvas().ink(),
        local.state().paper().canvas().ink(),
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

/// The app's link device guiding the firmware's pen in QEMU ("Guide me" on a QEMU pen): the
/// writer streams the stroke's moving point with the poses, the frames carry the point and
/// how far the pen is from it, the firmware's force carries the pull, and the guide fades out
/// and stops after the stroke.
#[test]
fn guided_writing_over_tcp_to_the_qemu_firmware() {
    use maobi::device::{DeviceCommand, HandInput};
    use std::sync::Arc;
    let Some(elf) = image() else { return };
    let length = f64::from(presets::LARGE.length_mm);
    let port = free_port().unwrap();
    let tick = format!("tick_us={EMULATED_TICK_US}");
    let mut run = Run::new(
        &elf,
        &["run", &tick, "state_hz=1000"],
        Clock::Deterministic { shift: 0 },
        Duration::from_secs(600),
    );
    run.uart_port = Some(port);
    let _guest = run.spawn().expect("QEMU starts");
    // The pen hangs 10 mm above the paper (the pointer does not move); the moving point runs
    // a 30 mm line in 0.5 s from 5 mm beside it.
    let z = length + 10.0;
    let mut dev = LinkDevice::new(LinkOptions::new(
        Endpoint::Tcp(format!("127.0.0.1:{port}")),
        HandInput {
            x: 0.0,
            y: 0.0,
            z,
            tilt_x_deg: 0.0,
            tilt_y_deg: 0.0,
        },
    ))
    .unwrap();
    // QEMU opens its socket when it is ready: the device keeps trying in the background.
    let _ = dev.connect();
    let mut frames = Vec::new();
    let end = Instant::now() + Duration::from_secs(30);
    while !dev.status().connected {
        assert!(Instant::now() < end, "connects to QEMU's UART0 socket");
        dev.poll(&mut frames);
        std::thread::sleep(Duration::from_millis(20));
    }
    dev.send(DeviceCommand::EnableForces(true)).unwrap();
    let end = Instant::now() + Duration::from_secs(20);
    while frames.len() < 300 && Instant::now() < end {
        dev.poll(&mut frames);
        std::thread::sleep(Duration::from_millis(5));
    }
    let csv = format!("t,x,y,z,qw,qx,qy,qz\n0,0,5,{z},1,0,0,0\n0.5,30,5,{z},1,0,0,0\n");
    let track = maobi::poses::PoseTrack::from_reader("line.csv", csv.as_bytes()).unwrap();
    dev.send(DeviceCommand::Guide(Some(Arc::new(track))))
        .unwrap();
    let mut all = Vec::new();
    let end = Instant::now() + Duration::from_secs(60);
    while Instant::now() < end {
        frames.clear();
        dev.poll(&mut frames);
        all.extend(frames.iter().cloned());
        let last = all.iter().rposition(|f| f.guide.is_some());
        if last.is_some_and(|i| all.len() > i + 200) {
            break;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    dev.disconnect();
    let guided: Vec<_> = all.iter().filter_map(|f| f.guide.map(|g| (f, g))).collect();
    let peak_gain = guided.iter().map(|(_, g)| g.gain).fold(0.0, f64::max);
    let pull = guided
        .iter()
        .map(|(f, _)| f.force_total[1])
        .fold(0.0, f64::max);
    eprintln!(
        "guided over QEMU: {} frames, {} guided, peak gain {peak_gain:.3}, device force toward \
         the line up to {pull:.3} N",
        all.len(),
        guided.len()
    );
    // 500 ticks of stroke and about 300 of fade-out, a state every tick.
    assert!(guided.len() > 500, "{}", guided.len());
    assert!(peak_gain > 0.9, "{peak_gain}");
    let last = all.iter().rposition(|f| f.guide.is_some()).unwrap();
    assert!(all[last + 1..].iter().all(|f| f.guide.is_none()));
    for (f, g) in &guided {
        let p = f.pose.pos.to_f64();
        let d = ((0..3).map(|i| (p[i] - g.anchor[i]).powi(2)).sum::<f64>()).sqrt();
        assert!(
            (d - g.distance_mm).abs() < 1e-9 && d >= 5.0 - 1e-6,
            "{d} {g:?}"
        );
        assert!(g.force.iter().map(|c| c * c).sum::<f64>().sqrt() <= 0.8 + 1e-6);
    }
    // The firmware's own force (the state's) pulls toward the line, y > 0: only the guide
    // acts sideways on a brush hanging in the air.
    assert!(pull > 0.1, "{pull}");
}
