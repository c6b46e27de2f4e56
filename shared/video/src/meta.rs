//! The twin's per-frame metadata on the wire: one RFC 8285 header extension element (two-byte form,
//! id [`ELEMENT_ID`]) on every packet of the frame, carrying what [`adapters::FrameMeta`] carries
//! but the size (the receiver scales every frame to its own).
//!
//! ```text
//! offset size  field (big-endian)
//!   0     2    magic "ct"
//!   2     1    version (1)
//!   3     1    flags: bit 0 = the true line is known
//!   4     8    seq: the device's frame counter
//!  12     8    time_ns: the device's clock when the frame was taken
//!  20     4    trial
//!  24     4    step
//!  28     1    status: 0 running, 1 cable lost, 2 time limit
//!  29     1    truth.found
//!  30     2    reserved (0)
//!  32    56    truth: rho, theta, x_g, y_g, x_g_rate, theta_rate, confidence (f64)
//! = 88 bytes
//! ```
//!
//! An element with this id but another magic is someone else's and ignored; ours with another
//! version or length is an error (the frame is refused, not misread).

use adapters::{CableObservationData, FrameMeta, StepStatus};
use std::fmt;

/// The element's id (RFC 8285 two-byte form).
pub const ELEMENT_ID: u8 = 100;
/// The element's length.
pub const LEN: usize = 88;
const MAGIC: [u8; 2] = *b"ct";
const VERSION: u8 = 1;
const TRUTH_KNOWN: u8 = 1;

/// A frame's metadata as carried on the wire (the status not yet checked).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WireMeta {
    pub seq: u64,
    pub time_ns: u64,
    pub trial: u32,
    pub step: u32,
    pub status: u8,
    pub truth: Option<CableObservationData>,
}

/// Why an element of ours cannot be read.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MetaError {
    Length(usize),
    Version(u8),
}

impl fmt::Display for MetaError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            MetaError::Length(n) => write!(f, "frame metadata of {n} bytes, expected {LEN}"),
            MetaError::Version(v) => write!(f, "frame metadata version {v}, expected {VERSION}"),
        }
    }
}

impl std::error::Error for MetaError {}

impl WireMeta {
    pub fn of(meta: &FrameMeta) -> Self {
        WireMeta {
            seq: meta.seq,
            time_ns: meta.time_ns,
            trial: meta.trial,
            step: meta.step,
            status: meta.status as u8,
            truth: meta.truth,
        }
    }

    /// The frame's metadata at the receiver's size, or why its status is unknown.
    pub fn frame_meta(&self, width: u32, height: u32) -> Result<FrameMeta, String> {
        let status = StepStatus::from_u8(self.status)
            .ok_or_else(|| format!("unknown status {}", self.status))?;
        Ok(FrameMeta {
            seq: self.seq,
            time_ns: self.time_ns,
            width,
            height,
            trial: self.trial,
            step: self.step,
            status,
            truth: self.truth,
            damaged: false,
        })
    }

    pub fn encode(&self) -> [u8; LEN] {
        let mut b = [0u8; LEN];
        b[0..2].copy_from_slice(&MAGIC);
        b[2] = VERSION;
        b[3] = if self.truth.is_some() { TRUTH_KNOWN } else { 0 };
        b[4..12].copy_from_slice(&self.seq.to_be_bytes());
        b[12..20].copy_from_slice(&self.time_ns.to_be_bytes());
        b[20..24].copy_from_slice(&self.trial.to_be_bytes());
        b[24..28].copy_from_slice(&self.step.to_be_bytes());
        b[28] = self.status;
        if let Some(t) = &self.truth {
            b[29] = t.found;
            let values = [
                t.rho,
                t.theta,
                t.x_g,
                t.y_g,
                t.x_g_rate,
                t.theta_rate,
                t.confidence,
            ];
            for (k, v) in values.iter().enumerate() {
                b[32 + 8 * k..40 + 8 * k].copy_from_slice(&v.to_be_bytes());
            }
        }
        b
    }

    /// Reads an element: `Ok(None)` when it is not ours (another magic).
    pub fn decode(data: &[u8]) -> Result<Option<WireMeta>, MetaError> {
        if data.len() < 2 || data[0..2] != MAGIC {
            return Ok(None);
        }
        if data.len() != LEN {
            return Err(MetaError::Length(data.len()));
        }
        if data[2] != VERSION {
            return Err(MetaError::Version(data[2]));
        }
        let u64_at = |at: usize| u64::from_be_bytes(data[at..at + 8].try_into().expect("8 bytes"));
        let u32_at = |at: usize| u32::from_be_bytes(data[at..at + 4].try_into().expect("4 bytes"));
        let f64_at = |k: usize| f64::from_bits(u64_at(32 + 8 * k));
        let truth = (data[3] & TRUTH_KNOWN != 0).then(|| CableObservationData {
            found: data[29],
            rho: f64_at(0),
            theta: f64_at(1),
            x_g: f64_at(2),
            y_g: f64_at(3),
            x_g_rate: f64_at(4),
            theta_rate: f64_at(5),
            confidence: f64_at(6),
            ..Default::default()
        });
        Ok(Some(WireMeta {
            seq: u64_at(4),
            time_ns: u64_at(12),
            trial: u32_at(20),
            step: u32_at(24),
            status: data[28],
            truth,
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn meta() -> FrameMeta {
        FrameMeta {
            seq: 0x0102_0304_0506_0708,
            time_ns: 123_456_789_012,
            width: 320,
            height: 240,
            trial: 7,
            step: 449,
            status: StepStatus::TimeLimit,
            truth: Some(CableObservationData {
                found: 1,
                rho: -12.5,
                theta: 0.25,
                x_g: -0.125,
                y_g: 0.0,
                x_g_rate: f64::MIN_POSITIVE,
                theta_rate: -0.0,
                confidence: 1.0,
                ..Default::default()
            }),
            damaged: false,
        }
    }

    #[test]
    fn the_metadata_round_trips_bit_for_bit() {
        let m = meta();
        let bytes = WireMeta::of(&m).encode();
        let back = WireMeta::decode(&bytes).unwrap().unwrap();
        assert_eq!(back.frame_meta(320, 240).unwrap(), m);
        assert_eq!(
            back.truth.unwrap().theta_rate.to_bits(),
            (-0.0f64).to_bits()
        );
        let unknown = FrameMeta { truth: None, ..m };
        let back = WireMeta::decode(&WireMeta::of(&unknown).encode())
            .unwrap()
            .unwrap();
        assert_eq!(back.frame_meta(320, 240).unwrap(), unknown);
        // The layout's fixed places.
        assert_eq!(&bytes[0..4], b"ct\x01\x01");
        assert_eq!(bytes[28], 2);
        assert_eq!(&bytes[4..12], &[1, 2, 3, 4, 5, 6, 7, 8]);
    }

    #[test]
    fn foreign_short_and_newer_elements_are_told_apart() {
        assert_eq!(WireMeta::decode(b"xy0123"), Ok(None));
        assert_eq!(WireMeta::decode(b""), Ok(None));
        let bytes = WireMeta::of(&meta()).encode();
        assert_eq!(WireMeta::decode(&bytes[..40]), Err(MetaError::Length(40)));
        let mut newer = bytes;
        newer[2] = 2;
        assert_eq!(WireMeta::decode(&newer), Err(MetaError::Version(2)));
        let mut bad_status = bytes;
        bad_status[28] = 9;
        let m = WireMeta::decode(&bad_status).unwrap().unwrap();
        assert_eq!(m.frame_meta(1, 1), Err("unknown status 9".into()));
    }
}
