//! Practice: copying a master's character (docs/practice.md). The writer picks a character;
//! the paper shows the master's strokes as faint red outlines under the writing (描紅) or
//! beside it (臨摹); "Watch" has the device write it, "Guide me" leads the hand along it;
//! "Write" records the writer's attempt from the device's frames (any device: the mouse, a
//! tablet, the built-in pen, a pen over serial, the Phantom) and "Score" scores it
//! (`crate::score`), draws each master stroke in the colour of its score, lists the figures
//! and plots the character's totals over attempts (the history file).
//!
//! The master is made and the attempt scored on threads of their own (a second or two of
//! brush simulation): the window keeps drawing, and a later frame picks up the result.

use crate::hanzi;
use crate::poses::{PoseRow, PoseTrack};
use crate::score::{self, Master, Report};
use egui::{Color32, RichText, Stroke};
use maobi_shared::{BrushParams, Pose};
use std::sync::mpsc::{channel, Receiver, TryRecvError};
use std::sync::Arc;

use super::canvas::PaperView;

/// The master's size on the paper (mm square, centred on the paper's origin).
pub const SIZE_MM: f64 = 80.0;

/// How far to the right of the writing the master is drawn in 臨摹 (mm).
pub const BESIDE_MM: f64 = SIZE_MM + 10.0;

/// Where the master's outlines are drawn.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub enum ModelView {
    /// 描紅: under the writing, to trace.
    Trace,
    /// 臨摹: beside it, to copy.
    Beside,
    Hidden,
}

impl ModelView {
    pub const ALL: [ModelView; 3] = [ModelView::Trace, ModelView::Beside, ModelView::Hidden];
    pub fn label(self) -> &'static str {
        match self {
            ModelView::Trace => "描紅 trace",
            ModelView::Beside => "臨摹 beside",
            ModelView::Hidden => "hidden",
        }
    }
}

/// What the panel asks the app to do with the device.
#[derive(Debug)]
pub enum PracticeAction {
    /// Replay the master's writing.
    Watch(Arc<PoseTrack>),
    /// Lead the hand along the master's writing.
    Guide(Arc<PoseTrack>),
    StopGuide,
    /// Keep the hand within this many millimetres of the master's path (a virtual fixture).
    Lane(Arc<PoseTrack>, f64),
    StopLane,
    /// Clear the paper for a new attempt.
    Clear,
}

/// The practice panel's state.
pub struct Practice {
    pub open: bool,
    /// The character field.
    pub input: String,
    pub view: ModelView,
    /// "Stay in the lane": on, and the tube's radius (mm).
    pub lane_on: bool,
    pub lane_mm: f64,
    master: Option<Arc<Master>>,
    /// The master's outlines flattened to polylines (mm), each stroke's rings: flattened once
    /// when the master arrives, drawn every frame.
    rings: Vec<Vec<Vec<[f64; 2]>>>,
    loading: Option<(String, Receiver<anyhow::Result<Master>>)>,
    /// The attempt's frames while "Write" is on: (tick, hand pose).
    writing: Option<Vec<(u64, Pose<f64>)>>,
    /// The last attempt, kept for "Score".
    attempt: Vec<(u64, Pose<f64>)>,
    scoring: Option<Receiver<anyhow::Result<Report>>>,
    pub report: Option<Report>,
    /// The character's totals over attempts, oldest first (from the history file).
    history: Vec<f64>,
    pub message: Option<(String, bool)>,
    /// Where the Write and Score buttons were last drawn (for [`Practice::layout`]).
    write_rect: egui::Rect,
    score_rect: egui::Rect,
}

impl Default for Practice {
    fn default() -> Self {
        Practice {
            open: false,
            input: "永".into(),
            view: ModelView::Trace,
            lane_on: false,
            lane_mm: 2.0,
            master: None,
            rings: Vec::new(),
            loading: None,
            writing: None,
            attempt: Vec::new(),
            scoring: None,
            report: None,
            history: Vec::new(),
            message: None,
            write_rect: egui::Rect::NOTHING,
            score_rect: egui::Rect::NOTHING,
        }
    }
}

impl Practice {
    /// The master loaded, if one is.
    pub fn master(&self) -> Option<&Master> {
        self.master.as_deref()
    }

    /// The panel's lines of the app's layout file (`gui::app::Automation::layout`), for a
    /// program driving the window: its state (`practice none`, `loading`, `ready`, `writing`
    /// or `scored TOTAL ORDER MATCHED`, the last two the order figure's score and the master
    /// strokes matched) and the Write and Score buttons' rectangles (`r` formats one).
    pub fn layout(&self, r: impl Fn(egui::Rect) -> String) -> String {
        let state = if self.loading.is_some() || self.scoring.is_some() {
            "loading".to_string()
        } else if self.writing.is_some() {
            "writing".to_string()
        } else if let Some(rep) = &self.report {
            format!(
                "scored {:.4} {:.4} {}",
                rep.total,
                rep.figure("order").map_or(0.0, |f| f.score),
                rep.strokes.iter().filter(|s| s.written.is_some()).count()
            )
        } else if self.master.is_some() {
            "ready".to_string()
        } else {
            "none".to_string()
        };
        format!(
            "practice {state}\npractice_write {}\npractice_score {}\n",
            r(self.write_rect),
            r(self.score_rect)
        )
    }

    /// Whether a master is being made or an attempt scored.
    pub fn busy(&self) -> bool {
        self.loading.is_some() || self.scoring.is_some()
    }

    pub fn is_writing(&self) -> bool {
        self.writing.is_some()
    }

    /// Makes the master for `ch` with the brush `params` (preset `brush`), on a thread.
    pub fn load(&mut self, ch: &str, brush: &str, params: BrushParams) {
        let (tx, rx) = channel();
        let (c, b) = (ch.to_string(), brush.to_string());
        std::thread::spawn(move || {
            let made = hanzi::load(&c)
                .map_err(anyhow::Error::from)
                .and_then(|h| Master::new(h, &b, params, SIZE_MM));
            let _ = tx.send(made);
        });
        self.loading = Some((ch.to_string(), rx));
        self.report = None;
        self.message = Some((format!("writing the master's {ch}..."), false));
    }

    /// Starts recording an attempt.
    pub fn start_writing(&mut self) {
        self.writing = Some(Vec::new());
        self.report = None;
    }

    /// Stops recording; the attempt is kept for [`Practice::score`].
    pub fn stop_writing(&mut self) {
        if let Some(w) = self.writing.take() {
            self.attempt = w;
        }
    }

    /// A device frame's tick and hand pose, recorded while writing.
    pub fn frame(&mut self, tick: u64, pose: Pose<f64>) {
        if let Some(w) = &mut self.writing {
            if w.last().is_none_or(|(t, _)| *t < tick) {
                w.push((tick, pose));
            }
        }
    }

    /// Scores the last attempt against the master, on a thread; appends it to the history.
    pub fn score(&mut self) {
        self.stop_writing();
        let Some(master) = self.master.clone() else {
            self.message = Some(("load a character first".into(), true));
            return;
        };
        let track = match attempt_track(&self.attempt) {
            Ok(t) => t,
            Err(e) => {
                self.message = Some((e.to_string(), true));
                return;
            }
        };
        let (tx, rx) = channel();
        std::thread::spawn(move || {
            let _ = tx.send(master.score(&track));
        });
        self.scoring = Some(rx);
        self.message = Some(("scoring...".into(), false));
    }

    /// Picks up a master made or a score computed since the last frame.
    pub fn poll(&mut self) {
        if let Some((ch, rx)) = &self.loading {
            if let Some(made) = finished(rx) {
                let ch = ch.clone();
                self.loading = None;
                match made {
                    Ok(m) => {
                        self.message = Some((
                            format!(
                                "{}: {} strokes, from {}",
                                m.hanzi.ch,
                                m.outlines().len(),
                                m.hanzi.source
                            ),
                            false,
                        ));
                        self.history = read_history(&m.hanzi.ch.to_string());
                        self.rings = m
                            .outlines()
                            .iter()
                            .map(|s| outline_rings(&s.outline))
                            .collect();
                        self.master = Some(Arc::new(m));
                    }
                    Err(e) => self.message = Some((format!("{ch}: {e:#}"), true)),
                }
            }
        }
        if let Some(rx) = &self.scoring {
            if let Some(scored) = finished(rx) {
                self.scoring = None;
                match scored {
                    Ok(r) => {
                        let appended = score::history_path()
                            .and_then(|p| score::append_history(&p, &r, "the app").map(|()| p));
                        self.message = Some(match appended {
                            Ok(p) => (
                                format!("total {:.2}; appended to {}", r.total, p.display()),
                                false,
                            ),
                            Err(e) => {
                                (format!("total {:.2}; history not kept: {e}", r.total), true)
                            }
                        });
                        self.history = read_history(&r.character);
                        self.report = Some(r);
                    }
                    Err(e) => self.message = Some((format!("{e:#}"), true)),
                }
            }
        }
    }

    /// The panel: character, view, Watch / Guide me / Write / Score, the report and the
    /// history's plot. `brush` and `params` are the device's brush (the master's).
    pub fn ui(
        &mut self,
        ui: &mut egui::Ui,
        brush: &str,
        params: BrushParams,
        guiding: bool,
    ) -> Option<PracticeAction> {
        let mut action = None;
        ui.heading("Practice");
        ui.horizontal(|ui| {
            let label = ui.label("character");
            let field = ui
                .add(egui::TextEdit::singleline(&mut self.input).desired_width(40.0))
                .labelled_by(label.id);
            let enter = field.lost_focus() && ui.input(|i| i.key_pressed(egui::Key::Enter));
            if (ui
                .add_enabled(!self.busy(), egui::Button::new("Load"))
                .on_hover_text("The master's character in its stroke order, written by this brush")
                .clicked()
                || enter)
                && !self.busy()
            {
                let ch = self.input.trim().to_string();
                self.load(&ch, brush, params);
            }
        });
        egui::ComboBox::from_label("master")
            .selected_text(self.view.label())
            .show_ui(ui, |ui| {
                for v in ModelView::ALL {
                    ui.selectable_value(&mut self.view, v, v.label());
                }
            });
        let ready = self.master.is_some() && !self.busy();
        ui.horizontal_wrapped(|ui| {
            if ui
                .add_enabled(ready, egui::Button::new("Watch"))
                .on_hover_text("The device writes the master's character")
                .clicked()
            {
                if let Some(m) = &self.master {
                    action = Some(PracticeAction::Watch(Arc::new(m.track().clone())));
                }
            }
            if guiding {
                if ui.button("Stop guiding").clicked() {
                    action = Some(PracticeAction::StopGuide);
                }
            } else if ui
                .add_enabled(ready, egui::Button::new("Guide me"))
                .on_hover_text("The pen leads your hand along the master's strokes")
                .clicked()
            {
                if let Some(m) = &self.master {
                    action = Some(PracticeAction::Guide(Arc::new(m.track().clone())));
                }
            }
            if self.lane_on {
                if ui.button("Leave the lane").clicked() {
                    self.lane_on = false;
                    action = Some(PracticeAction::StopLane);
                }
            } else if ui
                .add_enabled(ready, egui::Button::new("Stay in the lane"))
                .on_hover_text(
                    "No force while the pen is within the lane around the master's strokes; \
                     a spring back toward them outside",
                )
                .clicked()
            {
                if let Some(m) = &self.master {
                    self.lane_on = true;
                    action = Some(PracticeAction::Lane(
                        Arc::new(m.track().clone()),
                        self.lane_mm,
                    ));
                }
            }
            let lane = ui.label("lane mm");
            ui.add(
                egui::DragValue::new(&mut self.lane_mm)
                    .range(crate::device::api::LANE_RADIUS_MM)
                    .speed(0.1),
            )
            .labelled_by(lane.id);
            if self.writing.is_some() {
                let stop = ui.button("Stop writing");
                self.write_rect = stop.rect;
                if stop.clicked() {
                    self.stop_writing();
                }
            } else {
                let write = ui
                    .add_enabled(ready, egui::Button::new("Write"))
                    .on_hover_text("Clears the paper and records your attempt");
                self.write_rect = write.rect;
                if write.clicked() {
                    action = Some(PracticeAction::Clear);
                    self.start_writing();
                }
            }
            let score = ui
                .add_enabled(
                    ready && (self.writing.is_some() || !self.attempt.is_empty()),
                    egui::Button::new("Score"),
                )
                .on_hover_text("Your attempt against the master's, figure by figure");
            self.score_rect = score.rect;
            if score.clicked() {
                self.score();
            }
        });
        if self.writing.is_some() {
            ui.label(RichText::new("recording your attempt").color(Color32::from_rgb(200, 40, 30)));
        }
        super::message::label(ui, &self.message);
        if let Some(r) = &self.report {
            ui.separator();
            report_ui(ui, r);
        }
        if self.history.len() >= 2 {
            ui.separator();
            ui.label(format!("{} attempts: total by attempt", self.history.len()));
            let points: Vec<[f64; 2]> = self
                .history
                .iter()
                .enumerate()
                .map(|(i, t)| [i as f64 + 1.0, *t])
                .collect();
            egui_plot::Plot::new("practice history")
                .height(120.0)
                .include_y(0.0)
                .include_y(1.0)
                .allow_scroll(false)
                .show(ui, |p| p.line(egui_plot::Line::new("total", points)));
        }
        action
    }
}

/// The result a thread sent on `rx`, once it has (`None` while it runs).
fn finished<T>(rx: &Receiver<anyhow::Result<T>>) -> Option<anyhow::Result<T>> {
    match rx.try_recv() {
        Ok(r) => Some(r),
        Err(TryRecvError::Empty) => None,
        Err(TryRecvError::Disconnected) => {
            Some(Err(anyhow::anyhow!("its thread ended without an answer")))
        }
    }
}

/// The report's figures and strokes.
fn report_ui(ui: &mut egui::Ui, r: &Report) {
    ui.label(RichText::new(format!("{}: total {:.2}", r.character, r.total)).strong());
    egui::Grid::new("practice figures")
        .striped(true)
        .show(ui, |ui| {
            for f in &r.figures {
                ui.label(f.name).on_hover_text(f.meaning);
                ui.label(RichText::new(format!("{:.2}", f.score)).color(score_color(f.score)));
                ui.label(format!("{:.2} {}", f.value, f.unit));
                ui.end_row();
            }
        });
    for s in &r.strokes {
        let text = match s.written {
            None => format!("{} {}: missing", s.stroke, s.name),
            Some(_) => {
                let mut t = format!("{} {}: {:.2}", s.stroke, s.name, s.score);
                if !s.in_order {
                    t += ", out of order";
                }
                if s.backwards {
                    t += ", backwards";
                }
                t
            }
        };
        ui.label(RichText::new(text).color(score_color(s.score)));
    }
    if !r.extra.is_empty() {
        ui.label(format!("{} extra stroke(s)", r.extra.len()));
    }
    profile_plot(ui, r, "press (mm) along each stroke", |s| {
        (&s.press_mm, &s.master_press_mm)
    });
    profile_plot(ui, r, "speed (mm/s) along each stroke", |s| {
        (&s.speed_mm_s, &s.master_speed_mm_s)
    });
}

/// A profile along every written stroke against the master's, the strokes side by side
/// (stroke k from k - 1 to k on the x axis).
fn profile_plot(
    ui: &mut egui::Ui,
    r: &Report,
    title: &str,
    series: impl Fn(&score::StrokeReport) -> (&Vec<f64>, &Vec<f64>),
) {
    ui.label(title);
    let line = |k: usize, v: &[f64]| -> Vec<[f64; 2]> {
        let n = v.len().max(2) - 1;
        v.iter()
            .enumerate()
            .map(|(i, y)| [k as f64 + i as f64 / n as f64, *y])
            .collect()
    };
    egui_plot::Plot::new(title)
        .height(90.0)
        .allow_scroll(false)
        .allow_drag(false)
        .show(ui, |p| {
            for (k, s) in r.strokes.iter().enumerate() {
                let (written, master) = series(s);
                p.line(
                    egui_plot::Line::new("master", line(k, master))
                        .color(Color32::from_rgb(200, 60, 40)),
                );
                p.line(
                    egui_plot::Line::new("attempt", line(k, written))
                        .color(Color32::from_rgb(90, 150, 230)),
                );
            }
        });
}

/// A score's colour: red at 0, amber at 0.5, green at 1.
pub fn score_color(s: f64) -> Color32 {
    let s = s.clamp(0.0, 1.0) as f32;
    let (r, g) = if s < 0.5 {
        (1.0, s * 2.0)
    } else {
        (2.0 - s * 2.0, 1.0)
    };
    Color32::from_rgb((r * 210.0) as u8, (g * 170.0) as u8, 40)
}

/// Draws the master's outlines over the paper: faint red before a score, each stroke in the
/// colour of its score after one.
pub fn draw(painter: &egui::Painter, paper: &PaperView, practice: &Practice) {
    if practice.master.is_none() {
        return;
    }
    let dx = match practice.view {
        ModelView::Hidden => return,
        ModelView::Trace => 0.0,
        ModelView::Beside => BESIDE_MM,
    };
    for (k, rings) in practice.rings.iter().enumerate() {
        let color = match &practice.report {
            Some(r) => score_color(r.strokes.get(k).map_or(0.0, |s| s.score)),
            None => Color32::from_rgba_unmultiplied(200, 40, 30, 140),
        };
        for ring in rings {
            let pts: Vec<egui::Pos2> = ring
                .iter()
                .map(|p| paper.mm_to_screen(p[0] + dx, p[1]))
                .collect();
            painter.add(egui::Shape::closed_line(pts, Stroke::new(1.5, color)));
        }
    }
}

/// An outline's closed rings as polylines (mm).
fn outline_rings(outline: &kurbo::BezPath) -> Vec<Vec<[f64; 2]>> {
    let mut rings: Vec<Vec<[f64; 2]>> = Vec::new();
    kurbo::flatten(outline.elements().iter().copied(), 0.05, |el| match el {
        kurbo::PathEl::MoveTo(p) => rings.push(vec![[p.x, p.y]]),
        kurbo::PathEl::LineTo(p) => {
            if let Some(r) = rings.last_mut() {
                r.push([p.x, p.y]);
            }
        }
        _ => {}
    });
    rings
}

/// An attempt's frames as a pose track on the model's tick.
fn attempt_track(frames: &[(u64, Pose<f64>)]) -> anyhow::Result<PoseTrack> {
    if frames.len() < 2 {
        anyhow::bail!("nothing was written: press Write, write the character, then Score");
    }
    let t0 = frames[0].0;
    let rows: Vec<PoseRow> = frames
        .iter()
        .map(|(t, p)| PoseRow {
            t: (t - t0) as f64 * crate::poses::TICK_S,
            pos: p.pos.to_f64(),
            rot: [p.rot.w, p.rot.x, p.rot.y, p.rot.z],
        })
        .collect();
    let csv = crate::strokes::rows_to_csv(&rows);
    PoseTrack::from_reader("the attempt", csv.as_bytes()).map_err(|e| anyhow::anyhow!("{e}"))
}

/// The totals of `ch`'s attempts in the history file, oldest first (none if it cannot be
/// read).
fn read_history(ch: &str) -> Vec<f64> {
    let Ok(path) = score::history_path() else {
        return Vec::new();
    };
    let Ok(mut rd) = csv::Reader::from_path(&path) else {
        return Vec::new();
    };
    rd.records()
        .flatten()
        .filter(|r| r.get(1) == Some(ch))
        .filter_map(|r| r.get(3).and_then(|t| t.parse().ok()))
        .collect()
}
