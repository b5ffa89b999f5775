//! The GUI's protocol backend ([`LinkDevice`]) against the simulated protocol device over TCP
//! (and a pty): handshake, poses in and states out, ink from the received geometry, garbage
//! on the link, the peer dying mid-stroke and coming back, a peer of another protocol version.
//!
//! No check here depends on how fast the machine is: each one waits for the event it needs
//! (the pen at a place, a number of states, a link state, a counter) under [`HANG_GUARD`],
//! which only turns a hang into a failure; a link state the link passes through on its way
//! (lost, then reconnecting) is read with the link thread held there ([`LinkSteps`]). Rates
//! are checked in the device's ticks, not in seconds.

use std::io::{Read, Write};
use std::net::{TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{self, Receiver, Sender};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use maobi::device::{BrushFrame, Device, DeviceCommand, DeviceStatus, HandInput};
use maobi::device::{
    Endpoint, LinkDevice, LinkOptions, SimDeviceOptions, SimDeviceServer, LINK_TIMEOUT,
};
use maobi::gui::start_hand;
use maobi::poses::PoseTrack;
use maobi::raster::{Canvas, Frame};
use maobi::render::Inker;
use maobi_shared::guide::DEFAULT_GUIDE;
use maobi_shared::params::MAX_LAYERS;
use maobi_shared::presets;
use maobi_shared::protocol::{
    encode_raw, DeviceMsg, Message, CRC_LEN, DEVICE_TO_HOST, PROTOCOL_VERSION,
};

mod common;

/// The longest any wait below may take: only a hang gets near it (each wait ends at its
/// event), so it fails a test instead of hanging it, and a loaded machine never does.
const HANG_GUARD: Duration = Duration::from_secs(60);

/// The sim-device's state rate in these tests (its default), and the most device ticks
/// between two of its states: one every `1000 / 120` poses, and more when its state timer
/// fires while no pose comes.
const STATE_HZ: u32 = 120;
const MAX_TICKS_BETWEEN_STATES: u64 = 1000 / STATE_HZ as u64;

/// States a stroke waits for with the brush pressed at its end (the GUI's brush resting on
/// the paper for a moment).
const HOLD_STATES: usize = 30;

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

/// Connects `dev` to a device that is there. `connect` itself waits about two seconds for
/// the first handshake (what the GUI waits before it says "retrying in the background"); on
/// a loaded machine the handshake may come later, so wait on for it, under the hang guard.
fn connect(dev: &mut LinkDevice) {
    if let Err(e) = dev.connect() {
        assert!(
            dev.wait_connected(HANG_GUARD),
            "no connection: {e}; {:?}",
            dev.status().link
        );
    }
}

/// What `connect` says to a device that is not there or is refused: once the first attempt
/// has ended (however long that takes here), `connect` reports its reason.
fn connect_error(dev: &mut LinkDevice) -> String {
    let first = dev.connect().expect_err("no connection");
    wait_for(dev, "the first connection attempt ends", |s| {
        s.link.as_ref().is_some_and(|l| l.attempts >= 1)
    });
    let err = dev.connect().expect_err("still no connection").to_string();
    eprintln!("connect: {first}; after the first attempt: {err}");
    err
}

/// The GUI's paper, reduced to what these tests check.
struct Paper {
    inker: Inker,
    canvas: Canvas,
    frames: usize,
    touching: usize,
    kept: Vec<BrushFrame>,
    kept_last_tick: Option<u64>,
    /// The device tick of every state received, in order, with the link session it came in
    /// when that is known for certain ([`pump_until`]).
    ticks: Vec<(Option<u64>, u64)>,
    /// The session the states inked next came in, if known.
    session: Option<u64>,
    /// The link's session count as read just before the last poll.
    link_before_poll: Option<u64>,
    /// Where the last state received had the brush's handle (mm).
    handle: Option<[f64; 3]>,
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
            ticks: Vec::new(),
            session: None,
            link_before_poll: None,
            handle: None,
        }
    }
    fn ink(&mut self, frames: &[BrushFrame]) {
        for f in frames {
            self.frames += 1;
            self.ticks.push((self.session, f.tick));
            self.handle = Some(f.pose.pos.to_f64());
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
    /// The last state received had the handle at `at` (within the wire's fixed point).
    fn handle_at(&self, at: [f64; 3]) -> bool {
        self.handle
            .is_some_and(|h| (0..3).all(|i| (h[i] - at[i]).abs() < 1e-3))
    }
}

/// The most device ticks between two consecutive states of `ticks` that came in the same
/// link session: a session lost on a busy machine (the link's timeout) discards the states
/// in flight, which is not the device's rate.
fn largest_tick_gap(ticks: &[(Option<u64>, u64)]) -> u64 {
    ticks
        .windows(2)
        .filter(|w| w[0].0.is_some() && w[0].0 == w[1].0)
        .map(|w| w[1].1.saturating_sub(w[0].1))
        .max()
        .unwrap_or(0)
}

/// A number that changes whenever a link session starts or ends.
fn link_session(s: &DeviceStatus) -> Option<u64> {
    s.link
        .as_ref()
        .map(|l| u64::from(l.sessions) + u64::from(l.lost))
}

/// Polls `dev`, inking what arrives, until `done` holds for the paper and the status;
/// fails, naming `what`, if that takes [`HANG_GUARD`].
fn pump_until(
    dev: &mut dyn Device,
    paper: &mut Paper,
    what: &str,
    mut done: impl FnMut(&Paper, &DeviceStatus) -> bool,
) {
    let end = Instant::now() + HANG_GUARD;
    let mut frames = Vec::new();
    loop {
        let before_poll = link_session(&dev.status());
        frames.clear();
        dev.poll(&mut frames);
        let s = dev.status();
        // This poll's states came after the last poll took the queue: all in one session if
        // none started or ended from before that poll until after this one.
        let now = link_session(&s);
        paper.session = now.filter(|_| paper.link_before_poll == now);
        paper.link_before_poll = before_poll;
        paper.ink(&frames);
        if done(paper, &s) {
            return;
        }
        assert!(
            Instant::now() < end,
            "{what}: not within {HANG_GUARD:?} ({} states so far; {:?})",
            paper.frames,
            s.link
        );
        std::thread::sleep(Duration::from_millis(2));
    }
}

/// Pumps until `n` more states have come.
fn pump_states(dev: &mut dyn Device, paper: &mut Paper, n: usize) {
    let until = paper.frames + n;
    pump_until(dev, paper, &format!("{n} more states"), |p, _| {
        p.frames >= until
    });
}

/// Sends the hand to `h` and pumps until a state shows the brush's handle there.
fn move_hand(dev: &mut dyn Device, paper: &mut Paper, h: HandInput) {
    dev.send(DeviceCommand::Hand(h)).unwrap();
    let at = [h.x, h.y, h.z];
    pump_until(dev, paper, &format!("the pen reaches {at:?}"), |p, _| {
        p.handle_at(at)
    });
}

/// Waits until the status satisfies `what` (a state that lasts once reached).
fn wait_for(dev: &dyn Device, what: &str, done: impl Fn(&DeviceStatus) -> bool) -> DeviceStatus {
    let end = Instant::now() + HANG_GUARD;
    loop {
        let s = dev.status();
        if done(&s) {
            return s;
        }
        assert!(
            Instant::now() < end,
            "{what}: not within {HANG_GUARD:?}: {:?}",
            s.link
        );
        std::thread::sleep(Duration::from_millis(2));
    }
}

/// Holds the link thread at its wake-ups (a session up, a session ended, states in) while a
/// test reads the status there: a state the link only passes through (lost, before it
/// reconnects) is then read for certain, however the machine schedules the threads.
struct LinkSteps {
    armed: Arc<AtomicBool>,
    paused: Receiver<()>,
    resume: Sender<()>,
}

/// The link thread, held at one wake-up with the status it had there; it goes on when this
/// is dropped.
struct Held<'a> {
    steps: &'a LinkSteps,
    status: DeviceStatus,
}

impl Drop for Held<'_> {
    fn drop(&mut self) {
        let _ = self.steps.resume.send(());
    }
}

impl LinkSteps {
    /// Installs the hold as `dev`'s wake callback (the link thread calls it with no lock
    /// held); it holds nothing until [`LinkSteps::arm`] or [`LinkSteps::until`].
    fn install(dev: &mut LinkDevice) -> LinkSteps {
        let armed = Arc::new(AtomicBool::new(false));
        let (paused_tx, paused) = mpsc::channel();
        let (resume, resume_rx) = mpsc::channel::<()>();
        let resume_rx = Mutex::new(resume_rx);
        let hold = armed.clone();
        dev.on_frames(Arc::new(move || {
            if hold.load(Ordering::SeqCst) && paused_tx.send(()).is_ok() {
                // Until the test has looked (or has gone: the sender dropped).
                let _ = resume_rx.lock().unwrap().recv();
            }
        }));
        LinkSteps {
            armed,
            paused,
            resume,
        }
    }

    /// From now on the link thread stops at each wake-up until [`LinkSteps::until`] has
    /// looked at it.
    fn arm(&self) {
        self.armed.store(true, Ordering::SeqCst);
    }

    /// Lets the link thread run from wake-up to wake-up until the status there satisfies
    /// `what`, and returns with it held at that one (no longer armed).
    fn until(
        &self,
        dev: &LinkDevice,
        what: &str,
        done: impl Fn(&DeviceStatus) -> bool,
    ) -> Held<'_> {
        self.arm();
        let end = Instant::now() + HANG_GUARD;
        loop {
            let left = end.saturating_duration_since(Instant::now());
            if self.paused.recv_timeout(left).is_err() {
                self.armed.store(false, Ordering::SeqCst);
                panic!("{what}: not within {HANG_GUARD:?}: {:?}", dev.status().link);
            }
            let status = dev.status();
            if done(&status) {
                self.armed.store(false, Ordering::SeqCst);
                return Held {
                    steps: self,
                    status,
                };
            }
            let _ = self.resume.send(());
        }
    }
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

/// Brings the brush 6 mm above the paper at x = `from`, presses it 8 mm into the paper,
/// drags it to `to` and holds it there for [`HOLD_STATES`] states; each move waits until a
/// state shows the pen arrived. Returns the index in `paper.ticks` of the stroke's first
/// state.
fn stroke(dev: &mut dyn Device, paper: &mut Paper, from: f64, to: f64) -> usize {
    let first = paper.ticks.len();
    move_hand(dev, paper, hand(from, -6.0));
    move_hand(dev, paper, hand(from, 8.0));
    // The brush settles into the paper before it moves.
    pump_states(dev, paper, 10);
    move_hand(dev, paper, hand(to, 8.0));
    pump_states(dev, paper, HOLD_STATES);
    first
}

#[test]
fn handshake_then_poses_in_states_out_and_ink() {
    let srv = server("127.0.0.1:0", STATE_HZ);
    let mut dev = link(Endpoint::Tcp(srv.addr().to_string()));
    connect(&mut dev);
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
    let first = stroke(&mut dev, &mut paper, -10.0, 10.0);
    let s = dev.status();
    let l = s.link.clone().unwrap();
    let ticks = &paper.ticks[first..];
    let span = ticks.last().unwrap().1 - ticks[0].1;
    // States at 120 Hz of the device's 1 kHz loop: one at least every 8 of its ticks, over
    // a stroke whose moves alone take more than 80 ticks (0.4 mm per tick).
    assert!(span > 80, "the stroke spans {span} device ticks");
    assert!(
        largest_tick_gap(ticks) <= MAX_TICKS_BETWEEN_STATES,
        "{} device ticks between two states ({} states over {span} ticks)",
        largest_tick_gap(ticks),
        ticks.len()
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
    let srv = server("127.0.0.1:0", STATE_HZ);
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
    connect(&mut dev);
    let mut paper = Paper::new();
    stroke(&mut dev, &mut paper, -10.0, 10.0);
    // The proxy damages the stream every fifth chunk from the 25th on, each kind in turn:
    // wait until each kind has been met and good frames keep coming.
    pump_until(
        &mut dev,
        &mut paper,
        "every kind of damage counted, and good frames",
        |_, s| {
            let rx = &s.link.as_ref().unwrap().rx;
            rx.crc_errors > 0
                && rx.oversized_frames > 0
                && rx.framing_errors > 0
                && rx.frames_ok > 80
        },
    );
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
    let mut srv = server("127.0.0.1:0", STATE_HZ);
    let addr = srv.addr().to_string();
    let mut dev = link(Endpoint::Tcp(addr.clone()));
    let steps = LinkSteps::install(&mut dev);
    connect(&mut dev);
    let mut paper = Paper::new();
    move_hand(&mut dev, &mut paper, hand(-20.0, 8.0));
    pump_states(&mut dev, &mut paper, 10);
    // Mid-stroke: the pen on its way from x = -20 to 20, pressed.
    dev.send(DeviceCommand::Hand(hand(20.0, 8.0))).unwrap();
    pump_until(&mut dev, &mut paper, "the pen moving", |p, _| {
        p.handle.is_some_and(|h| h[0] > -15.0)
    });
    let ink_before = paper.canvas.ink_area_px();
    assert!(ink_before > 0.0, "inking when the peer dies");
    let lost_at = Instant::now();
    // Held from here on at each wake-up, so the status at the loss is read before the link
    // goes on to reconnect.
    steps.arm();
    srv.stop();
    let held = steps.until(&dev, "the loss is noticed", |s| !s.connected);
    let l = held.status.link.clone().unwrap();
    assert!(l.state.contains("lost"), "{}", l.state);
    assert_eq!(l.lost, 1);
    eprintln!("loss noticed after {:?}: {}", lost_at.elapsed(), l.state);
    // Commands other than the hand are refused while the link is down.
    assert!(dev.send(DeviceCommand::Dip(1.0)).is_err());
    // What arrived before the loss is inked.
    let mut frames = Vec::new();
    dev.poll(&mut frames);
    (paper.session, paper.link_before_poll) = (None, None);
    paper.ink(&frames);
    let ink_at_loss = paper.canvas.ink_area_px();
    assert!(ink_at_loss >= ink_before);
    let attempts_at_loss = l.attempts;
    drop(held);
    // Then nothing comes while the link is down, over two failed reconnection attempts: the
    // canvas is kept as it was.
    wait_for(&dev, "two attempts to reconnect", |s| {
        s.link
            .as_ref()
            .is_some_and(|l| l.attempts >= attempts_at_loss + 2)
    });
    frames.clear();
    dev.poll(&mut frames);
    assert!(
        frames.is_empty(),
        "{} states from a dead link",
        frames.len()
    );
    assert_eq!(
        paper.canvas.ink_area_px(),
        ink_at_loss,
        "the canvas is kept"
    );
    // The peer comes back on the same port.
    let _srv2 = server(&addr, STATE_HZ);
    wait_for(&dev, "reconnects", |s| s.connected);
    let first = stroke(&mut dev, &mut paper, 20.0, 35.0);
    // The virtual pen restarted where the new device's brush was: no jump, no fault.
    assert!(dev.status().faults.is_empty(), "{:?}", dev.status().faults);
    let l = dev.status().link.unwrap();
    assert_eq!(l.sessions, 2, "{l:?}");
    // States flow again, at the device's rate.
    let ticks = &paper.ticks[first..];
    assert!(
        largest_tick_gap(ticks) <= MAX_TICKS_BETWEEN_STATES,
        "{} device ticks between two states",
        largest_tick_gap(ticks)
    );
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
    let msg = connect_error(&mut dev);
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
    let err = connect_error(&mut dev);
    assert!(err.contains("cannot open"), "{err}");
    let _srv = server(&addr, STATE_HZ);
    wait_for(&dev, "connects once the device is there", |s| s.connected);
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
    let end = Instant::now() + HANG_GUARD;
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
    connect(&mut dev);
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
    let steps = LinkSteps::install(&mut dev);
    // Held at the session's start, before the link starts counting the silence.
    steps.arm();
    connect(&mut dev);
    let held = steps.until(&dev, "the session is up", |s| s.connected);
    assert!(held
        .status
        .firmware_version
        .as_deref()
        .unwrap()
        .contains("mute-board"));
    let track = maobi::poses::PoseTrack::from_path(
        &std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/poses/hook.csv"),
    )
    .unwrap();
    // A virtual pen takes replays.
    assert!(dev.send(DeviceCommand::Replay(Arc::new(track))).is_ok());
    let t = Instant::now();
    drop(held);
    let held = steps.until(&dev, "silence ends the session", |s| !s.connected);
    // The silence was counted from after `t`: the timeout cannot have fired early.
    let waited = t.elapsed();
    assert!(waited >= LINK_TIMEOUT, "{waited:?}");
    let l = held.status.link.clone().unwrap();
    assert!(l.state.contains("no data"), "{}", l.state);
    assert!(
        !held.status.replaying,
        "a replay the loss cut short has ended"
    );
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
        // Says nothing more, and holds the connection until the host closes it.
        while matches!(s.read(&mut buf), Ok(n) if n > 0) {}
    });
    let mut dev = link(Endpoint::Tcp(addr));
    let steps = LinkSteps::install(&mut dev);
    // Held at the session's start: the peer's silence cannot end it before the replay is
    // asked for.
    steps.arm();
    connect(&mut dev);
    let _held = steps.until(&dev, "the session is up", |s| s.connected);
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
            // The device's connection ends when the pty fails it (seen on a busy machine,
            // after the link had counted a session lost); like a pen that resets, it serves
            // again on the same pty, which this thread's handle keeps alive.
            while !stop.load(Ordering::SeqCst) {
                let conn = master
                    .try_clone_native()
                    .expect("a second handle on the pty");
                let _ = serve_stream(
                    Box::new(SerialConn(Box::new(conn))),
                    &SimDeviceOptions::default(),
                    &stop,
                );
                std::thread::sleep(Duration::from_millis(1));
            }
            drop(master);
        })
    };
    let mut dev = link(Endpoint::Serial(path.clone()));
    connect(&mut dev);
    let s = dev.status();
    assert!(s.connected);
    assert!(s.name.contains(&path), "{}", s.name);
    let mut paper = Paper::new();
    let first = stroke(&mut dev, &mut paper, -10.0, 10.0);
    let ticks = &paper.ticks[first..];
    assert!(
        largest_tick_gap(ticks) <= MAX_TICKS_BETWEEN_STATES,
        "{} device ticks between two states ({} states)",
        largest_tick_gap(ticks),
        ticks.len()
    );
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
    let srv = server("127.0.0.1:0", STATE_HZ);
    // It returns as soon as the device has answered: the timeout only guards a hang.
    let info = maobi::device::identify(&Endpoint::Tcp(srv.addr().to_string()), HANG_GUARD)
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
    connect(&mut dev);
    dev.send(DeviceCommand::EnableForces(true)).unwrap();
    // The pen hangs where it is (the GUI's pointer does not move); the moving point runs a
    // 30 mm line in 0.5 s from 5 mm beside it, in the air (no brush forces but gravity).
    let z = length() + 10.0;
    let track = common::guide_line(5.0, z);
    let mut paper = Paper::new();
    move_hand(
        &mut dev,
        &mut paper,
        HandInput {
            z,
            ..hand(0.0, 0.0)
        },
    );
    dev.send(DeviceCommand::Guide(Some(Arc::new(track))))
        .unwrap();
    // Until the guide has stayed off for `AFTER` states (at 1000 states per second, one per
    // device tick) after its last guided one: if it never stops, the hang guard fails this.
    const AFTER: usize = 300;
    let end = Instant::now() + HANG_GUARD;
    let mut frames = Vec::new();
    let mut all: Vec<BrushFrame> = Vec::new();
    loop {
        frames.clear();
        dev.poll(&mut frames);
        all.extend(frames.iter().cloned());
        let last = all.iter().rposition(|f| f.guide.is_some());
        if last.is_some_and(|i| all.len() > i + AFTER) {
            break;
        }
        assert!(
            Instant::now() < end,
            "the guide plays and stops: not within {HANG_GUARD:?} ({} states, the last \
             guided one {last:?})",
            all.len()
        );
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
    // skipped by the GUI's frame queue).
    assert!(guided.len() > 300, "{}", guided.len());
    // Every state from the first guided one to the last is guided (each pose of the stroke
    // and of the fade-out carries its point); after it, the wait above saw none.
    assert!(
        all[first..=last].iter().all(|f| f.guide.is_some()),
        "the guide plays without a gap until it stops"
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

/// Polls `dev` until the frames seen so far satisfy `done`; all of them. Fails, naming
/// `what`, after [`HANG_GUARD`].
fn frames_until(
    dev: &mut dyn Device,
    what: &str,
    mut done: impl FnMut(&[BrushFrame]) -> bool,
) -> Vec<BrushFrame> {
    let end = Instant::now() + HANG_GUARD;
    let mut all = Vec::new();
    let mut frames = Vec::new();
    loop {
        frames.clear();
        dev.poll(&mut frames);
        all.append(&mut frames);
        if done(&all) {
            return all;
        }
        assert!(Instant::now() < end, "{what}: not within {HANG_GUARD:?}");
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// "Stay in the lane" over the link: the writer computes the tube's wall point from each pose
/// it sends (the virtual pen's hand is the pose sent), so inside the lane the device's guide
/// gives exactly nothing, and 6 mm off the path it pulls back with k (d - r); let go, it
/// fades out and stops.
#[test]
fn the_lane_rides_with_the_poses_over_the_link() {
    let srv = server("127.0.0.1:0", 1000);
    let mut dev = link(Endpoint::Tcp(srv.addr().to_string()));
    connect(&mut dev);
    dev.send(DeviceCommand::EnableForces(true)).unwrap();
    let z = length() + 10.0;
    let mut paper = Paper::new();
    let at = |y: f64| HandInput {
        y,
        z,
        ..hand(0.0, 0.0)
    };
    move_hand(&mut dev, &mut paper, at(1.0));
    // A line pressed 3 mm along x through the origin.
    let pressed = length() - 3.0;
    let csv = format!("t,x,y,z,qw,qx,qy,qz\n0,-20,0,{pressed},1,0,0,0\n1,20,0,{pressed},1,0,0,0\n");
    let track = PoseTrack::from_reader("line.csv", csv.as_bytes()).unwrap();
    dev.send(DeviceCommand::Lane(Some((Arc::new(track), 2.0))))
        .unwrap();
    // Inside, 1 mm off the path: 300 states at full gain.
    let full = |fs: &[BrushFrame]| {
        fs.iter()
            .filter(|f| f.guide.is_some_and(|g| g.gain >= 1.0))
            .count()
    };
    let inside = frames_until(&mut dev, "the lane faded in", |fs| full(fs) >= 300);
    let largest = inside
        .iter()
        .filter_map(|f| f.guide)
        .map(|g| g.force.iter().fold(0.0f64, |m, c| m.max(c.abs())))
        .fold(0.0, f64::max);
    println!("over the link, inside a 2 mm lane: largest guide force {largest:e} N");
    assert_eq!(largest, 0.0);
    // Out to 6 mm: the pull back.
    move_hand(&mut dev, &mut paper, at(6.0));
    let k = DEFAULT_GUIDE.stiffness_n_per_m as f64 * 1e-3;
    let pulled = |f: &BrushFrame| f.guide.is_some_and(|g| (g.force[1] + 4.0 * k).abs() < 1e-3);
    let out = frames_until(&mut dev, "the pull back from 6 mm", |fs| {
        fs.iter().any(pulled)
    });
    let held = out.iter().find(|f| pulled(f)).unwrap().guide.unwrap().force;
    println!("over the link, 6 mm off the path: {held:?} N");
    assert!(held[0].abs() < 1e-3 && held[2].abs() < 1e-9, "{held:?}");
    // Let go: the guide fades out and the frames stop carrying it.
    dev.send(DeviceCommand::Lane(None)).unwrap();
    frames_until(&mut dev, "the lane let go", |fs| {
        fs.len() > 300 && fs[fs.len() - 300..].iter().all(|f| f.guide.is_none())
    });
    dev.disconnect();
}
