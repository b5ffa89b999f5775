//! Finding and loading OpenHaptics' `libHD.so` at run time.
//!
//! The library is proprietary and is not linked at build time, so the bridge builds and its
//! tests run on machines without it. Search order: `--hd-lib PATH`, then the environment
//! variable [`HD_LIB_ENV`], then [`DEFAULT_PATHS`] (where the OpenHaptics 3.0 and 3.4
//! installers and the Geomagic Touch device driver put it), then the dynamic loader's own
//! search (`libHD.so` by name: `LD_LIBRARY_PATH`, ld.so.cache). The first file that exists is
//! loaded; if it cannot be loaded, or lacks a symbol, that is the error (a broken install
//! should not be papered over by a different copy further down the list).

use std::fmt;
use std::path::{Path, PathBuf};

use super::hd::*;

/// Environment variable naming the library file.
pub const HD_LIB_ENV: &str = "MAOBI_HD_LIB";

/// The library's file name.
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
];

/// Where a candidate came from, for the error message.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Source {
    Flag,
    Env,
    Default,
    /// `libHD.so` by name through the dynamic loader's search path.
    LoaderSearch,
}

impl fmt::Display for Source {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Source::Flag => "--hd-lib",
            Source::Env => HD_LIB_ENV,
            Source::Default => "OpenHaptics install path",
            Source::LoaderSearch => "dynamic loader search (LD_LIBRARY_PATH, ld.so.cache)",
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

/// The candidates in search order: the flag, the environment variable, the default paths.
pub fn candidates(flag: Option<&Path>, env: Option<&std::ffi::OsStr>) -> Vec<(PathBuf, Source)> {
    let mut out = Vec::new();
    if let Some(p) = flag {
        out.push((p.to_path_buf(), Source::Flag));
    }
    if let Some(e) = env.filter(|e| !e.is_empty()) {
        out.push((PathBuf::from(e), Source::Env));
    }
    out.extend(
        DEFAULT_PATHS
            .iter()
            .map(|p| (PathBuf::from(p), Source::Default)),
    );
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
}

/// A loaded libHD.
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
    pub fn find(flag: Option<&Path>) -> Result<HdLib, LoadError> {
        let env = std::env::var_os(HD_LIB_ENV);
        let tried = candidates(flag, env.as_deref());
        for (path, source) in &tried {
            // An explicitly named file that is missing is an error of its own: falling back
            // to another copy would run a library the user did not ask for.
            if path.exists() || *source != Source::Default {
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

    /// Loads the library at `path` and resolves every symbol of [`SYMBOLS`].
    pub fn open(path: &Path, source: Source) -> Result<HdLib, LoadError> {
        // SAFETY: loading a shared library runs its initialisers. That is the point: the user
        // (or a test) named this file as an OpenHaptics HD library.
        let lib = unsafe { libloading::Library::new(path) }.map_err(|e| LoadError::Open {
            path: path.to_path_buf(),
            source: source.clone(),
            why: e.to_string(),
        })?;
        let fns = resolve(&lib, path)?;
        Ok(HdLib {
            lib,
            path: path.to_path_buf(),
            source,
            fns,
        })
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
        assert_eq!(c[2].0, PathBuf::from(DEFAULT_PATHS[0]));
        assert_eq!(c.len(), 2 + DEFAULT_PATHS.len());
        // An empty variable is no candidate.
        assert_eq!(
            candidates(None, Some(std::ffi::OsStr::new(""))).len(),
            DEFAULT_PATHS.len()
        );
    }

    #[test]
    fn a_missing_flag_file_is_the_error_not_a_fallback() {
        let e = HdLib::find(Some(Path::new("/nonexistent/maobi/libHD.so"))).unwrap_err();
        let text = e.to_string();
        assert!(text.contains("/nonexistent/maobi/libHD.so"), "{text}");
        assert!(text.contains("--hd-lib"), "{text}");
    }
}
