//! End-to-end tests across the Maobi crates live beside this file; this library holds what
//! they share.

use std::path::PathBuf;

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
