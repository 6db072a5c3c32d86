#!/usr/bin/env bash
# Where the time of the hash-grid field goes, per stage: records perf profiles of
#   (i)  hash-grid training steps: `nerf bench --only ngp-train` (the shipped nerf_lego_ngp
#        config, 16384 samples a step, from the shipped checkpoint, on ../shared/data/lego);
#   (ii) 400x400 hash-grid frames: `nerf bench --only ngp-render-400` (lego_ngp_400);
# and prints, for each, the share of every stage (hash encoding, MLP gemm, compositing,
# sampling and occupancy, allocation, ...) with its top symbols (scripts/perf_stages.py).
#
# usage: scripts/profile.sh [OUT_DIR]      (default target/profile; run from anywhere)
# env:   NERF_BIN      the binary to profile (default: cargo build --release, then its binary)
#        STEPS         timed training steps (default 100; 4 untimed ones come first)
#        VIEWS         400x400 frames (default 3)
#        FREQ          samples per second per thread (default 499)
#        PERF_EVENT    the event to sample (default: cycles where the VM allows it, else
#                      cpu-clock)
#
# Needs perf (Debian: linux-perf; installed with apt-get when missing and this runs as root)
# and python3. Call graphs are unwound from the stack with DWARF CFI (--call-graph dwarf), so
# the release build needs no debug info or frame pointers. Setup (dataset and checkpoint
# loading, model initialisation) is counted apart and left out of the stage percentages.
set -euo pipefail

root=$(cd "$(dirname "$0")/.." && pwd)
out=${1:-$root/target/profile}
mkdir -p "$out"
out=$(cd "$out" && pwd)
steps=${STEPS:-100}
views=${VIEWS:-3}
freq=${FREQ:-499}

if ! command -v perf >/dev/null; then
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
        apt-get install -y linux-perf >/dev/null
    else
        echo "perf is missing: install Debian's linux-perf (apt-get install linux-perf)" >&2
        exit 1
    fi
fi

bin=${NERF_BIN:-}
if [ -z "$bin" ]; then
    (cd "$root" && cargo build --release --quiet)
    bin=${CARGO_TARGET_DIR:-$root/target}/release/nerf
fi

event=${PERF_EVENT:-}
if [ -z "$event" ]; then
    if perf record -q -e cycles -o /dev/null -- true >/dev/null 2>&1; then
        event=cycles
    else
        # Many VMs expose no hardware counters: sample on the kernel's timer instead.
        event=cpu-clock
    fi
fi
echo "perf $(perf --version | awk '{print $3}'), event $event, $freq Hz; load: $(uptime | sed 's/.*load average: //')"

record() { # NAME ARGS...
    local name=$1
    shift
    (cd "$root" && perf record -q -e "$event" -F "$freq" --call-graph dwarf,32768 \
        -o "$out/$name.data" -- "$bin" "$@" >"$out/$name.table.md" 2>"$out/$name.log")
    perf script -i "$out/$name.data" -F tid,period,ip,sym,symoff 2>/dev/null >"$out/$name.txt"
    grep '^| hash-grid' "$out/$name.table.md" || true
}

record train bench --config box --only ngp-train --train-steps "$steps"
record render bench --config box --only ngp-render-400 --views "$views"

# The binary is given so that closures run on rayon's workers (whose stacks do not show who
# started them) are placed by its static call graph.
python3 "$root/scripts/perf_stages.py" "hash-grid training, $steps steps of nerf_lego_ngp" "$bin" \
    <"$out/train.txt" | tee "$out/train.stages"
echo
python3 "$root/scripts/perf_stages.py" "hash-grid 400x400 frames of lego_ngp_400, $views views" "$bin" \
    <"$out/render.txt" | tee "$out/render.stages"
echo
echo "profiles: $out/{train,render}.data (perf report -i FILE --no-children --sort symbol)"
