//! `vdbcook inspect ASSET.vpak`: sections, node counts, settings; checksums verified.

use anyhow::{Context, Result};
use serde_json::{json, Value};
use std::path::Path;
use vdbcook_vpak::coding::Coding;
use vdbcook_vpak::nodes::{l1_records, l3_node_count, L2_WORDS};
use vdbcook_vpak::{kind, Asset, AtlasLayout, Checked};

/// "density, temperature, vel": the channels stored at `level`, a vec3 grid's three by its name.
fn channels_at(meta: &vdbcook_vpak::Metadata, level: u32) -> Vec<String> {
    let mut names: Vec<String> = Vec::new();
    for (c, ch) in meta.channels.iter().enumerate().filter(|(c, _)| meta.channel_levels(*c).contains(&level)) {
        let whole = ch.component.is_some() && meta.channels.iter().enumerate().filter(|(o, x)| x.grid == ch.grid && x.component.is_some() && meta.channel_levels(*o).contains(&level)).count() == 3;
        let name = if whole { ch.grid.clone() } else { meta.channels[c].name.clone() };
        if !names.contains(&name) {
            names.push(name);
        }
    }
    names
}

pub enum Described {
    Text(String),
    Json(Value),
}

/// What one body (a segment, or a whole version-6 file) holds, in bytes and counts.
struct Body {
    meta: vdbcook_vpak::Metadata,
    /// (name, count, bytes) of the node levels and the bricks.
    nodes: [(&'static str, u64, u64); 4],
    /// Per plane, its atlases, ranges and brick table.
    plane_bytes: Vec<u64>,
    /// Per channel, its share of its planes and its channel table.
    channel_bytes: Vec<u64>,
    /// Per stored level, the bytes it needs on its own.
    level_bytes: Vec<u64>,
    /// The sections as stored, each with its restored size and how it is coded (when supercompressed).
    sections: Vec<(vdbcook_vpak::SectionEntry, u64, Option<Coding>)>,
    /// Bytes of the sections a renderer uploads (restored).
    gpu_bytes: u64,
    /// Where the body lies in the file.
    offset: u64,
    /// The body's bytes when the file stores it wrapped in one zstd frame (version 13).
    wrapped: Option<u64>,
}

/// The figures of a body from its restored sections (`asset`) and its sections as stored.
fn body(stored: &Asset, asset: &Asset, offset: u64) -> Result<Body, vdbcook_vpak::Error> {
    let checked = Checked::new(asset)?;
    let meta = checked.meta.clone();
    let size = |k: u32| asset.sections.iter().filter(|s| s.kind == k).map(|s| s.size).sum::<u64>();
    let l1 = l1_records(checked.l1).map_or(0, |r| r.len() as u64);
    let l2 = size(kind::L2_NODES) / (L2_WORDS as u64 * 4);
    // The L3 section counts its nodes in its first word (records follow, then sub-masks).
    let l3 = l3_node_count(checked.l3).map_or(0, |n| n as u64);
    let brick_bytes = size(kind::ATLAS) + size(kind::BRICK_RANGES) + size(kind::BRICK_TABLE) + size(kind::CHANNEL_TABLE);
    let nodes = [
        ("l1", l1, size(kind::L1_NODES) + size(kind::L1_ENTRIES)),
        ("l2", l2, size(kind::L2_NODES) + size(kind::L2_ENTRIES)),
        ("l3", l3, size(kind::L3_NODES)),
        ("bricks", u64::from(meta.brick_count), brick_bytes),
    ];
    // Bytes of each plane (its atlases, ranges and brick table), and each channel's share of its plane.
    let section_bytes = |k: u32, i: u32| asset.sections.iter().filter(|s| s.kind == k && s.index == i).map(|s| s.size).sum::<u64>();
    let plane_bytes: Vec<u64> = (0..meta.planes.len())
        .map(|p| {
            (0..meta.planes[p].atlases.len()).map(|a| section_bytes(kind::ATLAS, meta.atlas_section(p, a))).sum::<u64>()
                + section_bytes(kind::BRICK_RANGES, p as u32)
                + section_bytes(kind::BRICK_TABLE, p as u32)
        })
        .collect();
    let sharing = |p: usize| meta.channels.iter().filter(|c| c.plane as usize == p).count().max(1) as u64;
    // A channel's share of each of its planes, and its channel table (per-brick formats).
    let channel_bytes =
        (0..meta.channels.len()).map(|c| meta.channel_planes(c).iter().map(|&p| plane_bytes[p as usize] / sharing(p as usize)).sum::<u64>() + section_bytes(kind::CHANNEL_TABLE, c as u32)).collect();
    let level_bytes = meta.stored_levels().map(|k| checked.level_bytes(k)).collect();
    let codings = match stored.section(kind::CODING, 0) {
        Ok(b) => Coding::parse_all(b)?,
        Err(_) => Vec::new(),
    };
    let sections = stored
        .sections
        .iter()
        .map(|e| {
            let c = codings.iter().find(|c| (c.kind, c.index) == (e.kind, e.index)).copied();
            (*e, c.map_or(e.size, |c| c.raw_size), c)
        })
        .collect::<Vec<_>>();
    let gpu_bytes = sections.iter().filter(|(e, _, _)| kind::uploaded(e.kind)).map(|(_, restored, _)| restored).sum();
    Ok(Body { meta, nodes, plane_bytes, channel_bytes, level_bytes, sections, gpu_bytes, offset, wrapped: None })
}

pub fn describe(path: &Path, as_json: bool) -> Result<Described> {
    let name = path.display().to_string();
    let asset = Asset::open(path).with_context(|| name.clone())?;
    let table = asset.segments().with_context(|| name.clone())?;
    let bodies = (0..asset.segment_count())
        .map(|s| {
            let wrapped = |seg: &Asset| asset.is_wrapped(s).then_some(seg.bytes().len() as u64);
            asset.stored_segment(s).and_then(|seg| Ok(Body { wrapped: wrapped(&seg), ..body(&seg, &seg.restored()?, table[s].offset)? })).map_err(|e| {
                if asset.is_segmented() {
                    vdbcook_vpak::Error::InSegment(s, Box::new(e))
                } else {
                    e
                }
            })
        })
        .collect::<Result<Vec<Body>, _>>()
        .with_context(|| name.clone())?;
    let merged = asset.metadata().with_context(|| name.clone())?;
    let meta = &merged;
    let version = asset.version();
    let file_bytes = asset.bytes().len() as u64;
    let gpu_bytes: u64 = bodies.iter().map(|b| b.gpu_bytes).sum();
    let active: u64 = meta.frames.iter().fold(0u64, |a, f| a.saturating_add(f.active_voxels));
    // Figures of the whole asset: each body's added up (planes and channels by position, as the merged metadata lists them).
    let sum_at = |f: fn(&Body) -> &Vec<u64>, i: usize| bodies.iter().filter_map(|b| f(b).get(i)).sum::<u64>();
    let nodes: Vec<(&str, u64, u64)> = (0..4).map(|i| (bodies[0].nodes[i].0, bodies.iter().map(|b| b.nodes[i].1).sum(), bodies.iter().map(|b| b.nodes[i].2).sum())).collect();
    let plane_bytes: Vec<u64> = (0..meta.planes.len()).map(|p| sum_at(|b| &b.plane_bytes, p)).collect();
    let channel_bytes = |c: usize| sum_at(|b| &b.channel_bytes, c);
    // Over every segment, each format once (the merged metadata's planes are the first segment's).
    let names_over = |names: &dyn Fn(&vdbcook_vpak::Metadata) -> String| bodies.iter().fold(String::new(), |all, b| vdbcook_vpak::union_names(&all, &names(&b.meta)));
    let formats = names_over(&|m| m.format_names());
    let channel_formats = |c: usize| names_over(&|m| m.channel_format_names(c));
    // Levels of detail: figures over every frame, and the bytes each level needs on its own.
    let levels: Vec<(u32, u64, u64, u64, u64)> = meta
        .stored_levels()
        .enumerate()
        .map(|(i, k)| {
            let fig = |f: &vdbcook_vpak::FrameInfo| match k {
                0 => (u64::from(f.leaves), u64::from(f.tiles), f.active_voxels),
                _ => f.coarse.get(k as usize - 1).map_or((0, 0, 0), |c| (u64::from(c.leaves), u64::from(c.tiles), c.active_voxels)),
            };
            let (l, t, a) = meta.frames.iter().map(fig).fold((0u64, 0u64, 0u64), |acc, x| (acc.0 + x.0, acc.1 + x.1, acc.2.saturating_add(x.2)));
            (k, l, t, a, sum_at(|b| &b.level_bytes, i))
        })
        .collect();
    let segments: Vec<Value> = bodies
        .iter()
        .zip(&table)
        .map(|(b, e)| json!({"first_frame": e.first_frame, "first_number": meta.frame_number(e.first_frame as usize), "frames": e.frame_count, "offset": e.offset, "bytes": e.size, "wrapped": b.wrapped.is_some(), "body_bytes": b.wrapped.unwrap_or(e.size), "gpu_bytes": b.gpu_bytes, "bricks": b.meta.brick_count, "format": b.meta.format_names(), "index_offset": b.meta.index_offset}))
        .collect();
    let section_json = |b: &Body| {
        b.sections
            .iter()
            .map(|(s, restored, c)| {
                json!({"kind": s.kind, "name": kind::name(s.kind), "index": s.index, "offset": if b.wrapped.is_some() { s.offset } else { b.offset + s.offset }, "bytes": restored, "disk_bytes": s.size, "checksum": format!("{:016x}", s.checksum),
                    "coding": c.map(|c| json!({"scheme": c.scheme_name(), "filter": c.filter.name(), "checksum": format!("{:016x}", c.raw_checksum)}))})
            })
            .collect::<Vec<_>>()
    };
    if as_json {
        return Ok(Described::Json(json!({
            "path": name,
            "kind": "vpak",
            "checksums_ok": true,
            "version": version,
            "tool": meta.tool,
            "format": formats,
            "frames": meta.frame_count,
            "fps": meta.fps(),
            "time_recorded": meta.time.is_some(),
            "frame_numbers": (0..meta.frame_count as usize).map(|f| meta.frame_number(f)).collect::<Vec<_>>(),
            "channels": meta.channels.iter().enumerate().map(|(i, c)| json!({
                "name": c.name, "grid": c.grid, "component": c.component, "value_type": c.value_type, "class": c.class,
                "background": super::num32(c.background), "value_range": c.value_range.map(super::num32), "group": c.group, "plane": c.plane, "lane": c.lane,
                "alternates": c.alternates, "format": channel_formats(i), "bytes": channel_bytes(i),
                "level": meta.resolution(i).level, "voxel_size": meta.channel_voxel_size(i), "half_offset": meta.resolution(i).half_offset,
                "levels": meta.channel_levels(i).collect::<Vec<_>>(),
            })).collect::<Vec<_>>(),
            "bricks": meta.brick_count,
            "planes": meta.planes.iter().zip(&plane_bytes).enumerate().map(|(i, (p, b))| json!({
                "format": p.plane.format.name(), "lanes": p.plane.lanes, "z_per_texel": p.plane.z_per_texel, "bytes": b, "bricks": p.bricks,
                "brick_table": meta.plane_has_table(i),
                "atlases": p.atlases.iter().map(|a| json!({"bricks": a.bricks, "first_brick": a.first_brick, "count": a.count})).collect::<Vec<_>>(),
            })).collect::<Vec<_>>(),
            "map_type": meta.map_type,
            "transform": meta.transform,
            "index_offset": meta.index_offset,
            "index_bbox": meta.index_bbox.map(|(a, b)| json!({"min": a, "max": b})),
            "active_voxels": active,
            "file_bytes": file_bytes,
            "gpu_bytes": gpu_bytes,
            "bits_per_active_voxel": if active > 0 { file_bytes as f64 * 8.0 / active as f64 } else { 0.0 },
            "nodes": nodes.iter().map(|(n, c, b)| (n.to_string(), json!({"count": c, "bytes": b}))).collect::<serde_json::Map<_, _>>(),
            "segments": segments,
            "sections": bodies.iter().flat_map(section_json).collect::<Vec<_>>(),
            "settings": meta.settings.iter().map(|(k, v)| (k.clone(), json!(v))).collect::<serde_json::Map<_, _>>(),
            "sources": meta.sources.iter().map(|s| json!({"path": s.path, "bytes": s.bytes, "xxh3_128": s.xxh3_128})).collect::<Vec<_>>(),
            "frame_info": meta.frames.iter().enumerate().map(|(i, f)| json!({"number": meta.frame_number(i), "source": f.source, "active_voxels": f.active_voxels, "leaves": f.leaves, "tiles": f.tiles,
                "coarse": f.coarse.iter().map(|c| json!({"active_voxels": c.active_voxels, "leaves": c.leaves, "tiles": c.tiles})).collect::<Vec<_>>()})).collect::<Vec<_>>(),
            "first_level": meta.first_level,
            "level_filters": meta.level_filters.iter().map(|f| f.name()).collect::<Vec<_>>(),
            "levels": levels.iter().map(|&(k, l, t, a, b)| json!({"level": k, "voxel_scale": 1u64 << k, "leaves": l, "tiles": t, "active_voxels": a, "bytes": b,
                "channels": meta.channels.iter().enumerate().filter(|(c, _)| meta.channel_levels(*c).contains(&k)).map(|(_, ch)| ch.name.clone()).collect::<Vec<_>>()})).collect::<Vec<_>>(),
        })));
    }
    use std::fmt::Write;
    let mut s = String::new();
    let n = meta.channels.len();
    let _ = writeln!(
        s,
        "{name}: vpak v{version}, {formats}, {} frame{}, {n} channel{}{}, checksums ok",
        meta.frame_count,
        if meta.frame_count == 1 { "" } else { "s" },
        if n == 1 { "" } else { "s" },
        match table.len() {
            1 => String::new(),
            k => format!(", {k} segments"),
        },
    );
    let _ = writeln!(s, "  written by     {}", meta.tool);
    let numbers: Vec<i64> = (0..meta.frame_count as usize).map(|f| meta.frame_number(f)).collect();
    let _ = match meta.time {
        Some(_) => writeln!(s, "  time           frames {} at {} fps", vdbcook_vpak::time::numbers_text(&numbers), meta.fps()),
        None => writeln!(s, "  time           not recorded (an asset older than version 9): frames {}, {} fps assumed", vdbcook_vpak::time::numbers_text(&numbers), meta.fps()),
    };
    let _ = writeln!(s, "  transform      {}, index offset {:?}", meta.map_type, meta.index_offset);
    if let Some((a, b)) = meta.index_bbox {
        let _ = writeln!(s, "  index bbox     {a:?} .. {b:?}");
    }
    let _ = writeln!(s, "  size           {} bytes, {} active voxels, {:.3} bits per active voxel", file_bytes, active, if active > 0 { file_bytes as f64 * 8.0 / active as f64 } else { 0.0 });
    let _ = writeln!(
        s,
        "  on the GPU     {gpu_bytes} bytes of sections (the file is {:.3}× that{})",
        file_bytes as f64 / gpu_bytes.max(1) as f64,
        if bodies.iter().any(|b| b.wrapped.is_some() || b.sections.iter().any(|x| x.2.is_some())) { ", supercompressed" } else { "" }
    );
    let _ = writeln!(s, "  {:<16} {:<8} {:>3} {:>8} {:>6} {:>12}  {:<12} {:<24} background", "channel", "format", "lod", "voxel", "plane", "bytes", "class", "values");
    for (i, c) in meta.channels.iter().enumerate() {
        let planes = meta.channel_planes(i).iter().map(|p| p.to_string()).collect::<Vec<_>>().join(",");
        let _ = writeln!(
            s,
            "  {:<16} {:<8} {:>3} {:>8} {:>6} {:>12}  {:<12} {:<24} {}",
            c.name,
            channel_formats(i),
            meta.resolution(i).level,
            vdbcook_vpak::resolution::voxel_size_text(meta.channel_voxel_size(i)),
            if c.alternates.is_empty() { format!("{}.{}", c.plane, c.lane) } else { planes },
            channel_bytes(i),
            c.class,
            format!("[{}, {}]", c.value_range[0], c.value_range[1]),
            c.background
        );
    }
    // Channels whose voxel centres sit off their level's (grids that share an origin with the finest).
    let mut offsets: Vec<(vdbcook_vpak::Resolution, Vec<&str>)> = Vec::new();
    for (i, c) in meta.channels.iter().enumerate().filter(|(i, _)| meta.resolution(*i).half_offset != [0; 3]) {
        match offsets.iter_mut().find(|(r, _)| *r == meta.resolution(i)) {
            Some((_, names)) => names.push(&c.name),
            None => offsets.push((meta.resolution(i), vec![&c.name])),
        }
    }
    for (r, names) in &offsets {
        let _ = writeln!(s, "  offset         {}: centres {:?} voxels from level {}'s", names.join(", "), r.offset(), r.level);
    }
    let _ = writeln!(s, "  {:<12} {:>10} {:>14}", "level", "count", "bytes");
    for (n, c, b) in nodes {
        let _ = writeln!(s, "  {n:<12} {c:>10} {b:>14}");
    }
    if meta.levels > 1 {
        let filters: Vec<&str> = meta.level_filters.iter().map(|f| f.name()).collect();
        let stored = if meta.first_level > 0 { format!(", {} stored (finer ones left out to fit a byte budget)", meta.stored_levels_text()) } else { String::new() };
        let own = match meta.is_multi_resolution() {
            true => format!(" trees, {} from each channel's own voxels", meta.detail_levels()),
            false => String::new(),
        };
        let _ = writeln!(s, "  levels of detail: {}{own}{stored} (filters: {}); bytes: what a level needs on its own", meta.levels, filters.join(", "));
        let _ = writeln!(s, "  {:<5} {:>6} {:>10} {:>8} {:>14} {:>14} {:>9}  channels", "lod", "voxel", "leaves", "tiles", "active voxels", "bytes", format!("of lod {}", meta.first_level));
        let base = levels.first().map_or(1, |l| l.4.max(1));
        for &(k, l, t, a, b) in &levels {
            let _ = writeln!(s, "  {k:<5} {:>6} {l:>10} {t:>8} {a:>14} {b:>14} {:>8.1}%  {}", format!("{}x", 1u64 << k), b as f64 * 100.0 / base as f64, channels_at(meta, k).join(", "));
        }
    }
    if table.len() > 1 {
        let _ = writeln!(s, "  {:<8} {:>7} {:>7} {:>8} {:>10} {:>14} {:>14}  format", "segment", "frames", "from", "number", "bricks", "bytes", "gpu bytes");
        for (k, (b, e)) in bodies.iter().zip(&table).enumerate() {
            let number = meta.frame_number(e.first_frame as usize);
            let _ = writeln!(s, "  {k:<8} {:>7} {:>7} {number:>8} {:>10} {:>14} {:>14}  {}", e.frame_count, e.first_frame, b.meta.brick_count, e.size, b.gpu_bytes, b.meta.format_names());
        }
    }
    for (k, b) in bodies.iter().enumerate() {
        let _ = writeln!(s, "  sections{}:", if table.len() > 1 { format!(" of segment {k}") } else { String::new() });
        if let Some(n) = b.wrapped {
            let _ = writeln!(s, "    (wrapped: the body's {n} bytes stored as one zstd frame of {} bytes at {}; offsets in the body)", table[k].size, b.offset);
        }
        for (e, restored, c) in &b.sections {
            let label = kind::label(e.kind, e.index);
            let coding = c.map_or(String::new(), |c| format!("  {}, {}: {restored} bytes restored", c.scheme_name(), c.filter.name()));
            let at = if b.wrapped.is_some() { e.offset } else { b.offset + e.offset };
            let _ = writeln!(s, "    {label:<16} {:>12} bytes at {:>10}  xxh3 {:016x}{coding}", e.size, at, e.checksum);
        }
    }
    for (p, info) in meta.planes.iter().enumerate() {
        let plane = info.plane;
        let table = if meta.plane_has_table(p) {
            "through a brick table"
        } else if meta.is_mixed_plane(p) {
            "through its channel's table"
        } else {
            "one per brick"
        };
        let _ = writeln!(s, "  plane {p}  {} {}-lane: {} brick{} ({table})", plane.format.name(), plane.lanes, info.bricks, if info.bricks == 1 { "" } else { "s" });
        for (a, atlas) in info.atlases.iter().enumerate() {
            let t = AtlasLayout { plane, atlas: *atlas }.texels();
            let _ = writeln!(s, "    atlas {a}  {} bricks from #{}, {}×{}×{} texels", atlas.count, atlas.first_brick, t[0], t[1], t[2]);
        }
    }
    let set: Vec<String> = meta.settings.iter().filter(|(_, v)| !v.is_empty()).map(|(k, v)| format!("{k}={v}")).collect();
    let _ = writeln!(s, "  settings       {}", set.join(" "));
    let _ = writeln!(s, "  sources        {} file{}", meta.sources.len(), if meta.sources.len() == 1 { "" } else { "s" });
    Ok(Described::Text(s))
}
