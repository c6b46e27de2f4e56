//! The configuration files (`shared/config`: scenario, learning, twin, autopilot): any text must
//! parse and validate or be refused with an error.
#![no_main]
use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let Some((&which, text)) = data.split_first() else {
        return;
    };
    let Ok(text) = std::str::from_utf8(text) else {
        return;
    };
    let path = Path::new("fuzz.toml");
    let _ = match which % 4 {
        0 => config::parse::<config::Scenario>(text, path).map(|_| ()),
        1 => config::parse::<config::LearningParams>(text, path).map(|_| ()),
        2 => config::parse::<config::TwinParams>(text, path).map(|_| ()),
        _ => config::parse::<config::AutopilotParams>(text, path).map(|_| ()),
    };
});
