//! The external programs that `nerf process` runs (COLMAP, ffmpeg): whether one is there, with
//! a one-line error that says how it was looked for and how to install it.

use std::path::Path;
use std::process::{Command, Stdio};

use anyhow::{bail, Result};

/// An external program: how messages name it, the environment variable that points at it,
/// and its Debian package (also its executable's name).
pub struct ExternalTool {
    /// As messages name it ("COLMAP").
    pub name: &'static str,
    /// The variable that names its executable instead of `PATH`.
    pub env: &'static str,
    /// Its Debian package and executable.
    pub package: &'static str,
}

impl ExternalTool {
    /// Runs `command` (a cheap call of `program`, such as `ffmpeg -version`, its output
    /// discarded) to check that the program is there; the error is one line.
    pub fn check(&self, mut command: Command, program: &Path) -> Result<()> {
        let run = command
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .status();
        let Err(e) = run else {
            return Ok(());
        };
        let (name, env, package) = (self.name, self.env, self.package);
        let which = match std::env::var_os(env).filter(|v| !v.is_empty()) {
            Some(_) => format!("{env}={}", program.display()),
            None => format!("`{}` on PATH", program.display()),
        };
        bail!(
            "{name} is missing: cannot run {which} ({e}); install it with `sudo apt-get install \
             {package}` (Debian/Ubuntu) or set {env} to the {package} executable"
        )
    }
}
