//! A branch-free `e^x` for float32 that the compiler can vectorise (libm's `expf` is a call
//! per value), for the SDF training kernel's inner loop.

/// `e^x` for `x` in [−87.3, 88.7] (clamped to that range outside it), within 2 float32 ulps
/// of the exact value: Cephes' `expf`, `x = n·ln 2 + r` with `|r| ≤ ln 2 / 2`, `e^r` by a
/// degree-7 polynomial, `2^n` built from its exponent bits.
#[inline(always)]
pub(crate) fn exp_fast(x: f32) -> f32 {
    const LOG2_E: f32 = std::f32::consts::LOG2_E;
    // 1.5·2^23: adding and subtracting it rounds to the nearest integer (|x·log2 e| < 2^22).
    const ROUND: f32 = 12_582_912.0;
    let x = x.clamp(-87.3, 88.7);
    let n = (x * LOG2_E + ROUND) - ROUND;
    // ln 2 split in two so that n·C1 is exact.
    let r = x - n * 0.693_359_4 + n * 2.121_944_4e-4;
    let p = ((((1.987_569_1e-4 * r + 1.398_2e-3) * r + 8.333_452e-3) * r + 4.166_579_6e-2) * r
        + 0.166_666_65)
        * r
        + 0.5;
    let y = p * r * r + r + 1.0;
    y * f32::from_bits(((n as i32 + 127) as u32) << 23)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_exp_within_two_ulps() {
        let mut worst = 0f64;
        for i in 0..200_000 {
            let x = -87.0 + 175.0 * i as f32 / 200_000.0;
            let exact = (x as f64).exp();
            let rel = ((exp_fast(x) as f64 - exact) / exact).abs();
            worst = worst.max(rel);
        }
        assert!(worst < 2.5e-7, "worst relative error {worst:e}");
        assert_eq!(exp_fast(0.0), 1.0);
        assert!(exp_fast(-1000.0) < 1e-37);
    }
}
