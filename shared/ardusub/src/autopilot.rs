//! The autopilot as its heartbeat shows it: who it is, whether it is armed, its mode, and whether
//! it is still there. Only the autopilot's own HEARTBEAT counts: a companion component of the same
//! system (BlueOS's, ours) sends heartbeats too, some with the armed bit set.

use mavlink::dialects::ardupilotmega::{HEARTBEAT_DATA, MavAutopilot, MavModeFlag, MavType};
use std::time::{Duration, Instant};

/// The autopilot's MAVLink address.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Address {
    pub system: u8,
    pub component: u8,
}

/// What one heartbeat of the autopilot says.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Status {
    pub armed: bool,
    /// ArduSub's flight mode (`custom_mode`).
    pub mode: u32,
    /// MAV_STATE.
    pub system_status: u8,
}

impl Status {
    pub fn of(hb: &HEARTBEAT_DATA) -> Self {
        Status {
            armed: hb
                .base_mode
                .contains(MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED),
            mode: hb.custom_mode,
            system_status: hb.system_status as u8,
        }
    }
}

/// A change the watch saw.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Change {
    /// The autopilot's first heartbeat.
    Found(Address, Status),
    /// No heartbeat for the loss time: its state is unknown from now.
    Lost { silent: Duration },
    /// Its heartbeat again after a loss.
    Back(Status),
    /// A heartbeat that differs from the last one (armed, mode or state).
    Changed { from: Status, to: Status },
}

/// Watches the autopilot's heartbeat.
pub struct Watch {
    lost_after: Duration,
    address: Option<Address>,
    /// The last heartbeat and when it came.
    last: Option<(Instant, Status)>,
    lost: bool,
}

/// Whether a heartbeat is an autopilot's (a submarine's flight controller), not a companion's or a
/// ground station's.
pub fn is_autopilot(hb: &HEARTBEAT_DATA) -> bool {
    hb.mavtype == MavType::MAV_TYPE_SUBMARINE && hb.autopilot != MavAutopilot::MAV_AUTOPILOT_INVALID
}

impl Watch {
    pub fn new(lost_after: Duration) -> Self {
        Watch {
            lost_after,
            address: None,
            last: None,
            lost: false,
        }
    }

    /// The autopilot, once its first heartbeat came.
    pub fn address(&self) -> Option<Address> {
        self.address
    }

    /// Its state now: `None` before its first heartbeat and while it is lost.
    pub fn status(&self) -> Option<Status> {
        match self.last {
            Some((_, s)) if !self.lost => Some(s),
            _ => None,
        }
    }

    /// Whether a message from `from` comes from the autopilot.
    pub fn is_from(&self, from: Address) -> bool {
        self.address == Some(from)
    }

    /// A heartbeat from `from`, arrived at `at`: the autopilot's first one fixes its address; any
    /// other system's or component's is ignored.
    pub fn on_heartbeat(
        &mut self,
        at: Instant,
        from: Address,
        hb: &HEARTBEAT_DATA,
    ) -> Option<Change> {
        match self.address {
            None if is_autopilot(hb) => self.address = Some(from),
            Some(a) if a == from && is_autopilot(hb) => {}
            _ => return None,
        }
        let status = Status::of(hb);
        let before = self.last.map(|(_, s)| s);
        let was_lost = std::mem::replace(&mut self.lost, false);
        self.last = Some((at, status));
        match before {
            None => Some(Change::Found(from, status)),
            Some(_) if was_lost => Some(Change::Back(status)),
            Some(b) if b != status => Some(Change::Changed {
                from: b,
                to: status,
            }),
            Some(_) => None,
        }
    }

    /// Time passed: the loss of the heartbeat, once.
    pub fn on_time(&mut self, now: Instant) -> Option<Change> {
        match self.last {
            Some((at, _)) if !self.lost && now.saturating_duration_since(at) >= self.lost_after => {
                self.lost = true;
                Some(Change::Lost {
                    silent: now.saturating_duration_since(at),
                })
            }
            _ => None,
        }
    }

    /// When the heartbeat will count as lost if none comes (`None` when not watching).
    pub fn deadline(&self) -> Option<Instant> {
        match self.last {
            Some((at, _)) if !self.lost => Some(at + self.lost_after),
            _ => None,
        }
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use mavlink::dialects::ardupilotmega::MavState;

    pub(crate) fn heartbeat(mavtype: MavType, armed: bool, mode: u32) -> HEARTBEAT_DATA {
        let mut base_mode = MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED;
        if armed {
            base_mode |= MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED;
        }
        HEARTBEAT_DATA {
            custom_mode: mode,
            mavtype,
            autopilot: if mavtype == MavType::MAV_TYPE_SUBMARINE {
                MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA
            } else {
                MavAutopilot::MAV_AUTOPILOT_INVALID
            },
            base_mode,
            system_status: MavState::MAV_STATE_STANDBY,
            mavlink_version: 3,
        }
    }

    const SUB: MavType = MavType::MAV_TYPE_SUBMARINE;

    #[test]
    fn only_the_autopilots_heartbeat_counts_and_its_loss_is_told_both_ways() {
        let t0 = Instant::now();
        let s = Duration::from_secs(1);
        let mut w = Watch::new(3 * s);
        let ap = Address {
            system: 1,
            component: 1,
        };
        let companion = Address {
            system: 1,
            component: 194,
        };
        // A companion's heartbeat with the armed bit set says nothing of the autopilot.
        assert_eq!(
            w.on_heartbeat(
                t0,
                companion,
                &heartbeat(MavType::MAV_TYPE_ONBOARD_CONTROLLER, true, 0)
            ),
            None
        );
        assert_eq!(w.status(), None);
        let found = w.on_heartbeat(t0, ap, &heartbeat(SUB, false, 19));
        let disarmed = Status {
            armed: false,
            mode: 19,
            system_status: MavState::MAV_STATE_STANDBY as u8,
        };
        assert_eq!(found, Some(Change::Found(ap, disarmed)));
        assert_eq!(w.on_heartbeat(t0 + s, ap, &heartbeat(SUB, false, 19)), None);
        // Another submarine on the link is not ours.
        let other = Address {
            system: 2,
            component: 1,
        };
        assert_eq!(
            w.on_heartbeat(t0 + s, other, &heartbeat(SUB, true, 0)),
            None
        );
        let armed = Status {
            armed: true,
            ..disarmed
        };
        assert_eq!(
            w.on_heartbeat(t0 + 2 * s, ap, &heartbeat(SUB, true, 19)),
            Some(Change::Changed {
                from: disarmed,
                to: armed
            })
        );
        assert_eq!(w.deadline(), Some(t0 + 5 * s));
        assert_eq!(w.on_time(t0 + 5 * s - Duration::from_millis(1)), None);
        assert_eq!(w.on_time(t0 + 5 * s), Some(Change::Lost { silent: 3 * s }));
        assert_eq!(w.on_time(t0 + 9 * s), None, "told once");
        assert_eq!(w.status(), None, "unknown while lost");
        assert_eq!(
            w.on_heartbeat(t0 + 10 * s, ap, &heartbeat(SUB, false, 19)),
            Some(Change::Back(disarmed))
        );
        assert_eq!(w.status(), Some(disarmed));
    }
}
