//! Elementwise `exp` and `tanh` for the host training paths, written so the compiler can
//! vectorise them (no calls into libm per element): `exp(x)` as `2^k e^f` with
//! `f = x - k ln2`, `|f| <= ln2 / 2`, and a degree-6 Taylor polynomial for `e^f` (relative
//! error about 2e-7); `tanh` from that
//! `exp` (absolute error about 3e-7). Both saturate cleanly outside their ranges.
//!
//! Reductions (`max`, `exp_shifted`'s sum, `dot_shifted`) keep [`LANES`] partial results
//! so that a sum over a wide row is not one serial chain of additions: the compiler cannot
//! reorder float additions itself, so a plain `fold` runs one element per cycle.

const LOG2_E: f32 = std::f32::consts::LOG2_E;
/// ln 2 = LN2_HI + LN2_LO, the first with few enough mantissa bits that `k * LN2_HI` is exact.
const LN2_HI: f32 = 0.693_359_4;
const LN2_LO: f32 = -2.121_944_4e-4;
/// 1.5 * 2^23: adding it rounds an f32 of magnitude < 2^22 to an integer, kept in the low
/// mantissa bits.
const ROUNDER: f32 = 12_582_912.0;

/// `e^x` for `x` in `[-87, 87]`; outside it, the value at the nearer end.
#[inline(always)]
pub fn exp(x: f32) -> f32 {
    let x = x.clamp(-87.0, 87.0);
    let shifted = x * LOG2_E + ROUNDER;
    let k = shifted - ROUNDER; // x / ln2 rounded to the nearest integer
    // f = x - k ln2, |f| <= ln2 / 2, with ln2 in two parts so that k * LN2_HI is exact
    let f = (x - k * LN2_HI) - k * LN2_LO;
    // e^f by its Taylor series to degree 6 (Horner)
    let p = 1.0
        + f * (1.0
            + f * (0.5
                + f * (1.0 / 6.0 + f * (1.0 / 24.0 + f * (1.0 / 120.0 + f * (1.0 / 720.0))))));
    let k_int = shifted.to_bits().wrapping_sub(ROUNDER.to_bits()) as i32;
    let scale = f32::from_bits(((k_int + 127) as u32) << 23);
    p * scale
}

/// `tanh(x)`, as `1 - 2 / (e^{2x} + 1)` (exactly +-1 for `|x| >= 10`).
#[inline(always)]
pub fn tanh(x: f32) -> f32 {
    let e = exp(2.0 * x.clamp(-10.0, 10.0));
    1.0 - 2.0 / (e + 1.0)
}

/// Partial results a reduction keeps (an AVX2 register of f32; 16, an AVX-512 register,
/// measured no faster on the update here).
const LANES: usize = 8;

/// The largest of `xs` (`-inf` when empty; NaNs are passed over as `f32::max` does).
#[inline(always)]
pub fn max(xs: &[f32]) -> f32 {
    let mut acc = [f32::NEG_INFINITY; LANES];
    let chunks = xs.chunks_exact(LANES);
    let tail = chunks.remainder();
    for c in chunks {
        for (a, &v) in acc.iter_mut().zip(c) {
            *a = a.max(v);
        }
    }
    let m = tail.iter().fold(f32::NEG_INFINITY, |m, &v| m.max(v));
    acc.iter().fold(m, |m, &v| m.max(v))
}

/// `out[k] = e^(x[k] - shift)`; returns their sum.
#[inline(always)]
pub fn exp_shifted(out: &mut [f32], x: &[f32], shift: f32) -> f32 {
    // two simple loops vectorise where one mixing them does not
    for (o, &v) in out.iter_mut().zip(x) {
        *o = exp(v - shift);
    }
    sum(out)
}

/// The sum of `xs`.
#[inline(always)]
pub fn sum(xs: &[f32]) -> f32 {
    let mut acc = [0.0f32; LANES];
    let chunks = xs.chunks_exact(LANES);
    let tail: f32 = chunks.remainder().iter().sum();
    for c in chunks {
        for (a, &v) in acc.iter_mut().zip(c) {
            *a += v;
        }
    }
    acc.iter().sum::<f32>() + tail
}

/// `sum_k a[k] (b[k] - shift)`.
#[inline(always)]
pub fn dot_shifted(a: &[f32], b: &[f32], shift: f32) -> f32 {
    let mut acc = [0.0f32; LANES];
    let ac = a.chunks_exact(LANES);
    let bc = b.chunks_exact(LANES);
    let tail: f32 = ac
        .remainder()
        .iter()
        .zip(bc.remainder())
        .map(|(&p, &q)| p * (q - shift))
        .sum();
    for (p, q) in ac.zip(bc) {
        for ((s, &p), &q) in acc.iter_mut().zip(p).zip(q) {
            *s += p * (q - shift);
        }
    }
    acc.iter().sum::<f32>() + tail
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exp_and_tanh_match_the_standard_library() {
        let mut worst_exp = 0.0f32;
        let mut worst_tanh = 0.0f32;
        let mut x = -30.0f32;
        while x < 30.0 {
            worst_exp = worst_exp.max((exp(x) - x.exp()).abs() / x.exp());
            worst_tanh = worst_tanh.max((tanh(x) - x.tanh()).abs());
            x += 0.001_37;
        }
        assert!(worst_exp < 5e-7, "exp relative error {worst_exp}");
        assert!(worst_tanh < 5e-7, "tanh absolute error {worst_tanh}");
        assert_eq!(tanh(0.0), 0.0);
        assert_eq!(tanh(40.0), 1.0);
        assert_eq!(tanh(-40.0), -1.0);
        assert!(exp(-200.0) < 1e-37);
        assert!(exp(200.0).is_finite());
    }

    #[test]
    fn lane_reductions_equal_plain_ones() {
        for n in [0, 3, 8, 13, 512] {
            let x: Vec<f32> = (0..n).map(|i| ((i * 37) % 19) as f32 * 0.3 - 2.0).collect();
            assert_eq!(max(&x), x.iter().fold(f32::NEG_INFINITY, |m, &v| m.max(v)));
            let mut e = vec![0.0; n];
            let sum = exp_shifted(&mut e, &x, 1.5);
            let plain: f32 = x.iter().map(|v| (v - 1.5).exp()).sum();
            assert!(
                (sum - plain).abs() <= 1e-5 * plain.max(1.0),
                "{n}: {sum} {plain}"
            );
            assert!(
                e.iter()
                    .zip(&x)
                    .all(|(e, v)| (e - (v - 1.5).exp()).abs() < 1e-5)
            );
            let dot = dot_shifted(&e, &x, 0.5);
            let plain: f32 = e.iter().zip(&x).map(|(p, q)| p * (q - 0.5)).sum();
            assert!(
                (dot - plain).abs() <= 1e-4 * plain.abs().max(1.0),
                "{n}: {dot} {plain}"
            );
        }
    }
}
