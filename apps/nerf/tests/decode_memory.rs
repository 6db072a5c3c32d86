//! Bounded memory whatever the thread count: a capture of large photos loads within the
//! decoding budget (`nerf::io::decode_budget`) on 8 threads as on 2. The peak resident memory
//! of each run is the child's `ru_maxrss` (`getrusage(RUSAGE_CHILDREN)`, the largest of this
//! process's waited-for children: this file holds one test, so the runs are the only
//! children). The 2-thread run goes first; the 8-thread run may then raise the maximum by no
//! more than the budget (without it, each extra thread held another photo's ~600 MB of decoded
//! copies: 6 more threads, some 3.6 GB more).

mod common;

use common::lego_capture::*;

/// The largest peak resident memory, in bytes, of this process's children so far.
fn children_peak_bytes() -> u64 {
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    // SAFETY: getrusage writes one rusage into the pointer it is given.
    let rc = unsafe { libc::getrusage(libc::RUSAGE_CHILDREN, &mut usage) };
    assert_eq!(rc, 0);
    // Linux reports kilobytes.
    usage.ru_maxrss as u64 * 1024
}

#[test]
fn a_capture_of_large_photos_loads_in_the_same_memory_on_8_threads_as_on_2() {
    let Some(lego) = lego() else { return };
    let lego = lego.first(9);
    let root = tempfile::tempdir().unwrap();
    let dir = root.path().join("capture");
    write_colmap_text(&lego, &dir);
    // Every photo replaced by a 4096×4096 one (a flat colour: a small file, 64 MiB of RGBA32F
    // per copy), and the camera scaled to it.
    const SIDE: u32 = 4096;
    let scale = SIDE as f64 / lego.size.0 as f64;
    for entry in std::fs::read_dir(dir.join("images")).unwrap() {
        let path = entry.unwrap().path();
        image::RgbImage::from_pixel(SIDE, SIDE, image::Rgb([120, 130, 140]))
            .save(&path)
            .unwrap();
    }
    let f = lego.focal_px() * scale;
    let c = SIDE as f64 / 2.0;
    std::fs::write(
        dir.join("sparse/0/cameras.txt"),
        format!("1 PINHOLE {SIDE} {SIDE} {f} {f} {c} {c}\n"),
    )
    .unwrap();
    let mut peaks = Vec::new();
    for threads in ["2", "8"] {
        let ckpt = root.path().join(format!("t{threads}.safetensors"));
        let status = common::nerf_command()
            .args(["train", "--config", "nerf_scene_bounded", "--data-dir"])
            .arg(&dir)
            .arg(format!("training.checkpoint_path={}", ckpt.display()))
            .args([
                "training.num_epochs=1",
                "data.image_size=[16,16]",
                "sampler.n_pts_per_ray=16",
                "training.eval_views=0",
            ])
            .env("RAYON_NUM_THREADS", threads)
            .output()
            .unwrap();
        assert!(status.status.success(), "{}", common::stderr(&status));
        peaks.push(children_peak_bytes());
        eprintln!(
            "{threads} threads: peak of the runs so far {:.0} MiB",
            peaks.last().unwrap() / (1 << 20)
        );
    }
    let budget = nerf::io::decode_budget::DECODE_BUDGET_BYTES;
    assert!(
        peaks[1] - peaks[0] < budget,
        "8 threads peaked {} MiB above 2 threads' {} MiB",
        (peaks[1] - peaks[0]) >> 20,
        peaks[0] >> 20
    );
    // And the 2-thread run itself stayed near the budget: one photo's copies in flight beside
    // the process (a 4096² photo costs about 640 MiB to decode, so one at a time).
    assert!(peaks[0] < budget + (1 << 30), "{} MiB", peaks[0] >> 20);
}
