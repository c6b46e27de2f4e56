//! The channels of a flight record, in one table: one channel per topic of the endpoint (the camera's
//! topic gives three: its header as JSON, its image, and perception's estimate drawn over it).
//!
//! A JSON channel records a payload of the messages contract in the JSON form the payload derives,
//! with the JSON Schema it derives (`messages::json`): the schema is named after the payload's type
//! name (`cabletrack::VehicleState/2` gives `cabletrack.VehicleState`), its descriptions are the
//! payload's doc comments. Adding a payload to the record takes its derives (`Serialize`,
//! `Deserialize`, `JsonSchema`) and one line in the table below; the line gives the kind of
//! [`Recorded`] message, the channel, its topic in the record, the contract's topic it records, how
//! a message is kept once (`each_step`: a message of every control step, whose missed steps count
//! as holes; `stamped`: stamped, not every step; `by_seq`: no stamp, numbered by its `seq`;
//! `by_clock`: no stamp, ordered by the vehicle clock of its arrival, `clock_ns`, which goes on
//! across a publisher's restarts where its `seq` starts again), and
//! whether the recorder subscribes to it as it is (`tap`) or writes it itself (`own`: the frames'
//! headers come with their images, the status is the recorder's own).

use crate::FlightRecorder;
use crate::image::{Image, Video};
use config::Dof;
use messages::topics;
use messages::{
    AutopilotAttitude, AutopilotDepth, AutopilotState, CableObservationMsg, CameraFrameHeader,
    DofCommand, LearningStats, PortError, RecorderStatus, ServoOutputs, Stamp, StatusText,
    SupervisorEvent, ThrusterSetpoints, VehicleStateMsg, VideoUnit,
};
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
            CommandDof::Surge => topics::SURGE_COMMAND,
            CommandDof::Sway => topics::SWAY_COMMAND,
            CommandDof::Yaw => topics::YAW_COMMAND,
        }
    }

    pub fn channel(self) -> Channel {
        Recorded::Command(self, DofCommand::default()).channel()
    }
}

/// How a channel's messages are encoded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Encoding {
    /// JSON with a JSON Schema (`messages::json`).
    Json,
    /// A Foxglove well-known schema, protobuf-encoded (the schema is its FileDescriptorSet).
    Protobuf,
}

/// How a recorded message is kept once (`crate::keep`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Key {
    /// By its step: a message of every control step, whose missed steps are holes.
    EachStep(Stamp),
    /// By its step: stamped, but not every step has one (the episode reports).
    Stamped(Stamp),
    /// By its own sequence number (no stamp: the supervisor's events, the recorder's status).
    Seq(u64),
}

/// The recorder's subscription of one channel's topic.
pub trait Drain {
    /// Writes every message waiting in the subscription into `rec`.
    fn drain(&self, rec: &mut FlightRecorder) -> Result<(), PortError>;
}

struct Plain<P: messages::ports::Payload> {
    tap: messages::Tap<P>,
    wrap: fn(P) -> Recorded,
}

impl<P: messages::ports::Payload> Drain for Plain<P> {
    fn drain(&self, rec: &mut FlightRecorder) -> Result<(), PortError> {
        while let Some(m) = self.tap.receive()? {
            rec.log(&(self.wrap)(m));
        }
        Ok(())
    }
}

macro_rules! key {
    (each_step, $m:expr) => {
        Key::EachStep($m.stamp)
    };
    (stamped, $m:expr) => {
        Key::Stamped($m.stamp)
    };
    (by_seq, $m:expr) => {
        Key::Seq($m.seq)
    };
    // The vehicle clock is signed: flipping the sign bit keeps its order in the key's u64.
    (by_clock, $m:expr) => {
        Key::Seq(($m.clock_ns as u64) ^ (1 << 63))
    };
    // A video unit: its number within the camera's epoch (kept by `Keeper::video`).
    (by_unit, $m:expr) => {
        Key::Seq((($m.epoch as u64) << 32) | ($m.number & 0xFFFF_FFFF))
    };
}

macro_rules! per_step {
    (each_step) => {
        true
    };
    (stamped) => {
        false
    };
    (by_seq) => {
        false
    };
    (by_clock) => {
        false
    };
    (by_unit) => {
        false
    };
}

macro_rules! tap {
    (tap, $rt:ident, $source:expr, $wrap:expr) => {
        Some(Box::new(Plain {
            tap: $rt.tap(&$source)?,
            wrap: $wrap,
        }) as Box<dyn Drain>)
    };
    (own, $rt:ident, $source:expr, $wrap:expr) => {
        None
    };
}

macro_rules! flight_record {
    ($(
        $(#[$kind_doc:meta])*
        $kind:ident($payload:ty) $(by $key_type:ty)?, $keep:ident {$(
            $(#[$doc:meta])*
            $channel:ident $(($key:path))? = $topic:literal <- $source:expr, $sub:ident;
        )+}
    )+) => {
        /// A channel of the flight record.
        #[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
        pub enum Channel {
            $($($(#[$doc])* $channel,)+)+
            /// The camera's images, `foxglove.RawImage` `mono8`, decimated by `--frame-every` (and
            /// `--video-frame-every` where the compressed stream gives the frame).
            Image,
            /// Perception's estimate drawn over the image (`foxglove.ImageAnnotations`), for the
            /// frames whose image is recorded.
            Annotation,
            /// The camera's compressed stream as it arrived (`foxglove.CompressedVideo`, H.264),
            /// an access unit a message.
            Video,
        }

        /// A recorded message, as the mesh sent it.
        #[derive(Clone, Debug, PartialEq)]
        pub enum Recorded {
            $($(#[$kind_doc])* $kind($($key_type,)? $payload),)+
            Image(Image),
            /// Perception's overlay (not decoded: it is drawn from the observation).
            Overlay,
            Video(Video),
        }

        impl Channel {
            pub const ALL: [Channel; [$($(stringify!($channel),)+)+ "Image", "Annotation", "Video"].len()] =
                [$($(Channel::$channel,)+)+ Channel::Image, Channel::Annotation, Channel::Video];

            /// The channel's topic in the MCAP file and the live view: the contract's topic name
            /// (`messages::topics`) with a leading slash; the camera's header and perception's
            /// overlay below their topics.
            pub fn topic(self) -> &'static str {
                match self {
                    $($(Channel::$channel => $topic,)+)+
                    Channel::Image => "/camera_frame",
                    Channel::Annotation => "/cable_observation/overlay",
                    Channel::Video => "/camera_video",
                }
            }

            /// The iceoryx2 topic (below `cabletrack/<endpoint>/`) the channel records.
            pub fn source(self) -> &'static str {
                match self {
                    $($(Channel::$channel => $source.name,)+)+
                    Channel::Image => topics::CAMERA_FRAME.name,
                    Channel::Annotation => topics::CABLE_OBSERVATION.name,
                    Channel::Video => topics::CAMERA_VIDEO.name,
                }
            }

            /// The schema's name: the payload's type name for a JSON channel.
            pub fn schema_name(self) -> String {
                match self {
                    $($(Channel::$channel)|+ => messages::json::schema_name::<$payload>(),)+
                    Channel::Image => "foxglove.RawImage".into(),
                    Channel::Annotation => "foxglove.ImageAnnotations".into(),
                    Channel::Video => "foxglove.CompressedVideo".into(),
                }
            }

            /// The JSON Schema of a JSON channel, derived from its payload.
            pub fn json_schema(self) -> Option<Value> {
                match self {
                    $($(Channel::$channel)|+ => Some(messages::json::schema::<$payload>(
                        &self.schema_name(),
                    )),)+
                    Channel::Image | Channel::Annotation | Channel::Video => None,
                }
            }

            /// A message of this channel belongs to each control step: a step it missed while
            /// other channels had it is a hole.
            pub fn per_step(self) -> bool {
                match self {
                    $($(Channel::$channel)|+ => per_step!($keep),)+
                    Channel::Image | Channel::Annotation | Channel::Video => false,
                }
            }
        }

        impl Recorded {
            /// The channel the message is recorded on.
            pub fn channel(&self) -> Channel {
                match self {
                    $($(Recorded::$kind($($key,)? _) => Channel::$channel,)+)+
                    Recorded::Image(_) => Channel::Image,
                    Recorded::Overlay => Channel::Annotation,
                    Recorded::Video(_) => Channel::Video,
                }
            }

            /// How the message is kept once; `None` for an image or an overlay (written with their
            /// frame, `FlightRecorder::frame`) or a video unit (`FlightRecorder::video`).
            pub fn key(&self) -> Option<Key> {
                match self {
                    $(Recorded::$kind(.., m) => Some(key!($keep, m)),)+
                    Recorded::Image(_) | Recorded::Overlay | Recorded::Video(_) => None,
                }
            }

            /// Writes the message's JSON form; `false` for an image or an overlay.
            pub(crate) fn write_json(&self, out: &mut Vec<u8>) -> bool {
                match self {
                    $(Recorded::$kind(.., m) => serde_json::to_writer(out, m).is_ok(),)+
                    Recorded::Image(_) | Recorded::Overlay | Recorded::Video(_) => false,
                }
            }

            /// A message of JSON channel `channel` from its bytes.
            pub(crate) fn from_json(channel: Channel, data: &[u8]) -> Result<Recorded, String> {
                let e = |e: serde_json::Error| e.to_string();
                Ok(match channel {
                    $($(Channel::$channel => Recorded::$kind(
                        $($key,)? serde_json::from_slice(data).map_err(e)?
                    ),)+)+
                    Channel::Image | Channel::Annotation | Channel::Video => {
                        return Err(format!("{} is not a JSON channel", channel.topic()));
                    }
                })
            }
        }

        /// The recorder's subscriptions of the channels it records as they are (`tap` in the
        /// table), in the table's order.
        pub fn taps(rt: &runtime::Runtime) -> Result<Vec<Box<dyn Drain>>, PortError> {
            let taps: [Option<Box<dyn Drain>>; Channel::ALL.len() - 3] = [
                $($(tap!($sub, rt, $source, |m| Recorded::$kind($($key,)? m)),)+)+
            ];
            Ok(taps.into_iter().flatten().collect())
        }
    };
}

flight_record! {
    /// The vehicle's state (the sim endpoint's simulator; nobody publishes it on the vehicle).
    State(VehicleStateMsg), each_step {
        VehicleState = "/vehicle_state" <- topics::VEHICLE_STATE, tap;
    }
    /// Each camera frame's header: its step and the true line where known.
    FrameHeader(CameraFrameHeader), each_step {
        FrameHeader = "/camera_frame/header" <- topics::CAMERA_FRAME, own;
    }
    /// Each video unit's header: its number in the decoder's order, its frame's time, keyframe,
    /// damage (written with its unit, `FlightRecorder::video`).
    VideoHeader(VideoUnit), by_unit {
        VideoHeader = "/camera_video/header" <- topics::CAMERA_VIDEO, own;
    }
    /// Perception's estimate.
    Observation(CableObservationMsg), each_step {
        Observation = "/cable_observation" <- topics::CABLE_OBSERVATION, tap;
    }
    Command(DofCommand) by CommandDof, each_step {
        SurgeCommand(CommandDof::Surge) = "/command/surge" <- topics::SURGE_COMMAND, tap;
        SwayCommand(CommandDof::Sway) = "/command/sway" <- topics::SWAY_COMMAND, tap;
        YawCommand(CommandDof::Yaw) = "/command/yaw" <- topics::YAW_COMMAND, tap;
    }
    Setpoints(ThrusterSetpoints), each_step {
        Setpoints = "/thruster_setpoints" <- topics::THRUSTER_SETPOINTS, tap;
    }
    /// A behaviour's report at the end of an episode.
    Learning(LearningStats) by Dof, stamped {
        SwayLearning(Dof::Sway) = "/learning/sway" <- topics::SWAY_LEARNING, tap;
        YawLearning(Dof::Yaw) = "/learning/yaw" <- topics::YAW_LEARNING, tap;
    }
    /// The supervisor's events.
    Event(SupervisorEvent), by_seq { Events = "/supervisor/events" <- topics::SUPERVISOR_EVENTS, tap; }
    /// The recorder's own progress.
    Status(RecorderStatus), by_seq { Status = "/recorder/status" <- topics::RECORDER_STATUS, own; }
    /// The autopilot's telemetry (a vehicle under ArduSub, from the thruster driver that pilots
    /// it): its state, attitude, depth, outputs to the thrusters and texts.
    Autopilot(AutopilotState), by_clock {
        AutopilotState = "/autopilot/state" <- topics::AUTOPILOT_STATE, tap;
    }
    AutopilotAttitude(AutopilotAttitude), by_clock {
        AutopilotAttitude = "/autopilot/attitude" <- topics::AUTOPILOT_ATTITUDE, tap;
    }
    AutopilotDepth(AutopilotDepth), by_clock {
        AutopilotDepth = "/autopilot/depth" <- topics::AUTOPILOT_DEPTH, tap;
    }
    ServoOutputs(ServoOutputs), by_clock {
        ServoOutputs = "/autopilot/servo_outputs" <- topics::AUTOPILOT_SERVO_OUTPUTS, tap;
    }
    StatusText(StatusText), by_clock {
        StatusText = "/autopilot/status_text" <- topics::AUTOPILOT_STATUS_TEXT, tap;
    }
}

impl Channel {
    pub fn from_topic(topic: &str) -> Option<Channel> {
        Channel::ALL.into_iter().find(|c| c.topic() == topic)
    }

    pub fn encoding(self) -> Encoding {
        match self {
            Channel::Image | Channel::Annotation | Channel::Video => Encoding::Protobuf,
            _ => Encoding::Json,
        }
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
        assert_eq!(
            Channel::SwayLearning.source(),
            topics::learning(Dof::Sway).name
        );
    }

    /// Each kind of message is on its own channel, and reads back from its JSON as it was.
    #[test]
    fn a_message_knows_its_channel_and_reads_back_from_its_json() {
        let stamp = Stamp::new(3, 4, 0, 1, messages::StepStatus::Running);
        let items = [
            Recorded::Command(CommandDof::Sway, DofCommand { stamp, value: 0.5 }),
            Recorded::Learning(
                Dof::Yaw,
                LearningStats {
                    stamp,
                    evaluated: -1.0,
                    best_evaluated: -1.0,
                    ..Default::default()
                },
            ),
            Recorded::Event(SupervisorEvent::new(
                2,
                9,
                messages::ServiceEvent::Started,
                "camera",
            )),
            Recorded::Autopilot(AutopilotState {
                seq: 1,
                clock_ns: 77,
                battery_v: f64::NAN,
                armed: 1,
                mode: 19,
                ..Default::default()
            }),
            Recorded::StatusText(StatusText {
                seq: 1,
                clock_ns: 78,
                ..StatusText::new(2, "Lost manual control")
            }),
        ];
        let want = [
            (Channel::SwayCommand, Key::EachStep(stamp)),
            (Channel::YawLearning, Key::Stamped(stamp)),
            (Channel::Events, Key::Seq(2)),
            (Channel::AutopilotState, Key::Seq(77 ^ (1 << 63))),
            (Channel::StatusText, Key::Seq(78 ^ (1 << 63))),
        ];
        for (item, (channel, key)) in items.iter().zip(want) {
            assert_eq!((item.channel(), item.key()), (channel, Some(key)));
            let mut json = Vec::new();
            assert!(item.write_json(&mut json));
            let back = Recorded::from_json(channel, &json).unwrap();
            // NaN (an unknown battery) is null in JSON and NaN again when read.
            if let (Recorded::Autopilot(a), Recorded::Autopilot(b)) = (item, &back) {
                assert!(b.battery_v.is_nan());
                assert_eq!(
                    AutopilotState {
                        battery_v: 0.0,
                        ..*a
                    },
                    AutopilotState {
                        battery_v: 0.0,
                        ..*b
                    }
                );
            } else {
                assert_eq!(&back, item);
            }
        }
        assert!(Channel::Setpoints.per_step() && !Channel::YawLearning.per_step());
        assert!(!Channel::Events.per_step() && !Channel::Image.per_step());
        assert!(Recorded::from_json(Channel::Image, b"{}").is_err());
        assert!(Recorded::from_json(Channel::SwayCommand, b"{\"stamp\":1}").is_err());
    }
}
