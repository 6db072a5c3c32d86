//! The mapping stage of `nerf process`: COLMAP's incremental mapper run once (COLMAP 4
//! through pycolmap) or several times (the COLMAP program) with different `--random_seed`s, the run the others agree with best kept as `colmap/sparse`
//! ([`super::consensus`]), the images the other runs place elsewhere named so
//! that `transforms.json` can leave them out, and the kept model refined: observations further
//! than [`MappingOptions::max_reprojection_error`] from their point's projection dropped
//! (`colmap point_filtering`), then one more global bundle adjustment (`colmap
//! bundle_adjuster`).
//!
//! Why refine after mapping instead of mapping with the tighter threshold: on the lego
//! views the mapper with `--Mapper.filter_max_reproj_error 1.5` gave the same accuracy but
//! took several times as long a run (fewer points left to register the next image on, so
//! many more failed registration attempts), and runs at 1 to 2 px sometimes flipped a camera
//! (measured: docs/own-scene.md#mapper-settings).
//!
//! Why several runs with the COLMAP program (3.8): its mapper's RANSAC draws at random, and on photos with few features
//! (such as the 100 lego views on white) one run in a few places a camera at its mirror pose
//! or bends a stretch of cameras, while its own statistics (reprojection error, track length)
//! look like every other run's. Three runs cost about what exhaustive matching does
//! (measured: docs/own-scene.md#mapper-settings).

use std::ffi::{OsStr, OsString};
use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};

use super::consensus::{consensus, Centres};
use crate::process::colmap_run::{last_line, run_stage, Colmap};
use nerf::core::camera::alignment::spread;
use nerf::core::camera::alignment::{align_centres, CameraPair};
use nerf::core::camera::ColmapPose;

/// A run that registered at least this fraction of the most any run registered is compared
/// with the others; fewer, and it is not a candidate.
pub const COMPARABLE_FRACTION: f64 = 0.9;

/// A camera that more than half of the other runs place further than this fraction of the
/// camera spread from where the kept run has it is left out: well above what agreeing runs
/// differ by, far below a flipped camera (measured: docs/own-scene.md#mapper-settings).
pub const OUTLIER_FRACTION: f64 = 0.05;

/// Runs added, one at a time, while no run has registered half of the photos, or fewer than
/// [`MAJORITY_RUNS`] runs (or all requested, if fewer) are comparable. The mapper is not
/// repeatable even for one seed (its RANSAC runs on several threads): a run can register none
/// of a capture where the others register most, and one that registers few can leave two
/// comparable runs that disagree, with no majority (measured:
/// docs/own-scene.md#mapper-settings).
pub const MAX_EXTRA_RUNS: u64 = 3;

/// Fewest registered images written as a capture (a kept model with fewer is not refined:
/// `bundle_adjuster` has too little to work on, and the capture is refused anyway).
pub const MIN_REGISTERED: usize = 3;

/// Comparable runs wanted for a majority to decide between them.
pub const MAJORITY_RUNS: u64 = 3;

/// Two comparable runs whose centres all agree to within this fraction of the camera spread
/// settle the mapping: no further run is made (above what agreeing runs differ by, below a
/// bent stretch of cameras or a flipped one; measured: docs/own-scene.md#mapper-settings).
pub const SETTLED_FRACTION: f64 = 0.02;

/// Mapper runs by default with COLMAP 4 through pycolmap: one run placed the temple ring's
/// cameras as the program's consensus of three did (measured:
/// docs/own-scene.md#structure-from-motion-measured); more are added when it registers fewer
/// than half of the photos ([`MAX_EXTRA_RUNS`]).
pub const PYCOLMAP_RUNS: u64 = 1;

/// Mapper runs by default with the COLMAP program (3.8), whose runs now and then flip or bend
/// cameras (see the module doc).
pub const PROGRAM_RUNS: u64 = 3;

/// How the mapper is run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MappingOptions {
    /// Most mapper runs (seeds 0, 1, ...) unless more are needed, at least 1; fewer when two
    /// agree ([`SETTLED_FRACTION`]). `None`: [`PYCOLMAP_RUNS`] with pycolmap,
    /// [`PROGRAM_RUNS`] with the COLMAP program.
    pub runs: Option<u64>,
    /// Pixels: after mapping, observations of the kept model further than this from their
    /// point's projection are dropped and the model is bundle-adjusted again.
    pub max_reprojection_error: f64,
}

impl Default for MappingOptions {
    /// The runs by COLMAP ([`MappingOptions::runs`]); observations kept within 1.5 px (COLMAP maps with 4 px: on the lego views
    /// the refinement at 1.5 px lowered both the mean and the largest camera-centre error, in
    /// seconds; measured: docs/own-scene.md#mapper-settings).
    fn default() -> Self {
        Self {
            runs: None,
            max_reprojection_error: 1.5,
        }
    }
}

/// One mapper run.
#[derive(Debug, Clone, PartialEq)]
pub struct MapperRun {
    /// Its `--random_seed`.
    pub seed: u64,
    /// Images in its largest model.
    pub registered: usize,
    /// Mean over the other compared runs of its largest centre disagreement with each, as a
    /// fraction of the camera spread; `None` when it was not compared.
    pub disagreement: Option<f64>,
    /// Wall-clock seconds.
    pub seconds: f64,
}

/// What [`map`] did.
#[derive(Debug, Clone, PartialEq)]
pub struct Mapping {
    /// Each run, in seed order.
    pub runs: Vec<MapperRun>,
    /// The index in `runs` of the run kept as `colmap/sparse`; `None` when no run registered
    /// any image.
    pub chosen: Option<usize>,
    /// Images of the kept run that the other runs place elsewhere, with their median
    /// disagreement (fraction of the camera spread), largest first.
    pub outliers: Vec<(String, f64)>,
    /// Seconds the refinement of the kept model took.
    pub refine_seconds: f64,
}

/// The mapper's thresholds, below COLMAP's defaults (100, 30, 16°, 0.25): with them the 100
/// lego views (few features each) register 100 of 100 instead of 10.
const MAPPER_THRESHOLDS: [&str; 8] = [
    "--Mapper.init_min_num_inliers",
    "30",
    "--Mapper.abs_pose_min_num_inliers",
    "15",
    "--Mapper.init_min_tri_angle",
    "4",
    "--Mapper.abs_pose_min_inlier_ratio",
    "0.1",
];

/// The folder run `seed` writes its models to, under `colmap`.
fn run_folder(colmap: &Path, seed: u64) -> PathBuf {
    colmap.join(format!("sparse_seed{seed}"))
}

/// The log of run `seed`, under `colmap`.
pub fn run_log(colmap: &Path, seed: u64) -> PathBuf {
    colmap.join(format!("mapper_seed{seed}.log"))
}

/// Camera centres by image name of the largest model under `dir` (empty when there is none).
fn centres_in(dir: &Path) -> Result<Centres> {
    if nerf::io::colmap::find_model_folder(dir).is_none() {
        return Ok(Centres::new());
    }
    Ok(poses_in(dir)?
        .into_iter()
        .map(|(name, pose)| (name, pose.center()))
        .collect())
}

/// Camera poses by image name of the largest model under `dir`.
fn poses_in(dir: &Path) -> Result<std::collections::BTreeMap<String, ColmapPose>> {
    let (_, model) = nerf::io::colmap::find_model(dir)?;
    model
        .images
        .iter()
        .map(|image| {
            let pose = ColmapPose::from_quaternion(image.qvec, image.tvec)
                .with_context(|| format!("COLMAP image {}", image.name))?;
            Ok((image.name.clone(), pose))
        })
        .collect()
}

/// Runs the mapper up to `options.runs` times (COLMAP's default when `None`) on `database` and `images` (`n` photos) into
/// `colmap/sparse_seed<k>` (logs `colmap/mapper_seed<k>.log`), stopping early once two runs
/// that registered half of the photos agree ([`SETTLED_FRACTION`]), and up to
/// [`MAX_EXTRA_RUNS`] more while no run has registered half of the photos or too few runs are
/// comparable (see [`MAX_EXTRA_RUNS`]); keeps the run the others agree
/// with best as `colmap/sparse` and removes the other runs' models. An error when a run
/// failed after writing a model (naming its log) or a folder cannot be moved; a run that
/// failed with no model registered nothing.
pub fn map(
    sfm: &Colmap,
    colmap: &Path,
    database: &Path,
    images: &Path,
    n: usize,
    options: &MappingOptions,
) -> Result<Mapping> {
    let pixels = options.max_reprojection_error;
    let requested = options.runs.unwrap_or(if sfm.is_pycolmap() {
        PYCOLMAP_RUNS
    } else {
        PROGRAM_RUNS
    });
    if requested == 0 || !pixels.is_finite() || pixels <= 0.0 {
        bail!(
            "the mapper needs at least one run and a positive reprojection error (got {} runs, {} px)",
            requested,
            options.max_reprojection_error
        );
    }
    let mut runs = Vec::new();
    let mut centres = Vec::new();
    for seed in 0..requested + MAX_EXTRA_RUNS {
        let best = runs
            .iter()
            .map(|r: &MapperRun| r.registered)
            .max()
            .unwrap_or(0);
        if 2 * best >= n && settled(&centres, best) {
            log::info!(
                "two mapper runs agree to within {:.0}% of the camera spread: no more runs",
                100.0 * SETTLED_FRACTION
            );
            break;
        }
        if seed >= requested {
            let comparable = runs
                .iter()
                .filter(|r| r.registered > 0)
                .filter(|r| r.registered as f64 >= COMPARABLE_FRACTION * best as f64)
                .count() as u64;
            let wanted = requested.min(MAJORITY_RUNS);
            if 2 * best >= n && comparable >= wanted {
                break;
            }
            log::info!(
                "{comparable} comparable mapper runs of {wanted} wanted, the best registering {best} of {n} photos: running it again (seed {seed})"
            );
        }
        let folder = run_folder(colmap, seed);
        std::fs::create_dir_all(&folder)
            .with_context(|| format!("cannot create {}", folder.display()))?;
        let seed_text = seed.to_string();
        let args: Vec<OsString> = [
            OsStr::new("--database_path"),
            database.as_os_str(),
            OsStr::new("--image_path"),
            images.as_os_str(),
            OsStr::new("--output_path"),
            folder.as_os_str(),
            OsStr::new("--random_seed"),
            OsStr::new(&seed_text),
        ]
        .into_iter()
        .chain(MAPPER_THRESHOLDS.iter().map(OsStr::new))
        .map(OsStr::to_os_string)
        .collect();
        let args: Vec<&OsStr> = args.iter().map(OsString::as_os_str).collect();
        let log = run_log(colmap, seed);
        let (status, seconds) = run_stage(sfm, "mapper", &args, &log, n as u64)?;
        let run_centres = centres_in(&folder)?;
        if !status.success() && !run_centres.is_empty() {
            bail!(
                "COLMAP's mapper failed ({status}): see {} (its last line: {})",
                log.display(),
                last_line(&log)
            );
        }
        log::info!(
            "COLMAP mapper, seed {seed}: {} of {n} images registered in {seconds:.1} s",
            run_centres.len()
        );
        runs.push(MapperRun {
            seed,
            registered: run_centres.len(),
            disagreement: None,
            seconds,
        });
        centres.push(run_centres);
    }
    let Some(agreed) = consensus(&centres, COMPARABLE_FRACTION, OUTLIER_FRACTION) else {
        return Ok(Mapping {
            runs,
            chosen: None,
            outliers: Vec::new(),
            refine_seconds: 0.0,
        });
    };
    for (run, score) in runs.iter_mut().zip(&agreed.scores) {
        run.disagreement = *score;
    }
    let scores: Vec<String> = runs
        .iter()
        .map(|r| match r.disagreement {
            Some(d) => format!("seed {} {:.2}%", r.seed, 100.0 * d),
            None => format!("seed {} not compared", r.seed),
        })
        .collect();
    log::info!(
        "kept the mapper run of seed {} (each run's largest camera disagreement with the others, averaged, as a share of the camera spread: {})",
        runs[agreed.chosen].seed,
        scores.join(", ")
    );
    if agreed.split {
        log::warn!(
            "the mapper runs disagree on most cameras (no majority to name a misplaced one): kept seed {}'s cameras as they are; check the result, or run again with more --mapper-runs",
            runs[agreed.chosen].seed
        );
    }
    let seeds: Vec<u64> = runs.iter().map(|r| r.seed).collect();
    keep_run(colmap, &seeds, runs[agreed.chosen].seed)?;
    let refine_seconds = if runs[agreed.chosen].registered >= MIN_REGISTERED {
        refine(sfm, colmap, options.max_reprojection_error)?
    } else {
        0.0
    };
    Ok(Mapping {
        runs,
        chosen: Some(agreed.chosen),
        outliers: agreed.outliers,
        refine_seconds,
    })
}

/// Whether two of `centres` (each run's), both registering at least [`COMPARABLE_FRACTION`] of
/// `best`, place every camera they share within [`SETTLED_FRACTION`] of the spread of each
/// other.
fn settled(centres: &[Centres], best: usize) -> bool {
    let comparable: Vec<&Centres> = centres
        .iter()
        .filter(|c| !c.is_empty() && c.len() as f64 >= COMPARABLE_FRACTION * best as f64)
        .collect();
    comparable.iter().enumerate().any(|(i, a)| {
        comparable[i + 1..].iter().any(|b| {
            super::consensus::disagreement(a, b)
                .is_some_and(|d| d.iter().all(|e| e.1 <= SETTLED_FRACTION))
        })
    })
}

/// The lens model of the final bundle adjustment with COLMAP 4: after the adjustment with the
/// mapper's own lens (`SIMPLE_RADIAL`, [`crate::process::PYCOLMAP_CAMERA_MODEL`]), the
/// cameras become `OPENCV` (two focals, two radial and two tangential terms, the added ones
/// starting at zero) and are adjusted again with the principal point refined. The richer lens
/// is kept unless it turned a camera more than [`MAX_LENS_TURN_DEGREES`] or moved one more
/// than [`MAX_LENS_SHIFT`] of the cameras' spread (then it had too little to fit on: few
/// features, a narrow field of view). Mapping with `OPENCV` from the start lost most of the
/// temple ring; refined from a finished reconstruction it brought Herz-Jesu and the fox
/// closer to their references
/// (docs/own-scene.md#structure-from-motion-measured).
pub const FINAL_CAMERA_MODEL: &str = "OPENCV";

/// The richer lens is kept only when no camera turned more than this many degrees against
/// the plain adjustment ([`FINAL_CAMERA_MODEL`]).
pub const MAX_LENS_TURN_DEGREES: f64 = 1.0;

/// The richer lens is kept only when no camera moved more than this fraction of the cameras'
/// spread against the plain adjustment, after the similarity that best aligns their centres.
pub const MAX_LENS_SHIFT: f64 = 0.01;

/// The options of the final `bundle_adjuster`: with COLMAP 4, a second adjustment in
/// [`FINAL_CAMERA_MODEL`] with the principal point refined, written to `lens`; the COLMAP
/// program maps with `OPENCV` already and keeps its defaults.
fn final_adjustment<'a>(sfm: &Colmap, lens: &'a Path) -> Vec<&'a OsStr> {
    match sfm {
        Colmap::Pycolmap { .. } => {
            let mut args = [
                "--camera_model",
                FINAL_CAMERA_MODEL,
                "--BundleAdjustment.refine_principal_point",
                "1",
                "--lens_output_path",
            ]
            .map(OsStr::new)
            .to_vec();
            args.push(lens.as_os_str());
            args
        }
        Colmap::Program(_) => Vec::new(),
    }
}

/// How far the cameras of the model in `richer` stand from those of the model in `plain`:
/// the largest turn (degrees) and the largest move (a fraction of `plain`'s camera spread)
/// after the least-squares similarity of their centres
/// ([`nerf::core::camera::alignment::align_centres`]). `None` when the two do not register
/// the same images.
fn lens_change(plain: &Path, richer: &Path) -> Result<Option<(f64, f64)>> {
    let (plain, richer) = (poses_in(plain)?, poses_in(richer)?);
    if plain.len() < MIN_REGISTERED || !plain.keys().eq(richer.keys()) {
        return Ok(None);
    }
    let pairs: Vec<CameraPair> = plain
        .values()
        .zip(richer.values())
        .map(|(p, r)| CameraPair {
            true_rotation: p.rotation.transpose(),
            true_centre: p.center(),
            rotation: r.rotation.transpose(),
            centre: r.center(),
        })
        .collect();
    let alignment = align_centres(&pairs);
    let size = spread(&pairs.iter().map(|p| p.true_centre).collect::<Vec<_>>());
    let largest = |v: &[f64]| v.iter().copied().fold(0.0, f64::max);
    Ok(Some((
        largest(&alignment.rotation_errors_degrees),
        largest(&alignment.centre_errors) / size,
    )))
}

/// Refines the largest model under `colmap/sparse` in place: `colmap point_filtering
/// --max_reproj_error PX` then `colmap bundle_adjuster` (logs `colmap/point_filtering.log` and
/// `colmap/bundle_adjuster.log`), each into a folder of its own, the result renamed over the
/// model. Returns the seconds both took. An error names a stage that failed and its log.
fn refine(sfm: &Colmap, colmap: &Path, max_reprojection_error: f64) -> Result<f64> {
    let (model_dir, _) = nerf::io::colmap::find_model(colmap)?;
    let filtered = colmap.join("refine_filtered");
    let adjusted = colmap.join("refine_adjusted");
    let lens = colmap.join("refine_lens");
    let pixels = max_reprojection_error.to_string();
    let mut seconds = 0.0;
    let steps: [(&'static str, &Path, &Path, Vec<&OsStr>); 2] = [
        (
            "point_filtering",
            &model_dir,
            &filtered,
            vec![OsStr::new("--max_reproj_error"), OsStr::new(&pixels)],
        ),
        (
            "bundle_adjuster",
            &filtered,
            &adjusted,
            final_adjustment(sfm, &lens),
        ),
    ];
    for (stage, input, output, extra) in steps {
        std::fs::create_dir_all(output)
            .with_context(|| format!("cannot create {}", output.display()))?;
        let mut args = vec![
            OsStr::new("--input_path"),
            input.as_os_str(),
            OsStr::new("--output_path"),
            output.as_os_str(),
        ];
        args.extend(extra);
        let log = colmap.join(format!("{stage}.log"));
        let (status, took) = run_stage(sfm, stage, &args, &log, 1)?;
        if !status.success() || nerf::io::colmap::model_format(output).is_none() {
            bail!(
                "COLMAP's {stage} failed ({status}): see {} (its last line: {})",
                log.display(),
                last_line(&log)
            );
        }
        seconds += took;
    }
    // With COLMAP 4, the adjustment in the richer lens ([`final_adjustment`]) replaces the
    // plain one when it moved the cameras little.
    let mut said = String::new();
    if nerf::io::colmap::model_format(&lens).is_some() {
        let change = lens_change(&adjusted, &lens)?;
        let kept = change
            .is_some_and(|(turn, shift)| turn <= MAX_LENS_TURN_DEGREES && shift <= MAX_LENS_SHIFT);
        said = match change {
            Some((turn, shift)) if kept => format!(
                "; Lens {FINAL_CAMERA_MODEL}: cameras moved up to {turn:.2} deg, {:.2}% of their spread",
                100.0 * shift
            ),
            Some((turn, shift)) => format!(
                "; Lens {FINAL_CAMERA_MODEL} not kept: it moved the cameras up to {turn:.2} deg, {:.2}% of their spread (more than {MAX_LENS_TURN_DEGREES} deg or {}%)",
                100.0 * shift,
                100.0 * MAX_LENS_SHIFT
            ),
            None => format!("; Lens {FINAL_CAMERA_MODEL} not kept: it registered other images"),
        };
        let dropped = if kept { &adjusted } else { &lens };
        std::fs::remove_dir_all(dropped)
            .and_then(|()| {
                if kept {
                    std::fs::rename(&lens, &adjusted)
                } else {
                    Ok(())
                }
            })
            .with_context(|| {
                format!(
                    "cannot keep one of {} and {}",
                    adjusted.display(),
                    lens.display()
                )
            })?;
    }
    std::fs::remove_dir_all(&model_dir)
        .and_then(|()| std::fs::rename(&adjusted, &model_dir))
        .and_then(|()| std::fs::remove_dir_all(&filtered))
        .with_context(|| format!("cannot replace {} by its refinement", model_dir.display()))?;
    let lens = said;
    log::info!(
        "refined {}: observations beyond {max_reprojection_error} px dropped, bundle-adjusted again ({seconds:.1} s){lens}",
        model_dir.display()
    );
    Ok(seconds)
}

/// Moves run `seed`'s folder to `colmap/sparse` and removes the other `seeds`' folders.
fn keep_run(colmap: &Path, seeds: &[u64], seed: u64) -> Result<()> {
    let sparse = colmap.join("sparse");
    if sparse.symlink_metadata().is_ok() {
        std::fs::remove_dir_all(&sparse)
            .with_context(|| format!("cannot remove {}", sparse.display()))?;
    }
    let kept = run_folder(colmap, seed);
    std::fs::rename(&kept, &sparse)
        .with_context(|| format!("cannot move {} to {}", kept.display(), sparse.display()))?;
    for &other in seeds.iter().filter(|&&s| s != seed) {
        let folder = run_folder(colmap, other);
        std::fs::remove_dir_all(&folder)
            .with_context(|| format!("cannot remove {}", folder.display()))?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bad_options_are_refused_before_colmap_runs() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path();
        for options in [
            MappingOptions {
                runs: Some(0),
                ..MappingOptions::default()
            },
            MappingOptions {
                max_reprojection_error: f64::NAN,
                ..MappingOptions::default()
            },
        ] {
            let sfm = Colmap::Program("/nonexistent".into());
            let e = map(&sfm, p, p, p, 4, &options).unwrap_err();
            assert!(e.to_string().contains("at least one run"), "{e}");
        }
    }

    #[test]
    fn the_kept_run_becomes_sparse_and_the_others_go() {
        let dir = tempfile::tempdir().unwrap();
        let colmap = dir.path();
        for seed in 0..3 {
            std::fs::create_dir_all(run_folder(colmap, seed).join("0")).unwrap();
            std::fs::write(run_folder(colmap, seed).join("0/seed"), seed.to_string()).unwrap();
        }
        keep_run(colmap, &[0, 1, 2], 1).unwrap();
        let kept = std::fs::read_to_string(colmap.join("sparse/0/seed")).unwrap();
        assert_eq!(kept, "1");
        assert!((0..3).all(|s| !run_folder(colmap, s).exists()));
    }
}
