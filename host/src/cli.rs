//! The `maobi` command line.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use anyhow::{bail, Context};
use clap::{ArgGroup, Args, Parser, Subcommand};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressFinish, ProgressStyle};
use maobi_shared::baxter_lin::brush::BaxterLinBrush;
use maobi_shared::baxter_lin::head::HeadShape;
use maobi_shared::{presets, BrushParams, BrushScalar, Fx, ParamId};

use crate::device::{BrushChoice, ModelKind};
use crate::offline::{simulate, ScalarKind};
use crate::paper::{PaperKind, PaperSpec};
use crate::poses::PoseTrack;
use crate::render::{
    paper_frame, render_baxter_lin_with_progress, render_with_progress, write_png, RenderStats,
};
use crate::strokes::Character;
use crate::trace::{time_decimals, BaxterLinTraceWriter, TraceWriter};

#[derive(Debug, Parser)]
#[command(
    name = "maobi",
    version,
    about = "The Maobi virtual calligraphy brush: the GUI (no subcommand), or simulate recorded handle poses"
)]
#[command(args_conflicts_with_subcommands = true)]
pub struct Cli {
    /// Without a subcommand, opens the GUI with the built-in simulated device.
    #[command(subcommand)]
    pub command: Option<Command>,
    /// The GUI's options, without a subcommand (`maobi --device phantom`).
    #[command(flatten)]
    pub gui: GuiArgs,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Simulate a pose file and write the brush state of every 1 ms tick as CSV.
    Trace(TraceArgs),
    /// Simulate a pose file and render the ink it leaves as a greyscale PNG.
    Render(RenderArgs),
    /// Keyframed stroke files: sample one to poses, or fit poses with one.
    #[command(subcommand)]
    Stroke(StrokeCommand),
    /// Score a written character against the master's, stroke by stroke: order, shape,
    /// position, size, direction, speed and press, each a named figure, and a stated total.
    Score(ScoreArgs),
    /// Open the desktop GUI with the built-in simulated device (the default command).
    Gui(GuiArgs),
    /// Run the simulated brush behind the wire protocol on a TCP port (a stand-in for the
    /// pen: `maobi gui --device tcp:HOST:PORT` connects to it).
    SimDevice(SimDeviceArgs),
    /// Run a Phantom Omni / Geomagic Touch (OpenHaptics' libHD, loaded at run time) behind
    /// the wire protocol on a TCP port: `maobi gui --device tcp:HOST:PORT` connects to it.
    Bridge(BridgeArgs),
    /// The pen itself: `maobi device check` walks through its first power-on.
    #[command(subcommand)]
    Device(DeviceCmd),
}

#[derive(Debug, Subcommand)]
pub enum DeviceCmd {
    /// Bring-up: the handshake and the stored configuration, live sensor readings while you
    /// move each joint, each motor nudged gently (after a confirmation) with its direction
    /// checked, calibration in the inkwell, then a summary. Exits non-zero if a step failed;
    /// a step the device does not offer (`maobi sim-device` and `maobi bridge` stream no
    /// raw sensors and nudge no motor) is skipped, saying why.
    Check(DeviceCheckArgs),
    /// The pen's stored configuration (link lengths, encoders, motors, drive, force limits,
    /// calibration) as a TOML file: start from `template`, edit, `check`, then `set`.
    #[command(subcommand)]
    Config(DeviceConfigCmd),
}

#[derive(Debug, Subcommand)]
pub enum DeviceConfigCmd {
    /// Write the reference pen's configuration, every key commented, to start from.
    Template {
        /// Output file (default: standard output).
        #[arg(short = 'o', long, value_name = "FILE")]
        output: Option<PathBuf>,
    },
    /// Check a configuration file without a pen: syntax, unknown keys, every value's range,
    /// each motor's stall current against the driver's rating.
    Check {
        #[arg(value_name = "FILE")]
        file: PathBuf,
    },
    /// Read the configuration stored in the pen.
    Get {
        #[command(flatten)]
        pen: PenArgs,
        /// Output file (default: standard output).
        #[arg(short = 'o', long, value_name = "FILE")]
        output: Option<PathBuf>,
    },
    /// Check a configuration file, write it to the pen (forces must be off) and read it back.
    /// Without a `[calibration]` table the pen's own calibration is kept.
    Set {
        #[arg(value_name = "FILE")]
        file: PathBuf,
        #[command(flatten)]
        pen: PenArgs,
        /// Drop the pen's calibration (the pen gives no force until it is calibrated again).
        #[arg(long)]
        clear_calibration: bool,
    },
}

/// Which pen, and how long it may take to answer.
#[derive(Debug, Args)]
pub struct PenArgs {
    /// The pen's serial port (default: the first port with Maobi's USB IDs 1209:0001).
    #[arg(long, value_name = "PATH", conflicts_with = "connect")]
    pub port: Option<String>,
    /// A device on TCP instead (the QEMU board's UART, `maobi sim-device`).
    #[arg(long, value_name = "HOST:PORT")]
    pub connect: Option<String>,
    /// How long the pen may take to answer (s).
    #[arg(long, value_name = "S", default_value = "3", value_parser = parse_positive)]
    pub timeout: f64,
}

#[derive(Debug, Args)]
pub struct DeviceCheckArgs {
    #[command(flatten)]
    pub pen: PenArgs,
    /// The configuration to write if the pen has none or a corrupt one (a file from `maobi
    /// device config template`; default: the reference pen's).
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Answer yes to every question and wait for no key (scripts, tests).
    #[arg(long)]
    pub yes: bool,
    /// How long the live sensor readings run (Enter ends them sooner).
    #[arg(long, value_name = "S", default_value = "10", value_parser = parse_positive)]
    pub sensor_seconds: f64,
    /// Nudge strength in thousandths of full current (at most 150).
    #[arg(long, value_name = "N", default_value = "80", value_parser = clap::value_parser!(i16).range(1..=150))]
    pub nudge_permille: i16,
    /// Nudge duration (ms, at most 300).
    #[arg(long, value_name = "MS", default_value = "150", value_parser = clap::value_parser!(u16).range(1..=300))]
    pub nudge_ms: u16,
}

#[derive(Debug, Args)]
pub struct BridgeArgs {
    /// Address to listen on.
    #[arg(long, value_name = "HOST:PORT", default_value = "127.0.0.1:7879")]
    pub listen: String,
    #[command(flatten)]
    pub phantom: PhantomArgs,
    #[command(flatten)]
    pub brush: BrushArgs,
    /// Brush state frames per second (1 to 1000).
    #[arg(long, value_name = "HZ", default_value = "120")]
    pub state_hz: u32,
    /// Start with forces off (stylus button 2 or the host's command turns them on).
    #[arg(long)]
    pub no_forces: bool,
    /// Stop after this many 1 ms servo ticks (scripted runs).
    #[arg(long, value_name = "N")]
    pub stop_after_ticks: Option<u32>,
}

/// Where libHD is and how the Phantom's workspace maps to the paper.
#[derive(Debug, Args)]
pub struct PhantomArgs {
    /// OpenHaptics' libHD.so (default: $MAOBI_HD_LIB, then the usual install paths).
    #[arg(long, value_name = "PATH")]
    pub hd_lib: Option<PathBuf>,
    /// Device x,z (mm) above the paper's centre.
    #[arg(long, value_name = "X,Z", default_value = "0,0", value_parser = parse_origin, allow_hyphen_values = true)]
    pub origin: [f64; 2],
    /// Device height (mm) of the ferrule at the paper; both stylus buttons together
    /// recalibrate it (hold the brush tip just touching the paper). The default sits above
    /// the stylus resting in its inkwell.
    #[arg(
        long,
        value_name = "MM",
        default_value_t = crate::phantom::servo::DEFAULT_PAPER_HEIGHT_MM,
        allow_negative_numbers = true,
        value_parser = parse_finite
    )]
    pub paper_height: f64,
    /// Paper millimetres per device millimetre.
    #[arg(long, value_name = "S", default_value = "1", value_parser = parse_positive)]
    pub scale: f64,
}

impl PhantomArgs {
    pub fn mapping(&self) -> crate::phantom::Mapping {
        crate::phantom::Mapping {
            origin_mm: self.origin,
            paper_height_mm: self.paper_height,
            scale: self.scale,
        }
    }
}

fn parse_finite(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        _ => Err(format!("`{s}` is not a finite number")),
    }
}

fn parse_origin(s: &str) -> Result<[f64; 2], String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|p| p.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|_| format!("`{s}` is not X,Z"))?;
    match v[..] {
        [x, z] if x.is_finite() && z.is_finite() => Ok([x, z]),
        _ => Err(format!("`{s}` is not X,Z (two numbers)")),
    }
}

/// `--device` of the GUI: the choices of [`crate::gui::DeviceChoice`], or `phantom`.
#[derive(Clone, Debug, PartialEq)]
pub enum GuiDeviceArg {
    Choice(crate::gui::DeviceChoice),
    Phantom,
}

impl std::str::FromStr for GuiDeviceArg {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        if s == "phantom" {
            Ok(GuiDeviceArg::Phantom)
        } else {
            s.parse().map(GuiDeviceArg::Choice)
        }
    }
}

#[derive(Debug, Args)]
pub struct SimDeviceArgs {
    /// Address to listen on.
    #[arg(long, value_name = "HOST:PORT", default_value = "127.0.0.1:7878")]
    pub listen: String,
    #[command(flatten)]
    pub brush: BrushArgs,
    /// Brush state frames per second (1 to 1000).
    #[arg(long, value_name = "HZ", default_value = "120")]
    pub state_hz: u32,
}

/// `maobi gui --face`.
#[derive(Copy, Clone, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum FaceArg {
    Writing,
    Laboratory,
}

impl From<FaceArg> for crate::gui::writing::Face {
    fn from(f: FaceArg) -> Self {
        match f {
            FaceArg::Writing => crate::gui::writing::Face::Writing,
            FaceArg::Laboratory => crate::gui::writing::Face::Laboratory,
        }
    }
}

#[derive(Debug, Args)]
pub struct GuiArgs {
    /// The device: `sim` (the built-in simulator), `tcp:HOST:PORT` (the QEMU board, `maobi
    /// sim-device`, `maobi bridge`), `serial:PATH` (the pen) or `phantom` (a Phantom Omni /
    /// Geomagic Touch through libHD; falls back to the simulator if it cannot be used);
    /// connects at start. Default: the built-in simulator (the device chooser then holds the
    /// device used last, one click away).
    #[arg(long, value_name = "DEVICE")]
    pub device: Option<GuiDeviceArg>,
    /// With `--device phantom`: OpenHaptics' libHD.so (default: $MAOBI_HD_LIB, then the
    /// usual install paths).
    #[arg(long, value_name = "PATH")]
    pub hd_lib: Option<PathBuf>,
    /// Replay this pose CSV (t,x,y,z,qw,qx,qy,qz) through the simulator at start.
    #[arg(long, value_name = "POSES.csv")]
    pub replay: Option<PathBuf>,
    /// After the replay, save a screenshot of the window here and exit.
    #[arg(long, value_name = "OUT.png")]
    pub screenshot: Option<PathBuf>,
    /// Where "Save picture" (Ctrl+S) writes the paper as a PNG (default: as last used, else
    /// out/maobi-canvas.png).
    #[arg(long, value_name = "OUT.png")]
    pub picture: Option<PathBuf>,
    /// Open the practice panel on this character (the master written by the device's brush).
    /// With `--replay`, the replay is the attempt: it is recorded and scored, and
    /// `--screenshot` waits for the score.
    #[arg(long, value_name = "CHARACTER")]
    pub practice: Option<String>,
    /// The face the app opens with: `writing` (the paper first) or `laboratory` (devices,
    /// parameters, plots, files); F2 switches (default: the one left open last, else
    /// `writing`).
    #[arg(long, value_enum)]
    pub face: Option<FaceArg>,
    /// Open this session (saved with "Save session") at start: its paper re-rendered, the
    /// built-in simulator going on from where it ended.
    #[arg(long, value_name = "SESSION.maobi.toml", conflicts_with = "replay")]
    pub session: Option<PathBuf>,
    /// Brush preset (default: the one used last, else `large`).
    #[arg(
        long,
        value_name = "NAME",
        value_parser = parse_brush,
        help = format!(
            "Brush preset: {}; with --model baxter-lin also flat, filbert, fan (default: the \
             one used last, else `large`)",
            presets::NAMES
        )
    )]
    pub brush: Option<BrushChoice>,
    /// The brush model the built-in simulator (or the Phantom) runs: `liang` (the pen's) or
    /// `baxter-lin` (Baxter & Lin's spines, with the local force model for the hand); the
    /// app's model choice changes it (default: the one used last, else `liang`).
    #[arg(long, value_enum)]
    pub model: Option<ModelKind>,
    /// The paper at start: `sized` (熟宣) or `raw` (生宣); the app's paper choice changes it.
    #[arg(long, value_name = "NAME", value_parser = parse_paper, default_value = "sized")]
    pub paper: PaperKind,
    /// Paper size: a square of this many millimetres centred on the origin (default: as last
    /// used, else 200).
    #[arg(long, value_name = "MM", value_parser = parse_positive)]
    pub paper_mm: Option<f64>,
    /// Paper resolution (default: as last used, else 10; the default paper is 2000 x 2000 px).
    #[arg(long, value_name = "N", value_parser = parse_positive)]
    pub px_per_mm: Option<f64>,
    /// A pen tablet drives the brush: its evdev node (`/dev/input/eventN`, Linux; the app's
    /// "Find tablets" lists them) or a recording made with `evemu-record`, replayed along the
    /// model's clock. Pressure presses the brush, tilt tilts it.
    #[arg(long, value_name = "DEVICE|REC.evemu")]
    pub tablet: Option<PathBuf>,
    /// The tablet's pressure curve: depth = ((p - threshold) / (1 - threshold))^EXP of the
    /// full press (0.2 to 5; above 1 makes light pressure lighter; default: as last set,
    /// else 1).
    #[arg(long, value_name = "EXP")]
    pub pressure_curve: Option<f32>,
    /// Tablet pressure below this fraction presses nothing (0 to 0.5; default: as last set,
    /// else 0.02).
    #[arg(long, value_name = "P")]
    pub pressure_threshold: Option<f32>,
}

fn parse_brush(name: &str) -> Result<BrushChoice, String> {
    BrushChoice::parse(name)
}

/// A brush chosen on the command line: a preset, and parameters set on top of it. Every
/// command that runs a brush of its own takes it (`trace`, `render`, `sim-device`, `bridge`).
#[derive(Debug, Args)]
pub struct BrushArgs {
    /// Brush preset.
    #[arg(
        long,
        value_name = "NAME",
        default_value = "large",
        value_parser = parse_brush,
        help = format!("Brush preset: {}", presets::NAMES)
    )]
    pub brush: BrushChoice,
    /// Set a brush parameter on top of the preset, by the name the app's parameter panel
    /// shows (e.g. `substeps_per_tick=2`); repeatable, applied in order (`--help` lists them).
    #[arg(
        long = "param",
        value_name = "NAME=VALUE",
        value_parser = parse_param_setting,
        long_help = param_long_help()
    )]
    pub params: Vec<ParamSetting>,
}

impl BrushArgs {
    /// [`Self::params`] for Liang's brush (the pen's model): a Baxter & Lin shape is
    /// refused, naming the commands that draw it.
    pub fn liang_params(&self) -> anyhow::Result<BrushParams> {
        if let Some(shape) = self.brush.shape {
            bail!(
                "the {} brush is Baxter & Lin's: `maobi render` and `maobi trace` draw it \
                 with --model baxter-lin",
                shape.name()
            );
        }
        self.params()
    }

    /// [`Self::params`] for Baxter & Lin's brush, which reads only the preset's head profile
    /// (round heads), hair stiffness and ink ([`BaxterLinBrush::preset_params`]): any other
    /// `--param` is refused rather than ignored.
    pub fn baxter_lin_params(&self) -> anyhow::Result<BrushParams> {
        let shape = self.brush.shape.unwrap_or(HeadShape::Round);
        let reads = BaxterLinBrush::preset_params(shape);
        if let Some(s) = self.params.iter().find(|s| !reads.contains(&s.id)) {
            let names: Vec<&str> = reads.iter().map(|id| id.name()).collect();
            bail!(
                "--param {s}: Baxter & Lin's {} brush does not have it (of the parameters it \
                 reads only {})",
                shape.name(),
                names.join(", ")
            );
        }
        self.params()
    }

    /// The preset's parameters with every `--param` set in command-line order, each through
    /// [`BrushParams::set`], the check the app's parameter panel and the devices make.
    pub fn params(&self) -> anyhow::Result<BrushParams> {
        let mut params = self.brush.params;
        for s in &self.params {
            params
                .set(s.id, s.value)
                .with_context(|| format!("--param {s}"))?;
        }
        Ok(params)
    }

    /// The preset's name and the parameters set on top of it, for the summary line.
    pub fn describe(&self) -> String {
        if self.params.is_empty() {
            return self.brush.name.clone();
        }
        let set: Vec<String> = self.params.iter().map(ToString::to_string).collect();
        format!("{} ({})", self.brush.name, set.join(", "))
    }
}

/// One `--param NAME=VALUE`: a known parameter and a number, not yet checked against its
/// range (that needs the brush it is set on).
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct ParamSetting {
    pub id: ParamId,
    pub value: f32,
}

impl std::fmt::Display for ParamSetting {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}={}", self.id, self.value)
    }
}

/// Every parameter's name, in the order of the app's parameter panel.
fn param_names() -> String {
    ParamId::ALL.map(ParamId::name).join(", ")
}

fn parse_param_setting(s: &str) -> Result<ParamSetting, String> {
    let Some((name, value)) = s.split_once('=') else {
        return Err(format!(
            "`{s}` is not NAME=VALUE (e.g. substeps_per_tick=2)"
        ));
    };
    let (name, value) = (name.trim(), value.trim());
    let id = ParamId::from_name(name).ok_or_else(|| {
        format!(
            "unknown brush parameter `{name}`; valid parameters: {}",
            param_names()
        )
    })?;
    if value.is_empty() {
        return Err(format!("{name}: no value after `=`"));
    }
    let value = value
        .parse::<f32>()
        .map_err(|_| format!("{name}: `{value}` is not a number"))?;
    Ok(ParamSetting { id, value })
}

/// `--help` for `--param`: where the names come from, and each one with its range.
fn param_long_help() -> String {
    let width = ParamId::ALL.map(|p| p.name().len()).into_iter().max();
    let mut help = String::from(
        "Set a brush parameter on top of the --brush preset. NAME is the parameter's name as \
         the app's parameter panel and the device protocol spell it; VALUE is a number. \
         Repeatable: the parameters are set in command-line order, each checked as the app \
         checks it, against its range and the brush as it stands so far (to widen both the \
         root and the tip, give the root first).\n\nParameters (valid range):",
    );
    for p in ParamId::ALL {
        let (lo, hi, whole) = p.range();
        let whole = if whole { ", whole number" } else { "" };
        help += &format!(
            "\n  {:w$}  {lo} ..= {hi}{whole}",
            p.name(),
            w = width.unwrap_or(0)
        );
    }
    help
}

fn parse_paper(s: &str) -> Result<PaperKind, String> {
    PaperKind::from_name(s)
}

fn parse_positive(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 => Ok(v),
        _ => Err(format!("`{s}` is not a positive number")),
    }
}

#[derive(Debug, Args)]
#[command(group(ArgGroup::new("input").required(true).args(["poses", "stroke"])))]
pub struct TraceArgs {
    /// Pose CSV with the columns t,x,y,z,qw,qx,qy,qz (s, mm, unit quaternion).
    #[arg(long, value_name = "POSES.csv", conflicts_with = "stroke")]
    pub poses: Option<PathBuf>,
    /// Keyframed stroke file (TOML, see examples/strokes/README.md), sampled every 1 ms.
    #[arg(long, value_name = "STROKE.toml")]
    pub stroke: Option<PathBuf>,
    /// Place the stroke file's depths for a head this long (mm) instead of the file's
    /// `head_mm`: a keyframe's `depth` is then how far a head this long is pressed below
    /// touching (give the brush's own length to write a file meant for another size).
    #[arg(long, value_name = "MM", conflicts_with = "poses", value_parser = parse_positive)]
    pub head_mm: Option<f64>,
    #[command(flatten)]
    pub brush: BrushArgs,
    /// Number type to run the model in (default: fixed, the pen's; Baxter & Lin's model runs
    /// in f64 only, and refuses another).
    #[arg(long, value_enum)]
    pub scalar: Option<ScalarKind>,
    /// The brush model: `liang` (the pen's) or `baxter-lin` (Baxter & Lin's spines; round
    /// heads from the preset's size, and the `flat`, `filbert` and `fan` brushes). Its trace
    /// has every spine's joints instead of Liang's masses (see `host/src/trace.rs`).
    #[arg(long, value_enum, default_value_t = ModelKind::Liang)]
    pub model: ModelKind,
    /// Output trace CSV.
    #[arg(short = 'o', long = "output", value_name = "TRACE.csv")]
    pub output: PathBuf,
}

#[derive(Debug, Args)]
#[command(group(ArgGroup::new("input").required(true).args(["poses", "stroke", "session"])))]
pub struct RenderArgs {
    /// Pose CSV with the columns t,x,y,z,qw,qx,qy,qz (s, mm, unit quaternion).
    #[arg(
        long,
        value_name = "POSES.csv",
        conflicts_with_all = ["stroke", "session"]
    )]
    pub poses: Option<PathBuf>,
    /// A session saved from the app (`.maobi.toml`): re-rendered exactly, on its own paper
    /// (the brush, resolution and scalar options do not apply; `--param` is refused).
    #[arg(
        long,
        value_name = "SESSION.maobi.toml",
        conflicts_with_all = ["stroke", "params"]
    )]
    pub session: Option<PathBuf>,
    /// Keyframed stroke file (TOML, see examples/strokes/README.md), sampled every 1 ms.
    #[arg(long, value_name = "STROKE.toml")]
    pub stroke: Option<PathBuf>,
    /// Place the stroke file's depths for a head this long (mm) instead of the file's
    /// `head_mm`: a keyframe's `depth` is then how far a head this long is pressed below
    /// touching (give the brush's own length to write a file meant for another size).
    #[arg(long, value_name = "MM", conflicts_with_all = ["poses", "session"], value_parser = parse_positive)]
    pub head_mm: Option<f64>,
    #[command(flatten)]
    pub brush: BrushArgs,
    /// Image resolution.
    #[arg(
        long,
        value_name = "N",
        default_value = "10",
        value_parser = parse_positive,
        allow_negative_numbers = true
    )]
    pub px_per_mm: f64,
    /// Number type to run the model in (default: fixed, as the device runs it; Baxter & Lin's
    /// model runs in f64 only, and refuses another).
    #[arg(long, value_enum)]
    pub scalar: Option<ScalarKind>,
    /// The brush model: `liang` (the pen's) or `baxter-lin` (Baxter & Lin's spines; round
    /// heads from the preset's size, and the `flat`, `filbert` and `fan` brushes).
    #[arg(long, value_enum, default_value_t = ModelKind::Liang, conflicts_with = "session")]
    pub model: ModelKind,
    /// The paper: `sized` (熟宣, the ink stays where the brush laid it) or `raw` (生宣, the ink
    /// wicks outward along the fibres). Default: the stroke file's `paper`, else `sized`, since
    /// sized paper shows the brush's own deposit, which is what a render is mostly for
    /// (judging the brush model), and it is the faster; raw paper adds the paper's spread.
    #[arg(long, value_name = "NAME", value_parser = parse_paper, conflicts_with = "session")]
    pub paper: Option<PaperKind>,
    /// Output PNG.
    #[arg(short = 'o', long = "output", value_name = "OUT.png")]
    pub output: PathBuf,
}

/// Diagnostics go through `log`, at the level RUST_LOG asks for (`RUST_LOG=debug`, or per
/// module, `RUST_LOG=maobi::device=trace`); without it, warnings and errors only. Results and
/// progress lines are the commands' output, not diagnostics, and are printed whatever the level.
pub fn init_logging() {
    let env = env_logger::Env::default().default_filter_or("warn");
    // A second call (tests calling `main` twice) keeps the first logger.
    let _ = env_logger::Builder::from_env(env).try_init();
}

/// Parses the command line, runs the command, prints errors; the process's exit code.
pub fn main() -> ExitCode {
    init_logging();
    let cli = Cli::parse();
    log::debug!("{cli:?}");
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("maobi: error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

pub fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Some(Command::Trace(a)) => run_trace(&a),
        Some(Command::Render(a)) => run_render(&a),
        Some(Command::Stroke(c)) => run_stroke(&c),
        Some(Command::Score(a)) => run_score(&a),
        Some(Command::SimDevice(a)) => {
            let server = crate::device::SimDeviceServer::spawn(
                &a.listen,
                crate::device::SimDeviceOptions {
                    brush: a.brush.liang_params()?,
                    state_hz: a.state_hz,
                    ..Default::default()
                },
            )?;
            eprintln!(
                "maobi sim-device: the {} brush on {} ({} states/s); connect with `maobi gui --device tcp:{}`",
                a.brush.describe(),
                server.addr(),
                a.state_hz,
                server.addr()
            );
            server.wait();
            Ok(())
        }
        Some(Command::Bridge(a)) => run_bridge(&a),
        Some(Command::Device(DeviceCmd::Check(a))) => run_device_check(&a),
        Some(Command::Device(DeviceCmd::Config(c))) => run_device_config(&c),
        Some(Command::Gui(a)) => crate::gui::run(gui_options(a)),
        None => crate::gui::run(gui_options(cli.gui)),
    }
}

fn gui_options(a: GuiArgs) -> crate::gui::GuiOptions {
    let defaults = crate::gui::GuiOptions::default();
    let (device, phantom) = match a.device.clone() {
        None => (crate::gui::DeviceChoice::Sim, None),
        Some(GuiDeviceArg::Choice(c)) => (c, None),
        Some(GuiDeviceArg::Phantom) => (
            crate::gui::DeviceChoice::Sim,
            Some(crate::gui::PhantomChoice { hd_lib: a.hd_lib }),
        ),
    };
    let curve = match (a.pressure_curve, a.pressure_threshold) {
        (None, None) => None,
        (e, t) => Some((
            e.unwrap_or(defaults.pressure_curve.0),
            t.unwrap_or(defaults.pressure_curve.1),
        )),
    };
    crate::gui::GuiOptions {
        device,
        phantom,
        brush: a
            .brush
            .as_ref()
            .map_or(defaults.brush.clone(), |b| b.name.clone()),
        model: a.model.unwrap_or(defaults.model),
        paper_kind: a.paper,
        replay: a.replay,
        screenshot: a.screenshot,
        session: a.session,
        picture: a.picture,
        face: a.face.map(Into::into),
        practice: a.practice,
        paper_mm: a.paper_mm.unwrap_or(defaults.paper_mm),
        px_per_mm: a.px_per_mm.unwrap_or(defaults.px_per_mm),
        tablet: a.tablet,
        pressure_curve: curve.unwrap_or(defaults.pressure_curve),
        given: crate::gui::Given {
            device: a.device.is_some(),
            brush: a.brush.is_some() || a.model.is_some(),
            tablet: curve.is_some(),
            paper: a.paper_mm.is_some() || a.px_per_mm.is_some(),
        },
    }
}

/// Set by SIGINT / SIGTERM while `maobi bridge` runs.
static SIGNALLED: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

extern "C" fn on_signal(_: libc::c_int) {
    // Only an atomic store: async-signal-safe.
    SIGNALLED.store(true, std::sync::atomic::Ordering::Relaxed);
}

/// Routes SIGINT and SIGTERM to [`SIGNALLED`], so Ctrl-C stops the servo loop through its
/// own shutdown (the last frame commands zero, the device is released) rather than ending
/// the process in the middle of a frame.
fn stop_on_signals() -> &'static std::sync::atomic::AtomicBool {
    let handler: extern "C" fn(libc::c_int) = on_signal;
    // SAFETY: the handler only stores to an atomic.
    unsafe {
        libc::signal(libc::SIGINT, handler as libc::sighandler_t);
        libc::signal(libc::SIGTERM, handler as libc::sighandler_t);
    }
    &SIGNALLED
}

/// `maobi bridge`: libHD, the servo loop, the wire protocol on TCP, until the servo loop
/// stops (an HD error, `--stop-after-ticks`) or the process is ended.
fn run_bridge(a: &BridgeArgs) -> anyhow::Result<()> {
    use crate::phantom::device::BridgeModel;
    use crate::phantom::{Bridge, BridgeOptions, HdLib, Stopped};
    let brush = a.brush.liang_params()?;
    let lib = HdLib::find(a.phantom.hd_lib.as_deref())?;
    eprintln!(
        "maobi bridge: loaded {} (from {})",
        lib.path().display(),
        lib.source()
    );
    // The wire protocol's states carry Liang's brush, the pen's: the bridge over TCP runs it.
    let opts = BridgeOptions {
        brush,
        model: crate::phantom::ServoBrush::Liang,
        mapping: a.phantom.mapping(),
        state_hz: a.state_hz,
        forces_on: !a.no_forces,
        stop_after_ticks: a.stop_after_ticks,
        panic_at_tick: None,
    };
    let bridge = Bridge::start(lib.clone(), &opts)?;
    let limits = bridge.limits();
    let model = BridgeModel::new(bridge);
    let shared = model.shared();
    let mut server = crate::device::SimDeviceServer::spawn_model(
        &a.listen,
        Box::new(model),
        crate::device::SimDeviceOptions {
            brush,
            state_hz: a.state_hz,
            board: "maobi-phantom-bridge".into(),
        },
    )?;
    eprintln!(
        "maobi bridge: the {} brush, device limits {} N peak / {} N continuous, forces {}; \
         listening on {}; connect with `maobi gui --device tcp:{}`",
        a.brush.describe(),
        limits.peak_n,
        limits.continuous_n,
        if a.no_forces {
            "off"
        } else {
            "on once the brush is lifted clear above the paper"
        },
        server.addr(),
        server.addr()
    );
    let signalled = stop_on_signals();
    // What the user should know (the inkwell, forces waiting, device warnings), each time it
    // changes.
    let mut said: Vec<String> = Vec::new();
    let mut warnings_seen = 0;
    // A device that raises a warning every tick is reported once a second, not each time.
    let mut warned_at: Option<std::time::Instant> = None;
    while !shared.done() && !signalled.load(std::sync::atomic::Ordering::Relaxed) {
        let (warnings, last) = shared.warnings();
        let quiet = warned_at.is_some_and(|t| t.elapsed() < std::time::Duration::from_secs(1));
        if warnings != warnings_seen && !quiet {
            warnings_seen = warnings;
            warned_at = Some(std::time::Instant::now());
            if let Some((e, tick)) = last {
                eprintln!(
                    "maobi bridge: device warning {} at servo tick {tick} ({warnings} so far): \
                     forces off and the brush at rest; clear the fault (the host's ClearFaults, \
                     or stylus button 2) to go on",
                    crate::phantom::hd::error_name(e.error_code)
                );
            }
        }
        let notices = shared.notices(maobi_shared::protocol::Faults::empty());
        for n in notices.iter().filter(|n| !said.contains(n)) {
            eprintln!("maobi bridge: {n}");
        }
        said = notices;
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
    if signalled.load(std::sync::atomic::Ordering::Relaxed) {
        eprintln!("maobi bridge: interrupted; stopping the servo loop (forces to zero)");
    }
    let stopped = shared.stopped(&lib);
    // Dropping the model (with the server) stops the scheduler and releases the device.
    server.stop();
    let (mean, max) = shared.callback_cost_us();
    let (produced, skipped) = shared.state_counts();
    eprintln!(
        "maobi bridge: {} servo ticks, callback {mean:.1} us mean / {max:.1} us max, \
         {produced} states produced ({skipped} of them dropped: no host connected yet, or one too slow)",
        shared.ticks()
    );
    match stopped {
        Some(Stopped::TickLimit(n)) => {
            eprintln!("maobi bridge: stopped after {n} servo ticks as asked");
            Ok(())
        }
        Some(s) => anyhow::bail!("{s}"),
        None => Ok(()),
    }
}

/// `maobi device check`: the bring-up wizard on the terminal (or scripted with `--yes`).
/// The pen `--port` / `--connect` name, or the first serial port with Maobi's USB IDs.
fn pen_endpoint(a: &PenArgs) -> anyhow::Result<crate::device::Endpoint> {
    use crate::device::Endpoint;
    Ok(match (&a.connect, &a.port) {
        (Some(addr), _) => format!("tcp:{addr}")
            .parse::<Endpoint>()
            .map_err(|e| anyhow::anyhow!(e))?,
        (None, Some(p)) => Endpoint::Serial(p.clone()),
        (None, None) => {
            let ports = crate::device::serial_ports();
            match ports.iter().find(|p| p.is_maobi()) {
                Some(p) => Endpoint::Serial(p.name.clone()),
                None => {
                    anyhow::bail!(
                    "no serial port with Maobi's USB IDs (1209:0001); ports here: {}. Give one \
                     with --port PATH",
                    if ports.is_empty() {
                        "none".to_string()
                    } else {
                        ports.iter().map(|p| p.label()).collect::<Vec<_>>().join(", ")
                    }
                )
                }
            }
        }
    })
}

fn run_device_check(a: &DeviceCheckArgs) -> anyhow::Result<()> {
    use crate::device::bringup::{run_check, CheckOptions, Operator, Scripted, Terminal};
    let endpoint = pen_endpoint(&a.pen)?;
    let mut opts = CheckOptions::new(endpoint.clone());
    opts.sensor_time = std::time::Duration::from_secs_f64(a.sensor_seconds);
    opts.reply_timeout = std::time::Duration::from_secs_f64(a.pen.timeout);
    opts.nudge_permille = a.nudge_permille;
    if let Some(path) = &a.config {
        opts.first_config = crate::device::config_file::load(path)?;
    }
    opts.nudge_ms = a.nudge_ms;
    let mut scripted = Scripted {
        echo: true,
        ..Default::default()
    };
    let mut terminal;
    let op: &mut dyn Operator = if a.yes {
        &mut scripted
    } else {
        terminal = Terminal::new();
        &mut terminal
    };
    op.say(&format!("maobi device check: {endpoint}"));
    let report = run_check(&opts, op);
    op.say("");
    op.say(&report.table());
    let skipped = report
        .steps
        .iter()
        .filter(|s| s.outcome == crate::device::bringup::Outcome::Skip)
        .count();
    if report.passed() && skipped == 0 {
        op.say("All steps passed: the pen is ready for forces (`maobi gui --device ...`).");
        Ok(())
    } else if report.passed() {
        op.say(&format!(
            "No step failed; {skipped} skipped (see the table: declined, or not offered by \
             this device)."
        ));
        Ok(())
    } else {
        anyhow::bail!("some bring-up steps failed (see the table above)")
    }
}

/// `maobi device config ...`.
fn run_device_config(c: &DeviceConfigCmd) -> anyhow::Result<()> {
    use crate::device::bringup::Wire;
    use crate::device::config_file::{
        changes, load, read_from_pen, stall_currents, to_toml, warnings, write_to_pen, Written,
    };
    use maobi_shared::pen_io::DeviceConfig;

    let write_out = |text: &str, output: &Option<PathBuf>| -> anyhow::Result<()> {
        match output {
            Some(path) => {
                std::fs::write(path, text)
                    .with_context(|| format!("cannot write {}", path.display()))?;
                eprintln!("wrote {}", path.display());
            }
            None => write_stdout(text)?,
        }
        Ok(())
    };
    let connect = |pen: &PenArgs| -> anyhow::Result<(Wire, std::time::Duration)> {
        let endpoint = pen_endpoint(pen)?;
        let timeout = std::time::Duration::from_secs_f64(pen.timeout);
        let wire = Wire::connect(&endpoint, timeout).map_err(|e| anyhow::anyhow!(e))?;
        eprintln!(
            "{endpoint}: board {}, firmware {}, stored configuration {}, tick limits {}",
            wire.info.board, wire.info.firmware, wire.info.config, wire.info.limits
        );
        Ok((wire, timeout))
    };
    match c {
        DeviceConfigCmd::Template { output } => write_out(
            &to_toml(
                &DeviceConfig::DEFAULT,
                "The reference pen (maobi device config template): measure your own build and\n\
                 change what differs; `maobi device check` finds the motor signs.",
            ),
            output,
        ),
        DeviceConfigCmd::Check { file } => {
            let cfg = load(file)?;
            let diff = changes(&DeviceConfig::DEFAULT, &cfg);
            println!(
                "{}: a valid configuration, {}; {} value(s) differ from the reference pen{}",
                file.display(),
                if cfg.calibration.is_some() {
                    "with a calibration"
                } else {
                    "without a calibration (the pen's own is kept by `set`)"
                },
                diff.len(),
                if diff.is_empty() { "" } else { ":" }
            );
            for line in diff {
                println!("  {line}");
            }
            println!("{}", stall_currents(&cfg));
            for w in warnings(&cfg) {
                println!("warning: {w}");
            }
            Ok(())
        }
        DeviceConfigCmd::Get { pen, output } => {
            let (mut wire, timeout) = connect(pen)?;
            let cfg = read_from_pen(&mut wire, timeout)?;
            let mut title = format!(
                "Read from the pen ({}, firmware {}) by `maobi device config get`.",
                wire.info.board, wire.info.firmware
            );
            if let maobi_shared::pen_io::ConfigState::Migrated { from } = wire.info.config {
                title.push_str(&migrated_title(from));
            }
            write_out(&to_toml(&cfg, &title), output)
        }
        DeviceConfigCmd::Set {
            file,
            pen,
            clear_calibration,
        } => {
            let cfg = load(file)?;
            let (mut wire, timeout) = connect(pen)?;
            let Written { before, stored } =
                write_to_pen(&mut wire, cfg, *clear_calibration, timeout)?;
            match before.map(|o| changes(&o, &stored)) {
                Some(d) if d.is_empty() => {
                    println!("stored; the pen already had this configuration")
                }
                Some(d) => {
                    println!("stored and read back; {} value(s) changed:", d.len());
                    for line in d {
                        println!("  {line}");
                    }
                }
                None => println!("stored and read back (the pen had no valid configuration)"),
            }
            if stored.calibration.is_none() {
                println!(
                    "not calibrated: the pen gives no force until it is (`maobi device check`, \
                     step 4, with the pen in its inkwell)"
                );
            }
            Ok(())
        }
    }
}

/// What `maobi device config get` adds to the title of a configuration migrated from an
/// older format.
fn migrated_title(from: u16) -> String {
    format!(
        "\nMigrated from configuration format {from}, which lacks what bounds the motor \
         current:\nset drive.winding_mohm (each motor), power.supply_v and \
         power.driver_current_a (0 below: not given),\nkeep each drive.max_duty within \
         the driver's rating (`maobi device config check` says), then\n`maobi device \
         config set` this file to enable force."
    )
}

/// Writes `text` to standard output. A reader that has closed its end (`| head`) wanted no
/// more, which is no error; any other failure (a full disk) is one, not a panic as `print!`
/// would make it.
fn write_stdout(text: &str) -> anyhow::Result<()> {
    use std::io::Write as _;
    let mut out = std::io::stdout().lock();
    match out.write_all(text.as_bytes()).and_then(|()| out.flush()) {
        Err(e) if e.kind() != std::io::ErrorKind::BrokenPipe => {
            Err(anyhow::anyhow!("cannot write to standard output: {e}"))
        }
        _ => Ok(()),
    }
}

/// A progress bar on stderr for `total` ticks of long work (`what`: "rendering f.csv"), with
/// the ticks done and an ETA; hidden (drawing nothing at all) when stderr is not a terminal,
/// so a log file or a pipe gets only the command's summary line.
fn tick_bar(total: usize, what: String) -> ProgressBar {
    use std::io::IsTerminal as _;
    if !std::io::stderr().is_terminal() {
        return ProgressBar::hidden();
    }
    // Cleared when dropped too: an error's message then starts a clean line.
    let bar = ProgressBar::with_draw_target(Some(total as u64), ProgressDrawTarget::stderr())
        .with_finish(ProgressFinish::AndClear);
    // The template is a constant: were it ever wrong, a plain bar still shows progress.
    let style = ProgressStyle::with_template(
        "{msg} {wide_bar} {human_pos}/{human_len} ticks, {elapsed} gone, ETA {eta}",
    )
    .unwrap_or_else(|_| ProgressStyle::default_bar());
    bar.set_style(style);
    bar.set_message(what);
    bar
}

/// `maobi render --session`: the session's own paper, re-rendered through the model.
fn render_session(path: &Path, out: &Path, started: Instant) -> anyhow::Result<()> {
    let session = crate::gui::session::Session::load(path)?;
    let ticks = session.journal.ticks;
    let bar = tick_bar(
        ticks as usize,
        format!("maobi render: re-rendering {}", path.display()),
    );
    let r = crate::gui::rerender::rerender(&session, |f| {
        bar.set_position((f * ticks as f64).round() as u64)
    });
    bar.finish_and_clear();
    let r = r?;
    if let Some(note) = &r.model_note {
        eprintln!("maobi render: warning: {}: {note}", path.display());
    }
    write_png(r.paper.canvas(), out)?;
    let c = r.paper.canvas();
    eprintln!(
        "maobi render: {} ticks ({:.1} s) of the {} session, {} strokes, {} x {} px, ink {:.2}%, wrote {} in {:.2} s",
        session.journal.ticks,
        session.journal.ticks as f64 * 1e-3,
        session.journal.preset,
        r.paper.strokes(),
        c.width(),
        c.height(),
        c.ink_fraction() * 100.0,
        out.display(),
        started.elapsed().as_secs_f64()
    );
    Ok(())
}

/// Baxter & Lin's model runs in `f64` only: another `--scalar` is refused, not ignored.
fn baxter_lin_scalar(scalar: Option<ScalarKind>) -> anyhow::Result<()> {
    match scalar {
        None | Some(ScalarKind::F64) => Ok(()),
        Some(other) => bail!(
            "--scalar {other}: Baxter & Lin's model runs in f64 only (give --scalar f64 or \
             none)"
        ),
    }
}

fn run_trace(a: &TraceArgs) -> anyhow::Result<()> {
    let started = Instant::now();
    let loaded = load_track(a.poses.as_deref(), a.stroke.as_deref(), a.head_mm)?;
    refuse_overwriting(&a.output, &[a.poses.as_deref(), a.stroke.as_deref()])?;
    let track = &loaded.track;
    let (ticks, scalar) = match a.model {
        ModelKind::Liang => {
            let params = a.brush.liang_params()?;
            let desc = a.brush.describe();
            warn_if_never_touches("trace", &loaded, &a.brush, a.model, &params);
            let scalar = a.scalar.unwrap_or(ScalarKind::Fixed);
            let ticks = match scalar {
                ScalarKind::Fixed => trace_as::<Fx>(params, track, &desc, &a.output)?,
                ScalarKind::F32 => trace_as::<f32>(params, track, &desc, &a.output)?,
                ScalarKind::F64 => trace_as::<f64>(params, track, &desc, &a.output)?,
            };
            (ticks, scalar)
        }
        ModelKind::BaxterLin => {
            baxter_lin_scalar(a.scalar)?;
            let params = a.brush.baxter_lin_params()?;
            let shape = a.brush.brush.shape.unwrap_or(HeadShape::Round);
            warn_if_never_touches("trace", &loaded, &a.brush, a.model, &params);
            let ticks = trace_baxter_lin(shape, &params, track, &a.output)?;
            (ticks, ScalarKind::F64)
        }
    };
    eprintln!(
        "maobi trace: {ticks} ticks ({:.3} s) of the {} brush in {}, wrote {} in {:.2} s",
        (ticks - 1) as f64 * crate::poses::TICK_S,
        a.brush.describe(),
        scalar,
        a.output.display(),
        started.elapsed().as_secs_f64()
    );
    Ok(())
}

/// Baxter & Lin's brush of `shape` over `loaded`'s track: the rest state at the first pose,
/// then one row a tick. Returns the ticks written.
fn trace_baxter_lin(
    shape: HeadShape,
    params: &BrushParams,
    track: &PoseTrack,
    out: &Path,
) -> anyhow::Result<usize> {
    let mut poses = track.resample();
    let first = poses.next().context("the pose track is empty")?;
    let mut brush = BaxterLinBrush::of_shape(shape, params, first)
        .map_err(|e| anyhow::anyhow!("Baxter & Lin's spine: {e}"))?;
    let file = trace_output(out)?;
    let write_err = || format!("cannot write {}", out.display());
    let t0 = track.start();
    let mut w =
        BaxterLinTraceWriter::new(file, &brush, time_decimals(t0)).with_context(write_err)?;
    w.write_tick(t0, &first, &brush).with_context(write_err)?;
    let bar = tick_bar(track.ticks(), format!("maobi trace: {}", out.display()));
    let mut ticks = 1;
    bar.set_position(ticks);
    for pose in poses {
        brush.tick(&pose);
        let t = t0 + ticks as f64 * crate::poses::TICK_S;
        w.write_tick(t, &pose, &brush).with_context(write_err)?;
        ticks += 1;
        bar.set_position(ticks);
    }
    bar.finish_and_clear();
    w.finish().with_context(write_err)?;
    Ok(ticks as usize)
}

/// Where a trace goes: the file `out`, or standard output for `-`.
fn trace_output(out: &Path) -> anyhow::Result<Box<dyn std::io::Write>> {
    if out.as_os_str() == "-" {
        return Ok(Box::new(std::io::BufWriter::new(std::io::stdout().lock())));
    }
    let file =
        std::fs::File::create(out).with_context(|| format!("cannot create {}", out.display()))?;
    Ok(Box::new(std::io::BufWriter::new(file)))
}

/// Refuses an output that is one of the inputs: `-o` naming the recording would replace it.
fn refuse_overwriting(out: &Path, inputs: &[Option<&Path>]) -> anyhow::Result<()> {
    let Ok(out_real) = std::fs::canonicalize(out) else {
        return Ok(()); // not there yet: nothing to overwrite
    };
    for input in inputs.iter().flatten() {
        if std::fs::canonicalize(input).is_ok_and(|i| i == out_real) {
            anyhow::bail!(
                "the output {} is the input file: give the output another name",
                out.display()
            );
        }
    }
    Ok(())
}

/// Refuses a render's output name that says another image format: the render writes PNG.
fn refuse_non_png(out: &Path) -> anyhow::Result<()> {
    match out.extension().and_then(|e| e.to_str()) {
        Some(e) if e.eq_ignore_ascii_case("png") => Ok(()),
        other => anyhow::bail!(
            "`maobi render` writes PNG: name the output `.png`{}",
            other.map_or(String::new(), |e| format!(", not `.{e}`"))
        ),
    }
}

/// Refuses, before anything runs, a brush the number format `S` cannot step, saying what
/// would run it: the smallest substep rate that does, or another format.
fn check_scalar<S: BrushScalar>(params: &BrushParams, brush: &str) -> anyhow::Result<()> {
    let Err(e) = S::check_params(params) else {
        return Ok(());
    };
    // The parameter's own range bounds the search (`ParamId::range`).
    let most = ParamId::SubstepsPerTick.range().1 as u8;
    let runs = (params.substeps_per_tick..=most).find(|&n| {
        S::check_params(&BrushParams {
            substeps_per_tick: n,
            ..*params
        })
        .is_ok()
    });
    let hint = match runs {
        Some(n) => format!("`--param substeps_per_tick={n}` runs it, or `--scalar f64`"),
        None => "no substep rate runs it in fixed point; `--scalar f64` does".to_string(),
    };
    anyhow::bail!("the {brush} brush: {e}; {hint}")
}

fn trace_as<S: BrushScalar>(
    params: BrushParams,
    track: &PoseTrack,
    brush: &str,
    out: &Path,
) -> anyhow::Result<usize> {
    // A brush the number format cannot run is refused before the file is made.
    check_scalar::<S>(&params, brush)?;
    let file = trace_output(out)?;
    let write_err = || format!("cannot write {}", out.display());
    let mut w = TraceWriter::new(file, params.layers as usize, time_decimals(track.start()))
        .with_context(write_err)?;
    let bar = tick_bar(track.ticks(), format!("maobi trace: {}", out.display()));
    let ticks = simulate::<S>(params, track, |tick| {
        bar.set_position(tick.k as u64 + 1);
        w.write_tick(tick).with_context(write_err)
    });
    bar.finish_and_clear();
    let ticks = ticks?;
    w.finish().with_context(write_err)?;
    Ok(ticks)
}

fn run_render(a: &RenderArgs) -> anyhow::Result<()> {
    let started = Instant::now();
    if let Some(path) = &a.session {
        refuse_overwriting(&a.output, &[Some(path.as_path())])?;
        refuse_non_png(&a.output)?;
        return render_session(path, &a.output, started);
    }
    let params = match a.model {
        ModelKind::Liang => a.brush.liang_params()?,
        ModelKind::BaxterLin => {
            baxter_lin_scalar(a.scalar)?;
            a.brush.baxter_lin_params()?
        }
    };
    let loaded = load_track(a.poses.as_deref(), a.stroke.as_deref(), a.head_mm)?;
    refuse_overwriting(&a.output, &[a.poses.as_deref(), a.stroke.as_deref()])?;
    refuse_non_png(&a.output)?;
    let track = &loaded.track;
    let paper = PaperSpec::new(a.paper.or(loaded.paper).unwrap_or_default());
    log::debug!("the {} brush: {params:?}", a.brush.describe());
    let bar = tick_bar(
        track.ticks(),
        format!("maobi render: {}", a.output.display()),
    );
    // Every tick moves the bar; after the last one the paper dries, which the bar says.
    let progress = |done: usize, total: usize| {
        bar.set_position(done as u64);
        if done == total {
            bar.set_message(format!(
                "maobi render: {}: the paper dries",
                a.output.display()
            ));
        }
    };
    let (canvas, stats, scalar): (_, RenderStats, _) = match (a.model, a.brush.brush.shape) {
        (ModelKind::Liang, _) => {
            warn_if_never_touches("render", &loaded, &a.brush, a.model, &params);
            let frame = paper_frame(track, &params, a.px_per_mm)?;
            log::debug!("paper: {frame:?}, {paper:?}");
            let scalar = a.scalar.unwrap_or(ScalarKind::Fixed);
            let (canvas, stats) = match scalar {
                ScalarKind::Fixed => {
                    check_scalar::<Fx>(&params, &a.brush.describe())?;
                    render_with_progress::<Fx>(params, track, frame, paper, progress)?
                }
                ScalarKind::F32 => {
                    render_with_progress::<f32>(params, track, frame, paper, progress)?
                }
                ScalarKind::F64 => {
                    render_with_progress::<f64>(params, track, frame, paper, progress)?
                }
            };
            (canvas, stats, scalar)
        }
        (ModelKind::BaxterLin, shape) => {
            let shape = shape.unwrap_or(HeadShape::Round);
            let make = |pose| BaxterLinBrush::of_shape(shape, &params, pose);
            let first = track.resample().next().context("the pose track is empty")?;
            let brush = make(first).map_err(|e| anyhow::anyhow!("Baxter & Lin's spine: {e}"))?;
            warn_if_never_touches("render", &loaded, &a.brush, a.model, &params);
            // The paper's margin covers the head however its spines splay.
            let margin = BrushParams {
                length_mm: brush.reach_mm() as f32,
                ..params
            };
            let frame = paper_frame(track, &margin, a.px_per_mm)?;
            let (canvas, stats) =
                render_baxter_lin_with_progress(make, track, frame, paper, progress)?;
            (canvas, stats, ScalarKind::F64)
        }
    };
    bar.finish_and_clear();
    write_png(&canvas, &a.output)?;
    eprintln!(
        "maobi render: {} ticks ({} inking, {:.1} us/tick stamping, {:.1} us/tick paper, {} drying steps) of the {} brush in {} on {} paper, {} x {} px at {} px/mm, ink {:.2}%, wrote {} in {:.2} s",
        stats.ticks,
        stats.stamps,
        stats.stamp_seconds * 1e6 / stats.ticks as f64,
        stats.paper_seconds * 1e6 / stats.ticks as f64,
        stats.drying_steps,
        a.brush.describe(),
        scalar,
        paper.kind,
        stats.width,
        stats.height,
        a.px_per_mm,
        stats.ink_fraction * 100.0,
        a.output.display(),
        started.elapsed().as_secs_f64()
    );
    Ok(())
}

/// A pose track loaded from `--poses FILE` or `--stroke FILE`.
struct LoadedTrack {
    track: PoseTrack,
    /// The paper a stroke file names.
    paper: Option<PaperKind>,
    /// A stroke file's note on where its heights come from ([`Character::placement_note`])
    /// and whether `--head-mm` moves them.
    placement: Option<(String, bool)>,
}

/// The pose track of `--poses FILE` or `--stroke FILE` (clap makes sure there is exactly
/// one), a stroke file's depths placed for `head_mm` if given.
fn load_track(
    poses: Option<&Path>,
    stroke: Option<&Path>,
    head_mm: Option<f64>,
) -> anyhow::Result<LoadedTrack> {
    let loaded = match (poses, stroke) {
        (Some(p), None) => LoadedTrack {
            track: PoseTrack::from_path(p)?,
            paper: None,
            placement: None,
        },
        (None, Some(s)) => {
            let c = Character::from_path_for_head(s, head_mm)?;
            LoadedTrack {
                track: c.track(&s.display().to_string())?,
                paper: c.paper,
                placement: Some((c.placement_note(), c.relative_heights)),
            }
        }
        _ => anyhow::bail!("give exactly one of --poses and --stroke"),
    };
    let track = &loaded.track;
    log::debug!(
        "{}: {} ticks from t = {} s",
        poses
            .or(stroke)
            .map_or(String::new(), |p| p.display().to_string()),
        track.ticks(),
        track.start()
    );
    Ok(loaded)
}

/// Warns (on stderr, as `maobi CMD`) when `brush` cannot reach the paper on `loaded`'s track.
fn warn_if_never_touches(
    cmd: &str,
    loaded: &LoadedTrack,
    brush: &BrushArgs,
    model: ModelKind,
    params: &BrushParams,
) {
    let hair = brush.brush.hair_length_mm(model, params);
    if let Some(w) = never_touches(loaded, hair, &brush.describe()) {
        eprintln!("maobi {cmd}: {w}");
    }
}

/// [`PoseTrack::never_reaches_paper`] for `loaded`, with a stroke file's note and, where its
/// depths are relative, the option that places them for this brush.
fn never_touches(loaded: &LoadedTrack, hair_mm: f64, brush: &str) -> Option<String> {
    let mut msg = loaded.track.never_reaches_paper(hair_mm, brush)?;
    if let Some((note, relative)) = &loaded.placement {
        msg += &format!("; {note}");
        if *relative {
            msg += &format!(": `--head-mm {hair_mm:.1}` places them for this brush");
        }
    }
    Some(format!("warning: {msg}"))
}

#[derive(Debug, Subcommand)]
pub enum StrokeCommand {
    /// Sample a stroke file to a pose CSV (t,x,y,z,qw,qx,qy,qz).
    Sample(StrokeSampleArgs),
    /// Fit a pose CSV with the fewest keyframes within a tolerance; writes a stroke file.
    Fit(StrokeFitArgs),
    /// A character's strokes, in their writing order, as a stroke file for a brush: each along
    /// the median of Make Me a Hanzi's stroke, pressed to the outline's width there.
    FromChar(StrokeFromCharArgs),
}

#[derive(Debug, Args)]
pub struct StrokeFromCharArgs {
    /// The character (its data: $MAOBI_HANZI_DATA, else the installed set, else the shipped
    /// practice set of 101 characters).
    #[arg(value_name = "CHARACTER")]
    pub character: String,
    /// Output stroke file (TOML).
    #[arg(short = 'o', long = "output", value_name = "STROKE.toml")]
    pub output: PathBuf,
    /// The character's size on the paper (mm square).
    #[arg(long, value_name = "MM", default_value = "80", value_parser = parse_positive)]
    pub size_mm: f64,
    /// The brush it is written for (preset: large, small, wolf, goat, mixed).
    #[arg(long, value_name = "PRESET", default_value = "large")]
    pub brush: String,
}

#[derive(Debug, Args)]
pub struct StrokeSampleArgs {
    /// Stroke file (TOML).
    #[arg(value_name = "STROKE.toml")]
    pub file: PathBuf,
    /// Samples per second (default 1000: the model's 1 ms tick).
    #[arg(long, value_name = "HZ", default_value = "1000", value_parser = parse_positive)]
    pub rate: f64,
    /// Output pose CSV.
    #[arg(short = 'o', long = "output", value_name = "POSES.csv")]
    pub output: PathBuf,
}

#[derive(Debug, Args)]
pub struct StrokeFitArgs {
    /// Pose CSV to fit.
    #[arg(value_name = "POSES.csv")]
    pub file: PathBuf,
    /// Largest position error (mm).
    #[arg(long, value_name = "MM", default_value = "0.2", value_parser = parse_positive)]
    pub tol_mm: f64,
    /// Largest orientation error (degrees).
    #[arg(long, value_name = "DEG", default_value = "2", value_parser = parse_positive)]
    pub tol_deg: f64,
    /// Output stroke file (TOML).
    #[arg(short = 'o', long = "output", value_name = "STROKE.toml")]
    pub output: PathBuf,
}

#[derive(Debug, Args)]
#[command(group(ArgGroup::new("written").required(true).args(["session", "poses", "stroke"])))]
pub struct ScoreArgs {
    /// The character written (the master's: Make Me a Hanzi's data, see `stroke from-char`).
    #[arg(long = "char", value_name = "CHARACTER")]
    pub character: String,
    /// The writing: a session saved from the app (its brush is the session's).
    #[arg(long, value_name = "FILE")]
    pub session: Option<PathBuf>,
    /// The writing: a pose recording (t,x,y,z,qw,qx,qy,qz).
    #[arg(long, value_name = "FILE.csv")]
    pub poses: Option<PathBuf>,
    /// The writing: a stroke file.
    #[arg(long, value_name = "FILE.toml")]
    pub stroke: Option<PathBuf>,
    /// The brush that wrote `--poses` or `--stroke` (preset), and the master's.
    #[arg(long, value_name = "PRESET", default_value = "large")]
    pub brush: String,
    /// The master's size on the paper (mm square), centred on the origin.
    #[arg(long, value_name = "MM", default_value = "80", value_parser = parse_positive)]
    pub size_mm: f64,
    /// Print the report as JSON (`total`, and `figures` by name) instead of text.
    #[arg(long)]
    pub json: bool,
    /// Do not append the attempt to the history file.
    #[arg(long)]
    pub no_history: bool,
}

fn run_score(a: &ScoreArgs) -> anyhow::Result<()> {
    let hanzi = crate::hanzi::load(&a.character)?;
    let (track, params, brush, source) = if let Some(path) = &a.session {
        let session = crate::gui::session::Session::load(path)?;
        let j = &session.journal;
        (
            crate::score::journal_track(j)
                .with_context(|| format!("{}: its poses", path.display()))?,
            j.params,
            j.preset.clone(),
            path.display().to_string(),
        )
    } else {
        let params = presets::find(&a.brush).map_err(|e| anyhow::anyhow!("--brush: {e}"))?;
        let loaded = load_track(a.poses.as_deref(), a.stroke.as_deref(), None)?;
        let source = a
            .poses
            .as_ref()
            .or(a.stroke.as_ref())
            .map(|p| p.display().to_string());
        (
            loaded.track,
            params,
            a.brush.clone(),
            source.unwrap_or_default(),
        )
    };
    let master = crate::score::Master::new(hanzi, &brush, params, a.size_mm)?;
    let report = master
        .score(&track)
        .with_context(|| format!("scoring {source}"))?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&report.to_json())?);
    } else {
        print!("{}", report.to_text());
    }
    if !a.no_history {
        let path = crate::score::history_path()?;
        crate::score::append_history(&path, &report, &source)?;
        eprintln!("maobi score: appended to {}", path.display());
    }
    Ok(())
}

fn run_stroke(c: &StrokeCommand) -> anyhow::Result<()> {
    match c {
        StrokeCommand::Sample(a) => {
            let ch = Character::from_path(&a.file)?;
            // The pose file a 1 kHz sampling of the longest stroke file makes, and no more.
            let samples = ch.duration() * a.rate;
            let most = crate::strokes::MAX_SPAN_S * 1000.0;
            if samples > most {
                anyhow::bail!(
                    "{} lasts {:.1} s: at {} Hz that is {samples:.0} poses, more than the {most:.0} \
                     a pose file may hold; lower --rate",
                    a.file.display(),
                    ch.duration(),
                    a.rate
                );
            }
            let csv = ch.to_csv(1.0 / a.rate);
            std::fs::write(&a.output, &csv)
                .with_context(|| format!("cannot write {}", a.output.display()))?;
            eprintln!(
                "maobi stroke sample: {} strokes, {:.3} s, {} poses at {} Hz, wrote {}",
                ch.stroke_times.len(),
                ch.duration(),
                csv.lines().count() - 1,
                a.rate,
                a.output.display()
            );
        }
        StrokeCommand::FromChar(a) => {
            let params = presets::find(&a.brush).map_err(|e| anyhow::anyhow!("--brush: {e}"))?;
            let hanzi = crate::hanzi::load(&a.character)?;
            let curve = crate::hanzi::WidthCurve::measure(&params)?;
            let text = crate::hanzi::stroke_file(&hanzi, &a.brush, &params, a.size_mm, &curve)?;
            // What it wrote must be a stroke file that loads.
            let ch = Character::from_toml(&a.output.display().to_string(), &text)?;
            std::fs::write(&a.output, &text)
                .with_context(|| format!("cannot write {}", a.output.display()))?;
            let (lo, hi) = (curve.points()[0], curve.points()[curve.points().len() - 1]);
            eprintln!(
                "maobi stroke from-char: {} from {}, {} strokes, {} mm square, {:.1} s, {} brush \
                 (width {:.1}-{:.1} mm at depth {:.1}-{:.1} mm), wrote {}",
                hanzi.ch,
                hanzi.source,
                hanzi.strokes().len(),
                a.size_mm,
                ch.duration(),
                a.brush,
                lo.1,
                hi.1,
                lo.0,
                hi.0,
                a.output.display()
            );
        }
        StrokeCommand::Fit(a) => {
            let track = PoseTrack::from_path(&a.file)?;
            let (text, mm, deg) = crate::strokes::fit_track(&track, a.tol_mm, a.tol_deg)
                .with_context(|| format!("cannot fit {}", a.file.display()))?;
            std::fs::write(&a.output, &text)
                .with_context(|| format!("cannot write {}", a.output.display()))?;
            let keys = text.matches("at = ").count();
            eprintln!(
                "maobi stroke fit: {} poses -> {keys} keyframes, largest error {} mm and {} \
                 degrees (tolerance {} mm, {} degrees), wrote {}",
                track.rows().len(),
                crate::strokes::show_error(mm),
                crate::strokes::show_error(deg),
                a.tol_mm,
                a.tol_deg,
                a.output.display()
            );
        }
    }
    Ok(())
}
