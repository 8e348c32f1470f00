//! # crsh-core
//!
//! The contract every crsh backend implements: compact data types ([`Ray`], [`Hit`],
//! [`Surface`], [`Sphere`], [`Cone`], [`SphereCone`], [`Aabb`]), the stage traits of seed 000's
//! pipeline ([`RayGen`], [`Hasher`], [`Sorter`], [`HierarchyBuilder`], [`Traverser`],
//! [`Intersector`], [`Shader`], plus [`PrimaryVisibility`] for the rasterized first hit), the
//! serde pipeline description ([`PipelineConfig`]) shared by the CLI, tests and benchmarks,
//! the [`Stats`] every stage feeds, and the backend-generic frame driver ([`render_frame`]).
//!
//! Stages are generic over a [`Backend`], whose associated `Buffer<T>` is a host `Vec<T>` on
//! the CPU backend and a device buffer on the wgpu backend; the driver only moves buffers
//! between stages, so the same stage sequence runs on either backend.

#![warn(missing_docs)]

pub mod backend;
pub mod bounds;
pub mod config;
pub mod error;
pub mod metrics;
pub mod pipeline;
pub mod ray;
pub mod stage;
pub mod stats;

pub use backend::Backend;
pub use bounds::{Aabb, Cone, Sphere, SphereCone};
pub use config::{ParamInfo, ParamValue, PipelineConfig, StageKind, StageSpec, StageVariantInfo};
pub use error::{panic_message, CoreError, Result};
pub use pipeline::{
    count_self_hits, render_frame, timed, trace_batch, Frame, FrameOptions, Progress, Stages,
};
pub use ray::{Hit, HitMode, Ray, RayKind, Surface, NO_HIT};
pub use stage::{
    Candidate, CandidateBatch, Hasher, HierarchyBuilder, Intersector, PrimaryVisibility, Query,
    RayGen, RayHierarchy, Shader, Sorter, Traverser,
};
pub use stats::{
    AccuracyCounts, CullStats, KindStats, LevelStats, RayCounts, Stats, TestCounts, STAGE_TIMINGS,
};

pub use glam;
