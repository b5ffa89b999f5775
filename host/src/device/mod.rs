//! Devices over the wire protocol ([`maobi_shared::protocol`]), for the GUI and the Phantom
//! bridge.
//!
//! * [`endpoint`]: where a device is (`tcp:HOST:PORT`, `serial:PATH`) and opening a byte
//!   stream to it; serial port listing.
//! * [`client`]: [`client::LinkDevice`], the protocol client behind the GUI's
//!   [`Device`](crate::gui::device::Device) trait: a link thread that connects, shakes hands,
//!   decodes frames and reconnects; a writer thread that streams the virtual pen's poses at
//!   1 kHz and the commands.
//! * [`bringup`]: `maobi device check`, the first power-on of a pen step by step.
//! * [`server`]: the shared simulator behind the wire protocol over TCP (`maobi
//!   sim-device`): a stand-in for the pen in tests and demos. Its connection loop serves any
//!   [`ProtocolModel`]; `maobi bridge` serves the Phantom through it
//!   ([`crate::phantom::device::BridgeModel`]).

pub mod bringup;
pub mod client;
pub mod config_file;
pub mod endpoint;
pub mod server;

pub use client::{identify, probe_serial_ports, LinkDevice, LinkOptions, LINK_TIMEOUT};
pub use endpoint::{available_serial_ports, serial_ports, Conn, Endpoint, PortInfo, UsbIds};
pub use server::{ProtocolModel, SimDeviceOptions, SimDeviceServer};
