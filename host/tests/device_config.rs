//! `maobi device config template | check | get | set` end to end: the binary against a fake
//! pen on TCP that stores a configuration the way the firmware does (validated whole before
//! it is kept, refused while forces are on, answered with what was stored). The firmware's own
//! store is exercised the same way under QEMU in `hil/tests/config.rs`. Not run against a
//! real pen.

use std::io::{Read, Write};
use std::net::TcpListener;
use std::path::PathBuf;
use std::process::{Command, Output};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use maobi::device::endpoint::nothing_to_read_yet;
use maobi_shared::kinematics::RawReadings;
use maobi_shared::protocol::{
    Capabilities, ConfigRejected, ConfigState, DeviceConfig, DeviceInfo, DeviceMsg, DeviceRx,
    HostMsg, Message, Version,
};

#[derive(Debug, Default)]
struct Pen {
    config: Option<DeviceConfig>,
    forces_on: bool,
    /// `SetConfig` messages received (accepted or not).
    writes: usize,
}

/// Serves one connection on a loopback port; returns the address and the pen.
fn serve(pen: Pen) -> (String, Arc<Mutex<Pen>>) {
    let l = TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = l.local_addr().unwrap().to_string();
    let pen = Arc::new(Mutex::new(pen));
    let shared = pen.clone();
    std::thread::spawn(move || {
        let Ok((mut s, _)) = l.accept() else { return };
        s.set_read_timeout(Some(Duration::from_millis(20))).unwrap();
        let mut rx = DeviceRx::new();
        let mut buf = [0u8; 1024];
        let mut out = vec![0u8; DeviceMsg::MAX_FRAME];
        loop {
            let n = match s.read(&mut buf) {
                Ok(0) => return,
                Ok(n) => n,
                Err(e) if nothing_to_read_yet(&e) => 0,
                Err(_) => return,
            };
            let msgs: Vec<HostMsg> = rx.feed(&buf[..n]).filter_map(Result::ok).collect();
            let mut p = shared.lock().unwrap();
            for m in msgs {
                let reply = match m {
                    HostMsg::Hello(_) => DeviceMsg::Hello(
                        DeviceInfo::new(
                            "fake-pen",
                            Version::default(),
                            Capabilities::REAL_SENSORS | Capabilities::STORED_CONFIG,
                            3.3,
                            0.88,
                        )
                        .with_config(if p.config.is_some() {
                            ConfigState::Valid
                        } else {
                            ConfigState::Missing
                        }),
                    ),
                    HostMsg::Ping { seq } => DeviceMsg::Pong { seq },
                    HostMsg::GetConfig => DeviceMsg::Config(
                        p.config
                            .ok_or(ConfigRejected::NotStored(ConfigState::Missing)),
                    ),
                    HostMsg::SetConfig(c) => {
                        p.writes += 1;
                        DeviceMsg::Config(if p.forces_on {
                            Err(ConfigRejected::ForcesEnabled)
                        } else {
                            c.validate().map_err(ConfigRejected::Invalid).map(|()| {
                                p.config = Some(c);
                                c
                            })
                        })
                    }
                    _ => continue,
                };
                let n = reply.encode(&mut out).unwrap();
                if s.write_all(&out[..n]).is_err() {
                    return;
                }
            }
        }
    });
    (addr, pen)
}

fn maobi(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_maobi"))
        .args(args)
        .output()
        .expect("run maobi")
}

fn text(o: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

fn temp(name: &str) -> PathBuf {
    std::env::temp_dir().join(format!("maobi-devcfg-{}-{name}", std::process::id()))
}

/// The template written to a temp file by the binary.
fn template(name: &str) -> PathBuf {
    let file = temp(name);
    let o = maobi(&["device", "config", "template", "-o", file.to_str().unwrap()]);
    assert!(o.status.success(), "{}", text(&o));
    file
}

/// `maobi device config set FILE --connect ADDR [extra]`.
fn set(file: &std::path::Path, addr: &str, extra: &[&str]) -> Output {
    let mut args = vec![
        "device",
        "config",
        "set",
        file.to_str().unwrap(),
        "--connect",
        addr,
    ];
    args.extend_from_slice(extra);
    maobi(&args)
}

/// A pen holding the reference configuration with a calibration.
fn calibrated_pen() -> Pen {
    Pen {
        config: Some(DeviceConfig {
            calibration: Some(calibration()),
            ..DeviceConfig::DEFAULT
        }),
        ..Pen::default()
    }
}

fn calibration() -> RawReadings {
    RawReadings {
        encoders: [311, -2047, 64],
        gimbal: [2050, 1990, 2101],
    }
}

#[test]
fn template_edit_set_get_keeps_the_calibration_and_reads_back() {
    let file = template("pen.toml");
    let edited = std::fs::read_to_string(&file)
        .unwrap()
        .replace("upper_arm_mm = 133.35", "upper_arm_mm = 140.5")
        .replacen("deadband = 0.04", "deadband = 0.07", 1);
    std::fs::write(&file, &edited).unwrap();
    let o = maobi(&["device", "config", "check", file.to_str().unwrap()]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(text(&o).contains("2 value(s) differ"), "{}", text(&o));
    assert!(
        text(&o).contains("stall currents at the duty clamps 1.09 A, 1.09 A, 1.09 A"),
        "{}",
        text(&o)
    );

    let (addr, pen) = serve(calibrated_pen());
    let o = set(&file, &addr, &[]);
    let out = text(&o);
    assert!(o.status.success(), "{out}");
    assert!(out.contains("2 value(s) changed"), "{out}");
    assert!(out.contains("pen.upper_arm_mm: 133.35 -> 140.5"), "{out}");
    assert!(out.contains("drive[0].deadband: 0.04 -> 0.07"), "{out}");
    let stored = pen.lock().unwrap().config.unwrap();
    assert_eq!(stored.pen.upper_arm_mm, 140.5);
    assert_eq!(stored.drive[0].deadband, 0.07);
    assert_eq!(
        stored.calibration,
        Some(calibration()),
        "the calibration was not kept"
    );

    // What `get` writes is what the pen holds, calibration included.
    let (addr, _pen) = serve(Pen {
        config: Some(stored),
        ..Pen::default()
    });
    let got = temp("got.toml");
    let o = maobi(&[
        "device",
        "config",
        "get",
        "--connect",
        &addr,
        "-o",
        got.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o));
    let back = maobi::device::config_file::load(&got).unwrap();
    assert_eq!(back, stored);
    let _ = std::fs::remove_file(&file);
    let _ = std::fs::remove_file(&got);
}

#[test]
fn a_bad_file_never_reaches_the_pen() {
    let file = template("bad.toml");
    let good = std::fs::read_to_string(&file).unwrap();
    let (addr, pen) = serve(Pen::default());
    for (bad, expect) in [
        (
            good.replace("peak_n = 3.3", "peak_n = 80.0"),
            "limits.peak_n: 80 is outside the valid range",
        ),
        (
            good.replace("[limits]\n", "[limits]\npeak = 1.0\n"),
            "unknown key `limits.peak`",
        ),
        (good.replace("ratio = [13.2,", "ratio = [\"x\","), "line "),
        // The old default duty clamp: a stalled motor would draw 5.2 A from a 1.2 A driver.
        (
            good.replacen("max_duty = 0.2\n", "max_duty = 0.95\n", 1),
            "drive[0].max_duty = 0.95 lets the stalled motor draw 5.18 A (12 V x 0.95 / 2.2 Ohm), \
             more than the driver's rating of 1.2 A (power.driver_current_a); with this motor \
             and supply, max_duty may be at most 0.22",
        ),
        (
            good.replace("supply_v = 12.0", "supply_v = 24.0"),
            "power.supply_v: 24 is outside the valid range",
        ),
    ] {
        std::fs::write(&file, bad).unwrap();
        let o = set(&file, &addr, &[]);
        assert!(!o.status.success());
        assert!(text(&o).contains(expect), "{expect}: {}", text(&o));
        let o = maobi(&["device", "config", "check", file.to_str().unwrap()]);
        assert!(!o.status.success());
        assert!(text(&o).contains(expect), "{expect}: {}", text(&o));
    }
    assert_eq!(pen.lock().unwrap().writes, 0);
    let _ = std::fs::remove_file(&file);
}

#[test]
fn the_pen_refusing_is_an_error_that_says_why() {
    let file = template("refused.toml");
    let (addr, pen) = serve(Pen {
        config: Some(DeviceConfig::DEFAULT),
        forces_on: true,
        writes: 0,
    });
    let o = set(&file, &addr, &[]);
    assert!(!o.status.success());
    assert!(text(&o).contains("forces are enabled"), "{}", text(&o));
    assert_eq!(pen.lock().unwrap().writes, 1);

    let (addr, _) = serve(Pen::default());
    let o = maobi(&["device", "config", "get", "--connect", &addr]);
    assert!(!o.status.success());
    let out = text(&o);
    assert!(out.contains("no configuration in force (missing"), "{out}");
    assert!(out.contains("maobi device config set FILE"), "{out}");
    let _ = std::fs::remove_file(&file);
}

#[test]
fn clear_calibration_drops_it_and_says_the_pen_gives_no_force() {
    let file = template("clear.toml");
    let (addr, pen) = serve(calibrated_pen());
    let o = set(&file, &addr, &["--clear-calibration"]);
    let out = text(&o);
    assert!(o.status.success(), "{out}");
    assert!(out.contains("calibration: { encoders"), "{out}");
    assert!(
        out.contains("not calibrated: the pen gives no force"),
        "{out}"
    );
    assert_eq!(pen.lock().unwrap().config.unwrap().calibration, None);
    let _ = std::fs::remove_file(&file);
}

/// The template follows its own rule (`pen.max_current` is the stall current at the duty
/// clamp, from its own supply, clamp and winding), and `check` warns, without failing, about
/// a `max_current` above it: the field, both currents, what to set.
#[test]
fn the_template_sets_max_current_to_the_stall_current_and_check_warns_above_it() {
    let file = template("stall.toml");
    let good = std::fs::read_to_string(&file).unwrap();
    let cfg = maobi::device::config_file::load(&file).unwrap();
    for j in 0..3 {
        let stall = cfg.power.supply_v * cfg.drive[j].max_duty / cfg.drive[j].winding_ohm();
        assert!(
            (cfg.pen.max_current[j] - stall).abs() < 1e-6,
            "max_current[{j}] = {}, stall current {stall}:\n{good}",
            cfg.pen.max_current[j]
        );
    }
    let o = maobi(&["device", "config", "check", file.to_str().unwrap()]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(!text(&o).contains("warning"), "{}", text(&o));

    // The old template's figure on the first motor: a warning, not an error.
    let line = good
        .lines()
        .find(|l| l.starts_with("max_current = "))
        .unwrap();
    let above = line.replacen('[', "[2.0, ", 1);
    let above = format!("{}]", above.rsplit_once(',').unwrap().0);
    std::fs::write(&file, good.replace(line, &above)).unwrap();
    let o = maobi(&["device", "config", "check", file.to_str().unwrap()]);
    let out = text(&o);
    assert!(o.status.success(), "{out}");
    assert!(out.contains("a valid configuration"), "{out}");
    assert_eq!(out.matches("warning: ").count(), 1, "{out}");
    for part in [
        "warning: pen.max_current[0] = 2 A is more than motor 1's stall current at its duty \
         clamp, 1.09 A (power.supply_v 12 V x drive[0].max_duty 0.2 / 2.2 Ohm)",
        "Set pen.max_current[0] = 1.09 ",
    ] {
        assert!(out.contains(part), "{part}\n{out}");
    }
    // A value copied from the printed stall current is not flagged.
    std::fs::write(
        &file,
        good.replace(line, "max_current = [1.09, 1.09, 1.09]"),
    )
    .unwrap();
    let o = maobi(&["device", "config", "check", file.to_str().unwrap()]);
    assert!(
        o.status.success() && !text(&o).contains("warning"),
        "{}",
        text(&o)
    );
    let _ = std::fs::remove_file(&file);
}
