//! The hash encoding in float64, from its definitions, for the kernels' tests.

use crate::hash_level::HashGridParams;

/// The encoding of one point in f64, from the definitions (resolutions, hash, trilinear
/// weights), written independently of the kernels: `L·F` values; the point (in the box's
/// `[0, 1]³`) is clamped to it.
pub(crate) fn hash_encoding_f64(q: [f64; 3], table: &[f32], p: &HashGridParams) -> Vec<f64> {
    let t = 1u64 << p.log2_table_size;
    let b = ((p.max_resolution.ln() - p.base_resolution.ln()) / (p.n_levels as f64 - 1.0)).exp();
    let mut out = Vec::new();
    for l in 0..p.n_levels {
        let n = (p.base_resolution * b.powi(l as i32) + 1e-9).floor() as u64;
        let mut acc = vec![0f64; p.n_features];
        for k in 0..8u64 {
            let mut w = 1.0;
            let mut c = [0u64; 3];
            for a in 0..3 {
                let x = q[a].clamp(0.0, 1.0) * n as f64;
                let base = (x.floor() as u64).min(n - 1);
                let up = (k >> a) & 1;
                c[a] = base + up;
                w *= if up == 1 {
                    x - base as f64
                } else {
                    1.0 - (x - base as f64)
                };
            }
            let idx = if (n + 1).pow(3) <= t {
                c[0] + (n + 1) * c[1] + (n + 1) * (n + 1) * c[2]
            } else {
                ((c[0] ^ (c[1] * 2654435761) ^ (c[2] * 805459861)) & 0xffff_ffff) % t
            };
            let row = (l as u64 * t + idx) as usize * p.n_features;
            for (a, v) in acc.iter_mut().zip(&table[row..row + p.n_features]) {
                *a += w * *v as f64;
            }
        }
        out.extend(acc);
    }
    out
}
