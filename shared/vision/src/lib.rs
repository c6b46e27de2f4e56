//! The downward camera's image and the cable in it, as plain libraries (no IPC).
//!
//! - [`Renderer`]: the frame a downward B/W camera sees from a vehicle pose: the pool floor with
//!   texture, the cable, sand and algae clutter partly covering it, uneven light, motion blur from the
//!   vehicle's velocity and sensor noise; each effect switchable in [`config::RenderParams`], every
//!   frame reproducible from (seed, frame index). It renders into a caller's `&mut [u8]` (a shared
//!   memory slice, say). Camera and cable geometry come from [`model::Camera`] and [`model::Cable`].
//! - [`Perception`]: finds the cable's two long near-parallel edges (edges, a gradient-directed Hough
//!   transform, a least-squares fit of the pair), tracks the line from frame to frame and reports a
//!   [`model::CableObservation`] (rho, Theta, x_g, y_g, filtered rates, confidence, found or lost).
//! - [`SimulatedVision`]: the two in a loop (render, then perceive), for the trainer's step one with
//!   images in the loop instead of ideal geometry.
//! - [`Frame`] / [`ImageView`]: owned and borrowed 8-bit images; PGM and PNG files.
//! - [`sampling`]: poses that put the cable at a given x_g and Theta (tests, benchmarks, data sets).
//! - [`pace`]: perception timed frame by frame along a path, at the vehicle's pace or back to back.
//!
//! Coordinates are `model::camera`'s: centred pixels, columns right, rows down; Theta in
//! (-pi/2, pi/2] from the image's vertical, positive when the cable's top leans right; x_g and y_g
//! fractions of the width and height, 0 at the centre.

mod error;
pub mod geometry;
mod image;
pub mod pace;
mod perception;
mod render;
pub mod rng;
pub mod sampling;
mod simulated;
mod texture;
mod wide;

pub use error::{DecodeError, FrameError, VisionError};
pub use image::{Frame, ImageView, MAX_SIDE, MIN_SIDE};
pub use perception::{Detection, Perception};
pub use render::Renderer;
pub use simulated::{SimulatedVision, StageTimes};
