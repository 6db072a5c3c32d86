//! Marching cubes: the surface where a scalar field sampled on a regular grid crosses a level.
//!
//! The cube cases and triangle tables come from the `mcubes` crate. It emits three fresh
//! vertices per triangle, so this module welds the copies that neighbouring cubes make of the
//! same edge crossing (positions quantised to 1/1024 of a cell), drops the triangles that
//! welding makes degenerate, and gives each vertex the area-weighted normal of its triangles.

use std::collections::HashMap;

use anyhow::{ensure, Result};

/// A scalar field sampled at the points of a regular grid.
///
/// `values[i + nx·(j + ny·k)]` is the value at `aabb_min + (i, j, k) · cell`, where
/// `cell = (aabb_max − aabb_min) / (dims − 1)`: x varies fastest.
#[derive(Debug, Clone)]
pub struct VolumeGrid {
    /// Grid points per axis `(nx, ny, nz)`, each at least 2.
    pub dims: [usize; 3],
    /// `[min_x, min_y, min_z, max_x, max_y, max_z]`: the first and last grid points.
    pub aabb: [f32; 6],
    /// `nx·ny·nz` values, x fastest.
    pub values: Vec<f32>,
}

impl VolumeGrid {
    /// Distance between neighbouring grid points along each axis.
    pub fn cell(&self) -> [f32; 3] {
        std::array::from_fn(|a| (self.aabb[a + 3] - self.aabb[a]) / (self.dims[a] - 1) as f32)
    }

    /// World position of grid point `(i, j, k)`.
    pub fn point(&self, i: usize, j: usize, k: usize) -> [f32; 3] {
        let cell = self.cell();
        let idx = [i, j, k];
        std::array::from_fn(|a| self.aabb[a] + idx[a] as f32 * cell[a])
    }

    /// Checks the shape, the box and that every value is finite.
    pub fn validate(&self) -> Result<()> {
        ensure!(
            self.dims.iter().all(|&n| n >= 2),
            "a marching-cubes grid needs at least 2 points per axis (got {:?})",
            self.dims
        );
        ensure!(
            (0..3).all(|a| self.aabb[a] < self.aabb[a + 3]),
            "grid box must have min < max on every axis (got {:?})",
            self.aabb
        );
        ensure!(
            self.values.len() == self.dims.iter().product::<usize>(),
            "grid has {} values, dims {:?} need {}",
            self.values.len(),
            self.dims,
            self.dims.iter().product::<usize>()
        );
        ensure!(
            self.values.iter().all(|v| v.is_finite()),
            "the sampled field has a NaN or infinite value"
        );
        Ok(())
    }
}

/// An indexed triangle mesh.
#[derive(Debug, Clone, Default)]
pub struct TriMesh {
    /// Vertex positions.
    pub vertices: Vec<[f32; 3]>,
    /// Unit vertex normals, pointing from where the field is above the level to where it is
    /// below (out of a dense object).
    pub normals: Vec<[f32; 3]>,
    /// Triangles as vertex indices, counter-clockwise seen from the side the normals face.
    pub faces: Vec<[u32; 3]>,
}

fn sub(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn cross(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// `v / |v|`, or `None` for a zero or non-finite vector.
pub fn normalize(v: [f32; 3]) -> Option<[f32; 3]> {
    let len = v.iter().map(|c| c * c).sum::<f32>().sqrt();
    (len > 0.0 && len.is_finite()).then(|| v.map(|c| c / len))
}

/// The triangles of the surface `value = level` of `grid`, with the region `value > level`
/// inside (a density above a threshold; pass `−sdf` for a signed distance).
pub fn marching_cubes(grid: &VolumeGrid, level: f32) -> Result<TriMesh> {
    grid.validate()?;
    ensure!(level.is_finite(), "the surface level must be finite");
    let [nx, ny, nz] = grid.dims;
    let cell = grid.cell();
    let extent = [0, 1, 2].map(|a| grid.aabb[a + 3] - grid.aabb[a]);
    let mc = mcubes::MarchingCubes::new(
        (nx, ny, nz),
        (extent[0], extent[1], extent[2]),
        ((nx - 1) as f32, (ny - 1) as f32, (nz - 1) as f32),
        lin_alg::f32::Vec3::new(grid.aabb[0], grid.aabb[1], grid.aabb[2]),
        grid.values.clone(),
        level,
    )?;
    // `InsideOnly` keeps the tables' own winding, counter-clockwise seen from the low side
    // (`OutsideOnly` flips it); the sphere test checks every face.
    let raw = mc.generate(mcubes::MeshSide::InsideOnly);
    let mut mesh = TriMesh::default();
    let mut index_of: HashMap<[i64; 3], u32> = HashMap::new();
    for tri in raw.indices.chunks_exact(3) {
        let corners = [0, 1, 2].map(|c| {
            let p = raw.vertices[tri[c]].posit;
            [p.x, p.y, p.z]
        });
        // Grid units, quantised: copies of one edge crossing differ by float rounding only.
        let keys = corners.map(|p| {
            std::array::from_fn(|a| (((p[a] - grid.aabb[a]) / cell[a]) * 1024.0).round() as i64)
        });
        if keys[0] == keys[1] || keys[1] == keys[2] || keys[0] == keys[2] {
            continue;
        }
        let face = [0, 1, 2].map(|c| {
            *index_of.entry(keys[c]).or_insert_with(|| {
                mesh.vertices.push(corners[c]);
                (mesh.vertices.len() - 1) as u32
            })
        });
        mesh.faces.push(face);
    }
    mesh.normals = vertex_normals(&mesh.vertices, &mesh.faces, grid);
    Ok(mesh)
}

/// Area-weighted sums of the faces' normals, normalised. A vertex whose faces cancel out (or
/// have no area) gets the direction from the grid's centre instead, so every normal is a unit
/// vector.
fn vertex_normals(vertices: &[[f32; 3]], faces: &[[u32; 3]], grid: &VolumeGrid) -> Vec<[f32; 3]> {
    let mut sums = vec![[0.0f32; 3]; vertices.len()];
    for f in faces {
        let [a, b, c] = f.map(|i| vertices[i as usize]);
        // |cross| is twice the area, so the sum is area-weighted.
        let n = cross(sub(b, a), sub(c, a));
        for &i in f {
            for (s, v) in sums[i as usize].iter_mut().zip(n) {
                *s += v;
            }
        }
    }
    let centre: [f32; 3] = std::array::from_fn(|a| 0.5 * (grid.aabb[a] + grid.aabb[a + 3]));
    sums.iter()
        .zip(vertices)
        .map(|(n, v)| {
            normalize(*n)
                .or_else(|| normalize(sub(*v, centre)))
                .unwrap_or([0.0, 0.0, 1.0])
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `r − |p|` on an `n³` grid over `[−1, 1]³`: positive inside a sphere of radius `r`.
    fn sphere_grid(n: usize, r: f32) -> VolumeGrid {
        let mut grid = VolumeGrid {
            dims: [n; 3],
            aabb: [-1.0, -1.0, -1.0, 1.0, 1.0, 1.0],
            values: Vec::with_capacity(n * n * n),
        };
        for k in 0..n {
            for j in 0..n {
                for i in 0..n {
                    let p = grid.point(i, j, k);
                    grid.values
                        .push(r - p.iter().map(|c| c * c).sum::<f32>().sqrt());
                }
            }
        }
        grid
    }

    #[test]
    fn sphere_surface_is_closed_outward_and_on_the_radius() {
        let mesh = marching_cubes(&sphere_grid(33, 0.7), 0.0).unwrap();
        assert!(
            mesh.vertices.len() > 500,
            "{} vertices",
            mesh.vertices.len()
        );
        for v in &mesh.vertices {
            let r = v.iter().map(|c| c * c).sum::<f32>().sqrt();
            // Linear interpolation of the exact distance puts vertices within a cell's
            // curvature error of the radius (cell 1/16).
            assert!((r - 0.7).abs() < 0.01, "vertex at radius {r}");
        }
        // Every face is counter-clockwise seen from outside, and normals point outwards.
        for f in &mesh.faces {
            let [a, b, c] = f.map(|i| mesh.vertices[i as usize]);
            let n = cross(sub(b, a), sub(c, a));
            assert!(n.iter().zip(a).map(|(x, y)| x * y).sum::<f32>() > 0.0);
        }
        for (n, v) in mesh.normals.iter().zip(&mesh.vertices) {
            assert!(n.iter().zip(v).map(|(x, y)| x * y).sum::<f32>() > 0.6);
        }
        // Closed and welded: every edge is shared by exactly two faces (V − E + F = 2).
        let mut edges = HashMap::new();
        for f in &mesh.faces {
            for (a, b) in [(f[0], f[1]), (f[1], f[2]), (f[2], f[0])] {
                *edges.entry((a.min(b), a.max(b))).or_insert(0) += 1;
            }
        }
        assert!(edges.values().all(|&c| c == 2));
        let euler = mesh.vertices.len() as i64 - edges.len() as i64 + mesh.faces.len() as i64;
        assert_eq!(euler, 2);
    }

    #[test]
    fn empty_field_gives_no_triangles_and_bad_grids_are_refused() {
        let empty = marching_cubes(&sphere_grid(5, -1.0), 0.0).unwrap();
        assert!(empty.faces.is_empty() && empty.vertices.is_empty());
        let mut g = sphere_grid(4, 0.5);
        g.values[3] = f32::NAN;
        assert!(marching_cubes(&g, 0.0).is_err());
        let mut g = sphere_grid(4, 0.5);
        g.dims = [1, 16, 4];
        assert!(marching_cubes(&g, 0.0).is_err());
        assert!(marching_cubes(&sphere_grid(4, 0.5), f32::NAN).is_err());
    }
}
