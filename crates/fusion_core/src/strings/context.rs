//! What surrounds a segment: is it a piece of a longer line, is the space round its middle
//! clear?
//!
//! WHY each test (measured on the simulator's lattice towers, where legs, chords and struts
//! are as thick and as straight as a shed stack):
//! * a tower leg is cut into panel-long pieces at every joint, and each piece alone looks like
//!   a string; pieces that continue each other form one line much longer than any string;
//! * a chord of a cross-arm is webbed to the rest of the arm along its length: structure
//!   stands in the shell round its middle, where a string hangs in clear air;
//!
//! Not tested: which end hangs from the structure. A probe beyond each end was tried: a
//! tension string's attached end is the arm tip itself, whose chords run across the string,
//! not beyond it, and the far end's conductor, jumper and clamp meet there in a knot as thick
//! as steel; the probe told the two ends apart on only some of tower A's strings.
//!
//! Points of other shed-bearing segments are ignored by the shell test, so that the strings of
//! a doubled tension string or of a V pair do not hide each other.

use super::segments::{axial_radial, dot, Segment};
use super::cells::Cells;

/// Pieces whose axes differ by less than this continue each other (rad; 8 deg).
const LINE_ANGLE: f64 = 8.0 * std::f64::consts::PI / 180.0;
/// m: largest distance of one piece's centre from the other's axis, for continuing it.
const LINE_OFFSET: f64 = 0.25;
/// m: largest gap between the ends of two pieces of one line (a joint of the lattice).
const LINE_GAP: f64 = 1.0;
/// m: the shell round a segment's middle runs from SHELL_INNER (clear of its sheds) to
/// SHELL_OUTER from the axis.
const SHELL_INNER: f64 = 0.25;
const SHELL_OUTER: f64 = 0.6;
/// m: the shell leaves out this much at each end of the stack (the fittings, the arm tip, the
/// conductor clamp), but never more than half of the stack.
const SHELL_END_MARGIN: f64 = 0.35;
/// Structure allowed in the shell: this fraction of the segment's own points (a few stray
/// returns), at least SHELL_MIN_ALLOWED points.
const SHELL_MAX_FRACTION: f64 = 0.03;
const SHELL_MIN_ALLOWED: usize = 3;
/// For every segment, the length (m) of the line it is a piece of (itself alone: its extent).
/// Only pieces of at least `min_piece` m (their shed stack's length) join lines.
///
/// WHY the floor: the two strings of a tension tip are 12 deg apart, too far to continue each
/// other, but a short piece of the tip's steel between them, 6 deg from each, chained them into
/// one line; a leg's panels are each as long as a string.
pub(super) fn line_lengths(segments: &[Segment], min_piece: f64) -> Vec<f64> {
    let n = segments.len();
    let mut parent: Vec<usize> = (0..n).collect();
    fn root(parent: &mut [usize], mut x: usize) -> usize {
        while parent[x] != x {
            parent[x] = parent[parent[x]];
            x = parent[x];
        }
        x
    }
    let cos_max = LINE_ANGLE.cos();
    for i in 0..n {
        for j in i + 1..n {
            let (a, b) = (&segments[i], &segments[j]);
            if a.length < min_piece || b.length < min_piece || dot(a.axis, b.axis).abs() < cos_max {
                continue;
            }
            let (along, off) = axial_radial(b.center, a.center, a.axis);
            if off > LINE_OFFSET {
                continue;
            }
            // b's extent on a's axis, against a's.
            let s = dot(a.axis, b.axis).signum();
            let (b0, b1) = (along + s * b.extent.0, along + s * b.extent.1);
            let gap = b0.min(b1).max(a.extent.0) - b0.max(b1).min(a.extent.1);
            if gap <= LINE_GAP {
                let (ri, rj) = (root(&mut parent, i), root(&mut parent, j));
                parent[ri] = rj;
            }
        }
    }
    let roots: Vec<usize> = (0..n).map(|i| root(&mut parent, i)).collect();
    let mut lengths = vec![0.0; n];
    for (i, length) in lengths.iter_mut().enumerate() {
        let a = &segments[i];
        let (mut lo, mut hi) = (a.extent.0, a.extent.1);
        for (j, b) in segments.iter().enumerate() {
            if j != i && roots[j] == roots[i] {
                let s = dot(a.axis, b.axis).signum();
                let (along, _) = axial_radial(b.center, a.center, a.axis);
                for e in [b.extent.0, b.extent.1] {
                    lo = lo.min(along + s * e);
                    hi = hi.max(along + s * e);
                }
            }
        }
        *length = hi - lo;
    }
    lengths
}

/// Axis-aligned bounds of the ball at `c` of radius `r`.
fn ball_box(c: [f64; 3], r: f64) -> ([f64; 3], [f64; 3]) {
    ([c[0] - r, c[1] - r, c[2] - r], [c[0] + r, c[1] + r, c[2] + r])
}

/// Whether the shell round the middle of `seg` is clear: points of `cloud` for which
/// `counts(i)` holds, between SHELL_INNER and SHELL_OUTER from the axis.
pub(super) fn shell_is_clear(seg: &Segment, cloud: &[[f64; 3]], cells: &Cells, counts: impl Fn(usize) -> bool) -> bool {
    let half = 0.5 * seg.length;
    let reach = (half - SHELL_END_MARGIN).max(0.5 * half);
    let (lo, hi) = ball_box(seg.center, reach + SHELL_OUTER);
    let mut found = 0usize;
    cells.for_each_in_box(lo, hi, |i| {
        let (t, r) = axial_radial(cloud[i], seg.center, seg.axis);
        if t.abs() <= reach && (SHELL_INNER..=SHELL_OUTER).contains(&r) && counts(i) {
            found += 1;
        }
    });
    found <= SHELL_MIN_ALLOWED.max((SHELL_MAX_FRACTION * seg.members.len() as f64) as usize)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn piece(center: [f64; 3], axis: [f64; 3], half: f64) -> Segment {
        Segment { center, axis, length: 2.0 * half, extent: (-half, half), radius: 0.1, members: vec![0; 100], contrast: 0.0, cuts: Vec::new() }
    }

    #[test]
    fn collinear_pieces_with_short_gaps_form_one_line() {
        let up = [0.0, 0.0, 1.0];
        let segs = vec![
            piece([0.0, 0.0, 1.0], up, 1.0),
            piece([0.05, 0.0, 3.5], up, 1.0),  // 0.5 m gap: same line
            piece([0.0, 0.0, 7.0], up, 1.0),   // 1.5 m gap: another line
            piece([1.0, 0.0, 1.0], up, 1.0),   // parallel, 1 m aside
            piece([0.0, 0.0, 5.5], [1.0, 0.0, 0.0], 1.0), // across
        ];
        let l = line_lengths(&segs, 0.5);
        assert!((l[0] - 4.5).abs() < 1e-9 && (l[1] - 4.5).abs() < 1e-9, "{l:?}");
        assert!((l[2] - 2.0).abs() < 1e-9 && (l[3] - 2.0).abs() < 1e-9 && (l[4] - 2.0).abs() < 1e-9);
        // Pieces shorter than the floor join nothing.
        let l = line_lengths(&segs, 2.5);
        assert!(l.iter().all(|&x| (x - 2.0).abs() < 1e-9), "{l:?}");
    }

    #[test]
    fn structure_in_the_shell_round_the_middle_is_seen() {
        let seg = piece([0.0; 3], [0.0, 0.0, 1.0], 1.0);
        // A wall of points 0.4 m from the axis, and a blob beyond the top end (not in the shell).
        let mut cloud = vec![[0.4, 0.0, 0.0], [0.4, 0.1, 0.1], [0.4, -0.1, 0.2], [0.4, 0.0, -0.3], [0.4, 0.0, 0.3]];
        cloud.extend((0..10).map(|k| [0.0, 0.01 * f64::from(k), 1.6]));
        let cells = Cells::new(&cloud, 0.15);
        assert!(!shell_is_clear(&seg, &cloud, &cells, |_| true));
        assert!(shell_is_clear(&seg, &cloud, &cells, |i| i >= 5));
    }
}
