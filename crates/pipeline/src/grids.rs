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
    /// The sequence each channel is read from: 0 the main input, k the k-th
    /// `--with` input (one entry per spec).
    pub sequences: Vec<usize>,
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

/// A `--grids` name and the sequence it picks, when it ends in `@N` (`vel@1`:
/// the grid "vel" of the first `--with` input; 0 is the main input).
pub fn split_sequence(name: &str) -> (&str, Option<usize>) {
    match name.rsplit_once('@') {
        Some((grid, n)) if !grid.is_empty() && !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit()) => (grid, Some(n.parse().unwrap_or(usize::MAX))),
        _ => (name, None),
    }
}

/// Resolves the selection against the first frame's file.
pub fn resolve(vdb: &VdbFile, path: &str, sel: &GridSelection) -> Result<Channels> {
    resolve_in(&[(path.to_string(), Some(vdb))], sel)
}

/// Resolves the selection against one file of each sequence (`None`: the
/// sequence has no file to look in), the main input's first: each grid is
/// found in whichever file has it; one in several files must be picked with
/// `NAME@N`.
pub fn resolve_in(files: &[(String, Option<&VdbFile>)], sel: &GridSelection) -> Result<Channels> {
    let single = files.len() == 1;
    let has = |k: usize, grid: &str| files.get(k).and_then(|f| f.1).is_some_and(|v| v.grids.iter().any(|g| g.name == grid));
    let everything = || files.iter().map(|(p, v)| format!("{p} has: {}", v.map_or_else(|| "no file".into(), describe_grids))).collect::<Vec<_>>().join("; ");
    let find = |name: &str| -> Result<(usize, &GridInfo)> {
        let (grid, pick) = split_sequence(name);
        let holders: Vec<usize> = match pick {
            Some(k) if k >= files.len() => {
                let with = if single { "no --with input is given".to_string() } else { format!("the --with inputs are 1 to {}", files.len() - 1) };
                return Err(Error::Usage(format!("--grids {name}: there is no sequence {k} (0 is the main input; {with})")));
            }
            Some(k) => vec![k],
            None => (0..files.len()).filter(|&k| has(k, grid)).collect(),
        };
        let k = match holders[..] {
            [k] => k,
            [] if single => return Err(Error::Usage(format!("{}: no grid named \"{grid}\" (the file has: {})", files[0].0, files[0].1.map_or_else(|| "no file".into(), describe_grids)))),
            [] => return Err(Error::Usage(format!("no grid named \"{grid}\" in the frame's files ({})", everything()))),
            [a, b, ..] => {
                return Err(Error::Usage(format!("grid \"{grid}\" is in both {} and {}: say which with {grid}@{a} or {grid}@{b} (0 is the main input, 1 the first --with)", files[a].0, files[b].0)));
            }
        };
        let (path, vdb) = &files[k];
        let Some(vdb) = vdb else { return Err(Error::Usage(format!("--grids {name}: sequence {k} has no file to find it in"))) };
        let g = vdb.grids.iter().find(|g| g.name == grid).ok_or_else(|| Error::Usage(format!("{path}: no grid named \"{grid}\" (the file has: {})", describe_grids(vdb))))?;
        match &g.unsupported {
            Some(u) if !g.is_readable() => Err(Error::Usage(format!("{path}: grid \"{grid}\" cannot be cooked: {u}"))),
            _ => Ok((k, g)),
        }
    };
    let mut chosen: Vec<(usize, &GridInfo)> = Vec::new();
    match sel {
        GridSelection::Default if single => {
            let (path, vdb) = (&files[0].0, files[0].1.ok_or_else(|| Error::Failed(format!("{}: no file", files[0].0)))?);
            chosen.push((0, &vdb.grids[vdb.select(None).with_context(|| path.clone())?]));
        }
        // "density" wherever it is, else the first float grid of the first sequence that has one.
        GridSelection::Default => {
            let density: Vec<usize> = (0..files.len()).filter(|&k| files[k].1.is_some_and(|v| v.grids.iter().any(|g| g.name == "density" && g.is_readable_scalar()))).collect();
            let k = match density[..] {
                [] => None,
                [k] => Some(k),
                _ => Some(find("density")?.0),
            };
            let pick = k.or_else(|| (0..files.len()).find(|&k| files[k].1.is_some_and(|v| v.select(None).is_ok()))).and_then(|k| files[k].1.map(|v| (k, v)));
            let Some((k, vdb)) = pick else { return Err(Error::Usage(format!("no float grid in the frame's files ({})", everything()))) };
            chosen.push((k, &vdb.grids[vdb.select(None).with_context(|| files[k].0.clone())?]));
        }
        // One grid missing from a file is that frame's problem (exit 1, or an
        // empty frame with --allow-missing), as it is in any later frame.
        GridSelection::One(name) if single && matches!(split_sequence(name), (g, None | Some(0)) if !has(0, g)) => {
            let g = split_sequence(name).0;
            let (path, vdb) = (&files[0].0, files[0].1.map_or_else(|| "no file".into(), describe_grids));
            return Err(Error::Failed(format!("{path}: no grid named \"{g}\" (the file has: {vdb}; use --allow-missing to cook it as an empty frame)")));
        }
        GridSelection::One(name) => chosen.push(find(name)?),
        GridSelection::Many(names) => {
            let mut seen = std::collections::HashSet::new();
            if let Some(dup) = names.iter().find(|n| !seen.insert(split_sequence(n).0)) {
                return Err(Error::Usage(format!("--grids names \"{}\" twice", split_sequence(dup).0)));
            }
            for n in names {
                chosen.push(find(n)?);
            }
        }
        GridSelection::All => {
            let mut seen: Vec<(&str, usize)> = Vec::new();
            for (k, (_, vdb)) in files.iter().enumerate() {
                for g in vdb.iter().flat_map(|v| v.grids.iter()).filter(|g| g.is_readable()) {
                    match seen.iter().find(|(n, _)| *n == g.name) {
                        Some(&(_, j)) if j == k => {}
                        Some(&(_, j)) => {
                            let n = &g.name;
                            return Err(Error::Usage(format!(
                                "--grids all: grid \"{n}\" is in both {} and {}: name the grids with --grids, picking one with {n}@{j} or {n}@{k}",
                                files[j].0, files[k].0
                            )));
                        }
                        None => {
                            seen.push((&g.name, k));
                            chosen.push((k, g));
                        }
                    }
                }
            }
            if chosen.is_empty() {
                let what = if single {
                    format!("{}: --grids all found no float, double, half or vec3 grid (the file has: {})", files[0].0, files[0].1.map_or_else(|| "no file".into(), describe_grids))
                } else {
                    format!("--grids all found no float, double, half or vec3 grid ({})", everything())
                };
                return Err(Error::Usage(what));
            }
        }
    }
    let mut specs = Vec::new();
    let mut sequences = Vec::new();
    for (k, g) in chosen {
        let s = specs_of(g);
        sequences.extend(std::iter::repeat_n(k, s.len()));
        specs.extend(s);
    }
    Ok(Channels { several: specs.len() > 1 || !single || matches!(sel, GridSelection::Many(_) | GridSelection::All), specs, sequences })
}

/// Resolves the selection against the first file of each sequence of
/// `files` (the frames of a cook with `--with` inputs): the first frame that
/// has a file of that sequence on disk gives it.
pub fn resolve_sequences(files: &[FrameFile], sel: &GridSelection) -> Result<Channels> {
    let count = 1 + files.iter().map(|f| f.with.len()).max().unwrap_or(0);
    let mut opened: Vec<(String, Option<VdbFile>)> = Vec::with_capacity(count);
    for k in 0..count {
        let first = files.iter().find_map(|f| if k == 0 { f.path.as_ref() } else { f.with.get(k - 1).and_then(Option::as_ref) }.filter(|p| p.exists()));
        opened.push(match first {
            Some(p) => {
                let name = p.display().to_string();
                let vdb = vdbcook_vdb::open(p).with_context(|| name.clone())?;
                (name, Some(vdb))
            }
            None => (if k == 0 { "the main input".to_string() } else { format!("--with input {k}") }, None),
        });
    }
    let refs: Vec<(String, Option<&VdbFile>)> = opened.iter().map(|(p, v)| (p.clone(), v.as_ref())).collect();
    resolve_in(&refs, sel)
}

/// One frame as read: one grid per channel (`None`: missing or empty there).
pub struct Frame {
    pub path: PathBuf,
    /// `None` for a missing file (with `--allow-missing`).
    pub grids: Option<Vec<Option<Grid>>>,
    pub source: Option<SourceFile>,
    /// The files of the `--with` sequences read for this frame, and their records.
    pub with_sources: Vec<(PathBuf, SourceFile)>,
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
    /// The frame's file in each `--with` sequence, in their order (`None`:
    /// that sequence has none for this frame; its channels are empty there).
    pub with: Vec<Option<PathBuf>>,
}

impl FrameFile {
    /// One frame per file, each with the same rule for what is missing, numbered from 0.
    pub fn each(files: Vec<PathBuf>, allow_missing: bool) -> Vec<FrameFile> {
        files.into_iter().map(|p| FrameFile { path: Some(p), allow_missing, number: None, with: Vec::new() }).collect()
    }

    /// [`FrameFile::each`], frame `f` numbered `numbers[f]` when given.
    pub fn numbered(files: Vec<PathBuf>, numbers: Option<Vec<i64>>, allow_missing: bool) -> Vec<FrameFile> {
        let mut numbers = numbers.into_iter().flatten();
        files.into_iter().map(|p| FrameFile { path: Some(p), allow_missing, number: numbers.next(), with: Vec::new() }).collect()
    }
}

/// Grid `i` of a file as channels (a vec3 grid's three components), each to be taken once.
fn read_parts(vdb: &VdbFile, i: usize) -> Result<Vec<Option<Grid>>, vdbcook_vdb::Error> {
    Ok(vdb.read_channels(i)?.into_iter().map(Some).collect())
}

/// The channel `spec` takes from its grid's parts: moved out, not copied
/// (`--grids` names a grid, so a component, once).
fn take_part(parts: &mut [Option<Grid>], spec: &ChannelSpec) -> Option<Grid> {
    parts.get_mut(spec.component.unwrap_or(0) as usize).and_then(Option::take)
}

/// A file's record as an asset keeps it.
fn source_of(vdb: &VdbFile, path: &str) -> SourceFile {
    SourceFile { path: path.to_string(), bytes: vdb.bytes().len() as u64, xxh3_128: hash_hex(twox_hash::XxHash3_128::oneshot(vdb.bytes())) }
}

/// Reads one frame; the channels are resolved by the first frame that has a
/// file (a frame with `--with` files needs them resolved beforehand, by
/// [`resolve_sequences`]).
pub fn read_frame(file: FrameFile, sel: &GridSelection, channels: &mut Option<Channels>) -> Result<Frame> {
    if !file.with.is_empty() {
        if channels.is_none() {
            *channels = Some(resolve_sequences(std::slice::from_ref(&file), sel)?);
        }
        return read_files(file, channels.as_ref());
    }
    let FrameFile { path, allow_missing, number, .. } = file;
    let stated = crate::source_time::Stated::default();
    let with_sources = Vec::new();
    let Some(path) = path else { return Ok(Frame { path: PathBuf::new(), grids: None, source: None, with_sources, number, stated }) };
    let p = path.display().to_string();
    if !path.exists() {
        if allow_missing {
            return Ok(Frame { path, grids: None, source: None, with_sources, number, stated });
        }
        return Err(Error::Failed(format!("{p}: no such file (use --allow-missing to cook it as an empty frame)")));
    }
    let vdb = vdbcook_vdb::open(&path).with_context(|| p.clone())?;
    let stated = crate::source_time::stated(&vdb);
    let (mut records, grids) = recorded_beside(&[(&vdb, &p)], || grids_of(&vdb, &p, sel, channels, allow_missing));
    Ok(Frame { path, grids: grids?, source: records.pop(), with_sources, number, stated })
}

/// The channels of one file's frame (`None`: an empty frame), resolving
/// `channels` when this is the first file that has them.
fn grids_of(vdb: &VdbFile, p: &str, sel: &GridSelection, channels: &mut Option<Channels>, allow_missing: bool) -> Result<Option<Vec<Option<Grid>>>> {
    if channels.is_none() {
        match resolve(vdb, p, sel) {
            Ok(c) => *channels = Some(c),
            Err(_) if allow_missing && !matches!(sel, GridSelection::Many(_) | GridSelection::All) => return Ok(None),
            Err(e) => return Err(e),
        }
    }
    let Some(ch) = channels.as_ref() else { return Ok(None) };
    let mut grids: Vec<Option<Grid>> = Vec::with_capacity(ch.specs.len());
    // Each source grid once (a vec3 grid gives its three channels in order).
    let mut read: Option<(String, Vec<Option<Grid>>)> = None;
    for spec in &ch.specs {
        let Some(i) = vdb.grids.iter().position(|g| g.name == spec.grid) else {
            if ch.several {
                grids.push(None);
                continue;
            }
            if allow_missing {
                return Ok(None);
            }
            return Err(Error::Failed(format!("{p}: no grid named \"{}\" (the file has: {}; use --allow-missing to cook it as an empty frame)", spec.grid, describe_grids(vdb))));
        };
        if read.as_ref().is_none_or(|(name, _)| name != &spec.grid) {
            read = Some((spec.grid.clone(), read_parts(vdb, i).with_context(|| p.to_string())?));
        }
        grids.push(read.as_mut().and_then(|(_, parts)| take_part(parts, spec)));
    }
    Ok(Some(grids))
}

/// Runs `read` while the files' records are made on a thread beside it:
/// the record's hash is one serial pass over every byte of a file, which
/// overlaps with the serial scan of its trees (a third of a large frame's
/// read). Without a thread, the records are made first.
fn recorded_beside<T>(files: &[(&VdbFile, &str)], read: impl FnOnce() -> T) -> (Vec<SourceFile>, T) {
    let records = || files.iter().map(|&(vdb, name)| source_of(vdb, name)).collect::<Vec<_>>();
    std::thread::scope(|s| match std::thread::Builder::new().name("source hash".into()).spawn_scoped(s, records) {
        Ok(hashing) => {
            let out = read();
            (hashing.join().unwrap_or_else(|p| std::panic::resume_unwind(p)), out)
        }
        Err(_) => (records(), read()),
    })
}

/// Reads a frame from its main file and its `--with` files: each channel
/// from its sequence's file, all of them one frame for the cooker. A
/// sequence without its file (or, with `allow_missing`, whose file is not
/// on disk) leaves its channels empty in this frame.
fn read_files(file: FrameFile, channels: Option<&Channels>) -> Result<Frame> {
    let FrameFile { path, allow_missing, number, with } = file;
    let main = path.clone().unwrap_or_default();
    let mut opened: Vec<Option<(String, VdbFile)>> = Vec::with_capacity(1 + with.len());
    // Each opened file's path and whether it is the main one, in order.
    let mut paths = Vec::new();
    let mut stated = crate::source_time::Stated::default();
    for (k, p) in std::iter::once(path).chain(with).enumerate() {
        let Some(p) = p else {
            opened.push(None);
            continue;
        };
        let name = p.display().to_string();
        if !p.exists() {
            if allow_missing {
                opened.push(None);
                continue;
            }
            return Err(Error::Failed(format!("{name}: no such file (use --allow-missing to cook its channels empty in that frame)")));
        }
        let vdb = vdbcook_vdb::open(&p).with_context(|| name.clone())?;
        if k == 0 {
            stated = crate::source_time::stated(&vdb);
        }
        paths.push((k == 0, p));
        opened.push(Some((name, vdb)));
    }
    let files: Vec<(&VdbFile, &str)> = opened.iter().flatten().map(|(name, vdb)| (vdb, name.as_str())).collect();
    let (records, grids) = recorded_beside(&files, || with_grids(&opened, channels));
    let (mut source, mut with_sources) = (None, Vec::new());
    for ((main, p), record) in paths.into_iter().zip(records) {
        if main {
            source = Some(record);
        } else {
            with_sources.push((p, record));
        }
    }
    Ok(Frame { path: main, grids: grids?, source, with_sources, number, stated })
}

/// The channels of a frame from its opened files (`None`: an empty frame).
fn with_grids(opened: &[Option<(String, VdbFile)>], channels: Option<&Channels>) -> Result<Option<Vec<Option<Grid>>>> {
    let Some(ch) = channels.filter(|_| opened.iter().any(Option::is_some)) else { return Ok(None) };
    let mut grids: Vec<Option<Grid>> = Vec::with_capacity(ch.specs.len());
    // Each source grid once (a vec3 grid gives its three channels in order).
    let mut read: Option<(usize, String, Vec<Option<Grid>>)> = None;
    for (spec, &k) in ch.specs.iter().zip(&ch.sequences) {
        let Some((name, vdb)) = opened.get(k).and_then(Option::as_ref) else {
            grids.push(None);
            continue;
        };
        let Some(i) = vdb.grids.iter().position(|g| g.name == spec.grid) else {
            grids.push(None);
            continue;
        };
        if read.as_ref().is_none_or(|(s, g, _)| *s != k || g != &spec.grid) {
            read = Some((k, spec.grid.clone(), read_parts(vdb, i).with_context(|| name.clone())?));
        }
        grids.push(read.as_mut().and_then(|(_, _, parts)| take_part(parts, spec)));
    }
    Ok(Some(grids))
}

#[cfg(test)]
mod tests {
    use super::split_sequence;

    #[test]
    fn a_trailing_at_number_picks_a_sequence() {
        assert_eq!(split_sequence("vel@1"), ("vel", Some(1)));
        assert_eq!(split_sequence("vel@0"), ("vel", Some(0)));
        assert_eq!(split_sequence("vel"), ("vel", None));
        assert_eq!(split_sequence("a@b"), ("a@b", None));
        assert_eq!(split_sequence("@1"), ("@1", None));
        assert_eq!(split_sequence("vel@"), ("vel@", None));
        assert_eq!(split_sequence("x@99999999999999999999999"), ("x", Some(usize::MAX)));
    }
}
