//! Binary PLY files (little-endian, the layout MeshLab, Blender, Open3D and nerfstudio read):
//! meshes with per-vertex normals and colours, and coloured point clouds. Written atomically.
//!
//! Hand-written: the header is a few lines of text and the body packed numbers, which is less
//! code than filling a general PLY crate's property maps (`ply-rs` is unmaintained; its fork
//! would add a parser generator to the build for a format we only write).

use std::io::Write;
use std::path::Path;

use anyhow::{ensure, Result};

use crate::output::write_atomically;
use nerf_core::image::to_byte;
use nerf_core::marching_cubes::TriMesh;

/// The header of a binary PLY with `vertices` vertices (x, y, z; nx, ny, nz when `normals`;
/// red, green, blue) and `faces` triangles (none when 0).
fn header(vertices: usize, normals: bool, faces: usize) -> String {
    let mut h = String::from("ply\nformat binary_little_endian 1.0\ncomment written by nerf\n");
    h += &format!("element vertex {vertices}\n");
    h += "property float x\nproperty float y\nproperty float z\n";
    if normals {
        h += "property float nx\nproperty float ny\nproperty float nz\n";
    }
    h += "property uchar red\nproperty uchar green\nproperty uchar blue\n";
    if faces > 0 {
        h += &format!("element face {faces}\nproperty list uchar int vertex_indices\n");
    }
    h + "end_header\n"
}

/// Writes `points` with `(R, G, B)` colours in `[0, 1]` (one per point) as a binary PLY point
/// cloud.
pub fn write_points_ply(path: &Path, points: &[[f32; 3]], colors: &[[f32; 3]]) -> Result<()> {
    ensure!(
        points.len() == colors.len(),
        "{} points but {} colours",
        points.len(),
        colors.len()
    );
    write_atomically(path, |w| {
        w.write_all(header(points.len(), false, 0).as_bytes())?;
        for (p, c) in points.iter().zip(colors) {
            for v in p {
                w.write_all(&v.to_le_bytes())?;
            }
            w.write_all(&c.map(to_byte))?;
        }
        Ok(())
    })
}

/// Writes `mesh` (positions, normals, triangles) with `(R, G, B)` vertex colours in `[0, 1]`
/// as a binary PLY.
pub fn write_mesh_ply(path: &Path, mesh: &TriMesh, colors: &[[f32; 3]]) -> Result<()> {
    let n = mesh.vertices.len();
    ensure!(
        mesh.normals.len() == n && colors.len() == n,
        "{n} vertices but {} normals and {} colours",
        mesh.normals.len(),
        colors.len()
    );
    ensure!(
        mesh.faces.iter().flatten().all(|&i| (i as usize) < n),
        "a face refers to a vertex past the {n} there are"
    );
    write_atomically(path, |w| {
        w.write_all(header(n, true, mesh.faces.len()).as_bytes())?;
        for ((p, nrm), c) in mesh.vertices.iter().zip(&mesh.normals).zip(colors) {
            for v in p.iter().chain(nrm) {
                w.write_all(&v.to_le_bytes())?;
            }
            w.write_all(&c.map(to_byte))?;
        }
        for f in &mesh.faces {
            w.write_all(&[3])?;
            for i in f {
                w.write_all(&(*i as i32).to_le_bytes())?;
            }
        }
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mesh_file_has_header_and_packed_body() {
        let (_dir, path) = crate::test_files::temp_file("t.ply");
        let mesh = TriMesh {
            vertices: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
            normals: vec![[0.0, 0.0, 1.0]; 3],
            faces: vec![[0, 1, 2]],
        };
        write_mesh_ply(&path, &mesh, &[[1.0, 0.0, 0.5]; 3]).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        let h = header(3, true, 1);
        assert!(bytes.starts_with(h.as_bytes()));
        let body = &bytes[h.len()..];
        // 3 vertices of 6 floats and 3 bytes, one face of 1 + 3·4 bytes.
        assert_eq!(body.len(), 3 * 27 + 13);
        // Vertex 1 starts at byte 27 with x = 1.0.
        assert_eq!(&body[27..31], &1.0f32.to_le_bytes());
        assert_eq!(&body[24..27], &[255, 0, 127]);
        assert_eq!(&body[81..], &[3, 0, 0, 0, 0, 1, 0, 0, 0, 2, 0, 0, 0]);
    }

    #[test]
    fn mismatched_or_out_of_range_input_writes_nothing() {
        let (dir, path) = crate::test_files::temp_file("t.ply");
        assert!(write_points_ply(&path, &[[0.0; 3]], &[]).is_err());
        let mesh = TriMesh {
            vertices: vec![[0.0; 3]],
            normals: vec![[0.0, 0.0, 1.0]],
            faces: vec![[0, 1, 2]],
        };
        assert!(write_mesh_ply(&path, &mesh, &[[0.0; 3]]).is_err());
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
    }
}
