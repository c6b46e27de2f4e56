//! The latency file: camera-to-thruster latency as the hardware sees it, one answered frame a line
//! (`vehicle-twin --latency FILE` writes it, `mesh-bench` summarises it).

use std::io::Write;
use std::time::Duration;

/// One answered frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sample {
    pub seq: u64,
    pub trial: u32,
    pub step: u32,
    pub latency: Duration,
}

/// The header of a latency file.
pub const HEADER: &str = "seq,trial,step,latency_ns";

/// Writes samples as CSV lines under [`HEADER`].
pub fn write_sample(out: &mut impl Write, s: &Sample) -> std::io::Result<()> {
    writeln!(
        out,
        "{},{},{},{}",
        s.seq,
        s.trial,
        s.step,
        s.latency.as_nanos()
    )
}

/// Reads a latency file's latencies (ns), naming the line that is not one.
pub fn read_latencies(text: &str) -> Result<Vec<u64>, String> {
    let mut lines = text.lines();
    if lines.next() != Some(HEADER) {
        return Err(format!("the first line is not `{HEADER}`"));
    }
    lines
        .enumerate()
        .filter(|(_, l)| !l.is_empty())
        .map(|(i, l)| {
            l.rsplit(',')
                .next()
                .and_then(|v| v.parse().ok())
                .ok_or_else(|| format!("line {}: `{l}` is not seq,trial,step,latency_ns", i + 2))
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
            latency: Duration::from_nanos(812_345),
        };
        write_sample(&mut buf, &s).unwrap();
        write_sample(&mut buf, &s).unwrap();
        let text = String::from_utf8(buf).unwrap();
        assert_eq!(text.lines().nth(1), Some("41,2,9,812345"));
        assert_eq!(read_latencies(&text).unwrap(), vec![812_345, 812_345]);
        let err = read_latencies(&format!("{HEADER}\n1,2,3,x\n")).unwrap_err();
        assert!(err.contains("line 2"), "{err}");
        assert!(read_latencies("nonsense\n").is_err());
    }
}
