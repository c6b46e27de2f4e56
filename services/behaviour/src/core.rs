//! The behaviour's core: one learned DOF between perception and the allocator, without IPC.
//!
//! Per observation, [`Behaviour::step`] applies the trainer's rule ([`behave`]): while the episode
//! runs, an observation without the cable (perception missed it in this frame) is a skipped step
//! (action 0, nothing learned); otherwise the agent steps on the DOF's state with the step's status.
//! The answer is the DOF's command for that step and, when the step ended an episode, the episode's
//! learning statistics.
//!
//! A behaviour built [`Behaviour::for_step_two`] runs step two's protocol on top (see
//! [`crate::step_two`]): each trial is a learning or an evaluation trial, every actor update passes
//! the safety guard, and each evaluation is judged against the best pair of policies so far, on the
//! pair's cost, so that the sway and yaw behaviours keep and restore the policies of one and the
//! same evaluation. Each sums it apart, alike: the state costs from the observations both get
//! ([`learning::state_costs`]), the action costs from its own commands and its partner's
//! ([`learning::action_costs`]; the partner's come in through [`Behaviour::partner_command`]).
//!
//! Where the scenario's `[missed_frames] predict` is above 0, a step-two behaviour answers a missed
//! frame with the policy's mean action at the state its DOF's identified model predicts, for that
//! many missed frames in a row, instead of holding still (DESIGN.md, "A frame without the cable").

use crate::step_two::{SAFETY_ENVELOPE, StepTwo, TrialKind, guard, identified_model};
use config::{Dof, LearningParams, PerDof, QuadraticCost, Scenario};
use learning::lqr::{DiscreteSystem, LqrError};
use learning::{
    Agent, AgentState, Algorithm, EpisodeSummary, Evaluated, Verdict, action_costs, state_costs,
};
use messages::{CableObservationMsg, DofCommand, LearningStats, Stamp, StepStatus};
use model::CableObservation;
use std::collections::VecDeque;

/// The partner's commands a behaviour keeps to find the one of its last step: one comes per step,
/// and the shell hands them in before each observation; the rest is slack for re-sends.
const PARTNER_COMMANDS: usize = 8;

/// A fresh agent for `dof`, built exactly as the in-process trainer builds it: the configured
/// initial gain, the scenario's reward and observation box, exploration seeded by `seed` (the
/// experiment's stream of the DOF, `config::derive_seed(seed, dof.name())`).
pub fn new_agent(
    dof: Dof,
    algorithm: Algorithm,
    scenario: &Scenario,
    learning: &LearningParams,
    seed: u64,
) -> Agent {
    Agent::new(
        dof,
        algorithm,
        learning,
        *scenario.reward.of(dof),
        scenario.state_max(dof),
        seed,
    )
}

/// The exploration seed of an agent resumed from `state`: the DOF's stream seed for a state that has
/// taken no step, else a seed derived from it and the state's step count, so a behaviour restarted
/// from a later checkpoint does not replay the noise it already used.
pub fn resume_seed(stream_seed: u64, state: &AgentState) -> u64 {
    if state.steps == 0 {
        stream_seed
    } else {
        config::derive_seed(stream_seed, &format!("resume/{}", state.steps))
    }
}

/// One behaviour's step, the rule the in-process trainer (`trainer::world`) applies as well: its
/// action, and its episode summary when the episode ended.
pub fn behave(
    agent: &mut Agent,
    obs: &CableObservation,
    kind: StepStatus,
) -> (f64, Option<EpisodeSummary>) {
    if !obs.found && kind == StepStatus::Running {
        // Perception missed the cable in this frame although it is in view: hold still and learn
        // nothing from a state that was not observed.
        return (agent.skip(), None);
    }
    let step = agent.step(obs.state(agent.dof()), kind);
    (step.action, step.episode)
}

/// The statistics message of a finished episode of `agent` (its gain and counts as they are now).
pub fn learning_stats(stamp: Stamp, episode: &EpisodeSummary, agent: &Agent) -> LearningStats {
    let safety = agent.safety();
    LearningStats {
        stamp,
        episode_return: episode.return_,
        gain: agent.gain(),
        actor_updates: episode.actor_updates,
        steps: episode.steps,
        failed: episode.failed as u8,
        learning: agent.is_learning() as u8,
        evaluation: 0,
        rolled_back: 0,
        bounded: safety.bounded,
        refused: safety.refused,
        rollbacks: safety.rollbacks,
        evaluated: f64::NAN,
        best_evaluated: safety.reference().map_or(f64::NAN, |b| b.evaluated),
    }
}

/// The answer to one observation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Output {
    /// The DOF's command: the observation's stamp, the action applied.
    pub command: DofCommand,
    /// Present when the step ended an episode.
    pub stats: Option<LearningStats>,
    /// Present when the step began an episode before the last one had ended (its terminal step
    /// never came: lost while a service upstream was restarted or stalled): the statistics of the
    /// steps the behaviour saw of it, stamped with the last of them, so the trial is still
    /// reported. Never counted towards an evaluation (step two judges whole trials only).
    pub cut: Option<LearningStats>,
}

/// Step two, frames in which perception missed the cable although it is in view
/// (`[missed_frames]` of the scenario): the DOF's state as its identified model predicts it from the
/// last state acted on and the command given there, for at most `frames` missed frames in a row.
#[derive(Clone, Debug)]
struct Prediction {
    model: DiscreteSystem<2, 1>,
    frames: u32,
    /// The last state acted on (observed or predicted) and the command given at it.
    last: Option<([f64; 2], f64)>,
    /// Missed frames predicted in a row.
    run: u32,
}

impl Prediction {
    /// The state of the next frame, when one may still be predicted; past `frames` in a row nothing
    /// is, until the next observation.
    fn next(&mut self) -> Option<[f64; 2]> {
        let (x, u) = self.last.take()?;
        if self.run >= self.frames {
            return None;
        }
        self.run += 1;
        Some(self.model.next(x, [u]))
    }

    /// The behaviour gave command `u` at state `x`; `observed`: seen by perception.
    fn acted(&mut self, x: [f64; 2], u: f64, observed: bool) {
        self.last = Some((x, u));
        if observed {
            self.run = 0;
        }
    }

    fn forget(&mut self) {
        (self.last, self.run) = (None, 0);
    }
}

/// One learned DOF: its agent and the episode it is in.
#[derive(Clone, Debug)]
pub struct Behaviour {
    agent: Agent,
    /// The episode of the last observation, and whether that observation ended it.
    last: Option<(u32, bool)>,
    /// The stamp of the last observation.
    last_stamp: Option<Stamp>,
    /// Step two's protocol, when the behaviour runs it.
    step_two: Option<StepTwo>,
    /// What the current trial is for (step two).
    kind: TrialKind,
    /// Step two: the DOF's state left the safety envelope in this learning trial. With a best policy
    /// to restore, it was restored and the trial goes on with it without learning; without one, the
    /// trial goes on learning. Either way the envelope is not looked at again in this trial.
    left_envelope: bool,
    /// Step two: both DOFs' rewards (the scenario's), whose state and action costs make the
    /// pair's cost.
    rewards: Option<PerDof<QuadraticCost>>,
    /// Step two: the last evaluation judged, the trial that closed it and the pair's score there.
    judged: Option<(u32, f64)>,
    /// Step two: the partner DOF's latest commands, (seq, action applied), oldest first.
    partner: VecDeque<(u64, f64)>,
    /// Step two, in an evaluation trial: the last step's seq and this behaviour's command, whose
    /// action costs the next step of the trial adds.
    previous: Option<(u64, f64)>,
    /// Step two: steps of the evaluation in progress whose partner command was not there (its
    /// action cost taken as 0).
    partner_missing: u32,
    /// Step two: how a missed frame is answered, when not by holding still.
    prediction: Option<Prediction>,
    /// Step two: missed frames of the current trial answered from the prediction.
    predicted: u32,
}

impl Behaviour {
    pub fn new(agent: Agent) -> Self {
        Behaviour {
            agent,
            last: None,
            last_stamp: None,
            step_two: None,
            kind: TrialKind::Learning,
            left_envelope: false,
            rewards: None,
            judged: None,
            partner: VecDeque::new(),
            previous: None,
            partner_missing: 0,
            prediction: None,
            predicted: 0,
        }
    }

    /// A behaviour running step two's protocol `step_two`, with the safety guard of the agent's own
    /// learning parameters for `scenario`'s identified model.
    pub fn for_step_two(
        mut agent: Agent,
        step_two: StepTwo,
        scenario: &Scenario,
    ) -> Result<Self, LqrError> {
        agent.set_guard(guard(scenario, agent.params(), agent.dof())?);
        let dof = agent.dof();
        agent.learn_as_on_the_vehicle();
        agent.set_learning(step_two.learning);
        Ok(Behaviour {
            agent,
            last: None,
            last_stamp: None,
            step_two: Some(step_two),
            kind: TrialKind::Learning,
            left_envelope: false,
            rewards: Some(PerDof {
                sway: scenario.reward.sway,
                yaw: scenario.reward.yaw,
            }),
            judged: None,
            partner: VecDeque::new(),
            previous: None,
            partner_missing: 0,
            prediction: (scenario.missed_frames.predict > 0)
                .then(|| -> Result<Prediction, LqrError> {
                    Ok(Prediction {
                        model: identified_model(scenario, dof)?,
                        frames: scenario.missed_frames.predict,
                        last: None,
                        run: 0,
                    })
                })
                .transpose()?,
            predicted: 0,
        })
    }

    /// The partner DOF's command of a step (its `command/...` topic), for the action term of the
    /// pair's cost; hand each in as it comes, before the next observation (a repeated one is
    /// ignored). In lockstep the partner's command of step t is out before the observation of
    /// t + 1 is; on the vehicle, one camera period before it.
    pub fn partner_command(&mut self, command: &DofCommand) {
        if self.rewards.is_none() || self.partner.iter().any(|(s, _)| *s == command.stamp.seq) {
            return;
        }
        if self.partner.len() == PARTNER_COMMANDS {
            self.partner.pop_front();
        }
        self.partner.push_back((command.stamp.seq, command.value));
    }

    /// Step two's protocol, if the behaviour runs it.
    pub fn step_two(&self) -> Option<&StepTwo> {
        self.step_two.as_ref()
    }

    /// The pair's score ([`learning::pair_score`]) of the evaluation closed by trial `trial`, when
    /// this behaviour judged it.
    pub fn pair_score(&self, trial: u32) -> Option<f64> {
        self.judged.filter(|(t, _)| *t == trial).map(|(_, s)| s)
    }

    /// What the current trial is for.
    pub fn trial_kind(&self) -> TrialKind {
        self.kind
    }

    pub fn dof(&self) -> Dof {
        self.agent.dof()
    }

    pub fn agent(&self) -> &Agent {
        &self.agent
    }

    pub fn into_agent(self) -> Agent {
        self.agent
    }

    /// Everything needed to resume this behaviour.
    pub fn checkpoint(&self) -> AgentState {
        self.agent.checkpoint()
    }

    /// Answers one observation (call it once per step: the shell's `Once` sees to that).
    ///
    /// An observation of a new episode while the last one had not ended (the simulator was
    /// restarted, a terminal step was lost) aborts the old episode first: no transition may span a
    /// reset. That episode is reported with the steps seen of it ([`Output::cut`]); the abort is
    /// logged.
    pub fn step(&mut self, msg: &CableObservationMsg) -> Output {
        let status = msg.stamp.status();
        let mut cut_stats = None;
        if let Some((episode, false)) = self.last
            && episode != msg.stamp.episode
            && let Some(cut) = self.agent.abort_episode()
        {
            tracing::warn!(
                dof = %self.dof(),
                episode,
                next = msg.stamp.episode,
                seq = msg.stamp.seq,
                return_ = cut.return_,
                steps = cut.steps,
                "a new episode began before the last one ended: the last one is aborted, its pending step not learned, its steps so far reported"
            );
            cut_stats = self.last_stamp.map(|stamp| LearningStats {
                evaluation: self.kind.is_evaluation() as u8,
                ..learning_stats(stamp, &cut, &self.agent)
            });
        }
        let new_trial = self
            .last
            .is_none_or(|(e, ended)| ended || e != msg.stamp.episode);
        if new_trial {
            self.begin_trial(msg.stamp.episode);
        }
        self.last = Some((msg.stamp.episode, status.is_terminal()));
        self.last_stamp = Some(msg.stamp);
        let obs = msg.observation();
        if status == StepStatus::Running && obs.found {
            self.guard_envelope(&obs, msg.stamp.episode);
        }
        let evaluating = self.rewards.is_some() && self.kind.is_evaluation();
        if let Some(rewards) = self.rewards
            && evaluating
        {
            // The pair's cost, summed by both behaviours in the same order from the same numbers:
            // the last step's commands (the return's action term of that step), then this step's
            // observed states.
            if let Some((seq, own)) = self.previous.take() {
                let partner = match self.partner.iter().find(|(s, _)| *s == seq) {
                    Some(&(_, value)) => value,
                    None => {
                        self.partner_missing += 1;
                        0.0
                    }
                };
                let mut actions = PerDof::both(partner);
                *actions.get_mut(self.dof()) = own;
                self.add_to_evaluation_cost(action_costs(&rewards, actions));
            }
            if obs.found {
                let states = PerDof::from_fn(|dof| obs.state(dof));
                self.add_to_evaluation_cost(state_costs(&rewards, states));
            }
        }
        let predicted = match &mut self.prediction {
            Some(p) if !obs.found && status == StepStatus::Running => p.next(),
            _ => None,
        };
        let (action, episode) = match predicted {
            Some(x) => {
                // Acted on, not observed: nothing is learned from it, as from a frame held still.
                self.agent.skip();
                self.predicted += 1;
                (self.agent.mean_action(x), None)
            }
            None => behave(&mut self.agent, &obs, status),
        };
        if let Some(p) = &mut self.prediction {
            match predicted {
                Some(x) => p.acted(x, action, false),
                None if obs.found && status == StepStatus::Running => {
                    p.acted(obs.state(self.agent.dof()), action, true)
                }
                None => p.forget(),
            }
        }
        self.previous =
            (evaluating && status == StepStatus::Running).then_some((msg.stamp.seq, action));
        Output {
            command: DofCommand {
                stamp: msg.stamp,
                value: action,
            },
            stats: episode.map(|e| self.end_trial(msg.stamp, &e)),
            cut: cut_stats,
        }
    }

    /// Step two, a learning trial: when the DOF's observed position leaves the safety envelope
    /// ([`SAFETY_ENVELOPE`] of its observation box), the learned policy is heading for losing the cable:
    /// the best policy, if one was evaluated, is restored at once and the trial goes on with it,
    /// without learning.
    fn guard_envelope(&mut self, obs: &CableObservation, trial: u32) {
        let learning = self.step_two.as_ref().is_some_and(|s| s.learning);
        if !learning || self.left_envelope || self.kind.is_evaluation() {
            return;
        }
        let x = obs.state(self.dof())[0];
        let edge = SAFETY_ENVELOPE * self.agent.state_max()[0];
        if x.abs() <= edge {
            return;
        }
        if self.fall_back(trial, "the position left the safety envelope") {
            self.agent.set_learning(false);
        }
        // Once per trial: with nothing to restore, the trial goes on learning, and the next steps
        // outside the envelope would say the same again.
        self.left_envelope = true;
    }

    /// Step two: adds one step's share `step` to the pair's cost of the evaluation in progress.
    fn add_to_evaluation_cost(&mut self, step: PerDof<f64>) {
        let sum = &mut self.agent.safety_mut().evaluation_cost;
        sum.sway += step.sway;
        sum.yaw += step.yaw;
    }

    /// Step two: sets the agent up for trial `trial` (learning or not, its exploration noise).
    fn begin_trial(&mut self, trial: u32) {
        self.left_envelope = false;
        self.previous = None;
        if let Some(p) = &mut self.prediction {
            p.forget();
        }
        self.predicted = 0;
        let Some(s) = &self.step_two else { return };
        self.kind = s.kind(trial);
        let seed = s.noise_seed(trial, self.kind);
        let learning = s.learning && !self.kind.is_evaluation();
        if self.kind == (TrialKind::Evaluation { slot: 0 }) {
            // A new evaluation: whatever an earlier, unfinished one summed is not part of it.
            self.partner_missing = 0;
            let safety = self.agent.safety_mut();
            (
                safety.evaluation_sum,
                safety.evaluation_trials,
                safety.evaluation_lost,
                safety.evaluation_cost,
            ) = (0.0, 0, 0, PerDof::default());
        }
        self.agent.set_learning(learning);
        self.agent.reseed(seed);
    }

    /// The statistics of a finished trial; step two: an evaluation trial counts towards its
    /// evaluation, and the last one has it judged (and maybe the best policy restored). A trial
    /// that lost the cable ends the policy under which it was lost: the best one is restored at
    /// once ([`Behaviour::fall_back`]).
    fn end_trial(&mut self, stamp: Stamp, episode: &EpisodeSummary) -> LearningStats {
        if self.predicted > 0 {
            tracing::debug!(dof = %self.dof(), trial = stamp.episode, frames = self.predicted, failed = episode.failed, "missed frames acted on the identified model's prediction");
        }
        let learning_step_two = self.step_two.as_ref().is_some_and(|s| s.learning);
        if episode.failed && learning_step_two {
            self.fall_back(stamp.episode, "the cable was lost");
        }
        let TrialKind::Evaluation { slot } = self.kind else {
            if learning_step_two && !episode.failed && !self.left_envelope {
                self.adapt_trust_region(stamp.episode, true);
            }
            return learning_stats(stamp, episode, &self.agent);
        };
        let s = self.step_two.as_ref().expect("evaluations are step two's");
        let (closes, judge, wanted) = (s.closes(slot), s.keep_best, s.evaluation.trials);
        let safety = self.agent.safety_mut();
        safety.evaluation_sum += episode.return_;
        safety.evaluation_trials += 1;
        safety.evaluation_lost += episode.failed as u32;
        let (mut evaluated, mut rolled_back) = (f64::NAN, false);
        if closes {
            let (sum, n, cost) = (
                safety.evaluation_sum,
                safety.evaluation_trials,
                safety.evaluation_cost,
            );
            if n == wanted {
                evaluated = sum / n as f64;
                let e = Evaluated {
                    trial: stamp.episode,
                    gain: self.agent.gain(),
                    evaluated,
                    cost: PerDof {
                        sway: cost.sway / n as f64,
                        yaw: cost.yaw / n as f64,
                    },
                };
                rolled_back = self.judge(judge, &e);
                let scale = self.agent.safety().scale;
                self.judged = Some((e.trial, learning::pair_score(e.cost, scale)));
            }
            let safety = self.agent.safety_mut();
            (
                safety.evaluation_sum,
                safety.evaluation_trials,
                safety.evaluation_lost,
                safety.evaluation_cost,
            ) = (0.0, 0, 0, PerDof::default());
            let missing = std::mem::take(&mut self.partner_missing);
            if missing > 0 && n == wanted {
                tracing::warn!(
                    dof = %self.dof(),
                    trial = stamp.episode,
                    steps = missing,
                    "the partner's commands of some steps of this evaluation were not there: their action cost is taken as 0 (the partner's verdict may differ)"
                );
            }
            if n != wanted {
                tracing::warn!(
                    dof = %self.dof(),
                    trial = stamp.episode,
                    trials = n,
                    wanted,
                    "an evaluation missed some of its trials: not judged"
                );
            }
        }
        let mut stats = learning_stats(stamp, episode, &self.agent);
        stats.evaluation = 1;
        stats.rolled_back = rolled_back as u8;
        stats.evaluated = evaluated;
        stats
    }

    /// Step two: the trust region's bound after trial `trial`: doubled when it was a learning trial
    /// that kept the cable within the envelope (`kept`), halved when the cable was lost or the
    /// envelope left. An evaluation's verdict leaves it: with images most pairs not taken are within
    /// the evaluation's noise of the best, and halving on them kept the bound too small for yaw to
    /// follow sway (the harsh-cross twin's yaw closed 31% of its gap instead of 58%).
    fn adapt_trust_region(&mut self, trial: u32, kept: bool) {
        let before = self.agent.safety().action_change_bound;
        self.agent.adapt_trust_region(kept);
        let after = self.agent.safety().action_change_bound;
        if after != before {
            tracing::debug!(dof = %self.dof(), trial, kept, from = before, to = after, "the trust region's bound adapted");
        }
    }

    /// Judges the pair evaluated in `e`; returns whether the best pair's policy was restored.
    fn judge(&mut self, judge: learning::KeepBest, e: &Evaluated) -> bool {
        let (gain, evaluated, trial, cost) = (e.gain, e.evaluated, e.trial, e.cost);
        match judge.judge(self.agent.safety_mut(), e) {
            Verdict::Best => {
                tracing::info!(dof = %self.dof(), trial, ?gain, evaluated, ?cost, "evaluation: the best pair so far");
                false
            }
            Verdict::Kept { best, costlier } => {
                let why = match costlier {
                    None => "is not better than the best, within the tolerance".to_string(),
                    Some(dof) => format!(
                        "costs {dof} more than the simulation policies did, within the tolerance; it stays in force but is not the best"
                    ),
                };
                tracing::info!(
                    dof = %self.dof(),
                    trial,
                    ?gain,
                    evaluated,
                    ?cost,
                    best = best.evaluated,
                    best_trial = best.trial,
                    "evaluation: the pair {why}"
                );
                false
            }
            Verdict::RollBack { best } => {
                tracing::warn!(
                    dof = %self.dof(),
                    trial,
                    ?gain,
                    evaluated,
                    ?cost,
                    best = best.evaluated,
                    best_gain = ?best.gain,
                    best_trial = best.trial,
                    "evaluation: the pair is worse than the best pair beyond the tolerance; the best pair's policy is restored"
                );
                self.restore_best(Some(best))
            }
            Verdict::WorseThanStart { dof, restore } => {
                tracing::warn!(
                    dof = %self.dof(),
                    trial,
                    ?gain,
                    evaluated,
                    ?cost,
                    worse = %dof,
                    restored = restore.map(|b| b.trial),
                    "evaluation: the pair costs {dof} more than the simulation policies did, beyond the tolerance; not a candidate for the best (the best pair's policy restored where rollback is on)"
                );
                self.restore_best(restore)
            }
            Verdict::Failed { restore } => {
                let safety = self.agent.safety();
                let (lost, start_lost) = (safety.evaluation_lost, safety.start_lost);
                tracing::warn!(
                    dof = %self.dof(),
                    trial,
                    ?gain,
                    evaluated,
                    lost,
                    start_lost,
                    restored = restore.map(|b| b.trial),
                    "evaluation: the cable was lost; the policy is not a candidate for the best (the best pair's policy restored, or before one, the simulation policies' where they lost fewer trials)"
                );
                self.restore_best(restore)
            }
        }
    }

    /// Restores `best`'s policy, if there is one to restore; whether it did.
    fn restore_best(&mut self, best: Option<learning::BestPolicy>) -> bool {
        best.map(|b| self.agent.restore(b.gain)).is_some()
    }

    /// The policy in force failed (`cause`: the cable was lost, or the position left the safety
    /// envelope): the best policy evaluated so far is restored at once, its critic statistics
    /// dropped; with none evaluated yet, or rollback off, the policy stays. Returns whether it was
    /// restored.
    fn fall_back(&mut self, trial: u32, cause: &'static str) -> bool {
        self.adapt_trust_region(trial, false);
        let Some(s) = &self.step_two else {
            return false;
        };
        let judge = s.keep_best;
        let gain = self.agent.gain();
        match judge.fall_back(self.agent.safety_mut()) {
            Some(best) => {
                tracing::warn!(
                    dof = %self.dof(),
                    trial,
                    ?gain,
                    best_gain = ?best.gain,
                    best = best.evaluated,
                    cause,
                    "the best policy is restored"
                );
                self.agent.restore(best.gain);
                true
            }
            None => {
                tracing::warn!(
                    dof = %self.dof(),
                    trial,
                    ?gain,
                    cause,
                    "no policy has been evaluated to fall back to (or rollback is off)"
                );
                false
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use messages::CableObservationData;

    fn params() -> (Scenario, LearningParams) {
        let mut learning = LearningParams::default();
        learning.policy.initial_gain.sway = [-1.2, -0.3];
        learning.policy.initial_gain.yaw = [-0.8, -0.2];
        (Scenario::default(), learning)
    }

    fn obs(
        seq: u64,
        episode: u32,
        step: u32,
        status: StepStatus,
        found: bool,
    ) -> CableObservationMsg {
        let t = seq as f64;
        CableObservationMsg {
            stamp: Stamp::new(seq, seq * 200_000_000, episode, step, status),
            observation: CableObservationData {
                found: found as u8,
                x_g: 0.3 * (0.4 * t).sin(),
                x_g_rate: 0.2 * (0.4 * t).cos(),
                theta: 0.6 * (0.3 * t).cos(),
                theta_rate: -0.3 * (0.3 * t).sin(),
                ..Default::default()
            },
        }
    }

    /// A run through a skipped frame, a time limit, a reset and a lost cable.
    fn run() -> Vec<CableObservationMsg> {
        let mut v = Vec::new();
        let mut seq = 0;
        for (episode, len, end) in [(0, 12, StepStatus::TimeLimit), (1, 7, StepStatus::Lost)] {
            for step in 0..=len {
                let status = if step == len {
                    end
                } else {
                    StepStatus::Running
                };
                v.push(obs(seq, episode, step, status, step != 4));
                seq += 1;
            }
        }
        v
    }

    /// Step two with one evaluation trial and one learning trial in turn, a learner whose every step
    /// moves the gain, and the default safety layer.
    fn step_two_sway() -> Behaviour {
        step_two_sway_with(|_| {})
    }

    /// [`step_two_sway`] with its learning parameters changed by `edit`.
    fn step_two_sway_with(edit: impl FnOnce(&mut LearningParams)) -> Behaviour {
        let (scenario, mut learning) = params();
        learning.evaluation = config::EvaluationParams {
            trials: 1,
            learning_trials: 1,
        };
        learning.gpomdp.alpha.sway = 1.0;
        learning.safety.stability.enabled = false;
        edit(&mut learning);
        let agent = new_agent(Dof::Sway, Algorithm::Gpomdp, &scenario, &learning, 5);
        let step_two = StepTwo::new(&learning, true, 5, 6);
        Behaviour::for_step_two(agent, step_two, &scenario).unwrap()
    }

    /// Trial `episode` of `len` steps ending with `end`, its observations' x_g given by `x_g`: its
    /// statistics, if it ended, and the gain and whether the agent learns before the trial and
    /// after each of its observations.
    fn trial_steps(
        b: &mut Behaviour,
        seq: &mut u64,
        episode: u32,
        len: u32,
        end: StepStatus,
        x_g: impl Fn(u32) -> f64,
    ) -> (Option<LearningStats>, Vec<([f64; 2], bool)>) {
        let mut stats = None;
        let mut seen = vec![(b.agent().gain(), b.agent().is_learning())];
        for step in 0..=len {
            let status = if step == len {
                end
            } else {
                StepStatus::Running
            };
            let mut o = obs(*seq, episode, step, status, true);
            o.observation.x_g = x_g(step);
            *seq += 1;
            stats = b.step(&o).stats.or(stats);
            seen.push((b.agent().gain(), b.agent().is_learning()));
        }
        (stats, seen)
    }

    /// [`trial_steps`]'s trial: its statistics, and the gain before its last observation.
    fn trial(
        b: &mut Behaviour,
        seq: &mut u64,
        episode: u32,
        len: u32,
        end: StepStatus,
        x_g: impl Fn(u32) -> f64,
    ) -> (LearningStats, [f64; 2]) {
        let (stats, seen) = trial_steps(b, seq, episode, len, end, x_g);
        (stats.expect("the trial ended"), seen[seen.len() - 2].0)
    }

    /// With `[missed_frames] predict = 2`, a missed frame is answered with the policy's mean action
    /// at the state the identified model predicts from the last state acted on and the command
    /// given there, two in a row at most, then held still; an observation starts the count again.
    /// Nothing is learned from a predicted frame: the learning trial ends with the gain, return and
    /// steps of the same trial with its missed frames held still.
    #[test]
    fn a_missed_frame_is_acted_on_from_the_identified_models_prediction() {
        let (mut scenario, mut learning) = params();
        learning.evaluation = config::EvaluationParams {
            trials: 1,
            learning_trials: 1,
        };
        learning.gpomdp.alpha.sway = 1.0;
        learning.safety.stability.enabled = false;
        let build = |scenario: &Scenario| {
            let agent = new_agent(Dof::Sway, Algorithm::Gpomdp, scenario, &learning, 5);
            Behaviour::for_step_two(agent, StepTwo::new(&learning, true, 5, 6), scenario).unwrap()
        };
        let held = build(&scenario);
        scenario.missed_frames.predict = 2;
        let model = identified_model(&scenario, Dof::Sway).unwrap();
        let predicting = build(&scenario);
        // Trial 0 is an evaluation, trial 1 a learning trial; steps 3 to 5 and 8 are missed.
        let missed = |step: u32| (3..=5).contains(&step) || step == 8;
        // Each step's observation (as if found), command, and the gain in force after it.
        let run = |mut b: Behaviour| {
            let (mut steps, mut stats) = (Vec::new(), Vec::new());
            let mut seq = 0;
            for episode in 0..2 {
                for step in 0..=10 {
                    let status = if step == 10 {
                        StepStatus::TimeLimit
                    } else {
                        StepStatus::Running
                    };
                    let out = b.step(&obs(seq, episode, step, status, !missed(step)));
                    let seen = obs(seq, episode, step, status, true).observation();
                    steps.push((seen.state(Dof::Sway), out.command.value, b.agent().gain()));
                    stats.extend(out.stats);
                    seq += 1;
                }
            }
            (b, steps, stats)
        };
        let (held, held_steps, held_stats) = run(held);
        let (predicting, steps, stats) = run(predicting);
        // The policy's mean action at `x` under the gain in force after step `before`.
        let mean = |s: &[([f64; 2], f64, [f64; 2])], before: usize, x: [f64; 2]| {
            let g = s[before].2;
            (g[0] * x[0] + g[1] * x[1]).clamp(-1.0, 1.0)
        };
        let close = |a: f64, b: f64| (a - b).abs() < 1e-12;
        for trial in 0..2 {
            let s = &steps[trial * 11..(trial + 1) * 11];
            let x3 = model.next(s[2].0, [s[2].1]);
            let x4 = model.next(x3, [s[3].1]);
            assert!(close(s[3].1, mean(s, 2, x3)), "trial {trial}: {s:?}");
            assert!(close(s[4].1, mean(s, 3, x4)), "trial {trial}: {s:?}");
            assert!(s[3].1 != 0.0 && s[4].1 != 0.0);
            assert_eq!(
                s[5].1, 0.0,
                "trial {trial}: a third missed frame in a row is held still"
            );
            let x8 = model.next(s[7].0, [s[7].1]);
            assert!(
                close(s[8].1, mean(s, 7, x8)),
                "trial {trial}: counted again"
            );
            let h = &held_steps[trial * 11..(trial + 1) * 11];
            assert!((0..11).filter(|&k| missed(k as u32)).all(|k| h[k].1 == 0.0));
        }
        assert_eq!(predicting.agent().gain(), held.agent().gain());
        assert_ne!(predicting.agent().gain(), learning.policy.initial_gain.sway);
        let summary = |s: &[LearningStats]| -> Vec<(f64, u32)> {
            s.iter().map(|s| (s.episode_return, s.steps)).collect()
        };
        assert_eq!(summary(&stats), summary(&held_stats));
        assert_eq!(stats.len(), 2);
    }

    /// A learning trial that loses the cable ends its policy: the best one is restored before the
    /// next trial, counted as a rollback; an evaluation that loses it is never the best.
    #[test]
    fn a_lost_cable_restores_the_best_policy_at_once() {
        let mut b = step_two_sway();
        let mut seq = 0;
        let calm = |t: u32| 0.1 * (0.4 * t as f64).sin();
        // A long evaluation off the cable: costly, but the cable kept.
        let (first, _) = trial(&mut b, &mut seq, 0, 200, StepStatus::TimeLimit, |_| 0.3);
        let best = b
            .agent()
            .safety()
            .best
            .expect("the first evaluation is the best");
        assert_eq!((first.evaluation, best.gain), (1, b.agent().gain()));
        let (lost, learned) = trial(&mut b, &mut seq, 1, 20, StepStatus::Lost, calm);
        assert_ne!(learned, best.gain, "the learning trial moved the gain");
        assert_eq!((lost.gain, b.agent().gain()), (best.gain, best.gain));
        assert_eq!(b.agent().safety().rollbacks, 1);
        // An evaluation that loses the cable: a failure whatever its return, the best stays.
        let (failed, _) = trial(&mut b, &mut seq, 2, 3, StepStatus::Lost, calm);
        assert!(
            failed.evaluated > best.evaluated,
            "a short trial costs less"
        );
        assert_eq!(b.agent().safety().best, Some(best));
        assert_eq!(b.agent().gain(), best.gain);
    }

    /// In a learning trial, the position leaving the safety envelope (80% of the observation box)
    /// restores the best policy at once; the trial goes on with it, learning nothing more.
    #[test]
    fn leaving_the_safety_envelope_restores_the_best_policy_mid_trial() {
        let mut b = step_two_sway();
        let mut seq = 0;
        let calm = |t: u32| 0.1 * (0.4 * t as f64).sin();
        trial(&mut b, &mut seq, 0, 20, StepStatus::TimeLimit, calm);
        let best = b.agent().safety().best.unwrap();
        // Calm for 15 steps (learning moves the gain), then out to 0.45 > 0.8 x 0.5.
        let wide = |t: u32| if t < 15 { calm(t) } else { 0.45 };
        let (_, steps) = trial_steps(&mut b, &mut seq, 1, 20, StepStatus::TimeLimit, wide);
        // After each observation.
        let seen = &steps[1..];
        assert_ne!(seen[14].0, best.gain, "learning moved the gain");
        assert!(seen[14].1);
        for (gain, learning) in &seen[15..] {
            assert_eq!((*gain, *learning), (best.gain, false));
        }
        assert_eq!(b.agent().safety().rollbacks, 1);
        // The next learning trial learns again.
        trial(&mut b, &mut seq, 2, 5, StepStatus::TimeLimit, calm);
        trial(&mut b, &mut seq, 3, 5, StepStatus::TimeLimit, calm);
        assert!(b.agent().is_learning());
    }

    /// The trust region's bound starts at its smallest and adapts to how learning trials fare: a
    /// trial that kept the cable within the envelope doubles it, a lost cable halves it. Every
    /// actor update of the first learning trial stays within the smallest bound.
    #[test]
    fn the_trust_regions_bound_grows_with_trials_that_keep_the_cable_and_shrinks_on_a_loss() {
        let mut b = step_two_sway_with(|l| {
            l.evaluation.learning_trials = 3;
            l.safety.trust_region.min_action_change = 0.05;
            l.safety.trust_region.max_action_change = 0.5;
        });
        let region = b.agent().guard().trust_region.expect("a trust region");
        let bound = |b: &Behaviour| region.in_force(b.agent().safety().action_change_bound);
        assert_eq!(bound(&b), 0.05);
        let calm = |t: u32| 0.1 * (0.4 * t as f64).sin();
        let mut seq = 0;
        trial(&mut b, &mut seq, 0, 20, StepStatus::TimeLimit, calm);
        assert_eq!(bound(&b), 0.05, "an evaluation taken leaves it");
        // The first learning trial, step by step: no update moves the mean action more than 0.05.
        let (_, steps) = trial_steps(&mut b, &mut seq, 1, 20, StepStatus::TimeLimit, calm);
        let largest = steps
            .windows(2)
            .map(|w| region.action_change([w[1].0[0] - w[0].0[0], w[1].0[1] - w[0].0[1]]))
            .fold(0.0, f64::max);
        assert!(
            b.agent().safety().bounded > 0,
            "the learner asked for longer steps"
        );
        assert!(
            largest <= 0.05 + 1e-12,
            "a step moved the mean action by {largest}"
        );
        assert_eq!(bound(&b), 0.1);
        trial(&mut b, &mut seq, 2, 20, StepStatus::TimeLimit, calm);
        assert_eq!(bound(&b), 0.2);
        trial(&mut b, &mut seq, 3, 20, StepStatus::Lost, calm);
        assert_eq!(bound(&b), 0.1);
        // The bound is the agent's: a checkpoint keeps it.
        let resumed = learning::Agent::from_state(b.agent().checkpoint(), 7).unwrap();
        assert_eq!(region.in_force(resumed.safety().action_change_bound), 0.1);
    }

    /// Step two learns with its own eligibility rate: a NAC agent of step one's `nac.lambda` takes
    /// `step_two.lambda` when it becomes a step-two behaviour, and keeps it through a checkpoint.
    #[test]
    fn step_two_learns_with_its_own_eligibility_rate() {
        let (scenario, mut learning) = params();
        learning.nac.lambda = 0.8;
        learning.step_two.lambda = 0.95;
        let lambda = |b: &Behaviour| match b.agent().learner() {
            learning::Learner::Nac(n) => n.config().lambda,
            learning::Learner::Gpomdp(_) => unreachable!(),
        };
        let agent = new_agent(Dof::Yaw, Algorithm::Nac, &scenario, &learning, 5);
        let step_one = Behaviour::new(agent.clone());
        assert_eq!(lambda(&step_one), 0.8);
        let b =
            Behaviour::for_step_two(agent, StepTwo::new(&learning, true, 5, 6), &scenario).unwrap();
        assert_eq!(lambda(&b), 0.95);
        let resumed = learning::Agent::from_state(b.agent().checkpoint(), 7).unwrap();
        let b = Behaviour::for_step_two(resumed, StepTwo::new(&learning, true, 5, 6), &scenario)
            .unwrap();
        assert_eq!(lambda(&b), 0.95);
    }

    /// With no policy evaluated to restore (the first evaluation lost the cable), leaving the
    /// envelope changes nothing: the trial goes on learning, however long the state stays outside.
    #[test]
    fn leaving_the_envelope_with_nothing_to_restore_goes_on_learning() {
        let mut b = step_two_sway();
        let mut seq = 0;
        let calm = |t: u32| 0.1 * (0.4 * t as f64).sin();
        trial(&mut b, &mut seq, 0, 20, StepStatus::Lost, calm);
        assert_eq!(b.agent().safety().best, None);
        let mut gains = Vec::new();
        for step in 0..20 {
            let mut o = obs(seq, 1, step, StepStatus::Running, true);
            o.observation.x_g = if step < 5 {
                calm(step)
            } else {
                0.45 + 0.01 * step as f64
            };
            seq += 1;
            b.step(&o);
            assert!(b.agent().is_learning(), "step {step}");
            gains.push(b.agent().gain());
        }
        assert_ne!(gains[6], gains[19], "learning went on outside the envelope");
        assert_eq!(b.agent().safety().rollbacks, 0);
    }

    /// Step two for `dof` with one evaluation trial and one learning trial in turn, gains moving at
    /// every step, the default rollback.
    fn step_two_of(dof: Dof) -> Behaviour {
        let (scenario, mut learning) = params();
        learning.evaluation = config::EvaluationParams {
            trials: 1,
            learning_trials: 1,
        };
        learning.gpomdp.alpha = PerDof::both(1.0);
        learning.safety.stability.enabled = false;
        let agent = new_agent(dof, Algorithm::Gpomdp, &scenario, &learning, 5);
        Behaviour::for_step_two(agent, StepTwo::new(&learning, true, 5, 6), &scenario).unwrap()
    }

    /// Trial `episode`: 30 steps of a cable off by `a` in x_g and `b` in Theta.
    fn offset_trial(episode: u32, seq: &mut u64, (a, b): (f64, f64)) -> Vec<CableObservationMsg> {
        (0..=30)
            .map(|step| {
                let status = if step == 30 {
                    StepStatus::TimeLimit
                } else {
                    StepStatus::Running
                };
                let mut o = obs(*seq, episode, step, status, step != 7);
                let t = step as f64;
                o.observation.x_g = a * (0.4 * t).cos();
                o.observation.theta = b * (0.3 * t).sin();
                *seq += 1;
                o
            })
            .collect()
    }

    /// The sway and yaw behaviours, each with its own returns and gains, judge the pair on the same
    /// observations: after every evaluation both keep the same evaluation as the best, and restore
    /// its policies together. A behaviour restarted from its checkpoint between trials goes on as
    /// if it had not stopped.
    #[test]
    fn both_behaviours_keep_the_pair_of_one_evaluation_through_a_restart() {
        let (scenario, _) = params();
        let (mut sway, mut yaw, mut yaw_restarted) = (
            step_two_of(Dof::Sway),
            step_two_of(Dof::Yaw),
            step_two_of(Dof::Yaw),
        );
        // Evaluations (even trials) of varying pair costs; learning trials in between. Trial 4
        // costs sway more than the start (restored whatever the score); trial 8 is within the start
        // in both DOFs but worse than the best beyond the tolerance (restored).
        let offsets = [
            (0.2, 0.3),
            (0.1, 0.1),
            (0.1, 0.29),
            (0.2, 0.2),
            (0.3, 0.4),
            (0.1, 0.1),
            (0.05, 0.25),
            (0.1, 0.1),
            (0.15, 0.28),
        ];
        let (mut seq, mut bests, mut verdicts) = (0, Vec::new(), Vec::new());
        for (trial, &offset) in offsets.iter().enumerate() {
            if trial == 4 {
                // The restart: the checkpoint, then a new behaviour resumed from it.
                let state = yaw_restarted.checkpoint();
                let agent = Agent::from_state(state, 5).unwrap();
                let (_, mut learning) = params();
                learning.evaluation = config::EvaluationParams {
                    trials: 1,
                    learning_trials: 1,
                };
                let s = StepTwo::new(&learning, true, 5, 6);
                yaw_restarted = Behaviour::for_step_two(agent, s, &scenario).unwrap();
            }
            let mut closed = None;
            for m in offset_trial(trial as u32, &mut seq, offset) {
                let (s, y) = (sway.step(&m), yaw.step(&m));
                yaw_restarted.step(&m);
                sway.partner_command(&y.command);
                yaw.partner_command(&s.command);
                yaw_restarted.partner_command(&s.command);
                closed = closed.or(s.stats.zip(y.stats));
            }
            let (s, y) = closed.expect("the trial ended");
            if trial % 2 == 0 {
                let (bs, by) = (sway.agent().safety().best, yaw.agent().safety().best);
                let (bs, by) = (bs.unwrap(), by.unwrap());
                assert_eq!(bs.trial, by.trial, "trial {trial}");
                assert_eq!(bs.cost, by.cost);
                assert_ne!(bs.evaluated, by.evaluated, "each has its own return");
                assert_eq!(s.rolled_back, y.rolled_back);
                let score = sway.pair_score(trial as u32).unwrap();
                assert_eq!(
                    score.to_bits(),
                    yaw.pair_score(trial as u32).unwrap().to_bits()
                );
                if y.rolled_back == 1 {
                    assert_eq!(
                        (sway.agent().gain(), yaw.agent().gain()),
                        (bs.gain, by.gain)
                    );
                }
                bests.push(bs.trial);
                verdicts.push(y.rolled_back);
            }
            assert_eq!(
                yaw_restarted.checkpoint(),
                yaw.checkpoint(),
                "trial {trial}"
            );
        }
        // The pair's costs made new bests and rollbacks both.
        assert_eq!(bests, vec![0, 2, 2, 6, 6]);
        assert_eq!(verdicts, vec![0, 0, 1, 0, 1]);
        assert_ne!(sway.agent().safety().scale, PerDof::default());
    }

    /// The pair's cost of an evaluation is each DOF's return's cost: the observed states' `x'Qx`
    /// and the commands' `r u^2`, this behaviour's own and its partner's as they came in. A
    /// partner's command that never came counts as 0 (the allocator applies none).
    #[test]
    fn the_pair_cost_counts_both_dofs_commands() {
        let (scenario, _) = params();
        let rewards = scenario.reward;
        let mut b = step_two_of(Dof::Sway);
        let mut seq = 0;
        let trial = offset_trial(0, &mut seq, (0.2, 0.3));
        let partner = |seq: u64| 0.1 + 0.01 * seq as f64;
        let mut expected = PerDof::<f64>::default();
        for (i, m) in trial.iter().enumerate() {
            let o = m.observation();
            if o.found {
                let (x, th) = (o.state(Dof::Sway), o.state(Dof::Yaw));
                let (qs, qy) = (rewards.sway.q, rewards.yaw.q);
                expected.sway += qs[0] * x[0] * x[0] + qs[1] * x[1] * x[1];
                expected.yaw += qy[0] * th[0] * th[0] + qy[1] * th[1] * th[1];
            }
            let own = b.step(m).command.value;
            // Step 12's yaw command is lost on the way.
            if i != 12 {
                b.partner_command(&DofCommand {
                    stamp: m.stamp,
                    value: partner(m.stamp.seq),
                });
            }
            if m.stamp.status() == StepStatus::Running {
                expected.sway += rewards.sway.r * own * own;
                if i != 12 {
                    expected.yaw += rewards.yaw.r * partner(m.stamp.seq).powi(2);
                }
            }
        }
        let best = b
            .agent()
            .safety()
            .best
            .expect("the first evaluation is the best");
        assert_eq!(best.trial, 0);
        for dof in Dof::ALL {
            let (got, want) = (best.cost.get(dof), expected.get(dof));
            assert!(
                (got - want).abs() < 1e-12 * want,
                "{dof}: {got} against {want}"
            );
        }
        // The partner's commands weigh far beyond the comparison's tolerance: leaving them out fails.
        let actions = rewards.yaw.r * (0..30).map(|s| partner(s).powi(2)).sum::<f64>();
        assert!(
            actions > 1e-6 * expected.yaw,
            "{actions} of {}",
            expected.yaw
        );
    }

    #[test]
    fn the_behaviour_is_the_trainers_rule_for_either_dof() {
        let (scenario, learning) = params();
        for dof in Dof::ALL {
            let seed = config::derive_seed(9, dof.name());
            let mut b = Behaviour::new(new_agent(dof, Algorithm::Nac, &scenario, &learning, seed));
            // The reference, built from the learning crate alone: the trainer's construction.
            let mut a = Agent::new(
                dof,
                Algorithm::Nac,
                &learning,
                *scenario.reward.of(dof),
                scenario.state_max(dof),
                seed,
            );
            let mut episodes = 0;
            for m in run() {
                let out = b.step(&m);
                let o = m.observation();
                let status = m.stamp.status();
                let (action, episode) = if !o.found && status == StepStatus::Running {
                    (a.skip(), None)
                } else {
                    let s = a.step(o.state(dof), status);
                    (s.action, s.episode)
                };
                assert_eq!(
                    out.command.value.to_bits(),
                    action.to_bits(),
                    "{dof} seq {}",
                    m.stamp.seq
                );
                assert_eq!(out.command.stamp, m.stamp);
                match (out.stats, episode) {
                    (Some(s), Some(e)) => {
                        episodes += 1;
                        assert_eq!(s.episode_return.to_bits(), e.return_.to_bits());
                        assert_eq!(
                            (s.gain, s.steps, s.actor_updates),
                            (e.gain, e.steps, e.actor_updates)
                        );
                        assert_eq!((s.failed, s.learning), (e.failed as u8, 1));
                        assert_eq!(s.stamp, m.stamp);
                    }
                    (None, None) => {}
                    other => panic!("stats and episode disagree: {other:?}"),
                }
            }
            assert_eq!(episodes, 2);
            assert_eq!(b.checkpoint(), a.checkpoint());
        }
    }

    #[test]
    fn a_missed_frame_holds_still_and_the_yaw_state_is_theta() {
        let (scenario, learning) = params();
        let mut b = Behaviour::new(new_agent(Dof::Yaw, Algorithm::Nac, &scenario, &learning, 1));
        let first = b.step(&obs(0, 0, 0, StepStatus::Running, true));
        assert!(first.command.value != 0.0);
        let missed = b.step(&obs(1, 0, 1, StepStatus::Running, false));
        assert_eq!(missed.command.value, 0.0);
        assert!(missed.stats.is_none());
        // The skipped step still counts in the episode (its action was applied).
        assert_eq!(b.agent().steps(), 1);
    }

    #[test]
    fn a_new_episode_without_an_end_aborts_the_old_one() {
        let (scenario, learning) = params();
        let mut b = Behaviour::new(new_agent(
            Dof::Sway,
            Algorithm::Nac,
            &scenario,
            &learning,
            1,
        ));
        b.step(&obs(0, 3, 0, StepStatus::Running, true));
        b.step(&obs(1, 3, 1, StepStatus::Running, true));
        // Episode 4 starts with no terminal step of episode 3: the pending step is dropped, and
        // episode 3 is reported with what was seen of it, stamped with its last step.
        let out = b.step(&obs(2, 4, 0, StepStatus::Running, true));
        assert!(out.stats.is_none());
        let cut = out.cut.expect("the cut episode is reported");
        assert_eq!((cut.stamp.episode, cut.stamp.seq), (3, 1));
        assert_eq!((cut.steps, cut.failed, cut.evaluation), (1, 0, 0));
        assert!(cut.episode_return.is_finite() && cut.episode_return <= 0.0);
        assert_eq!((b.agent().episodes(), b.agent().steps()), (1, 1));
        // After a proper end, the next episode is no abort.
        let end = b.step(&obs(3, 4, 1, StepStatus::Lost, true));
        assert_eq!(end.stats.map(|s| (s.steps, s.failed)), Some((1, 1)));
        assert!(end.cut.is_none());
        assert!(
            b.step(&obs(4, 5, 0, StepStatus::Running, true))
                .cut
                .is_none()
        );
        assert_eq!(b.agent().episodes(), 2);
    }

    #[test]
    fn acting_only_reports_episodes_without_learning() {
        let (scenario, learning) = params();
        let mut agent = new_agent(Dof::Sway, Algorithm::Nac, &scenario, &learning, 1);
        agent.set_learning(false);
        let mut b = Behaviour::new(agent);
        let stats: Vec<_> = run().iter().filter_map(|m| b.step(m).stats).collect();
        assert_eq!(stats.len(), 2);
        assert!(
            stats
                .iter()
                .all(|s| s.learning == 0 && s.gain == [-1.2, -0.3])
        );
    }

    #[test]
    fn a_resumed_agent_draws_new_noise() {
        let (scenario, learning) = params();
        let mut a = new_agent(Dof::Sway, Algorithm::Nac, &scenario, &learning, 5);
        assert_eq!(resume_seed(5, &a.checkpoint()), 5);
        a.step([0.1, 0.0], StepStatus::Running);
        a.step([0.1, 0.0], StepStatus::Running);
        let s = a.checkpoint();
        assert_ne!(resume_seed(5, &s), 5);
        assert_eq!(resume_seed(5, &s), resume_seed(5, &s.clone()));
    }
}
