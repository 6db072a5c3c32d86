//! The dataset splits (train, val, test): the NeRF-synthetic release's file of each, and the
//! names a command line and a config use.

use std::fmt;
use std::path::{Path, PathBuf};
use std::str::FromStr;

use anyhow::{anyhow, Result};

/// A dataset split, naming `transforms_{split}.json` and the `{split}/` image folder.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Split {
    /// `train`: the training views.
    Train,
    /// `val`: the validation views.
    Val,
    /// `test`: the test views.
    Test,
}

impl Split {
    /// Every split, in the order of the reference camera file (train, val, test).
    pub(crate) const ALL: [Split; 3] = [Split::Train, Split::Val, Split::Test];

    /// `"train"`, `"val"` or `"test"`.
    pub fn name(self) -> &'static str {
        match self {
            Split::Train => "train",
            Split::Val => "val",
            Split::Test => "test",
        }
    }

    /// `transforms_{split}.json` inside `data_dir`.
    pub(crate) fn transforms_path(self, data_dir: &Path) -> PathBuf {
        data_dir.join(format!("transforms_{}.json", self.name()))
    }
}

impl fmt::Display for Split {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Split {
    type Err = anyhow::Error;

    fn from_str(s: &str) -> Result<Self> {
        Split::ALL
            .into_iter()
            .find(|split| split.name() == s)
            .ok_or_else(|| anyhow!("unknown dataset split {s:?} (expected train, val or test)"))
    }
}
