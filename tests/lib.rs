//! End-to-end tests across the Maobi crates live beside this file; this library holds what
//! they share.

use std::path::{Path, PathBuf};

use maobi::poses::PoseTrack;
use maobi::strokes::Character;
use maobi_shared::{presets, Pose};

/// The workspace's root folder.
pub fn workspace_root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("tests/ sits inside the workspace")
        .to_path_buf()
}

/// Every example pose file, sorted by name.
pub fn example_pose_files() -> Vec<PathBuf> {
    example_files("examples/poses", "csv")
}

/// Every example stroke file (keyframed TOML), sorted by name.
pub fn example_stroke_files() -> Vec<PathBuf> {
    example_files("examples/strokes", "toml")
}

/// The files in the workspace's folder `dir` whose names end in `.ext`, sorted by name.
fn example_files(dir: &str, ext: &str) -> Vec<PathBuf> {
    let dir = workspace_root().join(dir);
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| e.expect("readable directory entry").path())
        .filter(|p| p.extension().is_some_and(|x| x == ext))
        .collect();
    files.sort();
    files
}

/// An example stroke's 1 ms poses, placed for a head `head_mm` long.
pub struct Stroke {
    pub name: String,
    pub poses: Vec<Pose<f64>>,
}

fn stem(path: &Path) -> String {
    path.file_stem()
        .expect("a file name")
        .to_string_lossy()
        .into_owned()
}

/// Every example stroke (pose files, then stroke files), placed for a head `head_mm` long.
/// The examples are written for the large brush's head: a pose file's handle is moved along
/// its own axis by the difference, so that the tip goes where the large brush's would; a
/// stroke file places its depths for the head (its `head_mm`).
pub fn example_strokes(head_mm: f64) -> Vec<Stroke> {
    let written_for = presets::LARGE.length_mm as f64;
    let poses = example_pose_files();
    let strokes = example_stroke_files();
    assert!(
        poses.len() >= 4 && !strokes.is_empty(),
        "expected the example strokes, found {poses:?} and {strokes:?}"
    );
    let from_pose_files = poses.iter().map(|path| {
        let track = PoseTrack::from_path(path).unwrap_or_else(|e| panic!("{e}"));
        let poses = track
            .resample()
            .map(|p| Pose::new(p.pos + p.down().scale(written_for - head_mm), p.rot))
            .collect();
        Stroke {
            name: stem(path),
            poses,
        }
    });
    let from_stroke_files = strokes.iter().map(|path| {
        let name = stem(path);
        let track = Character::from_path_for_head(path, Some(head_mm))
            .and_then(|c| c.track(&name))
            .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        Stroke {
            name,
            poses: track.resample().collect(),
        }
    });
    from_pose_files.chain(from_stroke_files).collect()
}
