//! filled by the scene work.
