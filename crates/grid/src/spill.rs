//! Spill files: buffers that grow with a whole sequence, kept in an unnamed
//! temporary file beside the output once they pass a size.
//!
//! A [`Store`] is a vector that starts in memory and, when a reservation
//! would take it past its [`SpillPolicy`]'s size, moves into a [`SpillVec`]:
//! the pages of a file that has no name (Linux `O_TMPFILE`, so it cannot
//! outlive the process), mapped shared, so its users still see a slice. The
//! file's blocks are allocated before they are written (`fallocate`), so a
//! full disk is an error where it is reserved, never a signal on a write.
//! A trimming thread drops the mapped pages from the process whenever the
//! process's file-backed resident pages grow by [`TRIM_BYTES`] or more
//! (`madvise(MADV_DONTNEED)`, which on a shared file mapping keeps the data:
//! written pages stay in the page cache until the kernel writes them to the
//! file). The process's resident memory stays bounded; the kernel caches
//! what it can and reads back the rest. Elsewhere than Linux a store never
//! leaves memory.

use crate::mem::{mib, OutOfMemory};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

/// Where [`Store`]s go: into files in `dir` once the stores made with this
/// policy (and its clones) would together hold more than `above` bytes in memory.
#[derive(Clone, Debug)]
pub struct SpillPolicy {
    pub dir: PathBuf,
    pub above: u64,
    /// Bytes the policy's stores hold in memory now.
    held: Arc<AtomicU64>,
    /// Bytes of their spill files now, and the most there have been.
    in_files: Arc<AtomicU64>,
    peak_in_files: Arc<AtomicU64>,
}

impl SpillPolicy {
    pub fn new(dir: PathBuf, above: u64) -> SpillPolicy {
        SpillPolicy { dir, above, held: Arc::default(), in_files: Arc::default(), peak_in_files: Arc::default() }
    }

    /// Bytes its stores hold in memory now.
    pub fn held(&self) -> u64 {
        self.held.load(Ordering::Relaxed)
    }

    /// The most bytes its stores' spill files have held at once (0: nothing spilled).
    pub fn peak_in_files(&self) -> u64 {
        self.peak_in_files.load(Ordering::Relaxed)
    }
}

/// Memory that grows with what a policy's stores hold but cannot go to a
/// file itself (a builder's hash indexes and per-frame lists), counted in
/// the policy's total so that its stores spill sooner and the whole stays
/// near the budget; uncounted when dropped.
#[derive(Debug, Default)]
pub struct Charge {
    policy: Option<SpillPolicy>,
    bytes: u64,
}

impl Charge {
    pub fn new(policy: Option<SpillPolicy>) -> Charge {
        Charge { policy, bytes: 0 }
    }

    /// Counts `bytes` instead of what was counted.
    pub fn set(&mut self, bytes: u64) {
        if let Some(p) = &self.policy {
            recount(&p.held, self.bytes, bytes);
        }
        self.bytes = bytes;
    }
}

impl Drop for Charge {
    fn drop(&mut self) {
        self.set(0);
    }
}

/// A reservation that could not be met: memory, or the spill file's disk.
#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    #[error(transparent)]
    OutOfMemory(#[from] OutOfMemory),
    #[error("{what}: could not spill {} to a temporary file in {}: {error}", mib(*bytes), dir.display())]
    Disk { what: &'static str, bytes: u64, dir: PathBuf, error: std::io::Error },
}

/// Replaces `was` by `now` in a shared total; returns the total with `now`.
fn recount(total: &AtomicU64, was: u64, now: u64) -> u64 {
    let with = total.fetch_add(now, Ordering::Relaxed).wrapping_add(now);
    total.fetch_sub(was, Ordering::Relaxed);
    with.wrapping_sub(was)
}

/// A vector in memory, or spilled to a file (see the module's text).
pub struct Store<T: bytemuck::Pod> {
    data: Data<T>,
    policy: Option<SpillPolicy>,
    /// Bytes of its memory counted in the policy's `held`.
    counted: u64,
    /// Bytes of its spill file counted in the policy's `in_files`.
    filed: u64,
}

enum Data<T: bytemuck::Pod> {
    Memory(Vec<T>),
    #[cfg(target_os = "linux")]
    File(SpillVec<T>),
}

impl<T: bytemuck::Pod> Default for Store<T> {
    fn default() -> Self {
        Store { data: Data::Memory(Vec::new()), policy: None, counted: 0, filed: 0 }
    }
}

impl<T: bytemuck::Pod> From<Vec<T>> for Store<T> {
    fn from(v: Vec<T>) -> Self {
        Store { data: Data::Memory(v), policy: None, counted: 0, filed: 0 }
    }
}

impl<T: bytemuck::Pod> Drop for Store<T> {
    fn drop(&mut self) {
        self.count(0);
        self.file(0);
    }
}

impl<T: bytemuck::Pod> std::ops::Deref for Store<T> {
    type Target = [T];
    fn deref(&self) -> &[T] {
        match &self.data {
            Data::Memory(v) => v,
            #[cfg(target_os = "linux")]
            Data::File(f) => f.as_slice(),
        }
    }
}

impl<T: bytemuck::Pod> std::ops::DerefMut for Store<T> {
    fn deref_mut(&mut self) -> &mut [T] {
        match &mut self.data {
            Data::Memory(v) => v,
            #[cfg(target_os = "linux")]
            Data::File(f) => f.as_mut_slice(),
        }
    }
}

impl AsRef<[u8]> for Store<u8> {
    fn as_ref(&self) -> &[u8] {
        self
    }
}

impl<T: bytemuck::Pod> Store<T> {
    /// Counts `bytes` of memory in the policy's total instead of what was counted.
    fn count(&mut self, bytes: u64) {
        if let Some(p) = &self.policy {
            recount(&p.held, self.counted, bytes);
        }
        self.counted = bytes;
    }

    /// Counts `bytes` of spill file in the policy's total instead of what was counted.
    fn file(&mut self, bytes: u64) {
        if let Some(p) = &self.policy {
            p.peak_in_files.fetch_max(recount(&p.in_files, self.filed, bytes), Ordering::Relaxed);
        }
        self.filed = bytes;
    }

    /// Bytes of its spill file (0 in memory).
    fn file_bytes(&self) -> u64 {
        match &self.data {
            Data::Memory(_) => 0,
            #[cfg(target_os = "linux")]
            Data::File(f) => (f.capacity() * std::mem::size_of::<T>()) as u64,
        }
    }
}

impl<T: bytemuck::Pod + Send + Sync> Store<T> {
    /// An empty store under `policy` (`None`: it stays in memory).
    pub fn with_policy(policy: Option<SpillPolicy>) -> Store<T> {
        let mut s = Store::default();
        s.set_policy(policy);
        s
    }

    /// Spills under `policy` from now on (`None`: never).
    pub fn set_policy(&mut self, policy: Option<SpillPolicy>) {
        let (bytes, filed) = (self.counted, self.filed);
        self.count(0);
        self.file(0);
        self.policy = policy;
        self.count(bytes);
        self.file(filed);
    }

    /// The policy it spills under.
    pub fn policy(&self) -> Option<&SpillPolicy> {
        self.policy.as_ref()
    }

    /// Asks for transparent huge pages where it is in memory (see
    /// [`crate::mem::advise_huge_pages`]).
    pub fn advise_huge_pages(&self) {
        if let Data::Memory(v) = &self.data {
            crate::mem::advise_huge_pages(v);
        }
    }

    /// True once the store lives in a file.
    pub fn is_spilled(&self) -> bool {
        !matches!(self.data, Data::Memory(_))
    }

    /// Elements it can hold without another reservation.
    pub fn capacity(&self) -> usize {
        match &self.data {
            Data::Memory(v) => v.capacity(),
            #[cfg(target_os = "linux")]
            Data::File(f) => f.capacity(),
        }
    }

    /// Empties it, keeping its memory or file.
    pub fn clear(&mut self) {
        self.truncate(0);
    }

    pub fn truncate(&mut self, len: usize) {
        match &mut self.data {
            Data::Memory(v) => v.truncate(len),
            #[cfg(target_os = "linux")]
            Data::File(f) => f.truncate(len),
        }
    }

    /// Room for `additional` more elements; `what` names the buffer in errors.
    pub fn try_reserve(&mut self, additional: usize, what: &'static str) -> Result<(), StoreError> {
        let size = std::mem::size_of::<T>() as u64;
        let want = self.bytes_with(additional);
        let spill_to = self.spill_dir(additional);
        let disk = |dir: &Path, error| StoreError::Disk { what, bytes: want, dir: dir.to_path_buf(), error };
        match (&mut self.data, spill_to) {
            #[cfg(target_os = "linux")]
            (Data::Memory(v), Some(dir)) => {
                let mut f = SpillVec::new(&dir).map_err(|e| disk(&dir, e))?;
                f.reserve(v.len() + additional).map_err(|e| disk(&dir, e))?;
                // A chunk at a time, each chunk's pages out of the process
                // as soon as it is copied (the file keeps them): the move
                // holds little more than the memory it empties.
                for chunk in v.chunks((MOVE_CHUNK / size).max(1) as usize) {
                    f.extend_from_slice(chunk);
                    file::trim();
                }
                self.data = Data::File(f);
                self.count(0);
                self.file(self.file_bytes());
                Ok(())
            }
            (Data::Memory(v), _) => {
                // Room for what is asked, and no more where doubling would
                // pass the budget (untouched room costs no memory, but counts).
                let doubled = (v.capacity() as u64).saturating_mul(2 * size);
                if self.policy.as_ref().is_some_and(|p| p.held().saturating_sub(self.counted).saturating_add(doubled) > p.above) {
                    crate::mem::try_reserve_exact(v, additional, what)?;
                } else {
                    crate::mem::try_reserve(v, additional, what)?;
                }
                let bytes = v.capacity() as u64 * size;
                self.count(bytes);
                Ok(())
            }
            #[cfg(target_os = "linux")]
            (Data::File(f), _) => {
                let dir = self.policy.as_ref().map(|p| p.dir.clone()).unwrap_or_default();
                f.reserve(additional).map_err(|e| disk(&dir, e))?;
                self.file(self.file_bytes());
                Ok(())
            }
        }
    }

    /// Appends `items` (reserving room first).
    pub fn extend_from_slice(&mut self, items: &[T], what: &'static str) -> Result<(), StoreError> {
        self.try_reserve(items.len(), what)?;
        match &mut self.data {
            Data::Memory(v) => v.extend_from_slice(items),
            #[cfg(target_os = "linux")]
            Data::File(f) => f.extend_from_slice(items),
        }
        Ok(())
    }

    /// Appends one item (reserving room first when it has none: reserve
    /// ahead for many pushes).
    pub fn push(&mut self, item: T, what: &'static str) -> Result<(), StoreError> {
        match &mut self.data {
            Data::Memory(v) if v.len() < v.capacity() => {
                v.push(item);
                Ok(())
            }
            _ => self.extend_from_slice(std::slice::from_ref(&item), what),
        }
    }

    /// Bytes it holds with `additional` more elements.
    fn bytes_with(&self, additional: usize) -> u64 {
        (self.len() as u64).saturating_add(additional as u64).saturating_mul(std::mem::size_of::<T>() as u64)
    }

    /// Where it goes if it takes `additional` more elements: the spill
    /// directory when the policy's stores would hold more than its size in
    /// memory, else `None`.
    fn spill_dir(&self, additional: usize) -> Option<PathBuf> {
        let want = self.bytes_with(additional);
        let p = self.policy.as_ref()?;
        let held_elsewhere = p.held().saturating_sub(self.counted);
        (self.counted < want && held_elsewhere.saturating_add(want) > p.above).then(|| p.dir.clone())
    }

    /// Appends `n` zeroed elements (reserving room first).
    pub fn extend_zeroed(&mut self, n: usize, what: &'static str) -> Result<(), StoreError> {
        if self.capacity() == 0 && !self.is_spilled() && self.spill_dir(n).is_none() {
            // Fresh memory the system zeroes (calloc): no pass of our own over it.
            let bytes = self.bytes_with(n);
            let v = crate::mem::fallible(|| bytemuck::allocation::try_zeroed_vec::<T>(n)).map_err(|()| OutOfMemory { what, bytes })?;
            self.data = Data::Memory(v);
            self.count(bytes);
            return Ok(());
        }
        self.try_reserve(n, what)?;
        match &mut self.data {
            Data::Memory(v) => v.resize(v.len() + n, T::zeroed()),
            #[cfg(target_os = "linux")]
            Data::File(f) => f.grow_zeroed(n),
        }
        Ok(())
    }

    /// Appends what `items` makes, in parallel, in order (reserving room first).
    pub fn par_extend<I>(&mut self, items: I, what: &'static str) -> Result<(), StoreError>
    where
        I: rayon::iter::IndexedParallelIterator<Item = T>,
    {
        use rayon::prelude::*;
        self.try_reserve(items.len(), what)?;
        match &mut self.data {
            Data::Memory(v) => v.par_extend(items),
            #[cfg(target_os = "linux")]
            Data::File(f) => {
                let from = f.len();
                f.grow(items.len());
                f.as_mut_slice()[from..].par_iter_mut().zip(items).for_each(|(d, s)| *d = s);
            }
        }
        Ok(())
    }
}

/// File-backed resident pages the process may gain before the trimmer drops
/// the spill files' mapped pages, and how often it looks: a 32-frame cook
/// spilled past 8 MiB peaked at 135–154 MB polling every 10 ms with 16–32
/// MiB, 84 MB every 2 ms with 16 MiB (its 8-frame segments: 93 MB), at the
/// same time.
pub const TRIM_BYTES: u64 = 16 << 20;
/// Bytes a store moving into its file copies between two trims.
#[cfg(target_os = "linux")]
const MOVE_CHUNK: u64 = TRIM_BYTES;
#[cfg(target_os = "linux")]
const POLL: std::time::Duration = std::time::Duration::from_millis(2);

#[cfg(target_os = "linux")]
pub use file::SpillVec;

#[cfg(target_os = "linux")]
mod file {
    use super::*;
    use std::os::fd::AsRawFd;
    use std::sync::Mutex;

    /// Address space taken for one spill file's mapping (not memory: pages
    /// are only backed once the file has them; a cook may hold a few dozen
    /// stores, in 128 TiB of user address space); smaller halves are tried
    /// where the system refuses.
    const RESERVE: usize = 1 << 38;
    const MIN_RESERVE: usize = 1 << 30;

    /// A vector of `T` in an unnamed temporary file, mapped shared.
    pub struct SpillVec<T: bytemuck::Pod> {
        file: std::fs::File,
        base: *mut T,
        /// Bytes of address space mapped at `base`.
        reserved: usize,
        /// Elements the file has blocks for.
        cap: usize,
        len: usize,
        /// The longest it has been: past it the file holds zeros.
        touched: usize,
    }

    // SAFETY: the mapping is owned by the SpillVec as a Vec owns its heap
    // memory; shared access goes through &self and &mut self as for a Vec.
    unsafe impl<T: bytemuck::Pod + Send> Send for SpillVec<T> {}
    // SAFETY: as above.
    unsafe impl<T: bytemuck::Pod + Sync> Sync for SpillVec<T> {}

    /// The mappings the trimmer may drop pages of: (start, bytes).
    static REGIONS: Mutex<Vec<(usize, usize)>> = Mutex::new(Vec::new());

    impl<T: bytemuck::Pod> SpillVec<T> {
        /// An empty vector in a new unnamed file in `dir`.
        pub fn new(dir: &Path) -> std::io::Result<SpillVec<T>> {
            let file = unnamed_file(dir)?;
            let mut reserved = RESERVE;
            let base = loop {
                // SAFETY: a new shared mapping of our own file at an address the kernel picks.
                let p = unsafe { libc::mmap(std::ptr::null_mut(), reserved, libc::PROT_READ | libc::PROT_WRITE, libc::MAP_SHARED | libc::MAP_NORESERVE, file.as_raw_fd(), 0) };
                if p != libc::MAP_FAILED {
                    break p.cast::<T>();
                }
                if reserved <= MIN_RESERVE {
                    return Err(std::io::Error::last_os_error());
                }
                reserved /= 2;
            };
            start_trimmer();
            lock().push((base as usize, 0));
            LIVE.fetch_add(1, Ordering::Relaxed);
            Ok(SpillVec { file, base, reserved, cap: 0, len: 0, touched: 0 })
        }

        pub fn len(&self) -> usize {
            self.len
        }

        pub fn is_empty(&self) -> bool {
            self.len == 0
        }

        pub fn capacity(&self) -> usize {
            self.cap
        }

        pub fn as_slice(&self) -> &[T] {
            // SAFETY: the first `len` elements lie in file blocks mapped at `base`, and every bit pattern is a T.
            unsafe { std::slice::from_raw_parts(self.base, self.len) }
        }

        pub fn as_mut_slice(&mut self) -> &mut [T] {
            // SAFETY: as in `as_slice`, borrowed uniquely through &mut self.
            unsafe { std::slice::from_raw_parts_mut(self.base, self.len) }
        }

        /// Gives the file blocks for `additional` more elements (doubling, as
        /// a Vec does, where the disk and the mapping have room; else just
        /// enough); a full disk is an error here.
        pub fn reserve(&mut self, additional: usize) -> std::io::Result<()> {
            let need = self.len.checked_add(additional).ok_or(std::io::ErrorKind::OutOfMemory)?;
            if need <= self.cap {
                return Ok(());
            }
            let size = std::mem::size_of::<T>().max(1);
            let room = self.reserved / size;
            if need > room {
                return Err(std::io::Error::other(format!("more than the {} GiB of address space taken for it", self.reserved >> 30)));
            }
            let ample = need.max(self.cap.saturating_mul(2)).max((1 << 20) / size).min(room);
            match self.allocate(ample) {
                Err(e) if ample > need && e.raw_os_error() == Some(libc::ENOSPC) => self.allocate(need),
                done => done,
            }
        }

        /// File blocks for `cap` elements (more than it has).
        fn allocate(&mut self, cap: usize) -> std::io::Result<()> {
            let size = std::mem::size_of::<T>().max(1);
            let (had, bytes) = (self.cap * size, cap * size);
            // SAFETY: fallocate on our own descriptor, for the new part only; it only allocates blocks.
            let r = unsafe { libc::fallocate(self.file.as_raw_fd(), 0, had as libc::off_t, (bytes - had) as libc::off_t) };
            if r != 0 {
                let e = std::io::Error::last_os_error();
                // File systems without fallocate: grow the file (blocks come as pages are written).
                if !matches!(e.raw_os_error(), Some(libc::EOPNOTSUPP)) {
                    return Err(e);
                }
                self.file.set_len(bytes as u64)?;
            }
            self.cap = cap;
            if let Some(r) = lock().iter_mut().find(|r| r.0 == self.base as usize) {
                r.1 = bytes;
            }
            Ok(())
        }

        /// Lengthens it by `n` elements of whatever the file holds there
        /// (zeros, or an earlier use's values); `n` must be reserved.
        pub(crate) fn grow(&mut self, n: usize) {
            assert!(self.len + n <= self.cap, "spill file grown past its reservation");
            self.len += n;
            self.touched = self.touched.max(self.len);
        }

        /// Lengthens it by `n` zeroed elements; `n` must be reserved.
        pub(crate) fn grow_zeroed(&mut self, n: usize) {
            let (from, fresh) = (self.len, self.touched);
            self.grow(n);
            // Past `touched` the file's blocks are still as fallocate left them: zeros.
            let end = fresh.clamp(from, self.len);
            self.as_mut_slice()[from..end].fill(T::zeroed());
        }

        pub fn extend_from_slice(&mut self, items: &[T]) {
            let from = self.len;
            self.grow(items.len());
            self.as_mut_slice()[from..].copy_from_slice(items);
        }

        pub fn truncate(&mut self, len: usize) {
            self.len = self.len.min(len);
        }
    }

    impl<T: bytemuck::Pod> Drop for SpillVec<T> {
        fn drop(&mut self) {
            // Out of the trimmer's list before the mapping goes.
            let mut regions = lock();
            regions.retain(|r| r.0 != self.base as usize);
            LIVE.fetch_sub(1, Ordering::Relaxed);
            // SAFETY: unmaps exactly the mapping made in `new`; no slice of it outlives &self.
            unsafe {
                libc::munmap(self.base.cast(), self.reserved);
            }
        }
    }

    /// A file in `dir` with no name: `O_TMPFILE`, or on file systems without
    /// it a new file unlinked as soon as it is open (a name for an instant).
    fn unnamed_file(dir: &Path) -> std::io::Result<std::fs::File> {
        use std::os::unix::fs::OpenOptionsExt;
        let open = || {
            let mut o = std::fs::OpenOptions::new();
            o.read(true).write(true).mode(0o600);
            o
        };
        match open().custom_flags(libc::O_TMPFILE | libc::O_CLOEXEC).open(dir) {
            Err(e) if matches!(e.raw_os_error(), Some(libc::EOPNOTSUPP | libc::EISDIR | libc::EINVAL)) => {
                static SERIAL: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
                let serial = SERIAL.fetch_add(1, Ordering::Relaxed);
                let path = dir.join(format!(".vdbcook-spill-{}-{serial}.tmp", std::process::id()));
                let file = open().create_new(true).open(&path)?;
                std::fs::remove_file(&path)?;
                Ok(file)
            }
            other => other,
        }
    }

    fn lock() -> std::sync::MutexGuard<'static, Vec<(usize, usize)>> {
        REGIONS.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// The process's file-backed and shared resident bytes (`/proc/self/statm`, in pages).
    fn shared_resident() -> Option<u64> {
        let s = std::fs::read_to_string("/proc/self/statm").ok()?;
        let pages: u64 = s.split_whitespace().nth(2)?.parse().ok()?;
        // SAFETY: sysconf only reads a system constant.
        let page = u64::try_from(unsafe { libc::sysconf(libc::_SC_PAGESIZE) }).ok().filter(|&p| p > 0)?;
        Some(pages * page)
    }

    /// Starts the thread that keeps the spill files' mapped pages out of the
    /// process (once per process; it reads `/proc/self/statm` every [`POLL`]).
    fn start_trimmer() {
        static STARTED: std::sync::Once = std::sync::Once::new();
        STARTED.call_once(|| {
            let _ = std::thread::Builder::new().name("spill-trim".into()).spawn(|| {
                let mut floor = shared_resident().unwrap_or(0);
                loop {
                    std::thread::sleep(POLL);
                    if lock().is_empty() {
                        // No spill file now: look again later.
                        std::thread::sleep(POLL * 50);
                        continue;
                    }
                    let Some(now) = shared_resident() else { return };
                    if now < floor {
                        floor = now;
                    } else if now - floor >= TRIM_BYTES {
                        trim();
                        floor = shared_resident().unwrap_or(now);
                    }
                }
            });
        });
    }

    /// Bytes reported to [`super::scanned`] (see there).
    static SCANNED: AtomicU64 = AtomicU64::new(0);
    /// Live spill files: while there are none, reports cost one load.
    static LIVE: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);

    /// True when this report trimmed.
    pub(super) fn scanned(bytes: u64) -> bool {
        if LIVE.load(Ordering::Relaxed) == 0 {
            return false;
        }
        let before = SCANNED.fetch_add(bytes, Ordering::Relaxed);
        let trims = (before + bytes) / TRIM_BYTES != before / TRIM_BYTES;
        if trims {
            trim();
        }
        trims
    }

    /// Drops every spill file's mapped pages from the process.
    pub(super) fn trim() {
        for &(start, bytes) in lock().iter() {
            if bytes > 0 {
                // SAFETY: the range is one of our live shared file mappings (the
                // list is locked, and a SpillVec leaves it before unmapping);
                // MADV_DONTNEED there keeps the file's data and only unmaps pages.
                unsafe {
                    libc::madvise(start as *mut libc::c_void, bytes, libc::MADV_DONTNEED);
                }
            }
        }
    }
}

/// Drops the spill files' mapped pages from the process now (tests; the
/// trimming thread does it as they grow).
pub fn trim_now() {
    #[cfg(target_os = "linux")]
    file::trim();
}

/// Reports `bytes` read or written through spilled stores by a stage that
/// scans them: the kernel maps a cached file's pages many at a time, faster
/// than the trimming thread looks, so every [`TRIM_BYTES`] reported the
/// caller drops the mapped pages itself. Free while nothing is spilled.
pub fn scanned(bytes: usize) {
    #[cfg(target_os = "linux")]
    file::scanned(bytes as u64);
    #[cfg(not(target_os = "linux"))]
    let _ = bytes;
}

#[cfg(test)]
mod tests {
    use super::*;

    fn policy(above: u64) -> Option<SpillPolicy> {
        Some(SpillPolicy::new(std::env::temp_dir(), above))
    }

    #[test]
    fn a_spilled_store_holds_what_one_in_memory_does() {
        use rayon::prelude::*;
        let (mut mem, mut spilled) = (Store::<[u32; 4]>::default(), Store::<[u32; 4]>::default());
        spilled.set_policy(policy(1000));
        for round in 0..3u32 {
            for s in [&mut mem, &mut spilled] {
                s.extend_from_slice(&[[round; 4], [round + 1; 4]], "test").unwrap();
                s.par_extend((0..50_000u32).into_par_iter().map(|i| [i, i ^ round, i * 3, round]), "test").unwrap();
                s.truncate(s.len() - 7);
            }
            trim_now();
            assert_eq!(&mem[..], &spilled[..]);
        }
        assert!(!mem.is_spilled());
        assert!(cfg!(not(target_os = "linux")) || spilled.is_spilled());
        // Reused after clearing: what the file held before is overwritten.
        spilled.clear();
        spilled.extend_from_slice(&[[9; 4]], "test").unwrap();
        assert_eq!(&spilled[..], &[[9; 4]]);
    }

    #[test]
    fn stores_share_their_policys_memory_budget_and_zero_what_they_grow() {
        let p = policy(1000);
        let mut a = Store::<u8>::with_policy(p.clone());
        a.extend_zeroed(600, "a").unwrap();
        assert!(!a.is_spilled());
        let mut b = Store::<u8>::with_policy(p.clone());
        b.extend_from_slice(&[5; 300], "b").unwrap();
        assert!(!b.is_spilled(), "900 bytes of 1000 are in memory");
        b.extend_zeroed(300, "b").unwrap();
        assert!(cfg!(not(target_os = "linux")) || b.is_spilled(), "1200 bytes would be");
        assert_eq!(p.as_ref().unwrap().held(), a.capacity() as u64);
        assert_eq!((&b[..300], &b[300..]), (&[5u8; 300][..], &[0u8; 300][..]));
        // Grown again over what it held: zeros, not the old bytes.
        b.truncate(100);
        b.extend_zeroed(500, "b").unwrap();
        assert!(b[..100].iter().all(|&x| x == 5) && b[100..].iter().all(|&x| x == 0));
        drop(a);
        assert_eq!(p.as_ref().unwrap().held(), 0);
        let filed = p.as_ref().unwrap().peak_in_files();
        assert!(cfg!(not(target_os = "linux")) || filed >= 600, "{filed} bytes filed");
    }

    #[test]
    fn a_charge_takes_its_share_of_the_budget_until_dropped() {
        let p = policy(1000);
        let mut charge = Charge::new(p.clone());
        charge.set(700);
        charge.set(500);
        assert_eq!(p.as_ref().unwrap().held(), 500);
        // 500 charged and 600 stored would pass 1000: the store goes to its file.
        let mut s = Store::<u8>::with_policy(p.clone());
        s.extend_from_slice(&[1; 600], "s").unwrap();
        assert!(cfg!(not(target_os = "linux")) || s.is_spilled(), "600 bytes beside a charge of 500");
        drop(charge);
        assert_eq!(p.as_ref().unwrap().held(), s.capacity() as u64 * u64::from(!s.is_spilled()));
        // Without it the same store stays in memory.
        let mut t = Store::<u8>::with_policy(policy(1000));
        t.extend_from_slice(&[1; 600], "t").unwrap();
        assert!(!t.is_spilled());
    }

    #[cfg(target_os = "linux")]
    #[test]
    fn scanned_bytes_trim_every_trim_bytes_while_a_store_is_spilled() {
        let mut s = Store::<u8>::with_policy(policy(0));
        s.extend_from_slice(&[7; 4096], "test").unwrap();
        assert!(s.is_spilled());
        // Every TRIM_BYTES reported cross one multiple of it, wherever the count was.
        assert!(file::scanned(TRIM_BYTES));
        assert!(!file::scanned(0));
        let trims = (0..64).filter(|_| file::scanned(TRIM_BYTES / 4)).count();
        assert!((16..=17).contains(&trims), "{trims} trims for 16 × TRIM_BYTES");
        // Trimming keeps the data.
        assert!(s.iter().all(|&b| b == 7));
    }

    #[cfg(target_os = "linux")]
    #[test]
    fn a_spill_file_has_no_name_and_a_missing_directory_is_an_error() {
        let dir = std::env::temp_dir().join(format!("vdbcook-spill-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let mut s = Store::<u64>::default();
        s.set_policy(Some(SpillPolicy::new(dir.clone(), 0)));
        s.extend_from_slice(&[1, 2, 3], "test").unwrap();
        assert!(s.is_spilled());
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 0, "the spill file has a name");
        drop(s);
        std::fs::remove_dir(&dir).unwrap();
        let mut s = Store::<u64>::default();
        s.set_policy(Some(SpillPolicy::new(dir.join("gone"), 0)));
        let e = s.extend_from_slice(&[1], "the test buffer").unwrap_err().to_string();
        assert!(e.starts_with("the test buffer: could not spill") && e.contains("gone"), "{e}");
    }
}
