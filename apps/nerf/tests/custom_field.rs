//! A field kind defined outside the crate (the voxel grid of `examples/custom_field/`) trains
//! on lego with the library's trainer: the loss falls, the checkpoint holds its parameters and
//! optimiser state, and a second call resumes from it.

mod common;

#[path = "../../../examples/custom_field/voxels.rs"]
mod voxels;

use candle_core::Device;
use nerf::config::Config;
use nerf::io::dataset::{Dataset, Split};
use nerf::{fit, FieldSpec, Hooks, RunLimits, TrainModel, TrainPaths};

#[test]
fn a_field_kind_from_outside_the_crate_trains_and_resumes_with_the_library_trainer() {
    let Some(lego) = common::lego_dir() else {
        return;
    };
    let config = Config::load(
        "nerf_lego_fast",
        &[
            "data.image_size=[16,16]".into(),
            "training.batch_size=128".into(),
        ],
    )
    .unwrap();
    let spec = voxels::VoxelSpec {
        resolution: 12,
        half_extent: 1.5,
    };
    let mut settings = voxels::train_settings(&config, spec).unwrap();
    let (w, h) = config.image_size();
    let dataset = Dataset::load(&lego, Split::Train, w, h, true).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let paths = TrainPaths {
        checkpoint: dir.path().join("voxels.safetensors"),
        log: dir.path().join("log.jsonl"),
        images: dir.path().to_path_buf(),
    };
    let device = Device::Cpu;
    let run = |settings: &nerf::TrainSettings| {
        fit(
            settings,
            &dataset,
            &paths,
            RunLimits::default(),
            None,
            Hooks::default(),
            &device,
        )
        .unwrap()
    };
    let first = run(&settings).info();
    let steps = dataset.images.len() as u64;
    assert_eq!((first.epoch, first.adam_step), (1, steps));
    let losses: Vec<f64> = std::fs::read_to_string(&paths.log)
        .unwrap()
        .lines()
        .map(|l| {
            serde_json::from_str::<serde_json::Value>(l).unwrap()["loss"]
                .as_f64()
                .unwrap()
        })
        .collect();
    assert_eq!(losses.len() as u64, steps);
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    let (early, late) = (mean(&losses[..10]), mean(&losses[losses.len() - 10..]));
    eprintln!("voxel grid loss {early:.4} -> {late:.4}");
    assert!(late < 0.6 * early, "loss {early} -> {late}");

    // The checkpoint holds the grid (under the kind's own parameter name) and its sparse Adam
    // moments, and loads back into the same kind.
    let loaded = TrainModel::from_checkpoint(&spec, &paths.checkpoint, &device).unwrap();
    let (model, tensors, info) = (loaded.model, loaded.tensors, loaded.info);
    assert_eq!((info.epoch, info.adam_step), (first.epoch, first.adam_step));
    assert_eq!(model.field.kind(), spec.kind());
    let grid = &tensors[voxels::VOXELS];
    assert_eq!(grid.dims(), &[12 * 12 * 12, 4]);
    assert!(tensors
        .keys()
        .any(|k| k.contains("exp_avg") && k.contains(voxels::VOXELS)));

    // A second call with a longer schedule resumes where the first stopped.
    settings.num_epochs = 2;
    let second = run(&settings).info();
    assert_eq!((second.epoch, second.adam_step), (2, 2 * steps));
    let logged = std::fs::read_to_string(&paths.log).unwrap().lines().count() as u64;
    assert_eq!(logged, 2 * steps);
}
