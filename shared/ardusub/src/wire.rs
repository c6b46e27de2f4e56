//! MAVLink frames on the wire: bytes to messages and back, counting what is refused.
//!
//! The `mavlink` crate's readers skip a frame whose checksum fails without a word; an adapter must
//! say how much of its link is broken. [`Deframer`] splits bytes into frames itself (MAVLink 1 and
//! 2, signed frames accepted unverified), checks each frame's CRC with the dialect's CRC_EXTRA and
//! hands the payload to the crate's parser. What it cannot use is counted ([`WireCounts`]) and
//! skipped: scanning resumes at the byte after a refused frame's start, so a frame hidden behind
//! garbage is still found. A pure state machine: bytes in, frames out.

use mavlink::dialects::ardupilotmega::MavMessage;
use mavlink::{MAVLinkV2MessageRaw, MavHeader, MavlinkVersion, Message};

/// MAVLink 1's start marker.
const STX_V1: u8 = 0xFE;
/// MAVLink 2's start marker.
const STX_V2: u8 = 0xFD;
/// MAVLink 2's incompatibility flag for a signed frame (13 bytes of signature follow the CRC).
const SIGNED: u8 = 0x01;
const SIGNATURE_LEN: usize = 13;

/// A frame received whole: who sent it and what.
#[derive(Clone, Debug, PartialEq)]
pub struct Frame {
    pub system: u8,
    pub component: u8,
    pub sequence: u8,
    pub message: MavMessage,
}

/// What a [`Deframer`] has seen so far.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct WireCounts {
    /// Frames whole and decoded.
    pub frames: u64,
    /// Bytes outside any frame (no start marker where a frame should begin).
    pub garbage_bytes: u64,
    /// Frames whose checksum failed (corrupted on the way, or not MAVLink at all).
    pub bad_crc: u64,
    /// Frames of a message this dialect does not know (their checksum cannot be checked).
    pub unknown: u64,
    /// Frames with a good checksum whose payload does not decode (a value outside its enum), or
    /// with incompatibility flags this reader does not support.
    pub undecodable: u64,
    /// Frames cut short: a datagram ended inside one.
    pub truncated: u64,
}

impl WireCounts {
    /// Frames refused: broken, undecodable or cut short. Unknown messages are not refused: a newer
    /// autopilot may send messages this dialect lacks.
    pub fn refused(&self) -> u64 {
        self.bad_crc + self.undecodable + self.truncated
    }
}

impl std::fmt::Display for WireCounts {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} frames, refused {} (bad CRC {}, undecodable {}, truncated {}), {} bytes of garbage, {} of unknown messages",
            self.frames,
            self.refused(),
            self.bad_crc,
            self.undecodable,
            self.truncated,
            self.garbage_bytes,
            self.unknown
        )
    }
}

/// Splits a byte stream (TCP) or datagrams (UDP) into frames.
#[derive(Default)]
pub struct Deframer {
    buf: Vec<u8>,
    counts: WireCounts,
    /// The bytes end with the current datagram: a frame still incomplete never will be.
    ending: bool,
}

/// What the frame at the start of a buffer is.
enum Candidate {
    /// More bytes are needed.
    Incomplete,
    /// Not a frame: skip its first byte.
    Refused,
    /// A whole frame of `len` bytes.
    Whole {
        len: usize,
        frame: Option<Box<Frame>>,
    },
}

impl Deframer {
    pub fn new() -> Self {
        Deframer::default()
    }

    pub fn counts(&self) -> WireCounts {
        self.counts
    }

    /// Appends bytes received on a stream (TCP); [`Deframer::next_frame`] then yields its frames.
    pub fn push(&mut self, bytes: &[u8]) {
        self.buf.extend_from_slice(bytes);
    }

    /// The frames of one datagram (UDP), which holds whole frames only: a frame it cuts short is
    /// refused (and a frame behind its start still found), and nothing is carried to the next.
    pub fn datagram(&mut self, bytes: &[u8]) -> Vec<Frame> {
        self.buf.clear();
        self.push(bytes);
        self.ending = true;
        let mut out = Vec::new();
        while let Some(f) = self.next_frame() {
            out.push(f);
        }
        self.ending = false;
        out
    }

    /// The next whole frame in the bytes pushed so far; `None` when more bytes are needed.
    pub fn next_frame(&mut self) -> Option<Frame> {
        loop {
            let start = self.buf.iter().position(|&b| b == STX_V1 || b == STX_V2);
            let Some(start) = start else {
                self.counts.garbage_bytes += self.buf.len() as u64;
                self.buf.clear();
                return None;
            };
            if start > 0 {
                self.counts.garbage_bytes += start as u64;
                self.buf.drain(..start);
            }
            match self.candidate() {
                Candidate::Incomplete if self.ending => {
                    self.counts.truncated += 1;
                    self.buf.drain(..1);
                }
                Candidate::Incomplete => return None,
                Candidate::Refused => {
                    // Resume at the next byte: a real frame may start inside this one.
                    self.buf.drain(..1);
                }
                Candidate::Whole { len, frame } => {
                    self.buf.drain(..len);
                    if let Some(frame) = frame {
                        self.counts.frames += 1;
                        return Some(*frame);
                    }
                }
            }
        }
    }

    /// Judges the frame that starts at `buf[0]` (a start marker).
    fn candidate(&mut self) -> Candidate {
        let b = &self.buf;
        let v2 = b[0] == STX_V2;
        // Marker, length, then the rest of the header: MAVLink 2's is 9 bytes, MAVLink 1's 4.
        let header = if v2 { 10 } else { 6 };
        if b.len() < 3 {
            return Candidate::Incomplete;
        }
        let payload_len = b[1] as usize;
        let flags = if v2 { b[2] } else { 0 };
        if flags & !SIGNED != 0 {
            // Flags this reader does not know (a 32-bit system id...): it cannot be parsed safely.
            self.counts.undecodable += 1;
            return Candidate::Refused;
        }
        let signature = if flags & SIGNED != 0 {
            SIGNATURE_LEN
        } else {
            0
        };
        let len = header + payload_len + 2 + signature;
        if b.len() < len {
            return Candidate::Incomplete;
        }
        let (sequence, system, component, id) = if v2 {
            (b[4], b[5], b[6], u32::from_le_bytes([b[7], b[8], b[9], 0]))
        } else {
            (b[2], b[3], b[4], b[5] as u32)
        };
        if MavMessage::default_message_from_id(id).is_none() {
            // Unknown here: its CRC cannot be checked, so it may as well be garbage. Skip only its
            // marker; if it was a real frame, its bytes are scanned (and counted) as garbage.
            self.counts.unknown += 1;
            return Candidate::Refused;
        }
        let crc_at = header + payload_len;
        let expected = u16::from_le_bytes([b[crc_at], b[crc_at + 1]]);
        if mavlink::calculate_crc(&b[1..crc_at], MavMessage::extra_crc(id)) != expected {
            self.counts.bad_crc += 1;
            return Candidate::Refused;
        }
        let version = if v2 {
            MavlinkVersion::V2
        } else {
            MavlinkVersion::V1
        };
        match MavMessage::parse(version, id, &b[header..crc_at]) {
            Ok(message) => Candidate::Whole {
                len,
                frame: Some(Box::new(Frame {
                    system,
                    component,
                    sequence,
                    message,
                })),
            },
            Err(_) => {
                self.counts.undecodable += 1;
                Candidate::Whole { len, frame: None }
            }
        }
    }
}

/// `message` as a MAVLink 2 frame from `system`/`component`, numbered `sequence`.
pub fn encode(system: u8, component: u8, sequence: u8, message: &MavMessage) -> Vec<u8> {
    let mut raw = MAVLinkV2MessageRaw::new();
    raw.serialize_message(
        MavHeader {
            system_id: system as u32,
            component_id: component,
            sequence,
        },
        message,
    );
    raw.raw_bytes().to_vec()
}

/// The message's name, for logs.
pub fn name(message: &MavMessage) -> &'static str {
    message.message_name()
}

#[cfg(test)]
mod tests {
    use super::*;
    use mavlink::dialects::ardupilotmega::{
        HEARTBEAT_DATA, MANUAL_CONTROL_DATA, MavAutopilot, MavModeFlag, MavState, MavType,
    };

    fn heartbeat() -> MavMessage {
        MavMessage::HEARTBEAT(HEARTBEAT_DATA {
            custom_mode: 19,
            mavtype: MavType::MAV_TYPE_SUBMARINE,
            autopilot: MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA,
            base_mode: MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
            system_status: MavState::MAV_STATE_STANDBY,
            mavlink_version: 3,
        })
    }

    fn manual(x: i16) -> MavMessage {
        MavMessage::MANUAL_CONTROL(MANUAL_CONTROL_DATA {
            x,
            y: -3,
            z: 500,
            r: 7,
            target: 1,
            ..Default::default()
        })
    }

    /// Bytes with neither start marker: garbage that cannot be mistaken for a frame's start.
    const GARBAGE: &[u8] = b"not a MAVLink frame at all";

    #[test]
    fn frames_round_trip_through_a_stream_cut_anywhere() {
        let mut bytes = encode(1, 1, 7, &heartbeat());
        bytes.extend(encode(254, 191, 8, &manual(-1000)));
        // Fed one byte at a time, as a slow TCP stream might deliver them.
        let mut d = Deframer::new();
        let mut got = Vec::new();
        for b in &bytes {
            d.push(std::slice::from_ref(b));
            while let Some(f) = d.next_frame() {
                got.push(f);
            }
        }
        assert_eq!(got.len(), 2);
        assert_eq!(
            (got[0].system, got[0].component, got[0].sequence),
            (1, 1, 7)
        );
        assert_eq!(got[0].message, heartbeat());
        assert_eq!((got[1].system, got[1].component), (254, 191));
        assert_eq!(got[1].message, manual(-1000));
        assert_eq!(
            d.counts(),
            WireCounts {
                frames: 2,
                ..Default::default()
            }
        );
    }

    #[test]
    fn garbage_and_broken_checksums_are_counted_and_skipped() {
        let good = encode(1, 1, 0, &heartbeat());
        let mut broken = good.clone();
        // A payload byte flipped (the custom mode): the checksum no longer matches.
        broken[10] ^= 0x40;
        let mut bytes = GARBAGE.to_vec();
        bytes.extend(&broken);
        bytes.extend(GARBAGE);
        bytes.extend(&good);
        let mut d = Deframer::new();
        let got = d.datagram(&bytes);
        assert_eq!(got.len(), 1, "the good frame behind the broken one");
        assert_eq!(got[0].message, heartbeat());
        let c = d.counts();
        assert_eq!(c.frames, 1);
        assert_eq!(c.bad_crc, 1, "{c}");
        assert_eq!(c.refused(), 1, "{c}");
        // The garbage, and the broken frame's bytes after its marker (none of them a marker).
        assert!(!broken[1..].iter().any(|&b| b == STX_V1 || b == STX_V2));
        assert_eq!(
            c.garbage_bytes,
            2 * GARBAGE.len() as u64 + broken.len() as u64 - 1,
            "{c}"
        );
    }

    #[test]
    fn a_frame_cut_by_the_end_of_a_datagram_is_dropped_and_the_next_one_read() {
        let good = encode(1, 1, 0, &heartbeat());
        let cut = &good[..good.len() - 3];
        assert!(!cut[1..].iter().any(|&b| b == STX_V1 || b == STX_V2));
        let mut d = Deframer::new();
        assert_eq!(d.datagram(cut), vec![], "incomplete");
        assert_eq!(d.counts().truncated, 1);
        assert_eq!(d.counts().garbage_bytes, cut.len() as u64 - 1);
        let got = d.datagram(&good);
        assert_eq!(got.len(), 1);
        assert_eq!(got[0].message, heartbeat());
        assert_eq!(d.counts().refused(), 1);
        assert_eq!(d.counts().frames, 1);
        // On a stream, the same cut frame waits for the rest of its bytes.
        let mut s = Deframer::new();
        s.push(cut);
        assert_eq!(s.next_frame(), None);
        s.push(&good[cut.len()..]);
        assert_eq!(s.next_frame().map(|f| f.message), Some(heartbeat()));
        assert_eq!(s.counts().refused(), 0);
    }

    #[test]
    fn random_bytes_never_panic_and_never_hide_a_frame_behind_them() {
        // A deterministic generator: every byte value, markers included, in odd places.
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        let good = encode(1, 1, 3, &manual(250));
        let mut d = Deframer::new();
        for round in 0..300 {
            let noise: Vec<u8> = (0..(next() % 600)).map(|_| next() as u8).collect();
            assert_eq!(
                d.datagram(&noise),
                vec![],
                "round {round}: noise taken for a frame"
            );
            // A frame in the next datagram is read whole, and so is one behind noise in the same.
            let got = d.datagram(&good);
            assert_eq!(got.len(), 1, "round {round}");
            let mut both = noise.clone();
            both.extend(&good);
            let got = d.datagram(&both);
            assert_eq!(
                got.last().map(|f| &f.message),
                Some(&manual(250)),
                "round {round}"
            );
        }
        assert!(d.counts().refused() > 0);
    }

    #[test]
    fn unsupported_flags_and_unknown_messages_are_not_taken_for_frames() {
        let mut d = Deframer::new();
        let mut flagged = encode(1, 1, 0, &heartbeat());
        flagged[2] = 0x02;
        assert_eq!(d.datagram(&flagged), vec![]);
        assert_eq!(d.counts().undecodable, 1);
        // A message id no dialect has (0xABCDEF).
        let mut unknown = encode(1, 1, 0, &heartbeat());
        unknown[7..10].copy_from_slice(&[0xEF, 0xCD, 0xAB]);
        let mut d = Deframer::new();
        assert_eq!(d.datagram(&unknown), vec![]);
        assert_eq!(d.counts().unknown, 1);
        assert_eq!(d.counts().frames, 0);
    }

    #[test]
    fn mavlink_1_and_signed_frames_are_read() {
        // MAVLink 1 as the crate writes it.
        let mut v1 = Vec::new();
        mavlink::write_v1_msg(
            &mut v1,
            MavHeader {
                system_id: 1,
                component_id: 1,
                sequence: 9,
            },
            &heartbeat(),
        )
        .unwrap();
        let mut d = Deframer::new();
        d.push(&v1);
        let f = d.next_frame().expect("a MAVLink 1 frame");
        assert_eq!((f.message, f.sequence), (heartbeat(), 9));
        // A signed MAVLink 2 frame (the signature is not verified: ArduSub signs only when set up to).
        let mut signed = encode(1, 1, 0, &heartbeat());
        signed[2] = SIGNED;
        let crc_at = signed.len() - 2;
        let crc = mavlink::calculate_crc(&signed[1..crc_at], MavMessage::extra_crc(0));
        signed[crc_at..].copy_from_slice(&crc.to_le_bytes());
        signed.extend([0u8; SIGNATURE_LEN]);
        d.push(&signed);
        assert_eq!(d.next_frame().map(|f| f.message), Some(heartbeat()));
        assert_eq!(d.counts().refused(), 0);
    }
}
