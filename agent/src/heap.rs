//! The C heap that libtorch allocates tensors from (glibc malloc), tuned once per process.
//!
//! Why: an update allocates and frees hundreds of tensors of 0.1–1 MB each. By default glibc
//! serves blocks above its mmap threshold with fresh `mmap`s and returns freed memory at the
//! top of the heap to the kernel, so each update faults the same pages in again and the
//! kernel zeroes them: ~10 % of a learner update at the recipe's sizes went to page faults
//! (`perf record` on `million bench learner`, BENCHMARKS.md "Learner"). Keeping freed memory
//! in the heap costs a few tens of MB per process.

use std::sync::Once;

/// Blocks up to this size come from the heap, never from their own `mmap`.
const MMAP_THRESHOLD: i32 = 256 << 20;
/// Freed memory at the top of the heap is returned to the kernel only beyond this size.
const TRIM_THRESHOLD: i32 = 1 << 30;
/// Extra room taken whenever the heap grows, so growth is rare.
const TOP_PAD: i32 = 64 << 20;

/// Keeps freed tensor memory in the process instead of returning it to the kernel after
/// every update. Idempotent; a no-op outside glibc.
pub fn keep_freed_memory() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        #[cfg(all(target_os = "linux", target_env = "gnu"))]
        // SAFETY: mallopt only changes allocator parameters; it is called once, before the
        // heavy allocation starts, and glibc serialises it with the arenas' locks.
        unsafe {
            libc::mallopt(libc::M_MMAP_THRESHOLD, MMAP_THRESHOLD);
            libc::mallopt(libc::M_TRIM_THRESHOLD, TRIM_THRESHOLD);
            libc::mallopt(libc::M_TOP_PAD, TOP_PAD);
        }
    });
}
