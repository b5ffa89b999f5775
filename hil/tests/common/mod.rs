//! The fake pen shared by the serial and probe-rs backend tests: a thread on one end of a
//! pseudo-terminal pair that speaks the protocol and runs the shared brush model as the
//! firmware does.

#![allow(dead_code)] // each test binary uses part of it

use std::io::{Read, Write};
use std::time::{Duration, Instant};

use maobi_shared::protocol::{
    BrushState, Capabilities, DeviceInfo, DeviceMsg, DeviceRx, HostMsg, Message, Version,
};
use maobi_shared::{presets, Brush, Fx};
use serialport::{SerialPort, TTYPort};

/// A pseudo-terminal pair; `None` (the test skips, or fails where every test must run) on a
/// machine without pseudo-terminals.
pub fn pair() -> Option<(TTYPort, TTYPort)> {
    match TTYPort::pair() {
        Ok(p) => Some(p),
        Err(e) => {
            maobi_testenv::skip(&format!("no pseudo-terminals here ({e})"));
            None
        }
    }
}

/// Writes one frame. The port's 5 ms timeout also bounds writes: when the host reads slowly
/// (a loaded machine, several sessions at once) the pty fills, so a timed-out write is
/// retried rather than fatal.
pub fn write_msg(port: &mut TTYPort, m: &DeviceMsg) {
    let mut buf = vec![0u8; DeviceMsg::MAX_FRAME];
    let n = m.encode(&mut buf).unwrap();
    let mut rest = &buf[..n];
    let end = Instant::now() + Duration::from_secs(30);
    while !rest.is_empty() {
        match port.write(rest) {
            Ok(k) => rest = &rest[k..],
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut && Instant::now() < end => {}
            Err(e) => panic!("fake device: write failed: {e}"),
        }
    }
}

/// A device: hello, pong, and a state after every pose (the first pose places the brush).
pub fn fake_device(mut port: TTYPort, run_for: Duration) {
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

/// A pen that reads its own sensors (no `VIRTUAL_PEN`): hello, pong, a brush state every
/// 8 ms and a telemetry report every 100 ms whose longest tick is `tick_max_us`.
pub fn fake_sensor_pen(mut port: TTYPort, run_for: Duration, tick_max_us: u32) {
    use maobi_shared::protocol::Telemetry;
    port.set_timeout(Duration::from_millis(2)).unwrap();
    let mut rx = DeviceRx::new();
    let brush = Brush::<Fx>::new(
        presets::LARGE,
        maobi_shared::Pose::new(
            maobi_shared::Vec3::new(0.0, 0.0, 30.0),
            maobi_shared::Quat::IDENTITY,
        )
        .cast::<Fx>(),
    )
    .unwrap();
    let mut buf = [0u8; 256];
    let start = Instant::now();
    let (mut last_state, mut last_telemetry) = (Instant::now(), Instant::now());
    let mut greeted = false;
    while start.elapsed() < run_for {
        let n = port.read(&mut buf).unwrap_or(0);
        let msgs: Vec<_> = rx.feed(&buf[..n]).filter_map(Result::ok).collect();
        for m in msgs {
            match m {
                HostMsg::Hello(_) => {
                    greeted = true;
                    let info = DeviceInfo::new(
                        "fake-sensor-pen",
                        Version::default(),
                        Capabilities::REAL_SENSORS | Capabilities::FORCE_OUTPUT,
                        3.3,
                        0.88,
                    );
                    write_msg(&mut port, &DeviceMsg::Hello(info));
                }
                HostMsg::Ping { seq } => write_msg(&mut port, &DeviceMsg::Pong { seq }),
                _ => {}
            }
        }
        let tick = start.elapsed().as_millis() as u32;
        if greeted && last_state.elapsed() >= Duration::from_millis(8) {
            last_state = Instant::now();
            let st =
                BrushState::from_brush(&brush, tick, 0, Default::default(), Default::default());
            write_msg(&mut port, &DeviceMsg::State(st));
        }
        if greeted && last_telemetry.elapsed() >= Duration::from_millis(100) {
            last_telemetry = Instant::now();
            let t = Telemetry {
                tick,
                tick_period_min_us: 996,
                tick_period_mean_us: 1000,
                tick_period_max_us: tick_max_us,
                load_percent: 41,
                tick_busy_max_us: 410,
                tick_busy_max_cycles: 39_360,
                ..Default::default()
            };
            write_msg(&mut port, &DeviceMsg::Telemetry(t));
        }
    }
}
