//! Where the parallel work of the linear algebra and of the optimiser runs:
//! in the calling thread, or in a private pool of a fixed number of threads.
//!
//! A [`Parallelism`] with a pool is cheap to clone (the pool is shared), so
//! that the optimiser and its block systems use one pool. Nothing here
//! touches rayon's global pool.

use super::LinearError;
use rayon::prelude::*;
use std::sync::Arc;

/// The threads parallel work runs on: the calling thread alone
/// ([`Parallelism::sequential`]), or a private rayon pool of `N ≥ 2`
/// threads started by [`Parallelism::new`] and stopped when the last clone
/// is dropped.
#[derive(Clone, Debug, Default)]
pub struct Parallelism {
    pool: Option<Arc<rayon::ThreadPool>>,
}

impl Parallelism {
    /// Everything in the calling thread; no pool.
    pub fn sequential() -> Self {
        Self { pool: None }
    }

    /// `threads` 0 or 1: [`Parallelism::sequential`]. `threads ≥ 2`: a new
    /// private pool of exactly `threads` threads. Fails if the operating
    /// system does not start the threads.
    pub fn new(threads: usize) -> Result<Self, LinearError> {
        if threads < 2 {
            return Ok(Self::sequential());
        }
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .thread_name(|k| format!("pgo-solver-{k}"))
            .build()
            .map_err(|e| LinearError::ThreadPool(e.to_string()))?;
        Ok(Self {
            pool: Some(Arc::new(pool)),
        })
    }

    /// The number of threads work is split over: 1 without a pool, else the
    /// pool's size.
    pub fn threads(&self) -> usize {
        self.pool.as_ref().map_or(1, |p| p.current_num_threads())
    }

    /// Whether work is split over more than one thread.
    pub fn is_parallel(&self) -> bool {
        self.pool.is_some()
    }

    /// Runs `op` where parallel work belongs: in the pool (rayon's parallel
    /// iterators and `join` inside `op` then use the pool's threads), or in
    /// the calling thread. Blocks until `op` returns.
    pub fn install<R: Send>(&self, op: impl FnOnce() -> R + Send) -> R {
        match &self.pool {
            Some(pool) => pool.install(op),
            None => op(),
        }
    }

    /// `f` of every item, in order: on the pool's threads, each item a task
    /// of its own (for items of a millisecond or more, however few), or one
    /// after the other in the calling thread.
    pub fn map<T: Sync, R: Send>(&self, items: &[T], f: impl Fn(&T) -> R + Sync + Send) -> Vec<R> {
        match &self.pool {
            Some(pool) => pool.install(|| items.par_iter().with_max_len(1).map(f).collect()),
            None => items.iter().map(f).collect(),
        }
    }

    /// [`Self::map`] for many small items: on the pool, tasks of at least
    /// `run` items.
    pub fn map_runs<T: Sync, R: Send>(
        &self,
        items: &[T],
        run: usize,
        f: impl Fn(&T) -> R + Sync + Send,
    ) -> Vec<R> {
        match &self.pool {
            Some(pool) => pool.install(|| items.par_iter().with_min_len(run).map(f).collect()),
            None => items.iter().map(f).collect(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn map_keeps_the_order_and_runs_where_it_is_told() {
        let items: Vec<u64> = (0..1000).collect();
        let square = |x: &u64| x * x;
        let want: Vec<u64> = items.iter().map(square).collect();
        let caller = std::thread::current().id();
        let sequential = Parallelism::sequential();
        assert_eq!(sequential.map(&items, square), want);
        assert!(
            sequential
                .map(&items, |_| std::thread::current().id())
                .iter()
                .all(|&t| t == caller)
        );
        let pool = Parallelism::new(2).unwrap();
        assert_eq!(pool.map(&items, square), want);
        assert_eq!(pool.map_runs(&items, 64, square), want);
        assert_eq!(sequential.map_runs(&items, 64, square), want);
        let names = pool.map(&items, |_| std::thread::current().name().map(str::to_owned));
        assert!(
            names
                .iter()
                .all(|n| n.as_deref().is_some_and(|n| n.starts_with("pgo-solver-")))
        );
    }

    #[test]
    fn sequential_runs_in_the_calling_thread_and_a_pool_has_its_size() {
        let caller = std::thread::current().id();
        for threads in [0, 1] {
            let p = Parallelism::new(threads).unwrap();
            assert_eq!((p.threads(), p.is_parallel()), (1, false));
            assert_eq!(p.install(|| std::thread::current().id()), caller);
        }
        let p = Parallelism::new(3).unwrap();
        assert_eq!((p.threads(), p.is_parallel()), (3, true));
        // Inside, rayon sees the private pool, not the global one.
        assert_eq!(p.install(rayon::current_num_threads), 3);
        assert_ne!(p.install(|| std::thread::current().id()), caller);
        // Clones share the pool.
        let q = p.clone();
        let name = q.install(|| std::thread::current().name().map(str::to_owned));
        assert!(name.is_some_and(|n| n.starts_with("pgo-solver-")));
    }
}
