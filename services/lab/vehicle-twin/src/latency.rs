//! Camera-to-thruster latency as the hardware sees it: from the moment the twin publishes a frame to
//! the moment the setpoints answering it reach the twin's thrusters. Everything the vehicle does in
//! between is inside: the camera's frame source, perception, the behaviours and the surge rule, the
//! allocator, the thruster driver and its thruster sink, and every cross-process wake-up. Plain
//! times in, samples out; `vehicle-twin --latency FILE` writes them (`records::latency`),
//! `mesh-bench vehicle` summarises them.
//!
//! Behind the ArduSub stand-in (`--autopilot`) the far end is the wire: the moment the autopilot
//! reads the first MANUAL_CONTROL carrying the frame's command off its socket. The driver sends
//! MANUAL_CONTROL at a steady 20 Hz, holding the last step's command between steps; the one that
//! carries a new step's command goes out at once, followed by the step tag (`ct_step`, the frame's
//! time in ms). So a frame's command is the MANUAL_CONTROL the autopilot took just before the tag
//! naming the frame ([`LatencyMeter::stick`], [`LatencyMeter::tagged`]); held repeats are not
//! answers.

use crate::Shot;
use records::latency::Sample;
use std::time::{Duration, Instant};

/// Pairs each published frame with the first setpoints answering it.
#[derive(Debug, Default)]
pub struct LatencyMeter {
    pending: Option<(u64, Sample, Instant)>,
    /// When the autopilot took the last MANUAL_CONTROL, until a step tag says whose it was.
    stick: Option<Instant>,
}

impl LatencyMeter {
    pub fn new() -> Self {
        Self::default()
    }

    /// The frame `shot` was published at `now`, `now_ns` on the monotonic clock (a re-send of the
    /// same frame is not a new frame: do not call this for it). An unanswered earlier frame is
    /// forgotten.
    pub fn published(&mut self, shot: &Shot, now: Instant, now_ns: u64) {
        let sample = Sample {
            seq: shot.seq,
            trial: shot.trial,
            step: shot.step,
            time_ns: shot.time_ns(),
            sent_ns: now_ns,
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

    /// The autopilot took a MANUAL_CONTROL read off its socket at `at`.
    pub fn stick(&mut self, at: Instant) {
        self.stick = Some(at);
    }

    /// A step tag naming the frame taken at `frame_time_ms` (ms, truncated to u32 as the tag
    /// carries it) came: the latency of the pending frame to the MANUAL_CONTROL just before the tag,
    /// if the tag names the pending frame; first answer only.
    pub fn tagged(&mut self, frame_time_ms: u32) -> Option<Sample> {
        let stick = self.stick.take()?;
        match self.pending {
            Some((t, mut sample, at)) if (t / 1_000_000) as u32 == frame_time_ms => {
                self.pending = None;
                sample.latency = stick.saturating_duration_since(at);
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
        m.published(&a, t0, 1_000);
        assert_eq!(m.answered(b.time_ns(), t0 + Duration::from_micros(5)), None);
        let s = m
            .answered(a.time_ns(), t0 + Duration::from_micros(700))
            .expect("answered");
        assert_eq!((s.seq, s.step), (a.seq, a.step));
        assert_eq!((s.time_ns, s.sent_ns), (a.time_ns(), 1_000));
        assert_eq!(s.latency, Duration::from_micros(700));
        // A second answer to the same frame is not a new sample.
        assert_eq!(m.answered(a.time_ns(), t0 + Duration::from_millis(1)), None);
        // An answer to a frame superseded by a newer one is not counted.
        m.published(&a, t0, 0);
        m.published(&b, t0 + Duration::from_millis(200), 0);
        assert_eq!(
            m.answered(a.time_ns(), t0 + Duration::from_millis(201)),
            None
        );
        assert!(
            m.answered(b.time_ns(), t0 + Duration::from_millis(201))
                .is_some()
        );
    }

    #[test]
    fn over_mavlink_the_manual_control_before_the_frames_tag_is_timed() {
        let (a, b) = shots();
        let ms = |shot: &Shot| (shot.time_ns() / 1_000_000) as u32;
        assert_ne!(ms(&a), ms(&b));
        let t0 = Instant::now();
        let at = |us: u64| t0 + Duration::from_micros(us);
        let mut m = LatencyMeter::new();
        // A held stick before the frame, then the frame.
        m.stick(at(0));
        m.published(&a, at(100), 0);
        // Held repeats of the last step's stick: no tag follows them.
        m.stick(at(20_000));
        m.stick(at(70_000));
        // The new command at 71.2 ms, its tag read a little later: timed to the command.
        m.stick(at(71_200));
        let s = m.tagged(ms(&a)).expect("the frame's command");
        assert_eq!((s.seq, s.step), (a.seq, a.step));
        assert_eq!(s.latency, Duration::from_micros(71_100));
        // Its stick held afterwards, and a repeat of the tag: not new samples.
        m.stick(at(120_000));
        assert_eq!(m.tagged(ms(&a)), None);
        // A tag naming another frame than the pending one, or with no stick before it: none.
        m.published(&b, at(200_000), 0);
        m.stick(at(201_000));
        assert_eq!(m.tagged(ms(&a)), None);
        assert_eq!(
            m.tagged(ms(&b)),
            None,
            "its stick was taken by the other tag"
        );
        m.stick(at(202_500));
        let s = m.tagged(ms(&b)).expect("the frame's command");
        assert_eq!(s.latency, Duration::from_micros(2_500));
    }
}
