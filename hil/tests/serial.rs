//! Backend `serial` without hardware: the host session over a pseudo-terminal pair
//! (`serialport::TTYPort::pair`) against a fake device thread that speaks the protocol and
//! runs the shared brush model as the firmware does. (Not run against a real pen here.)

use std::io::{Read, Write};
use std::path::Path;
use std::time::{Duration, Instant};

use hil::link::{Session, StreamOptions};
use hil::run::run_session;
use maobi::poses::PoseTrack;
use maobi_shared::protocol::{
    encode_raw, BrushState, Capabilities, DeviceInfo, DeviceMsg, DeviceRx, HostMsg, Message,
    Version, DEVICE_MSG_MAX, DEVICE_TO_HOST, PROTOCOL_VERSION,
};
use maobi_shared::{presets, Brush, Fx};
use serialport::{SerialPort, TTYPort};

fn pair() -> Option<(TTYPort, TTYPort)> {
    match TTYPort::pair() {
        Ok(p) => Some(p),
        Err(e) => {
            eprintln!("SKIPPED: no pseudo-terminals here ({e})");
            None
        }
    }
}

fn write_msg(port: &mut TTYPort, m: &DeviceMsg) {
    let mut buf = vec![0u8; DeviceMsg::MAX_FRAME];
    let n = m.encode(&mut buf).unwrap();
    port.write_all(&buf[..n]).unwrap();
}

/// A device: hello, pong, and a state after every pose (the first pose places the brush).
fn fake_device(mut port: TTYPort, run_for: Duration) {
    port.set_timeout(Duration::from_millis(5)).unwrap();
    let mut rx = DeviceRx::new();
    let mut brush: Option<Brush<Fx>> = None;
    let mut tick = 0u32;
    let mut buf = [0u8; 256];
    let end = Instant::now() + run_for;
    while Instant::now() < end {
        let n = match port.read(&mut buf) {
            Ok(n) => n,
            Err(_) => continue,
        };
        let msgs: Vec<_> = rx.feed(&buf[..n]).filter_map(Result::ok).collect();
        for m in msgs {
            match m {
                HostMsg::Hello(_) => {
                    brush = None;
                    let info = DeviceInfo::new(
                        "fake-serial",
                        Version::default(),
                        Capabilities::VIRTUAL_PEN,
                        3.3,
                        0.88,
                    );
                    write_msg(&mut port, &DeviceMsg::Hello(info));
                }
                HostMsg::Ping { seq } => write_msg(&mut port, &DeviceMsg::Pong { seq }),
                HostMsg::Pose(s) => {
                    tick += 1;
                    let b = match brush.as_mut() {
                        None => brush.insert(Brush::new(presets::LARGE, s.pose()).unwrap()),
                        Some(b) => {
                            b.tick(s.pose());
                            b
                        }
                    };
                    let st = BrushState::from_brush(
                        b,
                        tick,
                        s.seq,
                        Default::default(),
                        Default::default(),
                    );
                    write_msg(&mut port, &DeviceMsg::State(st));
                }
                _ => {}
            }
        }
    }
}

#[test]
fn serial_backend_streams_and_checks_against_a_fake_device() {
    let Some((host, dev)) = pair() else { return };
    let t = std::thread::spawn(move || fake_device(dev, Duration::from_secs(60)));
    let track = PoseTrack::from_path(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/poses/hook.csv"),
    )
    .unwrap();
    let mut s = Session::new(host).unwrap();
    let r = run_session(&mut s, &track, StreamOptions::default()).unwrap();
    println!("{}", r.render());
    assert!(r.passed(), "{}", r.render());
    drop(s);
    drop(t);
}

#[test]
fn serial_backend_names_a_protocol_version_mismatch() {
    let Some((host, mut dev)) = pair() else {
        return;
    };
    let t = std::thread::spawn(move || {
        // Whatever the host sends, answer with a frame of the next protocol version.
        let mut buf = [0u8; 64];
        dev.set_timeout(Duration::from_millis(500)).unwrap();
        let _ = dev.read(&mut buf);
        let mut out = [0u8; 64];
        let next = PROTOCOL_VERSION + 1;
        let n = encode_raw(&[next, DEVICE_TO_HOST, 0], DEVICE_MSG_MAX, &mut out).unwrap();
        dev.write_all(&out[..n]).unwrap();
        std::thread::sleep(Duration::from_secs(2));
    });
    let mut s = Session::new(host).unwrap();
    let err = s
        .handshake(Duration::from_secs(5), &mut vec![])
        .unwrap_err()
        .to_string();
    let (theirs, ours) = (
        format!("protocol version {}", PROTOCOL_VERSION + 1),
        format!("this host {PROTOCOL_VERSION}"),
    );
    assert!(err.contains(&theirs) && err.contains(&ours), "{err}");
    t.join().unwrap();
}
