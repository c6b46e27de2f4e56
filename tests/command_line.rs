//! Command-line manners: a tool whose reader goes away (`vision detect DIR | head -1`) stops quietly,
//! as `head` asked: exit status 0, no panic, no error on standard error. Each tool here writes into
//! a pipe whose reading end is closed (or closed after the first line), with its standard error kept
//! in a log, and is waited for on its pidfd with a timeout.

use runtime::process::{Child, Spawn};
use std::io::{BufRead, BufReader, PipeWriter};
use std::path::Path;
use std::process::ExitStatus;
use std::time::Duration;
use testkit::Namespace;

/// Long enough for a tool to start and write its first line on a loaded 2-core machine; the tools
/// here stop at their first write.
const TIMEOUT: Duration = Duration::from_secs(60);

/// Starts `tool` with `args` in `ns`, standard output into `out`, standard error into a log.
fn start(ns: &Namespace, tool: &str, args: &[&str], out: PipeWriter) -> Child {
    Spawn::new(testkit::binary(tool))
        .args(args)
        .env("CABLETRACK_CONFIG", testkit::config_dir())
        .envs(ns.env())
        .log(ns.scratch().join(format!("{tool}.log")))
        .stdout(out)
        .die_with_parent()
        .start()
        .unwrap_or_else(|e| panic!("cannot start {tool}: {e}"))
}

/// Waits for `tool` to exit after its reader went away; returns its exit status and standard error.
fn stopped(tool: &str, mut child: Child) -> (ExitStatus, String) {
    let status = child.wait_timeout(TIMEOUT).unwrap_or_else(|| {
        panic!(
            "{tool} did not stop within {TIMEOUT:?} of its reader going away\n{}",
            child.tail(20)
        )
    });
    (status, child.log())
}

/// A pipe whose reading end is already closed: the first write fails with a broken pipe.
fn closed_pipe() -> PipeWriter {
    let (reader, writer) = std::io::pipe().expect("a pipe");
    drop(reader);
    writer
}

/// Exit status 0 and nothing on standard error that says panic or error.
fn assert_quiet(tool: &str, status: ExitStatus, stderr: &str) {
    assert!(status.success(), "{tool}: {status:?}\n{stderr}");
    for word in ["panicked", "Broken pipe", "error", "ERROR", "backtrace"] {
        assert!(!stderr.contains(word), "{tool} said `{word}`:\n{stderr}");
    }
}

/// Writes a few rendered frames into `dir` with `vision dataset` (standard output to the log).
fn frames(ns: &Namespace, dir: &Path) {
    let mut child = Spawn::new(testkit::binary("vision"))
        .args(["dataset", "--n", "3", "--clean", "--out"])
        .arg(dir)
        .log(ns.scratch().join("dataset.log"))
        .die_with_parent()
        .start()
        .expect("starting vision dataset");
    let status = child
        .wait_timeout(TIMEOUT)
        .unwrap_or_else(|| panic!("vision dataset did not finish in {TIMEOUT:?}"));
    assert!(
        status.success(),
        "vision dataset: {status:?}\n{}",
        child.log()
    );
}

#[test]
fn vision_detect_stops_quietly_when_its_reader_closes_after_one_line() {
    let ns = Namespace::new("clv");
    let dir = ns.scratch().join("frames");
    frames(&ns, &dir);
    let (reader, writer) = std::io::pipe().expect("a pipe");
    let child = start(&ns, "vision", &["detect", dir.to_str().unwrap()], writer);
    // `head -1`: read one line, then go away.
    let mut line = String::new();
    BufReader::new(reader)
        .read_line(&mut line)
        .expect("reading the first line");
    assert!(line.contains("\"found\""), "first line: {line}");
    let (status, stderr) = stopped("vision", child);
    assert_quiet("vision detect", status, &stderr);
}

#[test]
fn vision_detect_stops_quietly_into_a_closed_pipe() {
    let ns = Namespace::new("clc");
    let dir = ns.scratch().join("frames");
    frames(&ns, &dir);
    let child = start(
        &ns,
        "vision",
        &["detect", dir.to_str().unwrap()],
        closed_pipe(),
    );
    let (status, stderr) = stopped("vision", child);
    assert_quiet("vision detect", status, &stderr);
    assert!(stderr.is_empty(), "vision detect said: {stderr}");
}

#[test]
fn the_trainer_stops_quietly_into_a_closed_pipe() {
    let ns = Namespace::new("clt");
    let checkpoint = ns.scratch().join("step-one.ckpt");
    let config = testkit::config_dir();
    let args = [
        "--config",
        config.to_str().unwrap(),
        "train",
        "--episodes",
        "1",
        "--checkpoint",
        checkpoint.to_str().unwrap(),
    ];
    let child = start(&ns, "trainer", &args, closed_pipe());
    let (status, stderr) = stopped("trainer", child);
    assert_quiet("trainer train", status, &stderr);
}

#[test]
fn the_monitor_stops_quietly_into_a_closed_pipe() {
    let ns = Namespace::new("clm");
    let child = start(&ns, "monitor", &["--episodes", "1"], closed_pipe());
    let (status, stderr) = stopped("monitor", child);
    assert_quiet("monitor", status, &stderr);
    assert!(
        ns.leftovers().is_empty(),
        "shared memory left behind: {:?}",
        ns.leftovers()
    );
}
