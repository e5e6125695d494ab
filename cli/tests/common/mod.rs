//! Helpers shared by the CLI integration tests.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

pub fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").canonicalize().unwrap()
}

pub fn vdbcook(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_vdbcook")).args(args).current_dir(root()).output().expect("run vdbcook")
}

/// Every .vdb below `dir`, sorted.
pub fn vdb_files(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        let Ok(rd) = std::fs::read_dir(&d) else { continue };
        for e in rd.flatten() {
            let p = e.path();
            if p.is_dir() {
                stack.push(p);
            } else if p.extension().is_some_and(|x| x == "vdb") {
                out.push(p);
            }
        }
    }
    out.sort();
    out
}

pub fn in_ci() -> bool {
    std::env::var("CI").is_ok_and(|v| v == "true")
}

/// The real-world corpus beside the checkout; required in CI.
pub fn shared_samples() -> Option<PathBuf> {
    let p = root().join("../shared/vdb-samples");
    if p.is_dir() {
        Some(p)
    } else {
        assert!(!in_ci(), "CI=true but ../shared/vdb-samples is missing");
        eprintln!("note: ../shared/vdb-samples not found; testing fixtures only");
        None
    }
}

/// True when OpenVDB's Python module (the oracle) can be used.  In CI its
/// absence is a failure, never a skip.
pub fn oracle_available() -> bool {
    let ok = Command::new("/usr/bin/python3").args(["-c", "import pyopenvdb"]).output().is_ok_and(|o| o.status.success());
    if !ok {
        assert!(!in_ci(), "CI=true but /usr/bin/python3 cannot import pyopenvdb (scripts/test.sh installs python3-openvdb)");
        eprintln!("note: pyopenvdb not available; skipping differential checks (run scripts/test.sh)");
    }
    ok
}

/// Runs the oracle on `file`; `None` when OpenVDB itself cannot read the file.
pub fn oracle(file: &Path, voxels: Option<&Path>) -> Option<serde_json::Value> {
    let mut cmd = Command::new("/usr/bin/python3");
    cmd.arg(root().join("scripts/openvdb_oracle.py")).arg(file);
    if let Some(v) = voxels {
        cmd.arg("--voxels").arg(v);
    }
    let out = cmd.output().expect("run oracle");
    if !out.status.success() {
        eprintln!("note: OpenVDB cannot read {}: {}", file.display(), String::from_utf8_lossy(&out.stderr).trim());
        return None;
    }
    Some(serde_json::from_slice(&out.stdout).expect("oracle JSON"))
}

/// Runs `f` over `items` on two threads, keeping the input order in the result.
pub fn par_map<T: Sync, R: Send>(items: &[T], f: impl Fn(&T) -> R + Sync) -> Vec<R> {
    let half = items.len().div_ceil(2);
    std::thread::scope(|s| {
        let (a, b) = items.split_at(half);
        let h = s.spawn(|| b.iter().map(&f).collect::<Vec<_>>());
        let mut r: Vec<R> = a.iter().map(&f).collect();
        r.extend(h.join().unwrap());
        r
    })
}

/// True when a GPU adapter (lavapipe is enough) can be opened. In CI its
/// absence is a failure, never a skip.
pub fn gpu_available() -> bool {
    match vdbcook_validate::Renderer::new(None) {
        Ok(_) => true,
        Err(e) => {
            assert!(!in_ci(), "CI=true but no GPU adapter: {e} (scripts/test.sh installs mesa-vulkan-drivers)");
            eprintln!("note: no GPU adapter, skipping GPU checks: {e}");
            false
        }
    }
}

pub fn u32_at(b: &[u8], o: usize) -> u32 {
    u32::from_le_bytes(b[o..o + 4].try_into().unwrap())
}
pub fn i32_at(b: &[u8], o: usize) -> i32 {
    i32::from_le_bytes(b[o..o + 4].try_into().unwrap())
}
pub fn f64_at(b: &[u8], o: usize) -> f64 {
    f64::from_le_bytes(b[o..o + 8].try_into().unwrap())
}
pub fn xyz(b: &[u8], o: usize) -> [i32; 3] {
    [i32_at(b, o), i32_at(b, o + 4), i32_at(b, o + 8)]
}

/// One oracle dump (scripts/openvdb_oracle.py documents both layouts):
/// `--voxels` (one value per record) or `--vec3-voxels` (three).
pub struct Dump<const N: usize> {
    /// (grid index, coordinate, values)
    pub voxels: Vec<(u32, [i32; 3], [f64; N])>,
    pub tiles: Vec<TileRecord<N>>,
}

/// (grid index, min, max, values)
pub type TileRecord<const N: usize> = (u32, [i32; 3], [i32; 3], [f64; N]);

pub fn read_dump<const N: usize>(path: &Path) -> Dump<N> {
    let b = std::fs::read(path).unwrap();
    assert_eq!(&b[..8], if N == 3 { b"VDBORV01" } else { b"VDBORC01" });
    let nv = u64::from_le_bytes(b[16..24].try_into().unwrap()) as usize;
    let nt = u64::from_le_bytes(b[24..32].try_into().unwrap()) as usize;
    let vals = |o: usize| -> [f64; N] { std::array::from_fn(|c| f64_at(&b, o + 8 * c)) };
    let mut o = 32;
    let mut voxels = Vec::with_capacity(nv);
    for _ in 0..nv {
        voxels.push((u32_at(&b, o), xyz(&b, o + 4), vals(o + 16)));
        o += 16 + 8 * N;
    }
    let mut tiles = Vec::with_capacity(nt);
    for _ in 0..nt {
        tiles.push((u32_at(&b, o), xyz(&b, o + 4), xyz(&b, o + 16), vals(o + 28)));
        o += 28 + 8 * N;
    }
    assert_eq!(o, b.len());
    Dump { voxels, tiles }
}

/// The oracle with extra arguments; `Err` with its message when OpenVDB cannot read the file.
pub fn run_oracle(file: &Path, args: &[&str]) -> Result<serde_json::Value, String> {
    let out = Command::new("/usr/bin/python3").arg(root().join("scripts/openvdb_oracle.py")).arg(file).args(args).output().expect("run oracle");
    if !out.status.success() {
        return Err(format!("OpenVDB cannot read it: {}", String::from_utf8_lossy(&out.stderr).trim()));
    }
    Ok(serde_json::from_slice(&out.stdout).expect("oracle JSON"))
}

/// A path as the `&str` the command line takes.
pub fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// A fresh scratch directory for test `tag` of the suite `suite`, unique to
/// this run, removed with everything in it when dropped (a failing test's
/// too: runs must not fill the disk).
pub fn scratch_dir(suite: &str, tag: &str) -> Scratch {
    let d = std::env::temp_dir().join(format!("vdbcook-{suite}-{}-{tag}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    Scratch(d)
}

/// See [`scratch_dir`].
pub struct Scratch(PathBuf);

impl std::ops::Deref for Scratch {
    type Target = Path;
    fn deref(&self) -> &Path {
        &self.0
    }
}

impl AsRef<Path> for Scratch {
    fn as_ref(&self) -> &Path {
        &self.0
    }
}

impl AsRef<std::ffi::OsStr> for Scratch {
    fn as_ref(&self) -> &std::ffi::OsStr {
        self.0.as_os_str()
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// The output of a run that must succeed (its stderr is the failure message).
pub fn ok(out: Output) -> Output {
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    out
}

/// The documented keys of the section of `doc` whose heading starts with `name`.
pub fn doc_section(doc: &str, name: &str) -> Vec<String> {
    documented_keys(doc).into_iter().find(|(h, _)| h.starts_with(name)).map(|(_, k)| k).unwrap_or_else(|| panic!("no section {name}"))
}

/// Every documented key is in `obj` and every key of `obj` is documented.
pub fn assert_documented(obj: &serde_json::Value, documented: &[String], what: &str) {
    for k in documented {
        assert!(obj.get(k).is_some(), "{what}: documented key {k} is missing: {obj}");
    }
    for k in obj.as_object().unwrap().keys() {
        assert!(documented.contains(k), "{what}: key {k} is not documented");
    }
}

/// Keys in the first column of the tables under each `## ` heading of a doc.
pub fn documented_keys(doc: &str) -> Vec<(String, Vec<String>)> {
    let mut out: Vec<(String, Vec<String>)> = Vec::new();
    for line in doc.lines() {
        if let Some(h) = line.strip_prefix("## ") {
            out.push((h.to_string(), Vec::new()));
        } else if let (Some(first), Some((_, keys))) = (line.strip_prefix("| `").map(|l| l.split(" | ").next().unwrap_or("")), out.last_mut()) {
            keys.extend(format!("`{first}").split('`').skip(1).step_by(2).map(str::to_string));
        }
    }
    out
}

/// `vdbcook inspect --json` of one asset: its document.
pub fn inspect(asset: &Path) -> serde_json::Value {
    let v: serde_json::Value = serde_json::from_slice(&ok(vdbcook(&["inspect", "--json", s(asset)])).stdout).unwrap();
    v["files"][0].clone()
}

/// Copies the fixture's frames, cycling, to `dir/NAME_NNNN.vdb` for each number.
pub fn numbered_copies(dir: &Path, name: &str, numbers: impl Iterator<Item = i64>) {
    let src = vdb_files(&root().join("fixtures/smoke_seq"));
    for (i, n) in numbers.enumerate() {
        std::fs::copy(&src[i % src.len()], dir.join(format!("{name}_{n:04}.vdb"))).unwrap();
    }
}

/// `vdbcook cook` of `inputs` with `flags` into `dir/name` (replaced if there).
pub fn cook_into(dir: &Path, name: &str, inputs: &[&str], flags: &[&str]) -> PathBuf {
    let out = dir.join(name);
    let mut args = vec!["cook", "-q", "--force", "-o", s(&out)];
    args.extend(flags);
    args.extend(inputs);
    ok(vdbcook(&args));
    out
}
