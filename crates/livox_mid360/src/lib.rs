//! Livox Mid-360 over the Livox SDK2 communication protocol, in pure Rust.
//!
//! * [`packet`]: point-cloud (types 1, 2, 3) and IMU (type 0) datagrams: header,
//!   CRC-32, per-point times (`timestamp + i * time_interval * 100 / dot_num` ns);
//! * [`assembler`]: datagrams -> 10 Hz scans, counting duplicates, reordered, lost,
//!   late and malformed packets;
//! * [`control`]: command frames (CRC-16 header, CRC-32 data): discovery, work mode
//!   (start/stop sampling), host IP and ports, data type; their acks;
//! * [`crc`]: CRC-16/CCITT-FALSE and CRC-32;
//! * [`receiver`]: reader threads that stamp each datagram on arrival and assemble the scans,
//!   off the caller's lock (the GIL, for the Python driver).
//!
//! Reference: "Livox LiDAR Communication Protocol -- Mid360" (Livox wiki, v1.4.11) and
//! `livox_lidar_def.h` of Livox-SDK2. Nothing here panics on any input bytes.

pub mod assembler;
pub mod control;
pub mod crc;
pub mod error;
pub mod packet;
pub mod receiver;

pub use assembler::{Accepted, AssemblerConfig, Scan, ScanAssembler, Stats};
pub use error::{ControlError, PacketError};
pub use receiver::{LivoxReceiver, PacketStamp, ReceiverConfig, ReceiverStats, Taken};
pub use packet::{
    decode_imu, decode_points, encode_packet, parse_packet, DataType, ImuSample, Packet, PacketHeader, PacketMeta,
    PointColumns,
};
