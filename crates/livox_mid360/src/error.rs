//! What can be wrong with a datagram. Every variant names the field that is wrong.

use thiserror::Error;

/// A point-cloud / IMU datagram that cannot be used.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum PacketError {
    #[error("packet: truncated datagram, {got} bytes, need at least {need}")]
    Truncated { need: usize, got: usize },
    #[error("packet.length: header says {header} bytes, datagram holds {datagram}")]
    LengthMismatch { header: usize, datagram: usize },
    #[error("packet.version: unsupported protocol version {0} (expected 0)")]
    UnsupportedVersion(u8),
    #[error("packet.data_type: unknown data type {0:#04x}")]
    UnknownDataType(u8),
    #[error("packet.dot_num: {dot_num} samples of {sample_size} bytes do not fill {data_len} data bytes")]
    DotNumMismatch { dot_num: usize, sample_size: usize, data_len: usize },
    #[error("packet.crc32: stored {stored:#010x}, computed {computed:#010x} over timestamp + data")]
    Crc32Mismatch { stored: u32, computed: u32 },
    #[error("packet.data_type: {0} packets hold no points")]
    NotPoints(&'static str),
    #[error("packet.data_type: {0} packets hold no IMU samples")]
    NotImu(&'static str),
}

/// A control-command frame that cannot be used (or built).
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum ControlError {
    #[error("command: truncated frame, {got} bytes, need at least {need}")]
    Truncated { need: usize, got: usize },
    #[error("command.sof: expected 0xaa, got {0:#04x}")]
    BadSof(u8),
    #[error("command.length: header says {header} bytes, frame holds {frame}")]
    LengthMismatch { header: usize, frame: usize },
    #[error("command.length: {0} bytes exceeds the protocol's maximum of 1400")]
    TooLong(usize),
    #[error("command.crc16: stored {stored:#06x}, computed {computed:#06x} over the 18 header bytes")]
    Crc16Mismatch { stored: u16, computed: u16 },
    #[error("command.crc32: stored {stored:#010x}, computed {computed:#010x} over the data")]
    Crc32Mismatch { stored: u32, computed: u32 },
    #[error("command.cmd_id: expected {expected:#06x}, got {got:#06x}")]
    UnexpectedCommand { expected: u16, got: u16 },
    #[error("command.data: {field} needs {need} bytes, {got} left")]
    ShortData { field: &'static str, need: usize, got: usize },
}
