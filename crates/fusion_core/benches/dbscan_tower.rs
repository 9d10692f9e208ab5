//! DBSCAN on sparse tower-scale clouds (issue 23): a lattice tower and its conductors over
//! about 60 m, 10k-65k points, where most grid cells hold fewer than min_points points.
//!
//! Run: `nice cargo bench -p fusion_core --bench dbscan_tower -- --warm-up-time 1 --measurement-time 3`
//! Criterion's throughput line gives points/s; ns/point = 1e9 / that.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use fusion_core::dbscan;

mod tower;

/// The sizes; eps and min_points as the other DBSCAN benches (and bench_core.py).
const SIZES: [usize; 3] = [10_000, 30_000, 65_000];
const EPS: f64 = 0.3;
const MIN_POINTS: usize = 5;
/// localize's default eps (0.5 m), at the middle size: larger cells, more neighbours each.
const LOCALIZE_EPS: f64 = 0.5;

fn bench_tower(c: &mut Criterion) {
    let mut g = c.benchmark_group("dbscan_tower");
    for n in SIZES {
        let pts = tower::tower_cloud(n, 7);
        g.throughput(Throughput::Elements(n as u64));
        g.bench_with_input(BenchmarkId::new("eps0.3", n), &pts, |b, pts| {
            b.iter(|| dbscan(black_box(pts), EPS, MIN_POINTS).unwrap())
        });
    }
    let pts = tower::tower_cloud(SIZES[1], 7);
    g.throughput(Throughput::Elements(SIZES[1] as u64));
    g.bench_with_input(BenchmarkId::new("eps0.5", SIZES[1]), &pts, |b, pts| {
        b.iter(|| dbscan(black_box(pts), LOCALIZE_EPS, MIN_POINTS).unwrap())
    });
    g.finish();
}

criterion_group!(benches, bench_tower);
criterion_main!(benches);
