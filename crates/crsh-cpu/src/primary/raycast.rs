//! `raycast`: the G-buffer by casting one camera ray through every pixel centre.
//!
//! The alternative to rasterized primary visibility (seed 000 §3.1): the same [`Surface`]
//! records, found by tracing closest hits with the `accel` intersector (`bvh`: the CWBVH of
//! [`crate::intersect::bvh`] with the `medium` preset; `brute`: every triangle; `pipeline`:
//! the pipeline's own intersector, so that the camera rays take the same traversal as the
//! secondary rays, e.g. seed 003's packets and frusta of the `kdtree` intersector). Its test
//! counts go to the stats like any other trace. Camera rays start at the eye with the open
//! interval `(0, ∞)`; pixel `(x, y)` (`y = 0` the top row) looks through `(x + 0.5, y + 0.5)`
//! ([`camera_ray`], shared with the rasterizer so both resolve identical surfaces).

use std::sync::Arc;

use crsh_core::glam::Vec3;
use crsh_core::pipeline::MAX_IMAGE_SIDE;
use crsh_core::{
    CoreError, Hit, HitMode, Intersector, ParamInfo, PrimaryVisibility, Query, Ray, RayKind,
    Registry, Result, StageKind, StageSpec, StageVariantInfo, Stats, Surface,
};
use crsh_scene::{Camera, Scene};
use rayon::prelude::*;

use crate::backend::Cpu;
use crate::intersect::brute::BruteForce;
use crate::intersect::bvh::{BuildQuality, CwBvh};
use crate::surface::surface_from_hit;

/// Origin and unit direction of the camera ray through the centre of pixel `(x, y)`.
#[inline]
pub fn camera_ray(camera: &Camera, x: u32, y: u32, width: u32, height: u32) -> (Vec3, Vec3) {
    (
        camera.eye,
        camera.direction(x as f32 + 0.5, y as f32 + 0.5, width, height),
    )
}

/// Checks the image size and the camera before a G-buffer is rendered.
pub(crate) fn check_view(camera: &Camera, width: u32, height: u32) -> Result<()> {
    if width == 0 || height == 0 || width > MAX_IMAGE_SIDE || height > MAX_IMAGE_SIDE {
        return Err(CoreError::InvalidInput(format!(
            "image size {width}x{height} is outside 1..={MAX_IMAGE_SIDE} per side"
        )));
    }
    camera
        .validate()
        .map_err(|e| CoreError::InvalidInput(format!("camera: {e}")))
}

/// The intersector a [`RayCast`] traces with.
enum Accel {
    Bvh(CwBvh),
    Brute(BruteForce),
    /// The pipeline's intersector, handed over by [`PrimaryVisibility::gbuffer_with`].
    Pipeline,
}

/// The ray-cast primary visibility (variant `raycast`, parameter `accel`).
pub struct RayCast {
    scene: Arc<Scene>,
    accel: Accel,
}

/// The catalogue entry of the `raycast` primary stage.
pub fn info() -> StageVariantInfo {
    StageVariantInfo::new(
        StageKind::Primary,
        "raycast",
        "the same G-buffer by casting one camera ray per pixel centre",
    )
    .param(ParamInfo::choice(
        "accel",
        "bvh",
        &["bvh", "brute", "pipeline"],
        "what traces the camera rays: the obvhs CWBVH, every triangle, or the pipeline's \
         intersector (with its traversal)",
    ))
}

/// Registers `raycast` ([`info`], [`RayCast::new`]).
pub fn register(registry: &mut Registry<Cpu>) -> Result<()> {
    registry.add_primary(info(), |ctx, spec| {
        Ok(Box::new(RayCast::new(ctx.scene, spec)?))
    })?;
    Ok(())
}

impl RayCast {
    /// Prepares the `spec.accel` intersector (`bvh` | `brute` | `pipeline`) for `scene`.
    pub fn new(scene: &Arc<Scene>, spec: &StageSpec) -> Result<RayCast, CoreError> {
        let accel = match spec.str("accel")? {
            "bvh" => Accel::Bvh(CwBvh::build(scene, BuildQuality::Medium)),
            "brute" => Accel::Brute(BruteForce::from_scene(scene)),
            "pipeline" => Accel::Pipeline,
            other => {
                return Err(CoreError::InvalidParam {
                    key: "raycast.accel".into(),
                    reason: format!("`{other}` is not one of bvh, brute, pipeline"),
                })
            }
        };
        Ok(RayCast {
            scene: Arc::clone(scene),
            accel,
        })
    }

    /// The accelerator's variant name.
    pub fn accel_name(&self) -> &str {
        match &self.accel {
            Accel::Bvh(_) => "bvh",
            Accel::Brute(_) => "brute",
            Accel::Pipeline => "pipeline",
        }
    }

    /// The camera rays of a `width × height` image, row-major.
    pub fn camera_rays(&self, width: u32, height: u32) -> Vec<Ray> {
        let camera = &self.scene.camera;
        (0..width * height)
            .into_par_iter()
            .map(|pixel| {
                let (origin, dir) = camera_ray(camera, pixel % width, pixel / width, width, height);
                Ray {
                    origin,
                    t_min: 0.0,
                    dir,
                    t_max: f32::INFINITY,
                    throughput: Vec3::ONE,
                    kind: RayKind::Primary as u32,
                    pixel,
                    light: u32::MAX,
                    depth: 0,
                    source: pixel,
                }
            })
            .collect()
    }
}

impl PrimaryVisibility<Cpu> for RayCast {
    fn name(&self) -> &str {
        "raycast"
    }

    fn casts_rays(&self) -> bool {
        true
    }

    fn gbuffer(
        &self,
        backend: &Cpu,
        width: u32,
        height: u32,
        stats: &mut Stats,
    ) -> Result<Vec<Surface>> {
        let accel: &dyn Intersector<Cpu> = match &self.accel {
            Accel::Bvh(b) => b,
            Accel::Brute(b) => b,
            Accel::Pipeline => {
                return Err(CoreError::InvalidInput(
                    "raycast with accel = pipeline traces with the pipeline's intersector: \
                     render it through a pipeline"
                        .into(),
                ))
            }
        };
        self.cast(backend, width, height, accel, stats)
    }

    fn gbuffer_with(
        &self,
        backend: &Cpu,
        width: u32,
        height: u32,
        intersector: &dyn Intersector<Cpu>,
        stats: &mut Stats,
    ) -> Result<Vec<Surface>> {
        match self.accel {
            Accel::Pipeline => self.cast(backend, width, height, intersector, stats),
            _ => self.gbuffer(backend, width, height, stats),
        }
    }
}

impl RayCast {
    /// The G-buffer from the camera rays' closest hits with `accel`.
    fn cast(
        &self,
        backend: &Cpu,
        width: u32,
        height: u32,
        accel: &dyn Intersector<Cpu>,
        stats: &mut Stats,
    ) -> Result<Vec<Surface>> {
        check_view(&self.scene.camera, width, height)?;
        let rays = self.camera_rays(width, height);
        let mut hits = vec![Hit::MISS; rays.len()];
        accel.intersect(
            backend,
            &rays,
            Query::Scene,
            HitMode::Closest,
            &mut hits,
            stats,
        )?;
        let scene = &*self.scene;
        Ok(rays
            .par_iter()
            .zip(hits.par_iter())
            .map(|(r, h)| surface_from_hit(scene, r.origin, r.dir, h, r.pixel, Vec3::ONE, 0))
            .collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::surface::tests::raw_scene;
    use crsh_core::ParamValue;

    fn spec(accel: &str) -> StageSpec {
        let mut s = StageSpec::new("raycast");
        s.params
            .insert("accel".into(), ParamValue::Str(accel.into()));
        s
    }

    /// A quad filling the middle of the view, facing the camera at z = 0.
    fn quad_scene() -> Arc<Scene> {
        let p = vec![
            Vec3::new(-1.0, -1.0, 0.0),
            Vec3::new(1.0, -1.0, 0.0),
            Vec3::new(1.0, 1.0, 0.0),
            Vec3::new(-1.0, 1.0, 0.0),
        ];
        Arc::new(raw_scene(p, vec![Vec3::Z; 4], vec![[0, 1, 2], [0, 2, 3]]))
    }

    #[test]
    fn gbuffer_of_a_quad() {
        let scene = quad_scene();
        for accel in ["bvh", "brute"] {
            let rc = RayCast::new(&scene, &spec(accel)).unwrap();
            assert_eq!(rc.accel_name(), accel);
            let mut stats = Stats::default();
            let g = rc.gbuffer(&Cpu, 32, 24, &mut stats).unwrap();
            assert_eq!(g.len(), 32 * 24);
            assert!(stats.tests.ray_triangle > 0);
            // The centre sees the quad, the corners the background (camera at z = 5, 45°).
            let centre = &g[12 * 32 + 16];
            assert!(centre.is_hit());
            assert!(centre.front_face());
            assert_eq!(centre.normal, Vec3::Z);
            assert!(centre.position.z.abs() < 1e-6);
            assert_eq!(centre.depth, 0);
            assert_eq!(centre.throughput, Vec3::ONE);
            assert!(!g[0].is_hit());
            assert!(!g[32 * 24 - 1].is_hit());
            for (i, s) in g.iter().enumerate() {
                assert_eq!(s.pixel, i as u32);
                let (_, d) = camera_ray(&scene.camera, i as u32 % 32, i as u32 / 32, 32, 24);
                assert_eq!(s.incident, d.normalize());
            }
            // y = 0 is the top row: the top-left pixel's ray points up and left.
            assert!(g[0].incident.y > 0.0 && g[0].incident.x < 0.0);
        }
    }

    #[test]
    fn accel_pipeline_traces_with_the_pipelines_intersector() {
        let scene = quad_scene();
        let by_bvh = RayCast::new(&scene, &spec("bvh")).unwrap();
        let mut want_stats = Stats::default();
        let want = by_bvh.gbuffer(&Cpu, 32, 24, &mut want_stats).unwrap();
        let rc = RayCast::new(&scene, &spec("pipeline")).unwrap();
        assert_eq!(rc.accel_name(), "pipeline");
        // Without a pipeline there is nothing to trace with: an error, not a guess.
        let err = rc.gbuffer(&Cpu, 32, 24, &mut Stats::default()).unwrap_err();
        assert!(err.to_string().contains("accel = pipeline"), "{err}");
        // Handed brute force, it finds the same surfaces as the CWBVH, counting brute
        // force's tests (every ray against both triangles).
        let brute = BruteForce::from_scene(&scene);
        let mut stats = Stats::default();
        let got = rc.gbuffer_with(&Cpu, 32, 24, &brute, &mut stats).unwrap();
        assert_eq!(got, want);
        assert_eq!(stats.tests.ray_triangle, 32 * 24 * 2);
        // The other accelerators ignore the pipeline's intersector.
        let mut s2 = Stats::default();
        assert_eq!(
            by_bvh.gbuffer_with(&Cpu, 32, 24, &brute, &mut s2).unwrap(),
            want
        );
        assert_eq!(s2.tests, want_stats.tests);
    }

    #[test]
    fn bad_input_is_an_error() {
        let scene = quad_scene();
        assert!(matches!(
            RayCast::new(&scene, &spec("kd")),
            Err(CoreError::InvalidParam { .. })
        ));
        assert!(RayCast::new(&scene, &StageSpec::new("raycast")).is_err());
        let rc = RayCast::new(&scene, &spec("bvh")).unwrap();
        assert!(rc.gbuffer(&Cpu, 0, 10, &mut Stats::default()).is_err());
        assert!(rc
            .gbuffer(&Cpu, 10, MAX_IMAGE_SIDE + 1, &mut Stats::default())
            .is_err());
        let mut bad = (*scene).clone();
        bad.camera.target = bad.camera.eye;
        let rc = RayCast::new(&Arc::new(bad), &spec("brute")).unwrap();
        assert!(rc.gbuffer(&Cpu, 8, 8, &mut Stats::default()).is_err());
    }
}
