//! Camera frames from shared memory, as perception takes them (`perception::Observer::observe`):
//! a `CameraFrameHeader` of any bytes and an image of any length, with either eyes. Each step is one
//! byte (bit 0: whole image of the header's size, else the input's next bytes), a header, then for a
//! partial image a 2-byte length.
#![no_main]
use cabletrack_fuzz::{take, take_u64};
use config::{Eyes, Scenario};
use libfuzzer_sys::fuzz_target;
use messages::CameraFrameHeader;
use perception::Observer;
use std::sync::OnceLock;

/// The largest image made up: twice the scenario's 320x240, so a header asking for more gets less.
const MAX_IMAGE: usize = 2 * 320 * 240;

fn scenario() -> &'static Scenario {
    static SCENARIO: OnceLock<Scenario> = OnceLock::new();
    SCENARIO.get_or_init(Scenario::default)
}

fuzz_target!(|data: &[u8]| {
    let Some((&eyes, mut rest)) = data.split_first() else {
        return;
    };
    let eyes = if eyes & 1 == 0 {
        Eyes::Images
    } else {
        Eyes::Ideal
    };
    let mut observer = Observer::new(scenario(), eyes).expect("the default scenario's perception");
    while let Some(&how) = rest.first() {
        rest = &rest[1..];
        let Some(header) = take::<CameraFrameHeader>(&mut rest) else {
            return;
        };
        let image = if how & 1 == 1 {
            let len = (header.width as usize)
                .saturating_mul(header.height as usize)
                .min(MAX_IMAGE);
            // A gradient with a bright band where `how` says: something for the tracker to find.
            (0..len)
                .map(|i| {
                    let x = i % header.width.max(1) as usize;
                    if x / 8 == usize::from(how >> 1) % 40 {
                        220
                    } else {
                        (i % 61) as u8
                    }
                })
                .collect()
        } else {
            let len = (take_u64(&mut rest, 2) as usize).min(rest.len());
            let image = rest[..len].to_vec();
            rest = &rest[len..];
            image
        };
        if let Ok(observed) = observer.observe(&header, &image) {
            // The observation published is within the scenario's observation box.
            let o = observed.msg.observation;
            for v in [o.x_g, o.theta, o.x_g_rate, o.theta_rate] {
                assert!(v.is_finite(), "{o:?}");
            }
        }
    }
});
