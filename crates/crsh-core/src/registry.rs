//! The stage registry: every stage variant a backend can build (its catalogue entry and its
//! constructor) and the named pipelines (presets).
//!
//! A [`Registry`] is how a pipeline description becomes stage objects. The built-in variants
//! register themselves through the same `add_*` calls a third party uses
//! ([`Registry::builtin`]), and everything that resolves a name — the CLI's `--pipeline` and
//! `--set STAGE.kind=NAME`, `crsh pipelines`, `crsh ablate` plans, `crsh tables` — asks a
//! registry, so a program that adds a variant gets all of them for it.
//!
//! ```
//! use crsh_core::{
//!     Backend, Hasher, ParamInfo, Ray, RayKind, Registry, Result, StageKind, StageScene,
//!     StageVariantInfo, Stats,
//! };
//!
//! // A toy backend with host buffers, to show the calls without a real one.
//! struct Host;
//! struct NoScene;
//! impl StageScene for NoScene {
//!     fn triangle_count(&self) -> usize { 0 }
//! }
//! impl Backend for Host {
//!     type Buffer<T: bytemuck::Pod + Send + Sync> = Vec<T>;
//!     type Scene = NoScene;
//!     fn name(&self) -> &'static str { "host" }
//!     fn upload<T: bytemuck::Pod + Send + Sync>(&self, d: &[T]) -> Result<Vec<T>> { Ok(d.to_vec()) }
//!     fn download<T: bytemuck::Pod + Send + Sync>(&self, b: &Vec<T>) -> Result<Vec<T>> { Ok(b.clone()) }
//!     fn len<T: bytemuck::Pod + Send + Sync>(&self, b: &Vec<T>) -> usize { b.len() }
//!     fn concat<T: bytemuck::Pod + Send + Sync>(&self, p: Vec<Vec<T>>) -> Result<Vec<T>> { Ok(p.concat()) }
//! }
//!
//! /// Keys rays by the row of their pixel: needs the frame width, which the context gives.
//! struct Rows { width: u32 }
//! impl Hasher<Host> for Rows {
//!     fn name(&self) -> &str { "rows" }
//!     fn key_bits(&self) -> u32 { 32 }
//!     fn hash(&self, _: &Host, rays: &Vec<Ray>, _: RayKind, _: &mut Stats) -> Result<Vec<u64>> {
//!         Ok(rays.iter().map(|r| (r.pixel / self.width) as u64).collect())
//!     }
//! }
//!
//! let mut registry = Registry::<Host>::new();
//! registry
//!     .add_hasher(
//!         StageVariantInfo::new(StageKind::Hash, "rows", "pixel row of the ray"),
//!         |ctx, _spec| Ok(Box::new(Rows { width: ctx.frame.width })),
//!     )
//!     .unwrap();
//! assert!(registry.variant(StageKind::Hash, "rows").is_some());
//! // A second variant of the same name in the same slot is refused.
//! let again = registry.add_hasher(
//!     StageVariantInfo::new(StageKind::Hash, "rows", "again"),
//!     |ctx, _spec| Ok(Box::new(Rows { width: ctx.frame.width })),
//! );
//! assert!(again.is_err());
//! ```

use std::sync::Arc;
use std::time::Instant;

use crate::backend::{Backend, StageScene};
use crate::config::{
    check_name, resolve_spec, unknown_variant, PipelineConfig, StageKind, StageSpec,
    StageVariantInfo,
};
use crate::error::{CoreError, Result};
use crate::pipeline::{
    render_frame, Frame, FrameOptions, FrameSize, Pipeline, Progress, StageBuild, Stages,
};
use crate::stage::{
    Hasher, HierarchyBuilder, Intersector, PrimaryVisibility, RayGen, Shader, Sorter, Traverser,
};

/// What a stage constructor is given besides its parameters: the backend, the scene and the
/// frame the stage will run for.
pub struct StageContext<'a, B: Backend> {
    /// The backend the stage runs on.
    pub backend: &'a B,
    /// The scene (the backend's view of it, [`Backend::Scene`]).
    pub scene: &'a Arc<B::Scene>,
    /// The image the pipeline renders: [`crate::Ray::pixel`] is `y * frame.width + x`.
    pub frame: FrameSize,
}

impl<'a, B: Backend> StageContext<'a, B> {
    /// The context of stages for `scene` on `backend`, rendering `frame`.
    pub fn new(backend: &'a B, scene: &'a Arc<B::Scene>, frame: FrameSize) -> Self {
        StageContext {
            backend,
            scene,
            frame,
        }
    }
}

impl<B: Backend> Clone for StageContext<'_, B> {
    fn clone(&self) -> Self {
        *self
    }
}

impl<B: Backend> Copy for StageContext<'_, B> {}

/// A stage constructor: the context and the variant's resolved spec (every parameter present)
/// in, the stage object out.
type Ctor<B, S> = Arc<dyn Fn(&StageContext<'_, B>, &StageSpec) -> Result<Box<S>> + Send + Sync>;

/// A registered constructor, by slot.
enum Constructor<B: Backend> {
    Primary(Ctor<B, dyn PrimaryVisibility<B>>),
    Raygen(Ctor<B, dyn RayGen<B>>),
    Hash(Ctor<B, dyn Hasher<B>>),
    Sort(Ctor<B, dyn Sorter<B>>),
    Hierarchy(Ctor<B, dyn HierarchyBuilder<B>>),
    Traverse(Ctor<B, dyn Traverser<B>>),
    Intersect(Ctor<B, dyn Intersector<B>>),
    Shade(Ctor<B, dyn Shader<B>>),
}

impl<B: Backend> Clone for Constructor<B> {
    fn clone(&self) -> Self {
        match self {
            Constructor::Primary(f) => Constructor::Primary(Arc::clone(f)),
            Constructor::Raygen(f) => Constructor::Raygen(Arc::clone(f)),
            Constructor::Hash(f) => Constructor::Hash(Arc::clone(f)),
            Constructor::Sort(f) => Constructor::Sort(Arc::clone(f)),
            Constructor::Hierarchy(f) => Constructor::Hierarchy(Arc::clone(f)),
            Constructor::Traverse(f) => Constructor::Traverse(Arc::clone(f)),
            Constructor::Intersect(f) => Constructor::Intersect(Arc::clone(f)),
            Constructor::Shade(f) => Constructor::Shade(Arc::clone(f)),
        }
    }
}

/// A named pipeline of a registry (`--pipeline NAME`).
#[derive(Clone, Debug, PartialEq)]
pub struct Preset {
    /// Its name.
    pub name: String,
    /// One line of documentation.
    pub doc: String,
    /// The pipeline, resolved against the registry (every parameter present).
    pub config: PipelineConfig,
}

/// The stage variants and presets of one backend.
///
/// Built-in variants come from [`Registry::builtin`]; more are added with the `add_*` method of
/// their slot, each taking the variant's catalogue entry ([`StageVariantInfo`]: name,
/// documentation, parameters with defaults, choices and ranges) and a constructor. Names are
/// unique per slot. [`Registry::build`] resolves a [`PipelineConfig`] against the catalogue and
/// builds its stages; a pipeline whose slots do not fit together is refused there, before any
/// stage is constructed.
pub struct Registry<B: Backend> {
    infos: Vec<StageVariantInfo>,
    ctors: Vec<Constructor<B>>,
    presets: Vec<Preset>,
}

impl<B: Backend> Clone for Registry<B> {
    fn clone(&self) -> Self {
        Registry {
            infos: self.infos.clone(),
            ctors: self.ctors.clone(),
            presets: self.presets.clone(),
        }
    }
}

impl<B: Backend> Default for Registry<B> {
    fn default() -> Self {
        Registry::new()
    }
}

impl<B: Backend> std::fmt::Debug for Registry<B> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Registry")
            .field(
                "variants",
                &self
                    .infos
                    .iter()
                    .map(|v| format!("{}.{}", v.stage, v.name))
                    .collect::<Vec<_>>(),
            )
            .field(
                "presets",
                &self.presets.iter().map(|p| &p.name).collect::<Vec<_>>(),
            )
            .finish()
    }
}

/// A backend whose crate ships stage variants: [`Registry::builtin`] calls
/// [`BuiltinVariants::register_builtin`], which registers them through the public `add_*`
/// calls, then the backend's presets.
pub trait BuiltinVariants: Backend + Sized {
    /// Adds every built-in variant and preset of this backend to `registry`.
    fn register_builtin(registry: &mut Registry<Self>) -> Result<()>;
}

impl<B: BuiltinVariants> Registry<B> {
    /// The backend's built-in variants and presets.
    ///
    /// # Panics
    /// If a built-in registration is malformed: a bug of the backend crate, which its tests
    /// catch.
    pub fn builtin() -> Registry<B> {
        let mut r = Registry::new();
        if let Err(e) = B::register_builtin(&mut r) {
            panic!("built-in stage registration failed (a bug): {e}");
        }
        r
    }
}

macro_rules! adder {
    ($(#[$doc:meta])* $fn:ident, $slot:ident, $trait:ident) => {
        $(#[$doc])*
        ///
        /// # Errors
        /// [`CoreError::InvalidInput`] when `info` is for another slot or malformed
        /// ([`StageVariantInfo::validate`]), or when the slot already has a variant of that
        /// name.
        pub fn $fn<F>(&mut self, info: StageVariantInfo, build: F) -> Result<&mut Self>
        where
            F: Fn(&StageContext<'_, B>, &StageSpec) -> Result<Box<dyn $trait<B>>>
                + Send
                + Sync
                + 'static,
        {
            self.add(info, StageKind::$slot, Constructor::$slot(Arc::new(build)))
        }
    };
}

macro_rules! construct {
    ($self:ident, $ctx:ident, $slot:ident, $spec:expr) => {{
        let spec: &StageSpec = $spec;
        match $self.constructor(StageKind::$slot, &spec.kind)? {
            Constructor::$slot(f) => f($ctx, spec)?,
            _ => unreachable!("constructors are stored under their own slot"),
        }
    }};
}

impl<B: Backend> Registry<B> {
    /// An empty registry (no variants, no presets).
    pub fn new() -> Registry<B> {
        Registry {
            infos: Vec::new(),
            ctors: Vec::new(),
            presets: Vec::new(),
        }
    }

    fn add(
        &mut self,
        info: StageVariantInfo,
        slot: StageKind,
        ctor: Constructor<B>,
    ) -> Result<&mut Self> {
        if info.stage != slot {
            return Err(CoreError::InvalidInput(format!(
                "variant `{}` is described as a `{}` variant but registered in slot `{slot}`",
                info.name, info.stage
            )));
        }
        if info.scene_only && slot != StageKind::Intersect {
            return Err(CoreError::InvalidInput(format!(
                "variant {slot} `{}`: only intersectors can be scene-only",
                info.name
            )));
        }
        // Every generator can be traced in either order (`crate::order`).
        let info = if slot == StageKind::Raygen {
            crate::order::order_params(info)
        } else {
            info
        };
        info.validate()?;
        if self.variant(slot, info.name).is_some() {
            return Err(CoreError::InvalidInput(format!(
                "a {slot} variant named `{}` is already registered",
                info.name
            )));
        }
        self.infos.push(info);
        self.ctors.push(ctor);
        Ok(self)
    }

    adder!(
        /// Registers a primary-visibility variant.
        add_primary, Primary, PrimaryVisibility
    );
    adder!(
        /// Registers a ray-generation variant.
        add_raygen, Raygen, RayGen
    );
    adder!(
        /// Registers a hasher variant.
        add_hasher, Hash, Hasher
    );
    adder!(
        /// Registers a sorter variant.
        add_sorter, Sort, Sorter
    );
    adder!(
        /// Registers a hierarchy-builder variant.
        add_hierarchy, Hierarchy, HierarchyBuilder
    );
    adder!(
        /// Registers a traverser variant.
        add_traverser, Traverse, Traverser
    );
    adder!(
        /// Registers an intersector variant (mark it [`StageVariantInfo::scene_only`] when it
        /// cannot answer the candidate queries of a ray-space hierarchy).
        add_intersector, Intersect, Intersector
    );
    adder!(
        /// Registers a shader variant.
        add_shader, Shade, Shader
    );

    /// Registers the named pipeline `name` (`--pipeline NAME`): `config` with its name set to
    /// `name`, resolved against the variants registered so far.
    ///
    /// # Errors
    /// A malformed or taken name ([`CoreError::InvalidInput`]), or whatever
    /// [`Registry::resolve`] finds wrong with `config`.
    pub fn add_preset(
        &mut self,
        name: &str,
        doc: &str,
        config: PipelineConfig,
    ) -> Result<&mut Self> {
        check_name(name).map_err(|r| CoreError::InvalidInput(format!("preset name: {r}")))?;
        if self.presets.iter().any(|p| p.name == name) {
            return Err(CoreError::InvalidInput(format!(
                "a preset named `{name}` is already registered"
            )));
        }
        let mut config = PipelineConfig {
            name: name.to_string(),
            ..config
        };
        self.resolve(&mut config)?;
        self.presets.push(Preset {
            name: name.to_string(),
            doc: doc.to_string(),
            config,
        });
        Ok(self)
    }

    /// Every registered variant's catalogue entry, in registration order.
    pub fn variants(&self) -> &[StageVariantInfo] {
        &self.infos
    }

    /// The catalogue entry of variant `name` in `slot`.
    pub fn variant(&self, slot: StageKind, name: &str) -> Option<&StageVariantInfo> {
        self.infos
            .iter()
            .find(|v| v.stage == slot && v.name == name)
    }

    /// The presets, in registration order.
    pub fn presets(&self) -> &[Preset] {
        &self.presets
    }

    /// The presets this build can construct: those whose every stage variant is available
    /// ([`StageVariantInfo::unavailable`] unset), in registration order. Suites that run
    /// "every preset" use these and report the others as skipped ([`Self::unavailable`]).
    pub fn available_presets(&self) -> impl Iterator<Item = &Preset> {
        self.presets
            .iter()
            .filter(|p| self.unavailable(&p.config).is_none())
    }

    /// Why `cfg` cannot be built in this build (the first of its variants that is
    /// [`StageVariantInfo::unavailable`], named), or `None`.
    pub fn unavailable(&self, cfg: &PipelineConfig) -> Option<String> {
        StageKind::ALL.iter().find_map(|&slot| {
            let spec = cfg.slot(slot)?;
            let reason = self.variant(slot, &spec.kind)?.unavailable?;
            Some(format!("{} `{}`: {reason}", slot.key(), spec.kind))
        })
    }

    /// The preset `name` (resolved), if registered.
    pub fn preset(&self, name: &str) -> Option<PipelineConfig> {
        self.presets
            .iter()
            .find(|p| p.name == name)
            .map(|p| p.config.clone())
    }

    /// Resolves `cfg` against this registry's catalogue ([`PipelineConfig::resolve`]):
    /// unknown variants or parameters and values out of their choices or range are errors,
    /// defaults are filled in, and slots that do not fit together are refused.
    pub fn resolve(&self, cfg: &mut PipelineConfig) -> Result<()> {
        cfg.resolve(&self.infos)
    }

    fn constructor(&self, slot: StageKind, name: &str) -> Result<&Constructor<B>> {
        self.infos
            .iter()
            .position(|v| v.stage == slot && v.name == name)
            .map(|i| &self.ctors[i])
            .ok_or_else(|| unknown_variant(slot, name, &self.infos))
    }

    /// Builds the stages of `cfg` for `ctx`: resolves a copy of `cfg` ([`Registry::resolve`];
    /// nothing is constructed when it fails), constructs every filled slot, and checks the
    /// stage objects fit together ([`Stages::check`]).
    pub fn build(&self, ctx: &StageContext<'_, B>, cfg: &PipelineConfig) -> Result<Pipeline<B>> {
        self.build_from(ctx, cfg, None)
    }

    /// The pipeline `previous` (built by this registry) for a scene whose geometry changed
    /// (`ctx.scene`: same triangles, moved): every stage is constructed again for the new
    /// scene, except a traverser or an intersector that can refit its structure
    /// ([`Traverser::refit`], [`Intersector::refit`]), which does. [`Pipeline::builds`] says
    /// what each stage did and how long it took: the per-frame rebuild cost of a dynamic scene.
    pub fn rebuild(
        &self,
        ctx: &StageContext<'_, B>,
        previous: &Pipeline<B>,
    ) -> Result<Pipeline<B>> {
        self.build_from(ctx, &previous.config, Some(previous))
    }

    fn build_from(
        &self,
        ctx: &StageContext<'_, B>,
        cfg: &PipelineConfig,
        previous: Option<&Pipeline<B>>,
    ) -> Result<Pipeline<B>> {
        let mut cfg = cfg.clone();
        self.resolve(&mut cfg)?;
        let mut builds = Vec::new();
        let mut done =
            |slot: StageKind, spec: &StageSpec, refit: bool, t0: Instant| -> Result<()> {
                ctx.backend.sync()?;
                builds.push(StageBuild {
                    slot: slot.key().to_string(),
                    variant: spec.kind.clone(),
                    ms: t0.elapsed().as_secs_f64() * 1e3,
                    refit,
                    bytes: 0,
                });
                Ok(())
            };
        macro_rules! slot {
            ($slot:ident, $spec:expr) => {{
                let spec: &StageSpec = $spec;
                let t0 = Instant::now();
                let stage = construct!(self, ctx, $slot, spec);
                done(StageKind::$slot, spec, false, t0)?;
                stage
            }};
        }
        macro_rules! optional {
            ($slot:ident, $spec:expr) => {
                match $spec {
                    Some(spec) => Some(slot!($slot, spec)),
                    None => None,
                }
            };
        }
        let primary = slot!(Primary, &cfg.primary);
        let raygen = slot!(Raygen, &cfg.raygen);
        let hasher = optional!(Hash, &cfg.hash);
        let sorter = optional!(Sort, &cfg.sort);
        let hierarchy = optional!(Hierarchy, &cfg.hierarchy);
        let t0 = Instant::now();
        let refitted = match (previous, &cfg.traverse) {
            (Some(p), Some(spec)) if p.config.traverse.as_ref() == Some(spec) => {
                p.stages.traverser.as_ref().and_then(|t| t.refit(ctx))
            }
            _ => None,
        };
        let traverser = match (refitted, &cfg.traverse) {
            (Some(result), Some(spec)) => {
                let stage = result?;
                done(StageKind::Traverse, spec, true, t0)?;
                Some(stage)
            }
            _ => optional!(Traverse, &cfg.traverse),
        };
        let t0 = Instant::now();
        let refitted = match previous {
            Some(p) if p.config.intersect == cfg.intersect => p.stages.intersector.refit(ctx),
            _ => None,
        };
        let intersector = match refitted {
            Some(result) => {
                let stage = result?;
                done(StageKind::Intersect, &cfg.intersect, true, t0)?;
                stage
            }
            None => slot!(Intersect, &cfg.intersect),
        };
        let shader = slot!(Shade, &cfg.shade);
        if let Some(b) = builds
            .iter_mut()
            .find(|b| b.slot == StageKind::Raygen.key())
        {
            b.bytes = raygen.table_bytes();
        }
        let stages = Stages {
            primary,
            raygen,
            hasher,
            sorter,
            hierarchy,
            traverser,
            intersector,
            shader,
            order: crate::order::RayOrder::from_spec(&cfg.raygen)?,
        };
        stages.check()?;
        Ok(Pipeline {
            config: cfg,
            stages,
            frame: ctx.frame,
            triangles: ctx.scene.triangle_count() as u64,
            builds,
        })
    }

    /// Builds the intersector `spec` alone (resolved first), e.g. the reference of
    /// `--reference NAME`.
    pub fn build_intersector(
        &self,
        ctx: &StageContext<'_, B>,
        spec: &StageSpec,
    ) -> Result<Box<dyn Intersector<B>>> {
        let mut spec = spec.clone();
        resolve_spec(StageKind::Intersect, &mut spec, &self.infos)?;
        Ok(construct!(self, ctx, Intersect, &spec))
    }

    /// Builds `cfg` for `ctx` and renders one frame ([`Pipeline::render`]); with `reference`,
    /// that intersector (built by this registry) traces every batch again and
    /// [`crate::Stats::accuracy`] is filled.
    pub fn render(
        &self,
        ctx: &StageContext<'_, B>,
        cfg: &PipelineConfig,
        opts: &FrameOptions,
        reference: Option<&StageSpec>,
        progress: &mut dyn FnMut(Progress),
    ) -> Result<Frame<B>> {
        let pipeline = self.build(ctx, cfg)?;
        let reference = reference
            .map(|r| self.build_intersector(ctx, r))
            .transpose()?;
        render_frame(ctx.backend, &pipeline, opts, reference.as_deref(), progress)
    }
}
