//! The twin's plant: the identified model with what it leaves out put back (DESIGN.md, "The reality
//! gap"): quadratic damping, thrusters with a dead band, a forward/reverse asymmetry and a
//! first-order lag, and a water current. Each effect is switched by `config/twin.toml`; with all of
//! them off the plant is the simulator's model exactly.
//!
//! A setpoint becomes thrust in this order: made safe (clipped to [-1, 1], NaN to 0), the dead band
//! (a smaller magnitude gives no thrust), the asymmetry (reverse thrust scaled by `reverse_gain`),
//! the gain (thrust per unit of setpoint against the identified model's), then the lag (the thrust
//! follows that target with the time constant). The layout turns the
//! thrusts into the model's normalised forces; the body velocities are relative to the water, so
//! the current adds to the pose's drift.

use config::{ModelParams, Scenario, TwinParams};
use model::{Dynamics, PoseRate, ThrusterLayout, VehicleState};

/// What a thruster does with its setpoint.
#[derive(Clone, Debug, PartialEq)]
pub struct ThrusterModel {
    /// Time constant of the lag (s), if lagging.
    lag_s: Option<f64>,
    /// Setpoints below this magnitude give no thrust.
    dead_band: f64,
    /// Reverse thrust per unit of reverse setpoint.
    reverse_gain: f64,
    /// Thrust per unit of setpoint against the identified model's.
    gain: f64,
    /// Each thruster's thrust now (in the identified model's units: 1 is what the model takes for
    /// full forward thrust).
    thrust: Vec<f64>,
}

impl ThrusterModel {
    pub fn new(twin: &TwinParams, thrusters: usize) -> Self {
        let t = &twin.thrusters;
        ThrusterModel {
            lag_s: t.lag.enabled.then_some(t.lag.time_constant_s),
            dead_band: if t.dead_band.enabled {
                t.dead_band.setpoint
            } else {
                0.0
            },
            reverse_gain: if t.asymmetry.enabled {
                t.asymmetry.reverse_gain
            } else {
                1.0
            },
            gain: t.gain.factor(),
            thrust: vec![0.0; thrusters],
        }
    }

    /// The thrust a setpoint asks for, once settled: dead band, asymmetry and gain applied.
    pub fn target(&self, setpoint: f64) -> f64 {
        self.gain * target(self.dead_band, self.reverse_gain, setpoint)
    }

    /// The thrusts now.
    pub fn thrust(&self) -> &[f64] {
        &self.thrust
    }

    /// Stops every thruster at once (the vehicle is repositioned between trials).
    pub fn stop(&mut self) {
        self.thrust.iter_mut().for_each(|t| *t = 0.0);
    }

    /// Advances the thrusts by `h` seconds towards the setpoints' targets; returns the mean thrust
    /// of each thruster over the interval (what the model integrates). Missing setpoints count as 0.
    pub fn advance(&mut self, setpoints: &[f64], h: f64, mean: &mut [f64]) {
        let (dead_band, reverse_gain, gain) = (self.dead_band, self.reverse_gain, self.gain);
        for (i, (t, m)) in self.thrust.iter_mut().zip(mean.iter_mut()).enumerate() {
            let target = gain
                * target(
                    dead_band,
                    reverse_gain,
                    setpoints.get(i).copied().unwrap_or(0.0),
                );
            let start = *t;
            match self.lag_s {
                Some(tau) => {
                    // The exact first-order response over h, and its mean over the interval.
                    let decay = (-h / tau).exp();
                    *t = target + (start - target) * decay;
                    *m = target + (start - target) * tau / h * (1.0 - decay);
                }
                None => {
                    *t = target;
                    *m = target;
                }
            }
        }
    }
}

/// A setpoint's settled thrust: made safe, the dead band, the asymmetry.
fn target(dead_band: f64, reverse_gain: f64, setpoint: f64) -> f64 {
    let s = adapters::make_safe(setpoint);
    if s.abs() < dead_band {
        0.0
    } else if s < 0.0 {
        s * reverse_gain
    } else {
        s
    }
}

/// The twin's vehicle: model, thrusters, current.
#[derive(Clone, Debug)]
pub struct TwinPlant {
    dynamics: Dynamics,
    layout: ThrusterLayout,
    thrusters: ThrusterModel,
    current: [f64; 2],
    max_substep_s: f64,
    state: VehicleState,
    mean: Vec<f64>,
}

/// The scenario's model with the twin's quadratic damping (when enabled): each DOF's identified
/// linear drag split into a smaller linear part and the quadratic one (see
/// [`config::DampingParams`]).
pub fn twin_model(scenario: &Scenario, twin: &TwinParams) -> ModelParams {
    let mut m = scenario.model.clone();
    if twin.damping.enabled {
        let d = &twin.damping;
        for (dof, damping) in [
            (&mut m.surge, d.surge),
            (&mut m.sway, d.sway),
            (&mut m.yaw, d.yaw),
        ] {
            (dof.gamma, dof.beta) = damping.split(dof.gamma);
        }
    }
    m
}

impl TwinPlant {
    pub fn new(scenario: &Scenario, twin: &TwinParams) -> Self {
        let model = twin_model(scenario, twin);
        let layout = ThrusterLayout::new(&scenario.thrusters);
        let n = layout.len();
        TwinPlant {
            max_substep_s: model.max_substep_s,
            dynamics: Dynamics::new(model),
            thrusters: ThrusterModel::new(twin, n),
            layout,
            current: twin.current.velocity(),
            state: VehicleState::default(),
            mean: vec![0.0; n],
        }
    }

    pub fn state(&self) -> &VehicleState {
        &self.state
    }

    /// Puts the vehicle somewhere, its thrusters stopped (a reposition between trials).
    pub fn place(&mut self, state: VehicleState) {
        self.state = state;
        self.thrusters.stop();
    }

    /// The thrusts now, per thruster.
    pub fn thrust(&self) -> &[f64] {
        self.thrusters.thrust()
    }

    pub fn thrusters(&self) -> &ThrusterModel {
        &self.thrusters
    }

    pub fn layout(&self) -> &ThrusterLayout {
        &self.layout
    }

    /// The longest integration sub-step (the model's).
    pub fn max_substep_s(&self) -> f64 {
        self.max_substep_s
    }

    pub fn dynamics(&self) -> &Dynamics {
        &self.dynamics
    }

    /// The water's velocity (pool frame).
    pub fn current(&self) -> [f64; 2] {
        self.current
    }

    /// The pose's rate of change: the body velocities plus the current.
    pub fn pose_rate(&self) -> PoseRate {
        let r = self.state.pose_rate();
        PoseRate {
            x: r.x + self.current[0],
            y: r.y + self.current[1],
            psi: r.psi,
        }
    }

    /// Integrates `dt` seconds under constant setpoints (one per thruster of the layout).
    pub fn step(&mut self, setpoints: &[f64], dt: f64) {
        if dt <= 0.0 {
            return;
        }
        let n = (dt / self.max_substep_s).ceil().max(1.0);
        let h = dt / n;
        for _ in 0..n as usize {
            self.thrusters.advance(setpoints, h, &mut self.mean);
            let forces = self.layout.forces(&self.mean);
            self.state = self
                .dynamics
                .step_in_current(&self.state, forces, h, self.current);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use model::{Forces, Pose};

    fn only(edit: impl FnOnce(&mut TwinParams)) -> TwinParams {
        let mut t = TwinParams::ideal();
        edit(&mut t);
        t
    }

    /// With every effect off the twin is the simulator's model, step for step.
    #[test]
    fn with_every_effect_off_the_plant_is_the_identified_model() {
        let s = Scenario::default();
        let mut plant = TwinPlant::new(&s, &TwinParams::ideal());
        let model = Dynamics::new(s.model.clone());
        let layout = ThrusterLayout::new(&s.thrusters);
        let start = VehicleState {
            pose: Pose {
                x: 1.0,
                y: -0.2,
                psi: 0.3,
            },
            ..Default::default()
        };
        plant.place(start);
        let mut want = start;
        for k in 0..100 {
            let sp = [
                0.8 * (k as f64 * 0.1).sin(),
                0.6,
                -0.4 * (k as f64 * 0.2).cos(),
            ];
            plant.step(&sp, 0.2);
            want = model.step(&want, layout.forces(&sp), 0.2);
            let (a, b) = (plant.state(), &want);
            assert!(
                (a.pose.x - b.pose.x).abs() < 1e-12
                    && (a.pose.y - b.pose.y).abs() < 1e-12
                    && (a.pose.psi - b.pose.psi).abs() < 1e-12
                    && (a.velocity.v - b.velocity.v).abs() < 1e-12,
                "step {k}: {a:?} vs {b:?}"
            );
        }
    }

    /// The lag's step response: thrust(t) = 1 - e^{-t/tau}, 63.2% after one time constant.
    #[test]
    fn the_lag_is_a_first_order_step_response() {
        let twin = only(|t| t.thrusters.lag.enabled = true);
        let tau = twin.thrusters.lag.time_constant_s;
        let mut plant = TwinPlant::new(&Scenario::default(), &twin);
        let mut t = 0.0;
        for _ in 0..30 {
            plant.step(&[0.0, 0.0, 1.0], 0.05);
            t += 0.05;
            let want = 1.0 - (-t / tau).exp();
            assert!(
                (plant.thrust()[2] - want).abs() < 1e-12,
                "t={t}: {} vs {want}",
                plant.thrust()[2]
            );
        }
        // Off, the thrust is the setpoint at once.
        let mut plant = TwinPlant::new(&Scenario::default(), &TwinParams::ideal());
        plant.step(&[0.0, 0.0, 1.0], 0.05);
        assert_eq!(plant.thrust()[2], 1.0);
        // The lag slows the vehicle's response: less sway after 0.4 s.
        let mut lagged = TwinPlant::new(&Scenario::default(), &twin);
        let mut ideal = TwinPlant::new(&Scenario::default(), &TwinParams::ideal());
        lagged.step(&[0.0, 0.0, 1.0], 0.4);
        ideal.step(&[0.0, 0.0, 1.0], 0.4);
        assert!(lagged.state().velocity.v < 0.7 * ideal.state().velocity.v);
    }

    #[test]
    fn the_dead_band_swallows_small_setpoints() {
        let twin = only(|t| t.thrusters.dead_band.enabled = true);
        let d = twin.thrusters.dead_band.setpoint;
        let mut plant = TwinPlant::new(&Scenario::default(), &twin);
        let m = plant.thrusters();
        assert_eq!(m.target(0.9 * d), 0.0);
        assert_eq!(m.target(-0.9 * d), 0.0);
        assert_eq!(m.target(1.1 * d), 1.1 * d);
        // Only the model's own drift (delta) moves it: as with no setpoint at all.
        let mut idle = TwinPlant::new(&Scenario::default(), &twin);
        plant.step(&[0.0, 0.0, 0.9 * d], 2.0);
        idle.step(&[0.0; 3], 2.0);
        assert_eq!(plant.state(), idle.state(), "no thrust, no motion");
        plant.step(&[0.0, 0.0, 1.1 * d], 2.0);
        assert!(plant.state().velocity.v > 0.01);
        // Off, a small setpoint moves the vehicle.
        let mut plant = TwinPlant::new(&Scenario::default(), &TwinParams::ideal());
        plant.step(&[0.0, 0.0, 0.9 * d], 2.0);
        assert!(plant.state().velocity.v > 0.0);
    }

    #[test]
    fn reverse_thrust_is_weaker() {
        let twin = only(|t| t.thrusters.asymmetry.enabled = true);
        let g = twin.thrusters.asymmetry.reverse_gain;
        let s = Scenario::default();
        let mut fwd = TwinPlant::new(&s, &twin);
        let mut rev = TwinPlant::new(&s, &twin);
        assert_eq!(fwd.thrusters().target(0.5), 0.5);
        assert_eq!(fwd.thrusters().target(-0.5), -0.5 * g);
        fwd.step(&[0.0, 0.0, 0.5], 60.0);
        rev.step(&[0.0, 0.0, -0.5], 60.0);
        // Linear damping: the steady sway speed is proportional to the thrust.
        let (vf, vr) = (fwd.state().velocity.v, rev.state().velocity.v);
        let m = s.model.sway;
        assert!(
            (vf - (0.5 * m.alpha + m.delta) / m.gamma).abs() < 1e-4,
            "{vf}"
        );
        assert!(
            (vr - (-0.5 * g * m.alpha + m.delta) / m.gamma).abs() < 1e-4,
            "{vr}"
        );
        // A pure yaw command (port forward, starboard reverse) now also pushes forward.
        let mut turn = TwinPlant::new(&s, &twin);
        turn.step(&[0.5, -0.5, 0.0], 10.0);
        assert!(turn.state().velocity.u > 0.0);
        let mut sym = TwinPlant::new(&s, &TwinParams::ideal());
        sym.step(&[0.5, -0.5, 0.0], 10.0);
        assert!(
            sym.state().velocity.u.abs() < 0.02,
            "only the model's drift"
        );
    }

    /// A vehicle more responsive than identified: the same setpoint gives `factor` times the thrust,
    /// so (linear damping) `factor` times the steady speed; off, the identified thrust.
    #[test]
    fn the_thrust_gain_scales_the_response() {
        let twin = only(|t| t.thrusters.gain.enabled = true);
        let f = twin.thrusters.gain.factor;
        assert!(f != 1.0);
        let s = Scenario::default();
        let mut strong = TwinPlant::new(&s, &twin);
        assert_eq!(strong.thrusters().target(0.2), f * 0.2);
        strong.step(&[0.0, 0.0, 0.2], 60.0);
        let m = s.model.sway;
        let v = strong.state().velocity.v;
        assert!(
            (v - (f * 0.2 * m.alpha + m.delta) / m.gamma).abs() < 1e-4,
            "{v}"
        );
        let mut ideal = TwinPlant::new(&s, &TwinParams::ideal());
        assert_eq!(ideal.thrusters().target(0.2), 0.2);
        ideal.step(&[0.0, 0.0, 0.2], 60.0);
        assert!((ideal.state().velocity.v - (0.2 * m.alpha + m.delta) / m.gamma).abs() < 1e-4);
    }

    #[test]
    fn the_current_drifts_the_vehicle() {
        let twin = only(|t| t.current.enabled = true);
        let [cx, cy] = twin.current.velocity();
        let mut plant = TwinPlant::new(&Scenario::default(), &twin);
        plant.step(&[0.0; 3], 10.0);
        // The model's own drift (delta) moves it a little too: compare with still water.
        let mut still = TwinPlant::new(&Scenario::default(), &TwinParams::ideal());
        still.step(&[0.0; 3], 10.0);
        let (a, b) = (plant.state().pose, still.state().pose);
        assert!((a.x - b.x - 10.0 * cx).abs() < 1e-9 && (a.y - b.y - 10.0 * cy).abs() < 1e-9);
        assert!((plant.pose_rate().y - still.state().pose_rate().y - cy).abs() < 1e-12);
        assert!(cx.hypot(cy) > 0.0);
    }

    /// dv/dt = alpha tau - beta v|v| - gamma v + delta: the steady speed is the quadratic's root.
    /// The identified drag is kept at the identification speed; below it the twin is less damped.
    #[test]
    fn quadratic_damping_keeps_the_identified_drag_and_lowers_the_low_speed_damping() {
        let twin = only(|t| t.damping.enabled = true);
        let s = Scenario::default();
        let m = twin_model(&s, &twin);
        for (name, id, tw, d) in [
            ("surge", s.model.surge, m.surge, twin.damping.surge),
            ("sway", s.model.sway, m.sway, twin.damping.sway),
            ("yaw", s.model.yaw, m.yaw, twin.damping.yaw),
        ] {
            assert!(tw.beta > 0.0 && tw.gamma < id.gamma, "{name}");
            let v = d.identified_at;
            let drag = |p: config::DofModel, v: f64| p.beta * v * v.abs() + p.gamma * v;
            assert!(
                (drag(tw, v) - drag(id, v)).abs() < 1e-12,
                "{name}: same drag at {v}"
            );
            assert!(
                drag(tw, 0.5 * v) < drag(id, 0.5 * v),
                "{name}: less drag below"
            );
            assert!(
                drag(tw, 2.0 * v) > drag(id, 2.0 * v),
                "{name}: more drag above"
            );
        }
        // Integrated: the speed under constant thrust is the quadratic's root.
        let mut plant = TwinPlant::new(&s, &twin);
        plant.step(&[0.5, 0.5, 0.4], 60.0);
        let v = plant.state().velocity;
        assert!((v.u - m.surge.steady_velocity(0.5)).abs() < 1e-6, "{}", v.u);
        assert!((v.v - m.sway.steady_velocity(0.4)).abs() < 1e-6);
        let mut ideal = TwinPlant::new(&s, &TwinParams::ideal());
        ideal.step(&[0.5, 0.5, 0.4], 60.0);
        assert!((ideal.state().velocity.v - s.model.sway.steady_velocity(0.4)).abs() < 1e-6);
        let forces = plant.layout().forces(&[1.0, 1.0, 1.0]);
        assert_eq!(
            forces,
            Forces {
                surge: 1.0,
                sway: 1.0,
                yaw: 0.0
            }
        );
    }
}
