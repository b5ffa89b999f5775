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
