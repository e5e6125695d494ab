//! Helpers shared by the tests of the vdbcook crates. Only ever a
//! dev-dependency.

/// The value of `made`, or `None` after a note on stderr when it failed
/// (no GPU adapter, say): a test then skips its checks. Under `CI=true` a
/// failure is a test failure, never a skip.
pub fn or_skip<T, E: std::fmt::Display>(made: Result<T, E>, what: &str) -> Option<T> {
    match made {
        Ok(v) => Some(v),
        Err(e) => {
            assert!(std::env::var("CI").ok().as_deref() != Some("true"), "CI=true and no {what}: {e}");
            eprintln!("note: skipping: no {what}: {e}");
            None
        }
    }
}

/// A small deterministic generator (xorshift64*) for test inputs and
/// corruption corpora: the same seed gives the same stream everywhere.
#[derive(Clone, Debug)]
pub struct Rng(u64);

impl Rng {
    /// A generator from `seed` (0, which xorshift cannot leave, is replaced).
    pub fn new(seed: u64) -> Rng {
        Rng(if seed == 0 { 0x9e37_79b9_7f4a_7c15 } else { seed })
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }

    /// In `0..n` (`n` > 0; the slight modulo bias does not matter for tests).
    pub fn below(&mut self, n: u64) -> u64 {
        self.next_u64() % n.max(1)
    }

    /// In [0, 1), with 24 random bits.
    pub fn unit(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32
    }

    /// `n` random bytes.
    pub fn bytes(&mut self, n: usize) -> Vec<u8> {
        (0..n).map(|_| (self.next_u64() >> 56) as u8).collect()
    }
}

/// The link flags of a Rust static library on this platform (what
/// `--print native-static-libs` prints; include/vpak.h lists them too).
pub const STATIC_LIB_FLAGS: &[&str] = if cfg!(target_os = "macos") { &["-lSystem", "-lc", "-lm"] } else { &["-lgcc_s", "-lutil", "-lrt", "-lpthread", "-lm", "-ldl", "-lc"] };

/// The workspace's root directory.
pub fn workspace_root() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// Runs `cargo build` with `args` (in the profile of the running test) and
/// returns the file it built whose path ends in `suffix`, of the target
/// named `target` (from cargo's JSON messages).
pub fn cargo_build(args: &[&str], target: &str, suffix: &str) -> Result<std::path::PathBuf, String> {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let mut build = std::process::Command::new(cargo);
    build.current_dir(workspace_root()).args(["build", "-q", "--message-format=json-render-diagnostics"]).args(args);
    if !cfg!(debug_assertions) {
        build.arg("--release");
    }
    let out = build.output().map_err(|e| format!("cargo: {e}"))?;
    if !out.status.success() {
        return Err(format!("cargo build {args:?} failed: {}", String::from_utf8_lossy(&out.stderr)));
    }
    let text = String::from_utf8_lossy(&out.stdout);
    let name = format!("\"name\":\"{target}\"");
    text.lines()
        .filter(|l| l.contains("\"compiler-artifact\"") && l.contains(&name))
        .flat_map(|l| l.split('"'))
        .find(|f| f.ends_with(suffix))
        .map(std::path::PathBuf::from)
        .ok_or_else(|| format!("cargo build {args:?} named no file ending in {suffix}: {text}"))
}

/// Builds the C ABI's static library (`cargo build -p vdbcook-vpak-c`) and
/// compiles `examples/c/{name}.c` against it and `include/vpak.h` with `cc
/// -std=c99 -Wall -Wextra -Werror -pedantic`, into `out_dir`; returns the program's path.
pub fn c_example(name: &str, out_dir: &std::path::Path) -> Result<std::path::PathBuf, String> {
    let root = workspace_root();
    let lib = cargo_build(&["-p", "vdbcook-vpak-c"], "vpak", if cfg!(windows) { "vpak.lib" } else { "libvpak.a" })?;
    let exe = out_dir.join(name);
    let src = root.join("examples/c").join(format!("{name}.c"));
    let cc = std::process::Command::new(std::env::var("CC").unwrap_or_else(|_| "cc".into()))
        .args(["-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-I"])
        .arg(root.join("include"))
        .arg(&src)
        .arg(&lib)
        .args(STATIC_LIB_FLAGS)
        .arg("-o")
        .arg(&exe)
        .output()
        .map_err(|e| format!("cc: {e}"))?;
    if !cc.status.success() {
        return Err(format!("cc {} failed: {}", src.display(), String::from_utf8_lossy(&cc.stderr)));
    }
    Ok(exe)
}

#[cfg(test)]
mod tests {
    use super::Rng;

    #[test]
    fn streams_repeat_and_spread() {
        let (mut a, mut b) = (Rng::new(42), Rng::new(42));
        let xs: Vec<u64> = (0..1000).map(|_| a.next_u64()).collect();
        assert!(xs.iter().all(|&x| x == b.next_u64()));
        let mut r = Rng::new(0);
        let mut hits = [0u32; 10];
        for _ in 0..10_000 {
            hits[r.below(10) as usize] += 1;
            let u = r.unit();
            assert!((0.0..1.0).contains(&u));
        }
        assert!(hits.iter().all(|&h| (900..1100).contains(&h)), "{hits:?}");
        assert_eq!(r.bytes(7).len(), 7);
    }
}
