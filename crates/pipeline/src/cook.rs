//! Cooking from files: frames read on a thread one frame ahead and pushed
//! into one or more [`Cooker`]s (an asset and its lossless reference share
//! one read), from typed [`CookSettings`]; each segment finished and written
//! as soon as its last frame is in.

use crate::grids::{read_frame, Channels, Frame, FrameFile, GridSelection};
use crate::options::{CookSettings, Optimize};
use crate::{Context, Error, Result};
use std::path::{Path, PathBuf};
use std::time::Instant;
use vdbcook_cook::{CookOptions, CookReport, Cooker, Format, Progress};
use vdbcook_vpak::coding::Schemes;
use vdbcook_vpak::segments::PartInfo;
use vdbcook_vpak::{Asset, AtomicFile, DirectWriter, SourceFile, Writer};

/// Reads `files` on a thread that stays one frame ahead (at most two source
/// frames live at once; none ahead while a segment finishes once the cook
/// has spilled) and pushes each frame into one cooker per entry of
/// `opts` (an asset and its lossless reference share one read), made for the
/// channels the first frame with a file resolves (frames with `--with`
/// files: the first file of each sequence). Every `segment` frames (and
/// after the last frame) the cookers go to `on_segment` (with the next
/// segment's cookers, before their first frame) with the records of
/// the segment's `--with` files (the cooker records each frame's main file),
/// and cookers for the next segment take their place, so only one segment's
/// bricks are held at a time. Source paths are recorded relative to `base` when they
/// are below it. Returns the channels and the seconds spent waiting for frames.
pub fn feed(opts: Vec<CookOptions>, files: Vec<FrameFile>, sel: GridSelection, base: Option<PathBuf>, segment: Option<usize>, on_segment: &mut OnSegment, bars: &dyn Progress) -> Result<Fed> {
    // Each frame comes with the channels when they are first resolved.
    let (tx, rx) = std::sync::mpsc::sync_channel::<(Result<Frame>, Option<Channels>)>(0);
    // The reader reads the first frame of each segment after the first once
    // it is let (see `credit` below).
    let (credit, credits) = std::sync::mpsc::channel::<()>();
    let segment_frames = segment.unwrap_or(usize::MAX).max(1);
    let total = files.len() as u64;
    // A thread that cannot start (no memory for its stack) is an error, not a panic.
    let reader = std::thread::Builder::new()
        .name("frame reader".into())
        .spawn(move || {
            let mut channels = None;
            let mut sent = false;
            // Frames of several files: the channels from each sequence's first file, before any frame.
            if files.iter().any(|f| !f.with.is_empty()) {
                match crate::grids::resolve_sequences(&files, &sel) {
                    Ok(c) => channels = Some(c),
                    Err(e) => {
                        let _ = tx.send((Err(e), None));
                        return;
                    }
                }
            }
            for (i, f) in files.into_iter().enumerate() {
                if i > 0 && i % segment_frames == 0 && credits.recv().is_err() {
                    break;
                }
                let r = read_frame(f, &sel, &mut channels).map(|mut frame| {
                    if let Some(b) = base.as_deref() {
                        let relative = |s: &mut SourceFile, p: &Path| {
                            if let Ok(rel) = p.strip_prefix(b) {
                                s.path = rel.display().to_string();
                            }
                        };
                        if let Some(s) = frame.source.as_mut() {
                            relative(s, &frame.path);
                        }
                        for (p, s) in frame.with_sources.iter_mut() {
                            relative(s, p);
                        }
                    }
                    frame
                });
                let stop = r.is_err();
                let first = if sent { None } else { channels.clone() };
                sent |= first.is_some();
                if tx.send((r, first)).is_err() || stop {
                    break;
                }
            }
        })
        .map_err(|e| Error::Failed(format!("cannot start the frame reader thread: {e}")))?;
    bars.start("reading frames", total);
    let mut read_secs = 0.0;
    let mut wait = Instant::now();
    let mut failure = None;
    let mut segments = Segments { cookers: Vec::new(), pushed: 0, emitted: 0, segment: segment_frames, on_segment };
    let mut channels: Option<Channels> = None;
    // Frames before the first one whose file resolves the channels: empty.
    let mut leading: Vec<(Option<SourceFile>, Option<i64>)> = Vec::new();
    // The cookers, for the channels (or, when no frame resolved any, one
    // channel named by nothing), with the leading empty frames.
    let start = |specs: Option<&Channels>, leading: &mut Vec<(Option<SourceFile>, Option<i64>)>, segments: &mut Segments| -> Result<()> {
        segments.cookers = opts.iter().map(|o| specs.map_or_else(|| Cooker::new(o.clone()), |ch| Cooker::with_channels(o.clone(), ch.specs.clone()))).collect();
        for (s, number) in leading.drain(..) {
            segments.push(|c| {
                if let Some(n) = number {
                    c.number_next(n)?;
                }
                c.push_empty(s.clone());
                Ok(())
            })?;
            segments.hand_on_full()?;
        }
        Ok(())
    };
    let mut stated = Vec::new();
    // A cook that has spilled is held to its memory budget: there the next
    // frame is not read while a segment finishes (a decoded frame beside the
    // segment's last stages); elsewhere the reader stays a frame ahead.
    let spilled = || opts.iter().any(|o| o.spill.as_ref().is_some_and(|p| p.peak_in_files() > 0));
    for (received, (r, ch)) in rx.into_iter().enumerate() {
        read_secs += wait.elapsed().as_secs_f64();
        // Frame `received` of the reader's; the last of a segment lets it read on.
        let ends_segment = (received + 1) % segment_frames == 0;
        let held = ends_segment && !segments.cookers.is_empty() && spilled();
        if ends_segment && !held {
            let _ = credit.send(());
        }
        let pushed = r.and_then(|frame| {
            stated.push(frame.stated);
            if let Some(ch) = ch {
                start(Some(&ch), &mut leading, &mut segments)?;
                channels = Some(ch);
            }
            if segments.cookers.is_empty() {
                leading.push((frame.source, frame.number));
                return Ok(());
            }
            let n = segments.pushed;
            segments.push(|c| {
                let named = || format!("{}: frame {n}", frame.path.display());
                if let Some(number) = frame.number {
                    c.number_next(number).with_context(named)?;
                }
                match &frame.grids {
                    Some(g) => c.push_channels(&g.iter().map(Option::as_ref).collect::<Vec<_>>(), frame.source.clone()).with_context(named)?,
                    None => c.push_empty(frame.source.clone()),
                }
                c.add_sources(frame.with_sources.iter().map(|(_, s)| s.clone()));
                Ok(())
            })
        });
        if let Err(e) = pushed.and_then(|_| segments.hand_on_full()) {
            failure = Some(e);
            break;
        }
        if held {
            let _ = credit.send(());
        }
        bars.advance(1);
        wait = Instant::now();
    }
    bars.finish();
    // A reader waiting to be let read stops.
    drop(credit);
    reader.join().map_err(|_| Error::Failed("the frame reader thread panicked".into()))?;
    if let Some(e) = failure {
        return Err(e);
    }
    if segments.cookers.is_empty() {
        start(None, &mut leading, &mut segments)?;
    }
    segments.flush()?;
    Ok(Fed { channels, read_secs, source_time: crate::source_time::summarize(&stated) })
}

/// Takes a full segment's cookers, and the next segment's (before their first frame).
pub type OnSegment<'a> = dyn FnMut(Vec<Cooker>, &mut [Cooker]) -> Result<()> + 'a;

/// What [`feed`] read besides the frames it pushed.
pub struct Fed {
    /// The channels, once a frame resolved them.
    pub channels: Option<Channels>,
    /// Seconds spent waiting for frames to be read.
    pub read_secs: f64,
    /// What the files' metadata said of time.
    pub source_time: Option<vdbcook_cook::SourceTime>,
}

/// The cookers of the segment being fed, and where finished segments go.
struct Segments<'a> {
    cookers: Vec<Cooker>,
    /// Frames pushed over every segment.
    pushed: usize,
    /// Segments handed on.
    emitted: usize,
    segment: usize,
    on_segment: &'a mut OnSegment<'a>,
}

impl Segments<'_> {
    /// Pushes the next frame into every cooker.
    fn push(&mut self, mut push: impl FnMut(&mut Cooker) -> Result<()>) -> Result<()> {
        for c in self.cookers.iter_mut() {
            push(c)?;
        }
        self.pushed += 1;
        Ok(())
    }

    /// Hands a full segment on; called once its last frame is dropped, so
    /// that only the frame being read is held beside it.
    fn hand_on_full(&mut self) -> Result<()> {
        if self.cookers.first().is_some_and(|c| c.frame_count() >= self.segment) {
            let next = self.cookers.iter().map(|c| c.next_segment(self.pushed)).collect();
            let full = std::mem::replace(&mut self.cookers, next);
            self.emitted += 1;
            (self.on_segment)(full, &mut self.cookers)?;
            vdbcook_grid::mem::release_free();
        }
        Ok(())
    }

    /// Hands on the last segment (also when it is the only one and has no frames).
    fn flush(&mut self) -> Result<()> {
        if self.emitted == 0 || self.cookers.first().is_some_and(|c| c.frame_count() > 0) {
            (self.on_segment)(std::mem::take(&mut self.cookers), &mut [])?;
        }
        Ok(())
    }
}

/// The selection that reads back every channel of an asset's metadata.
pub fn selection_of(meta: &vdbcook_vpak::Metadata) -> GridSelection {
    let mut grids: Vec<String> = Vec::new();
    for c in &meta.channels {
        if !grids.contains(&c.grid) {
            grids.push(c.grid.clone());
        }
    }
    match grids.len() {
        0 => GridSelection::Default,
        1 if !grids[0].is_empty() => GridSelection::One(grids.remove(0)),
        _ => GridSelection::Many(grids),
    }
}

/// Cooks `files` losslessly in memory (f32, no clustering) with `levels` levels of detail, cut
/// into segments of `segment` frames when given: the reference asset `validate` compares with,
/// and what `render` draws for a .vdb.
pub fn cook_lossless_levels(files: Vec<FrameFile>, sel: GridSelection, levels: vdbcook_vpak::LevelCount, segment: Option<usize>, bars: &dyn Progress) -> Result<Asset> {
    let count = segment_count(files.len(), segment);
    let mut out = Output::scratch(count)?;
    let mut write = |cookers: Vec<Cooker>, next: &mut [Cooker]| -> Result<()> {
        for (i, c) in cookers.into_iter().enumerate() {
            out.add(c, next.get_mut(i), &vdbcook_cook::NoProgress)?;
        }
        Ok(())
    };
    feed(vec![CookOptions { levels, ..reference_options() }], files, sel, None, segment, &mut write, bars)?;
    Ok(out.finish()?.0)
}

fn reference_options() -> CookOptions {
    CookOptions { format: Format::F32, clustering: None, ..CookOptions::default() }
}

/// Segments of `frames` frames cut every `segment`: at least one.
pub fn segment_count(frames: usize, segment: Option<usize>) -> u32 {
    segment.map_or(1, |n| frames.div_ceil(n.max(1)).max(1)) as u32
}

/// One asset being written, segment after segment: in memory, or into a
/// file that gets its name only when [`Cooked::commit`] is called.
struct Output {
    /// The segment being written into the file, while the next one cooks
    /// (first, so that it is dropped, and waited for, before the file).
    writing: Option<Writing>,
    sink: Sink,
    reports: Vec<CookReport>,
    /// How each segment's sections are stored (`None`: as they are).
    coding: Option<Schemes>,
}

enum Sink {
    Memory(Writer<std::io::Cursor<Vec<u8>>>),
    /// The writer (away while a segment is written), the file it writes and
    /// the file's name (for errors).
    File(Option<Box<Writer<DirectWriter>>>, AtomicFile, String),
}

/// What a segment's write gives back: the writer, and the segment's entry
/// and seconds, or the error.
type Written = (Box<Writer<DirectWriter>>, std::result::Result<(vdbcook_vpak::SegmentEntry, f64), vdbcook_vpak::Error>);

/// What became of a segment's sections when the cooker gave them: the
/// seconds and section sizes of their supercompression, and (written into
/// memory) the segment's entry and seconds.
#[derive(Default)]
struct Delivered {
    coded: Option<(f64, Vec<(String, u64)>)>,
    written: Option<(vdbcook_vpak::SegmentEntry, f64)>,
}

/// A segment written on a thread of its own (its copy into the file's
/// buffers, bound by the disk, overlaps the segment's error figures and the
/// next segment's frames), and the index of its report. Dropped unfinished
/// (a cook that fails), it waits for the thread, so nothing writes the file
/// after.
struct Writing {
    thread: Option<std::thread::JoinHandle<Written>>,
    report: usize,
}

impl Drop for Writing {
    fn drop(&mut self) {
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl Output {
    fn memory(count: u32, coding: Option<Schemes>) -> Result<Output> {
        Ok(Output { sink: Sink::Memory(Writer::new(std::io::Cursor::new(Vec::new()), count)?), reports: Vec::new(), coding, writing: None })
    }

    /// An asset of `count` segments that is read back and let go: written into
    /// an unnamed file in the system's temporary directory (never given a name,
    /// so it goes with the process), read through a mapping a segment at a time.
    fn scratch(count: u32) -> Result<Output> {
        Output::file(&std::env::temp_dir().join("vdbcook-scratch.vpak"), true, count, None, None, false)
    }

    /// An asset (or, with `part`, a part file) of `count` segments written
    /// into an unnamed file for `path`; `past_cache` for an output that is
    /// not read back soon (its whole blocks go to disk with no copy in the page cache).
    fn file(path: &Path, overwrite: bool, count: u32, part: Option<&PartInfo>, coding: Option<Schemes>, past_cache: bool) -> Result<Output> {
        let ctx = || path.display().to_string();
        let mut file = AtomicFile::create(path, overwrite).with_context(ctx)?;
        let handle = file.file().try_clone().with_context(ctx)?;
        let handle = if past_cache { DirectWriter::new(handle) } else { DirectWriter::through_cache(handle) }.with_context(ctx)?;
        let writer = match part {
            Some(info) => vdbcook_vpak::segments::part_writer(handle, info, count),
            None => Writer::new(handle, count),
        }
        .with_context(ctx)?;
        Ok(Output { sink: Sink::File(Some(Box::new(writer)), file, ctx()), reports: Vec::new(), coding, writing: None })
    }

    /// Finishes a segment's cooker and writes the segment (beside the
    /// cooker's error figures, and into a file beside the next segment's
    /// frames); `next`, the next segment's cooker, takes over its brick
    /// pool's memory.
    fn add(&mut self, cooker: Cooker, next: Option<&mut Cooker>, bars: &dyn Progress) -> Result<()> {
        let frames = cooker.frame_count() as u32;
        let table = vdbcook_vpak::segments::first_offset(1);
        let mut delivered = None;
        let mut report = cooker.finish_into(next, bars, &mut |meta, sections| delivered = Some(self.deliver(frames, meta, sections))).map_err(|e| match e {
            // A byte budget is the whole file's: the segment table included.
            vdbcook_cook::Error::OverBudget { budget, smallest, level } => Error::from(vdbcook_cook::Error::OverBudget { budget: budget + table, smallest: smallest + table, level }),
            e => Error::from(e),
        })?;
        let Delivered { coded, written } = delivered.ok_or_else(|| Error::Failed("the cooker gave no sections".into()))??;
        if let Some(b) = report.budget.as_mut() {
            b.max_bytes += table;
            b.tries.iter_mut().for_each(|t| t.bytes += table);
        }
        if let Some((secs, disk)) = coded {
            report.timings.push(("supercompress".into(), secs));
            report.disk_sections = disk;
        }
        self.reports.push(report);
        if let Some((entry, secs)) = written {
            self.written(self.reports.len() - 1, &entry, secs);
        }
        Ok(())
    }

    /// Supercompresses a segment's sections when asked, and writes them:
    /// into memory at once, into a file on a thread of its own once the
    /// segment before is written. Its report comes next.
    fn deliver(&mut self, frames: u32, meta: &vdbcook_vpak::Metadata, mut sections: Vec<vdbcook_vpak::Section>) -> Result<Delivered> {
        let mut out = Delivered::default();
        if let Some(schemes) = self.coding {
            let t0 = Instant::now();
            sections = vdbcook_vpak::coding::supercompress(sections, meta, schemes)?;
            out.coded = Some((t0.elapsed().as_secs_f64(), sections.iter().map(|s| (vdbcook_vpak::kind::label(s.kind, s.index), s.data.len() as u64)).collect()));
        }
        self.wait()?;
        let index = self.reports.len();
        match &mut self.sink {
            Sink::Memory(w) => {
                let t0 = Instant::now();
                out.written = Some((w.add(frames, &sections)?, t0.elapsed().as_secs_f64()));
            }
            Sink::File(slot, _, name) => {
                let mut w = slot.take().ok_or_else(|| Error::Failed(format!("{name}: no writer")))?;
                let write = move || {
                    let t0 = Instant::now();
                    let r = w.add(frames, &sections).map(|e| (e, t0.elapsed().as_secs_f64()));
                    (w, r)
                };
                let thread = std::thread::Builder::new().name("segment writer".into()).spawn(write).map_err(|e| Error::Failed(format!("cannot start the segment writer thread: {e}")))?;
                self.writing = Some(Writing { thread: Some(thread), report: index });
            }
        }
        Ok(out)
    }

    /// Waits for the segment being written, if any; its writer comes back.
    fn wait(&mut self) -> Result<()> {
        let Some((thread, index)) = self.writing.take().and_then(|mut w| Some((w.thread.take()?, w.report))) else { return Ok(()) };
        let (w, r) = thread.join().map_err(|_| Error::Failed("the segment writer thread panicked".into()))?;
        let Sink::File(slot, _, name) = &mut self.sink else { return Ok(()) };
        *slot = Some(w);
        let (entry, secs) = r.with_context(|| name.clone())?;
        self.written(index, &entry, secs);
        Ok(())
    }

    /// Records segment `index`'s bytes and write time in its report.
    fn written(&mut self, index: usize, entry: &vdbcook_vpak::SegmentEntry, secs: f64) {
        if let Some(report) = self.reports.get_mut(index) {
            report.timings.push(("write".into(), secs));
            if let Some(seg) = report.segments.first_mut() {
                seg.bytes = entry.size;
            }
        }
    }

    /// The asset written, its file (to commit) and its report.
    fn finish(mut self) -> Result<(Asset, Option<AtomicFile>, Option<CookReport>)> {
        self.wait()?;
        let (asset, file) = match self.sink {
            Sink::Memory(w) => (Asset::from_bytes(&w.finish()?.into_inner())?, None),
            Sink::File(w, file, name) => {
                let w = w.ok_or_else(|| Error::Failed(format!("{name}: no writer")))?;
                let part = w.base() > 0;
                let f = w.finish().with_context(|| name.clone())?.into_file().map_err(Error::from).with_context(|| name.clone())?;
                let asset = if part { Asset::from_part_file(&f).map(|p| p.1) } else { Asset::from_file(&f) }.with_context(|| name.clone())?;
                (asset, Some(file))
            }
        };
        let report = match self.reports.len() {
            1 => self.reports.into_iter().next().map(|mut r| {
                r.file_bytes = asset.bytes().len() as u64;
                r.bits_per_active_voxel = if r.active_voxels > 0 { r.file_bytes as f64 * 8.0 / r.active_voxels as f64 } else { 0.0 };
                r
            }),
            _ => CookReport::merged(self.reports, asset.metadata()?, asset.bytes().len() as u64),
        };
        Ok((asset, file, report))
    }
}

/// One asset to cook: typed settings, its frame files and what to record.
pub struct CookJob<'a> {
    pub settings: &'a CookSettings,
    /// The frame files, in order.
    pub files: Vec<PathBuf>,
    /// The inputs as the user wrote them (recorded in the metadata).
    pub inputs: &'a [String],
    /// Source paths are recorded relative to this directory (a bake's manifest directory).
    pub base: Option<PathBuf>,
    /// Also cook the lossless reference (f32, no clustering) from the same reads.
    pub reference: bool,
    /// Write the asset into an unnamed file for this path (put in place by
    /// [`Cooked::commit`]; replacing an existing file when `.1`), not into memory.
    pub output: Option<(&'a Path, bool)>,
    /// Cook only this part of the segments, into a part file (`output` must be given).
    pub part: Option<Part>,
}

/// Part `index` (from 0) of `count`: one of `count` contiguous groups of an asset's segments.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Part {
    pub index: u32,
    pub count: u32,
}

impl std::str::FromStr for Part {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Part, String> {
        let bad = || format!("invalid part \"{s}\" (expected I/N with 1 <= I <= N, e.g. 2/4)");
        let (i, n) = s.split_once('/').ok_or_else(bad)?;
        let (i, n) = (i.trim().parse::<u32>().map_err(|_| bad())?, n.trim().parse::<u32>().map_err(|_| bad())?);
        if i == 0 || i > n {
            return Err(bad());
        }
        Ok(Part { index: i - 1, count: n })
    }
}

impl Part {
    /// The segments `[first, end)` of `segments` that this part cooks.
    pub fn segments(&self, segments: u32) -> std::ops::Range<u32> {
        let at = |i: u32| (u64::from(i) * u64::from(segments) / u64::from(self.count)) as u32;
        at(self.index)..at(self.index + 1)
    }
}

/// What parts of one cook share and parts of others do not: the tool, every
/// setting recorded, the segment length and each input file's path and size
/// (the `--with` files' after the main input's).
fn fingerprint(opts: &CookOptions, segment: Option<usize>, files: &[PathBuf], with: &[Vec<Option<PathBuf>>]) -> u64 {
    use std::hash::Hasher;
    let mut h = twox_hash::XxHash3_64::new();
    h.write(env!("CARGO_PKG_VERSION").as_bytes());
    for (k, v) in &opts.settings {
        h.write(&[0]);
        h.write(k.as_bytes());
        h.write(&[1]);
        h.write(v.as_bytes());
    }
    h.write(&(segment.unwrap_or(0) as u64).to_le_bytes());
    for f in files.iter().map(Some).chain(with.iter().flatten().map(Option::as_ref)) {
        match f {
            Some(f) => {
                h.write(f.to_string_lossy().as_bytes());
                h.write(&std::fs::metadata(f).map_or(u64::MAX, |m| m.len()).to_le_bytes());
            }
            None => h.write(&[2]),
        }
    }
    h.finish()
}

/// What [`cook_asset`] made: the asset (in memory, or in a file to commit),
/// the report, the channels cooked (names joined by ", ") and, when asked,
/// the reference asset.
pub struct Cooked {
    pub asset: Asset,
    pub file: Option<AtomicFile>,
    pub report: CookReport,
    pub grid: Option<String>,
    pub reference: Option<Asset>,
}

impl Cooked {
    /// Puts the asset's file in place (see [`CookJob::output`]).
    pub fn commit(&mut self) -> Result<()> {
        match self.file.take() {
            Some(f) => Ok(f.commit()?),
            None => Err(Error::Failed("the asset was cooked in memory, not into a file".into())),
        }
    }
}

/// Cooks one asset from typed settings: the one cook path of `cook` and `bake`.
pub fn cook_asset(job: CookJob, bars: &dyn Progress) -> Result<Cooked> {
    let format = job.settings.format;
    cook_formats(job, &[format], bars)?.into_iter().next().ok_or_else(|| Error::Failed("no cooker".into()))
}

/// Cooks the asset once per format of `formats` (every other setting as
/// given) from one read of the frames, in the order given, segment after
/// segment; the reference, when asked for, comes with the first.
pub fn cook_formats(job: CookJob, formats: &[Format], bars: &dyn Progress) -> Result<Vec<Cooked>> {
    let s = job.settings;
    let mut all: Vec<CookOptions> = formats.iter().map(|&format| CookSettings { format, ..s.clone() }.cook_options(job.inputs)).collect();
    if job.reference {
        // As many levels as the asset: its validation checks each.
        all.push(CookOptions { levels: s.lods, ..reference_options() });
    }
    // Pools that pass the size go to a file beside the output (or the system's temporary directory).
    let spill_dir = job.output.map_or_else(std::env::temp_dir, |(p, _)| vdbcook_vpak::directory_of(p));
    // One budget for every cooker's buffers.
    let spill = s.spill_above.bytes().map(|above| vdbcook_grid::spill::SpillPolicy::new(spill_dir, above));
    for o in &mut all {
        o.spill = spill.clone();
    }
    let sel = GridSelection::from_flags(s.grid.as_deref(), s.grids.as_deref());
    let segment = s.segment_frames.map(|n| n.get() as usize);
    let mut files = job.files;
    // Each frame's files of the --with sequences, matched over the whole sequence.
    let mut with = crate::inputs::with_files(&files, &s.with, job.base.as_deref(), s.frames, s.allow_missing)?;
    // Numbered from the whole sequence's names, so that parts number as one process does.
    let mut numbers = crate::inputs::frame_numbers(&files);
    let mut count = segment_count(files.len(), segment);
    // A part: its segments' frames alone, into a part file.
    let part = match job.part {
        Some(p) => {
            let total = count;
            if p.count > total {
                return Err(Error::Usage(format!("--part {}/{}: the asset has {total} segment(s) to share among {} parts (a smaller --segment-frames makes more)", p.index + 1, p.count, p.count)));
            }
            let fp = fingerprint(&all[0], segment, &files, &with);
            let range = p.segments(total);
            let n = segment.unwrap_or(files.len());
            let frames = (range.start as usize * n).min(files.len())..(range.end as usize * n).min(files.len());
            files = files.drain(frames.clone()).collect();
            with = with.drain(frames.clone()).collect();
            numbers = numbers.map(|mut n| n.drain(frames.clone()).collect());
            count = range.len() as u32;
            Some(PartInfo { index: p.index, count: p.count, segments: total, first_segment: range.start, first_frame: frames.start as u32, fingerprint: fp })
        }
        None => None,
    };
    let schemes = Schemes::of(s.supercompress, s.optimize == Optimize::Disk);
    let mut outs = formats
        .iter()
        .map(|_| match job.output {
            // An asset compared with its reference next is read back whole: through the page cache.
            Some((path, overwrite)) => Output::file(path, overwrite, count, part.as_ref(), schemes, !job.reference),
            None if part.is_some() => Err(Error::Failed("a part is cooked into a file".into())),
            None => Output::memory(count, schemes),
        })
        .collect::<Result<Vec<_>>>()?;
    if job.reference {
        outs.push(Output::scratch(count)?);
    }
    let mut write = |cookers: Vec<Cooker>, next: &mut [Cooker]| -> Result<()> {
        for (i, (c, out)) in cookers.into_iter().zip(outs.iter_mut()).enumerate() {
            if c.frame_count() == 0 {
                return Err(Error::Failed("no frames to cook".into()));
            }
            let is_reference = job.reference && i == formats.len();
            out.add(c, next.get_mut(i), bars).map_err(|e| if is_reference { Error::In("cooking the reference".into(), Box::new(e)) } else { e })?;
        }
        // A cook that has spilled is held to its memory budget: its segments
        // are written before the next frame is read (see `feed`).
        if spill.as_ref().is_some_and(|p| p.peak_in_files() > 0) {
            outs.iter_mut().try_for_each(Output::wait)?;
        }
        Ok(())
    };
    let mut frames = FrameFile::numbered(files, numbers, s.allow_missing);
    for (f, w) in frames.iter_mut().zip(with) {
        f.with = w;
    }
    let Fed { channels, read_secs, source_time } = feed(all, frames, sel, job.base, segment, &mut write, bars)?;
    let grid_name = channels.as_ref().map(|c| c.specs.iter().map(|s| s.name.as_str()).collect::<Vec<_>>().join(", "));
    let mut outs = outs.into_iter();
    let mut cooked = Vec::new();
    for out in outs.by_ref().take(formats.len()) {
        let (asset, file, report) = out.finish()?;
        let mut report = report.ok_or_else(|| Error::Failed("no frames to cook".into()))?;
        report.timings.insert(0, ("read".into(), read_secs));
        report.source_time = source_time.clone();
        cooked.push(Cooked { asset, file, report, grid: grid_name.clone(), reference: None });
    }
    let reference = outs.next().map(|o| o.finish().map(|(a, _, _)| a)).transpose().context("cooking the reference")?;
    if let Some(first) = cooked.first_mut() {
        first.reference = reference;
    }
    Ok(cooked)
}
