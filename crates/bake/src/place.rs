//! Where a bake may write. A manifest may come from someone else (a pull
//! request in CI), so its outputs stay inside `--out-dir` unless the person
//! running the bake says otherwise, and what is already at a path the bake
//! writes is replaced only when it is the bake's own kind of file.
//!
//! This module looks at the file system (metadata, symbolic links, a file's
//! first bytes); it never writes.

use crate::manifest::{normalize, Manifest, ManifestError, PlannedAsset};
use std::io::Read;
use std::path::{Component, Path, PathBuf};

/// `path` as the operating system will reach it: the longest prefix that
/// exists with its symbolic links and `..` resolved (canonicalized), the rest
/// (which does not exist yet) applied lexically. Relative paths are taken from
/// the current directory.
pub fn resolved(path: &Path) -> PathBuf {
    let path = if path.as_os_str().is_empty() { Path::new(".") } else { path };
    let abs = if path.is_absolute() { path.to_path_buf() } else { std::env::current_dir().map_or_else(|_| path.to_path_buf(), |d| d.join(path)) };
    let parts: Vec<Component> = abs.components().collect();
    for k in (1..=parts.len()).rev() {
        let prefix: PathBuf = parts[..k].iter().collect();
        if let Ok(mut out) = std::fs::canonicalize(&prefix) {
            for c in &parts[k..] {
                match c {
                    Component::CurDir => {}
                    Component::ParentDir => {
                        out.pop();
                    }
                    c => out.push(c),
                }
            }
            return out;
        }
    }
    normalize(&abs)
}

/// Why the manifest's `output` may not be written below `out_dir`, if it may not.
pub fn outside(out_dir: &Path, output: &str) -> Option<String> {
    if Path::new(output).has_root() {
        return Some(format!("output \"{output}\" is an absolute path (expected a path relative to --out-dir, or --allow-outside)"));
    }
    let root = resolved(out_dir);
    let target = resolved(&out_dir.join(output));
    if target == root || !target.starts_with(&root) {
        let how = if Path::new(output).components().any(|c| c == Component::ParentDir) { "through '..'" } else { "through a symbolic link" };
        let how = if target == root { "is the directory itself" } else { how };
        return Some(format!(
            "output \"{output}\" leaves the output directory {how} (it resolves to {}, not inside {}; expected a path inside --out-dir, or --allow-outside)",
            target.display(),
            root.display()
        ));
    }
    None
}

/// Checks that every planned output stays inside `out_dir` (after `..` and
/// symbolic links): the first that does not is an error at its `output`.
pub fn check_outputs(m: &Manifest, planned: &[PlannedAsset], out_dir: &Path) -> Result<(), ManifestError> {
    for a in planned {
        if let Some(message) = outside(out_dir, &a.output) {
            let span = m.assets.get(a.index).map_or(0..0, |e| e.get_ref().output.span());
            return Err(ManifestError { span, message });
        }
    }
    Ok(())
}

/// What is at a path the bake is about to write.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Existing {
    Nothing,
    /// A file (or a link to one) that starts with the .vpak magic (or a part file's).
    Vpak,
    /// Anything else: a file of another kind, a directory, a dangling link.
    Other,
}

/// Whether `path` holds nothing, a .vpak, or something else (its first 8 bytes decide).
pub fn existing(path: &Path) -> std::io::Result<Existing> {
    match std::fs::symlink_metadata(path) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Existing::Nothing),
        Err(e) => return Err(e),
        Ok(_) => {}
    }
    if !path.is_file() {
        return Ok(Existing::Other);
    }
    let mut head = [0u8; 8];
    let f = std::fs::File::open(path)?;
    let n = f.take(8).read(&mut head)?;
    Ok(if n == 8 && (head == vdbcook_vpak::MAGIC || head == vdbcook_vpak::segments::PART_MAGIC) { Existing::Vpak } else { Existing::Other })
}

/// Err with a one-line reason when an asset may not be written at `path`:
/// something other than a .vpak is there and `force` is off.
pub fn may_replace(path: &Path, force: bool) -> Result<(), String> {
    match existing(path) {
        Ok(Existing::Nothing | Existing::Vpak) => Ok(()),
        Ok(Existing::Other) if force => Ok(()),
        Ok(Existing::Other) => Err(format!("{} already exists and is not a .vpak asset (left as it is; --force replaces it)", path.display())),
        Err(e) => Err(format!("{}: {e}", path.display())),
    }
}

/// Err with a one-line reason when a report file may not be written at
/// `path`: something is there that is not an earlier bake report (its first
/// 512 bytes name vdbcook) and `force` is off.
pub fn may_replace_report(path: &Path, force: bool) -> Result<(), String> {
    let ours = || -> std::io::Result<bool> {
        let mut head = Vec::new();
        std::fs::File::open(path)?.take(512).read_to_end(&mut head)?;
        Ok(head.windows(7).any(|w| w == b"vdbcook"))
    };
    match existing(path) {
        Ok(Existing::Nothing) => Ok(()),
        _ if force => Ok(()),
        Ok(_) if path.is_file() && ours().unwrap_or(false) => Ok(()),
        Ok(_) => Err(format!("{} already exists and is not a vdbcook bake report (left as it is; --force replaces it)", path.display())),
        Err(e) => Err(format!("{}: {e}", path.display())),
    }
}

/// A directory the bake writes into (`what` names the flag): a file there is an error.
pub fn check_dir(dir: &Path, what: &str) -> Result<(), String> {
    match std::fs::metadata(dir) {
        Ok(m) if !m.is_dir() => Err(format!("{what} {}: not a directory", dir.display())),
        _ => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tmp(tag: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("vdbcook-bake-place-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn outputs_stay_inside_the_out_dir() {
        let d = tmp("inside");
        let out = d.join("out");
        std::fs::create_dir_all(out.join("sub")).unwrap();
        std::fs::create_dir_all(d.join("elsewhere")).unwrap();
        for ok in ["a.vpak", "sub/a.vpak", "new/deeper/a.vpak", "sub/../a.vpak", "./x/../y/a.vpak", "new/../a.vpak"] {
            assert_eq!(outside(&out, ok), None, "{ok}");
        }
        let abs = d.join("elsewhere/victim.txt");
        for (bad, says) in [
            (abs.to_str().unwrap(), "absolute"),
            ("../escape.vpak", "through '..'"),
            ("sub/../../escape.vpak", "through '..'"),
            ("new/../../escape.vpak", "through '..'"),
            (".", "the directory itself"),
        ] {
            let e = outside(&out, bad).unwrap_or_else(|| panic!("{bad} is outside"));
            assert!(e.contains(says) && e.contains("--allow-outside") && !e.contains('\n'), "{bad}: {e}");
        }
        #[cfg(unix)]
        {
            std::fs::write(&abs, "precious").unwrap();
            std::os::unix::fs::symlink(d.join("elsewhere"), out.join("link")).unwrap();
            std::os::unix::fs::symlink(d.join("elsewhere/victim.txt"), out.join("file_link.vpak")).unwrap();
            std::os::unix::fs::symlink(out.join("sub"), out.join("inner")).unwrap();
            for bad in ["link/a.vpak", "link/new/a.vpak", "file_link.vpak", "inner/../../escape.vpak"] {
                let e = outside(&out, bad).unwrap_or_else(|| panic!("{bad} is outside"));
                assert!(e.contains("leaves the output directory"), "{bad}: {e}");
            }
            assert_eq!(outside(&out, "inner/a.vpak"), None, "a link that stays inside is fine");
            // The out dir itself through a link: judged by where it leads.
            std::os::unix::fs::symlink(&out, d.join("out_link")).unwrap();
            assert_eq!(outside(&d.join("out_link"), "a.vpak"), None);
            assert!(outside(&d.join("out_link"), "../elsewhere/a.vpak").is_some());
        }
        let _ = std::fs::remove_dir_all(&d);
    }

    #[test]
    fn only_a_vpak_is_replaced_without_force() {
        let d = tmp("replace");
        let (vpak, text, dir) = (d.join("a.vpak"), d.join("victim.txt"), d.join("dir.vpak"));
        let mut bytes = vdbcook_vpak::MAGIC.to_vec();
        bytes.extend([0; 8]);
        std::fs::write(&vpak, bytes).unwrap();
        std::fs::write(&text, "precious").unwrap();
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(d.join("short"), b"VPAK").unwrap();
        assert_eq!(existing(&d.join("none")).unwrap(), Existing::Nothing);
        assert_eq!(existing(&vpak).unwrap(), Existing::Vpak);
        assert_eq!(existing(&text).unwrap(), Existing::Other);
        assert_eq!(existing(&dir).unwrap(), Existing::Other);
        assert_eq!(existing(&d.join("short")).unwrap(), Existing::Other);
        assert!(may_replace(&vpak, false).is_ok() && may_replace(&d.join("none"), false).is_ok());
        let e = may_replace(&text, false).unwrap_err();
        assert!(e.contains("victim.txt") && e.contains("--force"), "{e}");
        assert!(may_replace(&text, true).is_ok());
        #[cfg(unix)]
        {
            std::os::unix::fs::symlink(d.join("gone"), d.join("dangling")).unwrap();
            assert_eq!(existing(&d.join("dangling")).unwrap(), Existing::Other, "a dangling link is something");
        }
        std::fs::write(d.join("report.json"), "{\n  \"version\": 1,\n  \"tool\": \"vdbcook 0.1.0\"").unwrap();
        assert!(may_replace_report(&d.join("report.json"), false).is_ok() && may_replace_report(&d.join("report.xml"), false).is_ok());
        assert!(may_replace_report(&text, false).unwrap_err().contains("not a vdbcook bake report"));
        assert!(may_replace_report(&text, true).is_ok());
        assert!(check_dir(&text, "--cache").unwrap_err().contains("not a directory"));
        assert!(check_dir(&dir, "--cache").is_ok() && check_dir(&d.join("new"), "--cache").is_ok());
        let _ = std::fs::remove_dir_all(&d);
    }
}
