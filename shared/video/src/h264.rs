//! H.264 over RTP (RFC 6184, non-interleaved mode): the packetiser the twin's sender uses and the
//! depacketiser the frame source uses, both plain functions of bytes.
//!
//! - [`packetise`]: an access unit in Annex B form (start codes, as x264 writes it) into RTP
//!   payloads: a NAL unit that fits is sent alone (single NAL unit packet), a larger one in FU-A
//!   fragments; the caller sets the marker bit on the last payload.
//! - [`Depacketiser`]: payloads back into the access unit's Annex B bytes (single NAL units,
//!   STAP-A aggregates as GStreamer's `rtph264pay aggregate-mode=zero-latency` sends SPS and PPS,
//!   FU-A fragments), noting whether it holds an IDR picture (a keyframe: what follows it can be
//!   decoded without what came before) and dropping a fragmented NAL unit that lost a piece.

use std::fmt;

/// The Annex B start code written before each NAL unit.
pub const START_CODE: [u8; 4] = [0, 0, 0, 1];

/// NAL unit types (H.264 table 7-1; RFC 6184 table 1 for 24..=29).
pub mod nal {
    pub const SLICE: u8 = 1;
    pub const IDR: u8 = 5;
    pub const SEI: u8 = 6;
    pub const SPS: u8 = 7;
    pub const PPS: u8 = 8;
    pub const AUD: u8 = 9;
    pub const STAP_A: u8 = 24;
    pub const FU_A: u8 = 28;
}

/// The type of a NAL unit from its first byte.
pub fn nal_type(first: u8) -> u8 {
    first & 0x1F
}

/// Why an RTP payload is not usable H.264.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum H264Error {
    Empty,
    /// A packet type of the interleaved mode (STAP-B, MTAP, FU-B) or an undefined one (0, 30, 31).
    Unsupported(u8),
    /// A STAP-A whose unit sizes run past its end, or an empty unit.
    BadAggregate,
    /// An FU-A shorter than its two header bytes, or carrying an aggregate or fragment type.
    BadFragment,
}

impl fmt::Display for H264Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            H264Error::Empty => write!(f, "an empty H.264 payload"),
            H264Error::Unsupported(t) => {
                write!(
                    f,
                    "H.264 packet type {t} (only single NAL units, STAP-A and FU-A)"
                )
            }
            H264Error::BadAggregate => write!(f, "a STAP-A whose units run past its end"),
            H264Error::BadFragment => write!(f, "a malformed FU-A fragment"),
        }
    }
}

impl std::error::Error for H264Error {}

/// The NAL units of an Annex B byte stream (without their start codes).
pub fn nal_units(stream: &[u8]) -> impl Iterator<Item = &[u8]> {
    let mut starts = Vec::new();
    let mut i = 0;
    while i + 3 <= stream.len() {
        if stream[i] == 0 && stream[i + 1] == 0 && stream[i + 2] == 1 {
            starts.push(i + 3);
            i += 3;
        } else {
            i += 1;
        }
    }
    let ends: Vec<usize> = starts
        .iter()
        .skip(1)
        .map(|&s| s - 3)
        .chain(std::iter::once(stream.len()))
        .collect();
    starts.into_iter().zip(ends).filter_map(move |(s, e)| {
        // The zero bytes before the next start code (a 4-byte code's first, trailing zeros) are
        // not part of the unit.
        let mut e = e;
        while e > s && stream[e - 1] == 0 {
            e -= 1;
        }
        (e > s).then(|| &stream[s..e])
    })
}

/// The types of the NAL units of an Annex B access unit, in order.
pub fn nal_types(au: &[u8]) -> Vec<u8> {
    nal_units(au).map(|u| nal_type(u[0])).collect()
}

/// The last SPS and PPS seen on a stream, so that every keyframe carries its own: a camera that
/// sends its parameter sets once, or out of band, leaves keyframes a recording cannot start at
/// (Foxglove's `CompressedVideo` asks for the SPS in every keyframe's message). Inserting the
/// same parameter sets again changes no decoded picture.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ParameterSets {
    sps: Option<Vec<u8>>,
    pps: Option<Vec<u8>>,
}

impl ParameterSets {
    /// Remembers the SPS and PPS of `au` (Annex B); when it holds an IDR picture without an SPS
    /// or PPS of its own, writes the last ones seen before its first slice. Whether it wrote
    /// them.
    pub fn complete(&mut self, au: &mut Vec<u8>) -> bool {
        let (mut idr, mut sps, mut pps) = (false, false, false);
        for u in nal_units(au) {
            match nal_type(u[0]) {
                nal::SPS => {
                    sps = true;
                    self.sps = Some(u.to_vec());
                }
                nal::PPS => {
                    pps = true;
                    self.pps = Some(u.to_vec());
                }
                nal::IDR => idr = true,
                _ => {}
            }
        }
        if !idr || (sps && pps) {
            return false;
        }
        let mut insert = Vec::new();
        for (have, set) in [(sps, &self.sps), (pps, &self.pps)] {
            if let (false, Some(set)) = (have, set) {
                insert.extend_from_slice(&START_CODE);
                insert.extend_from_slice(set);
            }
        }
        if insert.is_empty() {
            return false;
        }
        // Before the first slice: after a delimiter, an SEI, and the unit's own SPS.
        let at = nal_units(au)
            .find(|u| (nal::SLICE..=nal::IDR).contains(&nal_type(u[0])))
            .map_or(au.len(), |u| start_of(au, u));
        au.splice(at..at, insert);
        true
    }
}

/// Where the start code of `unit` (a slice of `au`) begins.
fn start_of(au: &[u8], unit: &[u8]) -> usize {
    let mut at = unit.as_ptr() as usize - au.as_ptr() as usize - 3;
    if at > 0 && au[at - 1] == 0 {
        at -= 1;
    }
    at
}

/// The RTP payloads of one access unit (`au` in Annex B form), each at most `max_payload` bytes:
/// single NAL unit packets and FU-A fragments, in order. Access unit delimiters are left out (the
/// marker bit ends an access unit on RTP). The caller sets the marker on the last one.
///
/// # Panics
/// When `max_payload < 3` (an FU-A needs two header bytes and one of data).
pub fn packetise(au: &[u8], max_payload: usize) -> Vec<Vec<u8>> {
    assert!(max_payload >= 3, "a max payload of {max_payload} bytes");
    let mut out = Vec::new();
    for unit in nal_units(au) {
        if nal_type(unit[0]) == nal::AUD {
            continue;
        }
        if unit.len() <= max_payload {
            out.push(unit.to_vec());
            continue;
        }
        let indicator = (unit[0] & 0xE0) | nal::FU_A;
        let kind = nal_type(unit[0]);
        let body = &unit[1..];
        let chunk = max_payload - 2;
        let pieces = body.len().div_ceil(chunk);
        for (k, piece) in body.chunks(chunk).enumerate() {
            let start = if k == 0 { 0x80 } else { 0 };
            let end = if k + 1 == pieces { 0x40 } else { 0 };
            let mut p = Vec::with_capacity(2 + piece.len());
            p.push(indicator);
            p.push(start | end | kind);
            p.extend_from_slice(piece);
            out.push(p);
        }
    }
    out
}

/// One access unit put back together from its payloads.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Depacketiser {
    /// The access unit's NAL units, each after a start code.
    bytes: Vec<u8>,
    /// Where the fragmented NAL unit being received starts in `bytes` (its start code).
    fragment: Option<usize>,
    /// A fragment's start, middle or end was lost: a NAL unit was dropped.
    incomplete: bool,
    idr: bool,
}

impl Depacketiser {
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds one packet's payload. A malformed payload is an error and changes nothing.
    pub fn push(&mut self, payload: &[u8]) -> Result<(), H264Error> {
        let &first = payload.first().ok_or(H264Error::Empty)?;
        match nal_type(first) {
            1..=23 => {
                self.drop_fragment();
                self.unit(payload);
            }
            nal::STAP_A => {
                // Checked whole before anything is taken.
                let mut units = Vec::new();
                let mut rest = &payload[1..];
                while !rest.is_empty() {
                    let [a, b, ..] = *rest else {
                        return Err(H264Error::BadAggregate);
                    };
                    let len = u16::from_be_bytes([a, b]) as usize;
                    let unit = rest.get(2..2 + len).ok_or(H264Error::BadAggregate)?;
                    if len == 0 || !(1..=23).contains(&nal_type(unit[0])) {
                        return Err(H264Error::BadAggregate);
                    }
                    units.push(unit);
                    rest = &rest[2 + len..];
                }
                if units.is_empty() {
                    return Err(H264Error::BadAggregate);
                }
                self.drop_fragment();
                for u in units {
                    self.unit(u);
                }
            }
            nal::FU_A => {
                let [_, fu, ..] = *payload else {
                    return Err(H264Error::BadFragment);
                };
                let kind = nal_type(fu);
                if !(1..=23).contains(&kind) {
                    return Err(H264Error::BadFragment);
                }
                let (start, end) = (fu & 0x80 != 0, fu & 0x40 != 0);
                let data = &payload[2..];
                if start {
                    self.drop_fragment();
                    self.fragment = Some(self.bytes.len());
                    self.bytes.extend_from_slice(&START_CODE);
                    self.bytes.push((first & 0xE0) | kind);
                    self.idr |= kind == nal::IDR;
                } else if self.fragment.is_none() {
                    // Its start was lost.
                    self.incomplete = true;
                    return Ok(());
                }
                self.bytes.extend_from_slice(data);
                if end {
                    self.fragment = None;
                }
            }
            other => return Err(H264Error::Unsupported(other)),
        }
        Ok(())
    }

    /// Packets were lost here: a fragmented NAL unit in progress cannot be completed.
    pub fn lost(&mut self) {
        self.drop_fragment();
    }

    /// Whether an IDR slice was received.
    pub fn has_idr(&self) -> bool {
        self.idr
    }

    /// Whether a NAL unit was dropped for a lost fragment.
    pub fn incomplete(&self) -> bool {
        self.incomplete || self.fragment.is_some()
    }

    /// The bytes so far.
    pub fn len(&self) -> usize {
        self.bytes.len()
    }

    pub fn is_empty(&self) -> bool {
        self.bytes.is_empty()
    }

    /// Ends the access unit: its Annex B bytes (a fragment without its end dropped), and the
    /// depacketiser empty for the next.
    pub fn finish(&mut self) -> Vec<u8> {
        self.drop_fragment();
        self.incomplete = false;
        self.idr = false;
        std::mem::take(&mut self.bytes)
    }

    fn unit(&mut self, unit: &[u8]) {
        self.idr |= nal_type(unit[0]) == nal::IDR;
        self.bytes.extend_from_slice(&START_CODE);
        self.bytes.extend_from_slice(unit);
    }

    fn drop_fragment(&mut self) {
        if let Some(at) = self.fragment.take() {
            self.bytes.truncate(at);
            self.incomplete = true;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An access unit as x264 writes it: AUD, SPS, PPS, an IDR slice of `idr_len` bytes, a second
    /// slice, with 4- and 3-byte start codes.
    fn access_unit(idr_len: usize) -> (Vec<u8>, Vec<Vec<u8>>) {
        let units: Vec<Vec<u8>> = vec![
            vec![0x09, 0xF0],
            vec![0x67, 0x42, 0xC0, 0x1E, 0xAB],
            vec![0x68, 0xCE, 0x3C, 0x80],
            std::iter::once(0x65)
                .chain((0..idr_len - 1).map(|i| (i % 251) as u8 | 1))
                .collect(),
            vec![0x41, 0x9A, 0x02, 0x03],
        ];
        let mut au = Vec::new();
        for (k, u) in units.iter().enumerate() {
            au.extend_from_slice(if k % 2 == 0 {
                &[0, 0, 0, 1][..]
            } else {
                &[0, 0, 1]
            });
            au.extend_from_slice(u);
        }
        (au, units)
    }

    fn annex_b<U: AsRef<[u8]>>(units: &[U]) -> Vec<u8> {
        units
            .iter()
            .flat_map(|u| START_CODE.iter().chain(u.as_ref().iter()).copied())
            .collect()
    }

    #[test]
    fn nal_units_are_split_at_start_codes() {
        let (au, units) = access_unit(50);
        let got: Vec<&[u8]> = nal_units(&au).collect();
        assert_eq!(got, units.iter().map(|u| &u[..]).collect::<Vec<_>>());
        assert_eq!(nal_units(&[0, 0, 0]).count(), 0);
        assert_eq!(nal_units(b"no start code").count(), 0);
    }

    /// Split and reassembled for many payload sizes: the same NAL units (the AUD left out), every
    /// payload within the size, fragments only where a unit does not fit.
    #[test]
    fn packetiser_and_depacketiser_round_trip() {
        for idr_len in [1, 2, 50, 1000, 4097] {
            let (au, units) = access_unit(idr_len.max(2));
            let want = annex_b(&units[1..]);
            for max in [3, 4, 5, 7, 100, 1000, 1200, 1400, 5000] {
                let payloads = packetise(&au, max);
                assert!(payloads.iter().all(|p| p.len() <= max && !p.is_empty()));
                let singles = payloads
                    .iter()
                    .filter(|p| nal_type(p[0]) != nal::FU_A)
                    .count();
                let fitting = units[1..].iter().filter(|u| u.len() <= max).count();
                assert_eq!(singles, fitting, "idr {idr_len}, max {max}");
                let mut d = Depacketiser::new();
                for p in &payloads {
                    d.push(p).unwrap();
                }
                assert!(d.has_idr());
                assert!(!d.incomplete());
                assert_eq!(d.finish(), want, "idr {idr_len}, max {max}");
                assert!(d.is_empty() && !d.has_idr());
            }
        }
    }

    #[test]
    fn fragments_carry_the_units_header() {
        let (au, _) = access_unit(3000);
        let payloads = packetise(&au, 1200);
        let frags: Vec<&Vec<u8>> = payloads.iter().filter(|p| p[0] & 0x1F == 28).collect();
        assert_eq!(frags.len(), 3);
        // NRI of the IDR (0x65: NRI 3) in the indicator, type 5 in the FU header.
        assert!(frags.iter().all(|p| p[0] == 0x60 | 28 && p[1] & 0x1F == 5));
        assert_eq!(
            frags.iter().map(|p| p[1] & 0xC0).collect::<Vec<_>>(),
            vec![0x80, 0x00, 0x40]
        );
    }

    #[test]
    fn stap_a_aggregates_are_unpacked() {
        let sps = [0x67, 1, 2, 3];
        let pps = [0x68, 4];
        let mut stap = vec![0x78];
        for u in [&sps[..], &pps[..]] {
            stap.extend_from_slice(&(u.len() as u16).to_be_bytes());
            stap.extend_from_slice(u);
        }
        let mut d = Depacketiser::new();
        d.push(&stap).unwrap();
        d.push(&[0x65, 9, 9]).unwrap();
        assert!(d.has_idr());
        assert_eq!(
            d.finish(),
            annex_b(&[sps.to_vec(), pps.to_vec(), vec![0x65, 9, 9]])
        );
        // Sizes past the end, a zero size, nothing inside: refused, nothing taken.
        for bad in [
            vec![0x78, 0, 9, 0x67],
            vec![0x78, 0, 0],
            vec![0x78],
            vec![0x78, 0, 2, 0x67],
        ] {
            let mut d = Depacketiser::new();
            d.push(&[0x41, 1]).unwrap();
            assert_eq!(d.push(&bad), Err(H264Error::BadAggregate), "{bad:?}");
            assert_eq!(d.finish(), annex_b(&[vec![0x41, 1]]));
        }
    }

    #[test]
    fn a_fragment_that_lost_a_piece_is_dropped() {
        let (au, units) = access_unit(3000);
        let payloads = packetise(&au, 1000);
        let fu: Vec<usize> = (0..payloads.len())
            .filter(|&k| nal_type(payloads[k][0]) == nal::FU_A)
            .collect();
        assert!(fu.len() >= 3);
        // Lose the middle fragment: the IDR is dropped, the rest kept.
        let mut d = Depacketiser::new();
        for (k, p) in payloads.iter().enumerate() {
            if k == fu[1] {
                d.lost();
                continue;
            }
            d.push(p).unwrap();
        }
        assert!(d.incomplete());
        let without_idr = annex_b(&[units[1].clone(), units[2].clone(), units[4].clone()]);
        assert_eq!(d.finish(), without_idr);
        // Lose the start: the rest of the unit is skipped.
        let mut d = Depacketiser::new();
        for (k, p) in payloads.iter().enumerate() {
            if k != fu[0] {
                d.push(p).unwrap();
            }
        }
        assert!(d.incomplete());
        assert!(!d.has_idr());
        assert_eq!(d.finish(), without_idr);
        // Lose the end: dropped at the next unit.
        let mut d = Depacketiser::new();
        for (k, p) in payloads.iter().enumerate() {
            if k != *fu.last().unwrap() {
                d.push(p).unwrap();
            }
        }
        assert!(d.incomplete());
        assert_eq!(d.finish(), without_idr);
    }

    #[test]
    fn unsupported_and_malformed_payloads_are_refused() {
        let mut d = Depacketiser::new();
        assert_eq!(d.push(&[]), Err(H264Error::Empty));
        for t in [0u8, 25, 26, 27, 29, 30, 31] {
            assert_eq!(d.push(&[t, 1, 2]), Err(H264Error::Unsupported(t)));
        }
        assert_eq!(d.push(&[0x7C]), Err(H264Error::BadFragment));
        assert_eq!(d.push(&[0x7C, 0x80 | 28, 1]), Err(H264Error::BadFragment));
        assert!(d.is_empty());
    }

    #[test]
    fn a_keyframe_without_parameter_sets_gets_the_last_ones() {
        let (aud, sps, pps) = (
            &[0x09u8, 0xF0][..],
            &[0x67u8, 1, 2, 3][..],
            &[0x68u8, 4][..],
        );
        let (idr, slice) = (&[0x65u8, 7, 7][..], &[0x41u8, 8][..]);
        let mut sets = ParameterSets::default();
        // A keyframe before any parameter set: nothing to give it.
        let mut first = annex_b(&[idr]);
        assert!(!sets.complete(&mut first));
        assert_eq!(first, annex_b(&[idr]));
        // The sets come once, with a keyframe that needs nothing.
        let mut whole = annex_b(&[sps, pps, idr]);
        assert!(!sets.complete(&mut whole));
        assert_eq!(whole, annex_b(&[sps, pps, idr]));
        // A delta frame is left alone; a later keyframe gets both, after its delimiter.
        let mut delta = annex_b(&[slice]);
        assert!(!sets.complete(&mut delta));
        let mut bare = annex_b(&[aud, idr]);
        assert!(sets.complete(&mut bare));
        assert_eq!(bare, annex_b(&[aud, sps, pps, idr]));
        assert_eq!(nal_types(&bare), vec![9, 7, 8, 5]);
        // One with its own SPS but no PPS gets the PPS only.
        let sps2 = &[0x67u8, 9][..];
        let mut half = annex_b(&[sps2, idr]);
        assert!(sets.complete(&mut half));
        assert_eq!(half, annex_b(&[sps2, pps, idr]));
    }
}
