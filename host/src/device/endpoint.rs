//! Where a device is, and the byte stream to it.

use std::fmt;
use std::io::{self, Read, Write};
use std::net::{TcpStream, ToSocketAddrs};
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
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        self.0.write(buf)
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
                let port = serialport::new(path, SERIAL_BAUD)
                    .timeout(READ_POLL)
                    .open()
                    .map_err(io::Error::other)?;
                // Stale bytes from an earlier session would only count as errors.
                let _ = port.clear(serialport::ClearBuffer::All);
                Ok(Box::new(SerialConn(port)))
            }
        }
    }
}

/// Serial ports on this machine (names only: without libudev there are no USB details);
/// which one is the pen shows when the handshake answers.
pub fn available_serial_ports() -> Vec<String> {
    serialport::available_ports()
        .map(|v| v.into_iter().map(|p| p.port_name).collect())
        .unwrap_or_default()
}
