//! A stream of RTP datagrams from the camera (`video::stream::Receiver`): sessions, reordering,
//! loss, fragments and access units. Each datagram is a 2-byte length, its arrival 0 to 255 ms after
//! the previous one, then its bytes.
#![no_main]
use libfuzzer_sys::fuzz_target;
use std::time::{Duration, Instant};
use video::stream::{Receiver, StreamConfig};

fuzz_target!(|data: &[u8]| {
    let mut receiver = Receiver::new(StreamConfig {
        // Small, so the fuzzer reaches the cut of an oversized access unit.
        max_access_unit: 4096,
        ..StreamConfig::default()
    });
    let mut events = Vec::new();
    let mut now = Instant::now();
    let mut rest = data;
    while rest.len() >= 3 {
        let len = usize::from(u16::from_le_bytes([rest[0], rest[1]])).min(rest.len() - 3);
        now += Duration::from_millis(u64::from(rest[2]));
        let datagram = &rest[3..3 + len];
        rest = &rest[3 + len..];
        receiver.push(datagram, now, &mut events);
        if events.len() > 64 {
            events.clear();
        }
    }
    receiver.flush(&mut events);
    let counts = receiver.counts();
    assert!(counts.bytes <= data.len() as u64);
});
