//! The surge controller's core. Surge is not learned (paper section III-C): the vehicle cruises at
//! `speed_m_s` while the cable is centred in the image (|x_g| and |Theta| below their thresholds)
//! and stops otherwise. The vehicle has no speed sensor, so the command is the model's feed-forward
//! thrust that sustains the cruise speed.

use config::{DofModel, SurgeParams};
use model::CableObservation;

pub struct SurgeController {
    params: SurgeParams,
    /// The normalised thrust that holds `speed_m_s` in steady state.
    cruise_thrust: f64,
}

impl SurgeController {
    pub fn new(params: &SurgeParams, surge_model: &DofModel) -> Self {
        let v = params.speed_m_s;
        let m = surge_model;
        let cruise_thrust =
            ((m.gamma * v + m.beta * v * v.abs() - m.delta) / m.alpha).clamp(-1.0, 1.0);
        SurgeController {
            params: params.clone(),
            cruise_thrust,
        }
    }

    /// Whether the cable is centred enough to move forward.
    pub fn centred(&self, obs: &CableObservation) -> bool {
        obs.found
            && obs.x_g.abs() < self.params.x_g_max
            && obs.theta.abs() < self.params.theta_max_deg.to_radians()
    }

    /// The commanded speed (m/s) for this observation.
    pub fn speed(&self, obs: &CableObservation) -> f64 {
        if self.centred(obs) {
            self.params.speed_m_s
        } else {
            0.0
        }
    }

    /// The normalised surge force for this observation.
    pub fn command(&self, obs: &CableObservation) -> f64 {
        if self.centred(obs) {
            self.cruise_thrust
        } else {
            0.0
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use config::ModelParams;
    use model::{Dynamics, Forces, VehicleState};

    fn controller() -> SurgeController {
        SurgeController::new(&SurgeParams::default(), &ModelParams::default().surge)
    }

    #[test]
    fn cruises_only_while_centred() {
        let c = controller();
        let obs = |x_g: f64, theta_deg: f64| CableObservation {
            found: true,
            x_g,
            theta: theta_deg.to_radians(),
            ..Default::default()
        };
        assert_eq!(c.speed(&obs(0.0, 0.0)), 0.3);
        assert_eq!(c.speed(&obs(0.14, -14.0)), 0.3);
        assert_eq!(c.speed(&obs(0.16, 0.0)), 0.0);
        assert_eq!(c.speed(&obs(0.0, 16.0)), 0.0);
        assert_eq!(c.speed(&CableObservation::default()), 0.0);
        assert_eq!(c.command(&obs(0.3, 0.0)), 0.0);
    }

    #[test]
    fn the_cruise_thrust_reaches_the_cruise_speed() {
        let c = controller();
        let dynamics = Dynamics::new(ModelParams::default());
        let centred = CableObservation {
            found: true,
            ..Default::default()
        };
        let mut s = VehicleState::default();
        for _ in 0..200 {
            s = dynamics.step(
                &s,
                Forces {
                    surge: c.command(&centred),
                    ..Forces::default()
                },
                0.2,
            );
        }
        assert!((s.velocity.u - 0.3).abs() < 1e-3, "{}", s.velocity.u);
    }
}
