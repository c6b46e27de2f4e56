//! Cuts, short: `mesh-bench cuts` with 12 SIGKILLs at random moments (seeded) of the flight
//! recorder, the behaviours and the monitor, while the vehicle mesh runs on a tmpfs of 8 MiB of its
//! own that the record fills. Every file the cuts left must be readable: each record part by the
//! MCAP project's Python reader, all its chunks; each checkpoint by the project's loader; each run
//! record by Python's `json`. The loop must keep going (the mesh up at the end, episodes recorded),
//! and the disk-full error said. `scripts/bench-cuts` runs 100 cuts (docs/flight-records.md).

use runtime::process::Spawn;
use serde_json::Value;
use std::path::Path;
use std::time::Duration;
use testkit::Namespace;

/// Step one briefly, the vehicle mesh up, 12 cuts at most 1.5 s apart, the reads: well within this
/// on a loaded 2-core machine.
const TIMEOUT: Duration = Duration::from_secs(240);

#[test]
fn twelve_cuts_on_a_filling_disk_leave_every_file_readable_and_the_loop_going() {
    let ns = Namespace::new("cuts");
    let json = ns.scratch().join("cuts.json");
    let repo = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let python = std::env::var_os("MCAP_VENV")
        .map_or_else(|| repo.join("target/mcap-venv"), std::path::PathBuf::from);
    let python = python.join("bin/python");
    assert!(
        python.exists(),
        "{} is missing: run scripts/install-mcap-py (CI does)",
        python.display()
    );
    let mut bench = Spawn::new(testkit::binary("mesh-bench"))
        .arg("cuts")
        .args([
            "--cuts",
            "12",
            "--seed",
            "7",
            "--sim-episodes",
            "3",
            "--disk-mb",
            "8",
        ])
        .arg("--config")
        .arg(testkit::config_dir())
        .arg("--sim-mesh")
        .arg(repo.join("config/sim-mesh.toml"))
        .arg("--vehicle-mesh")
        .arg(repo.join("config/vehicle.toml"))
        .arg("--python")
        .arg(&python)
        .arg("--reader")
        .arg(repo.join("services/mesh/recorder/tests/read_cut_records.py"))
        .arg("--json")
        .arg(&json)
        .env("RUST_LOG", "warn")
        .log(ns.scratch().join("cuts.log"))
        .die_with_parent()
        .start()
        .expect("starting mesh-bench cuts");
    let status = bench.wait_timeout(TIMEOUT).unwrap_or_else(|| {
        panic!(
            "mesh-bench cuts did not finish within {TIMEOUT:?}\n{}",
            bench.tail(30)
        )
    });
    assert!(status.success(), "{status:?}\n{}", bench.tail(30));
    let text = std::fs::read_to_string(&json).expect("the bench's --json file");
    let raw: Value = serde_json::from_str(&text).unwrap();
    let n = |k: &str| raw[k].as_u64().unwrap_or_else(|| panic!("{k} in {raw}"));
    assert_eq!(n("cuts"), 12);
    let killed: u64 = raw["cuts_by_process"]
        .as_object()
        .unwrap()
        .values()
        .map(|v| v.as_u64().unwrap())
        .sum();
    assert_eq!(killed, 12, "{raw}");
    assert_eq!(raw["problems"], Value::Array(vec![]), "{raw}");
    assert_eq!(n("checkpoints_torn"), 0, "{raw}");
    assert_eq!(n("stores_unloadable"), 0, "{raw}");
    assert_eq!(n("run_records_torn"), 0, "{raw}");
    assert_eq!(n("record_parts_unreadable"), 0, "{raw}");
    // Every file was read: something of each kind, and every message of every part's chunks.
    assert!(
        n("checkpoints_read") > 0 && n("run_records_read") > 0,
        "{raw}"
    );
    assert!(n("record_parts_read") > 0, "{raw}");
    assert!(n("messages_read") > 0, "{raw}");
    assert_eq!(n("messages_read"), n("messages_in_chunks"), "{raw}");
    // The disk filled, the loop kept going.
    assert!(n("disk_full_said") > 0, "{raw}");
    assert_eq!(raw["mesh_up_at_end"], Value::Bool(true), "{raw}");
    assert!(n("episodes_recorded") > 0, "{raw}");
}
