//! A sparse tower-scale cloud for DBSCAN: a lattice tower with its conductors, as a UAV's
//! accumulated LiDAR scans see it (10k-65k returns spread over about 60 m).
//!
//! Shared by the criterion bench (`benches/dbscan_tower.rs`) and the crate's tests (included
//! with `#[path]`), so both measure and check the same clouds. The Python twin is
//! `insulator_rs.synthetic.tower_cloud` (the same recipe; the points differ, the RNGs do).
//!
//! Why this shape: on such clouds most grid cells (side eps/sqrt(3), eps 0.3 m) hold fewer than
//! 5 points, median 1 at 10k points and 3 at 65k (members and wires are thin lines, returns a
//! few cm to a few dm apart), which is where a grid DBSCAN pays per cell rather than per point.

use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

/// Tower height (m); body half-width at the base and at the top; cross-arm heights.
const HEIGHT: f64 = 48.0;
const BASE_HALF: f64 = 5.0;
const TOP_HALF: f64 = 1.0;
const ARMS: [(f64, f64); 3] = [(30.0, 9.0), (37.0, 7.5), (44.0, 6.0)];
/// Height step between the body's horizontal rings (each panel X-braced on all four faces).
const PANEL: f64 = 3.0;
/// Conductors run this far each way along the line (y): the cloud spans about 60 m.
const SPAN_HALF: f64 = 30.0;
/// Conductor sag (m) at the span's ends below the attachment point.
const SAG: f64 = 2.0;
/// Share of the points on conductors, and of uniform stray returns in the bounding box.
const CONDUCTOR_SHARE: f64 = 0.25;
const STRAY_SHARE: f64 = 0.02;
/// Range noise on the lattice and wires (m, uniform each axis).
const JITTER: f64 = 0.02;

type Segment = ([f64; 3], [f64; 3]);

fn half_width(z: f64) -> f64 {
    BASE_HALF + (TOP_HALF - BASE_HALF) * z / HEIGHT
}

/// The lattice as straight members: 4 legs, rings and X-bracing per panel, cross-arms
/// (a top and bottom chord on each side, braced) and an earth-wire peak.
fn lattice() -> Vec<Segment> {
    let corners = |z: f64| {
        let h = half_width(z);
        [[h, h, z], [-h, h, z], [-h, -h, z], [h, -h, z]]
    };
    let mut segs = Vec::new();
    let mut z = 0.0;
    while z < HEIGHT {
        let z1 = (z + PANEL).min(HEIGHT);
        let (lo, hi) = (corners(z), corners(z1));
        for k in 0..4 {
            let n = (k + 1) % 4;
            segs.push((lo[k], hi[k])); // leg
            segs.push((hi[k], hi[n])); // ring
            segs.push((lo[k], hi[n])); // X-bracing
            segs.push((lo[n], hi[k]));
        }
        z = z1;
    }
    for &(za, reach) in &ARMS {
        let h = half_width(za);
        for side in [-1.0, 1.0] {
            let tip = [side * reach, 0.0, za];
            for y in [-h, h] {
                segs.push(([side * h, y, za], tip)); // bottom chord
                segs.push(([side * h, y, za + 2.0], tip)); // top chord
                segs.push(([side * h, y, za], [side * (h + reach) / 2.0, 0.0, za + 1.0])); // brace
            }
        }
    }
    segs.push(([TOP_HALF, TOP_HALF, HEIGHT], [0.0, 0.0, HEIGHT + 3.0]));
    segs.push(([-TOP_HALF, -TOP_HALF, HEIGHT], [0.0, 0.0, HEIGHT + 3.0]));
    segs
}

fn length(s: &Segment) -> f64 {
    (0..3).map(|a| (s.1[a] - s.0[a]).powi(2)).sum::<f64>().sqrt()
}

/// `n` returns (deterministic in `seed`): lattice members sampled uniformly along their
/// length, parabolic-sag conductors from every arm tip along +-y, uniform stray returns.
pub fn tower_cloud(n: usize, seed: u64) -> Vec<[f64; 3]> {
    let mut rng = Pcg64::seed_from_u64(seed);
    let segs = lattice();
    let cum: Vec<f64> = segs.iter().scan(0.0, |acc, s| {
        *acc += length(s);
        Some(*acc)
    }).collect();
    let total = cum.last().copied().unwrap_or(0.0);
    let n_stray = (n as f64 * STRAY_SHARE) as usize;
    let n_wire = (n as f64 * CONDUCTOR_SHARE) as usize;
    let n_lattice = n - n_stray - n_wire;
    let mut pts = Vec::with_capacity(n);
    let jitter = |rng: &mut Pcg64, p: [f64; 3]| p.map(|v| v + rng.random_range(-JITTER..JITTER));
    for _ in 0..n_lattice {
        let at = rng.random_range(0.0..total);
        let k = cum.partition_point(|&c| c < at).min(segs.len() - 1);
        let (a, b) = segs[k];
        let t: f64 = rng.random_range(0.0..1.0);
        let p = [a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1]), a[2] + t * (b[2] - a[2])];
        pts.push(jitter(&mut rng, p));
    }
    for _ in 0..n_wire {
        let (za, reach) = ARMS[rng.random_range(0..ARMS.len())];
        let side = if rng.random_bool(0.5) { -1.0 } else { 1.0 };
        // The insulator string hangs 3 m below the arm tip; the wire sags from there.
        let y: f64 = rng.random_range(-SPAN_HALF..SPAN_HALF);
        let z = za - 3.0 - SAG * (y / SPAN_HALF).powi(2);
        pts.push(jitter(&mut rng, [side * reach, y, z]));
    }
    for _ in 0..n_stray {
        pts.push([rng.random_range(-12.0..12.0), rng.random_range(-SPAN_HALF..SPAN_HALF), rng.random_range(0.0..HEIGHT)]);
    }
    pts
}
