//! The runtime reader (`vdbcook_vpak::runtime`), its C ABI (through
//! examples/c/vpak_dump.c) and the example of docs/runtime.md
//! (crates/vpak/examples/stream.rs) against the validator's view of the same
//! cooked asset (`Asset::open`, `Asset::segment`): every format, channel
//! packing, level, segment, supercompressed or not; damage is an error.

mod common;
use common::*;
use std::path::{Path, PathBuf};
use std::process::Command;
use vdbcook_vpak::runtime::{Reader, SectionBuffers};
use vdbcook_vpak::{kind, Asset};

fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, &b| (h ^ u64::from(b)).wrapping_mul(0x100_0000_01b3))
}

/// What vpak_dump prints of `asset`, made from the validator's view (and
/// the runtime reader's section order, which the C ABI follows).
fn expected_dump(asset: &Asset, reader: &Reader) -> String {
    let meta = asset.metadata().unwrap();
    let mut out = format!("asset {} {}\nfps {:.6}\nlevels {} {}\ntransform", asset.frame_count().unwrap(), asset.segment_count(), meta.fps(), meta.first_level, meta.levels);
    for v in meta.transform.iter().flatten() {
        out += &format!(" {v:.6}");
    }
    out += "\n";
    for (c, ch) in meta.channels.iter().enumerate() {
        let (r, levels) = (meta.resolution(c), meta.channel_levels(c));
        let [x, y, z] = r.half_offset;
        out += &format!("channel {c} {} {} {x} {y} {z} {} {}\nvoxels {c}", ch.name, r.level, levels.start, levels.end);
        for v in meta.channel_transform(c, levels.start).iter().flatten() {
            out += &format!(" {v:.6}");
        }
        out += "\n";
    }
    for f in 0..asset.frame_count().unwrap() {
        let (s, local) = asset.locate(f).unwrap();
        out += &format!("frame {f} {s} {local} {}\n", meta.frame_number(f));
    }
    for s in 0..asset.segment_count() {
        let seg = asset.segment(s).unwrap();
        let e = asset.segments().unwrap()[s];
        let info = reader.segment(s).unwrap();
        out += &format!("segment {s} {} {} {}\n", e.first_frame, e.frame_count, info.sections.len());
        let [x, y, z] = seg.metadata().unwrap().index_offset;
        // The channel records from the validator's view of the segment.
        let records = vdbcook_vpak::Checked::new(&seg).unwrap().gpu_channels();
        let le: Vec<u8> = records.iter().flat_map(|c| c.words()).flat_map(u32::to_le_bytes).collect();
        out += &format!("offset {x} {y} {z}\nrecords {} {:016x}\n", records.len(), fnv1a(&le));
        for x in &info.sections {
            let b = seg.section(x.kind, x.index).unwrap();
            out += &format!("section {} {} {} {} {:016x}", x.kind, x.index, b.len(), u32::from(kind::uploaded(x.kind)), fnv1a(b));
            if x.kind == kind::ATLAS {
                // The texture from the segment's own metadata: atlas sections count plane 0's atlases, then plane 1's, ...
                let m = seg.metadata().unwrap();
                let (p, a) = (0..m.planes.len()).flat_map(|p| (0..m.planes[p].atlases.len()).map(move |a| (p, a))).find(|&(p, a)| m.atlas_section(p, a) == x.index).unwrap();
                let layout = vdbcook_vpak::AtlasLayout { plane: m.planes[p].plane, atlas: m.planes[p].atlases[a] };
                let [w, h, d] = layout.texels();
                out += &format!(" texture {p} {} {} {w} {h} {d}", layout.plane.format.code(), layout.plane.lanes);
            }
            out += "\n";
        }
    }
    out
}

/// The runtime reader's view of `path` equals the validator's, section by section and byte for byte.
fn same_as_validator(path: &Path) {
    let asset = Asset::open(path).unwrap();
    for r in [Reader::open(path).unwrap(), Reader::from_file(std::fs::File::open(path).unwrap()).unwrap()] {
        assert_eq!(r.metadata(), &asset.metadata().unwrap(), "{}", path.display());
        assert_eq!((r.frame_count(), r.segment_count()), (asset.frame_count().unwrap(), asset.segment_count()));
        for f in 0..=r.frame_count() {
            assert_eq!(r.locate(f), asset.locate(f).filter(|_| f < r.frame_count()), "frame {f}");
        }
        let (mut words, mut buffers) = (Vec::new(), SectionBuffers::default());
        let mut gpu = 0;
        for s in 0..r.segment_count() {
            let want = asset.segment(s).unwrap();
            let info = r.segment(s).unwrap();
            let mut listed: Vec<(u32, u32)> = info.sections.iter().map(|x| (x.kind, x.index)).collect();
            let mut have: Vec<(u32, u32)> = want.sections.iter().map(|x| (x.kind, x.index)).collect();
            listed.sort();
            have.sort();
            assert_eq!(listed, have, "{} segment {s}", path.display());
            r.fill_buffers(s, &mut buffers).unwrap();
            for (i, x) in info.sections.iter().enumerate() {
                assert!(buffers.section(i) == want.section(x.kind, x.index).unwrap(), "{} segment {s}: {}", path.display(), x.label());
                // And read alone (an atlas coded over its shown voxels reads the node arrays it needs itself).
                let mut one = vec![0u8; x.size as usize];
                r.read_section_into(s, i, &mut one).unwrap();
                assert!(one == want.section(x.kind, x.index).unwrap(), "{} segment {s}: {} read alone", path.display(), x.label());
            }
            let a = r.segment_asset(s, words).unwrap();
            assert!(a.bytes() == want.bytes(), "{} segment {s}: the restored body differs", path.display());
            assert_eq!(info.metadata, want.metadata().unwrap());
            gpu += info.gpu_bytes();
            words = a.into_words().unwrap();
        }
        assert_eq!(gpu, asset.gpu_bytes().unwrap());
        r.check().unwrap();
    }
}

/// A program built by the test: the C example and the Rust example, once per run.
fn programs() -> &'static (PathBuf, PathBuf) {
    static BUILT: std::sync::OnceLock<(PathBuf, PathBuf)> = std::sync::OnceLock::new();
    BUILT.get_or_init(|| {
        // Built where cargo keeps test artefacts: the statics are never dropped.
        let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("runtime-programs");
        std::fs::create_dir_all(&dir).unwrap();
        let c = vdbcook_testkit::c_example("vpak_dump", &dir).unwrap();
        let rust = vdbcook_testkit::cargo_build(&["-p", "vdbcook-vpak", "--example", "stream"], "stream", "/stream").unwrap();
        (c, rust)
    })
}

fn run(program: &Path, asset: &Path) -> std::process::Output {
    Command::new(program).arg(asset).output().unwrap()
}

#[test]
fn runtime_reader_and_c_abi_read_what_the_validator_reads() {
    let dir = scratch_dir("runtime", "same");
    let smoke = s(&root().join("fixtures/smoke_seq")).to_string();
    let multi = s(&root().join("fixtures/multi_grid.vdb")).to_string();
    let cases: Vec<(Vec<&str>, Vec<&str>)> = vec![
        (vec![&smoke], vec!["--format", "f32", "--segment-frames", "2"]),
        (vec![&smoke], vec!["--format", "f16", "--lods", "3"]),
        (vec![&smoke], vec!["--format", "unorm8", "--segment-frames", "3"]),
        (vec![&smoke], vec!["--format", "unorm16", "--lods", "2"]),
        (vec![&smoke], vec!["--format", "bc4", "--segment-frames", "2", "--lods", "2"]),
        (vec![&smoke], vec!["--format", "bc7", "--clusters", "40"]),
        (vec![&smoke], vec!["--max-error", "0.01", "--segment-frames", "2"]),
        // Supercompressed for the smallest file: atlases coded over their shown voxels.
        (vec![&smoke], vec!["--max-error", "0.004", "--supercompress", "zstd", "--optimize", "disk", "--segment-frames", "2"]),
        (vec![&multi], vec!["--grids", "all", "--format", "unorm8"]),
        (vec![&multi], vec!["--grids", "all", "--group", "density,temperature=bc7"]),
    ];
    let (c, _) = programs();
    // Each case as it is and supercompressed (a case supercompressed already, once).
    let jobs: Vec<(usize, bool)> = (0..cases.len()).flat_map(|k| [(k, false), (k, true)]).filter(|&(k, coded)| !(coded && cases[k].1.contains(&"--supercompress"))).collect();
    par_map(&jobs, |&(k, coded)| {
        let (inputs, flags) = &cases[k];
        let flags = [flags.as_slice(), if coded { &["--supercompress", "zstd"][..] } else { &[] }].concat();
        let path = cook_into(&dir, &format!("a{k}{}.vpak", if coded { "z" } else { "" }), inputs, &flags);
        same_as_validator(&path);
        let out = run(c, &path);
        assert!(out.status.success(), "{flags:?}: vpak_dump failed: {}", String::from_utf8_lossy(&out.stderr));
        let want = expected_dump(&Asset::open(&path).unwrap(), &Reader::open(&path).unwrap());
        assert_eq!(String::from_utf8_lossy(&out.stdout), want, "{flags:?}: the C ABI read other bytes");
    });
    let _ = std::fs::remove_dir_all(&dir);
}

/// Channels at their own voxel size (format v10): the C ABI gives each channel's level,
/// offset, stored levels and transform as the Rust reader does, on a pyro-style
/// sequence whose `vel` has voxels twice (and four times, half a voxel off) the
/// density's.
#[test]
fn channels_at_their_own_voxels_in_rust_and_in_c() {
    if !oracle_available() {
        return;
    }
    let dir = scratch_dir("runtime", "resolutions");
    let (c, _) = programs();
    for (k, (scale, offset, flags)) in
        [("2", "0", &["--format", "f16", "--lods", "2", "--segment-frames", "2"][..]), ("4", "1", &["--format", "bc7", "--supercompress", "zstd"][..])].into_iter().enumerate()
    {
        let seq = dir.join(format!("pyro{k}"));
        let made = Command::new("/usr/bin/python3")
            .args(["scripts/make_pyro_sequence.py", s(&seq), "--frames", "3", "--size", "32", "--vel-scale", scale, "--offset", offset])
            .current_dir(root())
            .output()
            .unwrap();
        assert!(made.status.success(), "{}", String::from_utf8_lossy(&made.stderr));
        let path = cook_into(&dir, &format!("p{k}.vpak"), &[s(&seq)], &[&["--grids", "density,temperature,vel"], flags].concat());
        same_as_validator(&path);
        let reader = Reader::open(&path).unwrap();
        let meta = reader.metadata();
        assert!(meta.is_multi_resolution());
        let level = if scale == "2" { 1 } else { 2 };
        let vel = meta.channels.iter().position(|ch| ch.name == "vel.x").unwrap();
        assert_eq!(meta.resolution(vel).level, level);
        assert_eq!(meta.channel_levels(0).start, 0);
        // vel's voxels are `scale` times the density's, centred where the source put them.
        let t = meta.channel_transform(vel, level);
        // make_pyro_sequence.py moves vel's origin by `offset` half density voxels (0.05 each).
        let shift = if offset == "1" { 0.05 } else { 0.0 };
        assert!((t[0][0] - 0.1 * f64::from(1u32 << level)).abs() < 1e-12 && (t[3][0] - shift).abs() < 1e-12, "{t:?}");
        let out = run(c, &path);
        assert!(out.status.success(), "{flags:?}: vpak_dump failed: {}", String::from_utf8_lossy(&out.stderr));
        let text = String::from_utf8_lossy(&out.stdout);
        assert_eq!(text, expected_dump(&Asset::open(&path).unwrap(), &reader), "{flags:?}: the C ABI said otherwise");
        assert!(text.contains(&format!("\nchannel {vel} vel.x {level} ")), "{text}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn the_guides_example_streams_every_segment() {
    let dir = scratch_dir("runtime", "example");
    let smoke = s(&root().join("fixtures/smoke_seq")).to_string();
    let path = cook_into(&dir, "a.vpak", &[&smoke], &["--segment-frames", "2", "--supercompress", "zstd", "--lods", "2"]);
    let (_, example) = programs();
    let out = run(example, &path);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8_lossy(&out.stdout);
    let asset = Asset::open(&path).unwrap();
    let reader = Reader::open(&path).unwrap();
    // Its sections are the C example's, in the same order with the same hashes.
    let sections: Vec<String> = text.lines().filter_map(|l| l.trim().strip_prefix("section ")).map(|l| l.split("  ").next().unwrap().to_string()).collect();
    let want: Vec<String> = expected_dump(&asset, &reader)
        .lines()
        .filter_map(|l| l.strip_prefix("section "))
        .map(|l| {
            let f: Vec<&str> = l.split(' ').collect();
            format!("{} {} {} {}", f[0], f[1], f[2], f[4])
        })
        .collect();
    assert_eq!(sections, want);
    let segments = text.lines().filter(|l| l.starts_with("segment ")).count();
    assert_eq!(segments, asset.segment_count());
    assert!(asset.segment_count() >= 2);
    for f in 0..asset.frame_count().unwrap() {
        let (s, local) = asset.locate(f).unwrap();
        let seg = asset.segment(s).unwrap();
        let root_word = seg.u32s(kind::FRAMES).unwrap()[local];
        assert!(text.contains(&format!("frame {f}: segment {s}, frame {local}, l1 node at word {root_word}\n")), "frame {f}: {text}");
    }
    // It read the file once: every body, the tables and metadata again at most.
    let read: u64 = text.lines().find_map(|l| l.strip_prefix("read ")).and_then(|l| l.split(' ').next()).unwrap().parse().unwrap();
    let len = std::fs::metadata(&path).unwrap().len();
    assert!(read <= len + reader.bytes_read(), "read {read} bytes of a {len}-byte file");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn damaged_assets_are_errors_in_rust_and_in_c() {
    let dir = scratch_dir("runtime", "damage");
    let smoke = s(&root().join("fixtures/smoke_seq")).to_string();
    let path = cook_into(&dir, "a.vpak", &[&smoke], &["--segment-frames", "2", "--supercompress", "zstd"]);
    let bytes = std::fs::read(&path).unwrap();
    let (c, _) = programs();
    // A flipped byte in the last atlas of segment 1: opening succeeds (it reads no atlas), reading the segment fails.
    let asset = Asset::open(&path).unwrap();
    let e = asset.segments().unwrap()[1];
    let seg = asset.stored_segment(1).unwrap();
    let atlas = seg.sections.iter().rfind(|x| x.kind == kind::ATLAS).unwrap();
    let mut bad = bytes.clone();
    bad[(e.offset + atlas.offset + atlas.size / 2) as usize] ^= 0x40;
    let flipped = dir.join("flipped.vpak");
    std::fs::write(&flipped, &bad).unwrap();
    let r = Reader::open(&flipped).unwrap();
    r.fill_buffers(0, &mut SectionBuffers::default()).unwrap();
    let err = r.fill_buffers(1, &mut SectionBuffers::default()).unwrap_err().to_string();
    assert!(err.starts_with("segment 1: section brick atlas") && err.contains("checksum mismatch"), "{err}");
    assert!(r.segment_asset(1, Vec::new()).is_err());
    let out = run(c, &flipped);
    let text = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1));
    assert!(text.starts_with("vpak_dump: error: fill: segment 1: section brick atlas"), "{text}");
    // Truncated anywhere: an error on opening.
    for cut in [0, 40, 64, bytes.len() / 3, bytes.len() - 1] {
        let short = dir.join(format!("short{cut}.vpak"));
        std::fs::write(&short, &bytes[..cut]).unwrap();
        assert!(Reader::open(&short).is_err(), "{cut} bytes");
        let out = run(c, &short);
        let text = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{cut} bytes");
        assert!(text.starts_with("vpak_dump: error: open: ") && (text.contains("truncated") || text.contains("not a .vpak file")), "{cut} bytes: {text}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn the_guide_shows_the_example_as_it_is() {
    let guide = std::fs::read_to_string(root().join("docs/runtime.md")).unwrap();
    let shown = guide.split("## A complete program").nth(1).and_then(|t| t.split("```rust\n").nth(1)).and_then(|t| t.split("```").next()).unwrap();
    let example = std::fs::read_to_string(root().join("crates/vpak/examples/stream.rs")).unwrap();
    let code: Vec<&str> = example.lines().skip_while(|l| l.starts_with("//!") || l.is_empty()).collect();
    assert_eq!(shown.trim_end(), code.join("\n").trim_end(), "docs/runtime.md's program is not crates/vpak/examples/stream.rs");
}

#[test]
fn frames_keep_their_source_numbers_and_rate_in_rust_and_in_c() {
    let dir = scratch_dir("runtime", "time");
    numbered_copies(&dir, "fire", 1001..=1010);
    let asset = cook_into(&dir, "fire.vpak", &[s(&dir.join("fire_####.vdb"))], &["--frames", "1001-1010:3", "--fps", "30", "--segment-frames", "2", "--supercompress", "zstd"]);
    let r = Reader::open(&asset).unwrap();
    assert_eq!(r.version(), vdbcook_vpak::VERSION);
    let numbers: Vec<i64> = (0..r.frame_count()).map(|f| r.frame_number(f)).collect();
    assert_eq!((numbers, r.fps()), (vec![1001, 1004, 1007, 1010], 30.0));
    assert_eq!((r.frame_of_number(1007), r.frame_of_number(1005)), (Some(2), None));
    let out = run(&programs().0, &asset);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success() && text.contains("\nfps 30.000000\n"), "{text}");
    let frames: Vec<&str> = text.lines().filter(|l| l.starts_with("frame ")).collect();
    assert_eq!(frames, ["frame 0 0 0 1001", "frame 1 0 1 1004", "frame 2 1 0 1007", "frame 3 1 1 1010"]);
    let _ = std::fs::remove_dir_all(&dir);
}
