//! The Phantom Omni / Geomagic Touch bridge: OpenHaptics' HD library, loaded at run time,
//! drives the shared brush and force model at 1 kHz (see docs/phantom.md).
//!
//! * [`hd`]: the HD C API (types, constants, function types) as `hdDefines.h` declares it,
//!   and how the SDK sorts its errors.
//! * [`loader`]: finding `libHD.so` / `hd.dll`, loading it once per process and resolving its
//!   symbols, with errors that say which file and which symbol.
//! * [`servo`]: the servo loop ([`servo::Bridge`]): the workspace-to-paper mapping and its
//!   calibration, the model in the scheduler callback (one frame per tick, device warnings,
//!   the device's calibration, the safe start), the non-blocking handoff of states.
//! * [`solver`]: Baxter & Lin's brush solved on a thread of its own beside the servo loop,
//!   which runs their local force model.
//! * [`device`]: the bridge behind the wire protocol (`maobi bridge`) and as a GUI device
//!   (`maobi --device phantom`).

pub mod device;
pub mod hd;
pub mod loader;
pub mod servo;
pub mod solver;

pub use loader::{HdLib, LoadError};
pub use servo::{
    Bridge, BridgeOptions, Mapping, ServoBrush, ServoCommand, ServoCore, ServoState, Stopped,
};
