"""COLMAP 4 through the `pycolmap` wheel, as the stages `nerf process` runs.

`nerf process` writes this file into `OUT/colmap/` and runs it as
`python3 pycolmap_stages.py STAGE --Option value ...`, with the stage names and options of
COLMAP's command line (`feature_extractor --SiftExtraction.max_num_features 8192`, ...), so
that one Rust driver runs either this or Debian's `colmap` program. It prints the progress
lines COLMAP's command line prints (`Processed file [i/N]`, `Matching image [i/N]`,
`Registering image #id (n)`), which the driver's progress bars follow.

Written by hand because pycolmap is a library, not a command line: this is the thin layer
that calls it. Two stages are the project's own, not COLMAP's:
- `retrieval_matcher`: pairs each image with its most similar images by a bag of visual
  words built from the database's own SIFT descriptors (k-means, tf-idf, cosine
  similarity), then matches those pairs. COLMAP's vocabulary-tree matcher does the same with
  a tree trained on Flickr photos, which the wheel does not ship and a machine without a
  network cannot download.
- `sequential_matcher --retrieval_neighbours K`: sequential matching, then the retrieval
  pairs, which close the loop of a walk-around without a vocabulary tree.
"""

import os
import sys
import time

STAGES = (
    "help",
    "feature_extractor",
    "exhaustive_matcher",
    "sequential_matcher",
    "retrieval_matcher",
    "mapper",
    "global_mapper",
    "point_filtering",
    "bundle_adjuster",
)


def fail(message):
    # The driver quotes this last line in its own one-line error.
    print(message, flush=True)
    sys.exit(1)


def parse(argv):
    """`--Key value` pairs into a dict (keys without the dashes)."""
    if len(argv) % 2:
        fail(f"options come in `--Key value` pairs, got {argv}")
    pairs = {}
    for key, value in zip(argv[::2], argv[1::2]):
        if not key.startswith("--"):
            fail(f"expected an option `--Key`, got {key!r}")
        pairs[key[2:]] = value
    return pairs


def assign(target, name, text):
    """Sets `target.name` from `text`, converted to the type the attribute has."""
    if not hasattr(target, name):
        fail(f"unknown option {name} of {type(target).__name__}")
    current = getattr(target, name)
    if isinstance(current, bool):
        value = text.strip().lower() in ("1", "true", "yes")
    elif isinstance(current, int):
        value = int(text)
    elif isinstance(current, float):
        value = float(text)
    else:
        value = text
    setattr(target, name, value)


def take(options, prefix, target):
    """Applies every `prefix.name` option to `target` and removes it from `options` (COLMAP's
    `use_gpu` options are dropped: the wheel runs on the CPU)."""
    for key in [k for k in options if k.startswith(prefix + ".")]:
        if key.endswith(".use_gpu"):
            options.pop(key)
            continue
        assign(target, key[len(prefix) + 1 :], options.pop(key))


def required(options, key):
    if key not in options:
        fail(f"--{key} is required")
    return options.pop(key)


def finish(options):
    """Ignores options for COLMAP's GPU and refuses any other left over."""
    for key in list(options):
        if key.endswith("use_gpu"):
            options.pop(key)
    if options:
        fail(f"unknown options: {', '.join('--' + k for k in options)}")


def matching_options(pycolmap, options):
    matching = pycolmap.FeatureMatchingOptions()
    matching.use_gpu = False
    take(options, "SiftMatching", matching.sift)
    take(options, "FeatureMatching", matching)
    return matching


def count_pairs(pycolmap, database):
    with pycolmap.Database.open(database) as db:
        return db.num_matched_image_pairs()


def feature_extractor(pycolmap, options):
    database = required(options, "database_path")
    images = required(options, "image_path")
    reader = pycolmap.ImageReaderOptions()
    single = options.pop("ImageReader.single_camera", "0") == "1"
    take(options, "ImageReader", reader)
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.use_gpu = False
    size = options.pop("SiftExtraction.max_image_size", None)
    if size is not None:
        extraction.max_image_size = int(size)
    take(options, "SiftExtraction", extraction.sift)
    finish(options)
    mode = pycolmap.CameraMode.SINGLE if single else pycolmap.CameraMode.AUTO
    # One call for all images (a call per batch would give each batch a camera of its own);
    # COLMAP's log prints `Processed file [i/N]` per image, which the driver follows.
    pycolmap.extract_features(
        database,
        images,
        camera_mode=mode,
        reader_options=reader,
        extraction_options=extraction,
        device=pycolmap.Device.cpu,
    )
    with pycolmap.Database.open(database) as db:
        print(f"Extracted features of {db.num_images()} images, {db.num_cameras()} camera(s)", flush=True)


def match_pairs(pycolmap, options, database, pairing, prefix, match):
    """Runs one of pycolmap's matchers (`match`) with the options of `prefix` set on
    `pairing`; returns the matching options for a later stage."""
    matching = matching_options(pycolmap, options)
    take(options, prefix, pairing)
    finish(options)
    match(database, matching_options=matching, pairing_options=pairing, device=pycolmap.Device.cpu)
    return matching


def exhaustive_matcher(pycolmap, options):
    database = required(options, "database_path")
    pairing = pycolmap.ExhaustivePairingOptions()
    match_pairs(pycolmap, options, database, pairing, "ExhaustiveMatching", pycolmap.match_exhaustive)
    print(f"Matched {count_pairs(pycolmap, database)} image pairs", flush=True)


def sequential_matcher(pycolmap, options):
    database = required(options, "database_path")
    neighbours = int(options.pop("retrieval_neighbours", "0"))
    pairing = pycolmap.SequentialPairingOptions()
    matching = match_pairs(
        pycolmap, options, database, pairing, "SequentialMatching", pycolmap.match_sequential
    )
    print(f"Matched {count_pairs(pycolmap, database)} image pairs sequentially", flush=True)
    if neighbours > 0:
        match_retrieved(pycolmap, database, matching, neighbours)


def retrieval_matcher(pycolmap, options):
    database = required(options, "database_path")
    neighbours = int(options.pop("retrieval_neighbours", "20"))
    matching = matching_options(pycolmap, options)
    finish(options)
    match_retrieved(pycolmap, database, matching, neighbours)


def match_retrieved(pycolmap, database, matching, neighbours):
    """Matches each image with its `neighbours` most similar images by visual words."""
    import os
    import tempfile

    import numpy as np

    with pycolmap.Database.open(database) as db:
        images = sorted(db.read_all_images(), key=lambda i: i.name)
        descriptors = []
        for image in images:
            d = db.read_descriptors(image.image_id)
            d = d if isinstance(d, np.ndarray) else d.data
            descriptors.append(evenly_spaced(np.asarray(d), PER_IMAGE))
    names = [i.name for i in images]
    # COLMAP's pair lists split a line at spaces and skip lines that start with '#'.
    awkward = [n for n in names if any(c.isspace() for c in n) or n.startswith("#")]
    if awkward:
        fail(f"retrieval matching cannot list photo names with spaces or a leading '#' ({awkward[0]!r}): rename them or use --matcher exhaustive")
    pairs = retrieval_pairs(names, descriptors, neighbours)
    folder = os.path.dirname(os.path.abspath(database))
    with tempfile.NamedTemporaryFile(
        "w", suffix=".txt", prefix="retrieval_pairs", dir=folder, delete=False
    ) as f:
        for a, b in pairs:
            f.write(f"{a} {b}\n")
        path = f.name
    print(f"Retrieved {len(pairs)} image pairs ({neighbours} per image)", flush=True)
    try:
        pairing = pycolmap.ImportedPairingOptions()
        pairing.match_list_path = path
        pycolmap.match_image_pairs(
            database, matching_options=matching, pairing_options=pairing,
            device=pycolmap.Device.cpu,
        )
    finally:
        os.remove(path)
    print(f"Matched {count_pairs(pycolmap, database)} image pairs in all", flush=True)


# Descriptors per image that describe it for retrieval (evenly spaced over the image's list).
PER_IMAGE = 1000


def evenly_spaced(rows, count):
    """At most `count` rows of `rows`, evenly spaced (all when there are fewer)."""
    import numpy as np

    if len(rows) <= count:
        return rows
    return rows[np.linspace(0, len(rows) - 1, count).astype(np.int64)]


def unit_rows(rows):
    import numpy as np

    rows = np.asarray(rows, dtype=np.float32)
    return rows / (np.linalg.norm(rows, axis=1, keepdims=True) + 1e-12)


def retrieval_pairs(names, descriptors, neighbours, words=1024, seed=0):
    """Pairs (name, name) of each image with its most similar images: a bag of visual words
    by k-means over a sample of the descriptors, tf-idf weights, cosine similarity. No
    self-pairs, each pair once."""
    import numpy as np

    rng = np.random.default_rng(seed)
    total = sum(len(d) for d in descriptors)
    if len(names) < 2 or total < 2:
        return []
    words = max(2, min(words, total // 20))
    # The k-means sample, drawn image by image (no copy of every descriptor at once).
    share = max(1, (50 * words) // len(names))
    sample = unit_rows(
        np.concatenate(
            [d[rng.choice(len(d), size=min(len(d), share), replace=False)] for d in descriptors if len(d)]
        )
    )
    words = min(words, len(sample))
    centres = sample[rng.choice(len(sample), size=words, replace=False)]
    for _ in range(8):
        labels = nearest(sample, centres)
        sums = np.zeros_like(centres)
        np.add.at(sums, labels, sample)
        counts = np.bincount(labels, minlength=words)[:, None]
        centres = np.where(counts > 0, sums / np.maximum(counts, 1), centres)
        centres = unit_rows(centres)
    histograms = np.zeros((len(names), words), dtype=np.float32)
    for i, d in enumerate(descriptors):
        if len(d):
            histograms[i] = np.bincount(nearest(unit_rows(d), centres), minlength=words)
    document_frequency = (histograms > 0).sum(axis=0)
    histograms *= np.log(len(names) / np.maximum(document_frequency, 1))[None, :]
    histograms /= np.linalg.norm(histograms, axis=1, keepdims=True) + 1e-12
    similarity = histograms @ histograms.T
    np.fill_diagonal(similarity, -np.inf)
    k = min(neighbours, len(names) - 1)
    pairs = set()
    for i in range(len(names)):
        for j in np.argsort(-similarity[i])[:k]:
            pairs.add((min(i, int(j)), max(i, int(j))))
    return [(names[a], names[b]) for a, b in sorted(pairs)]


def nearest(points, centres):
    """The index of each point's nearest centre (unit vectors: the largest dot product)."""
    import numpy as np

    labels = np.empty(len(points), dtype=np.int64)
    for start in range(0, len(points), 65536):
        labels[start : start + 65536] = np.argmax(points[start : start + 65536] @ centres.T, axis=1)
    return labels


def mapping_paths(options):
    """The database, the photos' folder and the output folder of a mapper stage."""
    return tuple(required(options, k) for k in ("database_path", "image_path", "output_path"))


def seed_all(options, *targets):
    """Sets the stage's `random_seed` option, when given, on each of `targets`."""
    seed = options.pop("random_seed", None)
    if seed is not None:
        for target in targets:
            target.random_seed = int(seed)


def mapper(pycolmap, options):
    database, images, output = mapping_paths(options)
    pipeline = pycolmap.IncrementalPipelineOptions()
    seed_all(options, pipeline, pipeline.mapper, pipeline.triangulation)
    take(options, "Mapper", pipeline.mapper)
    take(options, "Pipeline", pipeline)
    finish(options)
    registered = [0]

    def initial_pair():
        registered[0] = 2
        print("Initializing with image pair", flush=True)

    def next_image():
        registered[0] += 1
        print(f"Registering image #0 ({registered[0]})", flush=True)

    models = pycolmap.incremental_mapping(
        database, images, output, options=pipeline,
        initial_image_pair_callback=initial_pair, next_image_callback=next_image,
    )
    report(models)


def global_mapper(pycolmap, options):
    database, images, output = mapping_paths(options)
    pipeline = pycolmap.GlobalPipelineOptions()
    seed_all(options, pipeline)
    take(options, "GlobalMapper", pipeline)
    finish(options)
    models = pycolmap.global_mapping(database, images, output, options=pipeline)
    report(models)


def report(models):
    sizes = sorted((m.num_reg_images() for m in models.values()), reverse=True)
    print(f"Models: {len(sizes)}, registered images: {sizes}", flush=True)


def point_filtering(pycolmap, options):
    source = required(options, "input_path")
    output = required(options, "output_path")
    pixels = float(options.pop("max_reproj_error", "4"))
    finish(options)
    model = pycolmap.Reconstruction(source)
    manager = pycolmap.ObservationManager(model)
    # Reprojection error only (COLMAP's point_filtering also drops points seen at under
    # 1.5 degrees or by fewer than 2 images, which the mapper's own filters already did).
    points = set(model.point3D_ids())
    removed = manager.filter_points3D_with_large_reprojection_error(pixels, points)
    model.write(output)
    print(f"Filtered observations: {removed}", flush=True)


# A camera's parameters in OPENCV's layout (fx, fy, cx, cy, k1, k2, p1, p2), from the simpler
# models the mapper may have used: the terms they lack start at zero.
def as_opencv(pycolmap, camera):
    p = list(camera.params)
    name = camera.model.name
    if name == "SIMPLE_PINHOLE":
        params = [p[0], p[0], p[1], p[2], 0.0, 0.0, 0.0, 0.0]
    elif name == "PINHOLE":
        params = p + [0.0, 0.0, 0.0, 0.0]
    elif name == "SIMPLE_RADIAL":
        params = [p[0], p[0], p[1], p[2], p[3], 0.0, 0.0, 0.0]
    elif name == "RADIAL":
        params = [p[0], p[0], p[1], p[2], p[3], p[4], 0.0, 0.0]
    else:
        return camera
    return pycolmap.Camera(
        model="OPENCV", width=camera.width, height=camera.height,
        params=params, camera_id=camera.camera_id,
    )


def bundle_adjuster(pycolmap, options):
    """COLMAP's bundle adjustment. With `--camera_model OPENCV --lens_output_path P` it also
    adjusts a copy whose cameras are turned into OPENCV, with the `--BundleAdjustment.*`
    options (the plain adjustment keeps COLMAP's defaults), and writes it to P: the driver
    compares the two and keeps one."""
    source = required(options, "input_path")
    output = required(options, "output_path")
    camera_model = options.pop("camera_model", None)
    lens_output = options.pop("lens_output_path", None)
    adjustment = pycolmap.BundleAdjustmentOptions()
    adjustment.print_summary = False
    take(options, "BundleAdjustment", adjustment)
    finish(options)
    if camera_model is not None and (camera_model != "OPENCV" or lens_output is None):
        fail("--camera_model takes OPENCV, with --lens_output_path")
    model = pycolmap.Reconstruction(source)
    if camera_model is None:
        pycolmap.bundle_adjustment(model, adjustment)
    else:
        plain = pycolmap.BundleAdjustmentOptions()
        plain.print_summary = False
        pycolmap.bundle_adjustment(model, plain)
        richer = pycolmap.Reconstruction(model)
        for camera_id in list(richer.cameras):
            richer.cameras[camera_id] = as_opencv(pycolmap, richer.cameras[camera_id])
        pycolmap.bundle_adjustment(richer, adjustment)
        os.makedirs(lens_output, exist_ok=True)
        richer.write(lens_output)
        print(f"Bundle-adjusted {richer.num_reg_images()} images with {camera_model}", flush=True)
    model.write(output)
    print(f"Bundle-adjusted {model.num_reg_images()} images", flush=True)


def main():
    if len(sys.argv) < 2 or sys.argv[1] not in STAGES:
        fail(f"the first argument is a stage: {', '.join(STAGES)}")
    stage = sys.argv[1]
    try:
        import pycolmap
    except ImportError as e:
        fail(f"cannot import pycolmap ({e})")
    if stage == "help":
        print(f"pycolmap {pycolmap.__version__} (COLMAP {pycolmap.COLMAP_version})", flush=True)
        return
    options = parse(sys.argv[2:])
    start = time.time()
    globals()[stage](pycolmap, options)
    print(f"{stage}: {time.time() - start:.1f} s", flush=True)


if __name__ == "__main__":
    main()
