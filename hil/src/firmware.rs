//! Building the firmware image and reading its size.

use std::path::{Path, PathBuf};
use std::process::Command;

use anyhow::{bail, Context, Result};

pub const TARGET: &str = "thumbv7em-none-eabihf";
pub const BIN: &str = "maobi-fw";
/// The QEMU image with the firmware's test hooks (feature `test-hooks`: fault injection,
/// the `crash` boot modes), a bin of its own so that building it never replaces [`BIN`].
pub const HOOKS_BIN: &str = "maobi-fw-hooks";
/// `cargo build` arguments in `firmware/` for [`HOOKS_BIN`].
const HOOKS_BUILD_ARGS: &[&str] = &[
    "build",
    "--release",
    "--features",
    "test-hooks",
    "--bin",
    HOOKS_BIN,
];

/// The boards the firmware builds for (`firmware/Cargo.toml`'s `board-*` features).
#[derive(Copy, Clone, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Board {
    /// QEMU's mps2-an386: `maobi-fw`, profile `release`, default features.
    Qemu,
    /// The STM32F411CE Black Pill: `maobi-pen`, profile `pen` (built for size), feature
    /// `board-blackpill`.
    Blackpill,
}

impl Board {
    /// The image's name.
    pub fn bin(self) -> &'static str {
        match self {
            Board::Qemu => BIN,
            Board::Blackpill => "maobi-pen",
        }
    }
    /// The cargo profile, which is also its directory under `target/<triple>/`.
    pub fn profile(self) -> &'static str {
        match self {
            Board::Qemu => "release",
            Board::Blackpill => "pen",
        }
    }
    /// `cargo build` arguments in `firmware/`.
    pub fn build_args(self) -> &'static [&'static str] {
        match self {
            Board::Qemu => &["build", "--release"],
            Board::Blackpill => &[
                "build",
                "--profile",
                "pen",
                "--no-default-features",
                "--features",
                "board-blackpill",
            ],
        }
    }
    /// The defmt line each board logs once at boot (`hil run` and `hil size --check` look for
    /// it).
    pub const fn boot_line(self) -> &'static str {
        match self {
            Board::Qemu => "maobi-fw up",
            Board::Blackpill => "maobi-pen up",
        }
    }
    /// Where its RAM starts (both: the Cortex-M SRAM region).
    pub fn ram_start(self) -> u64 {
        0x2000_0000
    }
    /// What its image may take (`hil size --check`).
    ///
    /// The Black Pill's: the STM32F411CE has 512 KiB of flash, of which sectors 0-5
    /// (256 KiB) are for code (6 and 7 keep the configuration log, memory.x), and 128 KiB of
    /// RAM. The budget is 75% of those code sectors and half the RAM for statics, the other
    /// half left to the stack ([`Board::STACK_RESERVE`] is what it needs) and to growth: room
    /// the pen spends on quality (values in panic messages, the configuration's migration,
    /// the hot path built for speed) with a quarter of its sectors still free.
    ///
    /// The QEMU image is the pen's firmware on a virtual board: the same application and
    /// budget, plus the thesis's step (Kang & Cho, kept for comparison with the paper) and
    /// its state, which the pen's image leaves out. Growth past that fails, to be seen and
    /// answered, not found later.
    pub const fn budget(self) -> Budget {
        const PEN: Budget = Budget {
            flash: 192 * 1024,
            static_ram: 64 * 1024,
        };
        match self {
            Board::Blackpill => PEN,
            Board::Qemu => Budget {
                flash: PEN.flash + 10 * 1024,
                static_ram: PEN.static_ram + 1024,
            },
        }
    }
    /// The stack set aside beyond the static RAM (both boards). cortex-m-rt gives the stack all the RAM left, so nothing
    /// overflows at this size; the figure is the deepest stack measured plus a margin: the
    /// firmware paints its stack at reset and reports the high-water mark, and the hil test
    /// `stack` drives the deepest paths we know of under QEMU and fails when the mark passes
    /// this reserve. The deepest path under QEMU is the link task's state machine with the
    /// force-tick interrupt on top (the boards build the force loop in its static); the
    /// reserve leaves a margin over it (docs/figures.md has the measured depth:
    /// `MAOBI_REQUIRE_QEMU=1 cargo test -p hil --test stack -- --nocapture`, and the fuzz
    /// test's). The Black Pill's mark has not been read on a board (its largest frames, from
    /// the disassembly, are of the same sizes). The QEMU image's `bench` mode, a measurement
    /// that never runs on a pen, goes deeper than the reserve: it builds its force loop by
    /// value. It was 16 KiB until the fuzz at the pen's pace, whose tick interrupts land on
    /// the link task at its deepest more often, came within a few hundred bytes of it.
    pub const STACK_RESERVE: u64 = 24 * 1024;
}

/// `firmware/` beside this crate.
pub fn firmware_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("..")
        .join("firmware")
}

/// Where `cargo build --release` in `firmware/` puts the image.
pub fn default_elf() -> PathBuf {
    board_elf(Board::Qemu)
}

/// Where the board's build puts its image.
pub fn board_elf(board: Board) -> PathBuf {
    firmware_dir()
        .join("target")
        .join(TARGET)
        .join(board.profile())
        .join(board.bin())
}

/// Builds the release image (the firmware is its own workspace with its own target dir).
pub fn build() -> Result<PathBuf> {
    build_board(Board::Qemu)
}

/// The QEMU image for the hil tests, built once per test binary; `None` (the test skips, and
/// says so) when `qemu-system-arm` is not installed, unless every test must run (`CI=true`,
/// or `MAOBI_REQUIRE_QEMU` set: [`maobi_testenv::required`]), where a missing QEMU fails the
/// test instead.
pub fn qemu_test_image() -> Option<PathBuf> {
    static ELF: std::sync::OnceLock<Option<PathBuf>> = std::sync::OnceLock::new();
    let elf = ELF
        .get_or_init(|| crate::qemu::available().then(|| build().expect("firmware builds")))
        .clone();
    // Said by every test that cannot run, not only the first of its binary.
    if elf.is_none() {
        maobi_testenv::skip_unless_required(
            &["MAOBI_REQUIRE_QEMU"],
            &format!(
                "{} is not installed (apt-get install qemu-system-arm)",
                crate::qemu::qemu_binary().display()
            ),
        );
    }
    elf
}

/// The Black Pill's image (the pen's), built once per test binary for the tests that read
/// it (its interrupt handlers' reachable panics); `None` where [`qemu_test_image`] is (the
/// same tests need QEMU too). Built when missing, so such a test never passes on an image
/// nobody built.
pub fn blackpill_test_image() -> Option<PathBuf> {
    static ELF: std::sync::OnceLock<Option<PathBuf>> = std::sync::OnceLock::new();
    ELF.get_or_init(|| {
        qemu_test_image()?;
        Some(build_board(Board::Blackpill).expect("the Black Pill's image builds"))
    })
    .clone()
}

/// The QEMU image with the test hooks ([`HOOKS_BIN`]) for the hil tests that inject faults,
/// built once per test binary; `None` as for [`qemu_test_image`]. The pen's images never
/// have them: [`qemu_test_image`] is the image a test uses to show that.
pub fn qemu_test_hooks_image() -> Option<PathBuf> {
    static ELF: std::sync::OnceLock<Option<PathBuf>> = std::sync::OnceLock::new();
    ELF.get_or_init(|| {
        qemu_test_image()?;
        Some(build_test_hooks().expect("the firmware builds with its test hooks"))
    })
    .clone()
}

/// Builds [`HOOKS_BIN`]: the QEMU image's code with the `test-hooks` feature. Only the
/// firmware crate is compiled again (its dependencies' features do not change).
pub fn build_test_hooks() -> Result<PathBuf> {
    cargo_build(HOOKS_BUILD_ARGS)?;
    Ok(firmware_dir()
        .join("target")
        .join(TARGET)
        .join(Board::Qemu.profile())
        .join(HOOKS_BIN))
}

/// Builds `board`'s image.
pub fn build_board(board: Board) -> Result<PathBuf> {
    cargo_build(board.build_args())?;
    Ok(board_elf(board))
}

/// Runs `cargo ARGS` in `firmware/`.
fn cargo_build(args: &[&str]) -> Result<()> {
    let dir = firmware_dir();
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    let status = Command::new(cargo)
        .current_dir(&dir)
        // Not `--locked`: a dependency added to maobi-shared must not break the HIL build.
        .args(args)
        // The firmware's own target dir, whatever the calling cargo uses.
        .env("CARGO_TARGET_DIR", dir.join("target"))
        .env_remove("RUSTFLAGS")
        .env_remove("CARGO_BUILD_TARGET")
        .env_remove("CARGO_ENCODED_RUSTFLAGS")
        .status()
        .context("cannot run cargo to build the firmware")?;
    if !status.success() {
        bail!("building the firmware failed ({status})");
    }
    Ok(())
}

/// The image: `elf` if given, else a fresh build unless `no_build`.
pub fn image(elf: Option<&Path>, no_build: bool) -> Result<PathBuf> {
    board_image(Board::Qemu, elf, no_build)
}

/// `board`'s image: `elf` if given, else a fresh build unless `no_build`.
pub fn board_image(board: Board, elf: Option<&Path>, no_build: bool) -> Result<PathBuf> {
    match elf {
        Some(p) => Ok(p.to_path_buf()),
        None if no_build => Ok(board_elf(board)),
        None => build_board(board),
    }
}

/// The most flash and static RAM an image may take ([`Board::budget`]), in bytes.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub struct Budget {
    pub flash: u64,
    pub static_ram: u64,
}

/// Flash and static RAM of an ARM ELF image, from its section headers.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub struct Size {
    /// Bytes stored in flash: code, constants, the vector table and `.data`'s initial values.
    pub flash: u64,
    /// Bytes of RAM reserved statically: `.data`, `.bss`, `.uninit` (the stack comes on top).
    pub static_ram: u64,
}

impl Size {
    /// What exceeds `budget`, if anything.
    pub fn over_budget(&self, budget: Budget) -> Option<String> {
        let over: Vec<String> = [
            ("flash", self.flash, budget.flash),
            ("static RAM", self.static_ram, budget.static_ram),
        ]
        .into_iter()
        .filter(|&(_, have, budget)| have > budget)
        .map(|(what, have, budget)| {
            format!("{what} {have} bytes is {} over {budget}", have - budget)
        })
        .collect();
        (!over.is_empty()).then(|| over.join("; "))
    }

    /// `hil size --check`: an error naming what exceeds the budget (when `enforce`).
    pub fn check(&self, budget: Budget, enforce: bool) -> Result<()> {
        match self.over_budget(budget) {
            Some(why) if enforce => bail!("over budget: {why}"),
            _ => Ok(()),
        }
    }

    /// The `hil size` report: flash and static RAM against the budgets, and the RAM a chip
    /// needs with the stack reserve ([`Board::STACK_RESERVE`]).
    pub fn report(&self, budget: Budget) -> String {
        let ram = self.static_ram + Board::STACK_RESERVE;
        let kib = |b: u64| b as f64 / 1024.0;
        format!(
            "flash={} bytes ({:.1} KiB, budget {} KiB) static_ram={} bytes ({:.1} KiB, budget {} KiB) ram_with_stack={} bytes ({:.1} KiB: static RAM and a stack reserve of {} bytes)",
            self.flash,
            kib(self.flash),
            kib(budget.flash),
            self.static_ram,
            kib(self.static_ram),
            kib(budget.static_ram),
            ram,
            ram as f64 / 1024.0,
            Board::STACK_RESERVE,
        )
    }
}

/// Reads [`Size`] from an ARM ELF image: allocated sections at addresses below `ram_start`
/// are flash; allocated ones at or above it are RAM, and those with contents (`.data`) count
/// in flash too (their initial values are copied from there).
pub fn size(elf: &Path, ram_start: u64) -> Result<Size> {
    with_elf(elf, |file| Ok(size_of(file, ram_start)))
}

/// Reads and parses the image `elf` for `f`.
fn with_elf<T>(elf: &Path, f: impl FnOnce(&object::File) -> Result<T>) -> Result<T> {
    let bytes = std::fs::read(elf).with_context(|| format!("cannot read {}", elf.display()))?;
    let file = object::File::parse(&*bytes)
        .with_context(|| format!("{} is not an ELF image", elf.display()))?;
    f(&file)
}

/// The section takes memory when the image runs (code, constants, statics).
fn allocated(sec: &object::Section) -> bool {
    use object::{ObjectSection, SectionFlags};
    sec.size() > 0
        && matches!(sec.flags(), SectionFlags::Elf { sh_flags, .. }
            if sh_flags.contains(object::elf::SHF_ALLOC))
}

fn size_of(file: &object::File, ram_start: u64) -> Size {
    use object::{Object, ObjectSection, SectionKind};
    let mut s = Size {
        flash: 0,
        static_ram: 0,
    };
    for sec in file.sections().filter(allocated) {
        let size = sec.size();
        // `.bss` and `.uninit` take RAM but have nothing to store.
        let stored = !matches!(
            sec.kind(),
            SectionKind::UninitializedData | SectionKind::UninitializedTls
        );
        if sec.address() >= ram_start {
            s.static_ram += size;
        }
        if stored {
            s.flash += size;
        }
    }
    s
}

/// Where the image's stack lies: `(bottom, top)`, from cortex-m-rt's `_stack_end` and
/// `_stack_start` as the linker (flip-link) set them.
pub fn stack_bounds(elf: &Path) -> Result<(u64, u64)> {
    with_elf(elf, |file| stack_bounds_of(file, elf))
}

fn stack_bounds_of(file: &object::File, elf: &Path) -> Result<(u64, u64)> {
    use object::{Object, ObjectSymbol};
    let addr = |name: &str| {
        file.symbols()
            .find(|s| s.name() == Ok(name))
            .map(|s| s.address())
            .with_context(|| format!("{}: no symbol {name}", elf.display()))
    };
    Ok((addr("_stack_end")?, addr("_stack_start")?))
}

/// `hil size --check`'s layout check: the stack grows down to the RAM's start, below every
/// static (flip-link's layout), so an overflow faults at the RAM boundary instead of
/// overwriting statics. Returns the stack's size.
pub fn check_stack_layout(elf: &Path, board: Board) -> Result<u64> {
    use object::{Object, ObjectSection};
    let ((bottom, top), lowest_static) = with_elf(elf, |file| {
        // The lowest static in RAM (`.data`, `.bss`, `.uninit`).
        let lowest = file
            .sections()
            .filter(allocated)
            .map(|sec| sec.address())
            .filter(|&a| a >= board.ram_start())
            .min();
        Ok((stack_bounds_of(file, elf)?, lowest))
    })?;
    let statics_above = lowest_static.is_none_or(|a| a >= top);
    if bottom != board.ram_start() || top < bottom || !statics_above {
        bail!(
            "{}: the stack spans {bottom:#x}..{top:#x} and the statics start at {:#x}: an \
             overflow would run into them silently instead of off the RAM's start {:#x} (is the \
             image linked with flip-link? firmware/.cargo/config.toml)",
            elf.display(),
            lowest_static.unwrap_or(0),
            board.ram_start()
        );
    }
    Ok(top - bottom)
}

/// defmt's levels, lowest first.
const DEFMT_LEVELS: [&str; 5] = ["trace", "debug", "info", "warn", "error"];

/// The level of the defmt record in `elf` whose format string is exactly `text` (`None`:
/// the image does not carry it, as when `DEFMT_LOG` filtered it out at build time).
///
/// defmt keeps each log call's format string out of the image's loaded bytes, as the name of
/// a symbol in its `.defmt` section: JSON with the level as `"tag":"defmt_<level>"` and the
/// string as `"data"`.
pub fn defmt_record_level(elf: &Path, text: &str) -> Result<Option<&'static str>> {
    use object::{Object, ObjectSymbol};
    with_elf(elf, |file| {
        Ok(file
            .symbols()
            .filter_map(|sym| sym.name().ok())
            .find_map(|name| record_level(name, text)))
    })
}

/// The level of a defmt symbol `name` if it is the record of format string `text`.
fn record_level(name: &str, text: &str) -> Option<&'static str> {
    let data = format!("\"data\":{},", json_string(text));
    if !name.starts_with('{') || !name.contains(&data) {
        return None;
    }
    DEFMT_LEVELS
        .into_iter()
        .find(|level| name.contains(&format!("\"tag\":\"defmt_{level}\"")))
}

/// `text` as a JSON string literal (defmt escapes quotes and backslashes in the symbol).
fn json_string(text: &str) -> String {
    let mut out = String::with_capacity(text.len() + 2);
    out.push('"');
    for c in text.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            c => out.push(c),
        }
    }
    out.push('"');
    out
}

/// `hil size --check`'s log check: the board's boot line is in the image at info level or
/// above, so a probe's (or QEMU's) log shows that the firmware came up.
pub fn check_boot_line(elf: &Path, board: Board) -> Result<&'static str> {
    match defmt_record_level(elf, board.boot_line())? {
        Some(level) if !matches!(level, "trace" | "debug") => Ok(level),
        Some(level) => bail!(
            "{}: the boot line `{}` is logged at {level}, below the info level the probe's log \
             shows by default",
            elf.display(),
            board.boot_line()
        ),
        None => bail!(
            "{}: the boot line `{}` is not in the image (was it built with DEFMT_LOG below info? \
             firmware/.cargo/config.toml sets info)",
            elf.display(),
            board.boot_line()
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defmt_records_are_found_by_their_exact_text_and_level() {
        let boot = r#"{"package":"maobi-firmware","tag":"defmt_info","data":"maobi-pen up","disambiguator":"7084599705938531334","crate_name":"maobi_pen"}"#;
        assert_eq!(record_level(boot, "maobi-pen up"), Some("info"));
        // Another string that starts the same is not the boot line.
        assert_eq!(record_level(boot, "maobi-pen"), None);
        let warn = r#"{"package":"p","tag":"defmt_warn","data":"say \"hi\" \\ now","disambiguator":"1","crate_name":"c"}"#;
        assert_eq!(record_level(warn, r#"say "hi" \ now"#), Some("warn"));
        // Not a defmt symbol at all.
        assert_eq!(record_level("maobi-pen up", "maobi-pen up"), None);
    }

    #[test]
    fn the_budget_check_names_what_is_over() {
        let pen = Board::Blackpill.budget();
        assert_eq!(
            pen,
            Budget {
                flash: 196_608,
                static_ram: 65_536
            }
        );
        let at = Size {
            flash: pen.flash,
            static_ram: pen.static_ram,
        };
        assert_eq!(at.over_budget(pen), None);
        assert!(at.check(pen, true).is_ok());
        assert!(
            at.report(pen).contains("budget 192 KiB"),
            "{}",
            at.report(pen)
        );
        assert!(
            at.report(pen).contains("budget 64 KiB"),
            "{}",
            at.report(pen)
        );
        let over = Size {
            flash: pen.flash + 1,
            static_ram: pen.static_ram + 12,
        };
        let why = over.over_budget(pen).unwrap();
        assert!(why.contains("flash 196609 bytes is 1 over 196608"), "{why}");
        assert!(
            why.contains("static RAM 65548 bytes is 12 over 65536"),
            "{why}"
        );
        assert!(
            over.check(pen, false).is_ok(),
            "reported, not enforced, without --check"
        );
        let e = over.check(pen, true).unwrap_err().to_string();
        assert!(e.starts_with("over budget: flash"), "{e}");
        // The virtual pen's image may carry the thesis's step on top, and no more.
        assert!(over.over_budget(Board::Qemu.budget()).is_none());
    }
}
