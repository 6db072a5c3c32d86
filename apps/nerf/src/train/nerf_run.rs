//! `nerf train`: a config's NeRF training run, with test-PSNR logging and preview GIFs as the
//! loop's hooks.

use std::path::Path;

use std::sync::atomic::AtomicBool;

use anyhow::{bail, Result};
use candle_core::Device;

use crate::render::scene::render_nerf_gif;
use crate::render::scene_frame::{adopt_object_fit, note_scene_frame, stored_transform};
use nerf::config::{Config, SizeUse};
use nerf::core::image::colour_name;
use nerf::eval::evaluate::evaluate;
use nerf::io::dataset::backdrop::backdrop_colour;
use nerf::io::dataset::{Dataset, Split};
use nerf::render::renderer::BLACK;
use nerf::train::fit::{
    fit, CheckpointScore, FitOutcome, Hooks, RunLimits, TrainPaths, TrainSettings,
};
use nerf::train::step::StepSettings;

/// Refuses to start a fresh run over an existing checkpoint (`training.resume: False`) unless
/// `overwrite`; with it, removes the old checkpoint and log together, so that the new run's
/// log and checkpoint never mix with the old ones.
pub fn check_fresh_start(config: &Config, paths: &TrainPaths, overwrite: bool) -> Result<()> {
    if config.training()?.resume || !paths.checkpoint.exists() {
        return Ok(());
    }
    if !overwrite {
        bail!(
            "{} already holds a checkpoint and training.resume is False: pass --overwrite to \
             start again and replace it and its log, or resume with training.resume=True",
            paths.checkpoint.display()
        );
    }
    for p in [&paths.checkpoint, &paths.log] {
        // Through a link, its target: the link stays, and the new run writes through it.
        nerf::io::output::remove_output(p)?;
    }
    Ok(())
}

/// Installs the SIGINT/SIGTERM handler of a training run: the first signal sets the returned
/// flag (the loop finishes its step and writes a checkpoint); a second one exits at once with
/// status 130, removing the temporary file of a write under way (every file is written
/// atomically, so nothing is left half-written, and the log holds no step past the checkpoint).
pub fn stop_on_signal() -> Result<&'static AtomicBool> {
    use anyhow::Context as _;
    use std::sync::atomic::Ordering;
    static STOP: AtomicBool = AtomicBool::new(false);
    ctrlc::set_handler(|| {
        if STOP.swap(true, Ordering::SeqCst) {
            nerf::core::term::note("second interrupt: exiting now");
            nerf::io::output::exit_removing_temp_files(130);
        }
        nerf::core::term::note("interrupt: stopping after this step (again to exit at once)");
    })
    .context("cannot install the interrupt handler")?;
    Ok(&STOP)
}

/// Runs `nerf train` for `config` on the dataset in `data_dir` (a capture normalised as its
/// cameras say, or as the checkpoint a resumed run continues stores). `limits` end the run early
/// (after writing a checkpoint) after that many epochs or seconds of training in this process;
/// `stop` ends it after the current step.
pub fn train_nerf(
    config: &Config,
    data_dir: &Path,
    paths: &TrainPaths,
    limits: RunLimits,
    stop: Option<&AtomicBool>,
    device: &Device,
) -> Result<FitOutcome> {
    // The config's mistakes are reported before the data's.
    config.train_settings()?;
    let size = config
        .data
        .dataset_image_size(data_dir, SizeUse::Training)?;
    let white = config.renderer.white_background;
    // A resumed run keeps the frame it started in.
    let stored = match config.training()?.resume {
        true => stored_transform(&paths.checkpoint)?,
        false => None,
    };
    let mut dataset = Dataset::load_first_with(data_dir, Split::Train, size, white, None, stored)?;
    // With background auto a masked-out pixel holds the backdrop the masks leave out, the
    // colour training then composites the photos on (choose_background); else the loader's.
    let loader_background = if white { [1.0; 3] } else { BLACK };
    let fill = (!config.renderer.background_is_auto()).then_some(loader_background);
    let outlined = nerf::io::dataset::silhouette::masks_as_alpha(&mut dataset, fill);
    if let Some(o) = outlined {
        nerf::core::term::note(&format!(
            "{}: the masks of {} frames outline an object (they keep none of their photo's border): trained as its alpha, the space around it empty; held-out views are still scored inside their masks",
            data_dir.display(),
            o.frames
        ));
    }
    if dataset.normalisation.is_some() {
        nerf::io::dataset::shared_view::check_capture_shares_a_view(data_dir, &dataset.frames)?;
    }
    // A resumed run keeps the object fit it started with (other frames may carve another
    // hull, and a field of another box would not load).
    let mut resumed = config.clone();
    let resumed_fit = match config.training()?.resume {
        true => adopt_object_fit(&mut resumed, &paths.checkpoint)?,
        false => None,
    };
    let (narrowed, sample_depths, object_box) = match resumed_fit {
        Some((depths, cube)) => {
            if depths.is_some() || cube.is_some() {
                nerf::core::term::note(&format!(
                    "{}: keeping the object's depths and cube stored in {}",
                    data_dir.display(),
                    paths.checkpoint.display()
                ));
            }
            (resumed, depths, cube)
        }
        None => fitted_to_object(config, &dataset, data_dir),
    };
    let config = &narrowed;
    let mut settings = config.train_settings()?;
    settings.sample_depths = sample_depths;
    settings.object_box = object_box;
    if stored.is_some() {
        let n = dataset.normalisation.as_ref();
        note_scene_frame(data_dir, &paths.checkpoint, stored, n);
    }
    if let Some(sized) = settings.model.for_training_images(dataset.images.len()) {
        settings.model = sized;
    }
    if config.renderer.background_is_auto() {
        let masked_backdrop = outlined.map(|o| o.backdrop);
        let backdrop = choose_background(&mut settings.step, &dataset, masked_backdrop, data_dir);
        if !backdrop {
            let decay = config.renderer.occupancy_grid.as_ref();
            let decay = decay.and_then(|g| g.decay_without_backdrop);
            settings_without_backdrop(&mut settings, decay, data_dir);
        }
    }
    let frame = dataset.normalisation.map(|n| n.applied);
    let eval_views = config.training()?.eval_views;
    let test = if eval_views > 0 {
        match Dataset::load_first_with(data_dir, Split::Test, size, white, None, frame) {
            Ok(d) => Some(d),
            Err(e) => {
                nerf::core::term::note(&format!("warning: no test-PSNR logging: {e:#}"));
                None
            }
        }
    } else {
        None
    };
    let mut render = config.render_settings()?;
    render.renderer.background = settings.step.renderer.background;
    let mut hooks = Hooks::default();
    if let Some(test) = &test {
        hooks.evaluate = Some(Box::new(move |field| {
            let pipeline = render.with(field);
            let report = evaluate(&pipeline, test, Split::Test, None, Some(eval_views), device)?;
            Ok(CheckpointScore {
                psnr: report.mean_psnr,
                views: report.views.len(),
            })
        }));
    }
    let gif = paths.images.join("render_nerf_training.gif");
    hooks.preview = Some(Box::new(move |field| {
        render_nerf_gif(config, field, &gif, device)
    }));
    fit(&settings, &dataset, paths, limits, stop, hooks, device)
}

/// `config` fitted to the object when `dataset` is a capture of an object alone (photos
/// with alpha, or masks that outline it) and `renderer.background` is `auto`
/// ([`nerf::io::dataset::object_hull::object_fit`]): the sampler's depth range narrowed to the
/// object's visual hull, and a hash-grid field and the occupancy grid over the cube round it
/// without a scene contraction (nothing of the model lies outside the hull, so the grids'
/// cells are all spent on the object). Returns the narrowed range and the cube too (stored in
/// the checkpoint, so `eval`, `render` and `view` read the model the same way). Says so.
fn fitted_to_object(
    config: &Config,
    dataset: &Dataset,
    data_dir: &Path,
) -> (Config, Option<(f64, f64)>, Option<[f64; 6]>) {
    let mut config = config.clone();
    if dataset.normalisation.is_none() || !config.renderer.background_is_auto() {
        return (config, None, None);
    }
    let s = &config.sampler;
    let Some(fit) = nerf::io::dataset::object_hull::object_fit(dataset, (s.min_depth, s.max_depth))
    else {
        return (config, None, None);
    };
    if let Some((near, far)) = fit.depths {
        let s = &mut config.sampler;
        nerf::core::term::note(&format!(
            "{}: the photos outline an object: its visual hull lies {near:.3} to {far:.3} from the cameras, where the {} depths a ray are drawn (sampler.min_depth, max_depth were {}, {})",
            data_dir.display(),
            s.n_pts_per_ray,
            s.min_depth,
            s.max_depth
        ));
        (s.min_depth, s.max_depth) = (near, far);
    }
    let cube = config.fit_to_object(fit.cube).then(|| {
        let c = fit.cube;
        nerf::core::term::note(&format!(
            "{}: the hash grid and the occupancy grid cover the cube round the object's hull, [{:.3}, {:.3}] x [{:.3}, {:.3}] x [{:.3}, {:.3}], with no scene contraction",
            data_dir.display(),
            c[0],
            c[3],
            c[1],
            c[4],
            c[2],
            c[5]
        ));
        c
    });
    (config, fit.depths, cube)
}

/// `renderer.background: auto` at training: photos with alpha are trained on a random colour
/// per step (their own background stays the loader's, white or black); photos without are
/// trained on the colour of the plain backdrop their borders show
/// ([`nerf::io::dataset::backdrop::backdrop_colour`]), else on black (a scene with no
/// backdrop: what lies beyond is the contracted far field's). Masks that outline an object
/// (`masked_backdrop`: the mean colour they leave out) train as alpha, and eval, render and
/// view show the object over that colour, as the photos do: the pixels along a silhouette's
/// edge mix the object with the backdrop, in the photos and then in the renders (on black,
/// they held 15–18% of the error inside the masks; docs/own-scene.md#a-masked-object).
/// Says what it chose, and returns whether the photos show the object apart from its
/// surroundings (alpha, or a plain backdrop).
fn choose_background(
    step: &mut StepSettings,
    dataset: &Dataset,
    masked_backdrop: Option<[f32; 3]>,
    data_dir: &Path,
) -> bool {
    let has_alpha = dataset
        .transparency
        .iter()
        .any(|t| t.iter().any(|&v| v > 0.0));
    let (background, why, apart) = if let Some(backdrop) = masked_backdrop.filter(|_| has_alpha) {
        step.random_background = true;
        (
            backdrop,
            "the mean colour the masks leave out; trained on a random background colour per step",
            true,
        )
    } else if has_alpha {
        step.random_background = true;
        (
            step.renderer.background,
            "the photos have alpha: a random background colour per step",
            true,
        )
    } else {
        match backdrop_colour(&dataset.images) {
            Some(c) => (c, "the photos' borders show a plain backdrop", true),
            None => (BLACK, "no plain backdrop in the photos' borders", false),
        }
    };
    step.renderer.background = background;
    nerf::core::term::note(&format!(
        "{}: background {} ({why}); stored in the checkpoint for eval, render and view",
        data_dir.display(),
        colour_name(background)
    ));
    apart
}

/// `renderer.background: auto` on photos with no backdrop (a room, a street, a facade): the
/// cameras stand among the scene's own geometry (the floor, the ground in front of a
/// building), which the camera clearance would keep empty, so it is left off
/// (a facade's capture scored better held out without it, where a capture on a black
/// backdrop scored better with it; measured: docs/own-scene.md#background); and the grid
/// decays by `decay` (`renderer.occupancy_grid.decay_without_backdrop`) when one is given, and
/// a contracted grid keeps its far shell occupied, where the room or the street beyond is
/// learnt (`OccupancyGrid::keep_far_shell`; measured: docs/own-scene.md#a-handheld-capture-levers-measured). An
/// explicit `renderer.background` keeps the configured grid.
fn settings_without_backdrop(settings: &mut TrainSettings, decay: Option<f64>, data_dir: &Path) {
    let Some(grid) = settings.grid.as_mut() else {
        return;
    };
    let mut changed = Vec::new();
    if grid.camera_clearance > 0.0 {
        grid.camera_clearance = 0.0;
        changed.push("no camera clearance".to_string());
    }
    if let Some(decay) = decay.filter(|&d| d != grid.decay) {
        grid.decay = decay;
        changed.push(format!("occupancy-grid decay {decay}"));
    }
    if grid.grid.contraction != nerf::core::contraction::Contraction::None {
        grid.keep_far_shell = true;
        changed.push("the grid's far shell kept occupied".to_string());
    }
    if !changed.is_empty() {
        nerf::core::term::note(&format!(
            "{}: {} (no backdrop: the cameras stand among the scene; an explicit \
             renderer.background keeps renderer.occupancy_grid as configured)",
            data_dir.display(),
            changed.join(", ")
        ));
    }
}
