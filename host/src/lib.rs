//! # maobi: the desktop side of Maobi
//!
//! The command line (`maobi trace`, `maobi render`) and the pieces the GUI will reuse:
//!
//! * [`poses`]: reading, validating and resampling handle-pose CSV files.
//! * [`offline`]: running the shared brush model offline over a pose track, tick by tick.
//! * [`trace`]: the per-tick trace CSV.
//! * [`strokes`]: keyframed stroke files (TOML): reading, sampling to poses, fitting.
//! * [`paper`]: the paper: ink per pixel shown as tone, sized and raw paper.
//! * [`raster`]: the anti-aliased polygon stamper.
//! * [`render`]: inking a simulated stroke and writing it as PNG.
//! * [`device`]: devices over the wire protocol (TCP, serial) and the simulated protocol device.
//! * [`gui`]: the desktop GUI (`maobi`, `maobi gui`) and its device backends.
//! * [`phantom`]: the Phantom Omni / Geomagic Touch bridge (OpenHaptics' libHD at run time).
//! * [`cli`]: the command-line interface.

pub mod cli;
pub mod device;
pub mod gui;
pub mod hanzi;
pub mod offline;
pub mod paper;
pub mod phantom;
pub mod poses;
pub mod raster;
pub mod render;
pub mod score;
pub mod strokes;
pub mod tablet;
pub mod trace;
