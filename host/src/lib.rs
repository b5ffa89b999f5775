//! # maobi: the desktop side of Maobi
//!
//! The command line (`maobi trace`, `maobi render`) and the pieces the GUI will reuse:
//!
//! * [`poses`]: reading, validating and resampling handle-pose CSV files.
//! * [`raster`]: the paper canvas and the anti-aliased polygon stamper.

pub mod poses;
pub mod raster;
