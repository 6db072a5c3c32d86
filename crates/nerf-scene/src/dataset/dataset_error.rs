//! [`DatasetError`]: why a scene folder cannot be read as a dataset, whatever its format
//! (NeRF-synthetic, nerfstudio or instant-ngp, LLFF, COLMAP).

use std::path::{Path, PathBuf};

use nerf_core::camera::CameraError;
use nerf_core::error_chain;
use nerf_core::term::error_line;
use nerf_files::bounded_read::read_regular_file;

/// Why a scene folder cannot be read as a dataset. Returned by [`super::read_split`],
/// [`super::read_split_with`], `super::read_blender_split`, [`super::parse_split`],
/// [`super::read_capture_split`], [`super::read_capture_split_with`] and
/// [`super::Dataset::load`] (and its `load_first*` kin).
///
/// Every variant but [`DatasetError::Other`] holds the fields a caller tells cases apart by
/// and `message`, the one-line text the error displays (as the `nerf` binary prints it,
/// naming the file, and the frame where there is one); it has no source, so printing the
/// chain prints it once.
#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    /// The folder holds no dataset this crate reads, does not exist, or is a file (or a
    /// NeRF-synthetic folder was given where a capture is read).
    #[error("{message}")]
    NoDataset {
        /// The folder.
        dir: PathBuf,
        /// The one-line message (what a dataset folder holds, and where to get lego).
        message: String,
    },
    /// A file the dataset needs is not there: a split's `transforms_{split}.json`, a photo or
    /// mask a frame lists, or a capture's `images/` folder.
    #[error("{message}")]
    MissingFile {
        /// The file or folder.
        path: PathBuf,
        /// The one-line message.
        message: String,
    },
    /// A photo that cannot be used: not PNG or JPEG, one that does not decode or is past the
    /// decoder's limits, or one of another size than the split's first.
    #[error("{message}")]
    Photo {
        /// The photo.
        path: PathBuf,
        /// The one-line message.
        message: String,
    },
    /// A frame's camera that cannot be right ([`CameraError`]). `camera` is not the error's
    /// `source()`: its text ends `message` already.
    #[error("{message}")]
    Camera {
        /// What is wrong with the camera.
        camera: CameraError,
        /// The one-line message: the file, the frame, and the camera's error.
        message: String,
    },
    /// A file describing the dataset that does not read: JSON that does not parse or holds a
    /// key of a bad value, a frame listed twice or in no split, a malformed `poses_bounds.npy`
    /// or COLMAP model, or one that lists no frames.
    #[error("{message}")]
    Metadata {
        /// The file (or, for a COLMAP model, the capture folder).
        path: PathBuf,
        /// The one-line message.
        message: String,
    },
    /// Anything else (a link out of the capture, cameras that give the scene no scale, an
    /// empty split, ...), with its chain of causes as it was.
    #[error(transparent)]
    Other(anyhow::Error),
}

impl DatasetError {
    /// [`DatasetError::NoDataset`] with its message.
    pub(crate) fn no_dataset(dir: &Path, message: String) -> Self {
        Self::NoDataset {
            dir: dir.to_path_buf(),
            message,
        }
    }

    /// [`DatasetError::MissingFile`] with its message.
    pub(crate) fn missing_file(path: &Path, message: String) -> Self {
        Self::MissingFile {
            path: path.to_path_buf(),
            message,
        }
    }

    /// [`DatasetError::Photo`] with its message.
    pub(crate) fn photo(path: &Path, message: String) -> Self {
        Self::Photo {
            path: path.to_path_buf(),
            message,
        }
    }

    /// [`DatasetError::Metadata`] with its message.
    pub(crate) fn metadata(path: &Path, message: String) -> Self {
        Self::Metadata {
            path: path.to_path_buf(),
            message,
        }
    }

    /// The typed error in `error`'s chain (its message then the whole chain's line, when
    /// context was added around it); else, when the chain holds a [`CameraError`],
    /// [`DatasetError::Camera`] with the whole chain's line; else [`DatasetError::Other`]
    /// holding `error` as it is.
    pub(crate) fn from_anyhow(error: anyhow::Error) -> Self {
        let error = match error_chain::take::<Self>(error, |e| !matches!(e, Self::Other(_))) {
            Ok((typed, None)) => return typed,
            Ok((typed, Some(line))) => return typed.with_message(line),
            Err(error) => error,
        };
        match camera_error_in(&error) {
            Some(camera) => {
                let message = error_line(error.as_ref());
                Self::Camera { camera, message }
            }
            None => Self::Other(error),
        }
    }

    /// The same error with `line` as its message.
    fn with_message(mut self, line: String) -> Self {
        match &mut self {
            Self::NoDataset { message, .. }
            | Self::MissingFile { message, .. }
            | Self::Photo { message, .. }
            | Self::Camera { message, .. }
            | Self::Metadata { message, .. } => *message = line,
            Self::Other(_) => {}
        }
        self
    }
}

/// The [`CameraError`] in `error`'s chain, if any.
fn camera_error_in(error: &anyhow::Error) -> Option<CameraError> {
    error
        .chain()
        .find_map(|c| c.downcast_ref::<CameraError>())
        .cloned()
}

/// `error`, about the file `path` that describes the dataset, as a [`DatasetError::Metadata`]
/// with its whole chain as the message, unless it is about a camera (its chain holds a
/// [`CameraError`]) or typed already: then it is returned as it is.
pub(crate) fn metadata_unless_camera(path: &Path, error: anyhow::Error) -> anyhow::Error {
    let typed = error.chain().any(|c| c.is::<DatasetError>());
    if typed || camera_error_in(&error).is_some() {
        return error;
    }
    DatasetError::metadata(path, error_line(error.as_ref())).into()
}

/// The bytes of the dataset's file `path` ([`read_regular_file`], `what` naming it); a file
/// that is not there is a [`DatasetError::MissingFile`], with the reader's message.
pub(crate) fn read_dataset_file(
    path: &Path,
    what: &str,
    max_bytes: u64,
) -> anyhow::Result<Vec<u8>> {
    read_regular_file(path, what, max_bytes).map_err(|e| {
        let missing =
            std::fs::metadata(path).is_err_and(|m| m.kind() == std::io::ErrorKind::NotFound);
        match missing {
            true => DatasetError::missing_file(path, error_line(e.as_ref())).into(),
            false => e,
        }
    })
}
