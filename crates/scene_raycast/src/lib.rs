//! Triangle-mesh scenes and ray casting for the simulated LiDAR and camera.
//!
//! [`Scene`] holds a triangle mesh in the world frame W with one instance id per
//! triangle, in a SAH BVH; [`Scene::cast`] casts batches of rays in parallel
//! (rayon) and [`render`] draws a camera image with an instance-id image beside
//! it. Pure Rust: the Python binding lives in the root crate.

mod bvh;
pub mod error;
pub mod render;
pub mod scene;

pub use error::RaycastError;
pub use render::{render, Image, Lighting};
pub use scene::{Hit, Hits, Scene};
