//! Rendering a simulated stroke to a PNG: the footprint of every tick inked onto paper.
//!
//! At 500 mm/s the brush moves 0.5 mm per tick (5 px at 10 px/mm), so stamping each tick's
//! footprint alone would leave gaps, and stamping the area it swept would sum to a tone that
//! steps with the ticks (scallops). Ink is laid down per unit of travel instead ([`Inker`]):
//! each band's footprint is stamped at positions a pixel or less apart along its way since
//! the previous tick, each giving the band's ink per mm ([`ink_per_mm`]) times the travel it
//! stands for. The ink lands on the paper ([`crate::paper`]), which takes a step every few
//! ticks.

use std::io::Write;
use std::path::Path;
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use maobi_shared::footprint::Geometry;
use maobi_shared::{Brush, BrushParams, Scalar};

use crate::offline::simulate;
use crate::paper::{Canvas, PaperSpec};
use crate::poses::PoseTrack;
use crate::raster::{Frame, Stamper};

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
/// tick: ink is laid down per unit of travel by stamping the footprint at positions this
/// close along its path, so overlapping stamps sum to a tone that does not depend on where
/// the ticks fell (no periodic scallops at the tick spacing).
pub const MAX_STEP_PX: f64 = 1.0;

/// Travel (mm) a band counts per tick on top of its motion: a brush held still keeps giving
/// ink, and a slow stroke lays down more ink than a fast one (as if every stroke moved this
/// much faster, here 30 mm/s at the 1 ms tick).
pub const DWELL_MM_PER_TICK: f64 = 0.03;

/// Ink (optical depth) a band of the footprint lays down per mm it travels, from the layer
/// state the footprint carries: `wetness` W_i in [0, 1] and `press_mm`, how far the band's
/// lowest surface point is below the footprint threshold.
///
/// This is the one place the brush's ink feeds the paper: the amount per band (layer) per
/// tick. The brush's own finite ink load (issue 23, item 1) is to feed it here, in place of
/// (or scaling) the wetness.
pub fn ink_per_mm(wetness: f64, press_mm: f64) -> f32 {
    // A wet brush gives most of its ink; pressing harder opens the hairs and gives more.
    let wet = wetness.clamp(0.0, 1.0);
    let press = press_mm.max(0.0);
    (0.15 + 0.35 * wet * (0.4 + 0.6 * press / (press + 1.0))) as f32
}

/// Per band of the footprint: its polygon (pixels) and the ink it gives per mm.
#[derive(Clone, Debug, Default)]
struct BandStamp {
    poly: Vec<[f64; 2]>,
    centroid: [f64; 2],
    ink_per_mm: f32,
}

/// Inks a brush's footprint onto a canvas, tick after tick, per unit of travel: each band's
/// footprint is stamped at positions at most [`MAX_STEP_PX`] apart along the way its centroid
/// moved since the previous tick, each laying down the band's ink per mm times the travel
/// it stands for.
pub struct Inker {
    frame: Frame,
    stamper: Stamper,
    /// Per band: its centroid (pixels) at the previous tick, if it touched the paper then.
    prev: Vec<Option<[f64; 2]>>,
    /// This tick's bands.
    bands: Vec<(usize, BandStamp)>,
    /// Spare band buffers, so bands that come and go do not allocate.
    spare: Vec<BandStamp>,
    /// Pixel bounds `[x0, y0, x1, y1]` of what the last stamp could have touched.
    last_bounds: Option<[f64; 4]>,
}

impl Inker {
    pub fn new(frame: Frame, bands: usize) -> Inker {
        Inker {
            frame,
            stamper: Stamper::new(),
            prev: vec![None; bands],
            bands: Vec::new(),
            spare: Vec::new(),
            last_bounds: None,
        }
    }

    pub fn frame(&self) -> &Frame {
        &self.frame
    }

    /// Stamps the brush's current footprint (from the previous call's) onto `canvas`.
    /// Returns whether anything touched the paper.
    pub fn stamp<S: Scalar>(&mut self, brush: &Brush<S>, canvas: &mut Canvas) -> bool {
        self.stamp_geometry(&Geometry::of(brush), canvas)
    }

    /// Pixel bounds `[x0, y0, x1, y1]` (not clipped to the canvas) of everything the last
    /// [`Inker::stamp`] could have changed, or `None` if it touched nothing. The GUI
    /// re-uploads only this region.
    pub fn last_bounds(&self) -> Option<[f64; 4]> {
        self.last_bounds
    }

    /// [`Inker::stamp`] from a brush's geometry (as a device's state frame carries it).
    pub fn stamp_geometry<S: Scalar>(
        &mut self,
        geometry: &Geometry<'_, S>,
        canvas: &mut Canvas,
    ) -> bool {
        let Inker {
            frame,
            stamper,
            prev,
            bands,
            spare,
            last_bounds,
        } = self;
        *last_bounds = None;
        let eps = geometry.eps.to_f64();
        let lowest = |i: usize| {
            let (c, l) = (geometry.spine[i], geometry.layers[i]);
            let (a, b) = (
                l.long_radius.to_f64() * l.long_axis.z.to_f64(),
                l.short_radius.to_f64() * l.short_axis.z.to_f64(),
            );
            c.z.to_f64() - (a * a + b * b).sqrt()
        };
        geometry.for_each_polygon(|band, poly| {
            let mut b = spare.pop().unwrap_or_default();
            b.poly.clear();
            b.poly
                .extend(poly.iter().map(|p| frame.to_px(p.x.to_f64(), p.y.to_f64())));
            b.centroid = centroid(&b.poly);
            let wet = 0.5
                * (geometry.layers[band].wetness.to_f64()
                    + geometry.layers[band + 1].wetness.to_f64());
            let press = eps - lowest(band).min(lowest(band + 1));
            b.ink_per_mm = ink_per_mm(wet, press);
            bands.push((band, b));
        });
        let needed = bands.iter().map(|(i, _)| i + 1).max().unwrap_or(0);
        if prev.len() < needed {
            prev.resize(needed, None);
        }
        // How far each band moved since the previous tick, and the steps that covers.
        let mut steps = 1usize;
        for (i, b) in bands.iter() {
            if let Some(p) = prev.get(*i).copied().flatten() {
                let d = (b.centroid[0] - p[0]).hypot(b.centroid[1] - p[1]);
                steps = steps.max((d / MAX_STEP_PX).ceil() as usize);
            }
        }
        for k in 0..steps {
            // Position k + 1 of `steps` along the way from the previous tick to this one.
            let back = (steps - 1 - k) as f64 / steps as f64;
            stamper.begin();
            for (i, b) in bands.iter() {
                let (d, travel_mm) = match prev.get(*i).copied().flatten() {
                    Some(p) => {
                        let d = [b.centroid[0] - p[0], b.centroid[1] - p[1]];
                        (d, d[0].hypot(d[1]) / frame.px_per_mm)
                    }
                    None => ([0.0; 2], 0.0),
                };
                let ink = b.ink_per_mm as f64 * (travel_mm + DWELL_MM_PER_TICK) / steps as f64;
                let off = [-d[0] * back, -d[1] * back];
                stamper.add_weighted_polygon(
                    b.poly.iter().map(|p| [p[0] + off[0], p[1] + off[1]]),
                    ink as f32,
                );
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
            stamper.finish(canvas);
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

/// Simulates `track` in scalar type `S` and inks every tick onto new paper of `paper`; the
/// paper takes its step every [`crate::paper::TICKS_PER_STEP`] ticks, as in the app, and
/// after the last tick it is left to dry.
pub fn render<S: maobi_shared::BrushScalar>(
    params: BrushParams,
    track: &PoseTrack,
    frame: Frame,
    paper: PaperSpec,
) -> anyhow::Result<(Canvas, RenderStats)> {
    let mut canvas = Canvas::with_paper(frame.width, frame.height, paper);
    let mut inker = Inker::new(frame, params.layers as usize - 1);
    let mut stamps = 0;
    let mut stamp_time = Duration::ZERO;
    let mut paper_time = Duration::ZERO;
    let ticks = simulate::<S>(params, track, |tick| {
        let started = Instant::now();
        if inker.stamp(tick.brush, &mut canvas) {
            stamps += 1;
        }
        let stamped = Instant::now();
        stamp_time += stamped - started;
        canvas.tick();
        paper_time += stamped.elapsed();
        Ok(())
    })?;
    let started = Instant::now();
    let drying_steps = canvas.dry(MAX_DRYING_STEPS);
    paper_time += started.elapsed();
    let stats = RenderStats {
        ticks,
        stamps,
        width: frame.width,
        height: frame.height,
        ink_fraction: canvas.ink_fraction(),
        stamp_seconds: stamp_time.as_secs_f64(),
        paper_seconds: paper_time.as_secs_f64(),
        drying_steps,
    };
    Ok((canvas, stats))
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
        // Darkness-weighted: a brush held still gives its ink slowly.
        let area_mm2 = c.ink_area_px() / 25.0;
        assert!(area_mm2 > 10.0, "{area_mm2}");
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
