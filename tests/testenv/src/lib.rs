//! One rule for tests that need something a machine may lack (QEMU, a pseudo-terminal, an X
//! display's screenshot, a firmware image, the stand-in haptics library): on a developer's
//! machine such a test says what it skipped and passes; where every test must run (CI, which
//! sets `CI=true`) it fails, naming what was missing, so a green run means every test ran.
//!
//! Every skip is also appended, one line each, to the file named by [`SKIP_LOG_ENV`] when it
//! is set: `.ci/run` counts them into its closing `tests: N passed, M skipped` line.

use std::io::Write;

/// Names a file to which every skip appends one line (`.ci/run` sets it).
pub const SKIP_LOG_ENV: &str = "MAOBI_SKIP_LOG";

/// Makes every test required, like `CI=true`, on a developer's machine.
pub const REQUIRE_ALL_ENV: &str = "MAOBI_REQUIRE_ALL";

/// Whether `value` (an environment variable's) turns a requirement on: anything but unset,
/// empty, `0`, `false` or `no`.
fn truthy(value: Option<std::ffi::OsString>) -> bool {
    match value {
        None => false,
        Some(v) => {
            let v = v.to_string_lossy().trim().to_ascii_lowercase();
            !(v.is_empty() || v == "0" || v == "false" || v == "no")
        }
    }
}

/// Whether every test must run here: `CI` or [`REQUIRE_ALL_ENV`] is set (to anything but
/// empty, `0`, `false` or `no`), or one of `also` (a test's own older switch, such as
/// `MAOBI_REQUIRE_QEMU`) is set to any value at all.
pub fn required(also: &[&str]) -> bool {
    truthy(std::env::var_os("CI"))
        || truthy(std::env::var_os(REQUIRE_ALL_ENV))
        || also.iter().any(|v| std::env::var_os(v).is_some())
}

/// The test calling this cannot run here because `reason` (say what is missing and how to get
/// it). Where tests are [`required`] (with `also`), it panics with the reason; otherwise it
/// prints `SKIPPED: reason` and records the skip, and the caller returns.
#[track_caller]
pub fn skip_unless_required(also: &[&str], reason: &str) {
    let at = std::panic::Location::caller();
    if required(also) {
        panic!(
            "this test cannot run here, and every test must run (CI or {}{}): {reason} \
             (at {at})",
            REQUIRE_ALL_ENV,
            also.iter().map(|v| format!(" or {v}")).collect::<String>()
        );
    }
    eprintln!("SKIPPED: {reason} (at {at})");
    if let Some(path) = std::env::var_os(SKIP_LOG_ENV) {
        // A lost line only undercounts a skip on a developer's machine; CI never gets here.
        if let Ok(mut f) = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(path)
        {
            let _ = writeln!(f, "{at}: {reason}");
        }
    }
}

/// [`skip_unless_required`] with no switch of the test's own.
#[track_caller]
pub fn skip(reason: &str) {
    skip_unless_required(&[], reason)
}

#[cfg(test)]
mod tests {
    use super::truthy;

    #[test]
    fn what_counts_as_set() {
        for v in ["true", "1", "yes", "TRUE", "anything"] {
            assert!(truthy(Some(v.into())), "{v}");
        }
        for v in ["", "0", "false", "no", "False", " "] {
            assert!(!truthy(Some(v.into())), "{v:?}");
        }
        assert!(!truthy(None));
    }
}
