//! The runtime reader against `Asset` on small hand-made files (cooked
//! assets of every format: `cli/tests/runtime.rs`).

use super::*;
use crate::segments::tests::{body, meta};
use crate::{assemble, Section};
use std::sync::Arc;

/// Two segments, each with a long section worth compressing; supercompressed or not.
fn sample(coded: bool) -> Vec<u8> {
    let long = |m: &Metadata, marker: u32| {
        let mut b = body(m, marker);
        b.push(Section { kind: kind::L2_ENTRIES, index: 0, data: (0..5000u32).flat_map(|i| (i / 3 + marker).to_le_bytes()).collect::<Vec<u8>>().into() });
        b.push(Section { kind: kind::ATLAS, index: 0, data: (0..3000u32).map(|i| (i % 251) as u8).collect::<Vec<u8>>().into() });
        match coded {
            true => coding::supercompress(b, m, crate::coding::Schemes { level: 3, context: false }).unwrap(),
            false => b,
        }
    };
    let (a, b) = (meta(2, &["a.vdb", "b.vdb"], [0.0, 1.0], 0), meta(3, &["c.vdb"], [-1.0, 0.5], -128));
    segments::assemble_segments(&[(2, long(&a, 100)), (3, long(&b, 200))]).unwrap()
}

/// Every section of segment `s` read one by one, in the reader's order.
fn sections(r: &Reader, s: usize) -> Vec<Vec<u8>> {
    let info = r.segment(s).unwrap();
    (0..info.sections.len())
        .map(|i| {
            let mut b = vec![0u8; info.sections[i].size as usize];
            r.read_section_into(s, i, &mut b).unwrap();
            b
        })
        .collect()
}

#[test]
fn segments_read_as_asset_restores_them() {
    for coded in [false, true] {
        let bytes = sample(coded);
        let asset = Asset::from_bytes(&bytes).unwrap();
        let r = Reader::new(bytes.clone()).unwrap();
        // Opening reads the tables and the metadata, not the sections.
        let opened = r.bytes_read();
        let data: u64 = (0..2).flat_map(|s| r.segment(s).unwrap().sections.iter().filter(|x| x.kind != kind::METADATA).map(|x| x.stored_size)).sum();
        assert!(opened <= bytes.len() as u64 - data, "{opened} of {} bytes read to open, {data} of them in sections", bytes.len());
        assert_eq!(r.metadata(), &asset.metadata().unwrap());
        assert_eq!((r.segment_count(), r.frame_count(), r.is_segmented()), (2, 5, true));
        assert_eq!([0, 1, 2, 4, 5].map(|f| r.locate(f)), [0, 1, 2, 4, 5].map(|f| asset.locate(f).filter(|_| f < 5)));
        let mut buf = Vec::new();
        for s in 0..2 {
            let want = asset.segment(s).unwrap();
            let info = r.segment(s).unwrap();
            assert_eq!(info.supercompressed(), coded);
            assert_eq!(info.body_size as usize, want.bytes().len());
            let got = r.segment_asset(s, buf).unwrap();
            assert!(got.bytes() == want.bytes(), "coded {coded}, segment {s}");
            // Each section where the info says, and the same bytes read alone.
            for (sec, b) in info.sections.iter().zip(sections(&r, s)) {
                let at = sec.offset as usize..(sec.offset + sec.size) as usize;
                assert!(want.bytes()[at] == b[..], "{}", sec.label());
                assert_eq!(want.section(sec.kind, sec.index).unwrap(), &b[..]);
            }
            buf = got.into_words().unwrap();
        }
        r.check().unwrap_err(); // the hand-made bodies have no channels: the validator refuses them
    }
}

#[test]
fn a_body_on_its_own_is_one_segment() {
    let m = meta(2, &["a.vdb"], [0.0, 1.0], 0);
    let bytes = assemble(&body(&m, 7));
    let r = Reader::new(bytes.clone()).unwrap();
    assert_eq!((r.segment_count(), r.frame_count(), r.is_segmented(), r.locate(1)), (1, 2, false, Some((0, 1))));
    assert!(r.segment_asset(0, Vec::new()).unwrap().bytes() == &bytes[..]);
    assert!(matches!(r.segment(1), Err(Error::NoSegment { .. })));
}

#[test]
fn damage_is_an_error_never_a_panic() {
    for coded in [false, true] {
        let b = sample(coded);
        // Truncated: opening fails (the size field is the file's).
        for n in (0..b.len()).step_by(5) {
            assert!(Reader::new(b[..n].to_vec()).is_err(), "{n} bytes");
        }
        // Any flipped byte is caught by opening, reading a segment or the padding check.
        for i in (0..b.len()).step_by(3) {
            let mut c = b.clone();
            c[i] ^= 0x10;
            let caught = Reader::new(c).and_then(|r| (0..2).try_for_each(|s| r.segment_asset(s, Vec::new()).map(|_| ())).and_then(|()| r.zero_between_segments()));
            let free = (40..HEADER_LEN).contains(&i);
            assert!(caught.is_err() || free, "coded {coded}: flipped byte {i} read without an error");
        }
    }
}

#[test]
fn read_from_a_file_counts_its_bytes() {
    let bytes = sample(true);
    let path = std::env::temp_dir().join(format!("vpak-runtime-{}.vpak", std::process::id()));
    std::fs::write(&path, &bytes).unwrap();
    for r in [Reader::open(&path).unwrap(), Reader::from_file(std::fs::File::open(&path).unwrap()).unwrap()] {
        let before = r.bytes_read();
        let a = r.segment_asset(1, Vec::new()).unwrap();
        assert_eq!(r.bytes_read() - before, r.segment(1).unwrap().stored_size);
        assert!(a.bytes() == Asset::from_bytes(&bytes).unwrap().segment(1).unwrap().bytes());
    }
    std::fs::remove_file(&path).unwrap();
}

#[test]
fn buffers_of_the_wrong_size_are_refused() {
    let r = Reader::new(sample(true)).unwrap();
    let n = r.segment(0).unwrap().sections.len();
    let mut bufs: Vec<Vec<u8>> = vec![Vec::new(); n];
    let mut views: Vec<&mut [u8]> = bufs.iter_mut().map(|b| b.as_mut_slice()).collect();
    let err = r.fill_segment(0, &mut views).unwrap_err().to_string();
    assert!(err.contains("a buffer of 0 bytes for section frames"), "{err}");
    assert!(r.fill_segment(0, &mut views[1..]).unwrap_err().to_string().contains("buffers for the"));
    assert!(r.read_section_into(0, n, &mut []).is_err());
}

#[test]
fn prefetched_segments_are_the_segments_and_errors_reach_the_caller() {
    let bytes = sample(true);
    let r = Arc::new(Reader::new(bytes.clone()).unwrap());
    let asset = Asset::from_bytes(&bytes).unwrap();
    let mut ahead = Prefetcher::new(r.clone(), |r: &Reader, s| r.segment_asset(s, Vec::new()));
    ahead.request(1);
    ahead.request(0);
    assert_eq!(ahead.pending().collect::<Vec<_>>(), [1, 0]);
    for s in [0, 1] {
        let got = ahead.take(s).unwrap();
        assert!(got.value.bytes() == asset.segment(s).unwrap().bytes(), "segment {s}");
    }
    // Taken without a request: asked for then.
    assert!(ahead.take(1).unwrap().value.bytes() == asset.segment(1).unwrap().bytes());
    assert!(matches!(ahead.take(7), Err(Error::NoSegment { segment: 7, count: 2 })));
    // The caller's own work and errors, and a worker that panics.
    let mut odd = Prefetcher::new(r.clone(), |_: &Reader, s| if s % 2 == 1 { Err(Error::Invalid(format!("odd {s}"))) } else { Ok(s) });
    odd.request(0);
    odd.request(1);
    assert_eq!(odd.take(1).unwrap_err().to_string(), "the asset is inconsistent: odd 1");
    assert_eq!(odd.take(0).unwrap().value, 0);
    let mut broken = Prefetcher::new(r, |_: &Reader, _| -> Result<(), Error> { panic!("worker panic (expected by the test)") });
    assert!(broken.take(0).unwrap_err().to_string().contains("prefetch worker stopped"));
}

#[test]
fn a_wrapped_segment_is_read_whole_at_open_then_from_memory() {
    // A file of one segment wraps its small supercompressed body in one zstd frame (version 13).
    let bytes = segments::assemble_segments(&[(2, crate::wrap::tests::coded())]).unwrap();
    let asset = Asset::from_bytes(&bytes).unwrap();
    assert!(asset.is_wrapped(0));
    let r = Reader::new(bytes.clone()).unwrap();
    let info = r.segment(0).unwrap();
    assert!(info.wrapped && info.stored_size == asset.stored_bytes(0).unwrap().len() as u64);
    // Opening read the header, the table entry, the body's header (where the frame's magic is), then the frame.
    let opened = r.bytes_read();
    assert_eq!(opened, (HEADER_LEN + segments::SEGMENT_ENTRY_LEN + HEADER_LEN) as u64 + info.stored_size);
    let got = r.segment_asset(0, Vec::new()).unwrap();
    assert!(got.bytes() == asset.segment(0).unwrap().bytes());
    for (sec, b) in info.sections.iter().zip(sections(&r, 0)) {
        assert_eq!(asset.segment(0).unwrap().section(sec.kind, sec.index).unwrap(), &b[..]);
    }
    assert_eq!(r.bytes_read(), opened, "the body is read from memory once opened");
    // Any flipped byte but the header's reserved ones is caught at open or when read.
    for i in 0..bytes.len() {
        let mut c = bytes.clone();
        c[i] ^= 0x10;
        let caught = Reader::new(c).and_then(|r| r.segment_asset(0, Vec::new()).map(|_| ()));
        assert!(caught.is_err() || (40..HEADER_LEN).contains(&i), "flipped byte {i} read without an error");
    }
}
