//! Which grids of the input files become channels (`--grid`, `--grids`), and
//! reading them frame by frame.

use crate::{Context, Error, Result};
use std::path::PathBuf;
use vdbcook_cook::ChannelSpec;
use vdbcook_grid::Grid;
use vdbcook_vdb::{GridInfo, ValueType, VdbFile};
use vdbcook_vpak::SourceFile;

/// The grids asked for.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub enum GridSelection {
    /// "density", else the first float grid.
    #[default]
    Default,
    /// `--grid NAME`: that grid.
    One(String),
    /// `--grids a,b,c`: those grids, in that order.
    Many(Vec<String>),
    /// `--grids all`: every float, double, half and vec3 grid of the first frame, in file order.
    All,
}

impl GridSelection {
    pub fn from_flags(grid: Option<&str>, grids: Option<&str>) -> GridSelection {
        match (grid, grids) {
            (_, Some("all")) => GridSelection::All,
            (_, Some(list)) => GridSelection::Many(list.split(',').map(|s| s.trim().to_string()).filter(|s| !s.is_empty()).collect()),
            (Some(g), None) => GridSelection::One(g.to_string()),
            (None, None) => GridSelection::Default,
        }
    }
}

/// The channels of a cook: which grid each comes from.
#[derive(Clone, Debug)]
pub struct Channels {
    pub specs: Vec<ChannelSpec>,
    /// Whether several grids were asked for (a grid missing in a later frame
    /// is then an empty channel there, not an error).
    pub several: bool,
}

fn describe_grids(vdb: &VdbFile) -> String {
    let names: Vec<String> = vdb.grids.iter().map(|g| format!("{} ({})", g.display_name(), g.value_type.name())).collect();
    if names.is_empty() {
        "none".into()
    } else {
        names.join(", ")
    }
}

/// The channels of a grid: itself, or the x, y, z components of a vec3 grid.
fn specs_of(g: &GridInfo) -> Vec<ChannelSpec> {
    let vec3 = matches!(g.value_type, ValueType::Vec3(_));
    g.channel_names()
        .into_iter()
        .enumerate()
        .map(|(k, name)| ChannelSpec { name, grid: g.name.clone(), component: vec3.then_some(k as u32), value_type: g.value_type.name().to_string(), class: g.class.vdb_name().to_string() })
        .collect()
}

/// Resolves the selection against the first frame's file.
pub fn resolve(vdb: &VdbFile, path: &str, sel: &GridSelection) -> Result<Channels> {
    let find = |name: &str| -> Result<&GridInfo> {
        let g = vdb.grids.iter().find(|g| g.name == name).ok_or_else(|| Error::Usage(format!("{path}: no grid named \"{name}\" (the file has: {})", describe_grids(vdb))))?;
        match &g.unsupported {
            Some(u) if !g.is_readable() => Err(Error::Usage(format!("{path}: grid \"{name}\" cannot be cooked: {u}"))),
            _ => Ok(g),
        }
    };
    let specs = match sel {
        GridSelection::Default => specs_of(&vdb.grids[vdb.select(None).with_context(|| path.to_string())?]),
        // One grid missing from a file is that frame's problem (exit 1, or an
        // empty frame with --allow-missing), as it is in any later frame.
        GridSelection::One(name) if !vdb.grids.iter().any(|g| &g.name == name) => {
            return Err(Error::Failed(format!("{path}: no grid named \"{name}\" (the file has: {}; use --allow-missing to cook it as an empty frame)", describe_grids(vdb))));
        }
        GridSelection::One(name) => specs_of(find(name)?),
        GridSelection::Many(names) => {
            let mut seen = std::collections::HashSet::new();
            if let Some(dup) = names.iter().find(|n| !seen.insert(n.as_str())) {
                return Err(Error::Usage(format!("--grids names \"{dup}\" twice")));
            }
            names.iter().map(|n| find(n).map(specs_of)).collect::<Result<Vec<_>>>()?.concat()
        }
        GridSelection::All => {
            let mut seen = std::collections::HashSet::new();
            let all: Vec<ChannelSpec> = vdb.grids.iter().filter(|g| g.is_readable() && seen.insert(g.name.clone())).flat_map(specs_of).collect();
            if all.is_empty() {
                return Err(Error::Usage(format!("{path}: --grids all found no float, double, half or vec3 grid (the file has: {})", describe_grids(vdb))));
            }
            all
        }
    };
    Ok(Channels { several: specs.len() > 1 || matches!(sel, GridSelection::Many(_) | GridSelection::All), specs })
}

/// One frame as read: one grid per channel (`None`: missing or empty there).
pub struct Frame {
    pub path: PathBuf,
    /// `None` for a missing file (with `--allow-missing`).
    pub grids: Option<Vec<Option<Grid>>>,
    pub source: Option<SourceFile>,
    /// Its number in the source sequence, when known.
    pub number: Option<i64>,
    /// What its file's metadata says of time.
    pub stated: crate::source_time::Stated,
}

/// A source's recorded hash: XXH3-128 as 32 hex digits (`SourceFile::xxh3_128`).
pub(crate) fn hash_hex(xxh3_128: u128) -> String {
    format!("{xxh3_128:032x}")
}

/// One frame to read.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameFile {
    /// The file; `None` for a frame that has none (a reference's copy of an
    /// asset's frame cooked from a missing file).
    pub path: Option<PathBuf>,
    /// A missing file or grid makes an empty frame rather than an error.
    pub allow_missing: bool,
    /// Its number in the source sequence (`None`: numbered on from the frame before, from 0).
    pub number: Option<i64>,
}

impl FrameFile {
    /// One frame per file, each with the same rule for what is missing, numbered from 0.
    pub fn each(files: Vec<PathBuf>, allow_missing: bool) -> Vec<FrameFile> {
        files.into_iter().map(|p| FrameFile { path: Some(p), allow_missing, number: None }).collect()
    }

    /// [`FrameFile::each`], frame `f` numbered `numbers[f]` when given.
    pub fn numbered(files: Vec<PathBuf>, numbers: Option<Vec<i64>>, allow_missing: bool) -> Vec<FrameFile> {
        let mut numbers = numbers.into_iter().flatten();
        files.into_iter().map(|p| FrameFile { path: Some(p), allow_missing, number: numbers.next() }).collect()
    }
}

/// Reads one frame; the channels are resolved by the first frame that has a file.
pub fn read_frame(file: FrameFile, sel: &GridSelection, channels: &mut Option<Channels>) -> Result<Frame> {
    let FrameFile { path, allow_missing, number } = file;
    let stated = crate::source_time::Stated::default();
    let Some(path) = path else { return Ok(Frame { path: PathBuf::new(), grids: None, source: None, number, stated }) };
    let p = path.display().to_string();
    if !path.exists() {
        if allow_missing {
            return Ok(Frame { path, grids: None, source: None, number, stated });
        }
        return Err(Error::Failed(format!("{p}: no such file (use --allow-missing to cook it as an empty frame)")));
    }
    let vdb = vdbcook_vdb::open(&path).with_context(|| p.clone())?;
    let stated = crate::source_time::stated(&vdb);
    let source = SourceFile { path: p.clone(), bytes: vdb.bytes().len() as u64, xxh3_128: hash_hex(xxhash_rust::xxh3::xxh3_128(vdb.bytes())) };
    if channels.is_none() {
        match resolve(&vdb, &p, sel) {
            Ok(c) => *channels = Some(c),
            Err(_) if allow_missing && !matches!(sel, GridSelection::Many(_) | GridSelection::All) => return Ok(Frame { path, grids: None, source: Some(source), number, stated }),
            Err(e) => return Err(e),
        }
    }
    let Some(ch) = channels.as_ref() else { return Ok(Frame { path, grids: None, source: Some(source), number, stated }) };
    let mut grids: Vec<Option<Grid>> = Vec::with_capacity(ch.specs.len());
    // Each source grid once (a vec3 grid gives its three channels in order).
    let mut read: Option<(String, Vec<Grid>)> = None;
    for spec in &ch.specs {
        let Some(i) = vdb.grids.iter().position(|g| g.name == spec.grid) else {
            if ch.several {
                grids.push(None);
                continue;
            }
            if allow_missing {
                return Ok(Frame { path, grids: None, source: Some(source), number, stated });
            }
            return Err(Error::Failed(format!("{p}: no grid named \"{}\" (the file has: {}; use --allow-missing to cook it as an empty frame)", spec.grid, describe_grids(&vdb))));
        };
        if read.as_ref().is_none_or(|(name, _)| name != &spec.grid) {
            read = Some((spec.grid.clone(), vdb.read_channels(i).with_context(|| p.clone())?));
        }
        let parts = read.as_mut().map(|(_, g)| g).filter(|g| !g.is_empty());
        let grid = match spec.component {
            Some(k) => parts.and_then(|g| g.get(k as usize).cloned()),
            None => parts.map(|g| g.remove(0)),
        };
        grids.push(grid);
    }
    Ok(Frame { path, grids: Some(grids), source: Some(source), number, stated })
}
