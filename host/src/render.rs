//! Rendering a simulated stroke to a PNG: the footprint of every tick inked onto paper.
//!
//! At 500 mm/s the brush moves 0.5 mm per tick (5 px at 10 px/mm), so stamping each tick's
//! footprint alone would leave gaps. Each band is therefore stamped as the convex hull of its
//! polygon at the previous tick and at this tick (the area it swept, for the small motion of
//! one tick), or its polygon alone when it did not touch the paper at the previous tick.

use std::io::Write;
use std::path::Path;
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use maobi_shared::footprint::{self, Geometry};
use maobi_shared::{Brush, BrushParams, Scalar, Vec2};

use crate::offline::simulate;
use crate::poses::PoseTrack;
use crate::raster::{Canvas, Frame, Stamper};

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

/// Inks a brush's footprint onto a canvas, tick after tick.
pub struct Inker {
    frame: Frame,
    stamper: Stamper,
    /// Per band: its footprint at the previous tick (pixels), if it had one.
    prev: Vec<Option<Vec<[f64; 2]>>>,
    cur: Vec<Option<Vec<[f64; 2]>>>,
    /// Spare polygon buffers, so bands that come and go do not allocate.
    spare: Vec<Vec<[f64; 2]>>,
    union: Vec<Vec2<f64>>,
    hull: Vec<Vec2<f64>>,
    /// Pixel bounds `[x0, y0, x1, y1]` of what the last stamp could have touched.
    last_bounds: Option<[f64; 4]>,
}

impl Inker {
    pub fn new(frame: Frame, bands: usize) -> Inker {
        Inker {
            frame,
            stamper: Stamper::new(),
            prev: vec![None; bands],
            cur: vec![None; bands],
            spare: Vec::new(),
            union: Vec::new(),
            hull: Vec::new(),
            last_bounds: None,
        }
    }

    pub fn frame(&self) -> &Frame {
        &self.frame
    }

    /// Stamps the brush's current footprint (swept from the previous call's) onto `canvas`.
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
            cur,
            spare,
            union,
            hull,
            last_bounds,
        } = self;
        stamper.begin();
        let mut any = false;
        *last_bounds = None;
        geometry.for_each_polygon(|band, poly| {
            any = true;
            let mut buf = spare.pop().unwrap_or_default();
            buf.clear();
            buf.extend(poly.iter().map(|p| frame.to_px(p.x.to_f64(), p.y.to_f64())));
            let olds = prev[band].as_deref().unwrap_or(&[]);
            for p in buf.iter().chain(olds) {
                let b = last_bounds.get_or_insert([p[0], p[1], p[0], p[1]]);
                *b = [
                    b[0].min(p[0]),
                    b[1].min(p[1]),
                    b[2].max(p[0]),
                    b[3].max(p[1]),
                ];
            }
            match &prev[band] {
                Some(old) => {
                    union.clear();
                    union.extend(old.iter().chain(buf.iter()).map(|p| Vec2::new(p[0], p[1])));
                    hull.clear();
                    hull.resize(union.len() + 1, Vec2::new(0.0, 0.0));
                    let h = footprint::convex_hull(&mut union[..], &mut hull[..]);
                    stamper.add_polygon(hull[..h].iter().map(|p| [p.x, p.y]));
                }
                None => stamper.add_polygon(buf.iter().copied()),
            }
            if let Some(old) = cur[band].replace(buf) {
                spare.push(old);
            }
        });
        stamper.finish(canvas);
        // This tick's polygons become the previous ones; bands absent now are forgotten.
        for (p, c) in prev.iter_mut().zip(cur.iter_mut()) {
            if let Some(old) = p.take() {
                spare.push(old);
            }
            *p = c.take();
        }
        any
    }
}

/// Simulates `track` in scalar type `S` and inks every tick onto a new canvas.
pub fn render<S: maobi_shared::BrushScalar>(
    params: BrushParams,
    track: &PoseTrack,
    frame: Frame,
) -> anyhow::Result<(Canvas, RenderStats)> {
    let mut canvas = Canvas::new(frame.width, frame.height);
    let mut inker = Inker::new(frame, params.layers as usize - 1);
    let mut stamps = 0;
    let mut stamp_time = Duration::ZERO;
    let ticks = simulate::<S>(params, track, |tick| {
        let started = Instant::now();
        if inker.stamp(tick.brush, &mut canvas) {
            stamps += 1;
        }
        stamp_time += started.elapsed();
        Ok(())
    })?;
    let stats = RenderStats {
        ticks,
        stamps,
        width: frame.width,
        height: frame.height,
        ink_fraction: canvas.ink_fraction(),
        stamp_seconds: stamp_time.as_secs_f64(),
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
        let (c, stats) = render::<Fx>(p, &up, f).unwrap();
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
        let (c, stats) = render::<Fx>(p, &down, f).unwrap();
        assert!(stats.stamps > 0);
        let area_mm2 = c.ink_area_px() / 25.0;
        assert!(area_mm2 > 20.0, "{area_mm2}");
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
        assert_eq!(&buf[..7], &[255, 0, 0, 0, 128, 255, 255]);
    }
}
