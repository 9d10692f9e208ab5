//! Control-command frames (Mid-360 protocol, "Control Command"): discovery, parameter
//! configuration (work mode = start/stop sampling, host IP and ports, data type),
//! and their acknowledgements.
//!
//! Frame (little-endian): sof 0xAA | version 0 | length u16 (whole frame, <= 1400) |
//! seq_num u32 | cmd_id u16 | cmd_type u8 (0 REQ, 1 ACK) | sender_type u8 (0 host,
//! 1 LiDAR) | 6 reserved | crc16 u16 (CRC-16/CCITT-FALSE of bytes 0..18) |
//! crc32 u32 (of the data; 0 when there is none) | data.
//!
//! Ports: discovery broadcast to LiDAR port 56000; commands to 56100; the LiDAR
//! sends point data from 56300 and IMU from 56400 to the host ports configured here
//! (defaults 56301 / 56401).

use crate::crc::{crc16_ccitt_false, crc32};
use crate::error::ControlError;
use crate::packet::DataType;

pub const SOF: u8 = 0xAA;
pub const HEADER_LEN: usize = 24;
pub const MAX_FRAME_LEN: usize = 1400;

pub const PORT_DISCOVERY: u16 = 56000;
pub const PORT_COMMAND: u16 = 56100;
pub const PORT_POINT_DATA: u16 = 56300;
pub const PORT_IMU_DATA: u16 = 56400;
pub const HOST_PORT_COMMAND: u16 = 56101;
pub const HOST_PORT_POINT_DATA: u16 = 56301;
pub const HOST_PORT_IMU_DATA: u16 = 56401;

/// Command ids.
pub mod cmd {
    pub const DISCOVERY: u16 = 0x0000;
    pub const PARAM_CONFIG: u16 = 0x0100;
    pub const PARAM_QUERY: u16 = 0x0101;
    pub const INFO_PUSH: u16 = 0x0102;
    pub const REBOOT: u16 = 0x0200;
}

/// Keys of the key-value list of 0x0100 / 0x0101 / 0x0102.
pub mod key {
    pub const PCL_DATA_TYPE: u16 = 0x0000;
    pub const PATTERN_MODE: u16 = 0x0001;
    pub const LIDAR_IPCFG: u16 = 0x0004;
    pub const STATE_INFO_HOST_IPCFG: u16 = 0x0005;
    pub const POINTCLOUD_HOST_IPCFG: u16 = 0x0006;
    pub const IMU_HOST_IPCFG: u16 = 0x0007;
    pub const WORK_TGT_MODE: u16 = 0x001A;
    pub const IMU_DATA_EN: u16 = 0x001C;
    pub const SN: u16 = 0x8000;
    pub const CUR_WORK_STATE: u16 = 0x8006;
}

pub const CMD_TYPE_REQ: u8 = 0;
pub const CMD_TYPE_ACK: u8 = 1;
pub const SENDER_HOST: u8 = 0;
pub const SENDER_LIDAR: u8 = 1;

/// Target working states (key 0x001A).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WorkMode {
    Sampling = 0x01,
    Idle = 0x02,
}

/// One control frame.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct CommandFrame {
    pub seq_num: u32,
    pub cmd_id: u16,
    pub cmd_type: u8,
    pub sender_type: u8,
    pub data: Vec<u8>,
}

impl CommandFrame {
    pub fn request(seq_num: u32, cmd_id: u16, data: Vec<u8>) -> Self {
        Self { seq_num, cmd_id, cmd_type: CMD_TYPE_REQ, sender_type: SENDER_HOST, data }
    }

    /// The frame's bytes with both checksums.
    pub fn encode(&self) -> Result<Vec<u8>, ControlError> {
        let total = HEADER_LEN + self.data.len();
        if total > MAX_FRAME_LEN {
            return Err(ControlError::TooLong(total));
        }
        let mut buf = Vec::with_capacity(total);
        buf.push(SOF);
        buf.push(0); // version
        buf.extend_from_slice(&(total as u16).to_le_bytes());
        buf.extend_from_slice(&self.seq_num.to_le_bytes());
        buf.extend_from_slice(&self.cmd_id.to_le_bytes());
        buf.push(self.cmd_type);
        buf.push(self.sender_type);
        buf.extend_from_slice(&[0u8; 6]);
        let crc16 = crc16_ccitt_false(&buf[..18]);
        buf.extend_from_slice(&crc16.to_le_bytes());
        let crc32 = if self.data.is_empty() { 0 } else { crc32(&self.data) };
        buf.extend_from_slice(&crc32.to_le_bytes());
        buf.extend_from_slice(&self.data);
        Ok(buf)
    }

    /// Parses and checks a frame (sof, length, header CRC-16, data CRC-32).
    pub fn decode(buf: &[u8]) -> Result<Self, ControlError> {
        if buf.len() < HEADER_LEN {
            return Err(ControlError::Truncated { need: HEADER_LEN, got: buf.len() });
        }
        if buf[0] != SOF {
            return Err(ControlError::BadSof(buf[0]));
        }
        let length = usize::from(u16::from_le_bytes([buf[2], buf[3]]));
        if length > MAX_FRAME_LEN {
            return Err(ControlError::TooLong(length));
        }
        if length > buf.len() {
            return Err(ControlError::Truncated { need: length, got: buf.len() });
        }
        if length != buf.len() || length < HEADER_LEN {
            return Err(ControlError::LengthMismatch { header: length, frame: buf.len() });
        }
        let stored16 = u16::from_le_bytes([buf[18], buf[19]]);
        let computed16 = crc16_ccitt_false(&buf[..18]);
        if stored16 != computed16 {
            return Err(ControlError::Crc16Mismatch { stored: stored16, computed: computed16 });
        }
        let data = &buf[HEADER_LEN..];
        let stored32 = u32::from_le_bytes([buf[20], buf[21], buf[22], buf[23]]);
        let computed32 = if data.is_empty() { 0 } else { crc32(data) };
        if stored32 != computed32 {
            return Err(ControlError::Crc32Mismatch { stored: stored32, computed: computed32 });
        }
        Ok(Self {
            seq_num: u32::from_le_bytes([buf[4], buf[5], buf[6], buf[7]]),
            cmd_id: u16::from_le_bytes([buf[8], buf[9]]),
            cmd_type: buf[10],
            sender_type: buf[11],
            data: data.to_vec(),
        })
    }
}

/// Discovery (0x0000, data empty), broadcast to port 56000.
pub fn discovery_request(seq_num: u32) -> CommandFrame {
    CommandFrame::request(seq_num, cmd::DISCOVERY, Vec::new())
}

/// The data of a 0x0100 request: key_num, reserved, then key | length | value.
pub fn key_value_data(pairs: &[(u16, Vec<u8>)]) -> Vec<u8> {
    let mut data = Vec::new();
    data.extend_from_slice(&(pairs.len() as u16).to_le_bytes());
    data.extend_from_slice(&0u16.to_le_bytes());
    for (k, v) in pairs {
        data.extend_from_slice(&k.to_le_bytes());
        data.extend_from_slice(&(v.len() as u16).to_le_bytes());
        data.extend_from_slice(v);
    }
    data
}

/// Start (Sampling) or stop (Idle) the measurement: 0x0100 with key 0x001A.
pub fn work_mode_request(seq_num: u32, mode: WorkMode) -> CommandFrame {
    CommandFrame::request(
        seq_num,
        cmd::PARAM_CONFIG,
        key_value_data(&[(key::WORK_TGT_MODE, vec![mode as u8])]),
    )
}

fn ip_port_value(host_ip: [u8; 4], host_port: u16, lidar_port: u16) -> Vec<u8> {
    let mut v = host_ip.to_vec();
    v.extend_from_slice(&host_port.to_le_bytes());
    v.extend_from_slice(&lidar_port.to_le_bytes());
    v
}

/// Where the LiDAR sends point and IMU data: 0x0100 with keys 0x0006 and 0x0007
/// (destination IP, destination port, source port).
pub fn host_config_request(seq_num: u32, host_ip: [u8; 4], point_port: u16, imu_port: u16) -> CommandFrame {
    CommandFrame::request(
        seq_num,
        cmd::PARAM_CONFIG,
        key_value_data(&[
            (key::POINTCLOUD_HOST_IPCFG, ip_port_value(host_ip, point_port, PORT_POINT_DATA)),
            (key::IMU_HOST_IPCFG, ip_port_value(host_ip, imu_port, PORT_IMU_DATA)),
        ]),
    )
}

/// Point data format (key 0x0000): 1, 2 or 3.
pub fn data_type_request(seq_num: u32, data_type: DataType) -> CommandFrame {
    CommandFrame::request(
        seq_num,
        cmd::PARAM_CONFIG,
        key_value_data(&[(key::PCL_DATA_TYPE, vec![data_type.code()])]),
    )
}

fn need(field: &'static str, data: &[u8], n: usize) -> Result<(), ControlError> {
    if data.len() < n {
        return Err(ControlError::ShortData { field, need: n, got: data.len() });
    }
    Ok(())
}

fn expect_cmd(frame: &CommandFrame, expected: u16) -> Result<(), ControlError> {
    if frame.cmd_id != expected {
        return Err(ControlError::UnexpectedCommand { expected, got: frame.cmd_id });
    }
    Ok(())
}

/// The LiDAR's answer to discovery.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct DiscoveryAck {
    pub ret_code: u8,
    /// 9 = Mid-360.
    pub dev_type: u8,
    pub serial_number: String,
    pub lidar_ip: [u8; 4],
    pub cmd_port: u16,
}

impl DiscoveryAck {
    pub fn parse(frame: &CommandFrame) -> Result<Self, ControlError> {
        expect_cmd(frame, cmd::DISCOVERY)?;
        let d = &frame.data;
        need("discovery ack", d, 24)?;
        let sn_bytes = &d[2..18];
        let end = sn_bytes.iter().position(|&b| b == 0).unwrap_or(sn_bytes.len());
        Ok(Self {
            ret_code: d[0],
            dev_type: d[1],
            serial_number: String::from_utf8_lossy(&sn_bytes[..end]).into_owned(),
            lidar_ip: [d[18], d[19], d[20], d[21]],
            cmd_port: u16::from_le_bytes([d[22], d[23]]),
        })
    }

    /// The ack a LiDAR sends (for emitters and tests).
    pub fn to_frame(&self, seq_num: u32) -> CommandFrame {
        let mut d = vec![self.ret_code, self.dev_type];
        let mut sn = [0u8; 16];
        for (dst, src) in sn.iter_mut().zip(self.serial_number.bytes()) {
            *dst = src;
        }
        d.extend_from_slice(&sn);
        d.extend_from_slice(&self.lidar_ip);
        d.extend_from_slice(&self.cmd_port.to_le_bytes());
        CommandFrame {
            seq_num,
            cmd_id: cmd::DISCOVERY,
            cmd_type: CMD_TYPE_ACK,
            sender_type: SENDER_LIDAR,
            data: d,
        }
    }
}

/// The answer to a 0x0100 configuration: `ret_code` 0 = success, else `error_key`
/// names the key that failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ConfigAck {
    pub ret_code: u8,
    pub error_key: u16,
}

impl ConfigAck {
    pub fn parse(frame: &CommandFrame) -> Result<Self, ControlError> {
        expect_cmd(frame, cmd::PARAM_CONFIG)?;
        need("config ack", &frame.data, 3)?;
        let d = &frame.data;
        Ok(Self { ret_code: d[0], error_key: u16::from_le_bytes([d[1], d[2]]) })
    }
}

/// Splits a key-value list (the part after key_num/reserved, or after ret_code/key_num
/// of a query ack) into (key, value) pairs, checking every length.
pub fn parse_key_values(mut list: &[u8], count: usize) -> Result<Vec<(u16, Vec<u8>)>, ControlError> {
    let mut out = Vec::with_capacity(count.min(64));
    for _ in 0..count {
        need("key_value_list entry", list, 4)?;
        let k = u16::from_le_bytes([list[0], list[1]]);
        let len = usize::from(u16::from_le_bytes([list[2], list[3]]));
        need("key_value_list value", &list[4..], len)?;
        out.push((k, list[4..4 + len].to_vec()));
        list = &list[4 + len..];
    }
    Ok(out)
}

/// The key-values of an information push (0x0102) or a configuration request.
pub fn parse_info_push(frame: &CommandFrame) -> Result<Vec<(u16, Vec<u8>)>, ControlError> {
    let d = &frame.data;
    need("key_num", d, 4)?;
    let count = usize::from(u16::from_le_bytes([d[0], d[1]]));
    parse_key_values(&d[4..], count)
}
