//! Packets, control frames and scan assembly against hand-built streams; property
//! tests: arbitrary bytes never panic, valid packets round-trip.

// A test that meets an Err should stop right there.
#![allow(clippy::expect_used, clippy::unwrap_used)]

use livox_mid360::control::{self, CommandFrame, ConfigAck, DiscoveryAck, WorkMode};
use livox_mid360::crc::crc32;
use livox_mid360::packet::{cartesian_high_sample, CRC_START, HEADER_LEN};
use livox_mid360::{
    decode_imu, decode_points, encode_packet, parse_packet, Accepted, AssemblerConfig, DataType, PacketError,
    PacketMeta, PointColumns, ScanAssembler,
};
use proptest::prelude::*;

const SPACING_NS: u64 = 5_000; // 200k points/s
const DOTS: u64 = 96;

fn meta(k: u64, data_type: DataType) -> PacketMeta {
    PacketMeta {
        time_interval: (DOTS * SPACING_NS / 100) as u16,
        udp_cnt: k as u16,
        frame_cnt: 0,
        data_type,
        time_type: 0,
        timestamp_ns: 1_000_000_000 + k * DOTS * SPACING_NS,
    }
}

/// Packet `k` of a stream: point i at (k*96+i) mm along x, reflectivity i.
fn stream_packet(k: u64) -> Vec<u8> {
    let mut samples = Vec::new();
    for i in 0..DOTS {
        samples.extend_from_slice(&cartesian_high_sample((k * DOTS + i + 1) as i32, 0, 0, i as u8, 0));
    }
    encode_packet(&meta(k, DataType::CartesianHigh), &samples).unwrap_or_default()
}

fn run(order: &[u64]) -> (ScanAssembler, Vec<livox_mid360::Scan>) {
    let mut asm = ScanAssembler::new(AssemblerConfig::default());
    for &k in order {
        let _ = asm.push(&stream_packet(k));
    }
    asm.flush();
    let mut scans = Vec::new();
    while let Some(s) = asm.pop_scan() {
        scans.push(s);
    }
    (asm, scans)
}

#[test]
fn header_layout_matches_the_protocol_table() {
    let p = stream_packet(3);
    assert_eq!(p.len(), HEADER_LEN + 96 * 14);
    assert_eq!(p.len(), 1380);
    assert_eq!(p[0], 0);
    assert_eq!(u16::from_le_bytes([p[1], p[2]]) as usize, p.len());
    assert_eq!(u16::from_le_bytes([p[3], p[4]]), 4800);
    assert_eq!(u16::from_le_bytes([p[5], p[6]]), 96);
    assert_eq!(u16::from_le_bytes([p[7], p[8]]), 3);
    assert_eq!(p[10], 1);
    let stored = u32::from_le_bytes([p[24], p[25], p[26], p[27]]);
    assert_eq!(stored, crc32(&p[CRC_START..]));
    let parsed = parse_packet(&p).map_err(|e| e.to_string());
    let parsed = parsed.as_ref().map(|p| p.header);
    assert_eq!(parsed.map(|h| h.timestamp_ns), Ok(1_000_000_000 + 3 * 96 * 5000));
}

#[test]
fn per_point_times_follow_time_interval_over_dot_num() {
    let p = stream_packet(0);
    let packet = parse_packet(&p).expect("valid");
    let mut out = PointColumns::default();
    let (kept, skipped) = decode_points(&packet, &mut out, false).expect("points");
    assert_eq!((kept, skipped), (96, 0));
    for (i, &t) in out.times_ns.iter().enumerate() {
        assert_eq!(t, 1_000_000_000 + i as u64 * 5000);
    }
    assert!((out.xyz[3 * 5] - 0.006).abs() < 1e-7);
    assert_eq!(out.reflectivity[7], 7);
}

#[test]
fn cartesian_low_and_spherical_decode_to_metres() {
    let mut low = Vec::new();
    for v in [(150i16, -200i16, 30i16), (0, 0, 0)] {
        low.extend_from_slice(&v.0.to_le_bytes());
        low.extend_from_slice(&v.1.to_le_bytes());
        low.extend_from_slice(&v.2.to_le_bytes());
        low.extend_from_slice(&[9, 1]);
    }
    let bytes = encode_packet(&meta(0, DataType::CartesianLow), &low).expect("encode");
    let packet = parse_packet(&bytes).expect("valid");
    let mut out = PointColumns::default();
    assert_eq!(decode_points(&packet, &mut out, false), Ok((1, 1)));
    assert_eq!(out.xyz, vec![1.5, -2.0, 0.3]);
    assert_eq!(out.tag, vec![1]);

    // depth 10 m, zenith 90 deg, azimuth 90 deg -> (0, 10, 0); zenith 0 -> (0, 0, 2).
    let mut sph = Vec::new();
    for (d, th, ph) in [(10_000u32, 9000u16, 9000u16), (2000, 0, 1234)] {
        sph.extend_from_slice(&d.to_le_bytes());
        sph.extend_from_slice(&th.to_le_bytes());
        sph.extend_from_slice(&ph.to_le_bytes());
        sph.extend_from_slice(&[50, 0]);
    }
    let bytes = encode_packet(&meta(0, DataType::Spherical), &sph).expect("encode");
    let packet = parse_packet(&bytes).expect("valid");
    let mut out = PointColumns::default();
    assert_eq!(decode_points(&packet, &mut out, false), Ok((2, 0)));
    let want = [0.0f32, 10.0, 0.0, 0.0, 0.0, 2.0];
    for (g, w) in out.xyz.iter().zip(want) {
        assert!((g - w).abs() < 1e-5, "{g} vs {w}");
    }
}

#[test]
fn imu_packets_decode() {
    let mut s = Vec::new();
    for v in [0.1f32, -0.2, 0.3, 0.0, 0.0, -1.0] {
        s.extend_from_slice(&v.to_le_bytes());
    }
    let bytes = encode_packet(&meta(0, DataType::Imu), &s).expect("encode");
    let packet = parse_packet(&bytes).expect("valid");
    let imu = decode_imu(&packet).expect("imu");
    assert_eq!(imu.len(), 1);
    assert_eq!(imu[0].gyro, [0.1, -0.2, 0.3]);
    assert_eq!(imu[0].acc, [0.0, 0.0, -1.0]);
    let mut out = PointColumns::default();
    assert!(matches!(decode_points(&packet, &mut out, false), Err(PacketError::NotPoints(_))));
}

#[test]
fn each_malformation_is_named() {
    let good = stream_packet(0);
    assert!(matches!(parse_packet(&good[..20]), Err(PacketError::Truncated { need: 36, got: 20 })));
    assert!(matches!(parse_packet(&good[..500]), Err(PacketError::Truncated { need: 1380, got: 500 })));
    let mut long = good.clone();
    long.push(0);
    assert!(matches!(parse_packet(&long), Err(PacketError::LengthMismatch { .. })));
    let mut v = good.clone();
    v[0] = 1;
    assert_eq!(parse_packet(&v).err(), Some(PacketError::UnsupportedVersion(1)));
    let mut t = good.clone();
    t[10] = 0x11;
    assert_eq!(parse_packet(&t).err(), Some(PacketError::UnknownDataType(0x11)));
    let mut d = good.clone();
    d[5] = 95;
    assert!(matches!(parse_packet(&d), Err(PacketError::DotNumMismatch { .. })));
    let mut c = good.clone();
    c[100] ^= 0x40;
    assert!(matches!(parse_packet(&c), Err(PacketError::Crc32Mismatch { .. })));
    assert!(PacketError::Crc32Mismatch { stored: 1, computed: 2 }.to_string().starts_with("packet.crc32"));
}

#[test]
fn in_order_stream_gives_10hz_scans_with_every_point() {
    // 0.5 s of packets: 1042 packets.
    let n = 500_000_000 / (DOTS * SPACING_NS) + 1;
    let order: Vec<u64> = (0..n).collect();
    let (asm, scans) = run(&order);
    let s = asm.stats();
    assert_eq!((s.lost, s.duplicates, s.reordered, s.malformed()), (0, 0, 0, 0));
    assert_eq!(s.points, n * DOTS);
    let total: usize = scans.iter().map(|s| s.points.len()).sum();
    assert_eq!(total as u64, n * DOTS);
    // Stream starts at t = 1.0 s exactly: windows [1.0, 1.1), ... each 20000 points.
    assert_eq!(scans[0].start_ns, 1_000_000_000);
    assert!(!scans[0].partial);
    for scan in &scans[..5] {
        assert_eq!(scan.points.len(), 20_000);
        assert_eq!(scan.end_ns - scan.start_ns, 100_000_000);
        assert!(scan.points.times_ns.windows(2).all(|w| w[0] < w[1]));
        assert!(scan.points.times_ns.iter().all(|&t| t >= scan.start_ns && t < scan.end_ns));
    }
}

#[test]
fn loss_duplicates_and_reordering_are_counted_exactly() {
    let mut order: Vec<u64> = (0..600).collect();
    order.retain(|k| ![10, 11, 300].contains(k)); // 3 lost
    order.insert(50, 49); // 1 duplicate (49 sent twice)
    order.swap(100, 102); // 102 before 100 and 101: 1 packet arrives late (counted lost, then found)
    let (asm, scans) = run(&order);
    let s = asm.stats();
    assert_eq!(s.duplicates, 1);
    assert_eq!(s.lost, 3);
    assert!(s.reordered >= 1);
    assert_eq!(s.late_dropped, 0);
    let total: u64 = scans.iter().map(|s| s.points.len() as u64).sum();
    assert_eq!(total, (600 - 3) * DOTS);
    assert!(scans.iter().all(|s| s.points.times_ns.windows(2).all(|w| w[0] < w[1])));
}

#[test]
fn a_packet_later_than_its_scan_is_dropped_and_counted() {
    let mut order: Vec<u64> = (0..700).collect();
    let k = order.remove(5);
    order.push(k); // arrives ~0.3 s late: its scan is gone
    let (asm, _) = run(&order);
    assert_eq!(asm.stats().late_dropped, 1);
    assert_eq!(asm.stats().late_points, DOTS);
    assert_eq!(asm.stats().lost, 0);
}

#[test]
fn a_clock_jump_resyncs() {
    let mut asm = ScanAssembler::new(AssemblerConfig::default());
    for k in 0..10 {
        let _ = asm.push(&stream_packet(k));
    }
    for k in 100_000..100_010 {
        let _ = asm.push(&stream_packet(k));
    }
    assert_eq!(asm.stats().resyncs, 1);
    assert_eq!(asm.stats().lost, 0);
}

#[test]
fn frame_counter_restart_counts_lost_packets_by_time() {
    // frame_cnt 0 holds packets 0..9, frame_cnt 1 restarts udp_cnt at 0 with packet 10.
    let mut asm = ScanAssembler::new(AssemblerConfig::default());
    let encode = |k: u64, frame: u8, udp: u16| {
        let mut m = meta(k, DataType::CartesianHigh);
        m.frame_cnt = frame;
        m.udp_cnt = udp;
        let samples: Vec<u8> = (0..DOTS).flat_map(|i| cartesian_high_sample(i as i32 + 1, 1, 1, 0, 0)).collect();
        encode_packet(&m, &samples).unwrap_or_default()
    };
    for k in 0..8 {
        assert_eq!(asm.push(&encode(k, 0, k as u16)), Ok(Accepted::Points(96)));
    }
    // packets 8, 9 (end of frame 0) and 10 (udp 0 of frame 1) lost
    let _ = asm.push(&encode(11, 1, 1));
    assert_eq!(asm.stats().lost, 3);
}

#[test]
fn malformed_datagrams_change_nothing() {
    let order: Vec<u64> = (0..300).collect();
    let (clean, clean_scans) = run(&order);
    let mut asm = ScanAssembler::new(AssemblerConfig::default());
    for &k in &order {
        let p = stream_packet(k);
        let mut bad = p.clone();
        bad[200] ^= 1;
        assert!(asm.push(&bad).is_err());
        assert!(asm.push(&p[..p.len() / 2]).is_err());
        let _ = asm.push(&p);
    }
    asm.flush();
    assert_eq!(asm.stats().bad_crc, 300);
    assert_eq!(asm.stats().truncated, 300);
    assert_eq!(asm.stats().points, clean.stats().points);
    let mut scans = Vec::new();
    while let Some(s) = asm.pop_scan() {
        scans.push(s);
    }
    assert_eq!(scans, clean_scans);
}

#[test]
fn control_frames_round_trip_and_check_both_crcs() {
    let frame = control::host_config_request(7, [192, 168, 1, 50], 56301, 56401);
    let bytes = frame.encode().expect("encode");
    assert_eq!(bytes[0], 0xAA);
    assert_eq!(u16::from_le_bytes([bytes[2], bytes[3]]) as usize, bytes.len());
    assert_eq!(CommandFrame::decode(&bytes), Ok(frame.clone()));
    let kv = control::parse_info_push(&frame).expect("key values");
    assert_eq!(kv[0].0, control::key::POINTCLOUD_HOST_IPCFG);
    assert_eq!(kv[0].1, vec![192, 168, 1, 50, 0xED, 0xDB, 0xEC, 0xDB]); // 56301, 56300
    let mut h = bytes.clone();
    h[8] ^= 1;
    assert!(matches!(CommandFrame::decode(&h), Err(livox_mid360::ControlError::Crc16Mismatch { .. })));
    let mut d = bytes.clone();
    d[30] ^= 1;
    assert!(matches!(CommandFrame::decode(&d), Err(livox_mid360::ControlError::Crc32Mismatch { .. })));

    let disc = control::discovery_request(1).encode().expect("encode");
    assert_eq!(disc.len(), 24);
    assert_eq!(&disc[20..24], &[0, 0, 0, 0]); // no data: crc32 field 0

    let ack = DiscoveryAck {
        ret_code: 0,
        dev_type: 9,
        serial_number: "47MDL9T0020193".into(),
        lidar_ip: [192, 168, 1, 3],
        cmd_port: 56100,
    };
    let f = CommandFrame::decode(&ack.to_frame(1).encode().expect("encode")).expect("decode");
    assert_eq!(DiscoveryAck::parse(&f), Ok(ack));

    let start = control::work_mode_request(2, WorkMode::Sampling);
    assert_eq!(control::parse_info_push(&start), Ok(vec![(0x001A, vec![1])]));
    let cfg_ack = CommandFrame { seq_num: 2, cmd_id: 0x0100, cmd_type: 1, sender_type: 1, data: vec![0, 0, 0] };
    assert_eq!(ConfigAck::parse(&cfg_ack), Ok(ConfigAck { ret_code: 0, error_key: 0 }));
    assert!(ConfigAck::parse(&f).is_err());
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    #[test]
    fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..1600)) {
        let _ = parse_packet(&bytes);
        let _ = CommandFrame::decode(&bytes);
        let _ = control::parse_key_values(&bytes, 1000);
        let mut asm = ScanAssembler::new(AssemblerConfig::default());
        let _ = asm.push(&bytes);
        asm.flush();
    }

    /// Valid headers with arbitrary fields and payloads: parse, assemble, never panic.
    #[test]
    fn arbitrary_valid_packets_never_panic(
        metas in proptest::collection::vec((any::<u16>(), any::<u16>(), any::<u8>(), 0u8..4, any::<u64>(), 0usize..20), 1..40),
        fill in any::<u8>(),
    ) {
        let mut asm = ScanAssembler::new(AssemblerConfig { frame_period_ns: 0, ..AssemblerConfig::default() });
        for (ti, udp, frame, dt, ts, n) in metas {
            let data_type = DataType::from_code(dt).unwrap_or(DataType::CartesianHigh);
            let m = PacketMeta { time_interval: ti, udp_cnt: udp, frame_cnt: frame, data_type, time_type: 0, timestamp_ns: ts };
            let samples = vec![fill; n * data_type.sample_size()];
            let bytes = encode_packet(&m, &samples).unwrap_or_default();
            prop_assert!(asm.push(&bytes).is_ok());
        }
        asm.flush();
        while asm.pop_scan().is_some() {}
    }

    #[test]
    fn cartesian_high_round_trips(
        pts in proptest::collection::vec((-200_000i32..200_000, -200_000i32..200_000, -200_000i32..200_000, any::<u8>(), any::<u8>()), 1..96),
        ts in 0u64..(1u64 << 62), ti in any::<u16>(), udp in any::<u16>(),
    ) {
        let samples: Vec<u8> = pts.iter().flat_map(|&(x, y, z, r, t)| cartesian_high_sample(x, y, z, r, t)).collect();
        let m = PacketMeta { time_interval: ti, udp_cnt: udp, frame_cnt: 3, data_type: DataType::CartesianHigh, time_type: 1, timestamp_ns: ts };
        let bytes = encode_packet(&m, &samples).map_err(|e| TestCaseError::fail(e.to_string()))?;
        let packet = parse_packet(&bytes).map_err(|e| TestCaseError::fail(e.to_string()))?;
        prop_assert_eq!(packet.header.udp_cnt, udp);
        prop_assert_eq!(packet.header.timestamp_ns, ts);
        let mut out = PointColumns::default();
        decode_points(&packet, &mut out, true).map_err(|e| TestCaseError::fail(e.to_string()))?;
        for (i, &(x, y, z, r, t)) in pts.iter().enumerate() {
            prop_assert_eq!(out.xyz[3 * i], (f64::from(x) * 1e-3) as f32);
            prop_assert_eq!(out.xyz[3 * i + 1], (f64::from(y) * 1e-3) as f32);
            prop_assert_eq!(out.xyz[3 * i + 2], (f64::from(z) * 1e-3) as f32);
            prop_assert_eq!(out.reflectivity[i], r);
            prop_assert_eq!(out.tag[i], t);
            prop_assert_eq!(out.times_ns[i], ts + (i as u64 * u64::from(ti) * 100) / pts.len() as u64);
        }
    }

    /// CRC-32 catches every single-byte corruption of the covered part.
    #[test]
    fn any_flipped_covered_byte_is_caught(at in CRC_START..1380usize, mask in 1u8..=255) {
        let mut p = stream_packet(1);
        p[at] ^= mask;
        let is_crc_error = matches!(parse_packet(&p), Err(PacketError::Crc32Mismatch { .. }));
        prop_assert!(is_crc_error);
    }

    #[test]
    fn command_frames_round_trip(seq in any::<u32>(), id in any::<u16>(), ty in 0u8..2, data in proptest::collection::vec(any::<u8>(), 0..1376)) {
        let f = CommandFrame { seq_num: seq, cmd_id: id, cmd_type: ty, sender_type: 1 - ty, data };
        let bytes = f.encode().map_err(|e| TestCaseError::fail(e.to_string()))?;
        prop_assert_eq!(CommandFrame::decode(&bytes), Ok(f));
    }
}
