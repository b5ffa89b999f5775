//! The stroke editor: a keyframed stroke file (`examples/strokes/*.toml`) on a timeline.
//!
//! * the strokes as bars on the character's clock, their keyframes as diamonds, a playhead
//!   to scrub; play and pause send the strokes to the device as a replay from the playhead;
//! * the selected stroke's *kinetic curve* (time to path parameter, the thesis's double
//!   interpolant): dragging a keyframe along it (or its diamond along the timeline) retimes
//!   the stroke without changing its path;
//! * on the paper: every stroke's path, its keyframes and the moving point at the playhead;
//!   with "Edit keyframes" on, dragging a keyframe moves it (the path follows, its timing is
//!   kept);
//! * "Guide me": guided writing, the device pulls the hand toward the moving point, and the
//!   panel shows how far the writer strayed.
//!
//! Edits change the file's own description ([`StrokeFile`]) and are validated by building the
//! character again, exactly as `maobi render --stroke` would; an edit the model refuses is
//! undone and its error shown. "Save" writes the file back as TOML.

use std::path::{Path, PathBuf};

use egui::{Color32, Pos2, Rect, Sense, Stroke as Line, Vec2};

use super::canvas::PaperView;
use crate::device::BrushFrame;
use crate::poses::PoseTrack;
use crate::strokes::{rows_to_csv, Character, StrokeFile};

/// What the panel asks the app to do with the device.
#[derive(Clone, Debug)]
pub enum TimelineAction {
    /// Replay this track (the strokes from the playhead on).
    Play(PoseTrack),
    Pause,
    /// Guided writing along this track.
    Guide(PoseTrack),
    StopGuide,
    /// Choose a stroke file in the platform's dialog, starting from this path: to open
    /// (`save` false) or to save the strokes to.
    ChooseFile {
        save: bool,
        current: String,
    },
}

/// A keyframe being dragged: file stroke, keyframe, and what is being dragged.
#[derive(Copy, Clone, Debug, PartialEq)]
enum Drag {
    /// Its position on the paper.
    Place(usize, usize),
    /// Its time (on the timeline strip or the kinetic curve).
    Time(usize, usize),
}

/// How far the writer strayed from the moving point during guidance.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Stray {
    pub ticks: u64,
    sum2: f64,
    pub max_mm: f64,
}

impl Stray {
    pub fn rms_mm(&self) -> f64 {
        if self.ticks == 0 {
            0.0
        } else {
            (self.sum2 / self.ticks as f64).sqrt()
        }
    }
}

pub struct Timeline {
    pub path: String,
    file: Option<StrokeFile>,
    character: Option<Character>,
    /// Sampled paper path (x, y) of each of the file's strokes, for the overlay.
    paths: Vec<Vec<[f64; 2]>>,
    pub message: Option<(String, bool)>,
    selected: Option<usize>,
    /// Seconds on the character's clock.
    pub playhead: f64,
    /// Playing from this time, counted in replay frames since `frames_at_start`.
    playing: Option<(f64, u64)>,
    /// Guided writing from this time (device ticks are counted from its frames).
    guiding: Option<f64>,
    pub stray: Stray,
    /// Pointer edits keyframes on the paper instead of moving the pen.
    pub edit_on_paper: bool,
    drag: Option<Drag>,
    /// Edited since loaded or saved.
    pub dirty: bool,
}

impl Default for Timeline {
    fn default() -> Self {
        Timeline {
            path: "examples/strokes/yong.toml".into(),
            file: None,
            character: None,
            paths: Vec::new(),
            message: None,
            selected: None,
            playhead: 0.0,
            playing: None,
            guiding: None,
            stray: Stray::default(),
            edit_on_paper: false,
            drag: None,
            dirty: false,
        }
    }
}

/// Stroke colours on the overlay and the strip.
const SELECTED: Color32 = Color32::from_rgb(230, 90, 60);
const OTHER: Color32 = Color32::from_rgb(70, 130, 210);
const TRAVEL: Color32 = Color32::from_rgb(150, 150, 150);

impl Timeline {
    pub fn character(&self) -> Option<&Character> {
        self.character.as_ref()
    }
    pub fn file(&self) -> Option<&StrokeFile> {
        self.file.as_ref()
    }
    pub fn selected(&self) -> Option<usize> {
        self.selected
    }
    pub fn select(&mut self, stroke: usize) {
        if self.file.as_ref().is_some_and(|f| stroke < f.stroke.len()) {
            self.selected = Some(stroke);
        }
    }
    pub fn playing(&self) -> bool {
        self.playing.is_some()
    }
    pub fn guiding(&self) -> bool {
        self.guiding.is_some()
    }

    /// Loads a stroke file; on error the current one is kept.
    pub fn open(&mut self, path: &Path) -> anyhow::Result<()> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| anyhow::anyhow!("cannot read {}: {e}", path.display()))?;
        let name = path.display().to_string();
        let character = Character::from_toml(&name, &text)?;
        let file: StrokeFile = toml::from_str(&text).map_err(|e| anyhow::anyhow!("{name}: {e}"))?;
        self.path = name;
        self.set(file, character);
        self.selected = Some(0);
        self.playhead = 0.0;
        self.dirty = false;
        self.message = Some((
            format!(
                "{}: {} strokes, {:.2} s",
                self.path,
                self.file.as_ref().map_or(0, |f| f.stroke.len()),
                self.duration()
            ),
            false,
        ));
        Ok(())
    }

    /// Writes the (edited) file as TOML.
    pub fn save(&mut self, path: &Path) -> anyhow::Result<()> {
        let f = self
            .file
            .as_ref()
            .ok_or_else(|| anyhow::anyhow!("no stroke file open"))?;
        let text = toml::to_string(f)?;
        // What we write must read back as the same character.
        Character::from_toml(&path.display().to_string(), &text)?;
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir)?;
        }
        std::fs::write(path, text)
            .map_err(|e| anyhow::anyhow!("cannot write {}: {e}", path.display()))?;
        self.path = path.display().to_string();
        self.dirty = false;
        Ok(())
    }

    fn set(&mut self, file: StrokeFile, character: Character) {
        self.paths = vec![Vec::new(); file.stroke.len()];
        for seg in &character.segments {
            if let Some(i) = seg.from {
                let (t0, t1) = seg.stroke.domain();
                let n = (((t1 - t0) * 200.0).ceil() as usize).clamp(2, 2000);
                self.paths[i] = (0..=n)
                    .map(|k| {
                        let p = seg.stroke.pose_at(t0 + (t1 - t0) * k as f64 / n as f64).0;
                        [p[0], p[1]]
                    })
                    .collect();
            }
        }
        self.file = Some(file);
        self.character = Some(character);
    }

    pub fn duration(&self) -> f64 {
        self.character.as_ref().map_or(0.0, Character::duration)
    }

    /// Applies `edit` to a copy of the file and keeps it if the character still builds.
    fn edit(&mut self, what: &str, edit: impl FnOnce(&mut StrokeFile)) -> bool {
        let Some(f) = &self.file else { return false };
        let mut copy = f.clone();
        edit(&mut copy);
        let text = match toml::to_string(&copy) {
            Ok(t) => t,
            Err(e) => {
                self.message = Some((format!("{what}: {e}"), true));
                return false;
            }
        };
        match Character::from_toml(&self.path, &text) {
            Ok(c) => {
                self.set(copy, c);
                self.dirty = true;
                self.message = Some((what.to_string(), false));
                true
            }
            Err(e) => {
                self.message = Some((format!("{what} refused: {e:#}"), true));
                false
            }
        }
    }

    /// The file stroke `i`'s segment on the character's clock.
    fn segment(&self, i: usize) -> Option<&crate::strokes::Segment> {
        self.character
            .as_ref()?
            .segments
            .iter()
            .find(|s| s.from == Some(i))
    }

    /// Keyframe `k` of file stroke `i`: its time on the character's clock and its position.
    pub fn key(&self, i: usize, k: usize) -> Option<(f64, [f64; 3])> {
        let seg = self.segment(i)?;
        let t = *seg.stroke.key_times().get(k)?;
        Some((seg.start + t, seg.stroke.key(k).0))
    }

    /// Moves keyframe `k` of stroke `i` to `xy` on the paper (its height, orientation and
    /// time are kept).
    pub fn move_key(&mut self, i: usize, k: usize, xy: [f64; 2]) -> bool {
        self.edit(&format!("stroke {} keyframe {} moved", i + 1, k + 1), |f| {
            if let Some(key) = f.stroke.get_mut(i).and_then(|s| s.keys.get_mut(k)) {
                let mut at = key.at.clone().unwrap_or_default();
                at.resize(at.len().max(2), 0.0);
                at[0] = xy[0];
                at[1] = xy[1];
                key.at = Some(at);
            }
        })
    }

    /// Retimes keyframe `k` of stroke `i` to `t` seconds on the character's clock. Every
    /// keyframe of the stroke gets its current time written out first, so only this one
    /// moves; the path (the position spline) is untouched.
    pub fn retime_key(&mut self, i: usize, k: usize, t: f64) -> bool {
        let Some(seg) = self.segment(i) else {
            return false;
        };
        let times: Vec<f64> = seg.stroke.key_times().to_vec();
        let rel = t - seg.start;
        self.edit(
            &format!("stroke {} keyframe {} retimed to {rel:.3} s", i + 1, k + 1),
            |f| {
                if let Some(s) = f.stroke.get_mut(i) {
                    for (key, tk) in s.keys.iter_mut().zip(&times) {
                        key.t = Some(*tk);
                    }
                    if let Some(key) = s.keys.get_mut(k) {
                        key.t = Some(round_ms(rel));
                    }
                }
            },
        )
    }

    /// The strokes from `from` seconds on, as a 1 ms pose track starting at 0.
    pub fn track_from(&self, from: f64) -> anyhow::Result<PoseTrack> {
        let c = self
            .character
            .as_ref()
            .ok_or_else(|| anyhow::anyhow!("no stroke file open"))?;
        let rows: Vec<_> = c
            .sample(crate::poses::TICK_S)
            .into_iter()
            .filter(|r| r.t >= from - 1e-9)
            .map(|mut r| {
                r.t -= from;
                r
            })
            .collect();
        if rows.len() < 2 {
            anyhow::bail!("nothing left to play after {from:.3} s");
        }
        PoseTrack::from_reader(&self.path, rows_to_csv(&rows).as_bytes())
            .map_err(|e| anyhow::anyhow!("{e}"))
    }

    /// Play from the playhead (from the start if it is at the end).
    pub fn play(&mut self, replay_frames: u64) -> Option<TimelineAction> {
        if self.playhead >= self.duration() - 1e-3 {
            self.playhead = 0.0;
        }
        match self.track_from(self.playhead) {
            Ok(t) => {
                self.playing = Some((self.playhead, replay_frames));
                Some(TimelineAction::Play(t))
            }
            Err(e) => {
                self.message = Some((format!("{e:#}"), true));
                None
            }
        }
    }

    pub fn guide(&mut self) -> Option<TimelineAction> {
        if self.playhead >= self.duration() - 1e-3 {
            self.playhead = 0.0;
        }
        match self.track_from(self.playhead) {
            Ok(t) => {
                self.guiding = Some(self.playhead);
                self.stray = Stray::default();
                Some(TimelineAction::Guide(t))
            }
            Err(e) => {
                self.message = Some((format!("{e:#}"), true));
                None
            }
        }
    }

    /// Follows the device: the playhead advances with the replay's frames, and guided
    /// writing's frames give the moving point and how far the pen is from it.
    pub fn follow(&mut self, frames: &[BrushFrame], replay_frames: u64, replaying: bool) {
        if let Some((t0, f0)) = self.playing {
            self.playhead = (t0 + (replay_frames - f0) as f64 * 1e-3).min(self.duration());
            if !replaying && replay_frames > f0 {
                self.playing = None;
            }
        }
        if let Some(t0) = self.guiding {
            let mut any = false;
            for f in frames {
                if let Some(g) = &f.guide {
                    any = true;
                    self.playhead = (self.playhead.max(t0) + 1e-3).min(self.duration());
                    if g.gain >= 1.0 {
                        let p = f.pose.pos.to_f64();
                        let d2 = (p[0] - g.anchor[0]).powi(2) + (p[1] - g.anchor[1]).powi(2);
                        self.stray.ticks += 1;
                        self.stray.sum2 += d2;
                        self.stray.max_mm = self.stray.max_mm.max(d2.sqrt());
                    }
                }
            }
            let ended = !any && !frames.is_empty() && self.stray.ticks > 0;
            if ended {
                self.guiding = None;
                self.message = Some((
                    format!(
                        "guided writing done: strayed {:.1} mm RMS, {:.1} mm at most from the stroke",
                        self.stray.rms_mm(),
                        self.stray.max_mm
                    ),
                    false,
                ));
            }
        }
    }

    /// The panel (below the paper).
    /// Saves the strokes to `p`, saying how it went in the editor's message line.
    pub fn save_to(&mut self, p: &Path) {
        self.save_reporting(p);
    }

    fn save_reporting(&mut self, p: &Path) {
        self.message = Some(match self.save(p) {
            Ok(()) => (format!("saved {}", p.display()), false),
            Err(e) => (format!("{e:#}"), true),
        });
    }

    pub fn ui(
        &mut self,
        ui: &mut egui::Ui,
        replay_frames: u64,
        latest: Option<&BrushFrame>,
    ) -> Option<TimelineAction> {
        let mut action = None;
        ui.horizontal_wrapped(|ui| {
            let l = ui.label("stroke file");
            ui.add(egui::TextEdit::singleline(&mut self.path).desired_width(220.0))
                .labelled_by(l.id);
            if ui.button("Open strokes").clicked() {
                let p = PathBuf::from(self.path.trim());
                if let Err(e) = self.open(&p) {
                    self.message = Some((format!("{e:#}"), true));
                }
            }
            if ui
                .button("…")
                .on_hover_text("Choose a stroke file to open")
                .clicked()
            {
                action = Some(TimelineAction::ChooseFile {
                    save: false,
                    current: self.path.clone(),
                });
            }
            let save = egui::Button::new(if self.dirty {
                "Save strokes*"
            } else {
                "Save strokes"
            });
            if ui.add_enabled(self.file.is_some(), save).clicked() {
                let p = PathBuf::from(self.path.trim());
                self.save_reporting(&p);
            }
            if ui
                .add_enabled(self.file.is_some(), egui::Button::new("…"))
                .on_hover_text("Choose where to save the strokes")
                .clicked()
            {
                action = Some(TimelineAction::ChooseFile {
                    save: true,
                    current: self.path.clone(),
                });
            }
            ui.separator();
            let have = self.character.is_some();
            if self.playing.is_some() {
                if ui.button("Pause").clicked() {
                    self.playing = None;
                    action = Some(TimelineAction::Pause);
                }
            } else if ui.add_enabled(have, egui::Button::new("Play")).clicked() {
                action = self.play(replay_frames);
            }
            if ui
                .add_enabled(
                    have && self.playing.is_none(),
                    egui::Button::new("To start"),
                )
                .clicked()
            {
                self.playhead = 0.0;
            }
            if self.guiding.is_some() {
                if ui.button("Stop guiding").clicked() {
                    self.guiding = None;
                    action = Some(TimelineAction::StopGuide);
                }
            } else if ui
                .add_enabled(
                    have && self.playing.is_none(),
                    egui::Button::new("Guide me"),
                )
                .on_hover_text(
                    "Guided writing: the pen pulls your hand along the strokes from the playhead",
                )
                .clicked()
            {
                action = self.guide();
            }
            ui.checkbox(&mut self.edit_on_paper, "Edit keyframes")
                .on_hover_text("Drag keyframes on the paper (the pen stays up)");
            let dur = self.duration();
            ui.add_enabled(
                have && self.playing.is_none(),
                egui::Slider::new(&mut self.playhead, 0.0..=dur.max(1e-3))
                    .text("s")
                    .fixed_decimals(3),
            );
            if self.guiding.is_some() || self.stray.ticks > 0 {
                let d = latest
                    .and_then(|f| f.guide.map(|g| g.distance_mm))
                    .map_or(String::new(), |d| format!("now {d:.1} mm, "));
                ui.label(format!(
                    "strayed: {d}{:.1} mm RMS, {:.1} mm at most",
                    self.stray.rms_mm(),
                    self.stray.max_mm
                ));
            }
        });
        super::message::label(ui, &self.message);
        if self.character.is_some() {
            self.strip(ui);
            self.kinetic_view(ui);
        }
        action
    }

    /// The strokes on the clock: bars, keyframe diamonds, the playhead.
    fn strip(&mut self, ui: &mut egui::Ui) {
        let Some(c) = &self.character else { return };
        let dur = c.duration().max(1e-3);
        let (rect, resp) = ui.allocate_exact_size(
            Vec2::new(ui.available_width(), 46.0),
            Sense::click_and_drag(),
        );
        let painter = ui.painter_at(rect);
        painter.rect_filled(rect, 3.0, ui.visuals().extreme_bg_color);
        let x_of = |t: f64| rect.left() + (t / dur) as f32 * rect.width();
        let t_of = |x: f32| ((x - rect.left()) / rect.width()) as f64 * dur;
        let bar = Rect::from_min_max(
            Pos2::new(rect.left(), rect.top() + 8.0),
            Pos2::new(rect.right(), rect.bottom() - 16.0),
        );
        let mut diamonds = Vec::new();
        for seg in &c.segments {
            let (t0, t1) = seg.stroke.domain();
            let (a, b) = (x_of(seg.start + t0), x_of(seg.start + t1));
            let color = match seg.from {
                Some(i) if Some(i) == self.selected => SELECTED,
                Some(_) => OTHER,
                None => TRAVEL,
            };
            let r = Rect::from_min_max(
                Pos2::new(a, bar.top()),
                Pos2::new(b.max(a + 1.0), bar.bottom()),
            );
            painter.rect_filled(r, 2.0, color.gamma_multiply(0.5));
            if let Some(i) = seg.from {
                for (k, t) in seg.stroke.key_times().iter().enumerate() {
                    let p = Pos2::new(x_of(seg.start + t), bar.center().y);
                    diamonds.push((i, k, p));
                    let d = 4.0;
                    painter.add(egui::Shape::convex_polygon(
                        vec![
                            p + Vec2::new(0.0, -d),
                            p + Vec2::new(d, 0.0),
                            p + Vec2::new(0.0, d),
                            p + Vec2::new(-d, 0.0),
                        ],
                        color,
                        Line::NONE,
                    ));
                }
            }
        }
        let x = x_of(self.playhead);
        painter.line_segment(
            [Pos2::new(x, rect.top()), Pos2::new(x, rect.bottom())],
            Line::new(2.0, Color32::from_rgb(240, 200, 60)),
        );
        painter.text(
            Pos2::new(rect.left() + 4.0, rect.bottom() - 2.0),
            egui::Align2::LEFT_BOTTOM,
            format!("{:.3} / {:.3} s", self.playhead, dur),
            egui::FontId::monospace(11.0),
            ui.visuals().text_color(),
        );
        let pointer = resp.interact_pointer_pos();
        if resp.drag_started() {
            if let Some(p) = pointer {
                let near = diamonds
                    .iter()
                    .filter(|(_, _, d)| d.distance(p) < 7.0)
                    .min_by(|a, b| a.2.distance(p).total_cmp(&b.2.distance(p)));
                self.drag = near.map(|&(i, k, _)| Drag::Time(i, k));
                if let Some(Drag::Time(i, _)) = self.drag {
                    self.selected = Some(i);
                }
            }
        }
        match (self.drag, pointer) {
            (Some(Drag::Time(i, k)), Some(p)) if resp.dragged() => {
                self.retime_key(i, k, t_of(p.x).clamp(0.0, dur));
            }
            (None, Some(p)) if (resp.clicked() || resp.dragged()) && self.playing.is_none() => {
                self.playhead = t_of(p.x).clamp(0.0, dur);
                if let Some(seg) =
                    c.segments.iter().rev().find(|s| {
                        s.from.is_some() && s.start + s.stroke.domain().0 <= self.playhead
                    })
                {
                    self.selected = seg.from;
                }
            }
            _ => {}
        }
        if resp.drag_stopped() {
            self.drag = None;
        }
    }

    /// The selected stroke's kinetic curve: path parameter over time, keyframes on it.
    /// Dragging a keyframe sideways retimes it; the path stays the same.
    fn kinetic_view(&mut self, ui: &mut egui::Ui) {
        let Some(i) = self.selected else { return };
        let Some(seg) = self.segment(i) else { return };
        let stroke = seg.stroke.clone();
        let start = seg.start;
        let (t0, t1) = stroke.domain();
        let (u0, u1) = stroke.path().domain();
        let name = self
            .file
            .as_ref()
            .and_then(|f| f.stroke.get(i))
            .and_then(|s| s.name.clone())
            .unwrap_or_else(|| format!("stroke {}", i + 1));
        ui.label(format!(
            "{name}: kinetic curve (position along the path against time); drag a keyframe sideways to retime it, the path is kept"
        ));
        let (rect, resp) = ui.allocate_exact_size(
            Vec2::new(
                ui.available_width(),
                ui.available_height().clamp(60.0, 140.0),
            ),
            Sense::click_and_drag(),
        );
        let painter = ui.painter_at(rect);
        painter.rect_filled(rect, 3.0, ui.visuals().extreme_bg_color);
        let span_t = (t1 - t0).max(1e-6);
        let span_u = (u1 - u0).max(1e-9);
        let to_screen = |t: f64, u: f64| {
            Pos2::new(
                rect.left() + 6.0 + ((t - t0) / span_t) as f32 * (rect.width() - 12.0),
                rect.bottom() - 6.0 - ((u - u0) / span_u) as f32 * (rect.height() - 12.0),
            )
        };
        let t_of = |x: f32| t0 + ((x - rect.left() - 6.0) / (rect.width() - 12.0)) as f64 * span_t;
        let n = 200;
        let pts: Vec<Pos2> = (0..=n)
            .map(|k| {
                let t = t0 + span_t * k as f64 / n as f64;
                to_screen(t, stroke.kinetic().param(t))
            })
            .collect();
        painter.add(egui::Shape::line(pts, Line::new(1.5, OTHER)));
        let keys: Vec<(usize, Pos2)> = stroke
            .key_times()
            .iter()
            .zip(stroke.key_params())
            .enumerate()
            .map(|(k, (t, u))| (k, to_screen(*t, *u)))
            .collect();
        for (k, p) in &keys {
            painter.circle_filled(*p, 4.5, SELECTED);
            painter.text(
                *p + Vec2::new(5.0, -5.0),
                egui::Align2::LEFT_BOTTOM,
                format!("{}", k + 1),
                egui::FontId::proportional(11.0),
                ui.visuals().text_color(),
            );
        }
        let ph = self.playhead - start;
        if (t0..=t1).contains(&ph) {
            let p = to_screen(ph, stroke.kinetic().param(ph));
            painter.circle_stroke(p, 6.0, Line::new(2.0, Color32::from_rgb(240, 200, 60)));
        }
        let pointer = resp.interact_pointer_pos();
        if resp.drag_started() {
            self.drag = pointer.and_then(|p| {
                keys.iter()
                    .filter(|(_, q)| q.distance(p) < 8.0)
                    .min_by(|a, b| a.1.distance(p).total_cmp(&b.1.distance(p)))
                    .map(|&(k, _)| Drag::Time(i, k))
            });
        }
        if let (Some(Drag::Time(si, k)), Some(p)) = (self.drag, pointer) {
            if si == i && resp.dragged() {
                self.retime_key(i, k, start + t_of(p.x));
            }
        }
        if resp.drag_stopped() {
            self.drag = None;
        }
    }

    /// Draws the strokes' paths, keyframes and the moving point on the paper, and with
    /// "Edit keyframes" on, lets the pointer drag keyframes. Returns whether the pointer is
    /// busy editing (so it does not move the pen).
    pub fn paper_overlay(
        &mut self,
        ui: &egui::Ui,
        paper: &PaperView,
        pointer_mm: Option<[f64; 2]>,
        pressed: bool,
        guide_anchor: Option<[f64; 3]>,
    ) -> bool {
        if self.character.is_none() {
            return false;
        }
        let painter = ui.painter_at(paper.view_rect);
        for (i, path) in self.paths.iter().enumerate() {
            let color = if Some(i) == self.selected {
                SELECTED
            } else {
                OTHER
            };
            let pts: Vec<Pos2> = path
                .iter()
                .map(|p| paper.mm_to_screen(p[0], p[1]))
                .collect();
            painter.add(egui::Shape::line(
                pts,
                Line::new(1.0, color.gamma_multiply(0.8)),
            ));
        }
        let mut keys = Vec::new();
        if let Some(f) = &self.file {
            for i in 0..f.stroke.len() {
                for k in 0..f.stroke[i].keys.len() {
                    if let Some((_, p)) = self.key(i, k) {
                        let s = paper.mm_to_screen(p[0], p[1]);
                        keys.push((i, k, s));
                        let color = if Some(i) == self.selected {
                            SELECTED
                        } else {
                            OTHER
                        };
                        painter.circle_stroke(s, 3.5, Line::new(1.5, color));
                    }
                }
            }
        }
        let moving = match guide_anchor {
            Some(a) => Some([a[0], a[1]]),
            None => self.character.as_ref().map(|c| {
                let p = c.pose_at(self.playhead).0;
                [p[0], p[1]]
            }),
        };
        if let Some(m) = moving {
            let s = paper.mm_to_screen(m[0], m[1]);
            painter.circle_stroke(s, 7.0, Line::new(2.0, Color32::from_rgb(240, 200, 60)));
        }
        if !self.edit_on_paper {
            return false;
        }
        let screen = pointer_mm.map(|m| paper.mm_to_screen(m[0], m[1]));
        match (self.drag, pressed, pointer_mm, screen) {
            (None, true, Some(_), Some(s)) => {
                self.drag = keys
                    .iter()
                    .filter(|(_, _, q)| q.distance(s) < 8.0)
                    .min_by(|a, b| a.2.distance(s).total_cmp(&b.2.distance(s)))
                    .map(|&(i, k, _)| Drag::Place(i, k));
                if let Some(Drag::Place(i, _)) = self.drag {
                    self.selected = Some(i);
                }
            }
            (Some(Drag::Place(i, k)), true, Some(m), _)
                if self
                    .key(i, k)
                    .is_some_and(|(_, p)| (p[0] - m[0]).hypot(p[1] - m[1]) > 1e-3) =>
            {
                self.move_key(i, k, m);
            }
            (Some(Drag::Place(..)), false, _, _) => self.drag = None,
            _ => {}
        }
        true
    }
}

/// Times written out to the millisecond (the tick), so a saved file stays readable.
fn round_ms(t: f64) -> f64 {
    (t * 1e3).round() / 1e3
}
