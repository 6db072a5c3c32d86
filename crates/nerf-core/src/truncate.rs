//! `x as u32` for grid coordinates, without the saturating cast's range fix-ups.
//!
//! Rust's `f32 as u32` saturates (NaN to 0, the ends to the range), which the compiler emits
//! as compares and blends around every conversion: in the hash encoding's per-lane corner
//! loop they were a fifth of its time, and the occupancy grid's cell lookup spends them on
//! every sample it tests. [`truncate_u32`] takes NaN and the ends to the range first (two
//! min/max instructions), where the plain conversion is exact and gives the same values.

/// The largest f32 below 2^32.
const TOP: f32 = 4_294_967_040.0;

/// `x as u32` for every `x` in [0, 2^32) and for NaN (0): truncation toward zero. Negative
/// values give 0; values from 2^32 up give the largest f32 below 2^32, 4294967040, where the
/// saturating cast gives `u32::MAX`.
#[inline(always)]
// Not `clamp`: it keeps NaN, which the conversion must not see.
#[allow(clippy::manual_clamp)]
pub fn truncate_u32(x: f32) -> u32 {
    let x = x.max(0.0).min(TOP);
    // SAFETY: `max` returns 0 for NaN, so x is finite and in [0, TOP]: its truncation fits
    // in u32.
    unsafe { x.to_int_unchecked::<u32>() }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_the_saturating_cast_below_two_to_the_32() {
        let values = [
            0.0,
            -0.0,
            0.3,
            0.999_999_94,
            1.0,
            63.999_996,
            64.0,
            1023.5,
            16_777_215.0,
            TOP,
            -1.0,
            -1e30,
            f32::NAN,
            f32::NEG_INFINITY,
        ];
        for x in values {
            assert_eq!(truncate_u32(x), x as u32, "{x}");
        }
        assert_eq!(truncate_u32(f32::INFINITY), TOP as u32);
    }
}
