//! MAVLink on the wire, as the stand-in autopilot reads and writes it: datagrams scanned into frames
//! (MAVLink 1 and 2), every frame's checksum checked with its message's CRC_EXTRA, garbage and broken
//! frames counted and skipped, never a panic; and frames written as MAVLink 2.
//!
//! The messages themselves are the `mavlink` crate's (the ardupilotmega dialect); the framing is
//! done here so that what is refused is counted (the crate's reader skips a broken frame silently).

use mavlink::dialects::ardupilotmega::MavMessage;
use mavlink::{MavlinkVersion, Message};

const STX_V1: u8 = 0xFE;
const STX_V2: u8 = 0xFD;
/// MAVLink 2's incompatibility flag for a signed frame (13 bytes of signature follow the checksum).
const IFLAG_SIGNED: u8 = 0x01;
const SIGNATURE_LEN: usize = 13;

/// One frame whose checksum is right.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Frame {
    pub version: MavlinkVersion,
    pub sequence: u8,
    pub system_id: u8,
    pub component_id: u8,
    pub message_id: u32,
    pub payload: Vec<u8>,
}

impl Frame {
    /// The message, when the dialect knows it and its fields are valid.
    pub fn message(&self) -> Result<MavMessage, mavlink::error::ParserError> {
        MavMessage::parse(self.version, self.message_id, &self.payload)
    }
}

/// What a scan refused, by kind.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Refused {
    /// Bytes that were not part of any frame.
    pub garbage_bytes: u64,
    /// Frames whose checksum did not match.
    pub bad_crc: u64,
    /// Frames cut short by the datagram's end.
    pub truncated: u64,
    /// Frames of a message the dialect does not know (their checksum cannot be checked).
    pub unknown: u64,
    /// MAVLink 2 frames with incompatibility flags the twin does not support.
    pub unsupported: u64,
}

impl Refused {
    pub fn total(&self) -> u64 {
        self.garbage_bytes + self.bad_crc + self.truncated + self.unknown + self.unsupported
    }

    pub fn add(&mut self, other: &Refused) {
        self.garbage_bytes += other.garbage_bytes;
        self.bad_crc += other.bad_crc;
        self.truncated += other.truncated;
        self.unknown += other.unknown;
        self.unsupported += other.unsupported;
    }
}

fn known(message_id: u32) -> bool {
    MavMessage::default_message_from_id(message_id).is_some()
}

/// The frames of one datagram, in order; what is not a good frame is counted in `refused`. A byte
/// that starts a frame whose checksum fails is skipped alone, so a frame hidden behind it is found.
pub fn scan(datagram: &[u8], refused: &mut Refused) -> Vec<Frame> {
    let mut frames = Vec::new();
    let mut i = 0;
    while i < datagram.len() {
        let rest = &datagram[i..];
        let (header, version) = match rest[0] {
            STX_V2 => (10, MavlinkVersion::V2),
            STX_V1 => (6, MavlinkVersion::V1),
            _ => {
                refused.garbage_bytes += 1;
                i += 1;
                continue;
            }
        };
        // A frame running past the datagram's end: cut short, or a stray start byte; either way
        // the byte is skipped alone and the scan goes on.
        if rest.len() < header {
            refused.truncated += 1;
            refused.garbage_bytes += 1;
            i += 1;
            continue;
        }
        let len = rest[1] as usize;
        let (flags, message_id, seq, sys, comp) = match version {
            MavlinkVersion::V2 => (
                rest[2],
                u32::from_le_bytes([rest[7], rest[8], rest[9], 0]),
                rest[4],
                rest[5],
                rest[6],
            ),
            MavlinkVersion::V1 => (0, rest[5] as u32, rest[2], rest[3], rest[4]),
        };
        let signature = if flags & IFLAG_SIGNED != 0 {
            SIGNATURE_LEN
        } else {
            0
        };
        let total = header + len + 2 + signature;
        if rest.len() < total {
            refused.truncated += 1;
            refused.garbage_bytes += 1;
            i += 1;
            continue;
        }
        if flags & !IFLAG_SIGNED != 0 {
            refused.unsupported += 1;
            i += total;
            continue;
        }
        if !known(message_id) {
            refused.unknown += 1;
            i += total;
            continue;
        }
        let crc = u16::from_le_bytes([rest[header + len], rest[header + len + 1]]);
        let extra = MavMessage::extra_crc(message_id);
        if mavlink::calculate_crc(&rest[1..header + len], extra) != crc {
            refused.bad_crc += 1;
            refused.garbage_bytes += 1;
            i += 1;
            continue;
        }
        frames.push(Frame {
            version,
            sequence: seq,
            system_id: sys,
            component_id: comp,
            message_id,
            payload: rest[header..header + len].to_vec(),
        });
        i += total;
    }
    frames
}

/// A MAVLink 2 frame of `payload` (trailing zeros already removed or not: they are removed here, as
/// MAVLink 2 does, keeping at least one byte).
pub fn frame_v2(
    sequence: u8,
    system_id: u8,
    component_id: u8,
    message_id: u32,
    payload: &[u8],
) -> Vec<u8> {
    let mut len = payload.len();
    while len > 1 && payload[len - 1] == 0 {
        len -= 1;
    }
    let mut out = Vec::with_capacity(12 + len);
    let id = message_id.to_le_bytes();
    out.extend_from_slice(&[
        STX_V2,
        len as u8,
        0,
        0,
        sequence,
        system_id,
        component_id,
        id[0],
        id[1],
        id[2],
    ]);
    out.extend_from_slice(&payload[..len]);
    let crc = mavlink::calculate_crc(&out[1..], MavMessage::extra_crc(message_id));
    out.extend_from_slice(&crc.to_le_bytes());
    out
}

/// The MAVLink 2 payload of a message.
pub fn payload(message: &MavMessage) -> Vec<u8> {
    let mut buf = [0u8; 280];
    let n = message.ser(MavlinkVersion::V2, &mut buf);
    buf[..n].to_vec()
}

/// COMMAND_LONG's fields, read from the payload itself: the dialect's enum cannot hold a command
/// it does not know, and an unknown command still deserves its COMMAND_ACK (UNSUPPORTED).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CommandLong {
    pub params: [f32; 7],
    pub command: u16,
    pub target_system: u8,
    pub target_component: u8,
}

/// COMMAND_LONG's message id.
pub const COMMAND_LONG: u32 = 76;
/// COMMAND_ACK's message id.
pub const COMMAND_ACK: u32 = 77;

impl CommandLong {
    pub fn decode(payload: &[u8]) -> CommandLong {
        let mut p = [0u8; 33];
        let n = payload.len().min(33);
        p[..n].copy_from_slice(&payload[..n]);
        let f = |k: usize| f32::from_le_bytes([p[4 * k], p[4 * k + 1], p[4 * k + 2], p[4 * k + 3]]);
        CommandLong {
            params: [f(0), f(1), f(2), f(3), f(4), f(5), f(6)],
            command: u16::from_le_bytes([p[28], p[29]]),
            target_system: p[30],
            target_component: p[31],
        }
    }
}

/// COMMAND_ACK's payload for any command number (ArduPilot acknowledges SET_MODE, a message, with
/// its message id 11 as the command, which the dialect's command enum cannot hold).
pub fn command_ack_payload(
    command: u16,
    result: u8,
    target_system: u8,
    target_component: u8,
) -> Vec<u8> {
    let c = command.to_le_bytes();
    // command, result, progress, result_param2 (i32), target_system, target_component
    vec![
        c[0],
        c[1],
        result,
        0,
        0,
        0,
        0,
        0,
        target_system,
        target_component,
    ]
}

#[cfg(test)]
mod tests {
    use super::*;
    use mavlink::dialects::ardupilotmega::{HEARTBEAT_DATA, MANUAL_CONTROL_DATA};

    fn manual(x: i16) -> Vec<u8> {
        let m = MavMessage::MANUAL_CONTROL(MANUAL_CONTROL_DATA {
            x,
            y: 5,
            z: 500,
            r: 7,
            buttons: 0,
            target: 1,
            ..Default::default()
        });
        frame_v2(9, 255, 190, 69, &payload(&m))
    }

    #[test]
    fn a_frame_written_is_read_back() {
        let mut refused = Refused::default();
        let frames = scan(&manual(400), &mut refused);
        assert_eq!(refused, Refused::default());
        assert_eq!(frames.len(), 1);
        let f = &frames[0];
        assert_eq!((f.sequence, f.system_id, f.component_id), (9, 255, 190));
        let MavMessage::MANUAL_CONTROL(m) = f.message().unwrap() else {
            panic!()
        };
        assert_eq!((m.x, m.y, m.z, m.r, m.target), (400, 5, 500, 7, 1));
    }

    #[test]
    fn garbage_and_broken_frames_are_counted_and_good_ones_still_found() {
        let good = manual(100);
        let mut broken = manual(200);
        let last = broken.len() - 3;
        broken[last] ^= 0x55; // a payload byte: the checksum no longer matches
        let mut datagram = b"\x00hello\xfd".to_vec();
        datagram.extend_from_slice(&broken);
        datagram.extend_from_slice(&good);
        datagram.extend_from_slice(&good[..7]); // cut short
        let mut refused = Refused::default();
        let frames = scan(&datagram, &mut refused);
        assert_eq!(frames.len(), 1);
        let MavMessage::MANUAL_CONTROL(m) = frames[0].message().unwrap() else {
            panic!()
        };
        assert_eq!(m.x, 100);
        assert_eq!(refused.bad_crc, 1);
        // The stray start byte (its length runs past the end) and the frame cut short.
        assert_eq!(refused.truncated, 2);
        assert!(refused.garbage_bytes >= 7, "{refused:?}");
        // Random bytes never panic, and find nothing.
        let mut state = 0x1234_5678u32;
        let noise: Vec<u8> = (0..10_000)
            .map(|_| {
                state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                (state >> 24) as u8
            })
            .collect();
        let mut r = Refused::default();
        assert!(scan(&noise, &mut r).is_empty());
        assert!(r.total() > 0);
    }

    #[test]
    fn mavlink_1_frames_and_unknown_messages() {
        let hb = MavMessage::HEARTBEAT(HEARTBEAT_DATA::default());
        let mut buf = Vec::new();
        let header = mavlink::MavHeader {
            system_id: 255,
            component_id: 0,
            sequence: 3,
        };
        mavlink::write_v1_msg(&mut buf, header, &hb).unwrap();
        let mut refused = Refused::default();
        let frames = scan(&buf, &mut refused);
        assert_eq!(frames.len(), 1);
        assert_eq!(frames[0].version, MavlinkVersion::V1);
        assert!(matches!(frames[0].message(), Ok(MavMessage::HEARTBEAT(_))));
        // A message id no dialect has: counted as unknown, skipped whole.
        let unknown = frame_v2(1, 255, 0, 0x00AB_CDEF, &[1, 2, 3]);
        assert!(scan(&unknown, &mut refused).is_empty());
        assert_eq!(refused.unknown, 1);
    }

    #[test]
    fn command_long_is_read_whatever_its_command() {
        let mut p = vec![0u8; 33];
        p[0..4].copy_from_slice(&1.0f32.to_le_bytes());
        p[28..30].copy_from_slice(&60_000u16.to_le_bytes());
        p[30] = 1;
        p[31] = 1;
        let c = CommandLong::decode(&p);
        assert_eq!(
            (c.command, c.params[0], c.target_system, c.target_component),
            (60_000, 1.0, 1, 1)
        );
        // Trailing zeros removed on the wire read as zeros.
        let c = CommandLong::decode(&p[..2]);
        assert_eq!(c.command, 0);
    }
}
