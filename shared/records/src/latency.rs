//! The latency file: camera-to-thruster latency as the hardware sees it, one answered frame a line
//! (`vehicle-twin --latency FILE` writes it, `mesh-bench` summarises it). Each line also names the
//! frame's time (its stamp's `time_ns`) and the monotonic clock when it was sent, so that what another
//! process saw of the frame on the way (its cable observation, `mesh-bench vehicle --video`) is
//! timed from the same moment.

use std::io::Write;
use std::time::Duration;

/// One answered frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sample {
    pub seq: u64,
    pub trial: u32,
    pub step: u32,
    /// The frame's time (the `time_ns` of the stamps answering it).
    pub time_ns: u64,
    /// The monotonic clock (`CLOCK_MONOTONIC`, ns) when the frame was sent.
    pub sent_ns: u64,
    pub latency: Duration,
}

/// The header of a latency file.
pub const HEADER: &str = "seq,trial,step,time_ns,sent_ns,latency_ns";
/// The header of the files written before the frame's time and send time were kept.
const HEADER_V1: &str = "seq,trial,step,latency_ns";

/// Writes samples as CSV lines under [`HEADER`].
pub fn write_sample(out: &mut impl Write, s: &Sample) -> std::io::Result<()> {
    writeln!(
        out,
        "{},{},{},{},{},{}",
        s.seq,
        s.trial,
        s.step,
        s.time_ns,
        s.sent_ns,
        s.latency.as_nanos()
    )
}

/// Reads a latency file's latencies (ns), naming the line that is not one. Files of the first
/// format (`seq,trial,step,latency_ns`) read too.
pub fn read_latencies(text: &str) -> Result<Vec<u64>, String> {
    let mut lines = text.lines();
    let header = lines.next();
    if header != Some(HEADER) && header != Some(HEADER_V1) {
        return Err(format!("the first line is not `{HEADER}`"));
    }
    lines
        .enumerate()
        .filter(|(_, l)| !l.is_empty())
        .map(|(i, l)| {
            l.rsplit(',')
                .next()
                .and_then(|v| v.parse().ok())
                .ok_or_else(|| format!("line {}: `{l}` ends in no latency_ns", i + 2))
        })
        .collect()
}

/// Reads a latency file's samples, naming the line that is not one (files of the first format
/// have no send times: an error).
pub fn read_samples(text: &str) -> Result<Vec<Sample>, String> {
    let mut lines = text.lines();
    if lines.next() != Some(HEADER) {
        return Err(format!("the first line is not `{HEADER}`"));
    }
    lines
        .enumerate()
        .filter(|(_, l)| !l.is_empty())
        .map(|(i, l)| {
            let bad = || format!("line {}: `{l}` is not {HEADER}", i + 2);
            let v: Vec<u64> = l
                .split(',')
                .map(|v| v.parse().map_err(|_| bad()))
                .collect::<Result<_, _>>()?;
            let [seq, trial, step, time_ns, sent_ns, latency] = v[..] else {
                return Err(bad());
            };
            Ok(Sample {
                seq,
                trial: u32::try_from(trial).map_err(|_| bad())?,
                step: u32::try_from(step).map_err(|_| bad())?,
                time_ns,
                sent_ns,
                latency: Duration::from_nanos(latency),
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_latency_file_reads_back() {
        let mut buf = format!("{HEADER}\n").into_bytes();
        let s = Sample {
            seq: 41,
            trial: 2,
            step: 9,
            time_ns: 1_800_000_000,
            sent_ns: 77_000_123_456,
            latency: Duration::from_nanos(812_345),
        };
        write_sample(&mut buf, &s).unwrap();
        write_sample(&mut buf, &s).unwrap();
        let text = String::from_utf8(buf).unwrap();
        assert_eq!(
            text.lines().nth(1),
            Some("41,2,9,1800000000,77000123456,812345")
        );
        assert_eq!(read_latencies(&text).unwrap(), vec![812_345, 812_345]);
        assert_eq!(read_samples(&text).unwrap(), vec![s, s]);
        let err = read_latencies(&format!("{HEADER}\n1,2,3,4,5,x\n")).unwrap_err();
        assert!(err.contains("line 2"), "{err}");
        let err = read_samples(&format!("{HEADER}\n1,2,3,5,812345\n")).unwrap_err();
        assert!(err.contains("line 2"), "{err}");
        assert!(read_latencies("nonsense\n").is_err());
        // The first format's files still give their latencies, but no samples.
        let v1 = format!("{HEADER_V1}\n41,2,9,812345\n");
        assert_eq!(read_latencies(&v1).unwrap(), vec![812_345]);
        assert!(read_samples(&v1).is_err());
    }
}
