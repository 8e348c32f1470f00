//! # crsh-core
//!
//! The contract every crsh backend implements: compact data types ([`Ray`], [`Hit`],
//! [`Surface`], [`Sphere`], [`Cone`], [`SphereCone`], [`Aabb`]), the stage traits of seed 000's
//! pipeline ([`RayGen`], [`Hasher`], [`Sorter`], [`HierarchyBuilder`], [`Traverser`],
//! [`Intersector`], [`Shader`], plus [`PrimaryVisibility`] for the rasterized first hit), the
//! serde pipeline description ([`PipelineConfig`]) shared by the CLI, tests and benchmarks, the
//! stage [`Registry`] that turns a description into stage objects, the [`Stats`] every stage
//! feeds, the backend-generic frame driver ([`render_frame`]), and the backend-neutral math of
//! the ray hashes ([`quantize`]).
//!
//! Stages are generic over a [`Backend`], whose associated `Buffer<T>` is a host `Vec<T>` on
//! the CPU backend and a device buffer on the wgpu backend; the driver only moves buffers
//! between stages, so the same stage sequence runs on either backend.
//!
//! ```
//! use crsh_core::{CoreError, ParamInfo, PipelineConfig, StageKind, StageVariantInfo};
//!
//! // A catalogue (a registry's `variants()`) and a pipeline description checked against it.
//! let catalogue = vec![
//!     StageVariantInfo::new(StageKind::Primary, "raster", "z-buffer G-buffer"),
//!     StageVariantInfo::new(StageKind::Raygen, "whitted", "shadow, reflection, refraction"),
//!     StageVariantInfo::new(StageKind::Intersect, "brute", "every ray against every triangle"),
//!     StageVariantInfo::new(StageKind::Shade, "phong", "Phong shading")
//!         .param(ParamInfo::float("ambient", 0.05, "ambient fill").range(0.0, 1.0)),
//!     StageVariantInfo::new(StageKind::Hash, "thesis", "the thesis's hash"),
//! ];
//! let mut cfg = PipelineConfig::whitted("mine", "brute");
//! cfg.set("shade.ambient=0.2").unwrap();
//! cfg.resolve(&catalogue).unwrap();
//! assert_eq!(cfg.shade.f64("ambient").unwrap(), 0.2);
//!
//! // A hash without a sorter (and a hierarchy) is refused, naming the slots.
//! cfg.set("hash.kind=thesis").unwrap();
//! let err = cfg.resolve(&catalogue).unwrap_err();
//! assert!(matches!(err, CoreError::Incompatible { .. }), "{err}");
//! ```

#![warn(missing_docs)]

pub mod backend;
pub mod bounds;
pub mod config;
pub mod edge_width;
pub mod error;
pub mod metrics;
pub mod order;
pub mod pipeline;
pub mod quantize;
pub mod ray;
pub mod registry;
pub mod rng;
pub mod stage;
pub mod stats;

pub use backend::{Backend, StageScene};
pub use bounds::{f32_down, f32_up, Aabb, Cone, Sphere, SphereCone};
pub use config::{ParamInfo, ParamValue, PipelineConfig, StageKind, StageSpec, StageVariantInfo};
pub use error::{panic_message, CoreError, Result};
pub use order::RayOrder;
pub use pipeline::{
    count_self_hits, render_frame, timed, trace_batch, Frame, FrameOptions, FrameSize, Pipeline,
    Progress, StageBuild, Stages, MAX_DEPTH, MAX_IMAGE_SIDE,
};
pub use ray::{Hit, HitMode, Ray, RayKind, Surface, NO_HIT, UNKNOWN_TRI};
pub use registry::{BuiltinVariants, Preset, Registry, StageContext};
pub use stage::{
    check_leaf_offsets, lowest_node_leaves, Candidate, CandidateBatch, Hasher, HierarchyBuilder,
    Intersector, PrimaryVisibility, Query, RayGen, RayHierarchy, Shader, Sorter, Traverser,
    ALL_LANES,
};
pub use stats::{
    AccuracyCounts, CullStats, GenerationStats, KindStats, LevelStats, PacketStats, RayCounts,
    Stats, TestCounts, HALF_ANGLE_BIN_EDGES_DEG, STAGE_TIMINGS,
};

pub use glam;
