//! Cache keys: XXH3-128 over everything a cook reads. Two assets with the same
//! key have the same bytes, so a cache can serve either.
//!
//! What is hashed, each field length-prefixed, in this order: a scheme tag, the
//! tool version, the .vpak format version, every setting as (name, value) in
//! [`CookSettings::NAMES`] order (the `with` inputs among them), the inputs as
//! written, and per expanded input file (then each `with` sequence's file of
//! each frame, sequence after sequence) its path relative to the manifest, its
//! length and the XXH3-128 of its bytes (or a mark that it is missing, with
//! `allow_missing`).

use crate::CookSettings;
use twox_hash::XxHash3_128;

/// What a key depends on besides the asset's own settings and files.
#[derive(Clone, Debug)]
pub struct KeyContext {
    /// "vdbcook 0.1.0": a different tool version cooks again.
    pub tool: String,
    /// The .vpak format version ([`vdbcook_vpak::VERSION`]).
    pub format_version: u32,
}

impl KeyContext {
    pub fn new(tool: String) -> KeyContext {
        KeyContext { tool, format_version: vdbcook_vpak::VERSION }
    }
}

/// One input file: its path relative to the manifest and, unless it is
/// missing, its length and the XXH3-128 of its bytes.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FileDigest {
    pub path: String,
    pub content: Option<(u64, u128)>,
}

impl FileDigest {
    pub fn of(path: String, bytes: Option<&[u8]>) -> FileDigest {
        FileDigest { path, content: bytes.map(|b| (b.len() as u64, XxHash3_128::oneshot(b))) }
    }
}

/// Adds one field to a key: its length, then its bytes (so that no two
/// lists of fields hash the same bytes).
fn field(h: &mut XxHash3_128, bytes: &[u8]) {
    h.write(&(bytes.len() as u64).to_le_bytes());
    h.write(bytes);
}

/// A key of `fields`, each added as [`field`] adds it, as 32 hex digits.
pub(crate) fn key_of(fields: &[&[u8]]) -> String {
    let mut h = XxHash3_128::new();
    fields.iter().for_each(|f| field(&mut h, f));
    format!("{:032x}", h.finish_128())
}

/// The key, as 32 hex digits.
pub fn cache_key(ctx: &KeyContext, settings: &CookSettings, inputs: &[String], files: &[FileDigest]) -> String {
    let mut h = XxHash3_128::new();
    field(&mut h, b"vdbcook-bake-key 1");
    field(&mut h, ctx.tool.as_bytes());
    field(&mut h, &ctx.format_version.to_le_bytes());
    // Where buffers live changes nothing in the asset (and keeps older keys valid).
    for (name, value) in settings.pairs().into_iter().filter(|(name, _)| *name != "spill_above") {
        field(&mut h, name.as_bytes());
        field(&mut h, value.as_bytes());
    }
    field(&mut h, &(inputs.len() as u64).to_le_bytes());
    for i in inputs {
        field(&mut h, i.as_bytes());
    }
    field(&mut h, &(files.len() as u64).to_le_bytes());
    for f in files {
        field(&mut h, f.path.as_bytes());
        match f.content {
            Some((len, digest)) => {
                field(&mut h, &len.to_le_bytes());
                field(&mut h, &digest.to_le_bytes());
            }
            None => field(&mut h, b"missing"),
        }
    }
    format!("{:032x}", h.finish_128())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_part_changes_the_key() {
        let ctx = KeyContext::new("vdbcook 0.1.0".into());
        let s = CookSettings::default();
        let inputs = vec!["a.vdb".to_string()];
        let files = vec![FileDigest::of("a.vdb".into(), Some(b"abc"))];
        let k = cache_key(&ctx, &s, &inputs, &files);
        assert_eq!(k.len(), 32);
        assert_eq!(k, cache_key(&ctx, &s, &inputs, &files), "deterministic");
        let other_ctx = KeyContext { tool: "vdbcook 0.1.1".into(), ..ctx.clone() };
        assert_ne!(k, cache_key(&other_ctx, &s, &inputs, &files));
        assert_ne!(k, cache_key(&KeyContext { format_version: 99, ..ctx.clone() }, &s, &inputs, &files));
        assert_ne!(k, cache_key(&ctx, &CookSettings { iterations: "6".parse().unwrap(), ..s.clone() }, &inputs, &files));
        assert_ne!(k, cache_key(&ctx, &s, &inputs, &[FileDigest::of("a.vdb".into(), Some(b"abd"))]));
        assert_ne!(k, cache_key(&ctx, &s, &inputs, &[FileDigest::of("b.vdb".into(), Some(b"abc"))]));
        assert_ne!(k, cache_key(&ctx, &s, &inputs, &[FileDigest::of("a.vdb".into(), None)]));
        assert_ne!(k, cache_key(&ctx, &s, &["a.vd".into()], &files));
        // Where the cook keeps its buffers is no part of the asset.
        assert_eq!(k, cache_key(&ctx, &CookSettings { spill_above: "1MiB".parse().unwrap(), ..s.clone() }, &inputs, &files));
    }
}
