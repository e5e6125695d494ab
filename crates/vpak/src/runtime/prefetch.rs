//! Prefetch: a worker thread that reads and restores the segments a caller
//! asks for ahead of time (and runs whatever else the caller's closure adds,
//! an upload to the GPU say), while the caller plays the current one.

use super::Reader;
use crate::Error;
use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{mpsc, Arc};
use std::time::{Duration, Instant};

/// What [`Prefetcher::take`] gives: the worker's value for the segment, and
/// how long the caller waited for it (zero when it was ready).
#[derive(Debug)]
pub struct Fetched<T> {
    pub value: T,
    pub waited: Duration,
}

/// A worker thread running `work(reader, segment)` for each segment
/// requested, in the order requested, one at a time. The caller bounds the
/// memory: at most as many values exist as segments requested and not yet
/// taken, plus the one being made. Dropping it stops the worker (after the
/// segment in hand; requests not started are dropped).
///
/// ```no_run
/// # use std::sync::Arc;
/// # use vdbcook_vpak::runtime::{Prefetcher, Reader};
/// # fn main() -> Result<(), vdbcook_vpak::Error> {
/// let reader = Arc::new(Reader::open("fire.vpak".as_ref())?);
/// // Each segment as an Asset (restored, checked); an engine would upload it here too.
/// let mut ahead = Prefetcher::new(reader.clone(), |r: &Reader, s| r.segment_asset(s, Vec::new()));
/// for s in 0..reader.segment_count() {
///     if s + 1 < reader.segment_count() {
///         ahead.request(s + 1);
///     }
///     let seg = ahead.take(s)?; // blocks only when the worker is not done
///     println!("segment {s}: waited {:?}", seg.waited);
/// }
/// # Ok(()) }
/// ```
pub struct Prefetcher<T, E = Error> {
    requests: Option<mpsc::Sender<usize>>,
    results: mpsc::Receiver<(usize, Result<T, E>)>,
    stop: Arc<AtomicBool>,
    worker: Option<std::thread::JoinHandle<()>>,
    /// Requested and not yet taken, in request order.
    pending: VecDeque<usize>,
    /// Done and not yet taken.
    ready: Vec<(usize, Result<T, E>)>,
}

impl<T: Send + 'static, E: From<Error> + Send + 'static> Prefetcher<T, E> {
    /// Starts the worker. `work` runs on it for each requested segment: read
    /// and restore the segment ([`Reader::segment_asset`],
    /// [`Reader::fill_segment`]) and whatever the caller needs done off its
    /// own thread; its error is given to the caller by [`Prefetcher::take`].
    pub fn new(reader: Arc<Reader>, mut work: impl FnMut(&Reader, usize) -> Result<T, E> + Send + 'static) -> Prefetcher<T, E> {
        let (requests, jobs) = mpsc::channel::<usize>();
        let (done, results) = mpsc::channel();
        let stop = Arc::new(AtomicBool::new(false));
        let stopped = stop.clone();
        let worker = std::thread::Builder::new().name("vpak-prefetch".into()).spawn(move || {
            while let Ok(s) = jobs.recv() {
                if stopped.load(Ordering::Relaxed) {
                    break;
                }
                // A panic in `work` ends the worker; the caller hears of it as an error, not a panic.
                let Ok(r) = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| work(&reader, s))) else { break };
                if done.send((s, r)).is_err() {
                    break;
                }
            }
        });
        // A thread that cannot start leaves no worker: every take says so.
        let (worker, requests) = match worker {
            Ok(w) => (Some(w), Some(requests)),
            Err(_) => (None, None),
        };
        Prefetcher { requests, results, stop, worker, pending: VecDeque::new(), ready: Vec::new() }
    }

    /// Asks the worker for segment `s` (after those asked for before).
    pub fn request(&mut self, s: usize) {
        if let Some(tx) = &self.requests {
            // A stopped worker is reported by take.
            let _ = tx.send(s);
        }
        self.pending.push_back(s);
    }

    /// Segments requested and not yet taken, in request order.
    pub fn pending(&self) -> impl Iterator<Item = usize> + '_ {
        self.pending.iter().copied()
    }

    /// Segment `s`'s value (requested now if it was not), waiting for the
    /// worker only when it is not done. Values of other segments that come
    /// in meanwhile are kept for their own take.
    pub fn take(&mut self, s: usize) -> Result<Fetched<T>, E> {
        match self.pending.iter().position(|&p| p == s) {
            Some(k) => {
                self.pending.remove(k);
            }
            None => self.request(s),
        }
        if let Some(k) = self.ready.iter().position(|(r, _)| *r == s) {
            let (_, value) = self.ready.remove(k);
            return value.map(|value| Fetched { value, waited: Duration::ZERO });
        }
        let start = Instant::now();
        loop {
            match self.results.recv() {
                Ok((r, value)) if r == s => return value.map(|value| Fetched { value, waited: start.elapsed() }),
                Ok(other) => self.ready.push(other),
                Err(_) => return Err(Error::Invalid("the prefetch worker stopped (it panicked, or could not start)".into()).into()),
            }
        }
    }
}

impl<T, E> Drop for Prefetcher<T, E> {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        self.requests = None;
        if let Some(w) = self.worker.take() {
            let _ = w.join();
        }
    }
}
