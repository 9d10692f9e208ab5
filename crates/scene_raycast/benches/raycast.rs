//! Ray-casting and rendering cost on a lattice tower like the simulator's (~75k
//! triangles) and on a dense thicket of 6250 random members (100k triangles, a
//! worst case far denser than any tower).
//!
//! Side by side: the parallel batch `Scene::cast` against the same rays cast one
//! by one on one thread (the rayon speed-up), those against the previous caster
//! (parry3d's BVH, `common::parry_reference`) one by one, and a camera render
//! with and without shadow rays. `cargo bench -p scene_raycast` prints the ratios at the end.

#[path = "../tests/common/mod.rs"]
mod common;

use std::time::Instant;

use common::parry_reference::ParryScene;
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use nalgebra::{Matrix3, Point3, Vector3};
use scene_raycast::{render, Lighting, Scene};

/// Thicket: members x 2 x segments triangles = 6250 x 16 = 100,000.
const MEMBERS: u32 = 6250;
const SEGMENTS: u32 = 8;
/// One Mid-360 frame.
const LIDAR_RAYS: usize = 20_000;
const IMAGE: (usize, usize) = (320, 240);

fn scene(soup: &common::Soup) -> Scene {
    match Scene::new(&soup.vertices, &soup.triangles, &soup.ids) {
        Ok(s) => s,
        Err(e) => panic!("bench scene refused: {e}"),
    }
}

/// A LiDAR-like fan (360 deg x -7..52 deg) from 9 m beside the lattice.
fn lidar_rays() -> (Vec<[f64; 3]>, Vec<[f64; 3]>) {
    let origin = [14.0, 0.0, 15.0];
    let dirs = (0..LIDAR_RAYS)
        .map(|k| {
            let t = k as f64 / LIDAR_RAYS as f64;
            let az = 2.0 * std::f64::consts::PI * t * 4.0;
            let el = (-7.0 + 59.0 * ((t * 201.414) % 1.0)).to_radians();
            [el.cos() * az.cos(), el.cos() * az.sin(), el.sin()]
        })
        .collect();
    (vec![origin; LIDAR_RAYS], dirs)
}

fn camera_rays(w: usize, h: usize) -> Vec<[f64; 3]> {
    let f = 0.55 * w as f64;
    (0..h)
        .flat_map(|r| {
            (0..w).map(move |c| {
                [
                    (c as f64 - w as f64 / 2.0) / f,
                    (r as f64 - h as f64 / 2.0) / f,
                    1.0,
                ]
            })
        })
        .collect()
}

/// Camera at 9 m from the lattice looking at it (-x), level.
fn camera_pose() -> (Matrix3<f64>, Point3<f64>) {
    // C: z forward = -x_W, x right = +y_W, y down = -z_W.
    let r = Matrix3::from_columns(&[Vector3::y(), -Vector3::z(), -Vector3::x()]);
    (r, Point3::new(14.0, 0.0, 15.0))
}

fn bench(c: &mut Criterion) {
    for (name, soup) in [
        ("tower", common::lattice_tower()),
        ("thicket", common::tower_like(MEMBERS, SEGMENTS)),
    ] {
        let reference = ParryScene::new(&soup.vertices, &soup.triangles);
        bench_scene(c, name, &scene(&soup), &reference);
    }
}

fn bench_scene(c: &mut Criterion, name: &str, scene: &Scene, reference: &ParryScene) {
    let (origins, dirs) = lidar_rays();
    let mut group = c.benchmark_group(format!("{name}/lidar_frame"));
    group.throughput(Throughput::Elements(LIDAR_RAYS as u64));
    group.sample_size(20);
    group.bench_function(BenchmarkId::new("parallel", scene.n_triangles()), |b| {
        b.iter(|| scene.cast(&origins, &dirs, 40.0))
    });
    let one_by_one = || {
        origins
            .iter()
            .zip(&dirs)
            .filter_map(|(o, d)| {
                scene.cast_one(&Point3::from(*o), &Vector3::from(*d).normalize(), 40.0)
            })
            .count()
    };
    let reference_one_by_one = || {
        origins
            .iter()
            .zip(&dirs)
            .filter_map(|(o, d)| {
                reference.cast_one(&Point3::from(*o), &Vector3::from(*d).normalize(), 40.0)
            })
            .count()
    };
    group.bench_function(BenchmarkId::new("one_by_one", scene.n_triangles()), |b| {
        b.iter(one_by_one)
    });
    group.bench_function(
        BenchmarkId::new("parry_reference_one_by_one", scene.n_triangles()),
        |b| b.iter(reference_one_by_one),
    );
    group.finish();

    let (w, h) = IMAGE;
    let rays = camera_rays(w, h);
    let (rot, pos) = camera_pose();
    let mut group = c.benchmark_group(format!("{name}/camera_image"));
    group.throughput(Throughput::Elements((w * h) as u64));
    group.sample_size(10);
    for shadows in [false, true] {
        let lighting = Lighting {
            shadows,
            noise_sigma: 2.0,
            ..Lighting::default()
        };
        group.bench_function(
            BenchmarkId::new(
                if shadows { "shadows" } else { "no_shadows" },
                format!("{w}x{h}"),
            ),
            |b| b.iter(|| render(scene, &rot, &pos, &rays, w, h, &[[0.5; 3]; 101], &lighting)),
        );
    }
    group.finish();

    // Ratios, measured once more outside criterion so they print side by side.
    let time = |f: &dyn Fn()| {
        let t = Instant::now();
        for _ in 0..5 {
            f();
        }
        t.elapsed().as_secs_f64() / 5.0
    };
    let par = time(&|| drop(std::hint::black_box(scene.cast(&origins, &dirs, 40.0))));
    let seq = time(&|| {
        std::hint::black_box(one_by_one());
    });
    let seq_reference = time(&|| {
        std::hint::black_box(reference_one_by_one());
    });
    let lit = |s| Lighting {
        shadows: s,
        ..Lighting::default()
    };
    let no_sh = time(&|| drop(render(scene, &rot, &pos, &rays, w, h, &[], &lit(false))));
    let sh = time(&|| drop(render(scene, &rot, &pos, &rays, w, h, &[], &lit(true))));
    println!(
        "\n{name}, {} triangles: LiDAR frame {:.2} ms parallel vs {:.2} ms one-by-one (x{:.2}), \
         parry3d reference one-by-one {:.2} ms (ours x{:.2} faster); \
         {w}x{h} image {:.1} ms without shadows, {:.1} ms with (x{:.2}); \
         1280x960 extrapolated: {:.0} ms with shadows",
        scene.n_triangles(),
        par * 1e3,
        seq * 1e3,
        seq / par,
        seq_reference * 1e3,
        seq_reference / seq,
        no_sh * 1e3,
        sh * 1e3,
        sh / no_sh,
        sh * 1e3 * (1280.0 * 960.0) / (w * h) as f64
    );
}

criterion_group!(benches, bench);
criterion_main!(benches);
