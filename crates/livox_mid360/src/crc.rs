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

/// Slicing-by-8 tables: `T[k][b]` is the CRC of byte `b` followed by `k` zero bytes, so
/// eight bytes are folded per step (about 4x the byte-wise loop).
const fn crc32_slice_tables() -> [[u32; 256]; 8] {
    let base = crc32_table();
    let mut t = [[0u32; 256]; 8];
    t[0] = base;
    let mut k = 1;
    while k < 8 {
        let mut i = 0;
        while i < 256 {
            let prev = t[k - 1][i];
            t[k][i] = (prev >> 8) ^ base[(prev & 0xFF) as usize];
            i += 1;
        }
        k += 1;
    }
    t
}

static CRC32_TABLES: [[u32; 256]; 8] = crc32_slice_tables();
static CRC16_TABLE: [u16; 256] = crc16_table();

/// CRC-32 (IEEE, reflected) of `data`; equals Python's `zlib.crc32(data)`.
pub fn crc32(data: &[u8]) -> u32 {
    let t = &CRC32_TABLES;
    let mut c = 0xFFFF_FFFFu32;
    let mut chunks = data.chunks_exact(8);
    for w in &mut chunks {
        let lo = c ^ u32::from_le_bytes([w[0], w[1], w[2], w[3]]);
        c = t[7][(lo & 0xFF) as usize]
            ^ t[6][((lo >> 8) & 0xFF) as usize]
            ^ t[5][((lo >> 16) & 0xFF) as usize]
            ^ t[4][(lo >> 24) as usize]
            ^ t[3][w[4] as usize]
            ^ t[2][w[5] as usize]
            ^ t[1][w[6] as usize]
            ^ t[0][w[7] as usize];
    }
    for &b in chunks.remainder() {
        c = t[0][((c ^ u32::from(b)) & 0xFF) as usize] ^ (c >> 8);
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

    /// The sliced CRC equals the plain byte-wise definition at every length and alignment.
    #[test]
    fn sliced_equals_bytewise() {
        let table = crc32_table();
        let bytewise = |d: &[u8]| {
            let mut c = 0xFFFF_FFFFu32;
            for &b in d {
                c = table[((c ^ u32::from(b)) & 0xFF) as usize] ^ (c >> 8);
            }
            c ^ 0xFFFF_FFFF
        };
        let data: Vec<u8> = (0..300u32).map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8).collect();
        for start in 0..9 {
            for end in start..data.len() {
                assert_eq!(crc32(&data[start..end]), bytewise(&data[start..end]));
            }
        }
    }
}
