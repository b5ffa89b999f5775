//! The anti-aliased polygon stamper, and the frame from paper millimetres to pixels.
//!
//! Ink is laid down in *stamps*: a stamp is a set of convex polygons (one band's footprint at
//! one moment). Within a stamp the polygons' coverages are **summed** and clamped to 1, so
//! two polygons sharing an edge leave no seam; the stamp then adds its coverage times an
//! amount of ink to the [`Canvas`] (see [`crate::paper`]), so inking the same place again
//! darkens it.
//!
//! Coverage is computed on 4 sub-scanlines per pixel row (each weighing 1/4) with exact
//! horizontal coverage: each polygon's span on a sub-scanline is added to a per-row
//! difference accumulator, the end pixels getting their fractional share, and a prefix sum
//! over the row turns it into coverage.
//!
//! Pixel (i, j) covers `[i, i+1) x [j, j+1)` in pixel units; [`Frame`] maps paper millimetres
//! (+y up) to pixels (+y down).

/// Sub-scanlines per pixel row.
const SUB: usize = 4;
const SUB_WEIGHT: f32 = 1.0 / SUB as f32;

/// Maps paper millimetres to canvas pixels: pixel x = (x - x0) * ppmm, pixel y =
/// (y_top - y) * ppmm (the image's y axis points down the paper).
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct Frame {
    /// Paper x (mm) at the image's left edge.
    pub x0_mm: f64,
    /// Paper y (mm) at the image's top edge.
    pub y_top_mm: f64,
    pub px_per_mm: f64,
    pub width: usize,
    pub height: usize,
}

impl Frame {
    /// The frame covering `[lo, hi]` (paper mm) plus `margin_mm` on every side.
    pub fn covering(lo: [f64; 2], hi: [f64; 2], margin_mm: f64, px_per_mm: f64) -> Frame {
        let w_mm = hi[0] - lo[0] + 2.0 * margin_mm;
        let h_mm = hi[1] - lo[1] + 2.0 * margin_mm;
        Frame {
            x0_mm: lo[0] - margin_mm,
            y_top_mm: hi[1] + margin_mm,
            px_per_mm,
            width: (w_mm * px_per_mm).ceil().max(1.0) as usize,
            height: (h_mm * px_per_mm).ceil().max(1.0) as usize,
        }
    }

    #[inline]
    pub fn to_px(&self, x_mm: f64, y_mm: f64) -> [f64; 2] {
        [
            (x_mm - self.x0_mm) * self.px_per_mm,
            (self.y_top_mm - y_mm) * self.px_per_mm,
        ]
    }
}

pub use crate::paper::Canvas;

/// Rasterises stamps onto a [`Canvas`]; keeps its buffers between stamps so the hot loop
/// does not allocate once they have grown to the largest stamp.
#[derive(Clone, Debug, Default)]
pub struct Stamper {
    /// Vertices of all polygons of the current stamp (pixels).
    pts: Vec<[f64; 2]>,
    /// End index in `pts` of each polygon.
    ends: Vec<usize>,
    /// Ink per unit of coverage of each polygon.
    weights: Vec<f32>,
    /// Difference accumulator over the stamp's bounding box, `stride` per row. All zero
    /// between stamps (each stamp zeroes what it touched), so its layout can change freely.
    acc: Vec<f32>,
    /// Per row of the box: the first and last index of `acc` that the stamp touched.
    touched: Vec<(usize, usize)>,
    /// One row's coverage, handed to the canvas.
    row: Vec<f32>,
}

impl Stamper {
    pub fn new() -> Stamper {
        Stamper::default()
    }

    /// Starts a new stamp.
    pub fn begin(&mut self) {
        self.pts.clear();
        self.ends.clear();
        self.weights.clear();
    }

    /// Adds a convex polygon (pixel coordinates, either orientation) to the current stamp.
    /// Polygons with fewer than 3 vertices are ignored.
    pub fn add_polygon<I: IntoIterator<Item = [f64; 2]>>(&mut self, pts: I) {
        let start = self.pts.len();
        self.pts.extend(pts);
        if self.pts.len() - start < 3 {
            self.pts.truncate(start);
        } else {
            self.ends.push(self.pts.len());
            self.weights.push(1.0);
        }
    }

    /// Adds a convex polygon that lays down `ink` per unit of its coverage.
    pub fn add_weighted_polygon<I: IntoIterator<Item = [f64; 2]>>(&mut self, pts: I, ink: f32) {
        let n = self.ends.len();
        self.add_polygon(pts);
        if self.ends.len() > n {
            self.weights[n] = ink;
        }
    }

    /// Rasterises the current stamp and adds its ink to `canvas`: each polygon's coverage
    /// times its ink ([`Stamper::add_weighted_polygon`]; 1 for [`Stamper::add_polygon`]),
    /// summed, and clamped to the largest ink of the stamp where polygons overlap. Returns the
    /// ink laid down (pixel units of area times ink), for tests and statistics. The stamp is
    /// cleared.
    pub fn finish(&mut self, canvas: &mut Canvas) -> f64 {
        self.finish_with(canvas, true)
    }

    /// [`Stamper::finish`] without the clamp where polygons overlap: every polygon lays down
    /// all of its coverage times its ink, so a polygon given `amount / raster_area` (see
    /// [`raster_area`]) lays down `amount`, overlapping or not.
    pub fn finish_summed(&mut self, canvas: &mut Canvas) -> f64 {
        self.finish_with(canvas, false)
    }

    fn finish_with(&mut self, canvas: &mut Canvas, clamp: bool) -> f64 {
        if self.ends.is_empty() {
            return 0.0;
        }
        let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        for p in &self.pts {
            for a in 0..2 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
        // Bounding box in whole pixels, clipped to the canvas.
        let clip = |v: f64, max: usize| v.clamp(0.0, max as f64) as usize;
        let (x0, x1) = (
            clip(lo[0].floor(), canvas.width()),
            clip(hi[0].ceil(), canvas.width()),
        );
        let (y0, y1) = (
            clip(lo[1].floor(), canvas.height()),
            clip(hi[1].ceil(), canvas.height()),
        );
        if x0 >= x1 || y0 >= y1 {
            self.begin();
            return 0.0;
        }
        let (bw, bh) = (x1 - x0, y1 - y0);
        let stride = bw + 2;
        if self.acc.len() < stride * bh {
            self.acc.resize(stride * bh, 0.0);
        }
        self.touched.clear();
        self.touched.resize(bh, (usize::MAX, 0));

        let mut start = 0;
        let top = if clamp {
            self.weights.iter().fold(0.0f32, |a, &w| a.max(w))
        } else {
            f32::INFINITY
        };
        for (&end, &w) in self.ends.iter().zip(&self.weights) {
            scan_polygon(
                &self.pts[start..end],
                w,
                [x0 as f64, y0 as f64],
                [bw, bh],
                stride,
                &mut self.acc,
                &mut self.touched,
            );
            start = end;
        }

        let mut total = 0.0f64;
        for (row, &(lo, hi)) in self.touched.iter().enumerate() {
            if lo > hi {
                continue;
            }
            let acc = &mut self.acc[row * stride..(row + 1) * stride];
            // Past the last touched index every span has ended: the coverage is zero there.
            let end = hi.min(bw);
            self.row.clear();
            let mut sum = 0.0f32;
            let mut row_total = 0.0f32;
            for &a in &acc[lo..end] {
                sum += a;
                let c = sum.clamp(0.0, top);
                row_total += c;
                self.row.push(c);
            }
            canvas.deposit_row(y0 + row, x0 + lo, &self.row);
            acc[lo..=hi].fill(0.0);
            total += row_total as f64;
        }
        self.begin();
        total
    }
}

/// The indices of a polygon's first topmost and first bottommost vertices (least and
/// greatest y): where the stamper's and [`raster_area`]'s scans start and end, found the same
/// way so that the area is exactly what the stamper lays.
fn top_and_bottom(pts: &[[f64; 2]]) -> (usize, usize) {
    let (mut top, mut bot) = (0, 0);
    for (i, p) in pts.iter().enumerate().skip(1) {
        if p[1] < pts[top][1] {
            top = i;
        }
        if p[1] > pts[bot][1] {
            bot = i;
        }
    }
    (top, bot)
}

/// The coverage a convex polygon (pixel coordinates) lays on a `width` x `height` canvas,
/// summed over its pixels (pixel units of area): its area as the stamper samples it (on
/// four sub-scanlines per row, exact across each) and clipped to the canvas. Dividing an
/// amount of ink by it gives the weight that lays down exactly that amount.
pub fn raster_area(pts: &[[f64; 2]], width: usize, height: usize) -> f64 {
    let n = pts.len();
    if n < 3 {
        return 0.0;
    }
    let (top, bot) = top_and_bottom(pts);
    let sub = SUB as f64;
    let q0 = (pts[top][1] * sub - 0.5).ceil().max(0.0);
    let q1 = (pts[bot][1] * sub - 0.5).ceil().min((height * SUB) as f64);
    if q0 >= q1 {
        return 0.0;
    }
    let (mut a, mut b) = (top, top);
    let (mut an, mut bn) = ((top + 1) % n, (top + n - 1) % n);
    let w = width as f64;
    let mut total = 0.0;
    for q in q0 as usize..q1 as usize {
        let y = (q as f64 + 0.5) / sub;
        while pts[an][1] <= y {
            a = an;
            an = (a + 1) % n;
        }
        while pts[bn][1] <= y {
            b = bn;
            bn = (b + n - 1) % n;
        }
        let xa = edge_x(pts[a], pts[an], y);
        let xb = edge_x(pts[b], pts[bn], y);
        let (xl, xr) = if xa <= xb { (xa, xb) } else { (xb, xa) };
        total += (xr.clamp(0.0, w) - xl.clamp(0.0, w)).max(0.0);
    }
    total / sub
}

/// Adds the coverage of one convex polygon, times `weight`, to the difference rows `acc` of a `bw` x `bh`
/// pixel box (`[bw, bh]`) whose top-left pixel corner is `origin`.
fn scan_polygon(
    pts: &[[f64; 2]],
    weight: f32,
    origin: [f64; 2],
    [bw, bh]: [usize; 2],
    stride: usize,
    acc: &mut [f32],
    touched: &mut [(usize, usize)],
) {
    let n = pts.len();
    let p = |i: usize| [pts[i][0] - origin[0], pts[i][1] - origin[1]];
    let (top, bot) = top_and_bottom(pts);
    let (ymin, ymax) = (p(top)[1], p(bot)[1]);
    // Sub-scanline q samples y = (q + 1/2) / SUB; those with ymin <= y < ymax are inside.
    let sub = SUB as f64;
    let q0 = (ymin * sub - 0.5).ceil().max(0.0);
    let q1 = (ymax * sub - 0.5).ceil().min((bh * SUB) as f64);
    if q0 >= q1 {
        return;
    }
    let (q0, q1) = (q0 as usize, q1 as usize);
    // Two chains from the top vertex to the bottom one: forward and backward in index.
    let (mut a, mut b) = (top, top);
    let (mut an, mut bn) = ((top + 1) % n, (top + n - 1) % n);
    let bwf = bw as f64;
    for q in q0..q1 {
        let y = (q as f64 + 0.5) / sub;
        // Neither walk passes `bot`, whose y is beyond this sample.
        while p(an)[1] <= y {
            a = an;
            an = (a + 1) % n;
        }
        while p(bn)[1] <= y {
            b = bn;
            bn = (b + n - 1) % n;
        }
        let xa = edge_x(p(a), p(an), y);
        let xb = edge_x(p(b), p(bn), y);
        let (xl, xr) = if xa <= xb { (xa, xb) } else { (xb, xa) };
        let (xl, xr) = (xl.clamp(0.0, bwf), xr.clamp(0.0, bwf));
        if xr <= xl {
            continue;
        }
        let r = q / SUB;
        let row = &mut acc[r * stride..(r + 1) * stride];
        let first = add_edge(row, xl, SUB_WEIGHT * weight);
        let last = add_edge(row, xr, -SUB_WEIGHT * weight) + 1;
        let t = &mut touched[r];
        *t = (t.0.min(first), t.1.max(last));
    }
}

/// x where the edge `p -> q` (with `p.y <= y < q.y`) crosses height `y`.
#[inline]
fn edge_x(p: [f64; 2], q: [f64; 2], y: f64) -> f64 {
    p[0] + (y - p[1]) * (q[0] - p[0]) / (q[1] - p[1])
}

/// A span edge at `x` (0 <= x <= row.len() - 2) with weight `w`: the pixel containing `x`
/// gets the part of `w` right of `x`, the next pixel the rest. Returns the pixel's index.
#[inline]
fn add_edge(row: &mut [f32], x: f64, w: f32) -> usize {
    let i = x.floor();
    let f = (x - i) as f32;
    let i = i as usize;
    row[i] += w * (1.0 - f);
    row[i + 1] += w * f;
    i
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Ink at pixel (x, y): with an amount of 1, the stamps' summed coverage.
    fn ink_at(c: &Canvas, x: usize, y: usize) -> f32 {
        c.ink()[y * c.width() + x]
    }

    fn rect(x0: f64, y0: f64, x1: f64, y1: f64) -> [[f64; 2]; 4] {
        [[x0, y0], [x1, y0], [x1, y1], [x0, y1]]
    }

    #[test]
    fn unit_square_has_exact_area() {
        let mut c = Canvas::new(20, 20);
        let mut s = Stamper::new();
        s.begin();
        s.add_polygon(rect(3.3, 4.1, 4.3, 5.1));
        let stamped = s.finish(&mut c);
        assert!((stamped - 1.0).abs() < 1e-6, "{stamped}");
        assert!((c.total_ink() - 1.0).abs() < 1e-6);
        // Horizontal coverage is exact: 0.7 of pixel 3, 0.3 of pixel 4.
        let col3: f32 = (0..20).map(|y| ink_at(&c, 3, y)).sum();
        let col4: f32 = (0..20).map(|y| ink_at(&c, 4, y)).sum();
        assert!(
            (col3 - 0.7).abs() < 1e-6 && (col4 - 0.3).abs() < 1e-6,
            "{col3} {col4}"
        );
        assert_eq!(ink_at(&c, 10, 10), 0.0);
    }

    #[test]
    fn square_in_millimetres_through_the_frame() {
        // 1 mm^2 at 10 px/mm is 100 px^2, whatever the orientation of the polygon.
        let f = Frame::covering([0.0, 0.0], [5.0, 5.0], 1.0, 10.0);
        assert_eq!((f.width, f.height), (70, 70));
        let mut c = Canvas::new(f.width, f.height);
        let mut s = Stamper::new();
        s.begin();
        let mm = [[2.0, 2.0], [3.0, 2.0], [3.0, 3.0], [2.0, 3.0]];
        s.add_polygon(mm.iter().map(|p| f.to_px(p[0], p[1])));
        s.finish(&mut c);
        assert!((c.total_ink() - 100.0).abs() < 1e-3, "{}", c.total_ink());
        // Paper +y is up: the square (y 2..3 mm) lies in image rows (6 - 3)*10 .. (6 - 2)*10.
        assert_eq!(ink_at(&c, 35, 35), 1.0);
        assert_eq!(ink_at(&c, 35, 29), 0.0);
        assert_eq!(ink_at(&c, 35, 40), 0.0);
    }

    #[test]
    fn triangle_area_is_close() {
        let mut c = Canvas::new(50, 50);
        let mut s = Stamper::new();
        s.begin();
        s.add_polygon([[5.2, 3.7], [40.9, 10.1], [12.4, 44.6]]);
        s.finish(&mut c);
        let area: f64 = 0.5 * ((40.9 - 5.2) * (44.6 - 3.7) - (12.4 - 5.2) * (10.1 - 3.7));
        assert!(
            (c.total_ink() - area).abs() < 0.05 * area.sqrt(),
            "{}",
            c.total_ink()
        );
    }

    #[test]
    fn halves_leave_no_seam() {
        // A hexagon split along a slanted line into two convex halves, stamped together,
        // covers exactly what the whole hexagon covers.
        let whole = [
            [10.0, 3.3],
            [20.7, 6.1],
            [22.2, 14.9],
            [14.1, 21.6],
            [5.5, 17.2],
            [4.1, 8.0],
        ];
        let left = [whole[0], whole[3], whole[4], whole[5]];
        let right = [whole[0], whole[1], whole[2], whole[3]];
        let mut a = Canvas::new(30, 30);
        let mut b = Canvas::new(30, 30);
        let mut s = Stamper::new();
        s.begin();
        s.add_polygon(whole);
        s.finish(&mut a);
        s.begin();
        s.add_polygon(left);
        s.add_polygon(right);
        s.finish(&mut b);
        for (p, q) in a.ink().iter().zip(b.ink()) {
            assert!((p - q).abs() < 1e-5, "{p} vs {q}");
        }
        // The inside is solid black, seam included.
        assert_eq!(ink_at(&b, 13, 12), 1.0);
    }

    #[test]
    fn overlapping_polygons_in_one_stamp_clamp_to_one() {
        let mut c = Canvas::new(10, 10);
        let mut s = Stamper::new();
        s.begin();
        s.add_polygon(rect(1.0, 1.0, 5.0, 5.0));
        s.add_polygon(rect(3.0, 3.0, 7.0, 7.0));
        let area = s.finish(&mut c);
        assert!((area - 28.0).abs() < 1e-5, "{area}");
        assert_eq!(ink_at(&c, 4, 4), 1.0);
    }

    #[test]
    fn stamps_add_their_ink() {
        let mut c = Canvas::new(10, 10);
        let mut s = Stamper::new();
        for _ in 0..3 {
            s.begin();
            s.add_weighted_polygon(rect(2.0, 2.0, 4.5, 4.0), 0.5);
            s.finish(&mut c);
        }
        assert!((c.total_ink() - 7.5).abs() < 1e-5, "{}", c.total_ink());
        assert!((ink_at(&c, 4, 2) - 0.75).abs() < 1e-6);
        assert!((ink_at(&c, 3, 3) - 1.5).abs() < 1e-6);
    }

    #[test]
    fn clipped_at_the_canvas_edges() {
        let mut c = Canvas::new(10, 10);
        let mut s = Stamper::new();
        s.begin();
        s.add_polygon(rect(-5.0, -5.0, 2.5, 3.0));
        s.add_polygon(rect(8.0, 8.0, 15.0, 15.0));
        s.add_polygon(rect(20.0, 20.0, 25.0, 25.0));
        s.finish(&mut c);
        assert!((c.total_ink() - (2.5 * 3.0 + 4.0)).abs() < 1e-5);
        // Entirely outside: nothing.
        s.begin();
        s.add_polygon(rect(-9.0, 2.0, -1.0, 4.0));
        assert_eq!(s.finish(&mut c), 0.0);
    }

    #[test]
    fn degenerate_polygons_are_ignored() {
        let mut c = Canvas::new(10, 10);
        let mut s = Stamper::new();
        s.begin();
        s.add_polygon([[1.0, 1.0], [5.0, 5.0]]);
        s.add_polygon([[1.0, 1.0], [5.0, 1.0], [9.0, 1.0]]);
        s.add_polygon([[1.0, 1.0], [5.0, 5.0], [9.0, 9.0]]);
        assert!(s.finish(&mut c) < 1e-9);
    }

    /// Coverage of one pixel by a convex polygon, the slow and obvious way: on each
    /// sub-scanline, the polygon's span from all edges that cross it, overlapped with the pixel.
    fn reference_coverage(poly: &[[f64; 2]], px: usize, py: usize) -> f64 {
        let mut cov = 0.0;
        for sub in 0..SUB {
            let y = py as f64 + (sub as f64 + 0.5) / SUB as f64;
            let (mut xl, mut xr) = (f64::INFINITY, f64::NEG_INFINITY);
            for i in 0..poly.len() {
                let (p, q) = (poly[i], poly[(i + 1) % poly.len()]);
                let (lo, hi) = if p[1] < q[1] { (p, q) } else { (q, p) };
                if lo[1] <= y && y < hi[1] {
                    let x = edge_x(lo, hi, y);
                    xl = xl.min(x);
                    xr = xr.max(x);
                }
            }
            let overlap = (xr.min(px as f64 + 1.0) - xl.max(px as f64)).max(0.0);
            cov += overlap / SUB as f64;
        }
        cov
    }

    #[test]
    fn random_convex_polygons_match_the_reference() {
        use maobi_shared::{footprint, Vec2};
        // A fixed linear congruential generator: the test is the same every run.
        let mut seed = 0x2545_f491_4f6c_dd1du64;
        let mut rnd = move || {
            seed = seed
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        let (w, h) = (24, 20);
        let mut s = Stamper::new();
        for round in 0..200 {
            // One to three polygons per stamp, some reaching past the canvas.
            let mut polys = Vec::new();
            for _ in 0..1 + round % 3 {
                let (cx, cy, r) = (rnd() * 28.0 - 2.0, rnd() * 24.0 - 2.0, 0.3 + rnd() * 8.0);
                let mut pts: Vec<Vec2<f64>> = (0..3 + (rnd() * 12.0) as usize)
                    .map(|_| Vec2::new(cx + (rnd() - 0.5) * r, cy + (rnd() - 0.5) * r))
                    .collect();
                let mut hull = vec![Vec2::new(0.0, 0.0); pts.len() + 1];
                let n = footprint::convex_hull(&mut pts, &mut hull);
                let poly: Vec<[f64; 2]> = hull[..n].iter().map(|p| [p.x, p.y]).collect();
                polys.push(poly);
            }
            let mut c = Canvas::new(w, h);
            s.begin();
            for p in &polys {
                // Alternate orientations: the stamper accepts both.
                if round % 2 == 0 {
                    s.add_polygon(p.iter().copied());
                } else {
                    s.add_polygon(p.iter().rev().copied());
                }
            }
            s.finish(&mut c);
            for y in 0..h {
                for x in 0..w {
                    let want: f64 = polys
                        .iter()
                        .filter(|p| p.len() >= 3)
                        .map(|p| reference_coverage(p, x, y))
                        .sum::<f64>()
                        .min(1.0);
                    let got = ink_at(&c, x, y) as f64;
                    assert!(
                        (got - want).abs() < 1e-5,
                        "round {round}, pixel ({x}, {y}): {got} vs {want}, {polys:?}"
                    );
                }
            }
        }
    }

    #[test]
    fn gray_values() {
        let mut c = Canvas::new(4, 1);
        let mut s = Stamper::new();
        s.begin();
        s.add_polygon(rect(1.0, 0.0, 2.5, 1.0));
        s.finish(&mut c);
        // Ink 1 shows 1 - e^-1 dark; half of it, 1 - e^-0.5.
        assert_eq!(c.to_gray8(), [255, 94, 155, 255]);
    }
}
