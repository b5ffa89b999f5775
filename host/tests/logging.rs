//! Diagnostics under RUST_LOG: `RUST_LOG=debug` adds debug lines to a command's stderr;
//! without RUST_LOG the output is the command's result line alone, as it always was.

use std::process::Command;

fn render(rust_log: Option<&str>) -> (bool, String) {
    let dir = std::env::temp_dir().join(format!("maobi-logging-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let out = dir.join(format!("press-{}.png", rust_log.unwrap_or("none")));
    let poses = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../examples/poses/press_lift.csv"
    );
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_maobi"));
    cmd.args(["render", "--poses", poses, "--px-per-mm", "4", "-o"])
        .arg(&out)
        .env_remove("RUST_LOG");
    if let Some(l) = rust_log {
        cmd.env("RUST_LOG", l);
    }
    let o = cmd.output().expect("run maobi");
    let _ = std::fs::remove_file(&out);
    (
        o.status.success(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

#[test]
fn rust_log_debug_shows_debug_lines_and_none_leaves_the_output_alone() {
    let (ok, quiet) = render(None);
    assert!(ok, "{quiet}");
    let lines: Vec<&str> = quiet.lines().collect();
    assert_eq!(lines.len(), 1, "only the result line: {quiet}");
    assert!(lines[0].starts_with("maobi render: "), "{quiet}");

    let (ok, loud) = render(Some("debug"));
    assert!(ok, "{loud}");
    let debug: Vec<&str> = loud.lines().filter(|l| l.contains("DEBUG")).collect();
    assert!(
        debug
            .iter()
            .any(|l| l.contains("press_lift.csv") && l.contains("ticks")),
        "the pose file's debug line: {loud}"
    );
    assert!(debug.iter().any(|l| l.contains("paper:")), "{loud}");
    assert!(
        loud.lines().any(|l| l.starts_with("maobi render: ")),
        "the result line stays: {loud}"
    );

    // A module filter narrows it: nothing of ours at `maobi::device` for a render.
    let (ok, narrow) = render(Some("maobi::device=debug"));
    assert!(ok);
    assert!(!narrow.contains("DEBUG"), "{narrow}");
}
