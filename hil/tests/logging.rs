//! `hil` starts a logger: RUST_LOG reaches the host library's diagnostics (and hil's own),
//! and without it nothing below a warning is printed.

use std::process::Command;

/// `hil size` of an image that is not there: it fails at once, before any emulator or build.
fn hil(rust_log: Option<&str>) -> String {
    let missing = std::env::temp_dir().join(format!("hil-logging-{}.elf", std::process::id()));
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_hil"));
    cmd.arg("--elf")
        .arg(&missing)
        .args(["--no-build", "size"])
        .env_remove("RUST_LOG");
    if let Some(l) = rust_log {
        cmd.env("RUST_LOG", l);
    }
    let o = cmd.output().expect("run hil");
    assert!(!o.status.success(), "a missing image is an error");
    String::from_utf8_lossy(&o.stderr).into_owned()
}

#[test]
fn rust_log_reaches_hil_and_its_default_is_warnings() {
    let loud = hil(Some("debug"));
    assert!(
        loud.lines()
            .any(|l| l.contains("DEBUG") && l.contains("hil") && l.contains("size")),
        "{loud}"
    );
    let quiet = hil(None);
    assert!(!quiet.contains("DEBUG"), "{quiet}");
}
