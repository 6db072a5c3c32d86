//! Choosing the frames of a video to reconstruct from: a sharpness score per candidate frame
//! (the variance of the Laplacian of a grey thumbnail: motion blur and defocus flatten edges,
//! which lowers it) and, of candidates spread evenly over the clip, the sharpest of each
//! stretch, so that the kept frames stay spread over the clip while a blurred frame gives way
//! to a sharp neighbour.

/// The variance over the interior pixels of the 4-neighbour Laplacian
/// `f(x−1,y) + f(x+1,y) + f(x,y−1) + f(x,y+1) − 4·f(x,y)` of a grey image.
///
/// `grey`: `(height, width)` row-major intensities (any scale; the score scales with its
/// square). Returns 0 for an image under 3×3 pixels or when `grey` is shorter than
/// `width·height`.
pub(crate) fn laplacian_variance(grey: &[f32], width: usize, height: usize) -> f64 {
    if width < 3 || height < 3 || grey.len() < width * height {
        return 0.0;
    }
    let at = |x: usize, y: usize| f64::from(grey[y * width + x]);
    let (mut sum, mut sum_sq) = (0.0, 0.0);
    for y in 1..height - 1 {
        for x in 1..width - 1 {
            let l = at(x - 1, y) + at(x + 1, y) + at(x, y - 1) + at(x, y + 1) - 4.0 * at(x, y);
            sum += l;
            sum_sq += l * l;
        }
    }
    let n = ((width - 2) * (height - 2)) as f64;
    let mean = sum / n;
    (sum_sq / n - mean * mean).max(0.0)
}

/// The index of the highest score in each of `keep` contiguous stretches of `scores` (stretch
/// `k` is `k·n/keep .. (k+1)·n/keep`, so stretches differ in length by at most one), in
/// order; every index when `keep ≥ n`. The first of equal scores wins; a NaN score never does
/// unless its stretch holds nothing else.
///
/// `scores`: `(n,)`; returns `(min(keep, n),)` increasing indices.
pub(crate) fn sharpest_per_stretch(scores: &[f64], keep: usize) -> Vec<usize> {
    let n = scores.len();
    if keep >= n {
        return (0..n).collect();
    }
    (0..keep)
        .map(|k| {
            let (start, end) = (k * n / keep, (k + 1) * n / keep);
            (start..end).fold(start, |best, i| {
                if scores[i] > scores[best] || scores[best].is_nan() && !scores[i].is_nan() {
                    i
                } else {
                    best
                }
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A `width`×`height` pattern of random-looking values in 0..1 (a hash of the position).
    fn texture(width: usize, height: usize) -> Vec<f32> {
        (0..width * height)
            .map(|i| {
                let h = (i as u32).wrapping_mul(2_654_435_761).rotate_left(13) ^ 0x5bd1_e995;
                (h % 1000) as f32 / 1000.0
            })
            .collect()
    }

    /// `grey` averaged over a `(2r+1)²` box (clamped at the borders): a defocus blur.
    fn box_blur(grey: &[f32], width: usize, height: usize, r: usize) -> Vec<f32> {
        let mut out = vec![0.0; grey.len()];
        for y in 0..height {
            for x in 0..width {
                let (mut sum, mut count) = (0.0, 0.0);
                for yy in y.saturating_sub(r)..(y + r + 1).min(height) {
                    for xx in x.saturating_sub(r)..(x + r + 1).min(width) {
                        sum += grey[yy * width + xx];
                        count += 1.0;
                    }
                }
                out[y * width + x] = sum / count;
            }
        }
        out
    }

    #[test]
    fn a_single_bright_pixel_has_the_hand_computed_variance() {
        // 5×5 zeros with 1 at the centre: the 9 interior Laplacians are −4 once, 1 four times
        // and 0 four times; mean 0, so the variance is (16 + 4)/9.
        let mut grey = vec![0.0f32; 25];
        grey[12] = 1.0;
        assert!((laplacian_variance(&grey, 5, 5) - 20.0 / 9.0).abs() < 1e-12);
        // A quadratic ramp has a constant Laplacian (2): no variance. A plane has none either.
        let ramp: Vec<f32> = (0..36).map(|i| ((i % 6) * (i % 6)) as f32).collect();
        assert!(laplacian_variance(&ramp, 6, 6).abs() < 1e-9);
        let plane: Vec<f32> = (0..36).map(|i| (i % 6 + 2 * (i / 6)) as f32).collect();
        assert!(laplacian_variance(&plane, 6, 6).abs() < 1e-9);
        // Too small or too short: 0.
        assert_eq!(laplacian_variance(&grey, 2, 12), 0.0);
        assert_eq!(laplacian_variance(&grey[..20], 5, 5), 0.0);
    }

    #[test]
    fn blur_lowers_the_score_and_more_blur_lowers_it_more() {
        let (w, h) = (32, 24);
        let sharp = texture(w, h);
        let scores: Vec<f64> = [0, 1, 2]
            .iter()
            .map(|&r| {
                let image = if r == 0 {
                    sharp.clone()
                } else {
                    box_blur(&sharp, w, h, r)
                };
                laplacian_variance(&image, w, h)
            })
            .collect();
        assert!(scores[0] > 5.0 * scores[1], "{scores:?}");
        assert!(scores[1] > scores[2], "{scores:?}");
        // Brightness scaled by 2: the score by 4.
        let doubled: Vec<f32> = sharp.iter().map(|v| 2.0 * v).collect();
        let ratio = laplacian_variance(&doubled, w, h) / scores[0];
        assert!((ratio - 4.0).abs() < 1e-9, "{ratio}");
    }

    #[test]
    fn the_sharpest_of_each_stretch_is_kept() {
        // 10 candidates in 3 stretches: 0..3, 3..6, 6..10.
        let scores = [1.0, 5.0, 2.0, 9.0, 9.0, 0.5, 3.0, f64::NAN, 4.0, 1.0];
        assert_eq!(sharpest_per_stretch(&scores, 3), vec![1, 3, 8]);
        assert_eq!(
            sharpest_per_stretch(&scores, 10),
            (0..10).collect::<Vec<_>>()
        );
        assert_eq!(sharpest_per_stretch(&scores, 20).len(), 10);
        assert_eq!(sharpest_per_stretch(&[f64::NAN, 2.0], 1), vec![1]);
        assert!(sharpest_per_stretch(&[], 4).is_empty());
        // Every stretch is non-empty and they tile the candidates: 7 of 100.
        let many: Vec<f64> = (0..100).map(|i| ((i * 37) % 11) as f64).collect();
        let kept = sharpest_per_stretch(&many, 7);
        assert_eq!(kept.len(), 7);
        for (k, &i) in kept.iter().enumerate() {
            assert!((k * 100 / 7..(k + 1) * 100 / 7).contains(&i), "{kept:?}");
        }
    }
}
