//! The device link under QEMU: the firmware's state stream against the host simulation, bit
//! for bit; damaged frames; a link cut mid-stroke; an injected force-loop overrun.
//!
//! Needs `qemu-system-arm` (skipped with a message without it, unless `MAOBI_REQUIRE_QEMU`
//! is set, as in CI). Each test starts its own QEMU (`-icount shift=0,sleep=off`, the force
//! loop paced at 4 ms per 1 ms model tick, see `hil::selftest::EMULATED_TICK_US`).

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use hil::firmware;
use hil::run::{self, QemuDevice};
use hil::session::{self, Action, Session, StreamLog, StreamOptions};
use maobi::poses::PoseTrack;
use maobi_shared::protocol::{
    crc32, Command, CommandError, DeviceMsg, EventKind, Faults, HostMsg, HOST_TO_DEVICE,
    PROTOCOL_VERSION,
};
use maobi_shared::{presets, Fx, Scalar};

const TIMEOUT: Duration = Duration::from_secs(600);
/// How long a wait for the device's answer, state or event may take before the test calls it
/// a hang: only a guard, far longer than any of them takes on a loaded machine. Nothing here
/// is timed by the wall clock: the tests wait for events, and count in device ticks.
const HANG_GUARD: Duration = Duration::from_secs(120);
/// The firmware's link timeout (ticks): `app::LINK_TIMEOUT_TICKS`.
const LINK_TIMEOUT_TICKS: u32 = 100;

fn image() -> Option<PathBuf> {
    firmware::qemu_test_image()
}

fn examples() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/poses")
}

fn track(name: &str) -> PoseTrack {
    PoseTrack::from_path(&examples().join(name)).unwrap()
}

fn cobs(data: &[u8]) -> Vec<u8> {
    let mut out = vec![0];
    let mut code_at = 0;
    let mut code = 1u8;
    for &b in data {
        if b == 0 {
            out[code_at] = code;
            code_at = out.len();
            out.push(0);
            code = 1;
        } else {
            out.push(b);
            code += 1;
            if code == 0xFF {
                out[code_at] = code;
                code_at = out.len();
                out.push(0);
                code = 1;
            }
        }
    }
    out[code_at] = code;
    out.push(0);
    out
}

#[test]
fn every_example_stroke_streams_bit_identical_states() {
    let Some(elf) = image() else { return };
    let mut files: Vec<_> = std::fs::read_dir(examples())
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "csv"))
        .collect();
    files.sort();
    assert!(files.len() >= 4, "{files:?}");
    for f in files {
        // Every tick's state (state_hz=1000): each tick of the stroke is compared.
        let r = run::run_qemu(&elf, &f, 1000, TIMEOUT).unwrap();
        println!("{}:\n{}", f.display(), r.render());
        assert!(r.passed(), "{}", r.render());
        let t = track(f.file_name().unwrap().to_str().unwrap());
        let cmp_line = &r.checks[1].detail;
        assert!(
            cmp_line.contains(&format!("over {} of {} ticks", t.ticks(), t.ticks())),
            "every tick compared: {cmp_line}"
        );
    }
}

#[test]
fn state_stream_at_120_hz_matches_by_pose_seq() {
    let Some(elf) = image() else { return };
    let r = run::run_qemu(&elf, &examples().join("hook.csv"), 120, TIMEOUT).unwrap();
    println!("{}", r.render());
    assert!(r.passed(), "{}", r.render());
    // The firmware's own log, decoded from QEMU's stderr with the image's defmt table.
    assert!(
        r.defmt_log.iter().any(|l| l.ends_with("INFO maobi-fw up")),
        "{:?}",
        r.defmt_log
    );
    let f = &r.figures;
    assert!(
        (110.0..=130.0).contains(&f.states_per_device_s),
        "{}",
        f.states_per_device_s
    );
}

#[test]
fn damaged_frames_are_counted_and_dropped_while_the_loop_ticks() {
    let Some(elf) = image() else { return };
    let t = track("hook.csv");
    let poses = session::track_poses(&t);
    let sim = session::simulate(presets::LARGE, &poses).unwrap();
    let (dev, stream) =
        QemuDevice::start(&elf, &["state_hz=120", "telemetry_ticks=100"], TIMEOUT).unwrap();
    let mut s = Session::new(stream).unwrap();
    let mut log = StreamLog::default();
    s.handshake(HANG_GUARD, &mut log.received).unwrap();

    // A ping with a wrong CRC, a truncated ping, an oversized frame, plain garbage.
    let mut content = vec![PROTOCOL_VERSION, HOST_TO_DEVICE];
    let mut b = [0u8; 16];
    content.extend_from_slice(postcard_ping(7, &mut b));
    let mut bad_crc = content.clone();
    bad_crc.extend_from_slice(&(crc32(&content) ^ 0x0100).to_le_bytes());
    let mut good = content.clone();
    good.extend_from_slice(&crc32(&content).to_le_bytes());
    let mut truncated = cobs(&good);
    truncated.truncate(truncated.len() - 4);
    truncated.push(0);
    let mut oversized = vec![0x42u8; 600];
    oversized.push(0);
    let garbage = b"\x03\x17\xff\xfe\x80 line noise \x01\x02\x00".to_vec();
    let mut actions = std::collections::BTreeMap::new();
    actions.insert(
        300,
        vec![
            Action::Raw(cobs(&bad_crc)),
            Action::Raw(truncated),
            Action::Raw(oversized),
            Action::Raw(garbage),
        ],
    );
    let opts = StreamOptions {
        actions,
        ..Default::default()
    };
    session::stream(&mut s, &poses, opts, &mut log).unwrap();
    // Telemetry after the end of the stroke (counters since start).
    let mut more = vec![];
    let tel = s
        .wait_for(HANG_GUARD, &mut more, |m| match m {
            DeviceMsg::Telemetry(t) => Some(t.clone()),
            _ => None,
        })
        .unwrap()
        .expect("telemetry")
        .0;
    drop(dev);
    println!("{tel:?}");
    let rx = tel.rx;
    assert!(rx.crc_errors >= 1, "{rx:?}");
    assert!(rx.oversized_frames >= 1, "{rx:?}");
    assert!(rx.framing_errors >= 1, "{rx:?}");
    assert!(rx.dropped() >= 4, "{rx:?}");
    assert!(rx.frames_ok as usize >= poses.len(), "{rx:?}");
    // The stream went on, bit for bit, through the damage.
    let cmp = session::compare(&log, 1, &sim);
    assert!(cmp.mismatches.is_empty() && cmp.compared > 100, "{cmp:?}");
    let ticks: Vec<u32> = log.states().map(|(_, st)| st.tick).collect();
    assert!(
        ticks.windows(2).all(|w| w[1] > w[0]),
        "force loop kept ticking"
    );
    assert_eq!(
        log.states().last().map(|(_, st)| st.pose_seq),
        Some(poses.len() as u32)
    );
}

fn postcard_ping(seq: u32, buf: &mut [u8; 16]) -> &[u8] {
    // HostMsg::Ping is variant 1, then the varint seq (< 128 here).
    assert!(seq < 128);
    buf[0] = 1;
    buf[1] = seq as u8;
    &buf[..2]
}

#[test]
fn link_cut_mid_stroke_latches_link_silent_and_zeroes_the_motors() {
    let Some(elf) = image() else { return };
    let t = track("press_lift.csv");
    let poses = session::track_poses(&t);
    let (mut dev, stream) =
        QemuDevice::start(&elf, &["state_hz=120", "telemetry_ticks=100"], TIMEOUT).unwrap();
    let mut s = Session::new(stream).unwrap();
    let mut log = StreamLog::default();
    s.handshake(HANG_GUARD, &mut log.received).unwrap();
    s.send(&HostMsg::Command(Command::EnableForces)).unwrap();
    let mut actions = std::collections::BTreeMap::new();
    actions.insert(500, vec![Action::Stop]);
    let opts = StreamOptions {
        actions,
        ..Default::default()
    };
    session::stream(&mut s, &poses, opts, &mut log).unwrap();
    let driven = log
        .states()
        .filter(|(_, st)| st.haptics.enabled && st.haptics.motors.iter().any(|&m| m != 0))
        .count();
    assert!(
        driven > 10,
        "the motors were driven before the cut ({driven} states)"
    );
    // Cut: close the socket mid-stroke. Then stay silent until the device has latched
    // LINK_SILENT: a new connection that sends nothing is no frame to the device, and the
    // states it keeps sending tell when the timeout has passed (in its ticks).
    drop(s);
    let stream = dev.connect(HANG_GUARD).unwrap();
    let mut s = Session::new(stream).unwrap();
    let mut silent = Vec::new();
    s.wait_for(HANG_GUARD, &mut silent, |m| match m {
        DeviceMsg::State(st) if st.faults.contains(Faults::LINK_SILENT) => Some(()),
        _ => None,
    })
    .unwrap()
    .expect("LINK_SILENT latched while the host is silent");

    let mut after = StreamLog::default();
    s.handshake(HANG_GUARD, &mut after.received).unwrap();
    let end = Instant::now() + HANG_GUARD;
    while after.states().count() < 5 {
        assert!(Instant::now() < end, "5 states after the reconnection");
        after.received.extend(s.poll().unwrap());
    }
    drop(dev);
    let events: Vec<_> = after.events().cloned().collect();
    println!("after reconnect: {events:?}");
    let (t_r, silent_ms) = events
        .iter()
        .find_map(|e| match e.kind {
            EventKind::LinkReconnected { silent_ms } => Some((e.tick, silent_ms)),
            _ => None,
        })
        .expect("a LinkReconnected event");
    let t_f = events
        .iter()
        .find_map(|e| match &e.kind {
            EventKind::FaultRaised(f) if f.contains(Faults::LINK_SILENT) => Some(e.tick),
            _ => None,
        })
        .expect("LINK_SILENT reported on reconnect");
    let last_heard = t_r - silent_ms;
    println!(
        "last frame heard at tick {last_heard}, LINK_SILENT (motors off) at tick {t_f}, \
         reconnected at tick {t_r}"
    );
    assert!(
        t_f > last_heard && t_f - last_heard <= LINK_TIMEOUT_TICKS + 1,
        "motors off {} ticks after the last frame (timeout {LINK_TIMEOUT_TICKS} + 1)",
        t_f - last_heard
    );
    let states: Vec<_> = after.states().map(|(_, st)| st.clone()).collect();
    assert!(!states.is_empty());
    for st in &states {
        assert!(st.faults.contains(Faults::LINK_SILENT), "{:?}", st.faults);
        assert!(!st.haptics.enabled);
        assert_eq!(st.haptics.motors, [0; 3]);
    }
}

/// An injected overrun (the test image's hook) under QEMU at `-icount shift=SHIFT`: it costs
/// one tick's overrun by the board's own tick timer, so it latches `LOOP_OVERRUN` with the
/// motors off, never the watchdog's FATAL; the link answers throughout, forces are refused
/// while it is latched, and `ClearFaults` brings the pen back.
fn injected_overrun_degrades_at_shift(shift: u32) {
    let Some(elf) = firmware::qemu_test_hooks_image() else {
        return;
    };
    let t = track("hook.csv");
    let poses = session::track_poses(&t);
    let (mut dev, stream) = QemuDevice::start_at_shift(
        &elf,
        shift,
        &["state_hz=1000", "telemetry_ticks=100"],
        &[],
        TIMEOUT,
    )
    .unwrap();
    let mut s = Session::new(stream).unwrap();
    let mut log = StreamLog::default();
    s.handshake(HANG_GUARD, &mut log.received).unwrap();
    s.send(&HostMsg::Command(Command::EnableForces)).unwrap();
    let cmd = |c| vec![Action::Send(HostMsg::Command(c))];
    let mut actions = std::collections::BTreeMap::new();
    actions.insert(300, cmd(Command::InjectOverrun));
    // While latched: the link answers a ping, and enabling is refused.
    actions.insert(500, vec![Action::Send(HostMsg::Ping { seq: 0x0E_0001 })]);
    actions.insert(510, cmd(Command::EnableForces));
    actions.insert(700, cmd(Command::ClearFaults));
    actions.insert(710, cmd(Command::EnableForces));
    let opts = StreamOptions {
        actions,
        ..Default::default()
    };
    session::stream(&mut s, &poses, opts, &mut log).unwrap();
    // Still serving after the stroke: a round trip, and QEMU has not exited.
    s.ping(7, HANG_GUARD, &mut log.received)
        .expect("the link answers after the overrun");
    drop(s);
    let (alive, out) = dev.guest.stop().unwrap();
    assert!(
        alive.is_none(),
        "shift {shift}: QEMU exited ({alive:?}): {out}"
    );
    assert!(!out.contains("FATAL"), "shift {shift}: {out}");

    let events: Vec<_> = log.events().cloned().collect();
    println!("shift {shift}: {events:?}");
    let t_o = events
        .iter()
        .find_map(|e| match &e.kind {
            EventKind::FaultRaised(f) if f.contains(Faults::LOOP_OVERRUN) => Some(e.tick),
            _ => None,
        })
        .expect("LOOP_OVERRUN raised");
    let t_c = events
        .iter()
        .find_map(|e| match &e.kind {
            EventKind::FaultCleared(f) if f.contains(Faults::LOOP_OVERRUN) => Some(e.tick),
            _ => None,
        })
        .expect("LOOP_OVERRUN cleared");
    assert!(t_c > t_o);
    // Nothing but the overrun: no stall, no other fault raised by it.
    for e in &events {
        if let EventKind::FaultRaised(f) = &e.kind {
            assert_eq!(*f, Faults::LOOP_OVERRUN, "shift {shift}: {e:?}");
        }
    }
    let pong_at = log
        .received
        .iter()
        .position(|r| matches!(r.msg, DeviceMsg::Pong { seq: 0x0E_0001 }))
        .expect("the pong sent while the overrun was latched");
    let states: Vec<_> = log.states().map(|(_, st)| st.clone()).collect();
    let before = states.iter().filter(|st| st.tick < t_o);
    assert!(before.clone().any(|st| st.haptics.motors != [0; 3]));
    let latched: Vec<_> = states
        .iter()
        // The overrun is detected as the overrunning tick t_o ends (its state was already
        // taken, motors on): the motors go off then, and every later state shows it.
        .filter(|st| st.tick > t_o && st.tick < t_c)
        .collect();
    assert!(latched.len() > 50, "{} states while latched", latched.len());
    for st in &latched {
        assert!(st.faults.contains(Faults::LOOP_OVERRUN), "{st:?}");
        assert!(!st.haptics.enabled);
        assert_eq!(st.haptics.motors, [0; 3], "tick {}", st.tick);
    }
    // The pong came while latched: after the overrun, before the clear.
    let pong_tick = log.received[..pong_at]
        .iter()
        .rev()
        .find_map(|r| match &r.msg {
            DeviceMsg::State(st) => Some(st.tick),
            _ => None,
        })
        .unwrap();
    assert!(
        pong_tick > t_o && pong_tick < t_c,
        "pong at tick {pong_tick}"
    );
    // Off from the very next tick (whose state may be missed: it runs right after the
    // overrunning one, before the link task has taken that one's snapshot).
    let first = latched.first().unwrap();
    assert!(
        first.tick <= t_o + 2,
        "first state after the overrun: tick {}",
        first.tick
    );
    // After clear + enable: driven again.
    assert!(
        events
            .iter()
            .any(|e| e.kind == EventKind::ForcesEnabled && e.tick > t_c),
        "{events:?}"
    );
    assert!(
        states
            .iter()
            .any(|st| st.tick > t_c && st.haptics.enabled && st.haptics.motors != [0; 3]),
        "driven again after clear and enable"
    );
    // Every command answered OK but the enable while latched, refused for the overrun.
    let results: Vec<_> = log
        .received
        .iter()
        .filter_map(|r| match &r.msg {
            DeviceMsg::CommandDone { command, result } => Some((command.clone(), result.clone())),
            _ => None,
        })
        .collect();
    let refused: Vec<_> = results.iter().filter(|(_, r)| r.is_err()).collect();
    assert_eq!(refused.len(), 1, "{results:?}");
    match refused[0] {
        (Command::EnableForces, Err(CommandError::FaultsLatched(f))) => {
            assert!(f.contains(Faults::LOOP_OVERRUN), "{f:?}")
        }
        other => panic!("{other:?}"),
    }
    // One tick's overrun, by the board's own period: the overrunning tick ran on until the
    // next one fell due, which then started at once, so no interval between tick starts
    // reached two periods (a fixed burn of cycles would have, at one shift or another).
    let period = hil::selftest::EMULATED_TICK_US << shift;
    let max = log.telemetry().map(|t| t.tick_period_max_us).max().unwrap();
    assert!(
        max >= period && max < 2 * period,
        "longest tick period {max} us, paced at {period}"
    );
    println!("shift {shift}: overrun latched at tick {t_o}, cleared at {t_c}, longest tick period {max} us");
}

#[test]
fn injected_overrun_at_shift_0_latches_loop_overrun_until_cleared() {
    injected_overrun_degrades_at_shift(0);
}

#[test]
fn injected_overrun_at_shift_3_latches_loop_overrun_until_cleared() {
    injected_overrun_degrades_at_shift(3);
}

/// Sends `m` and returns the device's answer (`Param` or `CommandDone`).
fn ask(s: &mut Session<std::net::TcpStream>, m: HostMsg) -> DeviceMsg {
    s.send(&m).unwrap();
    s.wait_for(HANG_GUARD, &mut vec![], |r| match r {
        DeviceMsg::Param(_) | DeviceMsg::CommandDone { .. } => Some(r.clone()),
        _ => None,
    })
    .unwrap()
    .expect("an answer")
    .0
}

fn param(m: DeviceMsg) -> Result<f32, maobi_shared::protocol::RejectReason> {
    match m {
        DeviceMsg::Param(r) => r.result.map_err(|e| e.reason),
        other => panic!("{other:?}"),
    }
}

fn done(m: DeviceMsg) -> Result<(), maobi_shared::protocol::CommandError> {
    match m {
        DeviceMsg::CommandDone { result, .. } => result,
        other => panic!("{other:?}"),
    }
}

#[test]
fn parameters_and_commands_are_validated_and_answered() {
    use maobi_shared::params::ParamId;
    use maobi_shared::protocol::{bounded_str, CommandError, PresetRef, RejectReason};
    let Some(elf) = image() else { return };
    let (dev, stream) = QemuDevice::start(&elf, &[], TIMEOUT).unwrap();
    let mut s = Session::new(stream).unwrap();
    s.handshake(HANG_GUARD, &mut vec![]).unwrap();
    let id = |p: ParamId| p as u8;
    let large = presets::LARGE;

    assert_eq!(
        param(ask(
            &mut s,
            HostMsg::GetParam {
                id: id(ParamId::Plasticity)
            }
        )),
        Ok(large.plasticity)
    );
    let (lo, hi, _) = ParamId::PaperDrag.range();
    let v = (lo + hi) / 2.0;
    assert_eq!(
        param(ask(
            &mut s,
            HostMsg::SetParam {
                id: id(ParamId::PaperDrag),
                value: v
            }
        )),
        Ok(v)
    );
    assert_eq!(
        param(ask(
            &mut s,
            HostMsg::SetParam {
                id: id(ParamId::PaperDrag),
                value: f32::NAN
            }
        )),
        Err(RejectReason::NotFinite)
    );
    assert!(matches!(
        param(ask(
            &mut s,
            HostMsg::SetParam {
                id: id(ParamId::PaperDrag),
                value: hi * 2.0 + 1.0
            }
        )),
        Err(RejectReason::OutOfRange { .. })
    ));
    assert!(matches!(
        param(ask(
            &mut s,
            HostMsg::SetParam {
                id: id(ParamId::TipRadiusMm),
                value: large.radius_mm * 1.5
            }
        )),
        Err(RejectReason::Inconsistent { .. } | RejectReason::OutOfRange { .. })
    ));
    // A rejected write changed nothing.
    assert_eq!(
        param(ask(
            &mut s,
            HostMsg::GetParam {
                id: id(ParamId::PaperDrag)
            }
        )),
        Ok(v)
    );
    assert_eq!(
        param(ask(&mut s, HostMsg::GetParam { id: 200 })),
        Err(RejectReason::UnknownParam)
    );

    assert_eq!(
        done(ask(&mut s, HostMsg::Command(Command::Calibrate))),
        Err(CommandError::Unsupported)
    );
    assert_eq!(
        done(ask(
            &mut s,
            HostMsg::Command(Command::ChoosePreset(PresetRef::Name(bounded_str("nope"))))
        )),
        Err(CommandError::UnknownPreset)
    );
    // The hair types, by their Chinese name and by their index in `presets::PRESETS`.
    for (preset, want) in [
        (PresetRef::Name(bounded_str("羊毫")), presets::GOAT),
        (PresetRef::Name(bounded_str("jianhao")), presets::MIXED),
        (PresetRef::Index(2), presets::WOLF),
    ] {
        assert_eq!(
            done(ask(
                &mut s,
                HostMsg::Command(Command::ChoosePreset(preset.clone()))
            )),
            Ok(()),
            "{preset:?}"
        );
        for p in [ParamId::TieStiffness, ParamId::InkCapacity] {
            assert_eq!(
                param(ask(&mut s, HostMsg::GetParam { id: id(p) })),
                Ok(want.get(p)),
                "{preset:?}: {p}"
            );
        }
    }
    assert_eq!(
        done(ask(
            &mut s,
            HostMsg::Command(Command::ChoosePreset(PresetRef::Index(1)))
        )),
        Ok(())
    );
    assert_eq!(
        param(ask(
            &mut s,
            HostMsg::GetParam {
                id: id(ParamId::Layers)
            }
        )),
        Ok(f32::from(presets::SMALL.layers))
    );
    assert_eq!(
        done(ask(
            &mut s,
            HostMsg::Command(Command::DipInk { wetness: 1 << 31 })
        )),
        Ok(())
    );
    assert_eq!(
        done(ask(&mut s, HostMsg::Command(Command::ResetBrush))),
        Ok(())
    );
    // The image built without the test hooks (what `cargo build --release` makes, like the
    // pen's) refuses fault injection, and nothing overruns.
    assert_eq!(
        done(ask(&mut s, HostMsg::Command(Command::InjectOverrun))),
        Err(CommandError::Unsupported)
    );
    let mut after = vec![];
    for seq in 0..20 {
        s.ping(seq, HANG_GUARD, &mut after).unwrap();
    }
    let raised: Vec<_> = after
        .iter()
        .filter(|r| matches!(&r.msg, DeviceMsg::Event(e) if matches!(e.kind, EventKind::FaultRaised(_))))
        .collect();
    assert!(raised.is_empty(), "{raised:?}");
    assert_eq!(
        done(ask(&mut s, HostMsg::Command(Command::ClearFaults))),
        Ok(())
    );
    assert_eq!(
        done(ask(&mut s, HostMsg::Command(Command::EnableForces))),
        Ok(())
    );
    assert_eq!(
        done(ask(&mut s, HostMsg::Command(Command::DisableForces))),
        Ok(())
    );
    drop(dev);
}

/// Guided writing under QEMU: the hook streamed with a guide sample every tick (the moving
/// point 40 ticks ahead of the pen and 3 mm beside it, on for all but the last 200 ticks,
/// then held and fading out). Every state's brush is bit-identical to the host simulation
/// and every state's force (the model's plus the guide's) to the host's mirror of the force
/// loop; the same stroke unguided, on the same device, matches the unguided mirror, and the
/// guided forces differ from it.
#[test]
fn guided_stroke_forces_are_bit_identical_to_the_host_mirror() {
    let Some(elf) = image() else { return };
    let t = track("hook.csv");
    let poses = session::track_poses(&t);
    let n = poses.len();
    let guide = session::guide_along(&poses, 40, [0.0, 3.0, 0.0], n.saturating_sub(200));
    let sim = session::simulate(presets::LARGE, &poses).unwrap();
    let (dev, stream) =
        QemuDevice::start(&elf, &["state_hz=1000", "telemetry_ticks=1000"], TIMEOUT).unwrap();
    let mut s = Session::new(stream).unwrap();

    let mut log = StreamLog::default();
    s.handshake(HANG_GUARD, &mut log.received).unwrap();
    let opts = StreamOptions {
        guide: guide.clone(),
        ..Default::default()
    };
    session::stream(&mut s, &poses, opts, &mut log).unwrap();

    // Again unguided: a new handshake restarts the brush and the forces at the first pose.
    let base2 = 1 + n as u32;
    let mut log2 = StreamLog::default();
    s.handshake(HANG_GUARD, &mut log2.received).unwrap();
    let opts = StreamOptions {
        base: base2,
        ..Default::default()
    };
    session::stream(&mut s, &poses, opts, &mut log2).unwrap();
    drop(dev);

    // The host's mirror of the force loop, tick by tick as the device ran them.
    let timeline = session::device_timeline(&log, 1, n);
    let guided = session::simulate_forces(presets::LARGE, &poses, &guide, &timeline).unwrap();
    let unguided_here = session::simulate_forces(presets::LARGE, &poses, &[], &timeline).unwrap();
    let timeline2 = session::device_timeline(&log2, base2, n);
    let unguided = session::simulate_forces(presets::LARGE, &poses, &[], &timeline2).unwrap();
    let brush = session::compare(&log, 1, &sim);
    let forces = session::compare_forces(&log, &guided);
    let brush2 = session::compare(&log2, base2, &sim);
    let forces2 = session::compare_forces(&log2, &unguided);
    let gaps = |t: &[(u32, Option<usize>)]| t.iter().filter(|(_, k)| k.is_none()).count();
    println!(
        "guided: brush {} states over {} of {n} ticks, {} mismatches; force at {} device \
         ticks of {} on the timeline ({} without a new pose), {} mismatches",
        brush.compared,
        brush.ticks,
        brush.mismatches.len(),
        forces.compared,
        timeline.len(),
        gaps(&timeline),
        forces.mismatches.len()
    );
    println!(
        "unguided: brush over {} of {n} ticks, {} mismatches; force at {} device ticks of {} \
         ({} without a new pose), {} mismatches",
        brush2.ticks,
        brush2.mismatches.len(),
        forces2.compared,
        timeline2.len(),
        gaps(&timeline2),
        forces2.mismatches.len()
    );
    assert!(brush.mismatches.is_empty(), "{:?}", brush.mismatches);
    assert!(brush2.mismatches.is_empty(), "{:?}", brush2.mismatches);
    assert!(
        forces.mismatches.is_empty(),
        "guided force differs at ticks {:?}",
        &forces.mismatches[..forces.mismatches.len().min(10)]
    );
    assert!(forces2.mismatches.is_empty(), "{:?}", forces2.mismatches);
    // The timeline reaches the last pose (no ambiguous stretch cut it short).
    assert_eq!(brush.ticks, n);
    assert_eq!(timeline.iter().rev().find_map(|(_, k)| *k), Some(n - 1));
    assert_eq!(timeline2.iter().rev().find_map(|(_, k)| *k), Some(n - 1));
    assert!(forces.compared >= timeline.len() * 9 / 10, "{forces:?}");

    // The guide really acts: the device's guided force minus the unguided run's.
    let f = |b: &[i64; 3]| b.map(|x| Fx::from_bits(x).to_f64());
    let mut differ = 0;
    let mut max_diff = 0.0f64;
    let mut max_y = 0.0f64;
    for (_, st) in log.states() {
        // The same ticks without the guide.
        let Some(u) = unguided_here.get(&st.tick) else {
            continue;
        };
        let (a, b) = (f(&st.haptics.force_n), f(u));
        let d = ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt();
        if d > 0.0 {
            differ += 1;
        }
        max_diff = max_diff.max(d);
        max_y = max_y.max(a[1] - b[1]);
    }
    println!(
        "guided - unguided force: differs at {differ} states, largest {max_diff:.3} N \
         (toward the point, +y: {max_y:.3} N)"
    );
    assert!(differ > n / 2, "{differ} of {n}");
    // 3 mm beside and 40 ticks ahead at 100 N/m: a few tenths of a newton, under 0.8 N.
    assert!(max_diff > 0.2 && max_diff <= 0.8 + 1e-6, "{max_diff}");
}

/// The link cut while guiding: the host stops sending (poses and guide samples) mid-stroke
/// with the forces on and the guide leading; the firmware latches LINK_SILENT within the
/// link timeout and its motor command is zero from that tick on (the guide cut, the motors
/// off at once rather than ramped); a new hello reports the silence.
#[test]
fn link_cut_while_guiding_zeroes_the_motors_within_the_timeout() {
    let Some(elf) = image() else { return };
    let t = track("press_lift.csv");
    let poses = session::track_poses(&t);
    let n = poses.len();
    assert!(n > 800, "{n}");
    // 5 mm beside the pen: 0.5 N at full gain.
    let guide = session::guide_along(&poses, 0, [0.0, 5.0, 0.0], n);
    let (dev, stream) =
        QemuDevice::start(&elf, &["state_hz=1000", "telemetry_ticks=1000"], TIMEOUT).unwrap();
    let mut s = Session::new(stream).unwrap();
    let mut log = StreamLog::default();
    s.handshake(HANG_GUARD, &mut log.received).unwrap();
    s.send(&HostMsg::Command(Command::EnableForces)).unwrap();
    let mut actions = std::collections::BTreeMap::new();
    actions.insert(700, vec![Action::Stop]);
    let opts = StreamOptions {
        actions,
        guide,
        ..Default::default()
    };
    session::stream(&mut s, &poses, opts, &mut log).unwrap();
    // Silence: read what the device sends until 150 states after the fault latched.
    let end = Instant::now() + HANG_GUARD;
    loop {
        let silent = log
            .states()
            .filter(|(_, st)| st.faults.contains(Faults::LINK_SILENT))
            .count();
        if silent >= 150 {
            break;
        }
        assert!(
            Instant::now() < end,
            "150 states after LINK_SILENT: {silent}"
        );
        log.received.extend(s.poll().unwrap());
    }
    // Back: the device reports how long it heard nothing.
    let mut after = StreamLog::default();
    s.handshake(HANG_GUARD, &mut after.received).unwrap();
    // (The event comes before the device's hello.)
    let reconnected = |m: &DeviceMsg| match m {
        DeviceMsg::Event(e) => match e.kind {
            EventKind::LinkReconnected { silent_ms } => Some((silent_ms, e.tick)),
            _ => None,
        },
        _ => None,
    };
    let early = after.received.iter().find_map(|r| reconnected(&r.msg));
    let (silent_ms, t_r) = match early {
        Some(x) => x,
        None => {
            s.wait_for(HANG_GUARD, &mut after.received, reconnected)
                .unwrap()
                .expect("a LinkReconnected event")
                .0
        }
    };
    drop(dev);
    let last_heard = t_r - silent_ms;
    let states: Vec<_> = log.states().map(|(_, st)| st.clone()).collect();
    let guided_y = states
        .iter()
        .filter(|st| st.tick <= last_heard && st.haptics.enabled)
        .map(|st| Fx::from_bits(st.haptics.motors[1]).to_f64())
        .fold(0.0f64, f64::max);
    let t_f = states
        .iter()
        .find(|st| st.faults.contains(Faults::LINK_SILENT))
        .map(|st| st.tick)
        .expect("LINK_SILENT in a state during the silence");
    let last_driven = states
        .iter()
        .filter(|st| st.haptics.motors != [0; 3])
        .map(|st| st.tick)
        .max()
        .unwrap_or(0);
    println!(
        "guide pull on the motors before the cut up to {guided_y:.3} N; last frame heard at \
         tick {last_heard}, LINK_SILENT in the state of tick {t_f} (+{}), last nonzero motor \
         command at tick {last_driven} (+{}); {} states after it, all zero",
        t_f - last_heard,
        last_driven - last_heard,
        states.iter().filter(|st| st.tick > last_driven).count()
    );
    assert!(guided_y > 0.3, "the guide pulled toward +y: {guided_y}");
    assert!(
        t_f > last_heard && t_f - last_heard <= LINK_TIMEOUT_TICKS + 1,
        "{} ticks",
        t_f - last_heard
    );
    assert!(
        last_driven < t_f,
        "motors off from tick {t_f}: {last_driven}"
    );
    let silent: Vec<_> = states.iter().filter(|st| st.tick >= t_f).collect();
    assert!(silent.len() > 100, "{}", silent.len());
    for st in silent {
        assert!(!st.haptics.enabled && st.haptics.motors == [0; 3], "{st:?}");
    }
}

/// The pressed horizontal stroke of `maobi-shared`'s tests/guide.rs (large brush, z = 40
/// touches the paper): in at 3 mm above, pressed 5 mm along 60 mm, out.
fn guide_stroke() -> maobi_shared::stroke::Stroke {
    use maobi_shared::stroke::{orient::from_tilt_azimuth, Keyframe, Stroke};
    let q = from_tilt_azimuth(0.0, 0.0, 0.0);
    let key = |x: f64, y: f64, z: f64, t: f64| Keyframe {
        pos: [x, y, z],
        rot: q,
        t: Some(t),
    };
    let keys = [
        key(-32.0, 0.0, 43.0, 0.0),
        key(-30.0, 0.0, 36.0, 0.3),
        key(0.0, 1.0, 35.0, 0.8),
        key(28.0, 2.0, 36.0, 1.3),
        key(30.0, 2.0, 43.0, 1.6),
    ];
    Stroke::new(&keys, &[], &[], 60.0).unwrap()
}

/// The guide's moving point as tests/guide.rs plays it, `cycles` times: the stroke's start
/// held while the guide fades in, the stroke in real time, its end held while it fades out
/// (`on = false`). Also: which steps play the stroke (at full gain), the start and the pen's
/// orientation.
struct GuidePlan {
    anchors: Vec<(maobi_shared::Vec3<Fx>, bool)>,
    playing: Vec<bool>,
    start: [f64; 3],
    rot: maobi_shared::Quat<Fx>,
}

fn guide_plan(cycles: usize) -> GuidePlan {
    use maobi_shared::guide::DEFAULT_GUIDE;
    let s = guide_stroke();
    let (t0, t1) = s.domain();
    let fade = (DEFAULT_GUIDE.fade_s as f64 * 1e3) as usize + 50;
    let play = ((t1 - t0) * 1e3).round() as usize;
    let cycle = fade + play + fade;
    let (start, q0) = s.pose_at(t0);
    let mut plan = GuidePlan {
        anchors: vec![],
        playing: vec![],
        start,
        rot: maobi_shared::Quat::from_f64(q0),
    };
    for k in 0..cycles * cycle {
        let phase = k % cycle;
        let t = t0 + (phase.saturating_sub(fade)).min(play) as f64 * 1e-3;
        let a = maobi_shared::Vec3::<Fx>::from_f64(s.pose_at(t).0);
        plan.anchors.push((a, phase < fade + play));
        plan.playing.push(phase >= fade && phase < fade + play);
    }
    plan
}

/// What a closed-loop guided run measured.
struct HandFigures {
    rms_xy_mm: f64,
    max_xy_mm: f64,
    rms_mm: f64,
    max_mm: f64,
    /// Largest command the hand felt, and in any state (N).
    peak_felt: f64,
    peak_state: f64,
    /// Largest energy created over any window (J), from step 600 on (the ramp-in).
    worst_violation: f64,
    sourced_j: f64,
    /// Steps whose command was below the force the loop wanted (the output stage limited it).
    limited: usize,
    device_ticks: usize,
}

/// Runs the hand through the device and checks the run against the host mirror bit for bit
/// (brush and force of every state), then measures it as tests/guide.rs does.
fn guided_hand_run(
    hand_params: maobi_shared::hand::HandParams,
    cycles: usize,
    mut target: impl FnMut(usize, &maobi_shared::hand::SimHand) -> ([f64; 3], [f64; 3]),
) -> HandFigures {
    use maobi_shared::hand::SimHand;
    let elf = image().expect("checked by the caller");
    let plan = guide_plan(cycles);
    let (dev, stream) =
        QemuDevice::start(&elf, &["state_hz=1000", "telemetry_ticks=1000"], TIMEOUT).unwrap();
    let mut s = Session::new(stream).unwrap();
    let mut skipped = Vec::new();
    let info = s.handshake(HANG_GUARD, &mut skipped).unwrap();
    s.send(&HostMsg::Command(Command::EnableForces)).unwrap();
    let mut hand = SimHand::new(hand_params, plan.start);
    let run = session::guide_hand(
        &mut s,
        1,
        &plan.anchors,
        plan.rot,
        &mut hand,
        &mut target,
        HANG_GUARD,
    )
    .unwrap();
    drop(dev);
    let n = run.poses.len();

    // Bit for bit: every state's brush and force against the host's mirror, tick by tick as
    // the device ran them (it ticked on its own clock while the hand waited).
    let timeline = session::device_timeline(&run.log, 1, n);
    let mirror =
        session::mirror_force_loop(presets::LARGE, &run.poses, &run.guide, &timeline).unwrap();
    let forces = mirror.iter().map(|(t, m)| (*t, m.force_n)).collect();
    let brush = session::compare(
        &run.log,
        1,
        &session::simulate(presets::LARGE, &run.poses).unwrap(),
    );
    let fc = session::compare_forces(&run.log, &forces);
    println!(
        "{n} poses over {} device ticks; brush {} mismatches over {} poses, force {} \
         mismatches over {} states",
        timeline.len(),
        brush.mismatches.len(),
        brush.ticks,
        fc.mismatches.len(),
        fc.compared
    );
    assert_eq!(timeline.iter().rev().find_map(|(_, k)| *k), Some(n - 1));
    assert!(brush.mismatches.is_empty(), "{:?}", brush.mismatches);
    assert!(fc.mismatches.is_empty(), "{:?}", fc.mismatches);
    assert!(fc.compared >= timeline.len() * 9 / 10, "{fc:?}");

    let norm = |v: [f64; 3]| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    let f = |b: &[i64; 3]| b.map(|x| Fx::from_bits(x).to_f64());
    let mut fig = HandFigures {
        rms_xy_mm: 0.0,
        max_xy_mm: 0.0,
        rms_mm: 0.0,
        max_mm: 0.0,
        peak_felt: run.felt.iter().map(|c| norm(*c)).fold(0.0, f64::max),
        peak_state: run
            .log
            .states()
            .map(|(_, st)| norm(f(&st.haptics.motors)))
            .fold(0.0, f64::max),
        worst_violation: 0.0,
        sourced_j: 0.0,
        limited: 0,
        device_ticks: timeline.len(),
    };
    // The stated limit: the device's own, from its hello.
    assert!(
        fig.peak_state <= info.force_peak_n as f64 + 1e-6,
        "{} N > {} N",
        fig.peak_state,
        info.force_peak_n
    );
    let (mut sum2, mut sum2_xy, mut m) = (0.0, 0.0, 0usize);
    let mut best = f64::MIN;
    let mut sourced = 0.0;
    let mut by_pose = vec![None; n];
    for (&t, mt) in &mirror {
        sourced += mt.sourced_j;
        if let Some(k) = mt.pose {
            by_pose[k] = Some((t, mt.clone(), sourced));
        }
    }
    fig.sourced_j = sourced;
    let wanted: std::collections::BTreeMap<u32, [f64; 3]> = run
        .log
        .states()
        .map(|(_, st)| (st.tick, f(&st.haptics.force_n)))
        .collect();
    for (k, at) in by_pose.iter().enumerate() {
        let Some((t, mt, sourced)) = at else {
            panic!("pose {k} not on the timeline");
        };
        let (a, _) = plan.anchors[k];
        let (a, x) = (a.to_f64(), run.poses[k].pos.to_f64());
        if plan.playing[k] {
            let d2_xy = (a[0] - x[0]).powi(2) + (a[1] - x[1]).powi(2);
            let d2 = d2_xy + (a[2] - x[2]).powi(2);
            sum2 += d2;
            sum2_xy += d2_xy;
            m += 1;
            fig.max_mm = fig.max_mm.max(d2.sqrt());
            fig.max_xy_mm = fig.max_xy_mm.max(d2_xy.sqrt());
        }
        if let Some(w) = wanted.get(t) {
            if norm(run.felt[k]) + 1e-9 < norm(*w) {
                fig.limited += 1;
            }
        }
        if k < 600 {
            continue; // the output stage's ramp-in, as in tests/guide.rs
        }
        let stored = run.stylus_ke[k] + mt.stored_j;
        let phi = run.energy_in[k] + sourced - stored;
        best = best.max(phi);
        fig.worst_violation = fig.worst_violation.max(best - phi);
    }
    fig.rms_mm = (sum2 / m.max(1) as f64).sqrt();
    fig.rms_xy_mm = (sum2_xy / m.max(1) as f64).sqrt();
    fig
}

/// Same tolerance as the passivity audit of `maobi-shared`'s tests/guide.rs.
const AUDIT_TOLERANCE_J: f64 = 2e-3;

/// Guided writing through the firmware in QEMU with a simulated relaxed hand in the loop: the
/// device leads it along the stroke of `maobi-shared`'s tests/guide.rs within the error
/// stated there (2.5 mm RMS, 5 mm at most in the paper plane; 1.93 / 3.6 mm on the host), its
/// command stays within its limits, the passivity audit holds, and every state is the host
/// mirror's bit for bit.
#[test]
fn guided_writing_leads_a_relaxed_hand_through_the_device() {
    if image().is_none() {
        return;
    }
    let r = guided_hand_run(maobi_shared::hand::HandParams::RELAXED, 1, |_, h| {
        (h.hand(), [0.0; 3])
    });
    println!(
        "relaxed, over the wire: in the paper plane {:.2} mm RMS, {:.2} mm at most from the \
         moving point; in 3D {:.2} mm RMS, {:.2} mm at most; peak command {:.3} N (felt \
         {:.3} N), limited at {} steps; audit {:.2e} J (tolerance {AUDIT_TOLERANCE_J:e}); the \
         stroke supplied {:.4} J; {} device ticks",
        r.rms_xy_mm,
        r.max_xy_mm,
        r.rms_mm,
        r.max_mm,
        r.peak_state,
        r.peak_felt,
        r.limited,
        r.worst_violation,
        r.sourced_j,
        r.device_ticks
    );
    assert!(r.rms_xy_mm < 2.5, "{:.2} mm RMS", r.rms_xy_mm);
    assert!(r.max_xy_mm < 5.0, "{:.2} mm", r.max_xy_mm);
    assert!(
        r.rms_mm < 5.0 && r.max_mm < 8.0,
        "{r:?}",
        r = (r.rms_mm, r.max_mm)
    );
    assert!(r.peak_felt > 0.1, "the device did push: {}", r.peak_felt);
    assert!(
        r.worst_violation <= AUDIT_TOLERANCE_J,
        "{:e} J",
        r.worst_violation
    );
}

/// Guided writing through the firmware with a hand that resists (the random presses, drags
/// and bumps of the passivity audit around the stroke): the device's command never exceeds
/// its limits, the passivity audit holds, and every state is the host mirror's.
#[test]
fn guided_writing_against_a_resisting_hand_stays_in_the_limits() {
    if image().is_none() {
        return;
    }
    let start = guide_stroke().pose_at(0.0).0;
    let mut script = maobi_shared::hand::Script::new(23, start, (34.0, 48.0));
    script.xy_range = 30.0;
    let r = guided_hand_run(maobi_shared::hand::HandParams::WRITER, 2, |_, _| {
        script.tick()
    });
    println!(
        "resisting, over the wire: {:.1} mm RMS from the moving point; peak command {:.3} N \
         (felt {:.3} N), limited at {} steps; audit {:.2e} J (tolerance \
         {AUDIT_TOLERANCE_J:e}); {} device ticks",
        r.rms_mm, r.peak_state, r.peak_felt, r.limited, r.worst_violation, r.device_ticks
    );
    assert!(r.rms_mm > 3.0, "the hand did resist: {:.1} mm", r.rms_mm);
    assert!(
        r.worst_violation <= AUDIT_TOLERANCE_J,
        "{:e} J",
        r.worst_violation
    );
}
