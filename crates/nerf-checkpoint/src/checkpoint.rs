//! NeRF checkpoints as one safetensors file, written atomically.
//!
//! Tensors: the model's parameters under their PyTorch names (`mlp_xyz.mlp.0.0.weight`, …,
//! see `nerf::field::nerf`), and for training checkpoints the Adam moments
//! `adam.exp_avg.<name>` / `adam.exp_avg_sq.<name>`. Metadata: `epoch` (epochs completed),
//! `adam_step`, `format` = `nerf-candle-1`, and for a model trained on a capture
//! `scene_transform`, the normalisation its cameras were put in
//! ([`SceneTransform::to_text`]), `capture_orbit`, the views that suit it
//! ([`CaptureOrbit::to_text`]), and for a forward-facing capture `capture_spiral`, the views
//! that suit it better ([`CaptureSpiral::to_text`]). A loader that only wants the model
//! ignores `adam.*`.

use std::collections::HashMap;
use std::path::Path;

use anyhow::{bail, ensure, Context, Result};
use candle_core::{DType, Device, Tensor};
use candle_nn::VarMap;

pub use crate::checkpoint_error::CheckpointError;
use nerf_files::output::write_atomically;
use nerf_scene::dataset::{CaptureOrbit, CaptureSpiral, SceneTransform};

/// The metadata key of the scene normalisation a model was trained in.
pub(crate) const SCENE_TRANSFORM_KEY: &str = "scene_transform";

/// The metadata key of the orbit `nerf render` and `nerf view` show a capture's model from.
pub(crate) const CAPTURE_ORBIT_KEY: &str = "capture_orbit";

/// The metadata key of the spiral `nerf render` and `nerf view` show a forward-facing
/// capture's model from, instead of its orbit.
pub(crate) const CAPTURE_SPIRAL_KEY: &str = "capture_spiral";

/// The metadata key of the background colour a model was trained on (`r g b` in [0, 1]).
pub(crate) const BACKGROUND_KEY: &str = "background";

/// The metadata key of the image size a model was trained at (`width height`).
pub(crate) const IMAGE_SIZE_KEY: &str = "image_size";

/// The metadata key of the depth range training narrowed the sampler to (`near far`; an
/// object photographed alone, [`nerf_scene::dataset::object_hull`]).
pub(crate) const SAMPLE_DEPTHS_KEY: &str = "sample_depths";

/// The metadata key of the box training fitted the field and the occupancy grid to
/// (`min_x min_y min_z max_x max_y max_z`; an object photographed alone,
/// [`nerf_scene::dataset::object_hull`]).
pub(crate) const OBJECT_BOX_KEY: &str = "object_box";

/// The metadata key of the field's layout ([`CheckpointInfo::field_layout`]).
pub const FIELD_LAYOUT_KEY: &str = "field_layout";

/// The largest coordinate a stored object box may have (the normalised frame's cameras stand
/// within 1 of the origin).
pub(crate) const MAX_BOX_COORDINATE: f64 = 1e3;

/// The longest field layout line a checkpoint may store.
pub(crate) const MAX_LAYOUT_BYTES: usize = 4096;

/// The largest side a stored training image size may have.
pub(crate) const MAX_STORED_SIDE: usize = 1 << 16;

/// What a checkpoint holds besides tensors.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct CheckpointInfo {
    /// Epochs completed when it was written.
    pub epoch: usize,
    /// Adam steps taken.
    pub adam_step: u64,
    /// Training wall-clock seconds so far, over all resumed runs.
    pub wall_seconds: f64,
    /// Steps of epoch `epoch` already taken, when the run stopped mid-epoch (0 at an epoch
    /// boundary).
    pub step_in_epoch: usize,
    /// With `step_in_epoch > 0`: the position of that epoch's random stream, so a resumed run
    /// draws what the uninterrupted run would have.
    pub rng_word_pos: u128,
    /// Rays of the next step when training adapts them (`training.samples_per_step`; 0 when
    /// it does not).
    pub rays_per_step: usize,
    /// The normalisation of the capture the model was trained on (`None` for a NeRF-synthetic
    /// scene, or a checkpoint written before it was stored): evaluating or rendering the
    /// capture's cameras with this model must put them in this frame.
    pub scene_transform: Option<SceneTransform>,
    /// The views around a capture that `nerf render` and `nerf view` default to (`None` for
    /// a NeRF-synthetic scene, or a checkpoint written before it was stored).
    pub capture_orbit: Option<CaptureOrbit>,
    /// The spiral in front of a forward-facing capture that `nerf render` and `nerf view`
    /// default to instead of the orbit (`None` for other scenes, or a checkpoint written
    /// before spirals were stored).
    pub capture_spiral: Option<CaptureSpiral>,
    /// The colour training composited onto (`None` in a checkpoint written before it was
    /// stored): what `renderer.background: auto` renders on.
    pub background: Option<[f32; 3]>,
    /// The training images' size (`None` in a checkpoint written before it was stored): what
    /// renders of a config without `data.image_size` take.
    pub image_size: Option<(usize, usize)>,
    /// The sampler's depth range `(min_depth, max_depth)` when training narrowed it to an
    /// object (`None` otherwise, or in a checkpoint written before it was stored): what
    /// `eval`, `render` and `view` sample the model over.
    pub sample_depths: Option<(f64, f64)>,
    /// The box `[min x, y, z, max x, y, z]` the field and the occupancy grid were fitted to
    /// when training found an object alone (`None` otherwise, or in a checkpoint written
    /// before it was stored): the model holds nothing outside it.
    pub object_box: Option<[f64; 6]>,
    /// What the model's parameter shapes do not say about how they are read
    /// (`nerf::field::trainable::TrainableField::layout`; `None` for a kind without one, or
    /// a checkpoint written before it was stored): a model of another layout must not load it.
    pub field_layout: Option<String>,
}

/// The largest counts a checkpoint's metadata may hold: far past any real run, and small
/// enough that nothing sized or looped by them can exhaust memory or time. A file past one is
/// refused with an error naming the key, before anything is allocated.
pub mod metadata_limits {
    /// Epochs completed (`epoch`): a million, at a second each, is 11 days.
    pub const EPOCHS: u64 = 1 << 20;
    /// Adam steps taken (`adam_step`).
    pub(crate) const ADAM_STEPS: u64 = 1 << 40;
    /// Steps of an epoch already taken (`step_in_epoch`): one per training image.
    pub(crate) const STEP_IN_EPOCH: u64 = 1 << 20;
    /// Rays of the next step (`rays_per_step`): the most an adapted step may take
    /// (`config::limits::DRAWN_SAMPLES` at one sample per ray).
    pub(crate) const RAYS_PER_STEP: u64 = 1 << 23;
}

impl CheckpointInfo {
    /// An error naming the key ([`CheckpointError::Metadata`]) when a count is past
    /// [`metadata_limits`] or the training wall time is negative or not finite. (`rng_word_pos`
    /// needs no limit: the stream cycles, and setting it reads only its low 68 bits.)
    pub(crate) fn validate(&self, origin: &Path) -> Result<(), CheckpointError> {
        use metadata_limits as l;
        let counts = [
            ("epoch", self.epoch as u64, l::EPOCHS),
            ("adam_step", self.adam_step, l::ADAM_STEPS),
            ("step_in_epoch", self.step_in_epoch as u64, l::STEP_IN_EPOCH),
            ("rays_per_step", self.rays_per_step as u64, l::RAYS_PER_STEP),
        ];
        for (key, value, max) in counts {
            if value > max {
                let message = format!(
                    "checkpoint {}: metadata {key} = {value} is past the most a run can have \
                     ({max}); the file is corrupt or crafted",
                    origin.display()
                );
                return Err(CheckpointError::metadata(origin, key, message));
            }
        }
        if !(self.wall_seconds.is_finite() && self.wall_seconds >= 0.0) {
            let message = format!(
                "checkpoint {}: metadata wall_seconds = {} is not a time",
                origin.display(),
                self.wall_seconds
            );
            return Err(CheckpointError::metadata(origin, "wall_seconds", message));
        }
        if let Some(layout) = self
            .field_layout
            .as_ref()
            .filter(|l| l.len() > MAX_LAYOUT_BYTES)
        {
            let message = format!(
                "checkpoint {}: metadata {FIELD_LAYOUT_KEY} is {} bytes, past the {MAX_LAYOUT_BYTES} \
                 a layout line can have; the file is corrupt or crafted",
                origin.display(),
                layout.len()
            );
            return Err(CheckpointError::metadata(origin, FIELD_LAYOUT_KEY, message));
        }
        Ok(())
    }
}

/// Writes `tensors` (any shapes; f16 ones stored as f16, every other float dtype as f32) and
/// `info` to `path` (temp file + rename).
pub fn save(path: &Path, tensors: &[(String, Tensor)], info: CheckpointInfo) -> Result<()> {
    let mut data = Vec::with_capacity(tensors.len());
    for (name, t) in tensors {
        let t = t.to_device(&Device::Cpu)?.contiguous()?;
        let (dtype, bytes): (safetensors::Dtype, Vec<u8>) = if t.dtype() == DType::F16 {
            let v = t.flatten_all()?.to_vec1::<half::f16>()?;
            let bytes = v.iter().flat_map(|v| v.to_le_bytes()).collect();
            (safetensors::Dtype::F16, bytes)
        } else {
            let v = t.to_dtype(DType::F32)?.flatten_all()?.to_vec1::<f32>()?;
            let bytes = v.iter().flat_map(|v| v.to_le_bytes()).collect();
            (safetensors::Dtype::F32, bytes)
        };
        data.push((name.clone(), dtype, t.dims().to_vec(), bytes));
    }
    let views: Vec<(String, safetensors::tensor::TensorView)> = data
        .iter()
        .map(|(n, dtype, shape, bytes)| {
            Ok((
                n.clone(),
                safetensors::tensor::TensorView::new(*dtype, shape.clone(), bytes)?,
            ))
        })
        .collect::<Result<_>>()?;
    let mut metadata: HashMap<String, String> = [
        ("epoch".to_string(), info.epoch.to_string()),
        ("adam_step".to_string(), info.adam_step.to_string()),
        (
            "wall_seconds".to_string(),
            format!("{:.3}", info.wall_seconds),
        ),
        ("step_in_epoch".to_string(), info.step_in_epoch.to_string()),
        ("rng_word_pos".to_string(), info.rng_word_pos.to_string()),
        ("rays_per_step".to_string(), info.rays_per_step.to_string()),
        ("format".to_string(), "nerf-candle-1".to_string()),
    ]
    .into();
    if let Some(t) = &info.scene_transform {
        metadata.insert(SCENE_TRANSFORM_KEY.to_string(), t.to_text());
    }
    if let Some(o) = &info.capture_orbit {
        metadata.insert(CAPTURE_ORBIT_KEY.to_string(), o.to_text());
    }
    if let Some(s) = &info.capture_spiral {
        metadata.insert(CAPTURE_SPIRAL_KEY.to_string(), s.to_text());
    }
    if let Some([r, g, b]) = info.background {
        metadata.insert(BACKGROUND_KEY.to_string(), format!("{r} {g} {b}"));
    }
    if let Some((w, h)) = info.image_size {
        metadata.insert(IMAGE_SIZE_KEY.to_string(), format!("{w} {h}"));
    }
    if let Some((near, far)) = info.sample_depths {
        metadata.insert(SAMPLE_DEPTHS_KEY.to_string(), format!("{near} {far}"));
    }
    if let Some(b) = info.object_box {
        let text = b.map(|v| v.to_string()).join(" ");
        metadata.insert(OBJECT_BOX_KEY.to_string(), text);
    }
    if let Some(layout) = &info.field_layout {
        metadata.insert(FIELD_LAYOUT_KEY.to_string(), layout.clone());
    }
    let bytes = safetensors::serialize(views, Some(metadata))?;
    if let Some(dir) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("cannot create checkpoint directory {}", dir.display()))?;
    }
    write_atomically(path, |w| {
        use std::io::Write;
        w.write_all(&bytes)?;
        Ok(())
    })
}

/// Reads every tensor (f32, its stored shape, on `device`) and the metadata of a safetensors
/// checkpoint. Errors ([`CheckpointError`]): no file ([`CheckpointError::NotFound`]), a
/// PyTorch file or one that is not safetensors ([`CheckpointError::Format`]), metadata that does
/// not read or is out of bounds ([`CheckpointError::Metadata`]), a non-finite tensor
/// ([`CheckpointError::NonFinite`]).
pub fn load(
    path: &Path,
    device: &Device,
) -> Result<(HashMap<String, Tensor>, CheckpointInfo), CheckpointError> {
    load_safetensors(path, device).map_err(CheckpointError::from_anyhow)
}

/// [`load`], its typed errors inside an `anyhow::Error`.
fn load_safetensors(
    path: &Path,
    device: &Device,
) -> Result<(HashMap<String, Tensor>, CheckpointInfo)> {
    let bytes = std::fs::read(path).map_err(|e| CheckpointError::unreadable(path, e))?;
    // A safetensors file: an 8-byte header length that fits, then the JSON header's `{` (its
    // first byte may be 0x80, as a pickle stream's is).
    let safetensors_like = bytes.len() > 8
        && bytes[8] == b'{'
        && u64::from_le_bytes(bytes[..8].try_into().expect("8 bytes")) <= bytes.len() as u64 - 8;
    if !safetensors_like && (bytes.starts_with(b"PK\x03\x04") || bytes.first() == Some(&0x80)) {
        let message = format!(
            "checkpoint {} is a PyTorch file (torch.save), not safetensors: convert it with \
             `nerf import-torch {} --config CONFIG --out FILE.safetensors`",
            path.display(),
            path.display()
        );
        return Err(CheckpointError::format(path, message).into());
    }
    let corrupt = |e: safetensors::SafeTensorError| {
        let message = format!(
            "checkpoint {} is corrupt or not safetensors: {e}",
            path.display()
        );
        CheckpointError::format(path, message)
    };
    let (_, header) = safetensors::SafeTensors::read_metadata(&bytes).map_err(corrupt)?;
    let st = safetensors::SafeTensors::deserialize(&bytes).map_err(corrupt)?;
    let meta = header.metadata().clone().unwrap_or_default();
    let info = CheckpointInfo {
        epoch: metadata_value(&meta, "epoch", path)?,
        adam_step: metadata_value(&meta, "adam_step", path)?,
        wall_seconds: metadata_value(&meta, "wall_seconds", path)?,
        step_in_epoch: metadata_value(&meta, "step_in_epoch", path)?,
        rng_word_pos: metadata_value(&meta, "rng_word_pos", path)?,
        rays_per_step: metadata_value(&meta, "rays_per_step", path)?,
        scene_transform: SCENE_TRANSFORM.read(&meta, path)?,
        capture_orbit: CAPTURE_ORBIT.read(&meta, path)?,
        capture_spiral: CAPTURE_SPIRAL.read(&meta, path)?,
        background: BACKGROUND.read(&meta, path)?,
        image_size: IMAGE_SIZE.read(&meta, path)?,
        sample_depths: SAMPLE_DEPTHS.read(&meta, path)?,
        object_box: OBJECT_BOX.read(&meta, path)?,
        field_layout: meta.get(FIELD_LAYOUT_KEY).cloned(),
    };
    info.validate(path)?;
    let mut tensors = HashMap::new();
    for (name, view) in st.tensors() {
        let values: Vec<f32> = match view.dtype() {
            safetensors::Dtype::F32 => view
                .data()
                .chunks_exact(4)
                .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                .collect(),
            safetensors::Dtype::F16 => view
                .data()
                .chunks_exact(2)
                .map(|b| half::f16::from_le_bytes([b[0], b[1]]).to_f32())
                .collect(),
            other => {
                let message = format!(
                    "checkpoint {}: tensor {name} is {other:?}, expected F32 or F16",
                    path.display()
                );
                return Err(CheckpointError::format(path, message).into());
            }
        };
        ensure_finite_values(path, &name, &values)?;
        tensors.insert(name, Tensor::from_vec(values, view.shape(), device)?);
    }
    Ok((tensors, info))
}

/// An error naming the file and tensor ([`CheckpointError::NonFinite`]) when any of `values` is
/// NaN or infinite: such a weight makes the ReLU density NaN, which the occupancy grid then
/// reads as empty space and renders as black, silently.
pub(crate) fn ensure_finite_values(
    origin: &Path,
    name: &str,
    values: &[f32],
) -> Result<(), CheckpointError> {
    let bad = values.iter().filter(|v| !v.is_finite()).count();
    if bad > 0 {
        return Err(CheckpointError::NonFinite {
            path: origin.to_path_buf(),
            name: name.to_string(),
            count: bad,
            message: format!(
                "{}: tensor {name} has {bad} non-finite values (NaN or inf) of {}",
                origin.display(),
                values.len()
            ),
        });
    }
    Ok(())
}

/// The model parameters of `varmap`, by name, sorted.
pub fn model_tensors(varmap: &VarMap) -> Vec<(String, Tensor)> {
    let data = varmap.data().lock().expect("varmap lock");
    let mut v: Vec<(String, Tensor)> = data
        .iter()
        .map(|(k, var)| (k.clone(), var.as_tensor().clone()))
        .collect();
    v.sort_by(|a, b| a.0.cmp(&b.0));
    v
}

/// The largest safetensors header [`read_metadata`] reads (safetensors' own limit).
const MAX_HEADER_BYTES: u64 = 100_000_000;

/// The metadata of the safetensors checkpoint at `path`, read from its header alone (the
/// tensors are not read). An error names a missing file ([`CheckpointError::NotFound`]) or one
/// that is not safetensors ([`CheckpointError::Format`]).
pub fn read_metadata(path: &Path) -> Result<HashMap<String, String>, CheckpointError> {
    use std::io::Read;
    let corrupt = |why: &str| {
        let message = format!(
            "checkpoint {} is corrupt or not safetensors: {why}",
            path.display()
        );
        CheckpointError::format(path, message)
    };
    let mut file = std::fs::File::open(path).map_err(|e| CheckpointError::unreadable(path, e))?;
    let mut length = [0u8; 8];
    file.read_exact(&mut length)
        .map_err(|_| corrupt("shorter than a header"))?;
    let length = u64::from_le_bytes(length);
    let file_length = file
        .metadata()
        .map_err(|e| CheckpointError::unreadable(path, e))?
        .len();
    if length > MAX_HEADER_BYTES || length > file_length.saturating_sub(8) {
        return Err(corrupt("its header length does not fit"));
    }
    let mut header = vec![0u8; length as usize];
    file.read_exact(&mut header)
        .map_err(|_| corrupt("a short header"))?;
    let header: serde_json::Value =
        serde_json::from_slice(&header).map_err(|e| corrupt(&e.to_string()))?;
    let Some(meta) = header.get("__metadata__") else {
        return Ok(HashMap::new());
    };
    serde_json::from_value(meta.clone()).map_err(|e| corrupt(&format!("metadata: {e}")))
}

/// A metadata entry a checkpoint may store: its key and how its text reads.
pub struct StoredEntry<T> {
    /// The metadata key.
    pub key: &'static str,
    /// The value of the entry's text, or why it is not one.
    pub parse: fn(&str) -> Result<T>,
}

/// The scene normalisation a capture's model was trained in.
pub const SCENE_TRANSFORM: StoredEntry<SceneTransform> = StoredEntry {
    key: SCENE_TRANSFORM_KEY,
    parse: SceneTransform::from_text,
};
/// The orbit `nerf render` and `nerf view` show a capture's model from.
pub const CAPTURE_ORBIT: StoredEntry<CaptureOrbit> = StoredEntry {
    key: CAPTURE_ORBIT_KEY,
    parse: CaptureOrbit::from_text,
};
/// The spiral in front of a forward-facing capture.
pub const CAPTURE_SPIRAL: StoredEntry<CaptureSpiral> = StoredEntry {
    key: CAPTURE_SPIRAL_KEY,
    parse: CaptureSpiral::from_text,
};
/// The background colour (three numbers in [0, 1]).
pub const BACKGROUND: StoredEntry<[f32; 3]> = StoredEntry {
    key: BACKGROUND_KEY,
    parse: background_from_text,
};
/// The training image size (two whole numbers, 1 to `MAX_STORED_SIDE`).
pub const IMAGE_SIZE: StoredEntry<(usize, usize)> = StoredEntry {
    key: IMAGE_SIZE_KEY,
    parse: image_size_from_text,
};

/// The sampler's depth range (two finite numbers, 0 ≤ near < far).
pub const SAMPLE_DEPTHS: StoredEntry<(f64, f64)> = StoredEntry {
    key: SAMPLE_DEPTHS_KEY,
    parse: depths_from_text,
};

/// The box an object's model was fitted to (six finite numbers, each min below its max).
pub const OBJECT_BOX: StoredEntry<[f64; 6]> = StoredEntry {
    key: OBJECT_BOX_KEY,
    parse: object_box_from_text,
};

impl<T> StoredEntry<T> {
    /// The entry's value in the metadata `meta` of the checkpoint at `path`; `None` when
    /// there is none, an error naming the key ([`CheckpointError::Metadata`]) when it does not
    /// read.
    pub fn read(
        &self,
        meta: &HashMap<String, String>,
        path: &Path,
    ) -> Result<Option<T>, CheckpointError> {
        let key = self.key;
        meta.get(key)
            .map(|text| {
                (self.parse)(text).map_err(|e| {
                    let message = format!("checkpoint {}: bad metadata {key}: {e}", path.display());
                    CheckpointError::metadata(path, key, message)
                })
            })
            .transpose()
    }
}

/// The whitespace-separated numbers of `text`; an error saying it expected `what`.
fn numbers<T: std::str::FromStr>(text: &str, what: &str) -> Result<Vec<T>> {
    text.split_whitespace()
        .map(|t| t.parse::<T>())
        .collect::<std::result::Result<_, _>>()
        .map_err(|_| anyhow::anyhow!("expected {what}"))
}

/// `r g b`, each in [0, 1].
fn background_from_text(text: &str) -> Result<[f32; 3]> {
    let what = "three numbers in [0, 1]";
    match numbers::<f32>(text, what)?[..] {
        [r, g, b] if [r, g, b].iter().all(|c| (0.0..=1.0).contains(c)) => Ok([r, g, b]),
        _ => bail!("expected {what}"),
    }
}

/// `near far`, finite, with 0 ≤ near < far.
fn depths_from_text(text: &str) -> Result<(f64, f64)> {
    let what = "two depths, 0 <= near < far";
    match numbers::<f64>(text, what)?[..] {
        [near, far] if near >= 0.0 && far > near && far.is_finite() => Ok((near, far)),
        _ => bail!("expected {what}"),
    }
}

/// `min_x min_y min_z max_x max_y max_z`: finite, at most [`MAX_BOX_COORDINATE`] from the
/// origin, each min below its max.
fn object_box_from_text(text: &str) -> Result<[f64; 6]> {
    let what = "a box: min x, y, z then max x, y, z, each min < max";
    let v: [f64; 6] = numbers::<f64>(text, what)?
        .try_into()
        .map_err(|_| anyhow::anyhow!("expected {what}"))?;
    let finite = v.iter().all(|x| x.abs() <= MAX_BOX_COORDINATE);
    ensure!(finite && (0..3).all(|k| v[k] < v[k + 3]), "expected {what}");
    Ok(v)
}

/// `width height`, each 1 to [`MAX_STORED_SIDE`].
fn image_size_from_text(text: &str) -> Result<(usize, usize)> {
    let side = 1..=MAX_STORED_SIDE;
    match numbers::<usize>(text, "a width and a height")?[..] {
        [w, h] if side.contains(&w) && side.contains(&h) => Ok((w, h)),
        _ => bail!("expected a width and a height, each 1 to {MAX_STORED_SIDE}"),
    }
}

/// The metadata entry `key` of the checkpoint at `path` parsed as a `T`, its default (0)
/// when absent; an error naming the key when it does not parse.
fn metadata_value<T: std::str::FromStr + Default>(
    meta: &HashMap<String, String>,
    key: &str,
    path: &Path,
) -> Result<T, CheckpointError> {
    match meta.get(key) {
        None => Ok(T::default()),
        Some(v) => v.parse().map_err(|_| {
            let message = format!("checkpoint {}: bad metadata {key}", path.display());
            CheckpointError::metadata(path, key, message)
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{DMat3, DVec3};

    #[test]
    fn the_scene_transform_is_stored_and_read_back_exactly() {
        let (_dir, path) = nerf_files::test_files::temp_file("ck.safetensors");
        let w = Tensor::new(&[1.0f32, 2.0], &Device::Cpu).unwrap();
        let transform = SceneTransform {
            rotation: DMat3::from_axis_angle(DVec3::new(1.0, 2.0, 3.0).normalize(), 0.7),
            center: DVec3::new(0.1, -2.0 / 3.0, 5.0),
            scale: 1.0 / 7.0,
        };
        let info = CheckpointInfo {
            epoch: 3,
            scene_transform: Some(transform),
            background: Some([0.25, 1.0, 0.0]),
            image_size: Some((640, 360)),
            sample_depths: Some((0.7, 1.3125)),
            object_box: Some([-0.25, -0.5, 0.125, 0.75, 0.5, 0.625]),
            field_layout: Some("hash grid of 2 levels".to_string()),
            ..CheckpointInfo::default()
        };
        save(&path, &[("w".to_string(), w.clone())], info.clone()).unwrap();
        let (_, read) = load(&path, &Device::Cpu).unwrap();
        assert_eq!(read, info);
        let meta = read_metadata(&path).unwrap();
        assert_eq!(SCENE_TRANSFORM.read(&meta, &path).unwrap(), Some(transform));
        // Without one (a NeRF-synthetic run), none is written or read.
        save(&path, &[("w".to_string(), w)], CheckpointInfo::default()).unwrap();
        assert!(!read_metadata(&path)
            .unwrap()
            .contains_key(SCENE_TRANSFORM_KEY));
        assert_eq!(load(&path, &Device::Cpu).unwrap().1.scene_transform, None);
        // A bad one names the key.
        let bad: HashMap<String, String> =
            [(SCENE_TRANSFORM_KEY.to_string(), "1 2 3".to_string())].into();
        let err = SCENE_TRANSFORM.read(&bad, &path).unwrap_err().to_string();
        assert!(
            err.contains(SCENE_TRANSFORM_KEY) && err.contains("13"),
            "{err}"
        );
        // Depths that are no range are refused.
        for text in ["1.3 0.7", "-1 2", "0.5", "0.5 inf"] {
            let bad: HashMap<String, String> =
                [(SAMPLE_DEPTHS_KEY.to_string(), text.to_string())].into();
            assert!(SAMPLE_DEPTHS.read(&bad, &path).is_err(), "{text}");
        }
        // So are boxes that are no box, or lie past any camera's frame.
        for text in [
            "0 0 0 1 1",
            "0 0 0 1 1 0",
            "0 0 0 1 1 NaN",
            "0 0 0 1 1 1e9",
            "a b c d e f",
        ] {
            let bad: HashMap<String, String> =
                [(OBJECT_BOX_KEY.to_string(), text.to_string())].into();
            let err = OBJECT_BOX.read(&bad, &path).unwrap_err().to_string();
            assert!(err.contains(OBJECT_BOX_KEY), "{text}: {err}");
        }
        // A file that is not safetensors is named.
        std::fs::write(&path, b"hello").unwrap();
        assert!(read_metadata(&path)
            .unwrap_err()
            .to_string()
            .contains("corrupt"));
    }
}
