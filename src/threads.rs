//! Worker threads: every entry point (the CLI's `--threads`, Python's `threads=`) makes
//! its rayon pool here, so one limit applies everywhere.
//!
//! The limit is [`PER_CPU`] threads per logical CPU. Umbra's work is compute-bound, so
//! threads beyond the CPUs only add scheduling and per-thread scratch memory (`tri3`
//! keeps a histogram per thread); `--threads 10000` used to spawn ten thousand threads
//! and run for minutes. Oversubscription up to the limit stays allowed for timing
//! studies. Results never depend on the count (see `transport::render`).

use crate::error::{Error, Result};

/// Threads allowed per logical CPU.
pub const PER_CPU: usize = 4;

/// Logical CPUs of this machine (1 if unknown).
pub fn cpus() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// The most threads a pool may have here.
pub fn max_threads() -> usize {
    PER_CPU * cpus()
}

/// Checks a requested thread count (`None` or 0: one per CPU), `option` naming it in
/// the message (`--threads`, `threads`); returns the count for rayon (0 = its default).
pub fn check(requested: Option<usize>, option: &str) -> Result<usize> {
    let n = requested.unwrap_or(0);
    let max = max_threads();
    if n > max {
        return Err(Error::Invalid(format!(
            "{option}: {n} threads is more than {max} ({PER_CPU} per CPU, and this machine has {}); Umbra is compute-bound, so use at most the number of CPUs",
            cpus()
        )));
    }
    Ok(n)
}

/// A rayon pool of the checked size.
pub fn pool(requested: Option<usize>, option: &str) -> Result<rayon::ThreadPool> {
    rayon::ThreadPoolBuilder::new()
        .num_threads(check(requested, option)?)
        .build()
        .map_err(|e| Error::Invalid(format!("{option}: cannot start the threads: {e}")))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn refuses_more_than_the_limit() {
        assert_eq!(check(None, "--threads").unwrap(), 0);
        assert_eq!(
            check(Some(max_threads()), "--threads").unwrap(),
            max_threads()
        );
        let e = check(Some(10_000), "--threads").unwrap_err().to_string();
        assert!(
            e.starts_with("--threads: 10000 threads is more than"),
            "{e}"
        );
        assert_eq!(pool(Some(1), "threads").unwrap().current_num_threads(), 1);
    }
}
