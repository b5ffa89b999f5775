//! # maobi: the desktop side of Maobi
//!
//! The command line (`maobi trace`, `maobi render`) and the pieces the GUI will reuse:
//!
//! * [`poses`]: reading, validating and resampling handle-pose CSV files.

pub mod poses;
