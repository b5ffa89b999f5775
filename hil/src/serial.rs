//! Backend `serial`: the device link over a serial port (the pen's USB CDC port on real
//! hardware). The session code is the QEMU backend's ([`crate::session`]).

use std::path::Path;
use std::time::Duration;

use anyhow::{Context, Result};
use serialport::{SerialPort, TTYPort};

use crate::session::Transport;

/// Line rate asked of the port (a USB CDC port ignores it).
pub const BAUD: u32 = 1_000_000;

/// Opens `path` raw, 8N1, no flow control, DTR asserted (as `maobi` opens a pen's port:
/// firmware images before the pen answered whatever DTR says sent nothing without it).
pub fn open(path: &Path) -> Result<TTYPort> {
    let name = path.to_string_lossy();
    serialport::new(name.as_ref(), BAUD)
        .timeout(Duration::from_millis(2))
        .dtr_on_open(true)
        .open_native()
        .with_context(|| format!("cannot open serial port {}", path.display()))
}

impl Transport for TTYPort {
    fn set_read_timeout(&mut self, t: Duration) -> Result<()> {
        self.set_timeout(t)?;
        Ok(())
    }
}
