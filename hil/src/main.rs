//! `hil`: runs the Maobi pen firmware in the loop: `bench`, `size`, `selftest`, and `run`, a
//! pose file streamed over the wire protocol to the firmware in QEMU (`--backend qemu`) or to
//! a device on a serial port (`--backend serial --port PATH`; built and tested over a
//! pseudo-terminal, not yet run against a real pen), or a board flashed and run with the
//! probe-rs tool (`--backend probe-rs`: the Black Pill's `maobi-pen` image, built here unless
//! `--elf IMAGE` names one; tested against a fake probe-rs, not yet run on a board), every state checked bit for bit.

use std::path::PathBuf;
use std::time::Duration;

use anyhow::Result;
use clap::{Parser, Subcommand};

use hil::{bench, firmware, run, selftest};

#[derive(Parser)]
#[command(
    name = "hil",
    version,
    about = "Maobi firmware in the loop (QEMU mps2-an386)"
)]
struct Cli {
    /// Firmware image to run (default: build firmware/ and use its release image).
    #[arg(long, global = true)]
    elf: Option<PathBuf>,
    /// Do not build the firmware; use the existing release image.
    #[arg(long, global = true)]
    no_build: bool,
    /// Wall-clock limit for each emulator run, seconds.
    #[arg(long, global = true, default_value_t = 300)]
    timeout: u64,
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Instructions per force-loop tick, measured by the firmware under `-icount`, then the
    /// tick's cycle estimate on the Black Pill from a traced run; the last two lines are
    /// `instructions_per_tick=<N>` and `cycles_per_tick_estimate=<N>`.
    Bench {
        /// QEMU `-icount shift`: one timer count is 40 / 2^shift instructions.
        #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u32).range(0..=3))]
        shift: u32,
    },
    /// Flash and static RAM of the firmware image against the budget.
    Size {
        /// Which board's image (`blackpill`: built with `--profile pen`; its line adds the
        /// stack reserve to the RAM).
        #[arg(long, value_enum, default_value_t = firmware::Board::Qemu)]
        board: firmware::Board,
        /// Fail (exit status 1) when the image exceeds the budget (CI keeps both images
        /// within it).
        #[arg(long)]
        check: bool,
    },
    /// Boots the firmware and runs the bench stroke through the real force loop.
    Selftest {
        #[arg(long, default_value_t = 600)]
        ticks: u32,
    },
    /// Streams a pose file (CSV) to the device one pose per tick and checks every state
    /// frame against the host simulation, bit for bit.
    Run {
        /// `qemu`: the firmware in QEMU, UART0 on a loopback socket; `serial`: a device on
        /// a serial port (`--port`); `probe-rs`: the Black Pill's image (built unless `--elf`
        /// names one) flashed onto the board through a debug probe with the probe-rs tool, the checks over the pen's USB serial port,
        /// the defmt log checked (boot line, no panic or fault).
        #[arg(long, value_enum, default_value_t = Backend::Qemu)]
        backend: Backend,
        /// Serial port path (backend `serial`; backend `probe-rs`: default, the first port
        /// with Maobi's USB IDs 1209:0001).
        #[arg(long)]
        port: Option<PathBuf>,
        /// Backend `probe-rs`: the chip, as probe-rs names it.
        #[arg(long, default_value = hil::probe_rs::DEFAULT_CHIP)]
        chip: String,
        /// Backend `probe-rs`: which debug probe (VID:PID[:SERIAL]), passed to probe-rs.
        #[arg(long, value_name = "VID:PID[:SERIAL]")]
        probe: Option<String>,
        /// Backend `probe-rs`: the probe-rs executable (default: $MAOBI_PROBE_RS, else
        /// `probe-rs` on the PATH).
        #[arg(long = "probe-rs", value_name = "PATH")]
        probe_rs: Option<PathBuf>,
        /// Backend `probe-rs`: seconds for the pen's serial port to appear after probe-rs
        /// starts (flashing included).
        #[arg(long, default_value_t = 30)]
        port_timeout: u64,
        /// Backend `probe-rs`: the defmt record that says the firmware booted.
        #[arg(long, default_value = hil::probe_rs::BOOT_LINE)]
        boot_line: String,
        /// State frames per 1000 device ticks (QEMU boot argument; 1000: every tick).
        #[arg(long, default_value_t = 120)]
        state_hz: u32,
        poses: PathBuf,
    },
}

#[derive(Copy, Clone, Debug, PartialEq, Eq, clap::ValueEnum)]
enum Backend {
    Qemu,
    Serial,
    ProbeRs,
}

fn main() -> Result<()> {
    // The host library's diagnostics (`log`) reach stderr at the level RUST_LOG asks for;
    // without it, warnings and errors only. The reports below stay on stdout, unchanged.
    env_logger::Builder::from_env(env_logger::Env::default().default_filter_or("warn")).init();
    let cli = Cli::parse();
    log::debug!(
        "hil {}",
        std::env::args().skip(1).collect::<Vec<_>>().join(" ")
    );
    let timeout = Duration::from_secs(cli.timeout);
    if let Cmd::Run {
        backend: Backend::Serial,
        port,
        poses,
        ..
    } = &cli.cmd
    {
        let Some(port) = port else {
            anyhow::bail!("backend serial needs --port PATH");
        };
        let r = run::run_serial(port, poses)?;
        println!("{}", r.render());
        if !r.passed() {
            anyhow::bail!("some checks failed");
        }
        return Ok(());
    }
    if let Cmd::Run {
        backend: Backend::ProbeRs,
        port,
        chip,
        probe,
        probe_rs,
        port_timeout,
        boot_line,
        poses,
        ..
    } = &cli.cmd
    {
        // Not the default image (that one is built for the QEMU board): the Black Pill's,
        // built here unless --elf names one (or --no-build uses the last build).
        let elf =
            firmware::board_image(firmware::Board::Blackpill, cli.elf.as_deref(), cli.no_build)?;
        let mut opts = hil::probe_rs::ProbeRsOptions::new(probe_rs.clone());
        opts.chip = chip.clone();
        opts.probe = probe.clone();
        opts.port = port.clone();
        opts.port_timeout = Duration::from_secs(*port_timeout);
        opts.boot_line = boot_line.clone();
        let r = hil::probe_rs::run_probe_rs(&elf, poses, &opts)?;
        println!("{}", r.render());
        if !r.passed() {
            anyhow::bail!("some checks failed");
        }
        return Ok(());
    }
    if let Cmd::Size {
        board: board @ firmware::Board::Blackpill,
        check,
    } = cli.cmd
    {
        let elf = firmware::board_image(board, cli.elf.as_deref(), cli.no_build)?;
        return size(&elf, board, check);
    }
    let elf = firmware::image(cli.elf.as_deref(), cli.no_build)?;
    match cli.cmd {
        Cmd::Run {
            poses, state_hz, ..
        } => {
            let r = run::run_qemu(&elf, &poses, state_hz, timeout)?;
            println!("{}", r.render());
            if !r.passed() {
                anyhow::bail!("some checks failed");
            }
        }
        Cmd::Bench { shift } => {
            let r = bench::with_cycles(&elf, shift, timeout)?;
            println!("{}", bench::render(&r));
        }
        Cmd::Size { check, .. } => size(&elf, firmware::Board::Qemu, check)?,
        Cmd::Selftest { ticks } => {
            println!("{}", selftest::selftest(&elf, ticks, timeout)?);
        }
    }
    Ok(())
}

/// `hil size`: flash and static RAM against the budgets, and whether the image carries its
/// boot line at info level; `check` makes either a failure.
fn size(elf: &std::path::Path, board: firmware::Board, check: bool) -> anyhow::Result<()> {
    let s = firmware::size(elf, board.ram_start())?;
    println!("image: {}", elf.display());
    println!("{}", s.report(board.budget()));
    let boot = firmware::check_boot_line(elf, board);
    match &boot {
        Ok(level) => println!("boot_line=\"{}\" level={level}", board.boot_line()),
        Err(e) => println!("boot_line=missing: {e:#}"),
    }
    let layout = firmware::check_stack_layout(elf, board);
    match &layout {
        Ok(bytes) => {
            println!("stack=below_statics bytes={bytes} (an overflow faults at the RAM's start)")
        }
        Err(e) => println!("stack=above_statics: {e:#}"),
    }
    s.check(board.budget(), check)?;
    if check {
        boot?;
        layout?;
    }
    Ok(())
}
