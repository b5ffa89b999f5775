//! Rendering a simulated stroke to a PNG: the footprint of every tick inked onto paper.
//!
//! The brush model decides how much ink each layer gives each tick (`maobi_shared::brush::ink`);
//! this module decides where it lands. At 500 mm/s the brush moves 0.5 mm per tick (5 px at
//! 10 px/mm), so stamping each tick's footprint alone would leave gaps, and stamping the area
//! it swept would sum to a tone that steps with the ticks (scallops). So ([`Inker`]) each
//! band's footprint is stamped at positions a pixel or less apart along its way since the
//! previous tick, each laying an equal part of the ink its layers gave, over the band's
//! hair strips that ink (dry-brush streaks). The ink lands on the paper ([`crate::paper`]),
//! which takes a step every few ticks.

use std::io::Write;
use std::path::Path;
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use maobi_shared::footprint::Geometry;
use maobi_shared::{Brush, BrushParams, Scalar};

use crate::offline::simulate;
use crate::paper::{Canvas, PaperSpec};
use crate::poses::PoseTrack;
use crate::raster::{raster_area, Frame, Stamper};
use maobi_shared::baxter_lin::{self, brush::BaxterLinBrush, SpineParamError};
use maobi_shared::Pose;

/// Paper margin beyond the ferrule's extent, on top of the brush length (mm).
pub const EXTRA_MARGIN_MM: f64 = 10.0;

/// Largest image `render` makes (pixels), so a typo in `--px-per-mm` fails clearly instead of
/// exhausting memory.
pub const MAX_PIXELS: usize = 100_000_000;

/// Statistics of one render.
#[derive(Clone, Debug)]
pub struct RenderStats {
    pub ticks: usize,
    /// Stamps with a non-empty footprint.
    pub stamps: usize,
    pub width: usize,
    pub height: usize,
    /// Inked fraction of the image in [0, 1].
    pub ink_fraction: f64,
    /// Wall-clock time spent computing footprints and stamping them (s); for the summary
    /// only, it never reaches the image.
    pub stamp_seconds: f64,
    /// Wall-clock time the paper's steps took (s), for the summary only.
    pub paper_seconds: f64,
    /// Paper steps after the last tick until the paper was dry.
    pub drying_steps: usize,
}

/// The paper for `track`: the ferrule's x-y extent plus the brush length and
/// [`EXTRA_MARGIN_MM`] on every side.
pub fn paper_frame(
    track: &PoseTrack,
    params: &BrushParams,
    px_per_mm: f64,
) -> anyhow::Result<Frame> {
    if !(px_per_mm.is_finite() && px_per_mm > 0.0) {
        bail!("--px-per-mm must be a positive number, not {px_per_mm}");
    }
    let (lo, hi) = track.xy_bounds();
    let margin = params.length_mm as f64 + EXTRA_MARGIN_MM;
    let frame = Frame::covering(lo, hi, margin, px_per_mm);
    let pixels = frame.width as f64 * frame.height as f64;
    if pixels > MAX_PIXELS as f64 {
        bail!(
            "the image would be {} x {} px, more than {MAX_PIXELS} pixels: use a smaller --px-per-mm",
            frame.width,
            frame.height
        );
    }
    Ok(frame)
}

/// Longest step (pixels) between two positions of a band's footprint stamped within one
/// tick: ink is laid down along the band's path by stamping its footprint at positions this
/// close, so overlapping stamps sum to a tone that does not depend on where the ticks fell
/// (no periodic scallops at the tick spacing).
pub const MAX_STEP_PX: f64 = 1.0;

/// Hair strips across each band of the footprint (Baxter & Lin's bristle strips, 4.2): each
/// strip is a bundle of hairs with its own share of the band's ink and its own readiness to
/// give it, so a dry or fast brush leaves streaks (飛白).
pub const HAIR_STRIPS: usize = 16;

/// A band's hairs all ink while `DRY_GAIN x W - speed / DRY_SPEED_MM_S` is at least one (W
/// its wetness, the speed its footprint's, mm/s); below that only the strips whose seeded
/// readiness is under it do: a slow stroke with a loaded brush is full, a fast flick or a dry
/// brush splits into streaks. At the presets' dip (W = 0.6) every hair inks up to 560 mm/s.
pub const DRY_GAIN: f64 = 2.5;
/// See [`DRY_GAIN`].
pub const DRY_SPEED_MM_S: f64 = 700.0;

/// Seed of the hair strips' readiness and share: fixed, so renders are the same bits run to
/// run and the same brush streaks the same way.
const HAIR_SEED: u64 = 0x6d61_6f62_6900_0023;

/// A number in [0, 1) from `key`, the same on every run (SplitMix64's finaliser).
fn seeded_unit(key: u64) -> f64 {
    let mut z = key
        .wrapping_add(HAIR_SEED)
        .wrapping_mul(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^= z >> 31;
    (z >> 11) as f64 / (1u64 << 53) as f64
}

/// Strip `j` of band `band`: how ready its hairs are to ink (lower inks sooner, in [0, 1))
/// and its share of the band's ink relative to its area (in [0.6, 1.4)).
fn hair(band: usize, j: usize) -> (f64, f64) {
    let key = (band * HAIR_STRIPS + j) as u64 * 2;
    (seeded_unit(key), 0.6 + 0.8 * seeded_unit(key + 1))
}

/// Per band of the footprint: its polygon (pixels), the ink it lays this tick (ink units)
/// and its strips.
#[derive(Clone, Debug, Default)]
struct BandStamp {
    poly: Vec<[f64; 2]>,
    centroid: [f64; 2],
    wetness: f64,
    amount: f64,
    /// The runs of neighbouring strips that ink, each its end index into `strip_pts` and its
    /// strips' mean share; empty while every hair inks (the whole polygon is stamped).
    strip_pts: Vec<[f64; 2]>,
    strips: Vec<(usize, f64)>,
}

/// Inks a brush's footprint onto a canvas, tick after tick: the ink each layer gave to the
/// paper (the brush model's [`maobi_shared::brush::ink`]) is spread over the footprint of
/// the bands beside it, along the way each band moved since the previous tick, stamped at
/// positions at most [`MAX_STEP_PX`] apart, over the band's inking hair strips
/// ([`HAIR_STRIPS`]). The weights of every layer's ink sum to one over the pixels it reaches,
/// so the paper gets exactly the ink the brush lost, to rounding.
pub struct Inker {
    frame: Frame,
    stamper: Stamper,
    /// Per band: its centroid (pixels) at the previous tick, if it touched the paper then.
    prev: Vec<Option<[f64; 2]>>,
    /// Per layer: its running total of ink given, as last seen.
    deposited: Vec<f64>,
    /// The tick of the last frame stamped, if known.
    last_tick: Option<u64>,
    /// This tick's bands.
    bands: Vec<(usize, BandStamp)>,
    /// Spare band buffers, so bands that come and go do not allocate.
    spare: Vec<BandStamp>,
    /// Pixel bounds `[x0, y0, x1, y1]` of what the last stamp could have touched.
    last_bounds: Option<[f64; 4]>,
    /// Buffers for a polygon moved along the way and for the areas of a band's strips.
    scratch: Vec<[f64; 2]>,
    areas: Vec<f64>,
}

impl Inker {
    pub fn new(frame: Frame, bands: usize) -> Inker {
        Inker {
            frame,
            stamper: Stamper::new(),
            prev: vec![None; bands],
            deposited: vec![0.0; bands + 1],
            last_tick: None,
            bands: Vec::new(),
            spare: Vec::new(),
            last_bounds: None,
            scratch: Vec::new(),
            areas: Vec::new(),
        }
    }

    pub fn frame(&self) -> &Frame {
        &self.frame
    }

    /// Stamps the brush's current footprint (from the previous call's), one tick after the
    /// previous call, onto `canvas`. Returns whether anything touched the paper.
    pub fn stamp<S: Scalar>(&mut self, brush: &Brush<S>, canvas: &mut Canvas) -> bool {
        self.stamp_geometry(&Geometry::of(brush), canvas)
    }

    /// Pixel bounds `[x0, y0, x1, y1]` (not clipped to the canvas) of everything the last
    /// [`Inker::stamp`] could have changed, or `None` if it touched nothing. The GUI
    /// re-uploads only this region.
    pub fn last_bounds(&self) -> Option<[f64; 4]> {
        self.last_bounds
    }

    /// [`Inker::stamp`] from a brush's geometry (as a device's state frame carries it), one
    /// tick after the previous call.
    pub fn stamp_geometry<S: Scalar>(
        &mut self,
        geometry: &Geometry<'_, S>,
        canvas: &mut Canvas,
    ) -> bool {
        let tick = self.last_tick.map_or(0, |t| t.wrapping_add(1));
        self.stamp_geometry_at(geometry, tick, canvas)
    }

    /// [`Inker::stamp_geometry`] for a state of model tick `tick`: states that come every few
    /// ticks (a device's link) give their bands' speed over the ticks between them.
    pub fn stamp_geometry_at<S: Scalar>(
        &mut self,
        geometry: &Geometry<'_, S>,
        tick: u64,
        canvas: &mut Canvas,
    ) -> bool {
        let Inker {
            frame,
            stamper,
            prev,
            deposited,
            last_tick,
            bands,
            spare,
            last_bounds,
            scratch,
            areas,
        } = self;
        *last_bounds = None;
        let ticks = last_tick.map_or(1, |t| tick.wrapping_sub(t).clamp(1, 1000)) as f64;
        // The first state of a device that has been running (the app joining a pen): the ink
        // its brush gave before is not this paper's. From tick 0 (a render, a fresh device)
        // every bit of it is.
        let joining = last_tick.is_none() && tick > 0;
        *last_tick = Some(tick);
        let n = geometry.spine.len().min(geometry.layers.len());
        geometry.for_each_polygon(|band, poly| {
            let mut b = spare.pop().unwrap_or_default();
            b.poly.clear();
            b.poly
                .extend(poly.iter().map(|p| frame.to_px(p.x.to_f64(), p.y.to_f64())));
            b.centroid = centroid(&b.poly);
            b.wetness = 0.5
                * (geometry.layers[band].wetness.to_f64()
                    + geometry.layers[band + 1].wetness.to_f64());
            b.amount = 0.0;
            bands.push((band, b));
        });
        let needed = bands.iter().map(|(i, _)| i + 1).max().unwrap_or(0);
        if prev.len() < needed {
            prev.resize(needed, None);
        }
        if deposited.len() < n {
            deposited.resize(n, 0.0);
        }
        // Each layer's ink since the last state goes to the bands beside it (bands i - 1 and
        // i), or the nearest band, or, with no band on the paper, the pixel under the layer.
        let mut any_point = false;
        for (i, layer) in geometry.layers[..n].iter().enumerate() {
            let now = layer.deposited.to_f64();
            let last = std::mem::replace(&mut deposited[i], now);
            // A smaller total: the brush was reset, and counts from zero again.
            let amount = if joining {
                0.0
            } else if now >= last {
                now - last
            } else {
                now
            };
            if amount <= 0.0 {
                continue;
            }
            // Bands come in increasing order: those beside layer i are adjacent in the list.
            let first = bands.partition_point(|(b, _)| *b + 1 < i);
            let beside = bands[first..].iter().take_while(|(b, _)| *b <= i).count();
            if beside > 0 {
                for (_, b) in &mut bands[first..first + beside] {
                    b.amount += amount / beside as f64;
                }
            } else if let Some(k) = (0..bands.len()).min_by_key(|&k| bands[k].0.abs_diff(i)) {
                bands[k].1.amount += amount;
            } else {
                let s = geometry.spine[i];
                let p = frame.to_px(s.x.to_f64(), s.y.to_f64());
                any_point |= deposit_point(canvas, frame, p, amount);
            }
        }
        // How far each band moved since the previous tick, and the steps that covers; which
        // of its hair strips ink.
        let mut steps = 1usize;
        let mut moves = Vec::with_capacity(bands.len());
        for (i, b) in bands.iter_mut() {
            let d = match prev.get(*i).copied().flatten() {
                Some(p) => [b.centroid[0] - p[0], b.centroid[1] - p[1]],
                None => [0.0; 2],
            };
            let dist = d[0].hypot(d[1]);
            steps = steps.max((dist / MAX_STEP_PX).ceil() as usize);
            let speed = dist / frame.px_per_mm / ticks * 1e3;
            choose_strips(*i, b, d, speed);
            moves.push(d);
        }
        let scale = frame.px_per_mm * frame.px_per_mm;
        let (w, h) = (canvas.width(), canvas.height());
        for k in 0..steps {
            // Position k + 1 of `steps` along the way from the previous tick to this one.
            let back = (steps - 1 - k) as f64 / steps as f64;
            stamper.begin();
            for ((_, b), d) in bands.iter().zip(&moves) {
                if b.amount <= 0.0 {
                    continue;
                }
                // The part of the band's ink this position lays, in pixel optical depth.
                let ink = b.amount * scale / steps as f64;
                let off = [-d[0] * back, -d[1] * back];
                let moved = |pts: &[[f64; 2]], out: &mut Vec<[f64; 2]>| {
                    out.clear();
                    out.extend(pts.iter().map(|p| [p[0] + off[0], p[1] + off[1]]));
                };
                // The whole band, or its inking runs of strips, each `(end, share)`.
                let whole = [(b.poly.len(), 1.0)];
                let (pts, runs) = if b.strips.is_empty() {
                    (&b.poly, &whole[..])
                } else {
                    (&b.strip_pts, &b.strips[..])
                };
                // Weights `ink x share / sum(share x area)`: their coverage sums to `ink`.
                areas.clear();
                let mut start = 0;
                for &(end, share) in runs {
                    moved(&pts[start..end], scratch);
                    areas.push(share * raster_area(scratch, w, h));
                    start = end;
                }
                let total: f64 = areas.iter().sum();
                let laid = total > 0.0;
                if laid {
                    let mut start = 0;
                    for &(end, share) in runs {
                        let poly = pts[start..end]
                            .iter()
                            .map(|p| [p[0] + off[0], p[1] + off[1]]);
                        stamper.add_weighted_polygon(poly, (ink * share / total) as f32);
                        start = end;
                    }
                }
                if !laid {
                    // Too small for the sampling: the pixel under its centre gets the ink.
                    let c = [b.centroid[0] + off[0], b.centroid[1] + off[1]];
                    any_point |= deposit_point(canvas, frame, c, b.amount / steps as f64);
                }
                if k == 0 {
                    for p in &b.poly {
                        for q in [*p, [p[0] + off[0], p[1] + off[1]]] {
                            let r = last_bounds.get_or_insert([q[0], q[1], q[0], q[1]]);
                            *r = [
                                r[0].min(q[0]),
                                r[1].min(q[1]),
                                r[2].max(q[0]),
                                r[3].max(q[1]),
                            ];
                        }
                    }
                }
            }
            stamper.finish_summed(canvas);
        }
        if any_point && last_bounds.is_none() {
            *last_bounds = Some([0.0, 0.0, w as f64, h as f64]);
        }
        // This tick's centroids become the previous ones; bands absent now are forgotten.
        prev.iter_mut().for_each(|p| *p = None);
        let any = !bands.is_empty();
        for (i, b) in bands.drain(..) {
            prev[i] = Some(b.centroid);
            spare.push(b);
        }
        any
    }
}

/// Adds `amount` ink units to the pixel at `p` (pixels), if it is on the canvas; returns
/// whether it was.
fn deposit_point(canvas: &mut Canvas, frame: &Frame, p: [f64; 2], amount: f64) -> bool {
    let (x, y) = (p[0].floor(), p[1].floor());
    if x < 0.0 || y < 0.0 || x >= canvas.width() as f64 || y >= canvas.height() as f64 {
        return false;
    }
    let od = amount * frame.px_per_mm * frame.px_per_mm;
    canvas.deposit_row(y as usize, x as usize, &[od as f32]);
    true
}

/// Decides which of band `band`'s hair strips ink this tick, moving by `d` (pixels) at
/// `speed` (mm/s): all of them (no strips kept), or the ready ones, clipped from its polygon
/// across the way it moves.
fn choose_strips(band: usize, b: &mut BandStamp, d: [f64; 2], speed: f64) {
    b.strips.clear();
    b.strip_pts.clear();
    let reach = DRY_GAIN * b.wetness - speed / DRY_SPEED_MM_S;
    let len = d[0].hypot(d[1]);
    if reach >= 1.0 || len < 1e-9 {
        return;
    }
    // Across the way the band moves: the hairs lie side by side along this axis.
    let across = [-d[1] / len, d[0] / len];
    let along = |p: &[f64; 2]| p[0] * across[0] + p[1] * across[1];
    let (lo, hi) = b
        .poly
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
            (lo.min(along(p)), hi.max(along(p)))
        });
    let width = (hi - lo) / HAIR_STRIPS as f64;
    // The strips that ink; when none would, the readiest one (the last hairs with ink).
    let mut readiest = (f64::INFINITY, 0, 1.0);
    let mut inking = [false; HAIR_STRIPS];
    for (j, ink) in inking.iter_mut().enumerate() {
        let (ready, share) = hair(band, j);
        *ink = ready < reach;
        if ready < readiest.0 {
            readiest = (ready, j, share);
        }
    }
    if !inking.iter().any(|&i| i) {
        inking[readiest.1] = true;
    }
    // Neighbouring inking strips are clipped as one run, with their mean share.
    let mut clipped = Vec::new();
    let mut j = 0;
    while j < HAIR_STRIPS {
        if !inking[j] {
            j += 1;
            continue;
        }
        let first = j;
        let mut share = 0.0;
        while j < HAIR_STRIPS && inking[j] {
            share += hair(band, j).1;
            j += 1;
        }
        let (a, z) = (lo + first as f64 * width, lo + j as f64 * width);
        clip_slab(&b.poly, across, a, z, &mut clipped);
        if clipped.len() >= 3 {
            b.strip_pts.extend_from_slice(&clipped);
            b.strips
                .push((b.strip_pts.len(), share / (j - first) as f64));
        }
    }
}

/// The part of the convex polygon `poly` with `a <= p . axis <= z`, into `out`.
fn clip_slab(poly: &[[f64; 2]], axis: [f64; 2], a: f64, z: f64, out: &mut Vec<[f64; 2]>) {
    let mut half = Vec::with_capacity(poly.len() + 2);
    clip_half(poly, |p| p[0] * axis[0] + p[1] * axis[1] - a, &mut half);
    clip_half(&half, |p| z - (p[0] * axis[0] + p[1] * axis[1]), out);
}

/// Sutherland-Hodgman: the part of `poly` where `side(p) >= 0`, into `out`.
fn clip_half(poly: &[[f64; 2]], side: impl Fn(&[f64; 2]) -> f64, out: &mut Vec<[f64; 2]>) {
    out.clear();
    let n = poly.len();
    for k in 0..n {
        let (p, q) = (poly[k], poly[(k + 1) % n]);
        let (sp, sq) = (side(&p), side(&q));
        if sp >= 0.0 {
            out.push(p);
        }
        if (sp >= 0.0) != (sq >= 0.0) {
            let t = sp / (sp - sq);
            out.push([p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1])]);
        }
    }
}

/// Area centroid of a convex polygon (its vertex mean if it has no area).
fn centroid(poly: &[[f64; 2]]) -> [f64; 2] {
    let (mut a, mut cx, mut cy) = (0.0, 0.0, 0.0);
    let n = poly.len();
    for i in 0..n {
        let (p, q) = (poly[i], poly[(i + 1) % n]);
        let c = p[0] * q[1] - q[0] * p[1];
        a += c;
        cx += (p[0] + q[0]) * c;
        cy += (p[1] + q[1]) * c;
    }
    if a.abs() < 1e-12 {
        let m = n.max(1) as f64;
        let (sx, sy) = poly
            .iter()
            .fold((0.0, 0.0), |s, p| (s.0 + p[0], s.1 + p[1]));
        return [sx / m, sy / m];
    }
    [cx / (3.0 * a), cy / (3.0 * a)]
}

/// Simulates `track` in scalar type `S` and inks every tick onto a new canvas.
/// Most paper steps a render waits, after the last tick, for raw paper to dry.
pub const MAX_DRYING_STEPS: usize = 100_000;

/// The paper side of a render, whichever brush model inks it: the canvas, the inker, and
/// the time each takes.
struct PaperRun {
    frame: Frame,
    canvas: Canvas,
    inker: Inker,
    stamps: usize,
    ticks: usize,
    stamp_time: Duration,
    paper_time: Duration,
}

impl PaperRun {
    fn new(frame: Frame, paper: PaperSpec, bands: usize) -> PaperRun {
        PaperRun {
            frame,
            canvas: Canvas::with_paper(frame.width, frame.height, paper),
            inker: Inker::new(frame, bands),
            stamps: 0,
            ticks: 0,
            stamp_time: Duration::ZERO,
            paper_time: Duration::ZERO,
        }
    }

    /// One tick: the brush's surface inked onto the canvas, then the paper's step.
    fn tick<S: Scalar>(&mut self, geometry: &Geometry<'_, S>) {
        let started = Instant::now();
        if self.inker.stamp_geometry(geometry, &mut self.canvas) {
            self.stamps += 1;
        }
        let stamped = Instant::now();
        self.stamp_time += stamped - started;
        self.canvas.tick();
        self.paper_time += stamped.elapsed();
        self.ticks += 1;
    }

    /// The paper left to dry after the last tick, and the render's figures.
    fn finish(mut self) -> (Canvas, RenderStats) {
        let started = Instant::now();
        let drying_steps = self.canvas.dry(MAX_DRYING_STEPS);
        self.paper_time += started.elapsed();
        let stats = RenderStats {
            ticks: self.ticks,
            stamps: self.stamps,
            width: self.frame.width,
            height: self.frame.height,
            ink_fraction: self.canvas.ink_fraction(),
            stamp_seconds: self.stamp_time.as_secs_f64(),
            paper_seconds: self.paper_time.as_secs_f64(),
            drying_steps,
        };
        (self.canvas, stats)
    }
}

/// Simulates `track` in scalar type `S` and inks every tick onto new paper of `paper`; the
/// paper takes its step every [`crate::paper::TICKS_PER_STEP`] ticks, as in the app, and
/// after the last tick it is left to dry.
pub fn render<S: maobi_shared::BrushScalar>(
    params: BrushParams,
    track: &PoseTrack,
    frame: Frame,
    paper: PaperSpec,
) -> anyhow::Result<(Canvas, RenderStats)> {
    render_with_progress::<S>(params, track, frame, paper, |_, _| {})
}

/// [`render`], calling `progress(done, total)` after every tick with the ticks inked so far
/// and the track's ticks in all (the last call has `done == total`; the paper then dries).
/// The library prints nothing: the caller shows the progress, or not. It never changes the
/// result.
pub fn render_with_progress<S: maobi_shared::BrushScalar>(
    params: BrushParams,
    track: &PoseTrack,
    frame: Frame,
    paper: PaperSpec,
    mut progress: impl FnMut(usize, usize),
) -> anyhow::Result<(Canvas, RenderStats)> {
    let mut run = PaperRun::new(frame, paper, params.layers as usize - 1);
    let total = track.ticks();
    let ticks = simulate::<S>(params, track, |tick| {
        run.tick(&Geometry::of(tick.brush));
        progress(run.ticks, total);
        Ok(())
    })?;
    debug_assert_eq!(ticks, run.ticks);
    Ok(run.finish())
}

/// [`render`] with Baxter & Lin's brush (`maobi_shared::baxter_lin`, `f64`), built by
/// `make` at the track's first pose, run over `track` and inked every tick through the same
/// inker and paper as Liang's brush.
pub fn render_baxter_lin(
    make: impl FnOnce(Pose<f64>) -> Result<BaxterLinBrush, SpineParamError>,
    track: &PoseTrack,
    frame: Frame,
    paper: PaperSpec,
) -> anyhow::Result<(Canvas, RenderStats)> {
    render_baxter_lin_with_progress(make, track, frame, paper, |_, _| {})
}

/// [`render_baxter_lin`], calling `progress(done, total)` after every tick as
/// [`render_with_progress`] does.
pub fn render_baxter_lin_with_progress(
    make: impl FnOnce(Pose<f64>) -> Result<BaxterLinBrush, SpineParamError>,
    track: &PoseTrack,
    frame: Frame,
    paper: PaperSpec,
    mut progress: impl FnMut(usize, usize),
) -> anyhow::Result<(Canvas, RenderStats)> {
    let mut run = PaperRun::new(frame, paper, baxter_lin::brush::LEVELS - 1);
    let total = track.ticks();
    let mut poses = track.resample();
    let first = poses.next().context("the pose track is empty")?;
    let mut brush = make(first).map_err(|e| anyhow::anyhow!("Baxter & Lin's spine: {e}"))?;
    run.tick(&brush.geometry());
    progress(run.ticks, total);
    for pose in poses {
        brush.tick(&pose);
        run.tick(&brush.geometry());
        progress(run.ticks, total);
    }
    Ok(run.finish())
}

/// Encodes the canvas as an 8-bit greyscale PNG (black = ink). The bytes depend only on the
/// canvas: no time stamps or other metadata.
pub fn encode_png<W: Write>(canvas: &Canvas, out: W) -> anyhow::Result<()> {
    let mut enc = png::Encoder::new(out, canvas.width() as u32, canvas.height() as u32);
    enc.set_color(png::ColorType::Grayscale);
    enc.set_depth(png::BitDepth::Eight);
    let mut w = enc.write_header().context("writing the PNG header")?;
    w.write_image_data(&canvas.to_gray8())
        .context("writing the PNG data")?;
    w.finish().context("finishing the PNG")?;
    Ok(())
}

/// Writes the canvas as a PNG file at `path`.
pub fn write_png(canvas: &Canvas, path: &Path) -> anyhow::Result<()> {
    let mut bytes = Vec::new();
    encode_png(canvas, &mut bytes)?;
    std::fs::write(path, bytes).with_context(|| format!("cannot write {}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use maobi_shared::{presets, Fx};

    fn track(text: &str) -> PoseTrack {
        PoseTrack::from_reader("t.csv", text.as_bytes()).unwrap()
    }

    #[test]
    fn frame_covers_extent_and_margin() {
        let t = track("t,x,y,z,qw,qx,qy,qz\n0,0,0,40,1,0,0,0\n1,80,-10,40,1,0,0,0\n");
        let p = presets::by_name("large").unwrap();
        let f = paper_frame(&t, &p, 10.0).unwrap();
        // 80 + 2 * 50 mm wide, 10 + 2 * 50 mm high.
        assert_eq!((f.width, f.height), (1800, 1100));
        assert_eq!(f.to_px(-50.0, 50.0), [0.0, 0.0]);
        assert!(paper_frame(&t, &p, 0.0).is_err());
        assert!(paper_frame(&t, &p, f64::NAN).is_err());
        assert!(paper_frame(&t, &p, 1000.0).is_err());
    }

    #[test]
    fn pressed_brush_inks_and_lifted_brush_does_not() {
        let p = presets::by_name("large").unwrap();
        let up = track("t,x,y,z,qw,qx,qy,qz\n0,0,0,45,1,0,0,0\n0.05,0,0,45,1,0,0,0\n");
        let f = paper_frame(&up, &p, 5.0).unwrap();
        let (c, stats) = render::<Fx>(p, &up, f, PaperSpec::default()).unwrap();
        assert_eq!(stats.ticks, 51);
        assert_eq!(stats.stamps, 0);
        assert_eq!(c.ink_area_px(), 0.0);

        // Pressed 10 mm leaning 10 degrees with the tip toward -x: the brush lies down
        // toward -x, so the ink lies there, within a brush length of the ferrule.
        let q = [(5.0f64).to_radians().cos(), (5.0f64).to_radians().sin()];
        let down = track(&format!(
            "t,x,y,z,qw,qx,qy,qz\n0,0,0,45,{c},0,{s},0\n0.2,0,0,30,{c},0,{s},0\n",
            c = q[0],
            s = q[1]
        ));
        let (c, stats) = render::<Fx>(p, &down, f, PaperSpec::default()).unwrap();
        assert!(stats.stamps > 0);
        // Darkness-weighted: a brush held still gives its ink slowly (at the dwell's rate,
        // `maobi_shared::brush::ink::DWELL_MM`, from the layers that reach the paper).
        let area_mm2 = c.ink_area_px() / 25.0;
        assert!(area_mm2 > 2.0, "{area_mm2}");
        let (mut sx, mut sy) = (0.0, 0.0);
        for y in 0..f.height {
            for x in 0..f.width {
                let w = c.at(x, y) as f64;
                sx += w * (x as f64 + 0.5);
                sy += w * (y as f64 + 0.5);
            }
        }
        let a = c.ink_area_px();
        let centroid_mm = [sx / a / 5.0 + f.x0_mm, f.y_top_mm - sy / a / 5.0];
        assert!(
            centroid_mm[0] < 0.0 && centroid_mm[0] > -40.0,
            "{centroid_mm:?}"
        );
        assert!(centroid_mm[1].abs() < 1.0, "{centroid_mm:?}");
        assert_eq!(c.at(0, 0), 0.0);
    }

    /// The counts a render reports: one a tick, each one more, the last the total.
    fn assert_counts(calls: &[(usize, usize)], ticks: usize) {
        assert_eq!(calls.len(), ticks);
        for (i, &(done, total)) in calls.iter().enumerate() {
            assert_eq!((done, total), (i + 1, ticks), "call {i}");
        }
    }

    #[test]
    fn progress_counts_every_tick_and_leaves_the_image_alone() {
        let p = presets::by_name("large").unwrap();
        let q = [(5.0f64).to_radians().cos(), (5.0f64).to_radians().sin()];
        let t = track(&format!(
            "t,x,y,z,qw,qx,qy,qz\n0,0,0,45,{c},0,{s},0\n0.08,0,0,30,{c},0,{s},0\n",
            c = q[0],
            s = q[1]
        ));
        let f = paper_frame(&t, &p, 4.0).unwrap();

        let (plain, plain_stats) = render::<Fx>(p, &t, f, PaperSpec::default()).unwrap();
        let mut calls = Vec::new();
        let (c, stats) =
            render_with_progress::<Fx>(p, &t, f, PaperSpec::default(), |d, n| calls.push((d, n)))
                .unwrap();
        assert_counts(&calls, stats.ticks);
        assert_eq!(stats.ticks, t.ticks());
        assert!(plain_stats.stamps > 0);
        assert_eq!(c.to_gray8(), plain.to_gray8());

        let make = |pose| BaxterLinBrush::of_preset(&p, pose);
        let (plain, _) = render_baxter_lin(make, &t, f, PaperSpec::default()).unwrap();
        let mut calls = Vec::new();
        let (c, stats) =
            render_baxter_lin_with_progress(make, &t, f, PaperSpec::default(), |d, n| {
                calls.push((d, n))
            })
            .unwrap();
        assert_counts(&calls, stats.ticks);
        assert_eq!(stats.ticks, t.ticks());
        assert_eq!(c.to_gray8(), plain.to_gray8());
    }

    #[test]
    fn png_is_deterministic_and_decodes() {
        let mut c = Canvas::new(7, 3);
        let mut s = Stamper::new();
        s.begin();
        s.add_polygon([[1.0, 0.0], [4.5, 0.0], [4.5, 2.0], [1.0, 2.0]]);
        s.finish(&mut c);
        let (mut a, mut b) = (Vec::new(), Vec::new());
        encode_png(&c, &mut a).unwrap();
        encode_png(&c, &mut b).unwrap();
        assert_eq!(a, b);
        let dec = png::Decoder::new(std::io::Cursor::new(a));
        let mut r = dec.read_info().unwrap();
        let mut buf = vec![0; r.output_buffer_size().unwrap()];
        let info = r.next_frame(&mut buf).unwrap();
        assert_eq!((info.width, info.height), (7, 3));
        assert_eq!(&buf[..7], &[255, 94, 94, 94, 155, 255, 255]);
    }
}
