//! Stroke files: the 永 example renders deterministically with every stroke where the file
//! puts it, bad files are refused with the file, stroke and keyframe named, sampling and
//! fitting through the command line.

use std::path::{Path, PathBuf};
use std::process::Command;

use maobi::offline::simulate;
use maobi::paper::PaperSpec;
use maobi::raster::Canvas;
use maobi::render::{encode_png, paper_frame, render, Inker};
use maobi::strokes::{fit_track, Character};
use maobi_shared::stroke::orient::angle_between;
use maobi_shared::{presets, Fx};

fn yong_path() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/strokes/yong.toml")
}

fn yong() -> Character {
    Character::from_path(&yong_path()).expect("yong.toml is valid")
}

const PX_PER_MM: f64 = 4.0;

#[test]
fn yong_renders_byte_identically_twice() {
    let ch = yong();
    let params = presets::by_name("large").unwrap();
    let png = || {
        let track = ch.track("yong").unwrap();
        let frame = paper_frame(&track, &params, PX_PER_MM).unwrap();
        let (canvas, _) = render::<Fx>(params, &track, frame, PaperSpec::default()).unwrap();
        let mut bytes = Vec::new();
        encode_png(&canvas, &mut bytes).unwrap();
        bytes
    };
    let (a, b) = (png(), png());
    assert!(a.len() > 1000);
    assert!(a == b, "two renders of yong.toml differ");
}

/// Renders 永 with each stroke's ink on its own canvas (index 8: the travel between strokes).
fn per_stroke_ink(ch: &Character) -> (Vec<Canvas>, maobi::raster::Frame) {
    let params = presets::by_name("large").unwrap();
    let track = ch.track("yong").unwrap();
    let frame = paper_frame(&track, &params, PX_PER_MM).unwrap();
    let mut canvases: Vec<Canvas> = (0..=ch.stroke_times.len())
        .map(|_| Canvas::new(frame.width, frame.height))
        .collect();
    let mut inker = Inker::new(frame, params.layers as usize - 1);
    simulate::<Fx>(params, &track, |tick| {
        let idx = ch
            .stroke_times
            .iter()
            .position(|&(a, b)| tick.t >= a - 1e-9 && tick.t <= b + 1e-9)
            .unwrap_or(ch.stroke_times.len());
        inker.stamp(tick.brush, &mut canvases[idx]);
        Ok(())
    })
    .unwrap();
    (canvases, frame)
}

/// The paper-mm bounding box of a stroke's keyframes that are on or below the paper.
fn pressed_box(ch: &Character, i: usize) -> [f64; 4] {
    let seg = ch.segments.iter().find(|s| s.from == Some(i)).unwrap();
    let mut b = [
        f64::INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NEG_INFINITY,
    ];
    for k in 0..seg.stroke.len() {
        let (p, _) = seg.stroke.key(k);
        b = [
            b[0].min(p[0]),
            b[1].min(p[1]),
            b[2].max(p[0]),
            b[3].max(p[1]),
        ];
    }
    b
}

/// Darkness from which a pixel counts as inked. The ink has tones now (a stroke runs from
/// rich to dry, and splits into dry-brush streaks), so a mid-grey counts.
const INKED: f32 = 0.2;

fn inked_px(c: &Canvas) -> Vec<(usize, usize)> {
    let mut v = Vec::new();
    for y in 0..c.height() {
        for x in 0..c.width() {
            if c.at(x, y) > INKED {
                v.push((x, y));
            }
        }
    }
    v
}

#[test]
fn every_stroke_leaves_ink_where_the_file_puts_it_and_the_hook_tapers_without_a_gap() {
    let ch = yong();
    assert_eq!(ch.stroke_times.len(), 8);
    let (canvases, frame) = per_stroke_ink(&ch);
    // The brush is 40 mm long, leans and bends behind the ferrule: its ink may reach some mm
    // past the ferrule's keyframes, but the ink's centre lies close to the keyframes' box.
    let margin_mm = 12.0;
    for (i, canvas) in canvases.iter().enumerate().take(8) {
        let px = inked_px(canvas);
        let area_mm2 = px.len() as f64 / (PX_PER_MM * PX_PER_MM);
        assert!(
            area_mm2 > 15.0,
            "stroke {} left only {area_mm2:.1} mm^2 of ink",
            i + 1
        );
        let b = pressed_box(&ch, i);
        let lo = frame.to_px(b[0] - margin_mm, b[3] + margin_mm);
        let hi = frame.to_px(b[2] + margin_mm, b[1] - margin_mm);
        let beyond = px
            .iter()
            .map(|&(x, y)| {
                let (x, y) = (x as f64, y as f64);
                let dx = (lo[0] - x).max(x - hi[0]).max(0.0);
                let dy = (lo[1] - y).max(y - hi[1]).max(0.0);
                dx.max(dy) / PX_PER_MM
            })
            .fold(0.0, f64::max);
        assert!(
            beyond == 0.0,
            "stroke {}: ink {beyond:.2} mm outside its box",
            i + 1
        );
        let cx = px.iter().map(|p| p.0 as f64).sum::<f64>() / px.len() as f64;
        let cy = px.iter().map(|p| p.1 as f64).sum::<f64>() / px.len() as f64;
        let (clo, chi) = (
            frame.to_px(b[0] - 4.0, b[3] + 4.0),
            frame.to_px(b[2] + 4.0, b[1] - 4.0),
        );
        assert!(
            cx >= clo[0] && cx <= chi[0] && cy >= clo[1] && cy <= chi[1],
            "stroke {}: ink centred at ({cx}, {cy}) px, keyframes in {clo:?}..{chi:?}",
            i + 1
        );
    }
    // Nothing is inked while travelling between strokes.
    assert!(inked_px(&canvases[8]).is_empty(), "the travel left ink");

    // The hook (stroke 4): one blot, thinner at its end than at its start. A flick splits
    // into dry-brush streaks (飛白) along its way, so the blot's pixels are connected across
    // gaps narrower than `BRIDGE` px (a few hair strips), not only pixel to pixel.
    const BRIDGE: i64 = 6;
    let hook = &canvases[3];
    let px = inked_px(hook);
    let mut seen = vec![false; hook.width() * hook.height()];
    let mut stack = vec![px[0]];
    seen[px[0].1 * hook.width() + px[0].0] = true;
    let mut reached = 0;
    while let Some((x, y)) = stack.pop() {
        reached += 1;
        for dy in -BRIDGE..=BRIDGE {
            for dx in -BRIDGE..=BRIDGE {
                let (nx, ny) = (x as i64 + dx, y as i64 + dy);
                if nx < 0 || ny < 0 || nx >= hook.width() as i64 || ny >= hook.height() as i64 {
                    continue;
                }
                let (nx, ny) = (nx as usize, ny as usize);
                if !seen[ny * hook.width() + nx] && hook.at(nx, ny) > INKED {
                    seen[ny * hook.width() + nx] = true;
                    stack.push((nx, ny));
                }
            }
        }
    }
    assert_eq!(reached, px.len(), "the hook's ink is broken into pieces");
    // Along the flick's direction (up and to the left), the last third of the ink is thinner
    // than the first.
    let d = [-12.0f64, 6.5];
    let n = (d[0] * d[0] + d[1] * d[1]).sqrt();
    // Image y points down the paper.
    let proj: Vec<f64> = px
        .iter()
        .map(|&(x, y)| (x as f64 * d[0] - y as f64 * d[1]) / n)
        .collect();
    let (lo, hi) = proj
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &p| {
            (a.min(p), b.max(p))
        });
    // Ink per fifth of the hook's length: from its widest part on, the width only shrinks
    // toward the tip, and the tip (last fifth) is less than half as wide as the widest part.
    let fifth = (hi - lo) / 5.0;
    let bins: Vec<usize> = (0..5)
        .map(|j| {
            let (a, b) = (lo + j as f64 * fifth, lo + (j + 1) as f64 * fifth);
            proj.iter()
                .filter(|&&p| p >= a && (p < b || j == 4))
                .count()
        })
        .collect();
    let widest = (0..5).max_by_key(|&j| bins[j]).unwrap();
    assert!(
        widest < 4 && bins[4] * 2 < bins[widest],
        "the hook does not taper: {bins:?}"
    );
    assert!(
        bins[widest..].windows(2).all(|w| w[1] <= w[0]),
        "the hook thickens toward its tip: {bins:?}"
    );
}

#[test]
fn fitting_the_sampled_yong_stays_within_tolerance() {
    let ch = yong();
    let track = ch.track("yong").unwrap();
    let (text, mm, deg) = fit_track(&track, 0.2, 2.0).unwrap();
    assert!(mm <= 0.2 && deg <= 2.0, "{mm} mm {deg} deg");
    let fitted = Character::from_toml("fitted.toml", &text).unwrap();
    let rows = track.rows();
    let keys = text.matches("at = ").count();
    assert!(
        keys < rows.len() / 20,
        "{keys} keyframes for {} poses",
        rows.len()
    );
    for r in rows {
        let (p, q) = fitted.pose_at(r.t - rows[0].t);
        let e = ((p[0] - r.pos[0]).powi(2) + (p[1] - r.pos[1]).powi(2) + (p[2] - r.pos[2]).powi(2))
            .sqrt();
        // The file rounds to 1 um and 1e-9.
        assert!(e <= 0.2 + 1e-3, "t {}: {e} mm", r.t);
        assert!(angle_between(q, r.rot).to_degrees() <= 2.0 + 1e-3);
    }
}

/// A pen recording at 1 kHz: the pen rests 3 s, writes a wavy 60 mm stroke (12 waves) in
/// 1 s, rests 1 s, writes it back in 1 s and rests 2 s. Too wavy for one stroke's keyframes,
/// so the fit splits it, and pieces of it are all rest.
fn rests_and_waves() -> String {
    let mut rows = Vec::new();
    let wave = |s: f64| {
        let x = 60.0 * (1.0 - (std::f64::consts::PI * s.clamp(0.0, 1.0)).cos()) / 2.0;
        [
            x,
            3.0 * (std::f64::consts::TAU * 12.0 * x / 60.0).sin(),
            36.0,
        ]
    };
    for k in 0..=8000 {
        let t = k as f64 / 1000.0;
        let pos = if t <= 5.0 {
            wave(t - 3.0)
        } else {
            wave(1.0 - (t - 5.0))
        };
        rows.push(maobi::poses::PoseRow {
            t,
            pos,
            rot: [1.0, 0.0, 0.0, 0.0],
        });
    }
    maobi::strokes::rows_to_csv(&rows)
}

/// The largest distance (mm) and turn (degrees) between a fitted file's poses and the
/// recorded ones.
fn fitted_errors(fitted: &Character, rows: &[maobi::poses::PoseRow]) -> (f64, f64) {
    let (mut mm, mut deg) = (0.0f64, 0.0f64);
    for r in rows {
        let (p, q) = fitted.pose_at(r.t - rows[0].t);
        let e = ((p[0] - r.pos[0]).powi(2) + (p[1] - r.pos[1]).powi(2) + (p[2] - r.pos[2]).powi(2))
            .sqrt();
        mm = mm.max(e);
        deg = deg.max(angle_between(q, r.rot).to_degrees());
    }
    (mm, deg)
}

/// A user review: a recording that rests, then writes, was refused with "the pose stream never
/// moves" (a split-off piece that was all rest failed the whole file). The rests are stops
/// now: the file lasts as long as the recording, follows it within the tolerance and inks
/// the same paper.
#[test]
fn fitting_a_recording_with_rests_keeps_them_as_stops_and_renders_alike() {
    let csv = rests_and_waves();
    let track = maobi::poses::PoseTrack::from_reader("waves.csv", csv.as_bytes()).unwrap();
    let (text, mm, deg) = fit_track(&track, 0.2, 2.0).unwrap();
    assert!(mm <= 0.2 && deg <= 2.0, "{mm} mm {deg} deg");
    assert!(
        text.contains("stops"),
        "no rest was written as a stop:\n{text}"
    );
    let fitted = Character::from_toml("fitted.toml", &text).unwrap();
    assert!(
        fitted.stroke_times.len() > 1,
        "the recording was not split: {text}"
    );
    assert!(
        (fitted.duration() - 8.0).abs() < 1e-6,
        "the fitted file lasts {} s, the recording 8 s",
        fitted.duration()
    );
    let (e_mm, e_deg) = fitted_errors(&fitted, track.rows());
    // The file keeps positions to 1 nm and times to 1 us.
    assert!(
        e_mm <= 0.2 + 1e-5 && e_deg <= 2.0 + 1e-5,
        "{e_mm} mm {e_deg} deg"
    );

    // The same brush on the same paper inks (nearly) the same pixels.
    let params = presets::by_name("large").unwrap();
    let frame = paper_frame(&track, &params, PX_PER_MM).unwrap();
    let ink = |t: &maobi::poses::PoseTrack| {
        let (canvas, _) = render::<Fx>(params, t, frame, PaperSpec::default()).unwrap();
        inked_px(&canvas)
    };
    let (a, b) = (ink(&track), ink(&fitted.track("fitted").unwrap()));
    assert!(
        a.len() as f64 / (PX_PER_MM * PX_PER_MM) > 100.0,
        "the wave left no ink"
    );
    let a: std::collections::HashSet<_> = a.into_iter().collect();
    let b: std::collections::HashSet<_> = b.into_iter().collect();
    let iou = a.intersection(&b).count() as f64 / a.union(&b).count() as f64;
    assert!(
        iou > 0.95,
        "the fitted file's ink overlaps the recording's by {iou:.3}"
    );
}

/// The user's second case: 永 sampled and fitted within 1 um. Its hovers between strokes are
/// rests, and at that tolerance the fit splits it finely enough to cut some off whole.
#[test]
fn fitting_the_sampled_yong_within_a_micrometre_succeeds() {
    let track = yong().track("yong").unwrap();
    let (text, mm, deg) = fit_track(&track, 0.001, 2.0).unwrap();
    assert!(mm <= 0.001 && deg <= 2.0, "{mm} mm {deg} deg");
    let fitted = Character::from_toml("fitted.toml", &text).unwrap();
    let (e_mm, e_deg) = fitted_errors(&fitted, track.rows());
    assert!(
        e_mm <= 0.001 + 1e-5 && e_deg <= 2.0 + 1e-5,
        "{e_mm} mm {e_deg} deg"
    );
}

/// A tolerance finer than a stroke file can hold (it rounds positions to 1 nm) is refused,
/// saying so and naming the smallest tolerance that works; that one does, and the errors
/// reported are the written file's.
#[test]
fn a_tolerance_too_tight_for_the_file_names_the_smallest_that_works() {
    let track = yong().track("yong").unwrap();
    let e = match fit_track(&track, 1e-9, 2.0) {
        Ok((_, mm, _)) => panic!("fitted within 1e-9 mm, reporting {mm} mm"),
        Err(e) => format!("{e:#}"),
    };
    assert!(
        e.contains("--tol-mm 0.000000001 is too tight") && !e.contains("never moves"),
        "{e}"
    );
    let smallest: f64 = e
        .split("the smallest tolerance that works is --tol-mm ")
        .nth(1)
        .and_then(|w| w.split_whitespace().next())
        .and_then(|w| w.parse().ok())
        .unwrap_or_else(|| panic!("no tolerance named: {e}"));
    assert!(smallest > 1e-9 && smallest < 1e-3, "{e}");
    let (text, mm, _) = fit_track(&track, smallest, 2.0).unwrap();
    let fitted = Character::from_toml("fitted.toml", &text).unwrap();
    let (e_mm, _) = fitted_errors(&fitted, track.rows());
    assert!(
        e_mm <= smallest,
        "the file is {e_mm} mm off, more than {smallest}"
    );
    assert!(
        (mm - e_mm).abs() < 1e-12,
        "reported {mm} mm, the file is {e_mm} mm off"
    );
}

/// A recording where the pen never moves still says so.
#[test]
fn fitting_a_recording_that_never_moves_says_so() {
    let rows: Vec<_> = (0..500)
        .map(|k| maobi::poses::PoseRow {
            t: k as f64 * 0.001,
            pos: [5.0, 5.0, 36.0],
            rot: [1.0, 0.0, 0.0, 0.0],
        })
        .collect();
    let csv = maobi::strokes::rows_to_csv(&rows);
    let track = maobi::poses::PoseTrack::from_reader("still.csv", csv.as_bytes()).unwrap();
    let e = format!("{:#}", fit_track(&track, 0.2, 2.0).unwrap_err());
    assert!(e.contains("never moves"), "{e}");
}

fn err(text: &str) -> String {
    format!("{:#}", Character::from_toml("bad.toml", text).unwrap_err())
}

const HEAD: &str = "format = \"maobi-stroke\"\nversion = 1\n";

#[test]
fn bad_files_name_the_file_stroke_and_keyframe() {
    let two = "[[stroke]]\nkeys = [{ at = [0, 0], lift = 1 }, { at = [5, 0], depth = 2 }]\n";
    // Missing fields.
    let e = err(two);
    assert!(e.contains("bad.toml") && e.contains("format"), "{e}");
    let e = err("format = \"maobi-stroke\"\n");
    assert!(e.contains("bad.toml") && e.contains("version"), "{e}");
    let e = err(&format!(
        "{HEAD}{two}[[stroke]]\nname = \"x\"\nkeys = [{{ at = [0, 0], lift = 1 }}, {{ depth = 2 }}]\n"
    ));
    assert!(
        e.contains("bad.toml")
            && e.contains("stroke 2 (x)")
            && e.contains("keyframe 2")
            && e.contains("`at"),
        "{e}"
    );
    let e = err(&format!(
        "{HEAD}[[stroke]]\nkeys = [{{ at = [0, 0] }}, {{ at = [1, 0], depth = 2 }}]\n"
    ));
    assert!(
        e.contains("stroke 1") && e.contains("keyframe 1") && e.contains("depth"),
        "{e}"
    );
    // Times that go backwards.
    let e = err(&format!(
        "{HEAD}{two}[[stroke]]\nkeys = [{{ at = [0, 0], lift = 1, t = 0 }}, {{ at = [1, 0], depth = 1, t = 0.5 }}, {{ at = [2, 0], depth = 1, t = 0.3 }}]\n"
    ));
    assert!(
        e.contains("bad.toml")
            && e.contains("stroke 2")
            && e.contains("keyframe 3")
            && e.contains("time"),
        "{e}"
    );
    // NaN.
    let e = err(&format!(
        "{HEAD}[[stroke]]\nkeys = [{{ at = [0, nan], lift = 1 }}, {{ at = [1, 0], depth = 2 }}]\n"
    ));
    assert!(
        e.contains("stroke 1") && e.contains("keyframe 1") && e.contains("not finite"),
        "{e}"
    );
    let e = err(&format!("{HEAD}[[stroke]]\nkeys = [{{ at = [0, 0], lift = 1 }}, {{ at = [1, 0], depth = 2, t = inf }}]\n"));
    assert!(e.contains("keyframe 2") && e.contains("not finite"), "{e}");
    // Too few keyframes.
    let e = err(&format!(
        "{HEAD}{two}[[stroke]]\nname = \"dot\"\nkeys = [{{ at = [0, 0], lift = 1 }}]\n"
    ));
    assert!(
        e.contains("bad.toml")
            && e.contains("stroke 2 (dot)")
            && e.contains("at least 2 keyframes"),
        "{e}"
    );
    // Repeated pose, unknown field, wrong version, travel = false that does not join.
    let e = err(&format!(
        "{HEAD}[[stroke]]\nkeys = [{{ at = [0, 0], lift = 1 }}, {{ at = [0, 0], lift = 1 }}]\n"
    ));
    assert!(e.contains("keyframe 2") && e.contains("same pose"), "{e}");
    let e = err(&format!(
        "{HEAD}[[stroke]]\nkeys = [{{ at = [0, 0], lift = 1, speed = 3 }}]\n"
    ));
    assert!(e.contains("bad.toml") && e.contains("speed"), "{e}");
    let e = err("format = \"maobi-stroke\"\nversion = 2\n");
    assert!(e.contains("version 2") || e.contains("`version` 2"), "{e}");
    let e = err(&format!("{HEAD}{two}[[stroke]]\ntravel = false\nkeys = [{{ at = [9, 0], lift = 1 }}, {{ at = [5, 0], depth = 2 }}]\n"));
    assert!(
        e.contains("stroke 2") && e.contains("travel = false"),
        "{e}"
    );
    // Finite but absurd numbers are refused before anything is sampled (they had made the
    // sampler ask for petabytes and abort): a depth of a billion kilometres, a keyframe a
    // thousand million seconds in, a handle upside down, a crawl that would last days.
    let e = err(&format!(
        "{HEAD}[[stroke]]\nkeys = [{{ at = [0, 0], depth = 1e12 }}, {{ at = [1, 0], depth = 2 }}]\n"
    ));
    assert!(
        e.contains("keyframe 1") && e.contains("within 10000 mm"),
        "{e}"
    );
    let e = err(&format!(
        "{HEAD}[[stroke]]\nkeys = [{{ at = [0, 0], lift = 1 }}, {{ at = [1, 0], depth = 2, t = 1e9 }}]\n"
    ));
    assert!(e.contains("keyframe 2") && e.contains("`t`"), "{e}");
    let e = err(&format!(
        "{HEAD}[[stroke]]\nkeys = [{{ at = [0, 0], lift = 1, tilt = 180 }}, {{ at = [1, 0], depth = 2 }}]\n"
    ));
    assert!(e.contains("keyframe 1") && e.contains("-90..90"), "{e}");
    let e = err(&format!(
        "{HEAD}tilt_deg = 95\n[[stroke]]\nkeys = [{{ at = [0, 0], lift = 1 }}, {{ at = [1, 0], depth = 2 }}]\n"
    ));
    assert!(e.contains("`tilt_deg`"), "{e}");
    let e = err(&format!(
        "{HEAD}speed_mm_s = 1e-6\n[[stroke]]\nkeys = [{{ at = [0, 0], lift = 1 }}, {{ at = [100, 0], depth = 2 }}]\n"
    ));
    assert!(e.contains("4 hours"), "{e}");
}

#[test]
fn cli_samples_and_fits_stroke_files() {
    let dir = std::env::temp_dir().join(format!("maobi-strokes-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let poses = dir.join("yong.csv");
    let out = Command::new(env!("CARGO_BIN_EXE_maobi"))
        .args(["stroke", "sample"])
        .arg(yong_path())
        .arg("-o")
        .arg(&poses)
        .args(["--rate", "500"])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = std::fs::read_to_string(&poses).unwrap();
    assert!(text.starts_with("t,x,y,z,qw,qx,qy,qz\n"));
    let second = text.lines().nth(2).unwrap();
    assert!(second.starts_with("0.002000,"), "{second}");

    let fitted = dir.join("fitted.toml");
    let out = Command::new(env!("CARGO_BIN_EXE_maobi"))
        .args(["stroke", "fit"])
        .arg(&poses)
        .arg("-o")
        .arg(&fitted)
        .args(["--tol-mm", "0.2", "--tol-deg", "2"])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(Character::from_path(&fitted).is_ok());

    // --poses and --stroke are mutually exclusive, and one is needed.
    let both = Command::new(env!("CARGO_BIN_EXE_maobi"))
        .args([
            "render", "--poses", "a.csv", "--stroke", "b.toml", "-o", "x.png",
        ])
        .output()
        .unwrap();
    assert!(!both.status.success());
    assert!(String::from_utf8_lossy(&both.stderr).contains("--stroke"));
    let none = Command::new(env!("CARGO_BIN_EXE_maobi"))
        .args(["trace", "-o", "x.csv"])
        .output()
        .unwrap();
    assert!(!none.status.success());
    // A bad stroke file through render names it.
    let bad = dir.join("bad.toml");
    std::fs::write(
        &bad,
        "format = \"maobi-stroke\"\nversion = 1\n[[stroke]]\nkeys = []\n",
    )
    .unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_maobi"))
        .args(["render", "--stroke"])
        .arg(&bad)
        .args(["-o"])
        .arg(dir.join("bad.png"))
        .output()
        .unwrap();
    let msg = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && msg.contains("bad.toml") && msg.contains("stroke 1"),
        "{msg}"
    );
    std::fs::remove_dir_all(&dir).ok();
}

/// A stroke file is written for a head length (`head_mm`, 40 mm by default). Rendered with a
/// shorter brush it never touches the paper: the command says so, naming the lengths and
/// the option, and `--head-mm` places the depths for the brush in hand.
#[test]
fn a_file_for_a_longer_head_warns_and_head_mm_places_it_for_the_brush() {
    let dir = std::env::temp_dir().join(format!("maobi-head-mm-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("dash.toml");
    let text = format!(
        "{HEAD}tilt_deg = 10\n[[stroke]]\nkeys = [{{ at = [0, 0], depth = 4 }}, \
         {{ at = [10, 0], depth = 4 }}, {{ at = [20, 0], depth = 4 }}]\n"
    );
    std::fs::write(&file, &text).unwrap();

    // Placed for 18 mm, the pressed keyframes sit 18 cos 10 - 4 mm above the paper.
    let lowest = |c: &Character| {
        c.track("dash")
            .unwrap()
            .resample()
            .map(|p| p.pos.z)
            .fold(f64::INFINITY, f64::min)
    };
    let for_small = Character::from_toml_for_head("dash.toml", &text, Some(18.0)).unwrap();
    let as_written = Character::from_toml("dash.toml", &text).unwrap();
    assert_eq!((as_written.head_mm, for_small.head_mm), (40.0, 18.0));
    let want = 18.0 * 10f64.to_radians().cos() - 4.0;
    assert!(
        (lowest(&for_small) - want).abs() < 1e-6,
        "{}",
        lowest(&for_small)
    );
    assert!((lowest(&as_written) - (want + 22.0 * 10f64.to_radians().cos())).abs() < 1e-6);

    let run = |args: &[&str]| {
        let png = dir.join("out.png");
        let out = Command::new(env!("CARGO_BIN_EXE_maobi"))
            .args(args)
            .arg("--stroke")
            .arg(&file)
            .arg("-o")
            .arg(&png)
            .output()
            .unwrap();
        let msg = String::from_utf8_lossy(&out.stderr).into_owned();
        assert!(out.status.success(), "{args:?}: {msg}");
        let inked = args[0] == "render" && {
            let mut r =
                png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&png).unwrap()))
                    .read_info()
                    .unwrap();
            let mut buf = vec![0; r.output_buffer_size().unwrap()];
            let info = r.next_frame(&mut buf).unwrap();
            buf[..info.buffer_size()].iter().any(|&v| v < 128)
        };
        (msg, inked)
    };
    let (msg, inked) = run(&["render", "--brush", "small"]);
    assert!(
        msg.contains("never reaches the paper")
            && msg.contains("40.0 mm head")
            && msg.contains("`--head-mm 18.0`"),
        "{msg}"
    );
    assert!(!inked, "the small brush inked a file it cannot reach");
    let (msg, inked) = run(&["render", "--brush", "small", "--head-mm", "18"]);
    assert!(!msg.contains("warning"), "{msg}");
    assert!(inked, "placed for the small brush, the stroke left no ink");
    let (msg, inked) = run(&["render"]);
    assert!(!msg.contains("warning") && inked, "{msg}");
    // Placed for a head longer than the brush, by the option: the warning says so.
    let (msg, _) = run(&["render", "--brush", "small", "--head-mm", "30"]);
    assert!(
        msg.contains("30.0 mm head (as asked)") && msg.contains("`--head-mm 18.0`"),
        "{msg}"
    );
    // Baxter & Lin's flat head (18 mm of hair) and the trace say it too.
    let (msg, _) = run(&["trace", "--model", "baxter-lin", "--brush", "flat"]);
    assert!(
        msg.contains("never reaches the paper") && msg.contains("18.0 mm long"),
        "{msg}"
    );
    let (msg, inked) = run(&[
        "render",
        "--model",
        "baxter-lin",
        "--brush",
        "flat",
        "--head-mm",
        "18",
    ]);
    assert!(!msg.contains("warning") && inked, "{msg}");

    // Keyframes that give the ferrule's height: no head length moves them, and the warning
    // does not suggest one.
    let absolute = dir.join("absolute.toml");
    std::fs::write(
        &absolute,
        format!("{HEAD}[[stroke]]\nkeys = [{{ at = [0, 0, 30] }}, {{ at = [10, 0, 30] }}]\n"),
    )
    .unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_maobi"))
        .args(["render", "--brush", "small", "--stroke"])
        .arg(&absolute)
        .arg("-o")
        .arg(dir.join("abs.png"))
        .output()
        .unwrap();
    let msg = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success()
            && msg.contains("give the ferrule's height")
            && !msg.contains("--head-mm"),
        "{msg}"
    );

    // A pose file has no depths to place.
    let out = Command::new(env!("CARGO_BIN_EXE_maobi"))
        .args([
            "render",
            "--poses",
            "a.csv",
            "--head-mm",
            "18",
            "-o",
            "x.png",
        ])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--head-mm"));
    std::fs::remove_dir_all(&dir).ok();
}
