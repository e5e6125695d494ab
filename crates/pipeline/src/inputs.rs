//! Turning INPUT arguments into an ordered list of frame files.
//!
//! An INPUT is a file, a directory (every `.vdb` directly inside), a glob
//! (`smoke_*.vdb`), or a frame pattern (`smoke_####.vdb`, `smoke_%04d.vdb`,
//! `smoke_$F4.vdb`) expanded over `--frames A-B[:STEP]`.  Files, directories
//! and globs are put in natural order (`frame_2` before `frame_10`); pattern
//! frames keep the order of `--frames`.

use crate::{Context, Error, Result};
use std::cmp::Ordering;
use std::path::{Path, PathBuf};

pub use crate::options::FrameRange;

/// True when `input` is a frame pattern (and not an existing file or directory).
pub fn is_pattern(input: &str) -> bool {
    !Path::new(input).exists() && parse_pattern(input).is_some()
}

/// A frame pattern's pieces: prefix, zero-padded width, suffix.
fn parse_pattern(s: &str) -> Option<(String, usize, String)> {
    // ####
    if let Some(start) = s.find('#') {
        let width = s[start..].chars().take_while(|&c| c == '#').count();
        return Some((s[..start].to_string(), width, s[start + width..].to_string()));
    }
    // %04d, %4d, %d
    if let Some(start) = s.find('%') {
        let rest = &s[start + 1..];
        let digits: String = rest.chars().take_while(|c| c.is_ascii_digit()).collect();
        if rest[digits.len()..].starts_with('d') {
            let width = if digits.trim_start_matches('0').is_empty() { usize::from(!digits.is_empty()) } else { digits.trim_start_matches('0').parse().unwrap_or(usize::MAX) };
            return Some((s[..start].to_string(), width, rest[digits.len() + 1..].to_string()));
        }
    }
    // $F, $F4
    if let Some(start) = s.find("$F") {
        let rest = &s[start + 2..];
        let digits: String = rest.chars().take_while(|c| c.is_ascii_digit()).collect();
        let width = if digits.is_empty() { 0 } else { digits.parse().unwrap_or(usize::MAX) };
        return Some((s[..start].to_string(), width, rest[digits.len()..].to_string()));
    }
    None
}

fn format_frame(n: i64, width: usize) -> String {
    if n < 0 {
        format!("-{:0width$}", n.unsigned_abs(), width = width.saturating_sub(1))
    } else {
        format!("{n:0width$}")
    }
}

/// Widest zero padding a frame pattern may ask for.
const MAX_PAD: usize = 32;

/// Compares names the way people count: digit runs by value.
pub fn natural_cmp(a: &str, b: &str) -> Ordering {
    let (mut x, mut y) = (a.chars().peekable(), b.chars().peekable());
    loop {
        match (x.peek().copied(), y.peek().copied()) {
            (None, None) => return a.cmp(b),
            (None, Some(_)) => return Ordering::Less,
            (Some(_), None) => return Ordering::Greater,
            (Some(c), Some(d)) if c.is_ascii_digit() && d.is_ascii_digit() => {
                let mut n1 = String::new();
                while let Some(c) = x.next_if(|c| c.is_ascii_digit()) {
                    n1.push(c);
                }
                let mut n2 = String::new();
                while let Some(d) = y.next_if(|c| c.is_ascii_digit()) {
                    n2.push(d);
                }
                let (t1, t2) = (n1.trim_start_matches('0'), n2.trim_start_matches('0'));
                let o = t1.len().cmp(&t2.len()).then_with(|| t1.cmp(t2));
                if o != Ordering::Equal {
                    return o;
                }
            }
            (Some(c), Some(d)) => {
                if c != d {
                    return c.cmp(&d);
                }
                x.next();
                y.next();
            }
        }
    }
}

fn natural_sort(v: &mut [PathBuf]) {
    v.sort_by(|a, b| natural_cmp(&a.to_string_lossy(), &b.to_string_lossy()));
}

fn is_glob(s: &str) -> bool {
    s.contains(['*', '?', '['])
}

/// Expands INPUT arguments into frames, in order.
pub fn expand(inputs: &[String], frames: Option<FrameRange>) -> Result<Vec<PathBuf>> {
    let mut out = Vec::new();
    let mut plain: Vec<PathBuf> = Vec::new();
    let mut used_range = false;
    for input in inputs {
        let path = Path::new(input);
        if path.is_dir() {
            let mut found: Vec<PathBuf> = std::fs::read_dir(path)
                .with_context(|| format!("{input}: cannot list the directory"))?
                .flatten()
                .map(|e| e.path())
                .filter(|p| p.is_file() && p.extension().is_some_and(|x| x.eq_ignore_ascii_case("vdb")))
                .collect();
            if found.is_empty() {
                return Err(Error::Failed(format!("{input}: the directory holds no .vdb files")));
            }
            natural_sort(&mut found);
            plain.extend(found);
        } else if path.exists() {
            plain.push(path.to_path_buf());
        } else if let Some((pre, width, post)) = parse_pattern(input) {
            if width > MAX_PAD {
                return Err(Error::Usage(format!("{input}: a frame pattern pads to at most {MAX_PAD} digits")));
            }
            let Some(range) = frames else {
                return Err(Error::Usage(format!("{input}: a frame pattern needs --frames A-B[:STEP]")));
            };
            used_range = true;
            flush(&mut plain, &mut out);
            for n in range.frames() {
                out.push(PathBuf::from(format!("{pre}{}{post}", format_frame(n, width))));
            }
        } else if is_glob(input) {
            let mut found: Vec<PathBuf> = glob::glob(input).with_context(|| format!("{input}: invalid glob"))?.flatten().filter(|p| p.is_file()).collect();
            if found.is_empty() {
                return Err(Error::Failed(format!("{input}: no file matches")));
            }
            natural_sort(&mut found);
            plain.extend(found);
        } else {
            return Err(Error::Failed(format!("{input}: no such file or directory")));
        }
    }
    if frames.is_some() && !used_range {
        return Err(Error::Usage("--frames applies to frame patterns (smoke_####.vdb, smoke_%04d.vdb, smoke_$F4.vdb), and no INPUT is one".into()));
    }
    flush(&mut plain, &mut out);
    Ok(out)
}

/// The frame number a file's name carries: the last run of digits in its
/// stem (`fire_1001.vdb`: 1001; `smoke.0042.vdb`: 42), negative when a `-`
/// comes right before the digits and after something other than a letter or
/// digit (`smoke_-003.vdb`: -3; `fire-0012.vdb`: 12).
pub fn number_in_name(path: &Path) -> Option<i64> {
    let stem = path.file_stem()?.to_str()?;
    let b = stem.as_bytes();
    let end = b.iter().rposition(u8::is_ascii_digit)? + 1;
    let start = b[..end].iter().rposition(|c| !c.is_ascii_digit()).map_or(0, |i| i + 1);
    let n: i64 = stem[start..end].parse().ok()?;
    let signed = start >= 1 && b[start - 1] == b'-' && (start == 1 || !b[start - 2].is_ascii_alphanumeric());
    Some(if signed { -n } else { n })
}

/// The frames' numbers in their source sequence, from their file names
/// ([`number_in_name`]), when every name carries one and they increase
/// (else the frames are numbered from 0).
pub fn frame_numbers(files: &[PathBuf]) -> Option<Vec<i64>> {
    let numbers: Vec<i64> = files.iter().map(|f| number_in_name(f)).collect::<Option<_>>()?;
    numbers.windows(2).all(|w| w[0] < w[1]).then_some(numbers)
}

/// Expands one `--with` input (one sequence, in the forms INPUT takes): a
/// relative path is taken from `base` when one is given (a bake's manifest
/// directory); `--frames` applies when it is a frame pattern.
pub fn expand_with(input: &str, base: Option<&Path>, frames: Option<FrameRange>) -> Result<Vec<PathBuf>> {
    let joined = match base {
        Some(b) if Path::new(input).is_relative() => b.join(input).to_string_lossy().into_owned(),
        _ => input.to_string(),
    };
    let frames = if is_pattern(&joined) { frames } else { None };
    expand(&[joined], frames)
}

/// Expands the main INPUTs of a cook with `--with` inputs: `--frames`
/// applies to them when one is a frame pattern (it may be for a `--with`
/// input alone).
pub fn expand_main(inputs: &[String], with: &[String], frames: Option<FrameRange>) -> Result<Vec<PathBuf>> {
    if frames.is_some() && !inputs.iter().any(|i| is_pattern(i)) && with.iter().any(|w| is_pattern(w)) {
        return expand(inputs, None);
    }
    expand(inputs, frames)
}

/// Each frame's file in each `--with` sequence, `[frame][sequence]`: `with`
/// holds the inputs as written (relative ones taken from `base` when given),
/// matched to the main input's `files` by [`match_with`]. A frame whose file
/// a sequence lacks (or names but is not on disk) is an error naming both,
/// unless `allow_missing`: it then has none there (its channels from that
/// sequence are empty).
pub fn with_files(files: &[PathBuf], with: &[String], base: Option<&Path>, frames: Option<FrameRange>, allow_missing: bool) -> Result<Vec<Vec<Option<PathBuf>>>> {
    let mut out: Vec<Vec<Option<PathBuf>>> = vec![Vec::with_capacity(with.len()); files.len()];
    if with.is_empty() {
        return Ok(out);
    }
    let main_numbers = distinct_numbers(files);
    for w in with {
        let found = match_with(files.len(), main_numbers.as_deref(), w, expand_with(w, base, frames)?)?;
        for (f, (slot, file)) in out.iter_mut().zip(found).enumerate() {
            let file = match file {
                Some(p) if p.exists() => Some(p),
                _ if allow_missing => None,
                p => return Err(missing_with(f, main_numbers.as_ref().and_then(|n| n.get(f).copied()), &files[f], w, p.as_deref())),
            };
            slot.push(file);
        }
    }
    Ok(out)
}

/// The numbers in the names of a sequence's files, when every name carries
/// one and no two are the same (the frames can be matched by number).
pub fn distinct_numbers(files: &[PathBuf]) -> Option<Vec<i64>> {
    if_distinct(files.iter().map(|f| number_in_name(f)).collect::<Option<_>>()?)
}

/// `numbers`, when no two are the same.
pub fn if_distinct(numbers: Vec<i64>) -> Option<Vec<i64>> {
    let mut sorted = numbers.clone();
    sorted.sort_unstable();
    sorted.windows(2).all(|w| w[0] != w[1]).then_some(numbers)
}

/// The file of the `--with` sequence `name` (its files `files`) for each of
/// the main input's `frames` frames: the one whose name carries the frame's
/// number (`main_numbers`, when every main file's name has a distinct one),
/// else, when names carry no numbers, the one at the frame's position (the
/// counts must then be equal). `None` where the sequence has no file with the
/// frame's number; what a frame without its file becomes is the caller's to say.
pub fn match_with(frames: usize, main_numbers: Option<&[i64]>, name: &str, files: Vec<PathBuf>) -> Result<Vec<Option<PathBuf>>> {
    let numbered = main_numbers.filter(|m| m.len() == frames).and_then(|m| files.iter().map(|f| number_in_name(f)).collect::<Option<Vec<i64>>>().map(|n| (m, n)));
    let Some((main, numbers)) = numbered else {
        if files.len() != frames {
            return Err(Error::Failed(format!(
                "--with {name}: {} file(s) for the main input's {frames} frame(s) (file names without frame numbers are matched by position, so the counts must be equal)",
                files.len()
            )));
        }
        return Ok(files.into_iter().map(Some).collect());
    };
    let mut by_number: std::collections::BTreeMap<i64, PathBuf> = std::collections::BTreeMap::new();
    for (f, n) in files.into_iter().zip(numbers) {
        if let Some(other) = by_number.get(&n) {
            return Err(Error::Failed(format!("--with {name}: two files carry frame number {n} ({} and {})", other.display(), f.display())));
        }
        by_number.insert(n, f);
    }
    Ok(main.iter().map(|n| by_number.get(n).cloned()).collect())
}

/// The error for frame `frame` of the main input (`number`, its file `main`)
/// whose file in the `--with` sequence `name` is missing (`path`: the file
/// looked for, when the sequence names one).
pub fn missing_with(frame: usize, number: Option<i64>, main: &Path, name: &str, path: Option<&Path>) -> Error {
    let which = format!("frame {} ({})", number.unwrap_or(frame as i64), main.display());
    let why = match (path, number) {
        (Some(p), _) => format!("{} does not exist", p.display()),
        (None, Some(n)) => format!("no file of it carries frame number {n}"),
        (None, None) => "it has no file there".to_string(),
    };
    Error::Failed(format!("--with {name} has no file for {which}: {why}; --allow-missing cooks its channels empty in that frame"))
}

/// Moves the plain files gathered so far, in natural order, to the frame list.
fn flush(plain: &mut Vec<PathBuf>, out: &mut Vec<PathBuf>) {
    natural_sort(plain);
    out.append(plain);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_in_names() {
        let n = |s: &str| number_in_name(Path::new(s));
        assert_eq!(n("fire_1001.vdb"), Some(1001));
        assert_eq!(n("dir9/smoke.0042.vdb"), Some(42));
        assert_eq!(n("smoke_-003.vdb"), Some(-3));
        assert_eq!(n("fire-0012.vdb"), Some(12));
        assert_eq!(n("-7.vdb"), Some(-7));
        assert_eq!(n("cloud.vdb"), None);
        assert_eq!(n("a2_b.vdb"), Some(2));
        let files = |v: &[&str]| v.iter().map(PathBuf::from).collect::<Vec<_>>();
        assert_eq!(frame_numbers(&files(&["f_1001.vdb", "f_1004.vdb", "f_1007.vdb"])), Some(vec![1001, 1004, 1007]));
        assert_eq!(frame_numbers(&files(&["a_1.vdb", "b_1.vdb"])), None, "numbers that do not increase");
        assert_eq!(frame_numbers(&files(&["f_1.vdb", "g.vdb"])), None, "a name without a number");
    }

    #[test]
    fn with_sequences_match_by_number_else_by_position() {
        let files = |v: &[&str]| v.iter().map(PathBuf::from).collect::<Vec<_>>();
        let main = files(&["n/noise_0001.vdb", "n/noise_0002.vdb", "n/noise_0004.vdb"]);
        let numbers = distinct_numbers(&main);
        assert_eq!(numbers, Some(vec![1, 2, 4]));
        // By number: extra files are not read; a number without a file is None.
        let m = match_with(3, numbers.as_deref(), "d", files(&["d/data_0004.vdb", "d/data_0001.vdb", "d/data_0003.vdb"])).unwrap();
        assert_eq!(m, vec![Some(PathBuf::from("d/data_0001.vdb")), None, Some(PathBuf::from("d/data_0004.vdb"))]);
        let twice = match_with(3, numbers.as_deref(), "d", files(&["d/a_1.vdb", "e/b_1.vdb"])).unwrap_err().to_string();
        assert!(twice.contains("two files carry frame number 1"), "{twice}");
        // Names without numbers on either side: by position, counts equal.
        let m = match_with(3, numbers.as_deref(), "v", files(&["v/x.vdb", "v/y.vdb", "v/z.vdb"])).unwrap();
        assert_eq!(m[2], Some(PathBuf::from("v/z.vdb")));
        assert!(match_with(3, None, "v", files(&["v/a_1.vdb", "v/a_2.vdb"])).unwrap_err().to_string().contains("by position"));
        assert_eq!(distinct_numbers(&files(&["a_1.vdb", "b_1.vdb"])), None);
        let e = missing_with(1, Some(2), Path::new("n/noise_0002.vdb"), "d/data_####.vdb", Some(Path::new("d/data_0002.vdb"))).to_string();
        assert_eq!(e, "--with d/data_####.vdb has no file for frame 2 (n/noise_0002.vdb): d/data_0002.vdb does not exist; --allow-missing cooks its channels empty in that frame");
    }

    #[test]
    fn natural_order() {
        let mut v: Vec<PathBuf> = ["f_10.vdb", "f_2.vdb", "f_1.vdb", "g.vdb", "f_02.vdb"].iter().map(PathBuf::from).collect();
        natural_sort(&mut v);
        let names: Vec<String> = v.iter().map(|p| p.display().to_string()).collect();
        assert_eq!(names, ["f_1.vdb", "f_02.vdb", "f_2.vdb", "f_10.vdb", "g.vdb"]);
    }

    #[test]
    fn frame_ranges() {
        assert_eq!("1-120:2".parse::<FrameRange>().unwrap(), FrameRange { first: 1, last: 120, step: 2 });
        assert_eq!("5".parse::<FrameRange>().unwrap(), FrameRange { first: 5, last: 5, step: 1 });
        assert_eq!("-3-2".parse::<FrameRange>().unwrap().frames().collect::<Vec<_>>(), vec![-3, -2, -1, 0, 1, 2]);
        assert!("9-1".parse::<FrameRange>().is_err());
        assert!("1-9:0".parse::<FrameRange>().is_err());
        assert!("a-b".parse::<FrameRange>().is_err());
        // Ranges whose length overflows i64 are refused, not wrapped.
        assert!("-9223372036854775808-9223372036854775807".parse::<FrameRange>().is_err());
        assert_eq!(format_frame(i64::MIN, 3), "-9223372036854775808");
    }

    #[test]
    fn patterns() {
        let r = Some("8-10".parse().unwrap());
        for (p, want) in [("s_####.vdb", "s_0009.vdb"), ("s_%04d.vdb", "s_0009.vdb"), ("s_%d.vdb", "s_9.vdb"), ("s_$F4.vdb", "s_0009.vdb"), ("s_$F.vdb", "s_9.vdb")] {
            let f = expand(&[p.to_string()], r).unwrap();
            assert_eq!(f.len(), 3);
            assert_eq!(f[1], PathBuf::from(want), "{p}");
        }
        assert!(expand(&["s_####.vdb".into()], None).is_err());
        assert!(expand(&["s_%70000d.vdb".into()], r).is_err());
        assert!(expand(&["s_$F99999999999999999999.vdb".into()], r).is_err());
    }
}
