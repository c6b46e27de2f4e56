//! The supervisor's mesh files (`config/*-mesh.toml`, `config/vehicle.toml`): parsed, then every
//! service's command line built from them.
#![no_main]
use libfuzzer_sys::fuzz_target;
use std::collections::BTreeMap;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let path = Path::new("fuzz-mesh.toml");
    if let Ok(mesh) = supervisor::MeshFile::parse(text, path) {
        let _ = mesh.commands(&BTreeMap::new(), path);
    }
});
