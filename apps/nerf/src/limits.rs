//! Upper limits on the sizes of the command's own outputs (meshes, point clouds), so that a
//! typo such as an extra zero is a one-line error naming the option instead of an allocation
//! that exhausts memory, and the pieces its jobs work in. The limits a config file's keys
//! are held to are the config's (`nerf::config::limits`).

/// Most marching-cubes cells per side of `nerf export mesh`: 513³ density samples, 0.5 GiB
/// held as one grid (the field is evaluated into it [`GRID_BATCH`] points at a time, and
/// the mesher reads it in place, welding each cube's triangles as it goes).
pub(crate) const MESH_RESOLUTION: usize = 512;
/// Most triangles of a mesh (about 1 GiB for the mesh, its welding table and its colours
/// at this size); a field noisy enough to need more is refused before the PLY is written,
/// asking for a higher threshold or a lower resolution.
pub(crate) const MESH_FACES: usize = 1 << 24;
/// Most rays (views × pixels) of `nerf export points`, checked before anything is rendered:
/// the cloud is held until it is written, 24 bytes a point (at most 3 GiB).
pub(crate) const POINT_CLOUD_RAYS: usize = 1 << 27;

// Working memory. Whatever the sizes above, every job works through its images, sample
// sets and grids in pieces whose intermediate tensors stay within about 1 GiB, so that
// what a job holds at once is its outputs (the frames, the grid, the mesh) plus that:
// * the renderer evaluates at most `Field::max_samples_per_chunk` samples at once (each
//   field kind answers for its own), and, when it skips samples, draws at most
//   `nerf::render::renderer::DRAWN_SAMPLES_PER_CHUNK`;
// * an image's rays are made, rendered and turned into pixels [`BAND_RAYS`] at a time (the
//   vis images, the depth points and the mesh's colour rays too);
// * `point_vis`'s sample points are made and splatted [`POINT_SAMPLES`] at a time;
// * a mesh grid is evaluated [`GRID_BATCH`] points at a time.
// The environment variable `NERF_WORK_CHUNK=N` lowers every one of these pieces to N items
// (rays, points) for tests of chunking; the outputs do not depend on it. The peaks at the
// largest sizes: docs/reliability.md#working-memory-at-the-largest-sizes.

/// Rays per band of an image (rounded to whole renderer chunks where rendered): 2^18 rays
/// are about 60 MB of rays, pixels and outputs, on top of the renderer's chunk.
pub(crate) const BAND_RAYS: usize = nerf::render::bands::BAND_RAYS;
/// Sample points of `point_vis` made and splatted at once (2^22: about 100 MB).
pub(crate) const POINT_SAMPLES: usize = 1 << 22;
/// Grid points of a mesh grid evaluated at once.
pub(crate) const GRID_BATCH: usize = 1 << 16;
