//! roadmark: road markings from mobile laser scanning drives.
//!
//! LAS/LAZ tiles with intensity plus the vehicle trajectory go in; a GeoJSON
//! FeatureCollection of classified marking polygons and lane-line polylines comes out.
//! The external contract (CLI, GeoJSON schema, HTTP API) is `CONTRACT.md` of the project.

/// HTTP API (axum).
pub mod api;
/// The `roadmark` subcommands.
pub mod commands;
/// Service configuration (flags and environment).
pub mod config;
/// Accuracy metrics: pixel, object and lane-line level, as in the papers.
pub mod eval;
/// SQLite job queue and workers.
pub mod jobs;
/// Process-wide memory policy (the allocator's thresholds).
pub mod memory;
/// The extraction pipeline: pure, synchronous stages from points to vectors.
pub mod pipeline;
/// Synthetic mobile-mapping surveys (ray-cast scenes with truth) for tests and demos.
pub mod sim;
/// On-disk layout of uploads and results.
pub mod storage;
