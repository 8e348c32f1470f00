//! Animated scenes: instances placed by a manifest and moved per frame, evaluated into the
//! flat arrays of a [`Scene`].
//!
//! Seed 000's case for a ray-space hierarchy is dynamic geometry: its hierarchy is built over
//! rays, so a moving scene costs it only the mesh and triangle bounding spheres (§3.2.2,
//! §3.3), while an object BVH must be rebuilt or refitted and seed 002's uniform grid is
//! rebuilt every frame. This module is what moves: nothing more than the frames need, no scene
//! graph.
//!
//! - An [`AnimatedScene`] is a [`Scene`] (the frame being shown) plus the [`Instance`]s that
//!   move in it. Static geometry (the base mesh, instances without motion) is placed once and
//!   never touched again.
//! - A frame `f` is the scene at time `t = f / fps`. For each moving instance, every vertex of
//!   its object-space mesh goes through its *deforming* motions ([`Motion::Wave`],
//!   [`Motion::Twist`], in object space, in the listed order), then its placement
//!   (scale, rotation, translation), then its *rigid* motions ([`Motion::Translate`],
//!   [`Motion::Rotate`], [`Motion::Scale`], [`Motion::Keyframes`], in world space, in the
//!   listed order).
//! - [`AnimatedScene::update`] writes frame `f` into a scene in place: positions and normals of
//!   the moving instances ([`UpdateTimes::geometry_ms`]; rigid instances rotate their normals,
//!   deforming ones recompute area-weighted normals), their meshes' boxes, the scene bounds
//!   and the degenerate-triangle count; and, when asked, the triangles' and meshes' bounding
//!   spheres that the ray-space hierarchies cull with ([`UpdateTimes::spheres_ms`]). When the
//!   spheres are not asked for, those of the moving meshes become infinite: still bounding,
//!   so a consumer that reads them anyway stays correct.
//!
//! The manifest format is documented in [`crate::manifest`] and the project README.

use std::ops::Range;
use std::time::Instant;

use crsh_core::{Aabb, Sphere};
use glam::{Affine3A, Mat3A, Quat, Vec3, Vec3A};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::bounding;
use crate::error::SceneError;
use crate::model::{is_degenerate_triangle, Scene, MAX_COORDINATE};

/// Whether a vertex at `p` is outside what a scene may hold: not finite, or a coordinate
/// beyond [`MAX_COORDINATE`].
fn out_of_range(p: Vec3) -> bool {
    !p.is_finite() || p.abs().max_element() > MAX_COORDINATE
}

/// Frames per second of scene time when the manifest does not say.
pub const DEFAULT_FPS: f32 = 24.0;

/// Accepted frames per second: frame `f` is at `f / fps` seconds, which must stay finite for
/// every frame number (a subnormal `fps` made frame 1 infinitely far).
pub const FPS_RANGE: std::ops::RangeInclusive<f32> = 1e-3..=1e6;

/// One keyframe of [`Motion::Keyframes`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Keyframe {
    /// Time in seconds.
    pub time: f32,
    /// Offset added to the instance's position.
    #[serde(default, deserialize_with = "crate::manifest::exact")]
    pub translate: [f32; 3],
    /// Rotation about the instance's origin: `[axis_x, axis_y, axis_z, degrees]`.
    #[serde(default = "no_rotation", deserialize_with = "crate::manifest::exact")]
    pub rotate: [f32; 4],
    /// Uniform scale about the instance's origin.
    #[serde(default = "one")]
    pub scale: f32,
}

fn no_rotation() -> [f32; 4] {
    [0.0, 1.0, 0.0, 0.0]
}

fn one() -> f32 {
    1.0
}

fn y_axis() -> [f32; 3] {
    [0.0, 1.0, 0.0]
}

fn x_axis() -> [f32; 3] {
    [1.0, 0.0, 0.0]
}

/// A motion of an instance (`[[instances.motion]]` in a manifest, `kind = "..."`).
///
/// Times are in seconds of scene time; rigid motions act in world space about the instance's
/// origin (its position after the motions listed before) unless a `pivot` is given.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Motion {
    /// Constant velocity: `p + velocity·t`.
    Translate {
        /// Units per second.
        #[serde(deserialize_with = "crate::manifest::exact")]
        velocity: [f32; 3],
    },
    /// Constant spin about `axis` through `pivot`.
    Rotate {
        /// Rotation axis (normalized when used).
        #[serde(default = "y_axis", deserialize_with = "crate::manifest::exact")]
        axis: [f32; 3],
        /// Angular speed.
        degrees_per_second: f32,
        /// A point on the axis (default: the instance's origin).
        #[serde(default, deserialize_with = "crate::manifest::exact_opt")]
        pivot: Option<[f32; 3]>,
    },
    /// Uniform scale by `factor_per_second^t` about `pivot`.
    Scale {
        /// Scale factor after one second (> 0).
        factor_per_second: f32,
        /// Fixed point (default: the instance's origin).
        #[serde(default, deserialize_with = "crate::manifest::exact_opt")]
        pivot: Option<[f32; 3]>,
    },
    /// Rigid keyframes, linearly interpolated (rotation by slerp), held before the first and
    /// after the last key; they move the instance relative to its placement.
    Keyframes {
        /// Keys in increasing time.
        keys: Vec<Keyframe>,
        /// Repeat the key sequence (period: the last key's time).
        #[serde(default)]
        repeat: bool,
    },
    /// A travelling sine wave that displaces every vertex (object space):
    /// `p + axis·amplitude·sin(2π (p·direction − speed·t) / wavelength)`.
    Wave {
        /// Displacement amplitude.
        amplitude: f32,
        /// Wavelength (> 0).
        wavelength: f32,
        /// Phase speed, units per second.
        speed: f32,
        /// Direction of travel (normalized when used).
        #[serde(default = "x_axis", deserialize_with = "crate::manifest::exact")]
        direction: [f32; 3],
        /// Displacement direction (normalized when used).
        #[serde(default = "y_axis", deserialize_with = "crate::manifest::exact")]
        axis: [f32; 3],
    },
    /// A twist about `axis` through the object-space origin whose angle grows with the height
    /// along the axis and swings in time: `angle = degrees_per_unit · h · sin(2π t / period)`.
    Twist {
        /// Twist axis (normalized when used).
        #[serde(default = "y_axis", deserialize_with = "crate::manifest::exact")]
        axis: [f32; 3],
        /// Twist per unit of height at the swing's extreme.
        degrees_per_unit: f32,
        /// Swing period in seconds (> 0).
        period: f32,
    },
}

fn finite3(v: [f32; 3]) -> bool {
    v.iter().all(|x| x.is_finite())
}

fn unit(v: [f32; 3], what: &str) -> Result<Vec3, String> {
    let v = Vec3::from_array(v);
    if !v.is_finite() || v.length_squared() < 1e-12 {
        return Err(format!("{what} {v} must be finite and non-zero"));
    }
    Ok(v.normalize())
}

impl Motion {
    /// Whether it moves vertices relative to each other (so refitting is not free).
    pub fn deforms(&self) -> bool {
        matches!(self, Motion::Wave { .. } | Motion::Twist { .. })
    }

    /// Checks every value (finite, axes non-zero, positive periods, factors and wavelengths,
    /// keys in increasing time); the message names the offending value.
    pub fn validate(&self) -> Result<(), String> {
        match self {
            Motion::Translate { velocity } => {
                if !finite3(*velocity) {
                    return Err(format!("translate velocity {velocity:?} is not finite"));
                }
            }
            Motion::Rotate {
                axis,
                degrees_per_second,
                pivot,
            } => {
                unit(*axis, "rotate axis")?;
                if !degrees_per_second.is_finite() || pivot.is_some_and(|p| !finite3(p)) {
                    return Err("rotate: degrees_per_second and pivot must be finite".into());
                }
            }
            Motion::Scale {
                factor_per_second,
                pivot,
            } => {
                if !(factor_per_second.is_finite() && *factor_per_second > 0.0)
                    || pivot.is_some_and(|p| !finite3(p))
                {
                    return Err(format!(
                        "scale: factor_per_second {factor_per_second} must be finite and positive, pivot finite"
                    ));
                }
            }
            Motion::Keyframes { keys, .. } => {
                if keys.is_empty() {
                    return Err("keyframes: no keys".into());
                }
                for (i, k) in keys.iter().enumerate() {
                    if !k.time.is_finite() || !finite3(k.translate) {
                        return Err(format!("keyframe {i}: time and translate must be finite"));
                    }
                    unit(
                        [k.rotate[0], k.rotate[1], k.rotate[2]],
                        "keyframe rotate axis",
                    )
                    .map_err(|e| format!("keyframe {i}: {e}"))?;
                    if !(k.rotate[3].is_finite() && k.scale.is_finite() && k.scale > 0.0) {
                        return Err(format!(
                            "keyframe {i}: rotation angle must be finite and scale positive"
                        ));
                    }
                    if i > 0 && k.time <= keys[i - 1].time {
                        return Err(format!(
                            "keyframe {i}: time {} is not after the previous key's {}",
                            k.time,
                            keys[i - 1].time
                        ));
                    }
                }
            }
            Motion::Wave {
                amplitude,
                wavelength,
                speed,
                direction,
                axis,
            } => {
                unit(*direction, "wave direction")?;
                unit(*axis, "wave axis")?;
                if !(amplitude.is_finite()
                    && speed.is_finite()
                    && wavelength.is_finite()
                    && *wavelength > 0.0)
                {
                    return Err(format!(
                        "wave: amplitude {amplitude} and speed {speed} must be finite, wavelength {wavelength} positive"
                    ));
                }
            }
            Motion::Twist {
                axis,
                degrees_per_unit,
                period,
            } => {
                unit(*axis, "twist axis")?;
                if !(degrees_per_unit.is_finite() && period.is_finite() && *period > 0.0) {
                    return Err(format!(
                        "twist: degrees_per_unit {degrees_per_unit} must be finite, period {period} positive"
                    ));
                }
            }
        }
        Ok(())
    }

    /// The deformation of an object-space point at time `t` (identity for rigid motions).
    fn deform(&self, p: Vec3, t: f32) -> Vec3 {
        match self {
            Motion::Wave {
                amplitude,
                wavelength,
                speed,
                direction,
                axis,
            } => {
                let d = Vec3::from_array(*direction).normalize();
                let a = Vec3::from_array(*axis).normalize();
                let phase = std::f32::consts::TAU * (p.dot(d) - speed * t) / wavelength;
                p + a * (amplitude * phase.sin())
            }
            Motion::Twist {
                axis,
                degrees_per_unit,
                period,
            } => {
                let a = Vec3::from_array(*axis).normalize();
                let swing = (std::f32::consts::TAU * t / period).sin();
                let angle = (degrees_per_unit * p.dot(a) * swing).to_radians();
                Quat::from_axis_angle(a, angle) * p
            }
            _ => p,
        }
    }

    /// The rigid transform at time `t` applied after `so_far` (identity for deformations).
    fn rigid(&self, so_far: Affine3A, t: f32) -> Affine3A {
        let origin = Vec3::from(so_far.translation);
        let about = |pivot: Option<[f32; 3]>, m: Affine3A| {
            let p = pivot.map(Vec3::from_array).unwrap_or(origin);
            Affine3A::from_translation(p) * m * Affine3A::from_translation(-p)
        };
        let step = match self {
            Motion::Translate { velocity } => {
                Affine3A::from_translation(Vec3::from_array(*velocity) * t)
            }
            Motion::Rotate {
                axis,
                degrees_per_second,
                pivot,
            } => about(
                *pivot,
                Affine3A::from_axis_angle(
                    Vec3::from_array(*axis).normalize(),
                    (degrees_per_second * t).to_radians(),
                ),
            ),
            Motion::Scale {
                factor_per_second,
                pivot,
            } => about(
                *pivot,
                Affine3A::from_scale(Vec3::splat(factor_per_second.powf(t))),
            ),
            Motion::Keyframes { keys, repeat } => {
                let (translate, rotation, scale) = sample_keys(keys, *repeat, t);
                Affine3A::from_translation(translate)
                    * about(
                        None,
                        Affine3A::from_scale_rotation_translation(
                            Vec3::splat(scale),
                            rotation,
                            Vec3::ZERO,
                        ),
                    )
            }
            Motion::Wave { .. } | Motion::Twist { .. } => Affine3A::IDENTITY,
        };
        step * so_far
    }
}

fn key_rotation(k: &Keyframe) -> Quat {
    let axis = Vec3::new(k.rotate[0], k.rotate[1], k.rotate[2]).normalize();
    Quat::from_axis_angle(axis, k.rotate[3].to_radians())
}

/// Translation, rotation and scale of `keys` at time `t`.
fn sample_keys(keys: &[Keyframe], repeat: bool, t: f32) -> (Vec3, Quat, f32) {
    let first = &keys[0];
    let last = &keys[keys.len() - 1];
    let mut t = t;
    if repeat && last.time > first.time {
        let span = last.time - first.time;
        t = first.time + (t - first.time).rem_euclid(span);
    }
    let at = |k: &Keyframe| (Vec3::from_array(k.translate), key_rotation(k), k.scale);
    if t <= first.time {
        return at(first);
    }
    if t >= last.time {
        return at(last);
    }
    let i = keys.partition_point(|k| k.time <= t);
    let (a, b) = (&keys[i - 1], &keys[i]);
    let s = (t - a.time) / (b.time - a.time);
    (
        Vec3::from_array(a.translate).lerp(Vec3::from_array(b.translate), s),
        key_rotation(a).slerp(key_rotation(b), s),
        a.scale + (b.scale - a.scale) * s,
    )
}

/// A placed mesh of an animated scene and its motions.
#[derive(Clone, Debug)]
pub struct Instance {
    /// Name (reports).
    pub name: String,
    /// Its vertices in [`Scene::positions`].
    pub vertices: Range<usize>,
    /// Its meshes in [`Scene::meshes`] (their triangles are contiguous).
    pub meshes: Range<usize>,
    /// Its triangles in [`Scene::indices`].
    pub triangles: Range<usize>,
    /// Object-space positions (empty for an instance without motion).
    object_positions: Vec<Vec3>,
    /// Object-space unit normals (empty for an instance without motion).
    object_normals: Vec<Vec3>,
    /// Object-space centres of its meshes' minimal spheres (empty for an instance without
    /// motion).
    object_centers: Vec<Vec3>,
    /// Object to world at rest (scale, then rotation, then translation).
    pub placement: Affine3A,
    /// Its motions.
    pub motions: Vec<Motion>,
}

impl Instance {
    /// An instance of the vertices, meshes and triangles given (ranges into the scene handed
    /// to [`AnimatedScene::new`], in object space there), placed by `placement` and moved by
    /// `motions`.
    pub fn new(
        name: impl Into<String>,
        vertices: Range<usize>,
        meshes: Range<usize>,
        triangles: Range<usize>,
        placement: Affine3A,
        motions: Vec<Motion>,
    ) -> Instance {
        Instance {
            name: name.into(),
            vertices,
            meshes,
            triangles,
            object_positions: Vec::new(),
            object_normals: Vec::new(),
            object_centers: Vec::new(),
            placement,
            motions,
        }
    }

    /// Whether anything moves it.
    pub fn moves(&self) -> bool {
        !self.motions.is_empty()
    }

    /// Whether a motion deforms it.
    pub fn deforms(&self) -> bool {
        self.motions.iter().any(Motion::deforms)
    }

    /// The rigid transform (placement, then rigid motions) at time `t`.
    pub fn transform_at(&self, t: f32) -> Affine3A {
        self.motions
            .iter()
            .fold(self.placement, |m, motion| motion.rigid(m, t))
    }

    /// Whether the transform at `t` is a similarity (uniform scale): bounding spheres then map
    /// to bounding spheres.
    fn similarity(m: &Affine3A) -> bool {
        let c = [m.matrix3.x_axis, m.matrix3.y_axis, m.matrix3.z_axis].map(|v| v.length());
        let orth = m.matrix3.x_axis.dot(m.matrix3.y_axis).abs()
            + m.matrix3.y_axis.dot(m.matrix3.z_axis).abs()
            + m.matrix3.x_axis.dot(m.matrix3.z_axis).abs();
        let s = c[0].max(c[1]).max(c[2]);
        s > 0.0
            && (c[0] - c[1]).abs() <= 1e-5 * s
            && (c[1] - c[2]).abs() <= 1e-5 * s
            && orth <= 1e-5 * s * s
    }
}

/// Time spent bringing a scene to a frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct UpdateTimes {
    /// Transforming vertices and normals, mesh boxes, scene bounds, degenerate count, ms.
    pub geometry_ms: f64,
    /// Triangle and mesh bounding spheres of the moved meshes, ms (0 when not asked for).
    pub spheres_ms: f64,
    /// Vertices moved.
    pub vertices: u64,
    /// Triangles moved.
    pub triangles: u64,
}

/// A scene whose instances move: see the module documentation.
#[derive(Clone, Debug)]
pub struct AnimatedScene {
    scene: Scene,
    instances: Vec<Instance>,
    fps: f32,
    /// Degenerate triangles outside the moving instances.
    static_degenerate: usize,
}

impl AnimatedScene {
    /// A scene that never moves.
    pub fn fixed(scene: Scene) -> AnimatedScene {
        let static_degenerate = scene.degenerate_triangles;
        AnimatedScene {
            scene,
            instances: Vec::new(),
            fps: DEFAULT_FPS,
            static_degenerate,
        }
    }

    /// An animated scene from `scene`, whose instance vertices are still in object space, and
    /// its `instances` (ranges into `scene`): places every instance (static ones for good),
    /// then evaluates frame 0.
    ///
    /// # Errors
    /// [`SceneError::Invalid`] for an invalid motion, overlapping or out-of-range instance
    /// ranges, an `fps` outside [`FPS_RANGE`], or a placement or frame 0 that is not finite or moves a
    /// vertex beyond [`MAX_COORDINATE`].
    pub fn new(
        mut scene: Scene,
        mut instances: Vec<Instance>,
        fps: f32,
    ) -> Result<AnimatedScene, SceneError> {
        let context = scene.name.clone();
        if !FPS_RANGE.contains(&fps) {
            return Err(SceneError::invalid(
                context,
                format!(
                    "animation fps {fps:?} is outside {}..={}",
                    FPS_RANGE.start(),
                    FPS_RANGE.end()
                ),
            ));
        }
        let mut end_v = 0;
        for inst in &mut instances {
            let bad =
                |m: String| SceneError::invalid(format!("{context}: instance '{}'", inst.name), m);
            for m in &inst.motions {
                m.validate().map_err(bad)?;
            }
            if inst.vertices.start < end_v
                || inst.vertices.end > scene.positions.len()
                || inst.meshes.end > scene.meshes.len()
                || inst.triangles.end > scene.indices.len()
            {
                return Err(bad("instance ranges overlap or leave the scene".into()));
            }
            end_v = inst.vertices.end;
            if !inst.placement.is_finite() {
                return Err(bad("placement is not finite".into()));
            }
            let normal_m = normal_matrix(&inst.placement);
            let vs = inst.vertices.clone();
            if inst.moves() {
                inst.object_positions = scene.positions[vs.clone()].to_vec();
                inst.object_normals = scene.normals[vs.clone()].to_vec();
            }
            // Place it (static instances stay there).
            for v in vs.clone() {
                scene.positions[v] = inst.placement.transform_point3(scene.positions[v]);
                scene.normals[v] = (normal_m * Vec3A::from(scene.normals[v]))
                    .normalize_or_zero()
                    .into();
            }
            if let Some(p) = scene.positions[vs].iter().find(|p| out_of_range(**p)) {
                return Err(bad(format!(
                    "placement moves a vertex to {p}: non-finite or beyond the supported \
                     magnitude {MAX_COORDINATE:e}"
                )));
            }
        }
        let mut anim = AnimatedScene {
            scene,
            instances,
            fps,
            static_degenerate: 0,
        };
        // Everything placed: recompute what depends on positions, once, for all meshes.
        let all: Vec<(usize, Option<Vec3>)> =
            (0..anim.scene.meshes.len()).map(|k| (k, None)).collect();
        refresh_meshes(&mut anim.scene, &all, Refresh::Boxes);
        refresh_meshes(&mut anim.scene, &all, Refresh::Spheres);
        for inst in anim.instances.iter_mut().filter(|i| i.moves()) {
            let to_object = inst.placement.inverse();
            inst.object_centers = anim.scene.meshes[inst.meshes.clone()]
                .iter()
                .map(|m| to_object.transform_point3(m.sphere.center))
                .collect();
        }
        let moving_degenerate: usize = anim
            .instances
            .iter()
            .filter(|i| i.moves())
            .map(|i| count_degenerate(&anim.scene, i.triangles.clone()))
            .sum();
        // Placing can make a triangle degenerate (or not): count again, all of them.
        let all_degenerate = count_degenerate(&anim.scene, 0..anim.scene.indices.len());
        anim.static_degenerate = all_degenerate - moving_degenerate;
        let mut scene = anim.scene.clone();
        anim.update(&mut scene, 0, true)?;
        anim.scene = scene;
        Ok(anim)
    }

    /// The scene at frame 0.
    pub fn scene(&self) -> &Scene {
        &self.scene
    }

    /// Sets every light's radius ([`Scene::set_light_radius`]); frames made from
    /// [`AnimatedScene::scene`] carry it.
    ///
    /// # Errors
    /// As [`Scene::set_light_radius`].
    pub fn set_light_radius(&mut self, radius: f32) -> Result<(), SceneError> {
        self.scene.set_light_radius(radius)
    }

    /// The scene at frame 0, owned.
    pub fn into_scene(self) -> Scene {
        self.scene
    }

    /// The instances.
    pub fn instances(&self) -> &[Instance] {
        &self.instances
    }

    /// Frames per second of scene time.
    pub fn fps(&self) -> f32 {
        self.fps
    }

    /// Whether anything moves.
    pub fn is_animated(&self) -> bool {
        self.instances.iter().any(Instance::moves)
    }

    /// Triangles of the moving instances.
    pub fn moving_triangles(&self) -> usize {
        self.instances
            .iter()
            .filter(|i| i.moves())
            .map(|i| i.triangles.len())
            .sum()
    }

    /// The time of frame `frame`, in seconds.
    pub fn time_of(&self, frame: u32) -> f32 {
        frame as f32 / self.fps
    }

    /// Writes frame `frame` into `scene` (a clone of [`AnimatedScene::scene`], possibly left
    /// at another frame): positions and normals of the moving instances, their meshes' boxes,
    /// the scene bounds, the degenerate count and, with `spheres`, their triangle and mesh
    /// bounding spheres (else those become infinite). Parallel over vertices and triangles;
    /// the result does not depend on the thread count.
    ///
    /// # Errors
    /// [`SceneError::Invalid`] when `scene` is not this animation's (other array sizes), or a
    /// motion carries a vertex to a non-finite position or one beyond [`MAX_COORDINATE`].
    pub fn update(
        &self,
        scene: &mut Scene,
        frame: u32,
        spheres: bool,
    ) -> Result<UpdateTimes, SceneError> {
        if scene.positions.len() != self.scene.positions.len()
            || scene.indices.len() != self.scene.indices.len()
            || scene.meshes.len() != self.scene.meshes.len()
        {
            return Err(SceneError::invalid(
                &self.scene.name,
                "update: the scene is not this animation's",
            ));
        }
        let t = self.time_of(frame);
        let mut times = UpdateTimes::default();
        let t0 = Instant::now();
        let mut moved_meshes = Vec::new();
        for inst in self.instances.iter().filter(|i| i.moves()) {
            let m = inst.transform_at(t);
            let nm = normal_matrix(&m);
            let deforming: Vec<&Motion> = inst.motions.iter().filter(|m| m.deforms()).collect();
            let vs = inst.vertices.clone();
            let positions = &mut scene.positions[vs.clone()];
            positions
                .par_iter_mut()
                .zip(inst.object_positions.par_iter())
                .for_each(|(p, &o)| {
                    let d = deforming.iter().fold(o, |q, motion| motion.deform(q, t));
                    *p = m.transform_point3(d);
                });
            if let Some(i) = positions.iter().position(|p| out_of_range(*p)) {
                return Err(SceneError::invalid(
                    format!("{}: instance '{}'", self.scene.name, inst.name),
                    format!(
                        "frame {frame}: vertex {i} moves to {}: non-finite or beyond the \
                         supported magnitude {MAX_COORDINATE:e}",
                        positions[i]
                    ),
                ));
            }
            if deforming.is_empty() {
                scene.normals[vs.clone()]
                    .par_iter_mut()
                    .zip(inst.object_normals.par_iter())
                    .for_each(|(n, &o)| *n = (nm * Vec3A::from(o)).normalize_or_zero().into());
            } else {
                recompute_normals(scene, inst, &nm);
            }
            times.vertices += vs.len() as u64;
            times.triangles += inst.triangles.len() as u64;
            let sim = deforming.is_empty() && Instance::similarity(&m);
            for (i, k) in inst.meshes.clone().enumerate() {
                let center = sim.then(|| m.transform_point3(inst.object_centers[i]));
                moved_meshes.push((k, center));
            }
        }
        // Boxes, bounds, degenerate count (geometry), then spheres.
        let degenerate: usize = self
            .instances
            .iter()
            .filter(|i| i.moves())
            .map(|i| count_degenerate(scene, i.triangles.clone()))
            .sum();
        scene.degenerate_triangles = self.static_degenerate + degenerate;
        refresh_meshes(scene, &moved_meshes, Refresh::Boxes);
        times.geometry_ms = t0.elapsed().as_secs_f64() * 1e3;
        let t1 = Instant::now();
        if spheres {
            refresh_meshes(scene, &moved_meshes, Refresh::Spheres);
            times.spheres_ms = t1.elapsed().as_secs_f64() * 1e3;
        } else {
            for &(k, _) in &moved_meshes {
                let m = &mut scene.meshes[k];
                let range = m.first_tri as usize..(m.first_tri + m.tri_count) as usize;
                m.sphere = Sphere::new(m.aabb.center(), f32::INFINITY);
                for s in &mut scene.tri_spheres[range] {
                    s.radius = f32::INFINITY;
                }
            }
        }
        Ok(times)
    }
}

/// The inverse transpose of the linear part (normals under non-uniform scale).
fn normal_matrix(m: &Affine3A) -> Mat3A {
    // Divided by its largest entry first (normals are normalized after the transform), so a
    // uniform scale as small as `1e-30` or as large as `1e30` still inverts.
    let big = m
        .matrix3
        .abs()
        .to_cols_array()
        .into_iter()
        .fold(0.0, f32::max);
    let m3 = if big.is_finite() && big > 0.0 {
        m.matrix3 * (1.0 / big)
    } else {
        m.matrix3
    };
    let det = m3.determinant();
    if det.abs() > f32::MIN_POSITIVE {
        m3.inverse().transpose()
    } else {
        m3
    }
}

fn count_degenerate(scene: &Scene, tris: Range<usize>) -> usize {
    scene.indices[tris]
        .par_iter()
        .filter(|&&[a, b, c]| {
            is_degenerate_triangle(
                scene.positions[a as usize],
                scene.positions[b as usize],
                scene.positions[c as usize],
            )
        })
        .count()
}

/// Area-weighted vertex normals of a deformed instance; a vertex whose incident faces cancel
/// keeps its rigidly transformed rest normal.
fn recompute_normals(scene: &mut Scene, inst: &Instance, nm: &Mat3A) {
    let base = inst.vertices.start;
    let mut sums = vec![Vec3::ZERO; inst.vertices.len()];
    for &[a, b, c] in &scene.indices[inst.triangles.clone()] {
        let (pa, pb, pc) = (
            scene.positions[a as usize],
            scene.positions[b as usize],
            scene.positions[c as usize],
        );
        let n = (pb - pa).cross(pc - pa);
        for v in [a, b, c] {
            if let Some(s) = (v as usize).checked_sub(base).and_then(|i| sums.get_mut(i)) {
                *s += n;
            }
        }
    }
    scene.normals[inst.vertices.clone()]
        .par_iter_mut()
        .zip(sums.par_iter().zip(inst.object_normals.par_iter()))
        .for_each(|(n, (&s, &o))| {
            *n = if s.length_squared() > 0.0 && s.is_finite() {
                s.normalize()
            } else {
                (*nm * Vec3A::from(o)).normalize_or_zero().into()
            };
        });
}

/// What [`refresh_meshes`] recomputes.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Refresh {
    /// Mesh boxes and the scene bounds.
    Boxes,
    /// Triangle and mesh bounding spheres.
    Spheres,
}

/// Recomputes the boxes (and the scene bounds) or the spheres of `meshes`. Spheres are the
/// exact minimal ones, except for a mesh given a centre (moved by a similarity from its rest:
/// its rest sphere's centre mapped by the frame's transform), whose radius is re-measured over
/// its vertices and rounded up: as tight up to rounding, at a fraction of Welzl's cost.
fn refresh_meshes(scene: &mut Scene, meshes: &[(usize, Option<Vec3>)], what: Refresh) {
    let Scene {
        positions,
        indices,
        tri_spheres,
        meshes: scene_meshes,
        bounds,
        ..
    } = scene;
    for &(k, center) in meshes {
        let mesh = &mut scene_meshes[k];
        let range = mesh.first_tri as usize..(mesh.first_tri + mesh.tri_count) as usize;
        let tris = &indices[range.clone()];
        if what == Refresh::Boxes {
            mesh.aabb = tris
                .par_iter()
                .fold(
                    || Aabb::EMPTY,
                    |b, t| t.iter().fold(b, |b, &v| b.grow(positions[v as usize])),
                )
                .reduce(|| Aabb::EMPTY, Aabb::union);
            continue;
        }
        tri_spheres[range]
            .par_iter_mut()
            .zip(tris.par_iter())
            .for_each(|(s, &[a, b, c])| {
                *s = bounding::triangle_sphere(
                    positions[a as usize],
                    positions[b as usize],
                    positions[c as usize],
                );
            });
        mesh.sphere = match center {
            Some(center) => {
                let r = tris
                    .par_iter()
                    .map(|t| {
                        t.iter()
                            .map(|&v| (positions[v as usize] - center).length())
                            .fold(0.0f32, f32::max)
                    })
                    .reduce(|| 0.0, f32::max);
                Sphere::new(center, next_up(r))
            }
            None => {
                let mut seen = std::collections::HashSet::new();
                let used: Vec<Vec3> = tris
                    .iter()
                    .flatten()
                    .filter(|&&v| seen.insert(v))
                    .map(|&v| positions[v as usize])
                    .collect();
                bounding::min_sphere(&used)
            }
        };
    }
    if what == Refresh::Boxes {
        *bounds = scene_meshes
            .iter()
            .fold(Aabb::EMPTY, |b, m| b.union(m.aabb));
    }
}

/// The next `f32` above a non-negative `x` (so a re-measured radius bounds every vertex).
fn next_up(x: f32) -> f32 {
    if x.is_finite() {
        f32::from_bits(x.to_bits() + 1).max(x * (1.0 + 1e-6))
    } else {
        x
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::{Camera, Material, SceneBuilder};

    fn quad_scene(motions: Vec<Motion>) -> AnimatedScene {
        let mut b = SceneBuilder::new("anim");
        b.material(Material::default());
        b.camera(Camera {
            eye: Vec3::new(0.0, 0.0, 5.0),
            target: Vec3::ZERO,
            up: Vec3::Y,
            vfov_deg: 45.0,
            aspect: None,
        });
        let floor = [[-5.0, -5.0], [5.0, -5.0], [5.0, 5.0], [-5.0, 5.0]]
            .map(|[x, z]| Vec3::new(x, -1.0, z));
        b.mesh("floor", &floor, None, &[[0, 2, 1], [0, 3, 2]], 0);
        let g = crate::builtin::Geometry::icosphere(Vec3::ZERO, 1.0, 1);
        b.mesh("ball", &g.positions, Some(&g.normals), &g.indices, 0);
        let scene = b.build("anim").unwrap();
        let nv = scene.positions.len();
        let inst = Instance {
            name: "ball".into(),
            vertices: 4..nv,
            meshes: 1..2,
            triangles: 2..scene.indices.len(),
            object_positions: Vec::new(),
            object_normals: Vec::new(),
            object_centers: Vec::new(),
            placement: Affine3A::from_translation(Vec3::new(0.0, 1.0, 0.0)),
            motions,
        };
        AnimatedScene::new(scene, vec![inst], 10.0).unwrap()
    }

    fn check_bounds(scene: &Scene) {
        for m in &scene.meshes {
            let r = m.first_tri as usize..(m.first_tri + m.tri_count) as usize;
            for (t, tri) in scene.indices[r.clone()].iter().enumerate() {
                let s = scene.tri_spheres[r.start + t];
                for &v in tri {
                    let p = scene.positions[v as usize];
                    assert!(s.contains(p, 1e-6), "{s:?} {p}");
                    assert!(m.sphere.contains(p, 1e-6), "{:?} {p}", m.sphere);
                    assert!(m.aabb.contains(p));
                    assert!(scene.bounds.contains(p));
                }
            }
        }
    }

    #[test]
    fn rigid_motions_move_vertices_normals_and_bounds() {
        let anim = quad_scene(vec![
            Motion::Translate {
                velocity: [1.0, 0.0, 0.0],
            },
            Motion::Rotate {
                axis: [0.0, 0.0, 1.0],
                degrees_per_second: 90.0,
                pivot: None,
            },
        ]);
        let rest = anim.scene().clone();
        // Frame 0: the placement only (the ball centred at y = 1).
        let c = rest.meshes[1].sphere.center;
        assert!(c.abs_diff_eq(Vec3::new(0.0, 1.0, 0.0), 1e-5), "{c}");
        check_bounds(&rest);
        let mut s = rest.clone();
        let times = anim.update(&mut s, 10, true).unwrap(); // t = 1 s
        assert_eq!(times.triangles, 80);
        // Translated by (1, 0, 0), spun 90° about its own origin: the centre moves only.
        let c = s.meshes[1].sphere.center;
        assert!(c.abs_diff_eq(Vec3::new(1.0, 1.0, 0.0), 1e-5), "{c}");
        assert_eq!(
            s.positions[..4],
            rest.positions[..4],
            "the floor does not move"
        );
        check_bounds(&s);
        // Normals stay radial.
        for v in 4..s.positions.len() {
            let radial = (s.positions[v] - c).normalize();
            assert!(radial.dot(s.normals[v]) > 0.999);
        }
        // Updating to frame 0 again gives frame 0's arrays back.
        anim.update(&mut s, 0, true).unwrap();
        for (a, b) in s.positions.iter().zip(&rest.positions) {
            assert!(a.abs_diff_eq(*b, 1e-6));
        }
    }

    #[test]
    fn deformations_move_every_vertex_and_spheres_stay_bounding() {
        let anim = quad_scene(vec![Motion::Twist {
            axis: [0.0, 1.0, 0.0],
            degrees_per_unit: 40.0,
            period: 2.0,
        }]);
        let mut s = anim.scene().clone();
        anim.update(&mut s, 5, true).unwrap();
        let moved = s
            .positions
            .iter()
            .zip(&anim.scene().positions)
            .filter(|(a, b)| !a.abs_diff_eq(**b, 1e-6))
            .count();
        assert!(moved > 20, "{moved}");
        check_bounds(&s);
        let wave = quad_scene(vec![Motion::Wave {
            amplitude: 0.2,
            wavelength: 1.0,
            speed: 1.0,
            direction: [1.0, 0.0, 0.0],
            axis: [0.0, 1.0, 0.0],
        }]);
        let mut w = wave.scene().clone();
        wave.update(&mut w, 3, true).unwrap();
        check_bounds(&w);
        // Without spheres, the moving meshes' spheres become infinite (still bounding).
        wave.update(&mut w, 4, false).unwrap();
        assert!(w.meshes[1].sphere.radius.is_infinite());
        assert!(w.meshes[0].sphere.radius.is_finite());
    }

    #[test]
    fn keyframes_interpolate_and_hold() {
        let keys = vec![
            Keyframe {
                time: 0.0,
                translate: [0.0; 3],
                rotate: no_rotation(),
                scale: 1.0,
            },
            Keyframe {
                time: 1.0,
                translate: [2.0, 0.0, 0.0],
                rotate: [0.0, 1.0, 0.0, 90.0],
                scale: 2.0,
            },
        ];
        let (t, r, s) = sample_keys(&keys, false, 0.5);
        assert!(t.abs_diff_eq(Vec3::new(1.0, 0.0, 0.0), 1e-6));
        assert!((s - 1.5).abs() < 1e-6);
        assert!(r.angle_between(Quat::from_rotation_y(45f32.to_radians())) < 1e-4);
        assert_eq!(sample_keys(&keys, false, 7.0).2, 2.0);
        assert!((sample_keys(&keys, true, 1.5).2 - 1.5).abs() < 1e-5);
        let anim = quad_scene(vec![Motion::Keyframes {
            keys,
            repeat: false,
        }]);
        let mut s = anim.scene().clone();
        anim.update(&mut s, 10, true).unwrap();
        let m = &s.meshes[1].sphere;
        assert!(
            m.center.abs_diff_eq(Vec3::new(2.0, 1.0, 0.0), 1e-4),
            "{m:?}"
        );
        assert!((m.radius - 2.0).abs() < 1e-3, "{m:?}");
    }

    #[test]
    fn bad_motions_are_errors_naming_the_value() {
        for (m, what) in [
            (
                Motion::Rotate {
                    axis: [0.0; 3],
                    degrees_per_second: 1.0,
                    pivot: None,
                },
                "axis",
            ),
            (
                Motion::Wave {
                    amplitude: 1.0,
                    wavelength: 0.0,
                    speed: 1.0,
                    direction: x_axis(),
                    axis: y_axis(),
                },
                "wavelength",
            ),
            (
                Motion::Scale {
                    factor_per_second: f32::NAN,
                    pivot: None,
                },
                "factor",
            ),
        ] {
            let e = m.validate().unwrap_err();
            assert!(e.contains(what), "{e}");
        }
        let anim = quad_scene(vec![Motion::Scale {
            factor_per_second: 1e30,
            pivot: None,
        }]);
        let mut s = anim.scene().clone();
        let e = anim.update(&mut s, 100, true).unwrap_err();
        assert!(e.to_string().contains("non-finite"), "{e}");
    }
}
