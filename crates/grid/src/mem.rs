//! Large buffers, and running out of memory as an error rather than an abort.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

thread_local! {
    /// Whether this thread's failed allocations go back to the code that asked.
    static FALLIBLE: Cell<bool> = const { Cell::new(false) };
}

/// Runs `f` with this thread's failed allocations returned to the code that
/// asked for them (`Vec::try_reserve` sees the error) instead of ending the
/// process under [`ReportingAllocator`]. Without that allocator (library
/// tests, other programs) it only runs `f`. Keep `f` to the fallible call
/// itself: any other allocation that fails inside it aborts, as Rust's do.
pub fn fallible<R>(f: impl FnOnce() -> R) -> R {
    struct Restore(bool);
    impl Drop for Restore {
        fn drop(&mut self) {
            let _ = FALLIBLE.try_with(|c| c.set(self.0));
        }
    }
    let _restore = Restore(FALLIBLE.with(|c| c.replace(true)));
    f()
}

/// `Vec::try_reserve` under [`fallible`]; the error says how many bytes `what` needed.
pub fn try_reserve<T>(v: &mut Vec<T>, additional: usize, what: &'static str) -> Result<(), OutOfMemory> {
    fallible(|| v.try_reserve(additional)).map_err(|_| short(v, additional, what))
}

/// `Vec::try_reserve_exact` under [`fallible`], as [`try_reserve`].
pub fn try_reserve_exact<T>(v: &mut Vec<T>, additional: usize, what: &'static str) -> Result<(), OutOfMemory> {
    fallible(|| v.try_reserve_exact(additional)).map_err(|_| short(v, additional, what))
}

/// The error of `v` failing to take `additional` more elements.
fn short<T>(v: &[T], additional: usize, what: &'static str) -> OutOfMemory {
    OutOfMemory { what, bytes: additional.saturating_add(v.len()).saturating_mul(std::mem::size_of::<T>()) as u64 }
}

/// What to do when memory runs out, in both messages.
const ADVICE: &str = "cut the sequence into shorter segments (--segment-frames), cook fewer grids at once, or give it more memory";

/// A buffer that could not be allocated.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
#[error("out of memory: {what} needed {} ({ADVICE})", mib(*bytes))]
pub struct OutOfMemory {
    pub what: &'static str,
    pub bytes: u64,
}

/// Bytes as MiB with one decimal, as the out-of-memory and spill errors write them.
pub(crate) fn mib(bytes: u64) -> String {
    format!("{:.1} MiB", bytes as f64 / (1u64 << 20) as f64)
}

/// The system allocator, except that an allocation that fails outside
/// [`fallible`] ends the process with one line on stderr (`PROGRAM: error:
/// out of memory: ...`) and exit code 1, where Rust would print a backtrace
/// and abort. Installed by the `vdbcook` binary as its global allocator.
pub struct ReportingAllocator {
    pub program: &'static str,
}

// SAFETY: every call is forwarded to the system allocator unchanged; a null
// result is either returned (inside `fallible`) or ends the process.
unsafe impl GlobalAlloc for ReportingAllocator {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        self.checked(System.alloc(layout), layout.size())
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        self.checked(System.alloc_zeroed(layout), layout.size())
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        System.dealloc(ptr, layout)
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        self.checked(System.realloc(ptr, layout, new_size), new_size)
    }
}

impl ReportingAllocator {
    fn checked(&self, ptr: *mut u8, size: usize) -> *mut u8 {
        if ptr.is_null() && !FALLIBLE.try_with(Cell::get).unwrap_or(false) {
            self.out_of_memory(size);
        }
        ptr
    }

    /// Writes the line without allocating, then exits at once: no destructor
    /// runs (they might allocate), and no output file exists yet, since every
    /// output is written whole at the end, through an unnamed temporary file
    /// where the system has them.
    fn out_of_memory(&self, size: usize) -> ! {
        use std::io::Write;
        use std::sync::atomic::{AtomicBool, Ordering};
        // One line, from the first thread that fails; the others wait for the exit.
        static REPORTED: AtomicBool = AtomicBool::new(false);
        if REPORTED.swap(true, Ordering::SeqCst) {
            loop {
                std::thread::sleep(std::time::Duration::from_secs(1));
            }
        }
        let mut buf = [0u8; 256];
        let mut w = &mut buf[..];
        let what = if size >= 1 << 20 { format_args!("{:.1} MiB", size as f64 / (1u64 << 20) as f64) } else { format_args!("{size} bytes") };
        let _ = writeln!(w, "{}: error: out of memory: an allocation of {what} failed ({ADVICE})", self.program);
        let left = w.len();
        let n = buf.len() - left;
        #[cfg(unix)]
        // SAFETY: write(2) and _exit(2) on a stack buffer; both are async-signal-safe and allocate nothing.
        unsafe {
            libc::write(2, buf.as_ptr().cast(), n);
            libc::_exit(1);
        }
        #[cfg(not(unix))]
        {
            let _ = std::io::stderr().write_all(&buf[..n]);
            std::process::exit(1);
        }
    }
}

/// The memory this process may use: the machine's, or less where its
/// control group sets a limit (cgroup v2 `memory.max`, v1
/// `memory.limit_in_bytes`); 4 GiB where the system does not say.
pub fn usable_memory() -> u64 {
    #[cfg(target_os = "linux")]
    {
        // SAFETY: sysconf only reads system constants.
        let (pages, page) = unsafe { (libc::sysconf(libc::_SC_PHYS_PAGES), libc::sysconf(libc::_SC_PAGESIZE)) };
        let machine = if pages > 0 && page > 0 { pages as u64 * page as u64 } else { 4 << 30 };
        let limit = |path: &str| std::fs::read_to_string(path).ok().and_then(|s| s.trim().parse::<u64>().ok());
        let group = limit("/sys/fs/cgroup/memory.max").or_else(|| limit("/sys/fs/cgroup/memory/memory.limit_in_bytes"));
        group.map_or(machine, |g| g.min(machine))
    }
    #[cfg(not(target_os = "linux"))]
    {
        4 << 30
    }
}

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

/// Gives the memory freed since the last call back to the system where the
/// allocator keeps it (glibc's heaps): a cook that frees a segment's bricks
/// and allocates the next segment's in pieces of other sizes would otherwise
/// keep both high-water marks.
pub fn release_free() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim only walks the allocator's own free lists.
    unsafe {
        libc::malloc_trim(0);
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
