//! Allocator tuning for tensor work.

/// For programs that use this library on the system allocator (the `nerf` binary uses mimalloc
/// instead, and its test binaries use glibc): tunes glibc's allocator for tensor work. Tensors
/// of many megabytes are allocated and freed for every op, and by default glibc hands each
/// back to the OS, so the next op pays page faults to get it again (a large share of the box
/// render's time; measured: docs/speed-and-report.md#allocators). Raising the mmap and trim
/// thresholds keeps freed buffers for reuse. A no-op on other platforms. The library calls it
/// itself, once, before its first render or training run ([`ensure_allocator_tuned`]).
pub fn tune_allocator() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only changes allocator parameters, under glibc's own lock.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 32 << 20);
        libc::mallopt(libc::M_TRIM_THRESHOLD, 1 << 30);
        libc::mallopt(libc::M_TOP_PAD, 64 << 20);
    }
}

/// [`tune_allocator`], the first time only: called by `nerf::render_view` and
/// `nerf::fit`, so a library user gets the tuning without asking (mallopt is thread-safe in
/// glibc; changing the thresholds affects later allocations only).
pub fn ensure_allocator_tuned() {
    static TUNED: std::sync::Once = std::sync::Once::new();
    TUNED.call_once(tune_allocator);
}
