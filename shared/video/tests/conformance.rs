//! The RTP camera passes the frame-source conformance suite: its rig sends the suite's frames as
//! RTP/H.264 through the twin's sender on loopback, and the source decodes them.
//!
//! The suite checks every image bit for bit, which lossy H.264 cannot give; the rig encodes
//! losslessly (x264 at quantizer 0, which the decoder gives back exactly): the suite is unchanged,
//! and the lossy path is checked against its own measure in `stream.rs`.
#![cfg(feature = "gstreamer")]

use adapters::conformance::{self, SourceRig};
use adapters::{AdapterError, Frame};
use std::time::Duration;
use video::meta::WireMeta;
use video::sender::{Encoding, RtpSender, SenderConfig};
use video::source::{RtpSource, SourceConfig, Watch};

/// How long a frame may take from the sender through the decoder on a busy machine.
const DECODED_WITHIN: Duration = Duration::from_secs(20);

struct RtpRig {
    frames: Vec<Frame>,
    sender: Option<RtpSender>,
    watch: Option<Watch>,
    seed: u64,
}

impl RtpRig {
    fn new() -> Self {
        RtpRig {
            frames: Vec::new(),
            sender: None,
            watch: None,
            seed: 1,
        }
    }

    /// A source of 40x30 frames on a free loopback port, and a lossless sender to it.
    fn open_pair(&mut self, size: (u32, u32)) -> RtpSource {
        let source = RtpSource::open(SourceConfig::new(
            "127.0.0.1:0".parse().unwrap(),
            size.0,
            size.1,
        ))
        .expect("an RTP source on loopback");
        let mut config = SenderConfig::new(source.local_addr(), size);
        config.encoding = Encoding::Lossless;
        config.seed = self.seed;
        self.seed += 1;
        self.sender = Some(RtpSender::open(config).expect("a lossless sender"));
        self.watch = Some(source.watch());
        source
    }

    /// Sends a frame and waits until the source's decoder gave a picture for it.
    fn send(&mut self, meta: Option<&WireMeta>, image: &[u8]) {
        let watch = self.watch.as_ref().expect("opened");
        let before = watch.stats().decoded;
        self.sender
            .as_mut()
            .expect("opened")
            .send_wire(meta, image)
            .expect("sent");
        watch
            .wait_for(DECODED_WITHIN, |s| s.decoded > before)
            .unwrap_or_else(|| {
                panic!(
                    "the frame was not decoded within {DECODED_WITHIN:?}: {:?}",
                    watch.stats()
                )
            });
    }

    /// Datagrams sent as they are, then nothing else.
    fn send_datagrams(&self, datagrams: &[Vec<u8>]) {
        let socket = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
        let to = self.sender.as_ref().unwrap().config().destination;
        for d in datagrams {
            socket.send_to(d, to).unwrap();
        }
    }
}

const BAD: [&str; 4] = [
    "datagrams that are not RTP",
    "RTP packets of another payload type",
    "truncated RTP packets",
    "an unknown status in the frame metadata",
];

impl SourceRig for RtpRig {
    type Source = RtpSource;

    fn name(&self) -> String {
        "rtp camera".into()
    }

    fn live(&self) -> bool {
        true
    }

    fn speed(&self) -> Option<f64> {
        None
    }

    fn open(&mut self, frames: &[Frame]) -> Result<RtpSource, AdapterError> {
        self.frames = frames.to_vec();
        let size = (frames[0].meta.width, frames[0].meta.height);
        Ok(self.open_pair(size))
    }

    fn deliver(&mut self, k: usize) {
        let f = self.frames[k].clone();
        self.send(Some(&WireMeta::of(&f.meta)), &f.image);
    }

    fn bad_inputs(&self) -> Vec<String> {
        BAD.iter().map(|s| s.to_string()).collect()
    }

    fn open_bad(&mut self, k: usize) -> Result<RtpSource, AdapterError> {
        let good = conformance::sample_frames(40, 30).remove(0);
        let source = self.open_pair((40, 30));
        let mut rtp = vec![0x80, 97, 0, 1, 0, 0, 0, 0, 0, 0, 0, 9];
        rtp.extend_from_slice(&[0x65, 1, 2, 3]);
        match k {
            0 => self.send_datagrams(&[b"hello".to_vec(), vec![0x40; 100], vec![0xFF; 1400]]),
            1 => self.send_datagrams(&[rtp.clone(), rtp]),
            2 => self.send_datagrams(&[rtp[..7].to_vec(), {
                let mut t = rtp.clone();
                t[0] |= 0x0F;
                t
            }]),
            3 => {
                let mut m = WireMeta::of(&good.meta);
                m.status = 7;
                self.send(Some(&m), &good.image);
            }
            _ => unreachable!(),
        }
        let mut next = good.meta;
        next.seq += 1;
        next.time_ns += 200_000_000;
        self.send(Some(&WireMeta::of(&next)), &good.image);
        Ok(source)
    }
}

#[test]
fn the_rtp_camera_conforms() {
    conformance::frame_source(&mut RtpRig::new());
}
