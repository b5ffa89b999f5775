//! "Stay in the lane" from a pose track: the track's path on the paper, as the pieces
//! `maobi_shared::guide::Lane` keeps the hand near.

use crate::poses::PoseTrack;
use maobi_shared::guide::Lane;

/// The fixture a host-run force loop keeps: the path's pieces, each a polyline (mm).
pub type HostLane = Lane<Vec<Vec<[f64; 2]>>, Vec<[f64; 2]>>;

/// Points of a piece closer than this to the last one kept are dropped (mm): the search for
/// the nearest point runs every tick.
const SPACING_MM: f64 = 0.5;

/// The pieces of `track`'s path where a head `head_mm` long presses the paper (the ferrule at
/// or below touching height, `head_mm cos(tilt)`), x-y, split where it lifts.
pub fn pieces(track: &PoseTrack, head_mm: f64) -> Vec<Vec<[f64; 2]>> {
    let mut pieces: Vec<Vec<[f64; 2]>> = Vec::new();
    // The piece being gathered and its last pressed point (kept whatever the spacing: a
    // piece ends where the stroke does).
    let mut open: Option<(Vec<[f64; 2]>, [f64; 2])> = None;
    let close = |open: &mut Option<(Vec<[f64; 2]>, [f64; 2])>, pieces: &mut Vec<_>| {
        if let Some((mut piece, last)) = open.take() {
            if piece.last() != Some(&last) {
                piece.push(last);
            }
            pieces.push(piece);
        }
    };
    for pose in track.resample() {
        let [x, y, z] = pose.pos.to_f64();
        let q = pose.rot;
        let touching = head_mm * (1.0 - 2.0 * (q.x * q.x + q.y * q.y));
        if z > touching {
            close(&mut open, &mut pieces);
            continue;
        }
        let (piece, last) = open.get_or_insert_with(|| (Vec::new(), [x, y]));
        *last = [x, y];
        if piece
            .last()
            .is_none_or(|l| (l[0] - x).hypot(l[1] - y) >= SPACING_MM)
        {
            piece.push([x, y]);
        }
    }
    close(&mut open, &mut pieces);
    pieces
}
