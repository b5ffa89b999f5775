//! Backend `probe-rs` without a board or a probe: a fake `probe-rs` (a shell script that checks
//! the arguments it gets, prints a defmt-like log, and fails or halts as asked) and the fake
//! pen of `tests/serial.rs` on a pseudo-terminal, so the whole backend runs: starting the
//! tool, waiting for the port, the link session, stopping the tool, the log checks. (Not run
//! on a board.)

mod common;

use std::path::{Path, PathBuf};
use std::sync::OnceLock;
use std::time::Duration;

use common::{fake_device, pair};
use hil::probe_rs::{run_probe_rs_with, ProbeRsOptions};
use maobi::device::{PortInfo, UsbIds};
use serialport::SerialPort;

/// The fake tool. What it does comes from the "ELF" file it is given (its first word), so one
/// script serves every test; it is written once, before any test starts a process, so no
/// test forks while the script is open for writing (exec would fail with ETXTBSY).
const FAKE: &str = r#"#!/bin/sh
# fake probe-rs: `run --chip STM32F411CEUx [--probe P] --no-location ELF`
elf=""
for a in "$@"; do elf="$a"; done
printf '%s\n' "$*" > "$elf.args"
if [ "$1" != run ] || [ "$2" != --chip ] || [ "$3" != STM32F411CEUx ] || [ ! -f "$elf" ]; then
  echo "fake probe-rs: unexpected arguments: $*" >&2
  exit 2
fi
case " $* " in *" --no-location "*) ;; *) echo "fake probe-rs: no --no-location" >&2; exit 2;; esac
mode=$(head -n 1 "$elf")
stop() { echo "fake probe-rs: interrupted" >&2; exit 0; }
trap stop INT
case "$mode" in
  noprobe) echo "Error: No connected probes were found." >&2; exit 1;;
  flashfail) echo "      Erasing ✖ [00:00:00]" >&2; echo "Error: Failed to erase flash sector at 0x08000000" >&2; exit 1;;
esac
echo "      Erasing ✔ [00:00:01] 64.00 KiB/64.00 KiB" >&2
echo "  Programming ✔ [00:00:02] 60.12 KiB/60.12 KiB" >&2
echo "     Finished in 3.1s" >&2
echo "0.000000 INFO  maobi-pen up, config Valid"
# While the link session runs (the halting test's is long, see `long_poses`), so the halt
# comes early.
if [ "$mode" = panic ]; then echo "0.010000 ERROR panicked at src/board.rs:12:5: index out of bounds"; fi
if [ "$mode" = halt ]; then sleep 0.005; echo "Frame 0: HardFault @ 0x08000400"; echo "Error: the core halted" >&2; exit 1; fi
while :; do sleep 0.1; done
"#;

fn dir() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let d = std::env::temp_dir().join(format!("hil-probe-rs-{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        let tool = d.join("probe-rs");
        std::fs::write(&tool, FAKE).unwrap();
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            std::fs::set_permissions(&tool, std::fs::Permissions::from_mode(0o755)).unwrap();
        }
        d
    })
}

/// A firmware "image" that tells the fake tool what to do; one file per test (the tool
/// writes its arguments beside it).
fn elf(test: &str, mode: &str) -> PathBuf {
    let p = dir().join(format!("{test}.elf"));
    std::fs::write(&p, format!("{mode}\n")).unwrap();
    p
}

fn poses() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/poses/hook.csv")
}

/// Ten seconds of a brush held still above the paper: a link session of most of a second
/// against the fake pen (which ticks as fast as the poses come, about a hundred times real
/// time at the presets' one substep), long enough that a probe-rs that halts a few
/// milliseconds after it starts does so while the session runs, however slowly the machine
/// starts the fake's shell.
fn long_poses() -> PathBuf {
    let path = dir().join("long.csv");
    let mut csv = String::from("t,x,y,z,qw,qx,qy,qz\n");
    for k in 0..10_000 {
        csv.push_str(&format!("{:.3},0,0,60,1,0,0,0\n", k as f64 * 1e-3));
    }
    std::fs::write(&path, csv).unwrap();
    path
}

fn opts(port: Option<PathBuf>) -> ProbeRsOptions {
    let mut o = ProbeRsOptions::new(Some(dir().join("probe-rs")));
    o.port = port;
    o.port_timeout = Duration::from_secs(3);
    o
}

fn no_ports() -> Vec<PortInfo> {
    vec![]
}

/// A fake pen on a pseudo-terminal: the thread holds one end, the path of the other is the
/// pen's port (kept open here so the pair stays up).
fn pen() -> Option<(PathBuf, serialport::TTYPort)> {
    let (dev, host) = pair()?;
    let name = host.name().expect("the pty has a name");
    std::thread::spawn(move || fake_device(dev, Duration::from_secs(60)));
    Some((PathBuf::from(name), host))
}

#[test]
fn flashes_runs_the_checks_and_reads_a_clean_log() {
    let Some((port, _keep)) = pen() else { return };
    let mut o = opts(Some(port.clone()));
    o.probe = Some("0483:374b".into());
    let elf = elf("clean", "ok");
    let r = run_probe_rs_with(&elf, &poses(), &o, &no_ports).unwrap();
    println!("{}", r.render());
    assert!(r.passed(), "{}", r.render());
    let names: Vec<&str> = r.checks.iter().map(|c| c.name.as_str()).collect();
    assert_eq!(
        names,
        [
            "probe-rs ran to the end",
            "defmt log: the firmware booted once",
            "defmt log: no panic or fault"
        ]
    );
    let session = r.session.as_ref().expect("the link session ran");
    assert!(session.figures.states > 0);
    assert_eq!(r.log, ["0.000000 INFO  maobi-pen up, config Valid"]);
    let args = std::fs::read_to_string(elf.with_extension("elf.args")).unwrap();
    assert_eq!(
        args.trim(),
        format!(
            "run --chip STM32F411CEUx --probe 0483:374b --no-location {}",
            elf.display()
        )
    );
}

#[test]
fn a_panic_in_the_log_fails_its_check_and_the_port_is_found_by_usb_ids() {
    let Some((port, _keep)) = pen() else { return };
    let name = port.to_string_lossy().into_owned();
    let ports = move || {
        vec![
            PortInfo {
                name: "/dev/ttyACM7".into(),
                usb: Some(UsbIds {
                    vid: 0x0483,
                    pid: 0x374b,
                    product: Some("STLINK-V3".into()),
                    serial: None,
                }),
            },
            PortInfo {
                name: name.clone(),
                usb: Some(UsbIds {
                    vid: 0x1209,
                    pid: 0x0001,
                    product: Some("Maobi pen".into()),
                    serial: Some("0001".into()),
                }),
            },
        ]
    };
    let r = run_probe_rs_with(&elf("panic", "panic"), &poses(), &opts(None), &ports).unwrap();
    println!("{}", r.render());
    assert_eq!(r.port.as_deref(), Some(port.as_path()));
    assert!(r.session.as_ref().is_some_and(|s| s.passed()));
    assert!(!r.passed());
    let c = r
        .checks
        .iter()
        .find(|c| c.name == "defmt log: no panic or fault")
        .unwrap();
    assert!(!c.pass && c.detail.contains("index out of bounds"), "{c}");
}

#[test]
fn a_core_that_halts_during_the_run_fails() {
    let Some((port, _keep)) = pen() else { return };
    let r = run_probe_rs_with(
        &elf("halt", "halt"),
        &long_poses(),
        &opts(Some(port)),
        &no_ports,
    )
    .unwrap();
    println!("{}", r.render());
    assert!(!r.passed());
    let failed: Vec<&str> = r
        .checks
        .iter()
        .filter(|c| !c.pass)
        .map(|c| c.name.as_str())
        .collect();
    assert!(failed.contains(&"probe-rs ran to the end"), "{failed:?}");
    assert!(
        failed.contains(&"defmt log: no panic or fault"),
        "{failed:?}"
    );
}

#[test]
fn a_flash_failure_shows_what_probe_rs_said() {
    let e = run_probe_rs_with(
        &elf("flashfail", "flashfail"),
        &poses(),
        &opts(None),
        &no_ports,
    )
    .err()
    .unwrap()
    .to_string();
    assert!(e.contains("flashing with probe-rs failed"), "{e}");
    assert!(
        e.contains("Failed to erase flash sector at 0x08000000"),
        "{e}"
    );
}

#[test]
fn no_probe_is_named() {
    let e = run_probe_rs_with(&elf("noprobe", "noprobe"), &poses(), &opts(None), &no_ports)
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("no debug probe found"), "{e}");
    assert!(e.contains("No connected probes were found"), "{e}");
}

#[test]
fn wrong_arguments_are_refused_by_the_fake_tool() {
    // The fake checks its arguments: another chip is not what the pen has.
    let mut o = opts(None);
    o.chip = "STM32F401CCUx".into();
    let e = run_probe_rs_with(&elf("wrongchip", "ok"), &poses(), &o, &no_ports)
        .err()
        .unwrap()
        .to_string();
    assert!(
        e.contains("unexpected arguments: run --chip STM32F401CCUx"),
        "{e}"
    );
}

#[test]
fn a_missing_tool_says_how_to_install_it() {
    let mut o = opts(None);
    o.tool = dir().join("no-such-probe-rs");
    let e = run_probe_rs_with(&elf("notool", "ok"), &poses(), &o, &no_ports)
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("probe-rs not found"), "{e}");
    assert!(e.contains("cargo install probe-rs-tools"), "{e}");
}

#[test]
fn a_port_that_never_appears_times_out_and_probe_rs_is_stopped() {
    let mut o = opts(Some(dir().join("ttyACM-never")));
    o.port_timeout = Duration::from_secs(1);
    let t0 = std::time::Instant::now();
    let e = run_probe_rs_with(&elf("noport", "ok"), &poses(), &o, &no_ports)
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("ttyACM-never did not appear within 1 s"), "{e}");
    // The fake tool's log is quoted, and it was stopped, not left running.
    assert!(e.contains("maobi-pen up"), "{e}");
    assert!(t0.elapsed() < Duration::from_secs(8), "{:?}", t0.elapsed());
    let args = std::fs::read_to_string(dir().join("noport.elf.args")).unwrap_or_default();
    assert!(args.starts_with("run --chip STM32F411CEUx"), "{args}");
}

/// The Black Pill pen reads its own sensors: no poses are streamed, its link and force loop
/// are checked instead; a tick that overran fails.
#[test]
fn a_pen_with_its_own_sensors_gets_link_and_loop_checks() {
    for (tick_max_us, pass) in [(1012, true), (2300, false)] {
        let Some((dev, host)) = pair() else { return };
        let name = PathBuf::from(host.name().unwrap());
        std::thread::spawn(move || {
            common::fake_sensor_pen(dev, Duration::from_secs(30), tick_max_us)
        });
        let r = run_probe_rs_with(
            &elf(&format!("sensorpen{tick_max_us}"), "ok"),
            &poses(),
            &opts(Some(name)),
            &no_ports,
        )
        .unwrap();
        println!("{}", r.render());
        let session = r.session.as_ref().unwrap();
        let names: Vec<&str> = session.checks.iter().map(|c| c.name.as_str()).collect();
        assert_eq!(
            names,
            [
                "handshake",
                "pose file",
                "brush states stream",
                "force loop holds 1 ms",
                "no overrun, worst tick within 90%",
                "decoders clean"
            ]
        );
        assert_eq!(session.passed(), pass, "{}", r.render());
        assert_eq!(r.passed(), pass);
        assert!(session.checks[3]
            .detail
            .contains(&format!("/1000/{tick_max_us} us")));
        assert!(session.checks[4].pass, "{}", r.render());
        assert!(session.checks[4]
            .detail
            .contains("worst tick busy 410 us (41.0%"));
        drop(host);
    }
}
