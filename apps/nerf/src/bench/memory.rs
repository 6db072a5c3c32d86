//! `nerf bench`'s memory rows (`--only memory`): how many random rows of a hash table this
//! machine reads per second, from one level's table (2^18 rows of 2 f32, 2 MiB, as the shipped
//! grids have) and from all 16 levels' (32 MiB), on rayon's threads, 8 independent reads at a
//! time as a point's 8 corners are. The hash-grid field is bound by such reads rather than by
//! arithmetic: a training sample reads 128 rows forward (16 levels × 8 corners), adds into as
//! many backward, and the optimiser updates up to as many; so these rates bound the hash-grid
//! rows from above, as the matrix-multiply rate bounds the MLP's share.

use std::hint::black_box;
use std::time::Instant;

use rayon::prelude::*;

use crate::bench::row::{BenchResult, Throughput};
use crate::timing::fastest;

/// Rows of one level's table in the shipped configs (`log2_hashmap_size: 18`).
const LEVEL_ROWS: usize = 1 << 18;

/// Reads per timed run.
const READS: usize = 1 << 24;

/// Reads per rayon task.
const READS_PER_TASK: usize = 1 << 16;

/// The sum of `reads` rows of `table` (a power-of-two number of rows) chosen by a xorshift
/// stream from `seed`, 8 independent rows at a time.
fn read_rows(table: &[[f32; 2]], reads: usize, seed: u64) -> f32 {
    let mask = table.len() as u64 - 1;
    let mut state = seed | 1;
    let mut sum = 0f32;
    for _ in 0..reads / 8 {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        let mut corners = 0f32;
        for k in 0..8u64 {
            // Eight rows from one random word, as a point's corners come from one position.
            let row = (state.wrapping_mul(2 * k + 1) >> 20) & mask;
            let [a, b] = table[row as usize];
            corners += a + b;
        }
        sum += corners;
    }
    sum
}

/// Seconds of `READS` random row reads of `table` on rayon's threads, best of `repeats`.
fn time_reads(table: &[[f32; 2]], repeats: usize) -> Vec<f64> {
    let run = || {
        (0..READS / READS_PER_TASK)
            .into_par_iter()
            .map(|task| read_rows(table, READS_PER_TASK, 0x9E37_79B9_7F4A_7C15 ^ task as u64))
            .sum::<f32>()
    };
    black_box(run());
    (0..repeats.max(1))
        .map(|_| {
            let t = Instant::now();
            black_box(run());
            t.elapsed().as_secs_f64()
        })
        .collect()
}

/// The two read-rate rows, one level's table and all 16 levels' (best of `repeats`), and the
/// 16 levels' rate in rows per second: the reference the hash-grid rows' table traffic is
/// divided by (the shipped grids' whole table).
pub fn bench_table_reads(repeats: usize) -> (Vec<BenchResult>, f64) {
    let threads = rayon::current_num_threads();
    let rows: Vec<BenchResult> = [(1, "one level"), (16, "16 levels")]
        .into_iter()
        .map(|(levels, what)| {
            let rows = levels * LEVEL_ROWS;
            let table: Vec<[f32; 2]> = (0..rows).map(|i| [i as f32, 1.0]).collect();
            let runs = time_reads(&table, repeats);
            let seconds = fastest(&runs);
            let mib = (rows * 8) >> 20;
            BenchResult {
                name: format!("random row reads, {mib} MiB table ({what})"),
                work: format!(
                    "{READS} reads of one 8-byte row (2 f32) at random among {rows} rows, 8 independent at a time, on {threads} threads"
                ),
                seconds,
                runs,
                pytorch_seconds: None,
                error: None,
                throughput: Some(Throughput {
                    row_reads_per_second: Some(READS as f64 / seconds),
                    ..Throughput::default()
                }),
            }
        })
        .collect();
    let all_levels = rows[1]
        .throughput
        .as_ref()
        .and_then(|t| t.row_reads_per_second)
        .unwrap_or(0.0);
    (rows, all_levels)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_cover_the_table_and_sum_what_they_read() {
        // Every row holds 1 + 1: the sum counts the reads.
        let table = vec![[1f32, 1.0]; 1024];
        assert_eq!(read_rows(&table, 800, 3), 1600.0);
        // Rows are spread over the table: a table whose only non-zero row is the last is read
        // there at least once in 8192 reads.
        let mut sparse = vec![[0f32, 0.0]; 64];
        sparse[63] = [1.0, 0.0];
        assert!(read_rows(&sparse, 8192, 5) > 0.0);
    }
}
