//! Fixed-input runs of the fusion_core kernels for the instruction-count guard
//! (`benches/instructions.py` runs this under valgrind's callgrind and compares the counts with
//! `benches/instructions.json`).
//!
//! `instructions KERNEL [--setup-only]`: builds KERNEL's inputs from a fixed seed, then runs the
//! kernel once (or not, with `--setup-only`: the guard subtracts that run's count, so the figure
//! is the kernel's alone). Inputs come from a splitmix64 stream, not `rand`: their values, and so
//! the counts, must not change with a dependency's version.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::hint::black_box;
use std::process::ExitCode;

use fusion_core::{
    dbscan, deskew, deskew_points_in_boxes, localize, pca, points_in_boxes, project_points, CameraModel, LocalizeParams,
    Method, PixelBox, PoseStream,
};
use nalgebra::{Isometry3, Matrix3, Translation3, UnitQuaternion, Vector3};

/// A deterministic uniform stream in [0, 1) (splitmix64).
struct Stream(u64);

impl Stream {
    fn next(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }

    fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.next()
    }
}

/// A Mid-360-like frame of `n` points (L): all azimuths, -7..52 deg elevation, 1-40 m.
// The guard's fixed inputs: the literal bounds, not `PI`, made the committed counts.
#[allow(clippy::approx_constant)]
fn frame(n: usize, s: &mut Stream) -> Vec<[f64; 3]> {
    (0..n)
        .map(|_| {
            let (az, el, r) = (s.range(-3.14159, 3.14159), s.range(-7.0, 52.0).to_radians(), s.range(1.0, 40.0));
            [r * el.cos() * az.cos(), r * el.cos() * az.sin(), r * el.sin()]
        })
        .collect()
}

/// `n` points along a 1.5 m vertical string at `centre` (radius 0.1 m, 2 cm noise).
// As `frame`: the literal bound, not `TAU`, made the committed counts.
#[allow(clippy::approx_constant)]
fn string(centre: [f64; 3], n: usize, s: &mut Stream) -> Vec<[f64; 3]> {
    (0..n)
        .map(|_| {
            let (h, th) = (s.range(-0.75, 0.75), s.range(0.0, 6.28318));
            let r = 0.1 + s.range(-0.02, 0.02);
            [centre[0] + r * th.cos(), centre[1] + r * th.sin(), centre[2] + h]
        })
        .collect()
}

/// Strings 3 m apart on a grid, plus 20 % uniform noise over their extent.
fn strings(n: usize, per_string: usize, s: &mut Stream) -> Vec<[f64; 3]> {
    let n_strings = (n * 4 / 5) / per_string;
    let mut pts: Vec<[f64; 3]> = Vec::with_capacity(n);
    for k in 0..n_strings {
        pts.extend(string([3.0 * (k % 6) as f64, 3.0 * (k / 6) as f64, 0.0], per_string, s));
    }
    while pts.len() < n {
        pts.push([s.range(-1.0, 18.0), s.range(-1.0, 18.0), s.range(-2.0, 2.0)]);
    }
    pts
}

/// A sparse tower-scale cloud like the DBSCAN tower bench's (whose generator uses `rand`):
/// 24 conductors 60 m long, 96 % of the `n` points spread along them (about 15 cm apart, 2 cm
/// noise), the rest uniform strays over the box: most grid cells hold a point or two.
fn wires(n: usize, s: &mut Stream) -> Vec<[f64; 3]> {
    let per_wire = n * 24 / 25 / 24;
    let mut pts: Vec<[f64; 3]> = Vec::with_capacity(n);
    for k in 0..24 {
        let (x, z) = (-9.0 + 3.6 * (k % 6) as f64, 30.0 + 5.0 * (k / 6) as f64);
        pts.extend((0..per_wire).map(|_| [x + s.range(-0.02, 0.02), s.range(-30.0, 30.0), z + s.range(-0.02, 0.02)]));
    }
    while pts.len() < n {
        pts.push([s.range(-10.0, 10.0), s.range(-30.0, 30.0), s.range(25.0, 50.0)]);
    }
    pts
}

fn camera() -> (CameraModel, Isometry3<f64>) {
    let cam = CameraModel::new(1000.0, 1000.0, 640.0, 360.0, 1280, 720, [-0.1, 0.02, 0.001, -0.001, 0.0]).unwrap();
    let r = Matrix3::new(0.0, -1.0, 0.0, 0.0, 0.0, -1.0, 1.0, 0.0, 0.0);
    (cam, Isometry3::from_parts(Translation3::new(0.0, -0.05, 0.0), UnitQuaternion::from_matrix(&r)))
}

fn boxes() -> Vec<PixelBox> {
    [(300.0, 100.0, 420.0, 330.0), (600.0, 200.0, 700.0, 450.0), (900.0, 50.0, 1100.0, 200.0)]
        .iter()
        .map(|&(a, b, c, d)| PixelBox::new(a, b, c, d).unwrap())
        .collect()
}

/// Ten body poses over the frame's 0.1 s: 3 m/s forward, yawing and rolling a little.
fn poses() -> PoseStream {
    let times: Vec<f64> = (0..10).map(|i| i as f64 * 0.0125 - 0.0125).collect();
    let poses = times
        .iter()
        .map(|&t| {
            let rot = UnitQuaternion::from_euler_angles(0.05 * t, -0.1 * t, 0.3 * t);
            Isometry3::from_parts(Translation3::from(Vector3::new(3.0 * t, 0.1 * t, 0.0)), rot)
        })
        .collect();
    PoseStream::new(times, poses).unwrap()
}

/// Runs one kernel on its fixed inputs; false for an unknown name.
fn run(kernel: &str, setup_only: bool) -> bool {
    let mut s = Stream(20_261_202);
    let (cam, t_c_l) = camera();
    let t_b_l = Isometry3::translation(0.0, 0.0, 0.1);
    match kernel {
        "project_points_20k" => {
            let pts = frame(20_000, &mut s);
            if !setup_only {
                black_box(project_points(black_box(&pts), &t_c_l, &cam));
            }
        }
        "points_in_boxes_20k" => {
            let (pts, bx) = (frame(20_000, &mut s), boxes());
            if !setup_only {
                black_box(points_in_boxes(black_box(&pts), &t_c_l, &cam, &bx).unwrap());
            }
        }
        "deskew_20k" | "deskew_points_in_boxes_20k" => {
            let (pts, stream, bx) = (frame(20_000, &mut s), poses(), boxes());
            let times: Vec<f64> = (0..pts.len()).map(|i| i as f64 * 0.1 / 20_000.0).collect();
            if !setup_only {
                if kernel == "deskew_20k" {
                    black_box(deskew(black_box(&pts), &times, &stream, 0.05, &t_b_l).unwrap());
                } else {
                    black_box(deskew_points_in_boxes(black_box(&pts), &times, &stream, 0.05, &t_b_l, &t_c_l, &cam, &bx).unwrap());
                }
            }
        }
        "dbscan_3k" | "dbscan_30k" => {
            let n = if kernel == "dbscan_3k" { 3_000 } else { 30_000 };
            let pts = strings(n, 100, &mut s);
            if !setup_only {
                black_box(dbscan(black_box(&pts), 0.3, 5).unwrap());
            }
        }
        "dbscan_sparse_10k" => {
            let pts = wires(10_000, &mut s);
            if !setup_only {
                black_box(dbscan(black_box(&pts), 0.3, 5).unwrap());
            }
        }
        "localize_dbscan_ransac_2k" | "pca_2k" => {
            let mut pts = string([0.0, 0.0, 8.0], 1_600, &mut s);
            pts.extend((0..400).map(|_| [s.range(-2.0, 2.0), s.range(-2.0, 2.0), s.range(6.0, 10.0)]));
            if !setup_only {
                if kernel == "pca_2k" {
                    black_box(pca(black_box(&pts)).unwrap());
                } else {
                    black_box(localize(black_box(&pts), Method::DbscanRansac, &LocalizeParams::default(), None).unwrap());
                }
            }
        }
        _ => return false,
    }
    true
}

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let setup_only = args.iter().any(|a| a == "--setup-only");
    let Some(kernel) = args.iter().find(|a| !a.starts_with("--")) else {
        eprintln!("usage: instructions KERNEL [--setup-only]");
        return ExitCode::from(2);
    };
    if !run(kernel, setup_only) {
        eprintln!("instructions: unknown kernel {kernel:?}");
        return ExitCode::from(2);
    }
    ExitCode::SUCCESS
}
