#!/usr/bin/env bash
# Shows that `cargo build --release --features cuda` compiles and links on a machine with no GPU
# and no system CUDA: it assembles a CUDA 13.4 toolkit from NVIDIA's PyPI wheels, builds the
# library and the `nerf` binary with Candle's CUDA backend into target/cuda (so the CPU build in
# target/release is left alone), and prints a one-line verdict. Nothing here runs on a GPU.
#
#   scripts/check_cuda_build.sh            set up the toolkit if missing, then build
#   scripts/check_cuda_build.sh --setup    only set up the toolkit and print the variables
#
# Idempotent: a second run reuses the toolkit and the incremental build. Exit 0 when the build
# succeeds, 1 when cargo fails, 2 when the toolkit cannot be set up. See docs/cuda.md.
#
# Environment (all optional):
#   NERF_CUDA_TOOLCHAIN  where the toolkit goes (default: target/cuda-toolchain, git-ignored)
#   CUDA_COMPUTE_CAP     the GPU generation the kernels are built for (default: 80, Ampere);
#                        Candle needs it when no GPU can be queried
#   CUDAFORGE_THREADS    parallel nvcc jobs in candle-kernels' build script (default: 2)
#   NICE                 niceness of the build (default: 15)
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"

# The CUDA release: cudarc 0.19 (Candle 0.11's driver bindings) knows up to 13.4, and
# 13.x is the first series whose `nvidia-cuda-nvcc` wheel carries nvcc itself (12.x's has only
# ptxas). The `cuda-toolkit` meta-package pins the component wheels to one consistent release.
CUDA_TOOLKIT_WHEEL='cuda-toolkit[nvcc,cudart,cccl,crt,nvrtc,cublas,curand]==13.4.3'
TOOLCHAIN="${NERF_CUDA_TOOLCHAIN:-$ROOT/target/cuda-toolchain}"
VENV="$TOOLCHAIN/venv"
STAMP="$TOOLCHAIN/installed.txt"
export CUDA_COMPUTE_CAP="${CUDA_COMPUTE_CAP:-80}"
export CUDAFORGE_THREADS="${CUDAFORGE_THREADS:-2}"
NICE="${NICE:-15}"

fail_setup() {
    echo "CUDA BUILD: SETUP FAILED: $*"
    exit 2
}

# 1. The wheels, in a venv of their own.
if [[ ! -f "$STAMP" || "$(cat "$STAMP")" != "$CUDA_TOOLKIT_WHEEL" ]]; then
    echo "== installing $CUDA_TOOLKIT_WHEEL into $VENV"
    rm -rf "$VENV"
    python3 -m venv "$VENV" || fail_setup "python3 -m venv"
    "$VENV/bin/pip" install --quiet --disable-pip-version-check "$CUDA_TOOLKIT_WHEEL" ||
        fail_setup "pip install $CUDA_TOOLKIT_WHEEL"
    echo "$CUDA_TOOLKIT_WHEEL" >"$STAMP"
fi
CUDA_ROOT="$("$VENV/bin/python" -c 'import nvidia, os; print(os.path.join(nvidia.__path__[0], "cu13"))')"
[[ -x "$CUDA_ROOT/bin/nvcc" ]] || fail_setup "no nvcc at $CUDA_ROOT/bin/nvcc"

# 2. What the wheels leave out of a toolkit's usual layout, so that `-lcudart` and friends
#    resolve when the `nerf` binary is linked:
#    - the unversioned names of the shared libraries (the wheels ship libcudart.so.13 only);
#    - lib/stubs/libcuda.so, the driver API (in a real install the GPU driver provides
#      libcuda.so.1 and the toolkit a link-time stub). The wheels have no stub, so one is made
#      here: an empty function for every driver entry point named in cuda.h and in cudarc's
#      bindings, with the driver's soname, so the binary records `NEEDED libcuda.so.1` and uses
#      the real driver at run time. The stub is only linked against, never loaded.
for lib in cudart cublas cublasLt curand nvrtc; do
    versioned="$(cd "$CUDA_ROOT/lib" && ls "lib$lib.so."* 2>/dev/null | sort | head -n1 || true)"
    [[ -n "$versioned" ]] || fail_setup "no lib$lib.so.* in $CUDA_ROOT/lib"
    ln -sfn "$versioned" "$CUDA_ROOT/lib/lib$lib.so"
done
STUB="$CUDA_ROOT/lib/stubs/libcuda.so"
if [[ ! -f "$STUB" ]]; then
    echo "== generating the link-time stub $STUB"
    mkdir -p "$CUDA_ROOT/lib/stubs"
    cudarc_dir="$(cargo metadata --format-version 1 --features cuda 2>/dev/null |
        python3 -c 'import json, os, sys
pkgs = json.load(sys.stdin)["packages"]
print(next(os.path.dirname(p["manifest_path"]) for p in pkgs if p["name"] == "cudarc"))')" ||
        fail_setup "cargo metadata found no cudarc under --features cuda"
    {
        # cuda.h after the preprocessor: the versioned names (cuMemAlloc_v2, ...) it maps to.
        gcc -E -P -I"$CUDA_ROOT/include" "$CUDA_ROOT/include/cuda.h" | tr '\n' ' ' |
            grep -oE 'CUresult +(__attribute__ *\(\([^)]*\)\) *)?cu[A-Za-z0-9_]+ *\(' |
            grep -oE 'cu[A-Za-z0-9_]+ *\($' | tr -d ' ('
        # Every entry point cudarc declares, for any CUDA version.
        grep -ohE '^\s+fn cu[A-Za-z0-9_]+\(' "$cudarc_dir/src/driver/sys/mod.rs" |
            grep -oE 'cu[A-Za-z0-9_]+'
    } | sort -u | sed 's/.*/void &(void) {}/' >"$TOOLCHAIN/libcuda_stub.c"
    [[ "$(wc -l <"$TOOLCHAIN/libcuda_stub.c")" -gt 100 ]] || fail_setup "too few driver symbols for the stub"
    gcc -shared -fPIC -Wl,-soname,libcuda.so.1 -o "$STUB" "$TOOLCHAIN/libcuda_stub.c" ||
        fail_setup "compiling the libcuda stub"
fi

export PATH="$CUDA_ROOT/bin:$PATH"
export CUDA_ROOT CUDA_PATH="$CUDA_ROOT" CUDA_HOME="$CUDA_ROOT"
nvcc_version="$(nvcc --version | sed -n 's/.*release \([0-9.]*\),.*/\1/p')"
echo "== nvcc $nvcc_version at $CUDA_ROOT/bin/nvcc; host compiler $(gcc -dumpfullversion); CUDA_COMPUTE_CAP=$CUDA_COMPUTE_CAP"

if [[ "${1:-}" == "--setup" ]]; then
    echo "export PATH=\"$CUDA_ROOT/bin:\$PATH\" CUDA_ROOT=\"$CUDA_ROOT\" CUDA_PATH=\"$CUDA_ROOT\" CUDA_HOME=\"$CUDA_ROOT\" CUDA_COMPUTE_CAP=$CUDA_COMPUTE_CAP"
    exit 0
fi

# 3. The build, in its own target directory.
LOG="$ROOT/target/cuda/build.log"
mkdir -p "$ROOT/target/cuda"
start=$(date +%s)
set +e
CARGO_PROFILE_RELEASE_INCREMENTAL=true nice -n "$NICE" \
    cargo build --release --features cuda --lib --bin nerf --target-dir target/cuda 2>&1 | tee "$LOG"
status=${PIPESTATUS[0]}
set -e
elapsed=$(($(date +%s) - start))
took="$((elapsed / 60))m$((elapsed % 60))s"

if [[ $status -eq 0 ]]; then
    bin="target/cuda/release/nerf"
    size() { du -h "$1" | cut -f1; }
    cuda_libs="$(readelf -d "$bin" | grep -oE 'lib(cuda|cudart|cublas|cublasLt|curand|nvrtc)\.so[.0-9]*' | sort -u | tr '\n' ' ')"
    echo "CUDA BUILD: OK in $took (CUDA $nvcc_version, sm_$CUDA_COMPUTE_CAP): $bin $(size "$bin"), libnerf.rlib $(size target/cuda/release/libnerf.rlib); links ${cuda_libs% }"
    exit 0
fi
first_error="$(grep -m1 -E '^error|panicked|error:' "$LOG" || true)"
echo "CUDA BUILD: FAILED after $took (exit $status): ${first_error:-see $LOG}"
exit 1
