//! placeholder-free stub: filled by the fusion_core work.
