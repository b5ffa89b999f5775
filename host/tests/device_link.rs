//! The GUI's protocol backend ([`LinkDevice`]) against the simulated protocol device over TCP
//! (and a pty): handshake, poses in and states out, ink from the received geometry, garbage
//! on the link, the peer dying mid-stroke and coming back, a peer of another protocol version.

use std::io::{Read, Write};
use std::net::{TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use maobi::device::{BrushFrame, Device, DeviceCommand, DeviceStatus, HandInput};
use maobi::device::{
    Endpoint, LinkDevice, LinkOptions, SimDeviceOptions, SimDeviceServer, LINK_TIMEOUT,
};
use maobi::gui::start_hand;
use maobi::raster::{Canvas, Frame};
use maobi::render::Inker;
use maobi_shared::params::MAX_LAYERS;
use maobi_shared::presets;
use maobi_shared::protocol::{
    encode_raw, DeviceMsg, Message, CRC_LEN, DEVICE_TO_HOST, PROTOCOL_VERSION,
};

mod common;

fn length() -> f64 {
    presets::by_name("large").unwrap().length_mm as f64
}

fn server(addr: &str, state_hz: u32) -> SimDeviceServer {
    SimDeviceServer::spawn(
        addr,
        SimDeviceOptions {
            state_hz,
            ..Default::default()
        },
    )
    .expect("the sim-device starts")
}

fn link(endpoint: Endpoint) -> LinkDevice {
    LinkDevice::new(LinkOptions::new(endpoint, start_hand(length()))).unwrap()
}

/// The GUI's paper, reduced to what these tests check.
struct Paper {
    inker: Inker,
    canvas: Canvas,
    frames: usize,
    touching: usize,
    kept: Vec<BrushFrame>,
    kept_last_tick: Option<u64>,
}

impl Paper {
    fn new() -> Paper {
        let frame = Frame::covering([-60.0, -60.0], [60.0, 60.0], 0.0, 4.0);
        Paper {
            inker: Inker::new(frame, MAX_LAYERS),
            canvas: Canvas::new(frame.width, frame.height),
            frames: 0,
            touching: 0,
            kept: Vec::new(),
            kept_last_tick: None,
        }
    }
    fn ink(&mut self, frames: &[BrushFrame]) {
        for f in frames {
            self.frames += 1;
            // A device may repeat its last state when no pose came in time (its state timer
            // fired); stamping it again changes nothing (ink combines by max), but it is
            // the same tick touching, not another.
            let repeat = self.kept_last_tick == Some(f.tick);
            self.kept_last_tick = Some(f.tick);
            if self.inker.stamp_geometry(&f.geometry(), &mut self.canvas) && !repeat {
                self.touching += 1;
            }
        }
    }
}

/// Polls `dev` for `dur`, inking what arrives.
fn pump(dev: &mut dyn Device, paper: &mut Paper, dur: Duration) {
    let end = Instant::now() + dur;
    let mut frames = Vec::new();
    while Instant::now() < end {
        frames.clear();
        dev.poll(&mut frames);
        paper.ink(&frames);
        std::thread::sleep(Duration::from_millis(10));
    }
}

fn wait_for(dev: &dyn Device, dur: Duration, what: impl Fn(&DeviceStatus) -> bool) -> bool {
    let end = Instant::now() + dur;
    while Instant::now() < end {
        if what(&dev.status()) {
            return true;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    what(&dev.status())
}

fn hand(x: f64, press_mm: f64) -> HandInput {
    HandInput {
        x,
        y: 0.0,
        z: length() - press_mm,
        tilt_x_deg: 0.0,
        tilt_y_deg: 0.0,
    }
}

/// Presses the brush 8 mm into the paper at x = `from` and drags it to `to`.
fn stroke(dev: &mut dyn Device, paper: &mut Paper, from: f64, to: f64) {
    dev.send(DeviceCommand::Hand(hand(from, -6.0))).unwrap();
    pump(dev, paper, Duration::from_millis(150));
    dev.send(DeviceCommand::Hand(hand(from, 8.0))).unwrap();
    pump(dev, paper, Duration::from_millis(150));
    dev.send(DeviceCommand::Hand(hand(to, 8.0))).unwrap();
    pump(dev, paper, Duration::from_millis(300));
}

#[test]
fn handshake_then_poses_in_states_out_and_ink() {
    let srv = server("127.0.0.1:0", 120);
    let mut dev = link(Endpoint::Tcp(srv.addr().to_string()));
    dev.connect().expect("connects");
    let s = dev.status();
    assert!(s.connected);
    assert_eq!(s.protocol_version, Some(u32::from(PROTOCOL_VERSION)));
    assert!(
        s.firmware_version
            .as_deref()
            .unwrap()
            .contains("maobi-sim-device"),
        "{s:?}"
    );
    let mut paper = Paper::new();
    stroke(&mut dev, &mut paper, -10.0, 10.0);
    let s = dev.status();
    let l = s.link.clone().unwrap();
    assert!(
        paper.frames > 40,
        "states at ~120 Hz: {} in 0.6 s",
        paper.frames
    );
    assert!(
        paper.touching > 10,
        "the pressed brush touched: {}",
        paper.touching
    );
    assert!(
        paper.canvas.ink_fraction() > 0.001,
        "ink from the received geometry: {}",
        paper.canvas.ink_fraction()
    );
    assert_eq!(l.rx.dropped(), 0, "a clean link drops nothing: {:?}", l.rx);
    assert_eq!(s.frames_dropped, 0);
    // Parameters were read from the device.
    assert_eq!(s.params, presets::by_name("large").unwrap());
    // A rejected parameter never reaches the link; a valid one does.
    assert!(dev
        .send(DeviceCommand::SetParam(
            maobi_shared::ParamId::Layers,
            1000.0
        ))
        .is_err());
    dev.disconnect();
    assert!(!dev.status().connected);
}

/// Forwards a client to `upstream`, injecting `garbage` into the device-to-host stream
/// every few chunks.
fn garbage_proxy(upstream: String, garbage: Vec<Vec<u8>>) -> (String, Arc<AtomicBool>) {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap().to_string();
    let stop = Arc::new(AtomicBool::new(false));
    let stop2 = stop.clone();
    std::thread::spawn(move || {
        let (client, _) = listener.accept().unwrap();
        let dev = TcpStream::connect(upstream).unwrap();
        let (mut c_rx, mut d_tx) = (client.try_clone().unwrap(), dev.try_clone().unwrap());
        std::thread::spawn(move || {
            let mut buf = [0u8; 4096];
            while let Ok(n) = c_rx.read(&mut buf) {
                if n == 0 || d_tx.write_all(&buf[..n]).is_err() {
                    break;
                }
            }
        });
        let (mut d_rx, mut c_tx) = (dev, client);
        let mut buf = [0u8; 4096];
        let mut k = 0usize;
        while let Ok(n) = d_rx.read(&mut buf) {
            if n == 0 || stop2.load(Ordering::SeqCst) {
                break;
            }
            if c_tx.write_all(&buf[..n]).is_err() {
                break;
            }
            k += 1;
            if k > 20 && k.is_multiple_of(5) {
                let g = &garbage[(k / 5) % garbage.len()];
                if c_tx.write_all(g).is_err() {
                    break;
                }
            }
        }
    });
    (addr, stop)
}

#[test]
fn garbage_oversized_and_corrupt_bytes_are_counted_and_dropped() {
    let srv = server("127.0.0.1:0", 120);
    // A good Pong frame with one byte damaged: a CRC error.
    let mut pong = vec![0u8; DeviceMsg::MAX_FRAME];
    let n = DeviceMsg::Pong { seq: 0x0102_0304 }
        .encode(&mut pong)
        .unwrap();
    pong.truncate(n);
    pong[3] ^= 0x10;
    assert_ne!(pong[3], 0);
    let mut corrupt = vec![0u8];
    corrupt.extend(&pong);
    // 5000 stuffed bytes: more than the 4 KiB a device frame may hold.
    let mut oversized = vec![0u8];
    oversized.extend(std::iter::repeat_n(0x01u8, 5000));
    oversized.push(0);
    // Not COBS: a code byte promising more bytes than come before the delimiter.
    let framing = vec![0u8, 0x09, 0xAA, 0x55, 0x00];
    let (addr, _stop) = garbage_proxy(srv.addr().to_string(), vec![corrupt, oversized, framing]);
    let mut dev = link(Endpoint::Tcp(addr));
    dev.connect().expect("connects through the proxy");
    let mut paper = Paper::new();
    stroke(&mut dev, &mut paper, -10.0, 10.0);
    pump(&mut dev, &mut paper, Duration::from_millis(500));
    let s = dev.status();
    let rx = s.link.clone().unwrap().rx;
    assert!(s.connected, "garbage does not end the session: {s:?}");
    assert!(rx.crc_errors > 0, "{rx:?}");
    assert!(rx.oversized_frames > 0, "{rx:?}");
    assert!(rx.framing_errors > 0, "{rx:?}");
    assert!(s.frames_dropped >= u64::from(rx.dropped()), "{s:?}");
    assert!(rx.frames_ok > 80, "good frames still arrive: {rx:?}");
    assert!(paper.canvas.ink_fraction() > 0.001);
}

#[test]
fn peer_dies_mid_stroke_then_the_link_reconnects() {
    let mut srv = server("127.0.0.1:0", 120);
    let addr = srv.addr().to_string();
    let mut dev = link(Endpoint::Tcp(addr.clone()));
    dev.connect().expect("connects");
    let mut paper = Paper::new();
    dev.send(DeviceCommand::Hand(hand(-20.0, 8.0))).unwrap();
    pump(&mut dev, &mut paper, Duration::from_millis(300));
    dev.send(DeviceCommand::Hand(hand(20.0, 8.0))).unwrap();
    pump(&mut dev, &mut paper, Duration::from_millis(40));
    let ink_before = paper.canvas.ink_area_px();
    assert!(ink_before > 0.0, "inking when the peer dies");
    let lost_at = Instant::now();
    srv.stop();
    assert!(
        wait_for(&dev, LINK_TIMEOUT * 3, |s| !s.connected),
        "the loss is noticed"
    );
    let s = dev.status();
    let l = s.link.clone().unwrap();
    assert!(l.state.contains("lost"), "{}", l.state);
    assert_eq!(l.lost, 1);
    eprintln!("loss noticed after {:?}: {}", lost_at.elapsed(), l.state);
    // Commands other than the hand are refused while the link is down.
    assert!(dev.send(DeviceCommand::Dip(1.0)).is_err());
    // What arrived before the loss is inked; then nothing changes: the canvas is kept.
    pump(&mut dev, &mut paper, Duration::from_millis(50));
    let ink_at_loss = paper.canvas.ink_area_px();
    assert!(ink_at_loss >= ink_before);
    pump(&mut dev, &mut paper, Duration::from_millis(300));
    assert_eq!(
        paper.canvas.ink_area_px(),
        ink_at_loss,
        "the canvas is kept"
    );
    // The peer comes back on the same port.
    let _srv2 = server(&addr, 120);
    assert!(
        wait_for(&dev, Duration::from_secs(5), |s| s.connected),
        "reconnects: {:?}",
        dev.status().link
    );
    let frames_before = paper.frames;
    stroke(&mut dev, &mut paper, 20.0, 35.0);
    // The virtual pen restarted where the new device's brush was: no jump, no fault.
    assert!(dev.status().faults.is_empty(), "{:?}", dev.status().faults);
    let l = dev.status().link.unwrap();
    assert_eq!(l.sessions, 2, "{l:?}");
    assert!(paper.frames > frames_before + 40, "states flow again");
    assert!(paper.canvas.ink_area_px() > ink_at_loss, "and ink again");
}

#[test]
fn version_mismatch_is_a_clear_error() {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap().to_string();
    std::thread::spawn(move || {
        for stream in listener.incoming() {
            let Ok(mut s) = stream else { break };
            let mut buf = [0u8; 512];
            let _ = s.read(&mut buf);
            // A frame of the next protocol version: version byte, direction, some message.
            let content = [PROTOCOL_VERSION + 1, DEVICE_TO_HOST, 0, 2, 0, 0];
            let mut out = [0u8; 64];
            let n = encode_raw(&content, content.len() + CRC_LEN, &mut out).unwrap();
            let _ = s.write_all(&out[..n]);
            std::thread::sleep(Duration::from_millis(200));
        }
    });
    let mut dev = link(Endpoint::Tcp(addr));
    let err = dev
        .connect()
        .expect_err("a device of another version is refused");
    let msg = err.to_string();
    assert!(msg.contains("protocol version mismatch"), "{msg}");
    let theirs = format!("peer speaks {}", PROTOCOL_VERSION + 1);
    assert!(msg.contains(&theirs), "{msg}");
    let s = dev.status();
    assert!(!s.connected);
    let l = s.link.unwrap();
    assert!(l.rx.version_errors >= 1, "{l:?}");
    assert!(l.state.contains("version mismatch"), "{}", l.state);
    dev.disconnect();
}

#[test]
fn nobody_listening_says_so_and_keeps_trying() {
    let port = {
        let l = TcpListener::bind("127.0.0.1:0").unwrap();
        l.local_addr().unwrap().port()
    };
    let addr = format!("127.0.0.1:{port}");
    let mut dev = link(Endpoint::Tcp(addr.clone()));
    let err = dev.connect().expect_err("nothing listens").to_string();
    assert!(err.contains("cannot open"), "{err}");
    let _srv = server(&addr, 120);
    assert!(
        wait_for(&dev, Duration::from_secs(5), |s| s.connected),
        "connects once the device is there"
    );
}

#[test]
fn endpoints_parse() {
    assert_eq!(
        "tcp:127.0.0.1:7878".parse::<Endpoint>(),
        Ok(Endpoint::Tcp("127.0.0.1:7878".into()))
    );
    assert_eq!(
        "serial:/dev/ttyACM0".parse::<Endpoint>(),
        Ok(Endpoint::Serial("/dev/ttyACM0".into()))
    );
    assert!("tcp:nohost".parse::<Endpoint>().is_err());
    assert!("usb:1".parse::<Endpoint>().is_err());
    assert!("serial:".parse::<Endpoint>().is_err());
}

/// Replays `track` through `dev` and inks the replay's frames; returns the paper.
fn replay_through(dev: &mut dyn Device, track: maobi::poses::PoseTrack) -> Paper {
    let mut paper = Paper::new();
    let done0 = dev.status().replays_done;
    dev.send(DeviceCommand::Replay(Arc::new(track))).unwrap();
    let end = Instant::now() + Duration::from_secs(30);
    let mut frames = Vec::new();
    loop {
        frames.clear();
        dev.poll(&mut frames);
        let replay: Vec<BrushFrame> = frames.drain(..).filter(|f| f.replaying).collect();
        paper.ink(&replay);
        paper.kept.extend(replay);
        let s = dev.status();
        if s.replays_done > done0 && !s.replaying {
            // The last frames may have landed between the poll above and the status: the
            // app polls on every frame and would ink them next, so take them too.
            frames.clear();
            dev.poll(&mut frames);
            let replay: Vec<BrushFrame> = frames.drain(..).filter(|f| f.replaying).collect();
            paper.ink(&replay);
            paper.kept.extend(replay);
            break;
        }
        assert!(Instant::now() < end, "the replay finishes: {s:?}");
        std::thread::sleep(Duration::from_millis(2));
    }
    paper
}

/// Same poses, same geometry, same ink: a replay through the TCP backend (every state sent)
/// inks the canvas exactly as the built-in simulator does.
#[test]
fn replay_over_tcp_inks_like_the_built_in_simulator() {
    use maobi::device::builtin::{SimClock, SimDevice};
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/poses/hook.csv");
    let track = || maobi::poses::PoseTrack::from_path(&path).unwrap();

    let mut sim = SimDevice::new(SimClock::Stepped(20), "large", start_hand(length())).unwrap();
    sim.connect().unwrap();
    let local = replay_through(&mut sim, track());

    let srv = server("127.0.0.1:0", 1000);
    let mut dev = link(Endpoint::Tcp(srv.addr().to_string()));
    dev.connect().unwrap();
    let remote = replay_through(&mut dev, track());

    assert!(local.touching > 100, "the hook touches the paper");
    assert_eq!(
        remote.touching, local.touching,
        "the same ticks touch the paper"
    );
    assert!(local.canvas.ink_fraction() > 0.001);
    // Bit-identical geometry, tick by tick (the remote side may repeat a state).
    let mut remote_frames = remote.kept.clone();
    remote_frames.dedup_by(|a, b| a.tick == b.tick);
    assert_eq!(remote_frames.len(), local.kept.len());
    for (k, (r, l)) in remote_frames.iter().zip(&local.kept).enumerate() {
        let fx = |f: &BrushFrame| f.pose.pos.cast::<maobi_shared::Fx>().to_f64();
        assert_eq!(fx(r), fx(l), "handle at replay tick {k}");
        assert!(
            r.spine == l.spine && r.layers == l.layers,
            "geometry at replay tick {k}"
        );
    }
    let (a, b) = (remote.canvas.ink(), local.canvas.ink());
    assert_eq!(a.len(), b.len());
    let differ = a.iter().zip(b).filter(|(x, y)| x != y).count();
    let worst = a
        .iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0f32, f32::max);
    assert_eq!(
        differ,
        0,
        "same geometry, same ink: {differ} pixels differ, by up to {worst}; ink {} vs {}",
        remote.canvas.ink_fraction(),
        local.canvas.ink_fraction()
    );
    assert_eq!(dev.status().link.unwrap().rx.dropped(), 0);
}

/// A device that answers the handshake and then says nothing more.
#[test]
fn a_silent_peer_counts_as_lost() {
    use maobi_shared::protocol::{Capabilities, DeviceInfo, Version};
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap().to_string();
    std::thread::spawn(move || {
        let mut held = Vec::new();
        for stream in listener.incoming() {
            let Ok(mut s) = stream else { break };
            let mut buf = [0u8; 512];
            let _ = s.read(&mut buf);
            let info = DeviceInfo::new(
                "mute-board",
                Version::default(),
                Capabilities::VIRTUAL_PEN,
                1.0,
                0.5,
            );
            let mut out = vec![0u8; DeviceMsg::MAX_FRAME];
            let n = DeviceMsg::Hello(info).encode(&mut out).unwrap();
            let _ = s.write_all(&out[..n]);
            held.push(s);
        }
    });
    let mut dev = link(Endpoint::Tcp(addr));
    dev.connect().expect("the handshake succeeds");
    assert!(dev
        .status()
        .firmware_version
        .unwrap()
        .contains("mute-board"));
    let track = maobi::poses::PoseTrack::from_path(
        &std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/poses/hook.csv"),
    )
    .unwrap();
    // A virtual pen takes replays.
    assert!(dev.send(DeviceCommand::Replay(Arc::new(track))).is_ok());
    let t = Instant::now();
    assert!(
        wait_for(&dev, Duration::from_secs(3), |s| !s.connected),
        "silence ends the session"
    );
    let waited = t.elapsed();
    assert!(
        waited >= LINK_TIMEOUT - Duration::from_millis(50),
        "{waited:?}"
    );
    let s = dev.status();
    let l = s.link.unwrap();
    assert!(l.state.contains("no data"), "{}", l.state);
    assert!(!s.replaying, "a replay the loss cut short has ended");
}

/// A device with its own sensors takes no replays (there is no virtual pen to drive).
#[test]
fn replays_need_a_virtual_pen() {
    use maobi_shared::protocol::{Capabilities, DeviceInfo, Version};
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap().to_string();
    std::thread::spawn(move || {
        let Ok((mut s, _)) = listener.accept() else {
            return;
        };
        let mut buf = [0u8; 512];
        let _ = s.read(&mut buf);
        let info = DeviceInfo::new(
            "maobi-pen-r1",
            Version::default(),
            Capabilities::REAL_SENSORS | Capabilities::FORCE_OUTPUT,
            3.3,
            0.88,
        );
        let mut out = vec![0u8; DeviceMsg::MAX_FRAME];
        let n = DeviceMsg::Hello(info).encode(&mut out).unwrap();
        let _ = s.write_all(&out[..n]);
        std::thread::sleep(Duration::from_secs(2));
    });
    let mut dev = link(Endpoint::Tcp(addr));
    dev.connect().expect("the handshake succeeds");
    let track = maobi::poses::PoseTrack::from_path(
        &std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/poses/hook.csv"),
    )
    .unwrap();
    let err = dev
        .send(DeviceCommand::Replay(Arc::new(track)))
        .expect_err("no virtual pen");
    assert!(err.to_string().contains("virtual-pen"), "{err}");
    assert!(!dev.status().replaying);
}

/// The serial backend over a pty pair, the simulated device on the other end.
#[cfg(unix)]
#[test]
fn serial_backend_over_a_pty() {
    use maobi::device::endpoint::SerialConn;
    use maobi::device::server::serve_stream;
    use serialport::SerialPort;
    let (mut master, slave) = serialport::TTYPort::pair().expect("a pty pair");
    let path = slave.name().expect("the pty has a name");
    // The backend opens the pty by its path (and locks it); this handle, which holds no
    // lock, keeps the pty alive.
    master.set_timeout(Duration::from_millis(1)).unwrap();
    let stop = Arc::new(AtomicBool::new(false));
    let device = {
        let stop = stop.clone();
        std::thread::spawn(move || {
            let _ = serve_stream(
                Box::new(SerialConn(Box::new(master))),
                &SimDeviceOptions::default(),
                &stop,
            );
        })
    };
    let mut dev = link(Endpoint::Serial(path.clone()));
    dev.connect().expect("the device answers on the pty");
    let s = dev.status();
    assert!(s.connected);
    assert!(s.name.contains(&path), "{}", s.name);
    let mut paper = Paper::new();
    stroke(&mut dev, &mut paper, -10.0, 10.0);
    assert!(paper.frames > 40, "{} states", paper.frames);
    assert!(paper.canvas.ink_fraction() > 0.001);
    dev.disconnect();
    stop.store(true, Ordering::SeqCst);
    device.join().unwrap();
    drop(slave);
}

/// Recognising the device by its handshake: the sim-device answers with its board name; a
/// peer that only echoes (a loop-back, a terminal) is not a Maobi device.
#[test]
fn identify_recognises_the_device_by_its_handshake() {
    let srv = server("127.0.0.1:0", 120);
    let info = maobi::device::identify(
        &Endpoint::Tcp(srv.addr().to_string()),
        Duration::from_millis(500),
    )
    .expect("the sim-device answers");
    assert_eq!(info.board.as_str(), "maobi-sim-device");

    let echo = TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = echo.local_addr().unwrap().to_string();
    std::thread::spawn(move || {
        for stream in echo.incoming() {
            let Ok(mut s) = stream else { break };
            let mut buf = [0u8; 512];
            while let Ok(n) = s.read(&mut buf) {
                if n == 0 || s.write_all(&buf[..n]).is_err() {
                    break;
                }
            }
        }
    });
    let err = maobi::device::identify(&Endpoint::Tcp(addr), Duration::from_millis(300))
        .expect_err("an echo is not a device");
    assert!(err.contains("is this a Maobi device?"), "{err}");
}

/// Guided writing over the link: the writer streams the stroke's moving point (one guide
/// sample per pose), the frames show the point sent for their tick and how far the pen is
/// from it, the guide fades in and, after the stroke, fades out and stops; the sim-device's
/// force (the model's plus the guide's, through the output stage) carries the pull.
#[test]
fn guided_writing_streams_the_moving_point_and_frames_show_the_stray() {
    let srv = server("127.0.0.1:0", 1000);
    let mut dev = link(Endpoint::Tcp(srv.addr().to_string()));
    dev.connect().expect("connects");
    dev.send(DeviceCommand::EnableForces(true)).unwrap();
    // The pen hangs where it is (the GUI's pointer does not move); the moving point runs a
    // 30 mm line in 0.5 s from 5 mm beside it, in the air (no brush forces but gravity).
    let z = length() + 10.0;
    let track = common::guide_line(5.0, z);
    dev.send(DeviceCommand::Hand(HandInput {
        z,
        ..hand(0.0, 0.0)
    }))
    .unwrap();
    let mut paper = Paper::new();
    pump(&mut dev, &mut paper, Duration::from_millis(300));
    dev.send(DeviceCommand::Guide(Some(Arc::new(track))))
        .unwrap();
    let end = Instant::now() + Duration::from_millis(2000);
    let mut frames = Vec::new();
    let mut all = Vec::new();
    while Instant::now() < end {
        frames.clear();
        dev.poll(&mut frames);
        all.extend(frames.iter().cloned());
        std::thread::sleep(Duration::from_millis(5));
    }
    dev.disconnect();
    let guided: Vec<_> = all.iter().filter_map(|f| f.guide.map(|g| (f, g))).collect();
    let first = all
        .iter()
        .position(|f| f.guide.is_some())
        .expect("guided frames");
    let last = all.iter().rposition(|f| f.guide.is_some()).unwrap();
    println!(
        "{} frames, {} guided (frames {first}..={last}); largest stray {:.2} mm, largest \
         guide force {:.3} N, peak gain {:.3}",
        all.len(),
        guided.len(),
        guided
            .iter()
            .map(|(_, g)| g.distance_mm)
            .fold(0.0, f64::max),
        guided
            .iter()
            .map(|(_, g)| g.force.iter().map(|c| c * c).sum::<f64>().sqrt())
            .fold(0.0, f64::max),
        guided.iter().map(|(_, g)| g.gain).fold(0.0, f64::max),
    );
    // 500 ticks of stroke and about 300 of fade-out, at 1000 states per second (some
    // skipped by the GUI's frame queue or the sim-device's pacing).
    assert!(guided.len() > 300, "{}", guided.len());
    assert!(
        all[last + 1..].iter().all(|f| f.guide.is_none()),
        "the guide stops after fading out"
    );
    let mut last_gain: f64 = 0.0;
    let mut peak_gain: f64 = 0.0;
    for (f, g) in &guided {
        // The distance is from the frame's pen to the point sent for its tick.
        let p = f.pose.pos.to_f64();
        let d = (0..3)
            .map(|i| (p[i] - g.anchor[i]).powi(2))
            .sum::<f64>()
            .sqrt();
        assert!((d - g.distance_mm).abs() < 1e-9, "{d} vs {}", g.distance_mm);
        assert!(
            g.distance_mm >= 5.0 - 1e-6,
            "the pen stays put, 5 mm beside the line"
        );
        assert!((g.anchor[1] - 5.0).abs() < 1e-6 && g.anchor[0] >= -1e-9);
        assert!(g.anchor[0] <= 30.0 + 1e-6);
        let gf = g.force.iter().map(|c| c * c).sum::<f64>().sqrt();
        assert!(gf <= 0.8 + 1e-6, "{gf}");
        if g.gain > 0.01 {
            assert!(g.force[1] > 0.0, "pulls toward the line: {:?}", g.force);
        }
        // The device's force includes the pull (through the output stage, ramped in).
        if g.gain > 0.5 && f.output == maobi_shared::force::OutputState::Active {
            let along = (0..3).map(|i| f.force_total[i] * g.force[i]).sum::<f64>() / gf;
            assert!(along > 0.5 * gf, "{:?} vs {:?}", f.force_total, g.force);
        }
        peak_gain = peak_gain.max(g.gain);
        last_gain = g.gain;
    }
    assert!(peak_gain > 0.9, "faded in: {peak_gain}");
    assert!(last_gain < 0.05, "faded out: {last_gain}");
    // The point walked the whole line and was held at its end.
    let far = guided.iter().map(|(_, g)| g.anchor[0]).fold(0.0, f64::max);
    assert!((far - 30.0).abs() < 1e-6, "{far}");
}
