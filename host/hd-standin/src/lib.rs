//! A stand-in for OpenHaptics' `libHD.so`: the same `extern "C"` symbols the Maobi bridge
//! resolves, over a simulated device, so the bridge's real loading and servo code runs in
//! tests without a Phantom or the proprietary library.
//!
//! The simulated device:
//! * poses from a script (CSV `t,x,y,z,qw,qx,qy,qz[,buttons]`: seconds, device millimetres,
//!   unit quaternion, the HD_CURRENT_BUTTONS mask), held from row to row: scheduler tick `k`
//!   uses the last row with `t <= k ms`;
//! * a scheduler thread at the set rate (1 kHz by default) that runs the scheduled callbacks
//!   each tick, highest priority first;
//! * nominal limits of a Phantom Omni: 3.3 N peak (HD_NOMINAL_MAX_FORCE), 0.88 N continuous;
//! * injectable errors: `error=FRAME:CODE` puts `CODE` on the error stack at the start of
//!   scheduler tick `FRAME` (as a failed read of the device would);
//! * a record: the force held at the end of every tick, and a check of every force set
//!   against the peak limit (a violation also raises HD_EXCEEDED_MAX_FORCE at hdEndFrame, as
//!   the real library does with clamping off), written at `hdDisableDevice`.
//!
//! Configuration: the string `key=value;key=value` from `maobi_standin_configure` or, when
//! that was not called, the environment variable `MAOBI_HD_STANDIN`. Keys: `poses` (file),
//! `record` (CSV file; a summary goes to `FILE.summary`), `error` (`FRAME:CODE`, code in
//! decimal or 0x hex), `max_force`, `max_continuous` (N).
//!
//! Types follow `HD/hdDefines.h` (see `maobi::phantom::hd` for the values and where they
//! were checked). Only what the bridge uses is implemented; other enums raise
//! HD_INVALID_ENUM.

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
type Callback = unsafe extern "C" fn(*mut c_void) -> HdCallbackCode;

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
const HD_EXCEEDED_MAX_FORCE: HdError = 0x0201;
const HD_DEVICE_ALREADY_INITIATED: HdError = 0x0301;
const HD_COMM_ERROR: HdError = 0x0302;
const HD_COMM_CONFIG_ERROR: HdError = 0x0303;
const HD_ILLEGAL_BEGIN: HdError = 0x0400;
const HD_ILLEGAL_END: HdError = 0x0401;
const HD_CURRENT_BUTTONS: HdEnum = 0x2000;
const HD_CURRENT_POSITION: HdEnum = 0x2050;
const HD_CURRENT_VELOCITY: HdEnum = 0x2051;
const HD_CURRENT_TRANSFORM: HdEnum = 0x2052;
const HD_NOMINAL_MAX_FORCE: HdEnum = 0x2603;
const HD_NOMINAL_MAX_CONTINUOUS_FORCE: HdEnum = 0x2604;
const HD_CURRENT_FORCE: HdEnum = 0x2700;
const HD_FORCE_OUTPUT: HdEnum = 0x4000;
const HD_MAX_FORCE_CLAMPING: HdEnum = 0x4001;
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

#[derive(Clone, Debug, Default)]
struct Config {
    poses: Option<String>,
    record: Option<String>,
    error: Option<(u64, HdError)>,
    max_force: f64,
    max_continuous: f64,
}

fn parse_config(s: &str) -> Result<Config, String> {
    let mut c = Config {
        max_force: 3.3,
        max_continuous: 0.88,
        ..Config::default()
    };
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
            "error" => {
                let (f, code) = v
                    .split_once(':')
                    .ok_or_else(|| format!("error: `{v}` is not FRAME:CODE"))?;
                let frame = f
                    .trim()
                    .parse::<u64>()
                    .map_err(|_| format!("error: `{f}` is not a frame number"))?;
                let code = code.trim();
                let code = match code.strip_prefix("0x") {
                    Some(h) => u32::from_str_radix(h, 16),
                    None => code.parse::<u32>(),
                }
                .map_err(|_| format!("error: `{code}` is not an error code"))?;
                c.error = Some((frame, code));
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
    frame_depth: u32,
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
            config: parse_config("").unwrap_or_default(),
            rows: Vec::new(),
            initialized: false,
            frame: 0,
            row,
            last_pos: [0.0; 3],
            frame_depth: 0,
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
        }
    }

    fn push_error(&mut self, code: HdError) {
        self.errors.push(HdErrorInfo {
            error_code: code,
            internal_error_code: code as c_int,
            h_hd: HANDLE,
        });
    }

    /// The script's pose for tick `frame` (held between rows).
    fn pose_at(&self, frame: u64) -> Row {
        let t = frame as f64 * 1e-3 + 1e-9;
        let k = self.rows.partition_point(|r| r.t <= t);
        self.rows[k.saturating_sub(1).min(self.rows.len() - 1)]
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
            "frames={}\nforce_sets={}\nviolations={}\nmax_force_n={}\nlimit_n={}\n",
            self.record.len(),
            self.force_sets,
            self.violations,
            self.max_norm,
            self.config.max_force
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

#[no_mangle]
pub unsafe extern "C" fn hdInitDevice(_name: *const c_char) -> Hhd {
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
                d.config = c;
                if rows.is_empty() {
                    // No script: the stylus rests at the workspace origin.
                    d.rows = vec![d.row];
                } else {
                    d.rows = rows;
                }
                d.row = d.pose_at(0);
                d.last_pos = d.row.pos;
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
pub extern "C" fn hdDisableDevice(hhd: Hhd) {
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
pub extern "C" fn hdEnable(cap: HdEnum) {
    with(|d| match cap {
        HD_FORCE_OUTPUT => d.force_output = true,
        HD_MAX_FORCE_CLAMPING => d.clamping = true,
        _ => d.push_error(HD_INVALID_ENUM),
    })
}

#[no_mangle]
pub extern "C" fn hdDisable(cap: HdEnum) {
    with(|d| match cap {
        HD_FORCE_OUTPUT => {
            d.force_output = false;
            d.force = [0.0; 3];
        }
        HD_MAX_FORCE_CLAMPING => d.clamping = false,
        _ => d.push_error(HD_INVALID_ENUM),
    })
}

#[no_mangle]
pub extern "C" fn hdSetSchedulerRate(rate: c_ulong) {
    with(|d| {
        if (100..=2000).contains(&rate) {
            d.rate_hz = rate;
        } else {
            d.push_error(HD_INVALID_VALUE);
        }
    })
}

#[no_mangle]
pub extern "C" fn hdScheduleAsynchronous(
    callback: Callback,
    data: *mut c_void,
    priority: c_ushort,
) -> HdSchedulerHandle {
    with(|d| {
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
pub extern "C" fn hdUnschedule(handle: HdSchedulerHandle) {
    with(|d| {
        let before = d.scheduled.len();
        d.scheduled.retain(|s| s.handle != handle);
        if d.scheduled.len() == before {
            d.push_error(HD_INVALID_OPERATION);
        }
    })
}

#[no_mangle]
pub extern "C" fn hdStartScheduler() {
    let mut sched = SCHEDULER.lock().unwrap_or_else(|p| p.into_inner());
    if sched.is_some() {
        return;
    }
    let stop = Arc::new(AtomicBool::new(false));
    let s2 = stop.clone();
    match std::thread::Builder::new()
        .name("hd-standin-scheduler".into())
        .spawn(move || scheduler(&s2))
    {
        Ok(t) => *sched = Some((stop, t)),
        Err(_) => with(|d| d.push_error(HD_COMM_ERROR)),
    }
}

#[no_mangle]
pub extern "C" fn hdStopScheduler() {
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
            let k = d.frame;
            d.last_pos = d.row.pos;
            d.row = d.pose_at(k);
            if d.config.error.is_some_and(|(f, _)| f == k) {
                let code = d.config.error.map(|e| e.1).unwrap_or(HD_COMM_ERROR);
                d.push_error(code);
            }
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
        let rate = with(|d| {
            let f = if d.force_output { d.force } else { [0.0; 3] };
            d.record.push(f);
            d.frame += 1;
            d.rate_hz.max(1)
        });
        tick += 1;
        let due = start + Duration::from_nanos(tick * 1_000_000_000 / rate);
        let now = Instant::now();
        if due > now {
            std::thread::sleep(due - now);
        }
    }
}

#[no_mangle]
pub extern "C" fn hdBeginFrame(hhd: Hhd) {
    with(|d| {
        if hhd != HANDLE || !d.initialized {
            d.push_error(HD_BAD_HANDLE);
            return;
        }
        d.frame_depth += 1;
        if d.frame_depth > 2 {
            d.push_error(HD_ILLEGAL_BEGIN);
        }
    })
}

#[no_mangle]
pub extern "C" fn hdEndFrame(hhd: Hhd) {
    with(|d| {
        if hhd != HANDLE || d.frame_depth == 0 {
            d.push_error(HD_ILLEGAL_END);
            return;
        }
        d.frame_depth -= 1;
        if d.frame_depth == 0 {
            // The force goes to the motors now: check it against the device's limit.
            let f = d.force;
            let n = (f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sqrt();
            d.max_norm = d.max_norm.max(n);
            // NaN counts as a violation too.
            if n.is_nan() || n > d.config.max_force {
                d.violations += 1;
                if d.clamping && n.is_finite() {
                    let k = d.config.max_force / n;
                    d.force = [f[0] * k, f[1] * k, f[2] * k];
                } else {
                    d.force = [0.0; 3];
                }
                d.push_error(HD_EXCEEDED_MAX_FORCE);
            }
        }
    })
}

#[no_mangle]
pub unsafe extern "C" fn hdGetDoublev(name: HdEnum, out: *mut f64) {
    if out.is_null() {
        with(|d| d.push_error(HD_INVALID_VALUE));
        return;
    }
    let values: Option<Vec<f64>> = with(|d| match name {
        HD_CURRENT_TRANSFORM => Some(transform(d.row.pos, d.row.q).to_vec()),
        HD_CURRENT_POSITION => Some(d.row.pos.to_vec()),
        HD_CURRENT_VELOCITY => {
            let r = d.rate_hz as f64;
            Some((0..3).map(|i| (d.row.pos[i] - d.last_pos[i]) * r).collect())
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
pub unsafe extern "C" fn hdGetIntegerv(name: HdEnum, out: *mut c_int) {
    if out.is_null() {
        with(|d| d.push_error(HD_INVALID_VALUE));
        return;
    }
    let v = with(|d| match name {
        HD_CURRENT_BUTTONS => Some(d.row.buttons),
        _ => {
            d.push_error(HD_INVALID_ENUM);
            None
        }
    });
    if let Some(v) = v {
        // SAFETY: one int, as HD_CURRENT_BUTTONS documents.
        unsafe { *out = v };
    }
}

#[no_mangle]
pub unsafe extern "C" fn hdSetDoublev(name: HdEnum, values: *const f64) {
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
        if d.frame_depth == 0 {
            d.push_error(HD_INVALID_OPERATION);
            return;
        }
        d.force = f;
        d.force_sets += 1;
    })
}

#[no_mangle]
pub extern "C" fn hdGetError() -> HdErrorInfo {
    with(|d| {
        d.errors.pop().unwrap_or(HdErrorInfo {
            error_code: HD_SUCCESS,
            internal_error_code: 0,
            h_hd: HANDLE,
        })
    })
}

#[no_mangle]
pub extern "C" fn hdGetErrorString(code: HdError) -> *const c_char {
    let s: &'static CStr = match code {
        HD_SUCCESS => c"No error (maobi stand-in)",
        HD_INVALID_ENUM => c"Invalid enumeration (maobi stand-in)",
        HD_INVALID_VALUE => c"Invalid value (maobi stand-in)",
        HD_INVALID_OPERATION => c"Invalid operation (maobi stand-in)",
        HD_BAD_HANDLE => c"Bad device handle (maobi stand-in)",
        HD_EXCEEDED_MAX_FORCE => c"Exceeded the device's maximum force (maobi stand-in)",
        HD_DEVICE_ALREADY_INITIATED => c"Device already initiated (maobi stand-in)",
        HD_COMM_ERROR => c"Communication error with the device (maobi stand-in)",
        HD_COMM_CONFIG_ERROR => c"Device configuration error (maobi stand-in)",
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
        let c = parse_config("poses=/a.csv; record=/b.csv;error=700:0x0302;max_force=2").unwrap();
        assert_eq!(c.poses.as_deref(), Some("/a.csv"));
        assert_eq!(c.error, Some((700, 0x0302)));
        assert_eq!(c.max_force, 2.0);
        assert_eq!(c.max_continuous, 0.88);
        assert!(parse_config("error=7").is_err());
        assert!(parse_config("max_force=-1").is_err());
        assert!(parse_config("colour=red").is_err());
    }
}
