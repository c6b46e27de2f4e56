//! Recorded dives: [`DiveWriter`] records one (the vehicle twin does with `--record DIR`),
//! [`ReplaySource`] plays it back as the camera's frame source, paced by its timestamps, so
//! perception and the behaviours run on recorded data.
//!
//! # The dive format (version 1)
//!
//! A dive is a directory:
//!
//! ```text
//! DIR/index.csv
//! DIR/frames/0000000001.pgm      (or .png: 8-bit grey; PGM P5/P2 and PNG of any colour type are read)
//! DIR/frames/0000000002.pgm
//! ...
//! ```
//!
//! `index.csv` is text. Its first line is `# cabletrack dive v1`, its second `# width=W height=H`
//! (every frame has this size), its third the column names, either
//!
//! ```text
//! seq,time_ns,trial,step,status,file
//! ```
//!
//! or, when the true line of each frame is known (a dive recorded from the twin),
//!
//! ```text
//! seq,time_ns,trial,step,status,file,found,rho,theta,x_g,y_g,x_g_rate,theta_rate
//! ```
//!
//! and then one line per frame, in the order taken: `seq` the camera's frame counter (strictly
//! increasing; gaps are frames lost before the recorder), `time_ns` the vehicle clock when the frame
//! was taken (non-decreasing; the replay is paced by it), `trial` and `step` the trial and the step
//! within it, `status` `running`, `lost` or `time_limit` (the trial ended with this frame), `file`
//! the frame's image, relative to `DIR` (no `..`). The truth columns are those of
//! [`messages::CableObservationData`]: `found` 0 or 1, the others numbers (radians, fractions of the image,
//! per second). Lines starting with `#` after the first two are comments.
//!
//! A broken index is refused when the dive is opened, naming the line; a missing or corrupt frame
//! file is an error when its turn comes, and the replay goes on with the next frame.

use crate::record::{parse_status, status_name};
use crate::{
    AdapterError, CableObservationData, Frame, FrameMeta, FrameSource, Read, SeqOrigin, Wake,
};
use std::cell::Cell;
use std::io::{BufRead, BufWriter, Write};
use std::path::{Component, Path, PathBuf};
use std::time::{Duration, Instant};

/// The first line of a dive's index.
pub const DIVE_MAGIC: &str = "# cabletrack dive v1";
/// The index's file name in a dive's directory.
pub const INDEX: &str = "index.csv";

const COLUMNS: &str = "seq,time_ns,trial,step,status,file";
const TRUTH_COLUMNS: &str = "found,rho,theta,x_g,y_g,x_g_rate,theta_rate";

/// The image file format of a recorded dive's frames.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ImageFormat {
    /// Binary PGM: fast to write, 77 kB a frame.
    Pgm,
    /// PNG: smaller, slower.
    Png,
}

impl ImageFormat {
    fn extension(self) -> &'static str {
        match self {
            ImageFormat::Pgm => "pgm",
            ImageFormat::Png => "png",
        }
    }
}

/// Records a dive.
pub struct DiveWriter {
    dir: PathBuf,
    index: BufWriter<std::fs::File>,
    width: u32,
    height: u32,
    truth: bool,
    format: ImageFormat,
    last: Option<(u64, u64)>,
    frames: u64,
}

impl DiveWriter {
    /// Starts a dive of `width x height` frames in `dir` (created if needed; an existing dive there
    /// is not overwritten). With `truth`, every frame's true line is recorded too.
    pub fn create(
        dir: &Path,
        width: u32,
        height: u32,
        truth: bool,
        format: ImageFormat,
    ) -> Result<Self, AdapterError> {
        let index_path = dir.join(INDEX);
        let write_err = |path: &Path| {
            let path = path.to_owned();
            move |source| AdapterError::Write { path, source }
        };
        std::fs::create_dir_all(dir.join("frames")).map_err(write_err(dir))?;
        let file = std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&index_path)
            .map_err(write_err(&index_path))?;
        let mut index = BufWriter::new(file);
        let columns = if truth {
            format!("{COLUMNS},{TRUTH_COLUMNS}")
        } else {
            COLUMNS.to_owned()
        };
        writeln!(
            index,
            "{DIVE_MAGIC}\n# width={width} height={height}\n{columns}"
        )
        .and_then(|_| index.flush())
        .map_err(write_err(&index_path))?;
        Ok(DiveWriter {
            dir: dir.to_owned(),
            index,
            width,
            height,
            truth,
            format,
            last: None,
            frames: 0,
        })
    }

    /// Frames recorded so far.
    pub fn frames(&self) -> u64 {
        self.frames
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Records a frame (its image file, then its index line).
    pub fn write(&mut self, meta: &FrameMeta, image: &[u8]) -> Result<(), AdapterError> {
        let index_path = self.dir.join(INDEX);
        let bad = |reason: String| AdapterError::Format {
            file: index_path.clone(),
            line: self.frames as usize + 4,
            reason,
        };
        if (meta.width, meta.height) != (self.width, self.height) {
            return Err(AdapterError::Size {
                adapter: format!("dive {}", self.dir.display()),
                seq: meta.seq,
                width: self.width,
                height: self.height,
                got_width: meta.width,
                got_height: meta.height,
            });
        }
        if image.len() != meta.len() {
            return Err(bad(format!(
                "frame {}: {} image bytes for {}x{}",
                meta.seq,
                image.len(),
                meta.width,
                meta.height
            )));
        }
        if let Some((seq, time)) = self.last
            && (meta.seq <= seq || meta.time_ns < time)
        {
            return Err(bad(format!(
                "frame {} at {} ns comes after frame {seq} at {time} ns: out of order",
                meta.seq, meta.time_ns
            )));
        }
        let truth = match (self.truth, meta.truth) {
            (false, _) => None,
            (true, Some(t)) => Some(t),
            (true, None) => {
                return Err(bad(format!(
                    "frame {} has no truth, the dive records it",
                    meta.seq
                )));
            }
        };
        let file = format!("frames/{:010}.{}", meta.seq, self.format.extension());
        let frame =
            vision::Frame::from_vec(meta.width as usize, meta.height as usize, image.to_vec())
                .map_err(|e| bad(format!("frame {}: {e}", meta.seq)))?;
        frame
            .write(&self.dir.join(&file))
            .map_err(|source| AdapterError::Image {
                seq: meta.seq,
                source,
            })?;
        let mut line = format!(
            "{},{},{},{},{},{file}",
            meta.seq,
            meta.time_ns,
            meta.trial,
            meta.step,
            status_name(meta.status)
        );
        if let Some(t) = truth {
            line.push_str(&format!(
                ",{},{},{},{},{},{},{}",
                t.found, t.rho, t.theta, t.x_g, t.y_g, t.x_g_rate, t.theta_rate
            ));
        }
        line.push('\n');
        // One line at a time: a dive cut short by a crash is readable up to its last frame.
        self.index
            .write_all(line.as_bytes())
            .and_then(|_| self.index.flush())
            .map_err(|source| AdapterError::Write {
                path: index_path.clone(),
                source,
            })?;
        self.last = Some((meta.seq, meta.time_ns));
        self.frames += 1;
        Ok(())
    }

    /// Flushes the index to disk.
    pub fn finish(mut self) -> Result<u64, AdapterError> {
        let path = self.dir.join(INDEX);
        self.index
            .flush()
            .and_then(|_| self.index.get_ref().sync_all())
            .map_err(|source| AdapterError::Write { path, source })?;
        Ok(self.frames)
    }
}

/// One frame of a dive's index.
#[derive(Clone, Debug, PartialEq)]
pub struct Entry {
    pub meta: FrameMeta,
    /// The image file, relative to the dive's directory.
    pub file: PathBuf,
}

/// A dive's index: the frame size and every frame's entry.
#[derive(Clone, Debug, PartialEq)]
pub struct Index {
    pub width: u32,
    pub height: u32,
    pub truth: bool,
    pub entries: Vec<Entry>,
}

impl Index {
    /// Reads and checks `DIR/index.csv`.
    pub fn read(dir: &Path) -> Result<Index, AdapterError> {
        let path = dir.join(INDEX);
        let file = std::fs::File::open(&path).map_err(|source| AdapterError::Read {
            path: path.clone(),
            source,
        })?;
        let lines = std::io::BufReader::new(file).lines();
        Index::parse(lines, &path)
    }

    fn parse(
        lines: impl Iterator<Item = std::io::Result<String>>,
        path: &Path,
    ) -> Result<Index, AdapterError> {
        let bad = |line: usize, reason: String| AdapterError::Format {
            file: path.to_owned(),
            line,
            reason,
        };
        let mut size = None;
        let mut truth = None;
        let mut entries: Vec<Entry> = Vec::new();
        for (k, line) in lines.enumerate() {
            let n = k + 1;
            let line = line.map_err(|source| AdapterError::Read {
                path: path.to_owned(),
                source,
            })?;
            let line = line.trim_end_matches('\r');
            match n {
                1 => {
                    if line != DIVE_MAGIC {
                        return Err(bad(n, format!("expected `{DIVE_MAGIC}`")));
                    }
                    continue;
                }
                2 => {
                    size = Some(parse_size(line).map_err(|r| bad(n, r))?);
                    continue;
                }
                3 => {
                    truth = Some(if line == COLUMNS {
                        false
                    } else if line == format!("{COLUMNS},{TRUTH_COLUMNS}") {
                        true
                    } else {
                        return Err(bad(
                            n,
                            format!(
                                "expected the columns `{COLUMNS}` (and optionally `,{TRUTH_COLUMNS}`)"
                            ),
                        ));
                    });
                    continue;
                }
                _ => {}
            }
            if line.starts_with('#') || line.trim().is_empty() {
                continue;
            }
            let (width, height) = size.expect("line 2 was read");
            let with_truth = truth.expect("line 3 was read");
            let entry = parse_entry(line, width, height, with_truth).map_err(|r| bad(n, r))?;
            if let Some(prev) = entries.last() {
                if entry.meta.seq <= prev.meta.seq {
                    return Err(bad(
                        n,
                        format!(
                            "seq {} does not follow seq {}: frames must be in the order taken",
                            entry.meta.seq, prev.meta.seq
                        ),
                    ));
                }
                if entry.meta.time_ns < prev.meta.time_ns {
                    return Err(bad(
                        n,
                        format!(
                            "time {} ns is before the previous frame's {} ns",
                            entry.meta.time_ns, prev.meta.time_ns
                        ),
                    ));
                }
            }
            entries.push(entry);
        }
        let Some((width, height)) = size else {
            return Err(bad(1, "the index is empty".into()));
        };
        let Some(truth) = truth else {
            return Err(bad(3, "the column names are missing".into()));
        };
        Ok(Index {
            width,
            height,
            truth,
            entries,
        })
    }
}

fn parse_size(line: &str) -> Result<(u32, u32), String> {
    let err = || "expected `# width=W height=H`".to_owned();
    let rest = line.strip_prefix('#').ok_or_else(err)?;
    let mut words = rest.split_whitespace();
    let w = words
        .next()
        .and_then(|w| w.strip_prefix("width="))
        .ok_or_else(err)?;
    let h = words
        .next()
        .and_then(|h| h.strip_prefix("height="))
        .ok_or_else(err)?;
    if words.next().is_some() {
        return Err(err());
    }
    let side = |s: &str| -> Result<u32, String> {
        let v: u32 = s.parse().map_err(|e| format!("size `{s}`: {e}"))?;
        if !(vision::MIN_SIDE..=vision::MAX_SIDE).contains(&(v as usize)) {
            return Err(format!(
                "size {v} is not within [{}, {}] pixels",
                vision::MIN_SIDE,
                vision::MAX_SIDE
            ));
        }
        Ok(v)
    };
    Ok((side(w)?, side(h)?))
}

fn parse_entry(line: &str, width: u32, height: u32, truth: bool) -> Result<Entry, String> {
    let cols: Vec<&str> = line.split(',').collect();
    let expected = if truth { 13 } else { 6 };
    if cols.len() != expected {
        return Err(format!("{} fields, expected {expected}", cols.len()));
    }
    let int = |i: usize, name: &str| -> Result<u64, String> {
        cols[i]
            .trim()
            .parse::<u64>()
            .map_err(|e| format!("{name} `{}`: {e}", cols[i]))
    };
    let small = |i: usize, name: &str| -> Result<u32, String> {
        u32::try_from(int(i, name)?).map_err(|e| format!("{name}: {e}"))
    };
    let status = parse_status(cols[4].trim())
        .ok_or_else(|| format!("unknown status `{}` (running, lost or time_limit)", cols[4]))?;
    let file = PathBuf::from(cols[5].trim());
    if file.as_os_str().is_empty()
        || !file
            .components()
            .all(|c| matches!(c, Component::Normal(_) | Component::CurDir))
    {
        return Err(format!(
            "file `{}` must be a path inside the dive's directory",
            cols[5]
        ));
    }
    let truth = if truth {
        let num = |i: usize, name: &str| -> Result<f64, String> {
            let v: f64 = cols[i]
                .trim()
                .parse()
                .map_err(|e| format!("{name} `{}`: {e}", cols[i]))?;
            if v.is_finite() {
                Ok(v)
            } else {
                Err(format!("{name} `{}` is not a finite number", cols[i]))
            }
        };
        let found = match cols[6].trim() {
            "0" => 0,
            "1" => 1,
            other => return Err(format!("found `{other}` must be 0 or 1")),
        };
        Some(CableObservationData {
            found,
            rho: num(7, "rho")?,
            theta: num(8, "theta")?,
            x_g: num(9, "x_g")?,
            y_g: num(10, "y_g")?,
            x_g_rate: num(11, "x_g_rate")?,
            theta_rate: num(12, "theta_rate")?,
            confidence: if found == 1 { 1.0 } else { 0.0 },
            ..Default::default()
        })
    } else {
        None
    };
    Ok(Entry {
        meta: FrameMeta {
            seq: int(0, "seq")?,
            time_ns: int(1, "time_ns")?,
            width,
            height,
            trial: small(2, "trial")?,
            step: small(3, "step")?,
            status,
            truth,
            damaged: false,
        },
        file,
    })
}

/// How a replay is paced.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Pacing {
    /// Frame k is due `(time_k - time_0) / speed` after the first read: 1 is real time.
    Speed(f64),
    /// Every frame is due at once (in-process use: a tool, a test).
    Unpaced,
}

/// A recorded dive played back as a camera.
pub struct ReplaySource {
    dir: PathBuf,
    index: Index,
    pacing: Pacing,
    tick: Duration,
    next: Cell<usize>,
    start: Cell<Option<Instant>>,
}

impl ReplaySource {
    /// Opens the dive in `dir`; its index is read and checked now, its frames when they are due.
    pub fn open(dir: &Path, pacing: Pacing) -> Result<Self, AdapterError> {
        if let Pacing::Speed(k) = pacing
            && !(k.is_finite() && k > 0.0)
        {
            return Err(AdapterError::Format {
                file: dir.to_owned(),
                line: 0,
                reason: format!("replay speed {k} must be a finite number > 0"),
            });
        }
        let index = Index::read(dir)?;
        // The pace: the shortest interval between frames, at the replay's speed.
        let shortest_ns = index
            .entries
            .windows(2)
            .map(|w| w[1].meta.time_ns - w[0].meta.time_ns)
            .filter(|&d| d > 0)
            .min()
            .unwrap_or(200_000_000);
        let tick = match pacing {
            Pacing::Speed(k) => Duration::from_secs_f64(shortest_ns as f64 / 1e9 / k),
            Pacing::Unpaced => Duration::from_millis(1),
        }
        .clamp(Duration::from_millis(1), Duration::from_secs(1));
        Ok(ReplaySource {
            dir: dir.to_owned(),
            index,
            pacing,
            tick,
            next: Cell::new(0),
            start: Cell::new(None),
        })
    }

    pub fn index(&self) -> &Index {
        &self.index
    }

    /// Frames not yet read.
    pub fn remaining(&self) -> usize {
        self.index.entries.len() - self.next.get()
    }
}

impl FrameSource for ReplaySource {
    fn describe(&self) -> String {
        format!("dive {}", self.dir.display())
    }

    fn size(&self) -> (u32, u32) {
        (self.index.width, self.index.height)
    }

    fn wake(&self) -> Wake<'_> {
        Wake::Every(self.tick)
    }

    fn seq_origin(&self) -> SeqOrigin {
        SeqOrigin::Session
    }

    fn read(&self, now: Instant, out: &mut Frame) -> Result<Read, AdapterError> {
        let next = self.next.get();
        let Some(entry) = self.index.entries.get(next) else {
            return Ok(Read::End);
        };
        if let Pacing::Speed(k) = self.pacing {
            let start = self.start.get().unwrap_or(now);
            self.start.set(Some(start));
            let first = self.index.entries[0].meta.time_ns;
            let due =
                start + Duration::from_secs_f64((entry.meta.time_ns - first) as f64 / 1e9 / k);
            // A frame due within half a tick is read now: the reader wakes once a tick.
            let slack = self.tick / 2;
            if due > now + slack {
                return Ok(Read::Pending {
                    until: Some(due - slack),
                });
            }
        }
        let meta = entry.meta;
        let path = self.dir.join(&entry.file);
        self.next.set(next + 1);
        let image = vision::Frame::read(&path).map_err(|source| AdapterError::Image {
            seq: meta.seq,
            source,
        })?;
        if (image.width(), image.height()) != (meta.width as usize, meta.height as usize) {
            return Err(AdapterError::Size {
                adapter: self.describe(),
                seq: meta.seq,
                width: meta.width,
                height: meta.height,
                got_width: image.width() as u32,
                got_height: image.height() as u32,
            });
        }
        out.meta = meta;
        out.image.clear();
        out.image.extend_from_slice(image.data());
        Ok(Read::Frame)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use messages::StepStatus;

    fn parse(text: &str) -> Result<Index, AdapterError> {
        Index::parse(
            text.lines().map(|l| Ok(l.to_owned())),
            Path::new("d/index.csv"),
        )
    }

    const HEAD: &str =
        "# cabletrack dive v1\n# width=16 height=8\nseq,time_ns,trial,step,status,file\n";

    #[test]
    fn an_index_without_truth_parses() {
        let i = parse(&format!(
            "{HEAD}1,0,0,0,running,frames/a.pgm\n# a comment\n3,400000000,0,2,lost,frames/b.png\n"
        ))
        .unwrap();
        assert_eq!((i.width, i.height, i.truth), (16, 8, false));
        assert_eq!(i.entries.len(), 2);
        let e = &i.entries[1];
        assert_eq!(
            (e.meta.seq, e.meta.time_ns, e.meta.step, e.meta.status),
            (3, 400_000_000, 2, StepStatus::Lost)
        );
        assert_eq!(e.meta.truth, None);
        assert_eq!(e.file, PathBuf::from("frames/b.png"));
    }

    #[test]
    fn a_broken_index_names_the_line() {
        let cases = [
            ("# cabletrack dive v2\n", 1, "dive v1"),
            ("# cabletrack dive v1\n# width=16\n", 2, "width=W"),
            (
                "# cabletrack dive v1\n# width=4 height=8\n",
                2,
                "not within",
            ),
            (
                "# cabletrack dive v1\n# width=16 height=8\nseq,time\n",
                3,
                "columns",
            ),
            (&format!("{HEAD}1,0,0,0,running\n"), 4, "fields"),
            (&format!("{HEAD}x,0,0,0,running,f.pgm\n"), 4, "seq"),
            (&format!("{HEAD}1,0,0,0,sinking,f.pgm\n"), 4, "status"),
            (&format!("{HEAD}1,0,0,0,running,../f.pgm\n"), 4, "inside"),
            (&format!("{HEAD}1,0,0,0,running,/etc/passwd\n"), 4, "inside"),
            (
                &format!("{HEAD}2,0,0,0,running,a.pgm\n2,5,0,1,running,b.pgm\n"),
                5,
                "order",
            ),
            (
                &format!("{HEAD}2,9,0,0,running,a.pgm\n3,5,0,1,running,b.pgm\n"),
                5,
                "before",
            ),
            ("", 1, "empty"),
        ];
        for (text, line, what) in cases {
            match parse(text) {
                Err(AdapterError::Format {
                    line: l, reason, ..
                }) => {
                    assert_eq!(l, line, "{text:?}: {reason}");
                    assert!(reason.contains(what), "{text:?}: {reason}");
                }
                other => panic!("{text:?}: {other:?}"),
            }
        }
        let truth = "# cabletrack dive v1\n# width=16 height=8\nseq,time_ns,trial,step,status,file,found,rho,theta,x_g,y_g,x_g_rate,theta_rate\n";
        assert!(parse(&format!("{truth}1,0,0,0,running,a.pgm,1,0,0.1,0.2,0,0,0\n")).is_ok());
        for bad in ["2,0,0.1,0.2,0,0,0", "1,0,NaN,0.2,0,0,0", "1,0,0.1,0.2,0,0"] {
            assert!(
                parse(&format!("{truth}1,0,0,0,running,a.pgm,{bad}\n")).is_err(),
                "{bad}"
            );
        }
    }
}
