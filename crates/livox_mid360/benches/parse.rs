//! Parsing throughput: one second of Mid-360 output (200,000 points in 2084 type-1
//! packets of 96 points) through the full receive path: validation, CRC-32, decoding,
//! sequence accounting and 10 Hz scan assembly.
//!
//! Goal (issue 11): keep up with 200k points/s using at most 5 % of one core, i.e.
//! one iteration (one second of data) in at most [`BUDGET_MS`] ms.

use criterion::{criterion_group, criterion_main, BatchSize, Criterion, Throughput};
use livox_mid360::packet::cartesian_high_sample;
use livox_mid360::{encode_packet, AssemblerConfig, DataType, PacketMeta, ScanAssembler};

const POINT_RATE: u64 = 200_000;
const DOTS: u64 = 96;
/// 5 % of one core for one second of data.
#[allow(dead_code)]
const BUDGET_MS: f64 = 50.0;

fn one_second() -> Vec<Vec<u8>> {
    let packets = POINT_RATE.div_ceil(DOTS);
    let spacing_ns = 1_000_000_000 / POINT_RATE;
    (0..packets)
        .filter_map(|k| {
            let mut samples = Vec::with_capacity(14 * DOTS as usize);
            for i in 0..DOTS {
                let a = (k * DOTS + i) as f64 * 1e-3;
                let s = cartesian_high_sample(
                    (8000.0 * a.cos()) as i32,
                    (8000.0 * a.sin()) as i32,
                    (1000.0 * (0.3 * a).sin()) as i32,
                    (i % 255) as u8,
                    0,
                );
                samples.extend_from_slice(&s);
            }
            let meta = PacketMeta {
                time_interval: (DOTS * spacing_ns / 100) as u16,
                udp_cnt: k as u16,
                frame_cnt: 0,
                data_type: DataType::CartesianHigh,
                time_type: 0,
                timestamp_ns: k * DOTS * spacing_ns,
            };
            encode_packet(&meta, &samples).ok()
        })
        .collect()
}

fn bench_parse(c: &mut Criterion) {
    let packets = one_second();
    let points: u64 = packets.len() as u64 * DOTS;
    let mut group = c.benchmark_group("livox_mid360");
    group.throughput(Throughput::Elements(points));
    group.bench_function("assemble_1s_200k_points", |b| {
        b.iter_batched(
            || ScanAssembler::new(AssemblerConfig::default()),
            |mut asm| {
                for p in &packets {
                    let _ = asm.push(p);
                }
                asm.flush();
                let mut n = 0;
                while let Some(scan) = asm.pop_scan() {
                    n += scan.points.len();
                }
                n
            },
            BatchSize::LargeInput,
        )
    });
    group.bench_function("parse_packet_only", |b| {
        b.iter(|| {
            let mut ok = 0usize;
            for p in &packets {
                if livox_mid360::parse_packet(p).is_ok() {
                    ok += 1;
                }
            }
            ok
        })
    });
    group.finish();
}

criterion_group!(benches, bench_parse);
criterion_main!(benches);
