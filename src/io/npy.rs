//! Reading `.npy` images: the homework's training targets (`np.save` of an `(H, W, 3)`
//! float array, read there with `np.load`).

use std::path::Path;

use anyhow::{anyhow, bail, Context, Result};

use crate::core::image::RgbImage;

/// Reads a C-ordered float32 (or float64) `.npy` array of shape `(height, width, 3)` as an
/// image. An error names the file and what is wrong: missing or unreadable, not a `.npy`,
/// another shape, dtype or order, or a NaN or infinite value.
pub fn read_npy_image(path: &Path, width: usize, height: usize) -> Result<RgbImage> {
    let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    let npy = npyz::NpyFile::new(&bytes[..])
        .map_err(|e| anyhow!("{} is not a .npy array: {e}", path.display()))?;
    let shape: Vec<u64> = npy.shape().to_vec();
    let want = [height as u64, width as u64, 3];
    if shape != want {
        bail!(
            "{}: shape {:?}, but data.image_size [{width}, {height}] needs ({height}, {width}, 3)",
            path.display(),
            shape
        );
    }
    if npy.order() != npyz::Order::C {
        bail!(
            "{}: a Fortran-ordered array; save it with np.save(path, np.ascontiguousarray(a))",
            path.display()
        );
    }
    let dtype = npy.dtype().descr();
    let data: Vec<f32> = match dtype.as_str() {
        "'<f4'" => npy.into_vec::<f32>()?,
        "'<f8'" => npy
            .into_vec::<f64>()?
            .into_iter()
            .map(|v| v as f32)
            .collect(),
        other => bail!(
            "{}: dtype {other}, but a float32 image is expected",
            path.display()
        ),
    };
    if let Some(i) = data.iter().position(|v| !v.is_finite()) {
        bail!(
            "{}: value {} at index {i} is not finite",
            path.display(),
            data[i]
        );
    }
    RgbImage::new(width, height, data)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::images::write_npy;

    #[test]
    fn round_trips_and_names_bad_shapes() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("t.npy");
        let values: Vec<f32> = (0..2 * 3 * 3).map(|i| i as f32 / 18.0).collect();
        write_npy(&p, &[2, 3, 3], &values).unwrap();
        let img = read_npy_image(&p, 3, 2).unwrap();
        assert_eq!((img.width, img.height), (3, 2));
        assert_eq!(img.data, values);
        let err = read_npy_image(&p, 2, 3).unwrap_err().to_string();
        assert!(
            err.contains("shape [2, 3, 3]") && err.contains("(3, 2, 3)"),
            "{err}"
        );
        let missing = read_npy_image(&dir.path().join("none.npy"), 3, 2).unwrap_err();
        assert!(format!("{missing:#}").contains("none.npy"));
        std::fs::write(&p, b"not an array").unwrap();
        assert!(read_npy_image(&p, 3, 2)
            .unwrap_err()
            .to_string()
            .contains("not a .npy"));
        let mut nan = values.clone();
        nan[4] = f32::NAN;
        write_npy(&p, &[2, 3, 3], &nan).unwrap();
        assert!(read_npy_image(&p, 3, 2)
            .unwrap_err()
            .to_string()
            .contains("not finite"));
    }
}
