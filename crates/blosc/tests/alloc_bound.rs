//! Numbers in the input must not drive allocations: measures the peak heap
//! use of `decompress` with a counting global allocator.
//!
//! This file holds a single test so that no other test allocates
//! concurrently.

mod common;

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};
use vdbcook_blosc::{decompress, header};

struct Counting;

static CURRENT: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);

fn grew(by: usize) {
    let now = CURRENT.fetch_add(by, Ordering::SeqCst) + by;
    PEAK.fetch_max(now, Ordering::SeqCst);
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let p = unsafe { System.alloc(layout) };
        if !p.is_null() {
            grew(layout.size());
        }
        p
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        let p = unsafe { System.alloc_zeroed(layout) };
        if !p.is_null() {
            grew(layout.size());
        }
        p
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) };
        CURRENT.fetch_sub(layout.size(), Ordering::SeqCst);
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let p = unsafe { System.realloc(ptr, layout, new_size) };
        if !p.is_null() {
            if new_size >= layout.size() {
                grew(new_size - layout.size());
            } else {
                CURRENT.fetch_sub(layout.size() - new_size, Ordering::SeqCst);
            }
        }
        p
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

/// Peak bytes allocated (above what was live before) while running `f`.
fn peak_during<T>(f: impl FnOnce() -> T) -> (T, usize) {
    let base = CURRENT.load(Ordering::SeqCst);
    PEAK.store(base, Ordering::SeqCst);
    let r = f();
    (r, PEAK.load(Ordering::SeqCst).saturating_sub(base))
}

/// Fixed state a codec may need regardless of the output size: zlib's
/// inflate state (~43 KiB), zstd's tables, one 128 KiB zstd block and a
/// window of up to 1 MiB for small outputs, plus error strings.
const CODEC_STATE: usize = 1536 * 1024;

#[test]
fn allocations_are_bounded_by_the_expected_size() {
    let set = common::load();

    // Refused before allocating anything: nbytes differs from what the
    // caller expects, however large it is.
    let mut frame = vec![2, 1, 0, 4];
    frame.extend_from_slice(&(i32::MAX as u32).to_le_bytes());
    frame.extend_from_slice(&(1u32 << 20).to_le_bytes());
    frame.extend_from_slice(&16u32.to_le_bytes());
    let (r, peak) = peak_during(|| decompress(&frame, 4096));
    assert!(r.is_err());
    assert_eq!(peak, 0, "allocated {peak} bytes before refusing");

    // Valid buffers: the output, at most one block of scratch, codec state.
    let mut worst = 0usize;
    for v in set.vectors.iter().filter(|v| v.c_decodes) {
        let src = set.compressed(v);
        let blocksize = header(src).unwrap().blocksize as usize;
        let (r, peak) = peak_during(|| decompress(src, v.nbytes));
        let out = r.unwrap();
        let bound = v.nbytes + blocksize.min(v.nbytes) + CODEC_STATE;
        assert!(peak <= bound, "{}: peak {peak} > {bound}", v.name);
        worst = worst.max(peak.saturating_sub(2 * v.nbytes));
        drop(out);
    }
    eprintln!("largest allocation above twice the output size: {worst} bytes");

    // Corrupted buffers: whatever the flipped numbers say (block size,
    // stream sizes, zstd window, ...), never more than twice the expected
    // size plus the codec state.
    let mut rng = common::Rng(0x0123_4567_89AB_CDEF);
    let mut probes = 0;
    for v in set.vectors.iter().filter(|v| v.c_decodes && v.nbytes > 0).step_by(4) {
        let src = set.compressed(v);
        let mut mutated = src.to_vec();
        for _ in 0..60 {
            // Mostly the header and block table, where the sizes live.
            let at = if rng.below(2) == 0 { rng.below(src.len().min(64)) } else { rng.below(src.len()) };
            let bit = rng.below(8);
            mutated[at] ^= 1 << bit;
            let (_, peak) = peak_during(|| decompress(&mutated, v.nbytes));
            let bound = 2 * v.nbytes + CODEC_STATE;
            assert!(peak <= bound, "{}: byte {at} bit {bit}: peak {peak} > {bound}", v.name);
            mutated[at] ^= 1 << bit;
            probes += 1;
        }
    }
    assert!(probes > 5000, "only {probes} probes");
}
