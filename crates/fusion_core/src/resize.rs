//! `resize_linear`: bilinear resize of an interleaved 8-bit image, the same bytes on every CPU.
//!
//! The detector's letterbox used `cv2.resize(INTER_LINEAR)`, whose output depends on
//! the CPU: OpenCV's x86-64 wheels run the generic fixed-point path below, its
//! aarch64 wheels a different one (an ARM HAL), and the two differ by +-1 in about a
//! fifth of the values. This kernel is OpenCV's generic 8-bit INTER_LINEAR written
//! out in integers (the only floating-point steps are the tap positions, IEEE
//! binary32/64 operations without fused multiply-add, so they round the same on
//! every CPU):
//!
//! * taps: `f = f32((d + 0.5) * (1 / (dst / src)) - 0.5)` (the ratio in f64),
//!   `s = floor(f)`, `fx = f - s`; weights `round_even((1 - fx) * 2048)` and
//!   `round_even(fx * 2048)` (`INTER_RESIZE_COEF_BITS` = 11). Columns outside the
//!   image take the edge column with weights (2048, 0); rows are clamped to the
//!   image but keep their weights, as OpenCV does.
//! * horizontal pass: `h = p0 * a0 + p1 * a1` (i32);
//! * vertical pass: `(((b0 * (h0 >> 4)) >> 16) + ((b1 * (h1 >> 4)) >> 16) + 2) >> 2`,
//!   saturated to 255 -- OpenCV's `VResizeLinear<uchar, ..>` (its SIMD and scalar
//!   loops compute this same expression).
//!
//! Checked bit-for-bit against `cv2.resize(..., INTER_LINEAR)` of OpenCV's x86-64
//! wheels (`tests/test_detection_resize.py`), which is also what Ultralytics'
//! letterbox produced for the detector's reference fixture. An exact 2x reduction is
//! the same average as OpenCV's INTER_AREA shortcut for that case.

use crate::error::{invalid, Result};

/// Fixed-point scale of the interpolation weights (OpenCV's `INTER_RESIZE_COEF_SCALE`).
const COEF_SCALE: f32 = 2048.0;

/// The largest side accepted, input or output (OpenCV's own limit is `i32`).
pub const MAX_SIDE: usize = 1 << 20;

/// One output position: the two source indices and their fixed-point weights.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Tap {
    i0: usize,
    i1: usize,
    w0: i32,
    w1: i32,
}

/// Source position of each of `dst` outputs taken from `src` inputs.
/// `clamp_weights`: an out-of-range tap takes the edge with weights (2048, 0)
/// (OpenCV's columns); otherwise only the indices are clamped (its rows).
fn taps(src: usize, dst: usize, clamp_weights: bool) -> Vec<Tap> {
    let scale = 1.0 / (dst as f64 / src as f64);
    let last = src as i64 - 1;
    (0..dst)
        .map(|d| {
            let f = ((d as f64 + 0.5) * scale - 0.5) as f32;
            let s = f.floor();
            let mut frac = f - s;
            let mut s = s as i64;
            if clamp_weights {
                if s < 0 {
                    frac = 0.0;
                    s = 0;
                }
                if s >= last {
                    frac = 0.0;
                    s = last;
                }
            }
            let w0 = ((1.0f32 - frac) * COEF_SCALE).round_ties_even() as i32;
            let w1 = (frac * COEF_SCALE).round_ties_even() as i32;
            Tap {
                i0: s.clamp(0, last) as usize,
                i1: (s + 1).clamp(0, last) as usize,
                w0,
                w1,
            }
        })
        .collect()
}

/// Bilinear resize of an interleaved `height x width x channels` u8 image (row-major,
/// `src.len() == height * width * channels`) to `new_height x new_width`; returns the
/// `new_height * new_width * channels` bytes. Every side must be in 1..=[`MAX_SIDE`],
/// `channels` in 1..=4. An output too large to allocate is an error, never an abort.
pub fn resize_linear(
    src: &[u8],
    height: usize,
    width: usize,
    channels: usize,
    new_height: usize,
    new_width: usize,
) -> Result<Vec<u8>> {
    for (name, side) in [("height", height), ("width", width), ("new_height", new_height), ("new_width", new_width)] {
        if side == 0 || side > MAX_SIDE {
            return Err(invalid(name, format!("must be in 1..={MAX_SIDE}, got {side}")));
        }
    }
    if !(1..=4).contains(&channels) {
        return Err(invalid("channels", format!("must be 1, 2, 3 or 4, got {channels}")));
    }
    let expected = height.checked_mul(width).and_then(|n| n.checked_mul(channels));
    if expected != Some(src.len()) {
        return Err(invalid(
            "image",
            format!("{} bytes for {height} x {width} x {channels}", src.len()),
        ));
    }
    let total = new_height
        .checked_mul(new_width)
        .and_then(|n| n.checked_mul(channels))
        .ok_or_else(|| invalid("new_height", format!("{new_height} x {new_width} x {channels} overflows")))?;
    let mut out: Vec<u8> = Vec::new();
    out.try_reserve_exact(total)
        .map_err(|_| invalid("new_height", format!("{new_height} x {new_width} x {channels} bytes cannot be allocated")))?;
    let xs = taps(width, new_width, true);
    let ys = taps(height, new_height, false);
    let row_len = width * channels;
    for y in &ys {
        let r0 = &src[y.i0 * row_len..(y.i0 + 1) * row_len];
        let r1 = &src[y.i1 * row_len..(y.i1 + 1) * row_len];
        for x in &xs {
            let (c0, c1) = (x.i0 * channels, x.i1 * channels);
            for c in 0..channels {
                let h0 = i32::from(r0[c0 + c]) * x.w0 + i32::from(r0[c1 + c]) * x.w1;
                let h1 = i32::from(r1[c0 + c]) * x.w0 + i32::from(r1[c1 + c]) * x.w1;
                let v = (((y.w0 * (h0 >> 4)) >> 16) + ((y.w1 * (h1 >> 4)) >> 16) + 2) >> 2;
                out.push(v.clamp(0, 255) as u8);
            }
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn same_size_is_a_copy() {
        let src: Vec<u8> = (0..5 * 7 * 3).map(|i| (i * 37 % 256) as u8).collect();
        assert_eq!(resize_linear(&src, 5, 7, 3, 5, 7).unwrap(), src);
    }

    #[test]
    fn constant_image_stays_constant() {
        for value in [0u8, 1, 114, 254, 255] {
            let src = vec![value; 13 * 17 * 3];
            for (nh, nw) in [(1, 1), (5, 9), (26, 34), (320, 233), (7, 300)] {
                let out = resize_linear(&src, 13, 17, 3, nh, nw).unwrap();
                assert!(out.iter().all(|&v| v == value), "{value} -> {nh}x{nw}");
            }
        }
    }

    #[test]
    fn exact_halving_is_the_rounded_mean_of_each_2x2_block() {
        let src: Vec<u8> = (0..8 * 6).map(|i| (i * 53 % 256) as u8).collect();
        let out = resize_linear(&src, 8, 6, 1, 4, 3).unwrap();
        for y in 0..4 {
            for x in 0..3 {
                let p = |yy: usize, xx: usize| u32::from(src[yy * 6 + xx]);
                let sum = p(2 * y, 2 * x) + p(2 * y, 2 * x + 1) + p(2 * y + 1, 2 * x) + p(2 * y + 1, 2 * x + 1);
                assert_eq!(u32::from(out[y * 3 + x]), (sum + 2) >> 2, "({y}, {x})");
            }
        }
    }

    #[test]
    fn taps_match_opencv_worked_values() {
        // 412 -> 320: scale 1.2875; d = 0: f = 0.14375, d = 319: f = 410.21875.
        let t = taps(412, 320, true);
        assert_eq!((t[0].i0, t[0].i1), (0, 1));
        assert_eq!(t[0].w0 + t[0].w1, 2048);
        assert_eq!(t[0].w1, (0.14375f32 * 2048.0).round_ties_even() as i32);
        assert_eq!((t[319].i0, t[319].i1), (410, 411));
        // Upscaling 2 -> 4: the first column lies left of pixel 0 and takes it whole.
        let t = taps(2, 4, true);
        assert_eq!(t[0], Tap { i0: 0, i1: 1, w0: 2048, w1: 0 });
        assert_eq!(t[3], Tap { i0: 1, i1: 1, w0: 2048, w1: 0 });
        // Rows keep their weights when clamped.
        let t = taps(2, 4, false);
        assert_eq!((t[0].i0, t[0].i1, t[0].w0, t[0].w1), (0, 0, 512, 1536));
    }

    #[test]
    fn bad_arguments_are_errors_naming_them() {
        let src = vec![0u8; 12];
        let name = |r: Result<Vec<u8>>| match r {
            Err(crate::FusionError::InvalidArgument { name, .. }) => name,
            other => panic!("expected an argument error, got {other:?}"),
        };
        assert_eq!(name(resize_linear(&src, 0, 4, 3, 2, 2)), "height");
        assert_eq!(name(resize_linear(&src, 1, 4, 3, 0, 2)), "new_height");
        assert_eq!(name(resize_linear(&src, 1, 4, 3, 2, MAX_SIDE + 1)), "new_width");
        assert_eq!(name(resize_linear(&src, 1, 4, 5, 2, 2)), "channels");
        assert_eq!(name(resize_linear(&src, 2, 4, 3, 2, 2)), "image");
    }
}
