//! The payloads' JSON form and its JSON Schema (the flight record writes every payload but the
//! images this way), derived from the payloads themselves: `serde` for the form, `schemars` for the
//! schema, the payloads' doc comments for its descriptions. The form is the payload's fields without
//! its padding, in the payload's units; reading it back gives the very payload written, bit for bit
//! (numbers are written in their shortest exact form and read with `serde_json`'s exact parser), so
//! a replay can compare outputs bit for bit.
//!
//! What a field's plain form would get wrong has a helper here, named in the field's
//! `#[serde(with = "...")]` (each helper is both serde's `with` module and the schema's type):
//! - [`NumberOrNull`], [`NumbersOrNull`]: JSON has no NaN or infinity; a number that is not finite
//!   is written `null` and read back as NaN.
//! - [`Flag`]: a `u8` that says yes or no, as a boolean.
//! - [`Text`]: a fixed, NUL-padded UTF-8 name, as a string.
//! - [`EventKind`], and the codes [`StepStatusCode`], [`StopCauseCode`] (schema only: their values).
//!
//! A fixed array with a separate count (the thruster setpoints) is written as its used part; one
//! field cannot see another, so such a payload converts to a form of its own (`#[serde(into, from)]`).

use crate::payload::{ServiceEvent, StopCause};
use config::StepStatus;
use iceoryx2::prelude::ZeroCopySend;
use schemars::generate::{Contract, SchemaSettings};
use schemars::{JsonSchema, Schema, SchemaGenerator, json_schema};
use serde::{Deserialize, Deserializer, Serialize, Serializer};
use std::borrow::Cow;

/// The JSON Schema of payload `T`'s JSON form, titled `title`: draft 2020-12, describing what is
/// written (every field required), every part inline (some viewers do not follow `$ref`s), each
/// description one line as a viewer shows it (a doc comment's lines joined).
pub fn schema<T: JsonSchema>(title: &str) -> serde_json::Value {
    let mut settings = SchemaSettings::draft2020_12();
    settings.inline_subschemas = true;
    settings.contract = Contract::Serialize;
    let mut schema = settings.into_generator().into_root_schema_for::<T>();
    schema.insert("title".into(), title.into());
    let mut schema = schema.to_value();
    join_lines(&mut schema);
    schema
}

fn join_lines(v: &mut serde_json::Value) {
    use serde_json::Value;
    match v {
        Value::Object(map) => {
            for (k, v) in map.iter_mut() {
                match v {
                    Value::String(text) if k == "description" => {
                        *text = text.split_whitespace().collect::<Vec<_>>().join(" ");
                    }
                    v => join_lines(v),
                }
            }
        }
        Value::Array(items) => items.iter_mut().for_each(join_lines),
        _ => {}
    }
}

/// The name of payload `T`'s schema: its versioned type name without the version, with dots
/// (`cabletrack::VehicleState/2` is `cabletrack.VehicleState`), so a payload has one name.
pub fn schema_name<T: ZeroCopySend>() -> String {
    // SAFETY: reading the name has no precondition; the trait's safety contract binds the types
    // that implement it (the same name for the same layout).
    let versioned = unsafe { <T as ZeroCopySend>::type_name() };
    let name = versioned.split_once('/').map_or(versioned, |(n, _)| n);
    name.replace("::", ".")
}

/// A helper's schema, inline where it is used (it is a field's form, not a type of its own).
macro_rules! inline_schema {
    ($t:ident, |$g:tt| $schema:block) => {
        impl JsonSchema for $t {
            fn schema_name() -> Cow<'static, str> {
                stringify!($t).into()
            }

            fn inline_schema() -> bool {
                true
            }

            fn json_schema($g: &mut SchemaGenerator) -> Schema {
                $schema
            }
        }
    };
}

fn number_or_null() -> Schema {
    json_schema!({"type": ["number", "null"]})
}

/// An `f64` that may be non-finite: written `null`, read back as NaN.
pub enum NumberOrNull {}

impl NumberOrNull {
    pub fn serialize<S: Serializer>(v: &f64, s: S) -> Result<S::Ok, S::Error> {
        v.is_finite().then_some(*v).serialize(s)
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
        Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
    }

    /// A number a record of an older format does not hold (`#[serde(default = "...")]`).
    pub fn missing() -> f64 {
        f64::NAN
    }
}

inline_schema!(NumberOrNull, |_| { number_or_null() });

/// An `[f64; N]` whose numbers may be non-finite, each as [`NumberOrNull`].
pub struct NumbersOrNull<const N: usize>;

impl<const N: usize> NumbersOrNull<N> {
    pub fn serialize<S: Serializer>(v: &[f64; N], s: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeTuple;
        let mut t = s.serialize_tuple(N)?;
        for x in v {
            t.serialize_element(&x.is_finite().then_some(*x))?;
        }
        t.end()
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<[f64; N], D::Error> {
        let v = Vec::<Option<f64>>::deserialize(d)?;
        let n = v.len();
        let numbers: Vec<f64> = v.into_iter().map(|x| x.unwrap_or(f64::NAN)).collect();
        numbers.try_into().map_err(|_| {
            serde::de::Error::invalid_length(n, &format!("an array of {N} numbers").as_str())
        })
    }
}

impl<const N: usize> JsonSchema for NumbersOrNull<N> {
    fn schema_name() -> Cow<'static, str> {
        format!("NumbersOrNull{N}").into()
    }

    fn inline_schema() -> bool {
        true
    }

    fn json_schema(_: &mut SchemaGenerator) -> Schema {
        json_schema!({
            "type": "array",
            "items": number_or_null(),
            "minItems": N,
            "maxItems": N,
        })
    }
}

/// A `u8` that says yes (not 0) or no (0), as a boolean; read back as 1 or 0.
pub enum Flag {}

impl Flag {
    pub fn serialize<S: Serializer>(v: &u8, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_bool(*v != 0)
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<u8, D::Error> {
        Ok(bool::deserialize(d)? as u8)
    }
}

inline_schema!(Flag, |g| { bool::json_schema(g) });

/// A fixed, NUL-padded UTF-8 name of at most `N` bytes, as a string (invalid UTF-8 is replaced);
/// read back cut at a character boundary to fit.
pub struct Text<const N: usize>;

impl<const N: usize> Text<N> {
    /// The name in `bytes`: up to the first NUL.
    pub fn of(bytes: &[u8; N]) -> Cow<'_, str> {
        let end = bytes.iter().position(|&b| b == 0).unwrap_or(N);
        String::from_utf8_lossy(&bytes[..end])
    }

    /// `name` in `N` bytes, NUL-padded; a longer name is cut at a character boundary.
    pub fn to_bytes(name: &str) -> [u8; N] {
        let mut out = [0u8; N];
        let mut end = name.len().min(N);
        while !name.is_char_boundary(end) {
            end -= 1;
        }
        out[..end].copy_from_slice(&name.as_bytes()[..end]);
        out
    }

    pub fn serialize<S: Serializer>(v: &[u8; N], s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(&Self::of(v))
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<[u8; N], D::Error> {
        Ok(Self::to_bytes(&String::deserialize(d)?))
    }
}

impl<const N: usize> JsonSchema for Text<N> {
    fn schema_name() -> Cow<'static, str> {
        format!("Text{N}").into()
    }

    fn inline_schema() -> bool {
        true
    }

    fn json_schema(_: &mut SchemaGenerator) -> Schema {
        json_schema!({"type": "string", "maxLength": N})
    }
}

/// A [`ServiceEvent`] (`u8`) by its name; an unknown value (a newer supervisor) as `unknown-N`.
pub enum EventKind {}

impl EventKind {
    pub fn serialize<S: Serializer>(v: &u8, s: S) -> Result<S::Ok, S::Error> {
        match ServiceEvent::from_u8(*v) {
            Some(k) => s.serialize_str(k.name()),
            None => s.serialize_str(&format!("unknown-{v}")),
        }
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<u8, D::Error> {
        let name = String::deserialize(d)?;
        if let Some(k) = ServiceEvent::ALL.into_iter().find(|k| k.name() == name) {
            return Ok(k as u8);
        }
        Ok(name
            .strip_prefix("unknown-")
            .and_then(|n| n.parse().ok())
            .unwrap_or(0))
    }
}

inline_schema!(EventKind, |_| { json_schema!({"type": "string"}) });

/// The schema of a [`StepStatus`] carried as `u8`: its values.
pub enum StepStatusCode {}

inline_schema!(StepStatusCode, |_| {
    let values: Vec<u8> = (0..=u8::MAX)
        .filter(|&v| StepStatus::from_u8(v).is_some())
        .collect();
    json_schema!({"type": "integer", "enum": values})
});

/// The schema of a failsafe stop's cause carried as `u32`: 0 (none) or a [`StopCause`]'s value.
pub enum StopCauseCode {}

inline_schema!(StopCauseCode, |_| {
    let values: Vec<u32> = std::iter::once(0)
        .chain(StopCause::ALL.map(|c| c as u32))
        .collect();
    json_schema!({"type": "integer", "enum": values})
});

#[cfg(test)]
mod tests {
    use super::*;
    use crate::payload::*;
    use serde_json::{Value, json};

    fn stamp() -> Stamp {
        Stamp::new(
            1_700_000_000_123_456,
            9_400_000_000,
            3,
            47,
            StepStatus::Lost,
        )
        .timed(9, 77)
    }

    fn obs() -> CableObservationData {
        CableObservationData {
            found: 1,
            rho: -12.25,
            theta: 0.1 + 0.2,
            x_g: -1.0 / 3.0,
            y_g: 1e-300,
            x_g_rate: f64::MIN_POSITIVE,
            theta_rate: -0.0,
            confidence: 0.875,
            ..Default::default()
        }
    }

    /// Bit for bit: NaN is not equal to itself, and -0.0 equals 0.0.
    fn same_bits<P: Serialize>(a: &P, b: &P) -> bool {
        // The derived form without the null rule: every f64 as its bits.
        fn bits(v: Value) -> Value {
            match v {
                Value::Array(a) => Value::Array(a.into_iter().map(bits).collect()),
                Value::Object(m) => m.into_iter().map(|(k, v)| (k, bits(v))).collect(),
                Value::Number(n) if n.is_f64() => json!(n.as_f64().unwrap().to_bits()),
                v => v,
            }
        }
        bits(serde_json::to_value(a).unwrap()) == bits(serde_json::to_value(b).unwrap())
    }

    /// Writes `msg` as JSON and reads it back: the same payload, bit for bit.
    fn round_trip<P>(msg: &P) -> String
    where
        P: Serialize + for<'de> Deserialize<'de> + PartialEq + std::fmt::Debug,
    {
        let text = serde_json::to_string(msg).unwrap();
        let back: P = serde_json::from_str(&text).unwrap();
        assert_eq!(&back, msg, "{text}");
        assert!(same_bits(&back, msg), "{text}");
        text
    }

    #[test]
    fn every_payload_reads_back_exactly() {
        let stamp = stamp();
        round_trip(&VehicleStateMsg {
            stamp,
            x: 1.5,
            y: -0.1,
            psi: std::f64::consts::PI,
            u: 0.3,
            v: 1e-17,
            r: -2.5e-3,
            x_rate: 0.30000000000000004,
            y_rate: 0.0,
            psi_rate: 7.0,
        });
        round_trip(&CameraFrameHeader {
            stamp,
            width: 320,
            height: 240,
            flags: CameraFrameHeader::DAMAGED,
            _reserved: [0; 4],
            truth: obs(),
        });
        round_trip(&CableObservationMsg {
            stamp,
            observation: obs(),
        });
        round_trip(&DofCommand {
            stamp,
            value: -0.7071067811865475,
        });
        let mut values = [0.0; config::MAX_THRUSTERS];
        values[..3].copy_from_slice(&[0.61, -1.0, 1.0 / 7.0]);
        let setpoints = ThrusterSetpoints {
            stamp,
            count: 3,
            missing: 0b101,
            stop: 2,
            _reserved: 0,
            values,
            scale: 0.9,
        };
        let text = round_trip(&setpoints);
        assert!(
            text.contains(r#""values":[0.61,-1.0,0.14285714285714285]"#),
            "{text}"
        );
        round_trip(&LearningStats {
            stamp,
            episode_return: -11.57,
            gain: [4.65, -6.54],
            actor_updates: 12,
            steps: 450,
            failed: 1,
            learning: 1,
            evaluation: 0,
            rolled_back: 1,
            bounded: 3,
            refused: 1,
            rollbacks: 2,
            evaluated: -9.25,
            best_evaluated: -8.5,
        });
        let text = round_trip(&SupervisorEvent {
            pid: 4242,
            status: -9,
            restarts: 2,
            detail: 1,
            ..SupervisorEvent::new(7, 1 << 62, ServiceEvent::Stopped, "camera")
        });
        assert!(text.contains(r#""kind":"stopped""#) && text.contains(r#""service":"camera""#));
        round_trip(&RecorderStatus {
            seq: 2,
            wall_time_ns: 5,
            messages: 100,
            flushed_messages: 90,
            bytes: 1 << 20,
            holes: 1,
            repeats: 3,
            part: 1,
            _reserved: 0,
        });
    }

    #[test]
    fn a_number_that_is_not_finite_is_written_as_null_and_read_as_nan() {
        let c = DofCommand {
            stamp: stamp(),
            value: f64::INFINITY,
        };
        let text = serde_json::to_string(&c).unwrap();
        assert!(text.contains(r#""value":null"#), "{text}");
        let back: DofCommand = serde_json::from_str(&text).unwrap();
        assert!(back.value.is_nan());
        let s = LearningStats {
            evaluated: f64::NAN,
            gain: [f64::NEG_INFINITY, 2.0],
            ..Default::default()
        };
        let text = serde_json::to_string(&s).unwrap();
        assert!(text.contains(r#""gain":[null,2.0]"#), "{text}");
        let back: LearningStats = serde_json::from_str(&text).unwrap();
        assert!(back.evaluated.is_nan() && back.gain[0].is_nan() && back.gain[1] == 2.0);
        let three = text.replace(r#""gain":[null,2.0]"#, r#""gain":[1.0,2.0,3.0]"#);
        let err = serde_json::from_str::<LearningStats>(&three).unwrap_err();
        assert!(err.to_string().contains("2 numbers"), "{err}");
        let mut values = [0.0; config::MAX_THRUSTERS];
        values[1] = f64::NAN;
        let nan = ThrusterSetpoints {
            count: 2,
            values,
            ..Default::default()
        };
        let text = serde_json::to_string(&nan).unwrap();
        assert!(text.contains(r#""values":[0.0,null]"#), "{text}");
        let back: ThrusterSetpoints = serde_json::from_str(&text).unwrap();
        assert!(same_bits(&back, &nan) && back.count == 2);
    }

    /// Records written before the vehicle clock, the epoch and step two's safety layer read with
    /// those fields at their defaults; a newer supervisor's event kind and a name too long keep
    /// what they can.
    #[test]
    fn older_and_newer_forms_read_as_far_as_they_go() {
        let old = r#"{"stamp":{"seq":5,"time_ns":10,"episode":1,"step":2,"status":0},
            "episode_return":-3.5,"gain":[1.0,2.0],"actor_updates":4,"steps":20,
            "failed":false,"learning":true}"#;
        let s: LearningStats = serde_json::from_str(old).unwrap();
        assert_eq!((s.stamp.seq, s.stamp.clock_ns, s.stamp.epoch), (5, 0, 0));
        assert_eq!(
            (s.evaluation, s.rolled_back, s.bounded, s.refused),
            (0, 0, 0, 0)
        );
        assert!(s.evaluated.is_nan() && s.best_evaluated.is_nan());
        assert_eq!((s.learning, s.failed), (1, 0));

        let event = r#"{"seq":1,"wall_time_ns":2,"kind":"unknown-9","pid":3,"status":0,
            "restarts":0,"detail":0,"service":"a-service-name-longer-than-thirty-two-bytes"}"#;
        let e: SupervisorEvent = serde_json::from_str(event).unwrap();
        assert_eq!((e.kind, e.kind()), (9, None));
        assert_eq!(e.service(), "a-service-name-longer-than-thirt");
        assert!(
            serde_json::to_string(&e)
                .unwrap()
                .contains(r#""kind":"unknown-9""#)
        );
        let setpoints = r#"{"stamp":{"seq":1,"time_ns":2,"episode":0,"step":0,"status":0},
            "values":[0.5],"missing":0,"scale":1.0}"#;
        let s: ThrusterSetpoints = serde_json::from_str(setpoints).unwrap();
        assert_eq!((s.as_slice(), s.stop_cause()), (&[0.5][..], None));
    }

    #[test]
    fn schemas_are_inline_titled_and_list_what_is_written() {
        assert_eq!(schema_name::<VehicleStateMsg>(), "cabletrack.VehicleState");
        assert_eq!(
            schema_name::<CableObservationMsg>(),
            "cabletrack.CableObservation"
        );
        let s = schema::<ThrusterSetpoints>("cabletrack.ThrusterSetpoints");
        assert_eq!(s["title"], "cabletrack.ThrusterSetpoints");
        assert_eq!(s["$schema"], "https://json-schema.org/draft/2020-12/schema");
        assert!(!s.to_string().contains("$ref"), "{s:#}");
        let mut required: Vec<&str> = s["required"]
            .as_array()
            .unwrap()
            .iter()
            .filter_map(Value::as_str)
            .collect();
        required.sort();
        assert_eq!(required, ["missing", "scale", "stamp", "stop", "values"]);
        assert_eq!(s["properties"]["stop"]["enum"], json!([0, 1, 2, 3, 4, 255]));
        assert_eq!(
            s["properties"]["stamp"]["properties"]["status"]["enum"],
            json!([0, 1, 2])
        );
        assert_eq!(
            s["properties"]["values"]["maxItems"],
            json!(config::MAX_THRUSTERS)
        );
        let e = schema::<SupervisorEvent>("e");
        assert!(
            e["properties"].get("_pad").is_none() && e["properties"].get("_reserved").is_none()
        );
        assert_eq!(e["properties"]["kind"]["type"], "string");
        // The field's doc comment is its description.
        let v = schema::<VehicleStateMsg>("v");
        assert_eq!(v["properties"]["u"]["description"], "Surge velocity, m/s.");
        assert_eq!(v["properties"]["u"]["type"], json!(["number", "null"]));
        let stamp = &v["properties"]["stamp"]["properties"]["status"]["description"];
        assert_eq!(
            stamp,
            "The episode's status at this step (`StepStatus` as u8): 0 running, 1 cable lost, 2 \
             time limit."
        );
    }
}
