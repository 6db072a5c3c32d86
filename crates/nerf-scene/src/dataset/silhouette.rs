//! Masks that outline an object (a turntable capture's): trained as its alpha, not ignored.
//!
//! A mask means one of two things. Most often (nerfstudio's `mask_path`) it marks pixels to
//! ignore: a passer-by, the photographer's shadow; the rest of the photo is the scene. But a
//! mask that keeps only an object in the middle of every photo, touching no border, is the
//! object's silhouette: what lies outside it is not part of the model at all (a turntable
//! turns the object, not the room, so the room is not one scene). Ignoring those pixels
//! leaves the space around the object untrained, and the fog that grows there hides the
//! object from the held-out views; taking the silhouette as alpha trains that space empty,
//! as photos with an alpha channel do (a random background colour per step).

use super::Dataset;

/// A mask outlines an object when at most this fraction of its border ring is used.
pub(crate) const BORDER_USED_AT_MOST: f64 = 0.02;

/// The masks of a capture outline its object when at least this fraction of them do.
pub(crate) const SILHOUETTE_SHARE: f64 = 0.9;

/// Whether a row-major `width × height` mask (`used`: true for a used pixel) uses at most
/// [`BORDER_USED_AT_MOST`] of the pixels of its outermost ring.
pub(crate) fn outlines_an_object(used: &[bool], width: usize, height: usize) -> bool {
    if width < 3 || height < 3 || used.len() != width * height {
        return false;
    }
    let ring = (0..width)
        .flat_map(|x| [x, (height - 1) * width + x])
        .chain((1..height - 1).flat_map(|y| [y * width, y * width + width - 1]));
    let (mut on, mut all) = (0usize, 0usize);
    for p in ring {
        all += 1;
        on += usize::from(used[p]);
    }
    on as f64 <= BORDER_USED_AT_MOST * all as f64
}

/// What [`masks_as_alpha`] did with a capture whose masks outline its object.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OutlinedObject {
    /// How many masks were taken as alpha.
    pub frames: usize,
    /// The mean colour of the pixels the masks left out, linear RGB in [0, 1]: the backdrop
    /// the photos show round the object, where their silhouette's edge pixels mix with it.
    pub backdrop: [f32; 3],
}

/// When the dataset's masks outline an object (`outlines_an_object`, at least
/// `SILHOUETTE_SHARE` of the masked images), makes every masked-out pixel fully transparent
/// (its transparency 1, its colour `background`, or with `None` the backdrop the masks leave
/// out, [`OutlinedObject::backdrop`]: the colour a transparent pixel holds must be the one
/// training composites the photos on) and drops the masks, so that training draws rays from
/// every pixel and trains the space around the object empty. Returns what it did (`None`:
/// the masks stay masks).
pub fn masks_as_alpha(
    dataset: &mut Dataset,
    background: Option<[f32; 3]>,
) -> Option<OutlinedObject> {
    let (w, h) = (dataset.width, dataset.height);
    let masked: Vec<usize> = (0..dataset.images.len())
        .filter(|&i| dataset.mask(i).is_some())
        .collect();
    let outlines = masked
        .iter()
        .filter(|&&i| {
            dataset
                .mask(i)
                .is_some_and(|m| outlines_an_object(m.used(), w, h))
        })
        .count();
    if masked.is_empty() || (outlines as f64) < SILHOUETTE_SHARE * masked.len() as f64 {
        return None;
    }
    let masks = std::mem::take(&mut dataset.masks);
    let (mut sum, mut count) = ([0.0f64; 3], 0usize);
    for (i, mask) in masks.iter().enumerate() {
        let Some(mask) = mask else { continue };
        let data = &dataset.images[i].data;
        for (p, _) in mask.used().iter().enumerate().filter(|(_, &used)| !used) {
            for (s, &c) in sum.iter_mut().zip(&data[3 * p..3 * p + 3]) {
                *s += f64::from(c);
            }
            count += 1;
        }
    }
    let backdrop = sum.map(|s| (s / count.max(1) as f64) as f32);
    let fill = background.unwrap_or(backdrop);
    for (i, mask) in masks.into_iter().enumerate() {
        let Some(mask) = mask else { continue };
        let image = &mut dataset.images[i];
        let transparency = &mut dataset.transparency[i];
        if transparency.len() != w * h {
            *transparency = vec![0.0; w * h];
        }
        for (p, _) in mask.used().iter().enumerate().filter(|(_, &used)| !used) {
            transparency[p] = 1.0;
            image.data[3 * p..3 * p + 3].copy_from_slice(&fill);
        }
    }
    Some(OutlinedObject {
        frames: masked.len(),
        backdrop,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A `w × h` mask using the pixels inside `[x0, x1) × [y0, y1)`.
    fn rect(w: usize, h: usize, (x0, x1): (usize, usize), (y0, y1): (usize, usize)) -> Vec<bool> {
        (0..w * h)
            .map(|p| (x0..x1).contains(&(p % w)) && (y0..y1).contains(&(p / w)))
            .collect()
    }

    #[test]
    fn an_object_in_the_middle_is_a_silhouette_a_masked_corner_is_not() {
        // The object alone, away from every border.
        assert!(outlines_an_object(&rect(20, 10, (5, 15), (2, 8)), 20, 10));
        // A passer-by masked out of a scene: the rest, borders included, is used.
        let ignore_a_corner: Vec<bool> = rect(20, 10, (0, 5), (0, 4)).iter().map(|u| !u).collect();
        assert!(!outlines_an_object(&ignore_a_corner, 20, 10));
        // An object standing on the bottom border over a fifth of it: not a silhouette.
        assert!(!outlines_an_object(&rect(20, 10, (4, 16), (3, 10)), 20, 10));
        // Too small, or the wrong length: no.
        assert!(!outlines_an_object(&[false; 4], 2, 2));
        assert!(!outlines_an_object(&[false; 10], 4, 4));
    }

    #[test]
    fn outlining_masks_become_alpha_and_say_the_backdrop_round_the_object() {
        use crate::dataset::PixelMask;
        use nerf_core::image::RgbImage;
        let (w, h) = (8, 6);
        // Photo k: the object (white) inside [3, 5) × [2, 4), a backdrop of 0.2 + 0.1k, 0.5, 0.8.
        let photo = |k: usize| {
            let data = (0..w * h)
                .flat_map(|p| match rect(w, h, (3, 5), (2, 4))[p] {
                    true => [1.0, 1.0, 1.0],
                    false => [0.2 + 0.1 * k as f32, 0.5, 0.8],
                })
                .collect();
            RgbImage::new(w, h, data).unwrap()
        };
        let mask = || Some(PixelMask::from_flags(rect(w, h, (3, 5), (2, 4))));
        let mut dataset = Dataset {
            frames: Vec::new(),
            images: vec![photo(0), photo(2)],
            transparency: vec![Vec::new(), Vec::new()],
            width: w,
            height: h,
            masks: vec![mask(), mask()],
            normalisation: None,
            capture: None,
        };
        let black = [0.0; 3];
        let unfilled = dataset.clone();
        let outlined = masks_as_alpha(&mut dataset, Some(black)).expect("outlined");
        assert_eq!(outlined.frames, 2);
        for (got, want) in outlined.backdrop.iter().zip([0.3, 0.5, 0.8]) {
            assert!((got - want).abs() < 1e-6, "{:?}", outlined.backdrop);
        }
        assert!(dataset.masks.is_empty());
        for (image, transparency) in dataset.images.iter().zip(&dataset.transparency) {
            let object = rect(w, h, (3, 5), (2, 4));
            for (p, (&inside, &t)) in object.iter().zip(transparency).enumerate() {
                assert_eq!(t, if inside { 0.0 } else { 1.0 });
                let want = if inside { [1.0; 3] } else { black };
                assert_eq!(image.data[3 * p..3 * p + 3], want);
            }
        }
        // Without a colour of its own, a transparent pixel holds the backdrop.
        let mut on_backdrop = unfilled;
        assert_eq!(masks_as_alpha(&mut on_backdrop, None), Some(outlined));
        let transparent = on_backdrop.transparency[1]
            .iter()
            .position(|&t| t == 1.0)
            .unwrap();
        let colour = &on_backdrop.images[1].data[3 * transparent..3 * transparent + 3];
        assert_eq!(colour, outlined.backdrop);
        // Masks that ignore a corner of a scene stay masks.
        let mut scene = dataset.clone();
        let corner: Vec<bool> = rect(w, h, (0, 2), (0, 2)).iter().map(|u| !u).collect();
        scene.masks = vec![Some(PixelMask::from_flags(corner)); 2];
        assert_eq!(masks_as_alpha(&mut scene, Some(black)), None);
        assert_eq!(scene.masks.len(), 2);
    }
}
