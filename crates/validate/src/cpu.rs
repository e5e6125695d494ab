//! The same march on the CPU, to check the GPU path: every step mirrors
//! `shaders/vpak.wgsl` and `shaders/march.wgsl`; BC4/BC7 blocks are decoded by
//! bcdec_rs (BC4 in float, as `shaders/bcdec.wgsl`).

use crate::scene::{backdrop, ray_dir};
use crate::{AssetData, Error, Image, Model, Scene, View};
use vdbcook_vpak::{Asset, GpuChannel};

struct Sampler<'a> {
    d: AssetData<'a>,
    l1: u32,
    /// Level of detail of the tree `l1` (0: the frame itself).
    level: u32,
    /// The buffers the shader reads: channel table, brick tables, ranges (pairs).
    table: Vec<GpuChannel>,
    tables: Vec<u32>,
    ranges: Vec<f32>,
}

impl Sampler<'_> {
    fn new(d: AssetData<'_>, l1: u32, level: u32) -> Sampler<'_> {
        let (table, tables, ranges) = (d.c.gpu_channels(), d.c.gpu_tables(), d.c.gpu_ranges());
        Sampler { d, l1, level, table, tables, ranges }
    }

    fn entry(nodes: &[u32], base: usize, mask_words: usize, s: usize) -> Option<usize> {
        let (w, bit) = (s >> 5, s & 31);
        let word = *nodes.get(base + w)?;
        if (word >> bit) & 1 == 0 {
            return None;
        }
        let prefix = (nodes.get(base + mask_words + (w >> 1))? >> (16 * (w & 1))) & 0xffff;
        let first = *nodes.get(base + mask_words + mask_words / 2)?;
        let below = (word & ((1u32 << bit) - 1)).count_ones();
        Some(first.saturating_add(prefix).saturating_add(below) as usize)
    }

    /// Texel `t` of texture slot `slot` (an atlas of `size` bricks along x
    /// and y), as `vpak_atlas_buffer.wgsl` decodes it.
    fn texel(&self, slot: u32, size: [u32; 2], ch: &GpuChannel, [x, y, z]: [u32; 3]) -> [f32; 4] {
        let a = self.d.c.atlases.get(slot as usize).copied().unwrap_or(&[]);
        let [w, h] = size.map(|s| s as usize * 8);
        let (x, y, z) = (x as usize, y as usize, z as usize);
        let mut out = [0.0, 0.0, 0.0, 1.0];
        if ch.format == 3 || ch.format == 4 {
            let bb = if ch.format == 3 { 8 } else { 16 };
            let at = ((z * (h / 4) + y / 4) * (w / 4) + x / 4) * bb;
            let Some(block) = a.get(at..at + bb) else { return out };
            let t = (y & 3) * 4 + (x & 3);
            if ch.format == 3 {
                let mut r = [0.0f32; 16];
                bcdec_rs::bc4_float(block, &mut r, 4, false);
                out[0] = r[t];
            } else {
                let mut rgba = [0u8; 64];
                bcdec_rs::bc7(block, &mut rgba, 16);
                out = std::array::from_fn(|l| f32::from(rgba[t * 4 + l]) / 255.0);
            }
            return out;
        }
        let index = (z * h + y) * w + x;
        for (l, v) in out.iter_mut().enumerate().take(ch.lanes as usize) {
            let k = index * ch.lanes as usize + l;
            *v = match ch.format {
                0 => a.get(k * 4..k * 4 + 4).map_or(0.0, |b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])),
                1 => a.get(k * 2..k * 2 + 2).map_or(0.0, |b| half_to_f32(u16::from_le_bytes([b[0], b[1]]))),
                5 => a.get(k * 2..k * 2 + 2).map_or(0.0, |b| f32::from(u16::from_le_bytes([b[0], b[1]])) / 65535.0),
                _ => a.get(k).map_or(0.0, |&q| f32::from(q) / 255.0),
            };
        }
        out
    }

    /// Channel `c` of voxel `v` of brick `b`, as `vpak_brick_channel` and `vpak_brick_channel_value`.
    fn brick_value(&self, b: u32, v: [u32; 3], c: usize) -> f32 {
        let Some(mut ch) = self.table.get(c) else { return 0.0 };
        let entry = |b: u32| self.tables.get((ch.table as usize).saturating_add(b as usize)).copied().unwrap_or(0);
        let pb = if ch.alternates != u32::MAX {
            // Per-brick formats: the channel table picks the plane and its brick.
            let e = entry(b);
            if e >> vdbcook_vpak::CHOICE_SHIFT != 0 {
                let Some(alt) = self.table.get((ch.alternates as usize).saturating_add((e >> vdbcook_vpak::CHOICE_SHIFT) as usize - 1)) else { return 0.0 };
                ch = alt;
            }
            e & vdbcook_vpak::PLANE_BRICK_MASK
        } else if ch.table == u32::MAX {
            b
        } else {
            entry(b)
        };
        let [bx, by, _, per] = ch.atlas_bricks.map(u64::from);
        let pb64 = u64::from(pb);
        let (atlas, i) = if pb64 >= per { (pb64 / per.max(1), pb64 % per.max(1)) } else { (0, pb64) };
        let pos = [i % bx.max(1), (i / bx.max(1)) % by.max(1), i / (bx * by).max(1)].map(|p| p as u32);
        let atlas = atlas as u32;
        let size = if atlas == ch.last_atlas[0] { [ch.last_atlas[1], ch.last_atlas[2]] } else { [ch.atlas_bricks[0], ch.atlas_bricks[1]] };
        let shift = ch.z_shift.min(2);
        let r = (ch.range_base as usize).saturating_add((pb as usize).saturating_mul(ch.range_slots as usize)).saturating_add((ch.lane >> shift) as usize);
        let (lo, hi) = (self.ranges.get(2 * r).copied().unwrap_or(0.0), self.ranges.get(2 * r + 1).copied().unwrap_or(0.0));
        if ch.format == vdbcook_vpak::Format::Constant.code() {
            return lo;
        }
        let t = [pos[0] * 8 + v[0], pos[1] * 8 + v[1], pos[2].saturating_mul(ch.slices).saturating_add(v[2] >> shift)];
        let level = self.texel(ch.slot.saturating_add(atlas), size, ch, t)[((ch.lane + (v[2] & ((1 << shift) - 1))) & 3) as usize];
        if ch.ranged == 0 {
            return level;
        }
        lo + level * (hi - lo)
    }

    /// Channel `c`'s value and the empty-region edge (in level-0 voxels) at
    /// level-0 voxel `p`, as `vpak_query`: the level's voxel that covers it.
    fn query(&self, p: [i32; 3], c: usize) -> (f32, u32) {
        let (v, empty) = self.query_level(p.map(|x| x >> self.level), c);
        (v, empty << self.level)
    }

    /// [`Sampler::query`] at a voxel of the level.
    fn query_level(&self, p: [i32; 3], c: usize) -> (f32, u32) {
        let channels = self.d.c.meta.channels.len();
        let bg = self.table.get(c).map_or(0.0, |ch| f32::from_bits(ch.background));
        let tile = |e: u32| f32::from_bits(self.d.c.tiles.get(((e & 0x7fff_ffff) as usize).saturating_mul(channels).saturating_add(c)).copied().unwrap_or(0));
        if p.iter().any(|&c| !(0..4096).contains(&c)) {
            return (bg, 128);
        }
        let u = p.map(|c| c as u32);
        // The L1 node's size (its first word): past its slots is empty.
        let at = self.l1 as usize;
        let log2 = self.d.c.l1.get(at).copied().unwrap_or(0).min(5);
        let c1 = u.map(|v| v >> 7);
        if c1.iter().any(|&v| v >> log2 != 0) {
            return (bg, 128);
        }
        let s1 = (c1[0] << (2 * log2) | c1[1] << log2 | c1[2]) as usize;
        let Some(i1) = Self::entry(self.d.c.l1, at + 1, (1 << (3 * log2)) / 32, s1) else { return (bg, 128) };
        let e1 = self.d.c.l1_entries.get(i1).copied().unwrap_or(0);
        if e1 & 0x8000_0000 != 0 {
            return (tile(e1), 0);
        }
        let s2 = (((u[0] >> 3) & 15) << 8 | ((u[1] >> 3) & 15) << 4 | ((u[2] >> 3) & 15)) as usize;
        let Some(i2) = Self::entry(self.d.c.l2, e1 as usize * 193, 128, s2) else { return (bg, 8) };
        let e2 = self.d.c.l2_entries.get(i2).copied().unwrap_or(0);
        if e2 & 0x8000_0000 != 0 {
            return (tile(e2), 0);
        }
        let word = |k: usize| self.d.c.l3.get(k).copied().unwrap_or(0);
        let l3 = (e2 as usize).saturating_mul(3).saturating_add(1);
        let v = u.map(|c| c & 7);
        // The voxel's 4³ sub-block: empty, full, or partly active (a sub-mask).
        let states = word(l3.saturating_add(1));
        let sb = (v[0] >> 2) << 2 | (v[1] >> 2) << 1 | (v[2] >> 2);
        let state = (states >> (2 * sb)) & 3;
        if state == 0 {
            return (bg, 0);
        }
        if state >= 2 {
            let j = (v[0] & 3) << 4 | (v[1] & 3) << 2 | (v[2] & 3);
            let below = ((states >> 1) & 0x5555 & ((1u32 << (2 * sb)) - 1)).count_ones();
            let at = (word(l3.saturating_add(2)) as usize).saturating_add(2 * below as usize + (j >> 5) as usize);
            if (word(at) >> (j & 31)) & 1 == 0 {
                return (bg, 0);
            }
        }
        (self.brick_value(word(l3), v, c), 0)
    }
}

fn half_to_f32(h: u16) -> f32 {
    let sign = if h & 0x8000 != 0 { -1.0 } else { 1.0 };
    let exp = i32::from((h >> 10) & 0x1f);
    let man = f32::from(h & 0x3ff);
    sign * match exp {
        0 => man * 2f32.powi(-24),
        31 => {
            if man == 0.0 {
                f32::INFINITY
            } else {
                f32::NAN
            }
        }
        e => (1.0 + man / 1024.0) * 2f32.powi(e - 15),
    }
}

fn box_hit(o: [f32; 3], d: [f32; 3], lo: [f32; 3], hi: [f32; 3]) -> (f32, f32) {
    let (mut t0, mut t1) = (0.0f32, f32::INFINITY);
    for a in 0..3 {
        let inv = 1.0 / d[a];
        let (x, y) = ((lo[a] - o[a]) * inv, (hi[a] - o[a]) * inv);
        t0 = t0.max(x.min(y));
        t1 = t1.min(x.max(y));
    }
    (t0, t1)
}

fn cell_exit(p: [f32; 3], d: [f32; 3], dim: f32) -> f32 {
    let mut t = f32::INFINITY;
    for a in 0..3 {
        let lo = (p[a] / dim).floor() * dim;
        let inv = 1.0 / d[a];
        t = t.min(((lo - p[a]) * inv).max((lo + dim - p[a]) * inv));
    }
    t
}

fn at(o: [f32; 3], d: [f32; 3], t: f32) -> [f32; 3] {
    [o[0] + d[0] * t, o[1] + d[1] * t, o[2] + d[2] * t]
}

/// `v` when it is positive and finite, else 0 (`finite_positive`).
fn finite_positive(v: f32) -> f32 {
    if v > 0.0 && v.is_finite() {
        v
    } else {
        0.0
    }
}

/// As `inset_exit` in march.wgsl.
fn inset_exit(p: [f32; 3], d: [f32; 3], dim: f32, m: f32) -> f32 {
    let lo = p.map(|c| (c / dim).floor() * dim + m);
    let hi = lo.map(|l| l + (dim - 2.0 * m));
    if (0..3).any(|a| p[a] < lo[a] || p[a] > hi[a]) {
        return 0.0;
    }
    let mut t = f32::INFINITY;
    for a in 0..3 {
        let inv = 1.0 / d[a];
        t = t.min(((lo[a] - p[a]) * inv).max((hi[a] - p[a]) * inv));
    }
    t
}

/// The level set `c` at `p` (level-0 coordinates), as `ls_field`.
fn ls_field(s: &Sampler, c: usize, bg: f32, p: [f32; 3]) -> f32 {
    let scale = (1u32 << s.level) as f32;
    let q = p.map(|v| v / scale - 0.5);
    let i0 = q.map(|v| v.floor() as i32);
    let w = [0, 1, 2].map(|a| q[a] - q[a].floor());
    let mut acc = 0.0f32;
    for k in 0..8 {
        let sel = [k & 1 != 0, k & 2 != 0, k & 4 != 0];
        let ip = [0, 1, 2].map(|a| i0[a] + i32::from(sel[a]));
        let v = s.query_level(ip, c).0;
        let v = if v.is_finite() { v } else { bg };
        let wk = [0, 1, 2].map(|a| if sel[a] { w[a] } else { 1.0 - w[a] });
        acc += v * wk[0] * wk[1] * wk[2];
    }
    acc
}

/// The surface model's colour along the ray `o` + t `d` through the box
/// from `t0` to `t1`, as `surface` in march.wgsl.
fn surface(s: &Sampler, scene: &Scene, skip: bool, o: [f32; 3], d: [f32; 3], (t0, t1): (f32, f32)) -> f32 {
    if t0 >= t1 {
        return 0.0;
    }
    let c = scene.channels[0] as usize;
    let bg = s.table.get(c).map_or(0.0, |ch| f32::from_bits(ch.background));
    let field = |p: [f32; 3]| ls_field(s, c, bg, p);
    let step = scene.step;
    let voxel = (1u32 << s.level) as f32;
    let (mut t_prev, mut v_prev) = (t0, field(at(o, d, t0)));
    let mut t_hit = if v_prev <= 0.0 { t0 } else { -1.0 };
    let (mut k, mut n) = (0.5f32, 0u32);
    loop {
        let t = t0 + k * step;
        if t_hit >= 0.0 || t >= t1 || n >= scene.max_steps {
            break;
        }
        n += 1;
        let p = at(o, d, t);
        if skip {
            let (_, empty) = s.query(p.map(|v| v.floor() as i32), c);
            if empty > 0 {
                let deep = inset_exit(p, d, empty as f32, voxel);
                if deep > 0.0 {
                    let next = (k + 1.0).max(((t + deep - t0) / step - 0.5).ceil() + 0.5);
                    t_prev = t0 + (next - 1.0) * step;
                    v_prev = bg;
                    k = next;
                    continue;
                }
            }
        }
        let v = field(p);
        if v_prev > 0.0 && v <= 0.0 {
            let (mut a, mut va, mut b, mut vb) = (t_prev, v_prev, t, v);
            for _ in 0..4 {
                let m = 0.5 * (a + b);
                let vm = field(at(o, d, m));
                if vm > 0.0 {
                    (a, va) = (m, vm);
                } else {
                    (b, vb) = (m, vm);
                }
            }
            t_hit = a + (b - a) * (va / (va - vb));
        }
        (t_prev, v_prev) = (t, v);
        k += 1.0;
    }
    if t_hit < 0.0 {
        return 0.0;
    }
    let p = at(o, d, t_hit);
    let h = voxel;
    let diff = |a: usize| {
        let (mut hi, mut lo) = (p, p);
        hi[a] += h;
        lo[a] -= h;
        field(hi) - field(lo)
    };
    let g = [diff(0), diff(1), diff(2)];
    let len = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt();
    let normal = if len > 0.0 { g.map(|v| v / len) } else { d.map(|v| -v) };
    let lit = (normal[0] * scene.light[0] + normal[1] * scene.light[1] + normal[2] * scene.light[2]).max(0.0);
    0.8 * (0.25 + 0.75 * lit)
}

/// Renders like the GPU path (the asset's first stored level).
pub fn render_cpu(asset: &Asset, scene: &Scene, frame: usize, view: &View, width: u32, height: u32) -> Result<Image, Error> {
    render_cpu_level(asset, scene, frame, asset.metadata()?.first_level, view, width, height)
}

/// [`render_cpu`] of level of detail `level` of the frame, as `render_views_level`.
pub fn render_cpu_level(asset: &Asset, scene: &Scene, frame: usize, level: u32, view: &View, width: u32, height: u32) -> Result<Image, Error> {
    let d = AssetData::new(asset)?;
    let level = match d.meta().missing_level(level) {
        None => scene.drawn_level(d.meta(), level),
        Some(_) => level,
    };
    let l1 = d.tree_l1(frame, level)?;
    let view = &view.moved(scene.shift);
    let ext = scene.channels[0] as usize;
    let model = scene.model();
    let skip = d.meta().channels.get(ext).is_some_and(|c| if model == Model::Surface { c.background > 0.0 } else { c.background == 0.0 });
    let s = Sampler::new(d, l1, level);
    let basis = view.basis();
    let tf = (view.fov_deg.to_radians() * 0.5).tan();
    let shadow = |o: [f32; 3]| -> f32 {
        let dl = scene.light;
        let (_, t1) = box_hit(o, dl, scene.box_min, scene.box_max);
        let mut step = scene.shadow_step;
        let (mut t, mut depth, mut n) = (0.5 * step, 0.0f32, 0u32);
        loop {
            if t >= t1 || n >= scene.max_steps || depth > 8.0 {
                break;
            }
            n += 1;
            let p = at(o, dl, t);
            let (v, empty) = s.query(p.map(|c| c.floor() as i32), ext);
            if empty > 0 && skip {
                t += cell_exit(p, dl, empty as f32) + 0.5 * step;
                continue;
            }
            depth += finite_positive(v) * scene.density_scale * step;
            t += step;
            step *= 1.25;
        }
        depth
    };
    // The shadow grid, as `shadow_main` (only scattered light reads it).
    let g = scene.shadow_grid();
    let cell = scene.shadow_cell;
    let mut grid = vec![0.0f32; if model == Model::Scatter { (g[0] * g[1] * g[2]) as usize } else { 1 }];
    for (i, v) in grid.iter_mut().enumerate().filter(|_| model == Model::Scatter) {
        let i = i as u32;
        let c = [i % g[0], (i / g[0]) % g[1], i / (g[0] * g[1])];
        *v = shadow([0, 1, 2].map(|a| scene.box_min[a] + (c[a] as f32 + 0.5) * cell));
    }
    let shadow_at = |p: [f32; 3]| -> f32 {
        let f = [0, 1, 2].map(|a| ((p[a] - scene.box_min[a]) / cell - 0.5).clamp(0.0, (g[a] - 1) as f32));
        let i0 = f.map(|v| v.floor() as u32);
        let i1 = [0, 1, 2].map(|a| (i0[a] + 1).min(g[a] - 1));
        let w = [0, 1, 2].map(|a| f[a] - i0[a] as f32);
        let mut acc = 0.0f32;
        for k in 0..8 {
            let sel = [k & 1 != 0, k & 2 != 0, k & 4 != 0];
            let c = [0, 1, 2].map(|a| if sel[a] { i1[a] } else { i0[a] });
            let wk = [0, 1, 2].map(|a| if sel[a] { w[a] } else { 1.0 - w[a] });
            acc += grid.get(((c[2] * g[1] + c[1]) * g[0] + c[0]) as usize).copied().unwrap_or(0.0) * wk[0] * wk[1] * wk[2];
        }
        acc
    };
    // Emission, as `emission` and `cell_value` in march.wgsl.
    let [_, temperature, flames] = scene.channels;
    let emission = |p: [i32; 3]| -> [f32; 3] {
        let mut e = [0.0f32; 3];
        if temperature != crate::NONE {
            let t = (finite_positive(s.query(p, temperature as usize).0) * scene.emission[0]).clamp(0.0, 1.0);
            let ramp = [3.0 * t, 3.0 * t - 1.0, 3.0 * t - 2.0].map(|c| c.clamp(0.0, 1.0));
            for (e, r) in e.iter_mut().zip(ramp) {
                *e += r * t * t;
            }
        }
        if flames != crate::NONE {
            let f = (finite_positive(s.query(p, flames as usize).0) * scene.emission[1]).clamp(0.0, 1.0);
            for (e, c) in e.iter_mut().zip([1.0, 0.55, 0.15]) {
                *e += c * f;
            }
        }
        e.map(|v| v * scene.emission[2])
    };
    let mut pixels = vec![0.0f32; (width * height * 3) as usize];
    for y in 0..height {
        for x in 0..width {
            let dir = ray_dir(basis, tf, x, y, width, height);
            let (t0, t1) = box_hit(view.eye, dir, scene.box_min, scene.box_max);
            let mut radiance = [0.0f32; 3];
            let mut trans = 1.0f32;
            if model == Model::Surface {
                radiance = [surface(&s, scene, skip, view.eye, dir, (t0, t1)); 3];
            } else if t0 < t1 {
                let (mut k, mut n) = (0.5f32, 0u32);
                loop {
                    let t = t0 + k * scene.step;
                    if t >= t1 || n >= scene.max_steps || trans < 1e-3 {
                        break;
                    }
                    n += 1;
                    let p = at(view.eye, dir, t);
                    let ip = p.map(|c| c.floor() as i32);
                    let (v, empty) = s.query(ip, ext);
                    if empty > 0 && skip {
                        let exit = t + cell_exit(p, dir, empty as f32);
                        k = (k + 1.0).max(((exit - t0) / scene.step - 0.5).ceil() + 0.5);
                        continue;
                    }
                    for (r, e) in radiance.iter_mut().zip(emission(ip)) {
                        *r += trans * e * scene.step;
                    }
                    let sigma = finite_positive(v) * scene.density_scale;
                    if sigma > 0.0 {
                        let a = 1.0 - (-sigma * scene.step).exp();
                        let lit = 0.25 + 0.75 * (-shadow_at(p)).exp();
                        for r in radiance.iter_mut() {
                            *r += trans * a * lit * scene.emission[3];
                        }
                        trans *= 1.0 - a;
                    }
                    k += 1.0;
                }
            }
            if scene.has_backdrop() {
                let b = backdrop(dir);
                for r in radiance.iter_mut() {
                    *r += trans * b;
                }
            }
            pixels[(3 * (y * width + x)) as usize..][..3].copy_from_slice(&radiance);
        }
    }
    Ok(Image { width, height, pixels })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;
    use vdbcook_cook::{CookOptions, Cooker, Format, NoProgress};
    use vdbcook_grid::Coord;

    /// The twin's tree walk (which the GPU images are checked against, and
    /// which mirrors `vpak.wgsl` step by step) gives every voxel of real
    /// fixtures exactly: an active voxel its value, any other the background.
    /// This checks the compact L3 masks against the source, not against a
    /// second copy of the same arithmetic.
    #[test]
    fn the_sampler_reads_every_voxel_as_the_source_has_it() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
        for f in ["fixtures/smoke_seq/smoke_0004.vdb", "fixtures/fog_blosc.vdb", "fixtures/tiles.vdb", "fixtures/inactive_modes_zip.vdb"] {
            let v = vdbcook_vdb::open(&root.join(f)).unwrap();
            let grid = v.read_grid(v.select(None).unwrap()).unwrap();
            let mut c = Cooker::new(CookOptions { format: Format::F32, ..CookOptions::default() });
            c.push(&grid, None).unwrap();
            let bytes = vdbcook_vpak::assemble(&c.finish(&NoProgress).unwrap().0);
            let asset = Asset::from_bytes(&bytes).unwrap();
            let d = AssetData::new(&asset).unwrap();
            let (l1, offset) = (d.tree_l1(0, 0).unwrap(), d.meta().index_offset);
            let s = Sampler::new(d, l1, 0);
            let b = grid.stats().bbox.unwrap();
            let mut active = 0u64;
            for x in b.min.x - 8..=b.max.x + 8 {
                for y in b.min.y - 8..=b.max.y + 8 {
                    for z in b.min.z - 8..=b.max.z + 8 {
                        let (value, on) = grid.probe(Coord::new(x, y, z));
                        let want = if on { value } else { grid.background };
                        let (got, _) = s.query([x - offset[0], y - offset[1], z - offset[2]], 0);
                        assert_eq!(got.to_bits(), want.to_bits(), "{f}: voxel ({x}, {y}, {z})");
                        active += u64::from(on);
                    }
                }
            }
            // Every level of detail, as `unpack_level` gives it (the twin takes level-0 coordinates).
            let mut c = Cooker::new(CookOptions { format: Format::F32, levels: vdbcook_vpak::LevelCount::new(4).unwrap(), ..CookOptions::default() });
            c.push(&grid, None).unwrap();
            let levels = Asset::from_bytes(&vdbcook_vpak::assemble(&c.finish(&NoProgress).unwrap().0)).unwrap();
            for level in 1..4u32 {
                let g = vdbcook_cook::unpack_level(&levels, 0, level).unwrap().remove(0);
                let d = AssetData::new(&levels).unwrap();
                let s = Sampler::new(d, AssetData::new(&levels).unwrap().tree_l1(0, level).unwrap(), level);
                let lo = offset.map(|o| o >> level);
                let b = g.stats().bbox.unwrap();
                for x in b.min.x - 2..=b.max.x + 2 {
                    for y in b.min.y - 2..=b.max.y + 2 {
                        for z in b.min.z - 2..=b.max.z + 2 {
                            let (value, on) = g.probe(Coord::new(x, y, z));
                            let want = if on { value } else { g.background };
                            // Every level-0 voxel this level voxel covers reads it.
                            let fine = [(x - lo[0]) << level, (y - lo[1]) << level, (z - lo[2]) << level];
                            let k = (1 << level) - 1;
                            for p in [fine, [fine[0] + k, fine[1] + k, fine[2] + k]] {
                                let (got, _) = s.query(p, 0);
                                assert_eq!(got.to_bits(), want.to_bits(), "{f}: level {level} voxel ({x}, {y}, {z})");
                            }
                        }
                    }
                }
            }
            // A leaf whose active count is not a multiple of 64 has a partly active sub-block.
            let partial_leaves = grid.leaves.iter().filter(|l| l.mask.iter_on().count() % 64 != 0).count();
            assert!(active > 0, "{f}");
            if f.contains("smoke") || f.contains("fog") {
                assert!(partial_leaves > 10, "{f}: the fixture must exercise partly active sub-blocks");
            }
        }
    }

    /// Frames whose trees need L1 nodes of 8³, 16³ and 32³ slots (content out
    /// to x = 700, 1600 and 4000, a 128³ tile in the last): the twin reads
    /// every voxel around the content as the source has it, and the empty
    /// space past a small node's slots as the background.
    fn wide_frames() -> Vec<vdbcook_grid::Grid> {
        use vdbcook_grid::{Grid, GridClass, Leaf, LeafMask, Tile, Transform};
        let far = [[704, 8, 8], [1600, 8, 0], [4000, 0, 8]];
        (0..3)
            .map(|k| {
                let mut leaves: Vec<Leaf> = [[8 * k as i32, 0, 0], far[k], [896, 896, 896]]
                    .iter()
                    .enumerate()
                    .map(|(i, o)| Leaf { origin: Coord::new(o[0], o[1], o[2]), mask: LeafMask([0x00ff_00ff_00ff_00ff << i; 8]), values: std::array::from_fn(|v| 0.1 + (v + 7 * i + k) as f32 * 1e-3) })
                    .collect();
                leaves.sort_by_key(|l| l.origin); // as grids keep them (probe searches)
                let tiles = if k == 2 { vec![Tile { origin: Coord::new(3840, 128, 0), dim: 128, value: 0.75, active: true }] } else { Vec::new() };
                Grid { name: "density".into(), class: GridClass::FogVolume, background: 0.0, transform: Transform::identity(), leaves, tiles }
            })
            .collect()
    }

    #[test]
    fn the_sampler_reads_trees_of_every_l1_size() {
        let frames = wide_frames();
        let mut c = Cooker::new(CookOptions { format: Format::F32, ..CookOptions::default() });
        for g in &frames {
            c.push(g, None).unwrap();
        }
        let asset = Asset::from_bytes(&vdbcook_vpak::assemble(&c.finish(&NoProgress).unwrap().0)).unwrap();
        let d = AssetData::new(&asset).unwrap();
        let sizes: Vec<u32> = (0..3).map(|f| d.c.l1[d.tree_l1(f, 0).unwrap() as usize]).collect();
        assert_eq!(sizes, [3, 4, 5], "the frames' L1 nodes");
        let offset = d.meta().index_offset;
        for (f, grid) in frames.iter().enumerate() {
            let s = Sampler::new(AssetData::new(&asset).unwrap(), d.tree_l1(f, 0).unwrap(), 0);
            // Around every leaf and tile, and along a line through every L1 slot and past the node.
            let mut points: Vec<[i32; 3]> = grid
                .leaves
                .iter()
                .map(|l| l.origin)
                .chain(grid.tiles.iter().map(|t| t.origin))
                .flat_map(|o| (-3..11).map(move |d| [o.x + d, o.y + d.rem_euclid(8), o.z + (d * 5).rem_euclid(8)]))
                .collect();
            points.extend((0..4200).step_by(37).map(|x| [x, 130, 3]));
            for p in points {
                let (value, on) = grid.probe(Coord::new(p[0], p[1], p[2]));
                let want = if on { value } else { grid.background };
                let (got, _) = s.query([p[0] - offset[0], p[1] - offset[1], p[2] - offset[2]], 0);
                assert_eq!(got.to_bits(), want.to_bits(), "frame {f}: voxel {p:?}");
            }
        }
        // The shader walks the same nodes as the twin (lavapipe in CI; skipped without an adapter).
        let Ok(r) = crate::Renderer::new(None) else {
            assert!(std::env::var("CI").ok().as_deref() != Some("true"), "CI=true and no GPU adapter");
            return;
        };
        let scene = Scene::for_asset(d.meta());
        let gpu = r.upload(&asset).unwrap();
        for (f, view) in scene.orbit(3).iter().enumerate() {
            let g = r.render(&gpu, &scene, f, view, 64, 64).unwrap();
            let c = render_cpu(&asset, &scene, f, view, 64, 64).unwrap();
            let m = crate::compare(&c, &g);
            assert!(m.max_error < 2e-3, "frame {f}: {m:?}");
            assert!(f < 2 || g.pixels.iter().any(|&p| p > 0.01), "frame {f}: the tile is not drawn");
        }
    }
}
