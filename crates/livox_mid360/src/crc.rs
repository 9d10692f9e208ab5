//! The two checksums of the Livox SDK2 protocol ("CRC Algorithm" table of the Mid-360
//! communication protocol):
//!
//! * CRC-16/CCITT-FALSE: poly 0x1021, init 0xFFFF, no reflection, no final xor
//!   (control-frame header);
//! * CRC-32 (IEEE 802.3, as zlib): poly 0x04C11DB7 reflected, init and final xor
//!   0xFFFFFFFF (control-frame data, point-cloud timestamp + data).
//!
//! Tables are built at compile time; no dependency.

const fn crc32_table() -> [u32; 256] {
    let mut table = [0u32; 256];
    let mut i = 0;
    while i < 256 {
        let mut c = i as u32;
        let mut k = 0;
        while k < 8 {
            c = if c & 1 != 0 { 0xEDB8_8320 ^ (c >> 1) } else { c >> 1 };
            k += 1;
        }
        table[i] = c;
        i += 1;
    }
    table
}

const fn crc16_table() -> [u16; 256] {
    let mut table = [0u16; 256];
    let mut i = 0;
    while i < 256 {
        let mut c = (i as u16) << 8;
        let mut k = 0;
        while k < 8 {
            c = if c & 0x8000 != 0 { (c << 1) ^ 0x1021 } else { c << 1 };
            k += 1;
        }
        table[i] = c;
        i += 1;
    }
    table
}

static CRC32_TABLE: [u32; 256] = crc32_table();
static CRC16_TABLE: [u16; 256] = crc16_table();

/// CRC-32 (IEEE, reflected) of `data`; equals Python's `zlib.crc32(data)`.
pub fn crc32(data: &[u8]) -> u32 {
    let mut c = 0xFFFF_FFFFu32;
    for &b in data {
        c = CRC32_TABLE[((c ^ u32::from(b)) & 0xFF) as usize] ^ (c >> 8);
    }
    c ^ 0xFFFF_FFFF
}

/// CRC-16/CCITT-FALSE of `data`; equals Python's `binascii.crc_hqx(data, 0xFFFF)`.
pub fn crc16_ccitt_false(data: &[u8]) -> u16 {
    let mut c = 0xFFFFu16;
    for &b in data {
        c = CRC16_TABLE[(((c >> 8) ^ u16::from(b)) & 0xFF) as usize] ^ (c << 8);
    }
    c
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The catalogue check values of both algorithms (input "123456789").
    #[test]
    fn check_values() {
        assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
        assert_eq!(crc16_ccitt_false(b"123456789"), 0x29B1);
        assert_eq!(crc32(b""), 0);
        assert_eq!(crc16_ccitt_false(b""), 0xFFFF);
    }
}
