//! The device link under QEMU: the firmware's state stream against the host simulation, bit
//! for bit; damaged frames; a link cut mid-stroke; an injected force-loop overrun.
//!
//! Needs `qemu-system-arm` (skipped with a message without it, unless `MAOBI_REQUIRE_QEMU`
//! is set, as in CI). Each test starts its own QEMU (`-icount shift=0,sleep=off`, the force
//! loop paced at 4 ms per 1 ms model tick, see `hil::selftest::EMULATED_TICK_US`).

use std::path::{Path, PathBuf};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

use hil::link::{self, Action, Session, StreamLog, StreamOptions};
use hil::run::{self, QemuDevice};
use hil::{firmware, qemu};
use maobi::poses::PoseTrack;
use maobi_shared::presets;
use maobi_shared::protocol::{
    crc32, Command, DeviceMsg, EventKind, Faults, HostMsg, HOST_TO_DEVICE, PROTOCOL_VERSION,
};

const TIMEOUT: Duration = Duration::from_secs(600);
/// The firmware's link timeout (ticks): `app::LINK_TIMEOUT_TICKS`.
const LINK_TIMEOUT_TICKS: u32 = 100;

fn image() -> Option<PathBuf> {
    static ELF: OnceLock<Option<PathBuf>> = OnceLock::new();
    ELF.get_or_init(|| {
        if !qemu::available() {
            assert!(
                std::env::var_os("MAOBI_REQUIRE_QEMU").is_none(),
                "qemu-system-arm is missing (apt-get install qemu-system-arm)"
            );
            eprintln!("SKIPPED: qemu-system-arm is not installed");
            return None;
        }
        Some(firmware::build().expect("firmware builds"))
    })
    .clone()
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
    let poses = link::track_poses(&t);
    let sim = link::simulate(presets::LARGE, &poses).unwrap();
    let (dev, stream) =
        QemuDevice::start(&elf, &["state_hz=120", "telemetry_ticks=100"], TIMEOUT).unwrap();
    let mut s = Session::new(stream).unwrap();
    let mut log = StreamLog::default();
    s.handshake(Duration::from_secs(10), &mut log.received)
        .unwrap();

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
    link::stream(&mut s, &poses, opts, &mut log).unwrap();
    // Telemetry after the end of the stroke (counters since start).
    let mut more = vec![];
    let tel = s
        .wait_for(Duration::from_secs(20), &mut more, |m| match m {
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
    let cmp = link::compare(&log, 1, &sim);
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
    let poses = link::track_poses(&t);
    let (mut dev, stream) =
        QemuDevice::start(&elf, &["state_hz=120", "telemetry_ticks=100"], TIMEOUT).unwrap();
    let mut s = Session::new(stream).unwrap();
    let mut log = StreamLog::default();
    s.handshake(Duration::from_secs(10), &mut log.received)
        .unwrap();
    s.send(&HostMsg::Command(Command::EnableForces)).unwrap();
    let mut actions = std::collections::BTreeMap::new();
    actions.insert(500, vec![Action::Stop]);
    let opts = StreamOptions {
        actions,
        ..Default::default()
    };
    link::stream(&mut s, &poses, opts, &mut log).unwrap();
    let driven = log
        .states()
        .filter(|(_, st)| st.haptics.enabled && st.haptics.motors.iter().any(|&m| m != 0))
        .count();
    assert!(
        driven > 10,
        "the motors were driven before the cut ({driven} states)"
    );
    // Cut: close the socket mid-stroke, stay away a while.
    drop(s);
    std::thread::sleep(Duration::from_millis(500));

    let stream = dev.connect(Duration::from_secs(10)).unwrap();
    let mut s = Session::new(stream).unwrap();
    let mut after = StreamLog::default();
    s.handshake(Duration::from_secs(10), &mut after.received)
        .unwrap();
    let end = Instant::now() + Duration::from_secs(3);
    while Instant::now() < end {
        after.received.extend(s.poll().unwrap());
        if after.states().count() >= 5 {
            break;
        }
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

#[test]
fn injected_overrun_turns_the_motors_off_until_cleared() {
    let Some(elf) = image() else { return };
    let t = track("hook.csv");
    let poses = link::track_poses(&t);
    let (dev, stream) =
        QemuDevice::start(&elf, &["state_hz=1000", "telemetry_ticks=100"], TIMEOUT).unwrap();
    let mut s = Session::new(stream).unwrap();
    let mut log = StreamLog::default();
    s.handshake(Duration::from_secs(10), &mut log.received)
        .unwrap();
    s.send(&HostMsg::Command(Command::EnableForces)).unwrap();
    let cmd = |c| vec![Action::Send(HostMsg::Command(c))];
    let mut actions = std::collections::BTreeMap::new();
    actions.insert(300, cmd(Command::InjectOverrun));
    actions.insert(700, cmd(Command::ClearFaults));
    actions.insert(710, cmd(Command::EnableForces));
    let opts = StreamOptions {
        actions,
        ..Default::default()
    };
    link::stream(&mut s, &poses, opts, &mut log).unwrap();
    drop(dev);

    let events: Vec<_> = log.events().cloned().collect();
    println!("{:?}", events);
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
    // Off from the very next tick (whose state may be missed: it runs right after the
    // overrunning one, before the link task has taken that one's snapshot).
    let first = latched.first().unwrap();
    assert!(
        first.tick <= t_o + 2,
        "first state after the overrun: tick {}",
        first.tick
    );
    // Enable refused while latched? (Not sent then.) After clear + enable: driven again.
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
    // Commands were all answered OK.
    let results: Vec<_> = log.command_results().collect();
    assert!(results.iter().all(|(_, ok)| *ok), "{results:?}");
    // Telemetry saw the long tick.
    let max = log.telemetry().map(|t| t.tick_period_max_us).max().unwrap();
    assert!(max > 4000, "longest tick period {max} us");
}

/// Sends `m` and returns the device's answer (`Param` or `CommandDone`).
fn ask(s: &mut Session<std::net::TcpStream>, m: HostMsg) -> DeviceMsg {
    s.send(&m).unwrap();
    s.wait_for(Duration::from_secs(10), &mut vec![], |r| match r {
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
    s.handshake(Duration::from_secs(10), &mut vec![]).unwrap();
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
    assert_eq!(
        done(ask(&mut s, HostMsg::Command(Command::InjectOverrun))),
        Ok(())
    );
    // Wait for the overrun to latch, then enabling is refused with the latched faults.
    s.wait_for(Duration::from_secs(10), &mut vec![], |m| match m {
        DeviceMsg::Event(e) => match &e.kind {
            EventKind::FaultRaised(f) if f.contains(Faults::LOOP_OVERRUN) => Some(()),
            _ => None,
        },
        _ => None,
    })
    .unwrap()
    .expect("LOOP_OVERRUN raised");
    match done(ask(&mut s, HostMsg::Command(Command::EnableForces))) {
        Err(CommandError::FaultsLatched(f)) => assert!(f.contains(Faults::LOOP_OVERRUN)),
        other => panic!("{other:?}"),
    }
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
