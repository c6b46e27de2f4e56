//! The files a run leaves for the lab, in one place for whoever writes and reads them: the run
//! record and the observation trace the monitor writes ([`run`]), the latency file the vehicle twin
//! writes ([`latency`]). They are files, not messages: the IPC contract (`messages`) stays free of
//! them, and the trainer, the benchmarks and the tests read them without depending on the
//! processes that write them.

pub mod latency;
pub mod run;

pub use run::{EvaluationRecord, RunRecord, SafetyCounts, TracePoint};
