//! The stored configuration under QEMU: images preloaded into the board's store with QEMU's
//! generic loader (`hil::qemu::config_loader_args`, address `hil::qemu::CONFIG_REGION`).
//!
//! * a good image: the handshake says valid, forces enable; `SetConfig` validates (an invalid
//!   field is named, nothing written), refuses while forces are on, and round-trips through
//!   `GetConfig`; sensors stream, a nudge shows in the applied motor commands and ends,
//!   `Calibrate` stores the readings;
//! * a corrupt byte, a truncated image, erased flash, another format version: the handshake
//!   says which, `EnableForces` and nudges are refused, the motors stay at zero; a valid
//!   `SetConfig` recovers;
//! * an uncalibrated image: no force before calibration. State frames and events carry
//!   `NOT_CALIBRATED` (not cleared by `ClearFaults`), forces and nudges are refused; a
//!   `Calibrate` clears it and forces enable; a configuration written without zeros brings
//!   it back and ends a nudge that was running;
//! * no image: the virtual pen needs none (`NotApplicable`), as before;
//! * a format-1 image (built byte for byte, `shared/tests/common/format_1.rs`): migrated,
//!   the handshake says so and what to set; the pen's geometry, limits and calibration are
//!   in force (the sensors read its zeros at its inkwell) but forces and nudges are refused
//!   until a `SetConfig` with the missing values, after which forces enable.
//!
//! Needs `qemu-system-arm` (skipped with a message without it, unless `MAOBI_REQUIRE_QEMU`
//! is set, as in CI).

use std::path::PathBuf;
use std::time::Duration;

use hil::run::QemuDevice;
use hil::session::Session;
use hil::{firmware, qemu};
use maobi_shared::kinematics::{Joints, Pen, PenConfig, RawReadings};
use maobi_shared::pen_io::{self, ConfigError, ConfigState, DeviceConfig, CONFIG_IMAGE_MAX};
use maobi_shared::protocol::{
    crc32, BrushState, Buttons, Capabilities, Command, CommandError, ConfigRejected, DeviceInfo,
    DeviceMsg, EventKind, Faults, HostMsg, Nudge, PoseSample, SensorReport,
};
use maobi_shared::{Fx, Scalar};

#[path = "../../shared/tests/common/format_1.rs"]
mod format_1;

const TIMEOUT: Duration = Duration::from_secs(300);
const ANSWER: Duration = Duration::from_secs(20);

type Link = Session<std::net::TcpStream>;

fn image() -> Option<PathBuf> {
    firmware::qemu_test_image()
}

fn calibrated() -> DeviceConfig {
    let mut c = DeviceConfig::DEFAULT;
    c.calibration = Some(RawReadings {
        encoders: [0; 3],
        gimbal: [2048; 3],
    });
    c
}

fn encoded(cfg: &DeviceConfig) -> Vec<u8> {
    let mut buf = vec![0u8; CONFIG_IMAGE_MAX];
    let n = pen_io::encode(cfg, &mut buf).unwrap();
    buf.truncate(n);
    buf
}

/// Boots the firmware with `image` (if any) in its store, and shakes hands.
fn boot(elf: &std::path::Path, image: Option<&[u8]>) -> (QemuDevice, Link, DeviceInfo, PathBuf) {
    static N: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);
    let n = N.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
    let path = std::env::temp_dir().join(format!("maobi-cfg-{}-{n}.bin", std::process::id()));
    let args = match image {
        Some(bytes) => {
            std::fs::write(&path, bytes).unwrap();
            qemu::config_loader_args(&path)
        }
        None => Vec::new(),
    };
    let (dev, stream) = QemuDevice::start_with(elf, &[], &args, TIMEOUT).unwrap();
    let mut s = Session::new(stream).unwrap();
    let info = s.handshake(ANSWER, &mut vec![]).unwrap();
    (dev, s, info, path)
}

/// Sends `m`, returns the answer (`CommandDone` or `Config`).
fn ask(s: &mut Link, m: HostMsg) -> DeviceMsg {
    s.send(&m).unwrap();
    s.wait_for(ANSWER, &mut vec![], |r| match r {
        DeviceMsg::CommandDone { .. } | DeviceMsg::Config(_) => Some(r.clone()),
        _ => None,
    })
    .unwrap()
    .expect("an answer")
    .0
}

fn command(s: &mut Link, c: Command) -> Result<(), CommandError> {
    match ask(s, HostMsg::Command(c)) {
        DeviceMsg::CommandDone { result, .. } => result,
        other => panic!("{other:?}"),
    }
}

fn config(s: &mut Link, m: HostMsg) -> Result<DeviceConfig, ConfigRejected> {
    match ask(s, m) {
        DeviceMsg::Config(r) => r,
        other => panic!("{other:?}"),
    }
}

/// The applied motor commands (Fx bits), the enable flag and the tick of the next `n` state
/// frames ([`next_states`]).
fn motor_states(s: &mut Link, n: usize) -> Vec<([i64; 3], bool, u32)> {
    next_states(s, n)
        .into_iter()
        .map(|st| (st.haptics.motors, st.haptics.enabled, st.tick))
        .collect()
}

/// The pose of the reference pen resting in its inkwell (inside its workspace).
fn inkwell_pose() -> maobi_shared::Pose<Fx> {
    let pen = Pen::<Fx>::new(PenConfig::OMNI_LIKE).unwrap();
    let c = PenConfig::OMNI_LIKE;
    pen.forward(&Joints {
        arm: c.inkwell_joints.map(Fx::from_f32),
        gimbal: c.inkwell_gimbal.map(Fx::from_f32),
    })
}

fn next_sensors(s: &mut Link) -> SensorReport {
    s.wait_for(ANSWER, &mut vec![], |r| match r {
        DeviceMsg::Sensors(x) => Some(x.clone()),
        _ => None,
    })
    .unwrap()
    .expect("a sensor report")
    .0
}

#[test]
fn a_good_image_is_valid_and_configurable() {
    let Some(elf) = image() else { return };
    let cfg = calibrated();
    let (dev, mut s, info, path) = boot(&elf, Some(&encoded(&cfg)));
    assert_eq!(info.config, ConfigState::Valid);
    assert!(info.capabilities.contains(Capabilities::STORED_CONFIG));
    assert_eq!(config(&mut s, HostMsg::GetConfig), Ok(cfg));

    // Forces enable with a valid, calibrated configuration; writing it is refused then.
    assert_eq!(command(&mut s, Command::EnableForces), Ok(()));
    let mut changed = cfg;
    changed.drive[0].deadband = 0.08;
    changed.limits.max_step_n = 0.15;
    assert_eq!(
        config(&mut s, HostMsg::SetConfig(changed)),
        Err(ConfigRejected::ForcesEnabled)
    );
    let nudge = Nudge {
        channel: 1,
        command_permille: 100,
        duration_ms: 200,
    };
    assert_eq!(
        command(&mut s, Command::NudgeMotor(nudge.clone())),
        Err(CommandError::ForcesEnabled)
    );
    assert_eq!(command(&mut s, Command::DisableForces), Ok(()));

    // An invalid configuration is refused by name, and nothing is written.
    let mut bad = changed;
    bad.drive[1].deadband = 0.9;
    match config(&mut s, HostMsg::SetConfig(bad)) {
        Err(ConfigRejected::Invalid(f)) => assert_eq!(f.field.as_str(), "drive[1].deadband"),
        other => panic!("{other:?}"),
    }
    let mut bad = changed;
    bad.limits.peak_n = f32::NAN;
    match config(&mut s, HostMsg::SetConfig(bad)) {
        Err(ConfigRejected::Invalid(f)) => assert_eq!(f.field.as_str(), "limits.peak_n"),
        other => panic!("{other:?}"),
    }
    assert_eq!(config(&mut s, HostMsg::GetConfig), Ok(cfg));
    // A valid one is written and read back.
    assert_eq!(config(&mut s, HostMsg::SetConfig(changed)), Ok(changed));
    assert_eq!(config(&mut s, HostMsg::GetConfig), Ok(changed));

    // A nudge beyond the caps is refused; a gentle one shows in the applied commands, on
    // its channel only, and ends.
    for over in [
        Nudge {
            command_permille: 151,
            ..nudge.clone()
        },
        Nudge {
            duration_ms: 301,
            ..nudge.clone()
        },
        Nudge {
            channel: 3,
            ..nudge.clone()
        },
    ] {
        assert_eq!(
            command(&mut s, Command::NudgeMotor(over)),
            Err(CommandError::OutOfRange)
        );
    }
    assert_eq!(command(&mut s, Command::NudgeMotor(nudge)), Ok(()));
    let states = motor_states(&mut s, 60);
    let on: Vec<_> = states.iter().filter(|(m, _, _)| m[1] != 0).collect();
    // A tenth of full torque: ratio x k_t x max_current, the configuration's own.
    let p = changed.pen;
    let expected =
        Fx::from_f32(0.1 * p.ratio[1] * p.torque_constant[1] * p.max_current[1]).to_bits();
    assert!(!on.is_empty(), "the nudge shows: {states:?}");
    for (m, enabled, _) in &on {
        assert_eq!(m[0], 0);
        assert_eq!(m[2], 0);
        assert!((m[1] - expected).abs() < 1 << 12, "{m:?} vs {expected}");
        assert!(!enabled, "forces stay off during a nudge");
    }
    let first = on.first().unwrap().2;
    let last = on.last().unwrap().2;
    assert!(last - first <= 200, "at most 200 ticks: {first}..{last}");
    let after = states.iter().filter(|(_, _, t)| *t > first + 200);
    assert!(after.clone().count() > 5, "states after the nudge");
    assert!(
        after.clone().all(|(m, _, _)| *m == [0; 3]),
        "motors off after"
    );

    // Sensors: the virtual pen at the inkwell reads the calibration's zeros.
    s.send(&HostMsg::Pose(PoseSample::new(
        1,
        inkwell_pose(),
        Buttons::empty(),
    )))
    .unwrap();
    assert_eq!(
        command(&mut s, Command::StreamSensors { rate_hz: 1001 }),
        Err(CommandError::OutOfRange)
    );
    assert_eq!(
        command(&mut s, Command::StreamSensors { rate_hz: 100 }),
        Ok(())
    );
    let r = next_sensors(&mut s);
    let r2 = next_sensors(&mut s);
    println!("sensors at the inkwell: {r:?}, then {r2:?}");
    assert!(r.synthetic);
    assert!(r2.tick > r.tick);
    for k in 0..3 {
        assert!(r.encoders[k].abs() <= 1, "{r:?}");
        assert!((i32::from(r.gimbal[k]) - 2048).abs() <= 1, "{r:?}");
    }
    assert_eq!(
        command(&mut s, Command::StreamSensors { rate_hz: 0 }),
        Ok(())
    );
    // Calibrate stores those readings.
    assert_eq!(command(&mut s, Command::Calibrate), Ok(()));
    let stored = config(&mut s, HostMsg::GetConfig).unwrap();
    let cal = stored.calibration.expect("calibrated");
    assert_eq!(cal.encoders, r.encoders);
    assert_eq!(cal.gimbal, r.gimbal.map(i32::from));
    drop(dev);
    let _ = std::fs::remove_file(path);
}

#[test]
fn damaged_images_start_safe_and_say_why() {
    let Some(elf) = image() else { return };
    let good = encoded(&calibrated());
    let mut corrupt = good.clone();
    corrupt[good.len() / 2] ^= 0x40;
    let truncated = good[..good.len() - 10].to_vec();
    let erased = vec![0xFFu8; 512];
    let mut other_version = good.clone();
    let other = pen_io::CONFIG_FORMAT_VERSION + 1;
    other_version[4..6].copy_from_slice(&other.to_le_bytes());
    let n = other_version.len() - 4;
    let crc = crc32(&other_version[..n]);
    other_version[n..].copy_from_slice(&crc.to_le_bytes());

    type Expect = fn(&ConfigState) -> bool;
    let cases: [(&str, Vec<u8>, Expect); 4] = [
        ("corrupt byte", corrupt, |c| {
            matches!(c, ConfigState::Corrupt(ConfigError::CrcMismatch { .. }))
        }),
        ("truncated", truncated, |c| {
            matches!(c, ConfigState::Corrupt(ConfigError::Truncated))
        }),
        ("erased", erased, |c| matches!(c, ConfigState::Missing)),
        ("wrong version", other_version, |c| {
            matches!(
                c,
                ConfigState::Corrupt(ConfigError::UnsupportedVersion { found })
                    if *found == pen_io::CONFIG_FORMAT_VERSION + 1
            )
        }),
    ];
    for (i, (name, bytes, expect)) in cases.into_iter().enumerate() {
        let (dev, mut s, info, path) = boot(&elf, Some(&bytes));
        println!("{name}: handshake says {}", info.config);
        assert!(expect(&info.config), "{name}: {:?}", info.config);
        assert_eq!(
            command(&mut s, Command::EnableForces),
            Err(CommandError::ConfigNotValid),
            "{name}"
        );
        assert_eq!(
            command(
                &mut s,
                Command::NudgeMotor(Nudge {
                    channel: 0,
                    command_permille: 50,
                    duration_ms: 100,
                })
            ),
            Err(CommandError::ConfigNotValid),
            "{name}"
        );
        assert_eq!(
            config(&mut s, HostMsg::GetConfig),
            Err(ConfigRejected::NotStored(info.config.clone()))
        );
        let states = motor_states(&mut s, 20);
        assert!(
            states
                .iter()
                .all(|(m, enabled, _)| *m == [0; 3] && !enabled),
            "{name}: motors stay off: {states:?}"
        );
        if i == 0 {
            // A valid configuration written over it recovers the pen.
            assert_eq!(
                config(&mut s, HostMsg::SetConfig(calibrated())),
                Ok(calibrated())
            );
            assert_eq!(command(&mut s, Command::EnableForces), Ok(()));
            let mut skipped = vec![];
            let again = s.handshake(ANSWER, &mut skipped).unwrap();
            assert_eq!(again.config, ConfigState::Valid);
        }
        drop(dev);
        let _ = std::fs::remove_file(path);
    }
}

/// The next `n` state frames. Pings as it goes: the device latches LINK_SILENT after 100
/// ticks without a frame.
fn next_states(s: &mut Link, n: usize) -> Vec<BrushState> {
    let mut out = Vec::new();
    while out.len() < n {
        s.send(&HostMsg::Ping {
            seq: out.len() as u32,
        })
        .unwrap();
        let (st, _) = s
            .wait_for(ANSWER, &mut vec![], |r| match r {
                DeviceMsg::State(st) => Some(st.clone()),
                _ => None,
            })
            .unwrap()
            .expect("state frames");
        out.push(st);
    }
    out
}

#[test]
fn no_force_before_calibration() {
    let Some(elf) = image() else { return };
    let uncalibrated = DeviceConfig::DEFAULT;
    assert_eq!(uncalibrated.calibration, None);
    let (dev, mut s, info, path) = boot(&elf, Some(&encoded(&uncalibrated)));
    // The image is valid: the handshake says so; the faults say it is not calibrated.
    assert_eq!(info.config, ConfigState::Valid);
    let mut seen = vec![];
    let (connected, _) = s
        .wait_for(ANSWER, &mut seen, |r| match r {
            DeviceMsg::Event(e) if e.kind == EventKind::LinkConnected => Some(e.clone()),
            _ => None,
        })
        .unwrap()
        .expect("the connection event");
    assert!(
        connected.faults.contains(Faults::NOT_CALIBRATED),
        "{connected:?}"
    );
    for st in next_states(&mut s, 10) {
        assert!(
            st.faults.contains(Faults::NOT_CALIBRATED),
            "{:?}",
            st.faults
        );
        assert!(!st.haptics.enabled);
        assert_eq!(st.haptics.motors, [0; 3]);
    }
    // Forces and nudges are refused; clearing faults does not clear it.
    assert_eq!(
        command(&mut s, Command::EnableForces),
        Err(CommandError::ConfigNotValid)
    );
    let nudge = Nudge {
        channel: 0,
        command_permille: 100,
        duration_ms: 300,
    };
    assert_eq!(
        command(&mut s, Command::NudgeMotor(nudge.clone())),
        Err(CommandError::ConfigNotValid)
    );
    assert_eq!(command(&mut s, Command::ClearFaults), Ok(()));
    let st = next_states(&mut s, 3);
    assert!(
        st.iter().all(|st| st.faults == Faults::NOT_CALIBRATED),
        "{st:?}"
    );

    // Calibrate at the inkwell: the fault is cleared (an event says so), forces enable.
    s.send(&HostMsg::Pose(PoseSample::new(
        1,
        inkwell_pose(),
        Buttons::empty(),
    )))
    .unwrap();
    assert_eq!(command(&mut s, Command::Calibrate), Ok(()));
    let mut seen = vec![];
    let (cleared, _) = s
        .wait_for(ANSWER, &mut seen, |r| match r {
            DeviceMsg::Event(e) if matches!(e.kind, EventKind::FaultCleared(_)) => Some(e.clone()),
            _ => None,
        })
        .unwrap()
        .expect("a fault-cleared event");
    assert_eq!(
        cleared.kind,
        EventKind::FaultCleared(Faults::NOT_CALIBRATED)
    );
    assert_eq!(cleared.faults, Faults::empty());
    let st = next_states(&mut s, 3);
    assert!(st.iter().all(|st| st.faults.is_empty()), "{st:?}");
    assert_eq!(command(&mut s, Command::EnableForces), Ok(()));
    assert_eq!(command(&mut s, Command::DisableForces), Ok(()));

    // A nudge runs; a configuration without zeros written meanwhile ends it at once and
    // the pen is not calibrated again.
    assert_eq!(command(&mut s, Command::NudgeMotor(nudge)), Ok(()));
    let running = next_states(&mut s, 2);
    assert!(
        running.iter().any(|st| st.haptics.motors[0] != 0),
        "the nudge runs: {running:?}"
    );
    assert_eq!(
        config(&mut s, HostMsg::SetConfig(uncalibrated)),
        Ok(uncalibrated)
    );
    let after = next_states(&mut s, 40);
    let first = after[0].tick;
    // A state copied before the write may still be on its way; from the next tick on
    // the motors are off (the nudge had up to 300 ticks left).
    for st in after.iter().filter(|st| st.tick > first + 1) {
        assert_eq!(st.haptics.motors, [0; 3], "tick {}", st.tick);
        assert!(st.faults.contains(Faults::NOT_CALIBRATED));
    }
    assert!(after.last().unwrap().tick > first + 100, "{first}..");
    assert_eq!(
        command(&mut s, Command::EnableForces),
        Err(CommandError::ConfigNotValid)
    );
    drop(dev);
    let _ = std::fs::remove_file(path);
}

#[test]
fn without_an_image_the_virtual_pen_needs_none() {
    let Some(elf) = image() else { return };
    let (dev, mut s, info, _) = boot(&elf, None);
    assert_eq!(info.config, ConfigState::NotApplicable);
    assert_eq!(
        config(&mut s, HostMsg::GetConfig),
        Err(ConfigRejected::NotStored(ConfigState::NotApplicable))
    );
    // Nothing to calibrate, and forces behave as they always have.
    assert_eq!(
        command(&mut s, Command::Calibrate),
        Err(CommandError::Unsupported)
    );
    assert_eq!(command(&mut s, Command::EnableForces), Ok(()));
    // Calibrated by construction: the fault is never reported.
    for st in next_states(&mut s, 5) {
        assert!(
            !st.faults.contains(Faults::NOT_CALIBRATED),
            "{:?}",
            st.faults
        );
    }
    drop(dev);
}

/// The configuration's force limits are the ones in force: the handshake reports them and
/// the output stage holds the force of a 10 mm press to the configured peak (the Phantom
/// Omni's default would let about 1.5 N through).
#[test]
fn the_configurations_force_limits_are_the_ones_in_force() {
    let Some(elf) = image() else { return };
    let mut cfg = calibrated();
    cfg.limits.peak_n = 0.5;
    cfg.limits.continuous_n = 0.5;
    let (_dev, mut s, info, path) = boot(&elf, Some(&encoded(&cfg)));
    assert_eq!(info.config, ConfigState::Valid);
    assert_eq!(
        (info.force_peak_n, info.force_continuous_n),
        (0.5, 0.5),
        "{info:?}"
    );
    assert_eq!(command(&mut s, Command::EnableForces), Ok(()));
    let track = maobi::poses::PoseTrack::from_path(
        &std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/poses/press_lift.csv"),
    )
    .unwrap();
    let poses = hil::session::track_poses(&track);
    let mut log = hil::session::StreamLog::default();
    hil::session::stream(&mut s, &poses, Default::default(), &mut log).unwrap();
    // The virtual pen's motor commands are the output stage's force (N, world frame);
    // `haptics.force_n` is what the model asked for before it.
    let (mut asked, mut given) = (0.0f64, 0.0f64);
    for (_, st) in log.states() {
        asked = asked.max(st.haptics.force().cast::<f64>().norm());
        let m = st.haptics.motors.map(|b| Fx::from_bits(b).to_f64());
        given = given.max((m[0] * m[0] + m[1] * m[1] + m[2] * m[2]).sqrt());
    }
    println!("the press asked for {asked:.4} N; with a 0.5 N peak the motors gave {given:.4} N");
    assert!(given <= 0.5 + 1e-6, "{given} N");
    // The press asks for more than the limit: the clamp is what held it.
    assert!(
        asked > 1.0 && given > 0.45,
        "asked {asked} N, given {given} N"
    );
    let _ = std::fs::remove_file(path);
}

/// A pen updated from a format-1 firmware: its image is migrated, the kinematics and the
/// calibration work, force waits for the values format 1 lacks.
#[test]
fn a_format_1_image_is_migrated_and_force_waits_for_the_missing_values() {
    use format_1::{image_of, payload_v1, ConfigV1, DriveV1};
    let Some(elf) = image() else { return };
    let zeros = RawReadings {
        encoders: [40, -25, 12],
        gimbal: [2000, 2100, 1990],
    };
    let mut limits = maobi_shared::force::PHANTOM_OMNI;
    limits.peak_n = 2.5;
    limits.continuous_n = 0.7;
    let drive = |zero| DriveV1 {
        pwm_hz: 25_000,
        deadband: 0.04,
        max_duty: 0.95, // format 1's default: over a TB6612's rating with a 2.2 Ohm motor
        zero,
    };
    let old = ConfigV1 {
        pen: PenConfig::OMNI_LIKE,
        drive: [drive(0), drive(1), drive(0)],
        limits,
        calibration: Some(zeros),
    };
    let (dev, mut s, info, path) = boot(&elf, Some(&image_of(1, &payload_v1(&old))));
    println!("handshake: configuration {}", info.config);
    assert_eq!(info.config, ConfigState::Migrated { from: 1 });
    let said = info.config.to_string();
    assert!(
        said.starts_with("configuration migrated from format 1: set the motors' winding resistance, supply voltage and driver rating")
            && said.contains("maobi device config set")
            && said.ends_with("to enable force"),
        "{said}"
    );
    // The migrated limits are the ones announced (and in force).
    assert_eq!((info.force_peak_n, info.force_continuous_n), (2.5, 0.7));

    // The migrated configuration is in force and given: everything format 1 had, what it
    // lacked at zero.
    let migrated = config(&mut s, HostMsg::GetConfig).expect("the migrated configuration");
    assert_eq!(migrated.pen, old.pen);
    assert_eq!(migrated.limits, old.limits);
    assert_eq!(migrated.calibration, Some(zeros));
    for (d, o) in migrated.drive.iter().zip(&old.drive) {
        assert_eq!(
            (d.pwm_hz, d.deadband, d.max_duty),
            (o.pwm_hz, o.deadband, o.max_duty)
        );
        assert_eq!(d.winding_mohm, 0);
    }
    assert_eq!(migrated.drive[1].zero, pen_io::ZeroPolicy::Brake);
    assert_eq!(
        (migrated.power.supply_v, migrated.power.driver_current_a),
        (0.0, 0.0)
    );

    // No force, no nudge; calibrated (its zeros are stored), so no NOT_CALIBRATED.
    assert_eq!(
        command(&mut s, Command::EnableForces),
        Err(CommandError::ConfigNotValid)
    );
    let nudge = Nudge {
        channel: 0,
        command_permille: 100,
        duration_ms: 100,
    };
    assert_eq!(
        command(&mut s, Command::NudgeMotor(nudge.clone())),
        Err(CommandError::ConfigNotValid)
    );
    for st in next_states(&mut s, 10) {
        assert!(!st.haptics.enabled);
        assert_eq!(st.haptics.motors, [0; 3]);
        assert!(
            !st.faults.contains(Faults::NOT_CALIBRATED),
            "{:?}",
            st.faults
        );
    }

    // The kinematics and the calibration work: the virtual pen at its inkwell reads the
    // migrated zeros.
    s.send(&HostMsg::Pose(PoseSample::new(
        1,
        inkwell_pose(),
        Buttons::empty(),
    )))
    .unwrap();
    assert_eq!(
        command(&mut s, Command::StreamSensors { rate_hz: 100 }),
        Ok(())
    );
    let r = next_sensors(&mut s);
    println!("sensors at the inkwell: {r:?}");
    for k in 0..3 {
        assert!((r.encoders[k] - zeros.encoders[k]).abs() <= 1, "{r:?}");
        assert!(
            (i32::from(r.gimbal[k]) - zeros.gimbal[k]).abs() <= 1,
            "{r:?}"
        );
    }
    assert_eq!(
        command(&mut s, Command::StreamSensors { rate_hz: 0 }),
        Ok(())
    );
    // Calibrate works too (in force, not stored: still migrated, still no force).
    assert_eq!(command(&mut s, Command::Calibrate), Ok(()));
    let recalibrated = config(&mut s, HostMsg::GetConfig).unwrap();
    assert_eq!(recalibrated.calibration.unwrap().encoders, r.encoders);
    assert_eq!(
        command(&mut s, Command::EnableForces),
        Err(CommandError::ConfigNotValid)
    );
    let again = s.handshake(ANSWER, &mut vec![]).unwrap();
    assert_eq!(again.config, ConfigState::Migrated { from: 1 });

    // Written back as it is: refused by name, nothing written.
    match config(&mut s, HostMsg::SetConfig(recalibrated)) {
        Err(ConfigRejected::Invalid(f)) => assert_eq!(f.field.as_str(), "drive[0].winding_mohm"),
        other => panic!("{other:?}"),
    }
    // With the builder's values (and the duty clamps within the driver's rating): stored as
    // format 2, valid, forces enable.
    let mut complete = recalibrated;
    complete.power = pen_io::PowerConfig::DEFAULT;
    for d in &mut complete.drive {
        d.winding_mohm = 2200;
        d.max_duty = 0.2;
    }
    for j in 0..3 {
        complete.pen.max_current[j] = complete.stall_current_a(j);
    }
    assert_eq!(complete.validate(), Ok(()));
    assert_eq!(config(&mut s, HostMsg::SetConfig(complete)), Ok(complete));
    let again = s.handshake(ANSWER, &mut vec![]).unwrap();
    assert_eq!(again.config, ConfigState::Valid);
    assert_eq!(config(&mut s, HostMsg::GetConfig), Ok(complete));
    assert_eq!(command(&mut s, Command::EnableForces), Ok(()));
    assert_eq!(command(&mut s, Command::DisableForces), Ok(()));
    assert_eq!(command(&mut s, Command::NudgeMotor(nudge)), Ok(()));
    drop(dev);
    let _ = std::fs::remove_file(path);
}
