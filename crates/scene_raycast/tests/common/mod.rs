//! Analytic shapes as triangle meshes, shared by the tests and the bench.
#![allow(dead_code)]

pub mod parry_reference;

use std::f64::consts::PI;

use nalgebra::{Point3, Vector3};
use rand::Rng;
use rand_pcg::Pcg64Mcg;

/// A triangle soup: vertices, triangles, instance ids.
#[derive(Default, Clone)]
pub struct Soup {
    pub vertices: Vec<[f64; 3]>,
    pub triangles: Vec<[u32; 3]>,
    pub ids: Vec<i32>,
}

impl Soup {
    pub fn add(&mut self, other: Soup) {
        let offset = self.vertices.len() as u32;
        self.vertices.extend(other.vertices);
        self.triangles
            .extend(other.triangles.iter().map(|t| t.map(|i| i + offset)));
        self.ids.extend(other.ids);
    }
}

/// The square [-h, h]^2 in the plane z = `z`, facing +z.
pub fn plane_z(z: f64, h: f64, id: i32) -> Soup {
    Soup {
        vertices: vec![[-h, -h, z], [h, -h, z], [h, h, z], [-h, h, z]],
        triangles: vec![[0, 1, 2], [0, 2, 3]],
        ids: vec![id; 2],
    }
}

/// The axis-aligned box [lo, hi], outward winding.
pub fn aabb(lo: [f64; 3], hi: [f64; 3], id: i32) -> Soup {
    let mut vertices = Vec::new();
    for ix in 0..2 {
        for iy in 0..2 {
            for iz in 0..2 {
                vertices.push([
                    if ix == 0 { lo[0] } else { hi[0] },
                    if iy == 0 { lo[1] } else { hi[1] },
                    if iz == 0 { lo[2] } else { hi[2] },
                ]);
            }
        }
    }
    let quads = [
        [0, 1, 3, 2],
        [4, 6, 7, 5],
        [0, 4, 5, 1],
        [2, 3, 7, 6],
        [0, 2, 6, 4],
        [1, 5, 7, 3],
    ];
    let triangles = quads
        .iter()
        .flat_map(|[a, b, c, d]| [[*a, *b, *c], [*a, *c, *d]])
        .collect::<Vec<_>>();
    let n = triangles.len();
    Soup {
        vertices,
        triangles,
        ids: vec![id; n],
    }
}

/// A capped vertical cylinder around the z axis through (cx, cy), from z0 to
/// z1, its `segments` polygon vertices on the circle of radius `r` at angles
/// 2 pi k / segments.
pub fn cylinder_z(cx: f64, cy: f64, r: f64, z0: f64, z1: f64, segments: u32, id: i32) -> Soup {
    let mut soup = tube([cx, cy, z0], [cx, cy, z1], r, segments, id);
    let n = segments;
    soup.vertices.push([cx, cy, z0]);
    soup.vertices.push([cx, cy, z1]);
    for i in 0..n {
        let j = (i + 1) % n;
        soup.triangles.push([2 * n, j, i]);
        soup.triangles.push([2 * n + 1, n + i, n + j]);
    }
    soup.ids.resize(soup.triangles.len(), id);
    soup
}

/// An open (uncapped) faceted tube from `p0` to `p1` of radius `r`.
pub fn tube(p0: [f64; 3], p1: [f64; 3], r: f64, segments: u32, id: i32) -> Soup {
    frustum(p0, p1, r, r, segments, id)
}

/// An open faceted frustum from `p0` (radius `r0`) to `p1` (radius `r1`).
pub fn frustum(p0: [f64; 3], p1: [f64; 3], r0: f64, r1: f64, segments: u32, id: i32) -> Soup {
    let (a, b) = (nalgebra::Vector3::from(p0), nalgebra::Vector3::from(p1));
    let axis = (b - a).normalize();
    // For a z axis the ring starts on +x and turns toward +y (the analytic tests rely on it).
    let helper = if axis.z.abs() > 0.9 {
        nalgebra::Vector3::y()
    } else {
        nalgebra::Vector3::z()
    };
    let u = helper.cross(&axis).normalize();
    let v = axis.cross(&u);
    let mut vertices = Vec::new();
    for (end, r) in [(a, r0), (b, r1)] {
        for k in 0..segments {
            let ang = 2.0 * PI * f64::from(k) / f64::from(segments);
            let p = end + r * (ang.cos() * u + ang.sin() * v);
            vertices.push([p.x, p.y, p.z]);
        }
    }
    let n = segments;
    let mut triangles = Vec::new();
    for i in 0..n {
        let j = (i + 1) % n;
        triangles.push([i, j, n + j]);
        triangles.push([i, n + j, n + i]);
    }
    let count = triangles.len();
    Soup {
        vertices,
        triangles,
        ids: vec![id; count],
    }
}

/// A lattice tower like the simulator's (about 75k triangles): 4 tapered legs
/// in 2 m panels with X-bracing on every face, three cross-arm levels, 12 insulators
/// as stacks of 20 sheds (48 facets) and 12 conductors 60 m long, over a ground plane.
pub fn lattice_tower() -> Soup {
    let mut soup = plane_z(0.0, 200.0, 0);
    let half = |z: f64| 5.0 - 3.5 * z / 30.0;
    let corner = |k: usize, z: f64| {
        let (sx, sy) = ([1.0, -1.0, -1.0, 1.0][k], [1.0, 1.0, -1.0, -1.0][k]);
        [sx * half(z), sy * half(z), z]
    };
    let member = |soup: &mut Soup, a: [f64; 3], b: [f64; 3]| soup.add(tube(a, b, 0.07, 4, 500));
    for panel in 0..15 {
        let (z0, z1) = (2.0 * f64::from(panel), 2.0 * f64::from(panel + 1));
        for k in 0..4 {
            let k2 = (k + 1) % 4;
            member(&mut soup, corner(k, z0), corner(k, z1));
            member(&mut soup, corner(k, z1), corner(k2, z1));
            member(&mut soup, corner(k, z0), corner(k2, z1));
            member(&mut soup, corner(k2, z0), corner(k, z1));
        }
    }
    let mut insulator = 1;
    for z in [18.0, 22.0, 26.0] {
        for side in [-1.0, 1.0] {
            let root = half(z);
            let tip = [side * (root + 5.0), 0.0, z];
            member(&mut soup, [side * root, 1.0, z], tip);
            member(&mut soup, [side * root, -1.0, z], tip);
            member(&mut soup, [side * root, 0.0, z - 2.0], tip);
            for dy in [-0.3, 0.3] {
                // A suspension string hanging 2 m under the arm tip, then its conductor.
                let top = [tip[0], dy, z];
                for shed in 0..20 {
                    let zs = z - 0.1 * f64::from(shed) - 0.05;
                    soup.add(frustum(
                        [top[0], dy, zs],
                        [top[0], dy, zs - 0.03],
                        0.06,
                        0.13,
                        48,
                        insulator,
                    ));
                }
                soup.add(tube(top, [top[0], dy, z - 2.0], 0.05, 48, insulator));
                insulator += 1;
                let end = [top[0], dy, z - 2.0];
                for seg in 0..60 {
                    let (y0, y1) = (f64::from(seg) - 0.0, f64::from(seg + 1));
                    let sag = |y: f64| 0.004 * y * (60.0 - y);
                    soup.add(tube(
                        [end[0], dy + y0, end[2] - sag(y0)],
                        [end[0], dy + y1, end[2] - sag(y1)],
                        0.015,
                        8,
                        1000 + insulator,
                    ));
                }
            }
        }
    }
    soup
}

/// A lattice-tower-like scene of about `n_members * 2 * segments` triangles: a
/// ground plane and slender members, vertical and diagonal, 2 to 8 m long, in a
/// 10 m x 10 m x 30 m volume (deterministic).
pub fn tower_like(n_members: u32, segments: u32) -> Soup {
    let mut soup = plane_z(0.0, 200.0, 0);
    let mut state = 0x2545_F491_4F6C_DD1Du64;
    let mut next = move || {
        // xorshift64*: a fixed, dependency-free sequence for a reproducible bench scene.
        state ^= state >> 12;
        state ^= state << 25;
        state ^= state >> 27;
        (state.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64
    };
    for m in 0..n_members {
        let p0 = [-5.0 + 10.0 * next(), -5.0 + 10.0 * next(), 30.0 * next()];
        let len = 2.0 + 6.0 * next();
        let (az, el) = (2.0 * PI * next(), (next() - 0.5) * PI);
        let p1 = [
            p0[0] + len * el.cos() * az.cos(),
            p0[1] + len * el.cos() * az.sin(),
            p0[2] + len * el.sin(),
        ];
        soup.add(tube(
            p0,
            p1,
            0.03 + 0.05 * next(),
            segments,
            1 + (m % 100) as i32,
        ));
    }
    soup
}

/// A tower-sized test scene: a ground plane and a lattice of `n_members`
/// slender vertical and diagonal-free members as faceted cylinders.
pub fn lattice(n_members: u32, segments: u32) -> Soup {
    let mut soup = plane_z(0.0, 200.0, 0);
    let side = (f64::from(n_members)).sqrt().ceil() as u32;
    for m in 0..n_members {
        let x = -5.0 + 10.0 * f64::from(m % side) / f64::from(side);
        let y = -5.0 + 10.0 * f64::from(m / side) / f64::from(side);
        soup.add(cylinder_z(
            x,
            y,
            0.04,
            0.0,
            25.0,
            segments,
            1 + (m % 50) as i32,
        ));
    }
    soup
}

/// Nearest (distance, triangle) by f64 Moeller-Trumbore over every triangle,
/// with the crate's parallel-ray threshold.
pub fn brute_force(
    soup: &Soup,
    o: &Point3<f64>,
    d: &Vector3<f64>,
    range: f64,
) -> Option<(f64, u32)> {
    let mut best: Option<(f64, u32)> = None;
    for (k, tri) in soup.triangles.iter().enumerate() {
        let [a, b, c] = tri.map(|i| Point3::from(soup.vertices[i as usize]));
        let (e1, e2) = (b - a, c - a);
        let p = d.cross(&e2);
        let det = e1.dot(&p);
        if det.abs() < 1e-14 * e1.norm() * e2.norm() {
            continue;
        }
        let inv = 1.0 / det;
        let s = o - a;
        let u = s.dot(&p) * inv;
        let q = s.cross(&e1);
        let v = d.dot(&q) * inv;
        let t = e2.dot(&q) * inv;
        if (0.0..=1.0).contains(&u)
            && v >= 0.0
            && u + v <= 1.0
            && t >= 0.0
            && t <= range
            && best.is_none_or(|(bt, _)| t < bt)
        {
            best = Some((t, k as u32));
        }
    }
    best
}

/// A random unit vector (rejection from the cube).
pub fn random_unit(rng: &mut Pcg64Mcg) -> Vector3<f64> {
    loop {
        let v = Vector3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
        );
        if let Some(u) = v.try_normalize(1e-3) {
            return u;
        }
    }
}
