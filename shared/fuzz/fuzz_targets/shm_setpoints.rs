//! Thruster setpoints from shared memory, as the thruster driver takes them
//! (`thruster_driver::Driver::on_setpoints`): `ThrusterSetpoints` of any bytes, time passing between
//! them (2 bytes of microseconds), the failsafe's deadline checked after each.
#![no_main]
use adapters::record::NullSink;
use cabletrack_fuzz::{take, take_u64};
use libfuzzer_sys::fuzz_target;
use messages::ThrusterSetpoints;
use runtime::screen::{Screen, ScreenLimits};
use thruster_driver::{Driver, Taken};

fuzz_target!(|data: &[u8]| {
    let mut rest = data;
    let mut driver = Driver::new(
        NullSink::new(3).expect("a sink of 3 thrusters"),
        Screen::new("setpoints", ScreenLimits::control(0.2)),
    );
    driver.start().expect("the sink starts");
    let mut now_ns = 3_600_000_000_000i64;
    while !rest.is_empty() {
        now_ns += take_u64(&mut rest, 2) as i64 * 1_000;
        let Some(msg) = take::<ThrusterSetpoints>(&mut rest) else {
            return;
        };
        if let Ok(Taken::Written(applied)) = driver.on_setpoints(&msg, now_ns) {
            // What reaches the thrusters is finite and within [-1, 1].
            for v in applied.as_slice() {
                assert!(v.is_finite() && v.abs() <= 1.0, "{applied:?}");
            }
        }
        let _ = driver.on_time(now_ns);
        let _ = driver.time_left(now_ns);
    }
});
