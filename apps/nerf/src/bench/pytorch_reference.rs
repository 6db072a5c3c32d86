//! The PyTorch CPU figures that `nerf bench` sets beside its rows: read from
//! `docs/pytorch-reference.json` (built into the binary), each for exactly the work it timed.

/// The PyTorch CPU reference figures of the speed issue (2-core machine), kept with the docs
/// in `docs/pytorch-reference.json`, for exactly the work they timed, else `None`: a ratio
/// against different work would mean nothing.
pub fn pytorch_seconds(work: ReferenceWork) -> Option<f64> {
    pytorch_figures()
        .iter()
        .find(|(timed, _)| *timed == work)
        .map(|(_, seconds)| *seconds)
}

/// One figure of `docs/pytorch-reference.json`: the work's kind, its sizes and the seconds.
#[derive(Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct PytorchFigure {
    work: String,
    #[serde(default)]
    frames: usize,
    #[serde(default)]
    width: usize,
    #[serde(default)]
    height: usize,
    #[serde(default)]
    rays: usize,
    points_per_ray: usize,
    seconds: f64,
}

/// The figures of `docs/pytorch-reference.json` (built into the binary), read once.
fn pytorch_figures() -> &'static [(ReferenceWork, f64)] {
    static FIGURES: std::sync::OnceLock<Vec<(ReferenceWork, f64)>> = std::sync::OnceLock::new();
    FIGURES.get_or_init(|| {
        #[derive(serde::Deserialize)]
        struct File {
            figures: Vec<PytorchFigure>,
        }
        let file: File =
            serde_json::from_str(include_str!("../../../../docs/pytorch-reference.json"))
                .expect("docs/pytorch-reference.json is valid (a unit test reads it)");
        file.figures
            .into_iter()
            .map(|f| {
                let work = match f.work.as_str() {
                    "box" => ReferenceWork::Box(f.frames, f.width, f.height, f.points_per_ray),
                    "frame" => ReferenceWork::Frame(f.width, f.height, f.points_per_ray),
                    "step" => ReferenceWork::Step(f.rays, f.points_per_ray),
                    "box_step" => ReferenceWork::BoxStep(f.rays, f.points_per_ray),
                    other => panic!("docs/pytorch-reference.json: unknown work {other:?}"),
                };
                (work, f.seconds)
            })
            .collect()
    })
}

/// What a PyTorch reference figure timed (see [`pytorch_seconds`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ReferenceWork {
    /// Surround frames of the box: frames, width, height, points per ray.
    Box(usize, usize, usize, usize),
    /// One NeRF frame: width, height, points per ray.
    Frame(usize, usize, usize),
    /// One training step: rays, points per ray.
    Step(usize, usize),
    /// One step of the box fit (train_box): rays, points per ray.
    BoxStep(usize, usize),
}

#[cfg(test)]
mod tests {
    use super::*;
    use nerf::config::Config;

    #[test]
    fn pytorch_figures_apply_only_to_the_work_they_timed() {
        // The built-in configs describe exactly the reference work.
        let boxed = Config::load("box", &[]).unwrap();
        let (w, h) = boxed.image_size();
        let work = ReferenceWork::Box(boxed.cameras.n_poses, w, h, boxed.sampler.n_pts_per_ray);
        let mut found = vec![work];
        assert!(pytorch_seconds(work).is_some());
        let lego = Config::load("nerf_lego", &[]).unwrap();
        let (w, h) = lego.image_size();
        let points = lego.sampler.n_pts_per_ray;
        found.push(ReferenceWork::Frame(w, h, points));
        assert!(pytorch_seconds(*found.last().unwrap()).is_some());
        let rays = lego.training.as_ref().unwrap().batch_size.unwrap();
        found.push(ReferenceWork::Step(rays, points));
        assert!(pytorch_seconds(*found.last().unwrap()).is_some());
        let train_box = Config::load("train_box", &[]).unwrap();
        let settings = train_box.sdf_fit_settings().unwrap();
        found.push(ReferenceWork::BoxStep(
            settings.batch_size,
            train_box.sampler.n_pts_per_ray,
        ));
        assert!(pytorch_seconds(*found.last().unwrap()).is_some());
        // Every figure of docs/pytorch-reference.json is the work of a built-in config.
        assert_eq!(pytorch_figures().len(), found.len());
        // Other sizes have no figure.
        assert_eq!(pytorch_seconds(ReferenceWork::Box(20, 16, 16, 64)), None);
        assert_eq!(pytorch_seconds(ReferenceWork::Frame(128, 128, 64)), None);
        assert_eq!(pytorch_seconds(ReferenceWork::Step(512, 128)), None);
    }
}
