//! The summary of a cook, as text and as JSON (docs/cook-json.md).

use std::path::Path;
use vdbcook_cook::{ChannelReport, CookReport, Figure};

/// Bytes as megabytes, the summary's way.
pub fn mb(b: u64) -> String {
    format!("{:.2} MB", b as f64 / 1e6)
}

/// The human summary of a cook into `output`; `grid` names the channels cooked.
pub fn summary_text(output: &Path, grid: Option<&str>, r: &CookReport) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let what = if r.channels.len() == 1 { format!("grid \"{}\"", grid.unwrap_or("")) } else { format!("{} channels", r.channels.len()) };
    let _ = writeln!(s, "cooked {} frame{} of {what} into {} ({}, {})", r.frames, if r.frames == 1 { "" } else { "s" }, output.display(), r.format, mb(r.file_bytes));
    let m = &r.metadata;
    let numbers: Vec<i64> = (0..r.frames).map(|f| m.frame_number(f)).collect();
    let _ = writeln!(s, "  time            frames {} at {} fps", vdbcook_vpak::time::numbers_text(&numbers), m.fps());
    if let Some(t) = &r.source_time {
        let _ = writeln!(s, "  source time     {}", crate::source_time::text(t, m.fps()));
    }
    if r.disk_sections != r.sections {
        let _ = writeln!(s, "  supercompressed {} on disk, {} of sections on the GPU (the file is {:.3}× that)", mb(r.file_bytes), mb(r.gpu_bytes), r.file_bytes as f64 / r.gpu_bytes.max(1) as f64);
    }
    let _ = writeln!(s, "  active voxels   {} ({:.3} bits per active voxel)", r.active_voxels, r.bits_per_active_voxel);
    let _ = writeln!(s, "  bricks          {} leaves -> {} unique -> {} stored in {} texture{}", r.bricks, r.unique_bricks, r.stored_bricks, r.textures, if r.textures == 1 { "" } else { "s" });
    let _ = writeln!(s, "  nodes           L1 {}, L2 {}, L3 {}, tiles {}; tree {} (thesis layout: {})", r.l1_nodes, r.l2_nodes, r.l3_nodes, r.tiles, mb(r.tree_bytes), mb(r.thesis_tree_bytes));
    if r.segments.len() > 1 {
        let sizes: Vec<String> = r.segments.iter().map(|g| format!("{} ({} bricks)", mb(g.bytes), g.stored_bricks)).collect();
        let most = r.segments.iter().map(|g| g.frames).max().unwrap_or(0);
        let _ = writeln!(s, "  segments        {} of up to {most} frames: {}", r.segments.len(), sizes.join(", "));
    }
    if m.is_multi_resolution() {
        let _ = writeln!(s, "  voxel sizes     {}", voxel_sizes_text(m));
    }
    if r.channels.len() == 1 {
        let _ = writeln!(s, "  voxel error     rmse {:.3e}, psnr {:.1} dB, max {:.3e}", r.voxel_rmse, r.voxel_psnr, r.voxel_max_error);
    } else {
        for c in &r.channels {
            let _ = writeln!(
                s,
                "  {:<16}{:<7} {:>10} ({} brick{}), values [{:.4}, {:.4}], rmse {:.3e}, psnr {:.1} dB, max {:.3e}",
                c.name,
                c.format,
                mb(c.bytes),
                c.bricks,
                if c.bricks == 1 { "" } else { "s" },
                c.value_range[0],
                c.value_range[1],
                c.voxel_rmse,
                c.voxel_psnr,
                c.voxel_max_error
            );
        }
    }
    // Per-brick formats: what each format holds.
    for c in r.channels.iter().filter(|c| c.formats.len() > 1) {
        let f: Vec<String> = c.formats.iter().map(|f| format!("{} {} ({})", f.format.name(), f.bricks, mb(f.bytes))).collect();
        let who = if r.channels.len() > 1 { format!("{}: ", c.name) } else { String::new() };
        let _ = writeln!(s, "  brick formats   {who}{}", f.join(", "));
    }
    for c in &r.channels {
        if let Some(t) = non_finite_text(c, r.channels.len() > 1) {
            let _ = writeln!(s, "  non-finite      {t}");
        }
    }
    if let Some(b) = &r.budget {
        let tries: Vec<String> = b.tries.iter().map(|t| format!("from level {}: {}", t.first_level, mb(t.bytes))).collect();
        let last = r.first_level as usize + r.levels.len();
        let kept = if r.levels.is_empty() { format!("level {last} kept") } else { format!("levels {} to {last} kept", r.first_level) };
        let dropped = match b.dropped.as_slice() {
            [] => String::new(),
            [k] => format!(", level {k} left out"),
            [a, .., z] => format!(", levels {a} to {z} left out"),
        };
        let figures = if r.first_level > 0 { format!("; the error figures above are level {}'s", r.first_level) } else { String::new() };
        let _ = writeln!(s, "  byte budget     {}: {kept}{dropped} ({}){figures}", mb(b.max_bytes), tries.join(", "));
    }
    // With channels at their own voxel sizes and no levels of detail, the
    // coarser trees are channels' own levels, reported above.
    if !r.levels.is_empty() && m.detail_levels() > 1 {
        let per: Vec<String> = r.levels.iter().map(|l| format!("{} ({}x: {} leaves, rmse {:.3e})", l.level, l.voxel_scale, l.leaves, l.voxel_rmse)).collect();
        let _ = writeln!(s, "  levels          {}", per.join(", "));
    }
    if let Some(c) = &r.clustering {
        let _ = writeln!(
            s,
            "  clustering      {} -> {} bricks ({:.2}x; {} constant, {} high variance, {} over the error bound kept), rmse {:.3e} without, {:.3e} with",
            c.stats.bricks_in, c.stats.bricks_out, c.ratio, c.stats.constant, c.stats.high_variance, c.stats.over_error, c.rmse_without, c.rmse_with
        );
    }
    if r.spilled_bytes > 0 {
        let _ = writeln!(s, "  spilled         {} at most in temporary files beside the output (past --spill-above)", mb(r.spilled_bytes));
    }
    let t: Vec<String> = r.timings.iter().map(|(k, v)| format!("{k} {v:.2}s")).collect();
    let _ = writeln!(s, "  time            {}", t.join(", "));
    s
}

/// "0.1: density, temperature; 0.2 (level 1, offset -0.5 voxels): vel.x, vel.y, vel.z":
/// the channels by voxel size, where their voxels are in the asset's.
pub fn voxel_sizes_text(m: &vdbcook_vpak::Metadata) -> String {
    // (resolution, its first channel, the names of its channels)
    let mut groups: Vec<(vdbcook_vpak::Resolution, usize, Vec<&str>)> = Vec::new();
    for (c, ch) in m.channels.iter().enumerate() {
        match groups.iter_mut().find(|(r, _, _)| *r == m.resolution(c)) {
            Some((_, _, names)) => names.push(&ch.name),
            None => groups.push((m.resolution(c), c, vec![&ch.name])),
        }
    }
    groups
        .iter()
        .map(|&(r, c, ref names)| {
            let offset = r.offset();
            let place = match (r.level, offset == [0.0; 3]) {
                (0, true) => String::new(),
                (k, true) => format!(" (level {k})"),
                (k, false) if offset[0] == offset[1] && offset[1] == offset[2] => format!(" (level {k}, offset {} voxels)", offset[0]),
                (k, false) => format!(" (level {k}, offset {:?} voxels)", offset),
            };
            format!("{}{place}: {}", vdbcook_vpak::resolution::voxel_size_text(m.channel_voxel_size(c)), names.join(", "))
        })
        .collect::<Vec<_>>()
        .join("; ")
}

/// What happened to a channel's NaN and ±inf source voxels, if it had any.
fn non_finite_text(c: &ChannelReport, name: bool) -> Option<String> {
    let n = c.non_finite;
    if n.total() == 0 {
        return None;
    }
    let kinds: Vec<String> = [(n.nan, "NaN"), (n.pos_inf, "+inf"), (n.neg_inf, "-inf")].iter().filter(|(k, _)| *k > 0).map(|(k, what)| format!("{k} {what}")).collect();
    // Per-brick formats store bricks with non-finite voxels in f16 or f32, which keep them.
    let stored = if c.formats.iter().all(|f| f.format.is_ranged()) { format!("{} stores each as the mean of its finite neighbours", c.format) } else { format!("{} keeps them", c.format) };
    let who = if name { format!("{}: ", c.name) } else { String::new() };
    Some(format!("{who}{} source voxel{} ({}) left out of the error figures; {stored}", n.total(), if n.total() == 1 { "" } else { "s" }, kinds.join(", ")))
}

/// Pretty JSON and a newline.
pub fn json_text(v: &serde_json::Value) -> String {
    format!("{}\n", serde_json::to_string_pretty(v).unwrap_or_default())
}

/// The JSON summary of a cook into `output` (docs/cook-json.md), with its validation's document.
pub fn summary_json(output: &Path, grid: Option<&str>, r: &CookReport, validation: Option<&serde_json::Value>) -> serde_json::Value {
    let mut v = serde_json::to_value(r).unwrap_or_default();
    if let Some(o) = v.as_object_mut() {
        if let Some(val) = validation {
            o.insert("validation".into(), val.clone());
        }
        o.insert("output".into(), serde_json::json!(output.display().to_string()));
        o.insert("fps".into(), serde_json::json!(r.metadata.fps()));
        o.insert("frame_numbers".into(), serde_json::json!((0..r.frames).map(|f| r.metadata.frame_number(f)).collect::<Vec<_>>()));
        o.insert("grid".into(), serde_json::json!(grid));
        // Each section restored (what the GPU is given) and on disk; the coding section is on disk only.
        let disk = |name: &str| r.disk_sections.iter().find(|(n, _)| n == name).map_or(0, |(_, b)| *b);
        let restored = r.sections.iter().map(|(n, b)| serde_json::json!({"name": n, "bytes": b, "disk_bytes": disk(n)}));
        let disk_only = r.disk_sections.iter().filter(|(n, _)| !r.sections.iter().any(|(m, _)| m == n)).map(|(n, b)| serde_json::json!({"name": n, "bytes": 0, "disk_bytes": b}));
        o.insert("sections".into(), serde_json::json!(restored.chain(disk_only).collect::<Vec<_>>()));
        o.insert("spilled_bytes".into(), serde_json::json!(r.spilled_bytes));
        o.insert("timings".into(), serde_json::json!(r.timings.iter().map(|(n, s)| (n.clone(), serde_json::json!(s))).collect::<serde_json::Map<_, _>>()));
        o.insert(
            "frame_errors".into(),
            serde_json::json!(r
                .frame_errors
                .iter()
                .enumerate()
                .map(|(i, (rmse, max))| serde_json::json!({"frame": i, "number": r.metadata.frame_number(i), "rmse": Figure(*rmse), "max_error": Figure(*max)}))
                .collect::<Vec<_>>()),
        );
    }
    v
}
