//! The homework's pixel grid: `x = −linspace(−1, 1, W)`, `y = −linspace(−1, 1, H)`,
//! row-major, so the first row is the top of the image (+Y up) and the first column its left
//! (+X left), in NDC.

use anyhow::Result;
use candle_core::{Device, Tensor};

/// `linspace(start, end, n)` computed in f64 (torch's values up to one f32 rounding).
pub fn linspace(start: f64, end: f64, n: usize) -> Vec<f64> {
    (0..n).map(|i| linspace_value(start, end, n, i)).collect()
}

/// Value `i` of [`linspace`]`(start, end, n)`, alone.
pub fn linspace_value(start: f64, end: f64, n: usize, i: usize) -> f64 {
    if n < 2 {
        return start;
    }
    let step = (end - start) / (n - 1) as f64;
    // Symmetric evaluation as torch does, so the last value is exactly `end`.
    if i < n / 2 {
        start + step * i as f64
    } else {
        end - step * (n - 1 - i) as f64
    }
}

/// The homework's NDC point of pixel `(column, row)` of a `width × height` image:
/// `(−linspace(−1, 1, W)[column], −linspace(−1, 1, H)[row])`, the first row the top.
pub fn homework_ndc(column: usize, row: usize, (width, height): (usize, usize)) -> [f64; 2] {
    [
        -linspace_value(-1.0, 1.0, width, column),
        -linspace_value(-1.0, 1.0, height, row),
    ]
}

/// NDC coordinates of every pixel of a `width × height` image, row-major, as `(x, y)` pairs.
pub fn pixel_grid_values(width: usize, height: usize) -> Vec<[f64; 2]> {
    let xs = linspace(-1.0, 1.0, width);
    let ys = linspace(-1.0, 1.0, height);
    let mut grid = Vec::with_capacity(width * height);
    for y in &ys {
        for x in &xs {
            grid.push([-x, -y]);
        }
    }
    grid
}

/// The pixel grid as a tensor.
///
/// Returns `(W·H, 2)` f32: NDC `(x, y)` of each pixel, row-major from the top-left pixel.
pub fn pixel_grid(width: usize, height: usize, device: &Device) -> Result<Tensor> {
    let flat: Vec<f32> = pixel_grid_values(width, height)
        .into_iter()
        .flat_map(|[x, y]| [x as f32, y as f32])
        .collect();
    Ok(Tensor::from_vec(flat, (width * height, 2), device)?)
}
