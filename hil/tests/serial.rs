//! Backend `serial` without hardware: the host session over a pseudo-terminal pair
//! (`serialport::TTYPort::pair`) against a fake device thread that speaks the protocol and
//! runs the shared brush model as the firmware does. (Not run against a real pen here.)

mod common;

use std::io::{Read, Write};
use std::path::Path;
use std::time::Duration;

use common::{fake_device, pair};
use hil::run::run_session;
use hil::session::{Session, StreamOptions};
use maobi::poses::PoseTrack;
use maobi_shared::protocol::{encode_raw, DEVICE_MSG_MAX, DEVICE_TO_HOST, PROTOCOL_VERSION};
use serialport::SerialPort;

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
        let n = encode_raw(
            &[PROTOCOL_VERSION + 1, DEVICE_TO_HOST, 0],
            DEVICE_MSG_MAX,
            &mut out,
        )
        .unwrap();
        dev.write_all(&out[..n]).unwrap();
        std::thread::sleep(Duration::from_secs(2));
    });
    let mut s = Session::new(host).unwrap();
    let err = s
        .handshake(Duration::from_secs(5), &mut vec![])
        .unwrap_err()
        .to_string();
    assert!(
        err.contains(&format!("protocol version {}", PROTOCOL_VERSION + 1))
            && err.contains(&format!("this host {PROTOCOL_VERSION}")),
        "{err}"
    );
    t.join().unwrap();
}
