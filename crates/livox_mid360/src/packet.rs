//! Point-cloud and IMU datagrams (Mid-360 protocol, "Point Cloud & IMU Data Protocol").
//!
//! Little-endian header of 36 bytes:
//!
//! | field | offset | size |
//! | --- | --- | --- |
//! | version (0) | 0 | 1 |
//! | length (whole datagram) | 1 | 2 |
//! | time_interval (0.1 us: the span of the packet's samples) | 3 | 2 |
//! | dot_num | 5 | 2 |
//! | udp_cnt | 7 | 2 |
//! | frame_cnt | 9 | 1 |
//! | data_type (0 IMU, 1 int32 mm, 2 int16 cm, 3 spherical) | 10 | 1 |
//! | time_type (0 since power-on, 1 PTP, 2 GPS; all ns) | 11 | 1 |
//! | reserved | 12 | 12 |
//! | crc32 of timestamp + data | 24 | 4 |
//! | timestamp (ns, first point) | 28 | 8 |
//!
//! Per-point time: `timestamp + i * time_interval * 100 / dot_num` ns, the spacing
//! livox_ros_driver2 uses (`point_interval = time_interval * 100 / dot_num`).
//! Validation (length, version, type, size, CRC) happens before anything is read.

use crate::crc::crc32;
use crate::error::PacketError;

pub const HEADER_LEN: usize = 36;
pub const PROTOCOL_VERSION: u8 = 0;
/// The CRC-32 covers the datagram from the timestamp on.
pub const CRC_START: usize = 28;
/// Samples per point-cloud packet the Mid-360 sends (single echo, types 1-3).
pub const MID360_DOTS_PER_PACKET: usize = 96;
/// Largest datagram the protocol produces (type 1: 36 + 96 * 14 = 1380).
pub const MAX_DATAGRAM: usize = 1500;

/// What a packet carries (`data_type`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum DataType {
    /// 0: IMU, 24 bytes: gyro xyz (rad/s), acc xyz (g), f32.
    Imu,
    /// 1: x, y, z int32 mm, reflectivity, tag (14 bytes).
    CartesianHigh,
    /// 2: x, y, z int16 cm, reflectivity, tag (8 bytes).
    CartesianLow,
    /// 3: depth u32 mm, zenith u16 0.01 deg, azimuth u16 0.01 deg, reflectivity, tag (10 bytes).
    Spherical,
}

impl DataType {
    pub fn from_code(code: u8) -> Result<Self, PacketError> {
        match code {
            0 => Ok(Self::Imu),
            1 => Ok(Self::CartesianHigh),
            2 => Ok(Self::CartesianLow),
            3 => Ok(Self::Spherical),
            other => Err(PacketError::UnknownDataType(other)),
        }
    }

    pub fn code(self) -> u8 {
        match self {
            Self::Imu => 0,
            Self::CartesianHigh => 1,
            Self::CartesianLow => 2,
            Self::Spherical => 3,
        }
    }

    /// Bytes per sample.
    pub fn sample_size(self) -> usize {
        match self {
            Self::Imu => 24,
            Self::CartesianHigh => 14,
            Self::CartesianLow => 8,
            Self::Spherical => 10,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Self::Imu => "IMU",
            Self::CartesianHigh => "cartesian int32",
            Self::CartesianLow => "cartesian int16",
            Self::Spherical => "spherical",
        }
    }
}

/// The decoded 36-byte header.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PacketHeader {
    pub version: u8,
    pub length: u16,
    /// 0.1 us units.
    pub time_interval: u16,
    pub dot_num: u16,
    pub udp_cnt: u16,
    pub frame_cnt: u8,
    pub data_type: DataType,
    pub time_type: u8,
    pub reserved: [u8; 12],
    pub crc32: u32,
    /// Time of the first sample, ns (clock given by `time_type`).
    pub timestamp_ns: u64,
}

impl PacketHeader {
    /// Duration the packet spans, ns (`time_interval` is in 0.1 us).
    pub fn interval_ns(&self) -> u64 {
        u64::from(self.time_interval) * 100
    }

    /// Time of sample `i`, ns: `timestamp + i * time_interval * 100 / dot_num`.
    pub fn sample_time_ns(&self, i: usize) -> u64 {
        if self.dot_num == 0 {
            return self.timestamp_ns;
        }
        // i < 65536 and interval < 6.6e6: the product fits u64 with room to spare.
        let offset = (i as u64).saturating_mul(self.interval_ns()) / u64::from(self.dot_num);
        self.timestamp_ns.saturating_add(offset)
    }
}

/// A validated datagram: its header and the sample bytes.
#[derive(Clone, Copy, Debug)]
pub struct Packet<'a> {
    pub header: PacketHeader,
    pub data: &'a [u8],
}

fn u16_at(b: &[u8], at: usize) -> u16 {
    u16::from_le_bytes([b[at], b[at + 1]])
}

fn u32_at(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
}

fn i32_at(b: &[u8], at: usize) -> i32 {
    i32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
}

fn i16_at(b: &[u8], at: usize) -> i16 {
    i16::from_le_bytes([b[at], b[at + 1]])
}

fn f32_at(b: &[u8], at: usize) -> f32 {
    f32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
}

fn u64_at(b: &[u8], at: usize) -> u64 {
    let mut w = [0u8; 8];
    w.copy_from_slice(&b[at..at + 8]);
    u64::from_le_bytes(w)
}

/// Validates a datagram and splits it into header and samples.
///
/// Checks, in order: at least a header, version 0, `length` equal to the datagram's
/// size, a known `data_type`, `dot_num` samples exactly filling the data, and the
/// CRC-32 over timestamp + data. Nothing is trusted before its check.
pub fn parse_packet(buf: &[u8]) -> Result<Packet<'_>, PacketError> {
    if buf.len() < HEADER_LEN {
        return Err(PacketError::Truncated { need: HEADER_LEN, got: buf.len() });
    }
    let version = buf[0];
    if version != PROTOCOL_VERSION {
        return Err(PacketError::UnsupportedVersion(version));
    }
    let length = u16_at(buf, 1);
    let declared = usize::from(length);
    if declared > buf.len() {
        return Err(PacketError::Truncated { need: declared, got: buf.len() });
    }
    if declared != buf.len() {
        return Err(PacketError::LengthMismatch { header: declared, datagram: buf.len() });
    }
    let data_type = DataType::from_code(buf[10])?;
    let dot_num = u16_at(buf, 5);
    let data = &buf[HEADER_LEN..];
    let sample_size = data_type.sample_size();
    if usize::from(dot_num).saturating_mul(sample_size) != data.len() {
        return Err(PacketError::DotNumMismatch {
            dot_num: usize::from(dot_num),
            sample_size,
            data_len: data.len(),
        });
    }
    let stored = u32_at(buf, 24);
    let computed = crc32(&buf[CRC_START..]);
    if stored != computed {
        return Err(PacketError::Crc32Mismatch { stored, computed });
    }
    let mut reserved = [0u8; 12];
    reserved.copy_from_slice(&buf[12..24]);
    Ok(Packet {
        header: PacketHeader {
            version,
            length,
            time_interval: u16_at(buf, 3),
            dot_num,
            udp_cnt: u16_at(buf, 7),
            frame_cnt: buf[9],
            data_type,
            time_type: buf[11],
            reserved,
            crc32: stored,
            timestamp_ns: u64_at(buf, 28),
        },
        data,
    })
}

/// Decoded points in columns (metres, L frame; per-point times in the sensor's ns).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PointColumns {
    /// x, y, z interleaved, metres.
    pub xyz: Vec<f32>,
    pub reflectivity: Vec<u8>,
    pub tag: Vec<u8>,
    pub times_ns: Vec<u64>,
}

impl PointColumns {
    pub fn with_capacity(n: usize) -> Self {
        Self {
            xyz: Vec::with_capacity(3 * n),
            reflectivity: Vec::with_capacity(n),
            tag: Vec::with_capacity(n),
            times_ns: Vec::with_capacity(n),
        }
    }

    pub fn len(&self) -> usize {
        self.times_ns.len()
    }

    pub fn is_empty(&self) -> bool {
        self.times_ns.is_empty()
    }

    pub fn clear(&mut self) {
        self.xyz.clear();
        self.reflectivity.clear();
        self.tag.clear();
        self.times_ns.clear();
    }

    pub fn push(&mut self, p: [f32; 3], reflectivity: u8, tag: u8, t_ns: u64) {
        self.xyz.extend_from_slice(&p);
        self.reflectivity.push(reflectivity);
        self.tag.push(tag);
        self.times_ns.push(t_ns);
    }

    /// Appends all of `other`.
    pub fn extend(&mut self, other: &PointColumns) {
        self.xyz.extend_from_slice(&other.xyz);
        self.reflectivity.extend_from_slice(&other.reflectivity);
        self.tag.extend_from_slice(&other.tag);
        self.times_ns.extend_from_slice(&other.times_ns);
    }
}

// Scaled in f64 and rounded once, so 30 cm is the f32 nearest 0.3 m.
const MM: f64 = 1e-3;
const CM: f64 = 1e-2;
const CENTIDEG_TO_RAD: f64 = std::f64::consts::PI / 18000.0;

/// One sample of a point packet, in metres (a zero vector: no return).
fn sample_xyz(data_type: DataType, s: &[u8]) -> [f32; 3] {
    match data_type {
        DataType::CartesianHigh => [
            (f64::from(i32_at(s, 0)) * MM) as f32,
            (f64::from(i32_at(s, 4)) * MM) as f32,
            (f64::from(i32_at(s, 8)) * MM) as f32,
        ],
        DataType::CartesianLow => [
            (f64::from(i16_at(s, 0)) * CM) as f32,
            (f64::from(i16_at(s, 2)) * CM) as f32,
            (f64::from(i16_at(s, 4)) * CM) as f32,
        ],
        DataType::Spherical => {
            let depth = f64::from(u32_at(s, 0)) * 1e-3;
            let zenith = f64::from(u16_at(s, 4)) * CENTIDEG_TO_RAD;
            let azimuth = f64::from(u16_at(s, 6)) * CENTIDEG_TO_RAD;
            let (sz, cz) = zenith.sin_cos();
            let (sa, ca) = azimuth.sin_cos();
            [(depth * sz * ca) as f32, (depth * sz * sa) as f32, (depth * cz) as f32]
        }
        DataType::Imu => [0.0; 3],
    }
}

/// Appends the points of a validated point packet to `out`; returns how many were
/// appended. Samples without a return (all coordinates zero) are skipped unless
/// `keep_zero` (the Mid-360 sends them to keep the time grid). The second value is
/// the number skipped.
pub fn decode_points(
    packet: &Packet<'_>,
    out: &mut PointColumns,
    keep_zero: bool,
) -> Result<(usize, usize), PacketError> {
    let h = &packet.header;
    if h.data_type == DataType::Imu {
        return Err(PacketError::NotPoints(h.data_type.name()));
    }
    let size = h.data_type.sample_size();
    let refl_at = size - 2;
    let mut kept = 0usize;
    let mut skipped = 0usize;
    for (i, s) in packet.data.chunks_exact(size).enumerate() {
        let p = sample_xyz(h.data_type, s);
        if !keep_zero && p == [0.0, 0.0, 0.0] {
            skipped += 1;
            continue;
        }
        out.push(p, s[refl_at], s[refl_at + 1], h.sample_time_ns(i));
        kept += 1;
    }
    Ok((kept, skipped))
}

/// One IMU reading (Mid-360 axes = point-cloud axes).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImuSample {
    pub timestamp_ns: u64,
    /// rad/s.
    pub gyro: [f32; 3],
    /// g (standard gravities).
    pub acc: [f32; 3],
}

/// The IMU samples of a validated IMU packet.
pub fn decode_imu(packet: &Packet<'_>) -> Result<Vec<ImuSample>, PacketError> {
    let h = &packet.header;
    if h.data_type != DataType::Imu {
        return Err(PacketError::NotImu(h.data_type.name()));
    }
    Ok(packet
        .data
        .chunks_exact(DataType::Imu.sample_size())
        .enumerate()
        .map(|(i, s)| ImuSample {
            timestamp_ns: h.sample_time_ns(i),
            gyro: [f32_at(s, 0), f32_at(s, 4), f32_at(s, 8)],
            acc: [f32_at(s, 12), f32_at(s, 16), f32_at(s, 20)],
        })
        .collect())
}

/// Header fields the encoder takes (length, dot_num and crc32 are computed).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PacketMeta {
    pub time_interval: u16,
    pub udp_cnt: u16,
    pub frame_cnt: u8,
    pub data_type: DataType,
    pub time_type: u8,
    pub timestamp_ns: u64,
}

/// Builds a datagram from raw sample bytes (`samples.len()` a multiple of the sample
/// size). The inverse of [`parse_packet`]; used by tests, benches and emitters.
pub fn encode_packet(meta: &PacketMeta, samples: &[u8]) -> Result<Vec<u8>, PacketError> {
    let size = meta.data_type.sample_size();
    let n = samples.len() / size;
    let total = HEADER_LEN + samples.len();
    if n * size != samples.len() || n > usize::from(u16::MAX) {
        return Err(PacketError::DotNumMismatch { dot_num: n, sample_size: size, data_len: samples.len() });
    }
    let length = u16::try_from(total)
        .map_err(|_| PacketError::LengthMismatch { header: total, datagram: total })?;
    let mut buf = Vec::with_capacity(total);
    buf.push(PROTOCOL_VERSION);
    buf.extend_from_slice(&length.to_le_bytes());
    buf.extend_from_slice(&meta.time_interval.to_le_bytes());
    buf.extend_from_slice(&(n as u16).to_le_bytes());
    buf.extend_from_slice(&meta.udp_cnt.to_le_bytes());
    buf.push(meta.frame_cnt);
    buf.push(meta.data_type.code());
    buf.push(meta.time_type);
    buf.extend_from_slice(&[0u8; 12]);
    buf.extend_from_slice(&[0u8; 4]); // crc32, filled below
    buf.extend_from_slice(&meta.timestamp_ns.to_le_bytes());
    buf.extend_from_slice(samples);
    let crc = crc32(&buf[CRC_START..]);
    buf[24..28].copy_from_slice(&crc.to_le_bytes());
    Ok(buf)
}

/// Raw bytes of one type-1 sample (mm).
pub fn cartesian_high_sample(x_mm: i32, y_mm: i32, z_mm: i32, reflectivity: u8, tag: u8) -> [u8; 14] {
    let mut s = [0u8; 14];
    s[0..4].copy_from_slice(&x_mm.to_le_bytes());
    s[4..8].copy_from_slice(&y_mm.to_le_bytes());
    s[8..12].copy_from_slice(&z_mm.to_le_bytes());
    s[12] = reflectivity;
    s[13] = tag;
    s
}
