//! The format validator ([`Checked::new`]) refuses what a reader or a sampler
//! would misread, with an error and never a panic: each test makes a small
//! valid asset by hand (through this crate's own node and atlas encoders,
//! no cooker), checks that it is accepted, then breaks one thing at a time
//! and reseals the asset (checksums valid) so that only the validator stands
//! between the change and a reader.

use vdbcook_vpak::layout::{pack_atlas, plan_atlases, AtlasLayout, BrickSource};
use vdbcook_vpak::nodes::{l1_node_words, l3_words, node_words, L2_SLOTS};
use vdbcook_vpak::{kind, Asset, AtlasInfo, Channel, Checked, Format, FrameInfo, Metadata, Plane, PlaneInfo, Section, SourceFile};

/// A plane of a hand-made asset: its texels and, per brick, its plane brick
/// (`u32::MAX`: the plane does not hold the brick).
struct PlaneDef {
    plane: Plane,
    table: Vec<u32>,
}

impl PlaneDef {
    /// A plane holding every one of `bricks` bricks as its own.
    fn every(plane: Plane, bricks: u32) -> PlaneDef {
        PlaneDef { plane, table: (0..bricks).collect() }
    }
    fn bricks(&self) -> u32 {
        self.table.iter().filter(|&&b| b != u32::MAX).max().map_or(0, |&b| b + 1)
    }
}

fn plane(format: Format, lanes: u32, z_per_texel: u32) -> Plane {
    Plane { format, lanes, z_per_texel }
}

fn channel(name: &str, plane: u32, lane: u32, alternates: Vec<u32>) -> Channel {
    Channel {
        name: name.into(),
        grid: name.into(),
        component: None,
        value_type: "float".into(),
        class: "fog volume".into(),
        background: 0.0,
        value_range: [0.0, 1.0],
        group: 0,
        plane,
        lane,
        alternates,
    }
}

/// Zero bricks (any bytes are texels; the validator reads layouts, not values).
struct Zeros;
impl BrickSource for Zeros {
    fn write_brick(&self, _: usize, out: &mut [u8]) -> bool {
        out.fill(0);
        true
    }
}

fn words(v: &[u32]) -> Vec<u8> {
    v.iter().flat_map(|w| w.to_le_bytes()).collect()
}

/// One frame of `bricks` leaves (leaf i at L2 slot i, all voxels active,
/// brick i) in `planes`, atlases at most `max_dim` texels a side; a channel
/// in several planes gets a channel table choosing its first plane for the
/// bricks that plane holds, else its first alternate that does.
fn asset(bricks: u32, channels: Vec<Channel>, planes: Vec<PlaneDef>, max_dim: u32) -> (Metadata, Vec<Section>) {
    let n = bricks as usize;
    let occupied: Vec<usize> = (0..n).collect();
    let leaves: Vec<([u64; 8], u32)> = (0..bricks).map(|b| ([u64::MAX; 8], b)).collect();
    let mut sections = vec![
        Section { kind: kind::FRAMES, index: 0, data: words(&[0]).into() },
        Section { kind: kind::L1_NODES, index: 0, data: words(&l1_node_words(2, &[0], 0)).into() },
        Section { kind: kind::L1_ENTRIES, index: 0, data: words(&[0]).into() },
        Section { kind: kind::L2_NODES, index: 0, data: words(&node_words(&occupied, L2_SLOTS, 0)).into() },
        Section { kind: kind::L2_ENTRIES, index: 0, data: words(&(0..bricks).collect::<Vec<_>>()).into() },
        Section { kind: kind::L3_NODES, index: 0, data: words(&l3_words(leaves.len(), leaves.iter().copied()).unwrap()).into() },
        Section { kind: kind::TILES, index: 0, data: Vec::new().into() },
    ];
    let mixed = |p: usize| channels.iter().any(|c| !c.alternates.is_empty() && (c.plane as usize == p || c.alternates.contains(&(p as u32))));
    let mut infos = Vec::new();
    let mut atlases = Vec::new();
    for (p, def) in planes.iter().enumerate() {
        let count = def.bricks();
        let info = PlaneInfo { plane: def.plane, bricks: count, atlases: if def.plane.format == Format::Constant { Vec::new() } else { plan_atlases(def.plane.slices_per_brick(), count, max_dim) } };
        // A constant plane's range is its value; the others span [0, 1].
        let range = if def.plane.format == Format::Constant { [0.5f32, 0.5] } else { [0.0, 1.0] };
        let ranges: Vec<u32> = (0..count * info.range_slots()).flat_map(|_| range.map(f32::to_bits)).collect();
        sections.push(Section { kind: kind::BRICK_RANGES, index: p as u32, data: words(&ranges).into() });
        if def.table != (0..bricks).collect::<Vec<_>>() && !mixed(p) {
            sections.push(Section { kind: kind::BRICK_TABLE, index: p as u32, data: words(&def.table).into() });
        }
        for a in &info.atlases {
            atlases.push(Section { kind: kind::ATLAS, index: atlases.len() as u32, data: pack_atlas(&AtlasLayout { plane: def.plane, atlas: *a }, &Zeros).into() });
        }
        infos.push(info);
    }
    for (c, ch) in channels.iter().enumerate().filter(|(_, ch)| !ch.alternates.is_empty()) {
        let mine: Vec<u32> = std::iter::once(ch.plane).chain(ch.alternates.iter().copied()).collect();
        let table: Vec<u32> = (0..n)
            .map(|b| {
                let (j, pb) = mine.iter().enumerate().map(|(j, &p)| (j as u32, planes[p as usize].table[b])).find(|&(_, pb)| pb != u32::MAX).unwrap();
                j << vdbcook_vpak::CHOICE_SHIFT | pb
            })
            .collect();
        sections.push(Section { kind: kind::CHANNEL_TABLE, index: c as u32, data: words(&table).into() });
    }
    sections.extend(atlases);
    let meta = Metadata {
        tool: "hand-made".into(),
        frame_count: 1,
        map_type: "UniformScaleMap".into(),
        transform: [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]],
        index_offset: [0, 0, 0],
        index_bbox: Some(([0, 0, 0], [7, 7, 8 * bricks as i32 - 1])),
        channels,
        planes: infos,
        brick_count: bricks,
        settings: Vec::new(),
        sources: vec![SourceFile { path: "a.vdb".into(), bytes: 1, xxh3_128: String::new() }],
        frames: vec![FrameInfo { source: Some(0), active_voxels: u64::from(bricks) * 512, leaves: bricks, tiles: 0, coarse: Vec::new() }],
        levels: 1,
        level_filters: Vec::new(),
        first_level: 0,
        time: None,
        resolutions: Vec::new(),
    };
    sections.insert(0, Section { kind: kind::METADATA, index: 0, data: meta.to_bytes().unwrap().into() });
    (meta, sections)
}

fn copy(sections: &[Section]) -> Vec<Section> {
    sections.iter().map(|s| Section { kind: s.kind, index: s.index, data: s.data.to_vec().into() }).collect()
}

fn set_metadata(sections: &mut [Section], meta: &Metadata) {
    sections.iter_mut().find(|s| s.kind == kind::METADATA).unwrap().data = meta.to_bytes().unwrap().into();
}

/// What the validator says of the resealed `sections`: `Ok(())` when it
/// accepts them, else the error of whichever refused them first (the
/// reader, for the section table; the validator otherwise).  A panic fails the test.
fn verdict(what: &str, sections: &[Section]) -> Result<(), String> {
    let bytes = vdbcook_vpak::assemble(sections);
    let run = std::panic::catch_unwind(|| {
        let asset = Asset::from_bytes(&bytes).map_err(|e| e.to_string())?;
        asset.verify().map_err(|e| format!("checksums: {e}"))?;
        Checked::new(&asset).map(|_| ()).map_err(|e| e.to_string())
    });
    run.unwrap_or_else(|_| panic!("{what}: the validator panicked"))
}

/// Three channels over 12 bricks: "b" and "c" sharing an RG8 plane (plane
/// 0), "a" alone in BC7 (plane 1), where its last 4 bricks repeat its first
/// (8 plane bricks, a brick table).
fn three_channels() -> (Metadata, Vec<Section>) {
    let channels = vec![channel("a", 1, 0, Vec::new()), channel("b", 0, 0, Vec::new()), channel("c", 0, 1, Vec::new())];
    let repeats = PlaneDef { plane: plane(Format::Bc7, 4, 4), table: (0..8).chain(0..4).collect() };
    asset(12, channels, vec![PlaneDef::every(plane(Format::Unorm8, 2, 1), 12), repeats], 2048)
}

#[test]
fn absurd_channel_metadata_is_refused_never_a_panic() {
    let (meta, sections) = three_channels();
    verdict("the asset as made", &sections).unwrap();
    type Mutation = Box<dyn Fn(&mut Metadata)>;
    // (what, the error's words, the change)
    let mutations: Vec<(&str, &str, Mutation)> = vec![
        ("no channels", "0 channels (need 1 to 256)", Box::new(|m| m.channels.clear())),
        ("a million channels", "metadata", Box::new(|m| m.channels = vec![m.channels[0].clone(); 1 << 20])),
        ("plane out of range", "channel 0 (a) is in plane 99, the asset has 2", Box::new(|m| m.channels[0].plane = 99)),
        ("lanes shared", "channel 2 (c) shares lanes of plane 0", Box::new(|m| m.channels[2].lane = 0)),
        ("lane past the plane", "channel 1 (b) starts at lane 3 of a plane of 2 lanes", Box::new(|m| m.channels[1].lane = 3)),
        ("bc7 with two lanes", "plane 1: bc7 with 2 lanes and 4 z-slices per texel is not a plane", Box::new(|m| m.planes[1].plane.lanes = 2)),
        ("z-slices on unorm8", "plane 0: unorm8 with 2 lanes and 4 z-slices per texel is not a plane", Box::new(|m| m.planes[0].plane.z_per_texel = 4)),
        ("an empty plane", "plane 2 holds no channel", Box::new(|m| m.planes.push(m.planes[0].clone()))),
        ("more bricks than the tables map", "missing section brick table #0", Box::new(|m| m.brick_count += 1)),
        ("more plane bricks than bricks", "plane 0 stores 13 bricks for the asset's 12", Box::new(|m| m.planes[0].bricks = m.brick_count + 1)),
        ("more plane bricks than atlases hold", "the atlases of plane 1 hold 8 bricks, the metadata counts 9", Box::new(|m| m.planes[1].bricks += 1)),
        ("a plane of no bricks", "plane 0 stores 0 bricks", Box::new(|m| m.planes[0].bricks = 0)),
        ("a huge atlas", "is too large a texture", Box::new(|m| m.planes[0].atlases[0].bricks = [u32::MAX; 3])),
        ("frames missing", "0 frame records for 1 frames", Box::new(|m| m.frames.clear())),
        ("a source past the list", "frame 0 names a source the asset does not list", Box::new(|m| m.frames[0].source = Some(7))),
        ("an odd index offset", "index offset [0, 8, 0] is not a multiple of 128", Box::new(|m| m.index_offset[1] += 8)),
        ("no level", "0 levels of detail", Box::new(|m| m.levels = 0)),
        (
            "levels the frame table lacks",
            "1 trees in the frame table, 1 frames × 2 stored levels",
            Box::new(|m| {
                m.levels = 2;
                m.level_filters = vec![vdbcook_vpak::LevelFilter::Mean; 3];
                m.frames[0].coarse.push(Default::default());
            }),
        ),
        ("too many levels", "6 levels of detail", Box::new(|m| m.levels = vdbcook_vpak::MAX_LEVELS + 1)),
        ("level filters without levels", "3 level filters for 3 channels and 1 levels", Box::new(|m| m.level_filters = vec![vdbcook_vpak::LevelFilter::Mean; 3])),
        ("figures of a level the asset lacks", "frame 0 has figures for 2 levels, the asset has 1", Box::new(|m| m.frames[0].coarse.push(Default::default()))),
        ("a first level past the levels", "first stored level 1 of 1 levels", Box::new(|m| m.first_level = m.levels)),
    ];
    for (what, words, mutate) in mutations {
        let mut m = meta.clone();
        mutate(&mut m);
        let mut broken = copy(&sections);
        set_metadata(&mut broken, &m);
        let e = verdict(what, &broken).expect_err(what);
        assert!(e.contains(words), "{what}: {e}");
    }
}

/// Two channels over 8 bricks: "mixed" in a constant plane (bricks 0-3,
/// plane 0) and an f16 plane (bricks 4-7, plane 1) through its channel
/// table, as per-brick formats store them; "whole" in an f16 plane of its own (plane 2).
fn per_brick_formats() -> (Metadata, Vec<Section>) {
    let f16 = plane(Format::F16, 1, 1);
    let none = u32::MAX;
    let planes = vec![
        PlaneDef { plane: plane(Format::Constant, 1, 1), table: vec![0, 1, 2, 3, none, none, none, none] },
        PlaneDef { plane: f16, table: vec![none, none, none, none, 0, 1, 2, 3] },
        PlaneDef::every(f16, 8),
    ];
    asset(8, vec![channel("mixed", 0, 0, vec![1]), channel("whole", 2, 0, Vec::new())], planes, 2048)
}

#[test]
fn absurd_per_brick_format_metadata_is_refused_never_a_panic() {
    let (meta, sections) = per_brick_formats();
    verdict("the asset as made", &sections).unwrap();
    let (mixed, other, constant) = (0usize, 1usize, 0usize);
    type Mutation = Box<dyn Fn(&mut Metadata, &mut Vec<Section>)>;
    let table = move |sections: &mut Vec<Section>| sections.iter().position(|s| s.kind == kind::CHANNEL_TABLE && s.index == mixed as u32).unwrap();
    // (what, the error's words, the change)
    let mutations: Vec<(&str, &str, Mutation)> = vec![
        ("an alternate past the planes", "channel 0 (mixed) is in plane 99", Box::new(move |m, _| m.channels[mixed].alternates[0] = 99)),
        ("an alternate shared with another channel", "shares lanes of plane 2", Box::new(move |m, _| m.channels[mixed].alternates[0] = m.channels[other].plane)),
        (
            "a plane twice",
            "channel 0 (mixed) is in several planes, but shares plane 0",
            Box::new(move |m, _| {
                let p = m.channels[mixed].plane;
                m.channels[mixed].alternates.push(p);
            }),
        ),
        ("sixteen alternates", "has 16 alternate planes", Box::new(move |m, _| m.channels[mixed].alternates = vec![m.channels[mixed].alternates[0]; 16])),
        ("no alternates but a channel table", "plane 1 holds no channel", Box::new(move |m, _| m.channels[mixed].alternates.clear())),
        (
            "a channel table for a channel in one plane",
            "channel 1 (whole) is in one plane but has a channel table",
            Box::new(move |m, s| s.push(Section { kind: kind::CHANNEL_TABLE, index: other as u32, data: vec![0; 4 * m.brick_count as usize].into() })),
        ),
        (
            "alternates but no channel table",
            "missing section channel table #0",
            Box::new(move |_, s| {
                let t = table(s);
                s.remove(t);
            }),
        ),
        (
            "a choice past the alternates",
            "brick 0's entry 0xf0000000 names no plane brick",
            Box::new(move |_, s| {
                let t = table(s);
                s[t].data.to_mut()[0..4].copy_from_slice(&(15u32 << 28).to_le_bytes());
            }),
        ),
        (
            "a plane brick past its plane",
            "brick 0's entry 0x0fffffff names no plane brick",
            Box::new(move |_, s| {
                let t = table(s);
                s[t].data.to_mut()[0..4].copy_from_slice(&0x0fff_ffffu32.to_le_bytes());
            }),
        ),
        (
            "a constant plane with an atlas",
            "plane 0 is constant but has 1 atlases",
            Box::new(move |m, _| m.planes[constant].atlases = m.planes.iter().find(|p| !p.atlases.is_empty()).unwrap().atlases.clone()),
        ),
        (
            "a constant plane with a span",
            "plane 0 is constant, but its brick range 0 is [0.5, 1.5]",
            Box::new(move |_, s| {
                let r = s.iter_mut().find(|s| s.kind == kind::BRICK_RANGES && s.index == constant as u32).unwrap();
                let hi = f32::from_le_bytes(r.data[4..8].try_into().unwrap()) + 1.0;
                r.data.to_mut()[4..8].copy_from_slice(&hi.to_le_bytes());
            }),
        ),
        (
            "a mixed plane with a brick table",
            "plane 0 has a brick table it must not have",
            Box::new(move |m, s| s.push(Section { kind: kind::BRICK_TABLE, index: m.channels[mixed].plane, data: vec![0; 4 * m.brick_count as usize].into() })),
        ),
    ];
    for (what, words, mutate) in mutations {
        let mut m = meta.clone();
        let mut broken = copy(&sections);
        mutate(&mut m, &mut broken);
        set_metadata(&mut broken, &m);
        let e = verdict(what, &broken).expect_err(what);
        assert!(e.contains(words), "{what}: {e}");
    }
}

#[test]
fn brick_tables_pointing_past_their_plane_are_refused() {
    // "flat" repeats one brick everywhere: its plane stores it once, with a table.
    let f16 = plane(Format::F16, 1, 1);
    let (meta, sections) = asset(6, vec![channel("varied", 0, 0, Vec::new()), channel("flat", 1, 0, Vec::new())], vec![PlaneDef::every(f16, 6), PlaneDef { plane: f16, table: vec![0; 6] }], 2048);
    verdict("the asset as made", &sections).unwrap();
    let plane = meta.channels[1].plane;
    for (what, value) in [("past the plane", meta.planes[plane as usize].bricks), ("huge", u32::MAX)] {
        let mut broken = copy(&sections);
        let t = broken.iter_mut().find(|s| s.kind == kind::BRICK_TABLE && s.index == plane).expect("the flat plane has a table");
        t.data.to_mut()[0..4].copy_from_slice(&value.to_le_bytes());
        let e = verdict(what, &broken).unwrap_err();
        assert!(e.contains("brick 0 maps to plane brick"), "{what}: {e}");
        // Without its table, the plane no longer maps every brick.
        broken.retain(|s| !(s.kind == kind::BRICK_TABLE && s.index == plane));
        let e = verdict(what, &broken).unwrap_err();
        assert!(e.contains("brick table"), "{what}, a missing table: {e}");
    }
}

#[test]
fn what_samplers_would_misread_is_refused() {
    // 40 bricks of 8³ R8 texels in atlases of at most 16³: 8 bricks each, 5 atlases.
    let (meta, sections) = asset(40, vec![channel("density", 0, 0, Vec::new())], vec![PlaneDef::every(plane(Format::Unorm8, 1, 1), 40)], 16);
    verdict("the asset as made", &sections).unwrap();
    let edit = |kind: u32, f: &dyn Fn(&mut Vec<u8>)| {
        let mut s = copy(&sections);
        f(s.iter_mut().find(|s| s.kind == kind).unwrap().data.to_mut());
        s
    };
    // An L3 node's brick past the bricks (tables and ranges are indexed by it).
    let e = verdict("a brick past the bricks", &edit(kind::L3_NODES, &|d| d[4..8].copy_from_slice(&meta.brick_count.to_le_bytes()))).unwrap_err();
    assert!(e.contains("l3 node 0 points at brick 40"), "{e}");
    // A reversed range (samplers compute min + t·(max − min)).
    let e = verdict("a reversed range", &edit(kind::BRICK_RANGES, &|d| d[0..4].copy_from_slice(&f32::MAX.to_le_bytes()))).unwrap_err();
    assert!(e.contains("brick range 0 is"), "{e}");
    // A section listed twice.
    let mut twice = copy(&sections);
    twice.push(Section { kind: kind::TILES, index: 0, data: vec![].into() });
    let e = verdict("a section twice", &twice).unwrap_err();
    assert!(e.contains("listed twice"), "{e}");
    // A last atlas holding more bricks than the first (samplers find a
    // brick's atlas by the first atlas's capacity).
    let p = &meta.planes[0];
    let (f, n) = (p.atlases[0], p.bricks);
    let cap = f.count;
    assert!(p.atlases.len() > 2 && n > 2 * cap, "{p:?}");
    let mut m = meta.clone();
    let [fx, fy, _] = f.bricks;
    m.planes[0].atlases = vec![f, AtlasInfo { bricks: [fx, fy, (n - cap).div_ceil(fx * fy)], first_brick: cap, count: n - cap }];
    let mut broken = copy(&sections);
    set_metadata(&mut broken, &m);
    let e = verdict("a larger last atlas", &broken).unwrap_err();
    assert!(e.contains("atlas 1 of plane 0: its layout does not follow the first atlas's"), "{e}");
}
