//! Thruster sinks that drive no thruster: [`RecordSink`] writes every setpoint with its times to a
//! file (a dry run on the bench, a log of a dive), [`NullSink`] discards them.
//!
//! A record file is text, one line per write or stop:
//!
//! ```text
//! # cabletrack thruster record v2
//! seq,epoch,time_ns,clock_ns,trial,step,status,written_unix_ns,stop,port,starboard,lateral
//! 41,3921,8000000000,5120000000000,0,40,running,1763781234567890123,,0.61,0.2,-0.05
//! 41,3921,8000000000,5120000000000,0,40,running,1763781234967890123,deadline,0,0,0
//! ```
//!
//! `seq`, `epoch`, `time_ns` (the frame source's clock), `clock_ns` (the vehicle clock), `trial`,
//! `step` and `status` (`running`, `lost`, `time_limit`) are the stamp of the step the setpoints
//! answer (for a stop: the last step written);
//! `written_unix_ns` is when the sink wrote them (the wall clock, for people reading the file);
//! `stop` is empty for a step's setpoints, or the cause of a failsafe stop (`start`, `deadline`,
//! `shutdown`, `allocator_dead`); then one column per thruster, named after the layout, with the
//! setpoints as written (made safe). Floats are written in Rust's shortest round-trip form, so
//! [`read_record`] gives back the very values.

use crate::{
    AdapterError, Applied, LastSent, Stamp, StepStatus, StopCause, ThrusterSink, apply,
    check_thrusters,
};
use std::io::{BufRead, BufWriter, Write};
use std::path::{Path, PathBuf};

/// The first line of a record file.
pub const RECORD_MAGIC: &str = "# cabletrack thruster record v2";

/// The columns before the setpoints.
const STAMP_COLUMNS: [&str; 9] = [
    "seq",
    "epoch",
    "time_ns",
    "clock_ns",
    "trial",
    "step",
    "status",
    "written_unix_ns",
    "stop",
];

/// A status as written in files.
pub fn status_name(status: StepStatus) -> &'static str {
    match status {
        StepStatus::Running => "running",
        StepStatus::Lost => "lost",
        StepStatus::TimeLimit => "time_limit",
    }
}

/// A status read from a file.
pub fn parse_status(word: &str) -> Option<StepStatus> {
    match word {
        "running" => Some(StepStatus::Running),
        "lost" => Some(StepStatus::Lost),
        "time_limit" => Some(StepStatus::TimeLimit),
        _ => None,
    }
}

/// Writes setpoints with their times to a file.
pub struct RecordSink {
    path: PathBuf,
    file: Option<BufWriter<std::fs::File>>,
    thrusters: usize,
    last: LastSent,
}

impl RecordSink {
    /// Creates (or truncates) `path` for a layout with these thruster names.
    pub fn create(path: &Path, names: &[String]) -> Result<Self, AdapterError> {
        check_thrusters(&format!("record {}", path.display()), names.len())?;
        let write_err = |source| AdapterError::Write {
            path: path.to_owned(),
            source,
        };
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(write_err)?;
        }
        let mut file = BufWriter::new(std::fs::File::create(path).map_err(write_err)?);
        let columns: Vec<&str> = STAMP_COLUMNS
            .iter()
            .copied()
            .chain(names.iter().map(String::as_str))
            .collect();
        writeln!(file, "{RECORD_MAGIC}\n{}", columns.join(",")).map_err(write_err)?;
        Ok(RecordSink {
            path: path.to_owned(),
            file: Some(file),
            thrusters: names.len(),
            last: LastSent::default(),
        })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    fn write_err(&self, source: std::io::Error) -> AdapterError {
        AdapterError::Write {
            path: self.path.clone(),
            source,
        }
    }

    /// Writes one line: the stamp, the time, the stop's cause (if a stop), the values.
    fn line(
        &mut self,
        stamp: &Stamp,
        stop: Option<StopCause>,
        values: &[f64],
    ) -> Result<(), AdapterError> {
        let written = runtime::clock::unix_ns();
        let mut line = format!(
            "{},{},{},{},{},{},{},{written},{}",
            stamp.seq,
            stamp.epoch,
            stamp.time_ns,
            stamp.clock_ns,
            stamp.episode,
            stamp.step,
            status_name(stamp.status()),
            stop.map_or("", StopCause::name),
        );
        for v in values {
            line.push_str(&format!(",{v}"));
        }
        line.push('\n');
        let Some(file) = self.file.as_mut() else {
            return Err(crate::closed(self));
        };
        let result = file.write_all(line.as_bytes());
        result.map_err(|e| self.write_err(e))?;
        self.last.sent(stamp, stop.is_some());
        Ok(())
    }
}

impl ThrusterSink for RecordSink {
    fn describe(&self) -> String {
        format!("record {}", self.path.display())
    }

    fn thrusters(&self) -> usize {
        self.thrusters
    }

    fn write(&mut self, stamp: &Stamp, setpoints: &[f64]) -> Result<Applied, AdapterError> {
        if self.file.is_none() {
            return Err(crate::closed(self));
        }
        let applied = apply(&self.describe(), self.thrusters, setpoints)?;
        self.line(stamp, None, applied.as_slice())?;
        Ok(applied)
    }

    fn stop(&mut self, stamp: &Stamp, cause: StopCause) -> Result<(), AdapterError> {
        self.line(stamp, Some(cause), &vec![0.0; self.thrusters])
    }

    fn flush(&mut self) -> Result<(), AdapterError> {
        let Some(file) = self.file.as_mut() else {
            return Err(crate::closed(self));
        };
        let result = file.flush();
        result.map_err(|e| self.write_err(e))
    }

    fn close(&mut self) -> Result<(), AdapterError> {
        if self.file.is_none() {
            return Ok(());
        }
        if !self.last.stopped {
            let stamp = self.last.stamp;
            self.stop(&stamp, StopCause::Shutdown)?;
        }
        let Some(mut file) = self.file.take() else {
            return Ok(());
        };
        file.flush().map_err(|e| self.write_err(e))?;
        let result = file.get_ref().sync_all();
        result.map_err(|e| self.write_err(e))
    }
}

impl Drop for RecordSink {
    fn drop(&mut self) {
        if let Err(e) = self.close() {
            tracing::error!("{e}");
        }
    }
}

/// One line of a record file.
#[derive(Clone, Debug, PartialEq)]
pub struct Record {
    pub stamp: Stamp,
    pub written_unix_ns: u64,
    /// The cause of a failsafe stop; `None` for a step's setpoints.
    pub stop: Option<StopCause>,
    pub values: Vec<f64>,
}

/// Reads a record file: the thruster names and the records, in the order written.
pub fn read_record(path: &Path) -> Result<(Vec<String>, Vec<Record>), AdapterError> {
    let file = std::fs::File::open(path).map_err(|source| AdapterError::Read {
        path: path.to_owned(),
        source,
    })?;
    let bad = |line: usize, reason: String| AdapterError::Format {
        file: path.to_owned(),
        line,
        reason,
    };
    let mut names = Vec::new();
    let mut records = Vec::new();
    for (k, line) in std::io::BufReader::new(file).lines().enumerate() {
        let n = k + 1;
        let line = line.map_err(|source| AdapterError::Read {
            path: path.to_owned(),
            source,
        })?;
        match n {
            1 if line != RECORD_MAGIC => {
                return Err(bad(n, format!("expected `{RECORD_MAGIC}`")));
            }
            1 => continue,
            2 => {
                let cols: Vec<&str> = line.split(',').collect();
                if cols.len() <= STAMP_COLUMNS.len() || cols[..STAMP_COLUMNS.len()] != STAMP_COLUMNS
                {
                    return Err(bad(
                        n,
                        format!(
                            "expected the columns {} and one per thruster",
                            STAMP_COLUMNS.join(",")
                        ),
                    ));
                }
                names = cols[STAMP_COLUMNS.len()..]
                    .iter()
                    .map(|s| s.to_string())
                    .collect();
                continue;
            }
            _ => {}
        }
        let cols: Vec<&str> = line.split(',').collect();
        if cols.len() != STAMP_COLUMNS.len() + names.len() {
            return Err(bad(
                n,
                format!(
                    "{} fields, expected {}",
                    cols.len(),
                    STAMP_COLUMNS.len() + names.len()
                ),
            ));
        }
        let int = |i: usize| {
            cols[i]
                .parse::<u64>()
                .map_err(|e| bad(n, format!("{} `{}`: {e}", STAMP_COLUMNS[i], cols[i])))
        };
        let signed = |i: usize| {
            cols[i]
                .parse::<i64>()
                .map_err(|e| bad(n, format!("{} `{}`: {e}", STAMP_COLUMNS[i], cols[i])))
        };
        let small = |i: usize| {
            u32::try_from(int(i)?).map_err(|e| bad(n, format!("{}: {e}", STAMP_COLUMNS[i])))
        };
        let status =
            parse_status(cols[6]).ok_or_else(|| bad(n, format!("unknown status `{}`", cols[6])))?;
        let mut values = Vec::with_capacity(names.len());
        for (j, c) in cols[STAMP_COLUMNS.len()..].iter().enumerate() {
            values.push(
                c.parse::<f64>()
                    .map_err(|e| bad(n, format!("setpoint of {} `{c}`: {e}", names[j])))?,
            );
        }
        let stop = match cols[8] {
            "" => None,
            word => Some(
                StopCause::parse(word)
                    .ok_or_else(|| bad(n, format!("unknown stop cause `{word}`")))?,
            ),
        };
        let stamp = Stamp::new(int(0)?, int(2)?, small(4)?, small(5)?, status);
        records.push(Record {
            stamp: stamp.timed(small(1)?, signed(3)?),
            written_unix_ns: int(7)?,
            stop,
            values,
        });
    }
    if names.is_empty() {
        return Err(bad(1, "empty record file".into()));
    }
    Ok((names, records))
}

/// Discards setpoints (after checking and making them safe, as any sink does).
pub struct NullSink {
    thrusters: usize,
    written: u64,
    stops: u64,
    last: LastSent,
    closed: bool,
}

impl NullSink {
    pub fn new(thrusters: usize) -> Result<Self, AdapterError> {
        check_thrusters("null thrusters", thrusters)?;
        Ok(NullSink {
            thrusters,
            written: 0,
            stops: 0,
            last: LastSent::default(),
            closed: false,
        })
    }

    /// Writes accepted so far.
    pub fn written(&self) -> u64 {
        self.written
    }

    /// Stops so far.
    pub fn stops(&self) -> u64 {
        self.stops
    }
}

impl ThrusterSink for NullSink {
    fn describe(&self) -> String {
        "null thrusters".into()
    }

    fn thrusters(&self) -> usize {
        self.thrusters
    }

    fn write(&mut self, stamp: &Stamp, setpoints: &[f64]) -> Result<Applied, AdapterError> {
        if self.closed {
            return Err(crate::closed(self));
        }
        let applied = apply("null thrusters", self.thrusters, setpoints)?;
        self.written += 1;
        self.last.sent(stamp, false);
        Ok(applied)
    }

    fn stop(&mut self, stamp: &Stamp, _cause: StopCause) -> Result<(), AdapterError> {
        if self.closed {
            return Err(crate::closed(self));
        }
        self.stops += 1;
        self.last.sent(stamp, true);
        Ok(())
    }

    fn flush(&mut self) -> Result<(), AdapterError> {
        if self.closed {
            return Err(crate::closed(self));
        }
        Ok(())
    }

    fn close(&mut self) -> Result<(), AdapterError> {
        if self.closed {
            return Ok(());
        }
        if !self.last.stopped {
            let stamp = self.last.stamp;
            self.stop(&stamp, StopCause::Shutdown)?;
        }
        self.closed = true;
        Ok(())
    }
}
