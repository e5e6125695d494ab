//! Format choice: which texture planes the channels are stored in (their
//! groups' formats), or, with a maximum error, each brick channel's cheapest
//! format within it.

use crate::cluster::Clustered;
use crate::{channels_named, ChannelSpec, CookOptions, Error, Format, Progress};
use vdbcook_encode::{Bricks, Choices, PlaneSpec};

/// The planes of every channel group, in order: explicit groups first,
/// then each other channel alone in `format`, in a texture of its own
/// (measured, docs/benchmarks.md: a plane deduplicates its own bricks, so
/// a channel alone is stored as compactly as in an asset of its own, where
/// channels sharing a texture are stored once per distinct combination;
/// and packing uncorrelated channels into BC7's lanes raises their error,
/// up to 2.5x on c42).  Packing is asked for with a group.  Returns the
/// specs and each channel's group.
pub(crate) fn plan_planes(opts: &CookOptions, specs: &[ChannelSpec]) -> Result<(Vec<PlaneSpec>, Vec<u32>), Error> {
    if opts.format == Format::Constant || opts.groups.iter().any(|g| g.format == Format::Constant) {
        return Err(Error::ConstantFormat);
    }
    if opts.max_error.is_some() && !opts.groups.is_empty() {
        return Err(Error::MaxErrorGroups);
    }
    let mut group_of: Vec<Option<u32>> = vec![None; specs.len()];
    let mut groups: Vec<(Format, Vec<usize>)> = Vec::new();
    for g in &opts.groups {
        let mut members = Vec::new();
        for name in &g.channels {
            let named = channels_named(specs, name);
            if named.is_empty() {
                let channels = specs.iter().map(|s| s.name.as_str()).collect::<Vec<_>>().join(", ");
                return Err(Error::UnknownChannel { name: name.clone(), channels });
            }
            for c in named {
                if group_of[c].is_some() {
                    return Err(Error::TwiceGrouped(specs[c].name.clone()));
                }
                group_of[c] = Some(groups.len() as u32);
                members.push(c);
            }
        }
        groups.push((g.format, members));
    }
    for (c, g) in group_of.iter_mut().enumerate() {
        if g.is_none() {
            *g = Some(groups.len() as u32);
            groups.push((opts.format, vec![c]));
        }
    }
    let planes = groups.iter().flat_map(|(f, m)| vdbcook_encode::group_planes(*f, m)).collect();
    Ok((planes, group_of.into_iter().map(|g| g.unwrap_or(0)).collect()))
}

/// Per-brick formats: each work brick channel's cheapest format whose shown
/// voxels (`masks`, per pool brick) decode within `bound`, in work-brick
/// order.  Merged bricks are held to the bound too: one that its cluster's
/// stored brick leaves past it becomes a stray, stored (and chosen for) on
/// its own, after the centroids.
pub(crate) fn per_brick(pool: Bricks, masks: &[[u64; 8]], bound: f32, opts: &CookOptions, clustered: Option<&mut Clustered>, progress: &dyn Progress) -> Result<Choices, Error> {
    let channels = pool.channels();
    let mut choices = Choices::new(channels, opts.spill.clone());
    let choose = |choices: &mut Choices, bricks: Bricks, masks: &[[u64; 8]]| {
        progress.start("choosing formats", bricks.len() as u64);
        let r = choices.choose(bricks, masks, bound, opts.quality, opts.disk, &|n| progress.advance(n as u64));
        progress.finish();
        r
    };
    let Some(c) = clustered else {
        choose(&mut choices, pool, masks)?;
        return Ok(choices);
    };
    choose(&mut choices, Bricks::dense(&c.bricks, channels), &c.work_masks(masks, channels, opts.spill.as_ref())?)?;
    let first = c.bricks.len();
    let stray_masks = c.split_strays(pool, channels, masks, &choices, bound)?;
    choose(&mut choices, Bricks::dense(&c.bricks[first..], channels), &stray_masks)?;
    Ok(choices)
}
