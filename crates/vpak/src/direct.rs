//! Writing a large file past the page cache.
//!
//! A cook writes its asset once and does not read it back, and on Linux a
//! buffered write copies every byte into the page cache first: for a
//! 1.3 GB asset, seconds of system time (docs/benchmarks.md). [`DirectWriter`]
//! writes whole aligned blocks with `O_DIRECT` (the disk reads them from our
//! buffer) and only the ragged ends of a run of writes through the page
//! cache. Where the system or the file system has no `O_DIRECT`, it is a
//! plain buffered writer.

use memmap2::MmapMut;
use std::fs::File;
use std::io::{Seek, SeekFrom, Write};

/// The alignment `O_DIRECT` asks of offsets, lengths and memory (4 KiB
/// covers devices of 512-byte and of 4 KiB logical blocks).
const BLOCK: usize = 4096;
/// Bytes gathered before they are written.
const CHUNK: usize = 8 << 20;

/// A [`Write`] + [`Seek`] over a file that writes aligned blocks directly
/// to the disk where it can (see the module's text), on a thread of its
/// own while the next chunk is gathered. Every byte written reaches the
/// file by [`Write::flush`], a seek or [`DirectWriter::into_file`]; a writer
/// dropped before loses what it holds (an output given up on).
pub struct DirectWriter {
    file: File,
    /// The chunk being gathered (`None`: none yet, or since everything was written).
    buf: Option<MmapMut>,
    /// The file offset of the buffer's first byte (a multiple of [`BLOCK`]).
    base: u64,
    /// The buffer's bytes before this are not data (the start of the block the data starts in).
    head: usize,
    /// The buffer's bytes up to this are in use (`head` included).
    len: usize,
    /// Chunks to write, to the writing thread (`None`: written here).
    jobs: Option<std::sync::mpsc::SyncSender<Job>>,
    /// Chunks written, back from the writing thread, with how it went.
    done: Option<std::sync::mpsc::Receiver<(MmapMut, std::io::Result<()>)>>,
    thread: Option<std::thread::JoinHandle<()>>,
    /// Chunk buffers free, and out at the writing thread.
    free: Vec<MmapMut>,
    out: usize,
    /// Where blocks are written without the thread: the same file with `O_DIRECT`.
    direct: Option<File>,
    /// A failed write of the thread's, reported by the next call.
    failed: Option<std::io::Error>,
}

/// Bytes `[head, end)` of `buf`, which starts at file offset `base`.
struct Job {
    buf: MmapMut,
    base: u64,
    head: usize,
    end: usize,
}

/// Chunk buffers at most (one gathered while the other is written).
const BUFFERS: usize = 2;

/// A chunk buffer: anonymous memory, page-aligned (as `O_DIRECT` asks) and
/// zeroed by the system as its pages are first touched, so a small write
/// touches few of them. (An over-aligned heap allocation would be cleared
/// whole by hand: 8 MiB for every write after a seek.)
fn chunk_buffer() -> std::io::Result<MmapMut> {
    let buf = MmapMut::map_anon(CHUNK).map_err(|_| std::io::Error::new(std::io::ErrorKind::OutOfMemory, "no memory for a write buffer"))?;
    // Where huge pages are the default, a first touch would clear 2 MiB.
    #[cfg(target_os = "linux")]
    let _ = buf.advise(memmap2::Advice::NoHugePage);
    Ok(buf)
}

/// Writes a job: its whole blocks through `direct` where it is given (and
/// takes them; else, and for the ragged ends, through `file`).
fn write_job(file: &File, direct: &mut Option<File>, job: &Job) -> std::io::Result<()> {
    use std::os::unix::fs::FileExt;
    let data: &[u8] = &job.buf;
    let (from, to) = (job.head.next_multiple_of(BLOCK), job.end / BLOCK * BLOCK);
    if from >= to || direct.is_none() {
        return file.write_all_at(&data[job.head..job.end], job.base + job.head as u64);
    }
    file.write_all_at(&data[job.head..from], job.base + job.head as u64)?;
    if let Some(Err(e)) = direct.as_ref().map(|d| d.write_all_at(&data[from..to], job.base + from as u64)) {
        if e.raw_os_error() != Some(libc::EINVAL) {
            return Err(e);
        }
        // Alignment this device does not take: buffered from now on.
        *direct = None;
        file.write_all_at(&data[from..to], job.base + from as u64)?;
    }
    file.write_all_at(&data[to..job.end], job.base + to as u64)
}

impl DirectWriter {
    /// A writer at the start of `file` (opened for writing).
    pub fn new(file: File) -> std::io::Result<DirectWriter> {
        DirectWriter::with(file, true, true)
    }

    /// A writer of `file` through the page cache (still on a thread of its
    /// own): for a file that is read back soon.
    pub fn through_cache(file: File) -> std::io::Result<DirectWriter> {
        DirectWriter::with(file, false, true)
    }

    fn with(file: File, past_cache: bool, thread: bool) -> std::io::Result<DirectWriter> {
        let direct = if past_cache { open_direct(&file) } else { None };
        let mut w = DirectWriter { buf: None, base: 0, head: 0, len: 0, jobs: None, done: None, thread: None, free: Vec::new(), out: 0, direct: None, failed: None, file };
        let (jobs, job_rx) = std::sync::mpsc::sync_channel::<Job>(BUFFERS);
        let (done_tx, done) = std::sync::mpsc::channel();
        let (mut direct_there, file_there) = (direct.as_ref().and_then(|d| d.try_clone().ok()), w.file.try_clone()?);
        let spawned = thread.then(|| std::thread::Builder::new().name("writer".into())).ok_or(()).and_then(|b| {
            b.spawn(move || {
                for job in job_rx {
                    let r = write_job(&file_there, &mut direct_there, &job);
                    if done_tx.send((job.buf, r)).is_err() {
                        return;
                    }
                }
            })
            .map_err(|_| ())
        });
        match spawned {
            Ok(t) => (w.jobs, w.done, w.thread) = (Some(jobs), Some(done), Some(t)),
            // No thread (no memory for its stack): written here.
            Err(()) => w.direct = direct,
        }
        Ok(w)
    }

    /// The file, once every byte is written to it.
    pub fn into_file(mut self) -> std::io::Result<File> {
        self.write_out(true)?;
        self.file.try_clone()
    }

    fn bytes(&mut self) -> &mut [u8] {
        self.buf.as_deref_mut().unwrap_or_default()
    }

    fn position(&self) -> u64 {
        self.base + self.len as u64
    }

    /// A chunk buffer back from the writing thread (its write's error kept for the caller).
    fn take_back(&mut self) -> std::io::Result<MmapMut> {
        let back = self.done.as_ref().and_then(|d| d.recv().ok());
        let (buf, r) = back.ok_or_else(|| std::io::Error::other("the writing thread stopped"))?;
        self.out -= 1;
        if let Err(e) = r {
            self.failed.get_or_insert(e);
        }
        Ok(buf)
    }

    /// The first failed write of the thread's, once.
    fn check(&mut self) -> std::io::Result<()> {
        self.failed.take().map_or(Ok(()), Err)
    }

    /// Writes the buffer out: its whole blocks, and with `all` the rest too
    /// (without, the last partial block stays, moved to the buffer's front).
    /// With `all`, returns once everything is written.
    fn write_out(&mut self, all: bool) -> std::io::Result<()> {
        let end = if all { self.len } else { self.len / BLOCK * BLOCK };
        if end == self.head && self.out == 0 {
            return self.check();
        }
        // No buffer means nothing gathered since everything went (`len` is
        // `head`), which the return above covers: another state is a bug,
        // refused rather than losing bytes.
        let missing = || std::io::Error::other("the write buffer is missing");
        let Some(jobs) = self.jobs.clone() else {
            let full = self.buf.take().ok_or_else(missing)?;
            let job = Job { buf: full, base: self.base, head: self.head, end };
            let r = write_job(&self.file, &mut self.direct, &job);
            self.buf = (!all).then_some(job.buf);
            let len = self.len;
            if !all {
                self.bytes().copy_within(end..len, 0);
            }
            self.finish_chunk(end, all);
            return r;
        };
        if self.buf.is_none() {
            return Err(missing());
        }
        // The next buffer first: if there is none to be had, the chunk stays.
        let next = match self.free.pop() {
            // Everything goes: no buffer follows (until the next write).
            _ if all => None,
            Some(b) => Some(b),
            None if self.out + 1 < BUFFERS => Some(chunk_buffer()?),
            None => Some(self.take_back()?),
        };
        let full = std::mem::replace(&mut self.buf, next).ok_or_else(missing)?;
        let tail = self.len - end;
        self.bytes()[..tail].copy_from_slice(&full[end..end + tail]);
        jobs.send(Job { buf: full, base: self.base, head: self.head, end }).map_err(|_| std::io::Error::other("the writing thread stopped"))?;
        self.out += 1;
        self.finish_chunk(end, all);
        if all {
            while self.out > 0 {
                self.take_back()?;
            }
            // Written out: the buffers go until the next write (a cook writes a segment, then builds the next).
            self.free = Vec::new();
        }
        self.check()
    }

    /// The buffer after a chunk's bytes up to `end` went out (what was past them now at its front).
    fn finish_chunk(&mut self, end: usize, all: bool) {
        let pos = self.base + end as u64;
        if all {
            self.seek_to(pos);
        } else {
            // `end` is a multiple of BLOCK: the rest starts a block.
            (self.base, self.head, self.len) = (pos, 0, self.len - end);
        }
    }

    /// Makes the (empty) buffer start at file offset `pos`.
    fn seek_to(&mut self, pos: u64) {
        self.base = pos / BLOCK as u64 * BLOCK as u64;
        self.head = (pos - self.base) as usize;
        self.len = self.head;
    }
}

impl Drop for DirectWriter {
    fn drop(&mut self) {
        // The thread ends with its queue; wait for it, so the file is not written after.
        self.jobs = None;
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

#[cfg(target_os = "linux")]
fn open_direct(file: &File) -> Option<File> {
    use std::os::unix::fs::OpenOptionsExt;
    use std::os::unix::io::AsRawFd;
    // A second open file of the same inode (unnamed temporary files too).
    std::fs::OpenOptions::new().write(true).custom_flags(libc::O_DIRECT).open(format!("/proc/self/fd/{}", file.as_raw_fd())).ok()
}

#[cfg(not(target_os = "linux"))]
fn open_direct(_file: &File) -> Option<File> {
    None
}

impl Write for DirectWriter {
    fn write(&mut self, data: &[u8]) -> std::io::Result<usize> {
        if self.buf.is_none() {
            self.buf = Some(chunk_buffer()?);
        }
        let n = data.len().min(CHUNK - self.len);
        let len = self.len;
        self.bytes()[len..len + n].copy_from_slice(&data[..n]);
        self.len += n;
        if self.len == CHUNK {
            self.write_out(false)?;
        }
        Ok(n)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.write_out(true)
    }
}

impl Seek for DirectWriter {
    fn seek(&mut self, to: SeekFrom) -> std::io::Result<u64> {
        let pos = self.position();
        let target = match to {
            SeekFrom::Start(p) => Some(p),
            SeekFrom::Current(d) => pos.checked_add_signed(d),
            SeekFrom::End(d) => {
                self.write_out(true)?;
                self.file.metadata()?.len().checked_add_signed(d)
            }
        };
        let target = target.ok_or_else(|| std::io::Error::new(std::io::ErrorKind::InvalidInput, "a seek before the start of the file"))?;
        if target != pos {
            self.write_out(true)?;
            self.seek_to(target);
        }
        Ok(target)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Read;

    /// Writes, seeks back and rewrites at unaligned places, across chunk
    /// and block boundaries: the file is what a buffered writer makes.
    #[test]
    fn a_direct_writer_writes_what_a_buffered_one_does() {
        let dir = std::env::temp_dir().join(format!("vdbcook-direct-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let (a, b) = (dir.join("direct"), dir.join("plain"));
        let data: Vec<u8> = (0..CHUNK * 2 + 12_345).map(|i| (i * 7 + i / 4099) as u8).collect();
        let ops = |w: &mut dyn WriteSeek| {
            w.write_all(&data[..3]).unwrap();
            w.write_all(&data[3..BLOCK + 5]).unwrap();
            w.write_all(&data[BLOCK + 5..CHUNK + 77]).unwrap();
            w.flush().unwrap();
            w.write_all(&data[CHUNK + 77..]).unwrap();
            assert_eq!(w.stream_position().unwrap(), data.len() as u64);
            w.seek(SeekFrom::Start(10)).unwrap();
            w.write_all(b"patched at ten").unwrap();
            w.seek(SeekFrom::Start(CHUNK as u64 - 2)).unwrap();
            w.write_all(&[0xee; BLOCK * 3]).unwrap();
            w.seek(SeekFrom::End(0)).unwrap();
            w.write_all(b"tail").unwrap();
            w.flush().unwrap();
        };
        let read = |p: &std::path::Path| {
            let mut v = Vec::new();
            File::open(p).unwrap().read_to_end(&mut v).unwrap();
            v
        };
        ops(&mut std::io::BufWriter::new(File::create(&b).unwrap()));
        let plain = read(&b);
        assert_eq!(plain.len(), data.len() + 4);
        // Written on a thread of its own, and (where no thread can start) here.
        for thread in [true, false] {
            let mut d = DirectWriter::with(File::create(&a).unwrap(), true, thread).unwrap();
            ops(&mut d);
            d.into_file().unwrap();
            assert!(read(&a) == plain, "the files differ (thread: {thread})");
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    trait WriteSeek: Write + Seek {}
    impl<T: Write + Seek> WriteSeek for T {}
}
