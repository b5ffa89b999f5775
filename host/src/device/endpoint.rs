//! Where a device is, and the byte stream to it.

use std::fmt;
use std::io::{self, Read, Write};
use std::net::{TcpStream, ToSocketAddrs};
use std::path::Path;
use std::str::FromStr;
use std::time::Duration;

/// How long a read waits before the link thread checks its clock and its stop flag.
pub const READ_POLL: Duration = Duration::from_millis(20);
/// How long a write may block (a stalled peer) before the link counts as lost.
pub const WRITE_TIMEOUT: Duration = Duration::from_millis(500);
/// How long opening a TCP connection may take.
pub const CONNECT_TIMEOUT: Duration = Duration::from_secs(1);
/// Serial baud rate (ignored by USB CDC and ptys, which run at the link's own speed).
pub const SERIAL_BAUD: u32 = 1_000_000;

/// A device's address.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Endpoint {
    /// `tcp:HOST:PORT`: the QEMU board's UART bridged to TCP, the sim-device, the Phantom
    /// bridge.
    Tcp(String),
    /// `serial:PATH`: the pen on USB serial (`/dev/ttyACM0`, `COM3`).
    Serial(String),
}

impl fmt::Display for Endpoint {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Endpoint::Tcp(a) => write!(f, "tcp:{a}"),
            Endpoint::Serial(p) => write!(f, "serial:{p}"),
        }
    }
}

impl FromStr for Endpoint {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        if let Some(addr) = s.strip_prefix("tcp:") {
            match addr.rsplit_once(':') {
                Some((host, port)) if !host.is_empty() && port.parse::<u16>().is_ok() => {
                    Ok(Endpoint::Tcp(addr.to_string()))
                }
                _ => Err(format!(
                    "`{s}`: expected tcp:HOST:PORT, e.g. tcp:127.0.0.1:7878"
                )),
            }
        } else if let Some(path) = s.strip_prefix("serial:") {
            if path.is_empty() {
                Err(format!(
                    "`{s}`: expected serial:PATH, e.g. serial:/dev/ttyACM0"
                ))
            } else {
                Ok(Endpoint::Serial(path.to_string()))
            }
        } else {
            Err(format!("`{s}`: expected sim, tcp:HOST:PORT or serial:PATH"))
        }
    }
}

/// A read that ended without bytes but without failing: the read timeout ran out, a
/// non-blocking stream had nothing yet, or a signal interrupted it. The reader reads again.
pub fn nothing_to_read_yet(e: &io::Error) -> bool {
    matches!(
        e.kind(),
        io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut | io::ErrorKind::Interrupted
    )
}

/// A bidirectional byte stream to a device; reads time out after [`READ_POLL`].
pub trait Conn: Read + Write + Send {
    /// A second handle on the same stream (one thread reads, another writes).
    fn try_clone_conn(&self) -> io::Result<Box<dyn Conn>>;
    /// Makes a blocked read or write in another handle return (best effort).
    fn shut(&self) {}
}

impl Conn for TcpStream {
    fn try_clone_conn(&self) -> io::Result<Box<dyn Conn>> {
        Ok(Box::new(self.try_clone()?))
    }
    fn shut(&self) {
        let _ = self.shutdown(std::net::Shutdown::Both);
    }
}

/// A serial port as a [`Conn`].
pub struct SerialConn(pub Box<dyn serialport::SerialPort>);

impl Read for SerialConn {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        self.0.read(buf)
    }
}

impl Write for SerialConn {
    /// A serial port has one timeout for reads and writes, set to [`READ_POLL`] for the
    /// reads; a write may block as long as a TCP write does ([`WRITE_TIMEOUT`]) before it
    /// fails, so a peer that is slow to read for a moment (a busy machine) does not end the
    /// session.
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        let end = std::time::Instant::now() + WRITE_TIMEOUT;
        loop {
            match self.0.write(buf) {
                Err(e)
                    if e.kind() == io::ErrorKind::TimedOut && std::time::Instant::now() < end => {}
                r => return r,
            }
        }
    }
    fn flush(&mut self) -> io::Result<()> {
        self.0.flush()
    }
}

impl Conn for SerialConn {
    fn try_clone_conn(&self) -> io::Result<Box<dyn Conn>> {
        Ok(Box::new(SerialConn(
            self.0.try_clone().map_err(io::Error::other)?,
        )))
    }
}

impl Endpoint {
    /// Opens the stream (reads time out after [`READ_POLL`]).
    pub fn open(&self) -> io::Result<Box<dyn Conn>> {
        match self {
            Endpoint::Tcp(addr) => {
                let mut last = io::Error::new(io::ErrorKind::NotFound, "no address");
                for a in addr.to_socket_addrs()? {
                    match TcpStream::connect_timeout(&a, CONNECT_TIMEOUT) {
                        Ok(s) => {
                            s.set_nodelay(true)?;
                            s.set_read_timeout(Some(READ_POLL))?;
                            s.set_write_timeout(Some(WRITE_TIMEOUT))?;
                            return Ok(Box::new(s));
                        }
                        Err(e) => last = e,
                    }
                }
                Err(last)
            }
            Endpoint::Serial(path) => {
                let mut port = serial_settings(path).open().map_err(io::Error::other)?;
                prepare_serial(&mut port);
                Ok(Box::new(SerialConn(port)))
            }
        }
    }
}

/// How a pen's serial port is opened: [`SERIAL_BAUD`], reads timing out after [`READ_POLL`],
/// and DTR asserted on open.
///
/// DTR (data terminal ready) is how a USB CDC-ACM device knows a program has the port
/// open. Today's Black Pill firmware answers whatever DTR says
/// (`firmware/src/blackpill/usb.rs`); earlier images discarded what they would send until
/// the host asserted it, so the host asserts it for them. Linux asserts DTR when a tty is
/// opened; Windows does not, and serialport leaves it as the system has it unless told.
/// A port that answers nothing at all is named for this by `maobi device check`.
pub fn serial_settings(path: &str) -> serialport::SerialPortBuilder {
    serialport::new(path, SERIAL_BAUD)
        .timeout(READ_POLL)
        .dtr_on_open(true)
}

/// The modem-control lines and buffers of an open serial port: what [`prepare_serial`]
/// touches, so that its sequence is tested without a port.
pub trait SerialLines {
    fn set_dtr(&mut self, on: bool) -> serialport::Result<()>;
    fn set_rts(&mut self, on: bool) -> serialport::Result<()>;
    fn clear_buffers(&mut self) -> serialport::Result<()>;
}

impl SerialLines for Box<dyn serialport::SerialPort> {
    fn set_dtr(&mut self, on: bool) -> serialport::Result<()> {
        self.write_data_terminal_ready(on)
    }
    fn set_rts(&mut self, on: bool) -> serialport::Result<()> {
        self.write_request_to_send(on)
    }
    fn clear_buffers(&mut self) -> serialport::Result<()> {
        self.clear(serialport::ClearBuffer::All)
    }
}

/// Right after a pen's port is opened: DTR asserted (again: the builder's
/// [`serial_settings`] asks for it on open, which some backends do only on a best-effort
/// basis), RTS asserted as CDC hosts do, then stale bytes from an earlier session dropped
/// (they would only count as errors). Each step is best effort: a pseudo-terminal (the
/// tests' stand-in for a pen) has no modem lines and refuses them, and an older pen that
/// does not answer without DTR shows as a handshake that gets not one byte back.
pub fn prepare_serial(port: &mut impl SerialLines) {
    let _ = port.set_dtr(true);
    let _ = port.set_rts(true);
    let _ = port.clear_buffers();
}

/// A serial port and, for a USB one, its IDs.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PortInfo {
    /// The name to open (`/dev/ttyACM0`, `COM3`).
    pub name: String,
    pub usb: Option<UsbIds>,
}

/// What a USB serial port says of itself.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct UsbIds {
    pub vid: u16,
    pub pid: u16,
    pub product: Option<String>,
    pub serial: Option<String>,
}

impl PortInfo {
    /// The port enumerates with Maobi's USB IDs ([`maobi_shared::protocol::USB_VID`],
    /// [`USB_PID`](maobi_shared::protocol::USB_PID)). Only the handshake proves it.
    pub fn is_maobi(&self) -> bool {
        self.usb.as_ref().is_some_and(|u| {
            u.vid == maobi_shared::protocol::USB_VID && u.pid == maobi_shared::protocol::USB_PID
        })
    }

    /// `/dev/ttyACM0 (Maobi pen, 1209:0001)`, for the port list.
    pub fn label(&self) -> String {
        match &self.usb {
            Some(u) => format!(
                "{} ({}{:04x}:{:04x})",
                self.name,
                u.product
                    .as_deref()
                    .map(|p| format!("{p}, "))
                    .unwrap_or_default(),
                u.vid,
                u.pid
            ),
            None => self.name.clone(),
        }
    }
}

/// Serial ports on this machine, Maobi's USB IDs first. `serialport` reports the USB IDs on
/// every platform (on Linux it reads them from sysfs when built, as here, without libudev, so
/// the app needs no system library).
pub fn serial_ports() -> Vec<PortInfo> {
    // serialport's sysfs scan assumes /sys/class/tty exists (it panics otherwise); a container
    // without it simply has no serial ports.
    if cfg!(target_os = "linux") && !Path::new("/sys/class/tty").is_dir() {
        return Vec::new();
    }
    let mut ports: Vec<PortInfo> = serialport::available_ports()
        .unwrap_or_default()
        .into_iter()
        .map(PortInfo::from)
        .collect();
    // Stable: Maobi's ports first, then USB ones, then the rest, each in the OS's order.
    ports.sort_by_key(|p| (!p.is_maobi(), p.usb.is_none()));
    ports
}

impl From<serialport::SerialPortInfo> for PortInfo {
    fn from(p: serialport::SerialPortInfo) -> PortInfo {
        let usb = match p.port_type {
            serialport::SerialPortType::UsbPort(u) => Some(UsbIds {
                vid: u.vid,
                pid: u.pid,
                product: u.product,
                serial: u.serial_number,
            }),
            _ => None,
        };
        PortInfo {
            name: p.port_name,
            usb,
        }
    }
}

/// Serial port names, Maobi's USB IDs first (see [`serial_ports`]).
pub fn available_serial_ports() -> Vec<String> {
    serial_ports().into_iter().map(|p| p.name).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_pen_port_is_opened_with_dtr_asserted() {
        let s = serial_settings("/dev/ttyACM0");
        // DTR set to on, not left as the system has it (Windows: off).
        assert_ne!(s, s.clone().preserve_dtr_on_open());
        assert_ne!(s, s.clone().dtr_on_open(false));
        assert_eq!(s, s.clone().dtr_on_open(true));
        assert_eq!(
            s,
            serialport::new("/dev/ttyACM0", SERIAL_BAUD)
                .timeout(READ_POLL)
                .dtr_on_open(true)
        );
    }

    /// Records what [`prepare_serial`] does to the lines, failing as a pty does.
    #[derive(Default)]
    struct Lines {
        calls: Vec<&'static str>,
        refuse: bool,
    }

    impl SerialLines for Lines {
        fn set_dtr(&mut self, on: bool) -> serialport::Result<()> {
            self.calls.push(if on { "dtr on" } else { "dtr off" });
            self.result()
        }
        fn set_rts(&mut self, on: bool) -> serialport::Result<()> {
            self.calls.push(if on { "rts on" } else { "rts off" });
            self.result()
        }
        fn clear_buffers(&mut self) -> serialport::Result<()> {
            self.calls.push("clear");
            self.result()
        }
    }

    impl Lines {
        fn result(&self) -> serialport::Result<()> {
            if self.refuse {
                Err(serialport::Error::new(
                    serialport::ErrorKind::Unknown,
                    "not a tty with modem lines",
                ))
            } else {
                Ok(())
            }
        }
    }

    #[test]
    fn opening_asserts_dtr_and_rts_then_drops_stale_bytes() {
        for refuse in [false, true] {
            let mut lines = Lines {
                refuse,
                ..Lines::default()
            };
            prepare_serial(&mut lines);
            // Every step runs even where the lines are refused (a pty).
            assert_eq!(
                lines.calls,
                ["dtr on", "rts on", "clear"],
                "refuse {refuse}"
            );
        }
    }

    /// What serialport reports of a port becomes the app's port entry: the pen by its IDs,
    /// other ports without.
    #[test]
    fn ports_take_their_usb_ids_from_serialport() {
        let pen: PortInfo = serialport::SerialPortInfo {
            port_name: "/dev/ttyACM0".into(),
            port_type: serialport::SerialPortType::UsbPort(serialport::UsbPortInfo {
                vid: 0x1209,
                pid: 0x0001,
                serial_number: Some("E66118604B1F".into()),
                manufacturer: None,
                product: Some("Maobi pen".into()),
            }),
        }
        .into();
        assert!(pen.is_maobi());
        assert_eq!(pen.label(), "/dev/ttyACM0 (Maobi pen, 1209:0001)");
        assert_eq!(
            pen.usb.as_ref().unwrap().serial.as_deref(),
            Some("E66118604B1F")
        );
        let uart: PortInfo = serialport::SerialPortInfo {
            port_name: "/dev/ttyS0".into(),
            port_type: serialport::SerialPortType::Unknown,
        }
        .into();
        assert!(!uart.is_maobi());
        assert_eq!(uart.label(), "/dev/ttyS0");
    }
}
