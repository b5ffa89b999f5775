//! A stand-in for OpenHaptics' HD library (`libHD.so`, `hd.dll`): the same symbols the Maobi
//! bridge resolves, over a simulated device, so the bridge's real loading and servo code runs
//! in tests without a Phantom or the proprietary library.
//!
//! It is meant to be as strict as the real library where the bridge could get it wrong:
//! * frames: one `hdBeginFrame` / `hdEndFrame` pair per scheduler tick. A nested
//!   `hdBeginFrame`, or a second one in the same tick, is refused with HD_ILLEGAL_BEGIN (the
//!   real library's "more than once during a single servoloop tick"); `hdEndFrame` without a
//!   frame raises HD_ILLEGAL_END; `hdSetDoublev(HD_CURRENT_FORCE)` outside a frame raises
//!   HD_INVALID_OPERATION. A force reaches the motors only when its frame ends: a refused
//!   frame, or one left open at the end of the tick, commits nothing. Every such misuse is
//!   counted (`maobi_standin_frame_errors`, and `frame_errors` in the summary);
//! * device warnings as the library raises them at `hdEndFrame`: HD_EXCEEDED_MAX_FORCE for a
//!   force above the peak with HD_MAX_FORCE_CLAMPING off (with clamping on the force is
//!   clamped silently, and still counted as a violation), HD_EXCEEDED_MAX_VELOCITY above
//!   `max_velocity` while force output is on; in both cases that frame commits zero;
//! * calibration: `hdCheckCalibration` / `hdUpdateCalibration` over a device that may start
//!   uncalibrated (its positions offset by `cal_offset` until updated), needing the inkwell
//!   first (`calibration=manual`, the stylus enters the inkwell at tick `inkwell_at`) or only
//!   an update (`calibration=update`); HD_CALIBRATION_STYLE reads `cal_style` (inkwell);
//! * setup errors: `fail=CALL:CODE` makes the named setup call (`hdEnable`,
//!   `hdSetSchedulerRate`, `hdScheduleAsynchronous`, `hdStartScheduler`) fail with `CODE`.
//!
//! The simulated device otherwise:
//! * poses from a script (CSV `t,x,y,z,qw,qx,qy,qz[,buttons]`: seconds, device millimetres,
//!   unit quaternion, the HD_CURRENT_BUTTONS mask), held from row to row: scheduler tick `k`
//!   uses the last row with `t <= k ms`;
//! * a scheduler thread at the set rate (1 kHz by default) that runs the scheduled callbacks
//!   each tick, highest priority first (or ticks driven one at a time by
//!   `maobi_standin_tick` when no scheduler runs);
//! * nominal limits of a Phantom Omni: 3.3 N peak (HD_NOMINAL_MAX_FORCE), 0.88 N continuous;
//! * injectable errors: `error=FRAME:CODE` (the key may repeat) puts `CODE` on the error
//!   stack at the start of scheduler tick `FRAME` (as a failed read of the device would);
//! * a record: the force committed at the end of every tick, written at `hdDisableDevice`
//!   with a summary (frames, violations, frame errors, warnings, calibration updates).
//!
//! Configuration: the string `key=value;key=value` from `maobi_standin_configure` or, when
//! that was not called, the environment variable `MAOBI_HD_STANDIN`. Keys: `poses` (file),
//! `record` (CSV file; a summary goes to `FILE.summary`), `error` (`FRAME:CODE`, code in
//! decimal or 0x hex), `fail` (`CALL:CODE`), `max_force`, `max_continuous` (N),
//! `max_velocity` (mm/s, 0 = no limit), `calibration` (`ok`, `update`, `manual`),
//! `cal_offset` (`X,Y,Z` mm), `inkwell_at` (tick), `cal_style` (HD_CALIBRATION_STYLE mask),
//! `slow` (a whole number N >= 1: the scheduler's ticks come N times further apart in wall
//! time than the rate says, which every reading of the rate still reports; a test whose
//! client does work on other threads beside the servo loop gives them N times the room, so
//! it checks the same ticks on a loaded machine).
//!
//! Types follow `HD/hdDefines.h` (see `maobi::phantom::hd` for the values and where they
//! were checked); the functions use the HD API's calling convention (`HDAPIENTRY`,
//! `HDCALLBACK`: `__stdcall` on 32-bit Windows, which `extern "system"` is; the C convention
//! elsewhere). Only what the bridge uses is implemented; other enums raise HD_INVALID_ENUM.

#![allow(clippy::missing_safety_doc)]

use std::ffi::{c_char, c_int, c_uint, c_ulong, c_ushort, c_void, CStr};
use std::io::Write;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

type Hhd = c_uint;
type HdError = c_uint;
type HdEnum = c_uint;
type HdCallbackCode = c_uint;
type HdSchedulerHandle = c_ulong;
type Callback = unsafe extern "system" fn(*mut c_void) -> HdCallbackCode;

#[repr(C)]
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub struct HdErrorInfo {
    pub error_code: HdError,
    pub internal_error_code: c_int,
    pub h_hd: Hhd,
}

const HD_CALLBACK_DONE: HdCallbackCode = 0;
const HD_SUCCESS: HdError = 0;
const HD_INVALID_ENUM: HdError = 0x0100;
const HD_INVALID_VALUE: HdError = 0x0101;
const HD_INVALID_OPERATION: HdError = 0x0102;
const HD_BAD_HANDLE: HdError = 0x0104;
const HD_WARM_MOTORS: HdError = 0x0200;
const HD_EXCEEDED_MAX_FORCE: HdError = 0x0201;
const HD_EXCEEDED_MAX_FORCE_IMPULSE: HdError = 0x0202;
const HD_EXCEEDED_MAX_VELOCITY: HdError = 0x0203;
const HD_DEVICE_ALREADY_INITIATED: HdError = 0x0301;
const HD_COMM_ERROR: HdError = 0x0302;
const HD_COMM_CONFIG_ERROR: HdError = 0x0303;
const HD_TIMER_ERROR: HdError = 0x0304;
const HD_ILLEGAL_BEGIN: HdError = 0x0400;
const HD_ILLEGAL_END: HdError = 0x0401;
const HD_CURRENT_BUTTONS: HdEnum = 0x2000;
const HD_CURRENT_POSITION: HdEnum = 0x2050;
const HD_CURRENT_VELOCITY: HdEnum = 0x2051;
const HD_CURRENT_TRANSFORM: HdEnum = 0x2052;
const HD_CALIBRATION_STYLE: HdEnum = 0x2555;
const HD_NOMINAL_MAX_FORCE: HdEnum = 0x2603;
const HD_NOMINAL_MAX_CONTINUOUS_FORCE: HdEnum = 0x2604;
const HD_CURRENT_FORCE: HdEnum = 0x2700;
const HD_FORCE_OUTPUT: HdEnum = 0x4000;
const HD_MAX_FORCE_CLAMPING: HdEnum = 0x4001;
const HD_CALIBRATION_OK: HdEnum = 0x5000;
const HD_CALIBRATION_NEEDS_UPDATE: HdEnum = 0x5001;
const HD_CALIBRATION_NEEDS_MANUAL_INPUT: HdEnum = 0x5002;
const HD_CALIBRATION_INKWELL: c_int = 1 << 2;
const HD_INVALID_HANDLE: Hhd = 0xFFFF_FFFF;
/// The one device's handle.
const HANDLE: Hhd = 1;

/// One row of the pose script.
#[derive(Copy, Clone, Debug)]
struct Row {
    t: f64,
    pos: [f64; 3],
    q: [f64; 4],
    buttons: c_int,
}

/// The setup calls `fail=` can make fail.
const FAILABLE: &[&str] = &[
    "hdEnable",
    "hdSetSchedulerRate",
    "hdScheduleAsynchronous",
    "hdStartScheduler",
];

#[derive(Clone, Debug)]
struct Config {
    poses: Option<String>,
    record: Option<String>,
    errors: Vec<(u64, HdError)>,
    fail: Option<(String, HdError)>,
    max_force: f64,
    max_continuous: f64,
    max_velocity: f64,
    calibration: HdEnum,
    cal_offset: [f64; 3],
    inkwell_at: Option<u64>,
    cal_style: c_int,
    slow: u32,
}

impl Default for Config {
    fn default() -> Self {
        Config {
            poses: None,
            record: None,
            errors: Vec::new(),
            fail: None,
            max_force: 3.3,
            max_continuous: 0.88,
            max_velocity: 0.0,
            calibration: HD_CALIBRATION_OK,
            cal_offset: [0.0; 3],
            inkwell_at: None,
            cal_style: HD_CALIBRATION_INKWELL,
            slow: 1,
        }
    }
}

fn parse_code(code: &str) -> Result<HdError, String> {
    let code = code.trim();
    match code.strip_prefix("0x") {
        Some(h) => u32::from_str_radix(h, 16),
        None => code.parse::<u32>(),
    }
    .map_err(|_| format!("`{code}` is not an error code"))
}

fn parse_config(s: &str) -> Result<Config, String> {
    let mut c = Config::default();
    for part in s.split(';').map(str::trim).filter(|p| !p.is_empty()) {
        let (k, v) = part
            .split_once('=')
            .ok_or_else(|| format!("`{part}` is not key=value"))?;
        let num = |v: &str| -> Result<f64, String> {
            v.parse::<f64>()
                .ok()
                .filter(|x| x.is_finite() && *x >= 0.0)
                .ok_or_else(|| format!("{k}: `{v}` is not a number >= 0"))
        };
        match k.trim() {
            "poses" => c.poses = Some(v.to_string()),
            "record" => c.record = Some(v.to_string()),
            "max_force" => c.max_force = num(v)?,
            "max_continuous" => c.max_continuous = num(v)?,
            "max_velocity" => c.max_velocity = num(v)?,
            "error" => {
                let (f, code) = v
                    .split_once(':')
                    .ok_or_else(|| format!("error: `{v}` is not FRAME:CODE"))?;
                let frame = f
                    .trim()
                    .parse::<u64>()
                    .map_err(|_| format!("error: `{f}` is not a frame number"))?;
                c.errors.push((frame, parse_code(code)?));
            }
            "fail" => {
                let (call, code) = v
                    .split_once(':')
                    .ok_or_else(|| format!("fail: `{v}` is not CALL:CODE"))?;
                let call = call.trim();
                if !FAILABLE.contains(&call) {
                    return Err(format!("fail: `{call}` is not one of {FAILABLE:?}"));
                }
                c.fail = Some((call.to_string(), parse_code(code)?));
            }
            "calibration" => {
                c.calibration = match v.trim() {
                    "ok" => HD_CALIBRATION_OK,
                    "update" => HD_CALIBRATION_NEEDS_UPDATE,
                    "manual" => HD_CALIBRATION_NEEDS_MANUAL_INPUT,
                    other => return Err(format!("calibration: `{other}` is not ok/update/manual")),
                }
            }
            "cal_offset" => {
                let xs: Vec<f64> = v
                    .split(',')
                    .map(|x| x.trim().parse::<f64>())
                    .collect::<Result<_, _>>()
                    .map_err(|_| format!("cal_offset: `{v}` is not X,Y,Z"))?;
                match xs[..] {
                    [x, y, z] if xs.iter().all(|a| a.is_finite()) => c.cal_offset = [x, y, z],
                    _ => return Err(format!("cal_offset: `{v}` is not X,Y,Z")),
                }
            }
            "inkwell_at" => {
                c.inkwell_at = Some(
                    v.trim()
                        .parse::<u64>()
                        .map_err(|_| format!("inkwell_at: `{v}` is not a tick"))?,
                )
            }
            "cal_style" => {
                c.cal_style = v
                    .trim()
                    .parse::<c_int>()
                    .ok()
                    .filter(|s| (1..=7).contains(s))
                    .ok_or_else(|| format!("cal_style: `{v}` is not a style mask 1..=7"))?
            }
            "slow" => {
                c.slow = v
                    .trim()
                    .parse::<u32>()
                    .ok()
                    .filter(|n| (1..=1000).contains(n))
                    .ok_or_else(|| format!("slow: `{v}` is not a whole number 1..=1000"))?
            }
            other => return Err(format!("unknown key `{other}`")),
        }
    }
    Ok(c)
}

fn read_poses(path: &str) -> Result<Vec<Row>, String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("cannot read {path}: {e}"))?;
    let mut lines = text.lines();
    let header = lines.next().ok_or_else(|| format!("{path} is empty"))?;
    let cols: Vec<&str> = header.split(',').map(str::trim).collect();
    let want = ["t", "x", "y", "z", "qw", "qx", "qy", "qz"];
    if cols.len() < 8 || cols[..8] != want {
        return Err(format!("{path}: the header must start t,x,y,z,qw,qx,qy,qz"));
    }
    let with_buttons = cols.get(8) == Some(&"buttons");
    let mut rows = Vec::new();
    for (i, line) in lines.enumerate() {
        if line.trim().is_empty() {
            continue;
        }
        let v: Vec<f64> = line
            .split(',')
            .map(|f| f.trim().parse::<f64>())
            .collect::<Result<_, _>>()
            .map_err(|_| format!("{path} line {}: not a number", i + 2))?;
        if v.len() < 8 || v[..8].iter().any(|x| !x.is_finite()) {
            return Err(format!("{path} line {}: need 8 finite numbers", i + 2));
        }
        rows.push(Row {
            t: v[0],
            pos: [v[1], v[2], v[3]],
            q: [v[4], v[5], v[6], v[7]],
            buttons: if with_buttons {
                v.get(8).copied().unwrap_or(0.0) as c_int
            } else {
                0
            },
        });
    }
    if rows.is_empty() {
        return Err(format!("{path} has no poses"));
    }
    Ok(rows)
}

/// Column-major transform of a position and unit quaternion (w, x, y, z).
fn transform(pos: [f64; 3], q: [f64; 4]) -> [f64; 16] {
    let [w, x, y, z] = q;
    let r = [
        [
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y - w * z),
            2.0 * (x * z + w * y),
        ],
        [
            2.0 * (x * y + w * z),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z - w * x),
        ],
        [
            2.0 * (x * z - w * y),
            2.0 * (y * z + w * x),
            1.0 - 2.0 * (x * x + y * y),
        ],
    ];
    let mut m = [0.0; 16];
    for j in 0..3 {
        for i in 0..3 {
            m[4 * j + i] = r[i][j];
        }
    }
    m[12] = pos[0];
    m[13] = pos[1];
    m[14] = pos[2];
    m[15] = 1.0;
    m
}

struct Scheduled {
    handle: HdSchedulerHandle,
    callback: Callback,
    data: usize,
    priority: c_ushort,
}

struct Device {
    config: Config,
    rows: Vec<Row>,
    initialized: bool,
    /// Scheduler ticks run.
    frame: u64,
    row: Row,
    last_pos: [f64; 3],
    /// A frame is open (between a successful hdBeginFrame and its hdEndFrame).
    in_frame: bool,
    /// Frames begun in this tick (at most one is allowed).
    frames_this_tick: u32,
    /// The force set in the open frame.
    pending: [f64; 3],
    /// The force the motors hold: what the last ended frame committed.
    force: [f64; 3],
    force_sets: u64,
    errors: Vec<HdErrorInfo>,
    force_output: bool,
    clamping: bool,
    rate_hz: c_ulong,
    scheduled: Vec<Scheduled>,
    next_handle: HdSchedulerHandle,
    record: Vec<[f64; 3]>,
    violations: u64,
    max_norm: f64,
    /// Refused or unmatched frame calls (HD_ILLEGAL_BEGIN, HD_ILLEGAL_END) and frames left
    /// open at the end of a tick.
    frame_errors: u64,
    frames_left_open: u64,
    /// Device warnings raised at hdEndFrame.
    warnings: u64,
    calibration: HdEnum,
    cal_offset: [f64; 3],
    calibrations: u64,
}

impl Device {
    fn new() -> Device {
        let row = Row {
            t: 0.0,
            pos: [0.0; 3],
            q: [1.0, 0.0, 0.0, 0.0],
            buttons: 0,
        };
        Device {
            config: Config::default(),
            rows: Vec::new(),
            initialized: false,
            frame: 0,
            row,
            last_pos: [0.0; 3],
            in_frame: false,
            frames_this_tick: 0,
            pending: [0.0; 3],
            force: [0.0; 3],
            force_sets: 0,
            errors: Vec::new(),
            force_output: false,
            clamping: false,
            rate_hz: 1000,
            scheduled: Vec::new(),
            next_handle: 1,
            record: Vec::new(),
            violations: 0,
            max_norm: 0.0,
            frame_errors: 0,
            frames_left_open: 0,
            warnings: 0,
            calibration: HD_CALIBRATION_OK,
            cal_offset: [0.0; 3],
            calibrations: 0,
        }
    }

    fn push_error(&mut self, code: HdError) {
        self.errors.push(HdErrorInfo {
            error_code: code,
            internal_error_code: code as c_int,
            h_hd: HANDLE,
        });
    }

    /// `true` (and the configured error pushed) if setup call `name` is to fail.
    fn fails(&mut self, name: &str) -> bool {
        match self.config.fail.clone() {
            Some((call, code)) if call == name => {
                self.push_error(code);
                true
            }
            _ => false,
        }
    }

    /// The script's pose for tick `frame` (held between rows).
    fn pose_at(&self, frame: u64) -> Row {
        let t = frame as f64 * 1e-3 + 1e-9;
        let k = self.rows.partition_point(|r| r.t <= t);
        self.rows[k.saturating_sub(1).min(self.rows.len() - 1)]
    }

    /// The position the device reports: the script's, offset while uncalibrated.
    fn reported_pos(&self) -> [f64; 3] {
        let p = self.row.pos;
        let o = self.cal_offset;
        [p[0] + o[0], p[1] + o[1], p[2] + o[2]]
    }

    /// The start of tick `self.frame`: the pose, injected errors, the inkwell.
    fn begin_tick(&mut self) {
        let k = self.frame;
        self.last_pos = self.reported_pos();
        self.row = self.pose_at(k);
        let due: Vec<HdError> = self
            .config
            .errors
            .iter()
            .filter(|(f, _)| *f == k)
            .map(|(_, c)| *c)
            .collect();
        for code in due {
            self.push_error(code);
        }
        if self.config.inkwell_at == Some(k)
            && self.calibration == HD_CALIBRATION_NEEDS_MANUAL_INPUT
        {
            // The stylus went into the inkwell: the library now has what it needs.
            self.calibration = HD_CALIBRATION_NEEDS_UPDATE;
        }
        self.frames_this_tick = 0;
    }

    /// The end of the tick: a frame still open commits nothing; the motors' force recorded.
    fn end_tick(&mut self) {
        if self.in_frame {
            self.in_frame = false;
            self.frames_left_open += 1;
            self.frame_errors += 1;
        }
        let f = if self.force_output {
            self.force
        } else {
            [0.0; 3]
        };
        self.record.push(f);
        self.frame += 1;
    }

    fn write_record(&self) {
        let Some(path) = &self.config.record else {
            return;
        };
        let mut out = String::from("frame,fx,fy,fz\n");
        for (k, f) in self.record.iter().enumerate() {
            // `{}` prints the shortest text that parses back to the same f64.
            out.push_str(&format!("{k},{},{},{}\n", f[0], f[1], f[2]));
        }
        let summary = format!(
            "frames={}\nforce_sets={}\nviolations={}\nmax_force_n={}\nlimit_n={}\n\
             frame_errors={}\nframes_left_open={}\nwarnings={}\ncalibrations={}\n",
            self.record.len(),
            self.force_sets,
            self.violations,
            self.max_norm,
            self.config.max_force,
            self.frame_errors,
            self.frames_left_open,
            self.warnings,
            self.calibrations,
        );
        let write = |p: &str, s: &str| {
            if let Ok(mut f) = std::fs::File::create(p) {
                let _ = f.write_all(s.as_bytes());
            }
        };
        write(path, &out);
        write(&format!("{path}.summary"), &summary);
    }
}

static DEVICE: Mutex<Option<Device>> = Mutex::new(None);
static CONFIG: Mutex<Option<String>> = Mutex::new(None);
static SCHEDULER: Mutex<Option<(Arc<AtomicBool>, JoinHandle<()>)>> = Mutex::new(None);

fn device() -> MutexGuard<'static, Option<Device>> {
    DEVICE.lock().unwrap_or_else(|p| p.into_inner())
}

fn with<R>(f: impl FnOnce(&mut Device) -> R) -> R {
    let mut g = device();
    f(g.get_or_insert_with(Device::new))
}

fn scheduler_running() -> bool {
    SCHEDULER
        .lock()
        .unwrap_or_else(|p| p.into_inner())
        .is_some()
}

/// Sets the configuration used by the next `hdInitDevice` (instead of `$MAOBI_HD_STANDIN`).
/// Returns 0, or -1 if the string does not parse (or is not UTF-8 / NULL).
#[no_mangle]
pub unsafe extern "C" fn maobi_standin_configure(cfg: *const c_char) -> c_int {
    if cfg.is_null() {
        return -1;
    }
    // SAFETY: the caller passes a NUL-terminated string.
    let Ok(s) = unsafe { CStr::from_ptr(cfg) }.to_str() else {
        return -1;
    };
    if parse_config(s).is_err() {
        return -1;
    }
    *CONFIG.lock().unwrap_or_else(|p| p.into_inner()) = Some(s.to_string());
    0
}

/// Forces above the peak limit seen so far.
#[no_mangle]
pub extern "C" fn maobi_standin_violations() -> u64 {
    with(|d| d.violations)
}

/// Scheduler ticks run so far.
#[no_mangle]
pub extern "C" fn maobi_standin_frames() -> u64 {
    with(|d| d.frame)
}

/// Frame misuse so far: refused hdBeginFrame calls (nested, or a second in a tick),
/// hdEndFrame without a frame, frames left open at the end of a tick.
#[no_mangle]
pub extern "C" fn maobi_standin_frame_errors() -> u64 {
    with(|d| d.frame_errors)
}

/// Calibration updates applied so far.
#[no_mangle]
pub extern "C" fn maobi_standin_calibrations() -> u64 {
    with(|d| d.calibrations)
}

/// One servo tick without the scheduler thread (for tests that call the HD functions
/// directly): the tick's start (pose, injected errors), then its end (the force committed
/// and recorded). Does nothing while the scheduler runs; returns the ticks run so far.
#[no_mangle]
pub extern "C" fn maobi_standin_tick() -> u64 {
    if scheduler_running() {
        return with(|d| d.frame);
    }
    with(|d| {
        d.end_tick();
        d.begin_tick();
        d.frame
    })
}

#[no_mangle]
pub unsafe extern "system" fn hdInitDevice(_name: *const c_char) -> Hhd {
    let cfg = CONFIG
        .lock()
        .unwrap_or_else(|p| p.into_inner())
        .clone()
        .or_else(|| std::env::var("MAOBI_HD_STANDIN").ok())
        .unwrap_or_default();
    with(|d| {
        if d.initialized {
            d.push_error(HD_DEVICE_ALREADY_INITIATED);
            return HD_INVALID_HANDLE;
        }
        let loaded = parse_config(&cfg).and_then(|c| {
            let rows = match &c.poses {
                Some(p) => read_poses(p)?,
                None => Vec::new(),
            };
            Ok((c, rows))
        });
        match loaded {
            Ok((c, rows)) => {
                *d = Device::new();
                d.calibration = c.calibration;
                if c.calibration != HD_CALIBRATION_OK {
                    d.cal_offset = c.cal_offset;
                }
                d.config = c;
                if rows.is_empty() {
                    // No script: the stylus rests at the workspace origin.
                    d.rows = vec![d.row];
                } else {
                    d.rows = rows;
                }
                d.row = d.pose_at(0);
                d.last_pos = d.reported_pos();
                d.initialized = true;
                HANDLE
            }
            Err(e) => {
                eprintln!("maobi-hd-standin: {e}");
                d.push_error(HD_COMM_CONFIG_ERROR);
                HD_INVALID_HANDLE
            }
        }
    })
}

#[no_mangle]
pub extern "system" fn hdDisableDevice(hhd: Hhd) {
    with(|d| {
        if hhd != HANDLE || !d.initialized {
            d.push_error(HD_BAD_HANDLE);
            return;
        }
        d.write_record();
        d.initialized = false;
    })
}

#[no_mangle]
pub extern "system" fn hdEnable(cap: HdEnum) {
    with(|d| {
        if d.fails("hdEnable") {
            return;
        }
        match cap {
            HD_FORCE_OUTPUT => d.force_output = true,
            HD_MAX_FORCE_CLAMPING => d.clamping = true,
            _ => d.push_error(HD_INVALID_ENUM),
        }
    })
}

#[no_mangle]
pub extern "system" fn hdDisable(cap: HdEnum) {
    with(|d| match cap {
        HD_FORCE_OUTPUT => {
            d.force_output = false;
            d.force = [0.0; 3];
            d.pending = [0.0; 3];
        }
        HD_MAX_FORCE_CLAMPING => d.clamping = false,
        _ => d.push_error(HD_INVALID_ENUM),
    })
}

#[no_mangle]
pub extern "system" fn hdSetSchedulerRate(rate: c_ulong) {
    with(|d| {
        if d.fails("hdSetSchedulerRate") {
            return;
        }
        if (100..=2000).contains(&rate) {
            d.rate_hz = rate;
        } else {
            d.push_error(HD_INVALID_VALUE);
        }
    })
}

#[no_mangle]
pub extern "system" fn hdScheduleAsynchronous(
    callback: Callback,
    data: *mut c_void,
    priority: c_ushort,
) -> HdSchedulerHandle {
    with(|d| {
        if d.fails("hdScheduleAsynchronous") {
            return 0;
        }
        let handle = d.next_handle;
        d.next_handle += 1;
        d.scheduled.push(Scheduled {
            handle,
            callback,
            data: data as usize,
            priority,
        });
        // Highest priority first, as the real scheduler runs them.
        d.scheduled.sort_by_key(|s| std::cmp::Reverse(s.priority));
        handle
    })
}

#[no_mangle]
pub extern "system" fn hdUnschedule(handle: HdSchedulerHandle) {
    with(|d| {
        let before = d.scheduled.len();
        d.scheduled.retain(|s| s.handle != handle);
        if d.scheduled.len() == before {
            d.push_error(HD_INVALID_OPERATION);
        }
    })
}

#[no_mangle]
pub extern "system" fn hdStartScheduler() {
    let mut sched = SCHEDULER.lock().unwrap_or_else(|p| p.into_inner());
    if sched.is_some() {
        return;
    }
    if with(|d| d.fails("hdStartScheduler")) {
        return;
    }
    let stop = Arc::new(AtomicBool::new(false));
    let s2 = stop.clone();
    match std::thread::Builder::new()
        .name("hd-standin-scheduler".into())
        .spawn(move || scheduler(&s2))
    {
        Ok(t) => *sched = Some((stop, t)),
        Err(_) => with(|d| d.push_error(HD_TIMER_ERROR)),
    }
}

#[no_mangle]
pub extern "system" fn hdStopScheduler() {
    let taken = SCHEDULER.lock().unwrap_or_else(|p| p.into_inner()).take();
    if let Some((stop, t)) = taken {
        stop.store(true, Ordering::Release);
        let _ = t.join();
    }
}

/// The servo thread: one tick per period, callbacks outside the device lock (they call
/// back into this library).
fn scheduler(stop: &AtomicBool) {
    let start = Instant::now();
    let mut tick: u64 = 0;
    while !stop.load(Ordering::Acquire) {
        let calls: Vec<(HdSchedulerHandle, Callback, usize)> = with(|d| {
            d.begin_tick();
            d.scheduled
                .iter()
                .map(|s| (s.handle, s.callback, s.data))
                .collect()
        });
        for (handle, cb, data) in calls {
            // SAFETY: the callback and its data are what the client scheduled.
            let code = unsafe { cb(data as *mut c_void) };
            if code == HD_CALLBACK_DONE {
                with(|d| d.scheduled.retain(|s| s.handle != handle));
            }
        }
        let (rate, slow) = with(|d| {
            d.end_tick();
            (d.rate_hz.max(1), d.config.slow)
        });
        tick += 1;
        // `c_ulong` is 64 bits on Linux, 32 on Windows.
        #[allow(clippy::useless_conversion)]
        let due =
            start + Duration::from_nanos(tick * u64::from(slow) * 1_000_000_000 / u64::from(rate));
        let now = Instant::now();
        if due > now {
            std::thread::sleep(due - now);
        }
    }
}

#[no_mangle]
pub extern "system" fn hdBeginFrame(hhd: Hhd) {
    with(|d| {
        if hhd != HANDLE || !d.initialized {
            d.push_error(HD_BAD_HANDLE);
            return;
        }
        if d.in_frame || d.frames_this_tick > 0 {
            // Nested, or a second frame in this servo tick: refused, as the real library
            // refuses it. Nothing set until the next tick's frame reaches the motors.
            d.frame_errors += 1;
            d.push_error(HD_ILLEGAL_BEGIN);
            return;
        }
        d.in_frame = true;
        d.frames_this_tick += 1;
        d.pending = d.force;
    })
}

#[no_mangle]
pub extern "system" fn hdEndFrame(hhd: Hhd) {
    with(|d| {
        if hhd != HANDLE || !d.in_frame {
            d.frame_errors += 1;
            d.push_error(HD_ILLEGAL_END);
            return;
        }
        d.in_frame = false;
        // The force goes to the motors now: check it against the device's limits.
        let f = d.pending;
        let n = (f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sqrt();
        d.max_norm = d.max_norm.max(n);
        let mut commit = f;
        // NaN counts as a violation too.
        if n.is_nan() || n > d.config.max_force {
            d.violations += 1;
            if d.clamping && n.is_finite() {
                // Clamped silently: HD_EXCEEDED_MAX_FORCE is what clamping prevents.
                let k = d.config.max_force / n;
                commit = [f[0] * k, f[1] * k, f[2] * k];
            } else {
                commit = [0.0; 3];
                d.warnings += 1;
                d.push_error(HD_EXCEEDED_MAX_FORCE);
            }
        }
        if d.force_output && d.config.max_velocity > 0.0 {
            let p = d.reported_pos();
            let r = d.rate_hz as f64;
            let v: f64 = (0..3)
                .map(|i| ((p[i] - d.last_pos[i]) * r).powi(2))
                .sum::<f64>()
                .sqrt();
            if v > d.config.max_velocity {
                commit = [0.0; 3];
                d.warnings += 1;
                d.push_error(HD_EXCEEDED_MAX_VELOCITY);
            }
        }
        d.force = commit;
    })
}

#[no_mangle]
pub unsafe extern "system" fn hdGetDoublev(name: HdEnum, out: *mut f64) {
    if out.is_null() {
        with(|d| d.push_error(HD_INVALID_VALUE));
        return;
    }
    let values: Option<Vec<f64>> = with(|d| match name {
        HD_CURRENT_TRANSFORM => Some(transform(d.reported_pos(), d.row.q).to_vec()),
        HD_CURRENT_POSITION => Some(d.reported_pos().to_vec()),
        HD_CURRENT_VELOCITY => {
            let r = d.rate_hz as f64;
            let p = d.reported_pos();
            Some((0..3).map(|i| (p[i] - d.last_pos[i]) * r).collect())
        }
        HD_NOMINAL_MAX_FORCE => Some(vec![d.config.max_force]),
        HD_NOMINAL_MAX_CONTINUOUS_FORCE => Some(vec![d.config.max_continuous]),
        HD_CURRENT_FORCE => Some(d.force.to_vec()),
        _ => {
            d.push_error(HD_INVALID_ENUM);
            None
        }
    });
    if let Some(v) = values {
        // SAFETY: the caller provides room for the parameter's documented count.
        unsafe { std::ptr::copy_nonoverlapping(v.as_ptr(), out, v.len()) };
    }
}

#[no_mangle]
pub unsafe extern "system" fn hdGetIntegerv(name: HdEnum, out: *mut c_int) {
    if out.is_null() {
        with(|d| d.push_error(HD_INVALID_VALUE));
        return;
    }
    let v = with(|d| match name {
        HD_CURRENT_BUTTONS => Some(d.row.buttons),
        HD_CALIBRATION_STYLE => Some(d.config.cal_style),
        _ => {
            d.push_error(HD_INVALID_ENUM);
            None
        }
    });
    if let Some(v) = v {
        // SAFETY: one int, as HD_CURRENT_BUTTONS and HD_CALIBRATION_STYLE document.
        unsafe { *out = v };
    }
}

#[no_mangle]
pub unsafe extern "system" fn hdSetDoublev(name: HdEnum, values: *const f64) {
    if values.is_null() {
        with(|d| d.push_error(HD_INVALID_VALUE));
        return;
    }
    if name != HD_CURRENT_FORCE {
        with(|d| d.push_error(HD_INVALID_ENUM));
        return;
    }
    // SAFETY: three doubles, as HD_CURRENT_FORCE documents.
    let f = unsafe { [*values, *values.add(1), *values.add(2)] };
    with(|d| {
        if !d.in_frame {
            d.push_error(HD_INVALID_OPERATION);
            return;
        }
        d.pending = f;
        d.force_sets += 1;
    })
}

#[no_mangle]
pub extern "system" fn hdCheckCalibration() -> HdEnum {
    with(|d| d.calibration)
}

#[no_mangle]
pub extern "system" fn hdUpdateCalibration(style: HdEnum) {
    with(|d| {
        let supported = d.config.cal_style as HdEnum;
        if style.count_ones() != 1 || style & supported == 0 {
            d.push_error(HD_INVALID_VALUE);
            return;
        }
        if d.calibration == HD_CALIBRATION_NEEDS_UPDATE {
            // The positions jump to the calibrated ones from the next reading.
            d.cal_offset = [0.0; 3];
            d.calibration = HD_CALIBRATION_OK;
            d.calibrations += 1;
        }
    })
}

#[no_mangle]
pub extern "system" fn hdGetError() -> HdErrorInfo {
    with(|d| {
        d.errors.pop().unwrap_or(HdErrorInfo {
            error_code: HD_SUCCESS,
            internal_error_code: 0,
            h_hd: HANDLE,
        })
    })
}

#[no_mangle]
pub extern "system" fn hdGetErrorString(code: HdError) -> *const c_char {
    let s: &'static CStr = match code {
        HD_SUCCESS => c"No error (maobi stand-in)",
        HD_INVALID_ENUM => c"Invalid enumeration (maobi stand-in)",
        HD_INVALID_VALUE => c"Invalid value (maobi stand-in)",
        HD_INVALID_OPERATION => c"Invalid operation (maobi stand-in)",
        HD_BAD_HANDLE => c"Bad device handle (maobi stand-in)",
        HD_WARM_MOTORS => c"Motors are warm (maobi stand-in)",
        HD_EXCEEDED_MAX_FORCE => c"Exceeded the device's maximum force (maobi stand-in)",
        HD_EXCEEDED_MAX_FORCE_IMPULSE => c"Exceeded the maximum force impulse (maobi stand-in)",
        HD_EXCEEDED_MAX_VELOCITY => c"Exceeded the maximum velocity (maobi stand-in)",
        HD_DEVICE_ALREADY_INITIATED => c"Device already initiated (maobi stand-in)",
        HD_COMM_ERROR => c"Communication error with the device (maobi stand-in)",
        HD_COMM_CONFIG_ERROR => c"Device configuration error (maobi stand-in)",
        HD_TIMER_ERROR => c"Timer error (maobi stand-in)",
        HD_ILLEGAL_BEGIN => c"Illegal hdBeginFrame (maobi stand-in)",
        HD_ILLEGAL_END => c"Illegal hdEndFrame (maobi stand-in)",
        _ => c"Unknown error (maobi stand-in)",
    };
    s.as_ptr()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn config_parses_and_rejects() {
        let c = parse_config(
            "poses=/a.csv; record=/b.csv;error=700:0x0302;error=700:515;max_force=2;\
             fail=hdSetSchedulerRate:0x0101;calibration=manual;cal_offset=0,30,-1;inkwell_at=5",
        )
        .unwrap();
        assert_eq!(c.poses.as_deref(), Some("/a.csv"));
        assert_eq!(c.errors, vec![(700, 0x0302), (700, 0x0203)]);
        assert_eq!(c.fail, Some(("hdSetSchedulerRate".to_string(), 0x0101)));
        assert_eq!(c.max_force, 2.0);
        assert_eq!(c.max_continuous, 0.88);
        assert_eq!(c.calibration, HD_CALIBRATION_NEEDS_MANUAL_INPUT);
        assert_eq!(c.cal_offset, [0.0, 30.0, -1.0]);
        assert_eq!(c.inkwell_at, Some(5));
        assert!(parse_config("error=7").is_err());
        assert!(parse_config("max_force=-1").is_err());
        assert!(parse_config("colour=red").is_err());
        assert!(parse_config("fail=hdGetError:1").is_err());
        assert!(parse_config("calibration=maybe").is_err());
        assert!(parse_config("cal_offset=1,2").is_err());
        assert!(parse_config("cal_style=0").is_err());
    }
}
