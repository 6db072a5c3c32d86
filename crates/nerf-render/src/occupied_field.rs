//! A field seen through an occupancy grid. The grid is kept apart from the fields (as
//! nerfacc keeps its estimators apart from radiance fields): a field kind knows nothing of
//! it, training updates it from the field's density ([`OccupancyGrid::update`] takes the
//! density as a function), and it is paired with a field only to render, so that the
//! renderer skips the samples it marks empty.

use std::ops::Deref;
use std::sync::Arc;

use anyhow::Result;
use candle_core::Tensor;

use crate::field::{Field, FieldFastPaths, FieldOutput};
use crate::occupancy::OccupancyGrid;
use crate::sampler::RaySamples;

/// `field`, rendered through `grid`: everything is the field's but [`Field::occupancy`].
/// `F` is a pointer to a field (a `Box<dyn Field>`, an `Arc`, a reference).
#[derive(Debug, Clone)]
pub struct OccupiedField<F> {
    /// The field.
    pub field: F,
    /// Where the field can have density.
    pub grid: Arc<OccupancyGrid>,
}

impl<F> Field for OccupiedField<F>
where
    F: Deref,
    F::Target: Field,
{
    fn evaluate(
        &self,
        samples: &RaySamples,
        deltas: &Tensor,
        directions: &Tensor,
    ) -> Result<FieldOutput> {
        self.field.evaluate(samples, deltas, directions)
    }

    fn for_cameras(&self, camera_index: &Tensor) -> Result<Option<Box<dyn Field + '_>>> {
        Ok(self.field.for_cameras(camera_index)?.map(|field| {
            Box::new(OccupiedField {
                field,
                grid: self.grid.clone(),
            }) as Box<dyn Field + '_>
        }))
    }

    fn occupancy(&self) -> Option<&OccupancyGrid> {
        Some(&self.grid)
    }

    fn density(&self, points: &Tensor) -> Result<Tensor> {
        self.field.density(points)
    }

    fn fast_paths(&self) -> Option<&dyn FieldFastPaths> {
        self.field.fast_paths()
    }
}
