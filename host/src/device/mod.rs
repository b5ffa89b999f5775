//! Devices: what runs the brush model and sends back its state, behind one seam
//! ([`Device`]), for the GUI and the Phantom bridge.
//!
//! * [`api`]: the seam itself: the [`Device`] trait, the [`BrushFrame`] a device reports
//!   each tick, the [`HandInput`] and [`DeviceCommand`]s it takes (with the validation every
//!   device does before carrying one out), its [`DeviceStatus`] and [`DeviceError`].
//! * [`builtin`]: the built-in simulated device ([`SimDevice`]): the shared model on the
//!   host, in real time on a thread or stepped for tests.
//! * [`model`]: the brush models ([`ModelKind`]: Liang's, Baxter & Lin's) and a brush
//!   chosen by name for one ([`BrushChoice`]); [`sim_model`]: the chosen model in its 1 kHz
//!   loop, what the built-in device ticks.
//! * [`journal`]: what the built-in device did, tick by tick (poses and brush commands): what a
//!   session file stores and a re-render runs again.
//! * [`endpoint`]: where a device is (`tcp:HOST:PORT`, `serial:PATH`) and opening a byte
//!   stream to it; serial port listing.
//! * [`client`]: [`client::LinkDevice`], the protocol client behind the [`Device`] trait: a
//!   link thread that connects, shakes hands, decodes frames and reconnects; a writer thread
//!   that streams the virtual pen's poses at 1 kHz and the commands.
//! * [`bringup`]: `maobi device check`, the first power-on of a pen step by step.
//! * [`server`]: the shared simulator behind the wire protocol over TCP (`maobi
//!   sim-device`): a stand-in for the pen in tests and demos. Its connection loop serves any
//!   [`ProtocolModel`]; `maobi bridge` serves the Phantom through it (the phantom module's
//!   `BridgeModel`).

pub mod api;
pub mod bringup;
pub mod builtin;
pub mod client;
pub mod config_file;
pub mod endpoint;
pub mod journal;
pub mod lane;
pub mod model;
pub mod server;
pub mod sim_model;

pub use api::{
    BrushFrame, Device, DeviceCommand, DeviceError, DeviceStatus, GuideFrame, HandInput, LinkReport,
};
pub use builtin::{SimClock, SimCore, SimDevice};
pub use client::{identify, probe_serial_ports, LinkDevice, LinkOptions, LINK_TIMEOUT};
pub use endpoint::{available_serial_ports, serial_ports, Conn, Endpoint, PortInfo, UsbIds};
pub use model::{BrushChoice, ModelKind};
pub use server::{ProtocolModel, SimDeviceOptions, SimDeviceServer};
pub use sim_model::SimModel;
