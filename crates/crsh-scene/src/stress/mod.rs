//! The stability suite's cases: small procedural scenes where ray tracers go wrong, each with a
//! known right answer (issue 5).
//!
//! A [`StressCase`] is a scene plus a [`Probe`]: either explicit rays with one [`Expect`] each
//! ([`Probe::Rays`]: the intersector and the hierarchy stages are what is tested), or a small
//! frame whose secondary rays come from the pipeline's own primary and ray-generation stages
//! ([`Probe::Frame`]: the origin-offset policy is what is tested) with a [`FrameTruth`].
//! The suite is backend-agnostic; `crsh_cpu::stress` runs it against pipelines, and
//! `crsh stress` prints the table. Every case is deterministic (fixed seeds, SplitMix64).
//!
//! Families ([`cases`] lists the default suite):
//! - `closed`: rays from inside an icosphere, a torus and a cube of shared-edge triangles, aimed
//!   at vertices, edge midpoints and random directions: a miss is an *escape*;
//! - `edges`: rays aimed exactly at the shared edges and the centre vertex of a fan (escapes),
//!   and grazing rays nearly parallel to a triangle;
//! - `acne`: a tessellated, tilted plane lit at 1°-89°: any secondary ray that finds the plane
//!   is a self-intersection (shadow acne, reflection acne);
//! - `degenerate`: slivers, needles, zero-area triangles, coincident and coplanar triangles;
//! - `far`, `scale`: the same checks translated by 1e3 / 1e5 / 1e7 and scaled by 1e-4 / 1e4;
//! - `bundles`: reflections off a small curved mirror and rays in opposite directions from one
//!   point (cones near and past 90°, degenerate cone unions);
//! - `stadium`: a detailed bumpy mirror sphere inside a huge sparse box;
//! - `invalid`: NaN / infinite / zero ray components, all-miss rays, one triangle, and scenes
//!   that must be rejected with an error (empty, NaN vertex).

mod cases;
pub mod meshes;

use std::sync::Arc;

use crsh_core::{Ray, RayKind};
use glam::Vec3;

use crate::model::Scene;

pub use cases::cases;

/// The right answer for one explicit ray.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Expect {
    /// The ray starts inside a closed mesh, or is aimed at a point strictly inside a surface
    /// made of several triangles (a shared edge or vertex): it must hit something. A miss is
    /// an *escape* (through an edge or a vertex).
    MustHit,
    /// The nearest hit is triangle `tri` at distance `t` (known by construction). A miss is a
    /// false miss; a hit on another triangle at a `t` more than 1e-6 relative away is a wrong
    /// nearest hit.
    Nearest {
        /// Triangle id in scene order.
        tri: u32,
        /// Ray parameter of the hit.
        t: f32,
    },
    /// Nothing can be hit: any hit is a false hit.
    Miss,
    /// The truth is the f64 reference intersector (`brute64`) on the same ray.
    Reference,
    /// The ray has a NaN or infinite component, or a zero direction: counting it as a miss or
    /// rejecting the batch with an error are both right; a hit (or a panic) is not.
    Invalid,
}

/// What is known about a [`Probe::Frame`]'s secondary rays.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FrameTruth {
    /// Nothing in the scene can occlude or reflect anything back: the only surface a secondary
    /// ray can find is the one it leaves, so every hit is a self-intersection.
    Unoccluded,
    /// The f64 reference intersector (`brute64`) on the very same rays is the truth; a hit on
    /// the ray's own source triangle that the reference does not report is a self-intersection.
    Reference,
}

/// How a case is checked.
#[derive(Clone, Debug)]
pub enum Probe {
    /// Explicit rays of one kind (closest hit, or any hit for shadow rays), one expectation each.
    Rays {
        /// The query every ray gets.
        kind: RayKind,
        /// The rays.
        rays: Vec<Ray>,
        /// One expectation per ray.
        expect: Vec<Expect>,
    },
    /// A `width × height` frame through the pipeline's primary stage, then every secondary ray
    /// kind its ray generator makes from the primary hits (one bounce).
    Frame {
        /// Image width in pixels.
        width: u32,
        /// Image height in pixels.
        height: u32,
        /// What the secondary rays' hits are compared with.
        truth: FrameTruth,
    },
}

impl Probe {
    /// Whether this probe's secondary rays come from the pipeline's ray generator (so the
    /// offset policy matters).
    pub fn is_frame(&self) -> bool {
        matches!(self, Probe::Frame { .. })
    }
}

/// One case of the suite.
#[derive(Clone, Debug)]
pub struct StressCase {
    /// Unique name, `family/what` (e.g. `closed/torus`).
    pub name: String,
    /// The family (the part of the name before the slash).
    pub family: &'static str,
    /// One line: what is checked and what the right answer is.
    pub about: String,
    /// The scene, or the error [`crate::SceneBuilder`] gave for it (cases whose geometry must
    /// be rejected, such as an empty scene or a NaN vertex).
    pub scene: Result<Arc<Scene>, String>,
    /// How the case is checked.
    pub probe: Probe,
}

impl StressCase {
    /// Whether an error (instead of results) is an acceptable outcome: the scene is meant to be
    /// rejected, or the probe holds invalid rays.
    pub fn error_allowed(&self) -> bool {
        self.scene.is_err()
            || matches!(&self.probe, Probe::Rays { expect, .. }
                if expect.contains(&Expect::Invalid))
    }
}

/// A ray of `kind` from `origin` along `dir` over `(t_min, t_max)`, with a unit throughput,
/// `pixel = index`, no light, no source surface ([`u32::MAX`]).
pub fn probe_ray(
    kind: RayKind,
    origin: Vec3,
    dir: Vec3,
    t_min: f32,
    t_max: f32,
    index: u32,
) -> Ray {
    Ray {
        pixel: index,
        source: u32::MAX,
        ..Ray::new(kind, origin, dir, t_min, t_max)
    }
}
