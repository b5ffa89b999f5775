//! The window's icon, drawn in code at start: a drop of ink on a warm paper tile, with a
//! small vermilion seal in the corner. Drawing it here keeps the binary free of image files
//! and of a decoder for them, and it is the same on every platform.

/// The icon's side (pixels): large enough for a task bar or a dock, small enough to draw
/// at start without anyone noticing.
pub const SIZE: u32 = 64;

/// Samples per pixel along each axis: the shapes' edges are anti-aliased by coverage.
const SUPERSAMPLE: u32 = 4;

const PAPER: [u8; 3] = [0xf4, 0xec, 0xd8];
const INK: [u8; 3] = [0x1c, 0x1a, 0x18];
const SEAL: [u8; 3] = [0xc0, 0x36, 0x28];

/// The icon as eframe takes it: [`SIZE`] x [`SIZE`] straight-alpha RGBA.
pub fn icon() -> egui::IconData {
    egui::IconData {
        rgba: rgba(),
        width: SIZE,
        height: SIZE,
    }
}

/// The icon's pixels, row by row, 4 bytes (RGBA, straight alpha) a pixel.
pub fn rgba() -> Vec<u8> {
    let n = SIZE as usize;
    let mut out = Vec::with_capacity(n * n * 4);
    let step = 1.0 / SUPERSAMPLE as f64;
    for y in 0..SIZE {
        for x in 0..SIZE {
            // Coverage of each layer over this pixel's samples.
            let (mut tile, mut ink, mut seal) = (0.0, 0.0, 0.0);
            for sy in 0..SUPERSAMPLE {
                for sx in 0..SUPERSAMPLE {
                    let p = [
                        x as f64 + (sx as f64 + 0.5) * step,
                        y as f64 + (sy as f64 + 0.5) * step,
                    ];
                    if in_rounded_square(p, [2.0, 2.0], 60.0, 12.0) {
                        tile += 1.0;
                        if in_drop(p) {
                            ink += 1.0;
                        } else if in_rounded_square(p, [44.0, 44.0], 12.0, 2.5) {
                            seal += 1.0;
                        }
                    }
                }
            }
            let samples = (SUPERSAMPLE * SUPERSAMPLE) as f64;
            let alpha = tile / samples;
            // The colour within the tile: paper, ink and seal mixed by their coverage.
            let colour = |c: usize| {
                if tile == 0.0 {
                    return 0;
                }
                let paper = tile - ink - seal;
                let v =
                    (paper * PAPER[c] as f64 + ink * INK[c] as f64 + seal * SEAL[c] as f64) / tile;
                v.round() as u8
            };
            out.extend_from_slice(&[
                colour(0),
                colour(1),
                colour(2),
                (alpha * 255.0).round() as u8,
            ]);
        }
    }
    out
}

/// Whether `p` lies in the square at `origin` of side `side` with corners rounded by `r`.
fn in_rounded_square(p: [f64; 2], origin: [f64; 2], side: f64, r: f64) -> bool {
    let half = side / 2.0;
    let c = [origin[0] + half, origin[1] + half];
    // Distance beyond the inner square the corners are rounded around.
    let dx = ((p[0] - c[0]).abs() - (half - r)).max(0.0);
    let dy = ((p[1] - c[1]).abs() - (half - r)).max(0.0);
    (p[0] - c[0]).abs() <= half && (p[1] - c[1]).abs() <= half && dx * dx + dy * dy <= r * r
}

/// Whether `p` lies in the ink drop: a round belly low on the left and a cone narrowing to a
/// tip up and to the right, the mark a loaded brush leaves when it is pressed and lifted
/// away (點).
fn in_drop(p: [f64; 2]) -> bool {
    const BELLY: [f64; 2] = [27.0, 38.0];
    const RADIUS: f64 = 14.0;
    const TIP: [f64; 2] = [46.0, 8.0];
    let d = [p[0] - BELLY[0], p[1] - BELLY[1]];
    if d[0] * d[0] + d[1] * d[1] <= RADIUS * RADIUS {
        return true;
    }
    // Along the axis from the tip (0) to the belly's centre (1), and the distance off it.
    let axis = [BELLY[0] - TIP[0], BELLY[1] - TIP[1]];
    let len = axis[0].hypot(axis[1]);
    let u = [axis[0] / len, axis[1] / len];
    let q = [p[0] - TIP[0], p[1] - TIP[1]];
    let t = (q[0] * u[0] + q[1] * u[1]) / len;
    let off = (q[0] * u[1] - q[1] * u[0]).abs();
    (0.0..=1.0).contains(&t) && off <= RADIUS * t
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pixel(rgba: &[u8], x: u32, y: u32) -> [u8; 4] {
        let i = ((y * SIZE + x) * 4) as usize;
        rgba[i..i + 4].try_into().unwrap()
    }

    #[test]
    fn icon_is_its_stated_size_and_not_blank() {
        let icon = icon();
        assert_eq!((icon.width, icon.height), (SIZE, SIZE));
        assert_eq!(icon.rgba.len(), (SIZE * SIZE * 4) as usize);
        // Transparent outside the tile's rounded corner, opaque paper inside it.
        assert_eq!(pixel(&icon.rgba, 0, 0)[3], 0);
        assert_eq!(
            pixel(&icon.rgba, 6, 32),
            [PAPER[0], PAPER[1], PAPER[2], 255]
        );
        // The drop's belly is ink, the seal vermilion.
        assert_eq!(pixel(&icon.rgba, 27, 38), [INK[0], INK[1], INK[2], 255]);
        assert_eq!(pixel(&icon.rgba, 50, 50), [SEAL[0], SEAL[1], SEAL[2], 255]);
        // Each colour covers a good part of it, and the edges are blended.
        let count = |c: [u8; 3]| {
            icon.rgba
                .chunks(4)
                .filter(|p| p[..3] == c && p[3] == 255)
                .count()
        };
        let all = (SIZE * SIZE) as usize;
        assert!(count(INK) > all / 10, "{}", count(INK));
        assert!(count(PAPER) > all / 4, "{}", count(PAPER));
        assert!(count(SEAL) > 50, "{}", count(SEAL));
        let blended = icon
            .rgba
            .chunks(4)
            .filter(|p| p[3] == 255 && ![PAPER, INK, SEAL].iter().any(|c| p[..3] == *c))
            .count();
        assert!(blended > 50, "{blended}");
    }
}
