//! fusion_core: camera/LiDAR fusion and insulator localization kernels (pure Rust).
//!
//! Frames: L (LiDAR), B (body, FLU), C (camera optical, OpenCV). `T_a_b` maps frame-b
//! coordinates into frame a. Units: metres, radians, pixels.
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::expect_used))]

pub mod camera;
pub mod culling;
pub mod deskew;
pub mod dbscan;
pub mod error;
pub mod points;
pub mod projection;
pub mod resize;
pub mod strings;
pub mod transform;
#[cfg(test)]
mod test_scenes;

pub use localize::bounded::ambiguity::SCALE_TOLERANCE;
pub use localize::bounded::{BoxEvidence, BoxView};
pub use camera::{CameraModel, NEAR_LIMIT};
pub use culling::{points_in_boxes, points_in_boxes_scalar, PixelBox};
pub use dbscan::{dbscan, NOISE};
pub use deskew::{deskew, deskew_points_in_boxes, deskew_points_in_boxes_scalar, PoseStream};
pub use error::{FusionError, Result};
pub use points::{collect_finite, FinitePoints, PointCloud, StridedPoints};
pub use projection::{project_points, Projection};
pub use resize::resize_linear;
pub use strings::{find_insulator_strings, InsulatorString, StringParams};
pub use transform::{chain, rigid_from_matrix};
pub mod localize;
pub mod pca;
pub mod ransac;

pub use localize::{localize, LocalizeParams, Localization, Method};
pub use pca::{pca, Pca};
pub use ransac::{ransac_line, LineFit, RansacParams};
