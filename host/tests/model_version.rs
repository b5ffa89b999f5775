//! The brush model's version (`maobi::gui::session::MODEL_VERSION`) moves with the model:
//! a reference session (the 橫 example's poses on raw paper, every tick inked) re-rendered
//! through the built-in device and the inker must give the digest recorded for the
//! current version. A change to the model, the force loop, the inker or the paper that
//! changes a session's ink fails here until the version is raised and the digest recorded
//! with it, so that sessions saved before the change say, when opened, that their replay
//! differs (see `Session::model_note`).
//!
//! To record a new version: raise `MODEL_VERSION`, run `cargo test -p maobi --test
//! model_version -- --nocapture`, and put the printed digest in `DIGESTS`.

use maobi::gui::rerender::rerender;
use maobi::gui::session::{Session, MODEL_VERSION};
use maobi::poses::PoseTrack;

mod common;
use common::example;

/// `(model version, digest of the reference session's re-render)`.
const DIGESTS: &[(u32, u64)] = &[
    (1, 0xf8f4_0318_0178_30ad),
    (2, 0xed07_44fd_32e4_7560),
    (3, 0x60cc_1aac_554e_9d07),
    // The tie's weight near the paper taken where the substep ends (contact without hops).
    (4, 0x74c1_ecea_fb21_8871),
];

/// FNV-1a, 64 bits: a digest that any change to the bytes moves.
fn fnv1a(bytes: impl IntoIterator<Item = u8>, mut h: u64) -> u64 {
    for b in bytes {
        h ^= b as u64;
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

/// The reference session as a file would hold it: the example's poses at every tick.
fn reference_session() -> Session {
    let track = PoseTrack::from_path(&example("heng.csv")).unwrap();
    let ticks = track.ticks() - 1;
    let values = |p: maobi_shared::Pose<f64>| {
        let q = p.rot.to_f64();
        [p.pos.x, p.pos.y, p.pos.z, q[0], q[1], q[2], q[3]]
    };
    let mut poses = String::from("tick,x,y,z,qw,qx,qy,qz\n");
    for (k, p) in track.resample().enumerate().skip(1) {
        let v = values(p);
        poses.push_str(&format!(
            "{k},{},{},{},{},{},{},{}\n",
            v[0], v[1], v[2], v[3], v[4], v[5], v[6]
        ));
    }
    let start = values(track.pose_at_tick(0));
    let text = format!(
        "format = \"maobi-session\"\nversion = 2\nmodel = {MODEL_VERSION}\n\
         device = \"built-in simulator\"\npreset = \"large\"\nticks = {ticks}\n\
         start = {start:?}\ninked = [[1, {ticks}]]\nposes = \"\"\"\n{poses}\"\"\"\n\n\
         [paper]\nx0_mm = -20.0\ny_top_mm = 20.0\npx_per_mm = 5.0\nwidth = 500\nheight = 200\n\
         kind = \"raw\"\nseed = 7\n\n[params]\n"
    );
    Session::from_toml(&text).unwrap()
}

#[test]
fn the_model_version_moves_with_the_model() {
    let session = reference_session();
    let r = rerender(&session, |_| {}).unwrap();
    let canvas = r.paper.canvas();
    assert!(
        canvas.ink_fraction() > 0.01,
        "the reference stroke leaves ink"
    );
    let digest = fnv1a(
        canvas.ink().iter().flat_map(|v| v.to_bits().to_le_bytes()),
        0xcbf2_9ce4_8422_2325,
    );
    println!(
        "model version {MODEL_VERSION}: digest {digest:#018x} ({} ticks, ink on {:.2}% of the paper)",
        session.journal.ticks,
        canvas.ink_fraction() * 100.0
    );
    let recorded = DIGESTS.iter().find(|(v, _)| *v == MODEL_VERSION);
    assert_eq!(
        recorded.map(|(_, d)| *d),
        Some(digest),
        "the re-rendered session changed: if the model changed on purpose, raise \
         MODEL_VERSION (host/src/gui/session.rs) and record the printed digest in DIGESTS"
    );
}
