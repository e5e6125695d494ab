//! Any byte string as a .vpak asset, checksums not verified (so every byte is
//! reachable): the section table, the metadata, the validator, and unpacking
//! the first frames of every channel at every stored level. A second
//! mode takes the bytes as the metadata of a small, valid three-channel asset
//! (resealed), so absurd channels, planes, atlases and frames meet real
//! sections: they must be refused, never a panic.
#![no_main]
use libfuzzer_sys::fuzz_target;
use std::sync::OnceLock;

fn exercise(asset: &vdbcook_vpak::Asset) {
    let Ok(meta) = asset.metadata() else { return };
    let _ = vdbcook_vpak::Checked::new(asset);
    for frame in 0..(meta.frame_count as usize).min(3) {
        for level in meta.stored_levels().take(vdbcook_vpak::MAX_LEVELS as usize) {
            if let Ok(grids) = vdbcook_cook::unpack_level(asset, frame, level) {
                for g in grids {
                    let _ = g.stats();
                }
            }
        }
    }
}

/// Sections of a small asset of three channels (density, temperature, flames) in two formats.
fn seed() -> &'static Vec<vdbcook_vpak::Section> {
    static SEED: OnceLock<Vec<vdbcook_vpak::Section>> = OnceLock::new();
    SEED.get_or_init(|| {
        use vdbcook_grid::{Coord, Grid, GridClass, Leaf, LeafMask, Tile, Transform};
        let grid = |name: &str, k: usize, bg: f32| Grid {
            name: name.into(),
            class: GridClass::FogVolume,
            background: bg,
            transform: Transform::identity(),
            leaves: (0..3).map(|i| Leaf { origin: Coord::new(8 * (i + k as i32), 0, 0), mask: LeafMask([u64::MAX >> (i * 9); 8]), values: std::array::from_fn(|v| (v * (k + 1)) as f32 * 1e-3) }).collect(),
            tiles: vec![Tile { origin: Coord::new(128, 0, 0), dim: 8, value: k as f32, active: true }],
        };
        let specs = ["density", "temperature", "flames"].map(|n| vdbcook_cook::ChannelSpec { name: n.into(), grid: n.into(), value_type: "float".into(), ..Default::default() });
        let opts = vdbcook_cook::CookOptions { format: vdbcook_cook::Format::Bc7, groups: vec![vdbcook_cook::ChannelGroup { channels: vec!["temperature".into(), "flames".into()], format: vdbcook_cook::Format::Unorm8 }], ..Default::default() };
        let mut c = vdbcook_cook::Cooker::with_channels(opts, specs.to_vec());
        let g = [grid("density", 0, 0.0), grid("temperature", 1, 0.5), grid("flames", 2, 0.0)];
        c.push_channels(&[Some(&g[0]), Some(&g[1]), Some(&g[2])], None).expect("seed frame");
        c.finish(&vdbcook_cook::NoProgress).expect("seed asset").0
    })
}

fuzz_target!(|data: &[u8]| {
    match data.split_first() {
        Some((0xA5, metadata)) => {
            let mut sections: Vec<vdbcook_vpak::Section> = seed().iter().map(|s| vdbcook_vpak::Section { kind: s.kind, index: s.index, data: s.data.to_vec().into() }).collect();
            for s in sections.iter_mut().filter(|s| s.kind == vdbcook_vpak::kind::METADATA) {
                s.data = metadata.to_vec().into();
            }
            if let Ok(asset) = vdbcook_vpak::Asset::from_bytes(&vdbcook_vpak::assemble(&sections)) {
                exercise(&asset);
            }
        }
        _ => {
            if let Ok(asset) = vdbcook_vpak::Asset::from_bytes(data) {
                exercise(&asset);
            }
        }
    }
});
