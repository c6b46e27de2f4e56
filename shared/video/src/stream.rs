//! The receiving side's judgement of an RTP/H.264 stream, a plain state machine over datagrams (no
//! socket, no clock: arrival times are given).
//!
//! - **Sessions.** A stream is one SSRC. Another SSRC, or a sequence number jumping further than
//!   RFC 3550's limits (3000 ahead, 100 behind), starts a new session: the sender restarted.
//! - **Loss.** Sequence numbers are extended past their wrap; a gap is lost packets. A packet
//!   behind the highest number (late or repeated) is dropped: its frame was already judged.
//! - **Access units.** The packets of one RTP timestamp, ended by the marker bit, are one frame's
//!   access unit; a new timestamp before the marker ends the previous unit too (its marker packet
//!   was lost).
//! - **Damage.** A unit is *damaged* when a packet of it may be missing (a gap before or inside it,
//!   its end never came, a fragment lost, a payload refused), and so is every unit after a damaged
//!   one until an intact IDR unit (a keyframe): the frames between reference what was lost. A
//!   session starts damaged until its first keyframe (a receiver joining a stream mid-way has no
//!   reference). Damaged units are still handed on: the decoder needs them to go on.
//! - **Garbage** (not RTP version 2, truncated, another payload type, a malformed H.264 payload) is
//!   refused and counted, never a panic.

use crate::h264::{Depacketiser, H264Error};
use crate::meta::{self, MetaError, WireMeta};
use crate::rtp::{Packet, RtpError, SeqUnwrap, TimestampUnwrap};
use std::fmt;
use std::time::Instant;

/// RFC 3550, appendix A.1: the largest jump ahead taken as loss, and back as misordering.
pub const MAX_DROPOUT: i64 = 3000;
pub const MAX_MISORDER: i64 = 100;

/// What the receiver accepts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct StreamConfig {
    /// The dynamic payload type of H.264 (96 on BlueOS).
    pub payload_type: u8,
    /// The largest access unit kept (bytes); a larger one is cut and damaged.
    pub max_access_unit: usize,
}

impl Default for StreamConfig {
    fn default() -> Self {
        StreamConfig {
            payload_type: 96,
            max_access_unit: 8 << 20,
        }
    }
}

/// Why a datagram was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Refusal {
    Rtp(RtpError),
    PayloadType(u8),
    H264(H264Error),
}

impl fmt::Display for Refusal {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Refusal::Rtp(e) => e.fmt(f),
            Refusal::PayloadType(pt) => write!(f, "payload type {pt}"),
            Refusal::H264(e) => e.fmt(f),
        }
    }
}

/// One frame's access unit as received.
#[derive(Clone, Debug, PartialEq)]
pub struct AccessUnit {
    /// The receiver's count of access units, from 1 (across sessions).
    pub number: u64,
    /// The session it belongs to, from 1.
    pub session: u64,
    pub ssrc: u32,
    /// The RTP timestamp, extended past its wrap within the session (90 kHz for video).
    pub timestamp: u64,
    /// When its first packet arrived.
    pub arrival: Instant,
    /// The H.264 bytes as received, in Annex B form (start codes), without the NAL units that lost
    /// a fragment. What a recorder would keep.
    pub bytes: Vec<u8>,
    /// It holds an IDR picture.
    pub keyframe: bool,
    /// Every packet of it arrived, in order, and its marker.
    pub complete: bool,
    /// A packet of it, or of a unit it depends on since the last intact keyframe, is missing.
    pub damaged: bool,
    pub packets: u32,
    /// The frame's metadata element ([`meta`]), where the sender put one.
    pub meta: Option<Result<WireMeta, MetaError>>,
}

/// What one datagram did.
#[derive(Clone, Debug, PartialEq)]
pub enum Event {
    /// A stream session began: the first packet, another SSRC (`previous`), or the same SSRC whose
    /// sequence numbers jumped (`jumped`).
    Session {
        session: u64,
        ssrc: u32,
        previous: Option<u32>,
        jumped: bool,
    },
    /// Packets lost before this one.
    Lost(u64),
    /// The datagram was refused.
    Refused(Refusal),
    /// An access unit ended.
    AccessUnit(AccessUnit),
}

/// The receiver's counts since it started.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Counts {
    /// Datagrams received, refused ones included.
    pub datagrams: u64,
    pub bytes: u64,
    pub refused: u64,
    pub lost: u64,
    /// Late or repeated packets dropped.
    pub late: u64,
    pub sessions: u64,
    pub access_units: u64,
    pub damaged: u64,
    pub keyframes: u64,
}

struct Pending {
    timestamp: u32,
    extended: u64,
    arrival: Instant,
    depack: Depacketiser,
    /// A packet of it may be missing.
    gap: bool,
    /// Bytes dropped for the size limit.
    cut: bool,
    packets: u32,
    meta: Option<Result<WireMeta, MetaError>>,
}

struct Session {
    number: u64,
    ssrc: u32,
    seq: SeqUnwrap,
    ts: TimestampUnwrap,
    pending: Option<Pending>,
    /// Every unit since the last intact keyframe is intact.
    chain: bool,
}

/// The receiver's state machine.
pub struct Receiver {
    config: StreamConfig,
    session: Option<Session>,
    counts: Counts,
}

impl Receiver {
    pub fn new(config: StreamConfig) -> Self {
        Receiver {
            config,
            session: None,
            counts: Counts::default(),
        }
    }

    pub fn counts(&self) -> Counts {
        self.counts
    }

    /// Takes one datagram arrived at `arrival`; what it did goes to `events`.
    pub fn push(&mut self, datagram: &[u8], arrival: Instant, events: &mut Vec<Event>) {
        self.counts.datagrams += 1;
        self.counts.bytes += datagram.len() as u64;
        let packet = match Packet::parse(datagram) {
            Ok(p) => p,
            Err(e) => return self.refuse(Refusal::Rtp(e), events),
        };
        if packet.payload_type != self.config.payload_type {
            return self.refuse(Refusal::PayloadType(packet.payload_type), events);
        }
        // The session: a new SSRC, or a jump no loss or misordering explains.
        let (previous, jumped) = match &self.session {
            None => (None, false),
            Some(s) if s.ssrc != packet.ssrc => (Some(s.ssrc), false),
            Some(s) => {
                let d = s.seq.distance(packet.seq);
                (None, !(-MAX_MISORDER..=MAX_DROPOUT).contains(&d))
            }
        };
        if self.session.is_none() || previous.is_some() || jumped {
            self.flush(events);
            self.counts.sessions += 1;
            self.session = Some(Session {
                number: self.counts.sessions,
                ssrc: packet.ssrc,
                seq: SeqUnwrap::default(),
                ts: TimestampUnwrap::default(),
                pending: None,
                chain: false,
            });
            events.push(Event::Session {
                session: self.counts.sessions,
                ssrc: packet.ssrc,
                previous,
                jumped,
            });
        }
        let session = self.session.as_mut().expect("opened above");
        let distance = session.seq.distance(packet.seq);
        let first = session.seq.highest().is_none();
        if !first && distance <= 0 {
            self.counts.late += 1;
            return;
        }
        session.seq.accept(packet.seq);
        let lost = if first { 0 } else { (distance - 1) as u64 };
        if lost > 0 {
            self.counts.lost += lost;
            events.push(Event::Lost(lost));
            // The unit in progress may have lost its tail, and a whole unit may be gone.
            if let Some(p) = session.pending.as_mut() {
                p.gap = true;
                p.depack.lost();
            }
            session.chain = false;
        }
        if session
            .pending
            .as_ref()
            .is_some_and(|p| p.timestamp != packet.timestamp)
        {
            // A new frame before the last one's marker: its end was lost.
            let unit = Self::finish(session, &mut self.counts, false);
            events.push(Event::AccessUnit(unit));
        }
        let pending = session.pending.get_or_insert_with(|| Pending {
            timestamp: packet.timestamp,
            extended: session.ts.unwrap(packet.timestamp),
            arrival,
            depack: Depacketiser::new(),
            // The lost packets may have been this unit's first.
            gap: lost > 0,
            cut: false,
            packets: 0,
            meta: None,
        });
        pending.packets += 1;
        if pending.meta.is_none()
            && let Some(data) = packet.extension(meta::ELEMENT_ID)
        {
            pending.meta = WireMeta::decode(data).transpose();
        }
        if pending.depack.len() + packet.payload.len() > self.config.max_access_unit {
            pending.cut = true;
            pending.depack.lost();
        } else if let Err(e) = pending.depack.push(packet.payload) {
            // Part of the frame is unusable: as if lost.
            pending.gap = true;
            pending.depack.lost();
            self.counts.refused += 1;
            events.push(Event::Refused(Refusal::H264(e)));
        }
        if packet.marker {
            let unit = Self::finish(session, &mut self.counts, true);
            events.push(Event::AccessUnit(unit));
        }
    }

    /// What was received so far can no longer be relied on (the decoder started again): every
    /// unit is damaged until the next intact keyframe.
    pub fn damage(&mut self) {
        if let Some(s) = self.session.as_mut() {
            s.chain = false;
        }
    }

    /// Ends the unit in progress, if any, as incomplete (the stream stopped or changed).
    pub fn flush(&mut self, events: &mut Vec<Event>) {
        if let Some(s) = self.session.as_mut()
            && s.pending.is_some()
        {
            let unit = Self::finish(s, &mut self.counts, false);
            events.push(Event::AccessUnit(unit));
        }
    }

    fn refuse(&mut self, why: Refusal, events: &mut Vec<Event>) {
        self.counts.refused += 1;
        events.push(Event::Refused(why));
    }

    fn finish(session: &mut Session, counts: &mut Counts, marker: bool) -> AccessUnit {
        let mut p = session.pending.take().expect("a unit in progress");
        let complete = marker && !p.gap && !p.cut && !p.depack.incomplete();
        let keyframe = p.depack.has_idr();
        let damaged = if complete && keyframe {
            session.chain = true;
            false
        } else if complete {
            !session.chain
        } else {
            session.chain = false;
            true
        };
        counts.access_units += 1;
        counts.damaged += damaged as u64;
        counts.keyframes += keyframe as u64;
        AccessUnit {
            number: counts.access_units,
            session: session.number,
            ssrc: session.ssrc,
            timestamp: p.extended,
            arrival: p.arrival,
            bytes: p.depack.finish(),
            keyframe,
            complete,
            damaged,
            packets: p.packets,
            meta: p.meta,
        }
    }
}

/// The RTP clock as a frame time in ns: 90 kHz timestamps from the first frame of the stream;
/// a new session (the sender restarted, its timestamps start anywhere) goes on from the last time
/// plus the time that passed on the receiver's clock, so time never goes back.
#[derive(Clone, Copy, Debug, Default)]
pub struct RtpClock {
    /// (session, its first timestamp, the time of that first frame, its arrival)
    base: Option<(u64, u64, u64, Instant)>,
    last: Option<(u64, Instant)>,
}

/// The RTP clock rate of video.
pub const VIDEO_CLOCK_HZ: u64 = 90_000;

impl RtpClock {
    /// The time of a frame of `session` with the extended `timestamp`, arrived at `arrival`.
    pub fn time_ns(&mut self, session: u64, timestamp: u64, arrival: Instant) -> u64 {
        let base = match self.base {
            Some(b) if b.0 == session => b,
            _ => {
                let t0 = match self.last {
                    None => 0,
                    Some((t, at)) => {
                        t + (arrival.saturating_duration_since(at).as_nanos() as u64).max(1)
                    }
                };
                let b = (session, timestamp, t0, arrival);
                self.base = Some(b);
                b
            }
        };
        let ticks = timestamp.saturating_sub(base.1);
        let t = base.2 + (ticks as u128 * 1_000_000_000 / VIDEO_CLOCK_HZ as u128) as u64;
        // A timestamp that goes back within a session is held at the last time.
        let t = self.last.map_or(t, |(l, _)| t.max(l));
        self.last = Some((t, arrival));
        t
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::h264::packetise;
    use crate::rtp::{Header, write};
    use std::time::Duration;

    /// A sender of fake access units: an IDR or a P slice of `len` bytes, in packets of at most
    /// `max` payload bytes.
    struct Fake {
        ssrc: u32,
        seq: u16,
        ts: u32,
        max: usize,
    }

    impl Fake {
        fn new(ssrc: u32, seq: u16) -> Self {
            Fake {
                ssrc,
                seq,
                ts: 4_000_000_000,
                max: 100,
            }
        }

        fn frame(&mut self, key: bool, len: usize) -> Vec<Vec<u8>> {
            let mut au = vec![0, 0, 0, 1, if key { 0x65 } else { 0x41 }];
            au.extend((0..len).map(|i| (i % 200) as u8 + 1));
            let payloads = packetise(&au, self.max);
            let n = payloads.len();
            let out = payloads
                .iter()
                .enumerate()
                .map(|(k, p)| {
                    let mut b = Vec::new();
                    let h = Header {
                        marker: k + 1 == n,
                        payload_type: 96,
                        seq: self.seq,
                        timestamp: self.ts,
                        ssrc: self.ssrc,
                    };
                    write(&mut b, &h, None, p);
                    self.seq = self.seq.wrapping_add(1);
                    b
                })
                .collect();
            self.ts = self.ts.wrapping_add(3000);
            out
        }
    }

    fn feed(rx: &mut Receiver, packets: &[Vec<u8>]) -> Vec<Event> {
        let mut ev = Vec::new();
        let t = Instant::now();
        for p in packets {
            rx.push(p, t, &mut ev);
        }
        ev
    }

    fn units(ev: &[Event]) -> Vec<&AccessUnit> {
        ev.iter()
            .filter_map(|e| match e {
                Event::AccessUnit(u) => Some(u),
                _ => None,
            })
            .collect()
    }

    /// (number, keyframe, complete, damaged) of each unit.
    fn verdicts(ev: &[Event]) -> Vec<(u64, bool, bool, bool)> {
        units(ev)
            .iter()
            .map(|u| (u.number, u.keyframe, u.complete, u.damaged))
            .collect()
    }

    #[test]
    fn an_intact_stream_gives_intact_units_across_the_sequence_wrap() {
        let mut tx = Fake::new(7, 65530);
        let mut rx = Receiver::new(StreamConfig::default());
        let mut packets = tx.frame(true, 450);
        for _ in 0..3 {
            packets.extend(tx.frame(false, 250));
        }
        let ev = feed(&mut rx, &packets);
        assert!(matches!(
            ev[0],
            Event::Session {
                session: 1,
                ssrc: 7,
                previous: None,
                jumped: false
            }
        ));
        assert_eq!(
            verdicts(&ev),
            vec![
                (1, true, true, false),
                (2, false, true, false),
                (3, false, true, false),
                (4, false, true, false)
            ]
        );
        let u = units(&ev);
        assert_eq!(u[1].timestamp - u[0].timestamp, 3000, "across the wrap");
        assert_eq!(u[0].packets, 5);
        assert_eq!(u[0].bytes.len(), 4 + 451);
        let c = rx.counts();
        assert_eq!((c.lost, c.refused, c.late, c.sessions), (0, 0, 0, 1));
        assert_eq!((c.access_units, c.damaged, c.keyframes), (4, 0, 1));
    }

    /// A lost packet damages its frame and every frame after it up to the next intact keyframe.
    #[test]
    fn a_loss_damages_frames_until_the_next_keyframe() {
        let mut tx = Fake::new(1, 100);
        let frames: Vec<Vec<Vec<u8>>> = [true, false, false, false, true, false]
            .iter()
            .map(|&k| tx.frame(k, 350))
            .collect();
        let mut packets = Vec::new();
        for (f, ps) in frames.iter().enumerate() {
            for (k, p) in ps.iter().enumerate() {
                // Lose the second packet of the second frame.
                if !(f == 1 && k == 1) {
                    packets.push(p.clone());
                }
            }
        }
        let mut rx = Receiver::new(StreamConfig::default());
        let ev = feed(&mut rx, &packets);
        assert!(ev.contains(&Event::Lost(1)));
        assert_eq!(
            verdicts(&ev),
            vec![
                (1, true, true, false),
                (2, false, false, true),
                (3, false, true, true),
                (4, false, true, true),
                (5, true, true, false),
                (6, false, true, false)
            ]
        );
        assert_eq!(rx.counts().damaged, 3);
    }

    /// A frame's marker packet lost: the frame ends at the next timestamp, damaged; a whole frame
    /// lost: the next frame is damaged (its references may be gone).
    #[test]
    fn a_lost_marker_or_a_lost_frame_is_damage() {
        let mut tx = Fake::new(1, 0);
        let f0 = tx.frame(true, 250);
        let f1 = tx.frame(false, 250);
        let f2 = tx.frame(false, 250);
        let f3 = tx.frame(true, 250);
        let f4 = tx.frame(false, 250);
        let mut packets = f0.clone();
        packets.extend_from_slice(&f1[..f1.len() - 1]);
        packets.extend(f3.clone()); // f2 lost whole
        packets.extend(f4);
        let mut rx = Receiver::new(StreamConfig::default());
        let ev = feed(&mut rx, &packets);
        // f1 (end lost), f3 (a keyframe, but packets were lost just before it), f4 (after it).
        assert_eq!(
            verdicts(&ev),
            vec![
                (1, true, true, false),
                (2, false, false, true),
                (3, true, false, true),
                (4, false, true, true)
            ]
        );
        assert_eq!(rx.counts().lost, (1 + f2.len()) as u64);
    }

    #[test]
    fn a_session_starts_damaged_until_its_first_keyframe() {
        let mut tx = Fake::new(9, 0);
        let packets: Vec<Vec<u8>> = [false, false, true, false]
            .iter()
            .flat_map(|&k| tx.frame(k, 120))
            .collect();
        let mut rx = Receiver::new(StreamConfig::default());
        let ev = feed(&mut rx, &packets);
        assert_eq!(
            verdicts(&ev).iter().map(|v| v.3).collect::<Vec<_>>(),
            vec![true, true, false, false]
        );
    }

    /// Another SSRC is a new session; the unit in progress of the old one ends damaged.
    #[test]
    fn a_new_ssrc_or_a_jump_starts_a_new_session() {
        let mut a = Fake::new(1, 500);
        let mut b = Fake::new(2, 40_000);
        let mut packets = a.frame(true, 250);
        let half = a.frame(false, 250);
        packets.extend_from_slice(&half[..1]);
        packets.extend(b.frame(true, 250));
        packets.extend(b.frame(false, 250));
        // The same SSRC jumping far ahead: a restart too.
        b.seq = b.seq.wrapping_add(20_000);
        packets.extend(b.frame(false, 250));
        packets.extend(b.frame(true, 250));
        let mut rx = Receiver::new(StreamConfig::default());
        let ev = feed(&mut rx, &packets);
        let sessions: Vec<_> = ev
            .iter()
            .filter_map(|e| match e {
                Event::Session {
                    session,
                    ssrc,
                    previous,
                    jumped,
                } => Some((*session, *ssrc, *previous, *jumped)),
                _ => None,
            })
            .collect();
        assert_eq!(
            sessions,
            vec![
                (1, 1, None, false),
                (2, 2, Some(1), false),
                (3, 2, None, true)
            ]
        );
        let u = units(&ev);
        assert_eq!(
            u.iter().map(|u| (u.session, u.damaged)).collect::<Vec<_>>(),
            vec![
                (1, false),
                (1, true),
                (2, false),
                (2, false),
                (3, true),
                (3, false)
            ]
        );
        assert_eq!(rx.counts().lost, 0, "a restart is not loss");
    }

    #[test]
    fn late_and_repeated_packets_are_dropped() {
        let mut tx = Fake::new(1, 10);
        let f0 = tx.frame(true, 250);
        let f1 = tx.frame(false, 250);
        let mut packets = f0.clone();
        packets.push(f0[1].clone());
        packets.push(f1[0].clone());
        packets.push(f1[2].clone());
        packets.push(f1[1].clone()); // late: its frame is already damaged
        packets.extend_from_slice(&f1[3..]);
        let mut rx = Receiver::new(StreamConfig::default());
        let ev = feed(&mut rx, &packets);
        assert_eq!(
            verdicts(&ev),
            vec![(1, true, true, false), (2, false, false, true)]
        );
        let c = rx.counts();
        assert_eq!((c.late, c.lost), (2, 1));
    }

    #[test]
    fn garbage_is_counted_and_refused() {
        let mut tx = Fake::new(1, 0);
        let good = tx.frame(true, 250);
        let mut other_pt = good[0].clone();
        other_pt[1] = (other_pt[1] & 0x80) | 97;
        let garbage: Vec<Vec<u8>> = vec![
            vec![],
            vec![0x80; 5],
            b"GET / HTTP/1.1\r\n".to_vec(),
            vec![0x40; 40],
            other_pt,
            {
                let mut t = good[1].clone();
                t[0] |= 0x0F; // 15 CSRCs
                t.truncate(20);
                t
            },
        ];
        let mut rx = Receiver::new(StreamConfig::default());
        let ev = feed(&mut rx, &garbage);
        assert_eq!(ev.len(), garbage.len());
        assert!(ev.iter().all(|e| matches!(e, Event::Refused(_))));
        assert!(matches!(ev[4], Event::Refused(Refusal::PayloadType(97))));
        assert_eq!(rx.counts().refused, garbage.len() as u64);
        assert_eq!(rx.counts().sessions, 0, "garbage opens no session");
        // Then the good frame, intact; a malformed H.264 payload inside a frame damages it.
        let ev = feed(&mut rx, &good);
        assert_eq!(verdicts(&ev), vec![(1, true, true, false)]);
        let mut f = tx.frame(false, 250);
        f[1] = {
            let mut p = f[1].clone();
            p[12] = 29;
            p
        };
        let ev = feed(&mut rx, &f);
        assert!(ev.contains(&Event::Refused(Refusal::H264(H264Error::Unsupported(29)))));
        assert_eq!(verdicts(&ev), vec![(2, false, false, true)]);
    }

    #[test]
    fn the_metadata_rides_with_the_unit_and_the_size_limit_holds() {
        let m = WireMeta {
            seq: 5,
            time_ns: 1_000,
            trial: 1,
            step: 2,
            status: 0,
            truth: None,
        };
        let mut b = Vec::new();
        let h = Header {
            marker: true,
            payload_type: 96,
            seq: 1,
            timestamp: 0,
            ssrc: 3,
        };
        write(
            &mut b,
            &h,
            Some((meta::ELEMENT_ID, &m.encode())),
            &[0x65, 1, 2],
        );
        let mut rx = Receiver::new(StreamConfig {
            payload_type: 96,
            max_access_unit: 6,
        });
        let ev = feed(&mut rx, &[b.clone()]);
        assert_eq!(units(&ev)[0].meta, Some(Ok(m)));
        assert!(!units(&ev)[0].damaged);
        // Over the limit: cut and damaged.
        let h2 = Header {
            seq: 2,
            timestamp: 3000,
            ..h
        };
        write(&mut b, &h2, None, &[0x41; 10]);
        let ev = feed(&mut rx, &[b]);
        let u = units(&ev)[0];
        assert!(u.damaged && !u.complete && u.bytes.is_empty());
        assert_eq!(u.meta, None);
    }

    #[test]
    fn the_rtp_clock_maps_to_ns_and_never_goes_back_across_sessions() {
        let mut c = RtpClock::default();
        let t0 = Instant::now();
        assert_eq!(c.time_ns(1, 1_000_000, t0), 0);
        assert_eq!(c.time_ns(1, 1_003_000, t0), 33_333_333);
        assert_eq!(c.time_ns(1, 1_090_000, t0), 1_000_000_000);
        // A new session starting anywhere: the last time plus the receiver's time between.
        let t1 = t0 + Duration::from_millis(500);
        assert_eq!(c.time_ns(2, 5, t1), 1_500_000_000);
        assert_eq!(c.time_ns(2, 9005, t1), 1_600_000_000);
        // A timestamp going back within a session holds the time.
        assert_eq!(c.time_ns(2, 6, t1), 1_600_000_000);
    }
}
