//! A budget, in bytes, for the images being decoded at once. Datasets load their images on
//! rayon's threads; without a budget each thread holds one image's decoded copies, so the peak
//! grows with the thread count: a few large photos, small on disk, took gigabytes each while
//! decoding, and a run on more threads aborted (measured: docs/reliability.md#decoding-budget).
//! With it, a decode first reserves its cost (`decode_cost`) and waits while the images in
//! flight hold the rest; one image costlier than the whole budget runs alone. So the peak is
//! about [`DECODE_BUDGET_BYTES`] (or one image's cost) plus what the loaded, resized images
//! keep, on 2 threads or 64.

use std::sync::{Condvar, Mutex};

/// Bytes of decoding in flight at once (1 GiB: two 4096² photos, or one 8192² photo alone).
pub const DECODE_BUDGET_BYTES: u64 = 1 << 30;

/// Bytes one image of `width × height` pixels (a file of `file_bytes`) costs while it is
/// decoded, composited and resized: the file, its decoded pixels (up to 8 bytes a pixel:
/// 16-bit RGBA), the RGBA f32 copy (16) and the resize's f32 intermediate (16).
pub(crate) fn decode_cost(width: u32, height: u32, file_bytes: u64) -> u64 {
    file_bytes + u64::from(width) * u64::from(height) * (8 + 16 + 16)
}

/// The bytes reserved by the decodes in flight, and a wake-up for those waiting.
struct Ledger {
    reserved: Mutex<u64>,
    freed: Condvar,
}

/// The process's one ledger (datasets decode on rayon's global pool).
static LEDGER: Ledger = Ledger {
    reserved: Mutex::new(0),
    freed: Condvar::new(),
};

/// A reservation of decode bytes, returned to the budget when dropped.
pub struct Reservation {
    bytes: u64,
}

impl Drop for Reservation {
    fn drop(&mut self) {
        let mut reserved = LEDGER
            .reserved
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner());
        *reserved -= self.bytes;
        LEDGER.freed.notify_all();
    }
}

/// Reserves `cost` bytes of the budget (at most the whole budget: a costlier image waits
/// until nothing else is in flight, then runs alone), waiting while others hold them.
pub fn reserve(cost: u64) -> Reservation {
    let bytes = cost.min(DECODE_BUDGET_BYTES);
    let mut reserved = LEDGER
        .reserved
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner());
    while *reserved + bytes > DECODE_BUDGET_BYTES {
        reserved = LEDGER
            .freed
            .wait(reserved)
            .unwrap_or_else(|poisoned| poisoned.into_inner());
    }
    *reserved += bytes;
    Reservation { bytes }
}

/// What decoding the image file at `path` will cost (`decode_cost`), from its size on disk
/// and the dimensions its header gives, read without reading the rest; the file's size alone
/// when the header does not read (the decode then names the error), 0 when it is not a regular
/// file (a FIFO is never opened here; the reader refuses it).
pub fn file_decode_cost(path: &std::path::Path) -> u64 {
    let Ok(meta) = std::fs::metadata(path) else {
        return 0;
    };
    if !meta.is_file() {
        return 0;
    }
    match image::image_dimensions(path) {
        Ok((w, h)) => decode_cost(w, h, meta.len()),
        Err(_) => meta.len(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicU64, Ordering};

    #[test]
    fn reservations_never_exceed_the_budget_and_a_costly_one_runs_alone() {
        let in_flight = AtomicU64::new(0);
        let most = AtomicU64::new(0);
        let costs = [
            400u64 << 20,
            700 << 20,
            300 << 20,
            5 << 30,
            200 << 20,
            900 << 20,
        ];
        std::thread::scope(|s| {
            for cost in costs {
                let (in_flight, most) = (&in_flight, &most);
                s.spawn(move || {
                    let r = reserve(cost);
                    let now = in_flight.fetch_add(r.bytes, Ordering::SeqCst) + r.bytes;
                    most.fetch_max(now, Ordering::SeqCst);
                    std::thread::sleep(std::time::Duration::from_millis(20));
                    in_flight.fetch_sub(r.bytes, Ordering::SeqCst);
                });
            }
        });
        assert!(most.load(Ordering::SeqCst) <= DECODE_BUDGET_BYTES);
    }

    #[test]
    fn the_cost_counts_the_file_and_every_copy() {
        assert_eq!(decode_cost(2, 3, 10), 10 + 6 * 40);
        let (dir, png) = crate::test_files::temp_file("a.png");
        image::RgbImage::new(5, 7).save(&png).unwrap();
        let len = std::fs::metadata(&png).unwrap().len();
        assert_eq!(file_decode_cost(&png), decode_cost(5, 7, len));
        let text = dir.path().join("b.png");
        std::fs::write(&text, b"not an image").unwrap();
        assert_eq!(file_decode_cost(&text), 12);
        assert_eq!(file_decode_cost(dir.path()), 0);
    }
}
