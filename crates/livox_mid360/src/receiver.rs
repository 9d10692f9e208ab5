//! A Mid-360's datagrams read, stamped and assembled by threads of their own.
//!
//! Why not in Python: a Python thread that reads one datagram per `recvfrom` gives the GIL up
//! for every call and must win it back from whichever thread holds it, which on a busy
//! computer takes up to the interpreter's switch interval (5 ms). A Mid-360 sends about 2,000
//! datagrams a second, so a flight loop busy with detection and planning let that reader fall
//! behind by seconds, and every datagram was stamped when it was *read*, not when it
//! *arrived*: the sensor-to-host clock fit then read +-1000 ppm and the scans came too late to
//! pair with the camera frames. Here a thread per socket blocks in `recv_from` with no lock of
//! the caller's held, stamps each datagram the moment the kernel hands it over, takes it from
//! the LiDAR only, and feeds the [`ScanAssembler`]; the caller takes the finished scans, the
//! IMU samples and the packets' (sensor stamp, arrival) pairs in one call
//! ([`LivoxReceiver::take`]).
//!
//! Everything queued is bounded: finished scans and IMU samples by the assembler's config,
//! stamps by [`ReceiverConfig::max_queued_stamps`] (the oldest dropped and counted).

use std::collections::VecDeque;
use std::io::ErrorKind;
use std::net::{IpAddr, SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use crate::assembler::{Accepted, AssemblerConfig, Scan, ScanAssembler, Stats};
use crate::packet::{parse_packet, ImuSample};

/// The largest datagram read (a Mid-360 point packet is 1,380 bytes).
pub const MAX_DATAGRAM: usize = 2048;
/// How often a blocked reader looks at the stop flag.
const STOP_POLL: Duration = Duration::from_millis(50);

#[derive(Clone, Debug)]
pub struct ReceiverConfig {
    pub assembler: AssemblerConfig,
    /// Take datagrams from this address only; None: from the first address that sent a
    /// valid packet to each socket.
    pub lidar_ip: Option<IpAddr>,
    /// Most (stamp, arrival) pairs queued for the caller.
    pub max_queued_stamps: usize,
    /// Accept datagrams from the start; else they are dropped (counted `unstamped`) until
    /// [`LivoxReceiver::accept`] (a caller with no clock to stamp them with yet).
    pub accepting: bool,
}

impl Default for ReceiverConfig {
    fn default() -> Self {
        Self { assembler: AssemblerConfig::default(), lidar_ip: None, max_queued_stamps: 1 << 16, accepting: true }
    }
}

/// A valid packet's last-sample stamp (sensor clock, ns) and when it arrived.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PacketStamp {
    pub stamp_ns: u64,
    pub arrival: Instant,
}

/// What [`LivoxReceiver::take`] hands over.
#[derive(Debug, Default)]
pub struct Taken {
    pub scans: Vec<Scan>,
    pub imu: Vec<ImuSample>,
    pub stamps: Vec<PacketStamp>,
    /// Datagrams read so far (all of them: from the LiDAR or not, accepted or not).
    pub datagrams: u64,
}

/// Counters beyond the assembler's.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ReceiverStats {
    /// Datagrams read, from anyone.
    pub read: u64,
    /// From another address than the LiDAR's (never parsed).
    pub foreign: u64,
    /// Dropped before [`LivoxReceiver::accept`].
    pub unstamped: u64,
    /// Stamps dropped because the caller did not take them.
    pub stamps_overflowed: u64,
    /// `recv_from` failures other than the stop poll's time-out.
    pub read_errors: u64,
}

struct Intake {
    assembler: ScanAssembler,
    config: ReceiverConfig,
    sources: Vec<Option<SocketAddr>>,
    stamps: VecDeque<PacketStamp>,
    stats: ReceiverStats,
    /// Something arrived since the last take.
    fresh: bool,
}

impl Intake {
    fn new(config: ReceiverConfig, sockets: usize) -> Self {
        Self {
            assembler: ScanAssembler::new(config.assembler),
            sources: vec![None; sockets],
            stamps: VecDeque::new(),
            stats: ReceiverStats::default(),
            fresh: false,
            config,
        }
    }

    /// One datagram from `peer` on socket `socket`, arrived at `arrival`.
    fn push(&mut self, socket: usize, peer: SocketAddr, arrival: Instant, data: &[u8]) {
        self.stats.read += 1;
        self.fresh = true;
        let source = self.sources.get(socket).copied().flatten();
        let wrong_ip = self.config.lidar_ip.is_some_and(|ip| ip != peer.ip());
        if wrong_ip || source.is_some_and(|s| s != peer) {
            self.stats.foreign += 1;
            return;
        }
        if !self.config.accepting {
            self.stats.unstamped += 1;
            return;
        }
        let accepted = self.assembler.push(data);
        if matches!(accepted, Ok(Accepted::Points(_) | Accepted::Imu(_) | Accepted::LateDropped)) {
            if let Ok(packet) = parse_packet(data) {
                let h = packet.header;
                let stamp_ns = h.timestamp_ns.saturating_add(100 * u64::from(h.time_interval));
                if self.stamps.len() >= self.config.max_queued_stamps {
                    self.stamps.pop_front();
                    self.stats.stamps_overflowed += 1;
                }
                self.stamps.push_back(PacketStamp { stamp_ns, arrival });
            }
            if source.is_none() {
                if let Some(slot) = self.sources.get_mut(socket) {
                    *slot = Some(peer);
                }
            }
        }
    }

    fn take(&mut self) -> Taken {
        self.fresh = false;
        let mut scans = Vec::with_capacity(self.assembler.pending_scans());
        while let Some(scan) = self.assembler.pop_scan() {
            scans.push(scan);
        }
        Taken { scans, imu: self.assembler.drain_imu(), stamps: self.stamps.drain(..).collect(), datagrams: self.stats.read }
    }
}

struct Shared {
    intake: Mutex<Intake>,
    fresh: Condvar,
    stop: AtomicBool,
}

impl Shared {
    /// The intake, even after a reader panicked while holding it (its state is counters and
    /// queues, each left whole by every operation).
    fn intake(&self) -> MutexGuard<'_, Intake> {
        self.intake.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
    }
}

/// Reader threads over bound UDP sockets feeding one scan assembler.
pub struct LivoxReceiver {
    shared: Arc<Shared>,
    threads: Mutex<Vec<JoinHandle<()>>>,
}

impl LivoxReceiver {
    /// Without threads: datagrams come in through [`LivoxReceiver::push`] only (tests, replays).
    pub fn manual(config: ReceiverConfig, sockets: usize) -> Self {
        let shared = Arc::new(Shared {
            intake: Mutex::new(Intake::new(config, sockets.max(1))),
            fresh: Condvar::new(),
            stop: AtomicBool::new(false),
        });
        Self { shared, threads: Mutex::new(Vec::new()) }
    }

    /// Starts one reader thread per socket (socket index = position in `sockets`).
    pub fn spawn(sockets: Vec<UdpSocket>, config: ReceiverConfig) -> std::io::Result<Self> {
        let receiver = Self::manual(config, sockets.len());
        let mut threads = Vec::with_capacity(sockets.len());
        for (index, socket) in sockets.into_iter().enumerate() {
            socket.set_nonblocking(false)?;
            socket.set_read_timeout(Some(STOP_POLL))?;
            let shared = Arc::clone(&receiver.shared);
            let spawned = std::thread::Builder::new()
                .name(format!("livox-read-{index}"))
                .spawn(move || read_loop(index, &socket, &shared));
            match spawned {
                Ok(handle) => threads.push(handle),
                Err(err) => {
                    receiver.shared.stop.store(true, Ordering::Relaxed);
                    for handle in threads {
                        let _ = handle.join();
                    }
                    return Err(err);
                }
            }
        }
        *receiver.threads.lock().unwrap_or_else(|p| p.into_inner()) = threads;
        Ok(receiver)
    }

    /// Hands one datagram in as if read from socket `socket` (the readers' own path).
    pub fn push(&self, socket: usize, peer: SocketAddr, arrival: Instant, data: &[u8]) {
        self.shared.intake().push(socket, peer, arrival, data);
        self.shared.fresh.notify_all();
    }

    /// Everything finished since the last take; waits up to `timeout` until a datagram has
    /// arrived since then.
    pub fn take(&self, timeout: Duration) -> Taken {
        let deadline = Instant::now() + timeout;
        let mut intake = self.shared.intake();
        while !intake.fresh && !self.shared.stop.load(Ordering::Relaxed) {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                break;
            }
            intake = match self.shared.fresh.wait_timeout(intake, left) {
                Ok((guard, _)) => guard,
                Err(poisoned) => poisoned.into_inner().0,
            };
        }
        intake.take()
    }

    /// Closes every open scan (end of stream); the scans go out with the next take.
    pub fn flush(&self) {
        self.shared.intake().assembler.flush();
    }

    /// Datagrams are accepted from now on (see [`ReceiverConfig::accepting`]).
    pub fn accept(&self) {
        self.shared.intake().config.accepting = true;
    }

    pub fn stats(&self) -> (Stats, ReceiverStats) {
        let intake = self.shared.intake();
        (*intake.assembler.stats(), intake.stats)
    }

    /// Stops the readers and waits for them (within one stop poll); idempotent.
    pub fn stop(&self) {
        self.shared.stop.store(true, Ordering::Relaxed);
        self.shared.fresh.notify_all();
        let handles: Vec<_> = self.threads.lock().unwrap_or_else(|p| p.into_inner()).drain(..).collect();
        for handle in handles {
            // a reader that panicked has nothing left to hand over: its datagrams are in the intake
            let _ = handle.join();
        }
    }
}

impl Drop for LivoxReceiver {
    fn drop(&mut self) {
        self.stop();
    }
}

fn read_loop(index: usize, socket: &UdpSocket, shared: &Shared) {
    let mut buffer = [0u8; MAX_DATAGRAM];
    while !shared.stop.load(Ordering::Relaxed) {
        match socket.recv_from(&mut buffer) {
            Ok((n, peer)) => {
                let arrival = Instant::now();
                shared.intake().push(index, peer, arrival, &buffer[..n]);
                shared.fresh.notify_all();
            }
            Err(err) if matches!(err.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut | ErrorKind::Interrupted) => {}
            Err(_) => {
                shared.intake().stats.read_errors += 1;
                // a socket in error (closed under us): do not spin on it
                std::thread::sleep(STOP_POLL);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::packet::{encode_packet, DataType, PacketMeta};

    fn points_packet(udp_cnt: u16, timestamp_ns: u64) -> Vec<u8> {
        let meta = PacketMeta {
            time_interval: 48,
            udp_cnt,
            frame_cnt: 0,
            data_type: DataType::CartesianHigh,
            time_type: 0,
            timestamp_ns,
        };
        let mut sample = Vec::new();
        for v in [1000i32, 2000, 3000] {
            sample.extend_from_slice(&v.to_le_bytes());
        }
        sample.extend_from_slice(&[50, 0]);
        encode_packet(&meta, &sample).unwrap()
    }

    fn pair() -> (UdpSocket, UdpSocket) {
        let rx = UdpSocket::bind("127.0.0.1:0").unwrap();
        let tx = UdpSocket::bind("127.0.0.1:0").unwrap();
        tx.connect(rx.local_addr().unwrap()).unwrap();
        (rx, tx)
    }

    fn take_until(receiver: &LivoxReceiver, read: u64) -> Vec<Taken> {
        let deadline = Instant::now() + Duration::from_secs(5);
        let mut out = Vec::new();
        loop {
            let taken = receiver.take(Duration::from_millis(100));
            let done = taken.datagrams >= read || Instant::now() > deadline;
            out.push(taken);
            if done {
                return out;
            }
        }
    }

    #[test]
    fn datagrams_are_stamped_on_arrival_and_assembled_into_scans() {
        let (rx, tx) = pair();
        let receiver = LivoxReceiver::spawn(vec![rx], ReceiverConfig::default()).unwrap();
        let before = Instant::now();
        // 0.25 s of one point per 10 ms: two full 100 ms windows and the start of a third
        let n = 25u16;
        for k in 0..n {
            tx.send(&points_packet(k, 1_000_000_000 + u64::from(k) * 10_000_000)).unwrap();
        }
        let taken = take_until(&receiver, u64::from(n));
        let stamps: Vec<_> = taken.iter().flat_map(|t| t.stamps.iter().copied()).collect();
        assert_eq!(stamps.len(), usize::from(n));
        for (k, s) in stamps.iter().enumerate() {
            assert_eq!(s.stamp_ns, 1_000_000_000 + k as u64 * 10_000_000 + 4800);
            assert!(s.arrival >= before && s.arrival <= Instant::now());
        }
        let scans: usize = taken.iter().map(|t| t.scans.len()).sum();
        assert!(scans >= 1, "no finished scan among {n} packets over 0.25 s");
        assert_eq!(receiver.stats().1, ReceiverStats { read: u64::from(n), ..ReceiverStats::default() });
    }

    #[test]
    fn only_the_first_source_or_the_lidar_ip_is_taken() {
        let config = ReceiverConfig::default();
        let receiver = LivoxReceiver::manual(config, 1);
        let lidar: SocketAddr = "10.0.0.5:56300".parse().unwrap();
        let other: SocketAddr = "10.0.0.9:56300".parse().unwrap();
        let now = Instant::now();
        receiver.push(0, lidar, now, &points_packet(0, 1_000_000_000));
        receiver.push(0, other, now, &points_packet(1, 1_010_000_000));
        receiver.push(0, lidar, now, &[1, 2, 3]); // malformed: counted by the assembler
        let (assembler, own) = receiver.stats();
        assert_eq!(own.foreign, 1);
        assert_eq!(assembler.datagrams, 2);
        assert_eq!(receiver.take(Duration::ZERO).stamps.len(), 1);

        let fixed = LivoxReceiver::manual(ReceiverConfig { lidar_ip: Some(lidar.ip()), ..ReceiverConfig::default() }, 1);
        fixed.push(0, other, now, &points_packet(0, 1_000_000_000));
        assert_eq!(fixed.stats().1.foreign, 1);
        assert_eq!(fixed.stats().0.datagrams, 0);
    }

    #[test]
    fn datagrams_before_accept_are_counted_unstamped_and_never_assembled() {
        let receiver = LivoxReceiver::manual(ReceiverConfig { accepting: false, ..ReceiverConfig::default() }, 1);
        let peer: SocketAddr = "127.0.0.1:9".parse().unwrap();
        let now = Instant::now();
        receiver.push(0, peer, now, &points_packet(0, 1_000_000_000));
        receiver.accept();
        receiver.push(0, peer, now, &points_packet(1, 1_010_000_000));
        let (assembler, own) = receiver.stats();
        assert_eq!((own.unstamped, assembler.datagrams), (1, 1));
        assert_eq!(receiver.take(Duration::ZERO).datagrams, 2);
    }

    #[test]
    fn stamps_are_bounded_and_take_waits_no_longer_than_its_timeout() {
        let receiver = LivoxReceiver::manual(ReceiverConfig { max_queued_stamps: 3, ..ReceiverConfig::default() }, 1);
        let peer: SocketAddr = "127.0.0.1:9".parse().unwrap();
        for k in 0..10u16 {
            receiver.push(0, peer, Instant::now(), &points_packet(k, 1_000_000_000 + u64::from(k) * 1_000_000));
        }
        let taken = receiver.take(Duration::ZERO);
        assert_eq!(taken.stamps.len(), 3);
        assert_eq!(taken.stamps[0].stamp_ns, 1_007_004_800);
        assert_eq!(receiver.stats().1.stamps_overflowed, 7);
        let t0 = Instant::now();
        assert!(receiver.take(Duration::from_millis(30)).stamps.is_empty());
        assert!(t0.elapsed() >= Duration::from_millis(30));
    }

    #[test]
    fn stop_ends_the_readers_promptly() {
        let (rx, _tx) = pair();
        let receiver = LivoxReceiver::spawn(vec![rx], ReceiverConfig::default()).unwrap();
        let t0 = Instant::now();
        receiver.stop();
        receiver.stop();
        assert!(t0.elapsed() < Duration::from_secs(2));
        let t1 = Instant::now();
        receiver.take(Duration::from_secs(1));
        assert!(t1.elapsed() < Duration::from_millis(500));
    }
}
