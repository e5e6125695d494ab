//! Any byte string as a .vpak asset, checksums not verified (so every byte is
//! reachable): the section table, the metadata, and unpacking the first frames.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(asset) = vdbcook_vpak::Asset::from_bytes(data) {
        if let Ok(meta) = asset.metadata() {
            for frame in 0..(meta.frame_count as usize).min(3) {
                if let Ok(g) = vdbcook_cook::unpack_frame(&asset, frame) {
                    let _ = g.stats();
                }
            }
        }
    }
});
