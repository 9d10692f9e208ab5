//! Accuracy of the four localization methods on synthetic insulator clouds.
//!
//! Clouds are ray-cast from the UAV at the origin of B against analytic cylinders (the
//! insulator, a lattice member, a conductor) along Livox-like scan lines, 3 accumulated
//! frames with shifted lines, plus 2 cm (1 sigma) Gaussian range noise. The reference is
//! the generating geometry: centre error = distance from the estimated centre to the true
//! insulator centre (on its axis); axis error = angle between estimated and true axis.
//!
//! The LiDAR sees only the near half of the surface, so every method's centre sits ~0.8 r
//! in front of the axis (for returns uniform across the projected width the mean depth
//! offset is pi/4 r). That bias is part of the paper's methods and is why the < 0.1 m
//! requirement is checked on r <= 0.1 m; the along-axis error is checked separately.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use fusion_core::{localize, FusionError, LocalizeParams, Method};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

type V = [f64; 3];

fn sub(a: V, b: V) -> V {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
fn dot(a: V, b: V) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn scale(a: V, s: f64) -> V {
    [a[0] * s, a[1] * s, a[2] * s]
}
fn unit(a: V) -> V {
    scale(a, 1.0 / dot(a, a).sqrt())
}

/// A finite cylinder (side surface only), centre `c`, unit axis `d`, half length, radius.
#[derive(Clone, Copy)]
struct Cylinder {
    c: V,
    d: V,
    half: f64,
    r: f64,
}

impl Cylinder {
    /// Range along unit ray `u` from the origin to the first side hit, if any.
    fn hit(&self, u: V) -> Option<f64> {
        let oc = scale(self.c, -1.0);
        let up = sub(u, scale(self.d, dot(u, self.d)));
        let op = sub(oc, scale(self.d, dot(oc, self.d)));
        let a = dot(up, up);
        let b = 2.0 * dot(up, op);
        let c = dot(op, op) - self.r * self.r;
        let disc = b * b - 4.0 * a * c;
        if a < 1e-12 || disc < 0.0 {
            return None;
        }
        [(-b - disc.sqrt()) / (2.0 * a), (-b + disc.sqrt()) / (2.0 * a)]
            .into_iter()
            .find(|&s| s > 0.0 && dot(sub(scale(u, s), self.c), self.d).abs() <= self.half)
    }

    fn end(&self, sign: f64) -> V {
        let e = scale(self.d, sign * self.half);
        [self.c[0] + e[0], self.c[1] + e[1], self.c[2] + e[2]]
    }
}

/// Ray-casts the scene over the angular window around the insulator (what box culling
/// would keep): `lines` elevation scan lines spaced `line_step` rad, `az_step` rad apart,
/// 3 frames with shifted lines; Gaussian range noise `sigma` (m).
fn scan(scene: &[Cylinder], insulator: &Cylinder, seed: u64, sigma: f64) -> Vec<V> {
    let mut rng = Pcg64::seed_from_u64(seed);
    let (mut az_lo, mut az_hi, mut el_lo, mut el_hi) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for s in [-1.0, 1.0] {
        let e = insulator.end(s);
        let az = e[1].atan2(e[0]);
        let el = e[2].atan2((e[0] * e[0] + e[1] * e[1]).sqrt());
        az_lo = az_lo.min(az);
        az_hi = az_hi.max(az);
        el_lo = el_lo.min(el);
        el_hi = el_hi.max(el);
    }
    let margin = 0.03; // rad, about the detector's box padding
    let (line_step, az_step) = (0.004, 0.003); // ~0.23 deg and ~0.17 deg
    let mut pts = Vec::new();
    for _frame in 0..3 {
        let el_off: f64 = rng.random_range(0.0..line_step);
        let az_off: f64 = rng.random_range(0.0..az_step);
        let mut el = el_lo - margin + el_off;
        while el < el_hi + margin {
            let mut az = az_lo - margin + az_off;
            while az < az_hi + margin {
                let u = [el.cos() * az.cos(), el.cos() * az.sin(), el.sin()];
                let best = scene.iter().filter_map(|c| c.hit(u)).fold(f64::INFINITY, f64::min);
                if best.is_finite() {
                    // Box-Muller Gaussian range noise.
                    let (a, b): (f64, f64) = (rng.random_range(1e-12..1.0), rng.random_range(0.0..1.0));
                    let n = (-2.0 * a.ln()).sqrt() * (2.0 * std::f64::consts::PI * b).cos() * sigma;
                    pts.push(scale(u, best + n));
                }
                az += az_step;
            }
            el += line_step;
        }
    }
    pts
}

/// (centre error m, along-axis centre error m, axis error deg).
fn errors(method: Method, pts: &[V], truth: &Cylinder, params: &LocalizeParams) -> (f64, f64, f64) {
    let loc = localize(pts, method, params, None).unwrap();
    let e = sub(loc.center, truth.c);
    let cos = dot(loc.direction, truth.d).abs().min(1.0);
    (dot(e, e).sqrt(), dot(e, truth.d).abs(), cos.acos().to_degrees())
}

/// Vertical 2 m insulator (r = 0.1 m) at ~9 m, nothing else: every method close.
#[test]
fn clean_vertical_insulator() {
    let ins = Cylinder { c: [9.0, 0.8, 1.0], d: [0.0, 0.0, 1.0], half: 1.0, r: 0.1 };
    let pts = scan(&[ins], &ins, 1, 0.02);
    assert!(pts.len() > 100, "{} points", pts.len());
    let p = LocalizeParams::default();
    for m in Method::PAPER {
        let (ce, along, ae) = errors(m, &pts, &ins, &p);
        println!("clean vertical  {:>14}: centre error {ce:.3} m (along axis {along:.3}), axis error {ae:.2} deg ({} pts)", m.as_str(), pts.len());
        assert!(ce < 0.1, "{m}: centre error {ce}");
        assert!(along < 0.05, "{m}: along-axis error {along}");
        assert!(ae < 3.0, "{m}: axis error {ae}");
    }
}

/// Tilted horizontal-ish insulator (2.2 m, r = 0.12 m) with a lattice member crossing just
/// behind one end and a conductor leaving the other end: the robust methods stay accurate.
#[test]
fn insulator_with_lattice_and_conductor() {
    let d = unit([0.2, 1.0, -0.15]);
    let ins = Cylinder { c: [8.5, 0.0, 2.0], d, half: 1.1, r: 0.12 };
    let tower_end = ins.end(1.0);
    // Lattice member: 0.05 m radius, vertical-diagonal, 0.35 m behind the insulator's tower end.
    let lattice = Cylinder { c: [tower_end[0] + 0.35, tower_end[1], tower_end[2]], d: unit([0.3, 0.2, 1.0]), half: 1.5, r: 0.05 };
    // Conductor: 0.015 m radius leaving the free end downwards and sideways.
    let free_end = ins.end(-1.0);
    let cd = unit([0.1, -0.6, -0.8]);
    let conductor = Cylinder { c: [free_end[0] + cd[0] * 0.8, free_end[1] + cd[1] * 0.8, free_end[2] + cd[2] * 0.8], d: cd, half: 0.8, r: 0.015 };
    let pts = scan(&[ins, lattice, conductor], &ins, 2, 0.02);
    let p = LocalizeParams::default();
    let mut report = Vec::new();
    for m in Method::PAPER {
        let (ce, along, ae) = errors(m, &pts, &ins, &p);
        println!("lattice+conductor {:>12}: centre error {ce:.3} m (along axis {along:.3}), axis error {ae:.2} deg ({} pts)", m.as_str(), pts.len());
        report.push((m, ce, along, ae));
    }
    for (m, ce, along, ae) in report {
        // r = 0.12 m: ~0.1 m of the centre error is the near-surface bias described above.
        assert!(ce < 0.15, "{m}: centre error {ce}");
        assert!(along < 0.1, "{m}: along-axis error {along}");
        match m {
            // RANSAC lines ignore the member touching the end.
            // (the bounded method's line is Algorithm 1's: it needs boxes, not in this loop)
            Method::DbscanRansac | Method::Ransac | Method::Bounded => assert!(ae < 5.0, "{m}: axis error {ae}"),
            // The PCA axis of the merged cluster is tilted by the member; in this scene S does
            // not split, so Algorithm 2 keeps the initial PCA estimate (its else branch).
            Method::Dbscan | Method::DbscanPca => assert!(ae < 15.0, "{m}: axis error {ae}"),
        }
    }
}

/// DBSCAN+RANSAC under 0.1 m over several clean-ish random poses, lengths 1.5-2.5 m, r = 0.1 m,
/// seen from the side as the exploration path sees them: the axis at least 60 deg away from
/// the line of sight. (Seen end-on, the near end gets denser returns and pulls every
/// sample-based centre towards it; see `oblique_view_bias`.)
#[test]
fn dbscan_ransac_under_ten_centimetres_on_random_poses() {
    let mut rng = Pcg64::seed_from_u64(99);
    for case in 0..6 {
        let range: f64 = rng.random_range(8.0..10.0);
        let az: f64 = rng.random_range(-0.5..0.5);
        let c = [range * az.cos(), range * az.sin(), rng.random_range(-1.0..3.0)];
        let d = loop {
            let d = unit([rng.random_range(-0.3..0.3), rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0)]);
            if dot(d, unit(c)).abs() < 0.5 {
                break d;
            }
        };
        let ins = Cylinder { c, d, half: rng.random_range(0.75..1.25), r: 0.1 };
        let pts = scan(&[ins], &ins, 10 + case, 0.02);
        let (ce, along, ae) = errors(Method::DbscanRansac, &pts, &ins, &LocalizeParams::default());
        println!("random pose {case}: centre error {ce:.3} m (along axis {along:.3}), axis error {ae:.2} deg ({} pts)", pts.len());
        assert!(ce < 0.1, "case {case}: centre error {ce}");
        assert!(along < 0.05, "case {case}: along-axis error {along}");
        assert!(ae < 5.0, "case {case}: axis error {ae}");
    }
}

/// An insulator whose axis is 53 deg from the line of sight: the near end is ~1.4x denser,
/// which shifts the median along the axis. Reported, with a looser bound.
#[test]
fn oblique_view_bias() {
    let c = [7.22, -3.83, 0.49];
    let ins = Cylinder { c, d: unit([-0.217, 0.911, 0.351]), half: 1.15, r: 0.1 };
    let pts = scan(&[ins], &ins, 13, 0.02);
    for m in Method::PAPER {
        let (ce, along, ae) = errors(m, &pts, &ins, &LocalizeParams::default());
        println!("oblique view {:>14}: centre error {ce:.3} m (along axis {along:.3}), axis error {ae:.2} deg", m.as_str());
        assert!(ce < 0.25 && ae < 3.0, "{m}: {ce} {ae}");
    }
}

#[test]
fn deterministic_under_a_seed() {
    let ins = Cylinder { c: [9.0, -1.0, 0.5], d: unit([0.1, 1.0, 0.3]), half: 1.0, r: 0.12 };
    let pts = scan(&[ins], &ins, 5, 0.02);
    for m in Method::PAPER {
        let mut p = LocalizeParams::default();
        p.ransac.seed = 1234;
        assert_eq!(localize(&pts, m, &p, None).unwrap(), localize(&pts, m, &p, None).unwrap(), "{m}");
    }
}

#[test]
fn no_insulator_on_empty_or_noise() {
    let p = LocalizeParams::default();
    let empty: Vec<V> = Vec::new();
    let mut rng = Pcg64::seed_from_u64(3);
    // 40 points scattered over a 20 m cube: no 5 within the default eps (0.5 m).
    let noise: Vec<V> = (0..40).map(|_| [rng.random_range(0.0..20.0), rng.random_range(-10.0..10.0), rng.random_range(-10.0..10.0)]).collect();
    let nans = vec![[f64::NAN; 3]; 10];
    for m in Method::PAPER {
        assert!(matches!(localize(&empty, m, &p, None), Err(FusionError::NoInsulator(_))), "{m} empty");
        assert!(matches!(localize(&nans, m, &p, None), Err(FusionError::NoInsulator(_))), "{m} nan");
        if m != Method::Ransac {
            assert!(matches!(localize(&noise, m, &p, None), Err(FusionError::NoInsulator(_))), "{m} noise");
        }
    }
    // All points identical: RANSAC has no line.
    let same = vec![[5.0, 0.0, 0.0]; 20];
    assert!(matches!(localize(&same, Method::Ransac, &p, None), Err(FusionError::NoInsulator(_))));
}

#[test]
fn non_finite_points_are_skipped_and_counted() {
    let ins = Cylinder { c: [9.0, 0.0, 0.0], d: [0.0, 0.0, 1.0], half: 1.0, r: 0.1 };
    let mut pts = scan(&[ins], &ins, 8, 0.02);
    let clean = localize(&pts, Method::DbscanRansac, &LocalizeParams::default(), None).unwrap();
    pts.insert(3, [f64::NAN, 0.0, 0.0]);
    pts.push([f64::INFINITY, 1.0, 1.0]);
    let dirty = localize(&pts, Method::DbscanRansac, &LocalizeParams::default(), None).unwrap();
    assert_eq!(dirty.n_nonfinite, 2);
    assert_eq!(clean.n_nonfinite, 0);
    assert_eq!(dirty.center, clean.center);
    assert_eq!(dirty.n_points, clean.n_points);
}
