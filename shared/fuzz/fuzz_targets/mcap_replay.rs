//! A flight record given to replay (`replay::Frames` over the recorder's MCAP reader): every frame
//! and output read, or an error.
#![no_main]
use cabletrack_fuzz::TempFile;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let file = TempFile::new("record.mcap", data);
    if let Ok(frames) = replay::Frames::open(&file.path) {
        let _ = frames.finish();
    }
});
