//! Finding a typed error in an `anyhow` chain: the library's internals return
//! `anyhow::Result` and add context with `.context`, and a boundary function turns what they
//! return into its typed error (`nerf::io::checkpoint::CheckpointError`,
//! `nerf::io::dataset::DatasetError`, `nerf::config::ConfigError`) with [`take`].

use crate::term::error_line;

/// The typed error `T` that `error` holds, when `wanted` accepts it: `Ok((typed, None))` when
/// it is the outermost error (nothing was added to it), `Ok((typed, Some(line)))` when context
/// was added around it, `line` being the whole chain's one-line message
/// ([`error_line`]) for the typed error to carry instead of its own; `Err(error)`, unchanged,
/// when there is none.
pub fn take<T>(
    error: anyhow::Error,
    wanted: impl Fn(&T) -> bool,
) -> Result<(T, Option<String>), anyhow::Error>
where
    T: std::error::Error + Send + Sync + 'static,
{
    let outermost = (*error).is::<T>();
    let found = error
        .chain()
        .find_map(|c| c.downcast_ref::<T>())
        .is_some_and(wanted);
    if !found {
        return Err(error);
    }
    let line = (!outermost).then(|| error_line(error.as_ref()));
    error.downcast::<T>().map(|typed| (typed, line))
}
