//! Range checks that name the key of a bad value: what every config section's validation
//! (and every field kind's, `nerf::field::registry`) shares.

use anyhow::{bail, Result};

/// An error naming `key` when `v` is not a finite number.
pub fn finite(key: &str, v: f64) -> Result<()> {
    if !v.is_finite() {
        bail!("{key}: must be a finite number (got {v})");
    }
    Ok(())
}

/// An error naming `key` when `v` is not in `1..=max`.
pub fn count_in_range(key: &str, v: usize, max: usize) -> Result<()> {
    if v == 0 || v > max {
        bail!("{key}: must be 1 to {max} (got {v})");
    }
    Ok(())
}
