//! Packet traversal (`Scene::cast_packet`, `Scene::occluded_packet`) against
//! single rays (`cast_one`, `occluded`) and a brute-force f64 Moeller-Trumbore
//! over every triangle (`common::brute_force`).
//!
//! Reference and tolerance: exact. A packet gives every ray the very hit
//! `cast_one` gives it (distance bit for bit, same triangle) and the very
//! occlusion answer, and that hit is the brute force's (the lowest triangle index
//! among those at the nearest distance, both sides computing the same f64
//! formula): the boxes only cull, and the nearest hit does not depend on the
//! order of the visit. Packets: camera tiles (8x8 rays from one point, narrow and
//! wide), shadow rays (one direction from points on the surfaces), incoherent
//! rays, sizes that are not a whole packet, finite ranges.

mod common;

use common::{brute_force, random_unit as unit, Soup};
use nalgebra::{Point3, Vector3};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;
use scene_raycast::{Hit, RaycastError, Scene};

fn scene(soup: &Soup) -> Scene {
    match Scene::new(&soup.vertices, &soup.triangles, &soup.ids) {
        Ok(s) => s,
        Err(e) => panic!("{e}"),
    }
}

fn vertex(soup: &Soup, rng: &mut Pcg64Mcg) -> Point3<f64> {
    Point3::from(soup.vertices[rng.random_range(0..soup.vertices.len())])
}

/// A point on a random triangle, `offset` m off it along its normal.
fn surface_point(soup: &Soup, rng: &mut Pcg64Mcg, offset: f64) -> Point3<f64> {
    let t = soup.triangles[rng.random_range(0..soup.triangles.len())];
    let [a, b, c] = t.map(|i| Point3::from(soup.vertices[i as usize]));
    let (mut u, mut v) = (rng.random_range(0.0..1.0), rng.random_range(0.0..1.0));
    if u + v > 1.0 {
        (u, v) = (1.0 - u, 1.0 - v);
    }
    let normal = (b - a).cross(&(c - a)).normalize();
    a + (b - a) * u + (c - a) * v + normal * offset
}

/// A camera standpoint around, inside or far from the tower.
fn standpoint(rng: &mut Pcg64Mcg) -> Point3<f64> {
    match rng.random_range(0..3) {
        0 => Point3::new(
            rng.random_range(-40.0..40.0),
            rng.random_range(-40.0..40.0),
            rng.random_range(0.5..45.0),
        ),
        1 => Point3::new(
            rng.random_range(-8.0..8.0),
            rng.random_range(-8.0..8.0),
            rng.random_range(0.0..35.0),
        ),
        _ => Point3::from(unit(rng) * 600.0) + Vector3::new(0.0, 0.0, 300.0),
    }
}

/// One packet of `kind` (0 camera tile, 1 shadow rays, 2 incoherent).
fn packet(soup: &Soup, rng: &mut Pcg64Mcg, kind: u32) -> (Vec<Point3<f64>>, Vec<Vector3<f64>>) {
    let n = [64, 64, 64, 1, 7, 100][rng.random_range(0..6)];
    match kind {
        0 => {
            let o = standpoint(rng);
            let axis = (vertex(soup, rng) - o).normalize();
            let right = axis.cross(&unit(rng)).normalize();
            let down = axis.cross(&right);
            // Pixel pitch from a zoom lens's to a wide one's, in radians.
            let pitch = 10f64.powf(rng.random_range(-4.5..-1.5));
            let dirs = (0..n)
                .map(|k| {
                    let (row, col) = ((k / 8) as f64 - 3.5, (k % 8) as f64 - 3.5);
                    (axis + right * (col * pitch) + down * (row * pitch)).normalize()
                })
                .collect();
            (vec![o; n], dirs)
        }
        1 => {
            let sun = unit(rng);
            let origins = (0..n).map(|_| surface_point(soup, rng, 2e-3)).collect();
            (origins, vec![sun; n])
        }
        _ => {
            let origins = (0..n).map(|_| standpoint(rng)).collect();
            let dirs = (0..n).map(|_| unit(rng)).collect();
            (origins, dirs)
        }
    }
}

/// The packets each test draws, divided by `SCENE_RAYCAST_PACKET_DIVISOR` (default 1).
///
/// Under qemu-aarch64 (scripts/test-aarch64.sh sets 10) the brute-force reference over every
/// triangle costs ~50x what it costs natively (457 s for the full draw): a tenth of the packets
/// (60 and 30, some 4,300 rays) still crosses every packet kind, every lane of the NEON traversal
/// and both range kinds, and the native run keeps the full draw.
fn packets_to_draw(full: usize) -> usize {
    let divisor = match std::env::var("SCENE_RAYCAST_PACKET_DIVISOR") {
        Ok(text) => match text.parse::<usize>() {
            Ok(d) if d >= 1 => d,
            _ => panic!("SCENE_RAYCAST_PACKET_DIVISOR must be a whole number >= 1, not {text:?}"),
        },
        Err(_) => 1,
    };
    (full / divisor).max(1)
}

fn check(soup: &Soup, full_draw: usize, seed: u64) {
    let packets = packets_to_draw(full_draw);
    let scene = scene(soup);
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    let (mut hits, mut rays, mut occluded) = (0, 0, 0);
    for p in 0..packets {
        let (origins, dirs) = packet(soup, &mut rng, (p % 3) as u32);
        let range = if rng.random_bool(0.7) {
            f64::INFINITY
        } else {
            rng.random_range(1.0..30.0)
        };
        let mut got: Vec<Option<Hit>> = vec![None; origins.len()];
        let mut blocked = vec![false; origins.len()];
        let cast = scene.cast_packet(&origins, &dirs, range, &mut got);
        let occlusion = scene.occluded_packet(&origins, &dirs, range, &mut blocked);
        assert_eq!((cast, occlusion), (Ok(()), Ok(())));
        for (i, (o, d)) in origins.iter().zip(&dirs).enumerate() {
            let one = scene.cast_one(o, d, range);
            assert_eq!(got[i], one, "packet {p} ray {i} ({o}, {d}, range {range})");
            assert_eq!(
                blocked[i],
                scene.occluded(o, d, range),
                "packet {p} ray {i}: occlusion"
            );
            let exact = brute_force(soup, o, d, range);
            assert_eq!(
                one.map(|h| (h.distance, h.triangle)),
                exact,
                "packet {p} ray {i} ({o}, {d}, range {range}): brute force"
            );
            hits += usize::from(one.is_some());
            occluded += usize::from(blocked[i]);
            rays += 1;
        }
    }
    assert!(
        hits > rays / 10 && hits < rays * 9 / 10,
        "{hits} hits of {rays} rays"
    );
    println!("{packets} packets, {rays} rays: {hits} hits, {occluded} occluded");
}

#[test]
fn packets_match_single_rays_on_the_lattice_tower() {
    check(&common::lattice_tower(), 600, 11);
}

#[test]
fn packets_match_single_rays_in_a_dense_thicket() {
    check(&common::tower_like(2000, 8), 300, 12);
}

#[test]
fn packet_rows_must_match() {
    let scene = scene(&common::lattice_tower());
    let o = [Point3::origin(); 3];
    let d = [Vector3::z(); 2];
    let mut out = [None; 3];
    let err = scene.cast_packet(&o, &d, 10.0, &mut out);
    assert!(
        matches!(
            err,
            Err(RaycastError::LengthMismatch {
                name: "directions",
                expected: 3,
                got: 2
            })
        ),
        "{err:?}"
    );
    let mut blocked = [false; 2];
    let err = scene.occluded_packet(&o, &[Vector3::z(); 3], 10.0, &mut blocked);
    assert!(
        matches!(
            err,
            Err(RaycastError::LengthMismatch {
                name: "out",
                expected: 3,
                got: 2
            })
        ),
        "{err:?}"
    );
}
