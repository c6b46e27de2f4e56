//! The conformance suites: every [`FrameSource`] and every [`ThrusterSink`] passes the same tests
//! (STYLE.md, after iceoryx2's conformance tests). An implementation provides a *rig* that can open
//! it over given input and, for sinks, see what reached the far side; the suite does the rest.
//!
//! ```text
//! #[test]
//! fn the_replay_conforms() {
//!     adapters::conformance::frame_source(&mut ReplayRig::new());
//! }
//! ```
//!
//! The suites panic with the implementation's name and what failed, like any test assertion.

use crate::failsafe::Failsafe;
use crate::{
    AdapterError, CableObservationData, Frame, FrameMeta, FrameSource, Read, Stamp, StepStatus,
    StopCause, ThrusterSink, Wake,
};
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::time::{Duration, Instant};

/// What a frame-source implementation provides to run [`frame_source`].
pub trait SourceRig {
    type Source: FrameSource;
    /// The implementation's name, for failure messages.
    fn name(&self) -> String;
    /// A live source (a device) never ends; a recorded one ends after its last frame.
    fn live(&self) -> bool;
    /// The pacing of recorded sources opened by [`SourceRig::open`] (frames due at
    /// `(time_k - time_0) / speed` after the first read), `None` when unpaced or live.
    fn speed(&self) -> Option<f64>;
    /// A source of `frames`, in this order: a recorded source holds them from the start; a live one
    /// receives frame `k` when [`SourceRig::deliver`] is called with `k`. An implementation may
    /// refuse input it finds out of order here, with an error.
    fn open(&mut self, frames: &[Frame]) -> Result<Self::Source, AdapterError>;
    /// A live source: sends it frame `k` of the last [`SourceRig::open`] now. Recorded: nothing.
    fn deliver(&mut self, k: usize);
    /// The kinds of malformed input this implementation can meet, by name.
    fn bad_inputs(&self) -> Vec<String>;
    /// A source over bad input `k` of [`SourceRig::bad_inputs`] (the previous one has been dropped).
    /// It must be refused when opened, or yield a typed error when read and then, after it, the one
    /// good frame the rig puts behind the bad input.
    fn open_bad(&mut self, k: usize) -> Result<Self::Source, AdapterError>;
}

/// What a thruster-sink implementation provides to run [`thruster_sink`].
pub trait SinkRig {
    type Sink: ThrusterSink;
    fn name(&self) -> String;
    /// A sink for `thrusters` thrusters (the previous sink of this rig has been dropped).
    fn open(&mut self, thrusters: usize) -> Result<Self::Sink, AdapterError>;
    /// What reached the thrusters since the last call, in order (called after a flush or a
    /// close); `None` when the sink's output cannot be seen (a null sink).
    fn received(&mut self, sink: &mut Self::Sink) -> Option<Vec<Arrived>>;
    /// What arrives on this device for `sent` (the setpoints and stamp a write or stop gave the
    /// last sink opened): by default `sent` itself. A device whose wire carries something else
    /// says so here: ArduSub's pilot input carries the three forces the layout's setpoints make,
    /// and of the stamp only what its lockstep tag carries.
    fn as_arrives(&self, sent: &Arrived) -> Arrived {
        sent.clone()
    }
    /// How far an arriving value may lie from [`SinkRig::as_arrives`]'s: the device's resolution
    /// (0: exactly; ArduSub's pilot input has steps of 1/1000 of full thrust).
    fn resolution(&self) -> f64 {
        0.0
    }
}

/// Checks that `got` is what `sent` arrives as on the rig's device ([`SinkRig::as_arrives`]),
/// values within its resolution.
fn expect<R: SinkRig>(rig: &R, name: &str, got: &[Arrived], sent: &[Arrived], what: &str) {
    let want: Vec<Arrived> = sent.iter().map(|a| rig.as_arrives(a)).collect();
    let close = |a: &[f64], b: &[f64]| {
        a.len() == b.len()
            && a.iter()
                .zip(b)
                .all(|(x, y)| (x - y).abs() <= rig.resolution())
    };
    let same = got.len() == want.len()
        && got
            .iter()
            .zip(&want)
            .all(|(g, w)| g.stamp == w.stamp && g.stop == w.stop && close(&g.values, &w.values));
    assert!(same, "{name}: {what}: arrived {got:?}, expected {want:?}");
}

/// A step's setpoints as they were written.
fn written(stamp: Stamp, values: &[f64]) -> Arrived {
    Arrived {
        stamp,
        values: values.to_vec(),
        stop: None,
    }
}

/// What reached the thrusters: a step's setpoints, or a stop.
#[derive(Clone, Debug, PartialEq)]
pub struct Arrived {
    pub stamp: Stamp,
    pub values: Vec<f64>,
    /// The cause of a failsafe stop; `None` for a step's setpoints.
    pub stop: Option<StopCause>,
}

impl Arrived {
    /// A stop of `thrusters` thrusters, stamped `stamp`.
    pub fn stop(stamp: Stamp, thrusters: usize, cause: StopCause) -> Self {
        Arrived {
            stamp,
            values: vec![0.0; thrusters],
            stop: Some(cause),
        }
    }
}

/// The suite's test frames, `width x height`: seq gaps (frames lost before the source), a trial
/// that ends with the cable lost, the next one starting, and one that reaches its time limit; every
/// image different; the true line known.
pub fn sample_frames(width: u32, height: u32) -> Vec<Frame> {
    use StepStatus::*;
    let plan = [
        (1, 0, 0, 0, Running),
        (2, 200, 0, 1, Running),
        (3, 400, 0, 2, Running),
        (5, 800, 0, 4, Running),
        (6, 1000, 0, 5, Lost),
        (7, 1200, 1, 0, Running),
        (9, 1600, 1, 2, TimeLimit),
    ];
    plan.iter()
        .map(|&(seq, ms, trial, step, status)| frame(width, height, seq, ms, trial, step, status))
        .collect()
}

fn frame(
    width: u32,
    height: u32,
    seq: u64,
    ms: u64,
    trial: u32,
    step: u32,
    status: StepStatus,
) -> Frame {
    let meta = FrameMeta {
        seq,
        time_ns: ms * 1_000_000,
        width,
        height,
        trial,
        step,
        status,
        truth: Some(CableObservationData {
            found: (status != StepStatus::Lost) as u8,
            rho: seq as f64 * 1.5,
            theta: 0.01 * seq as f64,
            x_g: -0.02 * seq as f64,
            y_g: 0.0,
            x_g_rate: 0.05,
            theta_rate: -0.1,
            confidence: if status != StepStatus::Lost { 1.0 } else { 0.0 },
            ..Default::default()
        }),
        damaged: false,
    };
    let image = (0..meta.len())
        .map(|i| ((i as u64 * 7 + seq * 31) % 251) as u8)
        .collect();
    Frame { meta, image }
}

/// Reads until something other than a paced wait comes, moving `now` to each wait's end.
fn next<S: FrameSource>(
    name: &str,
    source: &S,
    now: &mut Instant,
    out: &mut Frame,
) -> Result<Read, AdapterError> {
    for _ in 0..1000 {
        let r = catch_unwind(AssertUnwindSafe(|| source.read(*now, out)))
            .unwrap_or_else(|_| panic!("{name}: read panicked"));
        match r {
            Ok(Read::Pending { until: Some(u) }) => {
                assert!(
                    u > *now,
                    "{name}: Pending until {u:?}, not after now {now:?}"
                );
                *now = u;
            }
            other => return other,
        }
    }
    panic!("{name}: still pending after 1000 paced waits");
}

/// Checks a frame's own consistency against its source's size.
fn well_formed(name: &str, size: (u32, u32), f: &Frame) {
    assert_eq!(
        (f.meta.width, f.meta.height),
        size,
        "{name}: frame {} has another size than the source's",
        f.meta.seq
    );
    assert_eq!(
        f.image.len(),
        f.meta.len(),
        "{name}: frame {}'s image length",
        f.meta.seq
    );
}

/// The frame-source suite.
///
/// - Frames come out exactly as they went in (metadata and image), in time order: seq strictly
///   increasing, time non-decreasing, trials never going back, a new trial after a terminal frame.
/// - Every frame has the source's size and an image of that size.
/// - No frame available: `Pending` at once (a live source), the end of a recording: `End`, again and
///   again; never an error.
/// - A paced recording yields each frame at its time (within half a tick), never before.
/// - Out-of-order input is refused when opened, or never yielded out of order (unless the source
///   reports a device restart); a repeated frame is yielded as `Repeat` with the same content.
/// - Malformed input gives a typed error, never a panic, and the source goes on after it.
pub fn frame_source<R: SourceRig>(rig: &mut R) {
    let name = rig.name();
    let frames = sample_frames(40, 30);

    // In order, exactly as given.
    let source = rig
        .open(&frames)
        .unwrap_or_else(|e| panic!("{name}: cannot open a source over good frames: {e}"));
    assert!(!source.describe().is_empty(), "{name}: describe()");
    assert_eq!(source.size(), (40, 30), "{name}: size()");
    if let Wake::Every(tick) = source.wake() {
        assert!(tick > Duration::ZERO, "{name}: a zero tick would spin");
    }
    let mut now = Instant::now();
    let mut out = Frame::default();
    if rig.live() {
        match source.read(now, &mut out) {
            Ok(Read::Pending { until: None }) => {}
            other => panic!("{name}: with no frame sent, read must be Pending, got {other:?}"),
        }
    }
    let mut yielded: Vec<(Instant, Frame)> = Vec::new();
    for (k, want) in frames.iter().enumerate() {
        rig.deliver(k);
        match next(&name, &source, &mut now, &mut out) {
            Ok(Read::Frame) => {}
            other => panic!("{name}: frame {k}: expected a frame, got {other:?}"),
        }
        well_formed(&name, source.size(), &out);
        assert_eq!(out.meta, want.meta, "{name}: frame {k}'s metadata");
        assert!(out.image == want.image, "{name}: frame {k}'s image");
        yielded.push((now, out.clone()));
    }
    for pair in yielded.windows(2) {
        let (a, b) = (&pair[0].1.meta, &pair[1].1.meta);
        assert!(b.seq > a.seq, "{name}: seq {} after {}", b.seq, a.seq);
        assert!(
            b.time_ns >= a.time_ns,
            "{name}: time goes back at seq {}",
            b.seq
        );
        assert!(
            b.trial >= a.trial,
            "{name}: trial goes back at seq {}",
            b.seq
        );
        if a.status.is_terminal() {
            assert!(
                b.trial > a.trial,
                "{name}: seq {} continues a trial that ended",
                b.seq
            );
        }
    }
    assert_eq!(source.restarts(), 0, "{name}: no restart happened");

    // No more frames.
    for _ in 0..3 {
        match next(&name, &source, &mut now, &mut out) {
            Ok(Read::End) if !rig.live() => {}
            Ok(Read::Pending { until: None }) if rig.live() => {}
            other => panic!(
                "{name}: after the last frame, expected {}, got {other:?}",
                if rig.live() { "Pending" } else { "End" }
            ),
        }
    }

    // Pacing: frame k at (t_k - t_0) / speed after the first, within half a tick.
    if let (Some(speed), Wake::Every(tick)) = (rig.speed(), source.wake()) {
        let (t0, f0) = (&yielded[0].0, &yielded[0].1.meta);
        for (t, f) in &yielded[1..] {
            let due = Duration::from_secs_f64((f.meta.time_ns - f0.time_ns) as f64 / 1e9 / speed);
            let got = t.duration_since(*t0);
            // 1 us for the rounding of two float-to-duration conversions.
            let slack = tick / 2 + Duration::from_micros(1);
            assert!(
                got + slack >= due && got <= due + slack,
                "{name}: frame {} read {got:?} after the first, due {due:?} (tick {tick:?})",
                f.meta.seq
            );
        }
        // And never earlier: a read between two frames' times waits.
        let source = rig.open(&frames).expect("opened before");
        let start = Instant::now();
        assert_eq!(source.read(start, &mut out).ok(), Some(Read::Frame));
        match source.read(start, &mut out) {
            Ok(Read::Pending { until: Some(u) }) => assert!(u > start),
            other => panic!("{name}: the second frame is not due yet, got {other:?}"),
        }
    }
    drop(source);

    // Out of order and repeated input.
    let a = &frames[0];
    let b = &frames[1];
    let c = &frames[2];
    let disordered = vec![
        a.clone(),
        c.clone(),
        b.clone(),
        b.clone(),
        frames[3].clone(),
    ];
    match rig.open(&disordered) {
        Err(e) => assert!(!e.to_string().is_empty()),
        Ok(source) => {
            let mut last: Option<Frame> = None;
            let mut restarts = source.restarts();
            for k in 0..disordered.len() {
                rig.deliver(k);
                match next(&name, &source, &mut now, &mut out) {
                    Ok(Read::Frame) => {
                        well_formed(&name, source.size(), &out);
                        if let Some(l) = &last
                            && (out.meta.seq <= l.meta.seq || out.meta.time_ns < l.meta.time_ns)
                        {
                            assert!(
                                source.restarts() > restarts,
                                "{name}: seq {} (time {}) yielded after seq {} (time {}) with no restart reported",
                                out.meta.seq,
                                out.meta.time_ns,
                                l.meta.seq,
                                l.meta.time_ns
                            );
                        }
                        restarts = source.restarts();
                        last = Some(out.clone());
                    }
                    Ok(Read::Repeat) => {
                        let l = last
                            .as_ref()
                            .unwrap_or_else(|| panic!("{name}: a repeat before any frame"));
                        assert_eq!(&out, l, "{name}: a repeat carries the last frame again");
                    }
                    Ok(Read::Pending { .. }) | Ok(Read::End) => {}
                    Err(e) => assert!(!e.to_string().is_empty()),
                }
            }
            let last = last.unwrap_or_else(|| panic!("{name}: nothing yielded"));
            assert_eq!(
                last.meta, frames[3].meta,
                "{name}: the last good frame is yielded"
            );
        }
    }

    // Malformed input.
    let cases = rig.bad_inputs();
    assert!(!cases.is_empty(), "{name}: the rig names its bad inputs");
    for (k, what) in cases.iter().enumerate() {
        let opened = catch_unwind(AssertUnwindSafe(|| rig.open_bad(k)))
            .unwrap_or_else(|_| panic!("{name}: opening a source over {what} panicked"));
        let source = match opened {
            Err(e) => {
                assert!(!e.to_string().is_empty(), "{name}: {what}: an empty error");
                continue;
            }
            Ok(s) => s,
        };
        let mut errors = 0;
        let mut good = 0;
        for _ in 0..8 {
            match next(&format!("{name}: {what}"), &source, &mut now, &mut out) {
                Err(e) => {
                    assert!(!e.to_string().is_empty(), "{name}: {what}: an empty error");
                    assert_eq!(
                        good, 0,
                        "{name}: {what}: the error comes before the good frame"
                    );
                    errors += 1;
                }
                Ok(Read::Frame) => {
                    well_formed(&name, source.size(), &out);
                    good += 1;
                }
                Ok(Read::Repeat) => panic!("{name}: {what}: a repeat"),
                Ok(Read::Pending { .. }) | Ok(Read::End) => break,
            }
        }
        assert!(errors >= 1, "{name}: {what}: no error was reported");
        assert_eq!(
            good, 1,
            "{name}: {what}: the source goes on after the error"
        );
    }
}

/// The thruster-sink suite. "Arrives" is as the rig's device carries it ([`SinkRig::as_arrives`],
/// within [`SinkRig::resolution`]): exactly what was sent, unless the device says otherwise.
///
/// - A sink has the thrusters it was opened for; 0 or more than `MAX_THRUSTERS` is refused.
/// - Setpoints within [-1, 1] arrive unchanged, with their stamp, in order.
/// - Out of range ones arrive clipped; NaN and infinities arrive as 0; the write says how many
///   were made safe, and how.
/// - A wrong count is an error and nothing arrives.
/// - `stop` makes every thruster 0 at once, marked as a stop with its cause and the last step's
///   stamp, before any write as after.
/// - Zero on close: `close` after a write stops the thrusters; after a stop it adds none; it is
///   idempotent; writing, stopping or flushing after it is an error.
/// - Zero on the deadline: driven by [`Failsafe`], the thrusters stop once (cause `deadline`) when
///   the setpoints they hold go stale, not before, and take setpoints again after.
/// - The deadline's rule ([`crate::failsafe::deadline`]) at 5 Hz: after one missed frame the next
///   step's setpoints find the thrusters still driven (no stop arrives); after two missed frames in
///   a row the thrusters stop, before a third frame's setpoints could come.
pub fn thruster_sink<R: SinkRig>(rig: &mut R) {
    let name = rig.name();
    for bad in [0, config::MAX_THRUSTERS + 1] {
        match rig.open(bad) {
            Err(AdapterError::Count { got, .. }) => assert_eq!(got, bad, "{name}"),
            Err(e) => panic!("{name}: {bad} thrusters: expected a count error, got {e}"),
            Ok(_) => panic!("{name}: a sink of {bad} thrusters was opened"),
        }
    }

    // Timed stamps, as on the vehicle: everything in them arrives.
    let stamp = |seq: u64, status: StepStatus| {
        Stamp::new(seq, seq * 200_000_000, 2, seq as u32, status)
            .timed(77, 5_000_000_000 + seq as i64)
    };
    let mut sink = rig
        .open(3)
        .unwrap_or_else(|e| panic!("{name}: cannot open a sink of 3: {e}"));
    assert_eq!(sink.thrusters(), 3, "{name}");
    assert!(!sink.describe().is_empty(), "{name}: describe()");
    sink.flush()
        .unwrap_or_else(|e| panic!("{name}: flush: {e}"));
    if let Some(got) = rig.received(&mut sink) {
        assert!(got.is_empty(), "{name}: something arrived before any write");
    }

    // A stop before any write: the thrusters start at rest.
    sink.stop(&Stamp::default(), StopCause::Start)
        .unwrap_or_else(|e| panic!("{name}: a stop before any write: {e}"));
    sink.flush()
        .unwrap_or_else(|e| panic!("{name}: flush: {e}"));
    if let Some(got) = rig.received(&mut sink) {
        expect(
            rig,
            &name,
            &got,
            &[Arrived::stop(Stamp::default(), 3, StopCause::Start)],
            "a stop before any write",
        );
    }

    let nan = f64::NAN;
    let inf = f64::INFINITY;
    // (given, as it must arrive, not finite, clamped)
    let cases: [(&[f64], [f64; 3], u64, u64); 5] = [
        (&[0.5, -0.25, 0.0], [0.5, -0.25, 0.0], 0, 0),
        (&[-1.0, 1.0, 0.999], [-1.0, 1.0, 0.999], 0, 0),
        (&[1.5, -3.0, nan], [1.0, -1.0, 0.0], 1, 2),
        (&[inf, -inf, 1.0], [0.0, 0.0, 1.0], 2, 0),
        (&[1.0 + 1e-9, -0.0, -1e300], [1.0, -0.0, -1.0], 0, 2),
    ];
    for (k, (given, want, non_finite, clamped)) in cases.iter().enumerate() {
        let st = stamp(k as u64 + 1, StepStatus::Running);
        let applied = sink
            .write(&st, given)
            .unwrap_or_else(|e| panic!("{name}: write {given:?}: {e}"));
        assert_eq!(applied.as_slice(), want, "{name}: {given:?} made safe");
        assert_eq!(
            (applied.fixes.non_finite, applied.fixes.clamped),
            (*non_finite, *clamped),
            "{name}: {given:?}: what the rule changed"
        );
        sink.flush()
            .unwrap_or_else(|e| panic!("{name}: flush: {e}"));
        if let Some(got) = rig.received(&mut sink) {
            expect(
                rig,
                &name,
                &got,
                &[written(st, want)],
                &format!("one write of {given:?}, with its stamp"),
            );
            assert!(
                got[0]
                    .values
                    .iter()
                    .all(|v| v.is_finite() && v.abs() <= 1.0)
            );
        }
    }

    for wrong in [&[0.1, 0.2][..], &[0.1, 0.2, 0.3, 0.4][..], &[][..]] {
        match sink.write(&stamp(50, StepStatus::Running), wrong) {
            Err(AdapterError::Count { expected, got, .. }) => {
                assert_eq!((expected, got), (3, wrong.len()), "{name}")
            }
            other => panic!(
                "{name}: {} setpoints for 3 thrusters: {other:?}",
                wrong.len()
            ),
        }
    }
    sink.flush()
        .unwrap_or_else(|e| panic!("{name}: flush: {e}"));
    if let Some(got) = rig.received(&mut sink) {
        assert!(got.is_empty(), "{name}: a refused write arrived: {got:?}");
    }

    // Several writes, then one flush: all arrive, in order (a terminal step's answer too).
    let burst: Vec<Stamp> = (60..64)
        .map(|s| stamp(s, StepStatus::Running))
        .chain([stamp(64, StepStatus::Lost)])
        .collect();
    let burst_sent: Vec<Arrived> = burst
        .iter()
        .enumerate()
        .map(|(k, st)| written(*st, &[0.1 * k as f64, -0.1, 0.0]))
        .collect();
    for (st, sent) in burst.iter().zip(&burst_sent) {
        sink.write(st, &sent.values)
            .unwrap_or_else(|e| panic!("{name}: write: {e}"));
        let k = st.seq - burst[0].seq;
        if k == 1 {
            // Sinks with a small window must be read as they go: the rig sees them after a flush.
            sink.flush()
                .unwrap_or_else(|e| panic!("{name}: flush: {e}"));
            if let Some(got) = rig.received(&mut sink) {
                expect(rig, &name, &got, &burst_sent[..2], "the burst's start");
            }
        }
    }
    sink.flush()
        .unwrap_or_else(|e| panic!("{name}: flush: {e}"));
    if let Some(got) = rig.received(&mut sink) {
        expect(rig, &name, &got, &burst_sent[2..], "the burst's order");
    }

    // A stop after writes: zeros, with the last step's stamp and the cause.
    let last = burst[4];
    sink.stop(&last, StopCause::AllocatorDead)
        .unwrap_or_else(|e| panic!("{name}: stop: {e}"));
    sink.flush()
        .unwrap_or_else(|e| panic!("{name}: flush: {e}"));
    if let Some(got) = rig.received(&mut sink) {
        expect(
            rig,
            &name,
            &got,
            &[Arrived::stop(last, 3, StopCause::AllocatorDead)],
            "a stop after writes",
        );
    }

    // Zero on close.
    let st = stamp(70, StepStatus::Running);
    sink.write(&st, &[0.3, 0.3, 0.3])
        .unwrap_or_else(|e| panic!("{name}: write: {e}"));
    sink.close()
        .unwrap_or_else(|e| panic!("{name}: close: {e}"));
    sink.close()
        .unwrap_or_else(|e| panic!("{name}: a second close must succeed: {e}"));
    if let Some(got) = rig.received(&mut sink) {
        expect(
            rig,
            &name,
            &got,
            &[
                written(st, &[0.3; 3]),
                Arrived::stop(st, 3, StopCause::Shutdown),
            ],
            "close stops the thrusters, once",
        );
    }
    match sink.write(&stamp(71, StepStatus::Running), &[0.0; 3]) {
        Err(AdapterError::Closed { .. }) => {}
        other => panic!("{name}: a write after close: {other:?}"),
    }
    assert!(
        matches!(
            sink.stop(&st, StopCause::Deadline),
            Err(AdapterError::Closed { .. })
        ),
        "{name}: a stop after close"
    );
    assert!(
        matches!(sink.flush(), Err(AdapterError::Closed { .. })),
        "{name}: a flush after close"
    );
    drop(sink);

    // A close after a stop adds none.
    let mut sink = rig
        .open(3)
        .unwrap_or_else(|e| panic!("{name}: cannot open a sink of 3: {e}"));
    sink.stop(&st, StopCause::Deadline)
        .unwrap_or_else(|e| panic!("{name}: stop: {e}"));
    sink.close()
        .unwrap_or_else(|e| panic!("{name}: close: {e}"));
    if let Some(got) = rig.received(&mut sink) {
        expect(
            rig,
            &name,
            &got,
            &[Arrived::stop(st, 3, StopCause::Deadline)],
            "a close after a stop",
        );
    }
    drop(sink);

    // Zero on the deadline, under the failsafe (the suite's own clock, in ns).
    let sink = rig
        .open(3)
        .unwrap_or_else(|e| panic!("{name}: cannot open a sink of 3: {e}"));
    let deadline = Duration::from_millis(400);
    let ms = 1_000_000i64;
    let mut failsafe = Failsafe::new(sink, deadline);
    failsafe
        .start()
        .unwrap_or_else(|e| panic!("{name}: failsafe start: {e}"));
    let t0 = 1_000 * ms;
    let st = stamp(80, StepStatus::Running);
    failsafe
        .apply(&st, &[0.6, -0.6, 0.2], failsafe.until_from(t0))
        .unwrap_or_else(|e| panic!("{name}: failsafe write: {e}"));
    let seen = |rig: &mut R, failsafe: &mut Failsafe<R::Sink>| rig.received(failsafe.sink_mut());
    if let Some(got) = seen(rig, &mut failsafe) {
        expect(
            rig,
            &name,
            &got,
            &[
                Arrived::stop(Stamp::default(), 3, StopCause::Start),
                written(st, &[0.6, -0.6, 0.2]),
            ],
            "the failsafe starts at rest, then writes",
        );
    }
    for at in [t0 + 100 * ms, t0 + 399 * ms] {
        assert_eq!(
            failsafe.on_time(at).unwrap(),
            None,
            "{name}: fresh until the deadline"
        );
    }
    if let Some(got) = seen(rig, &mut failsafe) {
        assert!(
            got.is_empty(),
            "{name}: nothing before the deadline: {got:?}"
        );
    }
    assert_eq!(
        failsafe
            .on_time(t0 + 400 * ms)
            .unwrap_or_else(|e| panic!("{name}: failsafe stop: {e}")),
        Some(StopCause::Deadline),
        "{name}: stale at the deadline"
    );
    assert_eq!(
        failsafe.on_time(t0 + 900 * ms).unwrap(),
        None,
        "{name}: once"
    );
    if let Some(got) = seen(rig, &mut failsafe) {
        expect(
            rig,
            &name,
            &got,
            &[Arrived::stop(st, 3, StopCause::Deadline)],
            "zero at the deadline",
        );
    }
    let st = stamp(85, StepStatus::Running);
    failsafe
        .apply(&st, &[0.1, 0.1, 0.1], failsafe.until_from(t0 + 1000 * ms))
        .unwrap_or_else(|e| panic!("{name}: failsafe write after a stop: {e}"));
    failsafe
        .close()
        .unwrap_or_else(|e| panic!("{name}: failsafe close: {e}"));
    if let Some(got) = seen(rig, &mut failsafe) {
        expect(
            rig,
            &name,
            &got,
            &[
                written(st, &[0.1, 0.1, 0.1]),
                Arrived::stop(st, 3, StopCause::Shutdown),
            ],
            "setpoints again, then zero on close",
        );
    }
    drop(failsafe);

    missed_frames(rig, &name);

    // The smallest and the largest layouts.
    for n in [1, config::MAX_THRUSTERS] {
        let mut sink = rig
            .open(n)
            .unwrap_or_else(|e| panic!("{name}: cannot open a sink of {n}: {e}"));
        let values: Vec<f64> = (0..n)
            .map(|i| if i % 2 == 0 { 2.0 } else { -0.5 })
            .collect();
        let want: Vec<f64> = (0..n)
            .map(|i| if i % 2 == 0 { 1.0 } else { -0.5 })
            .collect();
        let st = stamp(80, StepStatus::TimeLimit);
        let applied = sink
            .write(&st, &values)
            .unwrap_or_else(|e| panic!("{name}: {n} thrusters: {e}"));
        assert_eq!(applied.as_slice(), want, "{name}: {n} thrusters");
        sink.stop(&st, StopCause::Deadline)
            .unwrap_or_else(|e| panic!("{name}: {n} thrusters: stop: {e}"));
        sink.flush()
            .unwrap_or_else(|e| panic!("{name}: flush: {e}"));
        if let Some(got) = rig.received(&mut sink) {
            expect(
                rig,
                &name,
                &got,
                &[
                    written(st, &want),
                    Arrived::stop(st, n, StopCause::Deadline),
                ],
                &format!("{n} thrusters: a write and a stop"),
            );
        }
        sink.close()
            .unwrap_or_else(|e| panic!("{name}: close: {e}"));
    }
}

/// One missed frame passes, the second stops the thrusters: the deadline's rule at the vehicle's
/// 5 Hz, on the suite's own clock (ns), each step's setpoints arriving `LATENCY` after the camera
/// took its frame.
fn missed_frames<R: SinkRig>(rig: &mut R, name: &str) {
    const MS: i64 = 1_000_000;
    const PERIOD: i64 = 200 * MS;
    // Camera to thrusters, a slow frame's (benchmarks.md: p99 in single milliseconds).
    const LATENCY: i64 = 20 * MS;
    let sink = rig
        .open(3)
        .unwrap_or_else(|e| panic!("{name}: cannot open a sink of 3: {e}"));
    let mut failsafe = Failsafe::new(
        sink,
        crate::failsafe::deadline(Duration::from_nanos(PERIOD as u64)),
    );
    failsafe
        .start()
        .unwrap_or_else(|e| panic!("{name}: failsafe start: {e}"));
    // Frame k taken at t0 + k periods.
    let t0 = 60_000 * MS;
    let taken = |k: u32| t0 + i64::from(k) * PERIOD;
    let stamp = |k: u32| {
        Stamp::new(
            100 + u64::from(k),
            (10_000 + u64::from(k)) * 200_000_000,
            4,
            k,
            StepStatus::Running,
        )
        .timed(78, taken(k))
    };
    let step = |failsafe: &mut Failsafe<R::Sink>, k: u32, values: &[f64]| {
        let until = failsafe.fresh_until(taken(k));
        assert_eq!(
            failsafe.on_time(taken(k) + LATENCY).unwrap(),
            None,
            "{name}: frame {k}'s setpoints arrive with the thrusters still driven"
        );
        failsafe
            .apply(&stamp(k), values, until)
            .unwrap_or_else(|e| panic!("{name}: failsafe write: {e}"));
    };
    let seen = |rig: &mut R, failsafe: &mut Failsafe<R::Sink>| rig.received(failsafe.sink_mut());
    step(&mut failsafe, 0, &[0.3, -0.3, 0.1]);
    step(&mut failsafe, 1, &[0.4, -0.4, 0.1]);
    // Frame 2 is dropped: frame 1's setpoints hold until frame 3's come, a period later than usual.
    for at in (taken(2) + LATENCY..=taken(3) + LATENCY).step_by(MS as usize) {
        assert_eq!(
            failsafe.on_time(at).unwrap(),
            None,
            "{name}: one missed frame stopped the thrusters {} ms after frame 1",
            (at - taken(1)) / MS
        );
    }
    step(&mut failsafe, 3, &[0.5, -0.5, 0.2]);
    if let Some(got) = seen(rig, &mut failsafe) {
        expect(
            rig,
            name,
            &got,
            &[
                Arrived::stop(Stamp::default(), 3, StopCause::Start),
                written(stamp(0), &[0.3, -0.3, 0.1]),
                written(stamp(1), &[0.4, -0.4, 0.1]),
                written(stamp(3), &[0.5, -0.5, 0.2]),
            ],
            "one missed frame: driven throughout, no stop",
        );
    }
    // Frames 4 and 5 are dropped: frame 3's setpoints go stale three periods after it was taken,
    // before frame 6's setpoints could arrive.
    let mut stopped = None;
    for at in (taken(4)..=taken(6) + LATENCY).step_by(MS as usize) {
        if let Some(cause) = failsafe
            .on_time(at)
            .unwrap_or_else(|e| panic!("{name}: failsafe stop: {e}"))
        {
            assert_eq!(cause, StopCause::Deadline, "{name}");
            stopped.get_or_insert(at);
        }
    }
    assert_eq!(
        stopped.map(|at| (at - taken(3)) / MS),
        Some(3 * PERIOD / MS),
        "{name}: two missed frames stop the thrusters three periods after the last frame taken"
    );
    assert!(
        stopped.is_some_and(|at| at < taken(6) + LATENCY),
        "{name}: stopped before frame 6's setpoints"
    );
    if let Some(got) = seen(rig, &mut failsafe) {
        expect(
            rig,
            name,
            &got,
            &[Arrived::stop(stamp(3), 3, StopCause::Deadline)],
            "two missed frames: zero",
        );
    }
    failsafe
        .close()
        .unwrap_or_else(|e| panic!("{name}: failsafe close: {e}"));
}
