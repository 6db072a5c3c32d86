//! Marching cubes' cube cases: the corners of a cube, its edges, and for each of the 256
//! inside/outside patterns of the corners the edges the surface crosses and the triangles it
//! makes there. The triangles are the `mcubes` crate's (Paul Bourke's tables, "Polygonising a
//! scalar field", 1994), read from the crate once, by meshing each pattern on a single cube,
//! rather than copied: [`crate::marching_cubes`] walks the grid in place and welds as it
//! goes, and its meshes stay what the crate gives. The corner and edge order is the crate's.

use std::sync::OnceLock;

/// The 8 corners of a cube as offsets `(dx, dy, dz)` from its lowest corner.
pub(crate) const CUBE_CORNER_OFFSETS: [(usize, usize, usize); 8] = [
    (0, 0, 0),
    (1, 0, 0),
    (1, 1, 0),
    (0, 1, 0),
    (0, 0, 1),
    (1, 0, 1),
    (1, 1, 1),
    (0, 1, 1),
];

/// The 12 edges of a cube as pairs of corners.
pub(crate) const EDGE_VERTEX_PAIRS: [(usize, usize); 12] = [
    (0, 1),
    (1, 2),
    (2, 3),
    (3, 0),
    (4, 5),
    (5, 6),
    (6, 7),
    (7, 4),
    (0, 4),
    (1, 5),
    (2, 6),
    (3, 7),
];

/// The edges the surface crosses in corner pattern `case` (bit `i` set when corner `i` is
/// below the level): bit `e` set for each edge `e` whose two corners are on either side.
pub(crate) fn crossed_edges(case: usize) -> u16 {
    let side = |corner: usize| case >> corner & 1;
    (EDGE_VERTEX_PAIRS.iter().enumerate())
        .filter(|(_, &(a, b))| side(a) != side(b))
        .fold(0, |edges, (e, _)| edges | 1 << e)
}

/// The triangles of corner pattern `case` as triples of edges (each vertex is where the
/// surface crosses that edge), in the crate's order and winding.
pub(crate) fn case_triangles(case: usize) -> &'static [[u8; 3]] {
    static CASES: OnceLock<Vec<Vec<[u8; 3]>>> = OnceLock::new();
    &CASES.get_or_init(|| (0..256).map(triangles_from_crate).collect())[case]
}

/// The triangles the crate makes on one unit cube whose corners in `case` hold 0 and the
/// others 1, at level 0.5: every vertex is then the middle of its edge, which names the edge.
fn triangles_from_crate(case: usize) -> Vec<[u8; 3]> {
    // The crate's grid order: x fastest.
    let values = (0..8)
        .map(|j| {
            let offset = (j & 1, j >> 1 & 1, j >> 2 & 1);
            let corner = CUBE_CORNER_OFFSETS.iter().position(|&c| c == offset);
            let below = corner.is_some_and(|i| case >> i & 1 == 1);
            if below {
                0.0
            } else {
                1.0
            }
        })
        .collect();
    let origin = lin_alg::f32::Vec3::new(0.0, 0.0, 0.0);
    let cube = mcubes::MarchingCubes::new(
        (2, 2, 2),
        (1.0, 1.0, 1.0),
        (1.0, 1.0, 1.0),
        origin,
        values,
        0.5,
    )
    .expect("a 2×2×2 grid of 8 values");
    let mesh = cube.generate(mcubes::MeshSide::InsideOnly);
    let edge_at = |p: lin_alg::f32::Vec3| {
        // Twice the middle of an edge: the sum of its corners' offsets.
        let twice = [p.x, p.y, p.z].map(|v| (2.0 * v).round() as usize);
        let sum = |(a, b): (usize, usize)| {
            let (ca, cb) = (CUBE_CORNER_OFFSETS[a], CUBE_CORNER_OFFSETS[b]);
            [ca.0 + cb.0, ca.1 + cb.1, ca.2 + cb.2]
        };
        let edge = EDGE_VERTEX_PAIRS
            .iter()
            .position(|&pair| sum(pair) == twice);
        edge.expect("a crate vertex at the middle of an edge") as u8
    };
    mesh.indices
        .chunks_exact(3)
        .map(|t| [0, 1, 2].map(|c| edge_at(mesh.vertices[t[c]].posit)))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_case_has_triangles_on_just_its_crossed_edges() {
        for case in 0..256 {
            let used = (case_triangles(case).iter().flatten()).fold(0u16, |m, &e| m | 1 << e);
            // Every crossed edge is a vertex of some triangle, and no other edge is.
            assert_eq!(used, crossed_edges(case), "case {case}");
            // The complement pattern crosses the same edges.
            assert_eq!(crossed_edges(255 - case), used);
        }
        assert!(case_triangles(0).is_empty() && case_triangles(255).is_empty());
        // One corner apart: a single triangle.
        assert_eq!(case_triangles(1).len(), 1);
        // Bourke's table has 820 triangles over the 256 cases (as the copy this module held
        // until it read them from the crate).
        let triangles: usize = (0..256).map(|case| case_triangles(case).len()).sum();
        assert_eq!(triangles, 820);
    }
}
