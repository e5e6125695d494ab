//! The C ABI over [`vdbcook_vpak::runtime::Reader`]: the functions
//! `include/vpak.h` declares (and documents), each returning a status code
//! and leaving a message for `vpak_last_error` on failure. No Rust panic
//! crosses the boundary: every entry point catches it and returns
//! `VPAK_ERROR_PANIC`. A test keeps the header and these exports in step.

use std::cell::RefCell;
use std::ffi::{c_char, c_void, CStr, CString};
use std::panic::{catch_unwind, AssertUnwindSafe};
use vdbcook_vpak::runtime::Reader;
use vdbcook_vpak::{kind, Error, GPU_CHANNEL_WORDS};

pub const VPAK_OK: i32 = 0;
/// The file could not be opened or read.
pub const VPAK_ERROR_IO: i32 = 1;
/// Not a valid asset: not a .vpak, an unsupported version, truncated, damaged or inconsistent.
pub const VPAK_ERROR_FORMAT: i32 = 2;
/// A null pointer, a segment, frame or section out of range, or buffers that do not fit.
pub const VPAK_ERROR_ARGUMENT: i32 = 3;
/// A bug in this library (a Rust panic, caught).
pub const VPAK_ERROR_PANIC: i32 = 4;

/// `vpak_section`: one section of a segment.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default)]
pub struct VpakSection {
    pub kind: u32,
    pub index: u32,
    pub size: u64,
    pub offset: u64,
    pub stored_size: u64,
    pub checksum: u64,
    pub uploaded: u32,
    pub compressed: u32,
    pub plane: u32,
    pub format: u32,
    pub lanes: u32,
    pub extent: [u32; 3],
}

/// `vpak_buffer`: where one section goes.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct VpakBuffer {
    pub data: *mut c_void,
    pub size: u64,
}

/// The opaque `vpak_reader`.
pub struct VpakReader {
    reader: Reader,
    /// The channels' names, for `vpak_channel_name`.
    names: Vec<CString>,
}

thread_local! {
    static LAST_ERROR: RefCell<CString> = RefCell::new(CString::default());
}

struct Failure(i32, String);

impl From<Error> for Failure {
    fn from(e: Error) -> Failure {
        let code = match &e {
            Error::Io(_) => VPAK_ERROR_IO,
            Error::NoSegment { .. } => VPAK_ERROR_ARGUMENT,
            _ => VPAK_ERROR_FORMAT,
        };
        Failure(code, e.to_string())
    }
}

fn argument(what: impl Into<String>) -> Failure {
    Failure(VPAK_ERROR_ARGUMENT, what.into())
}

fn set_error(message: &str) {
    // A message with a NUL byte (a path, say) is cut there.
    let text = message.split('\0').next().unwrap_or_default();
    LAST_ERROR.with(|e| *e.borrow_mut() = CString::new(text).unwrap_or_default());
}

/// Runs `f`, turning its failure or panic into a status code and a message.
fn guard(f: impl FnOnce() -> Result<(), Failure>) -> i32 {
    match catch_unwind(AssertUnwindSafe(f)) {
        Ok(Ok(())) => VPAK_OK,
        Ok(Err(Failure(code, message))) => {
            set_error(&message);
            code
        }
        Err(_) => {
            set_error("internal error in vdbcook-vpak-c (a Rust panic, caught): please report it");
            VPAK_ERROR_PANIC
        }
    }
}

/// Runs `f` for a plain value, `fallback` on a panic.
fn value<T>(fallback: T, f: impl FnOnce() -> T) -> T {
    catch_unwind(AssertUnwindSafe(f)).unwrap_or(fallback)
}

/// # Safety
/// `r` is null or a reader from `vpak_open` not yet closed.
unsafe fn reader<'a>(r: *const VpakReader) -> Result<&'a Reader, Failure> {
    // SAFETY: the caller's promise.
    unsafe { r.as_ref() }.map(|r| &r.reader).ok_or_else(|| argument("the reader is null"))
}

/// Writes `v` to `out` when it is not null.
///
/// # Safety
/// `out` is null or valid for a write of a `T`.
unsafe fn put<T>(out: *mut T, v: T) {
    if !out.is_null() {
        // SAFETY: the caller's promise.
        unsafe { out.write(v) };
    }
}

/// See include/vpak.h.
///
/// # Safety
/// `path` is a NUL-terminated string; `out` is valid for a write.
#[no_mangle]
pub unsafe extern "C" fn vpak_open(path: *const c_char, out: *mut *mut VpakReader) -> i32 {
    guard(|| {
        if path.is_null() || out.is_null() {
            return Err(argument("vpak_open: a null path or out pointer"));
        }
        // SAFETY: the caller's promise.
        let text = unsafe { CStr::from_ptr(path) }.to_string_lossy().into_owned();
        // SAFETY: checked not null; the caller's promise.
        unsafe { out.write(std::ptr::null_mut()) };
        let reader = Reader::open(std::path::Path::new(&text)).map_err(|e| {
            let f = Failure::from(e);
            Failure(f.0, format!("{text}: {}", f.1))
        })?;
        let names = reader.metadata().channels.iter().map(|c| CString::new(c.name.replace('\0', "")).unwrap_or_default()).collect();
        // SAFETY: as above.
        unsafe { out.write(Box::into_raw(Box::new(VpakReader { reader, names }))) };
        Ok(())
    })
}

/// See include/vpak.h.
///
/// # Safety
/// `r` is null or a reader from `vpak_open` not yet closed.
#[no_mangle]
pub unsafe extern "C" fn vpak_close(r: *mut VpakReader) {
    if !r.is_null() {
        // SAFETY: the caller's promise: made by Box::into_raw in vpak_open, closed once.
        value((), || drop(unsafe { Box::from_raw(r) }));
    }
}

/// See include/vpak.h.
#[no_mangle]
pub extern "C" fn vpak_last_error() -> *const c_char {
    LAST_ERROR.with(|e| e.borrow().as_ptr())
}

/// See include/vpak.h.
///
/// # Safety
/// `r` is null or an open reader.
#[no_mangle]
pub unsafe extern "C" fn vpak_frame_count(r: *const VpakReader) -> u32 {
    // SAFETY: the caller's promise.
    value(0, || unsafe { reader(r) }.map_or(0, |r| r.frame_count() as u32))
}

/// See include/vpak.h.
///
/// # Safety
/// `r` is null or an open reader.
#[no_mangle]
pub unsafe extern "C" fn vpak_segment_count(r: *const VpakReader) -> u32 {
    // SAFETY: the caller's promise.
    value(0, || unsafe { reader(r) }.map_or(0, |r| r.segment_count() as u32))
}

/// See include/vpak.h.
///
/// # Safety
/// `r` is null or an open reader.
#[no_mangle]
pub unsafe extern "C" fn vpak_bytes_read(r: *const VpakReader) -> u64 {
    // SAFETY: the caller's promise.
    value(0, || unsafe { reader(r) }.map_or(0, |r| r.bytes_read()))
}

/// See include/vpak.h.
///
/// # Safety
/// `r` is null or an open reader; each out pointer is null or valid for a write.
#[no_mangle]
pub unsafe extern "C" fn vpak_locate(r: *const VpakReader, frame: u32, segment: *mut u32, frame_in_segment: *mut u32) -> i32 {
    guard(|| {
        // SAFETY: the caller's promise.
        let r = unsafe { reader(r) }?;
        let (s, f) = r.locate(frame as usize).ok_or_else(|| argument(format!("frame {frame} is out of range (the asset has {})", r.frame_count())))?;
        // SAFETY: the caller's promise.
        unsafe {
            put(segment, s as u32);
            put(frame_in_segment, f as u32);
        }
        Ok(())
    })
}

/// See include/vpak.h.
///
/// # Safety
/// `r` is null or an open reader; each out pointer is null or valid for a write.
#[no_mangle]
pub unsafe extern "C" fn vpak_segment_frames(r: *const VpakReader, segment: u32, first_frame: *mut u32, frame_count: *mut u32) -> i32 {
    guard(|| {
        // SAFETY: the caller's promise.
        let info = unsafe { reader(r) }?.segment(segment as usize)?;
        // SAFETY: the caller's promise.
        unsafe {
            put(first_frame, info.first_frame);
            put(frame_count, info.frame_count);
        }
        Ok(())
    })
}

/// See include/vpak.h.
///
/// # Safety
/// `r` is null or an open reader; `count` is null or valid for a write.
#[no_mangle]
pub unsafe extern "C" fn vpak_section_count(r: *const VpakReader, segment: u32, count: *mut u32) -> i32 {
    guard(|| {
        // SAFETY: the caller's promise.
        let info = unsafe { reader(r) }?.segment(segment as usize)?;
        // SAFETY: the caller's promise.
        unsafe { put(count, info.sections.len() as u32) };
        Ok(())
    })
}

/// See include/vpak.h.
///
/// # Safety
/// `r` is null or an open reader; `sections` is valid for `count` writes.
#[no_mangle]
pub unsafe extern "C" fn vpak_sections(r: *const VpakReader, segment: u32, sections: *mut VpakSection, count: u32) -> i32 {
    guard(|| {
        // SAFETY: the caller's promise.
        let info = unsafe { reader(r) }?.segment(segment as usize)?;
        if count as usize != info.sections.len() || sections.is_null() {
            return Err(argument(format!("vpak_sections: room for {count} sections, segment {segment} has {}", info.sections.len())));
        }
        for (i, s) in info.sections.iter().enumerate() {
            let v = VpakSection {
                kind: s.kind,
                index: s.index,
                size: s.size,
                offset: s.offset,
                stored_size: s.stored_size,
                checksum: s.checksum,
                uploaded: u32::from(s.uploaded()),
                compressed: u32::from(s.compressed),
                plane: s.texture.map_or(0, |t| t.plane),
                format: s.texture.map_or(0, |t| t.format.code()),
                lanes: s.texture.map_or(0, |t| t.lanes),
                extent: s.texture.map_or([0; 3], |t| t.extent),
            };
            // SAFETY: i < count, the caller's promise.
            unsafe { sections.add(i).write(v) };
        }
        Ok(())
    })
}

/// See include/vpak.h.
///
/// # Safety
/// `r` is null or an open reader; `buffers` holds `count` entries, each
/// `data` null or valid for `size` bytes of writes, none overlapping.
#[no_mangle]
pub unsafe extern "C" fn vpak_fill_segment(r: *const VpakReader, segment: u32, buffers: *const VpakBuffer, count: u32) -> i32 {
    guard(|| {
        // SAFETY: the caller's promise.
        let r = unsafe { reader(r) }?;
        let info = r.segment(segment as usize)?;
        if count as usize != info.sections.len() || buffers.is_null() {
            return Err(argument(format!("vpak_fill_segment: {count} buffers, segment {segment} has {} sections", info.sections.len())));
        }
        // SAFETY: the caller's promise.
        let given = unsafe { std::slice::from_raw_parts(buffers, count as usize) };
        let mut out = Vec::with_capacity(given.len());
        for (b, s) in given.iter().zip(&info.sections) {
            let skipped = b.data.is_null() && s.kind == kind::METADATA;
            if !skipped && (b.data.is_null() || b.size != s.size) {
                return Err(argument(format!("vpak_fill_segment: the buffer for section {} is {} bytes at {:p}; it needs {} bytes", s.label(), b.size, b.data, s.size)));
            }
            out.push(match skipped {
                true => &mut [][..],
                // SAFETY: not null, `size` bytes, not overlapping: the caller's promise.
                false => unsafe { std::slice::from_raw_parts_mut(b.data.cast::<u8>(), b.size as usize) },
            });
        }
        r.fill_segment(segment as usize, &mut out)?;
        Ok(())
    })
}

/// See include/vpak.h.
///
/// # Safety
/// `r` is null or an open reader; `data` is valid for `size` bytes of writes.
#[no_mangle]
pub unsafe extern "C" fn vpak_read_section(r: *const VpakReader, segment: u32, section: u32, data: *mut c_void, size: u64) -> i32 {
    guard(|| {
        // SAFETY: the caller's promise.
        let r = unsafe { reader(r) }?;
        let info = r.segment(segment as usize)?;
        let s = info.sections.get(section as usize).ok_or_else(|| argument(format!("segment {segment} has {} sections, not {}", info.sections.len(), section as u64 + 1)))?;
        if data.is_null() || size != s.size {
            return Err(argument(format!("vpak_read_section: a buffer of {size} bytes at {data:p} for section {} of {} bytes", s.label(), s.size)));
        }
        // SAFETY: not null, `size` bytes: the caller's promise.
        let out = unsafe { std::slice::from_raw_parts_mut(data.cast::<u8>(), size as usize) };
        r.read_section_into(segment as usize, section as usize, out)?;
        Ok(())
    })
}

/// See include/vpak.h.
///
/// # Safety
/// `r` is null or an open reader.
#[no_mangle]
pub unsafe extern "C" fn vpak_check(r: *const VpakReader) -> i32 {
    // SAFETY: the caller's promise.
    guard(|| Ok(unsafe { reader(r) }?.check()?))
}

/// See include/vpak.h.
///
/// # Safety
/// `r` is null or an open reader; `matrix` is null or valid for 16 writes.
#[no_mangle]
pub unsafe extern "C" fn vpak_transform(r: *const VpakReader, matrix: *mut f64) -> i32 {
    guard(|| {
        // SAFETY: the caller's promise.
        let m = unsafe { reader(r) }?.metadata().transform;
        if matrix.is_null() {
            return Err(argument("vpak_transform: a null matrix"));
        }
        for (i, v) in m.iter().flatten().enumerate() {
            // SAFETY: i < 16, the caller's promise.
            unsafe { matrix.add(i).write(*v) };
        }
        Ok(())
    })
}

/// See include/vpak.h.
///
/// # Safety
/// `r` is null or an open reader; each out pointer is null or valid for a write.
#[no_mangle]
pub unsafe extern "C" fn vpak_levels(r: *const VpakReader, first_level: *mut u32, levels: *mut u32) -> i32 {
    guard(|| {
        // SAFETY: the caller's promise.
        let m = unsafe { reader(r) }?.metadata();
        // SAFETY: the caller's promise.
        unsafe {
            put(first_level, m.first_level);
            put(levels, m.levels);
        }
        Ok(())
    })
}

/// See include/vpak.h.
///
/// # Safety
/// `r` is null or an open reader.
#[no_mangle]
pub unsafe extern "C" fn vpak_channel_count(r: *const VpakReader) -> u32 {
    // SAFETY: the caller's promise.
    value(0, || unsafe { r.as_ref() }.map_or(0, |r| r.names.len() as u32))
}

/// See include/vpak.h.
///
/// # Safety
/// `r` is null or an open reader.
#[no_mangle]
pub unsafe extern "C" fn vpak_channel_name(r: *const VpakReader, channel: u32) -> *const c_char {
    // SAFETY: the caller's promise.
    value(std::ptr::null(), || unsafe { r.as_ref() }.and_then(|r| r.names.get(channel as usize)).map_or(std::ptr::null(), |n| n.as_ptr()))
}

/// See include/vpak.h.
///
/// # Safety
/// `r` is null or an open reader; `offset` is null or valid for 3 writes.
#[no_mangle]
pub unsafe extern "C" fn vpak_segment_index_offset(r: *const VpakReader, segment: u32, offset: *mut i32) -> i32 {
    guard(|| {
        // SAFETY: the caller's promise.
        let info = unsafe { reader(r) }?.segment(segment as usize)?;
        if offset.is_null() {
            return Err(argument("vpak_segment_index_offset: a null offset"));
        }
        for (i, v) in info.metadata.index_offset.iter().enumerate() {
            // SAFETY: i < 3, the caller's promise.
            unsafe { offset.add(i).write(*v) };
        }
        Ok(())
    })
}

/// See include/vpak.h.
///
/// # Safety
/// `r` is null or an open reader; `count` is null or valid for a write.
#[no_mangle]
pub unsafe extern "C" fn vpak_segment_channel_records(r: *const VpakReader, segment: u32, count: *mut u32) -> i32 {
    guard(|| {
        // SAFETY: the caller's promise.
        let info = unsafe { reader(r) }?.segment(segment as usize)?;
        // SAFETY: the caller's promise.
        unsafe { put(count, info.metadata.gpu_channels().len() as u32) };
        Ok(())
    })
}

/// See include/vpak.h.
///
/// # Safety
/// `r` is null or an open reader; `words` is valid for `count` · 20 writes.
#[no_mangle]
pub unsafe extern "C" fn vpak_segment_channels(r: *const VpakReader, segment: u32, words: *mut u32, count: u32) -> i32 {
    guard(|| {
        // SAFETY: the caller's promise.
        let info = unsafe { reader(r) }?.segment(segment as usize)?;
        let records = info.metadata.gpu_channels();
        if words.is_null() || count as usize != records.len() {
            return Err(argument(format!("vpak_segment_channels: room for {count} records, segment {segment} has {}", records.len())));
        }
        for (i, w) in records.iter().flat_map(|c| c.words()).enumerate() {
            // SAFETY: i < count · GPU_CHANNEL_WORDS, the caller's promise.
            unsafe { words.add(i).write(w) };
        }
        debug_assert_eq!(GPU_CHANNEL_WORDS, 20);
        Ok(())
    })
}

/// See include/vpak.h.
///
/// # Safety
/// `r` is null or an open reader.
#[no_mangle]
pub unsafe extern "C" fn vpak_fps(r: *const VpakReader) -> f64 {
    // SAFETY: the caller's promise.
    value(0.0, || unsafe { reader(r) }.map_or(0.0, |r| r.fps()))
}

/// See include/vpak.h.
///
/// # Safety
/// `r` is null or an open reader; `number` is null or valid for a write.
#[no_mangle]
pub unsafe extern "C" fn vpak_frame_number(r: *const VpakReader, frame: u32, number: *mut i64) -> i32 {
    guard(|| {
        // SAFETY: the caller's promise.
        let r = unsafe { reader(r) }?;
        if frame as usize >= r.frame_count() {
            return Err(argument(format!("frame {frame} is out of range (the asset has {})", r.frame_count())));
        }
        // SAFETY: the caller's promise.
        unsafe { put(number, r.frame_number(frame as usize)) };
        Ok(())
    })
}

/// See include/vpak.h.
///
/// # Safety
/// `r` is null or an open reader; `frame` is null or valid for a write.
#[no_mangle]
pub unsafe extern "C" fn vpak_frame_of_number(r: *const VpakReader, number: i64, frame: *mut u32) -> i32 {
    guard(|| {
        // SAFETY: the caller's promise.
        let r = unsafe { reader(r) }?;
        let f = r.metadata().frame_by_number(number).map_err(argument)?;
        // SAFETY: the caller's promise.
        unsafe { put(frame, f as u32) };
        Ok(())
    })
}

/// Channel `channel` of `r`'s metadata, or an argument failure naming `what`.
fn channel_of(r: &Reader, channel: u32, what: &str) -> Result<usize, Failure> {
    let n = r.metadata().channels.len();
    match (channel as usize) < n {
        true => Ok(channel as usize),
        false => Err(argument(format!("{what}: channel {channel} is out of range (the asset has {n})"))),
    }
}

/// See include/vpak.h.
///
/// # Safety
/// `r` is null or an open reader; `level` is null or valid for a write;
/// `half_offset` is null or valid for 3 writes.
#[no_mangle]
pub unsafe extern "C" fn vpak_channel_resolution(r: *const VpakReader, channel: u32, level: *mut u32, half_offset: *mut i32) -> i32 {
    guard(|| {
        // SAFETY: the caller's promise.
        let r = unsafe { reader(r) }?;
        let res = r.metadata().resolution(channel_of(r, channel, "vpak_channel_resolution")?);
        // SAFETY: the caller's promise.
        unsafe { put(level, res.level) };
        if !half_offset.is_null() {
            for (i, h) in res.half_offset.iter().enumerate() {
                // SAFETY: i < 3, the caller's promise.
                unsafe { half_offset.add(i).write(*h) };
            }
        }
        Ok(())
    })
}

/// See include/vpak.h.
///
/// # Safety
/// `r` is null or an open reader; each out pointer is null or valid for a write.
#[no_mangle]
pub unsafe extern "C" fn vpak_channel_levels(r: *const VpakReader, channel: u32, first_level: *mut u32, end_level: *mut u32) -> i32 {
    guard(|| {
        // SAFETY: the caller's promise.
        let r = unsafe { reader(r) }?;
        let levels = r.metadata().channel_levels(channel_of(r, channel, "vpak_channel_levels")?);
        // SAFETY: the caller's promise.
        unsafe {
            put(first_level, levels.start);
            put(end_level, levels.end);
        }
        Ok(())
    })
}

/// See include/vpak.h.
///
/// # Safety
/// `r` is null or an open reader; `matrix` is null or valid for 16 writes.
#[no_mangle]
pub unsafe extern "C" fn vpak_channel_transform(r: *const VpakReader, channel: u32, level: u32, matrix: *mut f64) -> i32 {
    guard(|| {
        // SAFETY: the caller's promise.
        let r = unsafe { reader(r) }?;
        let c = channel_of(r, channel, "vpak_channel_transform")?;
        let meta = r.metadata();
        let levels = meta.channel_levels(c);
        if !levels.contains(&level) {
            return Err(argument(format!("vpak_channel_transform: channel {channel} is not stored at level {level} (its levels: {} to {})", levels.start, levels.end.saturating_sub(1))));
        }
        if matrix.is_null() {
            return Err(argument("vpak_channel_transform: a null matrix"));
        }
        for (i, v) in meta.channel_transform(c, level).iter().flatten().enumerate() {
            // SAFETY: i < 16, the caller's promise.
            unsafe { matrix.add(i).write(*v) };
        }
        Ok(())
    })
}
