//! The evaluation protocol of a capture, said in one line before its scores: which frames are
//! held out, what appearance they are rendered with, and how the photos became the targets.

use nerf_scene::dataset::photo_resize::PhotoResize;
use nerf_scene::dataset::{CaptureInfo, Split};

/// `protocol: 23 held-out frames (every 8th of the sorted photo names), mean appearance
/// vector, targets box-downscaled 1/1 to 544×960`: the `frames` of `split` of a capture
/// (`info`), scored at `size`, by a model with or without a per-photo appearance embedding.
pub fn protocol_line(
    info: &CaptureInfo,
    split: Split,
    frames: usize,
    size: (usize, usize),
    appearance: bool,
) -> String {
    let which = match split {
        Split::Train => "training",
        Split::Val | Split::Test => "held-out",
    };
    // Renders never carry a photo's index: every view takes the mean vector.
    let appearance = match appearance {
        false => "no appearance embedding",
        true => "mean appearance vector of the training photos",
    };
    let (w, h) = size;
    let targets = match info.photo_size {
        Some(photo) => {
            let resize = PhotoResize::between(photo, (w as u32, h as u32));
            format!("targets {} to {w}×{h}", resize.describe())
        }
        None => format!("targets at {w}×{h}"),
    };
    format!(
        "protocol: {frames} {which} frame{} ({}), {appearance}, {targets}",
        if frames == 1 { "" } else { "s" },
        info.protocol.describe()
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use nerf_scene::dataset::SplitProtocol;

    #[test]
    fn the_line_names_the_frames_the_appearance_and_the_targets() {
        let info = CaptureInfo {
            format: nerf_scene::dataset::colmap_scene::COLMAP,
            camera_source: "the COLMAP model sparse/0".into(),
            protocol: SplitProtocol::EveryEighth,
            photo_size: Some((544, 960)),
        };
        assert_eq!(
            protocol_line(&info, Split::Test, 23, (544, 960), true),
            "protocol: 23 held-out frames (every 8th of the sorted photo names), mean \
             appearance vector of the training photos, targets box-downscaled 1/1 to 544×960"
        );
        let line = protocol_line(&info, Split::Test, 1, (272, 480), false);
        assert!(
            line.contains("1 held-out frame (")
                && line.contains("no appearance embedding")
                && line.ends_with("box-downscaled 1/2 to 272×480"),
            "{line}"
        );
        let line = protocol_line(&info, Split::Test, 2, (300, 480), false);
        assert!(line.contains("triangle filter"), "{line}");
    }
}
