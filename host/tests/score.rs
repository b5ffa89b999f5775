//! `maobi score`'s figures (`maobi::score`), each test printing what it measured: the master's
//! own writing scores at the top; a shift costs position only; wrong order, a stroke written
//! backwards and half speed are named where they belong; the scores are the same bits run to
//! run; bad input is an error, never a panic.

use maobi::hanzi;
use maobi::poses::PoseTrack;
use maobi::score::{Master, Report};
use maobi::strokes::{rows_to_csv, Character};
use maobi_shared::presets;

const SIZE_MM: f64 = 80.0;

/// The master for `ch` with the large brush, and its own stroke file's text.
fn master(ch: &str) -> (Master, String) {
    let params = presets::LARGE;
    let h = hanzi::load_from(None, ch).unwrap();
    let curve = hanzi::WidthCurve::measure(&params).unwrap();
    let text = hanzi::stroke_file(&h, "large", &params, SIZE_MM, &curve).unwrap();
    let m = Master::with_stroke_file(h, params, SIZE_MM, &text).unwrap();
    (m, text)
}

fn track_of(text: &str) -> PoseTrack {
    Character::from_toml("written", text)
        .unwrap()
        .track("written")
        .unwrap()
}

/// `track` with each row changed by `f`.
fn transformed(track: &PoseTrack, f: impl Fn(&mut maobi::poses::PoseRow)) -> PoseTrack {
    let mut rows = track.rows().to_vec();
    rows.iter_mut().for_each(f);
    PoseTrack::from_reader("changed", rows_to_csv(&rows).as_bytes()).unwrap()
}

fn score(m: &Master, track: &PoseTrack) -> Report {
    m.score(track).unwrap()
}

fn fig(r: &Report, name: &str) -> f64 {
    r.figure(name).unwrap().score
}

#[test]
fn the_masters_own_writing_scores_at_the_top_for_yong_and_ten_others() {
    for ch in [
        "永", "中", "大", "人", "心", "的", "是", "不", "我", "国", "学",
    ] {
        let (m, text) = master(ch);
        let r = score(&m, &track_of(&text));
        println!(
            "{ch}: total {:.3}, order {:.3}, shape {:.3}, position {:.3}",
            r.total,
            fig(&r, "order"),
            fig(&r, "shape"),
            fig(&r, "position")
        );
        for name in ["shape", "order", "position"] {
            assert!(fig(&r, name) >= 0.9, "{ch} {name}: {}", r.to_text());
        }
        assert!(r.extra.is_empty() && r.strokes.iter().all(|s| s.written.is_some()));
    }
}

#[test]
fn a_shift_of_five_millimetres_costs_position_only() {
    let (m, text) = master("永");
    let track = track_of(&text);
    let base = score(&m, &track);
    let moved = score(&m, &transformed(&track, |r| r.pos[0] += 5.0));
    println!("{}{}", base.to_text(), moved.to_text());
    assert!(
        (moved.offset_mm[0] - 5.0).abs() < 0.3,
        "{:?}",
        moved.offset_mm
    );
    assert!(fig(&moved, "position") < 0.7, "{}", fig(&moved, "position"));
    for name in ["order", "shape", "size", "direction", "speed", "press"] {
        let (a, b) = (fig(&base, name), fig(&moved, name));
        assert!((a - b).abs() <= 0.02, "{name}: {a} -> {b}");
    }
}

/// The stroke file `text` with its strokes changed by `f` (the `[[stroke]]` array).
fn edited(text: &str, f: impl Fn(&mut Vec<toml::Value>)) -> String {
    let mut doc: toml::Table = text.parse().unwrap();
    let strokes = doc.get_mut("stroke").unwrap().as_array_mut().unwrap();
    f(strokes);
    toml::to_string(&doc).unwrap()
}

#[test]
fn strokes_written_in_the_wrong_order_are_named() {
    let (m, text) = master("永");
    let swapped = edited(&text, |s| s.swap(1, 2));
    let r = score(&m, &track_of(&swapped));
    println!("{}", r.to_text());
    assert!(fig(&r, "order") < 1.0);
    let out_of_order: Vec<usize> = r
        .strokes
        .iter()
        .filter(|s| !s.in_order)
        .map(|s| s.stroke)
        .collect();
    assert_eq!(out_of_order.len(), 1, "{out_of_order:?}");
    assert!([2, 3].contains(&out_of_order[0]));
    assert!(r.to_text().contains("written out of order"));
    assert!(r
        .strokes
        .iter()
        .all(|s| s.written.is_some() && !s.backwards));
}

#[test]
fn a_stroke_written_backwards_is_named() {
    let (m, text) = master("永");
    // Stroke 4 (啄) with its keyframes in reverse, its times mirrored.
    let reversed = edited(&text, |s| {
        let keys = s[3].get_mut("keys").unwrap().as_array_mut().unwrap();
        let end = keys.last().unwrap().get("t").unwrap().as_float().unwrap();
        keys.reverse();
        for k in keys.iter_mut() {
            let t = k.get("t").unwrap().as_float().unwrap();
            k.as_table_mut()
                .unwrap()
                .insert("t".into(), toml::Value::Float(end - t));
        }
    });
    let base = score(&m, &track_of(&text));
    let r = score(&m, &track_of(&reversed));
    println!("{}", r.to_text());
    let backwards: Vec<usize> = r
        .strokes
        .iter()
        .filter(|s| s.backwards)
        .map(|s| s.stroke)
        .collect();
    assert_eq!(backwards, vec![4]);
    assert!(
        r.to_text().contains("stroke 4 啄: written 4") && r.to_text().contains("written backwards")
    );
    assert!(fig(&r, "direction") < fig(&base, "direction") - 0.1);
    assert_eq!(fig(&r, "order"), 1.0);
}

#[test]
fn half_speed_shows_in_the_speed_figure_only() {
    let (m, text) = master("永");
    let track = track_of(&text);
    let base = score(&m, &track);
    let slow = score(&m, &transformed(&track, |r| r.t *= 2.0));
    println!("{}{}", base.to_text(), slow.to_text());
    assert!(fig(&slow, "speed") <= 0.6, "{}", fig(&slow, "speed"));
    for name in ["order", "position", "size", "direction"] {
        let (a, b) = (fig(&base, name), fig(&slow, name));
        assert!((a - b).abs() <= 0.05, "{name}: {a} -> {b}");
    }
    // The slower brush opens wider: shape and press move a little, not like speed.
    for name in ["shape", "press"] {
        let (a, b) = (fig(&base, name), fig(&slow, name));
        assert!((a - b).abs() <= 0.1, "{name}: {a} -> {b}");
    }
}

#[test]
fn scores_are_the_same_bits_run_to_run() {
    let (m, text) = master("永");
    let track = track_of(&text);
    let a = serde_json::to_string(&score(&m, &track).to_json()).unwrap();
    let b = serde_json::to_string(&score(&m, &track).to_json()).unwrap();
    assert_eq!(a, b);
    let (m2, text2) = master("永");
    assert_eq!(text, text2);
    assert_eq!(
        a,
        serde_json::to_string(&score(&m2, &track).to_json()).unwrap()
    );
}

#[test]
fn writing_that_never_inks_is_an_error_not_a_panic() {
    let (m, text) = master("永");
    let high = transformed(&track_of(&text), |r| r.pos[2] += 30.0);
    let e = m.score(&high).unwrap_err().to_string();
    assert!(e.contains("nothing was written"), "{e}");
}

/// `maobi score`'s command line: the same figures from a stroke file and from a session of the
/// same poses, JSON with `total` and `figures.position`, the history appended, and clear
/// errors for a character without data and a session with no strokes.
#[test]
fn the_score_command_prints_json_appends_history_and_refuses_bad_input() {
    use maobi::device::journal::Journal;
    use maobi::gui::session::{InkLog, Session, MODEL_VERSION};
    use maobi::paper::PaperSpec;
    use maobi::raster::Frame;
    use std::process::Command;

    let dir = std::env::temp_dir().join(format!("maobi-score-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let history = dir.join("history").join("scores.csv");
    let run = |args: &[&str]| {
        let o = Command::new(env!("CARGO_BIN_EXE_maobi"))
            .arg("score")
            .args(args)
            .env(maobi::score::HISTORY_ENV, &history)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr).to_string();
        assert!(!err.contains("panicked"), "{err}");
        (
            o.status.success(),
            String::from_utf8_lossy(&o.stdout).to_string(),
            err,
        )
    };

    let (_, text) = master("永");
    let stroke = dir.join("yong.toml");
    std::fs::write(&stroke, &text).unwrap();
    let stroke_arg = stroke.display().to_string();
    let (ok, out, err) = run(&["--char", "永", "--stroke", &stroke_arg, "--json"]);
    assert!(ok, "{err}");
    let json: serde_json::Value = serde_json::from_str(&out).unwrap();
    let total = json["total"].as_f64().unwrap();
    let position = json["figures"]["position"]["score"].as_f64().unwrap();
    println!("永 from its stroke file: total {total:.3}, position {position:.3}");
    assert!(total >= 0.9 && position >= 0.9, "{out}");
    assert_eq!(json["strokes"][3]["name"], "啄");

    // The same poses as a session saved from the app.
    let track = track_of(&text);
    let rows = track.rows();
    let params = presets::LARGE;
    let mut journal = Journal::new("large", params, rows[0].pose());
    for (k, r) in rows.iter().enumerate().skip(1) {
        journal.tick(k as u64, r.pose());
    }
    let session = |journal: Journal| Session {
        device: "built-in simulator".into(),
        journal,
        paper: Frame::covering([-60.0, -60.0], [60.0, 60.0], 0.0, 5.0),
        paper_spec: PaperSpec::default(),
        ink: InkLog::default(),
        model: Some(MODEL_VERSION),
    };
    let file = dir.join("yong.maobi.toml");
    session(journal).save(&file).unwrap();
    let (ok, out_session, err) = run(&[
        "--char",
        "永",
        "--session",
        &file.display().to_string(),
        "--json",
    ]);
    assert!(ok, "{err}");
    let from_session: serde_json::Value = serde_json::from_str(&out_session).unwrap();
    assert_eq!(from_session["figures"], json["figures"]);
    assert_eq!(from_session["total"], json["total"]);

    // Text, appended to the history as well: a header and one row per attempt.
    let (ok, out, err) = run(&["--char", "永", "--stroke", &stroke_arg]);
    assert!(
        ok && out.contains("stroke 4 啄") && out.contains("total"),
        "{out}{err}"
    );
    let csv = std::fs::read_to_string(&history).unwrap();
    let lines: Vec<&str> = csv.lines().collect();
    assert_eq!(lines.len(), 4, "{csv}");
    assert_eq!(lines[0], maobi::score::history_header());
    assert!(lines[1..].iter().all(|l| l.contains(",永,")), "{csv}");

    // Bad input.
    let (ok, _, err) = run(&["--char", "龘", "--stroke", &stroke_arg]);
    assert!(!ok && err.contains("no stroke data for 龘"), "{err}");
    let (ok, _, err) = run(&["--char", "永永", "--stroke", &stroke_arg]);
    assert!(!ok && err.contains("not one character"), "{err}");
    let empty = dir.join("empty.maobi.toml");
    session(Journal::new("large", params, rows[0].pose()))
        .save(&empty)
        .unwrap();
    let (ok, _, err) = run(&["--char", "永", "--session", &empty.display().to_string()]);
    println!("{err}");
    assert!(!ok && err.contains("nothing was written"), "{err}");
    let (ok, _, err) = run(&["--char", "永"]);
    assert!(!ok && err.contains("--session"), "{err}");
    assert_eq!(
        std::fs::read_to_string(&history).unwrap(),
        csv,
        "failed runs add nothing"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}
