//! RTP packets (RFC 3550) and their header extensions (RFC 8285), read and written as plain bytes.
//!
//! [`Packet::parse`] is a function of bytes: it never panics and never allocates, and a packet it
//! cannot use (not version 2, shorter than its header says, a padding or extension running past its
//! end) is a typed [`RtpError`]. The receiver ([`crate::stream`]) counts and refuses those.

use std::fmt;

/// The fixed header's length.
pub const HEADER_LEN: usize = 12;
/// The profile of RFC 8285's one-byte header extension.
pub const ONE_BYTE_PROFILE: u16 = 0xBEDE;
/// The profile of RFC 8285's two-byte header extension (the low 4 bits are application bits).
pub const TWO_BYTE_PROFILE: u16 = 0x1000;

/// Why a datagram is not a usable RTP packet.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RtpError {
    /// Shorter than the 12 bytes of the fixed header.
    Short { len: usize },
    /// Not RTP version 2.
    Version(u8),
    /// The CSRC list, extension or padding runs past the packet's end.
    Truncated { what: &'static str, len: usize },
    /// A header extension's element runs past the extension block.
    BadExtension,
    /// A padding count of 0 (RFC 3550: the count includes itself).
    BadPadding,
}

impl fmt::Display for RtpError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            RtpError::Short { len } => write!(f, "{len} bytes, shorter than an RTP header"),
            RtpError::Version(v) => write!(f, "RTP version {v}, not 2"),
            RtpError::Truncated { what, len } => {
                write!(f, "the {what} runs past the packet's end ({len} bytes)")
            }
            RtpError::BadExtension => {
                write!(f, "a header extension element runs past its block")
            }
            RtpError::BadPadding => write!(f, "a padding count of 0"),
        }
    }
}

impl std::error::Error for RtpError {}

/// A parsed RTP packet, borrowing the datagram.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Packet<'a> {
    pub marker: bool,
    pub payload_type: u8,
    pub seq: u16,
    pub timestamp: u32,
    pub ssrc: u32,
    csrc: &'a [u8],
    /// The extension's profile and its data (the elements, without the 4-byte extension header).
    extension: Option<(u16, &'a [u8])>,
    pub payload: &'a [u8],
}

impl<'a> Packet<'a> {
    /// Parses a datagram. The extension's elements are checked here too, so that
    /// [`Packet::extension`] cannot fail later.
    pub fn parse(data: &'a [u8]) -> Result<Packet<'a>, RtpError> {
        if data.len() < HEADER_LEN {
            return Err(RtpError::Short { len: data.len() });
        }
        let version = data[0] >> 6;
        if version != 2 {
            return Err(RtpError::Version(version));
        }
        let padding = data[0] & 0x20 != 0;
        let has_extension = data[0] & 0x10 != 0;
        let csrc_count = (data[0] & 0x0F) as usize;
        let marker = data[1] & 0x80 != 0;
        let payload_type = data[1] & 0x7F;
        let seq = u16::from_be_bytes([data[2], data[3]]);
        let timestamp = u32::from_be_bytes([data[4], data[5], data[6], data[7]]);
        let ssrc = u32::from_be_bytes([data[8], data[9], data[10], data[11]]);
        let truncated = |what| RtpError::Truncated {
            what,
            len: data.len(),
        };
        let mut at = HEADER_LEN;
        let csrc_end = at + 4 * csrc_count;
        let csrc = data.get(at..csrc_end).ok_or(truncated("CSRC list"))?;
        at = csrc_end;
        let extension = if has_extension {
            let head = data.get(at..at + 4).ok_or(truncated("header extension"))?;
            let profile = u16::from_be_bytes([head[0], head[1]]);
            let words = u16::from_be_bytes([head[2], head[3]]) as usize;
            let body = data
                .get(at + 4..at + 4 + 4 * words)
                .ok_or(truncated("header extension"))?;
            at += 4 + 4 * words;
            // Checks the elements once.
            for element in Elements::new(profile, body) {
                element?;
            }
            Some((profile, body))
        } else {
            None
        };
        let mut end = data.len();
        if padding {
            let count = data[end - 1] as usize;
            if count == 0 {
                return Err(RtpError::BadPadding);
            }
            if count > end - at {
                return Err(truncated("padding"));
            }
            end -= count;
        }
        Ok(Packet {
            marker,
            payload_type,
            seq,
            timestamp,
            ssrc,
            csrc,
            extension,
            payload: &data[at..end],
        })
    }

    /// The contributing sources.
    pub fn csrcs(&self) -> impl Iterator<Item = u32> + '_ {
        self.csrc
            .chunks_exact(4)
            .map(|c| u32::from_be_bytes([c[0], c[1], c[2], c[3]]))
    }

    /// The data of the RFC 8285 element `id`, in the one-byte or the two-byte form; `None` when
    /// there is no such element (or the extension has another profile).
    pub fn extension(&self, id: u8) -> Option<&'a [u8]> {
        let (profile, body) = self.extension?;
        Elements::new(profile, body)
            .filter_map(Result::ok)
            .find(|(i, _)| *i == id)
            .map(|(_, data)| data)
    }

    /// The extension's profile, if the packet has one.
    pub fn extension_profile(&self) -> Option<u16> {
        self.extension.map(|(p, _)| p)
    }
}

/// The elements of an RFC 8285 extension block: `(id, data)`. Another profile has none.
struct Elements<'a> {
    form: Option<Form>,
    body: &'a [u8],
    at: usize,
}

#[derive(Clone, Copy)]
enum Form {
    OneByte,
    TwoByte,
}

impl<'a> Elements<'a> {
    fn new(profile: u16, body: &'a [u8]) -> Self {
        let form = if profile == ONE_BYTE_PROFILE {
            Some(Form::OneByte)
        } else if profile & 0xFFF0 == TWO_BYTE_PROFILE {
            Some(Form::TwoByte)
        } else {
            None
        };
        Elements { form, body, at: 0 }
    }
}

impl<'a> Iterator for Elements<'a> {
    type Item = Result<(u8, &'a [u8]), RtpError>;

    fn next(&mut self) -> Option<Self::Item> {
        let form = self.form?;
        loop {
            let &first = self.body.get(self.at)?;
            let (id, len, head) = match form {
                Form::OneByte => {
                    let id = first >> 4;
                    if id == 0 {
                        // Padding.
                        self.at += 1;
                        continue;
                    }
                    if id == 15 {
                        // Reserved: stop reading (RFC 8285, 4.2).
                        self.at = self.body.len();
                        return None;
                    }
                    (id, (first & 0x0F) as usize + 1, 1)
                }
                Form::TwoByte => {
                    if first == 0 {
                        self.at += 1;
                        continue;
                    }
                    let Some(&len) = self.body.get(self.at + 1) else {
                        self.at = self.body.len();
                        return Some(Err(RtpError::BadExtension));
                    };
                    (first, len as usize, 2)
                }
            };
            let start = self.at + head;
            let Some(data) = self.body.get(start..start + len) else {
                self.at = self.body.len();
                return Some(Err(RtpError::BadExtension));
            };
            self.at = start + len;
            return Some(Ok((id, data)));
        }
    }
}

/// The fixed header of a packet to write.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Header {
    pub marker: bool,
    pub payload_type: u8,
    pub seq: u16,
    pub timestamp: u32,
    pub ssrc: u32,
}

/// The largest element data in the one-byte form, and its largest id.
const ONE_BYTE_MAX_LEN: usize = 16;
const ONE_BYTE_MAX_ID: u8 = 14;

/// How many bytes [`write`] adds for an extension element of `len` bytes (0 without one).
pub fn extension_len(len: Option<usize>, id: u8) -> usize {
    match len {
        None => 0,
        Some(len) => {
            let head = if one_byte(id, len) { 1 } else { 2 };
            4 + (head + len).div_ceil(4) * 4
        }
    }
}

fn one_byte(id: u8, len: usize) -> bool {
    (1..=ONE_BYTE_MAX_ID).contains(&id) && (1..=ONE_BYTE_MAX_LEN).contains(&len)
}

/// Writes a packet into `out` (cleared first): the header, one RFC 8285 element `(id, data)` if
/// given (the one-byte form where it fits, else the two-byte form; id 1..=255, data at most 255
/// bytes), and the payload.
///
/// # Panics
/// On an extension id of 0 or data longer than 255 bytes (the caller's constants).
pub fn write(out: &mut Vec<u8>, header: &Header, extension: Option<(u8, &[u8])>, payload: &[u8]) {
    out.clear();
    out.push(0x80 | if extension.is_some() { 0x10 } else { 0 });
    out.push((header.marker as u8) << 7 | (header.payload_type & 0x7F));
    out.extend_from_slice(&header.seq.to_be_bytes());
    out.extend_from_slice(&header.timestamp.to_be_bytes());
    out.extend_from_slice(&header.ssrc.to_be_bytes());
    if let Some((id, data)) = extension {
        assert!(
            id != 0 && data.len() <= 255,
            "an RFC 8285 element's id or length"
        );
        let start = out.len();
        let total = extension_len(Some(data.len()), id);
        let words = ((total - 4) / 4) as u16;
        if one_byte(id, data.len()) {
            out.extend_from_slice(&ONE_BYTE_PROFILE.to_be_bytes());
            out.extend_from_slice(&words.to_be_bytes());
            out.push(id << 4 | (data.len() - 1) as u8);
        } else {
            out.extend_from_slice(&TWO_BYTE_PROFILE.to_be_bytes());
            out.extend_from_slice(&words.to_be_bytes());
            out.push(id);
            out.push(data.len() as u8);
        }
        out.extend_from_slice(data);
        // Padding bytes of 0 up to the block's 32-bit words.
        out.resize(start + total, 0);
    }
    out.extend_from_slice(payload);
}

/// RTP sequence numbers extended to 64 bits (RFC 3550, appendix A.1): the distance of a new number
/// from the highest seen, taken modulo 2^16 as the shorter way round.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SeqUnwrap {
    highest: Option<u64>,
}

impl SeqUnwrap {
    /// The highest extended number seen.
    pub fn highest(&self) -> Option<u64> {
        self.highest
    }

    /// The signed distance of `seq` from the highest number seen (0 for the first).
    pub fn distance(&self, seq: u16) -> i64 {
        match self.highest {
            None => 0,
            Some(h) => seq.wrapping_sub(h as u16) as i16 as i64,
        }
    }

    /// Takes `seq` as the next number: the highest moves to it when it is ahead.
    pub fn accept(&mut self, seq: u16) -> u64 {
        let ext = match self.highest {
            // Start a cycle up so that a packet a little late never goes below 0.
            None => (1u64 << 16) + seq as u64,
            Some(h) => h.wrapping_add_signed(self.distance(seq)),
        };
        if self.highest.is_none_or(|h| ext > h) {
            self.highest = Some(ext);
        }
        ext
    }
}

/// RTP timestamps (32 bits, wrapping) extended to 64 bits, the same way.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct TimestampUnwrap {
    last: Option<u64>,
}

impl TimestampUnwrap {
    /// The extended timestamp of `ts`, next to the last one.
    pub fn unwrap(&mut self, ts: u32) -> u64 {
        let ext = match self.last {
            None => (1u64 << 32) + ts as u64,
            Some(l) => l.wrapping_add_signed(ts.wrapping_sub(l as u32) as i32 as i64),
        };
        self.last = Some(ext);
        ext
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn header(seq: u16) -> Header {
        Header {
            marker: true,
            payload_type: 96,
            seq,
            timestamp: 0xDEAD_BEEF,
            ssrc: 0x1234_5678,
        }
    }

    #[test]
    fn a_written_packet_parses_back() {
        let mut buf = Vec::new();
        write(&mut buf, &header(65535), None, b"hello");
        let p = Packet::parse(&buf).unwrap();
        assert_eq!(
            (p.marker, p.payload_type, p.seq, p.timestamp, p.ssrc),
            (true, 96, 65535, 0xDEAD_BEEF, 0x1234_5678)
        );
        assert_eq!(p.payload, b"hello");
        assert_eq!(p.extension(1), None);
        assert_eq!(p.csrcs().count(), 0);
        assert_eq!(buf.len(), HEADER_LEN + 5);
    }

    /// The bytes of a packet from RFC 3550's layout, built by hand: CSRCs, a one-byte extension
    /// with padding between its elements, and RTP padding.
    #[test]
    fn csrcs_extensions_and_padding_are_read() {
        let mut b = vec![0x80 | 0x20 | 0x10 | 2, 0x60, 0x00, 0x07];
        b.extend_from_slice(&1000u32.to_be_bytes());
        b.extend_from_slice(&42u32.to_be_bytes());
        b.extend_from_slice(&7u32.to_be_bytes());
        b.extend_from_slice(&8u32.to_be_bytes());
        // One-byte extension, 2 words: id 3 (2 bytes), a padding byte, id 5 (1 byte), padding.
        b.extend_from_slice(&[0xBE, 0xDE, 0x00, 0x02]);
        b.extend_from_slice(&[0x31, 0xAA, 0xBB, 0x00, 0x50, 0xCC, 0x00, 0x00]);
        b.extend_from_slice(b"payload");
        b.extend_from_slice(&[0, 0, 3]);
        let p = Packet::parse(&b).unwrap();
        assert!(!p.marker);
        assert_eq!(p.payload_type, 96);
        assert_eq!(p.seq, 7);
        assert_eq!(p.csrcs().collect::<Vec<_>>(), vec![7, 8]);
        assert_eq!(p.extension(3), Some(&[0xAA, 0xBB][..]));
        assert_eq!(p.extension(5), Some(&[0xCC][..]));
        assert_eq!(p.extension(4), None);
        assert_eq!(p.extension_profile(), Some(ONE_BYTE_PROFILE));
        assert_eq!(p.payload, b"payload");
    }

    #[test]
    fn extensions_round_trip_in_both_forms() {
        let mut buf = Vec::new();
        for (id, len) in [
            (1u8, 1usize),
            (14, 16),
            (14, 17),
            (15, 3),
            (200, 88),
            (255, 255),
        ] {
            let data: Vec<u8> = (0..len).map(|i| (i * 13 + len) as u8).collect();
            write(&mut buf, &header(9), Some((id, &data)), b"xyz");
            let p = Packet::parse(&buf).unwrap();
            assert_eq!(p.extension(id), Some(&data[..]), "id {id}, {len} bytes");
            assert_eq!(p.payload, b"xyz");
            let form = p.extension_profile().unwrap();
            assert_eq!(form == ONE_BYTE_PROFILE, id <= 14 && len <= 16, "id {id}");
            assert_eq!(
                buf.len(),
                HEADER_LEN + extension_len(Some(len), id) + 3,
                "id {id}"
            );
            assert_eq!((buf.len() - HEADER_LEN - 3) % 4, 0);
        }
    }

    #[test]
    fn malformed_packets_are_refused() {
        let mut good = Vec::new();
        write(&mut good, &header(1), Some((200, &[1; 40])), b"data");
        for len in 0..HEADER_LEN {
            assert_eq!(Packet::parse(&good[..len]), Err(RtpError::Short { len }));
        }
        // Cut inside the extension.
        assert!(matches!(
            Packet::parse(&good[..HEADER_LEN + 10]),
            Err(RtpError::Truncated { .. })
        ));
        let mut v1 = good.clone();
        v1[0] = (v1[0] & 0x3F) | 0x40;
        assert_eq!(Packet::parse(&v1), Err(RtpError::Version(1)));
        // 15 CSRCs announced, none there.
        let mut csrc = good.clone();
        csrc[0] |= 0x0F;
        csrc.truncate(HEADER_LEN + 8);
        assert!(matches!(
            Packet::parse(&csrc),
            Err(RtpError::Truncated {
                what: "CSRC list",
                ..
            })
        ));
        // An element longer than its block.
        let mut ext = good.clone();
        ext[HEADER_LEN + 5] = 200;
        assert_eq!(Packet::parse(&ext), Err(RtpError::BadExtension));
        // Padding longer than the packet, or of 0.
        let mut pad = good.clone();
        pad[0] |= 0x20;
        *pad.last_mut().unwrap() = 250;
        assert!(matches!(
            Packet::parse(&pad),
            Err(RtpError::Truncated {
                what: "padding",
                ..
            })
        ));
        *pad.last_mut().unwrap() = 0;
        assert_eq!(Packet::parse(&pad), Err(RtpError::BadPadding));
        // Every prefix and every single-byte corruption of a good packet: an answer, no panic.
        for len in 0..good.len() {
            let _ = Packet::parse(&good[..len]);
        }
        for i in 0..good.len() {
            for v in [0x00, 0xFF, 0x80, 0x7F] {
                let mut b = good.clone();
                b[i] = v;
                if let Ok(p) = Packet::parse(&b) {
                    let _ = p.extension(200);
                }
            }
        }
    }

    #[test]
    fn an_unknown_extension_profile_has_no_elements() {
        let mut b = vec![0x90, 96, 0, 1, 0, 0, 0, 1, 0, 0, 0, 2];
        b.extend_from_slice(&[0xAB, 0xCD, 0x00, 0x01, 0x10, 0x20, 0x30, 0x40]);
        b.extend_from_slice(b"p");
        let p = Packet::parse(&b).unwrap();
        assert_eq!(p.extension_profile(), Some(0xABCD));
        assert_eq!(p.extension(1), None);
        assert_eq!(p.payload, b"p");
    }

    #[test]
    fn sequence_numbers_unwrap_across_the_wrap() {
        let mut u = SeqUnwrap::default();
        let base = u.accept(65534);
        assert_eq!(u.accept(65535), base + 1);
        assert_eq!(u.distance(1), 2);
        assert_eq!(u.accept(1), base + 3);
        // Late: behind the highest, which stays.
        assert_eq!(u.distance(0), -1);
        assert_eq!(u.accept(0), base + 2);
        assert_eq!(u.highest(), Some(base + 3));
        // Far back, the shorter way round.
        assert_eq!(u.distance(40000), 40000 - 65536 - 1);
    }

    #[test]
    fn timestamps_unwrap_across_the_wrap() {
        let mut u = TimestampUnwrap::default();
        let a = u.unwrap(u32::MAX - 1499);
        let b = u.unwrap(1500);
        assert_eq!(b - a, 3000);
        let c = u.unwrap(0);
        assert_eq!(b - c, 1500, "a step back is a step back");
    }
}
