//! Test support shared by this crate's tests, the workspace tests and the CLI's: one device per
//! process, or a printed skip.

use std::cell::RefCell;
use std::sync::{Arc, Mutex, MutexGuard, OnceLock};

use crsh_core::glam::{DVec3, Vec3};
use crsh_core::{
    FrameSize, Hit, HitMode, Intersector, PipelineConfig, Ray, RayKind, Registry, StageContext,
    StageSpec, Stages,
};
use crsh_cpu::Cpu;
use crsh_scene::Scene;

use crate::adapter::GpuContext;
use crate::backend::Wgpu;

/// The CPU twins' registry, built once.
pub fn cpu_registry() -> &'static Registry<Cpu> {
    static REGISTRY: OnceLock<Registry<Cpu>> = OnceLock::new();
    REGISTRY.get_or_init(Registry::<Cpu>::builtin)
}

/// The CPU preset `name`, resolved. Panics when there is none (a test bug).
pub fn cpu_preset(name: &str) -> PipelineConfig {
    cpu_registry()
        .preset(name)
        .unwrap_or_else(|| panic!("no preset `{name}`"))
}

/// The stages of `cfg` built by the CPU registry for `scene` at `width × height`.
pub fn cpu_stages(
    cfg: &PipelineConfig,
    scene: &Arc<Scene>,
    width: u32,
    height: u32,
) -> Stages<Cpu> {
    let frame = FrameSize::new(width, height).expect("valid test frame");
    cpu_registry()
        .build(&StageContext::new(&Cpu, scene, frame), cfg)
        .unwrap_or_else(|e| panic!("building {}: {e}", cfg.name))
        .stages
}

/// The CPU intersector `spec` for `scene`.
pub fn cpu_intersector(spec: &StageSpec, scene: &Arc<Scene>) -> Box<dyn Intersector<Cpu>> {
    let frame = FrameSize::new(1, 1).expect("valid frame");
    cpu_registry()
        .build_intersector(&StageContext::new(&Cpu, scene, frame), spec)
        .unwrap_or_else(|e| panic!("building intersector {}: {e}", spec.kind))
}

/// Whether `CRSH_REQUIRE_GPU=1`: a missing adapter is then a failure rather than a skip.
pub fn gpu_required() -> bool {
    std::env::var("CRSH_REQUIRE_GPU").as_deref() == Ok("1")
}

/// The process-wide device for tests, or `None` after printing `SKIP: no wgpu adapter (...)`
/// naming `test`. Panics when [`gpu_required`] and no adapter can be opened.
///
/// On OpenGL the calling thread first takes its turn on the device ([`take_turn`]): the test
/// harness runs each test on a thread of its own, and wgpu's single GL context cannot be
/// shared by tests that run at once.
pub fn shared_context(test: &str) -> Option<Arc<GpuContext>> {
    static CTX: OnceLock<Result<Arc<GpuContext>, String>> = OnceLock::new();
    let ctx = CTX.get_or_init(|| GpuContext::new().map(Arc::new).map_err(|e| e.to_string()));
    match ctx {
        Ok(ctx) => {
            if ctx.info().backend == "gl" {
                take_turn();
            }
            Some(Arc::clone(ctx))
        }
        Err(e) => {
            if gpu_required() {
                panic!("CRSH_REQUIRE_GPU=1 but no usable wgpu adapter for `{test}`: {e}");
            }
            println!("SKIP: no wgpu adapter ({e}) in `{test}`");
            None
        }
    }
}

/// Makes the calling thread the only one of this process using a GL device, until it ends:
/// it waits for the thread that holds the turn to end (the test harness's threads end with
/// their test, panics included). Taking it again on the same thread does nothing.
///
/// wgpu's GL backend drives one GL context behind a lock that a call waits at most 6 s for,
/// and Mesa's llvmpipe runs a dispatch while holding it: two tests sharing the device on a
/// 2-core machine make one of them panic with "Could not lock adapter context".
pub fn take_turn() {
    static DEVICE: Mutex<()> = Mutex::new(());
    thread_local! {
        static TURN: RefCell<Option<MutexGuard<'static, ()>>> = const { RefCell::new(None) };
    }
    TURN.with(|t| {
        let mut t = t.borrow_mut();
        if t.is_none() {
            // A test that panicked with the turn poisons nothing the lock protects.
            *t = Some(DEVICE.lock().unwrap_or_else(|p| p.into_inner()));
        }
    });
}

/// [`shared_context`] as a [`Wgpu`] backend.
pub fn shared_backend(test: &str) -> Option<Wgpu> {
    shared_context(test).map(Wgpu::from_context)
}

/// A ray of `kind` from `origin` along `dir` over `[t_min, t_max]`, pixel and source `i`,
/// depth 1, throughput one, light 0.
pub fn ray(origin: Vec3, dir: Vec3, t_min: f32, t_max: f32, kind: RayKind, i: u32) -> Ray {
    Ray {
        pixel: i,
        light: 0,
        source: i,
        ..Ray::new(kind, origin, dir, t_min, t_max)
    }
}

/// `|a − b|` relative to the larger magnitude (0 when equal, infinities included).
pub fn rel_diff(a: f32, b: f32) -> f32 {
    if a == b {
        0.0
    } else {
        (a - b).abs() / a.abs().max(b.abs()).max(1e-6)
    }
}

/// `a` and `b` equal, or within `rel` of the largest of their magnitudes and `scale` (an
/// interval end is computed from points on the scale of the ray's origin, so its rounding is
/// too).
pub fn close_at(a: f32, b: f32, rel: f32, scale: f32) -> bool {
    a == b || (a - b).abs() <= rel * a.abs().max(b.abs()).max(scale).max(1e-6)
}

/// Where a ray's segment cuts an origin-offset hemisphere's sphere nearly at a tangent, the
/// query's root `sqrt(b² − c)` turns the rounding of `b² − c` into an error of about `sqrt(ε)`
/// times the scale: such intervals ("tangents") may differ between the device and the CPU by up
/// to this much, relative to the larger of the interval end and the origin's coordinates
/// ([`close_at`]). Where a start or end lies on a hemisphere's boundary, rounding flips it in or
/// out and the whole interval changes ("flips"). Lavapipe: neither. An NVIDIA H200,
/// 2026-12-04, which fuses `a·b + c`: 6 (Whitted) and 8 (the `ao`/`diffuse` twin query) tangents
/// of 1,164 Wächter shadow rays from the surface with the `center` set (`t_min` 0.13622 against
/// 0.13628 on one), and flips (`t_max` 3.857 against 4.160 on an `office-boxes` shadow ray from
/// the light). [`assert_boundary_cases`] bounds how many a batch may have.
pub const TANGENT_ABS: f32 = 1e-3;

/// Asserts the per-batch bounds of the boundary cases of [`TANGENT_ABS`] among `n` rays: at
/// most one tangent in 100 and one flip in 200, plus one each.
pub fn assert_boundary_cases(what: &str, tangents: usize, flips: usize, n: usize) {
    assert!(
        tangents <= n / 100 + 1,
        "{what}: {tangents} of {n} intervals near a tangent"
    );
    assert!(
        flips <= n / 200 + 1,
        "{what}: {flips} of {n} intervals flipped"
    );
}

/// Relative tolerance of a hit's `t`, and absolute tolerance of its barycentrics, between the
/// device and a CPU twin running the same ray-triangle test. WGSL lets a compiler fuse `a·b + c`
/// and round divisions to 2.5 ULP, so the device's values need not equal the CPU's bit for bit
/// (on lavapipe they do; on an NVIDIA H200, 2026-12-04, `u` and `v` differed by up to 8 ULP).
pub const HIT_T_REL: f32 = 1e-5;
/// See [`HIT_T_REL`].
pub const HIT_UV_ABS: f32 = 1e-5;

/// Whether device hit `a` and CPU hit `b` of one ray agree up to the rounding WGSL allows: the
/// same hit or miss for any-hit rays; for closest-hit rays the same triangle, `t` within
/// [`HIT_T_REL`] and `u`, `v` within [`HIT_UV_ABS`].
pub fn hits_agree(mode: HitMode, a: &Hit, b: &Hit) -> bool {
    match mode {
        HitMode::Any | HitMode::EdgeWidth(_) => a.is_hit() == b.is_hit(),
        HitMode::Closest => {
            a.tri == b.tri
                && (!a.is_hit()
                    || ((a.t - b.t).abs() <= HIT_T_REL * a.t.abs().max(b.t.abs())
                        && (a.u - b.u).abs() <= HIT_UV_ABS
                        && (a.v - b.v).abs() <= HIT_UV_ABS))
        }
    }
}

/// The barycentrics `u`, `v` of `ray` on triangle `tri` of `scene` in f64 (`None` for a
/// triangle the scene lacks), and the Möller-Trumbore test's condition
/// number `|d|·(|s| + |e1| + |e2|)·(|e1| + |e2|) / |det|` (`s` from the first vertex to the
/// origin): the rounding errors of `u = s·(d×e2)/det` and `v = d·(s×e1)/det` are about that
/// many times the unit roundoff. It grows as one over the sine of the angle between the ray
/// and the plane, and with the origin's distance over the triangle's size.
pub fn barycentrics_f64(scene: &Scene, ray: &Ray, tri: u32) -> Option<(f64, f64, f64)> {
    let tri = tri as usize;
    if tri >= scene.triangle_count() {
        return None;
    }
    let [p0, p1, p2] = scene.triangle(tri).map(|v| v.as_dvec3());
    let (o, d) = (ray.origin.as_dvec3(), ray.dir.as_dvec3());
    let (e1, e2) = (p1 - p0, p2 - p0);
    let p = d.cross(e2);
    let det = e1.dot(p);
    let s = o - p0;
    let u = s.dot(p) / det;
    let v = d.dot(s.cross(e1)) / det;
    let (l1, l2) = (e1.length(), e2.length());
    let condition = d.length() * (s.length() + l1 + l2) * (l1 + l2) / det.abs();
    Some((u, v, condition))
}

/// Whether a disagreement between hits `a` and `b` of `ray` on `scene` is float rounding:
/// - both hit different triangles at the same `t` within 1e-5 relative (a tie);
/// - both hit the same triangle, `t`, `u` and `v` within 1e-5 times the test's condition
///   number ([`hits_agree`] allows 1e-5 whatever the ray: a ray at a slant to the triangle
///   rounds more);
/// - one of the hit triangles, re-tested in f64, is met within 1e-5 times the condition number
///   of an edge.
///
/// The condition number ([`barycentrics_f64`]) grows as one over the sine of the angle between
/// the ray and the triangle's plane, so a ray grazing a triangle (or lying in its
/// plane) explains any disagreement on it, and a ray meeting a nearby triangle head-on only
/// one within about 1e-4 of an edge.
pub fn rounding_explains(scene: &Scene, ray: &Ray, a: &Hit, b: &Hit) -> bool {
    if a.is_hit()
        && b.is_hit()
        && a.tri != b.tri
        && (a.t - b.t).abs() <= 1e-5 * a.t.abs().max(b.t.abs())
    {
        return true;
    }
    if a.is_hit() && b.is_hit() && a.tri == b.tri {
        if let Some((_, _, condition)) = barycentrics_f64(scene, ray, a.tri) {
            let tol = 1e-5 * condition.max(1.0);
            let (da, db) = (a.t as f64, b.t as f64);
            if !tol.is_finite()
                || ((da - db).abs() <= tol * da.abs().max(db.abs())
                    && ((a.u - b.u) as f64).abs() <= tol
                    && ((a.v - b.v) as f64).abs() <= tol)
            {
                return true;
            }
        }
    }
    [a, b].iter().filter(|h| h.is_hit()).any(|h| {
        let Some((u, v, condition)) = barycentrics_f64(scene, ray, h.tri) else {
            return false;
        };
        let margin = u.min(v).min(1.0 - u - v).abs();
        margin < 1e-5 * condition.max(1.0) || !DVec3::new(u, v, condition).is_finite()
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A ray from `from` through the point of triangle `tri` at barycentrics `(u, v)`, with the
    /// hit it should report.
    fn aimed(scene: &Scene, tri: u32, from: Vec3, u: f32, v: f32) -> (Ray, Hit) {
        let [a, b, c] = scene.triangle(tri as usize);
        let p = a + (b - a) * u + (c - a) * v;
        let d = p - from;
        let ray = ray(from, d, 0.0, f32::INFINITY, RayKind::Reflection, 0);
        (ray, Hit { t: 1.0, tri, u, v })
    }

    /// The tolerances explain rounding and nothing more: a head-on ray's other triangle, or
    /// its barycentrics off by 1e-3, are not explained; the same ray at an edge, a tie, or a
    /// ray in the triangle's plane are.
    #[test]
    fn rounding_explains_edges_ties_and_grazing_rays_only() {
        let scene = crsh_scene::builtin::build("cornell-mirrors").unwrap();
        let [a, b, c] = scene.triangle(0);
        let n = (b - a).cross(c - a).normalize();
        let centre = (a + b + c) / 3.0;
        let head_on = centre + n * 0.5;
        let (ray, hit) = aimed(&scene, 0, head_on, 0.3, 0.3);
        let far = Hit {
            t: 3.0,
            tri: 5,
            u: 0.2,
            v: 0.2,
        };
        assert!(hits_agree(HitMode::Closest, &hit, &hit));
        assert!(!hits_agree(HitMode::Closest, &hit, &far));
        assert!(hits_agree(HitMode::Any, &hit, &far));
        assert!(!rounding_explains(&scene, &ray, &hit, &far));
        assert!(!rounding_explains(&scene, &ray, &hit, &Hit::MISS));
        let off = Hit {
            u: hit.u + 1e-3,
            ..hit
        };
        assert!(!hits_agree(HitMode::Closest, &hit, &off));
        assert!(!rounding_explains(&scene, &ray, &hit, &off));
        // At an edge (u = 0), against a miss or another triangle.
        let (edge_ray, edge_hit) = aimed(&scene, 0, head_on, 0.0, 0.5);
        assert!(rounding_explains(&scene, &edge_ray, &edge_hit, &Hit::MISS));
        assert!(rounding_explains(&scene, &edge_ray, &far, &edge_hit));
        // A tie: another triangle at the same t.
        let tie = Hit {
            t: 1.0 + 1e-6,
            ..far
        };
        assert!(rounding_explains(&scene, &ray, &hit, &tie));
        // A ray almost in the triangle's plane: its barycentrics are ill-conditioned.
        let (graze_ray, graze_hit) =
            aimed(&scene, 0, centre + (a - centre) * 40.0 + n * 1e-5, 0.3, 0.3);
        assert!(rounding_explains(
            &scene,
            &graze_ray,
            &graze_hit,
            &Hit::MISS
        ));
        assert!(rounding_explains(&scene, &graze_ray, &graze_hit, &off));
    }
}
