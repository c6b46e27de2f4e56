//! The stamp screen every consumer applies (`runtime::screen::Screen`): a sequence of `Stamp`s of
//! any bytes, each arriving a little later (a 2-byte step in microseconds) on the vehicle clock.
#![no_main]
use cabletrack_fuzz::{take, take_u64};
use libfuzzer_sys::fuzz_target;
use messages::Stamp;
use runtime::screen::{Screen, ScreenLimits, Verdict};

fuzz_target!(|data: &[u8]| {
    let mut rest = data;
    // The vehicle clock is signed: a producer's clock behind by more than the uptime reads below 0.
    let mut now_ns = take_u64(&mut rest, 8) as i64;
    let mut screen = Screen::new("fuzz", ScreenLimits::control(0.2));
    while let Some(stamp) = take::<Stamp>(&mut rest) {
        now_ns = now_ns.saturating_add(take_u64(&mut rest, 2) as i64 * 1_000);
        if let Verdict::New = screen.check(&stamp, now_ns) {
            let _ = screen.fresh_until_if_accepted(&stamp, now_ns);
            screen.accept(&stamp, now_ns);
        }
        let _ = screen.fresh_until();
    }
});
