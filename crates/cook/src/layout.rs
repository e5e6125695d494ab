//! Layout: the node arrays, and per plane its brick ranges, brick table and
//! atlases (`vdbcook_vpak::layout`), and the channel tables of channels
//! stored in several planes, as sections.

use crate::dedup::Stored;
use crate::{Error, Format, Progress};
use vdbcook_encode::{Encoded, PlaneSpec};
use vdbcook_grid::spill::{SpillPolicy, Store};
use vdbcook_vpak::layout::{pack_atlas_into, plan_atlases, AtlasLayout};
use vdbcook_vpak::nodes::Nodes;
use vdbcook_vpak::{kind, Bytes, PlaneInfo, Section};

/// The sections of an asset but its metadata, and what they cost.
pub(crate) struct Laid {
    /// Node arrays, then per plane its ranges and table, then the channel
    /// tables, then every atlas.
    pub(crate) sections: Vec<Section>,
    pub(crate) planes: Vec<PlaneInfo>,
    /// Per plane: bytes of its atlases, ranges and brick table.
    pub(crate) plane_bytes: Vec<u64>,
    /// Per channel: bytes of its channel table (0 for none).
    pub(crate) channel_table_bytes: Vec<u64>,
}

/// Each channel's planes, in spec order: the first is its `plane`, the
/// others (per-brick formats) its alternates, reached through its channel table.
pub(crate) fn planes_of(specs: &[PlaneSpec], channels: usize) -> Vec<Vec<usize>> {
    let mut planes_of: Vec<Vec<usize>> = vec![Vec::new(); channels];
    for (p, spec) in specs.iter().enumerate() {
        for &c in &spec.channels {
            planes_of[c].push(p);
        }
    }
    planes_of
}

/// Lays out the stored bricks of every plane of `encoded` in atlases of at
/// most `max_texture_dim` texels a side (atlases under `spill`: see
/// `vdbcook_grid::spill`); `tables`, [`Stored::tables`] taken out, become
/// the brick and channel tables.
pub(crate) fn lay_out(
    nodes: Nodes,
    encoded: &Encoded,
    stored: &Stored,
    mut tables: Vec<(Vec<usize>, Vec<u32>)>,
    max_texture_dim: u32,
    spill: Option<&SpillPolicy>,
    progress: &dyn Progress,
) -> Result<Laid, Error> {
    let specs = &encoded.specs;
    // The atlases' bricks: a constant plane has none.
    let atlas_bricks = specs.iter().zip(&stored.planes).filter(|(s, _)| s.plane.format != Format::Constant).map(|(_, keep)| keep.len() as u64);
    progress.start("laying out", atlas_bricks.sum());
    let mut sections = node_sections(nodes, spill)?;
    let mut plane_infos = Vec::with_capacity(specs.len());
    let mut plane_bytes = vec![0u64; specs.len()];
    let mut atlas_sections = Vec::new();
    for (p, (spec, pkeep)) in specs.iter().zip(&stored.planes).enumerate() {
        let atlases = match spec.plane.format {
            Format::Constant => Vec::new(),
            _ => plan_atlases(spec.plane.slices_per_brick(), pkeep.len() as u32, max_texture_dim),
        };
        let info = PlaneInfo { plane: spec.plane, bricks: pkeep.len() as u32, atlases };
        let slots = info.range_slots() as usize;
        let ranges: Vec<u32> = pkeep.iter().flat_map(|&k| (0..slots).flat_map(move |s| spec.channels.get(s).map_or([0.0; 2], |&c| encoded.range(k as usize, c)))).map(f32::to_bits).collect();
        plane_bytes[p] += 4 * ranges.len() as u64;
        sections.push(Section { kind: kind::BRICK_RANGES, index: p as u32, data: section_words(ranges, spill)? });
        // A plane alone in its family has a brick table where it stores fewer bricks than the asset.
        let own = tables.iter_mut().find(|(f, _)| f[..] == [p]).map(|(_, t)| t);
        if let (true, Some(table)) = (info.bricks as usize != stored.keep.len(), own) {
            plane_bytes[p] += 4 * table.len() as u64;
            sections.push(Section { kind: kind::BRICK_TABLE, index: p as u32, data: section_words(std::mem::take(table), spill)? });
        }
        let bricks = encoded.plane(p, pkeep);
        for atlas in &info.atlases {
            let layout = AtlasLayout { plane: spec.plane, atlas: *atlas };
            let mut data = Store::<u8>::with_policy(spill.cloned());
            data.extend_zeroed(layout.byte_len(), "an atlas")?;
            pack_atlas_into(&layout, &bricks, &mut data);
            progress.advance(u64::from(atlas.count));
            plane_bytes[p] += data.len() as u64;
            atlas_sections.push(Section { kind: kind::ATLAS, index: atlas_sections.len() as u32, data: Bytes::Held(Box::new(data)) });
        }
        plane_infos.push(info);
    }
    // A family of several planes (a channel's formats) has a channel table; a brick in none of them reads entry 0.
    let mut channel_table_bytes = vec![0u64; encoded.channels()];
    for (family, mut table) in tables.into_iter().filter(|(f, _)| f.len() > 1) {
        let Some(&c) = specs[family[0]].channels.first() else { continue };
        table.iter_mut().filter(|e| **e == u32::MAX).for_each(|e| *e = 0);
        channel_table_bytes[c] = 4 * table.len() as u64;
        sections.push(Section { kind: kind::CHANNEL_TABLE, index: c as u32, data: section_words(table, spill)? });
    }
    sections.extend(atlas_sections);
    progress.finish();
    Ok(Laid { sections, planes: plane_infos, plane_bytes, channel_table_bytes })
}

/// The node arrays' sections ([`section_words`]).
fn node_sections(n: Nodes, spill: Option<&SpillPolicy>) -> Result<Vec<Section>, Error> {
    [(kind::FRAMES, n.frames), (kind::L1_NODES, n.l1), (kind::L1_ENTRIES, n.l1_entries), (kind::L2_NODES, n.l2), (kind::L2_ENTRIES, n.l2_entries), (kind::L3_NODES, n.l3), (kind::TILES, n.tiles)]
        .into_iter()
        .map(|(k, v)| Ok(Section { kind: k, index: 0, data: section_words(v, spill)? }))
        .collect()
}

/// A section of words. Under a spill policy it moves into a store, which
/// leaves memory past the policy's size while the segment's writer has it
/// and the error figures are measured (the L3 nodes alone are about 21
/// bytes a distinct leaf, 25 MB in 96 frames of a 224³ plume); else the
/// words are held as they are (no copy).
fn section_words(words: Vec<u32>, spill: Option<&SpillPolicy>) -> Result<Bytes, Error> {
    let Some(policy) = spill else { return Ok(Bytes::from_words(words)) };
    let mut store = Store::<u8>::with_policy(Some(policy.clone()));
    store.try_reserve(4 * words.len(), "a section")?;
    for chunk in words.chunks(1 << 16) {
        let bytes: Vec<u8> = chunk.iter().flat_map(|w| w.to_le_bytes()).collect();
        store.extend_from_slice(&bytes, "a section")?;
    }
    Ok(Bytes::Held(Box::new(store)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sections_under_a_spill_policy_are_stores_with_the_same_bytes() {
        let words: Vec<u32> = (0..100_000u32).map(|i| i.wrapping_mul(0x9e37_79b9)).collect();
        let policy = SpillPolicy::new(std::env::temp_dir(), 1);
        let held = section_words(words.clone(), Some(&policy)).unwrap();
        assert_eq!(held[..], Bytes::from_words(words.clone())[..]);
        // Past a 1-byte budget they went to a file (where the system has them).
        #[cfg(target_os = "linux")]
        assert!(policy.peak_in_files() >= 4 * words.len() as u64, "{} bytes in files", policy.peak_in_files());
        assert_eq!(section_words(words.clone(), None).unwrap()[..], held[..]);
    }
}
