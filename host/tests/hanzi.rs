//! Characters from Make Me a Hanzi's data (`maobi::hanzi`): the shipped practice set, the
//! errors a missing or damaged file gives, and `maobi stroke from-char`'s stroke files, whose
//! render is held against the character's own outline (intersection over union, printed).

use maobi::hanzi::{self, HanziError};
use maobi::paper::{PaperKind, PaperSpec};
use maobi::strokes::Character;
use maobi_shared::{presets, Fx};
use std::process::Command;

#[test]
fn the_shipped_set_is_yong_and_the_hundred_most_common_characters_and_each_loads() {
    assert_eq!(hanzi::SHIPPED.len(), 101);
    for (name, _) in hanzi::SHIPPED {
        let h = hanzi::load_from(None, name).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert!(!h.strokes().is_empty(), "{name}");
        assert!(h.source.contains("shipped"), "{}", h.source);
    }
    assert_eq!(hanzi::load_from(None, "永").unwrap().strokes().len(), 5);
    assert_eq!(hanzi::load_from(None, "的").unwrap().strokes().len(), 8);
}

#[test]
fn a_folder_of_the_packages_files_comes_first_and_bad_input_is_a_clear_error() {
    let dir = std::env::temp_dir().join(format!("maobi-hanzi-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    // A file in the folder is read before the shipped one.
    let (_, yong) = hanzi::SHIPPED.iter().find(|(c, _)| *c == "永").unwrap();
    std::fs::write(dir.join("永.json"), yong).unwrap();
    let h = hanzi::load_from(Some(&dir), "永").unwrap();
    assert!(
        h.source.ends_with("永.json") && !h.source.contains("shipped"),
        "{}",
        h.source
    );

    // Damaged: not JSON, mismatched outlines and medians, an outline that is no path.
    let damaged = [
        ("不", "{\"strokes\": [\"M 0 0"),
        ("了", "{\"strokes\": [\"M 0 0 L 1 1 Z\"], \"medians\": []}"),
        (
            "人",
            "{\"strokes\": [\"M 0 0 X 1 1\"], \"medians\": [[[0, 0], [1, 1]]]}",
        ),
        ("大", "{\"strokes\": [], \"medians\": []}"),
        (
            "中",
            "{\"strokes\": [\"M 0 0 L 1 1 Z\"], \"medians\": [[[0, 0]]]}",
        ),
    ];
    for (ch, text) in damaged {
        std::fs::write(dir.join(format!("{ch}.json")), text).unwrap();
        let e = hanzi::load_from(Some(&dir), ch).unwrap_err();
        let msg = e.to_string();
        println!("{msg}");
        assert!(matches!(e, HanziError::Damaged { .. }), "{msg}");
        assert!(
            msg.contains(ch) && msg.contains(&format!("{ch}.json")),
            "{msg}"
        );
    }

    // Missing everywhere: names the character, the folder and the install script.
    let e = hanzi::load_from(Some(&dir), "龘").unwrap_err();
    let msg = e.to_string();
    println!("{msg}");
    assert!(matches!(e, HanziError::Missing { .. }), "{msg}");
    assert!(msg.contains("龘") && msg.contains("U+9F98") && msg.contains("install-hanzi-data"));
    assert!(msg.contains(&dir.display().to_string()), "{msg}");

    for not_one in ["", "永永", "ab"] {
        let e = hanzi::load_from(None, not_one).unwrap_err();
        assert!(matches!(e, HanziError::NotOneCharacter(_)), "{e}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn from_char_refuses_a_folder_that_is_not_there_and_a_character_without_data() {
    let out = std::env::temp_dir().join(format!("maobi-from-char-{}.toml", std::process::id()));
    let run = |ch: &str, data: &str| {
        Command::new(env!("CARGO_BIN_EXE_maobi"))
            .args(["stroke", "from-char", ch, "-o"])
            .arg(&out)
            .env(hanzi::DATA_ENV, data)
            .output()
            .unwrap()
    };
    let o = run("永", "/nonexistent/hanzi-writer-data");
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{err}");
    assert!(
        err.contains("MAOBI_HANZI_DATA=/nonexistent/hanzi-writer-data"),
        "{err}"
    );
    assert!(!err.contains("panicked"), "{err}");
    let o = run("龘", "");
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("no stroke data for 龘"),
        "{err}"
    );
    assert!(!out.exists());
}

/// Renders `ch`'s stroke file for the large brush and returns the intersection over union of
/// its ink with the character's outlines.
fn rendered_overlap(ch: &str, curve: &hanzi::WidthCurve) -> f64 {
    let params = presets::LARGE;
    let h = hanzi::load_from(None, ch).unwrap();
    let text = hanzi::stroke_file(&h, "large", &params, 80.0, curve).unwrap();
    let track = Character::from_toml(ch, &text).unwrap().track(ch).unwrap();
    let frame = maobi::render::paper_frame(&track, &params, 5.0).unwrap();
    let (canvas, _) =
        maobi::render::render::<Fx>(params, &track, frame, PaperSpec::new(PaperKind::Sized))
            .unwrap();
    let ink = hanzi::ink_mask(&canvas.to_gray8());
    let outline = hanzi::outline_mask(&h.to_mm(80.0), &frame);
    hanzi::overlap(&ink, &outline)
}

/// The bound: every character of the shipped set, written from its medians by the
/// default brush, overlaps its own outline at least this much.
const LEAST_OVERLAP: f64 = 0.5;

#[test]
fn every_shipped_character_written_from_its_medians_lies_on_its_own_outline() {
    let curve = hanzi::WidthCurve::measure(&presets::LARGE).unwrap();
    let mut figures = Vec::new();
    for (ch, _) in hanzi::SHIPPED {
        figures.push((*ch, rendered_overlap(ch, &curve)));
    }
    let line: Vec<String> = figures.iter().map(|(c, f)| format!("{c} {f:.2}")).collect();
    println!(
        "IoU with its own outline (large brush, 80 mm, 5 px/mm): {}",
        line.join(", ")
    );
    let (least, at) = figures
        .iter()
        .map(|(c, f)| (*f, *c))
        .fold((f64::INFINITY, ""), |a, b| if b.0 < a.0 { b } else { a });
    let mean = figures.iter().map(|(_, f)| f).sum::<f64>() / figures.len() as f64;
    println!(
        "{} characters: least {least:.3} ({at}), mean {mean:.3}",
        figures.len()
    );
    let below: Vec<_> = figures.iter().filter(|(_, f)| *f < LEAST_OVERLAP).collect();
    assert!(below.is_empty(), "below {LEAST_OVERLAP}: {below:?}");
}

#[test]
fn the_app_s_fonts_draw_every_shipped_character() {
    for (ch, _) in hanzi::SHIPPED {
        assert!(
            maobi::gui::fonts::CJK_TEXT.contains(ch),
            "{ch} is not in CJK_TEXT"
        );
    }
}
