//! The shape of a multiresolution hash encoding ([`crate::hash_grid`]) and of each of
//! its levels: resolutions, dense or hashed tables, and a point's 8 corners (rows and trilinear
//! weights) on one level. Both the encoding's loops ([`crate::hash_block`]) and its
//! point gradient ([`crate::hash_point_gradient`]) read them, so they live below all
//! three.

/// The multiplier of each axis in the spatial hash (instant-ngp's primes; x's is 1).
pub const HASH_PRIMES: [u32; 3] = [1, 2_654_435_761, 805_459_861];

/// The shape of a hash encoding: levels, features per level, table size and resolutions.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HashGridParams {
    /// Number of levels `L`.
    pub n_levels: usize,
    /// Features per level `F`.
    pub n_features: usize,
    /// `log2` of the rows per level's table `T`.
    pub log2_table_size: u32,
    /// Coarsest resolution `N_min`.
    pub base_resolution: f64,
    /// Finest resolution `N_max`.
    pub max_resolution: f64,
}

impl HashGridParams {
    /// Checks the shape: at least one level and feature, `log2_T` in 4..=24 and
    /// `1 ≤ N_min ≤ N_max` (one-line errors).
    pub fn validate(&self) -> anyhow::Result<()> {
        anyhow::ensure!(self.n_levels >= 1, "hash grid: n_levels must be at least 1");
        anyhow::ensure!(
            self.n_features >= 1,
            "hash grid: n_features_per_level must be at least 1"
        );
        anyhow::ensure!(
            (4..=24).contains(&self.log2_table_size),
            "hash grid: log2_hashmap_size must be in 4..=24, got {}",
            self.log2_table_size
        );
        anyhow::ensure!(
            self.base_resolution >= 1.0 && self.max_resolution >= self.base_resolution,
            "hash grid: need 1 <= base_resolution <= max_resolution, got {} and {}",
            self.base_resolution,
            self.max_resolution
        );
        Ok(())
    }

    /// Rows per level's table, `T`.
    pub(crate) fn table_size(&self) -> usize {
        1 << self.log2_table_size
    }

    /// Rows of the whole parameter tensor, `L·T`.
    pub fn n_rows(&self) -> usize {
        self.n_levels * self.table_size()
    }

    /// Output width, `L·F`.
    pub fn output_dim(&self) -> usize {
        self.n_levels * self.n_features
    }

    /// The growth factor `b` between levels (1 with one level).
    pub(crate) fn growth(&self) -> f64 {
        if self.n_levels < 2 {
            1.0
        } else {
            ((self.max_resolution.ln() - self.base_resolution.ln()) / (self.n_levels - 1) as f64)
                .exp()
        }
    }

    /// Each level's resolution `N_l = ⌊N_min · b^l⌋` and whether its table is dense.
    pub(crate) fn levels(&self) -> Vec<Level> {
        let b = self.growth();
        (0..self.n_levels)
            .map(|l| {
                // A hair above the product, so that b^l·N_min landing a rounding error under
                // an integer (N_max itself on the last level) still floors to it.
                let res = ((self.base_resolution * b.powi(l as i32)) * (1.0 + 1e-12)).floor();
                let res = res.max(1.0) as u32;
                let corners = (res as u64 + 1).pow(3);
                Level {
                    resolution: res,
                    dense: corners <= self.table_size() as u64,
                    table_mask: self.table_size() as u32 - 1,
                }
            })
            .collect()
    }
}

/// One level of the grid: its resolution and how its table is indexed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Level {
    /// Cells per axis `N_l` (corners `0..=N_l`).
    pub resolution: u32,
    /// Whether every corner has its own row (`(N_l+1)³ ≤ T`) rather than a hashed one.
    pub dense: bool,
    /// `T − 1`.
    pub table_mask: u32,
}

impl Level {
    #[cfg(test)]
    /// The row (within this level's table) of the integer corner `c`.
    pub(crate) fn index(&self, c: [u32; 3]) -> u32 {
        if self.dense {
            let n = self.resolution + 1;
            c[0] + n * (c[1] + n * c[2])
        } else {
            (c[0].wrapping_mul(HASH_PRIMES[0])
                ^ c[1].wrapping_mul(HASH_PRIMES[1])
                ^ c[2].wrapping_mul(HASH_PRIMES[2]))
                & self.table_mask
        }
    }

    /// On one axis, the cell holding the coordinate `v` (in [0, 1]; clamped there): the
    /// lower corner's integer coordinate `c` and the fraction `v·N − c` of the way to the
    /// upper one.
    #[inline(always)]
    pub(crate) fn cell(&self, v: f32) -> (u32, f32) {
        let n = self.resolution;
        let x = v.clamp(0.0, 1.0) * n as f32;
        // x ≥ 0 (NaN clamps to NaN and casts to 0), so truncation is the floor, without
        // a call to libm's floorf (not inlined on a baseline x86-64 build).
        let c = (x as u32).min(n - 1);
        (c, x - c as f32)
    }

    /// `∂ fraction / ∂ v` of [`Level::cell`]: the resolution `N` where `v` is in [0, 1], 0
    /// where it is clamped (or NaN).
    #[inline(always)]
    pub(crate) fn cell_slope(&self, v: f32) -> f32 {
        match (0.0..=1.0).contains(&v) {
            true => self.resolution as f32,
            false => 0.0,
        }
    }

    /// The 8 corners of the cell holding `p` as [`Level::corners`] gives them (row, weight),
    /// with each weight's gradient with respect to `p`: on axis `a`,
    /// `±[Level::cell_slope]·Π_{b≠a} w_b` (+ for the corner on the cell's upper side).
    pub(crate) fn corner_gradients(&self, p: [f32; 3]) -> [(u32, f32, [f32; 3]); 8] {
        let cells = p.map(|v| self.cell(v));
        let slope = p.map(|v| self.cell_slope(v));
        let w = cells.map(|(_, frac)| [1.0 - frac, frac]);
        let corners = self.corners(p);
        std::array::from_fn(|k| {
            let bit = [k & 1, k >> 1 & 1, k >> 2 & 1];
            let sign = bit.map(|b| if b == 1 { 1.0f32 } else { -1.0 });
            let (row, weight) = corners[k];
            let grad = [
                sign[0] * slope[0] * w[1][bit[1]] * w[2][bit[2]],
                sign[1] * slope[1] * w[0][bit[0]] * w[2][bit[2]],
                sign[2] * slope[2] * w[0][bit[0]] * w[1][bit[1]],
            ];
            (row, weight, grad)
        })
    }

    /// The 8 corners of the cell holding `p` (in [0, 1]³; clamped there): each corner's row in
    /// this level's table and its trilinear weight (corner `k` takes bit `a` of `k` on axis `a`).
    pub(crate) fn corners(&self, p: [f32; 3]) -> [(u32, f32); 8] {
        let n = self.resolution;
        // Per axis: the cell's two corner coordinates' terms of the row index, and their
        // weights. Corner `k` sums (dense) or XORs (hashed) one term per axis.
        let mut terms = [[0u32; 2]; 3];
        let mut weights = [[0f32; 2]; 3];
        let stride = [1, n + 1, (n + 1) * (n + 1)];
        for a in 0..3 {
            let (c, frac) = self.cell(p[a]);
            weights[a] = [1.0 - frac, frac];
            terms[a] = if self.dense {
                [c * stride[a], (c + 1) * stride[a]]
            } else {
                [
                    c.wrapping_mul(HASH_PRIMES[a]),
                    (c + 1).wrapping_mul(HASH_PRIMES[a]),
                ]
            };
        }
        let mut out = [(0u32, 0f32); 8];
        for (k, o) in out.iter_mut().enumerate() {
            let (x, y, z) = (k & 1, k >> 1 & 1, k >> 2 & 1);
            let row = if self.dense {
                terms[0][x] + terms[1][y] + terms[2][z]
            } else {
                (terms[0][x] ^ terms[1][y] ^ terms[2][z]) & self.table_mask
            };
            // Multiplied x, then y, then z, as before this form: renders stay bit-identical.
            *o = (row, weights[0][x] * weights[1][y] * weights[2][z]);
        }
        out
    }
}
