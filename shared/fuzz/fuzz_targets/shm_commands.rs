//! Per-DOF commands from shared memory, as the thruster allocator takes them
//! (`thruster_allocator::step::StepAllocator`): `DofCommand`s of any bytes from any of the three
//! inputs, time passing between them (1 byte: the input and whether the deadline is checked, 2 bytes
//! of microseconds, then the command).
#![no_main]
use cabletrack_fuzz::{take, take_u64};
use config::Scenario;
use libfuzzer_sys::fuzz_target;
use messages::DofCommand;
use runtime::screen::{Screen, ScreenLimits};
use std::time::{Duration, Instant};
use thruster_allocator::Allocator;
use thruster_allocator::step::{Event, Input, StepAllocator};

fuzz_target!(|data: &[u8]| {
    let mut rest = data;
    let mut allocator = StepAllocator::new(
        Allocator::new(&Scenario::default().thrusters),
        Duration::from_millis(100),
        Screen::new("commands", ScreenLimits::control(0.2)),
    );
    let start = Instant::now();
    let mut clock_ns = 3_600_000_000_000i64;
    while let Some(&which) = rest.first() {
        rest = &rest[1..];
        clock_ns += take_u64(&mut rest, 2) as i64 * 1_000;
        let Some(cmd) = take::<DofCommand>(&mut rest) else {
            return;
        };
        let now = start + Duration::from_nanos((clock_ns - 3_600_000_000_000) as u64);
        let input = Input::ALL[usize::from(which % 3)];
        check(allocator.on_command(input, cmd, now, clock_ns));
        if which & 0x80 != 0 {
            check(allocator.on_time(now, clock_ns));
        }
    }
});

/// Setpoints sent are finite and within [-1, 1]: what the thrusters may be given.
fn check(event: Event) {
    if let Event::Send { setpoints, .. } | Event::Overdue { setpoints, .. } = event {
        for v in setpoints.as_slice() {
            assert!(v.is_finite() && v.abs() <= 1.0, "{setpoints:?}");
        }
    }
}
