//! The source files an asset records: where `validate ASSET` finds them when
//! no `--source` is given, and whether they still are what was cooked.
//!
//! `cook` records each frame's file as it was named (relative paths: to the
//! directory cook ran in); `bake` records them relative to the manifest's
//! directory when they are below it. A relative path is looked up in the
//! current directory, then in the asset's directory.

use crate::{Context, Error, Result};
use std::path::{Path, PathBuf};
use vdbcook_vpak::Metadata;

/// One path per frame of `meta`, in frame order; `None` for a frame cooked
/// from a missing file (`--allow-missing`), which records none.
pub fn frame_files(meta: &Metadata, asset: &Path) -> Result<Vec<Option<PathBuf>>> {
    let name = asset.display();
    let asset_dir = asset.parent().unwrap_or(Path::new(""));
    let mut files = Vec::with_capacity(meta.frames.len());
    for (f, frame) in meta.frames.iter().enumerate() {
        let Some(i) = frame.source else {
            files.push(None);
            continue;
        };
        let src = meta.sources.get(i as usize).ok_or_else(|| Error::Failed(format!("{name}: frame {f} names source {i}, but the asset records {}", meta.sources.len())))?;
        let recorded = Path::new(&src.path);
        let found = if recorded.is_absolute() { vec![recorded.to_path_buf()] } else { vec![recorded.to_path_buf(), asset_dir.join(recorded)] }.into_iter().find(|p| p.is_file());
        let Some(path) = found else {
            return Err(Error::Failed(format!(
                "{name}: the recorded source of frame {f}, {}, does not exist here (relative paths are looked up in the current directory and the asset's); give the sources with --source",
                src.path
            )));
        };
        // The size first (free), then the bytes: a changed file is named before it is parsed.
        let bytes = std::fs::metadata(&path).map(|m| m.len()).unwrap_or(0);
        if bytes != src.bytes || file_hash(&path).map_err(|e| Error::Failed(format!("{}: {e}", path.display())))? != src.xxh3_128 {
            return Err(changed(&name.to_string(), &path));
        }
        files.push(Some(path));
    }
    Ok(files)
}

/// A setting the asset records (empty when it records none).
pub fn setting<'a>(meta: &'a Metadata, key: &str) -> &'a str {
    meta.settings.iter().find(|(k, _)| k == key).map_or("", |(_, v)| v.as_str())
}

/// The `--with` inputs an asset was cooked with, as written (its `with` setting).
pub fn with_inputs(meta: &Metadata) -> Result<Vec<String>> {
    match setting(meta, "with") {
        "" => Ok(Vec::new()),
        text => serde_json::from_str(text).map_err(|e| Error::Failed(format!("the asset's setting with = {text} is not a list of inputs: {e}"))),
    }
}

/// Each frame's `--with` files, `[frame][sequence]`, for an asset whose main
/// files are `files` ([`frame_files`]): the `with` inputs it records expanded
/// again from where its main files were found (over its recorded `frames`)
/// and matched as `cook` matched them, each checked against the record of
/// it among the asset's sources (every segment's: `meta` is the whole asset's). A file the asset does not
/// record was missing when it was cooked (`--allow-missing`): `None`.
pub fn with_files(meta: &Metadata, path: &Path, files: &[Option<PathBuf>]) -> Result<Vec<Vec<Option<PathBuf>>>> {
    let with = with_inputs(meta)?;
    let mut out: Vec<Vec<Option<PathBuf>>> = vec![Vec::with_capacity(with.len()); files.len()];
    if with.is_empty() {
        return Ok(out);
    }
    let name = path.display().to_string();
    // The directory the recorded paths are relative to: the current one, or the asset's.
    let base = meta.frames.iter().zip(files).find_map(|(fr, found)| {
        let recorded = Path::new(&meta.sources.get(fr.source? as usize)?.path);
        let found = found.as_deref()?;
        Some((found != recorded && recorded.is_relative()).then(|| path.parent().unwrap_or(Path::new("")).to_path_buf()))
    });
    let base = base.flatten();
    let frames = match setting(meta, "frames") {
        "" => None,
        t => Some(t.parse::<crate::FrameRange>().map_err(|e| Error::Failed(format!("{name}: its recorded frames: {e}")))?),
    };
    // The frames' numbers as cook matched them: from the main files' names (a frame without a file: its recorded number).
    let numbers: Option<Vec<i64>> = files.iter().enumerate().map(|(f, p)| p.as_deref().map_or(Some(meta.frame_number(f)), crate::inputs::number_in_name)).collect();
    let numbers = numbers.and_then(crate::inputs::if_distinct);
    // Every segment's sources, those no frame names included.
    let recorded = &meta.sources;
    for w in &with {
        let found = crate::inputs::match_with(files.len(), numbers.as_deref(), w, crate::inputs::expand_with(w, base.as_deref(), frames).with_context(|| format!("{name}: its recorded --with {w}"))?)?;
        for (slot, file) in out.iter_mut().zip(found) {
            let file = match file {
                Some(p) => {
                    let as_recorded = base.as_deref().and_then(|b| p.strip_prefix(b).ok()).unwrap_or(&p).display().to_string();
                    match recorded.iter().find(|s| s.path == as_recorded) {
                        None => None,
                        Some(_) if !p.is_file() => {
                            return Err(Error::Failed(format!(
                                "{name}: the recorded source {as_recorded} does not exist here (relative paths are looked up where the main files are); give the sources with --source and --with"
                            )));
                        }
                        Some(src) => {
                            let bytes = std::fs::metadata(&p).map(|m| m.len()).unwrap_or(0);
                            if bytes != src.bytes || file_hash(&p).map_err(|e| Error::Failed(format!("{}: {e}", p.display())))? != src.xxh3_128 {
                                return Err(changed(&name, &p));
                            }
                            Some(p)
                        }
                    }
                }
                None => None,
            };
            slot.push(file);
        }
    }
    Ok(out)
}

/// XXH3-128 of a file's bytes, hex (as recorded), read in chunks.
fn file_hash(path: &Path) -> std::io::Result<String> {
    use std::io::Read;
    let mut file = std::fs::File::open(path)?;
    let mut hasher = twox_hash::XxHash3_128::new();
    let mut buf = vec![0u8; 1 << 20];
    loop {
        let n = file.read(&mut buf)?;
        if n == 0 {
            return Ok(crate::grids::hash_hex(hasher.finish_128()));
        }
        hasher.write(&buf[..n]);
    }
}

fn changed(asset: &str, path: &Path) -> Error {
    Error::Failed(format!("{asset}: the recorded source {} changed since the cook (its bytes differ from those the asset records); cook again, or give the sources with --source", path.display()))
}

/// The asset of `validate`: the positional one, or, as a user may type
/// `validate --source SRC... ASSET`, the last of --source's values when it is an asset.
pub fn asset_and_sources(asset: Option<PathBuf>, mut source: Vec<String>) -> Result<(PathBuf, Vec<String>), String> {
    if let Some(a) = asset {
        return Ok((a, source));
    }
    match source.last() {
        Some(last) if last.ends_with(".vpak") || crate::is_vpak(Path::new(last)) => {
            let a = source.pop().map(PathBuf::from).unwrap_or_default();
            Ok((a, source))
        }
        _ => Err("the asset to validate is missing (usage: vdbcook validate ASSET.vpak [--source INPUT...])".into()),
    }
}

#[cfg(test)]
mod tests {
    use super::asset_and_sources;
    use std::path::PathBuf;

    #[test]
    fn the_asset_may_come_after_the_sources() {
        let v = |a: &[&str]| a.iter().map(|s| s.to_string()).collect::<Vec<_>>();
        assert_eq!(asset_and_sources(None, v(&["a.vdb", "x.vpak"])).unwrap(), (PathBuf::from("x.vpak"), v(&["a.vdb"])));
        assert_eq!(asset_and_sources(Some("y.vpak".into()), v(&["a.vdb"])).unwrap(), (PathBuf::from("y.vpak"), v(&["a.vdb"])));
        assert!(asset_and_sources(None, v(&["a.vdb"])).is_err());
        assert!(asset_and_sources(None, vec![]).is_err());
    }
}
