//! Bad input never panics: random bytes, flat frames, structured garbage, broken files and wrong
//! sizes give a 'lost' observation or a clear, typed error. A property test over thousands of
//! generated inputs (a fixed seed: a failure is reproducible).

use config::{RenderParams, Scenario};
use model::{Pose, PoseRate};
use vision::rng::SplitMix64;
use vision::{DecodeError, Frame, ImageView, Perception, Renderer, VisionError};

const W: usize = 320;
const H: usize = 240;

fn perception() -> Perception {
    Perception::from_scenario(&Scenario::default()).unwrap()
}

fn random_frame(rng: &mut SplitMix64) -> Vec<u8> {
    (0..W * H).map(|_| rng.next_u64() as u8).collect()
}

/// Every observation is either lost or made of finite numbers in their ranges.
fn check(obs: &model::CableObservation) {
    if obs.found {
        assert!(obs.rho.is_finite() && obs.theta.abs() <= std::f64::consts::FRAC_PI_2 + 1e-12);
        assert!(obs.x_g.abs() <= 0.5 + 1e-9 && obs.y_g.abs() <= 0.5 + 1e-9);
        assert!(obs.x_g_rate.is_finite() && obs.theta_rate.is_finite());
        assert!((0.0..=1.0).contains(&obs.confidence));
    }
}

#[test]
fn random_bytes_are_lost() {
    let mut p = perception();
    let mut rng = SplitMix64::new(1);
    for _ in 0..300 {
        let frame = random_frame(&mut rng);
        p.reset();
        let obs = p
            .process(ImageView::new(&frame, W, H).unwrap(), 0.2)
            .unwrap();
        assert!(!obs.found, "{obs:?}");
    }
}

#[test]
fn flat_frames_are_lost() {
    let mut p = perception();
    for level in [0u8, 1, 128, 254, 255] {
        let frame = vec![level; W * H];
        p.reset();
        let obs = p
            .process(ImageView::new(&frame, W, H).unwrap(), 0.2)
            .unwrap();
        assert!(!obs.found, "level {level}");
    }
}

/// Generated garbage of many kinds, processed as a tracked sequence with odd time steps: no panic, and
/// whatever is reported is well-formed.
#[test]
fn structured_garbage_never_panics() {
    let mut p = perception();
    let mut rng = SplitMix64::new(2);
    let dts = [0.2, 0.0, -1.0, f64::NAN, f64::INFINITY, 1e-9, 1e9];
    for k in 0..1500 {
        let kind = rng.next_u64() % 6;
        let a = rng.next_u64() as u8;
        let b = rng.next_u64() as u8;
        let period = 1 + (rng.next_u64() % 40) as usize;
        let frame: Vec<u8> = (0..W * H)
            .map(|i| {
                let (x, y) = (i % W, i / W);
                match kind {
                    0 => rng.next_u64() as u8,
                    1 => {
                        if (x / period).is_multiple_of(2) {
                            a
                        } else {
                            b
                        }
                    }
                    2 => {
                        if ((x + y) / period).is_multiple_of(2) {
                            a
                        } else {
                            b
                        }
                    }
                    3 => {
                        if rng.next_u64().is_multiple_of(100) {
                            255
                        } else {
                            a
                        }
                    }
                    4 => ((x * a as usize + y * b as usize) % 256) as u8,
                    _ => {
                        if (x / period + y / period).is_multiple_of(2) {
                            a
                        } else {
                            b
                        }
                    }
                }
            })
            .collect();
        let obs = p
            .process(ImageView::new(&frame, W, H).unwrap(), dts[k % dts.len()])
            .unwrap();
        check(&obs);
    }
}

#[test]
fn wrong_sizes_are_typed_errors() {
    let buf = vec![0u8; W * H - 1];
    assert!(matches!(
        ImageView::new(&buf, W, H),
        Err(VisionError::LengthMismatch { .. })
    ));
    assert!(matches!(
        ImageView::new(&buf, 0, H),
        Err(VisionError::BadSize { .. })
    ));
    let small = vec![0u8; 100 * 100];
    let view = ImageView::new(&small, 100, 100).unwrap();
    assert!(matches!(
        perception().process(view, 0.2),
        Err(VisionError::SizeMismatch { .. })
    ));
    let s = Scenario::default();
    let mut r = Renderer::new(&RenderParams::default(), &s.camera, &s.cable, 0).unwrap();
    let mut out = vec![0u8; W * H + 1];
    assert!(matches!(
        r.render(&Pose::default(), &PoseRate::default(), 0, &mut out),
        Err(VisionError::LengthMismatch { .. })
    ));
}

#[test]
fn a_frame_shorter_than_its_header_says_is_a_clear_error() {
    let mut bytes = b"P5\n320 240\n255\n".to_vec();
    bytes.extend(vec![7u8; W * H - 1]);
    match Frame::decode(&bytes) {
        Err(DecodeError::Truncated { expected, got }) => {
            assert_eq!((expected, got), (W * H, W * H - 1))
        }
        other => panic!("{other:?}"),
    }
    let err = Frame::decode(b"P5\n320 240\n255\n").unwrap_err();
    assert!(
        err.to_string().contains("shorter than the header says"),
        "{err}"
    );
    // A header announcing an absurd size is refused before anything is allocated.
    assert!(matches!(
        Frame::decode(b"P5\n999999999 999999999\n255\n"),
        Err(DecodeError::Image(VisionError::BadSize { .. }))
    ));
    assert!(matches!(
        Frame::decode(b"P5\nfoo"),
        Err(DecodeError::PgmHeader(_))
    ));
    assert!(matches!(
        Frame::decode(b"GIF89a"),
        Err(DecodeError::UnknownFormat)
    ));
}

/// Random bytes, and valid PGM and PNG files with random corruption (bit flips, truncation), decode
/// to a frame or an error: never a panic.
#[test]
fn corrupted_files_never_panic() {
    let mut rng = SplitMix64::new(3);
    let data: Vec<u8> = (0..64 * 48).map(|k| (k % 251) as u8).collect();
    let frame = Frame::from_vec(64, 48, data).unwrap();
    let originals = [frame.encode_pgm(), frame.encode_png().unwrap()];
    for k in 0..3000 {
        let mut bytes = match k % 3 {
            0 => (0..rng.next_u64() % 2000)
                .map(|_| rng.next_u64() as u8)
                .collect(),
            _ => originals[k % 2].clone(),
        };
        if k % 3 != 0 {
            for _ in 0..1 + rng.next_u64() % 8 {
                let i = (rng.next_u64() as usize) % bytes.len();
                bytes[i] ^= 1 << (rng.next_u64() % 8);
            }
            if rng.next_u64().is_multiple_of(2) {
                let keep = (rng.next_u64() as usize) % bytes.len();
                bytes.truncate(keep);
            }
        }
        if let Ok(f) = Frame::decode(&bytes) {
            assert_eq!(f.data().len(), f.width() * f.height());
        }
    }
}

#[test]
fn the_renderer_survives_absurd_poses() {
    let s = Scenario::default();
    let mut r = Renderer::new(&RenderParams::default(), &s.camera, &s.cable, 0).unwrap();
    let mut p = perception();
    let mut out = vec![0u8; W * H];
    let odd = [f64::NAN, f64::INFINITY, -f64::INFINITY, 1e300, -1e12, 0.0];
    for (k, &v) in odd.iter().enumerate() {
        for pose in [
            Pose {
                x: v,
                y: 0.0,
                psi: 0.0,
            },
            Pose {
                x: 0.0,
                y: v,
                psi: 0.0,
            },
            Pose {
                x: 0.0,
                y: 0.0,
                psi: v,
            },
        ] {
            let rate = PoseRate { x: v, y: v, psi: v };
            r.render(&pose, &rate, k as u64, &mut out).unwrap();
            check(&p.process(ImageView::new(&out, W, H).unwrap(), 0.2).unwrap());
        }
    }
}
