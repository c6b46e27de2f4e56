//! Camera-to-thruster latency as the hardware sees it: from the moment the twin publishes a frame to
//! the moment the setpoints answering it reach the twin's thrusters. Everything the vehicle does in
//! between is inside: the camera's frame source, perception, the behaviours and the surge rule, the
//! allocator, the thruster driver and its thruster sink, and every cross-process wake-up. Plain
//! times in, samples out; `vehicle-twin --latency FILE` writes them (`records::latency`),
//! `mesh-bench vehicle` summarises them.

use crate::Shot;
use records::latency::Sample;
use std::time::{Duration, Instant};

/// Pairs each published frame with the first setpoints answering it.
#[derive(Debug, Default)]
pub struct LatencyMeter {
    pending: Option<(u64, Sample, Instant)>,
}

impl LatencyMeter {
    pub fn new() -> Self {
        Self::default()
    }

    /// The frame `shot` was published at `now` (a re-send of the same frame is not a new frame: do
    /// not call this for it). An unanswered earlier frame is forgotten.
    pub fn published(&mut self, shot: &Shot, now: Instant) {
        let sample = Sample {
            seq: shot.seq,
            trial: shot.trial,
            step: shot.step,
            latency: Duration::ZERO,
        };
        self.pending = Some((shot.time_ns(), sample, now));
    }

    /// Setpoints stamped with the frame time `time_ns` arrived at `now`: the latency of the pending
    /// frame if they answer it, first answer only.
    pub fn answered(&mut self, time_ns: u64, now: Instant) -> Option<Sample> {
        match self.pending {
            Some((t, mut sample, at)) if t == time_ns => {
                self.pending = None;
                sample.latency = now.saturating_duration_since(at);
                Some(sample)
            }
            _ => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Twin;

    fn shots() -> (Shot, Shot) {
        let scenario: config::Scenario = config::load(
            &std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../config/scenario.toml"),
        )
        .unwrap();
        let mut twin = Twin::new(&scenario, &config::TwinParams::ideal(), 3, false).unwrap();
        let first = twin.start();
        let (second, _) = twin.advance(Some(&[0.0; 3]));
        (first, second)
    }

    #[test]
    fn the_first_answer_to_the_pending_frame_is_timed() {
        let (a, b) = shots();
        let t0 = Instant::now();
        let mut m = LatencyMeter::new();
        m.published(&a, t0);
        assert_eq!(m.answered(b.time_ns(), t0 + Duration::from_micros(5)), None);
        let s = m
            .answered(a.time_ns(), t0 + Duration::from_micros(700))
            .expect("answered");
        assert_eq!((s.seq, s.step), (a.seq, a.step));
        assert_eq!(s.latency, Duration::from_micros(700));
        // A second answer to the same frame is not a new sample.
        assert_eq!(m.answered(a.time_ns(), t0 + Duration::from_millis(1)), None);
        // An answer to a frame superseded by a newer one is not counted.
        m.published(&a, t0);
        m.published(&b, t0 + Duration::from_millis(200));
        assert_eq!(
            m.answered(a.time_ns(), t0 + Duration::from_millis(201)),
            None
        );
        assert!(
            m.answered(b.time_ns(), t0 + Duration::from_millis(201))
                .is_some()
        );
    }
}
