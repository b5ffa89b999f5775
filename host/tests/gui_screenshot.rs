//! Checks a screenshot taken by `maobi gui --replay FILE --screenshot OUT.png` (CI runs it
//! under Xvfb, then this test with `MAOBI_GUI_SCREENSHOT=OUT.png`): the paper view holds ink
//! (dark pixels on light paper) and the brush view shows the brush (hair-coloured pixels).
//! The app writes the views' rectangles to `OUT.png.layout`.
//!
//! Without `MAOBI_GUI_SCREENSHOT` the test has nothing to check and passes, unless
//! `MAOBI_REQUIRE_GUI=1` says the screenshot must exist.

use std::path::PathBuf;

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

#[test]
fn screenshot_shows_ink_and_the_brush() {
    let Some(path) = std::env::var_os("MAOBI_GUI_SCREENSHOT").map(PathBuf::from) else {
        assert!(
            std::env::var("MAOBI_REQUIRE_GUI").as_deref() != Ok("1"),
            "MAOBI_REQUIRE_GUI=1 but MAOBI_GUI_SCREENSHOT is not set"
        );
        eprintln!("MAOBI_GUI_SCREENSHOT not set: nothing to check");
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
    let luma = |p: [i32; 3]| (p[0] * 3 + p[1] * 6 + p[2]) / 10;
    let paper = count(canvas, &|p| luma(p) > 200);
    // Ink is a tone (1 - exp(-ink)), grey where a stroke runs dry, not solid black: a pixel
    // at half the paper's brightness or darker.
    let ink = count(canvas, &|p| luma(p) < 128);
    eprintln!(
        "canvas {canvas:?}: {paper} paper px, {ink} ink px of {}",
        area(canvas)
    );
    assert!(
        paper > area(canvas) / 3,
        "the paper view shows paper: {paper} light pixels"
    );
    assert!(ink > 500, "the paper view shows ink: {ink} dark pixels");

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
