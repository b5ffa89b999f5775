//! The paper: ink per pixel ([`Canvas`]) inked tick by tick from the device's frames
//! ([`Inker`]), stepped with them (raw paper spreads live), shown as a texture over a paper
//! tone, with zoom, pan, per-stroke undo and clear.
//!
//! Only the region the last frames inked or the paper's steps changed is re-uploaded
//! ([`TextureHandle::set_partial`]).

use egui::{
    Color32, ColorImage, Pos2, Rect, Response, Sense, Stroke, TextureHandle, TextureOptions, Vec2,
};

use crate::paper::{darkness, Canvas, PaperSpec};
use crate::raster::Frame;
use crate::render::Inker;

use crate::device::BrushFrame;

/// Most strokes undo remembers (each is a full canvas copy).
pub const UNDO_DEPTH: usize = 8;

const INK: [f32; 3] = [18.0, 16.0, 20.0];

/// What the pointer does over the paper this frame.
#[derive(Copy, Clone, Debug, Default)]
pub struct PaperPointer {
    /// Paper position under the pointer (mm), if it is over the paper view.
    pub mm: Option<[f64; 2]>,
    /// The primary button is held (the pen is pressed) over the view.
    pub pressed: bool,
}

pub struct PaperView {
    canvas: Canvas,
    frame: Frame,
    inker: Inker,
    /// Paper tone per pixel (0-255 grey, warm-tinted when shown).
    tone: Vec<u8>,
    texture: Option<TextureHandle>,
    /// Pixel region `[x0, y0, x1, y1)` changed since the last upload.
    dirty: Option<[usize; 4]>,
    full_upload: bool,
    /// The canvas before each remembered stroke, oldest first.
    undo: Vec<Canvas>,
    /// The canvas as it was when the last stroke ended (the "before" of the next one).
    settled: Canvas,
    in_stroke: bool,
    strokes: usize,
    /// Screen pixels per canvas pixel; 0 until fitted to the view.
    zoom: f32,
    /// Canvas pixel shown at the view's centre.
    center: Vec2,
    /// Pixels uploaded in the last frame (for the status line).
    pub uploaded_px: usize,
    /// Screen rectangle of the view in the last frame.
    pub view_rect: Rect,
}

impl PaperView {
    /// A blank paper of `spec` mapped by `frame`.
    pub fn new(frame: Frame, spec: PaperSpec) -> PaperView {
        let (w, h) = (frame.width, frame.height);
        let canvas = Canvas::with_paper(w, h, spec);
        PaperView {
            settled: canvas.clone(),
            canvas,
            frame,
            inker: Inker::new(frame, maobi_shared::params::MAX_LAYERS),
            tone: paper_tone(w, h),
            texture: None,
            dirty: None,
            full_upload: true,
            undo: Vec::new(),
            in_stroke: false,
            strokes: 0,
            zoom: 0.0,
            center: Vec2::new(w as f32 / 2.0, h as f32 / 2.0),
            uploaded_px: 0,
            view_rect: Rect::NOTHING,
        }
    }

    pub fn canvas(&self) -> &Canvas {
        &self.canvas
    }
    pub fn frame(&self) -> &Frame {
        &self.frame
    }
    /// The paper's kind and fibres.
    pub fn paper(&self) -> PaperSpec {
        self.canvas.paper()
    }

    /// A fresh sheet of `spec`: blank, with nothing to undo.
    pub fn set_paper(&mut self, spec: PaperSpec) {
        self.canvas = Canvas::with_paper(self.frame.width, self.frame.height, spec);
        self.settled = self.canvas.dry_copy();
        self.undo.clear();
        self.in_stroke = false;
        self.full_upload = true;
    }
    /// Strokes that can be undone.
    pub fn undo_depth(&self) -> usize {
        self.undo.len()
    }
    /// Strokes inked since start.
    pub fn strokes(&self) -> usize {
        self.strokes
    }
    pub fn in_stroke(&self) -> bool {
        self.in_stroke
    }

    /// Inks one device frame, and lets the paper take its step when one is due. A stroke
    /// begins with the first frame that touches the paper and ends with the first that does
    /// not.
    pub fn ink(&mut self, f: &BrushFrame) {
        let touched = self
            .inker
            .stamp_geometry_at(&f.geometry(), f.tick, &mut self.canvas);
        if let Some(r) = self.canvas.tick() {
            self.mark_dirty([r[0] as f64, r[1] as f64, r[2] as f64, r[3] as f64]);
        }
        if touched {
            if let Some(b) = self.inker.last_bounds() {
                self.mark_dirty(b);
            }
            if !self.in_stroke {
                self.in_stroke = true;
                self.strokes += 1;
                let before = std::mem::replace(&mut self.settled, Canvas::new(0, 0));
                self.push_undo(before);
            }
        } else if self.in_stroke {
            self.in_stroke = false;
            // Undo brings the paper back with its ink dry: the snapshot leaves out raw
            // paper's water, which would double its cost at every stroke's end.
            self.settled = self.canvas.dry_copy();
        }
    }

    fn push_undo(&mut self, c: Canvas) {
        if self.undo.len() == UNDO_DEPTH {
            self.undo.remove(0);
        }
        self.undo.push(c);
    }

    fn mark_dirty(&mut self, b: [f64; 4]) {
        let (w, h) = (self.frame.width, self.frame.height);
        let x0 = (b[0].floor() - 1.0).clamp(0.0, w as f64) as usize;
        let y0 = (b[1].floor() - 1.0).clamp(0.0, h as f64) as usize;
        let x1 = (b[2].ceil() + 1.0).clamp(0.0, w as f64) as usize;
        let y1 = (b[3].ceil() + 1.0).clamp(0.0, h as f64) as usize;
        if x0 >= x1 || y0 >= y1 {
            return;
        }
        self.dirty = Some(match self.dirty {
            Some(d) => [d[0].min(x0), d[1].min(y0), d[2].max(x1), d[3].max(y1)],
            None => [x0, y0, x1, y1],
        });
    }

    /// Takes back the last stroke (or the last clear). Returns whether there was one.
    pub fn undo(&mut self) -> bool {
        match self.undo.pop() {
            Some(c) => {
                self.canvas = c;
                self.settled = self.canvas.dry_copy();
                self.in_stroke = false;
                self.full_upload = true;
                true
            }
            None => false,
        }
    }

    /// Blank paper; undoable.
    pub fn clear(&mut self) {
        let blank = self.canvas.blank_like();
        let old = std::mem::replace(&mut self.canvas, blank);
        self.push_undo(old);
        self.settled = self.canvas.dry_copy();
        self.in_stroke = false;
        self.full_upload = true;
    }

    fn pixel(&self, i: usize) -> Color32 {
        let c = darkness(self.canvas.ink()[i]);
        let t = self.tone[i] as f32;
        let paper = [t, t * 0.975, t * 0.91];
        let mix = |k: usize| (paper[k] + (INK[k] - paper[k]) * c) as u8;
        Color32::from_rgb(mix(0), mix(1), mix(2))
    }

    fn image(&self, r: [usize; 4]) -> ColorImage {
        let (w, h) = (r[2] - r[0], r[3] - r[1]);
        let mut px = Vec::with_capacity(w * h);
        for y in r[1]..r[3] {
            let row = y * self.frame.width;
            px.extend((r[0]..r[2]).map(|x| self.pixel(row + x)));
        }
        ColorImage::new([w, h], px)
    }

    /// Sends what changed to the GPU: everything on the first call and after undo or clear,
    /// otherwise only the dirty region.
    pub fn upload(&mut self, ctx: &egui::Context) {
        self.uploaded_px = 0;
        let opts = TextureOptions::LINEAR;
        let (w, h) = (self.frame.width, self.frame.height);
        if self.texture.is_none() || self.full_upload {
            let img = self.image([0, 0, w, h]);
            match &mut self.texture {
                Some(t) => t.set(img, opts),
                None => self.texture = Some(ctx.load_texture("maobi-paper", img, opts)),
            }
            self.uploaded_px = w * h;
            self.full_upload = false;
            self.dirty = None;
        } else if let Some(d) = self.dirty.take() {
            let img = self.image(d);
            self.uploaded_px = img.pixels.len();
            if let Some(t) = &mut self.texture {
                t.set_partial([d[0], d[1]], img, opts);
            }
        }
    }

    fn to_screen(&self, rect: Rect, px: Vec2) -> Pos2 {
        rect.center() + (px - self.center) * self.zoom
    }
    fn to_canvas_px(&self, rect: Rect, p: Pos2) -> Vec2 {
        (p - rect.center()) / self.zoom + self.center
    }

    /// Fits the whole paper into the view.
    pub fn fit(&mut self) {
        self.zoom = 0.0;
    }
    /// One canvas pixel per screen pixel.
    pub fn actual_size(&mut self, ctx: &egui::Context) {
        self.zoom = 1.0 / ctx.pixels_per_point();
    }

    /// The sheet's rectangle on screen in the last frame (the paper itself, within
    /// [`Self::view_rect`]; larger than it when zoomed in).
    pub fn sheet_rect(&self) -> Rect {
        let (w, h) = (self.frame.width as f32, self.frame.height as f32);
        Rect::from_min_max(
            self.to_screen(self.view_rect, Vec2::ZERO),
            self.to_screen(self.view_rect, Vec2::new(w, h)),
        )
    }

    /// Paper mm to screen.
    pub fn mm_to_screen(&self, x: f64, y: f64) -> Pos2 {
        let p = self.frame.to_px(x, y);
        self.to_screen(self.view_rect, Vec2::new(p[0] as f32, p[1] as f32))
    }

    /// Draws the paper into all of `ui`'s space and handles zoom (ctrl + wheel or pinch) and
    /// pan (drag with the right or middle button).
    pub fn show(&mut self, ui: &mut egui::Ui) -> (Response, PaperPointer) {
        self.upload(ui.ctx());
        let size = ui.available_size();
        let (rect, resp) = ui.allocate_exact_size(size, Sense::click_and_drag());
        self.view_rect = rect;
        let (w, h) = (self.frame.width as f32, self.frame.height as f32);
        if self.zoom <= 0.0 {
            self.zoom = (rect.width() / w).min(rect.height() / h).max(1e-3);
            self.center = Vec2::new(w / 2.0, h / 2.0);
        }
        if resp.hovered() {
            let zoom = ui.input(|i| i.zoom_delta());
            if zoom != 1.0 {
                if let Some(p) = resp.hover_pos() {
                    let at = self.to_canvas_px(rect, p);
                    self.zoom = (self.zoom * zoom).clamp(0.02, 32.0);
                    // Keep the canvas point under the pointer in place.
                    self.center = at - (p - rect.center()) / self.zoom;
                }
            }
        }
        if resp.dragged_by(egui::PointerButton::Secondary)
            || resp.dragged_by(egui::PointerButton::Middle)
        {
            self.center -= resp.drag_delta() / self.zoom;
        }
        let painter = ui.painter_at(rect);
        painter.rect_filled(rect, 0.0, Color32::from_gray(60));
        if let Some(t) = &self.texture {
            let r = Rect::from_min_max(
                self.to_screen(rect, Vec2::ZERO),
                self.to_screen(rect, Vec2::new(w, h)),
            );
            painter.image(
                t.id(),
                r,
                Rect::from_min_max(Pos2::ZERO, Pos2::new(1.0, 1.0)),
                Color32::WHITE,
            );
            painter.rect_stroke(
                r,
                0.0,
                Stroke::new(1.0, Color32::from_gray(30)),
                egui::StrokeKind::Outside,
            );
        }
        let mut ptr = PaperPointer::default();
        if let Some(p) = resp.hover_pos() {
            let c = self.to_canvas_px(rect, p);
            let f = &self.frame;
            ptr.mm = Some([
                f.x0_mm + c.x as f64 / f.px_per_mm,
                f.y_top_mm - c.y as f64 / f.px_per_mm,
            ]);
            ptr.pressed = ui.input(|i| i.pointer.primary_down());
        }
        (resp, ptr)
    }
}

/// A faint paper grain: value noise from a hash of the pixel, plus longer fibres.
fn paper_tone(w: usize, h: usize) -> Vec<u8> {
    fn hash(x: u32, y: u32) -> u32 {
        let mut v = x.wrapping_mul(0x9E37_79B1) ^ y.wrapping_mul(0x85EB_CA77);
        v ^= v >> 15;
        v = v.wrapping_mul(0x2C1B_3C6D);
        v ^= v >> 12;
        v
    }
    let mut out = Vec::with_capacity(w * h);
    for y in 0..h as u32 {
        for x in 0..w as u32 {
            let fine = (hash(x, y) & 7) as i32;
            let fibre = (hash(x / 9, y / 2) & 7) as i32;
            out.push((238 + fine / 2 + fibre / 2 - 4) as u8);
        }
    }
    out
}
