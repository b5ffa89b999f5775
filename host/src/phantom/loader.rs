//! Finding and loading OpenHaptics' HD library (`libHD.so` on Linux, `hd.dll` on Windows)
//! at run time, once per process.
//!
//! The library is proprietary and is not linked at build time, so the bridge builds and its
//! tests run on machines without it. Search order: `--hd-lib PATH`, then the environment
//! variable [`HD_LIB_ENV`], then where the installers put it ([`default_candidates`]: on
//! Linux [`DEFAULT_PATHS`]; on Windows `%OH_SDK_BASE%\lib\x64\Release`, `System32` and the
//! Touch / Phantom device-driver folders under Program Files), then the dynamic loader's own
//! search ([`HD_LIB_NAME`] by name: `LD_LIBRARY_PATH` and ld.so.cache, or Windows' DLL search
//! order). The first file that exists is loaded; if it cannot be loaded, or lacks a symbol,
//! that is the error (a broken install should not be papered over by a different copy
//! further down the list).
//!
//! Loaded once, never unloaded: [`HdLib::open`] keeps every library it loaded for the rest of
//! the process and hands out the same [`Arc`] when asked again. The device driver behind
//! libHD does not survive being unloaded and loaded again in one process (CHAI3D keeps it
//! loaded for that reason), and the GUI connects, disconnects and connects again.
//!
//! On Windows `hd.dll` is loaded with `LOAD_WITH_ALTERED_SEARCH_PATH`, so the DLLs it needs
//! are looked for beside it first (the driver folder), not only in the program's folder.

use std::ffi::OsString;
use std::fmt;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use super::hd::*;

/// Environment variable naming the library file.
pub const HD_LIB_ENV: &str = "MAOBI_HD_LIB";

/// The OpenHaptics SDK's environment variable (set by its Windows installer): the SDK's
/// folder, with the DLL under `lib\x64\Release`.
pub const OH_SDK_ENV: &str = "OH_SDK_BASE";

/// The library's file name, as the dynamic loader is asked for it by name.
#[cfg(windows)]
pub const HD_LIB_NAME: &str = "hd.dll";
/// The library's file name, as the dynamic loader is asked for it by name.
#[cfg(not(windows))]
pub const HD_LIB_NAME: &str = "libHD.so";

/// Where OpenHaptics installs put `libHD.so` on Linux, in the order they are tried. The
/// OpenHaptics 3.4 (Geomagic Touch) installer copies it to `/usr/lib` (x86-64 Debian/Ubuntu
/// layout) and keeps a copy under `/opt/OpenHaptics/Developer/3.4-0/lib`; the 3.0 (Phantom
/// Omni) packages use `/usr/lib` or `/usr/lib64` (RPM layout). `.so.3.4.0` / `.so.3.0` are
/// the versioned names when the unversioned link is missing.
pub const DEFAULT_PATHS: &[&str] = &[
    "/usr/lib/libHD.so",
    "/usr/lib64/libHD.so",
    "/usr/lib/x86_64-linux-gnu/libHD.so",
    "/usr/local/lib/libHD.so",
    "/opt/OpenHaptics/Developer/3.4-0/lib/libHD.so",
    "/opt/OpenHaptics/Developer/3.4-0/lib/lin-x86_64/libHD.so",
    "/opt/OpenHaptics/Academic/3.4-0/lib/libHD.so",
    "/opt/OpenHaptics/Developer/3.0/lib/libHD.so",
    "/usr/lib/libHD.so.3.4.0",
    "/usr/lib/libHD.so.3.0.0",
    "/usr/lib64/libHD.so.3.0.0",
];

/// The vendors' folders under Program Files on Windows, in which every device-driver
/// folder (`<vendor>\<driver>\bin\hd.dll` or `<vendor>\<driver>\hd.dll`) is tried: 3D
/// Systems' Touch driver, Geomagic's, and SensAble's Phantom Device Drivers.
pub const WINDOWS_VENDOR_DIRS: &[&str] = &["3D Systems", "Geomagic", "SensAble"];

/// Where the installers put `hd.dll` on Windows, in the order they are tried:
/// `%OH_SDK_BASE%\lib\x64\Release\hd.dll` (the SDK), `%SystemRoot%\System32\hd.dll`
/// (OpenHaptics 3.5 copies it there), then the device-driver folders of
/// [`WINDOWS_VENDOR_DIRS`] under `%ProgramW6432%` / `%ProgramFiles%` (each driver folder
/// found by listing the vendor's folder with `list_dir`). `env` reads an environment
/// variable. A plain function of its inputs, so it is tested on any platform.
pub fn windows_candidates(
    env: &dyn Fn(&str) -> Option<OsString>,
    list_dir: &dyn Fn(&Path) -> Vec<PathBuf>,
) -> Vec<(PathBuf, Source)> {
    let var = |k: &str| env(k).filter(|v| !v.is_empty()).map(PathBuf::from);
    let mut out = Vec::new();
    if let Some(sdk) = var(OH_SDK_ENV) {
        out.push((
            sdk.join("lib").join("x64").join("Release").join("hd.dll"),
            Source::SdkBase,
        ));
    }
    let system_root = var("SystemRoot").unwrap_or_else(|| PathBuf::from(r"C:\Windows"));
    out.push((system_root.join("System32").join("hd.dll"), Source::Default));
    let mut roots: Vec<PathBuf> = Vec::new();
    for r in [var("ProgramW6432"), var("ProgramFiles")]
        .into_iter()
        .flatten()
        .chain([PathBuf::from(r"C:\Program Files")])
    {
        if !roots.contains(&r) {
            roots.push(r);
        }
    }
    for root in roots {
        for vendor in WINDOWS_VENDOR_DIRS {
            let mut drivers = list_dir(&root.join(vendor));
            drivers.sort();
            for d in drivers {
                out.push((d.join("bin").join("hd.dll"), Source::Default));
                out.push((d.join("hd.dll"), Source::Default));
            }
        }
    }
    out
}

/// The install locations of this platform (see [`DEFAULT_PATHS`], [`windows_candidates`]).
pub fn default_candidates() -> Vec<(PathBuf, Source)> {
    if cfg!(windows) {
        let list_dir = |p: &Path| -> Vec<PathBuf> {
            std::fs::read_dir(p)
                .map(|rd| {
                    rd.flatten()
                        .map(|e| e.path())
                        .filter(|p| p.is_dir())
                        .collect()
                })
                .unwrap_or_default()
        };
        windows_candidates(&|k| std::env::var_os(k), &list_dir)
    } else {
        DEFAULT_PATHS
            .iter()
            .map(|p| (PathBuf::from(p), Source::Default))
            .collect()
    }
}

/// Every symbol the bridge resolves, in the order they are looked up.
pub const SYMBOLS: &[&str] = &[
    "hdInitDevice",
    "hdDisableDevice",
    "hdEnable",
    "hdDisable",
    "hdStartScheduler",
    "hdStopScheduler",
    "hdSetSchedulerRate",
    "hdScheduleAsynchronous",
    "hdUnschedule",
    "hdBeginFrame",
    "hdEndFrame",
    "hdGetDoublev",
    "hdGetIntegerv",
    "hdSetDoublev",
    "hdGetError",
    "hdGetErrorString",
    "hdCheckCalibration",
    "hdUpdateCalibration",
];

/// Where a candidate came from, for the error message.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Source {
    Flag,
    Env,
    Default,
    /// Under the OpenHaptics SDK's folder (`%OH_SDK_BASE%`).
    SdkBase,
    /// The library by name through the dynamic loader's search path.
    LoaderSearch,
}

impl fmt::Display for Source {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Source::Flag => "--hd-lib",
            Source::Env => HD_LIB_ENV,
            Source::Default => "OpenHaptics install path",
            Source::SdkBase => "%OH_SDK_BASE%",
            Source::LoaderSearch => {
                if cfg!(windows) {
                    "the DLL search order (the program's folder, System32, PATH)"
                } else {
                    "dynamic loader search (LD_LIBRARY_PATH, ld.so.cache)"
                }
            }
        })
    }
}

/// Why libHD could not be loaded.
#[derive(Debug)]
pub enum LoadError {
    /// No candidate file exists (and the loader's search found none either).
    NotFound { tried: Vec<(PathBuf, Source)> },
    /// The file exists but the dynamic loader refused it.
    Open {
        path: PathBuf,
        source: Source,
        why: String,
    },
    /// The library lacks a symbol the servo loop needs.
    MissingSymbol {
        path: PathBuf,
        symbol: &'static str,
        why: String,
    },
}

impl fmt::Display for LoadError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            LoadError::NotFound { tried } => {
                writeln!(
                    f,
                    "cannot find OpenHaptics' {HD_LIB_NAME} (the Phantom Omni / Geomagic Touch \
                     driver library); looked for:"
                )?;
                for (p, s) in tried {
                    writeln!(f, "  {} ({s}): not found", p.display())?;
                }
                write!(
                    f,
                    "install OpenHaptics (see docs/phantom.md), or give the file with --hd-lib PATH \
                     or {HD_LIB_ENV}=PATH"
                )
            }
            LoadError::Open { path, source, why } => {
                write!(f, "cannot load {} (from {source}): {why}", path.display())
            }
            LoadError::MissingSymbol { path, symbol, why } => write!(
                f,
                "{} is not a usable OpenHaptics HD library: it lacks the symbol `{symbol}` ({why})",
                path.display()
            ),
        }
    }
}

impl std::error::Error for LoadError {}

/// The candidates in search order: the flag, the environment variable, the install
/// locations ([`default_candidates`]).
pub fn candidates(flag: Option<&Path>, env: Option<&std::ffi::OsStr>) -> Vec<(PathBuf, Source)> {
    let mut out = Vec::new();
    if let Some(p) = flag {
        out.push((p.to_path_buf(), Source::Flag));
    }
    if let Some(e) = env.filter(|e| !e.is_empty()) {
        out.push((PathBuf::from(e), Source::Env));
    }
    out.extend(default_candidates());
    out
}

/// The resolved HD functions. Plain function pointers (`Copy`), valid while the
/// [`HdLib`] that produced them is alive.
#[derive(Copy, Clone)]
pub struct HdFns {
    pub init_device: FnInitDevice,
    pub disable_device: FnDisableDevice,
    pub enable: FnEnable,
    pub disable: FnDisable,
    pub start_scheduler: FnStartScheduler,
    pub stop_scheduler: FnStopScheduler,
    pub set_scheduler_rate: FnSetSchedulerRate,
    pub schedule_asynchronous: FnScheduleAsynchronous,
    pub unschedule: FnUnschedule,
    pub begin_frame: FnBeginFrame,
    pub end_frame: FnEndFrame,
    pub get_doublev: FnGetDoublev,
    pub get_integerv: FnGetIntegerv,
    pub set_doublev: FnSetDoublev,
    pub get_error: FnGetError,
    pub get_error_string: FnGetErrorString,
    pub check_calibration: FnCheckCalibration,
    pub update_calibration: FnUpdateCalibration,
}

/// A loaded libHD. Only ever handed out as an `Arc` from the process-wide list of loaded
/// libraries, which keeps it (and so the mapping the function pointers point into) for the
/// rest of the process.
pub struct HdLib {
    // Declared first so nothing below outlives the mapping by accident; the functions in
    // `fns` point into it.
    lib: libloading::Library,
    path: PathBuf,
    source: Source,
    fns: HdFns,
}

impl fmt::Debug for HdLib {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("HdLib")
            .field("path", &self.path)
            .field("source", &self.source)
            .finish()
    }
}

impl HdLib {
    /// Finds and loads libHD: `flag` (`--hd-lib`), then `$MAOBI_HD_LIB`, then the install
    /// paths, then the dynamic loader's search.
    pub fn find(flag: Option<&Path>) -> Result<Arc<HdLib>, LoadError> {
        let env = std::env::var_os(HD_LIB_ENV);
        let tried = candidates(flag, env.as_deref());
        for (path, source) in &tried {
            // An explicitly named file that is missing is an error of its own: falling back
            // to another copy would run a library the user did not ask for.
            let explicit = matches!(source, Source::Flag | Source::Env);
            if path.exists() || explicit {
                if !path.exists() {
                    return Err(LoadError::NotFound {
                        tried: vec![(path.clone(), source.clone())],
                    });
                }
                return HdLib::open(path, source.clone());
            }
        }
        // Last, the loader's own search, by bare name.
        match HdLib::open(Path::new(HD_LIB_NAME), Source::LoaderSearch) {
            Ok(lib) => Ok(lib),
            Err(LoadError::Open { .. }) => {
                let mut tried = tried;
                tried.push((PathBuf::from(HD_LIB_NAME), Source::LoaderSearch));
                Err(LoadError::NotFound { tried })
            }
            Err(e) => Err(e),
        }
    }

    /// Loads the library at `path` and resolves every symbol of [`SYMBOLS`]; or, if this
    /// process has loaded that file before, the same library again (it is never unloaded).
    pub fn open(path: &Path, source: Source) -> Result<Arc<HdLib>, LoadError> {
        let mut loaded = LOADED.lock().unwrap_or_else(|p| p.into_inner());
        let key = identity(path);
        if let Some(lib) = loaded.iter().find(|l| identity(&l.path) == key) {
            return Ok(lib.clone());
        }
        let lib = load(path).map_err(|e| LoadError::Open {
            path: path.to_path_buf(),
            source: source.clone(),
            why: e.to_string(),
        })?;
        // A library without the symbols is dropped (unloaded) here: it never ran as libHD.
        let fns = resolve(&lib, path)?;
        let lib = Arc::new(HdLib {
            lib,
            path: path.to_path_buf(),
            source,
            fns,
        });
        loaded.push(lib.clone());
        Ok(lib)
    }

    /// The libraries this process has loaded (each once, none ever unloaded).
    pub fn loaded() -> Vec<Arc<HdLib>> {
        LOADED.lock().unwrap_or_else(|p| p.into_inner()).clone()
    }

    pub fn fns(&self) -> HdFns {
        self.fns
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    pub fn source(&self) -> &Source {
        &self.source
    }

    /// An extra symbol of this library (the stand-in's test controls), if it has it.
    ///
    /// # Safety
    /// `T` must be the symbol's true type.
    pub unsafe fn extra<T: Copy>(&self, name: &str) -> Option<T> {
        // SAFETY: forwarded to the caller.
        unsafe { self.lib.get::<T>(name.as_bytes()).ok().map(|s| *s) }
    }

    /// `hdGetErrorString(code)` as text.
    pub fn error_string(&self, code: HdError) -> String {
        error_string(self.fns, code)
    }
}

/// Every HD library loaded in this process, kept to the end (see the module docs).
static LOADED: Mutex<Vec<Arc<HdLib>>> = Mutex::new(Vec::new());

/// What makes two paths the same file for [`HdLib::open`]: the canonical path when the file
/// exists, else the path as given (a bare name the loader searches for).
fn identity(path: &Path) -> PathBuf {
    std::fs::canonicalize(path).unwrap_or_else(|_| path.to_path_buf())
}

/// `dlopen` on Linux. On Windows a path with a folder is loaded with
/// `LOAD_WITH_ALTERED_SEARCH_PATH` (made absolute first: the flag is undefined for relative
/// paths), so hd.dll's own DLLs are found beside it; a bare name takes the standard search.
fn load(path: &Path) -> Result<libloading::Library, libloading::Error> {
    #[cfg(windows)]
    {
        use libloading::os::windows::{Library, LOAD_WITH_ALTERED_SEARCH_PATH};
        if path.components().count() > 1 {
            let abs = std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf());
            // SAFETY: loading a library runs its initialisers; the user (or a test) named this
            // file as an OpenHaptics HD library.
            return unsafe { Library::load_with_flags(&abs, LOAD_WITH_ALTERED_SEARCH_PATH) }
                .map(Into::into);
        }
    }
    // SAFETY: as above.
    unsafe { libloading::Library::new(path) }
}

/// `hdGetErrorString(code)` as text (empty if the library returns NULL).
pub fn error_string(fns: HdFns, code: HdError) -> String {
    // SAFETY: hdGetErrorString returns a pointer to a static, NUL-terminated string (or NULL,
    // which we check).
    unsafe {
        let p = (fns.get_error_string)(code);
        if p.is_null() {
            String::new()
        } else {
            std::ffi::CStr::from_ptr(p).to_string_lossy().into_owned()
        }
    }
}

fn resolve(lib: &libloading::Library, path: &Path) -> Result<HdFns, LoadError> {
    fn get<T: Copy>(
        lib: &libloading::Library,
        path: &Path,
        symbol: &'static str,
    ) -> Result<T, LoadError> {
        // SAFETY: each call site names the symbol with its C type from hdDefines.h /
        // hdScheduler.h / hd.h (see `hd`).
        unsafe { lib.get::<T>(symbol.as_bytes()) }
            .map(|s| *s)
            .map_err(|e| LoadError::MissingSymbol {
                path: path.to_path_buf(),
                symbol,
                why: e.to_string(),
            })
    }
    Ok(HdFns {
        init_device: get(lib, path, "hdInitDevice")?,
        disable_device: get(lib, path, "hdDisableDevice")?,
        enable: get(lib, path, "hdEnable")?,
        disable: get(lib, path, "hdDisable")?,
        start_scheduler: get(lib, path, "hdStartScheduler")?,
        stop_scheduler: get(lib, path, "hdStopScheduler")?,
        set_scheduler_rate: get(lib, path, "hdSetSchedulerRate")?,
        schedule_asynchronous: get(lib, path, "hdScheduleAsynchronous")?,
        unschedule: get(lib, path, "hdUnschedule")?,
        begin_frame: get(lib, path, "hdBeginFrame")?,
        end_frame: get(lib, path, "hdEndFrame")?,
        get_doublev: get(lib, path, "hdGetDoublev")?,
        get_integerv: get(lib, path, "hdGetIntegerv")?,
        set_doublev: get(lib, path, "hdSetDoublev")?,
        get_error: get(lib, path, "hdGetError")?,
        get_error_string: get(lib, path, "hdGetErrorString")?,
        check_calibration: get(lib, path, "hdCheckCalibration")?,
        update_calibration: get(lib, path, "hdUpdateCalibration")?,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flag_then_env_then_defaults() {
        let c = candidates(
            Some(Path::new("/a/libHD.so")),
            Some(std::ffi::OsStr::new("/b/libHD.so")),
        );
        assert_eq!(c[0], (PathBuf::from("/a/libHD.so"), Source::Flag));
        assert_eq!(c[1], (PathBuf::from("/b/libHD.so"), Source::Env));
        let defaults = default_candidates();
        assert_eq!(c[2], defaults[0]);
        assert_eq!(c.len(), 2 + defaults.len());
        // An empty variable is no candidate.
        assert_eq!(
            candidates(None, Some(std::ffi::OsStr::new(""))).len(),
            defaults.len()
        );
        if cfg!(not(windows)) {
            assert_eq!(defaults[0].0, PathBuf::from(DEFAULT_PATHS[0]));
        }
    }

    #[test]
    fn windows_looks_in_the_sdk_system32_and_the_driver_folders() {
        let env = |k: &str| -> Option<OsString> {
            match k {
                "OH_SDK_BASE" => Some(r"D:\OpenHaptics\Developer\3.5.0".into()),
                "SystemRoot" => Some(r"C:\Windows".into()),
                "ProgramW6432" | "ProgramFiles" => Some(r"C:\Program Files".into()),
                _ => None,
            }
        };
        let list = |p: &Path| -> Vec<PathBuf> {
            if p == Path::new(r"C:\Program Files").join("3D Systems") {
                vec![p.join("Touch Device Driver")]
            } else if p == Path::new(r"C:\Program Files").join("SensAble") {
                vec![p.join("PHANToM Device Drivers")]
            } else {
                Vec::new()
            }
        };
        let c = windows_candidates(&env, &list);
        let text: Vec<String> = c.iter().map(|(p, _)| p.display().to_string()).collect();
        let sdk = Path::new(r"D:\OpenHaptics\Developer\3.5.0")
            .join("lib")
            .join("x64")
            .join("Release")
            .join("hd.dll");
        assert_eq!(c[0], (sdk, Source::SdkBase), "{text:?}");
        assert_eq!(
            c[1].0,
            Path::new(r"C:\Windows").join("System32").join("hd.dll")
        );
        let touch = Path::new(r"C:\Program Files")
            .join("3D Systems")
            .join("Touch Device Driver");
        assert!(c.contains(&(touch.join("bin").join("hd.dll"), Source::Default)));
        assert!(c.contains(&(touch.join("hd.dll"), Source::Default)));
        assert!(text.iter().any(|t| t.contains("PHANToM Device Drivers")));
        // The same Program Files named by both variables is listed once.
        assert_eq!(c.len(), 2 + 2 * 2, "{text:?}");
        // Without OH_SDK_BASE: System32 first.
        let bare = windows_candidates(&|_| None, &|_| Vec::new());
        assert_eq!(bare.len(), 1);
        assert!(bare[0].0.ends_with("hd.dll"));
    }

    #[test]
    fn a_missing_flag_file_is_the_error_not_a_fallback() {
        let e = HdLib::find(Some(Path::new("/nonexistent/maobi/libHD.so"))).unwrap_err();
        let text = e.to_string();
        assert!(text.contains("/nonexistent/maobi/libHD.so"), "{text}");
        assert!(text.contains("--hd-lib"), "{text}");
    }
}
