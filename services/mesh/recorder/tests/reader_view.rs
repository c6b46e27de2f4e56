//! What a reader of a flight record sees stays what it was: the channels' names and encodings, the
//! schemas' names, the property paths of their JSON Schemas with their types, and how a message is
//! written. The view of a synthetic record with every channel is kept in
//! `tests/fixtures/reader_view.json`; a change to the record's format shows here as a difference,
//! and is made on purpose by writing the fixture again (`RECORDER_FIXTURE=write`) and committing it.
//! Descriptions are not part of the view: their wording may change.

use crate::every_channel;

use serde_json::Value;
use std::path::Path;

#[test]
fn a_reader_sees_the_channels_schemas_and_messages_of_the_fixture() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("every-channel.mcap");
    every_channel::write(&path);
    let view = every_channel::reader_view(&path);
    let fixture = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/reader_view.json");
    if std::env::var("RECORDER_FIXTURE").as_deref() == Ok("write") {
        std::fs::create_dir_all(fixture.parent().unwrap()).unwrap();
        std::fs::write(
            &fixture,
            serde_json::to_string_pretty(&view).unwrap() + "\n",
        )
        .unwrap();
    }
    let want: Value = serde_json::from_str(
        &std::fs::read_to_string(&fixture).unwrap_or_else(|e| panic!("{}: {e}", fixture.display())),
    )
    .unwrap_or_else(|e| panic!("{}: {e}", fixture.display()));
    let (got, want) = (view.as_object().unwrap(), want.as_object().unwrap());
    assert_eq!(
        got.keys().collect::<Vec<_>>(),
        want.keys().collect::<Vec<_>>(),
        "the record's topics"
    );
    for (topic, w) in want {
        let g = &got[topic];
        for (key, wv) in w.as_object().unwrap() {
            assert_eq!(
                &g[key],
                wv,
                "{topic}: {key} differs from {}",
                fixture.display()
            );
        }
        assert_eq!(
            g.as_object().unwrap().len(),
            w.as_object().unwrap().len(),
            "{topic}: {g:#}"
        );
    }
}

/// The view follows `$ref`s and marks optional properties, so a schema that moves its parts into
/// `$defs` shows the same paths and one that stops requiring a property does not.
#[test]
fn property_paths_follow_references_and_mark_optional_properties() {
    let inline: Value = serde_json::json!({
        "type": "object",
        "required": ["stamp", "values"],
        "properties": {
            "stamp": {"type": "object", "required": ["seq"], "properties": {"seq": {"type": "integer"}}},
            "values": {"type": "array", "items": {"type": ["number", "null"]}},
        }
    });
    let referenced: Value = serde_json::json!({
        "type": "object",
        "required": ["stamp", "values"],
        "properties": {
            "stamp": {"$ref": "#/$defs/Stamp"},
            "values": {"type": "array", "items": {"type": ["null", "number"]}},
        },
        "$defs": {"Stamp": {"type": "object", "required": ["seq"], "properties": {"seq": {"type": "integer"}}}}
    });
    let paths = every_channel::property_paths(&inline);
    assert_eq!(paths, every_channel::property_paths(&referenced));
    assert_eq!(
        paths.into_iter().collect::<Vec<_>>(),
        [
            ("stamp", "object"),
            ("stamp.seq", "integer"),
            ("values", "array"),
            ("values[]", "null|number"),
        ]
        .map(|(p, t)| (p.to_owned(), t.to_owned()))
    );
    let mut loose = inline.clone();
    loose["required"] = serde_json::json!(["stamp"]);
    assert_eq!(
        every_channel::property_paths(&loose)["values"],
        "array optional"
    );
}
