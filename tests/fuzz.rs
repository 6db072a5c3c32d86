//! Property tests (proptest) for the parsers that read user input: configs (YAML and
//! overrides), the dataset's transforms JSON, nerfstudio camera paths, the viewer's
//! `/render.png` query (in the binary's view::request), and the file readers: checkpoints (safetensors and PyTorch archives,
//! mutated from the fixtures), pickles and `.npy` arrays. Whatever the input, they return a
//! value or an error of one line; they never panic, abort or hang.
//!
//! Deterministic: every run uses the same ChaCha seed ([`SEED`]) and writes no failure
//! files; the whole file runs in a few seconds in release.

use std::io::{Cursor, Read, Write};
use std::path::{Path, PathBuf};

use nerf::config::{apply_override, Config};
use nerf::io::camera_path::parse_camera_path;
use nerf::io::dataset::parse_split;
use proptest::prelude::*;
use proptest::test_runner::{RngAlgorithm, RngSeed};

/// The seed of every property here.
const SEED: u64 = 0x5eed_2026_0020;

/// `cases` cases from the fixed seed, with no failure persistence (nothing written to the
/// repository).
fn fixed(cases: u32) -> ProptestConfig {
    ProptestConfig {
        cases,
        rng_algorithm: RngAlgorithm::ChaCha,
        rng_seed: RngSeed::Fixed(SEED),
        failure_persistence: None,
        ..ProptestConfig::default()
    }
}

/// Fails the case when `result` is an error whose message (with its causes) spans more than
/// one line (the library's typed errors are checked as the binary prints them, through
/// `anyhow`).
fn ok_or_one_line<T, E: Into<anyhow::Error>>(result: Result<T, E>) -> Result<(), TestCaseError> {
    if let Err(e) = result {
        let text = format!("{:#}", e.into());
        prop_assert!(
            !text.contains('\n'),
            "error of more than one line: {text:?}"
        );
        prop_assert!(!text.is_empty(), "an empty error");
    }
    Ok(())
}

/// The built-in configs' text, as seeds for mutation.
fn seeds() -> Vec<String> {
    ["box", "sphere", "lego", "nerf_lego", "nerf_lego_fast"]
        .iter()
        .map(|n| nerf::config::config_text(n).unwrap().0)
        .collect()
}

/// One of `words`, each as likely as the others.
fn words(words: &'static [&'static str]) -> impl Strategy<Value = String> {
    prop::sample::select(words).prop_map(str::to_string)
}

/// A JSON matrix entry: a random float or one of `words`, each of these 1 + n choices as likely.
fn matrix_entry(words: &'static [&'static str]) -> impl Strategy<Value = String> {
    let n = words.len() as u32;
    prop_oneof![
        1 => any::<f64>().prop_map(|v| format!("{v:e}")),
        n => self::words(words),
    ]
}

/// YAML scalars and fragments that stress parsers: huge, negative, special floats, wrong
/// types, nesting, unicode.
fn nasty_value() -> impl Strategy<Value = String> {
    prop_oneof![
        13 => words(&[
            "0", "-1", ".nan", "-.inf", "1e400", "18446744073709551616", "[]", "[1, [2, 3]]",
            "{a: 1}", "null", "~", "'ü✓'", "True",
        ]),
        1 => any::<i64>().prop_map(|v| v.to_string()),
        1 => any::<f64>().prop_map(|v| format!("{v:e}")),
        1 => "[ -~]{0,12}",
    ]
}

proptest! {
    #![proptest_config(fixed(400))]

    #[test]
    fn arbitrary_text_never_panics(text in "(?s).{0,300}") {
        ok_or_one_line(Config::from_yaml(&text, &[]))?;
    }

    #[test]
    fn deeply_nested_yaml_is_refused_or_parsed_quickly(
        pieces in prop::collection::vec(prop_oneof![
            Just("["), Just("{a: "), Just("- "), Just("\n  "), Just("]"), Just("}"), Just("&x "),
            Just("*x"), Just("'["), Just("#["), Just(": "), Just("|\n"),
        ], 0..400),
        section in prop_oneof![Just("data: "), Just(""), Just("sampler:\n  ")],
    ) {
        let text = format!("{section}{}", pieces.concat());
        let start = std::time::Instant::now();
        ok_or_one_line(Config::from_yaml(&text, &[]))?;
        ok_or_one_line(Config::from_yaml(
            &nerf::config::config_text("box").unwrap().0,
            &[format!("data.image_size={}", pieces.concat())],
        ))?;
        prop_assert!(start.elapsed().as_secs_f64() < 2.0, "{:?}", start.elapsed());
    }

    #[test]
    fn mutated_configs_never_panic(
        seed in 0usize..5,
        line in 0usize..60,
        value in nasty_value(),
        cut in 0usize..2000,
    ) {
        let seeds = seeds();
        let text = &seeds[seed % seeds.len()];
        // Replace the value of one `key: value` line.
        let lines: Vec<&str> = text.lines().collect();
        let i = line % lines.len();
        let mut mutated: Vec<String> = lines.iter().map(|l| l.to_string()).collect();
        if let Some((key, _)) = lines[i].split_once(':') {
            mutated[i] = format!("{key}: {value}");
        }
        let mutated = mutated.join("\n");
        ok_or_one_line(Config::from_yaml(&mutated, &[]))?;
        // And a truncated copy.
        let cut = cut.min(text.len());
        if text.is_char_boundary(cut) {
            ok_or_one_line(Config::from_yaml(&text[..cut], &[]))?;
        }
    }

    #[test]
    fn overrides_never_panic(
        seed in 0usize..5,
        key in prop_oneof![
            Just("sampler.n_pts_per_ray".to_string()),
            Just("renderer.occupancy_grid.resolution".to_string()),
            Just("renderer.occupancy_grid".to_string()),
            Just("renderer.early_termination".to_string()),
            Just("implicit_function.append_xyz".to_string()),
            Just("implicit_function.sdf.side_lengths.val".to_string()),
            Just("cameras.up".to_string()),
            Just("training.batch_size".to_string()),
            Just("data".to_string()),
            "[a-z_.]{0,30}",
        ],
        value in nasty_value(),
    ) {
        let seeds = seeds();
        let text = &seeds[seed % seeds.len()];
        ok_or_one_line(Config::from_yaml(text, &[format!("{key}={value}")]))?;
        let mut root: serde_yaml_ng::Value = serde_yaml_ng::from_str(text).unwrap();
        ok_or_one_line(apply_override(&mut root, &format!("{key}{value}")))?;
    }

    #[test]
    fn transforms_json_never_panics(
        fov in prop_oneof![Just("0.69".to_string()), nasty_value()],
        matrix in prop::collection::vec(matrix_entry(&["0", "1", "null", "\"x\""]), 0..20),
        path in "[ -~]{0,20}",
        truncate in 0usize..400,
    ) {
        let rows: Vec<String> = matrix.chunks(4).map(|r| format!("[{}]", r.join(", "))).collect();
        let json = format!(
            r#"{{"camera_angle_x": {fov}, "frames": [{{"file_path": {path:?}, "rotation": 0.1, "transform_matrix": [{}]}}]}}"#,
            rows.join(", ")
        );
        let origin = Path::new("transforms_test.json");
        ok_or_one_line(parse_split(json.as_bytes(), Path::new("data"), origin))?;
        let cut = truncate.min(json.len());
        if json.is_char_boundary(cut) {
            ok_or_one_line(parse_split(&json.as_bytes()[..cut], Path::new("data"), origin))?;
        }
    }
}

proptest! {
    #![proptest_config(fixed(256))]

    #[test]
    fn camera_paths_never_panic(
        fov in prop_oneof![Just("50".to_string()), nasty_value()],
        size in prop_oneof![Just("64".to_string()), nasty_value()],
        fps in prop_oneof![Just("24".to_string()), nasty_value()],
        matrix in prop::collection::vec(matrix_entry(&["0", "1", "null"]), 0..20),
        truncate in 0usize..400,
    ) {
        let json = format!(
            r#"{{"camera_type": "perspective", "render_width": {size}, "render_height": 32, "fps": {fps},
               "camera_path": [{{"camera_to_world": [{}], "fov": {fov}}}]}}"#,
            matrix.join(", ")
        );
        ok_or_one_line(parse_camera_path(json.as_bytes()))?;
        let cut = truncate.min(json.len());
        if json.is_char_boundary(cut) {
            ok_or_one_line(parse_camera_path(&json.as_bytes()[..cut]))?;
        }
    }
}

#[test]
fn a_valid_transforms_file_parses() {
    // The identity-rotation camera 4 units up the z axis: a regression check that the fuzzed
    // parser accepts the real format.
    let json = r#"{"camera_angle_x": 0.6911112070083618, "frames": [{"file_path": "./test/r_0",
        "rotation": 0.0, "transform_matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]]}]}"#;
    let frames = parse_split(json.as_bytes(), Path::new("d"), Path::new("t.json")).unwrap();
    assert_eq!(frames.len(), 1);
    assert_eq!(frames[0].file_path, Path::new("d/test/r_0.png"));
}

/// The test fixtures' folder.
fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures")
}

/// The NeRF the checkpoint fixtures hold.
fn tiny_params() -> nerf::field::nerf::NerfParams {
    Config::load(fixtures().join("tiny_nerf.yaml").to_str().unwrap(), &[])
        .unwrap()
        .nerf_params()
        .unwrap()
}

/// A byte-level mutation: overwrite, insert, delete or truncate at a position (taken modulo
/// the length).
#[derive(Debug, Clone)]
enum Mutation {
    Set(usize, u8),
    Insert(usize, Vec<u8>),
    Delete(usize, usize),
    Truncate(usize),
}

fn mutation() -> impl Strategy<Value = Mutation> {
    prop_oneof![
        4 => (any::<usize>(), any::<u8>()).prop_map(|(i, b)| Mutation::Set(i, b)),
        2 => (any::<usize>(), prop::collection::vec(any::<u8>(), 1..16))
            .prop_map(|(i, b)| Mutation::Insert(i, b)),
        // Runs of opcodes that build, copy and nest: memo gets, DUP, MARK, tuples, lists.
        2 => (any::<usize>(), prop::sample::select(vec![b'h', b'2', b'(', b't', b']', b'a', 0x85, b'0', b'q']), 1..200usize)
            .prop_map(|(i, op, n)| Mutation::Insert(i, vec![op; n])),
        1 => (any::<usize>(), 1..64usize).prop_map(|(i, n)| Mutation::Delete(i, n)),
        1 => any::<usize>().prop_map(Mutation::Truncate),
    ]
}

fn apply(bytes: &mut Vec<u8>, mutations: &[Mutation]) {
    for m in mutations {
        let len = bytes.len().max(1);
        match m {
            Mutation::Set(i, b) => {
                if !bytes.is_empty() {
                    bytes[i % len] = *b;
                }
            }
            Mutation::Insert(i, b) => {
                let at = i % (bytes.len() + 1);
                bytes.splice(at..at, b.iter().copied());
            }
            Mutation::Delete(i, n) => {
                let at = i % len;
                let end = (at + n).min(bytes.len());
                if at < end {
                    bytes.drain(at..end);
                }
            }
            Mutation::Truncate(i) => bytes.truncate(i % len),
        }
    }
}

/// The members of a zip archive, in order.
fn members(zip_bytes: &[u8]) -> Vec<(String, Vec<u8>)> {
    let mut zip = zip::ZipArchive::new(Cursor::new(zip_bytes)).unwrap();
    (0..zip.len())
        .map(|i| {
            let mut m = zip.by_index(i).unwrap();
            let mut bytes = Vec::new();
            m.read_to_end(&mut bytes).unwrap();
            (m.name().unwrap().to_string(), bytes)
        })
        .collect()
}

/// A stored zip archive of `members` (CRCs recomputed, so mutations reach the readers behind
/// the archive).
fn rezip(members: &[(String, Vec<u8>)]) -> Vec<u8> {
    let stored =
        zip::write::SimpleFileOptions::default().compression_method(zip::CompressionMethod::Stored);
    let mut zip = zip::ZipWriter::new(Cursor::new(Vec::new()));
    for (name, bytes) in members {
        zip.start_file(name.as_str(), stored).unwrap();
        zip.write_all(bytes).unwrap();
    }
    zip.finish().unwrap().into_inner()
}

const TORCH_FIXTURES: [&str; 3] = [
    "tiny_nerf.pth",
    "tiny_nerf_homework.pth",
    "tiny_nerf_nested.pth",
];

/// Loads `bytes` as a checkpoint file through the crate's checkpoint API (either format).
fn load_checkpoint(bytes: &[u8], params: &nerf::field::nerf::NerfParams) -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let path = dir.path().join("checkpoint");
    std::fs::write(&path, bytes)?;
    let shapes = nerf::field::nerf::parameter_shapes(params);
    nerf::io::checkpoint_file::load(&path, &shapes, &candle_core::Device::Cpu)?;
    Ok(())
}

proptest! {
    #![proptest_config(fixed(160))]

    #[test]
    fn mutated_torch_pickles_never_panic(
        fixture in 0usize..3,
        mutations in prop::collection::vec(mutation(), 1..4),
    ) {
        let file = std::fs::read(fixtures().join(TORCH_FIXTURES[fixture])).unwrap();
        let mut parts = members(&file);
        let pkl = parts.iter().position(|(n, _)| n.ends_with("data.pkl")).unwrap();
        apply(&mut parts[pkl].1, &mutations);
        let start = std::time::Instant::now();
        ok_or_one_line(load_checkpoint(&rezip(&parts), &tiny_params()))?;
        prop_assert!(start.elapsed().as_secs_f64() < 2.0, "{:?}", start.elapsed());
    }

    #[test]
    fn mutated_torch_records_and_archives_never_panic(
        fixture in 0usize..3,
        member in any::<usize>(),
        mutations in prop::collection::vec(mutation(), 1..4),
        whole_file in any::<bool>(),
    ) {
        let file = std::fs::read(fixtures().join(TORCH_FIXTURES[fixture])).unwrap();
        let bytes = if whole_file {
            let mut bytes = file;
            apply(&mut bytes, &mutations);
            bytes
        } else {
            let mut parts = members(&file);
            let i = member % parts.len();
            apply(&mut parts[i].1, &mutations);
            rezip(&parts)
        };
        ok_or_one_line(load_checkpoint(&bytes, &tiny_params()))?;
    }

    #[test]
    fn mutated_safetensors_checkpoints_never_panic(
        mutations in prop::collection::vec(mutation(), 1..4),
        in_header in any::<bool>(),
    ) {
        let mut bytes = std::fs::read(fixtures().join("tiny_nerf_homework.safetensors")).unwrap();
        if in_header {
            // Keep the mutations inside the length field and the JSON header.
            let header = 8 + u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
            let (mut head, tail) = (bytes[..header].to_vec(), bytes[header..].to_vec());
            apply(&mut head, &mutations);
            head.extend_from_slice(&tail);
            bytes = head;
        } else {
            apply(&mut bytes, &mutations);
        }
        ok_or_one_line(load_checkpoint(&bytes, &tiny_params()))?;
    }
}

/// Tokens of `.npy` header dicts, valid and not.
fn npy_token() -> impl Strategy<Value = String> {
    prop_oneof![
        15 => words(&[
            "{", "}", "(", ")", "'descr'", "'fortran_order'", "'shape'", ": ", ", ", "'<f4'",
            "'<f8'", "'|u1'", "True", "False", "'",
        ]),
        1 => any::<u64>().prop_map(|v| v.to_string()),
        1 => (0u64..5).prop_map(|v| v.to_string()),
        1 => "[ -~]{0,4}",
    ]
}

/// A `.npy` file: magic, a version, a header length (right or not), the header and data.
fn npy_file(version: u8, header: &str, declared: Option<u32>, data: usize) -> Vec<u8> {
    let mut out = b"\x93NUMPY".to_vec();
    out.extend_from_slice(&[version, 0]);
    let len = declared.unwrap_or(header.len() as u32);
    if version == 1 {
        out.extend_from_slice(&(len as u16).to_le_bytes());
    } else {
        out.extend_from_slice(&len.to_le_bytes());
    }
    out.extend_from_slice(header.as_bytes());
    out.extend(std::iter::repeat_n(0x3f, data));
    out
}

proptest! {
    #![proptest_config(fixed(400))]

    #[test]
    fn npy_headers_never_panic_and_stay_linear(
        tokens in prop::collection::vec(npy_token(), 0..40),
        braces in 0usize..64,
        version in 0u8..4,
        declared in prop::option::of(any::<u32>()),
        data in 0usize..200,
    ) {
        let header = format!("{}{}", "{".repeat(braces), tokens.concat());
        let bytes = npy_file(version, &header, declared, data);
        let start = std::time::Instant::now();
        ok_or_one_line(nerf::io::npy::parse_npy_header(&bytes))?;
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.npy");
        std::fs::write(&path, &bytes).unwrap();
        ok_or_one_line(nerf::io::npy::read_npy_image(&path, 2, 2))?;
        prop_assert!(start.elapsed().as_millis() < 200, "{:?}", start.elapsed());
    }

    #[test]
    fn mutated_npy_arrays_never_panic(mutations in prop::collection::vec(mutation(), 1..4)) {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.npy");
        let values: Vec<f32> = (0..12).map(|i| i as f32 / 12.0).collect();
        nerf::io::images::write_npy(&path, &[2, 2, 3], &values).unwrap();
        let mut bytes = std::fs::read(&path).unwrap();
        apply(&mut bytes, &mutations);
        std::fs::write(&path, &bytes).unwrap();
        ok_or_one_line(nerf::io::npy::read_npy_image(&path, 2, 2))?;
    }
}

#[test]
fn unmutated_fixtures_load() {
    // The mutation tests start from files that load: a regression check that the fuzzed
    // readers accept the real formats.
    let params = tiny_params();
    for name in TORCH_FIXTURES
        .iter()
        .chain(&["tiny_nerf_homework.safetensors"])
    {
        let bytes = std::fs::read(fixtures().join(name)).unwrap();
        load_checkpoint(&bytes, &params).unwrap();
        if name.ends_with(".pth") {
            // Re-zipping keeps them loadable.
            load_checkpoint(&rezip(&members(&bytes)), &params).unwrap();
        }
    }
}
