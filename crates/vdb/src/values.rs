//! Node value buffers (OpenVDB's `readCompressedValues`).
//!
//! ```text
//! [u8 metadata]                       file version >= 222 only, 0..=6 (see below)
//! [value inactive0 [value inactive1]] metadata 2, 4: one value; 5: two (full precision)
//! [node mask: selection]              metadata 3, 4, 5 (which inactive value each voxel takes)
//! payload                             the stored values, `stored` of them:
//!    blosc / zip:  i64 n; n > 0: n compressed bytes; n <= 0: -n raw bytes
//!    none:         raw values
//! ```
//! With active-mask compression and metadata != 6, only the active values are
//! stored; inactive ones are rebuilt from the selection mask and the inactive
//! values (background and its negation by default).  Values are half floats
//! when the grid was saved as half, else the tree's own value type.
//!
//! A value has one component (float, double, half) or three (vec3s, vec3d):
//! vectors are stored as consecutive (x, y, z) triples, in the payload and in
//! the inactive values alike (OpenVDB reads `sizeof(ValueType)` bytes; a
//! half-float vec3 grid stores three halves per payload value, while its
//! inactive values stay at full precision).  Everything below works on flat
//! arrays of `count × components` scalars, so scalars and vectors share one
//! code path.
//!
//! Reading is split in two: [`scan`] walks the headers sequentially and
//! records where the payload is; [`ValueBlock::decode`] inflates it and can
//! run on any thread.

use crate::cursor::Cursor;
use crate::Error;

pub(crate) const COMPRESS_ZIP: u32 = 0x1;
pub(crate) const COMPRESS_ACTIVE_MASK: u32 = 0x2;
pub(crate) const COMPRESS_BLOSC: u32 = 0x4;

const NO_MASK_OR_INACTIVE_VALS: u8 = 0;
const NO_MASK_AND_ONE_INACTIVE_VAL: u8 = 2;
const MASK_AND_NO_INACTIVE_VALS: u8 = 3;
const MASK_AND_ONE_INACTIVE_VAL: u8 = 4;
const MASK_AND_TWO_INACTIVE_VALS: u8 = 5;
const NO_MASK_AND_ALL_VALS: u8 = 6;

/// File version from which per-node metadata and per-grid compression exist.
pub(crate) const VERSION_NODE_MASK_COMPRESSION: u32 = 222;

/// The scalar type a tree stores.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ScalarType {
    Half,
    Float,
    Double,
}

impl ScalarType {
    pub fn size(self) -> usize {
        match self {
            ScalarType::Half => 2,
            ScalarType::Float => 4,
            ScalarType::Double => 8,
        }
    }
    pub fn name(self) -> &'static str {
        match self {
            ScalarType::Half => "half",
            ScalarType::Float => "float",
            ScalarType::Double => "double",
        }
    }

    /// Decodes one little-endian value (`b.len() == self.size()`).
    pub(crate) fn decode(self, b: &[u8]) -> f32 {
        match self {
            ScalarType::Half => half_to_f32(u16::from_le_bytes([b[0], b[1]])),
            ScalarType::Float => f32::from_le_bytes([b[0], b[1], b[2], b[3]]),
            ScalarType::Double => f64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]) as f32,
        }
    }
}

/// Every half's float value, built once (256 KiB; exact, since every half is a float).
fn half_table() -> &'static [f32] {
    static TABLE: std::sync::OnceLock<Vec<f32>> = std::sync::OnceLock::new();
    TABLE.get_or_init(|| (0..=u16::MAX).map(|h| half::f16::from_bits(h).to_f32()).collect())
}

fn half_to_f32(bits: u16) -> f32 {
    half_table().get(usize::from(bits)).copied().unwrap_or(0.0)
}

/// Decodes little-endian values of type `st` from `bytes` into `out`, one loop per type.
fn convert(st: ScalarType, bytes: &[u8], out: &mut [f32]) {
    match st {
        ScalarType::Half => {
            let table = half_table();
            for (o, b) in out.iter_mut().zip(bytes.chunks_exact(2)) {
                *o = table.get(usize::from(u16::from_le_bytes([b[0], b[1]]))).copied().unwrap_or(0.0);
            }
        }
        ScalarType::Float => {
            for (o, b) in out.iter_mut().zip(bytes.chunks_exact(4)) {
                *o = f32::from_le_bytes([b[0], b[1], b[2], b[3]]);
            }
        }
        ScalarType::Double => {
            for (o, b) in out.iter_mut().zip(bytes.chunks_exact(8)) {
                *o = f64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]) as f32;
            }
        }
    }
}

/// Most components a value has (vec3).
pub(crate) const MAX_COMPONENTS: usize = 3;

/// One value: its components, unused ones zero.
pub(crate) type Value = [f32; MAX_COMPONENTS];

/// What every buffer of one grid shares.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Ctx {
    pub version: u32,
    pub compression: u32,
    /// Type of each component.
    pub value: ScalarType,
    /// Components per value: 1 (scalar) or 3 (vec3).
    pub components: usize,
    /// Values are stored as half floats (`_HalfFloat` grids).
    pub from_half: bool,
    pub background: Value,
}

impl Ctx {
    fn stored_type(&self) -> ScalarType {
        if self.from_half {
            ScalarType::Half
        } else {
            self.value
        }
    }

    /// Bytes of one full-precision value (background, tiles, inactive values).
    pub fn value_size(&self) -> usize {
        self.value.size() * self.components
    }

    /// Reads one full-precision value.
    pub fn read_value(&self, cur: &mut Cursor<'_>, what: &'static str) -> Result<Value, Error> {
        let bytes = cur.take(self.value_size(), what)?;
        let mut v = [0.0; MAX_COMPONENTS];
        for (o, b) in v.iter_mut().zip(bytes.chunks_exact(self.value.size())) {
            *o = self.value.decode(b);
        }
        Ok(v)
    }
}

/// Component-wise negation (OpenVDB's `math::negative`).
fn negative(v: Value) -> Value {
    v.map(|x| -x)
}

#[derive(Clone, Copy, Debug)]
enum Payload<'a> {
    Raw(&'a [u8]),
    Zip(&'a [u8]),
    Blosc(&'a [u8]),
}

/// One node's value buffer, located but not yet decoded.
#[derive(Clone, Debug)]
pub(crate) struct ValueBlock<'a> {
    inactive: [Value; 2],
    selection: Option<&'a [u8]>,
    /// Number of values in the payload (all, or only the active ones).
    stored: usize,
    payload: Payload<'a>,
    offset: usize,
}

/// Reads the header of a buffer of `count` values whose active mask is
/// `mask` (`count / 64` words), leaving the cursor after the payload.
pub(crate) fn scan<'a>(cur: &mut Cursor<'a>, ctx: &Ctx, count: usize, mask: &[u64]) -> Result<ValueBlock<'a>, Error> {
    let offset = cur.pos();
    let mut meta = NO_MASK_AND_ALL_VALS;
    if ctx.version >= VERSION_NODE_MASK_COMPRESSION {
        meta = cur.u8("node compression metadata")?;
        if meta > NO_MASK_AND_ALL_VALS {
            return Err(Error::invalid("node compression metadata", offset, format!("{meta} (expected 0 to 6)")));
        }
    }
    let bg = ctx.background;
    let mut inactive = [if meta == NO_MASK_OR_INACTIVE_VALS { bg } else { negative(bg) }, bg];
    if matches!(meta, NO_MASK_AND_ONE_INACTIVE_VAL | MASK_AND_ONE_INACTIVE_VAL | MASK_AND_TWO_INACTIVE_VALS) {
        inactive[0] = ctx.read_value(cur, "inactive value")?;
        if meta == MASK_AND_TWO_INACTIVE_VALS {
            inactive[1] = ctx.read_value(cur, "inactive value")?;
        }
    }
    let selection = if matches!(meta, MASK_AND_NO_INACTIVE_VALS | MASK_AND_ONE_INACTIVE_VAL | MASK_AND_TWO_INACTIVE_VALS) { Some(cur.take(count / 8, "selection mask")?) } else { None };
    let mask_compressed = ctx.compression & COMPRESS_ACTIVE_MASK != 0 && meta != NO_MASK_AND_ALL_VALS && ctx.version >= VERSION_NODE_MASK_COMPRESSION;
    let stored = if mask_compressed { mask.iter().map(|w| w.count_ones() as usize).sum() } else { count };
    let bytes = stored * ctx.components * ctx.stored_type().size();
    let payload_at = cur.pos();
    let payload = if stored == 0 && ctx.from_half {
        // OpenVDB's half reader returns before touching the stream when
        // there is nothing to read: no size prefix, no payload.
        Payload::Raw(&[])
    } else if ctx.compression & (COMPRESS_BLOSC | COMPRESS_ZIP) != 0 {
        let n = cur.i64("compressed chunk size")?;
        if n <= 0 {
            let raw = n.unsigned_abs();
            if raw != bytes as u64 {
                return Err(Error::invalid("value buffer", payload_at, format!("uncompressed chunk of {raw} bytes, expected {bytes}")));
            }
            Payload::Raw(cur.take(bytes, "value buffer")?)
        } else {
            let n = usize::try_from(n).unwrap_or(usize::MAX);
            let data = cur.take(n, "compressed value buffer")?;
            if ctx.compression & COMPRESS_BLOSC != 0 {
                Payload::Blosc(data)
            } else {
                Payload::Zip(data)
            }
        }
    } else {
        Payload::Raw(cur.take(bytes, "value buffer")?)
    };
    Ok(ValueBlock { inactive, selection, stored, payload, offset: payload_at })
}

fn inflate(src: &[u8], out: &mut [u8], offset: usize) -> Result<(), Error> {
    let expected = out.len();
    let mut z = flate2::Decompress::new(true);
    let status = z.decompress(src, out, flate2::FlushDecompress::Finish).map_err(|e| Error::Zip { offset: offset as u64, detail: e.to_string() })?;
    if status != flate2::Status::StreamEnd || z.total_out() != expected as u64 {
        return Err(Error::Zip { offset: offset as u64, detail: format!("inflated to at least {} bytes, expected exactly {expected}", z.total_out()) });
    }
    Ok(())
}

/// Buffers up to these sizes (a leaf of doubles; of vec3d) are inflated on
/// the stack; scalar leaves only pay for zeroing the smaller one.
const STACK_BYTES: usize = 512 * 8;
const STACK_BYTES_VEC3: usize = 512 * MAX_COMPONENTS * 8;

impl ValueBlock<'_> {
    /// Decodes into `out` (the node's full value count times the
    /// components, interleaved: x0 y0 z0 x1 …), rebuilding inactive values
    /// where only active ones were stored.
    pub fn decode(&self, ctx: &Ctx, mask: &[u64], out: &mut [f32]) -> Result<(), Error> {
        let expected = self.stored * ctx.components * ctx.stored_type().size();
        match self.payload {
            Payload::Raw(b) => self.expand(ctx, mask, b, out),
            _ if expected <= STACK_BYTES => self.inflate_expand(ctx, mask, &mut [0u8; STACK_BYTES][..expected], out),
            _ if expected <= STACK_BYTES_VEC3 => self.inflate_expand(ctx, mask, &mut [0u8; STACK_BYTES_VEC3][..expected], out),
            _ => self.inflate_expand(ctx, mask, &mut vec![0u8; expected], out),
        }
    }

    /// Decompresses the payload into `scratch` (exactly its expected size), then expands it.
    fn inflate_expand(&self, ctx: &Ctx, mask: &[u64], scratch: &mut [u8], out: &mut [f32]) -> Result<(), Error> {
        match self.payload {
            Payload::Raw(_) => return Err(Error::invalid("value buffer", self.offset, "raw payload passed as compressed")),
            Payload::Zip(b) => inflate(b, scratch, self.offset)?,
            Payload::Blosc(b) => vdbcook_blosc::decompress_into(b, scratch).map_err(|error| Error::Blosc { offset: self.offset as u64, error })?,
        }
        self.expand(ctx, mask, scratch, out)
    }

    /// Converts the stored values in `bytes` into `out`, rebuilding the inactive ones.
    fn expand(&self, ctx: &Ctx, mask: &[u64], bytes: &[u8], out: &mut [f32]) -> Result<(), Error> {
        let st = ctx.stored_type();
        let scalars = self.stored * ctx.components;
        let expected = scalars * st.size();
        if bytes.len() != expected {
            return Err(Error::invalid("value buffer", self.offset, format!("{} bytes, expected {expected}", bytes.len())));
        }
        if scalars == out.len() {
            convert(st, bytes, out);
            return Ok(());
        }
        // Only the active values are stored: convert them into a buffer sized
        // for them (on the stack up to a leaf's worth), then spread them out.
        match scalars {
            n if n <= 512 => self.fill(ctx, mask, bytes, &mut [0.0f32; 512][..n], out),
            n if n <= 512 * MAX_COMPONENTS => self.fill(ctx, mask, bytes, &mut [0.0f32; 512 * MAX_COMPONENTS][..n], out),
            n => self.fill(ctx, mask, bytes, &mut vec![0.0f32; n], out),
        }
        Ok(())
    }

    fn fill(&self, ctx: &Ctx, mask: &[u64], bytes: &[u8], vals: &mut [f32], out: &mut [f32]) {
        convert(ctx.stored_type(), bytes, vals);
        match ctx.components {
            1 => self.spread::<1>(vals, mask, out),
            _ => self.spread::<MAX_COMPONENTS>(vals, mask, out),
        }
    }

    /// Places the stored (active) values of `N` components at the active
    /// positions of `out` and the inactive values elsewhere.
    fn spread<const N: usize>(&self, vals: &[f32], mask: &[u64], out: &mut [f32]) {
        let mut next = vals.chunks_exact(N);
        for (i, o) in out.chunks_exact_mut(N).enumerate() {
            let bit = |m: &[u64]| m.get(i >> 6).is_some_and(|w| (w >> (i & 63)) & 1 == 1);
            if bit(mask) {
                if let Some(v) = next.next() {
                    o.copy_from_slice(v);
                }
            } else {
                let sel = self.selection.is_some_and(|s| s.get(i >> 3).is_some_and(|b| (b >> (i & 7)) & 1 == 1));
                o.copy_from_slice(&self.inactive[usize::from(sel)][..N]);
            }
        }
    }

    /// Number of values the payload holds.
    #[cfg(test)]
    pub fn stored(&self) -> usize {
        self.stored
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ctx(compression: u32) -> Ctx {
        Ctx { version: 224, compression, value: ScalarType::Float, components: 1, from_half: false, background: [0.5, 0.0, 0.0] }
    }

    #[test]
    fn mask_compressed_values_rebuild_inactive_from_selection() {
        // 64 values, active: 0 and 5; selection picks inactive1 at 1.
        let mask = [0b100001u64];
        let mut b = vec![MASK_AND_TWO_INACTIVE_VALS];
        b.extend(7.0f32.to_le_bytes());
        b.extend(9.0f32.to_le_bytes());
        b.extend([0b10, 0, 0, 0, 0, 0, 0, 0]);
        b.extend(1.0f32.to_le_bytes());
        b.extend(2.0f32.to_le_bytes());
        let c = ctx(COMPRESS_ACTIVE_MASK);
        let mut cur = Cursor::new(&b);
        let blk = scan(&mut cur, &c, 64, &mask).unwrap();
        assert_eq!(cur.remaining(), 0);
        assert_eq!(blk.stored(), 2);
        let mut out = vec![0.0; 64];
        blk.decode(&c, &mask, &mut out).unwrap();
        assert_eq!(&out[..7], &[1.0, 9.0, 7.0, 7.0, 7.0, 2.0, 7.0]);
    }

    #[test]
    fn default_inactive_values_are_background_and_its_negation() {
        let mask = [1u64];
        for (meta, want) in [(0u8, 0.5f32), (1, -0.5)] {
            let mut b = vec![meta];
            b.extend(3.0f32.to_le_bytes());
            let c = ctx(COMPRESS_ACTIVE_MASK);
            let blk = scan(&mut Cursor::new(&b), &c, 64, &mask).unwrap();
            let mut out = vec![0.0; 64];
            blk.decode(&c, &mask, &mut out).unwrap();
            assert_eq!((out[0], out[1]), (3.0, want));
        }
    }

    #[test]
    fn zip_chunks_inflate_and_negative_sizes_mean_raw() {
        use std::io::Write;
        let vals: Vec<u8> = (0..64).flat_map(|i| (i as f32).to_le_bytes()).collect();
        let mut enc = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
        enc.write_all(&vals).unwrap();
        let z = enc.finish().unwrap();
        let mut b = vec![NO_MASK_AND_ALL_VALS];
        b.extend((z.len() as i64).to_le_bytes());
        b.extend(&z);
        b.push(NO_MASK_AND_ALL_VALS);
        b.extend((-(vals.len() as i64)).to_le_bytes());
        b.extend(&vals);
        let c = ctx(COMPRESS_ZIP);
        let mut cur = Cursor::new(&b);
        for _ in 0..2 {
            let blk = scan(&mut cur, &c, 64, &[0]).unwrap();
            let mut out = vec![0.0; 64];
            blk.decode(&c, &[0], &mut out).unwrap();
            assert_eq!(out[63], 63.0);
        }
        assert_eq!(cur.remaining(), 0);
    }

    #[test]
    fn wrong_raw_size_and_bad_metadata_are_errors() {
        let c = ctx(COMPRESS_BLOSC);
        let mut b = vec![NO_MASK_AND_ALL_VALS];
        b.extend((-12i64).to_le_bytes());
        b.extend([0; 12]);
        assert!(scan(&mut Cursor::new(&b), &c, 64, &[0]).is_err());
        assert!(scan(&mut Cursor::new(&[7u8]), &c, 64, &[0]).is_err());
        let mut huge = vec![NO_MASK_AND_ALL_VALS];
        huge.extend(i64::MAX.to_le_bytes());
        assert!(matches!(scan(&mut Cursor::new(&huge), &c, 64, &[0]), Err(Error::Truncated { .. })));
    }

    #[test]
    fn half_values_decode() {
        let c = Ctx { from_half: true, ..ctx(0) };
        let b: Vec<u8> = [6u8].into_iter().chain((0..64).flat_map(|i| half::f16::from_f32(i as f32 * 0.5).to_bits().to_le_bytes())).collect();
        let blk = scan(&mut Cursor::new(&b), &c, 64, &[0]).unwrap();
        let mut out = vec![0.0; 64];
        blk.decode(&c, &[0], &mut out).unwrap();
        assert_eq!(out[3], 1.5);
    }

    fn vec3_ctx(compression: u32, value: ScalarType) -> Ctx {
        Ctx { version: 224, compression, value, components: 3, from_half: false, background: [0.5, -1.0, 2.0] }
    }

    fn vec3_bytes(v: [f32; 3], st: ScalarType) -> Vec<u8> {
        v.iter()
            .flat_map(|&x| match st {
                ScalarType::Double => f64::from(x).to_le_bytes().to_vec(),
                ScalarType::Float => x.to_le_bytes().to_vec(),
                ScalarType::Half => half::f16::from_f32(x).to_bits().to_le_bytes().to_vec(),
            })
            .collect()
    }

    #[test]
    fn vec3_inactive_values_and_selection_are_whole_vectors() {
        // Active: 0 and 5; two stored inactive vectors, the selection picks the second at 1.
        let mask = [0b100001u64];
        for st in [ScalarType::Float, ScalarType::Double] {
            let mut b = vec![MASK_AND_TWO_INACTIVE_VALS];
            b.extend(vec3_bytes([7.0, 8.0, 9.0], st));
            b.extend(vec3_bytes([-7.0, -8.0, -9.0], st));
            b.extend([0b10, 0, 0, 0, 0, 0, 0, 0]);
            b.extend(vec3_bytes([1.0, 2.0, 3.0], st));
            b.extend(vec3_bytes([4.0, 5.0, 6.0], st));
            let c = vec3_ctx(COMPRESS_ACTIVE_MASK, st);
            let mut cur = Cursor::new(&b);
            let blk = scan(&mut cur, &c, 64, &mask).unwrap();
            assert_eq!((cur.remaining(), blk.stored()), (0, 2), "{st:?}");
            let mut out = vec![0.0; 64 * 3];
            blk.decode(&c, &mask, &mut out).unwrap();
            assert_eq!(&out[..9], &[1.0, 2.0, 3.0, -7.0, -8.0, -9.0, 7.0, 8.0, 9.0]);
            assert_eq!(&out[15..21], &[4.0, 5.0, 6.0, 7.0, 8.0, 9.0]);
        }
    }

    #[test]
    fn vec3_default_inactive_values_negate_every_component() {
        let mask = [1u64];
        for (meta, want) in [(0u8, [0.5f32, -1.0, 2.0]), (1, [-0.5, 1.0, -2.0])] {
            let mut b = vec![meta];
            b.extend(vec3_bytes([3.0, 4.0, 5.0], ScalarType::Float));
            let c = vec3_ctx(COMPRESS_ACTIVE_MASK, ScalarType::Float);
            let blk = scan(&mut Cursor::new(&b), &c, 64, &mask).unwrap();
            let mut out = vec![0.0; 64 * 3];
            blk.decode(&c, &mask, &mut out).unwrap();
            assert_eq!(&out[..6], &[3.0, 4.0, 5.0, want[0], want[1], want[2]]);
        }
    }

    #[test]
    fn vec3_half_payload_is_three_halves_per_value_but_inactive_values_are_full() {
        // Mask-compressed, one stored inactive vector (full precision), one active value as halves.
        let mask = [1u64];
        for st in [ScalarType::Float, ScalarType::Double] {
            let c = Ctx { from_half: true, ..vec3_ctx(COMPRESS_ACTIVE_MASK, st) };
            let mut b = vec![NO_MASK_AND_ONE_INACTIVE_VAL];
            b.extend(vec3_bytes([0.1, 0.2, 0.3], st));
            b.extend(vec3_bytes([1.5, -2.25, 1e-3], ScalarType::Half));
            let mut cur = Cursor::new(&b);
            let blk = scan(&mut cur, &c, 64, &mask).unwrap();
            assert_eq!(cur.remaining(), 0);
            let mut out = vec![0.0; 64 * 3];
            blk.decode(&c, &mask, &mut out).unwrap();
            assert_eq!(&out[..3], &[1.5, -2.25, half::f16::from_f32(1e-3).to_f32()]);
            assert_eq!(&out[3..6], &[0.1, 0.2, 0.3]);
        }
    }

    #[test]
    fn vec3_compressed_chunks_hold_three_values_per_voxel() {
        use std::io::Write;
        let vals: Vec<u8> = (0..64 * 3).flat_map(|i| (i as f32).to_le_bytes()).collect();
        let mut enc = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
        enc.write_all(&vals).unwrap();
        let z = enc.finish().unwrap();
        let mut b = vec![NO_MASK_AND_ALL_VALS];
        b.extend((z.len() as i64).to_le_bytes());
        b.extend(&z);
        let c = vec3_ctx(COMPRESS_ZIP, ScalarType::Float);
        let blk = scan(&mut Cursor::new(&b), &c, 64, &[0]).unwrap();
        let mut out = vec![0.0; 64 * 3];
        blk.decode(&c, &[0], &mut out).unwrap();
        assert_eq!(out[64 * 3 - 1], 191.0);
        // A raw chunk sized for scalars is refused.
        let mut b = vec![NO_MASK_AND_ALL_VALS];
        b.extend((-(64 * 4i64)).to_le_bytes());
        b.extend([0; 64 * 4]);
        assert!(scan(&mut Cursor::new(&b), &c, 64, &[0]).is_err());
    }
}
