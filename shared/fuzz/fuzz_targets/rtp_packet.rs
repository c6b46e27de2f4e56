//! One RTP datagram from the camera (`video::rtp`): the packet, its header extension's elements
//! (the frame metadata, `video::meta`) and its H.264 payload (`video::h264`).
#![no_main]
use libfuzzer_sys::fuzz_target;
use video::{h264, meta, rtp};

fuzz_target!(|data: &[u8]| {
    let Ok(packet) = rtp::Packet::parse(data) else {
        let _ = meta::WireMeta::decode(data);
        return;
    };
    let _ = packet.csrcs().count();
    let _ = packet.extension_profile();
    for id in 0..16 {
        if let Some(element) = packet.extension(id) {
            if let Ok(Some(m)) = meta::WireMeta::decode(element) {
                let _ = m.frame_meta(320, 240);
            }
        }
    }
    let mut depacketiser = h264::Depacketiser::new();
    let _ = depacketiser.push(packet.payload);
    let _ = h264::nal_units(&depacketiser.finish()).count();
});
