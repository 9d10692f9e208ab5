//! Packets -> 10 Hz scans, with every fault counted.
//!
//! Scans are windows of the sensor clock, `[k T, (k+1) T)` with `T` the frame period
//! (0.1 s at 10 Hz), as livox_ros_driver2 publishes a frame per 100 ms of packet time;
//! each point goes to the window of its own time, so a packet straddling a boundary is
//! split. A window is closed (emitted) once an in-order packet starts `reorder_grace`
//! past its end, so a packet that arrives a little late still joins its scan.
//!
//! Sequence accounting, per point packet, in this order:
//! * duplicate: the same (frame_cnt, udp_cnt, timestamp) as one of the last
//!   [`RECENT_KEYS`] packets -> dropped, counted;
//! * reordered: older than the newest packet -> counted; its points join their
//!   window if still open, else the packet is counted `late_dropped`; since the gap it
//!   left was counted lost, `lost` is decremented (lost = never received, so far);
//! * resync: more than `resync_gap` away from the newest packet (sensor restart, clock
//!   step) -> open windows are closed, tracking restarts, counted;
//! * otherwise in order: packets missing in between are counted `lost`: from
//!   `udp_cnt` within one `frame_cnt` (16-bit wrap), and across a `frame_cnt` change
//!   (where `udp_cnt` restarts at 0) from the time gap in units of the previous
//!   packet's span (the Mid-360's packets tile time without gaps), never fewer than
//!   the new frame's `udp_cnt`.
//!
//! Malformed datagrams (truncated, bad length, version, type, size, CRC) are counted
//! by kind and change no state: a bad packet never alters what a good one yields.

use std::collections::{BTreeMap, VecDeque};

use crate::error::PacketError;
use crate::packet::{decode_imu, decode_points, parse_packet, DataType, ImuSample, Packet, PacketHeader, PointColumns};

/// How many recent packet keys the duplicate check remembers.
pub const RECENT_KEYS: usize = 256;

/// Tuning of the assembler; times in ns of the sensor clock.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct AssemblerConfig {
    /// Scan period (100 ms at 10 Hz).
    pub frame_period_ns: u64,
    /// How long past a window's end a late packet may still join it.
    pub reorder_grace_ns: u64,
    /// A jump larger than this between packets restarts the tracking.
    pub resync_gap_ns: u64,
    /// Keep samples without a return (all-zero coordinates).
    pub keep_zero_points: bool,
    /// Most scans held open at once (older ones are closed first).
    pub max_open_scans: usize,
    /// Most finished scans queued for the reader (the oldest is dropped, counted).
    pub max_queued_scans: usize,
    /// Most IMU samples queued for the reader.
    pub max_queued_imu: usize,
}

impl Default for AssemblerConfig {
    fn default() -> Self {
        Self {
            frame_period_ns: 100_000_000,
            reorder_grace_ns: 5_000_000,
            resync_gap_ns: 1_000_000_000,
            keep_zero_points: false,
            max_open_scans: 4,
            max_queued_scans: 16,
            max_queued_imu: 4096,
        }
    }
}

/// Counters of everything that arrived, by outcome.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Stats {
    pub datagrams: u64,
    pub point_packets: u64,
    pub imu_packets: u64,
    pub imu_samples: u64,
    pub points: u64,
    pub zero_points: u64,
    pub truncated: u64,
    pub length_mismatch: u64,
    pub bad_version: u64,
    pub unknown_data_type: u64,
    pub dot_num_mismatch: u64,
    pub bad_crc: u64,
    pub duplicates: u64,
    pub reordered: u64,
    pub late_dropped: u64,
    pub late_points: u64,
    pub lost: u64,
    pub resyncs: u64,
    pub scans: u64,
    pub scans_dropped: u64,
    pub imu_dropped: u64,
}

impl Stats {
    /// (name, value) of every counter, for reports.
    pub fn pairs(&self) -> [(&'static str, u64); 21] {
        [
            ("datagrams", self.datagrams),
            ("point_packets", self.point_packets),
            ("imu_packets", self.imu_packets),
            ("imu_samples", self.imu_samples),
            ("points", self.points),
            ("zero_points", self.zero_points),
            ("truncated", self.truncated),
            ("length_mismatch", self.length_mismatch),
            ("bad_version", self.bad_version),
            ("unknown_data_type", self.unknown_data_type),
            ("dot_num_mismatch", self.dot_num_mismatch),
            ("bad_crc", self.bad_crc),
            ("duplicates", self.duplicates),
            ("reordered", self.reordered),
            ("late_dropped", self.late_dropped),
            ("late_points", self.late_points),
            ("lost", self.lost),
            ("resyncs", self.resyncs),
            ("scans", self.scans),
            ("scans_dropped", self.scans_dropped),
            ("imu_dropped", self.imu_dropped),
        ]
    }

    /// Datagrams rejected as malformed (any reason).
    pub fn malformed(&self) -> u64 {
        self.truncated
            + self.length_mismatch
            + self.bad_version
            + self.unknown_data_type
            + self.dot_num_mismatch
            + self.bad_crc
    }
}

/// What became of a datagram that parsed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Accepted {
    /// A point packet; how many points were kept.
    Points(usize),
    /// An IMU packet; how many samples.
    Imu(usize),
    Duplicate,
    /// Arrived after its scan had been emitted.
    LateDropped,
}

/// One assembled scan: the points whose times fall in `[start_ns, end_ns)`, sorted by time.
#[derive(Clone, Debug, PartialEq)]
pub struct Scan {
    pub start_ns: u64,
    pub end_ns: u64,
    pub points: PointColumns,
    /// Point packets that contributed.
    pub packets: u32,
    /// The window was not covered from its start to its end (first scan of a stream,
    /// or closed by a resync or a flush before the stream reached its end).
    pub partial: bool,
}

#[derive(Default)]
struct OpenScan {
    points: PointColumns,
    packets: u32,
    sorted: bool,
}

#[derive(Clone, Copy)]
struct Newest {
    frame_cnt: u8,
    udp_cnt: u16,
    timestamp_ns: u64,
    end_ns: u64,
    interval_ns: u64,
}

impl Newest {
    fn of(h: &PacketHeader) -> Self {
        Self {
            frame_cnt: h.frame_cnt,
            udp_cnt: h.udp_cnt,
            timestamp_ns: h.timestamp_ns,
            end_ns: h.timestamp_ns.saturating_add(h.interval_ns()),
            interval_ns: h.interval_ns(),
        }
    }
}

/// The stateful receiver: push datagrams, pop scans and IMU samples.
pub struct ScanAssembler {
    config: AssemblerConfig,
    stats: Stats,
    open: BTreeMap<u64, OpenScan>,
    newest: Option<Newest>,
    recent: VecDeque<(u8, u16, u64)>,
    ready: VecDeque<Scan>,
    imu: VecDeque<ImuSample>,
    /// Highest window already emitted in this segment.
    closed_through: Option<u64>,
    /// (first window of the segment, whether the segment began after its start).
    segment_start: Option<(u64, bool)>,
    scratch: PointColumns,
}

impl ScanAssembler {
    /// A period of 0 is raised to 1 ns (no division by zero).
    pub fn new(mut config: AssemblerConfig) -> Self {
        config.frame_period_ns = config.frame_period_ns.max(1);
        config.max_open_scans = config.max_open_scans.max(1);
        config.max_queued_scans = config.max_queued_scans.max(1);
        Self {
            config,
            stats: Stats::default(),
            open: BTreeMap::new(),
            newest: None,
            recent: VecDeque::with_capacity(RECENT_KEYS),
            ready: VecDeque::new(),
            imu: VecDeque::new(),
            closed_through: None,
            segment_start: None,
            scratch: PointColumns::with_capacity(crate::packet::MID360_DOTS_PER_PACKET),
        }
    }

    pub fn config(&self) -> &AssemblerConfig {
        &self.config
    }

    pub fn stats(&self) -> &Stats {
        &self.stats
    }

    /// Takes one datagram. A malformed one is counted and returned as the error.
    pub fn push(&mut self, datagram: &[u8]) -> Result<Accepted, PacketError> {
        self.stats.datagrams += 1;
        let packet = match parse_packet(datagram) {
            Ok(p) => p,
            Err(err) => {
                self.count_error(&err);
                return Err(err);
            }
        };
        if packet.header.data_type == DataType::Imu {
            return self.push_imu(&packet);
        }
        Ok(self.push_points(&packet))
    }

    /// The oldest finished scan.
    pub fn pop_scan(&mut self) -> Option<Scan> {
        self.ready.pop_front()
    }

    pub fn pending_scans(&self) -> usize {
        self.ready.len()
    }

    /// All queued IMU samples, oldest first.
    pub fn drain_imu(&mut self) -> Vec<ImuSample> {
        self.imu.drain(..).collect()
    }

    /// Closes every open window (end of stream).
    pub fn flush(&mut self) {
        let windows: Vec<u64> = self.open.keys().copied().collect();
        for w in windows {
            self.close(w);
        }
    }

    fn count_error(&mut self, err: &PacketError) {
        let s = &mut self.stats;
        match err {
            PacketError::Truncated { .. } => s.truncated += 1,
            PacketError::LengthMismatch { .. } => s.length_mismatch += 1,
            PacketError::UnsupportedVersion(_) => s.bad_version += 1,
            PacketError::UnknownDataType(_) => s.unknown_data_type += 1,
            PacketError::DotNumMismatch { .. } => s.dot_num_mismatch += 1,
            PacketError::Crc32Mismatch { .. } => s.bad_crc += 1,
            // parse_packet does not return these; counted as a type problem if it ever did.
            PacketError::NotPoints(_) | PacketError::NotImu(_) => s.unknown_data_type += 1,
        }
    }

    fn push_imu(&mut self, packet: &Packet<'_>) -> Result<Accepted, PacketError> {
        let samples = decode_imu(packet)?;
        self.stats.imu_packets += 1;
        self.stats.imu_samples += samples.len() as u64;
        let n = samples.len();
        for s in samples {
            if self.imu.len() >= self.config.max_queued_imu {
                self.imu.pop_front();
                self.stats.imu_dropped += 1;
            }
            self.imu.push_back(s);
        }
        Ok(Accepted::Imu(n))
    }

    fn window_of(&self, t_ns: u64) -> u64 {
        t_ns / self.config.frame_period_ns
    }

    fn window_end(&self, w: u64) -> u64 {
        w.saturating_add(1).saturating_mul(self.config.frame_period_ns)
    }

    fn missing_between(n: &Newest, h: &PacketHeader) -> u64 {
        let by_time = h
            .timestamp_ns
            .saturating_sub(n.end_ns)
            .saturating_add(n.interval_ns / 2)
            .checked_div(n.interval_ns)
            .unwrap_or(0);
        if h.frame_cnt == n.frame_cnt {
            let gap = h.udp_cnt.wrapping_sub(n.udp_cnt).wrapping_sub(1);
            if gap < 0x8000 {
                u64::from(gap)
            } else {
                by_time
            }
        } else {
            by_time.max(u64::from(h.udp_cnt))
        }
    }

    fn resync(&mut self) {
        self.stats.resyncs += 1;
        self.flush();
        self.closed_through = None;
        self.segment_start = None;
        self.newest = None;
    }

    fn push_points(&mut self, packet: &Packet<'_>) -> Accepted {
        let h = packet.header;
        let key = (h.frame_cnt, h.udp_cnt, h.timestamp_ns);
        if self.recent.contains(&key) {
            self.stats.duplicates += 1;
            return Accepted::Duplicate;
        }
        if self.recent.len() >= RECENT_KEYS {
            self.recent.pop_front();
        }
        self.recent.push_back(key);
        self.stats.point_packets += 1;

        let mut late = false;
        if let Some(n) = self.newest {
            if h.timestamp_ns < n.timestamp_ns {
                if n.timestamp_ns - h.timestamp_ns > self.config.resync_gap_ns {
                    self.resync();
                } else {
                    late = true;
                    self.stats.reordered += 1;
                    self.stats.lost = self.stats.lost.saturating_sub(1);
                }
            } else if h.timestamp_ns.saturating_sub(n.end_ns) > self.config.resync_gap_ns {
                self.resync();
            } else {
                self.stats.lost += Self::missing_between(&n, &h);
            }
        }
        if !late {
            self.newest = Some(Newest::of(&h));
        }
        if self.segment_start.is_none() {
            let w = self.window_of(h.timestamp_ns);
            let began_late = h.timestamp_ns.saturating_sub(w.saturating_mul(self.config.frame_period_ns))
                > h.interval_ns();
            self.segment_start = Some((w, began_late));
        }

        let (kept, accepted) = self.distribute(packet);
        self.stats.points += accepted as u64;
        if late && accepted == 0 && kept > 0 {
            self.stats.late_dropped += 1;
            return Accepted::LateDropped;
        }
        if !late {
            self.close_before(h.timestamp_ns);
        }
        while self.open.len() > self.config.max_open_scans {
            match self.open.keys().next().copied() {
                Some(w) => self.close(w),
                None => break,
            }
        }
        Accepted::Points(accepted)
    }

    /// Adds the packet's points to the windows of their times; returns (decoded, accepted).
    fn distribute(&mut self, packet: &Packet<'_>) -> (usize, usize) {
        let h = packet.header;
        let n = usize::from(h.dot_num);
        let w_first = self.window_of(h.sample_time_ns(0));
        let w_last = self.window_of(h.sample_time_ns(n.saturating_sub(1)));
        let keep_zero = self.config.keep_zero_points;
        // Common case: the whole packet falls in one open window: decode straight into it.
        if w_first == w_last && !self.closed_through.is_some_and(|c| w_first <= c) {
            let scan = self.open.entry(w_first).or_insert_with(|| OpenScan { sorted: true, ..OpenScan::default() });
            let before = scan.points.len();
            let last = scan.points.times_ns.last().copied();
            let (kept, skipped) = decode_points(packet, &mut scan.points, keep_zero).unwrap_or((0, 0));
            if kept > 0 {
                scan.packets += 1;
            }
            if last.is_some_and(|t| scan.points.times_ns.get(before).is_some_and(|&first| first < t)) {
                scan.sorted = false;
            }
            self.stats.zero_points += skipped as u64;
            return (kept, kept);
        }
        let mut scratch = std::mem::take(&mut self.scratch);
        scratch.clear();
        let (kept, skipped) = decode_points(packet, &mut scratch, keep_zero).unwrap_or((0, 0));
        self.stats.zero_points += skipped as u64;
        let mut accepted = 0usize;
        let mut last_window: Option<u64> = None;
        for i in 0..scratch.len() {
            let t = scratch.times_ns[i];
            let w = self.window_of(t);
            if self.closed_through.is_some_and(|c| w <= c) {
                self.stats.late_points += 1;
                continue;
            }
            let scan = self.open.entry(w).or_insert_with(|| OpenScan { sorted: true, ..OpenScan::default() });
            if last_window != Some(w) {
                scan.packets += 1;
                last_window = Some(w);
            }
            if scan.points.times_ns.last().is_some_and(|&last| t < last) {
                scan.sorted = false;
            }
            scan.points.push(
                [scratch.xyz[3 * i], scratch.xyz[3 * i + 1], scratch.xyz[3 * i + 2]],
                scratch.reflectivity[i],
                scratch.tag[i],
                t,
            );
            accepted += 1;
        }
        self.scratch = scratch;
        (kept, accepted)
    }

    fn close_before(&mut self, t_ns: u64) {
        while let Some(w) = self.open.keys().next().copied() {
            if self.window_end(w).saturating_add(self.config.reorder_grace_ns) <= t_ns {
                self.close(w);
            } else {
                break;
            }
        }
    }

    fn close(&mut self, w: u64) {
        let Some(mut scan) = self.open.remove(&w) else { return };
        if !scan.sorted {
            sort_by_time(&mut scan.points);
        }
        let start_ns = w.saturating_mul(self.config.frame_period_ns);
        let end_ns = self.window_end(w);
        let began_late = matches!(self.segment_start, Some((first, true)) if first == w);
        let ended_early = self.newest.is_some_and(|n| n.end_ns.saturating_add(n.interval_ns) < end_ns);
        self.closed_through = Some(self.closed_through.map_or(w, |c| c.max(w)));
        if self.ready.len() >= self.config.max_queued_scans {
            self.ready.pop_front();
            self.stats.scans_dropped += 1;
        }
        self.stats.scans += 1;
        self.ready.push_back(Scan {
            start_ns,
            end_ns,
            points: scan.points,
            packets: scan.packets,
            partial: began_late || ended_early,
        });
    }
}

/// Reorders every column by time (stable: equal times keep arrival order).
fn sort_by_time(p: &mut PointColumns) {
    let mut order: Vec<usize> = (0..p.len()).collect();
    order.sort_by_key(|&i| p.times_ns[i]);
    let mut out = PointColumns::with_capacity(p.len());
    for &i in &order {
        out.push([p.xyz[3 * i], p.xyz[3 * i + 1], p.xyz[3 * i + 2]], p.reflectivity[i], p.tag[i], p.times_ns[i]);
    }
    *p = out;
}
