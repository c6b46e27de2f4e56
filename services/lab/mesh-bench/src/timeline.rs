//! When each step's message appeared on each topic, and the latencies of the hops between them.
//!
//! The probe records the first time it received each `seq` on each topic (a re-sent message does not
//! move it). A hop's latency for step `seq` is the time its output of `seq` appeared minus the time its
//! input of `seq` appeared: the stage's wake-up, its work and its publish, as seen from outside.

use serde::{Deserialize, Serialize};
use stats::Summary;

/// The mesh's topics in the order of the loop.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Point {
    State = 0,
    Frame = 1,
    Observation = 2,
    Surge = 3,
    Sway = 4,
    Yaw = 5,
    Setpoints = 6,
}

impl Point {
    pub const ALL: [Point; 7] = [
        Point::State,
        Point::Frame,
        Point::Observation,
        Point::Surge,
        Point::Sway,
        Point::Yaw,
        Point::Setpoints,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Point::State => "vehicle_state",
            Point::Frame => "camera_frame",
            Point::Observation => "cable_observation",
            Point::Surge => "command/surge",
            Point::Sway => "command/sway",
            Point::Yaw => "command/yaw",
            Point::Setpoints => "thruster_setpoints",
        }
    }
}

/// A latency measured between two points of the loop.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Hop {
    /// The stage (a process, or the whole step).
    pub name: &'static str,
    /// What it spans.
    pub span: &'static str,
}

/// The hops of the loop, each a process; then the step and the whole cycle.
pub const HOPS: [Hop; 9] = [
    Hop {
        name: "camera",
        span: "vehicle_state → camera_frame",
    },
    Hop {
        name: "perception",
        span: "camera_frame → cable_observation",
    },
    Hop {
        name: "surge-controller",
        span: "cable_observation → command/surge",
    },
    Hop {
        name: "sway-behaviour",
        span: "cable_observation → command/sway",
    },
    Hop {
        name: "yaw-behaviour",
        span: "cable_observation → command/yaw",
    },
    Hop {
        name: "thruster-allocator",
        span: "last command → thruster_setpoints",
    },
    Hop {
        name: "simulator",
        span: "thruster_setpoints → next vehicle_state",
    },
    Hop {
        name: "step",
        span: "vehicle_state → thruster_setpoints",
    },
    Hop {
        name: "cycle",
        span: "vehicle_state → next vehicle_state",
    },
];

/// First-reception times (ns, 0 = not seen), per topic, indexed by `seq`.
#[derive(Clone, Debug, Default)]
pub struct Timeline {
    seen: [Vec<u64>; 7],
    /// The episode and step of each `seq` (from the vehicle states' stamps).
    steps: Vec<(u32, u32)>,
}

/// One of the slowest steps of a run, and the stage that took longest in it.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct SlowStep {
    pub seq: u64,
    pub episode: u32,
    pub step: u32,
    /// The step's latency (vehicle_state → thruster_setpoints).
    pub step_ns: u64,
    pub worst_stage: String,
    pub worst_ns: u64,
}

/// How many of the slowest steps a run keeps.
pub const SLOWEST: usize = 5;

/// The latencies of every hop of [`HOPS`], in its order.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct HopLatencies {
    pub hops: Vec<Summary>,
    /// Steps in the window whose message on some topic the probe never received (overwritten in its
    /// buffer while it was late): left out of the hops that need it.
    pub missed: usize,
    /// Hops measured as negative (the probe read the output before the input in one wake-up) and
    /// counted as 0.
    pub reordered: usize,
    /// The [`SLOWEST`] slowest steps, slowest first.
    pub slowest: Vec<SlowStep>,
}

impl Timeline {
    pub fn new() -> Self {
        Self::default()
    }

    /// Notes that `seq` appeared on `point` at `t_ns`; only the first time counts.
    pub fn record(&mut self, point: Point, seq: u64, t_ns: u64) {
        let v = &mut self.seen[point as usize];
        let i = seq as usize;
        if v.len() <= i {
            v.resize(i + 1, 0);
        }
        if v[i] == 0 {
            v[i] = t_ns.max(1);
        }
    }

    /// Notes the episode and step of `seq` (from its vehicle state's stamp).
    pub fn record_step(&mut self, seq: u64, episode: u32, step: u32) {
        let i = seq as usize;
        if self.steps.len() <= i {
            self.steps.resize(i + 1, (0, 0));
        }
        self.steps[i] = (episode, step);
    }

    /// When `seq` first appeared on `point`.
    pub fn at(&self, point: Point, seq: u64) -> Option<u64> {
        self.seen[point as usize]
            .get(seq as usize)
            .copied()
            .filter(|&t| t != 0)
    }

    /// The highest `seq` seen on `point`.
    pub fn last_seq(&self, point: Point) -> Option<u64> {
        let v = &self.seen[point as usize];
        v.iter().rposition(|&t| t != 0).map(|i| i as u64)
    }

    /// Closed-loop steps per second over the steps from `first` on: the vehicle states' pace.
    pub fn steps_per_s(&self, first: u64) -> Option<f64> {
        let last = self.last_seq(Point::State)?;
        let first = (first..=last).find(|&s| self.at(Point::State, s).is_some())?;
        let (t0, t1) = (self.at(Point::State, first)?, self.at(Point::State, last)?);
        (last > first && t1 > t0).then(|| (last - first) as f64 / ((t1 - t0) as f64 * 1e-9))
    }

    /// The latencies of [`HOPS`] for the steps `first..` whose whole cycle was seen.
    pub fn hops(&self, first: u64) -> HopLatencies {
        let mut values: Vec<Vec<u64>> = vec![Vec::new(); HOPS.len()];
        let (mut missed, mut reordered) = (0, 0);
        let mut slowest: Vec<SlowStep> = Vec::new();
        let Some(last) = self.last_seq(Point::State) else {
            return HopLatencies::default();
        };
        // The last state's cycle never closed: it has no setpoints.
        for seq in first..last {
            let get = |p| self.at(p, seq);
            let (Some(state), Some(frame), Some(obs), Some(surge), Some(sway), Some(yaw)) = (
                get(Point::State),
                get(Point::Frame),
                get(Point::Observation),
                get(Point::Surge),
                get(Point::Sway),
                get(Point::Yaw),
            ) else {
                missed += 1;
                continue;
            };
            let (Some(sp), Some(next)) = (get(Point::Setpoints), self.at(Point::State, seq + 1))
            else {
                missed += 1;
                continue;
            };
            let last_cmd = surge.max(sway).max(yaw);
            let spans = [
                (state, frame),
                (frame, obs),
                (obs, surge),
                (obs, sway),
                (obs, yaw),
                (last_cmd, sp),
                (sp, next),
                (state, sp),
                (state, next),
            ];
            let mut worst = (0, 0);
            for (k, (from, to)) in spans.into_iter().enumerate() {
                if to < from {
                    reordered += 1;
                }
                let d = to.saturating_sub(from);
                values[k].push(d);
                // The stages only (not the step or the cycle).
                if k < 7 && d > worst.1 {
                    worst = (k, d);
                }
            }
            let step_ns = sp.saturating_sub(state);
            if slowest.len() < SLOWEST || slowest.last().is_some_and(|s| step_ns > s.step_ns) {
                let (episode, step) = self.steps.get(seq as usize).copied().unwrap_or_default();
                slowest.push(SlowStep {
                    seq,
                    episode,
                    step,
                    step_ns,
                    worst_stage: HOPS[worst.0].name.to_owned(),
                    worst_ns: worst.1,
                });
                slowest.sort_by_key(|s| std::cmp::Reverse(s.step_ns));
                slowest.truncate(SLOWEST);
            }
        }
        HopLatencies {
            hops: values.iter().map(|v| Summary::of(v)).collect(),
            missed,
            reordered,
            slowest,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A loop where every stage takes a fixed time: state at 1000*seq, then +100 frame, +200 obs,
    /// commands at +210/+220/+230, setpoints at +250.
    fn steady(steps: u64) -> Timeline {
        let mut t = Timeline::new();
        for seq in 1..=steps {
            let s = 1000 * seq;
            t.record(Point::State, seq, s);
            t.record(Point::Frame, seq, s + 100);
            t.record(Point::Observation, seq, s + 200);
            t.record(Point::Surge, seq, s + 210);
            t.record(Point::Sway, seq, s + 230);
            t.record(Point::Yaw, seq, s + 220);
            t.record(Point::Setpoints, seq, s + 250);
        }
        t
    }

    #[test]
    fn hops_of_a_steady_loop() {
        let t = steady(10);
        let h = t.hops(3);
        let p50: Vec<u64> = h.hops.iter().map(|s| s.p50).collect();
        assert_eq!(p50, [100, 100, 10, 30, 20, 20, 750, 250, 1000]);
        // Steps 3..=9: the 10th state's cycle never closed.
        assert!(h.hops.iter().all(|s| s.n == 7));
        assert_eq!((h.missed, h.reordered), (0, 0));
        assert_eq!(h.slowest.len(), SLOWEST);
        assert!(h.slowest.iter().all(|s| s.step_ns == 250));
        let rate = t.steps_per_s(3).unwrap();
        assert!((rate - 1e6).abs() < 1e-3, "{rate}");
    }

    #[test]
    fn re_sends_do_not_move_a_step_and_gaps_are_counted() {
        let mut t = steady(6);
        // A re-sent state and a late duplicate of a command.
        t.record(Point::State, 4, 999_999);
        t.record(Point::Yaw, 4, 999_999);
        assert_eq!(t.at(Point::State, 4), Some(4000));
        // The probe lost step 5's frame.
        t.seen[Point::Frame as usize][5] = 0;
        let h = t.hops(1);
        assert_eq!(h.missed, 1);
        assert_eq!(h.hops[0].n, 4);
        assert_eq!(t.last_seq(Point::State), Some(6));
        assert_eq!(t.at(Point::Frame, 99), None);
    }

    #[test]
    fn the_slowest_steps_name_their_slowest_stage() {
        let mut t = steady(10);
        // Step 7 (episode 1, step 3): the yaw behaviour took 5 µs longer.
        t.seen[Point::Yaw as usize][7] += 5_000;
        t.seen[Point::Setpoints as usize][7] += 5_000;
        t.record_step(7, 1, 3);
        let h = t.hops(1);
        let s = &h.slowest[0];
        assert_eq!((s.seq, s.episode, s.step, s.step_ns), (7, 1, 3, 5_250));
        assert_eq!(
            (s.worst_stage.as_str(), s.worst_ns),
            ("yaw-behaviour", 5_020)
        );
        assert_eq!(h.slowest[1].step_ns, 250);
    }

    #[test]
    fn an_output_read_before_its_input_counts_as_zero() {
        let mut t = steady(3);
        t.seen[Point::Frame as usize][1] = 900;
        let h = t.hops(1);
        assert_eq!(h.reordered, 1);
        assert_eq!(h.hops[0].p50, 0);
    }
}
