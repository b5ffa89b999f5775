//! The app as a user meets it, in a real window under a virtual X display, driven by the
//! pointer and the keyboard through xdotool: start with no settings (the writing view), write
//! a stroke with the pointer, undo it, write again, save the picture with Ctrl+S, open the
//! laboratory (F2) and change a parameter, quit (Ctrl+Q), start again: the laboratory is back.
//! Each step's screenshot (`xwd` of the display) goes to `out/gui-session/`, and ink and
//! layout are checked from those pictures; the app tells where its views are through
//! `MAOBI_LAYOUT` (`gui::app::Automation::layout`).
//!
//! A second session practises 永 (`maobi gui --practice 永`): Write, the five strokes written
//! with the pointer along the master's medians, Score; the report's figures come back through
//! the layout file and the screen (`out/gui-practice/practice-scored.png`).
//!
//! Nothing here waits a fixed time for the app: every step goes on when the screen or the
//! layout file shows its effect, so a loaded machine is slower, never wrong. Needs Debian's
//! `xvfb`, `xauth`, `xdotool` and `x11-apps` (xwd); without them it skips, or fails where
//! every test must run (`CI=true`, or `MAOBI_REQUIRE_GUI` set).

use std::io::{BufRead, BufReader, Read};
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// How long any one step may take to show on screen before the test gives up (a hang
/// guard, not a pace: steps go on as soon as their effect shows).
const HANG_GUARD: Duration = Duration::from_secs(120);

/// One display at a time: `xvfb-run -a` picks a free display number racily, and two runs
/// started together can land on the same display (each test's app then draws on the other's
/// screen).
static ONE_DISPLAY: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// A virtual X display (`xvfb-run -a`), stopped with its process group when dropped.
struct Display {
    child: Child,
    display: String,
    xauthority: String,
}

impl Display {
    fn start() -> Display {
        let mut child = Command::new("xvfb-run")
            .args(["-a", "-s", "-screen 0 1600x1000x24 -nolisten tcp"])
            .args([
                "sh",
                "-c",
                "echo \"$DISPLAY $XAUTHORITY\"; exec sleep 100000",
            ])
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .process_group(0)
            .spawn()
            .expect("xvfb-run starts");
        let mut line = String::new();
        BufReader::new(child.stdout.take().unwrap())
            .read_line(&mut line)
            .unwrap();
        let mut it = line.split_whitespace();
        let display = it.next().expect("xvfb-run names its display").to_string();
        let xauthority = it.next().unwrap_or_default().to_string();
        Display {
            child,
            display,
            xauthority,
        }
    }

    fn command(&self, program: &str) -> Command {
        let mut c = Command::new(program);
        c.env("DISPLAY", &self.display)
            .env("XAUTHORITY", &self.xauthority);
        c
    }

    /// Runs xdotool with `args`, which must succeed.
    fn xdotool(&self, args: &[&str]) {
        let out = self.command("xdotool").args(args).output().unwrap();
        assert!(
            out.status.success(),
            "xdotool {args:?}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
    }

    /// The whole screen.
    fn screenshot(&self) -> Image {
        let out = self
            .command("xwd")
            .args(["-root", "-silent"])
            .output()
            .unwrap();
        assert!(out.status.success(), "xwd failed");
        Image::from_xwd(&out.stdout)
    }
}

impl Drop for Display {
    fn drop(&mut self) {
        // SAFETY: a signal to the process group this test started.
        unsafe { libc::kill(-(self.child.id() as i32), libc::SIGTERM) };
        let _ = self.child.wait();
    }
}

/// An RGB picture of the screen.
struct Image {
    w: usize,
    h: usize,
    rgb: Vec<[u8; 3]>,
}

impl Image {
    /// X's window dump (ZPixmap, 24 or 32 bits per pixel, true colour).
    fn from_xwd(b: &[u8]) -> Image {
        let field = |i: usize| u32::from_be_bytes(b[i * 4..i * 4 + 4].try_into().unwrap());
        let header = field(0) as usize;
        assert_eq!(field(2), 2, "a ZPixmap");
        let (w, h) = (field(4) as usize, field(5) as usize);
        let lsb_first = field(7) == 0;
        let bpp = field(11) as usize;
        let line = field(12) as usize;
        let masks = [field(14), field(15), field(16)];
        let colours = field(19) as usize;
        assert!(bpp == 32 || bpp == 24, "{bpp} bits per pixel");
        let data = &b[header + colours * 12..];
        let mut rgb = Vec::with_capacity(w * h);
        for y in 0..h {
            for x in 0..w {
                let at = y * line + x * bpp / 8;
                let mut px = [0u8; 4];
                px[..bpp / 8].copy_from_slice(&data[at..at + bpp / 8]);
                let v = if lsb_first {
                    u32::from_le_bytes(px)
                } else {
                    u32::from_be_bytes(px) >> (32 - bpp)
                };
                let ch = |m: u32| ((v & m) >> m.trailing_zeros()) as u8;
                rgb.push([ch(masks[0]), ch(masks[1]), ch(masks[2])]);
            }
        }
        Image { w, h, rgb }
    }

    fn save(&self, path: &Path) {
        let f = std::fs::File::create(path).unwrap();
        let mut enc = png::Encoder::new(std::io::BufWriter::new(f), self.w as u32, self.h as u32);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        let mut wr = enc.write_header().unwrap();
        wr.write_image_data(&self.rgb.concat()).unwrap();
    }

    /// The part of the picture in `r`.
    fn crop(&self, r: [u32; 4]) -> Image {
        let (x0, y0) = (r[0] as usize, r[1] as usize);
        let (x1, y1) = ((r[2] as usize).min(self.w), (r[3] as usize).min(self.h));
        let mut rgb = Vec::with_capacity((x1 - x0) * (y1 - y0));
        for y in y0..y1 {
            rgb.extend_from_slice(&self.rgb[y * self.w + x0..y * self.w + x1]);
        }
        Image {
            w: x1 - x0,
            h: y1 - y0,
            rgb,
        }
    }

    /// Pixels in `r` for which `f` holds.
    fn count(&self, r: [u32; 4], f: impl Fn([u8; 3]) -> bool) -> usize {
        let mut n = 0;
        for y in r[1] as usize..(r[3] as usize).min(self.h) {
            for x in r[0] as usize..(r[2] as usize).min(self.w) {
                n += f(self.rgb[y * self.w + x]) as usize;
            }
        }
        n
    }
}

/// Ink: a neutral tone, dark (the brush's marks over the paper are coloured).
fn is_ink(p: [u8; 3]) -> bool {
    let (lo, hi) = (p.iter().min().unwrap(), p.iter().max().unwrap());
    let luma = (p[0] as u32 * 3 + p[1] as u32 * 6 + p[2] as u32) / 10;
    luma < 140 && hi - lo < 30
}

/// Paper: light and warm.
fn is_paper(p: [u8; 3]) -> bool {
    p[0] > 200 && p[1] > 190 && p[2] > 170 && p[0] >= p[2]
}

/// The rectangle `name` of a layout file, if it has one.
fn rect(layout: &str, name: &str) -> Option<[u32; 4]> {
    let line = layout.lines().find(|l| l.split(' ').next() == Some(name))?;
    let v: Vec<u32> = line
        .split_whitespace()
        .skip(1)
        .filter_map(|s| s.parse::<f64>().ok().map(|v| v.max(0.0) as u32))
        .collect();
    (v.len() == 4).then(|| [v[0], v[1], v[2], v[3]])
}

/// The sheet of a layout, within the paper's view (zoomed in, it is larger than the view),
/// less a pixel on each side: the sheet's rectangle is rounded to whole pixels, and where
/// its edge falls mid-pixel the column or row there shows the view's border, not paper.
fn sheet_of(layout: &str) -> [u32; 4] {
    let (s, c) = (
        rect(layout, "sheet").unwrap(),
        rect(layout, "canvas").unwrap(),
    );
    [
        s[0].max(c[0]) + 1,
        s[1].max(c[1]) + 1,
        s[2].min(c[2]) - 1,
        s[3].min(c[3]) - 1,
    ]
}

/// One run of the app on `display`, with its settings under `home`.
struct App {
    child: Child,
    layout: PathBuf,
    log: PathBuf,
}

impl App {
    fn start(display: &Display, home: &Path, picture: &Path) -> App {
        App::start_with(display, home, picture, &[])
    }

    /// [`App::start`] with more arguments to `maobi gui`.
    fn start_with(display: &Display, home: &Path, picture: &Path, args: &[&str]) -> App {
        let layout = home.join("layout");
        let _ = std::fs::remove_file(&layout);
        let log = home.join("app.log");
        let child = display
            .command(env!("CARGO_BIN_EXE_maobi"))
            .arg("gui")
            .arg("--picture")
            .arg(picture)
            .args(args)
            .env("MAOBI_LAYOUT", &layout)
            .env("MAOBI_SCORE_HISTORY", home.join("scores.csv"))
            .env("XDG_CONFIG_HOME", home.join("config"))
            .env("XDG_DATA_HOME", home.join("data"))
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(&log).unwrap())
            .spawn()
            .expect("maobi gui starts");
        App { child, layout, log }
    }

    fn log(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }

    /// Waits until the layout file satisfies `done`; its text.
    fn layout_until(&mut self, what: &str, done: impl Fn(&str) -> bool) -> String {
        let start = Instant::now();
        loop {
            if let Ok(t) = std::fs::read_to_string(&self.layout) {
                if done(&t) {
                    return t;
                }
            }
            if let Ok(Some(s)) = self.child.try_wait() {
                panic!("the app exited ({s}) waiting for {what}:\n{}", self.log());
            }
            assert!(
                start.elapsed() < HANG_GUARD,
                "no {what} after {HANG_GUARD:?}:\n{}",
                self.log()
            );
            std::thread::sleep(Duration::from_millis(50));
        }
    }
}

impl App {
    /// Waits until the screen shows the layout the app reports, the same before and after
    /// the screenshot (egui settles its panels over the first frames of a face), and both
    /// satisfy `done`; that layout and screenshot.
    fn settled(
        &mut self,
        d: &Display,
        what: &str,
        done: impl Fn(&str, &Image) -> bool,
    ) -> (String, Image) {
        let start = Instant::now();
        loop {
            let before = self.layout_until(what, |t| rect(t, "sheet").is_some());
            let img = d.screenshot();
            let after = std::fs::read_to_string(&self.layout).unwrap_or_default();
            if before == after && done(&before, &img) {
                return (before, img);
            }
            if start.elapsed() > HANG_GUARD {
                let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../out/gui-session");
                img.save(&dir.join("failed.png"));
                panic!("no {what} after {HANG_GUARD:?} (out/gui-session/failed.png):\n{after}");
            }
            std::thread::sleep(Duration::from_millis(50));
        }
    }
}

impl Drop for App {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Steps until `done` holds for a screenshot; the last screenshot.
fn screen_until(d: &Display, what: &str, mut done: impl FnMut(&Image) -> bool) -> Image {
    let start = Instant::now();
    loop {
        let img = d.screenshot();
        if done(&img) {
            return img;
        }
        if start.elapsed() > HANG_GUARD {
            let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../out/gui-session");
            img.save(&dir.join("failed.png"));
            panic!("no {what} after {HANG_GUARD:?} (the screen: out/gui-session/failed.png)");
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// The footprint's outline the writing view draws while the brush touches.
fn is_footprint(p: [u8; 3]) -> bool {
    p[0] > 150 && p[1] < 90 && p[2] < 90
}

/// Writes a stroke with the pointer: presses at `from`, moves right a few pixels at a time
/// and lets go once the screen shows `ink_px` ink pixels in `sheet` (and the pointer has
/// moved at least 150 px), whatever the machine's pace.
fn write_stroke(d: &Display, sheet: [u32; 4], from: (u32, u32), ink_px: usize) -> Image {
    let (x, y) = from;
    d.xdotool(&["mousemove", &x.to_string(), &y.to_string()]);
    d.xdotool(&["mousedown", "1"]);
    let start = Instant::now();
    let mut step = 0u32;
    loop {
        step += 1;
        let at = (x + 4 * step).min(sheet[2] - 10);
        d.xdotool(&["mousemove", &at.to_string(), &y.to_string()]);
        if step.is_multiple_of(10) {
            let img = d.screenshot();
            if step >= 40 && img.count(sheet, is_ink) >= ink_px {
                d.xdotool(&["mouseup", "1"]);
                // The stroke ends when the brush has left the paper.
                screen_until(d, "the brush lifted", |img| {
                    img.count(sheet, is_footprint) == 0
                });
                return img;
            }
        }
        assert!(
            start.elapsed() < HANG_GUARD,
            "no ink under the pointer after {HANG_GUARD:?}"
        );
    }
}

fn tools_available() -> bool {
    ["xvfb-run", "xdotool", "xwd"].iter().all(|t| {
        Command::new("sh")
            .args(["-c", &format!("command -v {t}")])
            .output()
            .is_ok_and(|o| o.status.success())
    })
}

/// A session's folders, both emptied: its screenshots (`shots`, under the repository) and the
/// app's home (no settings: a first start); `None` (skipped) without the tools.
fn session_dirs(shots: &str, home: &str) -> Option<(PathBuf, PathBuf)> {
    if !tools_available() {
        maobi_testenv::skip_unless_required(
            &["MAOBI_REQUIRE_GUI"],
            "no xvfb-run, xdotool or xwd to drive the app's window with (apt-get install xvfb \
             xauth xdotool x11-apps libgl1-mesa-dri libegl1 libgl1 libxkbcommon-x11-0)",
        );
        return None;
    }
    let shots = Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(shots);
    let home = Path::new(env!("CARGO_TARGET_TMPDIR")).join(home);
    for dir in [&shots, &home] {
        let _ = std::fs::remove_dir_all(dir);
        std::fs::create_dir_all(dir).unwrap();
    }
    Some((shots, home))
}

#[test]
fn a_user_writes_undoes_saves_tunes_and_comes_back_to_the_laboratory() {
    let Some((shots, home)) = session_dirs("out/gui-session", "gui_xdotool") else {
        return;
    };
    let picture = home.join("picture.png");
    let shot = |img: &Image, name: &str| img.save(&shots.join(name));

    let _one = ONE_DISPLAY.lock().unwrap_or_else(|e| e.into_inner());
    let d = Display::start();
    let mut app = App::start(&d, &home, &picture);

    // Without a window manager X leaves the keyboard's focus nowhere: give it the window.
    let id = d
        .command("xdotool")
        .args(["search", "--sync", "--onlyvisible", "--name", "^Maobi$"])
        .output()
        .unwrap();
    let id = String::from_utf8_lossy(&id.stdout);
    let id = id
        .lines()
        .next()
        .expect("the app's window")
        .trim()
        .to_string();
    d.xdotool(&["windowfocus", &id]);

    // 1. The writing view, its paper most of the window: the layout the screen shows.
    let (layout, start) = app.settled(&d, "the writing view", |t, img| {
        let sheet = sheet_of(t);
        let area = ((sheet[2] - sheet[0]) * (sheet[3] - sheet[1])) as usize;
        t.contains("face writing") && img.count(sheet, is_paper) * 10 > area * 9
    });
    let canvas = rect(&layout, "canvas").unwrap();
    let window = rect(&layout, "window").unwrap();
    let sheet = sheet_of(&layout);
    let area = |r: [u32; 4]| ((r[2] - r[0]) * (r[3] - r[1])) as f64;
    shot(&start, "01-writing-view.png");
    let share = area(canvas) / area(window);
    eprintln!(
        "writing view: paper view {canvas:?} {:.1}% of the window {window:?}",
        share * 100.0
    );
    assert!(share >= 0.7, "the paper view has {share:.3} of the window");
    assert_eq!(start.count(sheet, is_ink), 0, "a blank sheet");
    // The laboratory shows the paper smaller, where its layout says.
    let laboratory_on_screen = |layout: &str, img: &Image| {
        let lab = sheet_of(layout);
        area(lab) < 0.9 * area(sheet) && img.count(lab, is_paper) as f64 > 0.9 * area(lab)
    };

    // 2. A stroke with the pointer.
    let mid = ((sheet[0] + sheet[2]) / 2, (sheet[1] + sheet[3]) / 2);
    let first = write_stroke(&d, sheet, (mid.0 - 150, mid.1 - 80), 400);
    shot(&first, "02-stroke.png");

    // 3. Ctrl+Z takes it back.
    d.xdotool(&["key", "ctrl+z"]);
    let undone = screen_until(&d, "the stroke undone", |img| img.count(sheet, is_ink) < 20);
    shot(&undone, "03-undone.png");

    // 4. Another stroke, saved with Ctrl+S where --picture says.
    let second = write_stroke(&d, sheet, (mid.0 - 150, mid.1 + 80), 400);
    shot(&second, "04-second-stroke.png");
    d.xdotool(&["key", "ctrl+s"]);
    let start_wait = Instant::now();
    let saved = loop {
        if let Some(img) = std::fs::read(&picture).ok().and_then(|b| {
            let mut r = png::Decoder::new(std::io::Cursor::new(b))
                .read_info()
                .ok()?;
            let mut buf = vec![0; r.output_buffer_size()?];
            let info = r.next_frame(&mut buf).ok()?;
            buf.truncate(info.buffer_size());
            Some((info, buf))
        }) {
            break img;
        }
        assert!(
            start_wait.elapsed() < HANG_GUARD,
            "Ctrl+S wrote no picture at {}:\n{}",
            picture.display(),
            app.log()
        );
        std::thread::sleep(Duration::from_millis(50));
    };
    let (info, buf) = saved;
    let channels = info.color_type.samples();
    let dark = buf
        .chunks(channels)
        .filter(|p| match p {
            [r, g, b, ..] => (*r as u32 * 3 + *g as u32 * 6 + *b as u32) / 10 < 140,
            [grey, ..] => *grey < 140,
            [] => false,
        })
        .count();
    eprintln!("picture {}x{}: {dark} ink px", info.width, info.height);
    assert!(
        dark > 100,
        "the saved picture has the stroke: {dark} ink px"
    );

    // 5. F2: the laboratory, where a parameter is dragged to a new value.
    d.xdotool(&["key", "F2"]);
    let (layout, before) = app.settled(&d, "the laboratory", |t, img| {
        t.contains("face laboratory") && rect(t, "param").is_some() && laboratory_on_screen(t, img)
    });
    let param = rect(&layout, "param").unwrap();
    shot(&before, "05-laboratory.png");
    // The panel says what a change did, in green, above the parameters (where the first
    // one is until then): nothing yet.
    let message = [0, window[1], param[2], param[3]];
    let is_ok_message = |p: [u8; 3]| p[1] > 150 && p[1] as i32 - p[0] as i32 > 60 && p[2] < 150;
    assert_eq!(before.count(message, is_ok_message), 0, "no message yet");
    // Drag the first parameter's value to the right until the panel reports the new value.
    let (px, py) = ((param[0] + param[2]) / 2, (param[1] + param[3]) / 2);
    d.xdotool(&["mousemove", &px.to_string(), &py.to_string()]);
    d.xdotool(&["mousedown", "1"]);
    let start_wait = Instant::now();
    let mut dx = 0;
    let after = loop {
        dx += 10;
        d.xdotool(&["mousemove", &(px + dx).to_string(), &py.to_string()]);
        let img = d.screenshot();
        if img.count(message, is_ok_message) > 20 {
            break img;
        }
        if start_wait.elapsed() > HANG_GUARD {
            img.save(&shots.join("failed.png"));
            panic!("dragging the parameter changed nothing (out/gui-session/failed.png)");
        }
        if dx >= 300 {
            // Back to the start of the drag, still held: egui keeps counting.
            dx = 0;
        }
    };
    d.xdotool(&["mouseup", "1"]);
    shot(&after, "06-parameter-changed.png");

    // 6. Ctrl+Q quits, keeping the settings.
    d.xdotool(&["key", "ctrl+q"]);
    let start_wait = Instant::now();
    let status = loop {
        if let Some(s) = app.child.try_wait().unwrap() {
            break s;
        }
        assert!(start_wait.elapsed() < HANG_GUARD, "Ctrl+Q did not quit");
        std::thread::sleep(Duration::from_millis(50));
    };
    assert!(
        status.success(),
        "the app quit with {status}:\n{}",
        app.log()
    );

    // 7. Started again, it comes back in the laboratory.
    let mut again = App::start(&d, &home, &picture);
    let (_, back) = again.settled(&d, "the laboratory again", |t, img| {
        t.contains("face laboratory") && laboratory_on_screen(t, img)
    });
    shot(&back, "07-reopened.png");
    let mut log = String::new();
    std::fs::File::open(&again.log)
        .map(|mut f| f.read_to_string(&mut log))
        .ok();
    assert!(!log.contains("panicked"), "{log}");
}

/// The practice session: the master's 永 loaded at start, Write, each of its five strokes
/// written with the pointer along its median (the button held down the stroke, let go
/// between strokes until the brush has left the paper), Score; the report is checked from the
/// layout file (the panel's state line) and kept as a screenshot.
#[test]
fn a_writer_practises_yong_with_the_pointer_and_scores_it() {
    let Some((shots, home)) = session_dirs("out/gui-practice", "gui_xdotool_practice") else {
        return;
    };
    let picture = home.join("picture.png");

    let _one = ONE_DISPLAY.lock().unwrap_or_else(|e| e.into_inner());
    let d = Display::start();
    let mut app = App::start_with(
        &d,
        &home,
        &picture,
        &["--practice", "永", "--face", "writing"],
    );
    let (layout, _) = app.settled(&d, "the master's 永 loaded", |t, _| {
        t.contains("practice ready") && rect(t, "practice_write").is_some()
    });
    let click = |r: [u32; 4]| {
        let (x, y) = ((r[0] + r[2]) / 2, (r[1] + r[3]) / 2);
        d.xdotool(&["mousemove", &x.to_string(), &y.to_string()]);
        d.xdotool(&["click", "1"]);
    };
    click(rect(&layout, "practice_write").unwrap());
    let layout = app.layout_until("Write pressed", |t| t.contains("practice writing"));

    // Paper millimetres to the screen, from the sheet's rectangle and its extent in mm.
    let sheet = rect(&layout, "sheet").unwrap();
    let canvas = rect(&layout, "canvas").unwrap();
    let mm: Vec<f64> = layout
        .lines()
        .find_map(|l| l.strip_prefix("paper_mm "))
        .expect("the layout gives the paper's extent")
        .split_whitespace()
        .map(|v| v.parse().unwrap())
        .collect();
    let to_screen = |p: [f64; 2]| -> (u32, u32) {
        let fx = (p[0] - mm[0]) / (mm[2] - mm[0]);
        let fy = (mm[1] - p[1]) / (mm[1] - mm[3]);
        (
            (sheet[0] as f64 + fx * (sheet[2] - sheet[0]) as f64).round() as u32,
            (sheet[1] as f64 + fy * (sheet[3] - sheet[1]) as f64).round() as u32,
        )
    };
    // The hand (the brush's ferrule, mm) where the layout says it is now.
    let hand_at = |t: &str| -> Option<[f64; 2]> {
        let v: Vec<f64> = t
            .lines()
            .find_map(|l| l.strip_prefix("hand "))?
            .split_whitespace()
            .filter_map(|v| v.parse().ok())
            .collect();
        (v.len() == 3).then(|| [v[0], v[1]])
    };
    // The pixel a point lands on, back in mm: where the hand can be expected to arrive.
    let to_mm = |p: (u32, u32)| -> [f64; 2] {
        let fx = (p.0 as f64 - sheet[0] as f64) / (sheet[2] - sheet[0]) as f64;
        let fy = (p.1 as f64 - sheet[1] as f64) / (sheet[3] - sheet[1]) as f64;
        [mm[0] + fx * (mm[2] - mm[0]), mm[1] - fy * (mm[1] - mm[3])]
    };
    let px_mm = (mm[2] - mm[0]) / (sheet[2] - sheet[0]) as f64;
    let arrive = |app: &mut App, p: (u32, u32), what: &str| {
        let want = to_mm(p);
        app.layout_until(what, |t| {
            hand_at(t).is_some_and(|h| (h[0] - want[0]).hypot(h[1] - want[1]) <= px_mm)
        });
    };
    let view = sheet_of(&layout);
    let yong = maobi::hanzi::load_from(None, "永").unwrap();
    for (k, stroke) in yong.to_mm(maobi::gui::practice::SIZE_MM).iter().enumerate() {
        // The median every pixel and a half, as a hand would draw it.
        let mut pts = vec![to_screen(stroke.median[0])];
        for w in stroke.median.windows(2) {
            let (a, b) = (to_screen(w[0]), to_screen(w[1]));
            let len = ((b.0 as f64 - a.0 as f64).hypot(b.1 as f64 - a.1 as f64) / 1.5).ceil();
            for i in 1..=len as u32 {
                let f = i as f64 / len;
                pts.push((
                    (a.0 as f64 + (b.0 as f64 - a.0 as f64) * f).round() as u32,
                    (a.1 as f64 + (b.1 as f64 - a.1 as f64) * f).round() as u32,
                ));
            }
        }
        for p in &pts {
            assert!(
                p.0 > canvas[0] && p.0 < canvas[2] && p.1 > canvas[1] && p.1 < canvas[3],
                "stroke {} runs off the paper's view at {p:?}",
                k + 1
            );
        }
        // The hand travels to the stroke's start lifted, and presses there.
        let (x, y) = pts[0];
        d.xdotool(&["mousemove", &x.to_string(), &y.to_string()]);
        arrive(&mut app, pts[0], "the hand at the stroke's start");
        d.xdotool(&["mousedown", "1"]);
        for (x, y) in &pts[1..] {
            d.xdotool(&["mousemove", &x.to_string(), &y.to_string()]);
        }
        arrive(&mut app, pts[pts.len() - 1], "the hand at the stroke's end");
        d.xdotool(&["mouseup", "1"]);
        // Between strokes the brush leaves the paper.
        app.layout_until("the brush lifted after a stroke", |t| {
            !t.contains("mark touching")
        });
    }
    let layout = app.layout_until("the panel's Score", |t| rect(t, "practice_score").is_some());
    click(rect(&layout, "practice_score").unwrap());
    let layout = app.layout_until("the score", |t| t.contains("practice scored"));
    let figures: Vec<f64> = layout
        .lines()
        .find_map(|l| l.strip_prefix("practice scored "))
        .unwrap()
        .split_whitespace()
        .map(|v| v.parse().unwrap())
        .collect();
    let (total, order, matched) = (figures[0], figures[1], figures[2]);
    // On screen, the master's strokes take their scores' colours (red to amber to green,
    // saturated, where the paper had faint red outlines) once the report is drawn.
    let scored = |p: [u8; 3]| p[2] < 90 && p[1] > 120;
    let img = screen_until(&d, "the report on screen", |img| {
        img.count(view, scored) > 50
    });
    // The window alone, as the README shows it.
    img.crop(rect(&layout, "window").unwrap())
        .save(&shots.join("practice-scored.png"));
    eprintln!(
        "practised 永 with the pointer: total {total:.3}, order {order:.3}, {matched} of 5 strokes \
         matched (out/gui-practice/practice-scored.png)"
    );
    assert!(
        matched >= 4.0,
        "{matched} of the master's 5 strokes matched:\n{layout}"
    );
    assert!(total > 0.2 && total <= 1.0, "total {total}");
    let history = std::fs::read_to_string(home.join("scores.csv")).unwrap();
    assert_eq!(
        history.lines().count(),
        2,
        "the attempt appended:\n{history}"
    );
    assert!(!app.log().contains("panicked"), "{}", app.log());
}
