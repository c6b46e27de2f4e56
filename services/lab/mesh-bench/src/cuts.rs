//! Cuts (`mesh-bench cuts`, `scripts/bench-cuts`): the vehicle mesh against the twin under the
//! supervisor, its files on a small file system of their own when asked (a tmpfs, which the
//! recorder fills), and `cuts` SIGKILLs at random moments (seeded) of the processes that write
//! files: the flight recorder, the two behaviours (their checkpoints) and the monitor (its run
//! record). Right after each kill the victim's files are copied as the kill left them; at the end
//! every copy and every file left is read by readers that are not the project's writers:
//!
//! - each flight-record part by the Python `mcap` package (`make_reader(f).iter_messages()`, as a
//!   user's script would), its count compared with the messages in the chunks the file holds
//!   before its end (the `mcap` crate's record reader); a part whose last commit the kill
//!   interrupted (bytes after its end) is counted, with the messages of complete chunks in them;
//! - each checkpoint (`FILE`, `FILE.prev`) by the project's loader (`learning::Checkpoint`), and the
//!   behaviour's store as a restarted behaviour loads it;
//! - each run record by the Python `json` module and as a `records::RunRecord`.
//!
//! Figures: files torn (should be none), records unreadable (none), messages read, kills that
//! landed inside a write, and whether the loop kept going (the mesh up at the end, its episodes).

use crate::runs::{VehicleRunSetup, spawn};
use anyhow::{Context, Result, bail};
use config::Dof;
use runtime::Namespace;
use runtime::process::Child;
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// The processes cut: every one that writes a file that must stay readable.
pub const VICTIMS: [&str; 4] = ["recorder", "sway-behaviour", "yaw-behaviour", "monitor"];
/// How long any one thing may take before the run gives up on it.
const PATIENCE: Duration = Duration::from_secs(20);

/// What to run.
#[derive(Clone, Debug)]
pub struct CutsSetup {
    pub run: VehicleRunSetup,
    pub cuts: u32,
    /// The time between cuts is drawn uniformly from this range (seconds).
    pub between_s: (f64, f64),
    /// The vehicle's files on a tmpfs of this many MiB (made in a mount namespace of this
    /// process's own); `None`: on the machine's disk.
    pub disk_mb: Option<u64>,
    /// The Python interpreter with the `mcap` package, and the script reading records with it.
    pub python: PathBuf,
    pub reader: PathBuf,
    pub keep_log: Option<PathBuf>,
}

/// The figures of a run.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct CutsReport {
    pub cuts: u32,
    pub cuts_by_process: BTreeMap<String, u32>,
    /// Kills that landed inside a write: a recorder's commit (bytes after the part's end), a
    /// checkpoint's write (its temporary file left), a run record's write (likewise).
    pub cuts_inside_a_write: u32,
    pub checkpoints_read: u32,
    pub checkpoints_torn: u32,
    /// Stores (`FILE` and `FILE.prev`) from which a restarted behaviour could not load.
    pub stores_unloadable: u32,
    pub run_records_read: u32,
    pub run_records_torn: u32,
    pub record_parts_read: u32,
    pub record_parts_unreadable: u32,
    /// Messages the Python reader read from all parts, and those in the chunks before each part's
    /// end (they must be equal).
    pub messages_read: u64,
    pub messages_in_chunks: u64,
    /// Messages in complete chunks past a part's end: written by a commit the kill interrupted,
    /// not yet shown (see docs/flight-records.md for reading them).
    pub messages_past_the_end: u64,
    /// The recorder said the disk is full (times, over all its lives).
    pub disk_full_said: u32,
    /// The mesh was still up when the run stopped it, and the episodes its monitor recorded.
    pub mesh_up_at_end: bool,
    pub episodes_recorded: u32,
    pub problems: Vec<String>,
    pub wall_s: f64,
}

/// SplitMix64: the cuts' own seeded stream.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }

    fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// Puts this process (and so every process it starts) in a mount namespace of its own, with a tmpfs
/// of `mb` MiB on `dir`: the namespace, and the tmpfs with it, goes when the process does.
fn own_tmpfs(dir: &Path, mb: u64) -> Result<()> {
    use std::ffi::CString;
    let cstr = |s: &str| CString::new(s).expect("no NUL");
    // SAFETY: plain system calls with valid NUL-terminated strings; the process is still single
    // threaded here (no other thread shares its file-system view).
    unsafe {
        if libc::unshare(libc::CLONE_NEWNS) != 0 {
            bail!(
                "cannot make a mount namespace (unshare): {} (needs root or CAP_SYS_ADMIN)",
                std::io::Error::last_os_error()
            );
        }
        let root = cstr("/");
        if libc::mount(
            std::ptr::null(),
            root.as_ptr(),
            std::ptr::null(),
            libc::MS_REC | libc::MS_PRIVATE,
            std::ptr::null(),
        ) != 0
        {
            bail!(
                "cannot make the mounts private: {}",
                std::io::Error::last_os_error()
            );
        }
        let target = cstr(&dir.display().to_string());
        let (fs, opts) = (cstr("tmpfs"), cstr(&format!("size={mb}m")));
        if libc::mount(
            fs.as_ptr(),
            target.as_ptr(),
            fs.as_ptr(),
            0,
            opts.as_ptr().cast(),
        ) != 0
        {
            bail!(
                "cannot mount a tmpfs on {}: {}",
                dir.display(),
                std::io::Error::last_os_error()
            );
        }
    }
    Ok(())
}

/// Where a part's records end (the end of the first footer and its magic, read record by record
/// from the start), or `None` when the file is not an MCAP file one can walk.
fn visible_end(bytes: &[u8]) -> Option<usize> {
    if bytes.len() < 8 || bytes[..8] != recorder::seal::MAGIC {
        return None;
    }
    let mut pos = 8usize;
    while pos + 9 <= bytes.len() {
        let op = bytes[pos];
        let len = u64::from_le_bytes(bytes[pos + 1..pos + 9].try_into().ok()?);
        let next = (pos as u64 + 9).checked_add(len)? as usize;
        if op == 0x02 {
            return Some(next + 8).filter(|&e| e <= bytes.len());
        }
        pos = next;
    }
    None
}

/// Messages in the complete chunks of `bytes` (records from its start, or after a magic when
/// `sans_magic`), up to the first record that cannot be read.
fn messages_in_chunks(bytes: &[u8], sans_magic: bool) -> u64 {
    let reader = if sans_magic {
        mcap::read::LinearReader::sans_magic(bytes)
    } else {
        match mcap::read::LinearReader::new(bytes) {
            Ok(r) => r,
            Err(_) => return 0,
        }
    };
    let mut n = 0;
    for record in reader {
        match record {
            Ok(mcap::records::Record::Chunk { header, data }) => {
                let Ok(chunk) = mcap::read::ChunkReader::new(header, &data) else {
                    break;
                };
                n += chunk
                    .filter(|r| matches!(r, Ok(mcap::records::Record::Message { .. })))
                    .count() as u64;
            }
            Ok(mcap::records::Record::Footer(_)) | Err(_) => break,
            Ok(_) => {}
        }
    }
    n
}

/// The files a victim writes, in the mesh's state directory.
fn files_of(victim: &str, state: &Path) -> Vec<PathBuf> {
    match victim {
        "recorder" => recorder::parts(&state.join("flight.mcap")),
        "sway-behaviour" | "yaw-behaviour" => {
            let f = state.join(format!("{}.ckpt", &victim[..victim.find('-').unwrap_or(0)]));
            vec![behaviour::CheckpointFile::prev_of(&f), f]
        }
        _ => vec![state.join("run.json")],
    }
    .into_iter()
    .filter(|p| p.exists())
    .collect()
}

/// Temporary files that process `pid` left in `dir`: replacements it was writing when it died.
fn temporaries_of(dir: &Path, pid: u32) -> usize {
    let mark = format!(".tmp-{pid}");
    std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| durable::is_temporary(n) && n.contains(&mark))
        .count()
}

fn wait_gone(pid: u32, timeout: Duration) -> bool {
    let end = Instant::now() + timeout;
    while Instant::now() < end {
        // Gone once reaped by the supervisor (a zombie still has its /proc entry).
        if !Path::new(&format!("/proc/{pid}")).exists() {
            return true;
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    false
}

/// Runs step one briefly (for the policy the vehicle starts from), then the cuts, then the reads.
pub fn run(setup: &CutsSetup) -> Result<CutsReport> {
    let started = Instant::now();
    let ns = Namespace::new("cut");
    let scratch = ns.scratch();
    let state = scratch.join("vehicle");
    std::fs::create_dir_all(&state)?;
    if let Some(mb) = setup.disk_mb {
        own_tmpfs(&state, mb)?;
        eprintln!("cuts: the vehicle's files on a tmpfs of {mb} MiB");
    }
    let step_one = setup.run.step_one(&ns, "cuts")?;
    let vehicle_mesh = &setup.run.files.vehicle_mesh;
    // The vehicle's mesh with a restart budget for the cuts (the supervisor's own limit would take
    // the mesh down after 5 deaths a minute) and a recorder committing every 100 ms (more commits
    // for the cuts to land in).
    let mesh_text = std::fs::read_to_string(vehicle_mesh)
        .with_context(|| format!("reading {}", vehicle_mesh.display()))?;
    let patched = mesh_text
        .replace("max_restarts = 5 ", "max_restarts = 100000 ")
        .replace(
            r#"args = ["--out", "{record}", "#,
            r#"args = ["--flush-ms", "100", "--out", "{record}", "#,
        );
    if patched == mesh_text || !patched.contains("--flush-ms") || !patched.contains("100000") {
        bail!(
            "{}: its restart limit or recorder line is not where the cuts expect it",
            vehicle_mesh.display()
        );
    }
    let mesh = scratch.join("vehicle-cuts.toml");
    std::fs::write(&mesh, patched)?;
    let record = state.join("flight.mcap");
    let args = runtime::MeshArgs::new(&mesh, &setup.run.files.config, setup.run.seed, &ns.iox)
        .with_sets(&[
            ("trials", "100000".into()),
            // As fast as the mesh answers: a trial every few seconds, so the behaviours and
            // the monitor write often; a frame image every 5 steps keeps the record's size down.
            ("pacing", "--lockstep".into()),
            ("frame_every", "5".into()),
            ("initial", step_one.display().to_string()),
            ("state", state.display().to_string()),
            ("json", state.join("run.json").display().to_string()),
            ("trace", state.join("trace.jsonl").display().to_string()),
            ("record", record.display().to_string()),
            ("save_every", "1".into()),
        ])
        .command_line();
    let log = scratch.join("vehicle.log");
    let mut sup = spawn(
        "supervisor (vehicle)",
        &setup.run.bin_dir.join("supervisor"),
        &args,
        &[],
        log.clone(),
    )?;
    let snapshots = scratch.join("cuts");
    std::fs::create_dir_all(&snapshots)?;
    let mut report = CutsReport {
        cuts: setup.cuts,
        ..Default::default()
    };
    let outcome = cut(setup, &sup, &state, &snapshots, &mut report);
    report.mesh_up_at_end = sup
        .pid()
        .is_some_and(|p| Path::new(&format!("/proc/{p}")).exists())
        && VICTIMS.iter().all(|v| sup.child(v).is_some());
    let stopped = sup.stop(Duration::from_secs(15));
    if let Some(keep) = &setup.keep_log {
        std::fs::copy(&log, keep)
            .with_context(|| format!("keeping the log as {}", keep.display()))?;
        eprintln!("cuts: the vehicle mesh's log is {}", keep.display());
    }
    outcome?;
    if !stopped.success() {
        report
            .problems
            .push(format!("the supervisor stopped with {stopped:?}"));
    }
    let text = std::fs::read_to_string(&log).unwrap_or_default();
    report.disk_full_said = text.matches("the disk is full").count() as u32;
    if text.contains("panicked") {
        report
            .problems
            .push("a process panicked (see the log)".into());
    }
    // The files as the run left them, beside the copies taken at each cut.
    let end = snapshots.join("end");
    std::fs::create_dir_all(&end)?;
    for victim in VICTIMS {
        for f in files_of(victim, &state) {
            std::fs::copy(&f, end.join(f.file_name().unwrap_or_default()))?;
        }
    }
    read_all(setup, &snapshots, &mut report)?;
    report.wall_s = started.elapsed().as_secs_f64();
    Ok(report)
}

/// The cuts: a random process, at a random moment; its files copied as it left them.
fn cut(
    setup: &CutsSetup,
    sup: &Child,
    state: &Path,
    snapshots: &Path,
    report: &mut CutsReport,
) -> Result<()> {
    let mut rng = Rng(setup.run.seed ^ 0xC075);
    // The mesh is up once every victim runs and the recorder has committed its first second.
    let up = Instant::now() + 3 * PATIENCE;
    while !(VICTIMS.iter().all(|v| sup.child(v).is_some()) && record_started(state)) {
        if Instant::now() > up {
            bail!("the vehicle mesh did not come up");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    for k in 0..setup.cuts {
        let wait = rng.uniform(setup.between_s.0, setup.between_s.1);
        std::thread::sleep(Duration::from_secs_f64(wait));
        let victim = VICTIMS[rng.below(VICTIMS.len())];
        let Some(pid) = sup.child(victim) else {
            bail!("cut {k}: {victim} is not running");
        };
        // SAFETY: kill(2) on the supervisor's child just read from /proc; never 0 or a group.
        if unsafe { libc::kill(pid as libc::pid_t, libc::SIGKILL) } != 0 {
            bail!("cut {k}: cannot kill {victim} ({pid})");
        }
        if !wait_gone(pid, PATIENCE) {
            bail!("cut {k}: {victim} ({pid}) did not die");
        }
        *report.cuts_by_process.entry(victim.to_owned()).or_default() += 1;
        let dir = snapshots.join(format!("{k:03}-{victim}"));
        std::fs::create_dir_all(&dir)?;
        let files = files_of(victim, state);
        // The recorder's killed part is its last (a restarted recorder starts the next).
        let files = if victim == "recorder" {
            files.into_iter().last().into_iter().collect()
        } else {
            files
        };
        for f in files {
            std::fs::copy(&f, dir.join(f.file_name().unwrap_or_default()))?;
        }
        // A replacement cut half-way leaves its temporary file (the recorder's interrupted
        // commits are counted when its parts are read).
        if victim != "recorder" && temporaries_of(state, pid) > 0 {
            report.cuts_inside_a_write += 1;
        }
        // The next cut once the victim runs again.
        let end = Instant::now() + PATIENCE;
        while sup.child(victim).is_none_or(|p| p == pid) {
            if Instant::now() > end {
                bail!("cut {k}: {victim} was not restarted");
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        eprintln!("cuts: {} of {}: {victim}", k + 1, setup.cuts);
    }
    Ok(())
}

fn record_started(state: &Path) -> bool {
    std::fs::metadata(state.join("flight.mcap")).is_ok_and(|m| m.len() > 0)
}

/// Every copy read: records by the Python reader, checkpoints by the loader, run records by
/// Python's `json` and as a run record.
fn read_all(setup: &CutsSetup, snapshots: &Path, report: &mut CutsReport) -> Result<()> {
    let mut mcaps = Vec::new();
    let mut jsons = Vec::new();
    let mut dirs: Vec<PathBuf> = std::fs::read_dir(snapshots)?
        .flatten()
        .map(|e| e.path())
        .collect();
    dirs.sort();
    for dir in &dirs {
        let mut stores = Vec::new();
        for f in std::fs::read_dir(dir)?.flatten().map(|e| e.path()) {
            let name = f
                .file_name()
                .unwrap_or_default()
                .to_string_lossy()
                .into_owned();
            if name.ends_with(".mcap") {
                mcaps.push(f);
            } else if name.ends_with(".json") {
                jsons.push(f);
            } else if name.ends_with(".ckpt") || name.ends_with(".ckpt.prev") {
                let dof = if name.starts_with("sway") {
                    Dof::Sway
                } else {
                    Dof::Yaw
                };
                report.checkpoints_read += 1;
                if let Err(e) = learning::Checkpoint::load_dof(&f, dof) {
                    report.checkpoints_torn += 1;
                    report.problems.push(format!("{}: {e}", f.display()));
                }
                if name.ends_with(".ckpt") {
                    stores.push((f, dof));
                }
            }
        }
        for (f, dof) in stores {
            if !matches!(behaviour::CheckpointFile::new(&f).load(dof), Ok(Some(_))) {
                report.stores_unloadable += 1;
                report
                    .problems
                    .push(format!("{}: no checkpoint loads", f.display()));
            }
        }
    }
    // The run records, as a run record.
    for f in &jsons {
        report.run_records_read += 1;
        let parsed = std::fs::read_to_string(f)
            .map_err(anyhow::Error::from)
            .and_then(|t| Ok(serde_json::from_str::<records::RunRecord>(&t)?));
        match parsed {
            Ok(r) => report.episodes_recorded = report.episodes_recorded.max(r.episodes as u32),
            Err(e) => {
                report.run_records_torn += 1;
                report.problems.push(format!("{}: {e:#}", f.display()));
            }
        }
    }
    // Every record part and run record through Python, in one process.
    let out = snapshots.join("python.json");
    let mut child = runtime::process::Spawn::new(&setup.python)
        .arg(&setup.reader)
        .arg(&out)
        .args(mcaps.iter().chain(&jsons))
        .log(snapshots.join("python.log"))
        .die_with_parent()
        .start()
        .context("starting the Python reader")?;
    let status = child
        .wait_timeout(Duration::from_secs(600))
        .context("the Python reader did not finish in 10 minutes")?;
    if !status.success() {
        bail!("the Python reader failed:\n{}", child.log());
    }
    let read: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&out)?)?;
    for f in &jsons {
        if read[f.display().to_string()].get("error").is_some() {
            report.run_records_torn += 1;
            report.problems.push(format!(
                "{}: {}",
                f.display(),
                read[f.display().to_string()]
            ));
        }
    }
    for f in &mcaps {
        report.record_parts_read += 1;
        let bytes = std::fs::read(f)?;
        let end = visible_end(&bytes);
        let in_chunks = messages_in_chunks(&bytes, false);
        report.messages_in_chunks += in_chunks;
        if let Some(end) = end
            && end < bytes.len()
        {
            // A commit the kill interrupted: what of it was written, past the end.
            report.messages_past_the_end += messages_in_chunks(&bytes[end..], true);
            report.cuts_inside_a_write += u32::from(!f.starts_with(snapshots.join("end")));
        }
        let r = &read[f.display().to_string()];
        match r.get("messages").and_then(serde_json::Value::as_u64) {
            Some(n) => {
                report.messages_read += n;
                if n != in_chunks {
                    report.problems.push(format!(
                        "{}: the Python reader read {n} messages of {in_chunks}",
                        f.display()
                    ));
                }
            }
            None => {
                report.record_parts_unreadable += 1;
                report.problems.push(format!("{}: {r}", f.display()));
            }
        }
    }
    Ok(())
}

impl CutsReport {
    /// The figures as a Markdown table.
    pub fn markdown(&self) -> String {
        let by: Vec<String> = self
            .cuts_by_process
            .iter()
            .map(|(k, v)| format!("{k} {v}"))
            .collect();
        format!(
            "| figure | value |\n|---|---|\n\
             | SIGKILLs | {} ({}) |\n\
             | of them inside a write | {} |\n\
             | checkpoints read / torn | {} / {} |\n\
             | checkpoint stores that would not load | {} |\n\
             | run records read / torn | {} / {} |\n\
             | record parts read / unreadable by the Python reader | {} / {} |\n\
             | messages read by the Python reader / in the parts' chunks | {} / {} |\n\
             | messages in complete chunks past a cut part's end | {} |\n\
             | disk full said | {} |\n\
             | mesh up at the end, episodes recorded | {}, {} |\n\
             | problems | {} |\n\
             | wall time | {:.0} s |\n",
            self.cuts,
            by.join(", "),
            self.cuts_inside_a_write,
            self.checkpoints_read,
            self.checkpoints_torn,
            self.stores_unloadable,
            self.run_records_read,
            self.run_records_torn,
            self.record_parts_read,
            self.record_parts_unreadable,
            self.messages_read,
            self.messages_in_chunks,
            self.messages_past_the_end,
            self.disk_full_said,
            self.mesh_up_at_end,
            self.episodes_recorded,
            self.problems.len(),
            self.wall_s
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_end_of_a_record_is_its_first_footer() {
        let mut bytes = recorder::seal::MAGIC.to_vec();
        bytes.extend_from_slice(&recorder::seal::trailer());
        assert_eq!(visible_end(&bytes), Some(bytes.len()));
        let n = bytes.len();
        bytes.extend_from_slice(&[0xAB; 40]);
        assert_eq!(visible_end(&bytes), Some(n));
        assert_eq!(visible_end(b"not mcap"), None);
    }

    #[test]
    fn the_cuts_draw_from_their_seed() {
        let (mut a, mut b) = (Rng(3), Rng(3));
        let xs: Vec<usize> = (0..20).map(|_| a.below(4)).collect();
        assert_eq!(xs, (0..20).map(|_| b.below(4)).collect::<Vec<_>>());
        assert!((0..4).all(|v| xs.contains(&v)), "{xs:?}");
        let u = Rng(1).uniform(0.2, 0.5);
        assert!((0.2..0.5).contains(&u));
    }
}
