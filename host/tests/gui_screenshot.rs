//! Checks a screenshot taken by `maobi gui --replay FILE --screenshot OUT.png` in a real
//! window: the paper view holds ink (dark pixels on light paper) and the brush view shows the
//! brush (hair-coloured pixels). The app writes the views' rectangles to `OUT.png.layout`.
//!
//! The test takes the screenshot itself under a virtual X display (`xvfb-run`, Debian's
//! `xvfb`), replaying `examples/poses/hook.csv`; `MAOBI_GUI_SCREENSHOT=OUT.png` checks one
//! taken elsewhere instead. Without either it skips, or fails where every test must run
//! (`CI=true`, or `MAOBI_REQUIRE_GUI` set to anything).

use std::path::{Path, PathBuf};
use std::process::Command;

fn rect(layout: &str, name: &str) -> [u32; 4] {
    let line = layout
        .lines()
        .find(|l| l.starts_with(name))
        .unwrap_or_else(|| panic!("no `{name}` in the layout file"));
    let v: Vec<u32> = line
        .split_whitespace()
        .skip(1)
        .map(|s| s.parse::<f64>().expect("a number") as u32)
        .collect();
    [v[0], v[1], v[2], v[3]]
}

/// Whether `xvfb-run` can be started.
fn xvfb_available() -> bool {
    Command::new("sh")
        .args(["-c", "command -v xvfb-run"])
        .output()
        .is_ok_and(|o| o.status.success())
}

/// Replays the hook in the app under a fresh virtual display and saves its screenshot.
fn take_screenshot() -> Option<PathBuf> {
    if !xvfb_available() {
        maobi_testenv::skip_unless_required(
            &["MAOBI_REQUIRE_GUI"],
            "no xvfb-run to open the app's window in (apt-get install xvfb xauth \
             libgl1-mesa-dri libegl1 libgl1 libxkbcommon-x11-0), and MAOBI_GUI_SCREENSHOT \
             names no screenshot",
        );
        return None;
    }
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("gui_screenshot");
    std::fs::create_dir_all(&dir).unwrap();
    let shot = dir.join("gui-hook.png");
    for stale in [shot.clone(), dir.join("gui-hook.png.layout")] {
        let _ = std::fs::remove_file(stale);
    }
    let hook = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/poses/hook.csv");
    // The app's settings stay out of the developer's own (and out of this test's way).
    let out = Command::new("xvfb-run")
        .args(["-a", "-s", "-screen 0 1600x1000x24"])
        .arg(env!("CARGO_BIN_EXE_maobi"))
        .arg("gui")
        .arg("--replay")
        .arg(&hook)
        .arg("--screenshot")
        .arg(&shot)
        .env("XDG_CONFIG_HOME", dir.join("config"))
        .env("XDG_DATA_HOME", dir.join("data"))
        .output()
        .expect("xvfb-run starts");
    assert!(
        out.status.success(),
        "maobi gui --replay under xvfb-run failed ({}):\n{}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    Some(shot)
}

#[test]
fn screenshot_shows_ink_and_the_brush() {
    let given = std::env::var_os("MAOBI_GUI_SCREENSHOT").map(PathBuf::from);
    let Some(path) = given.or_else(take_screenshot) else {
        return;
    };
    let bytes = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut dec = png::Decoder::new(std::io::Cursor::new(bytes));
    dec.set_transformations(png::Transformations::EXPAND);
    let mut r = dec.read_info().unwrap();
    let mut buf = vec![0; r.output_buffer_size().unwrap()];
    let info = r.next_frame(&mut buf).unwrap();
    assert_eq!(info.color_type, png::ColorType::Rgba, "an RGBA screenshot");
    let (w, h) = (info.width, info.height);
    let px = |x: u32, y: u32| {
        let i = ((y * w + x) * 4) as usize;
        [buf[i] as i32, buf[i + 1] as i32, buf[i + 2] as i32]
    };
    let mut layout_path = path.clone().into_os_string();
    layout_path.push(".layout");
    let layout = std::fs::read_to_string(&layout_path).expect("the layout file");

    let count = |r: [u32; 4], f: &dyn Fn([i32; 3]) -> bool| {
        let mut n = 0u64;
        for y in r[1]..r[3].min(h) {
            for x in r[0]..r[2].min(w) {
                if f(px(x, y)) {
                    n += 1;
                }
            }
        }
        n
    };
    let area = |r: [u32; 4]| (r[2].min(w) - r[0]) as u64 * (r[3].min(h) - r[1]) as u64;

    let canvas = rect(&layout, "canvas");
    // The sheet within the view (the view's margin around it is dark, not ink).
    let s = rect(&layout, "sheet");
    let sheet = [
        s[0].max(canvas[0]),
        s[1].max(canvas[1]),
        s[2].min(canvas[2]),
        s[3].min(canvas[3]),
    ];
    let luma = |p: [i32; 3]| (p[0] * 3 + p[1] * 6 + p[2]) / 10;
    let paper = count(sheet, &|p| luma(p) > 200);
    // Ink is a tone (1 - exp(-ink)), grey where a stroke runs dry, not solid black: a pixel
    // at half the paper's brightness or darker.
    let ink = count(sheet, &|p| luma(p) < 128);
    eprintln!(
        "sheet {sheet:?} in the view {canvas:?}: {paper} paper px, {ink} ink px of {}",
        area(sheet)
    );
    assert!(
        paper > area(sheet) / 2,
        "the sheet shows paper: {paper} light pixels"
    );
    assert!(ink > 500, "the paper view shows ink: {ink} dark pixels");

    // The app opens in the writing view: the paper's view takes most of the window.
    let window = rect(&layout, "window");
    let share = area(canvas) as f64 / area(window) as f64;
    eprintln!(
        "window {window:?}: the paper view has {:.1}%",
        share * 100.0
    );
    assert!(share >= 0.7, "the paper view has {share:.3} of the window");

    let brush = rect(&layout, "brush");
    let hair = count(brush, &|p| {
        p[0] >= 110 && p[0] - p[2] >= 60 && p[1] > p[2] && p[0] >= p[1]
    });
    eprintln!("brush view {brush:?}: {hair} hair px of {}", area(brush));
    assert!(
        hair > 300,
        "the brush view shows the brush: {hair} hair pixels"
    );
}
