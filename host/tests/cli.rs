//! End-to-end tests of the `maobi` binary: bad input is refused with a message that says
//! where and why, and the example strokes trace and render.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::atomic::{AtomicUsize, Ordering};

const HEADER: &str = "t,x,y,z,qw,qx,qy,qz\n";

fn maobi(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_maobi"))
        .args(args)
        .output()
        .expect("run maobi")
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn example(name: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../examples/poses")
        .join(name)
        .to_str()
        .unwrap()
        .to_string()
}

/// A file in the temp directory, unique to this process and call, removed on drop.
struct Temp(PathBuf);

impl Temp {
    fn new(name: &str) -> Temp {
        static N: AtomicUsize = AtomicUsize::new(0);
        let n = N.fetch_add(1, Ordering::Relaxed);
        Temp(std::env::temp_dir().join(format!("maobi-cli-{}-{n}-{name}", std::process::id())))
    }
    fn with(name: &str, contents: &[u8]) -> Temp {
        let t = Temp::new(name);
        std::fs::write(&t.0, contents).unwrap();
        t
    }
    fn path(&self) -> &str {
        self.0.to_str().unwrap()
    }
}

impl Drop for Temp {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

/// Runs `trace` (and `render`) on a bad pose file; both must fail saying `wants`.
fn assert_rejected(contents: &[u8], wants: &[&str]) {
    let input = Temp::with("bad.csv", contents);
    let out = Temp::new("out");
    for cmd in ["trace", "render"] {
        let o = maobi(&[cmd, "--poses", input.path(), "-o", out.path()]);
        let err = stderr(&o);
        assert!(!o.status.success(), "{cmd} accepted {contents:?}");
        assert_eq!(o.status.code(), Some(1), "{cmd}: {err}");
        assert!(err.contains(input.path()), "{cmd}: no file name in {err:?}");
        for w in wants {
            assert!(err.contains(w), "{cmd}: {w:?} not in {err:?}");
        }
        assert!(!out.0.exists(), "{cmd} wrote output for bad input");
    }
}

#[test]
fn rejects_empty_file() {
    assert_rejected(b"", &["empty", "t,x,y,z,qw,qx,qy,qz"]);
}

#[test]
fn rejects_header_without_rows() {
    assert_rejected(HEADER.as_bytes(), &["no data rows"]);
}

#[test]
fn rejects_wrong_or_missing_header_columns() {
    assert_rejected(
        b"t,x,y,z,qw,qx,qy\n0,0,0,40,1,0,0\n",
        &[":1:", "missing column(s) qz"],
    );
    assert_rejected(
        b"time,x,y,z,qw,qx,qy,qz\n0,0,0,40,1,0,0,0\n",
        &[":1:", "missing column(s) t", "unexpected column(s) time"],
    );
}

#[test]
fn rejects_malformed_rows() {
    let csv = format!("{HEADER}0,0,0,40,1,0,0,0\n0.01,0,0,40,1,0\n");
    assert_rejected(csv.as_bytes(), &[":3:", "expected 8 fields, found 6"]);
    let mut bytes = HEADER.as_bytes().to_vec();
    bytes.extend_from_slice(b"0,0,0,\xfe,1,0,0,0\n");
    assert_rejected(&bytes, &[":2:", "UTF-8"]);
}

#[test]
fn rejects_non_numbers_with_line_and_column() {
    let csv = format!("{HEADER}0,0,0,40,1,0,0,0\n0.01,0,0,40,1,0,zero,0\n");
    assert_rejected(
        csv.as_bytes(),
        &[":3:", "column `qy`", "`zero` is not a number"],
    );
}

#[test]
fn rejects_non_finite_numbers() {
    let csv = format!("{HEADER}0,0,0,40,1,0,0,0\n0.01,NaN,0,40,1,0,0,0\n");
    assert_rejected(
        csv.as_bytes(),
        &[":3:", "column `x`", "not a finite number"],
    );
    let csv = format!("{HEADER}0,0,0,inf,1,0,0,0\n");
    assert_rejected(
        csv.as_bytes(),
        &[":2:", "column `z`", "not a finite number"],
    );
}

#[test]
fn rejects_time_going_backwards() {
    let csv = format!("{HEADER}0,0,0,40,1,0,0,0\n0.02,0,0,40,1,0,0,0\n0.01,0,0,40,1,0,0,0\n");
    assert_rejected(
        csv.as_bytes(),
        &[":4:", "column `t`", "before the previous row"],
    );
}

#[test]
fn rejects_non_unit_quaternions() {
    let csv = format!("{HEADER}0,0,0,40,1,0,0,0\n0.01,0,0,40,0.9,0,0,0\n");
    assert_rejected(csv.as_bytes(), &[":3:", "quaternion norm 0.9"]);
}

#[test]
fn rejects_missing_input_file() {
    let out = Temp::new("out.csv");
    let o = maobi(&["trace", "--poses", "/nonexistent/p.csv", "-o", out.path()]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("/nonexistent/p.csv"), "{}", stderr(&o));
}

#[test]
fn rejects_unknown_brush_listing_valid_ones() {
    let out = Temp::new("out.csv");
    let p = example("press_lift.csv");
    for cmd in ["trace", "render"] {
        let o = maobi(&[cmd, "--poses", &p, "--brush", "nonsense", "-o", out.path()]);
        let err = stderr(&o);
        assert!(!o.status.success());
        assert!(err.contains("unknown brush `nonsense`"), "{cmd}: {err:?}");
        for (name, _) in maobi_shared::presets::PRESETS {
            assert!(err.contains(name), "{cmd}: {name:?} not in {err:?}");
        }
    }
}

/// Every command that chooses a brush lists the presets in its `--help`.
#[test]
fn help_lists_every_brush_preset() {
    for cmd in ["trace", "render", "sim-device", "bridge", "gui"] {
        let o = maobi(&[cmd, "--help"]);
        let help = String::from_utf8_lossy(&o.stdout);
        assert!(o.status.success(), "{cmd}");
        assert!(
            help.contains(maobi_shared::presets::NAMES),
            "{cmd}: the presets are not listed in {help}"
        );
    }
}

/// The hair types answer to their name, pinyin and Chinese name alike (the same trace), and
/// each traces a brush of its own (not the large brush's trace).
#[test]
fn hair_types_are_chosen_by_any_of_their_names() {
    let p = example("press_lift.csv");
    let trace = |brush: &str| {
        let out = Temp::new("hair.csv");
        let o = maobi(&["trace", "--poses", &p, "--brush", brush, "-o", out.path()]);
        assert!(o.status.success(), "{brush}: {}", stderr(&o));
        std::fs::read(out.path()).unwrap()
    };
    let large = trace("large");
    for names in [
        ["wolf", "langhao", "狼毫"],
        ["goat", "yanghao", "羊毫"],
        ["mixed", "jianhao", "兼毫"],
    ] {
        let own = trace(names[0]);
        assert!(own != large, "{}: the large brush's trace", names[0]);
        for alias in &names[1..] {
            assert!(
                trace(alias) == own,
                "{alias} traces another brush than {}",
                names[0]
            );
        }
    }
}

#[test]
fn rejects_bad_options() {
    let out = Temp::new("out.png");
    let p = example("press_lift.csv");
    let o = maobi(&["trace", "--poses", &p, "--scalar", "f16", "-o", out.path()]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("f16"), "{}", stderr(&o));
    for bad in ["0", "-3", "nan", "ten"] {
        let o = maobi(&[
            "render",
            "--poses",
            &p,
            "--px-per-mm",
            bad,
            "-o",
            out.path(),
        ]);
        assert!(!o.status.success(), "--px-per-mm {bad}");
        assert!(stderr(&o).contains("positive number"), "{}", stderr(&o));
    }
}

fn trace(poses: &str, scalar: &str) -> Vec<Vec<String>> {
    let out = Temp::new(&format!("trace-{scalar}.csv"));
    let o = maobi(&[
        "trace",
        "--poses",
        poses,
        "--scalar",
        scalar,
        "-o",
        out.path(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("ticks"), "{}", stderr(&o));
    let text = std::fs::read_to_string(&out.0).unwrap();
    text.lines()
        .map(|l| l.split(',').map(str::to_string).collect())
        .collect()
}

#[test]
fn trace_of_press_lift_has_one_row_per_millisecond() {
    let rows = trace(&example("press_lift.csv"), "fixed");
    let mut want = String::from("t,x,y,z,qw,qx,qy,qz");
    for i in 0..maobi_shared::presets::LARGE.layers {
        want += &format!(",s{i}_x,s{i}_y,s{i}_z");
    }
    want += ",contacts,fx,fy,fz,depth";
    assert_eq!(rows[0].join(","), want);
    let col = |name: &str| rows[0].iter().position(|c| c == name).unwrap();
    let (contacts, fz, depth) = (col("contacts"), col("fz"), col("depth"));
    // 0 .. 1.000 s inclusive.
    assert_eq!(rows.len() - 1, 1001);
    for (k, r) in rows[1..].iter().enumerate() {
        assert_eq!(r.len(), rows[0].len(), "row {k}");
        assert_eq!(r[0], format!("{:.3}", k as f64 / 1000.0));
    }
    // Tick 0 is the rest state at the first pose: the ferrule is the handle position and
    // the brush, 5 mm above the paper, touches nothing.
    let first = &rows[1];
    assert_eq!(&first[1..4], ["0.000000", "0.000000", "45.000000"]);
    assert_eq!(&first[8..11], &first[1..4]);
    assert_eq!(first[contacts], "0");
    // In the air only the brush's weight (15 g) pulls down, and nothing is below the paper.
    assert_eq!(first[fz], "-0.147100");
    assert_eq!(first[depth], "0.000000");
    // Pressed 10 mm at 0.5 s, the brush lies on the paper and pushes back up.
    let mid = &rows[501];
    assert_eq!(mid[0], "0.500");
    assert_eq!(mid[3], "30.000000");
    assert!(mid[contacts].parse::<u32>().unwrap() > 0);
    assert!(mid[fz].parse::<f64>().unwrap() > 0.3, "fz = {}", mid[fz]);
    assert!(
        mid[depth].parse::<f64>().unwrap() > 5.0,
        "depth = {}",
        mid[depth]
    );
}

#[test]
fn trace_runs_in_f32_and_f64_close_to_fixed() {
    let p = example("press_lift.csv");
    let fixed = trace(&p, "fixed");
    for scalar in ["f32", "f64"] {
        let rows = trace(&p, scalar);
        assert_eq!(rows[0], fixed[0]);
        assert_eq!(rows.len(), fixed.len());
        // The same model in another number type: the spine agrees to well under 0.1 mm.
        let mut worst = 0.0f64;
        for (a, b) in rows[1..].iter().zip(&fixed[1..]) {
            assert_eq!(a[..8], b[..8], "{scalar}: the handle pose is the input's");
            for (x, y) in a[8..a.len() - 1].iter().zip(&b[8..b.len() - 1]) {
                let d = (x.parse::<f64>().unwrap() - y.parse::<f64>().unwrap()).abs();
                worst = worst.max(d);
            }
        }
        assert!(worst < 0.1, "{scalar} differs from fixed by {worst} mm");
    }
}

/// Renders `poses` and returns the PNG bytes.
fn render(poses: &str, extra: &[&str]) -> Vec<u8> {
    let out = Temp::new("render.png");
    let mut args = vec!["render", "--poses", poses, "-o", out.path()];
    args.extend_from_slice(extra);
    let o = maobi(&args);
    let err = stderr(&o);
    assert!(o.status.success(), "{err}");
    assert!(err.contains(out.path()) && err.contains("ink"), "{err}");
    std::fs::read(&out.0).unwrap()
}

/// Decodes an 8-bit greyscale PNG: (width, height, pixels).
fn decode(png_bytes: &[u8]) -> (u32, u32, Vec<u8>) {
    let mut r = png::Decoder::new(std::io::Cursor::new(png_bytes))
        .read_info()
        .unwrap();
    let mut buf = vec![0; r.output_buffer_size().unwrap()];
    let info = r.next_frame(&mut buf).unwrap();
    assert_eq!(info.color_type, png::ColorType::Grayscale);
    assert_eq!(info.bit_depth, png::BitDepth::Eight);
    buf.truncate(info.buffer_size());
    (info.width, info.height, buf)
}

#[test]
fn render_is_deterministic_and_inks_the_paper() {
    let p = example("press_lift.csv");
    let a = render(&p, &[]);
    let b = render(&p, &[]);
    assert!(a == b, "two renders of the same input differ");
    let (w, h, px) = decode(&a);
    // The ferrule stays at (0, 0): the paper is the brush length + 10 mm on each side.
    assert_eq!((w, h), (1000, 1000));
    let dark = px.iter().filter(|&&v| v < 128).count();
    // A 10 mm press of the large brush leaves a blob of tens of square millimetres.
    assert!(dark > 2_000, "only {dark} dark pixels");
    assert!(
        px[0] == 255 && px[px.len() - 1] == 255,
        "the margin has ink"
    );
}

#[test]
fn render_of_the_fast_hook_is_continuous() {
    let p = example("hook.csv");
    let (w, h, px) = decode(&render(&p, &[]));
    assert!(px.iter().any(|&v| v < 128));
    // The ink is one connected blot: the flick at 500 mm/s leaves no gaps between ticks.
    let dark: Vec<bool> = px.iter().map(|&v| v < 250).collect();
    let start = dark.iter().position(|&d| d).unwrap();
    let mut seen = vec![false; dark.len()];
    let mut stack = vec![start];
    seen[start] = true;
    while let Some(i) = stack.pop() {
        let (x, y) = ((i % w as usize) as i64, (i / w as usize) as i64);
        for (dx, dy) in [
            (-1, 0),
            (1, 0),
            (0, -1),
            (0, 1),
            (-1, -1),
            (1, 1),
            (-1, 1),
            (1, -1),
        ] {
            let (nx, ny) = (x + dx, y + dy);
            if nx >= 0 && ny >= 0 && nx < w as i64 && ny < h as i64 {
                let j = (ny * w as i64 + nx) as usize;
                if dark[j] && !seen[j] {
                    seen[j] = true;
                    stack.push(j);
                }
            }
        }
    }
    let total = dark.iter().filter(|&&d| d).count();
    let reached = seen.iter().filter(|&&s| s).count();
    // A gap between ticks would cut the stroke across (at 500 mm/s a tick is 5 px): whole
    // pieces apart. The hair strips' streaks at the flick's dry end (飛白) may stand apart
    // from the blot, thin and short: it holds all but a hundredth.
    assert!(
        reached * 100 >= total * 99,
        "the ink falls apart into pieces: {reached} of {total} dark pixels in one blot"
    );
}

#[test]
fn render_runs_every_scalar() {
    let p = example("heng.csv");
    for scalar in ["f32", "f64"] {
        let (_, _, px) = decode(&render(&p, &["--scalar", scalar]));
        assert!(px.iter().any(|&v| v < 128), "{scalar}: no ink");
    }
}

#[test]
fn render_with_the_small_brush() {
    // The small brush's head is 18 mm: press it 4 mm, leaning 10 degrees, and drag it 10 mm.
    let (c, s) = ((5.0f64).to_radians().cos(), (5.0f64).to_radians().sin());
    let csv =
        format!("{HEADER}0,0,0,20,{c},0,{s},0\n0.2,0,0,14,{c},0,{s},0\n0.4,10,0,14,{c},0,{s},0\n");
    let input = Temp::with("small.csv", csv.as_bytes());
    let (w, h, px) = decode(&render(input.path(), &["--brush", "small"]));
    // 10 mm of motion plus (18 + 10) mm on each side at 10 px/mm.
    assert_eq!((w, h), (660, 560));
    assert!(
        px.iter().filter(|&&v| v < 128).count() > 500,
        "too little ink"
    );
}

/// `--model baxter-lin` renders Baxter & Lin's brush (the large preset's round head, and
/// the paper's flat): deterministic, and a press leaves ink.
#[test]
fn render_with_baxter_and_lins_brush() {
    let p = example("press_lift.csv");
    let a = render(&p, &["--model", "baxter-lin"]);
    assert!(
        a == render(&p, &["--model", "baxter-lin"]),
        "not deterministic"
    );
    let (_, _, px) = decode(&a);
    let dark = px.iter().filter(|&&v| v < 128).count();
    assert!(dark > 500, "Baxter & Lin's press left {dark} dark pixels");
    // The flat's head is 18 mm: press it 4 mm straight down.
    let csv = format!("{HEADER}0,0,0,20,1,0,0,0\n0.2,0,0,14,1,0,0,0\n0.4,0,0,14,1,0,0,0\n");
    let input = Temp::with("flat.csv", csv.as_bytes());
    let (_, _, px) = decode(&render(
        input.path(),
        &["--model", "baxter-lin", "--brush", "flat"],
    ));
    let dark = px.iter().filter(|&&v| v < 128).count();
    assert!(dark > 500, "the flat's press left {dark} dark pixels");
}

/// A trace of `--model baxter-lin`: the header, and each row's numbers by column name.
struct BlTrace {
    names: Vec<String>,
    rows: Vec<Vec<f64>>,
}

impl BlTrace {
    fn of(poses: &str) -> BlTrace {
        let out = Temp::new("bl.csv");
        let o = maobi(&[
            "trace",
            "--poses",
            poses,
            "--model",
            "baxter-lin",
            "-o",
            out.path(),
        ]);
        assert!(o.status.success(), "{}", stderr(&o));
        let text = std::fs::read_to_string(&out.0).unwrap();
        let mut lines = text.lines();
        let names: Vec<String> = lines.next().unwrap().split(',').map(String::from).collect();
        let rows = lines
            .map(|l| l.split(',').map(|v| v.parse::<f64>().unwrap()).collect())
            .collect();
        BlTrace { names, rows }
    }
    fn col(&self, name: &str) -> usize {
        self.names
            .iter()
            .position(|n| n == name)
            .unwrap_or_else(|| panic!("no column {name}"))
    }
    /// (spines, joints a spine) from the `p{k}_{i}_x` columns.
    fn shape(&self) -> (usize, usize) {
        let spines = (0..)
            .take_while(|k| self.names.contains(&format!("p{k}_0_x")))
            .count();
        let joints = (0..)
            .take_while(|i| self.names.contains(&format!("p0_{i}_x")))
            .count();
        (spines, joints - 1)
    }
    fn point(&self, row: usize, k: usize, i: usize) -> [f64; 3] {
        let c = self.col(&format!("p{k}_{i}_x"));
        [
            self.rows[row][c],
            self.rows[row][c + 1],
            self.rows[row][c + 2],
        ]
    }
}

/// The must-show of Baxter & Lin's model, on its traces of the example strokes: no joint
/// below the paper; at rest in free air the centre spine hangs along the handle's axis; a
/// steady drag (橫) leaves the tip trailing the handle; and the paper's friction on each
/// spine opposes the slide of its joints on the paper, every tick.
#[test]
fn baxter_lin_traces_keep_the_physical_invariants() {
    for name in ["heng.csv", "hook.csv", "shu.csv", "press_lift.csv"] {
        let tr = BlTrace::of(&example(name));
        let (spines, joints) = tr.shape();
        assert_eq!((spines, joints), (7, 3), "{name}");
        let lowest = tr
            .names
            .iter()
            .enumerate()
            .filter(|(_, n)| n.starts_with('p') && n.ends_with("_z"))
            .flat_map(|(c, _)| tr.rows.iter().map(move |r| r[c]))
            .fold(f64::MAX, f64::min);
        assert!(lowest >= 0.0, "{name}: a joint at z = {lowest}");

        // At rest (tick 0, in free air) the centre spine's chord lies along the handle's -z.
        let (root, tip) = (tr.point(0, 0, 0), tr.point(0, 0, joints));
        let q: Vec<f64> = ["qw", "qx", "qy", "qz"]
            .iter()
            .map(|n| tr.rows[0][tr.col(n)])
            .collect();
        let (w, x, y, z) = (q[0], q[1], q[2], q[3]);
        let axis = [
            -2.0 * (x * z + w * y),
            -2.0 * (y * z - w * x),
            -(1.0 - 2.0 * (x * x + y * y)),
        ];
        let chord = [tip[0] - root[0], tip[1] - root[1], tip[2] - root[2]];
        let len = chord.iter().map(|c| c * c).sum::<f64>().sqrt();
        let cos = chord.iter().zip(axis).map(|(c, a)| c * a).sum::<f64>() / len;
        assert!(
            cos > (0.01f64).to_radians().cos(),
            "{name}: hangs {} deg off",
            cos.acos().to_degrees()
        );

        // Friction opposes each spine's slide on the paper. A contact that sticks creeps up
        // to the slip distance from where it stuck, and back as its load eases (the friction
        // cone's rounding, `FRICTION_SMOOTHING_MM`), its friction pulling it home: a joint's
        // move between two ticks is a slide when it is longer than that. A move of over a
        // millimetre in a tick (1 m/s) is no slide the hand drives but a pressed spine
        // snapping through from one bend to another; the friction written is that of the
        // tick's last solve, whose own move can point anywhere along the snap.
        let slip = maobi_shared::baxter_lin::SpineParams::DEFAULT.slip_mm;
        let (mut slides, mut resisted, mut creeps, mut snaps) = (0, 0, 0, 0);
        for r in 1..tr.rows.len() {
            for k in 0..spines {
                let mut slide = [0.0; 2];
                let mut snapped = false;
                for i in 1..=joints {
                    let (a, b) = (tr.point(r - 1, k, i), tr.point(r, k, i));
                    if a[2] == 0.0 && b[2] == 0.0 {
                        let m = [b[0] - a[0], b[1] - a[1]];
                        let len = m[0].hypot(m[1]);
                        if len > 1.0 {
                            snapped = true;
                        } else if len > slip {
                            slide[0] += m[0];
                            slide[1] += m[1];
                        } else if len > 1e-4 {
                            creeps += 1;
                        }
                    }
                }
                if snapped {
                    snaps += 1;
                    continue;
                }
                let s = slide[0].hypot(slide[1]);
                if s > 1e-4 {
                    slides += 1;
                    let c = tr.col(&format!("fr{k}_x"));
                    let along = (tr.rows[r][c] * slide[0] + tr.rows[r][c + 1] * slide[1]) / s;
                    assert!(
                        along <= 1e-6,
                        "{name}: row {r}, spine {k}: friction {along} N along the slide"
                    );
                    resisted += usize::from(along < -1e-4);
                }
            }
        }
        println!(
            "{name}: {slides} slides, {resisted} of them resisted by more than 0.1 mN; \
             {creeps} moves of a held joint within the slip distance; {snaps} snaps"
        );
        // press_lift presses straight down and lifts: its tips hold where they land.
        if name != "press_lift.csv" {
            assert!(slides > 1000, "{name}: only {slides} slides");
        }
        assert!(
            slides == 0 || 2 * resisted > slides,
            "{name}: {resisted} of {slides} slides resisted"
        );

        // 橫 drags the pressed brush along +x: the centre spine's tip trails the handle.
        if name == "heng.csv" {
            let (xc, cc) = (tr.col("x"), tr.col("contacts"));
            // The handle's 15 degree lean alone puts the tip 10 mm behind at rest: the drag
            // must add to that.
            let at_rest = tr.rows[0][xc] - tr.point(0, 0, joints)[0];
            let mut dragged = 0;
            for r in 1..tr.rows.len() {
                let v = (tr.rows[r][xc] - tr.rows[r - 1][xc]) / 0.001;
                if v > 10.0 && tr.rows[r][cc] > 0.0 {
                    dragged += 1;
                    let behind = tr.rows[r][xc] - tr.point(r, 0, joints)[0];
                    assert!(
                        behind > at_rest + 2.0,
                        "row {r}: the tip {behind} mm behind, {at_rest} at rest"
                    );
                }
            }
            assert!(dragged > 500, "only {dragged} rows dragged");
        }
    }
}

/// An unknown model is refused with the names; a Baxter & Lin head is refused with Liang's
/// model and on the commands that run Liang's brush, naming the model that draws it; a
/// `--param` Baxter & Lin's brush does not read is refused, naming those it does.
#[test]
fn rejects_unknown_models_and_heads_of_the_other_model() {
    let out = Temp::new("out.png");
    let p = example("press_lift.csv");
    // `maobi CMD --poses P ARGS.. -o OUT`.
    let on = |cmd: &str, args: &[&str]| {
        let mut all = vec![cmd, "--poses", &p];
        all.extend_from_slice(args);
        all.extend_from_slice(&["-o", out.path()]);
        maobi(&all)
    };
    let o = on("render", &["--model", "nonsense"]);
    let err = stderr(&o);
    assert!(!o.status.success());
    assert!(
        err.contains("nonsense") && err.contains("liang") && err.contains("baxter-lin"),
        "{err}"
    );
    let o = on("render", &["--brush", "flat"]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("--model baxter-lin"), "{}", stderr(&o));
    let o = on("trace", &["--brush", "fan"]);
    assert!(!o.status.success());
    let err = stderr(&o);
    assert!(
        err.contains("Baxter & Lin") && err.contains("--model baxter-lin"),
        "{err}"
    );
    let o = on("trace", &["--model", "baxter-lin", "--brush", "fan"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = on("render", &["--model", "baxter-lin", "--param", "mass_g=2"]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("mass_g") && stderr(&o).contains("length_mm"),
        "{}",
        stderr(&o)
    );
    // The hair's stiffness is one it reads (its joints' springs).
    let o = on(
        "render",
        &[
            "--model",
            "baxter-lin",
            "--brush",
            "goat",
            "--param",
            "tie_stiffness_n_per_m=2",
        ],
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let o = on("render", &["--brush", "nonsense"]);
    let err = stderr(&o);
    for name in ["flat", "filbert", "fan"] {
        assert!(err.contains(name), "{name} not in {err}");
    }
    // Baxter & Lin's model runs in f64: another number type is refused, not ignored.
    let o = on("render", &["--model", "baxter-lin", "--scalar", "fixed"]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("f64 only"), "{}", stderr(&o));
    // The app: a Baxter & Lin head needs their model, on the simulator as on the Phantom.
    // Refused before any window opens (no display is needed to see it).
    for args in [
        &["gui", "--brush", "flat"][..],
        &["gui", "--device", "phantom", "--brush", "fan"][..],
    ] {
        let o = maobi(args);
        assert!(!o.status.success());
        assert!(
            stderr(&o).contains("baxter-lin"),
            "{args:?}: {}",
            stderr(&o)
        );
    }
    let o = maobi(&["gui", "--model", "spline"]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("baxter-lin"), "{}", stderr(&o));
}

/// Runs `maobi trace` on `poses` with `extra` options; the trace's text, or the failed run.
fn trace_with(poses: &str, extra: &[&str]) -> Result<String, Output> {
    let out = Temp::new("trace-param.csv");
    let mut args = vec!["trace", "--poses", poses, "-o", out.path()];
    args.extend_from_slice(extra);
    let o = maobi(&args);
    if !o.status.success() {
        assert!(!out.0.exists(), "a failed trace wrote {}", out.path());
        return Err(o);
    }
    Ok(std::fs::read_to_string(&out.0).unwrap())
}

/// A short press (50 ms) of the large brush: enough ticks for the model's settings to show.
fn short_press() -> Temp {
    let csv = format!("{HEADER}0,0,0,45,1,0,0,0\n0.05,0,0,36,1,0,0,0\n");
    Temp::with("short-press.csv", csv.as_bytes())
}

#[test]
fn param_changes_the_trace_and_is_named_in_the_summary() {
    let input = short_press();
    let default = trace_with(input.path(), &[]).unwrap();
    let out = Temp::new("two-substeps.csv");
    let o = maobi(&[
        "trace",
        "--poses",
        input.path(),
        "--param",
        "substeps_per_tick=2",
        "-o",
        out.path(),
    ]);
    let err = stderr(&o);
    assert!(o.status.success(), "{err}");
    assert!(
        err.contains("the large (substeps_per_tick=2) brush"),
        "{err}"
    );
    let two = std::fs::read_to_string(&out.0).unwrap();
    assert_eq!(two.lines().count(), default.lines().count());
    assert_eq!(two.lines().next(), default.lines().next(), "the header");
    assert_ne!(two, default, "2 substeps per tick traced as the default 25");
    // Another brush shape changes the header: one spine mass fewer, three columns fewer.
    let fewer = format!("layers={}", maobi_shared::presets::LARGE.layers - 1);
    let layers = trace_with(input.path(), &["--param", &fewer]).unwrap();
    let columns = |t: &str| t.lines().next().unwrap().split(',').count();
    assert_eq!(columns(&layers) + 3, columns(&default));
}

#[test]
fn every_parameter_is_accepted_by_its_name() {
    // Each parameter set to the preset's own value: accepted, and the trace is unchanged.
    let input = short_press();
    let default = trace_with(input.path(), &[]).unwrap();
    for id in maobi_shared::ParamId::ALL {
        let value = maobi_shared::presets::LARGE.get(id);
        let arg = format!("{}={value}", id.name());
        match trace_with(input.path(), &["--param", &arg]) {
            Ok(t) => assert!(t == default, "--param {arg} changed the trace"),
            Err(o) => panic!("--param {arg}: {}", stderr(&o)),
        }
    }
}

#[test]
fn repeated_params_apply_in_command_line_order() {
    let input = short_press();
    let p = input.path();
    let default = trace_with(p, &[]).unwrap();
    let two = trace_with(p, &["--param", "substeps_per_tick=2"]).unwrap();
    assert!(two != default, "two substeps change the trace");
    // The preset's own rate, given after another.
    let own = format!(
        "substeps_per_tick={}",
        maobi_shared::presets::LARGE.substeps_per_tick
    );
    let then_own = ["--param", "substeps_per_tick=2", "--param", &own];
    assert!(
        trace_with(p, &then_own).unwrap() == default,
        "the last one wins"
    );
    let then_2 = ["--param", &own, "--param", "substeps_per_tick=2"];
    assert!(trace_with(p, &then_2).unwrap() == two, "the last one wins");
    // Each is checked against the brush as it stands, on top of the chosen preset: a 4 mm
    // tip is wider than the small brush's 2.5 mm root (not the large brush's 6 mm), so it is
    // refused until the root is widened first.
    let small = ["--brush", "small"];
    let tip_first = ["--param", "tip_radius_mm=4", "--param", "radius_mm=5"];
    let o = trace_with(p, &[&small[..], &tip_first].concat()).unwrap_err();
    let err = stderr(&o);
    assert!(
        err.contains("tip_radius_mm=4") && err.contains("the tip cannot be wider than the root"),
        "{err}"
    );
    trace_with(p, &["--param", "tip_radius_mm=4"]).unwrap_or_else(|o| panic!("{}", stderr(&o)));
    let root_first = ["--param", "radius_mm=5", "--param", "tip_radius_mm=4"];
    trace_with(p, &[&small[..], &root_first].concat()).unwrap_or_else(|o| panic!("{}", stderr(&o)));
}

/// A brush too stiff for the fixed-point step at its substep rate is refused in fixed point
/// (the pen's format, whose one chain solve has a range), naming what to raise; the same
/// brush runs in `f64`, and in fixed point at more substeps a tick.
#[test]
fn a_brush_too_stiff_for_fixed_point_is_refused_saying_what_to_raise() {
    let input = short_press();
    let p = input.path();
    let stiff = ["--param", "axial_stiffness_n_per_m=50000"];
    let o = trace_with(p, &stiff).expect_err("a brush beyond the fixed-point step's range");
    let err = stderr(&o);
    assert!(
        err.contains("substeps_per_tick") && err.contains("too stiff"),
        "{err}"
    );
    // It names the brush as set and the smallest rate that runs it: that one runs, the one
    // below does not.
    assert!(err.contains("axial_stiffness_n_per_m=50000"), "{err}");
    let n: u32 = err
        .split("--param substeps_per_tick=")
        .nth(1)
        .and_then(|r| r.split('`').next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no rate suggested: {err}"));
    let rate = |n: u32| format!("substeps_per_tick={n}");
    trace_with(p, &[&stiff[..], &["--param", &rate(n)]].concat())
        .unwrap_or_else(|o| panic!("{}", stderr(&o)));
    assert!(n > 1, "{err}");
    trace_with(p, &[&stiff[..], &["--param", &rate(n - 1)]].concat())
        .expect_err("the rate below the suggested one");
    trace_with(p, &[&stiff[..], &["--scalar", "f64"]].concat())
        .unwrap_or_else(|o| panic!("{}", stderr(&o)));
    trace_with(
        p,
        &[&stiff[..], &["--param", "substeps_per_tick=5"]].concat(),
    )
    .unwrap_or_else(|o| panic!("{}", stderr(&o)));
}

#[test]
fn rejects_unknown_param_listing_valid_ones() {
    let input = short_press();
    let out = Temp::new("out");
    for cmd in ["trace", "render"] {
        let o = maobi(&[
            cmd,
            "--poses",
            input.path(),
            "--param",
            "stifness=3",
            "-o",
            out.path(),
        ]);
        let err = stderr(&o);
        assert!(!o.status.success(), "{cmd}");
        assert!(err.contains("unknown brush parameter `stifness`"), "{err}");
        for id in maobi_shared::ParamId::ALL {
            assert!(err.contains(id.name()), "{cmd}: {id} not in {err:?}");
        }
        assert!(!out.0.exists(), "{cmd} wrote output");
    }
}

#[test]
fn rejects_bad_param_values_saying_why() {
    let input = short_press();
    let out = Temp::new("out");
    let (lo, hi, _) = maobi_shared::ParamId::SubstepsPerTick.range();
    let range = format!("{lo} ..= {hi}");
    let cases: [(&str, &[&str]); 6] = [
        ("substeps_per_tick=0", &["substeps_per_tick", &range]),
        ("substeps_per_tick=1000", &["substeps_per_tick", &range]),
        (
            "substeps_per_tick=2.5",
            &["substeps_per_tick", "whole number"],
        ),
        (
            "substeps_per_tick=two",
            &["substeps_per_tick", "`two` is not a number"],
        ),
        (
            "substeps_per_tick",
            &["`substeps_per_tick` is not NAME=VALUE"],
        ),
        ("wetness=nan", &["wetness", "not a finite number"]),
    ];
    for cmd in ["trace", "render"] {
        for (arg, wants) in cases {
            let o = maobi(&[
                cmd,
                "--poses",
                input.path(),
                "--param",
                arg,
                "-o",
                out.path(),
            ]);
            let err = stderr(&o);
            assert!(!o.status.success(), "{cmd} accepted --param {arg}");
            for w in wants {
                assert!(err.contains(w), "{cmd} --param {arg}: {w:?} not in {err:?}");
            }
            assert!(!out.0.exists(), "{cmd} wrote output for --param {arg}");
        }
    }
}

#[test]
fn param_changes_the_render() {
    let p = example("press_lift.csv");
    let default = render(&p, &[]);
    let wide = render(&p, &["--param", "footprint_eps_mm=1"]);
    let dark = |png: &[u8]| decode(png).2.iter().filter(|&&v| v < 128).count();
    // Surface up to 1 mm above the paper inks, not only what is within 0.1 mm of it.
    assert!(
        dark(&wide) > dark(&default),
        "a wider footprint inked no more"
    );
}

#[test]
fn help_lists_every_param_and_session_refuses_them() {
    for cmd in ["trace", "render"] {
        let o = maobi(&[cmd, "--help"]);
        let help = String::from_utf8_lossy(&o.stdout);
        assert!(o.status.success());
        assert!(help.contains("--param <NAME=VALUE>"), "{help}");
        for id in maobi_shared::ParamId::ALL {
            let (lo, hi, _) = id.range();
            let line = help.lines().find(|l| l.trim_start().starts_with(id.name()));
            assert!(
                line.is_some_and(|l| l.contains(&format!("{lo} ..= {hi}"))),
                "{cmd}: no line for {id} with its range in {help}"
            );
        }
    }
    let out = Temp::new("out.png");
    let o = maobi(&[
        "render",
        "--session",
        "s.maobi.toml",
        "--param",
        "layers=4",
        "-o",
        out.path(),
    ]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("cannot be used with"), "{}", stderr(&o));
}

#[test]
fn sim_device_starts_with_the_params_given() {
    use maobi::device::{Device, Endpoint, LinkDevice, LinkOptions};
    use std::io::{BufRead, BufReader};
    use std::process::Stdio;
    let mut child = Command::new(env!("CARGO_BIN_EXE_maobi"))
        .args(["sim-device", "--listen", "127.0.0.1:0", "--brush", "small"])
        .args(["--param", "substeps_per_tick=5", "--param", "wetness=0.25"])
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut line = String::new();
    BufReader::new(child.stderr.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    let addr = line
        .split("--device tcp:")
        .nth(1)
        .and_then(|s| s.split('`').next())
        .map(str::to_string);
    let mut want = maobi_shared::presets::SMALL;
    want.substeps_per_tick = 5;
    want.wetness = 0.25;
    let mut status = None;
    if let Some(addr) = &addr {
        let hand = maobi::gui::start_hand(want.length_mm as f64);
        let mut dev = LinkDevice::new(LinkOptions::new(Endpoint::Tcp(addr.clone()), hand)).unwrap();
        if dev.connect().is_ok() {
            let end = std::time::Instant::now() + std::time::Duration::from_secs(3);
            while dev.status().params != want && std::time::Instant::now() < end {
                std::thread::sleep(std::time::Duration::from_millis(10));
            }
            status = Some(dev.status());
        }
    }
    let _ = child.kill();
    let _ = child.wait();
    assert!(
        line.contains("the small (substeps_per_tick=5, wetness=0.25) brush"),
        "{line}"
    );
    let status = status.unwrap_or_else(|| panic!("cannot connect to `maobi sim-device`: {line}"));
    assert_eq!(status.params, want, "the device's parameters");
}

#[test]
fn sim_device_and_bridge_refuse_bad_params() {
    // Checked before anything starts: no port is taken, no libHD looked for.
    for cmd in ["sim-device", "bridge"] {
        let o = maobi(&[
            cmd,
            "--listen",
            "127.0.0.1:0",
            "--param",
            "substeps_per_tick=0",
            "--param",
            "wetness=2",
        ]);
        let err = stderr(&o);
        assert_eq!(o.status.code(), Some(1), "{cmd}: {err}");
        assert!(
            err.contains("--param substeps_per_tick=0") && err.contains("1 ..= 100"),
            "{cmd}: {err}"
        );
        let o = maobi(&[cmd, "--param", "stifness=3"]);
        let err = stderr(&o);
        assert!(!o.status.success(), "{cmd}");
        assert!(
            err.contains("unknown brush parameter `stifness`"),
            "{cmd}: {err}"
        );
    }
}

/// What a user review found crashing, hanging or overwriting: each is refused with a message
/// that says what to do, and nothing is written.
#[test]
fn absurd_inputs_and_outputs_are_refused_not_crashed() {
    // Times in milliseconds written as seconds: a track 1000 times too long (a billion
    // seconds had run without end and filled the disk through `trace`).
    let long = Temp::with(
        "long.csv",
        format!("{HEADER}0,0,0,30,1,0,0,0\n1e9,0,0,30,1,0,0,0\n").as_bytes(),
    );
    let out = Temp::new("long.png");
    for cmd in ["render", "trace"] {
        let o = maobi(&[cmd, "--poses", long.path(), "-o", out.path()]);
        let e = stderr(&o);
        assert!(
            !o.status.success() && e.contains(":3: column `t`") && e.contains("milliseconds"),
            "{e}"
        );
        assert!(!out.0.exists(), "{cmd} wrote its output");
    }
    // A sampling rate that would make billions of poses.
    let yong = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/strokes/yong.toml");
    let csv = Temp::new("yong.csv");
    let o = maobi(&[
        "stroke",
        "sample",
        yong.to_str().unwrap(),
        "-o",
        csv.path(),
        "--rate",
        "1e9",
    ]);
    assert!(
        !o.status.success() && stderr(&o).contains("lower --rate"),
        "{}",
        stderr(&o)
    );
    // The output named as the input: the recording is kept.
    let heng = Temp::with(
        "heng.csv",
        std::fs::read(example("heng.csv")).unwrap().as_slice(),
    );
    let before = std::fs::read(&heng.0).unwrap();
    for cmd in ["render", "trace"] {
        let o = maobi(&[cmd, "--poses", heng.path(), "-o", heng.path()]);
        assert!(
            !o.status.success() && stderr(&o).contains("is the input file"),
            "{}",
            stderr(&o)
        );
    }
    assert_eq!(std::fs::read(&heng.0).unwrap(), before);
    // A render named for another image format.
    let jpg = Temp::new("x.jpg");
    let o = maobi(&["render", "--poses", heng.path(), "-o", jpg.path()]);
    assert!(
        !o.status.success() && stderr(&o).contains("`.png`, not `.jpg`"),
        "{}",
        stderr(&o)
    );
    assert!(!jpg.0.exists());
    // `-` is standard output for a trace.
    let o = maobi(&["trace", "--poses", heng.path(), "-o", "-"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(String::from_utf8_lossy(&o.stdout).starts_with("t,x,y,z,"));
    assert!(!Path::new("-").exists());
    // No input: the error names every kind a render takes.
    let o = maobi(&["render", "-o", "x.png"]);
    let e = stderr(&o);
    assert!(
        e.contains("--poses") && e.contains("--stroke") && e.contains("--session"),
        "{e}"
    );
    // A full disk on standard output is an error, not a panic.
    if Path::new("/dev/full").exists() {
        let full = std::fs::File::create("/dev/full").unwrap();
        let o = Command::new(env!("CARGO_BIN_EXE_maobi"))
            .args(["device", "config", "template"])
            .stdout(full)
            .output()
            .unwrap();
        let e = stderr(&o);
        assert!(
            !o.status.success() && e.contains("cannot write to standard output"),
            "{e}"
        );
        assert!(!e.contains("panicked"), "{e}");
    }
}

/// Progress bars are for a person at a terminal: with stderr a pipe (a log, CI, this test)
/// `render` and `trace`, of either model, print their summary line and nothing else.
#[test]
fn no_progress_bar_when_stderr_is_not_a_terminal() {
    let p = example("press_lift.csv");
    let png = Temp::new("quiet.png");
    let csv = Temp::new("quiet.csv");
    for model in ["liang", "baxter-lin"] {
        for (cmd, out) in [("render", &png), ("trace", &csv)] {
            let o = Command::new(env!("CARGO_BIN_EXE_maobi"))
                .args([cmd, "--poses", &p, "--model", model, "-o", out.path()])
                .args(if cmd == "render" {
                    &["--px-per-mm", "4"][..]
                } else {
                    &[]
                })
                .env_remove("RUST_LOG")
                .output()
                .expect("run maobi");
            let e = stderr(&o);
            assert!(o.status.success(), "{cmd} {model}: {e}");
            let lines: Vec<&str> = e.lines().collect();
            assert_eq!(lines.len(), 1, "{cmd} {model}: the summary alone: {e:?}");
            assert!(
                lines[0].starts_with(&format!("maobi {cmd}: ")),
                "{cmd} {model}: {e:?}"
            );
            for bar in ['\r', '\x1b', '█', '░', '▏', '#'] {
                assert!(!e.contains(bar), "{cmd} {model}: {bar:?} in {e:?}");
            }
            assert!(!e.contains("ETA"), "{cmd} {model}: {e:?}");
        }
    }
}
