//! The bounded method's rule for a box that holds more than one line: take the line that is
//! clearly the insulator, refuse the box when it cannot tell.
//!
//! The line fit takes the *nearest* cluster in the box: the insulator stands in front of the
//! steel and conductors seen through its box. A conductor or a member in front of the string,
//! running along it inside the box, breaks that premise: it is fitted, bounded by the box,
//! and looks like a string of the right size. The string behind it is still in the box, and
//! is the larger line. So, given the insulator's known length, the method looks at the other
//! lines in the box (the same fit on the points farther than tau from the lines found so far,
//! nearest first, at most [`MAX_OTHER_LINES`], so a second wire in front is peeled off before
//! the string is reached). A *rival* is another line that
//!
//! * rests on more points than the fitted line,
//! * has its (bounded) centre more than [`SEPARATION`] from the fitted one's, and
//! * fits the box's scale better: the known length, projected at the line's centre along
//!   its axis, spans the box's longer side to within [`SCALE_TOLERANCE`] and closer to it
//!   than the fitted line's does (median over the views).
//!
//! The first rival found decides: if it fits the scale better by more than the box's own
//! noise ([`SCALE_MARGIN`]) it is the insulator, and the method returns it; otherwise the
//! box cannot tell the two apart and is refused ([`FusionError::Ambiguous`]).
//!
//! A string in front of the lattice keeps its localization: the steel behind it projects
//! smaller than the box. In the clutter study (`insulator_rs.evaluation.clutter_study`)
//! every gross error (0.7-1.9 m) was a conductor 0.7-1.6 m in front of the string, along it
//! in the box, fitted instead of it.

use nalgebra::{Point3, Vector3};

use crate::localize::bounded::{bound_line, BoxEvidence, LineBounds};
use crate::error::{FusionError, Result};
use crate::localize::{dbscan_ransac_line, InsulatorLine, LocalizeParams};
use crate::ransac::line_distance;

/// The known length of an insulator at its localized centre, projected into a view, must
/// span the box's longer side to within this factor to be a plausible insulator at the
/// box's scale (a far-side insulator seen through the lattice gets localized on the nearer
/// lattice, and then looks too long for its box). Read by the Python pipeline's size gate
/// too (`ir.SCALE_TOLERANCE`).
pub const SCALE_TOLERANCE: f64 = 1.5;
/// Metres: another line whose centre lies farther than this from the fitted one's is
/// another object (the clutter study's conductors stood 0.7-1.6 m in front of the string);
/// nearer, it is the same string seen again (its far surface, a shed row).
pub const SEPARATION: f64 = 0.3;
/// The other lines looked at, nearest first (each peeled off before the next is fitted).
pub const MAX_OTHER_LINES: usize = 4;
/// A rival that fits the scale better than the fitted line by more than this (in
/// |ln(ratio)|, about 10 %) is told apart and returned; within it, the box is refused. A
/// detector's box edges wander by a few percent of the box (the studies' stand-in: 3 %, one
/// sigma, on each edge), so the box's longer side, and with it both ratios, by about 4 %: 10 %
/// is over two sigma of that noise. In the clutter study the rivals of every conductor fitted
/// in front of a string fit 10-80 % better but for two of twelve (1 and 7 %).
pub const SCALE_MARGIN: f64 = 0.095;

/// The ratio of the known `length`'s projected span (px), at `center` along `direction`
/// (frame B), to the longer side of each view's box; the median over the views in front of
/// which both ends lie, `None` if there is none.
pub(crate) fn scale_ratio(center: [f64; 3], direction: [f64; 3], length: f64, evidence: &BoxEvidence<'_>) -> Option<f64> {
    let c = Point3::from(center);
    let half = Vector3::from(direction).normalize() * (0.5 * length);
    let mut ratios: Vec<f64> = evidence
        .views
        .iter()
        .filter_map(|view| {
            let t_c_b = view.t_b_c.inverse();
            let (p0, p1) = (t_c_b * (c - half), t_c_b * (c + half));
            let uv0 = evidence.camera.project_xyz(p0.x, p0.y, p0.z)?;
            let uv1 = evidence.camera.project_xyz(p1.x, p1.y, p1.z)?;
            let predicted = (uv1[0] - uv0[0]).abs().max((uv1[1] - uv0[1]).abs());
            let b = &view.pixel_box;
            let measured = (b.x2 - b.x1).max(b.y2 - b.y1).max(1.0);
            Some(predicted / measured)
        })
        .collect();
    if ratios.is_empty() {
        return None;
    }
    ratios.sort_by(f64::total_cmp);
    let h = ratios.len() / 2;
    Some(if ratios.len() % 2 == 1 { ratios[h] } else { 0.5 * (ratios[h - 1] + ratios[h]) })
}

/// The points farther than `tau` from `line`.
fn off_line(points: &[[f64; 3]], line: &InsulatorLine, tau: f64) -> Vec<[f64; 3]> {
    points.iter().copied().filter(|p| line_distance(p, &line.point, &line.direction) > tau).collect()
}

fn distance(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

/// What the rule decided about the fitted line.
#[derive(Debug)]
pub(crate) enum Verdict {
    /// No rival: the fitted line is the insulator.
    Fitted,
    /// A rival told apart from the fitted line: it is the insulator, with its bounds.
    Rival(InsulatorLine, LineBounds),
}

/// The rule of the module docs for the fitted line `fitted`, its bounded centre `center`:
/// `Fitted`, `Rival` or `Err(Ambiguous)`. `Fitted` also when no scale can be compared (the
/// line's ends behind every camera).
pub(crate) fn resolve(
    coords: &[[f64; 3]],
    params: &LocalizeParams,
    evidence: &BoxEvidence<'_>,
    fitted: &InsulatorLine,
    center: [f64; 3],
    length: f64,
) -> Result<Verdict> {
    let Some(mine) = scale_ratio(center, fitted.direction, length, evidence) else {
        return Ok(Verdict::Fitted);
    };
    let n_fitted = fitted.members.len();
    let mut rest = off_line(coords, fitted, params.tau);
    for _ in 0..MAX_OTHER_LINES {
        if rest.len() <= n_fitted {
            return Ok(Verdict::Fitted); // too few points left for a larger line
        }
        let other = match dbscan_ransac_line(&rest, params) {
            Ok(line) => line,
            Err(FusionError::NoInsulator(_)) => return Ok(Verdict::Fitted),
            Err(e) => return Err(e),
        };
        if other.members.len() > n_fitted {
            let bounds = bound_line(&other, evidence)?;
            let other_center = other.at(bounds.t_center);
            let apart = distance(other_center, center);
            let theirs = scale_ratio(other_center, other.direction, length, evidence)
                .filter(|r| (1.0 / SCALE_TOLERANCE..=SCALE_TOLERANCE).contains(r));
            if let Some(theirs) = theirs.filter(|r| apart > SEPARATION && r.ln().abs() < mine.ln().abs()) {
                if mine.ln().abs() - theirs.ln().abs() > SCALE_MARGIN {
                    return Ok(Verdict::Rival(other, bounds));
                }
                return Err(FusionError::Ambiguous(format!(
                    "another line {apart:.2} m from the fitted one, on {} points against {n_fitted}, fits the \
                     box's scale about as well (known length over box: {theirs:.2} against {mine:.2})",
                    other.members.len()
                )));
            }
        }
        rest = off_line(&rest, &other, params.tau);
    }
    Ok(Verdict::Fitted)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::localize::bounded::BoxView;
    use crate::culling::PixelBox;
    use crate::localize::Method;
    use crate::test_scenes::{dist, ends, forward_camera, pinhole, seen_part, segment_box};
    use crate::Localization;

    /// A 2 m horizontal string 9 m ahead, across the view (two rows of returns, 202 points),
    /// and its box (10 px of shed radius above and below the axis).
    const STRING_CENTER: [f64; 3] = [9.0, 0.0, 0.0];
    const ACROSS: [f64; 3] = [0.0, 1.0, 0.0];
    const LENGTH: f64 = 2.0;

    fn string_points() -> Vec<[f64; 3]> {
        let mut pts = seen_part(STRING_CENTER, ACROSS, LENGTH, 0.0, 1.0);
        pts.extend(seen_part([9.0, 0.0, 0.03], ACROSS, LENGTH, 0.0, 1.0));
        pts
    }

    fn string_box() -> PixelBox {
        let (e0, e1) = ends(STRING_CENTER, ACROSS, LENGTH);
        let mut bx = segment_box(&pinhole(), &forward_camera(), e0, e1);
        bx.y1 -= 10.0;
        bx.y2 += 10.0;
        bx
    }

    /// A line of returns at `x` m ahead along the string, `every` 2 cm sample kept, only the
    /// part inside the string's box (as the culling leaves it).
    fn line_in_box(x: f64, z: f64, every: usize) -> Vec<[f64; 3]> {
        let half = 0.5 * LENGTH * x / 9.0;
        seen_part([x, 0.0, z], ACROSS, 2.0 * half, 0.0, 1.0).into_iter().step_by(every).collect()
    }

    fn bounded(pts: &[[f64; 3]], length: Option<f64>) -> Result<Localization> {
        bounded_in(pts, length, string_box())
    }

    fn bounded_in(pts: &[[f64; 3]], length: Option<f64>, pixel_box: PixelBox) -> Result<Localization> {
        let cam = pinhole();
        let views = [BoxView { pixel_box, t_b_c: forward_camera() }];
        let evidence = BoxEvidence { insulator_length: length, ..BoxEvidence::new(&views, &cam) };
        crate::localize(pts, Method::Bounded, &LocalizeParams::default(), Some(&evidence))
    }

    /// The string's points and, 1 m in front, a conductor along it inside its box, half as
    /// dense: the nearest cluster, so the line fit takes it, and the box bounds it to a
    /// string's size.
    fn string_behind_a_conductor() -> Vec<[f64; 3]> {
        let mut pts = string_points();
        pts.extend(line_in_box(8.0, 0.05, 2));
        pts
    }

    #[test]
    fn conductor_in_front_of_the_string_is_told_apart() {
        let pts = string_behind_a_conductor();
        // Without the length there is no scale to judge: the conductor is returned (1 m off).
        let blind = bounded(&pts, None).unwrap();
        assert!(dist(blind.center, STRING_CENTER) > 0.9, "{:?}", blind.center);
        // With it: the conductor's known length spans 9/8 of the box, the string's exactly the
        // box (12 % better, over SCALE_MARGIN): the string is returned, on its own points.
        let loc = bounded(&pts, Some(LENGTH)).unwrap();
        assert!(dist(loc.center, STRING_CENTER) < 0.05, "{:?}", loc.center);
        assert_eq!(loc.n_points, string_points().len());
        assert_eq!((loc.ends_from_image, loc.n_clusters), (2, blind.n_clusters));
        assert!((loc.length.unwrap() - LENGTH).abs() < 0.05, "{:?}", loc.length);
    }

    #[test]
    fn rival_that_fits_about_as_well_is_refused() {
        // The same scene in a box 5 % larger about its centre: the conductor's length spans 1.07
        // of it, the string's 0.95; the string fits better, by 2 % only (under SCALE_MARGIN).
        let bx = string_box();
        let (cx, cy, k) = (0.5 * (bx.x1 + bx.x2), 0.5 * (bx.y1 + bx.y2), 1.05);
        let big = PixelBox {
            x1: cx - k * (cx - bx.x1),
            y1: cy - k * (cy - bx.y1),
            x2: cx + k * (bx.x2 - cx),
            y2: cy + k * (bx.y2 - cy),
        };
        match bounded_in(&string_behind_a_conductor(), Some(LENGTH), big) {
            Err(FusionError::Ambiguous(msg)) => assert!(msg.contains("about as well"), "{msg}"),
            other => panic!("expected Ambiguous, got {other:?}"),
        }
    }

    #[test]
    fn string_in_front_of_the_lattice_is_kept() {
        // A member 1 m behind the string, along it, denser (three rows): larger, but it projects
        // smaller than the box, so the string stays localized.
        let mut pts = string_points();
        for z in [0.0, 0.03, 0.06] {
            pts.extend(line_in_box(10.0, z, 1));
        }
        let loc = bounded(&pts, Some(LENGTH)).unwrap();
        assert!(dist(loc.center, STRING_CENTER) < 0.05, "{:?}", loc.center);
        assert_eq!(loc.ends_from_image, 2);
    }

    #[test]
    fn a_smaller_line_behind_is_no_ambiguity() {
        // The conductor in front but with more points than the string behind: the fit's premise
        // holds for the larger line, no refusal (the box's string is then the conductor's).
        let mut pts = seen_part(STRING_CENTER, ACROSS, LENGTH, 0.0, 1.0).into_iter().step_by(3).collect::<Vec<_>>();
        pts.extend(line_in_box(8.0, 0.05, 1));
        assert!(bounded(&pts, Some(LENGTH)).is_ok());
    }

    #[test]
    fn scale_ratio_is_the_known_length_over_the_box() {
        let cam = pinhole();
        let views = [BoxView { pixel_box: string_box(), t_b_c: forward_camera() }];
        let evidence = BoxEvidence::new(&views, &cam);
        // 2 m at 9 m across a 700 px focal length: 155.6 px, the box's longer side exactly.
        let r = scale_ratio(STRING_CENTER, ACROSS, LENGTH, &evidence).unwrap();
        assert!((r - 1.0).abs() < 1e-6, "{r}");
        // at 8 m: 9/8
        let r = scale_ratio([8.0, 0.0, 0.0], ACROSS, LENGTH, &evidence).unwrap();
        assert!((r - 9.0 / 8.0).abs() < 1e-6, "{r}");
        // behind the camera: no scale
        assert!(scale_ratio([-8.0, 0.0, 0.0], ACROSS, LENGTH, &evidence).is_none());
    }
}
