//! The channels of a flight record: one per topic of the endpoint (the camera's topic gives three:
//! its header as JSON, its image, and perception's estimate drawn over it), each with its schema.

use crate::json;
use serde_json::Value;

/// A DOF that has a command topic.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum CommandDof {
    Surge,
    Sway,
    Yaw,
}

impl CommandDof {
    pub const ALL: [CommandDof; 3] = [CommandDof::Surge, CommandDof::Sway, CommandDof::Yaw];

    /// Its topic in the messages contract.
    pub fn topic(self) -> messages::Topic<messages::DofCommand> {
        match self {
            CommandDof::Surge => messages::topics::SURGE_COMMAND,
            CommandDof::Sway => messages::topics::SWAY_COMMAND,
            CommandDof::Yaw => messages::topics::YAW_COMMAND,
        }
    }

    pub fn channel(self) -> Channel {
        match self {
            CommandDof::Surge => Channel::SurgeCommand,
            CommandDof::Sway => Channel::SwayCommand,
            CommandDof::Yaw => Channel::YawCommand,
        }
    }
}

/// How a channel's messages are encoded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Encoding {
    /// JSON with a JSON Schema (`crate::json`).
    Json,
    /// A Foxglove well-known schema, protobuf-encoded (the schema is its FileDescriptorSet).
    Protobuf,
}

/// A channel of the flight record.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Channel {
    /// The vehicle's state (the sim endpoint's simulator; nobody publishes it on the vehicle).
    VehicleState,
    /// Each camera frame's header: its step and the true line where known.
    FrameHeader,
    /// The camera's images, `foxglove.RawImage` `mono8`, decimated by `--frame-every`.
    Image,
    /// Perception's estimate.
    Observation,
    /// Perception's estimate drawn over the image (`foxglove.ImageAnnotations`), for the frames whose
    /// image is recorded.
    Annotation,
    SurgeCommand,
    SwayCommand,
    YawCommand,
    Setpoints,
    SwayLearning,
    YawLearning,
    /// The supervisor's events.
    Events,
    /// The recorder's own progress.
    Status,
}

impl Channel {
    pub const ALL: [Channel; 13] = [
        Channel::VehicleState,
        Channel::FrameHeader,
        Channel::Image,
        Channel::Observation,
        Channel::Annotation,
        Channel::SurgeCommand,
        Channel::SwayCommand,
        Channel::YawCommand,
        Channel::Setpoints,
        Channel::SwayLearning,
        Channel::YawLearning,
        Channel::Events,
        Channel::Status,
    ];

    /// The channel's topic in the MCAP file and the live view: the contract's topic name
    /// (`messages::topics`) with a leading slash; the camera's header and perception's overlay below
    /// their topics.
    pub fn topic(self) -> &'static str {
        match self {
            Channel::VehicleState => "/vehicle_state",
            Channel::FrameHeader => "/camera_frame/header",
            Channel::Image => "/camera_frame",
            Channel::Observation => "/cable_observation",
            Channel::Annotation => "/cable_observation/overlay",
            Channel::SurgeCommand => "/command/surge",
            Channel::SwayCommand => "/command/sway",
            Channel::YawCommand => "/command/yaw",
            Channel::Setpoints => "/thruster_setpoints",
            Channel::SwayLearning => "/learning/sway",
            Channel::YawLearning => "/learning/yaw",
            Channel::Events => "/supervisor/events",
            Channel::Status => "/recorder/status",
        }
    }

    pub fn from_topic(topic: &str) -> Option<Channel> {
        Channel::ALL.into_iter().find(|c| c.topic() == topic)
    }

    pub fn encoding(self) -> Encoding {
        match self {
            Channel::Image | Channel::Annotation => Encoding::Protobuf,
            _ => Encoding::Json,
        }
    }

    /// The schema's name.
    pub fn schema_name(self) -> &'static str {
        match self {
            Channel::VehicleState => "cabletrack.VehicleState",
            Channel::FrameHeader => "cabletrack.CameraFrameHeader",
            Channel::Image => "foxglove.RawImage",
            Channel::Observation => "cabletrack.CableObservation",
            Channel::Annotation => "foxglove.ImageAnnotations",
            Channel::SurgeCommand | Channel::SwayCommand | Channel::YawCommand => {
                "cabletrack.DofCommand"
            }
            Channel::Setpoints => "cabletrack.ThrusterSetpoints",
            Channel::SwayLearning | Channel::YawLearning => "cabletrack.LearningStats",
            Channel::Events => "cabletrack.SupervisorEvent",
            Channel::Status => "cabletrack.RecorderStatus",
        }
    }

    /// The JSON Schema of a JSON channel.
    pub fn json_schema(self) -> Option<Value> {
        Some(match self {
            Channel::VehicleState => json::vehicle_state_schema(),
            Channel::FrameHeader => json::frame_header_schema(),
            Channel::Observation => json::observation_msg_schema(),
            Channel::SurgeCommand | Channel::SwayCommand | Channel::YawCommand => {
                json::command_schema()
            }
            Channel::Setpoints => json::setpoints_schema(),
            Channel::SwayLearning | Channel::YawLearning => json::learning_schema(),
            Channel::Events => json::event_schema(),
            Channel::Status => json::status_schema(),
            Channel::Image | Channel::Annotation => return None,
        })
    }

    /// The iceoryx2 topic (below `cabletrack/<endpoint>/`) the channel records.
    pub fn source(self) -> &'static str {
        use messages::topics as t;
        match self {
            Channel::VehicleState => t::VEHICLE_STATE.name,
            Channel::FrameHeader | Channel::Image => t::CAMERA_FRAME.name,
            Channel::Observation | Channel::Annotation => t::CABLE_OBSERVATION.name,
            Channel::SurgeCommand => t::SURGE_COMMAND.name,
            Channel::SwayCommand => t::SWAY_COMMAND.name,
            Channel::YawCommand => t::YAW_COMMAND.name,
            Channel::Setpoints => t::THRUSTER_SETPOINTS.name,
            Channel::SwayLearning => t::SWAY_LEARNING.name,
            Channel::YawLearning => t::YAW_LEARNING.name,
            Channel::Events => t::SUPERVISOR_EVENTS.name,
            Channel::Status => t::RECORDER_STATUS.name,
        }
    }

    /// A message of this channel belongs to one control step (it carries a `Stamp`).
    pub fn per_step(self) -> bool {
        matches!(
            self,
            Channel::VehicleState
                | Channel::FrameHeader
                | Channel::Observation
                | Channel::SurgeCommand
                | Channel::SwayCommand
                | Channel::YawCommand
                | Channel::Setpoints
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn topics_follow_the_contract_and_are_unique() {
        for c in Channel::ALL {
            assert!(
                c.topic().starts_with(&format!("/{}", c.source())),
                "{c:?}: {} records {}",
                c.topic(),
                c.source()
            );
            assert_eq!(Channel::from_topic(c.topic()), Some(c));
            assert_eq!(
                c.json_schema().is_some(),
                c.encoding() == Encoding::Json,
                "{c:?}"
            );
            if let Some(s) = c.json_schema() {
                assert_eq!(s["title"], c.schema_name(), "{c:?}");
            }
        }
        let mut topics: Vec<&str> = Channel::ALL.iter().map(|c| c.topic()).collect();
        topics.sort();
        topics.dedup();
        assert_eq!(topics.len(), Channel::ALL.len());
        for d in CommandDof::ALL {
            assert_eq!(d.channel().source(), d.topic().name);
        }
    }
}
