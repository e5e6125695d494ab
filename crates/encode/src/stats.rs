//! Error figures of decoded values against their source.

use crate::BRICK_VOXELS;

/// Counts of non-finite values.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct NonFinite {
    pub nan: u64,
    pub pos_inf: u64,
    pub neg_inf: u64,
}

impl NonFinite {
    /// Counts `v` if it is NaN or ±∞.
    pub fn tally(&mut self, v: f32) {
        if v.is_nan() {
            self.nan += 1;
        } else if v == f32::INFINITY {
            self.pos_inf += 1;
        } else if v == f32::NEG_INFINITY {
            self.neg_inf += 1;
        }
    }
    pub fn total(&self) -> u64 {
        self.nan + self.pos_inf + self.neg_inf
    }
    pub fn merge(&mut self, o: &NonFinite) {
        self.nan += o.nan;
        self.pos_inf += o.pos_inf;
        self.neg_inf += o.neg_inf;
    }
}

/// Voxel-domain error figures (RMSE, PSNR with the given peak, max abs
/// error) over the voxels whose reference value is finite: a NaN or ±∞
/// reference has no error to measure (and one would make every figure NaN),
/// so it is only counted, in `non_finite`.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ErrorStats {
    /// Voxels measured (finite reference values).
    pub count: u64,
    pub sum_sq: f64,
    pub max_abs: f64,
    /// Voxels left out: their reference value is NaN or ±∞.
    pub non_finite: NonFinite,
}

impl ErrorStats {
    pub fn add(&mut self, reference: f32, value: f32) {
        if !reference.is_finite() {
            self.non_finite.tally(reference);
            return;
        }
        let d = f64::from(value) - f64::from(reference);
        self.count += 1;
        self.sum_sq += d * d;
        self.max_abs = self.max_abs.max(d.abs());
    }
    /// Adds the voxels of `mask` (512 bits) of a reference brick and its decoding.
    pub fn add_masked(&mut self, reference: &[f32; BRICK_VOXELS], value: &[f32; BRICK_VOXELS], mask: &[u64; 8]) {
        // Most bricks: every voxel on (no mask bits to read), every difference
        // finite (the sum says so: a NaN or ±∞ would carry into it).
        let (sq, mx) = if mask.iter().all(|&w| w == u64::MAX) { lanes::<true>(reference, value, mask) } else { lanes::<false>(reference, value, mask) };
        let sum_sq: f64 = sq.iter().sum();
        if sum_sq.is_finite() {
            self.count += mask.iter().map(|w| u64::from(w.count_ones())).sum::<u64>();
            self.sum_sq += sum_sq;
            self.max_abs = mx.iter().copied().fold(self.max_abs, f64::max);
            return;
        }
        // A non-finite reference (or decoding) on the mask: voxel by voxel.
        for (w, &word) in mask.iter().enumerate() {
            let mut bits = word;
            while bits != 0 {
                let i = w * 64 + bits.trailing_zeros() as usize;
                bits &= bits - 1;
                self.add(reference[i], value[i]);
            }
        }
    }

    pub fn merge(&mut self, o: &ErrorStats) {
        self.count += o.count;
        self.sum_sq += o.sum_sq;
        self.max_abs = self.max_abs.max(o.max_abs);
        self.non_finite.merge(&o.non_finite);
    }
    pub fn rmse(&self) -> f64 {
        if self.count == 0 {
            0.0
        } else {
            (self.sum_sq / self.count as f64).sqrt()
        }
    }
    /// PSNR in dB for the given peak (the value range); infinite when exact.
    pub fn psnr(&self, peak: f64) -> f64 {
        let r = self.rmse();
        if r == 0.0 {
            f64::INFINITY
        } else {
            20.0 * (peak / r).log10()
        }
    }
}

/// Per lane, the sum of squared differences and the largest absolute
/// difference over the voxels of `mask` (voxel 8j + k is bit k of byte j;
/// `FULL`: every bit is set), in eight fixed lanes the compiler can vectorise.
#[inline(always)]
fn lanes<const FULL: bool>(reference: &[f32; BRICK_VOXELS], value: &[f32; BRICK_VOXELS], mask: &[u64; 8]) -> ([f64; 8], [f64; 8]) {
    let (mut sq, mut mx) = ([0.0f64; 8], [0.0f64; 8]);
    for (j, (r, v)) in reference.chunks_exact(8).zip(value.chunks_exact(8)).enumerate() {
        let byte = (mask[j / 8] >> (8 * (j % 8))) as u8;
        for k in 0..8 {
            let on = FULL || (byte >> k) & 1 == 1;
            let d = if on { f64::from(v[k]) - f64::from(r[k]) } else { 0.0 };
            sq[k] += d * d;
            let a = d.abs();
            mx[k] = if a > mx[k] { a } else { mx[k] };
        }
    }
    (sq, mx)
}
