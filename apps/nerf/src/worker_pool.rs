//! Running a command's work on a worker of a rayon pool rather than beside it.
//!
//! A thread that is not one of the pool's workers and calls into it (a parallel iterator,
//! Candle's multi-threaded matmul) competes for the cores with the pool's workers during its
//! own serial stretches: Candle's element-wise ops, a render's bookkeeping between field
//! calls. The workers spin a while after each parallel job, so on a machine of few cores the
//! serial work waits for a core. On a worker of the pool, the caller's serial work and the
//! other workers share the pool's one thread a core: both a hash-grid frame and a training
//! step got faster (docs/speed-and-report.md#hash-grid-throughput-against-the-machine).

/// Runs `f` on a worker of a new rayon pool of one thread a core (the pool its parallel work
/// then uses), the calling thread blocked until it returns; on the calling thread if the pool
/// cannot be built. A panic in `f` resumes on the caller.
pub fn on_own_pool<T: Send>(f: impl FnOnce() -> T + Send) -> T {
    match rayon::ThreadPoolBuilder::new().build() {
        Ok(pool) => pool.install(f),
        Err(_) => f(),
    }
}
