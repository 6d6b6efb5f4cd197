//! The thread pool every binding runs its GIL-released work in: one per process.
//!
//! Rayon's global pool does not survive `fork()`: the child inherits its state but not its
//! threads, so the first parallel call in a forked child (an `os.fork()` or a
//! `multiprocessing` "fork" worker after the parent extracted features) would wait forever
//! for workers that do not exist. Work is therefore run with `install` in a pool that
//! belongs to the current process id; a forked child builds its own on first use. Nested
//! rayon calls (`par_iter`, `join`, faer) run in the installed pool.

use std::sync::atomic::{AtomicPtr, Ordering};

use pyo3::exceptions::PyRuntimeError;
use pyo3::prelude::*;
use rayon::{ThreadPool, ThreadPoolBuilder};

struct ProcessPool {
    pid: u32,
    pool: ThreadPool,
}

/// The current process's pool (leaked: a parent's pool in a forked child has no threads and
/// must never be dropped there). A pointer rather than a lock, so that a fork taken while
/// another thread held a lock cannot leave the child waiting on it.
static POOL: AtomicPtr<ProcessPool> = AtomicPtr::new(std::ptr::null_mut());

fn process_pool() -> PyResult<&'static ThreadPool> {
    let pid = std::process::id();
    let current = POOL.load(Ordering::Acquire);
    // SAFETY: POOL only ever holds null or a leaked, never freed `ProcessPool`.
    if let Some(p) = unsafe { current.as_ref() }.filter(|p| p.pid == pid) {
        return Ok(&p.pool);
    }
    let pool = ThreadPoolBuilder::new()
        .thread_name(|i| format!("ferroslam-worker-{i}"))
        .build()
        .map_err(|e| PyRuntimeError::new_err(format!("cannot start the worker threads: {e}")))?;
    let fresh = Box::into_raw(Box::new(ProcessPool { pid, pool }));
    match POOL.compare_exchange(current, fresh, Ordering::AcqRel, Ordering::Acquire) {
        // SAFETY: `fresh` is now in POOL, never freed.
        Ok(_) => Ok(unsafe { &(*fresh).pool }),
        Err(other) => {
            // Another thread of this process installed its pool first: use that one.
            // SAFETY: `fresh` was never shared; `other` is a leaked `ProcessPool`.
            drop(unsafe { Box::from_raw(fresh) });
            Ok(unsafe { &(*other).pool })
        }
    }
}

/// `work` with the GIL released, in this process's pool.
pub fn detach<T: Send>(py: Python<'_>, work: impl FnOnce() -> T + Send) -> PyResult<T> {
    let pool = process_pool()?;
    Ok(py.detach(|| pool.install(work)))
}
