//! The twin's pacing, as plain state machines (no IPC, no clock of their own: every call is given
//! `now`), so the `vehicle-twin` binary only binds them to its two ports.
//!
//! - [`RealTime`]: the camera's clock. Every period (`sample_time_s / speed` of wall time: 5 Hz in
//!   real time, `K` times faster with `--speed K`) the twin advances one control period with the
//!   newest setpoints received since the last tick (none: the thrusters hold) and takes a frame.
//!   The first trial starts once a frame source is listening (the vehicle is in the water when its
//!   camera is on).
//! - Lockstep: the data-driven loop of the simulator (`--lockstep`), the shared
//!   `runtime::lockstep::Lockstep` with the twin as its [`Plant`]. The twin publishes frame `t`,
//!   waits for the setpoints answering it (matched by the frame's time, which the vehicle side
//!   copies into its stamp), integrates and publishes `t + 1`: deterministic for a seed, as fast as
//!   the mesh answers. Past the deadline a frame is integrated without an answer: the thrusters hold,
//!   then the twin's own watchdog stops them.
//!
//! In both, a dropped frame is not published: nothing answers it and the twin moves on (in lockstep
//! at once). Both stop after the requested number of trials.

use crate::ardusub::{self, ArduSub};
use crate::twin::{Shot, TrialEnd, Twin};
use runtime::lockstep::{Advanced, Plant};
use std::time::{Duration, Instant};

/// How the twin takes its next frame: with an answer (or none), or driven by an autopilot.
type Step<'a> = dyn FnMut(&mut Twin, Option<&[f64]>) -> (Shot, Option<TrialEnd>) + 'a;

/// Advances once with `answer`, then past dropped frames (integrated without an answer).
fn advance_to_visible(
    twin: &mut Twin,
    answer: Option<&[f64]>,
    ended: &mut Vec<TrialEnd>,
    step: &mut Step,
) -> (Shot, u32) {
    let (mut shot, end) = step(twin, answer);
    ended.extend(end);
    let mut passed = 0;
    while shot.dropped {
        passed += 1;
        let (next, end) = step(twin, None);
        ended.extend(end);
        shot = next;
    }
    (shot, passed)
}

fn answered(twin: &mut Twin, answer: Option<&[f64]>) -> (Shot, Option<TrialEnd>) {
    twin.advance(answer)
}

/// The twin behind its stand-in ArduSub piloted over MAVLink (`--autopilot`): its horizontal
/// thrusters are the autopilot's motors 1..4, driven at every sub-step of the plant by the
/// autopilot's attitude loop from the pilot input it holds (the newest MANUAL_CONTROL, which the
/// shell hands to [`Piloted::autopilot_mut`]).
pub struct Piloted {
    pub twin: Twin,
}

impl Piloted {
    /// Refuses a twin without an autopilot (its config has no `[autopilot]`).
    pub fn new(twin: Twin) -> Result<Piloted, String> {
        if twin.autopilot().is_none() {
            return Err("the twin's config has no [autopilot]".into());
        }
        Ok(Piloted { twin })
    }

    pub fn autopilot(&self) -> &ArduSub {
        self.twin.autopilot().expect("checked by new").core()
    }

    pub fn autopilot_mut(&mut self) -> &mut ArduSub {
        self.twin
            .autopilot_mut()
            .expect("checked by new")
            .core_mut()
    }

    /// The next frame, the period driven by the autopilot.
    pub fn step(twin: &mut Twin) -> (Shot, Option<TrialEnd>) {
        twin.advance_piloted()
    }

    /// Whether a lockstep tag is the current frame's: its time in ms, as the stack's side sends it
    /// (`frame_time_ns / 1_000_000` as u32).
    pub fn tags(shot: &Shot, tag: &ardusub::StepTag) -> bool {
        (shot.time_ns() / 1_000_000) as u32 == tag.frame_time_ms
    }
}

/// The twin behind the autopilot as a plant of the lockstep protocol: a frame is answered by the
/// step tag that follows its MANUAL_CONTROL (the autopilot holds that input; the answer itself
/// carries nothing).
impl Plant for Piloted {
    type Step = Shot;
    type End = TrialEnd;

    fn answers(shot: &Shot, time_ns: u64) -> bool {
        shot.time_ns() == time_ns
    }

    fn is_terminal(shot: &Shot) -> bool {
        shot.status.is_terminal()
    }

    fn start(&mut self) -> Advanced<Self> {
        let shot = self.twin.start();
        let mut ended = Vec::new();
        if !shot.dropped {
            return Advanced {
                step: shot,
                passed: 0,
                ended,
            };
        }
        let (step, passed) = advance_to_visible(&mut self.twin, None, &mut ended, &mut |t, _| {
            Piloted::step(t)
        });
        Advanced {
            step,
            passed,
            ended,
        }
    }

    fn advance(&mut self, answer: Option<&[f64]>) -> Advanced<Self> {
        let mut ended = Vec::new();
        let (step, passed) = advance_to_visible(&mut self.twin, answer, &mut ended, &mut |t, _| {
            Piloted::step(t)
        });
        Advanced {
            step,
            passed,
            ended,
        }
    }

    fn finish(&mut self) -> Vec<TrialEnd> {
        Piloted::step(&mut self.twin).1.into_iter().collect()
    }
}

/// What the clock-paced shell does next.
#[derive(Clone, Debug, PartialEq)]
pub enum Tick {
    /// Nothing to do.
    Idle,
    /// Publish this new frame; `ended` are the trials that closed on the way, `answered` whether
    /// setpoints arrived for the period that led to it (`None` for the first frame).
    Publish {
        shot: Shot,
        ended: Vec<TrialEnd>,
        answered: Option<bool>,
    },
    /// The requested trials are done.
    Finished { ended: Vec<TrialEnd> },
}

/// Counts trials against the requested number (0: forever).
#[derive(Clone, Copy, Debug)]
struct Budget {
    trials: u32,
    done: u32,
}

impl Budget {
    /// Whether the answer to `shot` would end the last requested trial.
    fn last(&self, shot: &Shot) -> bool {
        shot.status.is_terminal() && self.trials > 0 && self.done + 1 >= self.trials
    }
}

/// The twin as a plant of the lockstep protocol: it publishes frames, and matches setpoints by the
/// time of the frame they answer.
impl Plant for Twin {
    type Step = Shot;
    type End = TrialEnd;

    fn answers(shot: &Shot, time_ns: u64) -> bool {
        shot.time_ns() == time_ns
    }

    fn is_terminal(shot: &Shot) -> bool {
        shot.status.is_terminal()
    }

    fn start(&mut self) -> Advanced<Self> {
        let shot = Twin::start(self);
        let mut ended = Vec::new();
        if !shot.dropped {
            return Advanced {
                step: shot,
                passed: 0,
                ended,
            };
        }
        let (step, passed) = advance_to_visible(self, None, &mut ended, &mut answered);
        Advanced {
            step,
            passed,
            ended,
        }
    }

    fn advance(&mut self, answer: Option<&[f64]>) -> Advanced<Self> {
        let mut ended = Vec::new();
        let (step, passed) = advance_to_visible(self, answer, &mut ended, &mut answered);
        Advanced {
            step,
            passed,
            ended,
        }
    }

    fn finish(&mut self) -> Vec<TrialEnd> {
        // The answer to the last trial's last frame: done, no next trial.
        Twin::advance(self, None).1.into_iter().collect()
    }
}

/// The twin paced by the clock.
pub struct RealTime {
    twin: Twin,
    period: Duration,
    budget: Budget,
    next_tick: Option<Instant>,
    newest: Option<Vec<f64>>,
    /// Trials that ended on the way to a frame that was dropped: reported with the next one.
    ended: Vec<TrialEnd>,
    finished: bool,
}

impl RealTime {
    /// A twin ticking every `period` of wall time once started.
    pub fn new(twin: Twin, period: Duration, trials: u32) -> Self {
        RealTime {
            twin,
            period,
            budget: Budget { trials, done: 0 },
            next_tick: None,
            newest: None,
            ended: Vec::new(),
            finished: false,
        }
    }

    pub fn twin(&self) -> &Twin {
        &self.twin
    }

    pub fn twin_mut(&mut self) -> &mut Twin {
        &mut self.twin
    }

    pub fn is_finished(&self) -> bool {
        self.finished
    }

    /// Setpoints arrived: the newest are applied from the next tick on.
    pub fn on_setpoints(&mut self, setpoints: &[f64]) {
        if self.next_tick.is_some() {
            self.newest = Some(setpoints.to_vec());
        }
    }

    /// When the shell must call [`RealTime::on_time`] next (`None` before the start).
    pub fn next_tick(&self) -> Option<Instant> {
        self.next_tick
    }

    /// The clock: starts the first trial when `listening` (a frame source is connected); then, at
    /// each due tick, advances one period.
    pub fn on_time(&mut self, now: Instant, listening: bool) -> Tick {
        self.on_time_with(now, listening, &mut answered)
    }

    /// [`RealTime::on_time`] with the period integrated by `step` (the autopilot's: see
    /// [`Piloted::step`]; it is given the newest setpoints, if any).
    pub fn on_time_with(&mut self, now: Instant, listening: bool, step: &mut Step) -> Tick {
        if self.finished {
            return Tick::Idle;
        }
        let Some(due) = self.next_tick else {
            if !listening {
                return Tick::Idle;
            }
            self.next_tick = Some(now + self.period);
            let shot = self.twin.start();
            if shot.dropped {
                return Tick::Idle;
            }
            return Tick::Publish {
                shot,
                ended: Vec::new(),
                answered: None,
            };
        };
        if now < due {
            return Tick::Idle;
        }
        // The next tick keeps the cadence; after a stall (a suspended process) it restarts from now.
        let next = due + self.period;
        self.next_tick = Some(if next > now { next } else { now + self.period });
        let current = *self.twin.current().expect("started");
        let answer = self.newest.take();
        let answered = answer.is_some();
        if self.budget.last(&current) {
            let (_, end) = step(&mut self.twin, None);
            self.finished = true;
            let mut ended = std::mem::take(&mut self.ended);
            ended.extend(end);
            return Tick::Finished { ended };
        }
        let (shot, end) = step(&mut self.twin, answer.as_deref());
        self.budget.done += end.is_some() as u32;
        self.ended.extend(end);
        if shot.dropped {
            // Not published; its tick passes.
            return Tick::Idle;
        }
        Tick::Publish {
            shot,
            ended: std::mem::take(&mut self.ended),
            answered: Some(answered),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use config::{Scenario, StepStatus, TwinParams};
    use runtime::lockstep::{Cause, Limits, Lockstep, Phase, Reaction};

    const MS: Duration = Duration::from_millis(1);

    fn twin(duration_s: f64, drops: f64, seed: u64) -> Twin {
        let mut t = TwinParams::default();
        t.trials.duration_s = duration_s;
        t.frames.dropped.probability = drops;
        Twin::new(&Scenario::default(), &t, seed, false).unwrap()
    }

    fn published<P: Plant<Step = Shot>>(r: Reaction<P>) -> Shot {
        match r {
            Reaction::Publish { next, .. } => next,
            other => panic!("expected a frame, got {other:?}"),
        }
    }

    fn ticked(r: Tick) -> Shot {
        match r {
            Tick::Publish { shot, .. } => shot,
            other => panic!("expected a frame, got {other:?}"),
        }
    }

    /// Lockstep follows the core exactly: the same frames as a twin advanced by hand, dropped
    /// frames passed at once.
    #[test]
    fn lockstep_follows_the_twin_and_passes_dropped_frames() {
        let t0 = Instant::now();
        let (mut ls, first) =
            Lockstep::start(twin(2.0, 0.2, 7), Limits::new(100 * MS, 2000 * MS), 0, t0);
        let mut reference = twin(2.0, 0.2, 7);
        let mut want = reference.start();
        while want.dropped {
            want = reference.advance(None).0;
        }
        assert_eq!(published(first), want);
        let mut passed_total = 0;
        for k in 0..200 {
            let sp = [0.5, 0.4, 0.1 * (k % 5) as f64];
            let r = ls.on_answer(ls.current().time_ns(), &sp, t0);
            let Reaction::Publish {
                next: shot, passed, ..
            } = r
            else {
                panic!("{r:?}")
            };
            let mut w = reference.advance(Some(&sp)).0;
            for _ in 0..passed {
                assert!(w.dropped);
                w = reference.advance(None).0;
            }
            assert!(!w.dropped);
            assert_eq!(shot, w);
            passed_total += passed;
        }
        assert!(passed_total > 10, "the twin dropped frames: {passed_total}");
        // Setpoints for another frame are ignored.
        assert!(matches!(ls.on_answer(1, &[1.0; 3], t0), Reaction::Idle));
    }

    #[test]
    fn lockstep_resends_then_holds_at_the_deadline_and_stops_after_its_trials() {
        let t0 = Instant::now();
        let limits = Limits::new(100 * MS, 1000 * MS);
        let (mut ls, first) = Lockstep::start(twin(0.6, 0.0, 1), limits, 2, t0);
        let first = published(first);
        // Connecting: re-sends forever, never advances.
        for k in 1..50u32 {
            match ls.on_time(t0 + k * 100 * MS) {
                Reaction::Resend { step, .. } => assert_eq!(step, first),
                other => panic!("{other:?}"),
            }
        }
        assert_eq!(ls.phase(), Phase::Connecting);
        let t1 = t0 + 10_000 * MS;
        let second = published(ls.on_answer(first.time_ns(), &[0.0; 3], t1));
        assert_eq!(second.step, 1);
        assert!(matches!(ls.on_time(t1 + 100 * MS), Reaction::Resend { .. }));
        match ls.on_time(t1 + 1000 * MS) {
            Reaction::Publish { next, cause, .. } => {
                assert_eq!(cause, Cause::Deadline);
                assert_eq!(next.step, 2);
            }
            other => panic!("{other:?}"),
        }
        // Answer everything: two trials of 3 steps, then finished.
        let mut ends = Vec::new();
        loop {
            match ls.on_answer(ls.current().time_ns(), &[0.0; 3], t1) {
                Reaction::Publish { ended, .. } => ends.extend(ended),
                Reaction::Finished { ended, .. } => {
                    ends.extend(ended);
                    break;
                }
                other => panic!("{other:?}"),
            }
        }
        assert_eq!(
            ends.iter().map(|e| (e.trial, e.status)).collect::<Vec<_>>(),
            vec![(0, StepStatus::TimeLimit), (1, StepStatus::TimeLimit)]
        );
        assert_eq!(ls.phase(), Phase::Finished);
        assert!(matches!(ls.on_time(t1 + 60_000 * MS), Reaction::Idle));
    }

    /// Real time: nothing until a frame source listens, then one frame per period, each period
    /// integrated with the newest setpoints; a dropped frame's tick publishes nothing.
    #[test]
    fn real_time_ticks_at_its_period_with_the_newest_setpoints() {
        let period = 200 * MS;
        let mut rt = RealTime::new(twin(90.0, 0.0, 3), period, 0);
        let t0 = Instant::now();
        assert_eq!(rt.on_time(t0, false), Tick::Idle);
        rt.on_setpoints(&[1.0; 3]); // before the start: ignored
        let first = ticked(rt.on_time(t0, true));
        assert_eq!(first.seq, 1);
        assert_eq!(rt.next_tick(), Some(t0 + period));
        assert_eq!(rt.on_time(t0 + 199 * MS, true), Tick::Idle);
        rt.on_setpoints(&[0.0, 0.0, 0.2]);
        rt.on_setpoints(&[0.0, 0.0, 0.6]);
        let mut reference = twin(90.0, 0.0, 3);
        reference.start();
        let second = ticked(rt.on_time(t0 + 201 * MS, true));
        assert_eq!(second, reference.advance(Some(&[0.0, 0.0, 0.6])).0);
        assert_eq!(rt.next_tick(), Some(t0 + 2 * period), "the cadence is kept");
        match rt.on_time(t0 + 400 * MS, true) {
            Tick::Publish { shot, answered, .. } => {
                assert_eq!(answered, Some(false));
                assert_eq!(shot, reference.advance(None).0);
            }
            other => panic!("{other:?}"),
        }
    }

    fn bluerov2() -> Scenario {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../../config/bluerov2/scenario.toml");
        config::load(&path).unwrap()
    }

    /// Lockstep behind the autopilot: a frame is answered by the tag carrying its time in ms; the
    /// period is driven by the autopilot's motors (forward stick: the vehicle moves forward; the
    /// same twin disarmed stays still); a scenario without the vectored layout is refused, and a
    /// twin without an autopilot is not piloted.
    #[test]
    fn lockstep_behind_the_autopilot_steps_on_the_frames_tag() {
        use crate::ardusub::StepTag;
        use crate::twin::TwinError;
        let t0 = Instant::now();
        let mut params = TwinParams::ideal();
        params.trials.duration_s = 20.0;
        params.autopilot = Some(config::AutopilotParams::default());
        let run = |arm: bool| {
            let mut twin = Twin::new(&bluerov2(), &params, 5, false).unwrap();
            if arm {
                let core = twin.autopilot_mut().unwrap().core_mut();
                core.arm_for_test(t0, 1000);
            }
            let piloted = Piloted::new(twin).unwrap();
            let (mut ls, first) = Lockstep::start(piloted, Limits::new(100 * MS, 2000 * MS), 0, t0);
            let mut shot = published(first);
            for _ in 0..10 {
                let tag = StepTag {
                    frame_time_ms: (shot.time_ns() / 1_000_000) as u32,
                    step: shot.step as i32,
                };
                assert!(Piloted::tags(&shot, &tag));
                let other = StepTag {
                    frame_time_ms: tag.frame_time_ms + 200,
                    ..tag
                };
                assert!(!Piloted::tags(&shot, &other), "another frame's tag");
                shot = published(ls.on_answer(shot.time_ns(), &[], t0));
            }
            shot.state.velocity.u
        };
        let (moving, still) = (run(true), run(false));
        assert!(moving > 0.1, "forward at {moving} m/s");
        assert_eq!(still, 0.0);
        let default = Scenario {
            pilot: bluerov2().pilot,
            ..Scenario::default()
        };
        assert!(matches!(
            Twin::new(&default, &params, 5, false),
            Err(TwinError::Autopilot(e)) if e.contains("vectored")
        ));
        let plain = Twin::new(&Scenario::default(), &TwinParams::ideal(), 5, false).unwrap();
        assert!(Piloted::new(plain).is_err());
    }

    #[test]
    fn real_time_stops_after_its_trials() {
        let mut rt = RealTime::new(twin(0.4, 0.0, 3), 10 * MS, 1);
        let t0 = Instant::now();
        ticked(rt.on_time(t0, true));
        let mut k = 1;
        loop {
            match rt.on_time(t0 + k * 10 * MS, true) {
                Tick::Publish { .. } => {}
                Tick::Finished { ended } => {
                    assert_eq!(ended.len(), 1);
                    assert_eq!(ended[0].steps, 2);
                    break;
                }
                other => panic!("{other:?}"),
            }
            k += 1;
        }
        assert!(rt.is_finished());
        assert_eq!(rt.on_time(t0 + 10_000 * MS, true), Tick::Idle);
    }
}
