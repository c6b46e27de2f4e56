//! What a mesh answered to a dive, and how a replay's answers compare with the recorded ones: per
//! topic the steps compared, equal, differing, missing and extra; the first differing step; the
//! largest absolute difference of every field. Equal means the same bits (NaN equals NaN).

use config::Dof;
use messages::{CableObservationMsg, DofCommand, LearningStats, ThrusterSetpoints};
use recorder::{CommandDof, Recorded};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// The outputs of a mesh for each step (`seq`): what is compared.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Outputs {
    pub observations: BTreeMap<u64, CableObservationMsg>,
    pub commands: BTreeMap<CommandDof, BTreeMap<u64, DofCommand>>,
    pub setpoints: BTreeMap<u64, ThrusterSetpoints>,
    /// The behaviours' episode reports, by the `seq` of the step that ended the episode.
    pub learning: BTreeMap<Dof, BTreeMap<u64, LearningStats>>,
}

impl Outputs {
    /// Keeps `item` if it is an output (the first message of a step: a re-send is the same).
    pub fn add(&mut self, item: &Recorded) {
        match item {
            Recorded::Observation(o) => {
                self.observations.entry(o.stamp.seq).or_insert(*o);
            }
            Recorded::Command(d, c) => {
                self.commands
                    .entry(*d)
                    .or_default()
                    .entry(c.stamp.seq)
                    .or_insert(*c);
            }
            Recorded::Setpoints(s) => {
                self.setpoints.entry(s.stamp.seq).or_insert(*s);
            }
            Recorded::Learning(d, s) => {
                self.learning
                    .entry(*d)
                    .or_default()
                    .entry(s.stamp.seq)
                    .or_insert(*s);
            }
            _ => {}
        }
    }

    /// The outputs of steps `seqs` only (a replay compares the steps it played).
    pub fn only(&self, keep: impl Fn(u64) -> bool) -> Outputs {
        fn f<T: Copy>(m: &BTreeMap<u64, T>, keep: &impl Fn(u64) -> bool) -> BTreeMap<u64, T> {
            m.iter()
                .filter(|(s, _)| keep(**s))
                .map(|(s, v)| (*s, *v))
                .collect()
        }
        Outputs {
            observations: f(&self.observations, &keep),
            commands: self
                .commands
                .iter()
                .map(|(d, m)| (*d, f(m, &keep)))
                .collect(),
            setpoints: f(&self.setpoints, &keep),
            learning: self
                .learning
                .iter()
                .map(|(d, m)| (*d, f(m, &keep)))
                .collect(),
        }
    }
}

/// The numbers a payload carries, by field name.
trait Fields {
    fn fields(&self) -> Vec<(String, f64)>;
    fn at(&self) -> (u32, u32);
}

impl Fields for CableObservationMsg {
    fn fields(&self) -> Vec<(String, f64)> {
        let o = &self.observation;
        [
            ("found", o.found as f64),
            ("rho", o.rho),
            ("theta", o.theta),
            ("x_g", o.x_g),
            ("y_g", o.y_g),
            ("x_g_rate", o.x_g_rate),
            ("theta_rate", o.theta_rate),
            ("confidence", o.confidence),
        ]
        .map(|(k, v)| (k.to_owned(), v))
        .into()
    }
    fn at(&self) -> (u32, u32) {
        (self.stamp.episode, self.stamp.step)
    }
}

impl Fields for DofCommand {
    fn fields(&self) -> Vec<(String, f64)> {
        vec![("value".to_owned(), self.value)]
    }
    fn at(&self) -> (u32, u32) {
        (self.stamp.episode, self.stamp.step)
    }
}

impl Fields for ThrusterSetpoints {
    fn fields(&self) -> Vec<(String, f64)> {
        let mut f: Vec<(String, f64)> = self
            .as_slice()
            .iter()
            .enumerate()
            .map(|(i, v)| (format!("values[{i}]"), *v))
            .collect();
        f.push(("count".to_owned(), self.count as f64));
        f.push(("missing".to_owned(), self.missing as f64));
        f.push(("scale".to_owned(), self.scale));
        f
    }
    fn at(&self) -> (u32, u32) {
        (self.stamp.episode, self.stamp.step)
    }
}

impl Fields for LearningStats {
    fn fields(&self) -> Vec<(String, f64)> {
        [
            ("episode_return", self.episode_return),
            ("gain[0]", self.gain[0]),
            ("gain[1]", self.gain[1]),
            ("actor_updates", self.actor_updates as f64),
            ("steps", self.steps as f64),
            ("failed", self.failed as f64),
        ]
        .map(|(k, v)| (k.to_owned(), v))
        .into()
    }
    fn at(&self) -> (u32, u32) {
        (self.stamp.episode, self.stamp.step)
    }
}

fn same(a: f64, b: f64) -> bool {
    a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan())
}

/// One topic's comparison.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TopicReport {
    /// Steps the record has on this topic, and the replay.
    pub recorded: u64,
    pub replayed: u64,
    /// Steps both have, and of those the ones equal bit for bit and the ones that differ.
    pub compared: u64,
    pub equal: u64,
    pub differing: u64,
    /// Recorded steps the replay did not answer, and replayed ones the record does not have.
    pub missing: u64,
    pub extra: u64,
    /// The largest absolute difference of each field over the compared steps.
    pub max_abs_difference: BTreeMap<String, f64>,
}

/// The first step where the replay differs from the record.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Difference {
    pub seq: u64,
    pub episode: u32,
    pub step: u32,
    pub topic: String,
    /// The first differing field (`missing`: the replay has no answer for the step; `extra`: the
    /// record has none).
    pub field: String,
    pub recorded: Option<f64>,
    pub replayed: Option<f64>,
}

/// A replay against its record.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Report {
    /// The record replayed.
    pub record: String,
    /// Frames published into the mesh.
    pub frames: u64,
    /// Every compared output equal bit for bit, none missing, none extra.
    pub identical: bool,
    pub topics: BTreeMap<String, TopicReport>,
    pub first_difference: Option<Difference>,
}

fn compare_topic<T: Fields>(
    topic: &str,
    recorded: &BTreeMap<u64, T>,
    replayed: &BTreeMap<u64, T>,
    first: &mut Option<Difference>,
) -> TopicReport {
    let mut r = TopicReport {
        recorded: recorded.len() as u64,
        replayed: replayed.len() as u64,
        ..Default::default()
    };
    let mut note = |d: Difference| {
        if first.as_ref().is_none_or(|f| d.seq < f.seq) {
            *first = Some(d);
        }
    };
    for (seq, rec) in recorded {
        let (episode, step) = rec.at();
        let Some(rep) = replayed.get(seq) else {
            r.missing += 1;
            note(Difference {
                seq: *seq,
                episode,
                step,
                topic: topic.to_owned(),
                field: "missing".to_owned(),
                recorded: None,
                replayed: None,
            });
            continue;
        };
        r.compared += 1;
        let (a, b) = (rec.fields(), rep.fields());
        let mut equal = a.len() == b.len();
        let mut first_field = None;
        for ((name, x), (_, y)) in a.iter().zip(&b) {
            let d = (x - y).abs();
            let slot = r.max_abs_difference.entry(name.clone()).or_insert(0.0);
            if !same(*x, *y) {
                equal = false;
                *slot = slot.max(if d.is_nan() { f64::INFINITY } else { d });
                first_field.get_or_insert((name.clone(), *x, *y));
            }
        }
        if equal {
            r.equal += 1;
        } else {
            r.differing += 1;
            let (field, x, y) = first_field.unwrap_or(("count".to_owned(), f64::NAN, f64::NAN));
            note(Difference {
                seq: *seq,
                episode,
                step,
                topic: topic.to_owned(),
                field,
                recorded: Some(x),
                replayed: Some(y),
            });
        }
    }
    for (seq, rep) in replayed.iter().filter(|(s, _)| !recorded.contains_key(s)) {
        r.extra += 1;
        let (episode, step) = rep.at();
        note(Difference {
            seq: *seq,
            episode,
            step,
            topic: topic.to_owned(),
            field: "extra".to_owned(),
            recorded: None,
            replayed: None,
        });
    }
    r
}

impl Report {
    /// Compares `replayed` with `recorded`, topic by topic.
    pub fn compare(record: &str, frames: u64, recorded: &Outputs, replayed: &Outputs) -> Report {
        let mut first = None;
        let mut topics = BTreeMap::new();
        let empty_c = BTreeMap::new();
        let empty_l = BTreeMap::new();
        topics.insert(
            recorder::Channel::Observation.topic().to_owned(),
            compare_topic(
                recorder::Channel::Observation.topic(),
                &recorded.observations,
                &replayed.observations,
                &mut first,
            ),
        );
        for d in CommandDof::ALL {
            let topic = d.channel().topic();
            topics.insert(
                topic.to_owned(),
                compare_topic(
                    topic,
                    recorded.commands.get(&d).unwrap_or(&empty_c),
                    replayed.commands.get(&d).unwrap_or(&empty_c),
                    &mut first,
                ),
            );
        }
        topics.insert(
            recorder::Channel::Setpoints.topic().to_owned(),
            compare_topic(
                recorder::Channel::Setpoints.topic(),
                &recorded.setpoints,
                &replayed.setpoints,
                &mut first,
            ),
        );
        for d in Dof::ALL {
            let c = match d {
                Dof::Sway => recorder::Channel::SwayLearning,
                Dof::Yaw => recorder::Channel::YawLearning,
            };
            topics.insert(
                c.topic().to_owned(),
                compare_topic(
                    c.topic(),
                    recorded.learning.get(&d).unwrap_or(&empty_l),
                    replayed.learning.get(&d).unwrap_or(&empty_l),
                    &mut first,
                ),
            );
        }
        let identical = topics
            .values()
            .all(|t| t.differing == 0 && t.missing == 0 && t.extra == 0);
        Report {
            record: record.to_owned(),
            frames,
            identical,
            topics,
            first_difference: first,
        }
    }

    /// The report as a few lines of text.
    pub fn text(&self) -> String {
        let mut out = format!(
            "replay of {}: {} frames; {}\n",
            self.record,
            self.frames,
            if self.identical {
                "every output equal to the record, bit for bit"
            } else {
                "the outputs DIFFER from the record"
            }
        );
        out.push_str("topic                       recorded replayed  equal differing missing extra  largest difference\n");
        for (topic, t) in &self.topics {
            let largest = t
                .max_abs_difference
                .iter()
                .filter(|(_, v)| **v > 0.0)
                .max_by(|a, b| a.1.total_cmp(b.1))
                .map_or("-".to_owned(), |(k, v)| format!("{k} {v:.3e}"));
            out.push_str(&format!(
                "{topic:<27} {:>8} {:>8} {:>6} {:>9} {:>7} {:>5}  {largest}\n",
                t.recorded, t.replayed, t.equal, t.differing, t.missing, t.extra
            ));
        }
        if let Some(d) = &self.first_difference {
            out.push_str(&format!(
                "first difference: step seq {} (episode {}, step {}), {} {}: recorded {}, replayed {}\n",
                d.seq,
                d.episode,
                d.step,
                d.topic,
                d.field,
                d.recorded.map_or("-".to_owned(), |v| format!("{v:e}")),
                d.replayed.map_or("-".to_owned(), |v| format!("{v:e}")),
            ));
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use messages::{CableObservationData, Stamp, StepStatus};

    fn obs(seq: u64, x_g: f64) -> Recorded {
        Recorded::Observation(CableObservationMsg {
            stamp: Stamp::new(seq, 0, 1, seq as u32, StepStatus::Running),
            observation: CableObservationData {
                found: 1,
                x_g,
                ..Default::default()
            },
        })
    }

    fn cmd(seq: u64, value: f64) -> Recorded {
        Recorded::Command(
            CommandDof::Yaw,
            DofCommand {
                stamp: Stamp::new(seq, 0, 1, seq as u32, StepStatus::Running),
                value,
            },
        )
    }

    fn outputs(items: &[Recorded]) -> Outputs {
        let mut o = Outputs::default();
        for i in items {
            o.add(i);
        }
        o
    }

    #[test]
    fn the_same_outputs_are_identical() {
        let a = outputs(&[obs(1, 0.1), cmd(1, 0.5), obs(2, f64::NAN), cmd(2, -0.0)]);
        let r = Report::compare("d.mcap", 2, &a, &a.clone());
        assert!(r.identical, "{}", r.text());
        assert_eq!(r.topics["/cable_observation"].equal, 2);
        assert_eq!(r.first_difference, None);
    }

    #[test]
    fn a_difference_is_located_counted_and_measured() {
        let rec = outputs(&[
            obs(1, 0.1),
            cmd(1, 0.5),
            obs(2, 0.2),
            cmd(2, 0.25),
            obs(3, 0.3),
            cmd(3, 0.125),
        ]);
        let rep = outputs(&[
            obs(1, 0.1),
            cmd(1, 0.5),
            obs(2, 0.2),
            // One ulp off at step 2, a lot at step 3; step 3's observation is missing; 4 is extra.
            cmd(2, f64::from_bits(0.25f64.to_bits() + 1)),
            cmd(3, 0.625),
            obs(4, 0.4),
        ]);
        let r = Report::compare("d.mcap", 4, &rec, &rep);
        assert!(!r.identical);
        let c = &r.topics["/command/yaw"];
        assert_eq!((c.compared, c.equal, c.differing), (3, 1, 2));
        assert_eq!(c.max_abs_difference["value"], 0.5);
        let o = &r.topics["/cable_observation"];
        assert_eq!((o.compared, o.missing, o.extra), (2, 1, 1));
        let d = r.first_difference.as_ref().unwrap();
        assert_eq!(
            (d.seq, d.topic.as_str(), d.field.as_str()),
            (2, "/command/yaw", "value")
        );
        assert!(r.text().contains("DIFFER") && r.text().contains("first difference: step seq 2"));
        // Only the steps played are compared.
        let part = rec.only(|s| s <= 1);
        assert!(Report::compare("d.mcap", 1, &part, &rep.only(|s| s <= 1)).identical);
    }
}
