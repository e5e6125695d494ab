//! Any byte string through the runtime reader (`vdbcook_vpak::runtime`), the
//! way an engine opens a file: the tables and metadata at open, then every
//! segment filled into reused buffers and as an `Asset`, and the whole-file
//! check. A bad file must be an error, never a panic or an allocation sized
//! by what it claims.
#![no_main]
use libfuzzer_sys::fuzz_target;
use vdbcook_vpak::runtime::{Reader, SectionBuffers};

fuzz_target!(|data: &[u8]| {
    let Ok(reader) = Reader::new(data.to_vec()) else { return };
    let meta = reader.metadata();
    for f in 0..reader.frame_count().min(4) {
        let _ = (reader.locate(f), meta.frame_number(f));
    }
    let mut buffers = SectionBuffers::default();
    for s in 0..reader.segment_count().min(4) {
        let _ = reader.fill_buffers(s, &mut buffers);
        if let Ok(asset) = reader.segment_asset(s, Vec::new()) {
            let _ = vdbcook_vpak::Checked::new(&asset);
        }
    }
    let _ = reader.check();
});
