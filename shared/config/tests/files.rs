//! The shipped configuration files load, agree with the code's defaults, and bad files are refused
//! with the file and key named.

use config::{ConfigError, LearningParams, Scenario};
use std::path::{Path, PathBuf};

fn repo_config(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../config")
        .join(name)
}

#[test]
fn shipped_scenario_equals_the_defaults() {
    let s: Scenario = config::load(&repo_config("scenario.toml")).unwrap();
    assert_eq!(s, Scenario::default());
}

#[test]
fn shipped_learning_parameters_equal_the_defaults() {
    let l: LearningParams = config::load(&repo_config("learning.toml")).unwrap();
    assert_eq!(l, LearningParams::default());
    // The learning rates are the sweep's choice; the rest is the paper's.
    assert_eq!(
        (l.nac.beta, l.nac.gamma, l.nac.lambda, l.nac.epsilon_deg),
        (0.9, 0.95, 0.8, 1.0)
    );
    assert_eq!(l.policy.sigma, 0.1);
}

#[test]
fn the_paper_preset_uses_the_papers_learning_rate() {
    let p = LearningParams::default().with_preset(config::Preset::Paper);
    assert_eq!((p.nac.alpha.sway, p.nac.alpha.yaw), (0.01, 0.01));
}

#[test]
fn missing_keys_take_their_defaults() {
    let s: Scenario = config::parse("[camera]\nwidth = 640\n", Path::new("x.toml")).unwrap();
    assert_eq!(s.camera.width, 640);
    assert_eq!(s.camera.height, 240);
    assert_eq!(s.model, Scenario::default().model);
}

#[test]
fn an_unknown_key_is_refused_with_file_and_key() {
    let err =
        config::parse::<Scenario>("[camera]\nwidht = 640\n", Path::new("config/scenario.toml"))
            .unwrap_err();
    assert!(matches!(err, ConfigError::Parse { .. }));
    let msg = err.to_string();
    assert!(
        msg.contains("config/scenario.toml") && msg.contains("widht"),
        "{msg}"
    );
}

#[test]
fn an_out_of_range_value_is_refused_with_file_key_and_value() {
    let err = config::parse::<Scenario>(
        "[model.yaw]\nalpha = -1.0\nbeta = 0.0\ngamma = 1.0\ndelta = 0.0\n",
        Path::new("s.toml"),
    )
    .unwrap_err();
    let ConfigError::Invalid { invalid, .. } = &err else {
        panic!("{err}")
    };
    assert_eq!(invalid.key, "model.yaw.alpha");
    assert_eq!(invalid.value, "-1");
    let msg = err.to_string();
    assert!(
        msg.contains("s.toml") && msg.contains("model.yaw.alpha"),
        "{msg}"
    );

    let err =
        config::parse::<LearningParams>("[nac]\ngamma = 1.5\n", Path::new("l.toml")).unwrap_err();
    assert!(err.to_string().contains("nac.gamma"), "{err}");

    // The trust region's smallest bound above its largest.
    let err = config::parse::<LearningParams>(
        "[safety.trust_region]\nmax_action_change = 0.1\nmin_action_change = 0.2\n",
        Path::new("l.toml"),
    )
    .unwrap_err();
    let ConfigError::Invalid { invalid, .. } = &err else {
        panic!("{err}")
    };
    assert_eq!(invalid.key, "safety.trust_region.min_action_change");
    assert_eq!(invalid.value, "0.2");
    assert!(err.to_string().contains("max_action_change (0.1)"), "{err}");

    // More missed frames predicted than a prediction of the identified model is worth.
    let err = config::parse::<Scenario>("[missed_frames]\npredict = 200\n", Path::new("s.toml"))
        .unwrap_err();
    let ConfigError::Invalid { invalid, .. } = &err else {
        panic!("{err}")
    };
    assert_eq!(
        (invalid.key.as_str(), invalid.value.as_str()),
        ("missed_frames.predict", "200")
    );
}

#[test]
fn a_wrong_type_is_refused() {
    let err = config::parse::<Scenario>("[timing]\nmax_steps = \"many\"\n", Path::new("s.toml"))
        .unwrap_err();
    assert!(err.to_string().contains("max_steps"), "{err}");
}

#[test]
fn a_layout_that_cannot_yaw_is_refused() {
    let text = r#"
[[thrusters.thruster]]
name = "a"
x_m = 0.0
y_m = 0.0
heading_deg = 0.0
[[thrusters.thruster]]
name = "b"
x_m = 0.0
y_m = 0.0
heading_deg = 90.0
"#;
    let err = config::parse::<Scenario>(text, Path::new("s.toml")).unwrap_err();
    assert!(err.to_string().contains("thrusters.thruster"), "{err}");
}

#[test]
fn a_missing_file_names_the_path() {
    let err = config::load::<Scenario>(Path::new("/nonexistent/scenario.toml")).unwrap_err();
    assert!(matches!(err, ConfigError::Read { .. }));
    assert!(err.to_string().contains("/nonexistent/scenario.toml"));
}

#[test]
fn derived_seeds_differ_per_stream_and_are_stable() {
    assert_eq!(
        config::derive_seed(1, "sway"),
        config::derive_seed(1, "sway")
    );
    assert_ne!(
        config::derive_seed(1, "sway"),
        config::derive_seed(1, "yaw")
    );
    assert_ne!(
        config::derive_seed(1, "sway"),
        config::derive_seed(2, "sway")
    );
}
