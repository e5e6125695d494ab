//! Large buffers.

/// Buffers smaller than this are left alone.
const MIN_BYTES: usize = 8 << 20;

/// Asks the kernel to back a large vector's allocation with transparent huge
/// pages, before it is first written (Linux; elsewhere, and for buffers
/// under 8 MiB, it does nothing).  The cooker writes several buffers of
/// hundreds of MB once each; with 4 KiB pages, page faults were a third of
/// its CPU time.  Call it again after the vector reallocates.
pub fn advise_huge_pages<T>(v: &Vec<T>) {
    let bytes = v.capacity().saturating_mul(std::mem::size_of::<T>());
    if bytes < MIN_BYTES {
        return;
    }
    #[cfg(target_os = "linux")]
    {
        const PAGE: usize = 4096;
        let start = v.as_ptr() as usize;
        let (Some(begin), Some(end)) = (start.checked_next_multiple_of(PAGE), start.checked_add(bytes)) else { return };
        let end = end / PAGE * PAGE;
        if end > begin {
            // SAFETY: madvise only gives the kernel advice about pages inside
            // this vector's own allocation (whole pages between its start and
            // the end of its capacity); it changes no memory contents, and a
            // failure (for example a kernel without huge pages) is harmless.
            unsafe {
                libc::madvise(begin as *mut libc::c_void, end - begin, libc::MADV_HUGEPAGE);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn advice_keeps_contents() {
        let mut v = vec![7u32; 3 << 20];
        super::advise_huge_pages(&v);
        v.iter_mut().step_by(1000).for_each(|x| *x += 1);
        assert_eq!(v[0], 8);
        assert_eq!(v[1], 7);
        assert_eq!(v.iter().map(|&x| u64::from(x)).sum::<u64>(), 7 * (3u64 << 20) + (3u64 << 20).div_ceil(1000));
        super::advise_huge_pages(&Vec::<u8>::new());
    }
}
