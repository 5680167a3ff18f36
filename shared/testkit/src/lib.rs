//! Test support shared by bdis-slam's crates.
//!
//! [`service`]: what the service binaries' tests share (refused input, the one clear line, /dev/shm leftovers).
//!
//! [`CountingAllocator`] proves that a hot path allocates nothing once warmed up. A test binary installs it:
//!
//! ```ignore
//! #[global_allocator]
//! static GLOBAL: bdis_testkit::CountingAllocator = bdis_testkit::CountingAllocator;
//!
//! let before = bdis_testkit::allocations();
//! hot_path();
//! assert_eq!(bdis_testkit::allocations() - before, 0);
//! ```
//!
//! Counts are per thread: a test measures the thread that runs the hot path, and helpers on other threads (the
//! bundle-adjustment worker, the test harness) do not disturb it.

pub mod service;

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

thread_local! {
    static ALLOCATIONS: Cell<usize> = const { Cell::new(0) };
    static BYTES: Cell<usize> = const { Cell::new(0) };
}

fn count(bytes: usize) {
    // try_with: the thread-local may already be gone while a thread exits.
    let _ = ALLOCATIONS.try_with(|c| c.set(c.get() + 1));
    let _ = BYTES.try_with(|c| c.set(c.get() + bytes));
}

/// Allocations (and reallocations) made by the calling thread so far.
pub fn allocations() -> usize {
    ALLOCATIONS.with(Cell::get)
}

/// Bytes requested by the calling thread's allocations and reallocations so far.
pub fn bytes() -> usize {
    BYTES.with(Cell::get)
}

/// The system allocator, counting each thread's allocations and reallocations.
#[derive(Debug, Clone, Copy)]
pub struct CountingAllocator;

// SAFETY: every call is forwarded unchanged to the system allocator; counting touches only thread-locals.
unsafe impl GlobalAlloc for CountingAllocator {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count(layout.size());
        // SAFETY: the caller's contract for `alloc` is passed on as is.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: as for `alloc`.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count(new_size);
        // SAFETY: as for `alloc`.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[cfg(test)]
mod tests {
    #[global_allocator]
    static GLOBAL: super::CountingAllocator = super::CountingAllocator;

    #[test]
    fn counts_this_threads_allocations_and_bytes_only() {
        let (a0, b0) = (super::allocations(), super::bytes());
        let v: Vec<u8> = Vec::with_capacity(1000);
        std::hint::black_box(&v);
        assert_eq!(super::allocations() - a0, 1);
        assert!(super::bytes() - b0 >= 1000);
        // Another thread's allocations are not counted here (spawning allocates a little on this thread: the
        // thread's handle, not its 64 kB vector).
        let before = super::bytes();
        std::thread::scope(|s| {
            s.spawn(|| std::hint::black_box(vec![0u8; 65_536]));
        });
        assert!(super::bytes() - before < 65_536, "{} bytes", super::bytes() - before);
    }
}
