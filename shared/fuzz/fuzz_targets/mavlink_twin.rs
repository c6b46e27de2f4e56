//! MAVLink from the companion into the twin's ArduSub stand-in (`vehicle_twin::ardusub::wire`):
//! a datagram scanned into frames, each frame's message decoded.
#![no_main]
use libfuzzer_sys::fuzz_target;
use vehicle_twin::ardusub::wire;

fuzz_target!(|data: &[u8]| {
    let mut refused = wire::Refused::default();
    for frame in wire::scan(data, &mut refused) {
        let _ = frame.message();
        let _ = wire::CommandLong::decode(&frame.payload);
    }
    assert!(refused.garbage_bytes <= data.len() as u64);
});
