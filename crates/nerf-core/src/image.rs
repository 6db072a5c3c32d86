//! An RGB image with float channels, the form every rendered view takes.

use anyhow::{bail, Result};

/// Float colour in [0, 1] → byte, as matplotlib's `imsave` does (`(x·255).astype(uint8)`, so
/// truncation); values outside [0, 1] are clamped.
pub fn to_byte(v: f32) -> u8 {
    (v.clamp(0.0, 1.0) * 255.0) as u8
}

/// An RGB image with float channels in [0, 1], row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct RgbImage {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// `width · height · 3` values.
    pub data: Vec<f32>,
}

impl RgbImage {
    /// An image from `width · height · 3` row-major RGB values (an error for any other count).
    pub fn new(width: usize, height: usize, data: Vec<f32>) -> Result<Self> {
        if data.len() != width * height * 3 {
            bail!(
                "image data has {} values, expected {}×{}×3",
                data.len(),
                width,
                height
            );
        }
        Ok(Self {
            width,
            height,
            data,
        })
    }

    /// The pixels as 8-bit RGB (values clamped to [0, 1], then as matplotlib's `imsave`).
    pub fn to_bytes(&self) -> Vec<u8> {
        self.data.iter().map(|&v| to_byte(v)).collect()
    }
}

/// `white`, `black`, or `rgb(r, g, b)` in bytes: how a background colour (RGB in [0, 1]) is
/// named in messages.
pub fn colour_name(rgb: [f32; 3]) -> String {
    match rgb {
        [1.0, 1.0, 1.0] => "white".to_string(),
        [0.0, 0.0, 0.0] => "black".to_string(),
        [r, g, b] => format!("rgb({}, {}, {})", to_byte(r), to_byte(g), to_byte(b)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bytes_truncate_like_matplotlib() {
        assert_eq!(to_byte(1.0), 255);
        assert_eq!(to_byte(0.9995), 254);
        assert_eq!(to_byte(-0.5), 0);
        assert_eq!(to_byte(2.0), 255);
    }
}
