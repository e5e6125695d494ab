//! `bake.toml`: a `[defaults]` table and `[[asset]]` entries, and the plan
//! built from them. Every error carries the byte span it is about; the caller
//! turns it into `FILE:LINE:COLUMN: message` with [`line_column`].

use crate::key::{cache_key, FileDigest, KeyContext};
use crate::options::CookSettings;
use crate::table::{AssetTable, SettingsTable};
use std::ops::Range;
use std::path::{Component, Path, PathBuf};
use toml::Spanned;

/// A problem with the manifest, at a byte span of its text.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ManifestError {
    pub span: Range<usize>,
    pub message: String,
}

impl ManifestError {
    fn at(span: Range<usize>, message: impl Into<String>) -> ManifestError {
        ManifestError { span, message: message.into() }
    }

    /// "LINE:COLUMN: message" for the manifest `text`.
    pub fn located(&self, text: &str) -> String {
        let (l, c) = line_column(text, self.span.start);
        format!("{l}:{c}: {}", self.message)
    }
}

/// 1-based line and column (in characters) of byte `offset` of `text`.
pub fn line_column(text: &str, offset: usize) -> (usize, usize) {
    let mut offset = offset.min(text.len());
    while !text.is_char_boundary(offset) {
        offset -= 1;
    }
    let before = &text[..offset];
    let line = before.matches('\n').count() + 1;
    let col = before.rsplit('\n').next().map_or(0, |l| l.chars().count()) + 1;
    (line, col)
}

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct File {
    #[serde(default)]
    defaults: Option<Spanned<SettingsTable>>,
    #[serde(default)]
    asset: Vec<Spanned<AssetTable>>,
}

/// A parsed manifest (types checked, nothing on disk looked at yet).
pub struct Manifest {
    text: String,
    pub defaults: SettingsTable,
    pub assets: Vec<Spanned<AssetTable>>,
}

impl Manifest {
    pub fn parse(text: &str) -> Result<Manifest, ManifestError> {
        let file: File = toml::from_str(text).map_err(|e| {
            let message = e.message().trim().replace('\n', " ");
            ManifestError::at(e.span().unwrap_or(0..0), message)
        })?;
        if file.asset.is_empty() {
            return Err(ManifestError::at(0..0, "the manifest has no [[asset]] entries (expected at least one, with name, output and inputs)"));
        }
        Ok(Manifest { text: text.to_string(), defaults: file.defaults.map(|d| d.into_inner()).unwrap_or_default(), assets: file.asset })
    }
}

/// What the planner needs from the file system (the caller's I/O).
pub trait Sources {
    /// The files `inputs` name (paths already joined to the manifest's
    /// directory), in cook order; an error says what is wrong.
    fn expand(&self, inputs: &[String], frames: Option<crate::FrameRange>) -> Result<Vec<PathBuf>, String>;
    /// Whether `input` is a frame pattern (expanded over `frames`).
    fn is_pattern(&self, input: &str) -> bool;
    /// A file's bytes; `Ok(None)` when it does not exist.
    fn read(&self, path: &Path) -> std::io::Result<Option<Vec<u8>>>;
}

/// One asset of the plan.
#[derive(Clone, Debug)]
pub struct PlannedAsset {
    /// Position in the manifest, from 0.
    pub index: usize,
    pub name: String,
    /// As written: relative to the output directory (or absolute).
    pub output: String,
    /// As written: relative to the manifest's directory (or absolute).
    pub inputs: Vec<String>,
    /// The inputs joined to the manifest's directory (what the cooker expands).
    pub input_paths: Vec<String>,
    /// Every input file, in cook order, as the cooker will read it.
    pub files: Vec<PathBuf>,
    /// The files of the `with` sequences the cook reads besides (each
    /// sequence's, in frame order; the cook matches them to `files` again).
    pub with_files: Vec<PathBuf>,
    pub settings: CookSettings,
    /// `parts = N`: cooked as N part units, joined into the asset (see [`crate::parts`]).
    pub parts: Option<u32>,
    pub key: String,
}

/// A name usable on a command line and in file names.
fn valid_name(n: &str) -> bool {
    !n.is_empty() && n.len() <= 128 && !n.starts_with(['.', '-']) && n.chars().all(|c| c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.'))
}

/// `p` without `.` components and with `..` applied where it can be (no file system access).
pub fn normalize(p: &Path) -> PathBuf {
    let mut out = PathBuf::new();
    for c in p.components() {
        match c {
            Component::CurDir => {}
            Component::ParentDir if matches!(out.components().next_back(), Some(Component::Normal(_))) => {
                out.pop();
            }
            c => out.push(c),
        }
    }
    out
}

/// A path written in the manifest, relative to `base` unless absolute.
pub fn resolve(base: &Path, written: &str) -> PathBuf {
    let p = Path::new(written);
    if p.is_absolute() {
        p.to_path_buf()
    } else {
        base.join(p)
    }
}

/// Settles every asset's settings, checks names, outputs and inputs, reads every
/// input file and computes the keys. `base` is the manifest's directory.
pub fn plan(m: &Manifest, base: &Path, sources: &dyn Sources, ctx: &KeyContext) -> Result<Vec<PlannedAsset>, ManifestError> {
    let mut out: Vec<PlannedAsset> = Vec::new();
    let mut seen_outputs: Vec<(PathBuf, Range<usize>)> = Vec::new();
    for (index, entry) in m.assets.iter().enumerate() {
        let (table_span, a) = (entry.span(), entry.get_ref());
        let name = a.name.get_ref().clone();
        if !valid_name(&name) {
            return Err(ManifestError::at(a.name.span(), format!("invalid asset name \"{name}\" (expected letters, digits, '_', '-' and '.', not starting with '.' or '-')")));
        }
        if let Some(first) = out.iter().find(|p| p.name == name) {
            let first_span = m.assets[first.index].get_ref().name.span();
            return Err(ManifestError::at(a.name.span(), format!("duplicate asset name \"{name}\" (expected each name once; the first is on line {})", line_column(&m.text, first_span.start).0)));
        }
        let output = a.output.get_ref().clone();
        if output.trim().is_empty() {
            return Err(ManifestError::at(a.output.span(), "empty output (expected a path such as \"smoke.vpak\")"));
        }
        let norm = normalize(Path::new(&output));
        if seen_outputs.iter().any(|(o, _)| *o == norm) {
            return Err(ManifestError::at(a.output.span(), format!("duplicate output \"{output}\" (expected each asset to write its own file)")));
        }
        seen_outputs.push((norm, a.output.span()));

        let mut settings = CookSettings::default();
        m.defaults.apply(&mut settings);
        a.settings.apply(&mut settings);
        if let Err(crate::options::SettingError { name: key, message }) = settings.check() {
            let span = a.settings.span(key).or_else(|| m.defaults.span(key)).unwrap_or(table_span.clone());
            return Err(ManifestError::at(span, format!("{key}: {message}")));
        }

        let inputs: Vec<&Spanned<String>> = a.inputs.get_ref().iter().collect();
        if inputs.is_empty() {
            return Err(ManifestError::at(a.inputs.span(), "empty inputs (expected at least one file, directory, glob or frame pattern)"));
        }
        let input_paths: Vec<String> = inputs.iter().map(|i| resolve(base, i.get_ref()).to_string_lossy().into_owned()).collect();
        let frames = settings.frames;
        let with_paths: Vec<String> = settings.with.iter().map(|w| resolve(base, w).to_string_lossy().into_owned()).collect();
        let main_pattern = input_paths.iter().any(|i| sources.is_pattern(i));
        if frames.is_some() && !main_pattern && !with_paths.iter().any(|i| sources.is_pattern(i)) {
            let span = a.settings.span("frames").or_else(|| m.defaults.span("frames")).unwrap_or(table_span.clone());
            return Err(ManifestError::at(span, "frames applies to frame patterns (smoke_####.vdb, smoke_%04d.vdb, smoke_$F4.vdb), and no input is one"));
        }
        // Each input on its own first, so that an error points at it.
        let mut owner: Vec<(PathBuf, usize)> = Vec::new();
        for (k, (i, p)) in inputs.iter().zip(&input_paths).enumerate() {
            let f = if sources.is_pattern(p) { frames } else { None };
            let files = sources.expand(std::slice::from_ref(p), f).map_err(|e| ManifestError::at(i.span(), format!("input \"{}\": {e}", i.get_ref())))?;
            owner.extend(files.into_iter().map(|f| (f, k)));
        }
        let files = sources.expand(&input_paths, if main_pattern { frames } else { None }).map_err(|e| ManifestError::at(a.inputs.span(), e))?;
        let mut digests = Vec::with_capacity(files.len());
        for f in &files {
            let span = owner.iter().find(|(p, _)| p == f).map_or(a.inputs.span(), |(_, k)| inputs[*k].span());
            let bytes = sources.read(f).map_err(|e| ManifestError::at(span.clone(), format!("{}: {e}", f.display())))?;
            if bytes.is_none() && !settings.allow_missing {
                return Err(ManifestError::at(span, format!("{}: no such file (expected an existing input, or allow_missing = true)", f.display())));
            }
            let rel = f.strip_prefix(base).unwrap_or(f).to_string_lossy().into_owned();
            digests.push(FileDigest::of(rel, bytes.as_deref()));
        }
        let with_files = with_digests(m, a, base, sources, &settings, &with_paths, &files, &mut digests)?;
        let parts = check_parts(m, a, &settings, files.len())?;
        let written: Vec<String> = inputs.iter().map(|i| i.get_ref().clone()).collect();
        // The same key with or without parts: the joined asset is the unsplit one, byte for byte.
        let key = cache_key(ctx, &settings, &written, &digests);
        out.push(PlannedAsset { index, name, output, inputs: written, input_paths, files, with_files, settings, parts, key });
    }
    Ok(out)
}

/// Appends the digests of each frame's `with` files (`with_paths`: the
/// `with` inputs joined to the manifest's directory), sequence after
/// sequence, matched to the main `files` as `cook --with` matches them; a
/// frame without its file is an error unless `allow_missing`. Returns the
/// files found.
#[allow(clippy::too_many_arguments)]
fn with_digests(
    m: &Manifest,
    a: &AssetTable,
    base: &Path,
    sources: &dyn Sources,
    settings: &CookSettings,
    with_paths: &[String],
    files: &[PathBuf],
    digests: &mut Vec<FileDigest>,
) -> Result<Vec<PathBuf>, ManifestError> {
    use vdbcook_pipeline::inputs::{distinct_numbers, match_with, missing_with};
    let span = a.settings.span("with").or_else(|| m.defaults.span("with")).unwrap_or(a.inputs.span());
    let at = |message: String| ManifestError::at(span.clone(), message);
    // The pipeline's messages name the flags; a manifest has keys.
    let keys = |e: &vdbcook_pipeline::Error| vdbcook_pipeline::one_line(e).replacen("--with ", "with ", 1).replace("--allow-missing", "allow_missing = true");
    let main_numbers = distinct_numbers(files);
    let mut read = Vec::new();
    for (w, p) in settings.with.iter().zip(with_paths) {
        let f = if sources.is_pattern(p) { settings.frames } else { None };
        let seq = sources.expand(std::slice::from_ref(p), f).map_err(|e| at(format!("with \"{w}\": {e}")))?;
        let found = match_with(files.len(), main_numbers.as_deref(), w, seq).map_err(|e| at(keys(&e)))?;
        for (frame, file) in found.into_iter().enumerate() {
            let bytes = match &file {
                Some(f) => sources.read(f).map_err(|e| at(format!("{}: {e}", f.display())))?,
                None => None,
            };
            if bytes.is_none() && !settings.allow_missing {
                let number = main_numbers.as_ref().and_then(|n| n.get(frame).copied());
                let main = files.get(frame).map_or(Path::new(""), PathBuf::as_path);
                return Err(at(keys(&missing_with(frame, number, main, w, file.as_deref()))));
            }
            let rel = file.as_deref().map_or_else(String::new, |f| f.strip_prefix(base).unwrap_or(f).to_string_lossy().into_owned());
            digests.push(FileDigest::of(rel, bytes.as_deref()));
            read.extend(file.filter(|_| bytes.is_some()));
        }
    }
    Ok(read)
}

/// The largest `parts` (a sanity bound: a part is a CI job).
pub const MAX_PARTS: u32 = 1024;

/// `parts = N` of an asset of `frames` files: 2 to [`MAX_PARTS`], with
/// `segment_frames` (parts share segments) and at least N segments, and
/// without `validate` (it decides over the whole asset: validate the joined one).
fn check_parts(m: &Manifest, a: &AssetTable, s: &CookSettings, frames: usize) -> Result<Option<u32>, ManifestError> {
    let Some(p) = &a.parts else { return Ok(None) };
    let (n, span) = (*p.get_ref(), p.span());
    let err = |message: String| Err(ManifestError::at(span.clone(), format!("parts: {message}")));
    if !(2..=MAX_PARTS).contains(&n) {
        return err(format!("{n} is not in 2..={MAX_PARTS}"));
    }
    let Some(seg) = s.segment_frames else {
        return err("needs segment_frames (the parts are groups of the asset's segments, e.g. segment_frames = 24)".into());
    };
    if s.validate {
        let at = a.settings.span("validate").or_else(|| m.defaults.span("validate")).unwrap_or(span.clone());
        return Err(ManifestError::at(at, "validate: decides over the whole asset, so an asset cooked in parts takes none (validate = false; `vdbcook validate` the joined asset)"));
    }
    let segments = frames.div_ceil(seg.get() as usize);
    if n as usize > segments {
        return err(format!("{n} parts of {segments} segment(s) ({frames} frames, segment_frames = {}): expected at most one part per segment", seg.get()));
    }
    Ok(Some(n))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::BTreeMap;

    /// Files in memory; patterns are `#` runs, expanded over frames.
    struct Mem(BTreeMap<String, Vec<u8>>);

    impl Sources for Mem {
        fn expand(&self, inputs: &[String], frames: Option<crate::FrameRange>) -> Result<Vec<PathBuf>, String> {
            let mut out = Vec::new();
            for i in inputs {
                if let (true, Some(r)) = (self.is_pattern(i), frames) {
                    out.extend(r.frames().map(|n| PathBuf::from(i.replace('#', &n.to_string()))));
                } else if self.0.contains_key(i) {
                    out.push(PathBuf::from(i));
                } else {
                    return Err(format!("{i}: no such file or directory"));
                }
            }
            Ok(out)
        }
        fn is_pattern(&self, input: &str) -> bool {
            input.contains('#')
        }
        fn read(&self, path: &Path) -> std::io::Result<Option<Vec<u8>>> {
            Ok(self.0.get(&path.to_string_lossy().into_owned()).cloned())
        }
    }

    fn mem() -> Mem {
        Mem([("p/a.vdb", "A"), ("p/b.vdb", "B"), ("p/s1.vdb", "1"), ("p/s2.vdb", "2")].into_iter().map(|(k, v)| (k.to_string(), v.as_bytes().to_vec())).collect())
    }

    fn run(text: &str) -> Result<Vec<PlannedAsset>, String> {
        let m = Manifest::parse(text).map_err(|e| e.located(text))?;
        plan(&m, Path::new("p"), &mem(), &KeyContext::new("vdbcook test".into())).map_err(|e| e.located(text))
    }

    const GOOD: &str = "[defaults]\nformat = \"bc7\"\nquality = \"fast\"\n\n[[asset]]\nname = \"a\"\noutput = \"a.vpak\"\ninputs = [\"a.vdb\"]\n\n[[asset]]\nname = \"s\"\noutput = \"out/s.vpak\"\ninputs = [\"s#.vdb\"]\nframes = \"1-2\"\nformat = \"f16\"\nclusters = 4\n";

    #[test]
    fn defaults_then_the_asset_then_built_in() {
        let p = run(GOOD).unwrap();
        assert_eq!(p.len(), 2);
        assert_eq!(p[0].settings.format, crate::options::Format::Bc7);
        assert_eq!(p[0].settings.quality, crate::options::Quality::Fast);
        assert_eq!(p[1].settings.format, crate::options::Format::F16);
        assert_eq!(p[1].settings.clusters.map(crate::options::Clusters::get), Some(4));
        assert_eq!(p[1].settings.iterations, CookSettings::default().iterations);
        assert_eq!(p[1].files, [PathBuf::from("p/s1.vdb"), PathBuf::from("p/s2.vdb")]);
        // The comparison's settings are keys like any other.
        let q = run(&GOOD.replace("clusters = 4", "views = 3\nmax_rmse = 0.5")).unwrap();
        assert_eq!((q[1].settings.viewing.views.get(), q[1].settings.gate.max_rmse.map(|x| x.get())), (3, Some(0.5)));
        assert_eq!(q[0].settings.viewing, crate::options::Viewing::default());
        assert_ne!(p[0].key, p[1].key);
        assert_eq!(run(GOOD).unwrap()[1].key, p[1].key);
    }

    #[test]
    fn errors_point_at_line_and_column() {
        let cases = [
            (GOOD.replace("clusters = 4", "clustres = 4"), "16:1: unknown field `clustres`"),
            (GOOD.replace("clusters = 4", "clusters = \"4\""), "16:12: clusters: invalid type: string \"4\", expected u32"),
            (GOOD.replace("\"bc7\"", "\"bc9\""), "2:10: format: unknown variant `bc9`"),
            (GOOD.replace("[\"a.vdb\"]", "[\"a.vdb\", \"nope.vdb\"]"), "8:20: input \"nope.vdb\": p/nope.vdb: no such file"),
            (GOOD.replace("out/s.vpak", "./a.vpak"), "12:10: duplicate output \"./a.vpak\""),
            (GOOD.replace("name = \"s\"", "name = \"a\""), "11:8: duplicate asset name \"a\""),
            (GOOD.replace("frames = \"1-2\"", "frames = \"1-3\""), "13:11: p/s3.vdb: no such file"),
            (GOOD.replace("clusters = 4", "variance_threshold = -1.0"), "16:22: variance_threshold: must be a number >= 0"),
            (GOOD.replace("frames = \"1-2\"", "frames = \"2-1\""), "14:10: frames: invalid frame range \"2-1\""),
            (GOOD.replace("clusters = 4", "views = 0"), "16:9: views: 0 is not a view count (expected 1 to 360)"),
            (GOOD.replace("clusters = 4", "lods = 6"), "16:8: lods: 6 is more levels than the tree has"),
            (GOOD.replace("quality = \"fast\"", "size = \"4x4\""), "3:8: size: invalid size \"4x4\""),
            (GOOD.replace("name = \"s\"\n", ""), "missing field `name`"),
        ];
        for (text, want) in cases {
            let e = run(&text).unwrap_err();
            assert!(e.starts_with(want) || (!want.starts_with(char::is_numeric) && e.contains(want)), "{e:?} does not start with {want:?}");
            assert!(!e.contains('\n'), "{e:?}");
        }
        assert!(run("").unwrap_err().contains("no [[asset]]"));
    }

    #[test]
    fn missing_files_are_allowed_when_asked() {
        let text = GOOD.replace("frames = \"1-2\"", "frames = \"1-3\"\nallow_missing = true");
        let p = run(&text).unwrap();
        assert_eq!(p[1].files.len(), 3);
    }

    #[test]
    fn parts_need_segments_and_no_validation() {
        let seg = |extra: &str| GOOD.replace("clusters = 4", &format!("segment_frames = 1\n{extra}"));
        let p = run(&seg("parts = 2")).unwrap();
        assert_eq!((p[0].parts, p[1].parts), (None, Some(2)));
        // The parts are not in the key: the joined asset is the unsplit one.
        let whole = run(&seg("")).unwrap();
        assert_eq!((p[0].key.as_str(), p[1].key.as_str()), (whole[0].key.as_str(), whole[1].key.as_str()));
        let cases = [
            (GOOD.replace("clusters = 4", "parts = 2"), "16:9: parts: needs segment_frames"),
            (seg("parts = 1"), "17:9: parts: 1 is not in 2..=1024"),
            (seg("parts = 3"), "17:9: parts: 3 parts of 2 segment(s)"),
            (seg("parts = -1"), "parts: invalid value"),
            (seg("parts = 2\nvalidate = true"), "18:12: validate: decides over the whole asset"),
            (seg("parts = 2").replace("quality = \"fast\"", "validate = true"), "3:12: validate: decides over the whole asset"),
            (GOOD.replace("format = \"bc7\"", "parts = 2"), "unknown field `parts`"),
        ];
        for (text, want) in cases {
            let e = run(&text).unwrap_err();
            assert!(e.starts_with(want) || (!want.starts_with(char::is_numeric) && e.contains(want)), "{e:?} does not start with {want:?}");
        }
    }

    #[test]
    fn with_files_are_matched_and_keyed() {
        let text = GOOD.replace("clusters = 4", "with = [\"w#.vdb\"]\ngrids = \"density@0,vel\"");
        let mut files = mem();
        files.0.insert("p/w1.vdb".into(), b"W1".to_vec());
        files.0.insert("p/w2.vdb".into(), b"W2".to_vec());
        let plan_with = |f: &Mem, text: &str| plan(&Manifest::parse(text).unwrap(), Path::new("p"), f, &KeyContext::new("vdbcook test".into())).map_err(|e| e.located(text));
        let key = plan_with(&files, &text).unwrap()[1].key.clone();
        files.0.insert("p/w2.vdb".into(), b"W2'".to_vec());
        assert_ne!(plan_with(&files, &text).unwrap()[1].key, key, "a with file's bytes are in the key");
        files.0.remove("p/w2.vdb");
        let e = plan_with(&files, &text).unwrap_err();
        assert!(e.starts_with("16:8: with w#.vdb has no file for frame 2") && e.contains("allow_missing = true"), "{e}");
        let allowed = text.replace("frames = \"1-2\"", "frames = \"1-2\"\nallow_missing = true");
        assert_ne!(plan_with(&files, &allowed).unwrap()[1].key, key);
        // frames may apply to a with pattern alone.
        let e = plan_with(&mem(), &GOOD.replace("inputs = [\"s#.vdb\"]", "inputs = [\"s1.vdb\", \"s2.vdb\"]").replace("clusters = 4", "with = [\"w#.vdb\"]")).unwrap_err();
        assert!(e.contains("p/w1.vdb: no such file") || e.contains("with w#.vdb has no file"), "{e}");
    }

    #[test]
    fn line_columns() {
        assert_eq!(line_column("ab\ncd", 0), (1, 1));
        assert_eq!(line_column("ab\ncd", 4), (2, 2));
        assert_eq!(line_column("é\nx", 3), (2, 1));
    }
}
