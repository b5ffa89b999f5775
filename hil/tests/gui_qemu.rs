//! The desktop app connected over TCP to the firmware in QEMU: a replay of an example stroke
//! leaves the same canvas, pixel for pixel, as the app's built-in simulator.
//!
//! This is the real `MaobiApp` (egui_kittest, no window) with the TCP device backend
//! (`maobi --device tcp:127.0.0.1:PORT`) connected to QEMU's UART0 socket; the firmware sends
//! every tick's state (`state_hz=1000`, as the built-in simulator hands the paper every
//! tick).
//!
//! The firmware runs in lock-step (`lockstep`, `firmware/src/qemu/mod.rs`): its pen ticks
//! exactly once per pose the app's link writer sends, as the in-process simulator does, and
//! holds until the state of its last tick is on its way, so every state reaches the app
//! however slowly QEMU or the app runs. Nothing here is paced by the wall clock: the only
//! deadlines are generous guards against a hang.
//!
//! Needs `qemu-system-arm` (skipped with a message without it, unless `MAOBI_REQUIRE_QEMU`
//! is set, as in CI).

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use egui_kittest::Harness;
use hil::firmware;
use hil::qemu::{Clock, Guest, Run};
use hil::selftest::EMULATED_TICK_US;
use maobi::device::builtin::{SimClock, SimDevice};
use maobi::device::Device;
use maobi::device::{Endpoint, LinkDevice, LinkOptions};
use maobi::gui::app::{Automation, MaobiApp};
use maobi::gui::{start_hand, GuiOptions};
use maobi_shared::force::OutputState;
use maobi_shared::presets;

/// Only a guard against a hang: far longer than any of these steps takes on a loaded machine.
const HANG_GUARD: Duration = Duration::from_secs(600);

/// Telemetry (the pen's counters of dropped frames and of ticks without a pose) every this
/// many ticks: the counters that cover a replay arrive soon after it.
const TELEMETRY_TICKS: u32 = 10;

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
    )
    // egui's own fonts, no system lookup: the same glyphs on every machine (the replay shows
    // no CJK text).
    .with_fonts(maobi::gui::fonts::FontSource::Fixed(None));
    Harness::builder()
        .with_size(egui::vec2(1400.0, 900.0))
        .build_ui_state(|ui, app: &mut MaobiApp| app.frame_ui(ui), app)
}

/// Steps the UI until `done` says so; fails (naming `what`) only if that takes longer than
/// the hang guard.
fn step_until(
    h: &mut Harness<'static, MaobiApp>,
    what: &str,
    mut done: impl FnMut(&MaobiApp) -> bool,
) {
    let end = Instant::now() + HANG_GUARD;
    while !done(h.state()) {
        assert!(
            Instant::now() < end,
            "{what}: not within {HANG_GUARD:?} (hung?): {:?}",
            h.state().status()
        );
        h.run_steps(1);
        std::thread::sleep(Duration::from_millis(2));
    }
}

/// Replays `poses` in the app and steps the UI until the replay is done and inked.
fn replay(h: &mut Harness<'static, MaobiApp>, poses: &Path) {
    h.state_mut()
        .start_replay(poses)
        .expect("the replay starts");
    step_until(h, "the replay finishes", |app| {
        let s = app.status();
        s.replays_done == 1 && !s.replaying
    });
    // The frames of the replay's last ticks are inked on the next UI frames.
    h.run_steps(3);
}

/// The firmware in QEMU in lock-step, every tick's state on its UART0 socket; returns the
/// emulator and the socket's address.
/// The app's link to a lock-step pen: a silence of the link's usual half second ends a
/// session (`LINK_TIMEOUT`), and a pen that ticks only on the test's poses is silent for as
/// long as this machine is busy elsewhere (on a loaded CI machine, both tests' links once
/// went quiet for more than that at the same moment). What these tests check is that every
/// state arrives, counted by sequence number, so the silence the link tolerates is the
/// tests' hang guard, not the wall clock of one frame.
fn lockstep_link(options: LinkOptions) -> LinkOptions {
    LinkOptions {
        silence_limit: Duration::from_secs(60),
        ..options
    }
}

fn lockstep_firmware(elf: &Path) -> (Guest, String) {
    let tick = format!("tick_us={EMULATED_TICK_US}");
    let telemetry = format!("telemetry_ticks={TELEMETRY_TICKS}");
    let mut run = Run::new(
        elf,
        &["run", &tick, "state_hz=1000", &telemetry, "lockstep"],
        Clock::Deterministic { shift: 0 },
        HANG_GUARD * 2,
    );
    let port = run.listen_uart().expect("a loopback socket for UART0");
    let guest = run.spawn().expect("QEMU starts");
    (guest, format!("127.0.0.1:{port}"))
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
    replay(&mut local, &hook);

    let (mut guest, addr) = lockstep_firmware(&elf);
    let device = LinkDevice::new(lockstep_link(LinkOptions::new(
        Endpoint::Tcp(addr),
        start_hand(length),
    )))
    .unwrap();
    let mut remote = app(Box::new(device));
    step_until(&mut remote, "connects to QEMU's UART0 socket", |app| {
        app.status().connected
    });
    if let Ok(Some(st)) = guest.child.try_wait() {
        panic!("QEMU exited ({st})");
    }
    let status = remote.state().status().clone();
    assert!(
        status
            .firmware_version
            .as_deref()
            .is_some_and(|v| v.contains("qemu")),
        "the handshake names the QEMU board: {status:?}"
    );
    replay(&mut remote, &hook);
    // The pen's counters that cover the whole replay: telemetry comes every
    // `TELEMETRY_TICKS` ticks, so it has come once this many more states have.
    let states = |app: &MaobiApp| app.status().link.as_ref().map_or(0, |l| l.states);
    let replayed = states(remote.state());
    step_until(&mut remote, "telemetry after the replay", |app| {
        states(app) > replayed + 4 * u64::from(TELEMETRY_TICKS)
    });
    let status = remote.state().status().clone();
    let link = status.link.clone().expect("a link report");
    assert_eq!(
        (status.frames_dropped, link.pose_gaps, link.lost),
        (0, 0, 0),
        "every state reached the app, every tick had its pose, the link held: {link:?}"
    );

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
    let (_guest, addr) = lockstep_firmware(&elf);
    // The pen hangs 10 mm above the paper (the pointer does not move); the moving point runs
    // a 30 mm line in 0.5 s from 5 mm beside it.
    let z = length + 10.0;
    let mut dev = LinkDevice::new(lockstep_link(LinkOptions::new(
        Endpoint::Tcp(addr),
        HandInput {
            x: 0.0,
            y: 0.0,
            z,
            tilt_x_deg: 0.0,
            tilt_y_deg: 0.0,
        },
    )))
    .unwrap();
    // QEMU opens its socket when it is ready: the device keeps trying in the background.
    let _ = dev.connect();
    let mut frames = Vec::new();
    let end = Instant::now() + HANG_GUARD;
    while !dev.status().connected {
        assert!(Instant::now() < end, "connects to QEMU's UART0 socket");
        dev.poll(&mut frames);
        std::thread::sleep(Duration::from_millis(20));
    }
    dev.send(DeviceCommand::EnableForces(true)).unwrap();
    // The pen hangs at rest with its forces on (the state says so) before the guide starts.
    let end = Instant::now() + HANG_GUARD;
    while frames.len() < 300
        || !frames
            .last()
            .is_some_and(|f| f.output == OutputState::Active)
    {
        assert!(
            Instant::now() < end,
            "300 states, forces on: {} states",
            frames.len()
        );
        dev.poll(&mut frames);
        std::thread::sleep(Duration::from_millis(5));
    }
    let csv = format!("t,x,y,z,qw,qx,qy,qz\n0,0,5,{z},1,0,0,0\n0.5,30,5,{z},1,0,0,0\n");
    let track = maobi::poses::PoseTrack::from_reader("line.csv", csv.as_bytes()).unwrap();
    dev.send(DeviceCommand::Guide(Some(Arc::new(track))))
        .unwrap();
    // Until 200 states after the guide's last: the stroke, its fade-out, and quiet.
    let mut all = std::mem::take(&mut frames);
    let end = Instant::now() + HANG_GUARD;
    loop {
        let last = all.iter().rposition(|f| f.guide.is_some());
        if last.is_some_and(|i| all.len() > i + 200) {
            break;
        }
        assert!(
            Instant::now() < end,
            "the guide did not end: {} states",
            all.len()
        );
        dev.poll(&mut all);
        std::thread::sleep(Duration::from_millis(5));
    }
    dev.disconnect();
    // Lock-step: a state for every tick, none lost on the way.
    let gaps: Vec<_> = all
        .windows(2)
        .filter(|w| w[1].tick != w[0].tick + 1)
        .map(|w| (w[0].tick, w[1].tick))
        .collect();
    assert!(gaps.is_empty(), "states missing between ticks {gaps:?}");
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
