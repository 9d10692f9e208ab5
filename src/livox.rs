//! Bindings of `livox_mid360`: the scan assembler (datagrams in, scans as numpy
//! arrays out, moved without copying), the packet-header parser and the control-frame
//! builders/parsers. Protocol errors become `insulator_rs.exceptions.PacketError` (a
//! `SensorError`) whose message starts with the packet or frame field at fault
//! (`packet.crc32: ...`, `command.sof: ...`); bad arguments stay `ValueError`. No
//! protocol logic lives here.

use std::net::{IpAddr, Ipv4Addr, SocketAddr, UdpSocket};
use std::os::fd::BorrowedFd;
use std::sync::{Mutex, MutexGuard};
use std::time::{Duration, Instant};

use livox_mid360::control::{self, CommandFrame, ConfigAck, DiscoveryAck, WorkMode};
use livox_mid360::{
    parse_packet, Accepted, AssemblerConfig, ImuSample, LivoxReceiver as Receiver, PacketError, ReceiverConfig, Scan,
    ScanAssembler,
};
use numpy::ndarray::Array2;
use numpy::{IntoPyArray, PyArray1, PyArray2};
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict};

use crate::errors::to_pyerr;
use crate::pyutils::frozen_array;

/// The counter name a malformed datagram is filed under (same names as `stats()`).
fn error_kind(err: &PacketError) -> &'static str {
    match err {
        PacketError::Truncated { .. } => "truncated",
        PacketError::LengthMismatch { .. } => "length_mismatch",
        PacketError::UnsupportedVersion(_) => "bad_version",
        PacketError::UnknownDataType(_) | PacketError::NotPoints(_) | PacketError::NotImu(_) => "unknown_data_type",
        PacketError::DotNumMismatch { .. } => "dot_num_mismatch",
        PacketError::Crc32Mismatch { .. } => "bad_crc",
    }
}

fn seconds_to_ns(name: &str, seconds: f64, allow_zero: bool) -> PyResult<u64> {
    let ok = seconds.is_finite() && (seconds > 0.0 || (allow_zero && seconds == 0.0)) && seconds < 1.0e6;
    if !ok {
        let bound = if allow_zero { ">= 0" } else { "> 0" };
        return Err(PyValueError::new_err(format!(
            "{name}: must be a finite number of seconds {bound} and < 1e6, got {seconds}"
        )));
    }
    Ok((seconds * 1e9).round() as u64)
}

/// One assembled scan (sensor clock): points in the LiDAR frame, metres.
#[pyclass(frozen, module = "insulator_rs._core")]
pub struct LivoxScan {
    #[pyo3(get)]
    points: Py<PyArray2<f32>>,
    #[pyo3(get)]
    times_ns: Py<PyArray1<u64>>,
    #[pyo3(get)]
    reflectivity: Py<PyArray1<u8>>,
    #[pyo3(get)]
    tag: Py<PyArray1<u8>>,
    #[pyo3(get)]
    start_ns: u64,
    #[pyo3(get)]
    end_ns: u64,
    #[pyo3(get)]
    packets: u32,
    #[pyo3(get)]
    partial: bool,
    n: usize,
}

#[pymethods]
impl LivoxScan {
    fn __len__(&self) -> usize {
        self.n
    }

    fn __repr__(&self) -> String {
        format!(
            "LivoxScan(points={}, start_ns={}, end_ns={}, packets={}, partial={})",
            self.n,
            self.start_ns,
            self.end_ns,
            self.packets,
            if self.partial { "True" } else { "False" }
        )
    }
}

fn scan_to_py(py: Python<'_>, scan: Scan) -> PyResult<LivoxScan> {
    let p = scan.points;
    let n = p.times_ns.len();
    let xyz = Array2::from_shape_vec((n, 3), p.xyz).map_err(|e| PyRuntimeError::new_err(format!("LivoxScan.points: {e}")))?;
    Ok(LivoxScan {
        points: frozen_array(xyz.into_pyarray(py))?,
        times_ns: frozen_array(p.times_ns.into_pyarray(py))?,
        reflectivity: frozen_array(p.reflectivity.into_pyarray(py))?,
        tag: frozen_array(p.tag.into_pyarray(py))?,
        start_ns: scan.start_ns,
        end_ns: scan.end_ns,
        packets: scan.packets,
        partial: scan.partial,
        n,
    })
}

/// Datagrams in (point-cloud and IMU ports), 10 Hz scans out; every fault counted.
#[pyclass(frozen, module = "insulator_rs._core")]
pub struct LivoxScanAssembler {
    inner: Mutex<ScanAssembler>,
}

impl LivoxScanAssembler {
    fn lock(&self) -> PyResult<MutexGuard<'_, ScanAssembler>> {
        self.inner
            .lock()
            .map_err(|_| PyRuntimeError::new_err("LivoxScanAssembler: state poisoned by an earlier panic"))
    }
}

#[pymethods]
impl LivoxScanAssembler {
    #[new]
    #[pyo3(signature = (*, frame_period_s = 0.1, reorder_grace_s = 0.005, resync_gap_s = 1.0,
                        keep_zero_points = false, max_queued_scans = 16))]
    fn new(
        frame_period_s: f64,
        reorder_grace_s: f64,
        resync_gap_s: f64,
        keep_zero_points: bool,
        max_queued_scans: usize,
    ) -> PyResult<Self> {
        let config = assembler_config(frame_period_s, reorder_grace_s, resync_gap_s, keep_zero_points, max_queued_scans)?;
        Ok(Self { inner: Mutex::new(ScanAssembler::new(config)) })
    }

    /// Takes one datagram; returns what it was: "points", "imu", "duplicate", "late",
    /// or the counter a malformed one was filed under ("bad_crc", "truncated", ...).
    fn push(&self, datagram: &[u8]) -> PyResult<&'static str> {
        Ok(match self.lock()?.push(datagram) {
            Ok(Accepted::Points(_)) => "points",
            Ok(Accepted::Imu(_)) => "imu",
            Ok(Accepted::Duplicate) => "duplicate",
            Ok(Accepted::LateDropped) => "late",
            Err(err) => error_kind(&err),
        })
    }

    /// The oldest finished scan, or None.
    fn pop_scan(&self, py: Python<'_>) -> PyResult<Option<LivoxScan>> {
        let scan = self.lock()?.pop_scan();
        scan.map(|scan| scan_to_py(py, scan)).transpose()
    }

    /// Queued IMU samples: (times_ns (M,) uint64, gyro (M, 3) float32 rad/s, acc (M, 3) float32 g).
    fn drain_imu(&self, py: Python<'_>) -> PyResult<ImuArrays> {
        let samples = self.lock()?.drain_imu();
        imu_arrays(py, samples)
    }

    /// Closes every open scan (end of stream).
    fn flush(&self) -> PyResult<()> {
        self.lock()?.flush();
        Ok(())
    }

    #[getter]
    fn pending_scans(&self) -> PyResult<usize> {
        Ok(self.lock()?.pending_scans())
    }

    /// Every counter: datagrams, point/IMU packets, points, each malformation, duplicates,
    /// reordered, late, lost, resyncs, scans.
    fn stats<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let stats = *self.lock()?.stats();
        let d = PyDict::new(py);
        for (name, value) in stats.pairs() {
            d.set_item(name, value)?;
        }
        d.set_item("malformed", stats.malformed())?;
        Ok(d)
    }
}

/// What `LivoxReceiver.take` hands over: (scans, IMU (times_ns, gyro, acc), packet stamps (ns,
/// sensor clock), their arrivals (s, `time.monotonic()`'s clock), datagrams read so far).
type TakenTuple = (Vec<LivoxScan>, ImuArrays, Py<PyArray1<u64>>, Py<PyArray1<f64>>, u64);
type ImuArrays = (Py<PyArray1<u64>>, Py<PyArray2<f32>>, Py<PyArray2<f32>>);

fn imu_arrays(py: Python<'_>, samples: Vec<ImuSample>) -> PyResult<ImuArrays> {
    let m = samples.len();
    let times: Vec<u64> = samples.iter().map(|s| s.timestamp_ns).collect();
    let gyro: Vec<f32> = samples.iter().flat_map(|s| s.gyro).collect();
    let acc: Vec<f32> = samples.iter().flat_map(|s| s.acc).collect();
    let shape_err = |e: numpy::ndarray::ShapeError| PyRuntimeError::new_err(format!("imu: {e}"));
    let gyro = Array2::from_shape_vec((m, 3), gyro).map_err(shape_err)?;
    let acc = Array2::from_shape_vec((m, 3), acc).map_err(shape_err)?;
    Ok((frozen_array(times.into_pyarray(py))?, frozen_array(gyro.into_pyarray(py))?, frozen_array(acc.into_pyarray(py))?))
}

fn assembler_config(
    frame_period_s: f64,
    reorder_grace_s: f64,
    resync_gap_s: f64,
    keep_zero_points: bool,
    max_queued_scans: usize,
) -> PyResult<AssemblerConfig> {
    if max_queued_scans == 0 {
        return Err(PyValueError::new_err("max_queued_scans: must be >= 1, got 0"));
    }
    Ok(AssemblerConfig {
        frame_period_ns: seconds_to_ns("frame_period_s", frame_period_s, false)?,
        reorder_grace_ns: seconds_to_ns("reorder_grace_s", reorder_grace_s, true)?,
        resync_gap_ns: seconds_to_ns("resync_gap_s", resync_gap_s, false)?,
        keep_zero_points,
        max_queued_scans,
        ..AssemblerConfig::default()
    })
}

/// A Mid-360 read by Rust threads (livox_mid360::receiver): each datagram is read, stamped on
/// arrival, filtered by source and assembled with no GIL held; `take` hands everything over in
/// one call.
///
/// `fds`: the bound sockets' file descriptors (each is duplicated: the Python socket objects
/// keep theirs and must stay open while this runs; empty: no threads, datagrams come in through
/// `push`). `lidar_ip`: take datagrams from it only (None: from the first address that sent a
/// valid packet to each socket). `accepting`: False drops datagrams (counted `unstamped`)
/// until `accept()`.
#[pyclass(frozen, module = "insulator_rs._core")]
pub struct LivoxReceiver {
    receiver: Receiver,
    /// The same instant on both clocks: `Instant` and Python's `time.monotonic()` (read back to
    /// back while holding the GIL; both CLOCK_MONOTONIC on Linux).
    origin: (Instant, f64),
}

#[pymethods]
impl LivoxReceiver {
    #[new]
    #[pyo3(signature = (fds, *, lidar_ip = None, accepting = true, frame_period_s = 0.1, reorder_grace_s = 0.005,
                        resync_gap_s = 1.0, keep_zero_points = false, max_queued_scans = 64))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        fds: Vec<i32>,
        lidar_ip: Option<&str>,
        accepting: bool,
        frame_period_s: f64,
        reorder_grace_s: f64,
        resync_gap_s: f64,
        keep_zero_points: bool,
        max_queued_scans: usize,
    ) -> PyResult<Self> {
        let lidar_ip = lidar_ip
            .map(|ip| ip.parse::<IpAddr>().map_err(|_| PyValueError::new_err(format!("lidar_ip: expected an IP address, got {ip:?}"))))
            .transpose()?;
        let config = ReceiverConfig {
            assembler: assembler_config(frame_period_s, reorder_grace_s, resync_gap_s, keep_zero_points, max_queued_scans)?,
            lidar_ip,
            accepting,
            ..ReceiverConfig::default()
        };
        let mut sockets = Vec::with_capacity(fds.len());
        for fd in &fds {
            if *fd < 0 {
                return Err(PyValueError::new_err(format!("fds: {fd} is not an open file descriptor")));
            }
            // SAFETY: the fd is only borrowed for the duplication; the caller's socket keeps it open.
            let owned = unsafe { BorrowedFd::borrow_raw(*fd) }
                .try_clone_to_owned()
                .map_err(|e| PyValueError::new_err(format!("fds: cannot duplicate {fd}: {e}")))?;
            sockets.push(UdpSocket::from(owned));
        }
        let monotonic = py.import("time")?.getattr("monotonic")?;
        let before: f64 = monotonic.call0()?.extract()?;
        let instant = Instant::now();
        let after: f64 = monotonic.call0()?.extract()?;
        let receiver = if sockets.is_empty() {
            Receiver::manual(config, 2)
        } else {
            Receiver::spawn(sockets, config).map_err(|e| PyValueError::new_err(format!("fds: not usable as UDP sockets: {e}")))?
        };
        Ok(Self { receiver, origin: (instant, 0.5 * (before + after)) })
    }

    /// Everything finished since the last take: (scans, (imu times_ns, gyro, acc), stamps_ns,
    /// arrivals (s, `time.monotonic()`'s clock), datagrams read so far). Waits up to
    /// `timeout_s` (GIL released) until a datagram has arrived since the last take.
    fn take(&self, py: Python<'_>, timeout_s: f64) -> PyResult<TakenTuple> {
        if !(timeout_s.is_finite() && (0.0..=60.0).contains(&timeout_s)) {
            return Err(PyValueError::new_err(format!("timeout_s: must be within 0..60 s, got {timeout_s}")));
        }
        let taken = py.detach(|| self.receiver.take(Duration::from_secs_f64(timeout_s)));
        let (origin, origin_s) = self.origin;
        let stamps: Vec<u64> = taken.stamps.iter().map(|s| s.stamp_ns).collect();
        let arrivals: Vec<f64> =
            taken.stamps.iter().map(|s| origin_s + s.arrival.saturating_duration_since(origin).as_secs_f64()).collect();
        let scans = taken.scans.into_iter().map(|scan| scan_to_py(py, scan)).collect::<PyResult<Vec<_>>>()?;
        Ok((
            scans,
            imu_arrays(py, taken.imu)?,
            frozen_array(stamps.into_pyarray(py))?,
            frozen_array(arrivals.into_pyarray(py))?,
            taken.datagrams,
        ))
    }

    /// Hands in one datagram as if socket `socket` had read it from `host:port` just now.
    fn push(&self, socket: usize, host: &str, port: u16, datagram: &[u8]) -> PyResult<()> {
        let ip: IpAddr = host.parse().map_err(|_| PyValueError::new_err(format!("host: expected an IP address, got {host:?}")))?;
        self.receiver.push(socket, SocketAddr::new(ip, port), Instant::now(), datagram);
        Ok(())
    }

    /// Datagrams are accepted from now on.
    fn accept(&self) {
        self.receiver.accept();
    }

    /// Closes every open scan (end of stream); they come with the next take.
    fn flush(&self) {
        self.receiver.flush();
    }

    /// The assembler's counters plus read, foreign, unstamped, stamps_overflowed, read_errors.
    fn stats<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let (assembler, own) = self.receiver.stats();
        let d = PyDict::new(py);
        for (name, value) in assembler.pairs() {
            d.set_item(name, value)?;
        }
        d.set_item("malformed", assembler.malformed())?;
        d.set_item("read", own.read)?;
        d.set_item("foreign", own.foreign)?;
        d.set_item("unstamped", own.unstamped)?;
        d.set_item("stamps_overflowed", own.stamps_overflowed)?;
        d.set_item("read_errors", own.read_errors)?;
        Ok(d)
    }

    /// Stops the reader threads (within 50 ms); idempotent.
    fn stop(&self, py: Python<'_>) {
        py.detach(|| self.receiver.stop());
    }
}

/// The header of a point/IMU datagram after every check (CRC included), as a dict.
#[pyfunction]
fn livox_parse_header<'py>(py: Python<'py>, datagram: &[u8]) -> PyResult<Bound<'py, PyDict>> {
    let h = parse_packet(datagram).map_err(|e| to_pyerr(py, e))?.header;
    let d = PyDict::new(py);
    d.set_item("version", h.version)?;
    d.set_item("length", h.length)?;
    d.set_item("time_interval", h.time_interval)?;
    d.set_item("dot_num", h.dot_num)?;
    d.set_item("udp_cnt", h.udp_cnt)?;
    d.set_item("frame_cnt", h.frame_cnt)?;
    d.set_item("data_type", h.data_type.code())?;
    d.set_item("time_type", h.time_type)?;
    d.set_item("crc32", h.crc32)?;
    d.set_item("timestamp_ns", h.timestamp_ns)?;
    Ok(d)
}

/// A control frame with both checksums.
#[pyfunction]
#[pyo3(signature = (cmd_id, seq_num, data = b"".as_slice(), *, cmd_type = 0, sender_type = 0))]
fn livox_encode_command<'py>(
    py: Python<'py>,
    cmd_id: u16,
    seq_num: u32,
    data: &[u8],
    cmd_type: u8,
    sender_type: u8,
) -> PyResult<Bound<'py, PyBytes>> {
    let frame = CommandFrame { seq_num, cmd_id, cmd_type, sender_type, data: data.to_vec() };
    Ok(PyBytes::new(py, &frame.encode().map_err(|e| to_pyerr(py, e))?))
}

/// (cmd_id, seq_num, cmd_type, sender_type, data) of a checked control frame.
#[pyfunction]
fn livox_decode_command<'py>(py: Python<'py>, frame: &[u8]) -> PyResult<(u16, u32, u8, u8, Bound<'py, PyBytes>)> {
    let f = CommandFrame::decode(frame).map_err(|e| to_pyerr(py, e))?;
    Ok((f.cmd_id, f.seq_num, f.cmd_type, f.sender_type, PyBytes::new(py, &f.data)))
}

fn frame_bytes<'py>(py: Python<'py>, frame: CommandFrame) -> PyResult<Bound<'py, PyBytes>> {
    Ok(PyBytes::new(py, &frame.encode().map_err(|e| to_pyerr(py, e))?))
}

/// Discovery request (cmd 0x0000), to broadcast to port 56000.
#[pyfunction]
fn livox_discovery_request(py: Python<'_>, seq_num: u32) -> PyResult<Bound<'_, PyBytes>> {
    frame_bytes(py, control::discovery_request(seq_num))
}

/// Start (sampling=True) or stop sampling: cmd 0x0100, key 0x001A.
#[pyfunction]
fn livox_work_mode_request(py: Python<'_>, seq_num: u32, sampling: bool) -> PyResult<Bound<'_, PyBytes>> {
    let mode = if sampling { WorkMode::Sampling } else { WorkMode::Idle };
    frame_bytes(py, control::work_mode_request(seq_num, mode))
}

/// Send point data to host_ip:point_port and IMU data to host_ip:imu_port (keys 0x0006, 0x0007).
#[pyfunction]
fn livox_host_config_request<'py>(
    py: Python<'py>,
    seq_num: u32,
    host_ip: &str,
    point_port: u16,
    imu_port: u16,
) -> PyResult<Bound<'py, PyBytes>> {
    let ip: Ipv4Addr = host_ip
        .parse()
        .map_err(|_| PyValueError::new_err(format!("host_ip: expected an IPv4 address, got {host_ip:?}")))?;
    frame_bytes(py, control::host_config_request(seq_num, ip.octets(), point_port, imu_port))
}

/// The discovery ack: ret_code, dev_type (9 = Mid-360), serial_number, lidar_ip, cmd_port.
#[pyfunction]
fn livox_parse_discovery_ack<'py>(py: Python<'py>, frame: &[u8]) -> PyResult<Bound<'py, PyDict>> {
    let f = CommandFrame::decode(frame).map_err(|e| to_pyerr(py, e))?;
    let ack = DiscoveryAck::parse(&f).map_err(|e| to_pyerr(py, e))?;
    let d = PyDict::new(py);
    d.set_item("ret_code", ack.ret_code)?;
    d.set_item("dev_type", ack.dev_type)?;
    d.set_item("serial_number", ack.serial_number)?;
    d.set_item("lidar_ip", Ipv4Addr::from(ack.lidar_ip).to_string())?;
    d.set_item("cmd_port", ack.cmd_port)?;
    Ok(d)
}

/// (ret_code, error_key) of the ack to a 0x0100 configuration.
#[pyfunction]
fn livox_parse_config_ack(py: Python<'_>, frame: &[u8]) -> PyResult<(u8, u16)> {
    let f = CommandFrame::decode(frame).map_err(|e| to_pyerr(py, e))?;
    let ack = ConfigAck::parse(&f).map_err(|e| to_pyerr(py, e))?;
    Ok((ack.ret_code, ack.error_key))
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<LivoxScan>()?;
    m.add_class::<LivoxScanAssembler>()?;
    m.add_class::<LivoxReceiver>()?;
    m.add_function(wrap_pyfunction!(livox_parse_header, m)?)?;
    m.add_function(wrap_pyfunction!(livox_encode_command, m)?)?;
    m.add_function(wrap_pyfunction!(livox_decode_command, m)?)?;
    m.add_function(wrap_pyfunction!(livox_discovery_request, m)?)?;
    m.add_function(wrap_pyfunction!(livox_work_mode_request, m)?)?;
    m.add_function(wrap_pyfunction!(livox_host_config_request, m)?)?;
    m.add_function(wrap_pyfunction!(livox_parse_discovery_ack, m)?)?;
    m.add_function(wrap_pyfunction!(livox_parse_config_ack, m)?)?;
    Ok(())
}
