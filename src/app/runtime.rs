//! Names kept from when the config's runtime conversions lived here: the shipped checkpoints
//! and [`plural`]. Each config section now converts itself beside its schema in
//! [`crate::app::config`] (the `sampler` section into the sampler, the `renderer` section into
//! the renderer, the `implicit_function` section into its field in
//! [`crate::app::config::field_section`]), and checkpoint paths are
//! [`crate::app::config::checkpoint_paths`]'s.

pub use crate::app::config::checkpoint_paths::{
    HOMEWORK_CHECKPOINT, SHIPPED_CHECKPOINT, SHIPPED_NGP_CHECKPOINT,
};
pub use crate::app::config::messages::plural;
