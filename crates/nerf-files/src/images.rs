//! Writing what people look at: PNG, GIF and NPY files, by the one writing rule of
//! [`crate::output`] (temp file beside the real target, then rename; links followed,
//! devices written directly), so an interrupted or failed write never leaves a half-written
//! file behind.

use std::io::Write;
use std::path::Path;

use anyhow::{bail, Context, Result};
use image::{ImageBuffer, Rgb};
use nerf_core::image::RgbImage;
use npyz::WriterBuilder;

use crate::output::write_atomically;

/// An 8-bit RGB PNG file's bytes.
pub fn png_bytes(image: &RgbImage) -> Result<Vec<u8>> {
    let buffer: ImageBuffer<Rgb<u8>, Vec<u8>> =
        ImageBuffer::from_raw(image.width as u32, image.height as u32, image.to_bytes())
            .context("image buffer size")?;
    let mut bytes = std::io::Cursor::new(Vec::new());
    buffer
        .write_to(&mut bytes, image::ImageFormat::Png)
        .context("cannot encode PNG")?;
    Ok(bytes.into_inner())
}

/// Writes an 8-bit RGB PNG.
pub fn write_png(path: &Path, image: &RgbImage) -> Result<()> {
    let bytes = png_bytes(image).with_context(|| format!("{}", path.display()))?;
    write_atomically(path, |w| {
        w.write_all(&bytes)?;
        Ok(())
    })
}

/// Writes an animated, looping GIF (a palette per frame, its frames quantised in parallel),
/// `delay_cs` hundredths of a second per frame.
pub fn write_gif(path: &Path, frames: &[RgbImage], delay_cs: u16) -> Result<()> {
    use rayon::prelude::*;
    let Some(first) = frames.first() else {
        bail!("no frames to write to {}", path.display());
    };
    let (w, h) = (first.width as u16, first.height as u16);
    let encoded: Vec<gif::Frame> = frames
        .par_iter()
        .map(|f| {
            let (palette, indices) = gif_palette(f)?;
            let mut frame = gif::Frame::from_palette_pixels(w, h, indices, palette, None);
            frame.delay = delay_cs;
            Ok(frame)
        })
        .collect::<Result<_>>()?;
    write_atomically(path, |out| {
        let mut encoder = gif::Encoder::new(out, w, h, &[])?;
        encoder.set_repeat(gif::Repeat::Infinite)?;
        for frame in &encoded {
            encoder.write_frame(frame)?;
        }
        Ok(())
    })
}

/// A frame's GIF palette (at most 256 colours, `r, g, b` bytes) and each pixel's index in it,
/// by Wu's colour quantiser (quantette, in Oklab, no dithering).
///
/// Wu's method is both faster and closer to the frames than gif's own NeuQuant at full
/// quality, whose faster settings lose more; quantette's k-means gains little for its time;
/// on smooth shading Wu and NeuQuant are even (measured:
/// docs/speed-and-report.md#gif-palettes).
pub(crate) fn gif_palette(frame: &RgbImage) -> Result<(Vec<u8>, Vec<u8>)> {
    use quantette::{ImageBuf, Pipeline, QuantizeMethod};
    let bytes = frame.to_bytes();
    let pixels: Vec<palette::Srgb<u8>> = bytes
        .chunks_exact(3)
        .map(|c| palette::Srgb::new(c[0], c[1], c[2]))
        .collect();
    let image = ImageBuf::new(frame.width as u32, frame.height as u32, pixels)
        .map_err(|e| anyhow::anyhow!("GIF frame: {e}"))?;
    let indexed = Pipeline::new()
        .ditherer(None)
        .quantize_method(QuantizeMethod::Wu)
        .input_image(image.as_ref())
        .output_srgb8_indexed_image();
    let palette = indexed
        .palette()
        .iter()
        .flat_map(|c| [c.red, c.green, c.blue])
        .collect();
    Ok((palette, indexed.indices().to_vec()))
}

/// Writes a little-endian float32 `.npy` array of the given shape.
pub fn write_npy(path: &Path, shape: &[u64], data: &[f32]) -> Result<()> {
    let expected: u64 = shape.iter().product();
    if expected != data.len() as u64 {
        bail!(
            "npy data has {} values, shape {:?} needs {}",
            data.len(),
            shape,
            expected
        );
    }
    write_atomically(path, |w| {
        let mut writer = npyz::WriteOptions::<f32>::new()
            .default_dtype()
            .shape(shape)
            .writer(w)
            .begin_nd()?;
        writer.extend(data.iter().copied())?;
        writer.finish()?;
        Ok(())
    })
}

/// Maps values to matplotlib's viridis after min–max normalisation (what `plt.imsave` does
/// with a 2-D array): `(H·W)` values → RGB image.
pub fn viridis_image(width: usize, height: usize, values: &[f32]) -> Result<RgbImage> {
    let (lo, hi) = values
        .iter()
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &v| {
            (lo.min(v), hi.max(v))
        });
    let range = if hi > lo { hi - lo } else { 1.0 };
    let mut data = Vec::with_capacity(values.len() * 3);
    for &v in values {
        // matplotlib: index = floor(x · 256), clipped to 255.
        let x = (v - lo) / range;
        let idx = ((x * 256.0) as usize).min(255);
        let c = colorous::VIRIDIS.eval_rational(idx, 256);
        data.extend([c.r, c.g, c.b].map(|b| (b as f32 + 0.5) / 255.0));
    }
    RgbImage::new(width, height, data)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn png_and_npy_round_trip() {
        let dir = tempfile::tempdir().unwrap();
        let img = RgbImage::new(2, 1, vec![0.0, 0.5, 1.0, 1.0, 0.0, 0.25]).unwrap();
        let p = dir.path().join("a.png");
        write_png(&p, &img).unwrap();
        let back = image::open(&p).unwrap().to_rgb8();
        assert_eq!(back.into_raw(), vec![0, 127, 255, 255, 0, 63]);
        let n = dir.path().join("a.npy");
        write_npy(&n, &[1, 2, 3], &img.data).unwrap();
        let bytes = std::fs::read(&n).unwrap();
        let arr = npyz::NpyFile::new(&bytes[..]).unwrap();
        assert_eq!(arr.shape(), &[1, 2, 3]);
        assert_eq!(arr.into_vec::<f32>().unwrap(), img.data);
    }

    #[test]
    fn viridis_ends() {
        let img = viridis_image(2, 1, &[0.0, 1.0]).unwrap();
        let b = img.to_bytes();
        // matplotlib viridis(0) = #440154, viridis(1) = #fde725.
        assert_eq!(&b[..3], &[0x44, 0x01, 0x54]);
        assert_eq!(&b[3..], &[0xfd, 0xe7, 0x25]);
    }
}
