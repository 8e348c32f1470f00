//! A third-party intersector, registered in the CPU registry with a preset of its own and
//! compared with brute force and the BVH in an ablation plan run by `crsh ablate`.
//!
//! ```sh
//! cargo run --release --example custom_intersector     # runs examples/custom_intersector.toml
//! cargo run --release --example custom_intersector -- render --pipeline mesh_spheres --reference brute
//! ```
//!
//! Without arguments it runs `ablate --plan examples/custom_intersector.toml --out
//! ablate-custom-intersector`: `mesh_spheres` (with and without its culling) against `brute`
//! and `bvh` on the built-in scenes, with brute force as the reference.
//!
//! `mesh_spheres` is brute force with one level of culling: a ray is tested against a mesh's
//! triangles only when its segment passes through the mesh's minimal bounding sphere. The
//! triangles are tested with crsh's Möller-Trumbore, so its hits equal brute force's; it
//! answers whole-scene queries only (its catalogue entry says so, so a pipeline with a
//! ray-space hierarchy refuses it when the pipeline is built).

use std::sync::Arc;

use crsh::crsh_core::glam::Vec3;
use crsh::crsh_core::{CoreError, Hit, HitMode, Intersector, Query, Ray, Result, Stats};
use crsh::crsh_cpu::triangle::moller_trumbore::{PreparedTriangle, RayPre};
use crsh::{Cpu, ParamInfo, PipelineConfig, Registries, Scene, StageKind, StageVariantInfo};
use rayon::prelude::*;

/// Brute force behind per-mesh bounding spheres.
struct MeshSpheres {
    scene: Arc<Scene>,
    tris: Vec<PreparedTriangle>,
    cull: bool,
}

impl MeshSpheres {
    /// Whether the segment `(t_min, t_max)` of `ray` passes within the mesh's sphere (with a
    /// relative margin for rounding, so no hit is lost).
    fn near(&self, mesh: usize, ray: &Ray) -> bool {
        let s = self.scene.meshes[mesh].sphere;
        let d = ray.dir.normalize();
        let scale = ray.dir.length();
        let to_c: Vec3 = s.center - ray.origin;
        let t = to_c
            .dot(d)
            .clamp(ray.t_min.max(0.0) * scale, ray.t_max.min(f32::MAX) * scale);
        let slack =
            1e-5 * (s.radius + s.center.abs().max_element() + ray.origin.abs().max_element());
        (ray.origin + d * t - s.center).length() <= s.radius + slack
    }

    /// The hit of one ray (`best` on entry: the hit already stored).
    fn trace(&self, ray: &Ray, mode: HitMode, mut best: Hit, counts: &mut (u64, u64)) -> Hit {
        if !ray.is_valid() {
            return best;
        }
        let pre = RayPre::new(ray.origin, ray.dir);
        for (m, mesh) in self.scene.meshes.iter().enumerate() {
            counts.0 += u64::from(self.cull);
            if self.cull && !self.near(m, ray) {
                continue;
            }
            let first = mesh.first_tri as usize;
            for (i, tri) in self.tris[first..first + mesh.tri_count as usize]
                .iter()
                .enumerate()
            {
                counts.1 += 1;
                if let Some(h) = tri.hit(&pre, ray.t_min, ray.t_max, (first + i) as u32) {
                    if mode == HitMode::Any {
                        return h;
                    }
                    if h.closer_than(&best) {
                        best = h;
                    }
                }
            }
        }
        best
    }
}

impl Intersector<Cpu> for MeshSpheres {
    fn name(&self) -> &str {
        "mesh_spheres"
    }

    fn supports_candidates(&self) -> bool {
        false
    }

    fn intersect(
        &self,
        _: &Cpu,
        rays: &Vec<Ray>,
        query: Query<'_, Cpu>,
        mode: HitMode,
        hits: &mut Vec<Hit>,
        stats: &mut Stats,
    ) -> Result<()> {
        if !matches!(query, Query::Scene) {
            return Err(CoreError::Unsupported {
                stage: "intersect",
                variant: "mesh_spheres".into(),
                what: "candidate queries".into(),
            });
        }
        let counts = rays
            .par_iter()
            .zip(hits.par_iter_mut())
            .map(|(ray, hit)| {
                let mut c = (0, 0);
                *hit = self.trace(ray, mode, *hit, &mut c);
                c
            })
            .reduce(|| (0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
        stats.add_bounds(counts.0);
        stats.add_ray_triangle(counts.1);
        Ok(())
    }
}

fn main() {
    let mut registries = Registries::builtin();
    let info = StageVariantInfo::new(
        StageKind::Intersect,
        "mesh_spheres",
        "brute force behind per-mesh bounding spheres (example); whole-scene queries only",
    )
    .param(ParamInfo::bool(
        "cull",
        true,
        "test the mesh spheres first (false: plain brute force)",
    ))
    .scene_only();
    registries
        .cpu
        .add_intersector(info, |ctx, spec| {
            let scene = Arc::clone(ctx.scene);
            let tris = (0..scene.triangle_count())
                .map(|t| {
                    let [a, b, c] = scene.triangle(t);
                    PreparedTriangle::new(a, b, c)
                })
                .collect();
            Ok(Box::new(MeshSpheres {
                scene,
                tris,
                cull: spec.bool("cull")?,
            }))
        })
        .expect("a new intersector")
        .add_preset(
            "mesh_spheres",
            "raster primaries, Whitted rays and Phong shading traced by mesh_spheres (example)",
            PipelineConfig::whitted("mesh_spheres", "mesh_spheres"),
        )
        .expect("a preset of registered variants");

    let mut args: Vec<String> = std::env::args().collect();
    if args.len() == 1 {
        let plan = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/examples/custom_intersector.toml"
        );
        args.extend(
            [
                "ablate",
                "--plan",
                plan,
                "--out",
                "ablate-custom-intersector",
            ]
            .map(String::from),
        );
    }
    crsh_cli::main_with_args(registries, args)
}
