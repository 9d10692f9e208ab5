//! The fifth localization method, [`Method::Bounded`](crate::Method::Bounded): the LiDAR
//! gives the insulator's line, the camera gives its ends.
//!
//! The LiDAR sees only part of a string (a few returns per shed, sheds hidden behind
//! each other, the far end beyond the Mid-360's field), so the paper's centres (median
//! or centroid of the points) move with whichever part it hit; that is most of their
//! error, and it lies along the axis. The detection box, though, spans the whole
//! visible insulator in the image. This method fits the line as Algorithm 1 does
//! (nearest DBSCAN cluster, RANSAC line, inliers within tau) and then, for each
//! detection event's box, walks along that line from the points' median until its
//! projection (through the full camera model, distortion included) leaves the box:
//! the two exits bound the insulator's extent on the line. Over several events the
//! median of each bound is taken; the centre is the middle of the two.
//!
//! A box edge on the image border (within `border_margin` px) does not bound anything
//! (the insulator may go on beyond the frame), nor does a line that leaves the camera's
//! front half-space or runs on for `max_extent` m (seen end-on). With one bound left the
//! centre is that end plus half the insulator's known length (if given); with none it
//! is Algorithm 1's centre. [`Localization::ends_from_image`] says which.
//!
//! Given the insulator's length, the method also looks at the other lines in the box
//! ([`ambiguity`]): another, larger line that fits the length clearly better is taken
//! instead of the fitted one (a conductor in front of the string), and a box where the two fit
//! about as well is refused. With both ends bounded, a line whose bounded extent is not the
//! known length (within [`SCALE_TOLERANCE`]) crosses the box: no insulator.
//!
//! Frames: points in B; each view's camera pose `t_b_c` (C -> B) in that same B.

use nalgebra::{Isometry3, Point3, Vector3};

// The rule for a box holding several lines lives beside the method it serves, as its child:
// it reads the method's box evidence and line bounds, and the method asks it for a verdict.
pub mod ambiguity;

use crate::camera::CameraModel;
use crate::culling::PixelBox;
use crate::error::{check_positive, invalid, FusionError, Result};
use ambiguity::{resolve, Verdict, SCALE_TOLERANCE};
use crate::localize::{dbscan_ransac_line, InsulatorLine, Localization, LocalizeParams};

/// Pixels: a box edge this close to the image border is the frame's edge, not the insulator's.
pub const DEFAULT_BORDER_MARGIN: f64 = 2.0;
/// Metres: the walk along the line stops this far from the points' median (a line seen
/// nearly end-on exits the box far away, or never: no bound). Longer than the longest
/// strings of transmission lines (400 kV: about 4 m).
pub const DEFAULT_MAX_EXTENT: f64 = 6.0;
/// The tuning of [`BoxEvidence`], by their Python keyword names (see `Method::parameters`).
pub const BOX_PARAMETERS: [&str; 3] = ["insulator_length", "border_margin", "max_extent"];
/// Metres: walking step along the line before the exit is refined by bisection. The box
/// is convex and the projected line nearly straight, so a step only has to be shorter
/// than the insulator (it cannot skip out and back in).
const WALK_STEP: f64 = 0.02;
/// Metres: bisection stops when the exit is bracketed this tightly.
const EXIT_TOLERANCE: f64 = 1e-6;

/// One detection event: its box (pixels) and where its camera was, `t_b_c` (C -> B).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BoxView {
    pub pixel_box: PixelBox,
    pub t_b_c: Isometry3<f64>,
}

/// What the bounded method reads besides the cloud: the detection events' boxes, the camera
/// that took them, and the method's own tuning.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BoxEvidence<'a> {
    /// The detection events (at least one).
    pub views: &'a [BoxView],
    /// The camera model of every view.
    pub camera: &'a CameraModel,
    /// Known length of the insulator string (m): places the centre when the image bounds
    /// only one end, and lets the method refuse an ambiguous box ([`ambiguity`]).
    pub insulator_length: Option<f64>,
    /// See [`DEFAULT_BORDER_MARGIN`].
    pub border_margin: f64,
    /// See [`DEFAULT_MAX_EXTENT`].
    pub max_extent: f64,
}

impl<'a> BoxEvidence<'a> {
    /// The boxes of `views` in `camera`, without a known length, default tuning.
    pub fn new(views: &'a [BoxView], camera: &'a CameraModel) -> Self {
        Self {
            views,
            camera,
            insulator_length: None,
            border_margin: DEFAULT_BORDER_MARGIN,
            max_extent: DEFAULT_MAX_EXTENT,
        }
    }

    /// Validates every field, naming it as the Python keyword argument.
    pub fn validate(&self) -> Result<()> {
        self.camera.validate()?;
        if self.views.is_empty() {
            return Err(invalid("boxes", "need at least one detection box"));
        }
        for v in self.views {
            v.pixel_box.validate("boxes")?;
        }
        if let Some(l) = self.insulator_length {
            check_positive("insulator_length", l)?;
        }
        if !(self.border_margin.is_finite() && self.border_margin >= 0.0) {
            return Err(invalid("border_margin", format!("must be finite and >= 0, got {}", self.border_margin)));
        }
        check_positive("max_extent", self.max_extent)
    }
}

/// Where the walk along the line left the box, on one side.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Exit {
    /// Through an edge of the box that is not on the image border, at line parameter t.
    Bound(f64),
    /// Through the image border, behind the camera, or not within `max_extent`.
    Open,
}

/// The line in one view's camera frame and what "inside the box" means there.
struct ViewLine<'a> {
    a: Vector3<f64>,
    d: Vector3<f64>,
    cam: &'a CameraModel,
    pixel_box: PixelBox,
}

impl ViewLine<'_> {
    fn pixel(&self, t: f64) -> Option<[f64; 2]> {
        let p = self.a + self.d * t;
        self.cam.project_xyz(p.x, p.y, p.z)
    }

    fn inside(&self, t: f64) -> bool {
        self.pixel(t).is_some_and(|uv| self.pixel_box.contains(uv))
    }

    /// True when the box edge nearest `uv` lies on the image border (within `margin` px).
    fn exits_through_border(&self, uv: [f64; 2], margin: f64) -> bool {
        let b = &self.pixel_box;
        let (w, h) = (f64::from(self.cam.width), f64::from(self.cam.height));
        // (distance of uv to the edge, the edge is on the border)
        let edges = [
            ((uv[0] - b.x1).abs(), b.x1 <= margin),
            ((uv[0] - b.x2).abs(), b.x2 >= w - margin),
            ((uv[1] - b.y1).abs(), b.y1 <= margin),
            ((uv[1] - b.y2).abs(), b.y2 >= h - margin),
        ];
        edges.iter().min_by(|x, y| x.0.total_cmp(&y.0)).is_some_and(|e| e.1)
    }

    /// Walks from `t0` (inside) in direction `sign` until the projection leaves the box.
    fn exit(&self, t0: f64, sign: f64, evidence: &BoxEvidence<'_>) -> Exit {
        let steps = (evidence.max_extent / WALK_STEP).ceil() as usize;
        let mut inside_t = t0;
        for k in 1..=steps {
            let t = t0 + sign * (k as f64 * WALK_STEP).min(evidence.max_extent);
            if self.inside(t) {
                inside_t = t;
                continue;
            }
            // Bracketed: inside at inside_t, outside at t. Bisect to the crossing.
            let (mut lo, mut hi) = (inside_t, t);
            while (hi - lo).abs() > EXIT_TOLERANCE {
                let mid = 0.5 * (lo + hi);
                if self.inside(mid) {
                    lo = mid;
                } else {
                    hi = mid;
                }
            }
            // The crossing pixel: where the line meets the box edge (just inside it).
            return match self.pixel(lo) {
                Some(uv) if self.pixel(hi).is_some() && !self.exits_through_border(uv, evidence.border_margin) => {
                    Exit::Bound(0.5 * (lo + hi))
                }
                _ => Exit::Open, // behind the camera, or the frame's edge
            };
        }
        Exit::Open
    }
}

fn median(v: &mut [f64]) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let h = v.len() / 2;
    Some(if v.len() % 2 == 1 { v[h] } else { 0.5 * (v[h - 1] + v[h]) })
}

/// The bounds (lower, upper) of the line parameter each view's box gives, as the line
/// `(a, d)` in B; `None` for a view whose box the line does not pass through at `t0`.
fn view_bounds(line: &InsulatorLine, t0: f64, view: &BoxView, evidence: &BoxEvidence<'_>) -> Option<(Exit, Exit)> {
    let t_c_b = view.t_b_c.inverse();
    let a = t_c_b * Point3::from(line.point);
    let d = t_c_b.rotation * Vector3::from(line.direction);
    let vl = ViewLine { a: a.coords, d, cam: evidence.camera, pixel_box: view.pixel_box };
    if !vl.inside(t0) {
        return None;
    }
    Some((vl.exit(t0, -1.0, evidence), vl.exit(t0, 1.0, evidence)))
}

/// Where the boxes put the insulator on a line.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct LineBounds {
    /// The centre, as the line parameter `t` (point `a + t d`).
    pub t_center: f64,
    /// Ends bounded by the image (see [`Localization::ends_from_image`]).
    pub ends_from_image: usize,
    /// Extent (m) between the two image bounds, when both ends were bounded.
    pub length: Option<f64>,
    /// Views whose box the line passed through.
    pub views_used: usize,
}

/// The insulator's centre on `line` from the boxes: the middle of the median bounds, or one
/// bound plus half the known length, or (no bound) the median projection of the line's points.
pub(crate) fn bound_line(line: &InsulatorLine, evidence: &BoxEvidence<'_>) -> Result<LineBounds> {
    let mut t = line.sorted_projections();
    let t_med = median(&mut t).ok_or_else(|| FusionError::NoInsulator("no points on the line".into()))?;
    let mut lower = Vec::new();
    let mut upper = Vec::new();
    let mut views_used = 0;
    for view in evidence.views {
        if let Some((lo, hi)) = view_bounds(line, t_med, view, evidence) {
            views_used += 1;
            if let Exit::Bound(t) = lo {
                lower.push(t);
            }
            if let Exit::Bound(t) = hi {
                upper.push(t);
            }
        }
    }
    let (lo, hi) = (median(&mut lower), median(&mut upper));
    let half = evidence.insulator_length.map(|l| 0.5 * l);
    let (t_center, ends_from_image, length) = match (lo, hi, half) {
        (Some(lo), Some(hi), _) => (0.5 * (lo + hi), 2, Some(hi - lo)),
        (Some(lo), None, Some(h)) => (lo + h, 1, None),
        (None, Some(hi), Some(h)) => (hi - h, 1, None),
        (Some(_), None, None) | (None, Some(_), None) => (t_med, 1, None),
        (None, None, _) => (t_med, 0, None),
    };
    Ok(LineBounds { t_center, ends_from_image, length, views_used })
}

/// The bounded method on the finite points of a B-frame cloud (see the module docs);
/// `localize` has validated `params` and `evidence`.
pub(crate) fn by_bounded(coords: &[[f64; 3]], params: &LocalizeParams, evidence: &BoxEvidence<'_>) -> Result<Localization> {
    let mut line = dbscan_ransac_line(coords, params)?;
    let mut bounds = bound_line(&line, evidence)?;
    if let Some(length) = evidence.insulator_length {
        // Another line in the box may be the insulator (a conductor fitted in front of it).
        if let Verdict::Rival(other, other_bounds) =
            resolve(coords, params, evidence, &line, line.at(bounds.t_center), length)?
        {
            // the clusters of the first DBSCAN stay the cloud's count
            line = InsulatorLine { n_clusters: line.n_clusters, ..other };
            bounds = other_bounds;
        }
        // Bounded at both ends, the insulator's line spans the known length (the box holds the
        // whole string); a line the box cuts far shorter or longer crosses it: another object.
        if let Some(extent) = bounds.length {
            if !(1.0 / SCALE_TOLERANCE..=SCALE_TOLERANCE).contains(&(extent / length)) {
                return Err(FusionError::NoInsulator(format!(
                    "the boxes bound the line to {extent:.2} m, not the insulator's {length:.2} m (within a factor \
                     {SCALE_TOLERANCE}): another object crossing the box"
                )));
            }
        }
    }
    Ok(Localization {
        ends_from_image: bounds.ends_from_image,
        length: bounds.length,
        views_used: bounds.views_used,
        ..Localization::from_cloud(line.at(bounds.t_center), line.direction, line.members.len(), line.n_clusters)
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_scenes::{dist, ends, forward_camera, pinhole, seen_part, segment_box};
    use proptest::prelude::*;

    /// The bounded method through the one entry point, default line fit.
    fn bounded(pts: &[[f64; 3]], views: &[BoxView], cam: &CameraModel, length: Option<f64>) -> Result<Localization> {
        let evidence = BoxEvidence { insulator_length: length, ..BoxEvidence::new(views, cam) };
        crate::localize(pts, crate::Method::Bounded, &LocalizeParams::default(), Some(&evidence))
    }

    #[test]
    fn image_ends_fix_a_partly_seen_string() {
        // A 2.2 m horizontal string 9 m ahead, across the view; the LiDAR saw only its
        // first 40 %: Algorithm 1's median sits 0.66 m off, the bounded centre on it.
        let cam = pinhole();
        let t_b_c = forward_camera();
        let (c, u, len) = ([9.0, 0.3, 0.5], [0.0, 1.0, 0.0], 2.2);
        let (e0, e1) = ends(c, u, len);
        let views = [BoxView { pixel_box: segment_box(&cam, &t_b_c, e0, e1), t_b_c }];
        let pts = seen_part(c, u, len, 0.0, 0.4);
        let alg1 = crate::localize(&pts, crate::Method::DbscanRansac, &LocalizeParams::default(), None).unwrap();
        assert!(dist(alg1.center, c) > 0.6, "{:?}", alg1.center);
        let b = bounded(&pts, &views, &cam, None).unwrap();
        assert!(dist(b.center, c) < 1e-4, "{:?}", b.center);
        assert_eq!(b.ends_from_image, 2);
        assert_eq!(b.views_used, 1);
        assert!((b.length.unwrap() - len).abs() < 1e-4);
    }

    #[test]
    fn distorted_lens_is_followed_exactly() {
        // Barrel distortion bends the projected line: the walk uses the full camera model.
        let cam = CameraModel::new(700.0, 700.0, 639.5, 479.5, 1280, 960, [-0.12, 0.03, 0.001, -0.001, 0.0]).unwrap();
        let t_b_c = forward_camera();
        let (c, u, len) = ([7.0, 2.5, 1.8], [0.0, 0.8, 0.6], 2.0);
        let (e0, e1) = ends(c, u, len);
        let views = [BoxView { pixel_box: segment_box(&cam, &t_b_c, e0, e1), t_b_c }];
        let pts = seen_part(c, u, len, 0.5, 0.9);
        let b = bounded(&pts, &views, &cam, None).unwrap();
        // The box comes from 4000 samples of the 2 m segment: 0.5 mm between samples.
        assert!(dist(b.center, c) < 1e-3, "{:?}", b.center);
        assert_eq!(b.ends_from_image, 2);
    }

    #[test]
    fn border_edge_bounds_nothing_and_the_length_fills_in() {
        // The string runs out of the frame on the left (u < 0): the box is clipped at x1 = 0.
        let cam = pinhole();
        let t_b_c = forward_camera();
        let (c, u, len) = ([6.0, 4.6, 0.0], [0.0, 1.0, 0.0], 2.2);
        let (e0, e1) = ends(c, u, len);
        let mut bx = segment_box(&cam, &t_b_c, e0, e1);
        assert!(bx.x1 < 0.0, "the test needs the string cut by the frame: {bx:?}");
        bx.x1 = 0.0;
        // The string's diameter gives the box its height (the axis alone projects to one row).
        bx.y1 -= 10.0;
        bx.y2 += 10.0;
        let views = [BoxView { pixel_box: bx, t_b_c }];
        let pts = seen_part(c, u, len, 0.0, 0.3);
        let without = bounded(&pts, &views, &cam, None).unwrap();
        assert_eq!(without.ends_from_image, 1);
        assert_eq!(without.length, None);
        let b = bounded(&pts, &views, &cam, Some(len)).unwrap();
        assert_eq!(b.ends_from_image, 1);
        assert!(dist(b.center, c) < 1e-4, "{:?}", b.center);
    }

    #[test]
    fn median_over_views_and_views_that_miss() {
        // Three views of the same string from three positions, one box belonging to
        // something else (the line does not pass through it): two used, exact centre.
        let cam = pinhole();
        let (c, u, len) = ([9.0, 0.0, 1.0], [0.0, 0.6, 0.8], 1.5);
        let (e0, e1) = ends(c, u, len);
        let mut views = Vec::new();
        for dy in [-0.5, 0.4] {
            let mut t_b_c = forward_camera();
            t_b_c.translation.vector.y = dy;
            views.push(BoxView { pixel_box: segment_box(&cam, &t_b_c, e0, e1), t_b_c });
        }
        let t_b_c = forward_camera();
        views.push(BoxView { pixel_box: PixelBox::new(10.0, 10.0, 60.0, 40.0).unwrap(), t_b_c });
        let pts = seen_part(c, u, len, 0.2, 0.55);
        let b = bounded(&pts, &views, &cam, None).unwrap();
        assert_eq!(b.views_used, 2);
        assert!(dist(b.center, c) < 1e-4, "{:?}", b.center);
    }

    #[test]
    fn a_line_crossing_the_box_is_not_the_insulator() {
        // A vertical line through a horizontal string's box (2 m string, 10 px of rim): the box
        // bounds it to about 0.3 m. Without the known length it is returned; with it, refused.
        let cam = pinhole();
        let t_b_c = forward_camera();
        let (e0, e1) = ends([9.0, 0.0, 0.0], [0.0, 1.0, 0.0], 2.0);
        let mut bx = segment_box(&cam, &t_b_c, e0, e1);
        bx.y1 -= 10.0;
        bx.y2 += 10.0;
        let views = [BoxView { pixel_box: bx, t_b_c }];
        let pts = seen_part([9.0, 0.3, 0.0], [0.0, 0.0, 1.0], 1.0, 0.0, 1.0);
        let b = bounded(&pts, &views, &cam, None).unwrap();
        assert!((b.length.unwrap() - 20.0 * 9.0 / 700.0).abs() < 0.01, "{:?}", b.length);
        match bounded(&pts, &views, &cam, Some(2.0)) {
            Err(FusionError::NoInsulator(msg)) => assert!(msg.contains("another object crossing"), "{msg}"),
            other => panic!("expected NoInsulator, got {other:?}"),
        }
    }

    #[test]
    fn end_on_line_is_not_bounded() {
        // A line along the viewing ray never leaves the box within max_extent on the far side.
        let cam = pinhole();
        let t_b_c = forward_camera();
        let pts: Vec<[f64; 3]> = (0..60).map(|k| [8.0 + f64::from(k) * 0.02, 0.0, 0.0]).collect();
        let views = [BoxView { pixel_box: PixelBox::new(600.0, 440.0, 680.0, 520.0).unwrap(), t_b_c }];
        let b = bounded(&pts, &views, &cam, None).unwrap();
        assert!(b.ends_from_image < 2, "{b:?}");
    }

    #[test]
    fn bad_input_names_the_argument() {
        let cam = pinhole();
        let t_b_c = forward_camera();
        let pts = seen_part([9.0, 0.0, 0.0], [0.0, 1.0, 0.0], 1.0, 0.0, 1.0);
        let views = [BoxView { pixel_box: PixelBox::new(0.0, 0.0, 10.0, 10.0).unwrap(), t_b_c }];
        let name = |r: Result<Localization>| match r {
            Err(crate::FusionError::InvalidArgument { name, .. }) => name,
            other => panic!("expected InvalidArgument, got {other:?}"),
        };
        let p = LocalizeParams::default();
        let run = |e: BoxEvidence<'_>, q: &LocalizeParams| crate::localize(&pts, crate::Method::Bounded, q, Some(&e));
        let ev = BoxEvidence::new(&views, &cam);
        assert_eq!(name(run(BoxEvidence::new(&[], &cam), &p)), "boxes");
        let flat = [BoxView { pixel_box: PixelBox { x1: 5.0, y1: 0.0, x2: 5.0, y2: 1.0 }, t_b_c }];
        assert_eq!(name(run(BoxEvidence::new(&flat, &cam), &p)), "boxes");
        assert_eq!(name(run(BoxEvidence { insulator_length: Some(0.0), ..ev }, &p)), "insulator_length");
        assert_eq!(name(run(BoxEvidence { border_margin: f64::NAN, ..ev }, &p)), "border_margin");
        assert_eq!(name(run(BoxEvidence { max_extent: -1.0, ..ev }, &p)), "max_extent");
        assert_eq!(name(run(ev, &LocalizeParams { tau: 0.0, ..p })), "tau");
        // the bounded method without boxes, a paper method with them: refused, never ignored
        assert_eq!(name(crate::localize(&pts, crate::Method::Bounded, &p, None)), "boxes");
        assert_eq!(name(crate::localize(&pts, crate::Method::DbscanRansac, &p, Some(&ev))), "boxes");
        let empty: Vec<[f64; 3]> = vec![[f64::NAN, 0.0, 0.0]];
        let r = crate::localize(&empty, crate::Method::Bounded, &p, Some(&ev));
        assert!(matches!(r, Err(crate::FusionError::NoInsulator(_))));
    }

    proptest! {
        /// Any string in front of a pinhole camera, at least 35 deg off the viewing ray and
        /// whole in frame, seen by the LiDAR over any part of at least 25 % of its length:
        /// the centre is within 1 mm of the truth and the image length within 2 mm.
        #[test]
        fn centre_is_exact_whatever_part_was_seen(
            dist_m in 5.0f64..14.0, az in -0.3f64..0.3, el in -0.2f64..0.2,
            yaw in -1.0f64..1.0, pitch in -1.4f64..1.4, len in 0.8f64..3.0,
            f0 in 0.0f64..0.75, span in 0.25f64..1.0,
        ) {
            let cam = pinhole();
            let t_b_c = forward_camera();
            let c = [dist_m * az.cos() * el.cos(), dist_m * az.sin() * el.cos(), dist_m * el.sin()];
            // Axis mostly across the view (B's y-z plane), tilted by yaw towards x.
            let u = [yaw.sin() * pitch.cos(), yaw.cos() * pitch.cos(), pitch.sin()];
            let n = dist(c, [0.0; 3]);
            let cos_view = ((c[0] * u[0] + c[1] * u[1] + c[2] * u[2]) / n).abs();
            prop_assume!(cos_view < 35f64.to_radians().cos()); // > 35 deg off the ray
            let (e0, e1) = ends(c, u, len);
            let bx = segment_box(&cam, &t_b_c, e0, e1);
            prop_assume!(bx.x1 > 3.0 && bx.y1 > 3.0 && bx.x2 < 1277.0 && bx.y2 < 957.0);
            let f1 = (f0 + span).min(1.0);
            let pts = seen_part(c, u, len, f0, f1);
            prop_assume!(pts.len() >= 10);
            let b = bounded(&pts, &[BoxView { pixel_box: bx, t_b_c }], &cam, None).unwrap();
            prop_assert_eq!(b.ends_from_image, 2);
            prop_assert!(dist(b.center, c) < 1e-3, "centre {:?} vs {:?}", b.center, c);
            prop_assert!((b.length.unwrap_or(f64::NAN) - len).abs() < 2e-3);
        }
    }
}
