#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is the failure report
//! Hot-path discipline: once warmed up on a size, the matcher allocates nothing per pair.

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};

use bdis_stereo::{Algorithm, DisparityMap, GrayImage, Matcher, Params};

struct Counting;
static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn a_warmed_up_pair_allocates_nothing() {
    let (w, h) = (640, 480);
    let tex = |x: usize, y: usize| -> u8 { (((x * 2_654_435_761) ^ (y * 40_503)) >> 6) as u8 | 1 };
    let left: Vec<u8> = (0..w * h).map(|i| tex(i % w, i / w)).collect();
    let right: Vec<u8> = (0..w * h).map(|i| tex(i % w + 5, i / w)).collect();
    for params in [
        Params::default(),
        Params::colon(),
        Params { algorithm: Algorithm::Dis, ..Params::default() },
        Params { variance: true, ..Params::colon() },
    ] {
        let mut matcher = Matcher::new(params).unwrap();
        let mut out = DisparityMap::default();
        let (l, r) = (GrayImage { width: w, height: h, data: &left }, GrayImage { width: w, height: h, data: &right });
        matcher.compute_into(l, r, &mut out).unwrap();
        let before = ALLOCATIONS.load(Ordering::Relaxed);
        matcher.compute_into(l, r, &mut out).unwrap();
        matcher.compute_into(l, r, &mut out).unwrap();
        let after = ALLOCATIONS.load(Ordering::Relaxed);
        assert_eq!(after - before, 0, "{params:?}: {} allocations in two warmed-up pairs", after - before);
    }
}
