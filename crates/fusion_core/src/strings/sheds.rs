//! The shed signature: how strongly the points of a segment bunch at a regular pitch along its
//! axis.
//!
//! WHY this is the test that names an insulator: a string is a stack of sheds (discs or
//! skirts) at a fixed pitch, 40-170 mm on composite and cap-and-pin strings alike, and a LiDAR
//! that sees the stack returns more points where a shed stands than between two. A lattice
//! angle, a chord, a conductor or a jumper is uniform along its length; a junction is one bump,
//! not a comb. Thickness and length alone cannot tell a 2 m panel of a tower leg (as thick as a
//! shed stack, as straight) from a string; the comb can.

use std::f64::consts::TAU;

/// m: histogram bin along the axis (a quarter of the shortest pitch looked for).
const BIN: f64 = 0.01;
/// m: the pitches looked for (composite 40-100 mm, cap-and-pin discs 146-170 mm, with room).
pub(super) const MIN_PITCH: f64 = 0.05;
pub(super) const MAX_PITCH: f64 = 0.25;

/// Shed contrast of the axial positions `t` (m) over `t0..t1`: the largest power of the
/// histogram's spectrum at a pitch in MIN_PITCH..=MAX_PITCH, over the mean power of the whole
/// spectrum (about 1 for a uniform segment, tens for a shed stack). 0 for fewer than two bins.
pub(super) fn shed_contrast(t: &[f64], t0: f64, t1: f64) -> f64 {
    let n = ((t1 - t0) / BIN).floor();
    // NaN (a non-finite extent) is refused with the short ones.
    if n.is_nan() || n < 2.0 {
        return 0.0;
    }
    let n = n as usize;
    let mut hist = vec![0.0f64; n];
    for &x in t {
        let k = ((x - t0) / BIN).floor();
        if k >= 0.0 && (k as usize) < n {
            hist[k as usize] += 1.0;
        }
    }
    let mean = hist.iter().sum::<f64>() / n as f64;
    hist.iter_mut().for_each(|h| *h -= mean);
    // Parseval: the one-sided spectrum's mean power (frequencies 1..n/2) is sum(h^2).
    let mean_power: f64 = hist.iter().map(|h| h * h).sum();
    if mean_power <= 0.0 {
        return 0.0;
    }
    // Frequency k is k / (n BIN) cycles per metre: the pitch band is k in n BIN / pitch.
    let length = n as f64 * BIN;
    let k_lo = (length / MAX_PITCH).ceil().max(1.0) as usize;
    let k_hi = ((length / MIN_PITCH).floor() as usize).min(n / 2);
    let mut best = 0.0f64;
    for k in k_lo..=k_hi {
        let w = TAU * k as f64 / n as f64;
        let (mut re, mut im) = (0.0, 0.0);
        for (i, h) in hist.iter().enumerate() {
            let (s, c) = (w * i as f64).sin_cos();
            re += h * c;
            im -= h * s;
        }
        best = best.max(re * re + im * im);
    }
    best / mean_power
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_comb_at_a_shed_pitch_stands_out_and_a_uniform_line_does_not() {
        // 2 m, points every 2 mm, doubled within 15 mm of every 80 mm pitch.
        let mut comb = Vec::new();
        let mut uniform = Vec::new();
        for i in 0..1000 {
            let x = f64::from(i) * 0.002;
            uniform.push(x);
            comb.push(x);
            if x % 0.08 < 0.015 {
                comb.push(x);
                comb.push(x);
            }
        }
        let c = shed_contrast(&comb, 0.0, 2.0);
        let u = shed_contrast(&uniform, 0.0, 2.0);
        assert!(c > 20.0, "comb {c}");
        assert!(u < 5.0, "uniform {u}");
        assert_eq!(shed_contrast(&[0.1], 0.0, 0.015), 0.0);
    }
}
