//! Memory given back to the system after a job.
//!
//! glibc's allocator keeps freed memory in its arenas (one per thread that allocated:
//! the rayon threads of a render each have one) and returns only what lies at the top
//! of a heap. A 4096² job's frames and layers are hundreds of MB freed in the middle of
//! those heaps, so the server stayed 0.8–1.25 GB resident after one such job, and after
//! a burst of watchers 6 GB. `malloc_trim(0)` walks every arena and returns the free
//! pages inside it too (`madvise(MADV_DONTNEED)`; glibc ≥ 2.8). It costs milliseconds
//! per GB of heap, so it runs once a job has ended and again a little later, when the
//! watchers and late writes that still held its last frame have let go.

use std::time::Duration;

/// When the second trim after a job runs: the late files are written and a watcher has
/// read the final frame within this in all but stalled cases (those are cut at 20 s).
pub const SECOND_TRIM_AFTER: Duration = Duration::from_secs(10);

/// Returns the allocator's free memory to the system (glibc on Linux; elsewhere nothing,
/// as other allocators purge by themselves or do not offer this).
pub fn release_free_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim only takes the allocator's own locks and touches free chunks.
    unsafe {
        libc::malloc_trim(0);
    }
}

/// [`release_free_memory`] now on this (worker) thread, and again after
/// [`SECOND_TRIM_AFTER`] on a blocking thread of `rt`.
pub fn after_job(rt: &tokio::runtime::Handle) {
    release_free_memory();
    rt.spawn(async {
        tokio::time::sleep(SECOND_TRIM_AFTER).await;
        let _ = tokio::task::spawn_blocking(release_free_memory).await;
    });
}
