//! Any byte string through the blosc decoder, with the expected size taken
//! from the first two bytes (as OpenVDB's callers know it from the tree).
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if data.len() < 2 {
        return;
    }
    let expected = usize::from(u16::from_le_bytes([data[0], data[1]]));
    let _ = vdbcook_blosc::decompress(&data[2..], expected);
});
