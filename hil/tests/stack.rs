//! The firmware's stack under QEMU, measured: cortex-m-rt paints the stack at reset and the
//! supervisor reports each new high-water mark on stdout (`STACK high_water_bytes=N`,
//! `firmware/src/app/stack.rs`). This drives the deepest paths we know of (boot; a stored
//! configuration written, read back and calibrated; sensor reports; a stroke with a state
//! frame every tick; telemetry) and holds the reading to the stack reserve the RAM budget
//! counts (`hil::firmware::Board::STACK_RESERVE`, reported by `hil size`).
//!
//! Needs `qemu-system-arm` (skipped with a message without it, unless `MAOBI_REQUIRE_QEMU`
//! is set, as in CI).

use std::path::Path;
use std::time::Duration;

use hil::firmware::{self, Board};
use hil::qemu::stack_readings as readings;
use hil::run::QemuDevice;
use hil::session::{self, Session, StreamLog, StreamOptions};
use maobi::poses::PoseTrack;
use maobi_shared::kinematics::RawReadings;
use maobi_shared::pen_io::{self, DeviceConfig, CONFIG_IMAGE_MAX};
use maobi_shared::protocol::{Command, DeviceMsg, HostMsg};

const TIMEOUT: Duration = Duration::from_secs(600);
const ANSWER: Duration = Duration::from_secs(20);

#[test]
fn readings_are_parsed_deepest_first() {
    let out = "boot\nSTACK high_water_bytes=100\nx\nSTACK high_water_bytes=4096\n";
    assert_eq!(readings(out), vec![4096, 100]);
    assert!(readings("STACK high_water_bytes=\n").is_empty());
}

#[test]
fn the_deepest_stack_fits_the_reserve() {
    let Some(elf) = firmware::qemu_test_image() else {
        return;
    };
    let mut cfg = DeviceConfig::DEFAULT;
    cfg.calibration = Some(RawReadings {
        encoders: [0; 3],
        gimbal: [2048; 3],
    });
    let mut image = vec![0u8; CONFIG_IMAGE_MAX];
    let n = pen_io::encode(&cfg, &mut image).unwrap();
    image.truncate(n);
    let path = std::env::temp_dir().join(format!("maobi-stack-{}.bin", std::process::id()));
    std::fs::write(&path, &image).unwrap();

    let (mut dev, stream) = QemuDevice::start_with(
        &elf,
        &["state_hz=1000", "telemetry_ticks=100"],
        &hil::qemu::config_loader_args(&path),
        TIMEOUT,
    )
    .unwrap();
    let mut s = Session::new(stream).unwrap();
    s.handshake(ANSWER, &mut vec![]).unwrap();
    let answer = |s: &mut Session<_>, m: HostMsg| {
        s.send(&m).unwrap();
        s.wait_for(ANSWER, &mut vec![], |r| match r {
            DeviceMsg::CommandDone { .. } | DeviceMsg::Config(_) => Some(()),
            _ => None,
        })
        .unwrap();
    };
    // The configuration paths: encode, store, read back, decode; a calibration.
    answer(&mut s, HostMsg::SetConfig(cfg));
    answer(&mut s, HostMsg::GetConfig);
    answer(
        &mut s,
        HostMsg::Command(Command::StreamSensors { rate_hz: 1000 }),
    );
    answer(&mut s, HostMsg::Command(Command::EnableForces));
    // A stroke with a state frame every tick.
    let track = PoseTrack::from_path(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/poses/hook.csv"),
    )
    .unwrap();
    let poses = session::track_poses(&track);
    let mut log = StreamLog::default();
    session::stream(&mut s, &poses, StreamOptions::default(), &mut log).unwrap();
    answer(
        &mut s,
        HostMsg::Command(Command::StreamSensors { rate_hz: 0 }),
    );
    // The supervisor reads the mark every 100 of its looks (4 s of device time here): let
    // the device idle past the next reading.
    for seq in 0..40 {
        s.send(&HostMsg::Ping { seq }).unwrap();
        std::thread::sleep(Duration::from_millis(100));
        let _ = s.poll();
    }
    drop(s);
    let (_, out) = dev.guest.stop().unwrap();
    let _ = std::fs::remove_file(&path);
    let r = readings(&out);
    println!("stack readings (bytes, deepest first): {r:?}");
    let deepest = *r.first().expect("the firmware reports its stack");
    assert!(
        deepest <= Board::STACK_RESERVE,
        "the stack reached {deepest} bytes, over the {} reserved in the RAM budget",
        Board::STACK_RESERVE
    );
}
