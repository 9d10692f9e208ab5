//! Errors of scene construction, ray casting and rendering.

use thiserror::Error;

/// Everything that can be wrong with the input of this crate. Each variant names
/// the argument at fault so the binding can forward it to the user unchanged.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum RaycastError {
    /// The scene has no triangle to cast against.
    #[error("triangles: the scene needs at least one triangle")]
    EmptyScene,
    /// A vertex coordinate is NaN or infinite.
    #[error("vertices: vertex {index} is not finite")]
    NonFiniteVertex { index: usize },
    /// A triangle refers to a vertex that does not exist.
    #[error("triangles: triangle {triangle} refers to vertex {vertex}, but there are {n_vertices} vertices")]
    IndexOutOfRange {
        triangle: usize,
        vertex: u32,
        n_vertices: usize,
    },
    /// A triangle has (numerically) zero area.
    #[error("triangles: triangle {triangle} is degenerate (area {area:e} m^2)")]
    DegenerateTriangle { triangle: usize, area: f64 },
    /// The per-triangle instance ids do not match the triangles.
    #[error("instance_ids: expected one id per triangle ({expected}), got {got}")]
    InstanceCountMismatch { expected: usize, got: usize },
    /// An instance id is negative (-1 is reserved for "no hit").
    #[error("instance_ids: id {id} of triangle {triangle} is negative (-1 means no hit)")]
    NegativeInstanceId { triangle: usize, id: i32 },
    /// Two per-ray arrays have different lengths.
    #[error("{name}: expected {expected} rows (one per ray), got {got}")]
    LengthMismatch {
        name: &'static str,
        expected: usize,
        got: usize,
    },
    /// A ray origin or direction is not finite.
    #[error("{name}: row {index} is not finite")]
    NonFiniteRay { name: &'static str, index: usize },
    /// A ray direction has zero length.
    #[error("{name}: row {index} has zero length")]
    ZeroDirection { name: &'static str, index: usize },
    /// A scalar parameter is out of its domain.
    #[error("{name}: {reason}, got {value}")]
    BadParameter {
        name: &'static str,
        reason: &'static str,
        value: f64,
    },
}
