//! Random protocol traffic, both ways (`maobi_shared::protocol::fuzz`, the same generator the
//! pen's fuzz test under QEMU uses, `hil/tests/fuzz.rs`):
//!
//! * random well-formed host messages of every kind, and a share of damaged frames, at
//!   `maobi sim-device` and at `maobi bridge` (on the stand-in libHD): neither panics nor
//!   exits, and each serves the next client (handshake, ping) afterwards;
//! * a fake device sending random well-formed device messages (and damaged frames) after
//!   its handshake: the app's link (`LinkDevice`) and the CLI's device commands
//!   (`maobi device check`, `device config get`, `device config set`) never panic.
//!
//! Seed: `MAOBI_FUZZ_SEED` (printed; the same seed gives the same streams).

use std::io::{Read, Write};
use std::net::{TcpListener, TcpStream};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use maobi::device::client::host_version;
use maobi::device::endpoint::nothing_to_read_yet;
use maobi::device::Device;
use maobi::device::{Endpoint, LinkDevice, LinkOptions};
use maobi::gui::start_hand;
use maobi_shared::protocol::fuzz::{self, Fuzz, Piece};
use maobi_shared::protocol::{
    Capabilities, DeviceInfo, DeviceMsg, HostHello, HostMsg, HostRx, Message, Version, DELIMITER,
};

mod common;

/// Host messages streamed at each server.
const HOST_MESSAGES: usize = 4000;
/// Share of frames damaged.
const DAMAGED: f64 = 0.1;

fn seed() -> u64 {
    let s = fuzz::seed_from_env(fuzz::DEFAULT_SEED);
    println!("fuzz seed {s:#x} (MAOBI_FUZZ_SEED to repeat)");
    s
}

/// A server process (`maobi sim-device`, `maobi bridge`) with its stderr collected.
struct Server {
    child: Child,
    addr: String,
    log: Arc<Mutex<String>>,
}

impl Server {
    /// Starts `maobi ARGS` and waits for the line that gives its address (`find` picks the
    /// address out of a line).
    fn spawn(args: &[&str], env: &[(&str, &str)], find: fn(&str) -> Option<String>) -> Server {
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_maobi"));
        cmd.args(args)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::piped());
        for (k, v) in env {
            cmd.env(k, v);
        }
        let mut child = cmd.spawn().expect("maobi starts");
        let (log, rx) = common::collect_stderr(child.stderr.take().unwrap(), find);
        let addr = rx
            .recv_timeout(Duration::from_secs(30))
            .unwrap_or_else(|_| {
                let _ = child.kill();
                panic!("{args:?} did not start listening:\n{}", log.lock().unwrap())
            });
        Server { child, addr, log }
    }

    /// Still running, and never panicked.
    fn assert_healthy(&mut self, what: &str) {
        let status = self.child.try_wait().unwrap();
        let log = self.log.lock().unwrap().clone();
        assert!(status.is_none(), "{what} exited ({status:?}):\n{log}");
        assert!(!log.contains("panicked"), "{what} panicked:\n{log}");
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Streams `n` random host messages (and damaged frames) at `addr`, reading whatever comes
/// back meanwhile. Returns the messages sent and the kinds covered.
fn stream_host_traffic(addr: &str, fz: &mut Fuzz, n: usize) -> (usize, usize) {
    let mut s = TcpStream::connect(addr).expect("connects");
    s.set_nodelay(true).unwrap();
    s.set_read_timeout(Some(Duration::from_millis(1))).unwrap();
    s.set_write_timeout(Some(Duration::from_secs(10))).unwrap();
    let mut buf = vec![0u8; 65536];
    let mut sent = 0;
    while sent < n {
        for p in fz.host_pieces(DAMAGED) {
            // A server that stops reading is a finding too: the write times out and fails.
            s.write_all(p.bytes()).expect("the server keeps reading");
            sent += 1;
        }
        match s.read(&mut buf) {
            Ok(0) => panic!("the server closed the connection after {sent} messages"),
            Ok(_) => {}
            Err(e) if nothing_to_read_yet(&e) => {}
            Err(e) => panic!("reading from the server: {e}"),
        }
        if sent % 16 == 0 {
            std::thread::sleep(Duration::from_millis(1));
        }
    }
    (sent, fz.host_kinds().len())
}

/// A new client: handshake, then a ping answered.
fn next_client_is_served(addr: &str) {
    let mut s = TcpStream::connect(addr).expect("the next client connects");
    s.set_read_timeout(Some(Duration::from_millis(10))).unwrap();
    let mut send = |m: &HostMsg| {
        let mut b = vec![0u8; HostMsg::MAX_FRAME];
        let n = m.encode(&mut b).unwrap();
        s.write_all(&b[..n]).unwrap();
    };
    send(&HostMsg::Hello(HostHello::new("fuzz-next", host_version())));
    send(&HostMsg::Ping { seq: 0xF0F0 });
    let mut rx = Box::new(HostRx::new());
    let mut buf = vec![0u8; 65536];
    let (mut hello, mut pong) = (false, false);
    let end = Instant::now() + Duration::from_secs(20);
    while !(hello && pong) && Instant::now() < end {
        let n = match s.read(&mut buf) {
            Ok(0) => panic!("the server closed the next client's connection"),
            Ok(n) => n,
            Err(_) => continue,
        };
        for m in rx.feed(&buf[..n]).flatten() {
            match m {
                DeviceMsg::Hello(info) => hello = info.check().is_ok(),
                DeviceMsg::Pong { seq: 0xF0F0 } => pong = true,
                _ => {}
            }
        }
    }
    assert!(hello && pong, "the next client: hello {hello}, pong {pong}");
}

fn host_fuzz_at(server: &mut Server, what: &str, seed: u64) {
    let mut fz = Fuzz::new(seed);
    let (sent, kinds) = stream_host_traffic(&server.addr.clone(), &mut fz, HOST_MESSAGES);
    server.assert_healthy(what);
    next_client_is_served(&server.addr);
    server.assert_healthy(what);
    println!(
        "FUZZ {what}: seed={seed:#x} messages={sent} kinds={kinds}/{}",
        fuzz::HOST_KINDS.len()
    );
    assert_eq!(kinds, fuzz::HOST_KINDS.len(), "{:?}", fz.host_kinds());
}

#[test]
fn random_host_traffic_never_takes_the_sim_device_down() {
    let seed = seed();
    let mut server = Server::spawn(&["sim-device", "--listen", "127.0.0.1:0"], &[], |line| {
        line.split("--device tcp:")
            .nth(1)
            .and_then(|s| s.split('`').next())
            .map(str::to_string)
    });
    host_fuzz_at(&mut server, "sim-device", seed);
}

/// The stand-in libHD the cargo build put beside this test (a dev-dependency of `maobi`),
/// the newest if there are several.
fn standin() -> PathBuf {
    let exe = std::env::current_exe().unwrap();
    let deps = exe.parent().unwrap();
    [deps, deps.parent().unwrap_or(deps)]
        .iter()
        .filter_map(|d| std::fs::read_dir(d).ok())
        .flat_map(|r| r.flatten())
        .filter(|e| {
            let n = e.file_name().to_string_lossy().into_owned();
            n.starts_with("libmaobi_hd_standin") && n.ends_with(".so")
        })
        .filter_map(|e| Some((e.metadata().ok()?.modified().ok()?, e.path())))
        .max()
        .map(|(_, p)| p)
        .unwrap_or_else(|| panic!("no libmaobi_hd_standin*.so near {}", exe.display()))
}

#[test]
fn random_host_traffic_never_takes_the_bridge_down() {
    let seed = seed();
    let lib = standin();
    let mut server = Server::spawn(
        &[
            "bridge",
            "--listen",
            "127.0.0.1:0",
            "--hd-lib",
            lib.to_str().unwrap(),
        ],
        &[("MAOBI_HD_STANDIN", "")],
        |line| {
            line.split("listening on ")
                .nth(1)
                .and_then(|r| r.split(';').next())
                .map(|a| a.trim().to_string())
        },
    );
    host_fuzz_at(&mut server, "bridge", seed ^ 0xB1D6E);
}

/// Panics anywhere in this process (the link's threads included), counted by a hook.
fn count_panics() -> &'static AtomicUsize {
    static PANICS: AtomicUsize = AtomicUsize::new(0);
    static HOOK: std::sync::Once = std::sync::Once::new();
    HOOK.call_once(|| {
        let prev = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            PANICS.fetch_add(1, Ordering::SeqCst);
            prev(info);
        }));
    });
    &PANICS
}

/// A fake device on a loopback port: to every connection it answers the first Hello with a
/// good one (a sensor pen with a stored configuration), then streams random device traffic
/// until the peer leaves or `stop`. Returns its address.
fn fake_device(seed: u64, stop: Arc<AtomicBool>) -> (String, Arc<Mutex<Vec<usize>>>) {
    let l = TcpListener::bind("127.0.0.1:0").unwrap();
    l.set_nonblocking(true).unwrap();
    let addr = l.local_addr().unwrap().to_string();
    let sent = Arc::new(Mutex::new(Vec::new()));
    let record = sent.clone();
    std::thread::spawn(move || {
        let mut conn = 0u64;
        while !stop.load(Ordering::SeqCst) {
            let Ok((s, _)) = l.accept() else {
                std::thread::sleep(Duration::from_millis(5));
                continue;
            };
            conn += 1;
            let n = serve_random(s, Fuzz::new(seed.wrapping_add(conn)), &stop);
            record.lock().unwrap().push(n);
        }
    });
    (addr, sent)
}

/// One connection of [`fake_device`]; returns the random messages sent.
fn serve_random(mut s: TcpStream, mut fz: Fuzz, stop: &AtomicBool) -> usize {
    s.set_nonblocking(false).unwrap();
    s.set_read_timeout(Some(Duration::from_millis(1))).unwrap();
    s.set_write_timeout(Some(Duration::from_millis(500)))
        .unwrap();
    let mut rx = Box::new(maobi_shared::protocol::DeviceRx::new());
    let mut buf = [0u8; 4096];
    let mut greeted = false;
    let mut sent = 0;
    let start = Instant::now();
    while !stop.load(Ordering::SeqCst) && start.elapsed() < Duration::from_secs(30) {
        match s.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => {
                let hello = rx
                    .feed(&buf[..n])
                    .flatten()
                    .any(|m| matches!(m, HostMsg::Hello(_)));
                if hello && !greeted {
                    greeted = true;
                    let info = DeviceInfo::new(
                        "fuzz-pen",
                        Version::default(),
                        Capabilities::REAL_SENSORS
                            | Capabilities::FORCE_OUTPUT
                            | Capabilities::STORED_CONFIG,
                        3.3,
                        0.88,
                    )
                    .with_config(maobi_shared::protocol::ConfigState::Valid);
                    let mut b = vec![0u8; DeviceMsg::MAX_FRAME + 1];
                    b[0] = DELIMITER;
                    let k = DeviceMsg::Hello(info).encode(&mut b[1..]).unwrap();
                    if s.write_all(&b[..k + 1]).is_err() {
                        break;
                    }
                }
            }
            Err(e) if nothing_to_read_yet(&e) => {}
            Err(_) => break,
        }
        if greeted {
            for p in fz.device_pieces(DAMAGED) {
                if let Piece::Frame(..) = p {
                    sent += 1;
                }
                if s.write_all(p.bytes()).is_err() {
                    return sent;
                }
            }
        }
    }
    sent
}

#[test]
fn random_device_traffic_never_panics_the_link_or_the_cli() {
    let seed = seed();
    let panics = count_panics();
    let before = panics.load(Ordering::SeqCst);
    let stop = Arc::new(AtomicBool::new(false));
    let (addr, sent) = fake_device(seed, stop.clone());

    // The app's link, as the GUI holds it: connected, polled for frames for a while.
    let mut dev = LinkDevice::new(LinkOptions::new(
        Endpoint::Tcp(addr.clone()),
        start_hand(30.0),
    ))
    .unwrap();
    let connected = dev.connect();
    let mut frames = Vec::new();
    let mut polled = 0usize;
    let end = Instant::now() + Duration::from_secs(4);
    while Instant::now() < end {
        frames.clear();
        dev.poll(&mut frames);
        polled += frames.len();
        let _ = dev.status();
        std::thread::sleep(Duration::from_millis(10));
    }
    dev.disconnect();
    drop(dev);

    // The CLI's device commands, each a process on its own connection.
    let dir = std::env::temp_dir().join(format!("maobi-fuzz-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let template = dir.join("pen.toml");
    let out = Command::new(env!("CARGO_BIN_EXE_maobi"))
        .args(["device", "config", "template", "-o"])
        .arg(&template)
        .output()
        .unwrap();
    assert!(out.status.success(), "{out:?}");
    let template = template.to_str().unwrap().to_string();
    let commands: Vec<Vec<&str>> = vec![
        vec!["device", "config", "get", "--connect", &addr],
        vec!["device", "config", "set", &template, "--connect", &addr],
        vec![
            "device",
            "check",
            "--connect",
            &addr,
            "--yes",
            "--sensor-seconds",
            "1",
        ],
    ];
    for args in &commands {
        let mut child = Command::new(env!("CARGO_BIN_EXE_maobi"))
            .args(args)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        // A command may wait on the random stream for its answer; it must end, not hang.
        let end = Instant::now() + Duration::from_secs(60);
        let status = loop {
            if let Some(s) = child.try_wait().unwrap() {
                break s;
            }
            assert!(
                Instant::now() < end,
                "`maobi {}` did not end",
                args.join(" ")
            );
            std::thread::sleep(Duration::from_millis(20));
        };
        let mut err = String::new();
        child
            .stderr
            .take()
            .unwrap()
            .read_to_string(&mut err)
            .unwrap();
        // Failing (a garbled answer) is fine; panicking (exit code 101) is not.
        assert_ne!(
            status.code(),
            Some(101),
            "`maobi {}`:\n{err}",
            args.join(" ")
        );
        assert!(
            !err.contains("panicked"),
            "`maobi {}`:\n{err}",
            args.join(" ")
        );
        println!("`maobi {}`: {status}", args.join(" "));
    }
    stop.store(true, Ordering::SeqCst);
    let _ = std::fs::remove_dir_all(&dir);

    let sent = sent.lock().unwrap().clone();
    println!(
        "FUZZ device->host: seed={seed:#x} connections={} messages={} frames_polled={polled} link_connected={}",
        sent.len(),
        sent.iter().sum::<usize>(),
        connected.is_ok(),
    );
    assert_eq!(
        panics.load(Ordering::SeqCst),
        before,
        "something panicked (see above)"
    );
    assert!(connected.is_ok(), "the link's handshake: {connected:?}");
    assert!(
        sent.iter().sum::<usize>() > 1000,
        "the fake device sent {sent:?}"
    );
}
