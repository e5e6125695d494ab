//! `vdbcook inspect`: what a .vdb file holds, as text or JSON.

/// The .vpak half of `inspect`.
#[path = "inspect_vpak.rs"]
mod inspect_vpak;

use crate::{emit, exit, report_error};
use anyhow::Context;
use serde_json::{json, Map, Value};
use std::path::Path;
use vdbcook_grid::Stats;
use vdbcook_vdb::{GridInfo, MetaMap, MetaValue, VdbFile};

pub const AFTER_HELP: &str = "\
For a .vpak asset: its sections with sizes, the node and brick counts and bytes
(L1, L2, L3, bricks), format, frames, settings and sources; every section checksum
is verified (a mismatch is an error, exit code 1).

For a .vdb file, every grid is listed. Float, double and half grids are read in full: active
voxel count (tile voxels included), inclusive index-space bbox, leaf count,
active tile count, and min / max / sum of the active values. Grids of other
types (vec3s, int32, points, ...) are listed with the reason they are skipped.
A file that cannot be read prints one error line and makes the exit code 1;
the other files are still described.";

/// One grid's figures, or why it was skipped.
struct GridReport<'a> {
    info: &'a GridInfo,
    background: Option<f32>,
    stats: Option<Stats>,
    skipped: Option<String>,
}

fn describe(file: &VdbFile) -> anyhow::Result<Vec<GridReport<'_>>> {
    let mut out = Vec::with_capacity(file.grids.len());
    // Figures per tree: instances share their parent's, which is read once.
    let mut trees: std::collections::HashMap<&str, (f32, Stats)> = std::collections::HashMap::new();
    for (i, info) in file.grids.iter().enumerate() {
        let skipped = info.unsupported.as_ref().map(|u| u.to_string());
        let tree = info.instance_parent.as_deref().unwrap_or(&info.unique_name);
        let (background, stats) = if skipped.is_some() {
            (None, None)
        } else if let Some((bg, st)) = trees.get(tree) {
            (Some(*bg), Some(*st))
        } else {
            let grid = file.read_grid(i)?;
            let st = grid.stats();
            trees.insert(tree, (grid.background, st));
            (Some(grid.background), Some(st))
        };
        out.push(GridReport { info, background, stats, skipped });
    }
    Ok(out)
}

pub fn run(files: &[std::path::PathBuf], as_json: bool, quiet: bool) -> u8 {
    let mut code = exit::SUCCESS;
    let mut docs = Vec::new();
    for path in files {
        if vdbcook_pipeline::is_vpak(path) {
            match inspect_vpak::describe(path, as_json) {
                Ok(inspect_vpak::Described::Text(t)) => {
                    if !quiet {
                        if let Err(e) = emit(&t) {
                            return stdout_failed(&e, code);
                        }
                    }
                }
                Ok(inspect_vpak::Described::Json(v)) => docs.push(v),
                Err(e) => {
                    report_error(&e);
                    code = exit::FAILURE;
                }
            }
            continue;
        }
        let result = vdbcook_vdb::open(path).with_context(|| path.display().to_string()).and_then(|file| {
            let grids = describe(&file).with_context(|| path.display().to_string())?;
            Ok(if as_json { Err(file_json(path, &file, &grids)) } else { Ok(file_text(path, &file, &grids)) })
        });
        match result {
            Ok(Ok(text)) => {
                if !quiet {
                    if let Err(e) = emit(&text) {
                        return stdout_failed(&e, code);
                    }
                }
            }
            Ok(Err(doc)) => docs.push(doc),
            Err(e) => {
                report_error(&e);
                code = exit::FAILURE;
            }
        }
    }
    if as_json && !quiet {
        let doc = json!({ "files": docs });
        if let Err(e) = emit(&format!("{}\n", serde_json::to_string_pretty(&doc).unwrap_or_default())) {
            return stdout_failed(&e, code);
        }
    }
    code
}

/// The exit code after a failed write to stdout: a closed pipe ends the output
/// quietly; anything else is reported and is a failure.
fn stdout_failed(e: &anyhow::Error, code: u8) -> u8 {
    if e.is::<crate::PipeClosed>() {
        return code;
    }
    report_error(e);
    exit::FAILURE
}

/// `%g`-style number: `digits` significant digits, trailing zeros dropped.
fn fmt_g(x: f64, digits: i32) -> String {
    if x == 0.0 || !x.is_finite() {
        return format!("{x}");
    }
    let exp = x.abs().log10().floor() as i32;
    let trim = |s: String| if s.contains('.') { s.trim_end_matches('0').trim_end_matches('.').to_string() } else { s };
    if exp < -4 || exp >= digits {
        let s = format!("{:.*e}", (digits - 1).max(0) as usize, x);
        match s.split_once('e') {
            Some((m, e)) => format!("{}e{e}", trim(m.to_string())),
            None => s,
        }
    } else {
        trim(format!("{:.*}", (digits - 1 - exp).max(0) as usize, x))
    }
}

fn fmt_vec(v: [f64; 3]) -> String {
    format!("{} × {} × {}", fmt_g(v[0], 6), fmt_g(v[1], 6), fmt_g(v[2], 6))
}

fn file_text(path: &Path, file: &VdbFile, grids: &[GridReport<'_>]) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let n = grids.len();
    let _ = writeln!(s, "{}: OpenVDB file version {}, library {}.{}, {} grid{}", path.display(), file.file_version, file.library_version.0, file.library_version.1, n, if n == 1 { "" } else { "s" });
    for g in grids {
        let i = g.info;
        let _ = write!(s, "  grid \"{}\": {} {}", i.display_name(), i.value_type.name(), i.class.vdb_name());
        if i.half_float {
            s.push_str(", saved as half");
        }
        let _ = write!(s, ", compression {}", i.compression_names().join("+"));
        if let Some(p) = &i.instance_parent {
            let _ = write!(s, ", instance of \"{}\"", p.replace('\u{1e}', "#"));
        }
        s.push('\n');
        if let Some(t) = &i.transform {
            let _ = writeln!(s, "    transform      {}, voxel size {}", t.map_type.vdb_name(), fmt_vec(t.voxel_size()));
        }
        if let Some(reason) = &g.skipped {
            let _ = writeln!(s, "    skipped        {reason}");
            continue;
        }
        let Some(st) = &g.stats else { continue };
        let _ = writeln!(s, "    active voxels  {} in {} leaves and {} active tiles", st.active_voxels, st.leaf_count, st.active_tiles);
        match st.bbox {
            Some(b) => {
                let _ = writeln!(s, "    bbox           {:?} .. {:?}", b.min.to_array(), b.max.to_array());
            }
            None => s.push_str("    bbox           empty\n"),
        }
        if let (Some(lo), Some(hi)) = (st.min, st.max) {
            let _ = writeln!(s, "    values         min {}, max {}, sum {}", fmt_g(lo, 7), fmt_g(hi, 7), fmt_g(st.sum, 12));
        }
        if st.non_finite > 0 {
            let _ = writeln!(s, "    non-finite     {} active value{} (NaN or ±inf)", st.non_finite, if st.non_finite == 1 { "" } else { "s" });
        }
        if let Some(bg) = g.background {
            let _ = writeln!(s, "    background     {}", fmt_g(f64::from(bg), 7));
        }
    }
    s
}

/// A number; NaN and ±inf as the strings `vdbcook_cook::Figure` writes (`null` means "no value").
pub fn num(v: f64) -> Value {
    serde_json::to_value(vdbcook_cook::Figure(v)).unwrap_or(Value::Null)
}

/// [`num`] for an f32, written with its own shortest spelling.
pub fn num32(v: f32) -> Value {
    if v.is_finite() {
        json!(v)
    } else {
        num(f64::from(v))
    }
}

fn meta_json(m: &MetaMap) -> Value {
    let mut obj = Map::new();
    for (k, v) in &m.0 {
        let val = match v {
            MetaValue::String(s) => json!(s),
            MetaValue::Bool(b) => json!(b),
            MetaValue::Int32(x) => json!(x),
            MetaValue::Int64(x) => json!(x),
            MetaValue::Float(x) => num(f64::from(*x)),
            MetaValue::Double(x) => num(*x),
            MetaValue::Vec2i(a) => json!(a),
            MetaValue::Vec3i(a) => json!(a),
            MetaValue::Vec4i(a) => json!(a),
            MetaValue::Vec2s(a) => Value::Array(a.iter().map(|x| num(f64::from(*x))).collect()),
            MetaValue::Vec3s(a) => Value::Array(a.iter().map(|x| num(f64::from(*x))).collect()),
            MetaValue::Vec4s(a) => Value::Array(a.iter().map(|x| num(f64::from(*x))).collect()),
            MetaValue::Mat4s(a) => Value::Array(a.iter().map(|x| num(f64::from(*x))).collect()),
            MetaValue::Vec2d(a) => Value::Array(a.iter().map(|x| num(*x)).collect()),
            MetaValue::Vec3d(a) => Value::Array(a.iter().map(|x| num(*x)).collect()),
            MetaValue::Vec4d(a) => Value::Array(a.iter().map(|x| num(*x)).collect()),
            MetaValue::Mat4d(a) => Value::Array(a.iter().map(|x| num(*x)).collect()),
            MetaValue::Other { type_name, size } => json!({ "type": type_name, "bytes": size }),
        };
        obj.insert(k.clone(), val);
    }
    Value::Object(obj)
}

fn file_json(path: &Path, file: &VdbFile, grids: &[GridReport<'_>]) -> Value {
    let grids: Vec<Value> = grids
        .iter()
        .map(|g| {
            let i = g.info;
            let st = g.stats.as_ref();
            let transform = i.transform.map(|t| {
                json!({
                    "map_type": t.map_type.vdb_name(),
                    "voxel_size": t.voxel_size().map(num),
                    "matrix": t.matrix.map(|r| r.map(num)),
                })
            });
            json!({
                "name": i.name,
                "unique_name": i.unique_name,
                "value_type": i.value_type.name(),
                "tree_type": i.tree_type,
                "class": i.class.vdb_name(),
                "half_float": i.half_float,
                "compression": i.compression_names(),
                "instance_of": i.instance_parent,
                "transform": transform,
                "voxel_size": i.transform.map(|t| t.voxel_size().map(num)),
                "background": g.background.map(|b| num(f64::from(b))),
                "active_voxels": st.map(|s| s.active_voxels),
                "bbox_min": st.and_then(|s| s.bbox).map(|b| b.min.to_array()),
                "bbox_max": st.and_then(|s| s.bbox).map(|b| b.max.to_array()),
                "leaf_count": st.map(|s| s.leaf_count),
                "active_tiles": st.map(|s| s.active_tiles),
                "min": st.and_then(|s| s.min).map(num),
                "max": st.and_then(|s| s.max).map(num),
                "sum": st.filter(|s| s.active_voxels > 0).map(|s| num(s.sum)),
                "non_finite": st.map(|s| s.non_finite),
                "skipped": g.skipped,
                "metadata": meta_json(&i.metadata),
            })
        })
        .collect();
    json!({
        "path": path.display().to_string(),
        "kind": "vdb",
        "file_version": file.file_version,
        "library_version": format!("{}.{}", file.library_version.0, file.library_version.1),
        "uuid": file.uuid,
        "metadata": meta_json(&file.metadata),
        "grids": grids,
    })
}

#[cfg(test)]
mod tests {
    use super::fmt_g as g;

    #[test]
    fn general_number_format() {
        assert_eq!(g(0.009999999605339876, 6), "0.01");
        assert_eq!(g(0.800000011920929, 6), "0.8");
        assert_eq!(g(1.92784e-5, 6), "1.92784e-5");
        assert_eq!(g(373269726.4420656, 12), "373269726.442");
        assert_eq!(g(-4.515625, 7), "-4.515625");
        assert_eq!(g(1e10, 7), "1e10");
        assert_eq!(g(0.0, 7), "0");
    }
}
