use super::*;
use vdbcook_grid::{GridClass, Leaf, LeafMask, Tile, Transform};
use vdbcook_vpak::nodes::{decode_l3_mask, encode_l3_mask, l3_node_count, Slot, L3_WORDS, SUB_EMPTY, SUB_FULL, SUB_PARTIAL};

fn grid(leaves: Vec<Leaf>, tiles: Vec<Tile>) -> Grid {
    Grid { name: "density".into(), class: GridClass::FogVolume, background: 0.0, transform: Transform::identity(), leaves, tiles }
}

fn leaf(origin: Coord, seed: u32, active: usize) -> Leaf {
    let mut mask = LeafMask::default();
    let mut values = [0.0f32; 512];
    for (i, v) in values.iter_mut().enumerate().take(active) {
        mask.set(i, true);
        *v = (seed as f32 + i as f32 * 0.001).sin().abs();
    }
    // An inactive value that must not leak into the brick.
    values[511] = 9.0;
    Leaf { origin, mask, values }
}

#[test]
fn pool_stores_identical_bricks_once() {
    let mut p = BrickPool::default();
    let a = [0.5f32; 512];
    let mut b = a;
    b[3] = -0.0;
    let mut c = a;
    c[3] = 0.0;
    assert_eq!(p.insert(std::slice::from_ref(&a)).unwrap(), 0);
    assert_eq!(p.insert(std::slice::from_ref(&b)).unwrap(), 1);
    assert_eq!(p.insert(std::slice::from_ref(&c)).unwrap(), 2);
    assert_eq!(p.insert(std::slice::from_ref(&a)).unwrap(), 0);
    assert_eq!(p.len(), 3);
}

#[test]
fn pool_keeps_bricks_apart_when_their_hashes_collide() {
    // Three different bricks given one hash, then looked up again.
    let mut p = BrickPool::default();
    let bricks = [[0.25f32; 512], [0.5; 512], [0.75; 512]];
    for (k, b) in bricks.iter().enumerate() {
        p.stage(std::slice::from_ref(b), &[pool::Made::of(b, false)]).unwrap();
        let mut next = k;
        assert_eq!(p.settle(&[pool::Channel::At(k)], &mut next, 42).unwrap(), k as u32);
        assert_eq!(next, k + 1);
    }
    for (k, b) in bricks.iter().enumerate().rev() {
        p.stage(std::slice::from_ref(b), &[pool::Made::of(b, false)]).unwrap();
        let mut next = 3;
        assert_eq!(p.settle(&[pool::Channel::At(3)], &mut next, 42).unwrap(), k as u32);
        assert_eq!(next, 3, "a duplicate takes no slot");
        p.truncate_stored(3);
    }
}

#[test]
fn constant_channel_bricks_are_held_once_and_compare_by_content() {
    let mut p = BrickPool::new(2);
    let a: Brick = std::array::from_fn(|i| i as f32);
    let zero = [0.0f32; 512];
    let mut almost = zero;
    almost[511] = -0.0;
    assert_eq!(p.insert(&[a, zero]).unwrap(), 0);
    assert_eq!(p.insert(&[zero, zero]).unwrap(), 1);
    assert_eq!(p.insert(&[a, almost]).unwrap(), 2, "-0.0 is not 0.0: not constant, not equal");
    assert_eq!(p.insert(&[a, zero]).unwrap(), 0);
    assert_eq!(p.insert(&[zero, zero]).unwrap(), 1);
    // a twice (bricks 0 and 2), almost, and one zero brick held once.
    assert_eq!(p.held(), 4);
    let view = p.bricks();
    assert_eq!((view.get(0, 1), view.get(1, 0), view.get(2, 1)), (&zero, &zero, &almost));
    assert!(view.constant_of(0, 1).is_some() && view.constant_of(0, 0).is_none());
    // One channel: every brick stored, one dense slice.
    let mut one = BrickPool::new(1);
    one.insert(&[zero]).unwrap();
    one.insert(&[a]).unwrap();
    assert_eq!(one.bricks().as_dense(), Some(&[zero, a][..]));
}

#[test]
fn a_channel_stored_at_another_level_costs_one_brick() {
    // Channel 1 has no grid at level 0: each level-0 brick's channel 1 is
    // its background (known from the second frame on), made as
    // `brick_of_leaf` makes it under the leaf's mask, and held once when it
    // is constant (always with +0.0; other backgrounds' neighbour averages
    // need not be exact).
    for background in [0.0f32, 0.3, 1.0 / 3.0] {
        let o: Vec<Coord> = (0..40).map(|k| Coord::new(8 * k, 0, 0)).collect();
        let density = |seed: u32| named("density", 0.0, o.iter().enumerate().map(|(k, &c)| leaf(c, seed + k as u32, 100)).collect(), vec![]);
        let (d0, d1) = (density(0), density(100));
        let v = named("vel", background, vec![leaf(Coord::new(0, 0, 0), 99, 512)], vec![]);
        let mut builder = Builder::new(2);
        for d in [&d0, &d1] {
            builder.push(&[Some(d), None]).unwrap();
            builder.push_level(1, &[None, Some(&v)]).unwrap();
        }
        let built = builder.finish().unwrap();
        assert_eq!(built.pool.len(), 81);
        let filled = brick_of_leaf(&Leaf { origin: o[0], mask: d1.leaves[0].mask, values: [background; 512] });
        let constant = filled.iter().all(|v| v.to_bits() == filled[0].to_bits());
        // 80 density bricks, the vel brick, the zero brick, and the filled background's.
        let want = 81
            + 1
            + if background == 0.0 {
                0
            } else if constant {
                1
            } else {
                40
            };
        assert_eq!(built.pool.held(), want, "background {background}");
        for (k, l) in d1.leaves.iter().enumerate() {
            let brick = built.pool.brick(41 + k).unwrap();
            assert!(same_bits(&brick, &[brick_of_leaf(l), filled]), "background {background}");
        }
    }
}

#[test]
fn a_frame_with_repeated_leaves_pools_each_brick_once_in_first_order() {
    // 5,000 leaves (more than one batch): every third repeats one of 50
    // patterns, the others are new, so new bricks follow duplicates inside
    // a batch; every fifth is partly active.
    let leaves: Vec<Leaf> =
        (0..5000).map(|i| leaf(Coord::new(8 * (i / 64), 8 * (i % 64), 0), if i % 3 == 0 { (i / 3 % 50) as u32 } else { 1000 + i as u32 }, if i % 5 == 0 { 100 } else { 512 })).collect();
    let g = grid(leaves.clone(), vec![Tile { origin: Coord::new(0, 0, 1024), dim: 8, value: -3.0, active: true }]);
    let mut first: Vec<Brick> = Vec::new();
    for l in &leaves {
        let br = brick_of_leaf(l);
        if !first.iter().any(|f| same_bits(std::slice::from_ref(f), std::slice::from_ref(&br))) {
            first.push(br);
        }
    }
    assert!(first.len() > 3000 && first.len() < 3500, "{}", first.len());
    let mut b = Builder::new(1);
    let fs = b.push(&[Some(&g)]).unwrap();
    assert_eq!(fs.new_bricks, first.len());
    let st = g.stats();
    assert_eq!(fs.ranges[0], Some([st.min.unwrap() as f32, st.max.unwrap() as f32]));
    let built = b.finish().unwrap();
    assert_eq!(built.pool.bricks().as_dense(), Some(&first[..]));
    for (origin, l3) in &built.frames[0].leaves {
        let l = leaves.iter().find(|l| l.origin == *origin).unwrap();
        let node = built.l3[*l3 as usize];
        assert_eq!(node.mask, l.mask.0);
        assert!(same_bits(&built.pool.brick(node.brick as usize).unwrap(), &[brick_of_leaf(l)]));
    }
}

#[test]
fn a_pool_in_the_memory_of_an_earlier_one_holds_what_a_fresh_one_does() {
    let frame = |seed: u32| grid((0..40).map(|i| leaf(Coord::new(8 * i, 0, 0), seed + i as u32, 100 + i as usize)).collect(), Vec::new());
    let build = |b: &mut Builder| {
        for seed in [1, 50, 1] {
            b.push(&[Some(&frame(seed))]).unwrap();
        }
    };
    // An earlier segment's pool, its memory taken once it is done.
    let mut earlier = Builder::new(1);
    for seed in 100..104 {
        earlier.push(&[Some(&frame(seed))]).unwrap();
    }
    let storage = earlier.finish().unwrap().pool.take_storage();
    assert!(storage.is_empty() && storage.capacity() >= 160);
    let memory = storage.as_ptr();
    let mut fresh = Builder::new(1);
    build(&mut fresh);
    let mut reusing = Builder::new(1);
    reusing.reuse(storage);
    build(&mut reusing);
    let (fresh, reusing) = (fresh.finish().unwrap(), reusing.finish().unwrap());
    assert_eq!(reusing.pool.bricks().as_dense(), fresh.pool.bricks().as_dense());
    assert_eq!(fresh.pool.len(), 80);
    // The ranges are recorded in step in the reused memory too.
    assert_eq!(reusing.pool.ranges.len(), reusing.pool.stored.len());
    assert_eq!(&reusing.pool.ranges[..], &fresh.pool.ranges[..]);
    // Its 80 bricks are in the earlier pool's memory (room for 160: nothing moved).
    assert_eq!(reusing.pool.bricks().as_dense().map(<[_]>::as_ptr), Some(memory));
    assert_eq!(reusing.nodes(|id| id).unwrap().frames, fresh.nodes(|id| id).unwrap().frames);
}

#[test]
fn unchanging_frames_share_every_node() {
    let g = grid(vec![leaf(Coord::new(-8, 0, 16), 1, 300), leaf(Coord::new(200, 8, 0), 2, 512)], vec![Tile { origin: Coord::new(128, 128, 0), dim: 128, value: 0.25, active: true }]);
    let mut b = Builder::new(1);
    for _ in 0..100 {
        b.push(&[Some(&g)]).unwrap();
    }
    let built = b.finish().unwrap();
    let n = built.nodes(|id| id).unwrap();
    assert_eq!(n.frames, vec![0; 100]);
    assert_eq!((n.l1_count(), n.l2_count(), n.l3_count()), (1, 2, 2));
    assert_eq!(built.pool.len(), 2);
    assert_eq!(built.leaves_in, 200);
}

#[test]
fn nodes_give_back_every_leaf_and_tile() {
    let leaves = vec![leaf(Coord::new(-136, 5 * 8, 64), 1, 512), leaf(Coord::new(0, 0, 0), 2, 17), leaf(Coord::new(1000, -304, 8), 3, 64)];
    let tiles = vec![
        Tile { origin: Coord::new(256, 0, 0), dim: 128, value: 0.5, active: true },
        Tile { origin: Coord::new(8, 8, 8), dim: 8, value: 0.75, active: true },
        Tile { origin: Coord::new(16, 8, 8), dim: 8, value: 2.0, active: false },
    ];
    let g = grid(leaves.clone(), tiles);
    let mut b = Builder::new(1);
    b.push(&[Some(&g)]).unwrap();
    b.push_empty();
    let built = b.finish().unwrap();
    assert_eq!(built.offset, Coord::new(-256, -384, 0));
    let n = built.nodes(|id| id).unwrap();
    let (got, got_tiles) = n.frame_contents(0, usize::MAX, usize::MAX).unwrap();
    let mut want: Vec<([i32; 3], [u64; 8])> = leaves.iter().map(|l| (l.origin.to_array(), l.mask.0)).collect();
    want.sort_by_key(|w| w.0);
    let mut have: Vec<([i32; 3], [u64; 8])> = got.iter().map(|l| (l.0, l.1)).collect();
    have.sort_by_key(|w| w.0);
    assert_eq!(have, want);
    for (o, _, brick) in &got {
        let src = leaves.iter().find(|l| l.origin.to_array() == *o).unwrap();
        let b = built.pool.bricks().get(*brick as usize, 0);
        for i in src.mask.iter_on() {
            assert_eq!(b[i], src.values[i]);
        }
    }
    let mut t = got_tiles.clone();
    t.sort_by_key(|t| t.0);
    let t: Vec<([i32; 3], u32, Vec<f32>)> = t.iter().map(|&(o, d, i)| (o, d, n.tile(i).unwrap())).collect();
    assert_eq!(t, vec![([8, 8, 8], 8, vec![0.75]), ([256, 0, 0], 128, vec![0.5])]);
    assert_eq!(n.frame_contents(1, usize::MAX, usize::MAX), Some((vec![], vec![])));
    assert!(n.frame_contents(0, 2, usize::MAX).is_none(), "the leaf limit holds");
}

#[test]
fn prefix_counts_make_lookup_match_a_scan() {
    let mut leaves = Vec::new();
    for i in 0..300 {
        leaves.push(leaf(Coord::new((i * 37 % 40) * 8, (i * 11 % 30) * 8, (i % 16) * 8), i as u32, 100 + i as usize % 400));
    }
    leaves.sort_by_key(|l| l.origin);
    leaves.dedup_by_key(|l| l.origin);
    let mut b = Builder::new(1);
    b.push(&[Some(&grid(leaves.clone(), vec![]))]).unwrap();
    let built = b.finish().unwrap();
    let n = built.nodes(|id| id).unwrap();
    let (got, _) = n.frame_contents(0, usize::MAX, usize::MAX).unwrap();
    assert_eq!(got.len(), leaves.len());
}

#[test]
fn root_tiles_fill_the_l1_slots_they_cover() {
    let g = grid(vec![leaf(Coord::new(0, 0, 0), 1, 5)], vec![Tile { origin: Coord::new(0, 0, 0), dim: 4096, value: 1.0, active: true }]);
    let mut b = Builder::new(1);
    b.push(&[Some(&g)]).unwrap();
    let n = b.finish().unwrap().nodes(|id| id).unwrap();
    let (leaves, tiles) = n.frame_contents(0, usize::MAX, usize::MAX).unwrap();
    assert_eq!(leaves.len(), 1);
    // Slot 0 holds the leaf's L2 node; the other 32767 slots are the tile.
    assert_eq!(tiles.len(), 32767);
    assert!(matches!(n.l1_slot(n.frames[0], [0, 0, 0]), Slot::Child(_)));
    let Slot::Tile(t) = n.l1_slot(n.frames[0], [0, 0, 5]) else { panic!("slot 5 is no tile") };
    assert_eq!(n.tile(t), Some(vec![1.0]));
}

#[test]
fn too_wide_sequences_are_refused() {
    let mut b = Builder::new(1);
    b.push(&[Some(&grid(vec![leaf(Coord::new(0, 0, 0), 1, 5)], vec![]))]).unwrap();
    b.push(&[Some(&grid(vec![leaf(Coord::new(0, 4096, 0), 1, 5)], vec![]))]).unwrap();
    let e = b.finish().err().unwrap().to_string();
    assert!(e.contains("4104 voxels along y"), "{e}");
}

#[test]
fn a_changed_background_is_an_error() {
    let mut b = Builder::new(1);
    b.push(&[Some(&grid(vec![], vec![]))]).unwrap();
    let mut g = grid(vec![], vec![]);
    g.background = 1.0;
    assert!(b.push(&[Some(&g)]).is_err());
}

#[test]
fn brick_remap_merges_l3_nodes() {
    let g = grid(vec![leaf(Coord::new(0, 0, 0), 1, 512), leaf(Coord::new(8, 0, 0), 2, 512)], vec![]);
    let mut b = Builder::new(1);
    b.push(&[Some(&g)]).unwrap();
    let built = b.finish().unwrap();
    assert_eq!(built.nodes(|id| id).unwrap().l3_count(), 2);
    assert_eq!(built.nodes(|_| 0).unwrap().l3_count(), 1);
}

#[test]
fn thesis_layout_size() {
    assert_eq!(thesis_tree_bytes(1, 0), 4100 + 32768 * 516);
    assert_eq!(thesis_tree_bytes(2, 10), 2 * (4100 + 32768 * 516) + 680);
}

#[test]
fn inactive_voxels_are_filled_within_the_active_range() {
    let mut l = leaf(Coord::new(0, 0, 0), 4, 0);
    // One active corner and one active voxel in the middle.
    l.mask.set(0, true);
    l.values[0] = 0.2;
    l.mask.set(4 * 64 + 4 * 8 + 4, true);
    l.values[4 * 64 + 4 * 8 + 4] = 0.6;
    let b = brick_of_leaf(&l);
    assert_eq!((b[0], b[4 * 64 + 4 * 8 + 4]), (0.2, 0.6));
    assert!(b.iter().all(|&v| (0.2..=0.6).contains(&v)), "fill leaves the active range");
    // The inactive value 9.0 of the leaf never reaches the brick.
    assert!(b[511] < 1.0);
    // Neighbours of an active voxel take its value in the first pass.
    assert_eq!(b[1], 0.2);
    let full = leaf(Coord::new(0, 0, 0), 5, 512);
    assert_eq!(brick_of_leaf(&full), full.values);
}

/// The first sessions' fill: every voxel every pass, the straightforward way.
fn reference_fill(leaf: &vdbcook_grid::Leaf) -> Brick {
    let n = leaf.mask.count_on();
    if n as usize == LEAF_VOXELS {
        return leaf.values;
    }
    let mut b = [0.0f32; LEAF_VOXELS];
    let mut known = [false; LEAF_VOXELS];
    let mut sum = 0.0f64;
    for i in leaf.mask.iter_on() {
        b[i] = leaf.values[i];
        known[i] = true;
        sum += f64::from(leaf.values[i]);
    }
    let mean = if n > 0 { (sum / f64::from(n)) as f32 } else { 0.0 };
    for _ in 0..FILL_PASSES {
        let (prev_b, prev_known) = (b, known);
        let mut changed = false;
        for i in 0..LEAF_VOXELS {
            if prev_known[i] {
                continue;
            }
            let (x, y, z) = (i >> 6, (i >> 3) & 7, i & 7);
            let (mut acc, mut cnt) = (0.0f32, 0u32);
            let mut visit = |j: usize| {
                if prev_known[j] {
                    acc += prev_b[j];
                    cnt += 1;
                }
            };
            if x > 0 {
                visit(i - 64);
            }
            if x < 7 {
                visit(i + 64);
            }
            if y > 0 {
                visit(i - 8);
            }
            if y < 7 {
                visit(i + 8);
            }
            if z > 0 {
                visit(i - 1);
            }
            if z < 7 {
                visit(i + 1);
            }
            if cnt > 0 {
                b[i] = acc / cnt as f32;
                known[i] = true;
                changed = true;
            }
        }
        if !changed {
            break;
        }
    }
    for i in 0..LEAF_VOXELS {
        if !known[i] {
            b[i] = mean;
        }
    }
    b
}

#[test]
fn the_bitmask_fill_equals_the_plain_one_bit_for_bit() {
    // Random masks from nearly empty to nearly full, and a few shapes.
    let mut rng = vdbcook_testkit::Rng::new(0x9e37_79b9_7f4a_7c15);
    let mut leaves = Vec::new();
    for round in 0..400 {
        let density = round % 20;
        let mut mask = LeafMask::default();
        let mut values = [0.0f32; 512];
        for (i, v) in values.iter_mut().enumerate() {
            *v = rng.below(10_000) as f32 / 7_919.0;
            mask.set(i, rng.below(20) < density);
        }
        leaves.push(Leaf { origin: Coord::new(0, 0, 0), mask, values });
    }
    for shape in [|i: usize| i == 0, |i: usize| i == 511, |i: usize| i & 7 == 3, |i: usize| i >> 6 == 7, |i: usize| (i >> 3) & 7 == 0 && i & 7 == 0] {
        let mut mask = LeafMask::default();
        for i in 0..512 {
            mask.set(i, shape(i));
        }
        leaves.push(Leaf { origin: Coord::new(0, 0, 0), mask, values: std::array::from_fn(|i| i as f32 * 0.37) });
    }
    for (k, l) in leaves.iter().enumerate() {
        let (a, b) = (brick_of_leaf(l), reference_fill(l));
        assert!(same_bits(&[a], &[b]), "leaf {k}: {:?}", a.iter().zip(b.iter()).position(|(x, y)| x.to_bits() != y.to_bits()));
    }
}

/// Voxel `i = x·64 + y·8 + z` of a leaf mask.
fn bit(mask: &[u64; 8], i: usize) -> bool {
    (mask[i / 64] >> (i % 64)) & 1 == 1
}

#[test]
fn compact_l3_masks_round_trip() {
    // Random masks of five densities, half spaces along each axis, single
    // voxels, and the empty and full masks.
    let mut rng = vdbcook_testkit::Rng::new(7);
    let mut masks: Vec<[u64; 8]> = vec![[0; 8], [u64::MAX; 8]];
    for density in [1u64, 8, 32, 56, 63] {
        for _ in 0..200 {
            masks.push(std::array::from_fn(|_| (0..64).fold(0u64, |m, b| m | (u64::from(rng.below(64) < density) << b))));
        }
    }
    for axis in 0..3 {
        for cut in 1..8 {
            let mut m = [0u64; 8];
            for i in 0..512 {
                let c = [i / 64, (i / 8) % 8, i % 8];
                if c[axis] < cut {
                    m[i / 64] |= 1 << (i % 64);
                }
            }
            masks.push(m);
        }
    }
    for i in 0..512 {
        let mut m = [0u64; 8];
        m[i / 64] |= 1 << (i % 64);
        masks.push(m);
    }
    for mask in &masks {
        let (states, partial) = encode_l3_mask(mask);
        // Each sub-block's state says what its 64 voxels are.
        for b in 0..8 {
            let voxels: Vec<bool> = (0..512).filter(|i| (i / 64 / 4) * 4 + ((i / 8) % 8 / 4) * 2 + (i % 8 / 4) == b).map(|i| bit(mask, i)).collect();
            let want = if voxels.iter().all(|&v| !v) {
                SUB_EMPTY
            } else if voxels.iter().all(|&v| v) {
                SUB_FULL
            } else {
                SUB_PARTIAL
            };
            assert_eq!((states >> (2 * b)) & 3, want, "sub-block {b}");
        }
        assert_eq!(partial.len() as u32, (0..8).filter(|b| (states >> (2 * b)) & 3 == SUB_PARTIAL).count() as u32);
        let words: Vec<u32> = partial.iter().flat_map(|m| [*m as u32, (*m >> 32) as u32]).collect();
        assert_eq!(decode_l3_mask(states, &words), Some(*mask));
        // Bit j of a sub-mask is voxel (x%4)·16 + (y%4)·4 + z%4 of its sub-block.
        for (k, b) in (0..8).filter(|b| (states >> (2 * b)) & 3 == SUB_PARTIAL).enumerate() {
            for j in 0..64 {
                let (x, y, z) = ((b >> 2) * 4 + j / 16, ((b >> 1) & 1) * 4 + (j / 4) % 4, (b & 1) * 4 + j % 4);
                assert_eq!((partial[k] >> j) & 1 == 1, bit(mask, x * 64 + y * 8 + z));
            }
        }
        if !partial.is_empty() {
            assert_eq!(decode_l3_mask(states, &words[..words.len() - 1]), None, "a missing sub-mask word is refused");
        }
    }
    assert_eq!(decode_l3_mask(3, &[0, 0]), None, "state 3 is invalid");
    assert_eq!(decode_l3_mask(1 << 16, &[]), None, "bits past the eight states are invalid");
}

#[test]
fn l3_array_holds_count_nodes_and_sub_masks() {
    // Two leaves: one full (no sub-mask), one with 300 voxels (a partial
    // sub-block or more); the array is the count, two 3-word nodes, and the
    // partial sub-masks of the second; every node reads back.
    let g = grid(vec![leaf(Coord::new(0, 0, 0), 1, 512), leaf(Coord::new(8, 0, 0), 2, 300)], vec![]);
    let mut b = Builder::new(1);
    b.push(&[Some(&g)]).unwrap();
    let built = b.finish().unwrap();
    let n = built.nodes(|id| id).unwrap();
    assert_eq!(n.l3_count(), 2);
    let partial: usize = built.l3.iter().map(|l| encode_l3_mask(&l.mask).1.len()).sum();
    assert!(partial >= 1);
    assert_eq!(n.l3.len(), 1 + 2 * L3_WORDS + 2 * partial);
    for (id, l) in built.l3.iter().enumerate() {
        assert_eq!(n.l3_node(id as u32), Some((l.mask, l.brick)));
    }
    assert_eq!(n.l3_node(2), None);
    // A count the array cannot hold reads as no nodes.
    let mut bad = n.clone();
    bad.l3[0] = 1000;
    assert_eq!((bad.l3_count(), bad.l3_node(0)), (0, None));
    assert_eq!((l3_node_count(&n.l3), l3_node_count(&bad.l3), l3_node_count(&[])), (Some(2), None, None));
}

fn named(name: &str, background: f32, leaves: Vec<Leaf>, tiles: Vec<Tile>) -> Grid {
    Grid { name: name.into(), class: GridClass::FogVolume, background, transform: Transform::identity(), leaves, tiles }
}

/// The value of voxel `i` of channel `c` at leaf `origin`, as a reader of the built tree sees it.
fn read(built: &Built, n: &Nodes, origin: [i32; 3], c: usize, i: usize) -> Option<f32> {
    let (leaves, _) = n.frame_contents(0, usize::MAX, usize::MAX).unwrap();
    let (_, mask, brick) = leaves.into_iter().find(|l| l.0 == origin)?;
    let on = mask[i / 64] >> (i % 64) & 1 == 1;
    Some(if on { built.pool.brick(brick as usize).unwrap()[c][i] } else { built.backgrounds[c] })
}

#[test]
fn channels_share_one_tree_over_the_union_of_their_leaves() {
    // Channel 0 has leaves at A and B, channel 1 (background 0.5) at B and C;
    // at B, channel 1 is active on other voxels than channel 0.
    let (a, b, c) = (Coord::new(0, 0, 0), Coord::new(8, 0, 0), Coord::new(16, 0, 0));
    let d = named("density", 0.0, vec![leaf(a, 1, 512), leaf(b, 2, 100)], vec![]);
    let mut tb = leaf(b, 3, 512);
    for i in 0..50 {
        tb.mask.set(i, false);
    }
    let t = named("temperature", 0.5, vec![tb.clone(), leaf(c, 4, 512)], vec![]);
    let mut builder = Builder::new(2);
    let fs = builder.push(&[Some(&d), Some(&t)]).unwrap();
    assert_eq!(fs.leaves, 3);
    let built = builder.finish().unwrap();
    let n = built.nodes(|id| id).unwrap();
    assert_eq!(built.frames[0].channel_masks.leaves(), 3, "two masks per leaf");
    let src = [[Some(leaf(a, 1, 512)), Some(leaf(b, 2, 100)), None], [None, Some(tb), Some(leaf(c, 4, 512))]];
    for (k, o) in [a, b, c].iter().enumerate() {
        for (ch, per_leaf) in src.iter().enumerate() {
            for i in 0..512 {
                let want = match &per_leaf[k] {
                    Some(l) if l.mask.is_on(i) => l.values[i],
                    _ => built.backgrounds[ch],
                };
                assert_eq!(read(&built, &n, o.to_array(), ch, i), Some(want), "leaf {k} channel {ch} voxel {i}");
            }
        }
    }
    // The union is active where either channel is.
    let (leaves, _) = n.frame_contents(0, usize::MAX, usize::MAX).unwrap();
    let at_b = leaves.iter().find(|l| l.0 == b.to_array()).unwrap();
    assert_eq!(at_b.1.iter().map(|w| w.count_ones()).sum::<u32>(), 512);
    assert_eq!(fs.ranges.len(), 2);
}

#[test]
fn a_tile_over_another_channels_leaf_is_split_and_equal_tiles_merge() {
    // Channel 0: a 128³ tile at the origin and an 8³ tile at (256, 0, 0).
    // Channel 1: one leaf inside channel 0's big tile, and an 8³ tile where channel 0 has one.
    let d = named("density", 0.0, vec![], vec![Tile { origin: Coord::new(0, 0, 0), dim: 128, value: 0.25, active: true }, Tile { origin: Coord::new(256, 0, 0), dim: 8, value: 0.75, active: true }]);
    let t = named("flames", 0.0, vec![leaf(Coord::new(16, 8, 0), 5, 300)], vec![Tile { origin: Coord::new(256, 0, 0), dim: 8, value: 2.0, active: true }]);
    let mut builder = Builder::new(2);
    builder.push(&[Some(&d), Some(&t)]).unwrap();
    let built = builder.finish().unwrap();
    let n = built.nodes(|id| id).unwrap();
    let (leaves, tiles) = n.frame_contents(0, usize::MAX, usize::MAX).unwrap();
    // The big tile became 4095 8³ tiles and the density part of the one leaf.
    assert_eq!(leaves.len(), 1);
    assert_eq!(leaves[0].1, [u64::MAX; 8], "the tile makes every voxel of the leaf active");
    let brick = built.pool.brick(leaves[0].2 as usize).unwrap();
    assert!(brick[0].iter().all(|&v| v == 0.25));
    let src = leaf(Coord::new(16, 8, 0), 5, 300);
    for (i, &v) in brick[1].iter().enumerate() {
        assert_eq!(v, if src.mask.is_on(i) { src.values[i] } else { 0.0 });
    }
    let values: Vec<([i32; 3], u32, Vec<f32>)> = tiles.iter().map(|&(o, d, i)| (o, d, n.tile(i).unwrap())).collect();
    assert_eq!(values.len(), 4096);
    assert!(values.iter().all(|(o, d, v)| *d == 8 && if *o == [256, 0, 0] { v == &vec![0.75, 2.0] } else { v == &vec![0.25, 0.0] }));
    // Active voxels: the whole 128³ tile, the leaf's extra voxels are inside it, plus the 8³ tile.
    assert_eq!(built.frames[0].active_voxels, 128 * 128 * 128 + 512);
}

#[test]
fn a_brick_is_shared_only_when_every_channel_matches() {
    let o = [Coord::new(0, 0, 0), Coord::new(8, 0, 0), Coord::new(16, 0, 0)];
    let d = named("density", 0.0, o.iter().map(|&c| leaf(c, 1, 512)).collect(), vec![]);
    // Channel 1 equal at the first two leaves, different at the third.
    let t = named("temperature", 0.0, vec![leaf(o[0], 7, 512), leaf(o[1], 7, 512), leaf(o[2], 8, 512)], vec![]);
    let mut builder = Builder::new(2);
    builder.push(&[Some(&d), Some(&t)]).unwrap();
    let built = builder.finish().unwrap();
    assert_eq!(built.pool.len(), 2);
    let ids: Vec<u32> = built.frames[0].leaves.iter().map(|l| built.l3[l.1 as usize].brick).collect();
    assert_eq!(ids, vec![0, 0, 1]);
    // A missing channel is an empty one; a frame must give every channel.
    let mut builder = Builder::new(2);
    builder.push(&[None, Some(&t)]).unwrap();
    assert!(matches!(builder.push(&[Some(&d)]), Err(Error::Channels { found: 1, expected: 2 })));
}

#[test]
fn hash_index_tells_apart_items_of_one_hash_and_ignores_other_hashes() {
    let mut index = HashIndex::default();
    index.try_reserve(3, "a test index").unwrap();
    for (h, id) in [(7, 0), (7, 1), (9, 2)] {
        index.add(h, id);
    }
    // Items of one hash are told apart by `same` ...
    assert_eq!(index.find(7, |id| id == 1), Some(1));
    assert_eq!(index.find(7, |id| id == 0), Some(0));
    // ... and an item of another hash is never one of them, whatever `same` says.
    assert_eq!(index.find(7, |id| id == 2), None);
    assert_eq!(index.find(9, |_| true), Some(2));
    assert_eq!(index.find(8, |_| true), None);
    // Past its reservation it grows and still finds every item.
    let hash = |id: u32| twox_hash::XxHash3_64::oneshot(&id.to_le_bytes()) & 0xffff;
    for id in 3..20_000 {
        index.add(hash(id), id);
    }
    assert!((3..20_000).all(|id| index.find(hash(id), |k| k == id) == Some(id)));
}

#[test]
fn l3_nodes_spill_with_the_bricks_and_give_the_same_nodes() {
    let frame = |seed: u32| grid((0..60).map(|i| leaf(Coord::new(8 * (i % 10), 8 * (i / 10), 0), seed + i as u32 % 7, 64 + i as usize)).collect(), Vec::new());
    let build = |spill: Option<SpillPolicy>| {
        let mut b = Builder::new(1);
        b.spill_to(spill);
        for seed in [1, 2, 1, 30] {
            b.push(&[Some(&frame(seed))]).unwrap();
        }
        b.finish().unwrap()
    };
    let (memory, spilled) = (build(None), build(Some(SpillPolicy::new(std::env::temp_dir(), 1))));
    assert!(!memory.l3.is_spilled() && spilled.l3.is_spilled());
    assert_eq!(&spilled.l3[..], &memory.l3[..]);
    assert_eq!(spilled.nodes(|id| id).unwrap(), memory.nodes(|id| id).unwrap());
    // Leaves whose bricks become one (as clustering makes them) become one L3 node.
    let n = memory.nodes(|_| 0).unwrap();
    let distinct_masks: std::collections::HashSet<[u64; 8]> = memory.l3.iter().map(|l| l.mask).collect();
    assert!(memory.l3.len() > distinct_masks.len());
    assert_eq!(n.l3_count(), distinct_masks.len());
}

#[test]
fn the_builders_indexes_and_lists_count_against_the_spill_budget_while_held() {
    let frame = |seed: u32| grid((0..200).map(|i| leaf(Coord::new(8 * (i % 20), 8 * (i / 20), 0), seed * 1000 + i as u32, 100)).collect(), Vec::new());
    // A budget no store reaches: what it holds is the stores and the charges.
    let policy = SpillPolicy::new(std::env::temp_dir(), u64::MAX / 4);
    let mut b = Builder::new(1);
    b.spill_to(Some(policy.clone()));
    for seed in 1..=6 {
        b.push(&[Some(&frame(seed))]).unwrap();
    }
    let stores = |pool: &BrickPool, l3: &Store<L3>| (pool.stored.capacity() * std::mem::size_of::<Brick>() + pool.ranges.capacity() * 8 + l3.capacity() * std::mem::size_of::<L3>()) as u64;
    // 1,200 distinct bricks and L3 nodes: their hashes alone are 19 kB, the leaf lists 19 kB.
    let building = policy.held() - stores(&b.pool, &b.l3);
    assert!(building >= 40_000, "{building} bytes charged while building");
    let built = b.finish().unwrap();
    // The indexes go with the build; the leaf lists and brick slots stay charged with what holds them.
    let kept = policy.held() - stores(&built.pool, &built.l3);
    assert!((19_200..building).contains(&kept), "{kept} bytes charged after the build ({building} while building)");
    drop(built);
    assert_eq!(policy.held(), 0);
}

#[test]
fn the_pool_records_each_stored_bricks_range_as_it_is_made() {
    // Duplicates inside a batch and across frames move the bricks being
    // pooled; a second channel is constant at some positions, and some
    // values are not finite.
    let frame = |seed: u32| {
        let mut leaves: Vec<Leaf> =
            (0..300).map(|i| leaf(Coord::new(8 * (i % 30), 8 * (i / 30), 0), if i % 4 == 0 { seed } else { seed * 1000 + i as u32 }, if i % 3 == 0 { 512 } else { 200 })).collect();
        leaves[7].values[3] = f32::INFINITY;
        leaves[9].values[0] = f32::NAN;
        grid(leaves, Vec::new())
    };
    let other = |seed: u32| grid((0..150).map(|i| leaf(Coord::new(8 * (i % 30), 8 * (i / 30), 0), seed + i as u32, 300)).collect(), Vec::new());
    for (channels, spill) in [(1, None), (2, None), (1, Some(SpillPolicy::new(std::env::temp_dir(), 1)))] {
        let spilled = spill.is_some();
        let mut b = Builder::new(channels);
        b.spill_to(spill);
        for seed in [3, 4, 3] {
            let (g, o) = (frame(seed), other(seed));
            let grids: Vec<Option<&Grid>> = [Some(&g), Some(&o)].into_iter().take(channels).collect();
            b.push(&grids).unwrap();
        }
        let built = b.finish().unwrap();
        // Recorded, one per stored brick (else the view takes them anew).
        assert_eq!(built.pool.ranges.len(), built.pool.stored.len());
        assert_eq!(built.pool.stored.is_spilled(), spilled);
        let view = built.pool.bricks();
        assert!(view.len() > 300);
        for i in 0..view.len() {
            for c in 0..channels {
                let (r, taken) = (view.range(i, c), vdbcook_grid::range_of(view.get(i, c)));
                assert_eq!(r.map(f32::to_bits), taken.map(f32::to_bits), "brick {i} channel {c} of {channels}");
            }
        }
    }
}
