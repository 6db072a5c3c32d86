#!/usr/bin/env bash
# Downloads the NeRF-synthetic "lego" scene (Mildenhall et al., ECCV 2020) for `nerf`.
#
# Usage: scripts/download_lego.sh [DEST_DIR [ZIP_URL_OR_FILE]]
#
#   DEST_DIR         where the scene goes (default: ../shared/data/lego next to this repository,
#                    which is the default data.data_dir for dataset_name "lego").
#   ZIP_URL_OR_FILE  a URL or an already downloaded zip holding nerf_synthetic/lego
#                    (default: $NERF_DATA_URL, else the original authors' example-data zip).
#
# Sources:
#   * nerf_example_data.zip, the original NeRF authors' example data (nerf_synthetic/lego and
#     nerf_llff_data/fern), from
#     http://cseweb.ucsd.edu/~viscomp/projects/LF/papers/ECCV20/nerf/nerf_example_data.zip
#   * nerf_synthetic.zip, the full data release (all eight scenes), from the project's Google
#     Drive folder https://drive.google.com/drive/folders/128yBriW1IG_3NJ5Rp7APSTZsJqdJdfc1 .
#     Google Drive needs a browser (or a tool such as gdown); download it by hand and pass the
#     zip file as the second argument.
#
# Afterwards DEST_DIR holds transforms_{train,val,test}.json and {train,val,test}/r_*.png.
# Images are 800×800 RGBA; `nerf` resizes them to data.image_size when loading.
set -euo pipefail

repo_root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
dest="${1:-$repo_root/../shared/data/lego}"
source="${2:-${NERF_DATA_URL:-http://cseweb.ucsd.edu/~viscomp/projects/LF/papers/ECCV20/nerf/nerf_example_data.zip}}"

for tool in unzip find; do
    command -v "$tool" >/dev/null || { echo "error: $tool is required" >&2; exit 1; }
done

if [[ -f "$dest/transforms_train.json" ]]; then
    echo "lego scene already present in $dest"
    exit 0
fi
if [[ -e "$dest" ]] && [[ -n "$(ls -A "$dest")" ]]; then
    echo "error: $dest exists and is not empty; move it away or pick another DEST_DIR" >&2
    exit 1
fi

work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT

if [[ -f "$source" ]]; then
    zip="$source"
else
    command -v curl >/dev/null || { echo "error: curl is required" >&2; exit 1; }
    zip="$work/data.zip"
    echo "downloading $source"
    curl --fail --location --retry 3 --output "$zip" "$source"
fi

echo "extracting the lego scene"
unzip -q "$zip" '*lego/*' -d "$work/unzipped" || {
    echo "error: cannot extract a lego/ folder from $source" >&2
    exit 1
}
transforms="$(find "$work/unzipped" -path '*lego/transforms_train.json' -not -path '*__MACOSX*' -print -quit)"
if [[ -z "$transforms" ]]; then
    echo "error: no lego/transforms_train.json in $source" >&2
    exit 1
fi

mkdir -p "$(dirname "$dest")"
rmdir "$dest" 2>/dev/null || true
mv "$(dirname "$transforms")" "$dest"
echo "lego scene written to $dest"
