//! A behaviour's checkpoint file (`learning::checkpoint`): any bytes must load or be refused.
#![no_main]
use cabletrack_fuzz::TempFile;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let file = TempFile::new("sway.ckpt", data);
    if let Ok(checkpoint) = learning::checkpoint::Checkpoint::load(&file.path) {
        // What loads must save and load again unchanged.
        let again = TempFile::new("again.ckpt", b"");
        checkpoint
            .save(&again.path)
            .expect("a loaded checkpoint saves");
        let reloaded = learning::checkpoint::Checkpoint::load(&again.path).expect("reloads");
        assert_eq!(format!("{checkpoint:?}"), format!("{reloaded:?}"));
    }
});
