//! [`ConfigError`]: why a config cannot be found, read or used.

use std::path::{Path, PathBuf};

use nerf_core::error_chain;
use nerf_core::term::error_line;

/// Why a config cannot be found, read or used. Returned by [`crate::Config::load`],
/// [`crate::Config::from_yaml`], [`crate::apply_override`] and
/// [`crate::config_text`].
///
/// Every variant but [`ConfigError::Other`] holds the fields a caller tells cases apart by
/// and `message`, the one-line text the error displays (as the `nerf` binary prints it,
/// including where the bad value came from: `config FILE, line N: …` or ``override `…`: …``);
/// it has no source, so printing the chain prints it once.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// `--config NAME_OR_PATH` names no file, no `configs/NAME.yaml` and no built-in config.
    #[error("{message}")]
    NotFound {
        /// The name or path given.
        name: String,
        /// The one-line message (listing the built-in configs for a name).
        message: String,
    },
    /// The file is there but is no config file: a directory, a FIFO or device, larger than
    /// [`crate::yaml_bounds::MAX_YAML_BYTES`], not UTF-8, or unreadable.
    #[error("{message}")]
    Unreadable {
        /// The file.
        path: PathBuf,
        /// The one-line message.
        message: String,
    },
    /// The text is not a config's YAML: malformed, a top level that is not a mapping of
    /// sections, or nested or sized past [`crate::yaml_bounds`].
    #[error("{message}")]
    Syntax {
        /// The one-line message.
        message: String,
    },
    /// A key with a bad value: of the wrong type, out of range, unknown, or missing.
    #[error("{message}")]
    Invalid {
        /// The key's dotted path (`sampler.n_pts_per_ray`, `data.image_size[0]`; `config` for
        /// the top level).
        key: String,
        /// The one-line message: where the value came from, the key, and what is wrong.
        message: String,
    },
    /// A `key.sub=value` override that does not parse or cannot be applied (not of that form,
    /// an empty key, a value that is not YAML, a key under a value that is not a section).
    #[error("{message}")]
    Override {
        /// The override as given.
        assignment: String,
        /// The one-line message, ``override `key=value`: `` and what is wrong with it.
        message: String,
    },
    /// Anything else (a rule between several keys, ...), with its chain of causes as it was.
    #[error(transparent)]
    Other(anyhow::Error),
}

impl ConfigError {
    /// [`ConfigError::Unreadable`] about `path`, with `error`'s whole chain as the message.
    pub(crate) fn unreadable(path: &Path, error: &anyhow::Error) -> Self {
        let (path, message) = (path.to_path_buf(), error_line(error.as_ref()));
        Self::Unreadable { path, message }
    }

    /// [`ConfigError::Invalid`] when `message` starts with a dotted key (letters, digits, `_`,
    /// `.` and `[i]`) and `": "`, as the config's checks word their errors; else `None`.
    pub(crate) fn keyed(message: &str) -> Option<Self> {
        let (key, _) = message.split_once(": ")?;
        let is_key = key.starts_with(|c: char| c.is_ascii_alphabetic() || c == '_')
            && key
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || "_.[]".contains(c));
        is_key.then(|| Self::Invalid {
            key: key.to_string(),
            message: message.to_string(),
        })
    }

    /// The typed error in `error`'s chain (its message then the whole chain's line, when
    /// context was added around it), else a keyed message as [`ConfigError::Invalid`] (see
    /// [`ConfigError::keyed`]; the key is looked for in the innermost cause), else
    /// [`ConfigError::Other`] holding `error` as it is.
    pub(crate) fn from_anyhow(error: anyhow::Error) -> Self {
        let error = match error_chain::take::<Self>(error, |e| !matches!(e, Self::Other(_))) {
            Ok((typed, None)) => return typed,
            Ok((typed, Some(line))) => return typed.with_message(line),
            Err(error) => error,
        };
        let line = error_line(error.as_ref());
        match Self::keyed(&error.root_cause().to_string()) {
            Some(Self::Invalid { key, .. }) => Self::Invalid { key, message: line },
            _ => Self::Other(error),
        }
    }

    /// The same error with `line` as its message.
    fn with_message(mut self, line: String) -> Self {
        match &mut self {
            Self::NotFound { message, .. }
            | Self::Unreadable { message, .. }
            | Self::Syntax { message }
            | Self::Invalid { message, .. }
            | Self::Override { message, .. } => *message = line,
            Self::Other(_) => {}
        }
        self
    }
}
