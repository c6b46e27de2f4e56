//! The pilot's stick: the DOF forces of a step as MANUAL_CONTROL, sent at once and repeated at a
//! steady rate until the next step or a stop, which holds neutral.
//!
//! How ArduSub reads MANUAL_CONTROL (its `joystick.cpp`, `mode_manual.cpp`): x (forward), y
//! (lateral, positive to starboard) and r (yaw, positive clockwise seen from above, the project's
//! positive yaw) run from -1000 to 1000; each becomes an RC pulse of 1500 + axis x 0.4 x gain
//! microseconds, held within 1100..1900, and MANUAL mode passes the pulse's fraction of its
//! 400 us half-range to the motor mixer as that axis's thrust: a full axis gives `gain` of the
//! axis's full thrust. Yaw in MANUAL is further scaled by ACRO_YAW_P / 4.5 (1 at its default). So a
//! DOF command f is sent as f / reach x 1000 (computed as `model::pilot` computes it), where reach
//! is what a full axis gives, and f is reachable only up to the reach: beyond it the axis is clipped. z is heave (0..1000, 500
//! neutral): the cable tracker does not use it.

use mavlink::dialects::ardupilotmega::{MANUAL_CONTROL_DATA, MavMessage};
use model::Forces;
use std::time::{Duration, Instant};

/// MANUAL_CONTROL's axes, the twin's and the companion's one type; heave (z) stays at its neutral.
pub use model::pilot::{Axes, Z_NEUTRAL};

/// One axis's scale: a DOF command f is sent as `f x fraction x 1000 / gain`, rounded, within
/// +-1000 (`model::pilot::axis`, the very arithmetic of the twin's own conversion, so that both
/// round alike), so a full axis gives `gain / fraction` of the command.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AxisScale {
    pub fraction: f64,
    pub gain: f64,
}

impl AxisScale {
    /// The command a full axis gives.
    pub fn full(&self) -> f64 {
        self.gain / self.fraction
    }

    fn axis(&self, command: f64) -> i16 {
        model::pilot::axis(command, self.fraction, self.gain)
    }
}

/// What a full axis (1000) gives, per DOF.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Reach {
    pub surge: AxisScale,
    pub sway: AxisScale,
    pub yaw: AxisScale,
}

impl Reach {
    /// ArduSub's pilot gain on every axis, yaw scaled by `yaw_scale` (MANUAL's ACRO_YAW_P / 4.5):
    /// a command is that fraction of the axis's full thrust.
    pub fn new(gain: f64, yaw_scale: f64) -> Self {
        let whole = |gain| AxisScale {
            fraction: 1.0,
            gain,
        };
        Reach {
            surge: whole(gain),
            sway: whole(gain),
            yaw: whole(gain * yaw_scale),
        }
    }

    /// Under the scenario's `[pilot]`: a full axis gives `gain / fraction` of the stack's command
    /// on each DOF, so that a command is sent as `command x fraction x 1000 / gain`, the axis step
    /// one's model assumes (`model::pilot`). In the stabilised modes the yaw axis is then a rate,
    /// as the model's yaw is.
    pub fn of_pilot(gain: f64, fractions: &config::PilotFractions) -> Self {
        let of = |fraction| AxisScale { fraction, gain };
        Reach {
            surge: of(fractions.surge),
            sway: of(fractions.sway),
            yaw: of(fractions.yaw),
        }
    }
}

/// A command beyond what a full axis gives: sent as the full axis.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Clipped {
    /// "surge", "sway" or "yaw".
    pub dof: &'static str,
    pub command: f64,
    pub reach: f64,
}

/// `forces` as axes with `reach`; the first DOF clipped, if any.
pub fn axes(forces: &Forces, reach: &Reach) -> (Axes, Option<Clipped>) {
    let mut clipped = None;
    let mut axis = |dof: &'static str, f: f64, scale: AxisScale| {
        let reach = scale.full();
        // Half a step of slack: a command that rounds to the full axis is not clipped.
        if f.abs() > reach + 0.5e-3 {
            clipped.get_or_insert(Clipped {
                dof,
                command: f,
                reach,
            });
        }
        scale.axis(f)
    };
    let a = Axes {
        x: axis("surge", forces.surge, reach.surge),
        y: axis("sway", forces.sway, reach.sway),
        z: Z_NEUTRAL,
        r: axis("yaw", forces.yaw, reach.yaw),
    };
    (a, clipped)
}

/// The forces `axes` command with `reach` (what the far side reads back).
pub fn forces(axes: &Axes, reach: &Reach) -> Forces {
    Forces {
        surge: f64::from(axes.x) / 1000.0 * reach.surge.full(),
        sway: f64::from(axes.y) / 1000.0 * reach.sway.full(),
        yaw: f64::from(axes.r) / 1000.0 * reach.yaw.full(),
    }
}

/// The MANUAL_CONTROL of `axes` for the autopilot `target`.
pub fn manual_control(axes: &Axes, target: u8) -> MavMessage {
    MavMessage::MANUAL_CONTROL(MANUAL_CONTROL_DATA {
        x: axes.x,
        y: axes.y,
        z: axes.z,
        r: axes.r,
        buttons: 0,
        target,
        ..Default::default()
    })
}

/// The stick: what it holds, and when to send it again.
pub struct Pilot {
    period: Duration,
    reach: Reach,
    held: Axes,
    /// The next periodic send; `None` until the first.
    next: Option<Instant>,
}

impl Pilot {
    pub fn new(period: Duration, reach: Reach) -> Self {
        Pilot {
            period,
            reach,
            held: Axes::NEUTRAL,
            next: None,
        }
    }

    pub fn reach(&self) -> Reach {
        self.reach
    }

    pub fn set_reach(&mut self, reach: Reach) {
        self.reach = reach;
    }

    pub fn held(&self) -> Axes {
        self.held
    }

    /// A step's forces: held from now; the axes to send at once, and what was clipped.
    pub fn command(&mut self, forces: &Forces) -> (Axes, Option<Clipped>) {
        let (a, clipped) = axes(forces, &self.reach);
        self.held = a;
        (a, clipped)
    }

    /// A stop: neutral from now; the axes to send at once.
    pub fn neutral(&mut self) -> Axes {
        self.held = Axes::NEUTRAL;
        self.held
    }

    /// The held axes if a periodic send is due at `now`. Sends keep to their grid (a step's own
    /// send does not move it), and a grid fallen behind (the process was not scheduled) restarts
    /// from now rather than bursting.
    pub fn due(&mut self, now: Instant) -> Option<Axes> {
        match self.next {
            Some(t) if now < t => None,
            Some(t) => {
                let next = t + self.period;
                self.next = Some(if next <= now { now + self.period } else { next });
                Some(self.held)
            }
            None => {
                self.next = Some(now + self.period);
                Some(self.held)
            }
        }
    }

    /// When the next periodic send is due (`None` before the first).
    pub fn next_due(&self) -> Option<Instant> {
        self.next
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn f(surge: f64, sway: f64, yaw: f64) -> Forces {
        Forces { surge, sway, yaw }
    }

    #[test]
    fn each_dof_drives_its_own_axis_with_its_sign() {
        let full = Reach::new(1.0, 1.0);
        assert_eq!(
            axes(&f(0.4, 0.0, 0.0), &full).0,
            Axes {
                x: 400,
                y: 0,
                z: Z_NEUTRAL,
                r: 0
            }
        );
        assert_eq!(
            axes(&f(-0.4, 0.0, 0.0), &full).0,
            Axes {
                x: -400,
                y: 0,
                z: Z_NEUTRAL,
                r: 0
            }
        );
        // Sway to starboard is positive y; yaw clockwise seen from above is positive r.
        assert_eq!(
            axes(&f(0.0, 0.25, 0.0), &full).0,
            Axes {
                x: 0,
                y: 250,
                z: Z_NEUTRAL,
                r: 0
            }
        );
        assert_eq!(
            axes(&f(0.0, 0.0, -0.7), &full).0,
            Axes {
                x: 0,
                y: 0,
                z: Z_NEUTRAL,
                r: -700
            }
        );
        match manual_control(
            &Axes {
                x: 1,
                y: -2,
                z: Z_NEUTRAL,
                r: 3,
            },
            7,
        ) {
            MavMessage::MANUAL_CONTROL(m) => {
                assert_eq!(
                    (m.x, m.y, m.z, m.r, m.buttons, m.target),
                    (1, -2, 500, 3, 0, 7)
                )
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn under_a_pilot_section_the_axes_are_those_step_ones_model_assumes() {
        // The BlueROV2 scenario's fractions, at ArduSub's default gain and at others.
        let pilot = config::PilotParams {
            mode: config::PilotMode::AltHold,
            fraction: config::PilotFractions {
                surge: 0.0524,
                sway: 0.0681,
                yaw: 0.191,
            },
            yaw_rate_time_constant_s: Some(0.05),
            autopilot: Default::default(),
        };
        for gain in [0.25, 0.5, 1.0] {
            let reach = Reach::of_pilot(gain, &pilot.fraction);
            for forces in [f(1.0, 0.0, 0.0), f(0.0, -1.0, 0.0), f(0.3, 0.77, -0.41)] {
                let (ours, clipped) = axes(&forces, &reach);
                let model = model::pilot::axes(&forces, &pilot, gain);
                assert_eq!(
                    (ours.x, ours.y, ours.r),
                    (model.x, model.y, model.r),
                    "gain {gain}, {forces:?}"
                );
                assert_eq!(clipped, None);
            }
        }
        // A full yaw command at gain 0.5: 0.191 of the stick at gain 1 is 382 of 1000.
        let (a, _) = axes(&f(0.0, 0.0, 1.0), &Reach::of_pilot(0.5, &pilot.fraction));
        assert_eq!(a.r, 382);
    }

    #[test]
    fn the_gain_is_divided_out_and_what_it_cannot_reach_is_clipped() {
        // ArduSub's default gain of 0.5: a command of 0.3 needs 60% of the stick.
        let half = Reach::new(0.5, 1.0);
        let (a, clipped) = axes(&f(0.3, -0.5, 0.0), &half);
        assert_eq!(
            a,
            Axes {
                x: 600,
                y: -1000,
                z: Z_NEUTRAL,
                r: 0
            }
        );
        assert_eq!(clipped, None, "exactly the full axis is reachable");
        let (a, clipped) = axes(&f(0.0, 0.0, -0.8), &half);
        assert_eq!(a.r, -1000);
        assert_eq!(
            clipped,
            Some(Clipped {
                dof: "yaw",
                command: -0.8,
                reach: 0.5
            })
        );
        // MANUAL's yaw scale: ACRO_YAW_P = 9 doubles what the yaw axis gives.
        let (a, clipped) = axes(&f(0.0, 0.0, 0.8), &Reach::new(0.5, 2.0));
        assert_eq!((a.r, clipped), (800, None));
        // Read back, the far side's forces are the command within half a step.
        let got = forces(&axes(&f(0.123, -0.0456, 0.0), &half).0, &half);
        assert!((got.surge - 0.123).abs() <= 0.25e-3 && (got.sway + 0.0456).abs() <= 0.25e-3);
    }

    #[test]
    fn the_stick_holds_its_command_at_a_steady_rate_and_a_stop_holds_neutral() {
        let t0 = Instant::now();
        let ms = Duration::from_millis(1);
        let mut p = Pilot::new(50 * ms, Reach::new(1.0, 1.0));
        assert_eq!(p.due(t0), Some(Axes::NEUTRAL), "neutral until commanded");
        assert_eq!(p.due(t0 + 49 * ms), None);
        let (a, _) = p.command(&f(0.2, 0.0, 0.1));
        assert_eq!(
            a,
            Axes {
                x: 200,
                y: 0,
                z: Z_NEUTRAL,
                r: 100
            }
        );
        // The step's own send does not move the grid.
        assert_eq!(p.next_due(), Some(t0 + 50 * ms));
        assert_eq!(p.due(t0 + 50 * ms), Some(a));
        assert_eq!(p.due(t0 + 101 * ms), Some(a));
        assert_eq!(p.next_due(), Some(t0 + 150 * ms), "on the grid");
        assert_eq!(p.neutral(), Axes::NEUTRAL);
        assert_eq!(p.due(t0 + 150 * ms), Some(Axes::NEUTRAL));
        // Half a second unscheduled: one send, then the grid restarts from now.
        assert_eq!(p.due(t0 + 700 * ms), Some(Axes::NEUTRAL));
        assert_eq!(p.due(t0 + 701 * ms), None);
        assert_eq!(p.next_due(), Some(t0 + 750 * ms));
    }
}
