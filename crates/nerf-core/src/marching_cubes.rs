//! Marching cubes: the surface where a scalar field sampled on a regular grid crosses a level.
//!
//! The cube cases and their triangles are the `mcubes` crate's
//! (`crate::marching_tables`). Cubes are visited in the grid, in place, and each cube's
//! triangles are welded into the mesh as they are made: the copies that neighbouring cubes make
//! of the same edge crossing become one vertex (positions quantised to 1/1024 of a cell), the
//! triangles that welding makes degenerate are dropped, and each vertex gets the area-weighted
//! normal of its triangles. Memory: the grid, the mesh and its welding table.

use std::collections::HashMap;

use anyhow::{ensure, Result};

use crate::marching_tables::{
    case_triangles, crossed_edges, CUBE_CORNER_OFFSETS, EDGE_VERTEX_PAIRS,
};

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
    pub(crate) fn validate(&self) -> Result<()> {
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
pub(crate) fn normalize(v: [f32; 3]) -> Option<[f32; 3]> {
    let len = v.iter().map(|c| c * c).sum::<f32>().sqrt();
    (len > 0.0 && len.is_finite()).then(|| v.map(|c| c / len))
}

/// The triangles of the surface `value = level` of `grid`, with the region `value > level`
/// inside (a density above a threshold; pass `−sdf` for a signed distance). An error, before
/// any more memory is taken, once the mesh would have more than `max_faces` triangles.
///
/// The grid is read in place, cube by cube (x slowest, z fastest), and each triangle is welded
/// into the mesh as it is made, so that besides the grid only the mesh and its welding table
/// are held. The triangles, their order and their vertices' positions are those of the
/// `mcubes` crate's `InsideOnly` mesh (its tables, loop order and arithmetic), welded.
pub fn marching_cubes(grid: &VolumeGrid, level: f32, max_faces: usize) -> Result<TriMesh> {
    grid.validate()?;
    ensure!(level.is_finite(), "the surface level must be finite");
    let [nx, ny, nz] = grid.dims;
    let cell = grid.cell();
    let mut welder = Welder {
        mesh: TriMesh::default(),
        index_of: HashMap::new(),
        aabb: grid.aabb,
        cell,
    };
    let cubes = CubeSurfaces::new(grid, level);
    for x in 0..nx - 1 {
        for y in 0..ny - 1 {
            for z in 0..nz - 1 {
                cubes.triangles([x, y, z], |corners| welder.add(corners));
                ensure!(
                    welder.mesh.faces.len() <= max_faces,
                    "the mesh has more than {max_faces} triangles at this level; raise the \
                     threshold or lower the resolution"
                );
            }
        }
    }
    let mut mesh = welder.mesh;
    mesh.normals = vertex_normals(&mesh.vertices, &mesh.faces, grid);
    Ok(mesh)
}

/// The surface's triangles in one cube of a grid, as the `mcubes` crate makes them.
struct CubeSurfaces<'a> {
    grid: &'a VolumeGrid,
    level: f32,
    /// World units per grid step along each axis (the crate's `size / sampling_interval`).
    scale: [f32; 3],
}

impl<'a> CubeSurfaces<'a> {
    fn new(grid: &'a VolumeGrid, level: f32) -> Self {
        let [nx, ny, nz] = grid.dims;
        let steps = [nx - 1, ny - 1, nz - 1];
        let scale = std::array::from_fn(|a| (grid.aabb[a + 3] - grid.aabb[a]) / steps[a] as f32);
        Self { grid, level, scale }
    }

    fn value(&self, [x, y, z]: [usize; 3]) -> f32 {
        let [nx, ny, _] = self.grid.dims;
        self.grid.values[x + y * nx + z * nx * ny]
    }

    /// Calls `emit` with the three corners of each triangle of cube `cube` (its lowest grid
    /// point), in the tables' order.
    fn triangles(&self, cube: [usize; 3], mut emit: impl FnMut([[f32; 3]; 3])) {
        let corner = |i: usize| {
            let (dx, dy, dz) = CUBE_CORNER_OFFSETS[i];
            [cube[0] + dx, cube[1] + dy, cube[2] + dz]
        };
        let values: [f32; 8] = std::array::from_fn(|i| self.value(corner(i)));
        let case = (0..8)
            .filter(|&i| values[i] < self.level)
            .fold(0usize, |c, i| c | 1 << i);
        let edges = crossed_edges(case);
        if edges == 0 {
            return;
        }
        let mut crossing = [[0f32; 3]; 12];
        for (e, &(a, b)) in EDGE_VERTEX_PAIRS.iter().enumerate() {
            if edges & (1 << e) == 0 {
                continue;
            }
            let (pa, pb) = (corner(a), corner(b));
            let mu = (self.level - values[a]) / (values[b] - values[a]);
            crossing[e] = std::array::from_fn(|k| {
                let (ca, cb) = (pa[k] as f32 * self.scale[k], pb[k] as f32 * self.scale[k]);
                ca + (cb - ca) * mu + self.grid.aabb[k]
            });
        }
        for tri in case_triangles(case) {
            emit(tri.map(|e| crossing[e as usize]));
        }
    }
}

/// A mesh built a triangle at a time, with the copies that neighbouring cubes make of one edge
/// crossing welded into one vertex.
struct Welder {
    mesh: TriMesh,
    /// Vertex of each quantised position (grid units × 1024).
    index_of: HashMap<[i64; 3], u32>,
    aabb: [f32; 6],
    cell: [f32; 3],
}

impl Welder {
    /// Adds a triangle, unless welding makes it degenerate.
    fn add(&mut self, corners: [[f32; 3]; 3]) {
        // Grid units, quantised: copies of one edge crossing differ by float rounding only.
        let keys = corners.map(|p| {
            std::array::from_fn(|a| {
                (((p[a] - self.aabb[a]) / self.cell[a]) * 1024.0).round() as i64
            })
        });
        if keys[0] == keys[1] || keys[1] == keys[2] || keys[0] == keys[2] {
            return;
        }
        let face = [0, 1, 2].map(|c| {
            *self.index_of.entry(keys[c]).or_insert_with(|| {
                self.mesh.vertices.push(corners[c]);
                (self.mesh.vertices.len() - 1) as u32
            })
        });
        self.mesh.faces.push(face);
    }
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
        let mesh = marching_cubes(&sphere_grid(33, 0.7), 0.0, usize::MAX).unwrap();
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

    /// The mesh as the `mcubes` crate makes it (three vertices per triangle), welded as
    /// [`Welder`] does: the reference the in-place walk must match.
    fn crate_mesh(grid: &VolumeGrid, level: f32) -> TriMesh {
        let [nx, ny, nz] = grid.dims;
        let extent = [0, 1, 2].map(|a| grid.aabb[a + 3] - grid.aabb[a]);
        let mc = mcubes::MarchingCubes::new(
            (nx, ny, nz),
            (extent[0], extent[1], extent[2]),
            ((nx - 1) as f32, (ny - 1) as f32, (nz - 1) as f32),
            lin_alg::f32::Vec3::new(grid.aabb[0], grid.aabb[1], grid.aabb[2]),
            grid.values.clone(),
            level,
        )
        .unwrap();
        let raw = mc.generate(mcubes::MeshSide::InsideOnly);
        let mut welder = Welder {
            mesh: TriMesh::default(),
            index_of: HashMap::new(),
            aabb: grid.aabb,
            cell: grid.cell(),
        };
        for tri in raw.indices.chunks_exact(3) {
            welder.add([0, 1, 2].map(|c| {
                let p = raw.vertices[tri[c]].posit;
                [p.x, p.y, p.z]
            }));
        }
        welder.mesh
    }

    #[test]
    fn the_walk_in_place_gives_the_crates_mesh_bit_for_bit() {
        // A lumpy field on a box that is not a cube, so that every case and axis is exercised.
        let mut grid = sphere_grid(23, 0.6);
        grid.dims = [23, 23, 23];
        grid.aabb = [-1.3, -0.7, 0.1, 0.9, 1.4, 2.3];
        for (i, v) in grid.values.iter_mut().enumerate() {
            *v += 0.3 * ((i as f32 * 0.37).sin() * (i as f32 * 0.011).cos());
        }
        for level in [0.0, 0.2, -0.35] {
            let ours = marching_cubes(&grid, level, usize::MAX).unwrap();
            let theirs = crate_mesh(&grid, level);
            assert!(ours.faces.len() > 1000, "{} faces", ours.faces.len());
            assert_eq!(ours.faces, theirs.faces, "level {level}");
            let bits = |v: &[[f32; 3]]| -> Vec<[u32; 3]> {
                v.iter().map(|p| p.map(f32::to_bits)).collect()
            };
            assert_eq!(
                bits(&ours.vertices),
                bits(&theirs.vertices),
                "level {level}"
            );
        }
    }

    #[test]
    fn a_mesh_over_the_face_limit_is_refused() {
        let grid = sphere_grid(17, 0.7);
        let n = marching_cubes(&grid, 0.0, usize::MAX).unwrap().faces.len();
        assert!(marching_cubes(&grid, 0.0, n).is_ok());
        let e = marching_cubes(&grid, 0.0, n - 1).unwrap_err().to_string();
        assert!(e.contains(&format!("more than {} triangles", n - 1)), "{e}");
    }

    #[test]
    fn empty_field_gives_no_triangles_and_bad_grids_are_refused() {
        let empty = marching_cubes(&sphere_grid(5, -1.0), 0.0, usize::MAX).unwrap();
        assert!(empty.faces.is_empty() && empty.vertices.is_empty());
        let mut g = sphere_grid(4, 0.5);
        g.values[3] = f32::NAN;
        assert!(marching_cubes(&g, 0.0, usize::MAX).is_err());
        let mut g = sphere_grid(4, 0.5);
        g.dims = [1, 16, 4];
        assert!(marching_cubes(&g, 0.0, usize::MAX).is_err());
        assert!(marching_cubes(&sphere_grid(4, 0.5), f32::NAN, usize::MAX).is_err());
    }
}
