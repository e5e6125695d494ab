//! Any byte string through the whole reader: parse, then every readable grid
//! (scalar, and vec3 as its three channels).
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(file) = vdbcook_vdb::VdbFile::parse(data.to_vec()) {
        for i in 0..file.grids.len() {
            if let Ok(grids) = file.read_channels(i) {
                for g in grids {
                    let _ = g.stats();
                }
            }
        }
    }
});
