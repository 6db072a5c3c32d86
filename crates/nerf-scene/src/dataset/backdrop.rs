//! Whether a capture's photos were taken on a plain white backdrop, judged by their borders.
//! An unbounded model trained on such photos composited on black must explain the white by
//! density, and grows a white veil that held-out cameras facing it see as a wall, so those
//! views score poorly; told the backdrop is white (`renderer.white_background=True`), empty
//! space renders white and every held-out view scores well (measured:
//! docs/own-scene.md#white-backdrops). `nerf process` uses this to say so.

use std::path::{Path, PathBuf};

use anyhow::Result;

use crate::dataset::frame_image::load_frame_image;
use nerf_core::image::RgbImage;

/// Photos looked at, at most (evenly spaced through the list).
pub(crate) const MAX_PHOTOS: usize = 20;

/// Side of the thumbnail each photo is reduced to before its border is read.
pub(crate) const THUMBNAIL_SIDE: usize = 64;

/// A border pixel counts as white when each channel is at least this (of 1).
pub(crate) const WHITE_LEVEL: f32 = 0.94;

/// The backdrop is white when at least this fraction of the border pixels is.
pub const WHITE_FRACTION: f64 = 0.9;

/// The fraction of border pixels (the outermost ring of a `THUMBNAIL_SIDE`² thumbnail, each
/// photo's transparent parts taken as black) that are white, over at most `MAX_PHOTOS` of
/// `photos` (paths under `dir`). An error names a photo that cannot be read.
pub fn white_border_fraction(dir: &Path, photos: &[PathBuf]) -> Result<f64> {
    let step = photos.len().div_ceil(MAX_PHOTOS).max(1);
    let (mut white, mut total) = (0usize, 0usize);
    for name in photos.iter().step_by(step) {
        let thumbnail =
            load_frame_image(&dir.join(name), THUMBNAIL_SIDE, THUMBNAIL_SIDE, false)?.image;
        let (w, h) = (thumbnail.width, thumbnail.height);
        for y in 0..h {
            for x in 0..w {
                if x != 0 && y != 0 && x != w - 1 && y != h - 1 {
                    continue;
                }
                let i = 3 * (y * w + x);
                total += 1;
                if thumbnail.data[i..i + 3].iter().all(|&c| c >= WHITE_LEVEL) {
                    white += 1;
                }
            }
        }
    }
    Ok(if total == 0 {
        0.0
    } else {
        white as f64 / total as f64
    })
}

/// A border pixel belongs to a plain backdrop when no channel is further than this (of 1)
/// from the backdrop's colour: about 15 of 255 levels, room for JPEG noise and vignetting.
pub(crate) const BACKDROP_TOLERANCE: f32 = 0.06;

/// The colour of a plain backdrop behind `images` (each `width × height × 3`, RGB in [0, 1]),
/// judged by their borders (the outermost ring of pixels, at most `MAX_PHOTOS` images,
/// evenly spaced): the per-channel median of the border pixels, when at least
/// [`WHITE_FRACTION`] of them lie within `BACKDROP_TOLERANCE` of it; `None` for anything
/// else (a room, a street, a sky: borders of many colours). A channel within the tolerance
/// of 0 or 1 is snapped there, so a white or black backdrop is exactly white or black.
pub fn backdrop_colour(images: &[RgbImage]) -> Option<[f32; 3]> {
    let step = images.len().div_ceil(MAX_PHOTOS).max(1);
    let mut border: Vec<[f32; 3]> = Vec::new();
    for image in images.iter().step_by(step) {
        let (w, h) = (image.width, image.height);
        for y in 0..h {
            for x in 0..w {
                if x != 0 && y != 0 && x + 1 != w && y + 1 != h {
                    continue;
                }
                let i = 3 * (y * w + x);
                border.push([image.data[i], image.data[i + 1], image.data[i + 2]]);
            }
        }
    }
    if border.is_empty() {
        return None;
    }
    let median = |c: usize| {
        let mut v: Vec<f32> = border.iter().map(|p| p[c]).collect();
        let mid = v.len() / 2;
        *v.select_nth_unstable_by(mid, f32::total_cmp).1
    };
    let colour = [median(0), median(1), median(2)];
    let near = border
        .iter()
        .filter(|p| (0..3).all(|c| (p[c] - colour[c]).abs() <= BACKDROP_TOLERANCE))
        .count();
    if (near as f64) < WHITE_FRACTION * border.len() as f64 {
        return None;
    }
    Some(colour.map(|v| {
        if v <= BACKDROP_TOLERANCE {
            0.0
        } else if v >= 1.0 - BACKDROP_TOLERANCE {
            1.0
        } else {
            v
        }
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A `w × h` image of `backdrop` with a grey object in its middle half; with `noise`,
    /// every fifth pixel blue (a busy scene).
    fn loaded(w: usize, h: usize, backdrop: [f32; 3], noise: bool) -> RgbImage {
        let mut data = Vec::with_capacity(3 * w * h);
        for y in 0..h {
            for x in 0..w {
                let inside = (w / 4..3 * w / 4).contains(&x) && (h / 4..3 * h / 4).contains(&y);
                data.extend(match (inside, noise && (x * 7 + y * 13) % 5 == 0) {
                    (true, _) => [0.5, 0.4, 0.3],
                    (false, true) => [0.1, 0.3, 0.7],
                    (false, false) => backdrop,
                });
            }
        }
        RgbImage::new(w, h, data).unwrap()
    }

    #[test]
    fn a_plain_backdrop_gives_its_colour_and_a_busy_one_none() {
        let white = vec![loaded(40, 30, [0.97, 0.99, 1.0], false); 3];
        assert_eq!(backdrop_colour(&white), Some([1.0, 1.0, 1.0]));
        let black = vec![loaded(30, 40, [0.02, 0.0, 0.03], false); 2];
        assert_eq!(backdrop_colour(&black), Some([0.0, 0.0, 0.0]));
        let green = vec![loaded(20, 20, [0.2, 0.6, 0.3], false)];
        assert_eq!(backdrop_colour(&green), Some([0.2, 0.6, 0.3]));
        assert_eq!(backdrop_colour(&[loaded(40, 30, [1.0; 3], true)]), None);
        assert_eq!(backdrop_colour(&[]), None);
        // Half the photos on white, half on black: no one backdrop.
        let mixed = vec![
            loaded(20, 20, [1.0; 3], false),
            loaded(20, 20, [0.0; 3], false),
        ];
        assert_eq!(backdrop_colour(&mixed), None);
    }

    /// A 100×80 photo: `border` around a grey object covering the middle half.
    fn photo(dir: &Path, name: &str, border: [u8; 3], noise: bool) -> PathBuf {
        let image = image::RgbImage::from_fn(100, 80, |x, y| {
            let inside = (25..75).contains(&x) && (20..60).contains(&y);
            if inside {
                image::Rgb([120, 110, 90])
            } else if noise && (x * 7 + y * 13) % 5 == 0 {
                image::Rgb([40, 90, 160])
            } else {
                image::Rgb(border)
            }
        });
        image.save(dir.join(name)).unwrap();
        PathBuf::from(name)
    }

    #[test]
    fn white_borders_are_told_from_others() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let white: Vec<PathBuf> = (0..3)
            .map(|i| photo(d, &format!("w{i}.png"), [250, 252, 255], false))
            .collect();
        assert_eq!(white_border_fraction(d, &white).unwrap(), 1.0);
        let grey = vec![photo(d, "g.png", [200, 200, 200], false)];
        assert_eq!(white_border_fraction(d, &grey).unwrap(), 0.0);
        // A busy scene behind: about a fifth of the border is not white.
        let busy = vec![photo(d, "b.png", [255, 255, 255], true)];
        let f = white_border_fraction(d, &busy).unwrap();
        assert!(f < WHITE_FRACTION, "{f}");
        let e = white_border_fraction(d, &[PathBuf::from("missing.png")]).unwrap_err();
        assert!(e.to_string().contains("missing.png"), "{e}");
    }

    #[test]
    fn many_photos_are_sampled_evenly() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        // 45 photos: every third is read (15 of them), all of them grey but the white ones at
        // indices divisible by 3.
        let photos: Vec<PathBuf> = (0..45)
            .map(|i| {
                let border = if i % 3 == 0 { [255; 3] } else { [90; 3] };
                photo(d, &format!("p{i:02}.png"), border, false)
            })
            .collect();
        assert_eq!(white_border_fraction(d, &photos).unwrap(), 1.0);
    }
}
