//! MAVLink from the autopilot (`ardusub::wire::Deframer`): the first byte says how the rest arrives,
//! as datagrams (UDP) or a stream cut into pieces (TCP).
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Some((&mode, rest)) = data.split_first() else {
        return;
    };
    let mut deframer = ardusub::wire::Deframer::new();
    if mode & 1 == 0 {
        // Datagrams separated where a byte 0x55 0xAA pair stands.
        for datagram in split(rest) {
            let _ = deframer.datagram(datagram);
        }
    } else {
        // A stream in pieces of (mode >> 1) + 1 bytes.
        for piece in rest.chunks(usize::from(mode >> 1) + 1) {
            deframer.push(piece);
            while deframer.next_frame().is_some() {}
        }
    }
    let counts = deframer.counts();
    assert!(counts.garbage_bytes <= rest.len() as u64);
});

fn split(data: &[u8]) -> impl Iterator<Item = &[u8]> {
    let mut rest = data;
    std::iter::from_fn(move || {
        if rest.is_empty() {
            return None;
        }
        let cut = rest.windows(2).position(|w| w == [0x55, 0xAA]);
        let (head, tail) = match cut {
            Some(i) => (&rest[..i], &rest[i + 2..]),
            None => (rest, &rest[rest.len()..]),
        };
        rest = tail;
        Some(head)
    })
}
