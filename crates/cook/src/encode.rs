//! Encoding: the work bricks (the pool, or the clustered pool) in their
//! planes' formats, or in the formats chosen per brick.

use crate::cluster::{used_work, Clustered};
use crate::{Error, Progress};
use vdbcook_encode::{Bricks, Choices, Encoded, PlaneSpec, Quality};
use vdbcook_flipbook::Built;
use vdbcook_grid::spill::{SpillPolicy, Store, StoreError};

/// Which voxels of each pool brick some L3 node shows: block encoders may
/// spend nothing on the others, and per-brick formats bound only these.
/// `None` when neither is at work.
pub(crate) fn shown_masks(built: &Built, specs: &[PlaneSpec], max_error: Option<f32>, spill: Option<&SpillPolicy>) -> Result<Option<Store<[u64; 8]>>, StoreError> {
    let any_block = specs.iter().any(|s| s.plane.format.is_block());
    (any_block || max_error.is_some()).then(|| union_masks(built.pool.len(), built.l3.iter().map(|l| (l.brick as usize, l.mask)), spill)).transpose()
}

/// Per item `0..n`, the union of the masks given for it (a store under
/// `spill`: 64 bytes a brick).
pub(crate) fn union_masks(n: usize, masks: impl Iterator<Item = (usize, [u64; 8])>, spill: Option<&SpillPolicy>) -> Result<Store<[u64; 8]>, StoreError> {
    let mut out = Store::<[u64; 8]>::with_policy(spill.cloned());
    out.extend_zeroed(n, "the bricks' masks")?;
    for (i, m) in masks {
        if let Some(o) = out.get_mut(i) {
            for (o, m) in o.iter_mut().zip(m) {
                *o |= m;
            }
        }
    }
    Ok(out)
}

/// Per pool brick per channel, true when no tree that uses the brick is at
/// a level where the channel is stored (`stored[c]`: channel c's levels);
/// `None` when every channel is stored at every level.
pub(crate) fn absent_channels(built: &Built, stored: &[std::ops::Range<u32>]) -> Option<Vec<bool>> {
    if built.frames.iter().all(|f| stored.iter().all(|r| r.contains(&f.level))) {
        return None;
    }
    let channels = stored.len();
    let mut absent = vec![true; built.pool.len() * channels];
    for f in &built.frames {
        for &(_, id) in &f.leaves {
            let b = built.l3[id as usize].brick as usize;
            for (c, r) in stored.iter().enumerate() {
                if r.contains(&f.level) {
                    absent[b * channels + c] = false;
                }
            }
        }
    }
    Some(absent)
}

/// The work bricks in the planes `specs` (`masks`: the pool's shown voxels;
/// `absent`: see [`absent_channels`], for an unclustered pool; block
/// textures under `spill`).
#[allow(clippy::too_many_arguments)]
pub(crate) fn in_planes<'a>(
    pool: Bricks<'a>,
    specs: Vec<PlaneSpec>,
    quality: Quality,
    masks: Option<&[[u64; 8]]>,
    absent: Option<Vec<bool>>,
    clustered: Option<&'a Clustered>,
    spill: Option<&SpillPolicy>,
    progress: &dyn Progress,
) -> Result<Encoded<'a>, crate::Error> {
    let channels = pool.channels();
    let work = clustered.map_or(pool, |c| Bricks::dense(&c.bricks, channels));
    // Clustered, the work bricks' own masks; else the pool's, as they are.
    let clustered_masks = match (masks, clustered) {
        (Some(m), Some(c)) => Some(c.work_masks(m, channels, spill)?),
        _ => None,
    };
    let work_masks = clustered_masks.as_deref().or(masks);
    progress.start("encoding", (work.len() * specs.len()) as u64);
    // Centroids stand for bricks of several levels: every channel counts.
    let absent = absent.filter(|_| clustered.is_none());
    let encoded = Encoded::with_absent(specs, quality, work, work_masks, absent, spill, &|n| progress.advance(n as u64))?;
    progress.finish();
    Ok(encoded)
}

/// The work bricks in the formats chosen for them (`choices`, per work brick
/// and channel); centroids no pool brick uses any more are in no plane.
pub(crate) fn as_chosen<'a>(pool: Bricks<'a>, choices: Choices, clustered: Option<&'a Clustered>) -> Encoded<'a> {
    let work = clustered.map_or(pool, |c| Bricks::dense(&c.bricks, pool.channels()));
    Encoded::from_choices(work, choices, &used_work(clustered, work.len()))
}

/// An asset holds at most `vdbcook_vpak::MAX_CHANNELS` planes.
pub(crate) fn check_planes(encoded: &Encoded) -> Result<(), Error> {
    match encoded.specs.len() {
        n if n > vdbcook_vpak::MAX_CHANNELS => Err(Error::TooManyPlanes(n)),
        _ => Ok(()),
    }
}
