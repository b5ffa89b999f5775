//! `maobi device check` against the firmware in QEMU: the bring-up wizard's protocol
//! (handshake with the configuration state, the sensor stream while the wizard moves the
//! virtual pen, nudges, calibration) against the real firmware's link task. The QEMU board's
//! motors are virtual: a nudge is accepted but cannot move a joint, so nudges are SKIP; the
//! sensors are computed by the board from the poses the wizard streams (the reference pen's
//! inverse kinematics).
//!
//! Needs `qemu-system-arm` (skipped with a message without it, unless `MAOBI_REQUIRE_QEMU`
//! is set, as in CI).

use std::path::PathBuf;
use std::time::Duration;

use hil::run::QemuDevice;
use hil::{firmware, qemu};
use maobi::device::bringup::{run_check, CheckOptions, CheckReport, Outcome, Scripted};
use maobi::device::Endpoint;
use maobi_shared::pen_io::{self, DeviceConfig, CONFIG_IMAGE_MAX};

fn image() -> Option<PathBuf> {
    firmware::qemu_test_image()
}

/// Boots the firmware (with `store` preloaded as its configuration, if any) and runs the
/// wizard, non-interactively, over the UART socket.
fn check(store: Option<&[u8]>) -> Option<(CheckReport, Vec<String>)> {
    let elf = image()?;
    let loader = match store {
        Some(bytes) => {
            let path = std::env::temp_dir().join(format!(
                "maobi-check-cfg-{}-{}.bin",
                std::process::id(),
                bytes.len()
            ));
            std::fs::write(&path, bytes).unwrap();
            qemu::config_loader_args(&path)
        }
        None => vec![],
    };
    let (mut dev, first) =
        QemuDevice::start_with(&elf, &[], &loader, Duration::from_secs(600)).unwrap();
    // The wizard opens its own connection: QEMU's UART socket takes the next client.
    drop(first);
    let mut opts = CheckOptions::new(Endpoint::Tcp(format!("127.0.0.1:{}", dev.port)));
    // The emulated firmware runs slower than real time.
    opts.reply_timeout = Duration::from_secs(10);
    let mut op = Scripted::default();
    let r = run_check(&opts, &mut op);
    println!("{}\n\n{}", op.transcript.join("\n"), r.table());
    assert!(dev.guest.child.try_wait().unwrap().is_none(), "QEMU died");
    Some((r, op.transcript))
}

#[test]
fn a_virtual_pen_without_a_store_passes_sensors_and_skips_motors_and_calibration() {
    let Some((r, said)) = check(None) else { return };
    assert!(r.passed(), "{}", r.table());
    assert_eq!(r.outcome("1 handshake"), Some(Outcome::Pass));
    assert_eq!(r.outcome("2 sensors"), Some(Outcome::Pass), "{}", r.table());
    for s in &r.steps[2..5] {
        assert_eq!(s.outcome, Outcome::Skip, "{}", r.table());
    }
    assert_eq!(r.outcome("4 calibration"), Some(Outcome::Skip));
    assert!(said.iter().any(|l| l.contains("synthetic")));
}

#[test]
fn a_corrupt_store_is_rewritten_then_calibrated() {
    let mut buf = vec![0u8; CONFIG_IMAGE_MAX];
    let n = pen_io::encode(&DeviceConfig::DEFAULT, &mut buf).unwrap();
    buf.truncate(n);
    // One payload byte damaged: the CRC no longer matches.
    buf[n / 2] ^= 0x40;
    let Some((r, said)) = check(Some(&buf)) else {
        return;
    };
    assert!(said.iter().any(|l| l.contains("corrupt")), "{said:?}");
    assert!(r.passed(), "{}", r.table());
    assert!(
        r.steps[0]
            .detail
            .contains("the reference configuration was written"),
        "{}",
        r.table()
    );
    assert_eq!(r.outcome("2 sensors"), Some(Outcome::Pass), "{}", r.table());
    assert_eq!(
        r.outcome("4 calibration"),
        Some(Outcome::Pass),
        "{}",
        r.table()
    );
}

/// `maobi device config set` / `get` (the library functions behind them) against the
/// firmware's own store: a builder's file without a calibration keeps the pen's, the pen
/// answers with exactly what it stored, and its own validation refuses what the host's would.
#[test]
fn configuration_files_go_through_the_firmware_store() {
    use maobi::device::bringup::Wire;
    use maobi::device::config_file::{from_toml, read_from_pen, to_toml, write_to_pen};
    use maobi_shared::kinematics::RawReadings;
    use maobi_shared::protocol::ConfigRejected;

    let Some(elf) = image() else { return };
    let answer = Duration::from_secs(10);
    let calibrated = DeviceConfig {
        calibration: Some(RawReadings {
            encoders: [0; 3],
            gimbal: [2048; 3],
        }),
        ..DeviceConfig::DEFAULT
    };
    let mut buf = vec![0u8; CONFIG_IMAGE_MAX];
    let n = pen_io::encode(&calibrated, &mut buf).unwrap();
    let path = std::env::temp_dir().join(format!("maobi-cfgfile-{}.bin", std::process::id()));
    std::fs::write(&path, &buf[..n]).unwrap();
    let loader = qemu::config_loader_args(&path);
    let (dev, first) =
        QemuDevice::start_with(&elf, &[], &loader, Duration::from_secs(600)).unwrap();
    drop(first);
    let mut wire =
        Wire::connect(&Endpoint::Tcp(format!("127.0.0.1:{}", dev.port)), answer).unwrap();

    // The builder's file: the template with their arm and gentler limits, no calibration.
    let text = to_toml(&DeviceConfig::DEFAULT, "a builder's pen")
        .replace("forearm_mm = 133.35", "forearm_mm = 141.0")
        .replace("peak_n = 3.3", "peak_n = 2.5");
    let mine = from_toml(&text).unwrap();
    assert_eq!(mine.calibration, None);
    let w = write_to_pen(&mut wire, mine, false, answer).unwrap();
    assert_eq!(w.before, Some(calibrated));
    assert_eq!(w.stored.pen.forearm_mm, 141.0);
    assert_eq!(w.stored.limits.peak_n, 2.5);
    assert_eq!(
        w.stored.calibration, calibrated.calibration,
        "calibration lost"
    );
    assert_eq!(read_from_pen(&mut wire, answer).unwrap(), w.stored);

    // Past the host's check, the firmware's own refuses the same value and keeps the old.
    let mut bad = w.stored;
    bad.drive[2].max_duty = 1.5;
    match wire.set_config(bad, answer).unwrap() {
        Err(ConfigRejected::Invalid(f)) => assert_eq!(f.field.as_str(), "drive[2].max_duty"),
        other => panic!("{other:?}"),
    }
    assert_eq!(read_from_pen(&mut wire, answer).unwrap(), w.stored);
    let _ = std::fs::remove_file(&path);

    // Without a store the virtual pen keeps no configuration, and says so.
    let (dev, first) = QemuDevice::start_with(&elf, &[], &[], Duration::from_secs(600)).unwrap();
    drop(first);
    let mut wire =
        Wire::connect(&Endpoint::Tcp(format!("127.0.0.1:{}", dev.port)), answer).unwrap();
    let e = write_to_pen(&mut wire, mine, false, answer)
        .unwrap_err()
        .to_string();
    assert!(e.contains("keeps no configuration"), "{e}");
    let e = read_from_pen(&mut wire, answer).unwrap_err().to_string();
    assert!(e.contains("not applicable"), "{e}");
}
