//! Ink and paper: a fast stroke's tone shows no stamps, the ink inside a stroke has tones,
//! raw paper spreads wider than sized, the paper step conserves ink, renders are the same
//! bits run to run, and an unknown paper is refused on the command line and in files.

use std::fmt::Write as _;
use std::process::Command;

use maobi::offline::simulate;
use maobi::paper::{Canvas, PaperKind, PaperSpec};
use maobi::poses::PoseTrack;
use maobi::raster::Frame;
use maobi::render::{paper_frame, render, Inker};
use maobi_shared::{presets, BrushParams, Fx};

const PX_PER_MM: f64 = 10.0;

/// The large brush tilted 15 degrees, settled 0.2 s pressed at x = 0, then drawn along +x
/// for `length_mm` at `speed` mm/s, then held 0.05 s.
fn stroke(speed: f64, length_mm: f64) -> PoseTrack {
    let h = 15f64.to_radians() / 2.0;
    let (qw, qy) = (h.cos(), h.sin());
    let mut csv = String::from("t,x,y,z,qw,qx,qy,qz\n");
    let travel = length_mm / speed;
    let total = 0.2 + travel + 0.05;
    let n = (total * 1000.0).round() as usize;
    for k in 0..=n {
        let t = k as f64 * 1e-3;
        let x = ((t - 0.2).max(0.0) * speed).min(length_mm);
        let _ = writeln!(csv, "{t:.3},{x},0,33,{qw},0,{qy},0");
    }
    PoseTrack::from_reader("stroke.csv", csv.as_bytes()).unwrap()
}

fn render_on(track: &PoseTrack, kind: PaperKind) -> (Canvas, Frame) {
    render_with(presets::by_name("large").unwrap(), track, kind)
}

fn render_with(params: BrushParams, track: &PoseTrack, kind: PaperKind) -> (Canvas, Frame) {
    let frame = paper_frame(track, &params, PX_PER_MM).unwrap();
    let (c, _) = render::<Fx>(params, track, frame, PaperSpec::new(kind)).unwrap();
    (c, frame)
}

/// Relative amplitude of the component of period `period` (samples) in `v`:
/// |sum v_k e^(-2 pi i k / period)| / sum |v_k|.
fn periodic_amplitude(v: &[f64], period: f64) -> f64 {
    let (mut re, mut im, mut sum) = (0.0, 0.0, 0.0);
    let mean = v.iter().sum::<f64>() / v.len() as f64;
    for (k, &x) in v.iter().enumerate() {
        let a = 2.0 * std::f64::consts::PI * k as f64 / period;
        re += (x - mean) * a.cos();
        im -= (x - mean) * a.sin();
        sum += x.abs();
    }
    2.0 * (re * re + im * im).sqrt() / sum
}

/// The measure: along the steady middle half of a 500 mm/s stroke (0.5 mm = 5 px per tick at
/// 10 px/mm), (a) the ink along the stroke's centre line and (b) the sub-pixel row where the
/// darkness crosses 0.5 on each edge, per column; the amplitude of their Fourier component
/// at the tick spacing, relative to their mean (ink) or in pixels (edges), must be tiny.
#[test]
fn a_500_mm_s_stroke_shows_no_stamps_at_the_tick_spacing() {
    let track = stroke(500.0, 120.0);
    let (c, frame) = render_on(&track, PaperKind::Sized);
    let period = 500.0 * 1e-3 * PX_PER_MM;
    let x_at = |mm: f64| frame.to_px(mm, 0.0)[0] as usize;
    // The middle half of the travel; the brush trails behind the ferrule.
    let (x0, x1) = (x_at(30.0), x_at(90.0));
    let w = c.width();
    // The centre line: the row with the most ink over the middle section.
    let row_ink = |y: usize| -> f64 { (x0..x1).map(|x| c.ink()[y * w + x] as f64).sum() };
    let centre = (0..c.height())
        .max_by(|&a, &b| row_ink(a).total_cmp(&row_ink(b)))
        .unwrap();
    let line: Vec<f64> = (x0..x1).map(|x| c.ink()[centre * w + x] as f64).collect();
    let mean = line.iter().sum::<f64>() / line.len() as f64;
    assert!(mean > 0.5, "the centre line is inked ({mean})");
    let tone = periodic_amplitude(&line, period);
    // Edges: where the darkness crosses 0.5 above and below the centre line.
    let crossing = |x: usize, dir: i64| -> f64 {
        let mut y = centre as i64;
        loop {
            let (a, b) = (c.at(x, y as usize), c.at(x, (y + dir) as usize));
            if b < 0.5 {
                return y as f64 + dir as f64 * (a as f64 - 0.5) / (a - b) as f64;
            }
            y += dir;
        }
    };
    let top: Vec<f64> = (x0..x1).map(|x| crossing(x, -1)).collect();
    let bottom: Vec<f64> = (x0..x1).map(|x| crossing(x, 1)).collect();
    let amp_px = |v: &[f64]| {
        let sum = v.iter().map(|x| x.abs()).sum::<f64>();
        periodic_amplitude(v, period) * sum / v.len() as f64
    };
    let (top_px, bottom_px) = (amp_px(&top), amp_px(&bottom));
    println!(
        "500 mm/s, period {period} px: centre-line tone {:.4}% of its mean ink {mean:.2}; \
         edge rows {top_px:.4} px (top), {bottom_px:.4} px (bottom); width {:.1} px",
        tone * 100.0,
        bottom.iter().zip(&top).map(|(b, t)| b - t).sum::<f64>() / top.len() as f64
    );
    assert!(
        tone < 0.005,
        "centre-line tone varies {tone} at the tick spacing"
    );
    assert!(
        top_px < 0.05 && bottom_px < 0.05,
        "edges scallop: {top_px} / {bottom_px} px"
    );
}

/// Inside a stroke the ink has tones: many grey levels, and the stroke is not one flat fill.
#[test]
fn inside_a_stroke_the_ink_has_tones() {
    let (c, _) = render_on(&stroke(100.0, 80.0), PaperKind::Sized);
    let grey = c.to_gray8();
    let inked: Vec<u8> = grey.into_iter().filter(|&g| g < 230).collect();
    let mut levels = [false; 256];
    inked.iter().for_each(|&g| levels[g as usize] = true);
    let distinct = levels.iter().filter(|&&l| l).count();
    let black = inked.iter().filter(|&&g| g <= 5).count() as f64 / inked.len() as f64;
    let mean = inked.iter().map(|&g| g as f64).sum::<f64>() / inked.len() as f64;
    let sd = (inked
        .iter()
        .map(|&g| (g as f64 - mean).powi(2))
        .sum::<f64>()
        / inked.len() as f64)
        .sqrt();
    println!(
        "{} inked px: {distinct} grey levels, {:.1}% near black, grey {mean:.1} +- {sd:.1}",
        inked.len(),
        black * 100.0
    );
    assert!(distinct > 100, "{distinct} grey levels");
    assert!(
        black < 0.8,
        "{:.1}% of the stroke is flat black",
        black * 100.0
    );
    assert!(sd > 15.0, "the tone hardly varies: sd {sd}");
}

/// The same stroke on raw paper inks a larger area than on sized paper.
#[test]
fn raw_paper_spreads_the_same_stroke_wider() {
    let track = stroke(100.0, 60.0);
    let inked = |kind| {
        let (c, _) = render_on(&track, kind);
        let n = (0..c.height())
            .flat_map(|y| (0..c.width()).map(move |x| (x, y)))
            .filter(|&(x, y)| c.at(x, y) > 0.1)
            .count();
        (n, c.total_ink())
    };
    let ((sized, ink_s), (raw, ink_r)) = (inked(PaperKind::Sized), inked(PaperKind::Raw));
    println!("inked px (darkness > 0.1): sized {sized}, raw {raw}; ink {ink_s:.1} vs {ink_r:.1}");
    assert!(
        raw as f64 > 1.05 * sized as f64,
        "raw {raw} vs sized {sized}"
    );
    // The same ink went down on both: the raw paper only moved it.
    assert!((ink_r - ink_s).abs() < 1e-4 * ink_s, "{ink_r} vs {ink_s}");
}

/// Every paper step of a real stroke on raw paper conserves the ink on the paper.
#[test]
fn each_paper_step_of_a_stroke_conserves_ink() {
    let track = stroke(200.0, 60.0);
    let params = presets::by_name("large").unwrap();
    let frame = paper_frame(&track, &params, PX_PER_MM).unwrap();
    let mut c = Canvas::with_paper(frame.width, frame.height, PaperSpec::new(PaperKind::Raw));
    let mut inker = Inker::new(frame, params.layers as usize - 1);
    let mut steps = 0;
    let mut worst = 0.0f64;
    simulate::<Fx>(params, &track, |tick| {
        inker.stamp(tick.brush, &mut c);
        let before = c.total_ink();
        if c.tick().is_some() {
            steps += 1;
            let after = c.total_ink();
            worst = worst.max((after - before).abs() / before.max(1e-9));
        }
        Ok(())
    })
    .unwrap();
    let before = c.total_ink();
    steps += c.dry(100_000);
    let after = c.total_ink();
    worst = worst.max((after - before).abs() / before);
    println!("{steps} paper steps, largest relative change of the total ink {worst:.2e}");
    assert!(steps > 100 && !c.is_wet());
    assert!(worst < 1e-5, "{worst}");
}

#[test]
fn raw_renders_are_the_same_bits_run_to_run() {
    let track = stroke(300.0, 40.0);
    let (a, _) = render_on(&track, PaperKind::Raw);
    let (b, _) = render_on(&track, PaperKind::Raw);
    assert!(a.ink() == b.ink(), "two raw renders differ");
}

fn maobi(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_maobi"))
        .args(args)
        .output()
        .unwrap()
}

fn tmp(name: &str) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("maobi-paper-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

#[test]
fn an_unknown_paper_is_refused_on_the_command_line_and_in_stroke_files() {
    let heng = concat!(env!("CARGO_MANIFEST_DIR"), "/../examples/poses/heng.csv");
    let out = tmp("never.png");
    let o = maobi(&[
        "render",
        "--poses",
        heng,
        "--paper",
        "washi",
        "-o",
        out.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        err.contains("unknown paper `washi`") && err.contains("sized, raw"),
        "{err}"
    );
    assert!(!out.exists());

    let yong = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../examples/strokes/yong.toml"
    ))
    .unwrap();
    let bad = tmp("bad-paper.toml");
    let text = yong.replacen("version = 1\n", "version = 1\npaper = \"washi\"\n", 1);
    let line = text.lines().position(|l| l.starts_with("paper")).unwrap() + 1;
    std::fs::write(&bad, &text).unwrap();
    let o = maobi(&[
        "render",
        "--stroke",
        bad.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        err.contains("bad-paper.toml")
            && err.contains(&format!("line {line}"))
            && err.contains("`paper`")
            && err.contains("sized, raw"),
        "{err}"
    );
    assert!(!out.exists());

    // A known paper in the file is used, and `--paper` overrides it.
    let good = tmp("raw-paper.toml");
    std::fs::write(&good, text.replace("\"washi\"", "\"raw\"")).unwrap();
    let o = maobi(&[
        "render",
        "--stroke",
        good.to_str().unwrap(),
        "--px-per-mm",
        "2",
        "-o",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("on raw paper"));
    let o = maobi(&[
        "render",
        "--stroke",
        good.to_str().unwrap(),
        "--px-per-mm",
        "2",
        "--paper",
        "sized",
        "-o",
        out.to_str().unwrap(),
    ]);
    assert!(String::from_utf8_lossy(&o.stderr).contains("on sized paper"));
}

/// Ink on the paper plus ink in the brush is the ink dipped, to rounding: the brush model
/// gives each layer's ink to the paper (`maobi_shared::brush::ink`), and the inker spreads
/// it over the pixels it stamps with weights that sum to one, on both papers and in both
/// the pen's format and f64.
#[test]
fn ink_on_paper_plus_ink_in_brush_is_the_ink_dipped() {
    fn check<S: maobi_shared::BrushScalar>(kind: PaperKind) {
        let track = stroke(200.0, 80.0);
        let params = presets::by_name("large").unwrap();
        let frame = paper_frame(&track, &params, PX_PER_MM).unwrap();
        let start = maobi_shared::Brush::<S>::new(params, track.pose_at_tick(0).cast()).unwrap();
        let dipped = start.ink_load().to_f64();
        let mut c = Canvas::with_paper(frame.width, frame.height, PaperSpec::new(kind));
        let mut inker = Inker::new(frame, params.layers as usize - 1);
        let mut in_brush = dipped;
        simulate::<S>(params, &track, |tick| {
            inker.stamp(tick.brush, &mut c);
            c.tick();
            in_brush = tick.brush.ink_load().to_f64();
            Ok(())
        })
        .unwrap();
        c.dry(100_000);
        let on_paper = c.total_ink() / (PX_PER_MM * PX_PER_MM);
        let err = (on_paper + in_brush - dipped).abs() / dipped;
        println!(
            "{} on {}: dipped {dipped:.3}, on the paper {on_paper:.3}, in the brush {in_brush:.3}, \
             relative error {err:.1e}",
            S::NAME,
            kind.name()
        );
        assert!(on_paper > 0.1 * dipped, "the stroke gave ink: {on_paper}");
        assert!(err < 1e-5, "{err}");
    }
    check::<Fx>(PaperKind::Sized);
    check::<Fx>(PaperKind::Raw);
    check::<f64>(PaperKind::Sized);
}

/// Mean darkness of the columns of `c` from x = `from_mm` to `to_mm` on the paper, over the
/// rows within 6 mm of y = 0.
fn mean_darkness(c: &Canvas, frame: &Frame, from_mm: f64, to_mm: f64) -> f64 {
    let (x0, x1) = (
        frame.to_px(from_mm, 0.0)[0] as usize,
        frame.to_px(to_mm, 0.0)[0] as usize,
    );
    let (y0, y1) = (
        frame.to_px(0.0, 6.0)[1] as usize,
        frame.to_px(0.0, -6.0)[1] as usize,
    );
    let mut sum = 0.0;
    for y in y0..y1 {
        for x in x0..x1 {
            sum += c.at(x, y) as f64;
        }
    }
    sum / ((x1 - x0) * (y1 - y0)) as f64
}

/// A 250 mm stroke written without dipping fades along its length: the brush runs dry.
#[test]
fn a_long_stroke_without_dipping_fades() {
    let track = stroke(100.0, 250.0);
    let (c, frame) = render_on(&track, PaperKind::Sized);
    // The first and last quarters of the way the ferrule went; the brush trails behind it.
    let first = mean_darkness(&c, &frame, 0.0, 62.5);
    let last = mean_darkness(&c, &frame, 187.5, 250.0);
    println!("250 mm at 100 mm/s: mean darkness first quarter {first:.4}, last {last:.4}");
    assert!(first > 0.05, "{first}");
    assert!(last < 0.75 * first, "{first} -> {last}");
}

/// The same long stroke without dipping, written with each hair type: goat hair, which holds
/// the most ink, goes furthest before the stroke fades to half its first darkness, wolf hair
/// the least far. The fade is read off the paper in 25 mm windows of the way the ferrule went.
#[test]
fn goat_hair_fades_later_than_mixed_and_mixed_later_than_wolf() {
    const LENGTH_MM: f64 = 400.0;
    const WINDOW_MM: f64 = 25.0;
    let track = stroke(100.0, LENGTH_MM);
    let fades: Vec<(f64, Vec<f64>)> = [presets::WOLF, presets::MIXED, presets::GOAT]
        .into_iter()
        .map(|params| {
            let (c, frame) = render_with(params, &track, PaperKind::Sized);
            let windows: Vec<f64> = (0..(LENGTH_MM / WINDOW_MM) as usize)
                .map(|k| {
                    let from = k as f64 * WINDOW_MM;
                    mean_darkness(&c, &frame, from, from + WINDOW_MM)
                })
                .collect();
            let half = windows.iter().position(|&d| d < 0.5 * windows[0]);
            (half.map_or(LENGTH_MM, |k| k as f64 * WINDOW_MM), windows)
        })
        .collect();
    for ((fade, windows), name) in fades.iter().zip(["wolf", "mixed", "goat"]) {
        let tones: Vec<String> = windows.iter().map(|d| format!("{d:.3}")).collect();
        println!(
            "{name}: darker than half its start for {fade:.0} mm; darkness per {WINDOW_MM} mm: {}",
            tones.join(" ")
        );
    }
    let [wolf, mixed, goat] = [fades[0].0, fades[1].0, fades[2].0];
    assert!(
        wolf < mixed && mixed < goat,
        "fades at wolf {wolf} mm, mixed {mixed} mm, goat {goat} mm"
    );
}

/// Of the columns of the stroke's middle (x from `from_mm` to `to_mm`), the share whose
/// profile across the stroke has a gap: a pixel lighter than a quarter of the column's
/// darkest between two pixels darker than half of it (the stroke split into streaks).
fn columns_with_gaps(c: &Canvas, frame: &Frame, from_mm: f64, to_mm: f64) -> f64 {
    let (x0, x1) = (
        frame.to_px(from_mm, 0.0)[0] as usize,
        frame.to_px(to_mm, 0.0)[0] as usize,
    );
    let gaps = (x0..x1)
        .filter(|&x| {
            let col: Vec<f32> = (0..c.height()).map(|y| c.at(x, y)).collect();
            let top = col.iter().fold(0.0f32, |a, &d| a.max(d));
            let dark: Vec<usize> = (0..col.len()).filter(|&y| col[y] > 0.5 * top).collect();
            match (dark.first(), dark.last()) {
                (Some(&a), Some(&b)) => (a..=b).any(|y| col[y] < 0.25 * top),
                _ => false,
            }
        })
        .count();
    gaps as f64 / (x1 - x0) as f64
}

/// A 600 mm/s flick splits into dry-brush streaks (飛白): gaps across the stroke; a 40 mm/s
/// stroke from the same dip is full.
#[test]
fn a_flick_shows_dry_brush_gaps_that_a_slow_stroke_does_not() {
    let gaps = |speed: f64| {
        let track = stroke(speed, 60.0);
        let (c, frame) = render_on(&track, PaperKind::Sized);
        columns_with_gaps(&c, &frame, 15.0, 45.0)
    };
    let (flick, slow) = (gaps(600.0), gaps(40.0));
    // The same flick with the brush at five substeps a tick: the streaks are the ink's, not
    // an artefact of the brush's step (a drag split from the step once made them).
    let finer = {
        let mut params = presets::by_name("large").unwrap();
        params.substeps_per_tick = 5;
        let (c, frame) = render_with(params, &stroke(600.0, 60.0), PaperKind::Sized);
        columns_with_gaps(&c, &frame, 15.0, 45.0)
    };
    println!(
        "columns with gaps across the stroke: 600 mm/s {:.1}% (at 5 substeps {:.1}%), \
         40 mm/s {:.1}%",
        flick * 100.0,
        finer * 100.0,
        slow * 100.0
    );
    assert!(flick > 0.5, "the flick has few gaps: {flick}");
    assert!(finer > 0.5, "the flick at 5 substeps has few gaps: {finer}");
    assert!(slow < 0.05, "the slow stroke has gaps: {slow}");
}

/// The same flick (hair strips, dry-brush gaps) renders to the same bytes run to run.
#[test]
fn dry_brush_renders_are_the_same_bytes_run_to_run() {
    let track = stroke(600.0, 60.0);
    let png = || {
        let (c, _) = render_on(&track, PaperKind::Sized);
        let mut bytes = Vec::new();
        maobi::render::encode_png(&c, &mut bytes).unwrap();
        bytes
    };
    assert!(png() == png(), "two renders of the flick differ");
}

/// States that come every few ticks (a device's link at 120 Hz) lose no ink: the inker lays
/// the increase of each layer's running total since the last state it saw.
#[test]
fn states_every_eighth_tick_lay_the_same_ink() {
    let track = stroke(200.0, 60.0);
    let params = presets::by_name("large").unwrap();
    let frame = paper_frame(&track, &params, PX_PER_MM).unwrap();
    let ink = |every: usize| {
        let mut c = Canvas::new(frame.width, frame.height);
        let mut inker = Inker::new(frame, params.layers as usize - 1);
        let ticks = simulate::<Fx>(params, &track, |_| Ok(())).unwrap();
        simulate::<Fx>(params, &track, |tick| {
            if tick.k % every == 0 || tick.k + 1 == ticks {
                let g = maobi_shared::footprint::Geometry::of(tick.brush);
                inker.stamp_geometry_at(&g, tick.k as u64, &mut c);
            }
            Ok(())
        })
        .unwrap();
        c.total_ink()
    };
    let (all, eighth) = (ink(1), ink(8));
    println!("ink with a state every tick {all:.3}, every eighth tick {eighth:.3}");
    assert!(all > 1000.0);
    assert!((all - eighth).abs() < 1e-5 * all, "{all} vs {eighth}");
}
