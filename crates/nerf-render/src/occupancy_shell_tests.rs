//! Tests of the cells an occupancy grid keeps empty (around the cameras) and keeps occupied
//! (a contracted grid's far shell), through updates and a save.

use super::*;

#[test]
fn a_kept_far_shell_stays_occupied_and_is_saved_so() {
    let params = |contraction| OccupancyGridParams {
        resolution: 4,
        aabb: [-2.0, -2.0, -2.0, 2.0, 2.0, 2.0],
        density_threshold: 0.5,
        contraction,
    };
    for contraction in [Contraction::None, Contraction::LInf] {
        let mut grid = OccupancyGrid::new(&params(contraction)).unwrap();
        grid.density = vec![0.0; grid.n_cells()];
        grid.refresh_occupied();
        assert!(
            grid.occupied.iter().all(|o| !o),
            "not kept: nothing occupied"
        );
        grid.keep_far_shell();
        for cell in 0..grid.n_cells() {
            let i = [cell / 16, (cell / 4) % 4, cell % 4];
            let outer = i.iter().any(|&k| k == 0 || k == 3);
            assert_eq!(grid.is_far_shell(cell), outer, "cell {cell}");
            // Empty density: only a contracted grid's outer layer is kept occupied.
            let expected = outer && contraction == Contraction::LInf;
            assert_eq!(grid.occupied[cell], expected, "{contraction:?} cell {cell}");
        }
        assert!(!grid.any_dense_cell(), "{contraction:?}");
        // 4³ − 2³ cells in the shell.
        let shell = (0..grid.n_cells())
            .filter(|&c| grid.is_far_shell(c))
            .count();
        assert_eq!(shell, 64 - 8);
        // A saved grid read back (eval, render) keeps the shell without being told.
        let back = OccupancyGrid::from_tensor(
            &params(contraction),
            &grid.to_tensor(&Device::Cpu).unwrap(),
        )
        .unwrap();
        assert_eq!(back.occupied, grid.occupied, "{contraction:?}");
        assert_eq!(back.far_shell_kept, grid.far_shell_kept, "{contraction:?}");
    }
    // The shell does not raise the threshold of the cells inside it: a cell just above
    // the mean of the inside stays occupied, saved and read back too.
    let mut grid = OccupancyGrid::new(&params(Contraction::LInf)).unwrap();
    grid.density = vec![0.0; grid.n_cells()];
    let inner = (0..grid.n_cells())
        .find(|&c| !grid.is_far_shell(c))
        .unwrap();
    grid.density[inner] = 0.1;
    grid.keep_far_shell();
    assert!(grid.occupied[inner] && grid.any_dense_cell());
    let back = OccupancyGrid::from_tensor(
        &params(Contraction::LInf),
        &grid.to_tensor(&Device::Cpu).unwrap(),
    )
    .unwrap();
    assert!(back.occupied[inner] && back.far_shell_kept);
}

#[test]
fn cells_around_cameras_stay_empty_through_updates_and_a_save() {
    let params = OccupancyGridParams {
        resolution: 8,
        aabb: [-2.0, -2.0, -2.0, 2.0, 2.0, 2.0],
        density_threshold: 0.5,
        contraction: Contraction::LInf,
    };
    let mut grid = OccupancyGrid::new(&params).unwrap();
    // A camera 1.5 from the origin: cells within 0.75 of it are kept empty.
    let camera = [1.5, 0.0, 0.0];
    let kept = grid.clear_around_cameras(&[camera], 0.5);
    assert!(kept > 0 && kept < grid.n_cells());
    for cell in 0..grid.n_cells() {
        let p = grid.point_in_cell(cell, [0.5; 3]).map(f64::from);
        let d2: f64 = (0..3).map(|k| (p[k] - camera[k]).powi(2)).sum();
        assert_eq!(grid.kept_empty[cell], d2 < 0.75 * 0.75, "cell {cell}");
        assert_eq!(grid.occupied[cell], !grid.kept_empty[cell], "cell {cell}");
    }
    // Dense everywhere: every other cell becomes occupied, the kept ones stay empty.
    let dense = |p: &Tensor| -> Result<Tensor> { Ok(p.ones_like()?.narrow(1, 0, 1)?) };
    let mut rng = rand::rngs::StdRng::seed_from_u64(1);
    use rand::SeedableRng;
    grid.update(&dense, true, 0.9, &mut rng, &Device::Cpu)
        .unwrap();
    let occupied = grid.occupied.iter().filter(|o| **o).count();
    assert_eq!(occupied, grid.n_cells() - kept);
    // A saved grid read back (as eval reads it) keeps them empty.
    let back = OccupancyGrid::from_tensor(&params, &grid.to_tensor(&Device::Cpu).unwrap());
    assert_eq!(back.unwrap().occupied, grid.occupied);
    // Nothing is cleared at fraction 0.
    let mut fresh = OccupancyGrid::new(&params).unwrap();
    assert_eq!(fresh.clear_around_cameras(&[camera], 0.0), 0);
    assert!(fresh.occupied.iter().all(|o| *o));
}
