//! The mesh's camera and perception stages, composed without IPC, observe exactly what the trainer's
//! in-process `vision::SimulatedVision` observes: the same frames (seed stream and frame numbering),
//! the same time steps, the same resets at each episode's start.

use camera::SimCamera;
use config::Eyes;
use config::{Scenario, derive_seed};
use messages::CableObservationData;
use perception::Observer;
use simulator::Simulator;
use simulator::lockstep::Published;
use vision::SimulatedVision;

#[test]
fn camera_and_perception_stages_match_the_trainers_eyes_bit_for_bit() {
    let mut scenario = Scenario::default();
    scenario.timing.max_steps = 12;
    let seed = 21;
    let render_seed = derive_seed(seed, "render");
    let mut sim = Simulator::new(&scenario, derive_seed(seed, "simulator"));
    let mut camera = SimCamera::new(&scenario, Eyes::Images, render_seed).unwrap();
    let mut observer = Observer::new(&scenario, Eyes::Images).unwrap();
    let mut trainer_eyes = SimulatedVision::new(&scenario, render_seed).unwrap();
    let mut image = vec![0; camera.image_len()];

    let mut step = sim.reset();
    let mut episodes = 0;
    let mut found = 0;
    for seq in 1..=40u64 {
        let state = Published { seq, step }.message();
        let header = camera.header(&state);
        camera.render(&state, &mut image).unwrap();
        let mesh = observer.observe(&header, &image).expect("a good frame");

        if step.step == 0 {
            trainer_eyes.reset();
            episodes += 1;
        }
        let trainer = CableObservationData::from(&trainer_eyes.observe(&step.state));
        assert_eq!(image, trainer_eyes.frame().data(), "frame of seq {seq}");
        let bits = |t: &CableObservationData| {
            [
                t.rho,
                t.theta,
                t.x_g,
                t.y_g,
                t.x_g_rate,
                t.theta_rate,
                t.confidence,
            ]
            .map(f64::to_bits)
        };
        assert_eq!(mesh.msg.observation.found, trainer.found, "seq {seq}");
        assert_eq!(bits(&mesh.msg.observation), bits(&trainer), "seq {seq}");
        found += trainer.found as u32;

        let k = seq as f64;
        step = sim.step(&[0.6, 0.4, 0.3 * (0.7 * k).sin()]);
    }
    assert!(episodes >= 3, "the run crosses episode boundaries");
    assert!(found > 30, "the cable is mostly found ({found} of 40)");
}
