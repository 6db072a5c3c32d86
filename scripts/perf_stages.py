#!/usr/bin/env python3
"""Groups the samples of a `perf script -F tid,period,ip,sym,symoff` dump (recorded with
`--call-graph dwarf`) into the stages of a hash-grid step or frame, and prints the share of each
stage with its top leaf symbols. Used by scripts/profile.sh.

Each sample is given the stage of the first frame, walking from the leaf towards the root,
whose function name says which stage it belongs to (hash encoding, MLP gemm, ...). Generic
frames (closures, rayon, std, memset/memcpy) are passed over, so their time goes to the stage
that called them. A rayon closure run on a worker thread has no named caller on its stack; its
stage is the one its function (by address) had on the stacks where the caller was visible,
else the stage of the named functions it calls (e.g. the table gradient's scatter calls the
hash encoding's `Level::corners`).
Samples inside setup (dataset and checkpoint loading, model initialisation, argument
parsing) are counted apart and left out of the stage percentages.

Closures that no stack places are placed by the static call graph of BINARY when it is given: the
nearest named function that calls them, through rayon's monomorphised plumbing (a job's
function is handed over by address, which the disassembly shows as a rip-relative load).

usage: perf_stages.py TITLE [BINARY] < perf-script.txt
"""

import re
import subprocess
import sys
from collections import Counter, defaultdict

# Anywhere on the stack: setup, left out of the percentages.
SETUP = re.compile(
    r"load_frame_image|Dataset::load|load_model|load_field|TrainModel::load|from_checkpoint|"
    r"::seeded|Optimizer::new|clap_builder|checkpoint::load|Config::load|Config::from_yaml|"
    r"bench_gemm|_dl_|dl_main|run_benchmarks.*drop|drop_in_place<nerf::io::dataset"
)
# Anywhere on the stack: reported as a context (share of the steps spent under it).
CONTEXTS = {
    "occupancy-grid update (training)": re.compile(r"OccupancyGrid::update"),
    "backward pass (Candle backprop + fused kernels' backward)": re.compile(
        r"Tensor::backward|::backward\b|KernelGradients|CpuKernel<\d+_usize>>::gradients"
    ),
}
WAITING = "threads waiting (barriers, idle workers)"
# Leaf-first: the first frame matching one of these (in this order of priority within a frame)
# decides the stage.
STAGES = [
    ("allocation (page faults, zeroing, malloc/free)",
     re.compile(r"clear_page|page_fault|folio|^_?mi_|mi_malloc|mi_free|__rust_alloc|"
                r"__rust_dealloc|__rdl_|munmap|mmap|madvise|do_anonymous|alloc_pages|"
                r"zap_|free_pages|release_pages|tlb_")),
    (WAITING,
     re.compile(r"BarrierGuard|sched_yield|futex|rayon_core::sleep|crossbeam|"
                r"finish_task_switch|__schedule|schedule$|do_nanosleep")),
    ("optimiser (sparse Adam on the table, Adam on the MLPs)",
     re.compile(r"sparse_adam|train::adam|Optimizer::step")),
    ("hash encoding (forward and table gradient)",
     re.compile(r"hash_grid|hash_block|Ngp::encode|sh_encode|sh_basis")),
    ("MLP gemm (matrix products)", re.compile(r"gemm")),
    ("MLP other (bias, activations, packing)",
     re.compile(r"ngp_mlp|kernels::bias|field::ngp|trunc_exp")),
    ("compositing", re.compile(r"kernels::composite|::composite")),
    ("sampling and occupancy (depths, ray marching, grid tests)",
     re.compile(r"render::skipping|render::occupancy|render::sampler|sample_points|"
                r"rand_chacha|rand::|RayMarch|jittered|StdRng|ChaCha")),
    ("rays and batch (camera rays, targets)",
     re.compile(r"core::rays|camera_model|training_batch|core::camera")),
    ("Candle tensor ops (loss, background, copies)", re.compile(r"candle_core|candle_nn")),
    ("image output and metrics", re.compile(r"core::image|core::metrics|png::|image::")),
]
# Passed over: their time goes to the first named caller.
GENERIC = re.compile(
    r"call_mut|call_once|\{\{closure\}\}|^rayon|^core::|^alloc::|^std::|^<core::|^<alloc::|"
    r"^<std::|__memset|__memmove|__memcpy|^\[unknown\]$|^$|^<rayon|^<&|^<F as"
)
# Closures whose stage is learned by address: the per-item closures of rayon's iterators and
# this crate's own closures (not rayon's or std's, such as the thread-start closure at the root
# of every worker's stack).
CLOSURE = re.compile(r"FnMut<A> for &F>::call_mut|^nerf::.*\{\{closure\}\}")
FRAME = re.compile(r"^\s*([0-9a-f]+)\s+(.*?)(?:\+0x([0-9a-f]+))?(?:\s+\(.*\))?$")


def samples(lines):
    """Yields (period, [(function id, name)]) per sample, leaf first."""
    period, frames = None, []
    for line in lines:
        if not line.strip():
            if period is not None:
                yield period, frames
            period, frames = None, []
            continue
        if not line.startswith("\t"):
            parts = line.split()
            period = int(parts[-1]) if parts and parts[-1].isdigit() else 1
            continue
        m = FRAME.match(line)
        if not m:
            continue
        addr, name, off = m.group(1), m.group(2).strip(), m.group(3)
        start = int(addr, 16) - (int(off, 16) if off else 0)
        frames.append((start, name))
    if period is not None:
        yield period, frames


def stage_of(name):
    for stage, pattern in STAGES:
        if pattern.search(name):
            return stage
    return None


# The leaf frame only: a thread's own loop (a pool worker spinning or parking between jobs).
IDLE_LEAF = re.compile(r"__rust_begin_short_backtrace|thread::functions::park|wait_until")


def classify(frames):
    """(stage or None, closure function ids passed over before the stage was found, the
    closure that called the frame that decided it (within two frames), or None)."""
    if frames and IDLE_LEAF.search(frames[0][1]):
        return WAITING, [], None
    closures = []
    for i, (fid, name) in enumerate(frames):
        if GENERIC.search(name):
            if CLOSURE.search(name):
                closures.append(fid)
            continue
        stage = stage_of(name)
        if stage:
            caller = next(
                (f for f, n in frames[i + 1:i + 3] if CLOSURE.search(n)), None)
            return stage, closures, caller
    return None, closures, None


def static_callers(binary):
    """(function start -> demangled name, function start -> the functions that call it or
    take its address), from the disassembly of `binary` (direct calls and jumps, calls through
    the GOT, and rip-relative address loads, which is how rayon's jobs are handed over)."""
    got = {}
    relocs = subprocess.run(["readelf", "-rW", binary], capture_output=True, text=True)
    for line in relocs.stdout.splitlines():
        p = line.split()
        if len(p) >= 4 and p[2] == "R_X86_64_RELATIVE":
            got[int(p[0], 16)] = int(p[-1], 16)
    names, callers, cur = {}, defaultdict(set), None
    head = re.compile(r"^([0-9a-f]+) <(.*)>:$")
    ref = re.compile(r"(?:call|jmp)\s+([0-9a-f]+) <(.*)>$|# ([0-9a-f]+) <(.*)>$")
    dis = subprocess.run(["objdump", "-d", "--no-show-raw-insn", "-C", binary],
                         capture_output=True, text=True)
    for line in dis.stdout.splitlines():
        m = head.match(line)
        if m:
            cur = int(m.group(1), 16)
            names[cur] = m.group(2)
            continue
        m = ref.search(line)
        if not m or cur is None:
            continue
        target = int(m.group(1) or m.group(3), 16)
        symbol = m.group(2) or m.group(4)
        if "+0x" not in symbol and "@plt" not in symbol:
            callers[target].add(cur)
        elif "_DYNAMIC" in symbol or "_GLOBAL_OFFSET_TABLE_" in symbol:
            if target in got:
                callers[got[target]].add(cur)
    return names, callers


def stage_by_callers(start, names, callers, depth=24):
    """The stage of the nearest named caller of the function at `start` (breadth first)."""
    seen, frontier = {start}, [start]
    for _ in range(depth):
        nxt = []
        for f in frontier:
            for c in callers.get(f, ()):
                if c in seen:
                    continue
                seen.add(c)
                name = names.get(c, "")
                if SETUP.search(name):
                    return "setup", name
                if not GENERIC.search(name) and stage_of(name):
                    return stage_of(name), name
                nxt.append(c)
        frontier = nxt
    return None, None


def main():
    title = sys.argv[1] if len(sys.argv) > 1 else "profile"
    data = list(samples(sys.stdin))
    learned = defaultdict(Counter)
    callers = defaultdict(Counter)
    resolved = []
    for period, frames in data:
        names = [n for _, n in frames]
        if any(SETUP.search(n) for n in names):
            # Worker threads run setup's closures too (the table's seeded initialisation).
            for fid, name in frames:
                if CLOSURE.search(name):
                    learned[fid]["setup"] += period
            resolved.append((period, "setup", frames))
            continue
        stage, closures, caller = classify(frames)
        if stage:
            for fid in closures:
                learned[fid][stage] += period
            if caller is not None:
                # Weaker evidence: the closure called a function of this stage.
                callers[caller][stage] += period
        resolved.append((period, stage, frames))
    static = None
    if len(sys.argv) > 2:
        names, static_edges = static_callers(sys.argv[2])
        starts = defaultdict(set)
        for start, name in names.items():
            starts[name].add(start)
        # perf's addresses and the file's differ by the load offset of the text.
        shifts = Counter()
        for _, _, frames in resolved:
            for fid, name in frames:
                if len(starts.get(name, ())) == 1 and not name.startswith("["):
                    shifts[next(iter(starts[name])) - fid] += 1
        if shifts:
            static = (shifts.most_common(1)[0][0], names, static_edges, {})
    by_stage = Counter()
    leaves = defaultdict(Counter)
    contexts = Counter()
    total = sum(p for p, _, _ in resolved)
    for period, stage, frames in resolved:
        leaf = frames[0][1] if frames else "[no stack]"
        if stage is None and static is not None:
            shift, names, static_edges, memo = static
            for fid, name in frames:
                if CLOSURE.search(name):
                    if fid not in memo:
                        memo[fid] = stage_by_callers(fid + shift, names, static_edges)
                    stage, caller = memo[fid]
                    if stage:
                        if fid == frames[0][0]:
                            leaf = f"closure run by {caller}"
                        break
        if stage is None:
            for evidence in (learned, callers):
                for fid, name in frames:
                    if fid in evidence and CLOSURE.search(name):
                        stage = evidence[fid].most_common(1)[0][0]
                        break
                if stage:
                    break
        stage = stage or "unattributed (no named caller on the stack)"
        by_stage[stage] += period
        leaves[stage][leaf[:150]] += period
        if stage != "setup":
            names = [n for _, n in frames]
            for context, pattern in CONTEXTS.items():
                if any(pattern.search(n) for n in names):
                    contexts[context] += period
    setup = by_stage.pop("setup", 0)
    work = max(total - setup, 1)
    print(f"== {title}: {len(data)} samples; setup (loading, initialisation) "
          f"{100 * setup / max(total, 1):.1f}% of them, left out below")
    for stage, period in by_stage.most_common():
        print(f"{100 * period / work:6.1f}%  {stage}")
        for leaf, p in leaves[stage].most_common(4):
            print(f"           {100 * p / work:5.1f}%  {leaf}")
    for context, period in contexts.most_common():
        print(f"  (at least {100 * period / work:.1f}% of the above under {context}: counted "
              f"where the stack shows it, which rayon workers' stacks mostly do not)")


if __name__ == "__main__":
    main()
