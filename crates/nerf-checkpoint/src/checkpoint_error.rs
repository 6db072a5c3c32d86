//! [`CheckpointError`]: why a checkpoint cannot be found, read, or loaded into a model.

use std::path::{Path, PathBuf};

use nerf_core::error_chain;
use nerf_core::term::error_line;

/// Why a checkpoint cannot be found or read. Returned by [`crate::checkpoint::load`],
/// [`crate::checkpoint::read_metadata`] and the metadata readers beside it,
/// [`crate::checkpoint_file::load`], [`crate::checkpoint_file::detect_format`], the
/// path rule ([`crate::checkpoint_file::resolve_for`] and its kin),
/// [`crate::torch::read_torch_checkpoint`], and
/// `nerf::train::model::TrainModel::from_checkpoint` / `nerf::train::model::TrainModel::load`,
/// which render, eval, view and export open checkpoints with.
///
/// Every variant but [`CheckpointError::Other`] holds the fields a caller tells cases apart by
/// and `message`, the one-line text the error displays (as the `nerf` binary prints it, context
/// included); it has no source, so printing the chain prints it once.
#[derive(Debug, thiserror::Error)]
pub enum CheckpointError {
    /// Nothing at the path, or a directory that holds no checkpoint.
    #[error("{message}")]
    NotFound {
        /// The path looked at.
        path: PathBuf,
        /// The one-line message.
        message: String,
    },
    /// A directory holding several checkpoints where one is wanted.
    #[error("{message}")]
    Ambiguous {
        /// The directory.
        dir: PathBuf,
        /// The checkpoints it holds.
        found: Vec<PathBuf>,
        /// The one-line message.
        message: String,
    },
    /// Not a checkpoint this crate reads: neither safetensors nor a PyTorch file, corrupt or
    /// truncated, a PyTorch file where only safetensors is read, a tensor of a dtype other than
    /// f32 or f16, or not a regular file.
    #[error("{message}")]
    Format {
        /// The file.
        path: PathBuf,
        /// The one-line message.
        message: String,
    },
    /// A parameter the model needs is not in the checkpoint.
    #[error("{message}")]
    MissingParameter {
        /// The checkpoint.
        path: PathBuf,
        /// The parameter's name (`mlp_xyz.mlp.0.0.weight`, ...).
        name: String,
        /// The one-line message.
        message: String,
    },
    /// A parameter whose shape is not the model's.
    #[error("{message}")]
    Shape {
        /// The checkpoint.
        path: PathBuf,
        /// The parameter's name.
        name: String,
        /// The shape the model (the config) needs.
        expected: Vec<usize>,
        /// The shape in the checkpoint.
        found: Vec<usize>,
        /// The one-line message.
        message: String,
    },
    /// A tensor holding NaN or infinite values.
    #[error("{message}")]
    NonFinite {
        /// The checkpoint.
        path: PathBuf,
        /// The tensor's name.
        name: String,
        /// How many of its values are not finite.
        count: usize,
        /// The one-line message.
        message: String,
    },
    /// A metadata entry that does not read, or a count past what a run can have
    /// ([`crate::checkpoint::metadata_limits`]).
    #[error("{message}")]
    Metadata {
        /// The checkpoint.
        path: PathBuf,
        /// The metadata key (`epoch`, `scene_transform`, ...).
        key: String,
        /// The one-line message.
        message: String,
    },
    /// Anything else (a file that exists but cannot be read, a device error), with its chain
    /// of causes as it was.
    #[error(transparent)]
    Other(anyhow::Error),
}

impl CheckpointError {
    /// [`CheckpointError::NotFound`] with its message.
    pub fn not_found(path: &Path, message: String) -> Self {
        let path = path.to_path_buf();
        Self::NotFound { path, message }
    }

    /// [`CheckpointError::Format`] with its message.
    pub(crate) fn format(path: &Path, message: String) -> Self {
        let path = path.to_path_buf();
        Self::Format { path, message }
    }

    /// [`CheckpointError::Metadata`] for `key` with its message.
    pub fn metadata(path: &Path, key: &str, message: String) -> Self {
        let (path, key) = (path.to_path_buf(), key.to_string());
        Self::Metadata { path, key, message }
    }

    /// The error of reading the checkpoint file `path`, which failed with `error`: a missing
    /// file is [`CheckpointError::NotFound`], any other [`CheckpointError::Other`]; the text is
    /// `cannot read checkpoint PATH` and the cause.
    pub(crate) fn unreadable(path: &Path, error: std::io::Error) -> Self {
        let context = format!("cannot read checkpoint {}", path.display());
        match error.kind() {
            std::io::ErrorKind::NotFound => Self::not_found(path, format!("{context}: {error}")),
            _ => Self::Other(anyhow::Error::new(error).context(context)),
        }
    }

    /// The typed error in `error`'s chain (its message then the whole chain's line, when
    /// context was added around it), else [`CheckpointError::Other`] holding `error` as it is.
    pub fn from_anyhow(error: anyhow::Error) -> Self {
        match error_chain::take::<Self>(error, |e| !matches!(e, Self::Other(_))) {
            Ok((typed, None)) => typed,
            Ok((typed, Some(line))) => typed.with_message(line),
            Err(error) => Self::Other(error),
        }
    }

    /// The same error with `line` as its message.
    fn with_message(mut self, line: String) -> Self {
        match &mut self {
            Self::NotFound { message, .. }
            | Self::Ambiguous { message, .. }
            | Self::Format { message, .. }
            | Self::MissingParameter { message, .. }
            | Self::Shape { message, .. }
            | Self::NonFinite { message, .. }
            | Self::Metadata { message, .. } => *message = line,
            Self::Other(_) => {}
        }
        self
    }
}

/// `error` as a [`CheckpointError::Format`] about `path` (its whole chain as the message), unless
/// it is a typed checkpoint error already.
pub(crate) fn format_unless_typed(path: &Path, error: anyhow::Error) -> CheckpointError {
    match CheckpointError::from_anyhow(error) {
        CheckpointError::Other(error) => CheckpointError::format(path, error_line(error.as_ref())),
        typed => typed,
    }
}
