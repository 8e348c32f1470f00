//! The stage registries of both backends, and resolution of a pipeline for one of them.

use std::fmt;
use std::str::FromStr;

use crsh_core::config::resolve_spec;
use crsh_core::{CoreError, PipelineConfig, Registry, StageKind, StageVariantInfo};
use crsh_cpu::Cpu;
use crsh_wgpu::Wgpu;
use serde::{Deserialize, Serialize};

/// Where a pipeline runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum BackendKind {
    /// The CPU backend (rayon), [`Cpu`].
    Cpu,
    /// The wgpu backend, [`Wgpu`].
    Wgpu,
}

impl BackendKind {
    /// Both backends.
    pub const ALL: [BackendKind; 2] = [BackendKind::Cpu, BackendKind::Wgpu];

    /// The name in stats and on the command line (`cpu`, `wgpu`).
    pub fn name(self) -> &'static str {
        match self {
            BackendKind::Cpu => "cpu",
            BackendKind::Wgpu => "wgpu",
        }
    }

    fn other(self) -> BackendKind {
        match self {
            BackendKind::Cpu => BackendKind::Wgpu,
            BackendKind::Wgpu => BackendKind::Cpu,
        }
    }
}

impl fmt::Display for BackendKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for BackendKind {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        BackendKind::ALL
            .into_iter()
            .find(|b| b.name() == s)
            .ok_or_else(|| format!("unknown backend `{s}` (backends: cpu, wgpu)"))
    }
}

/// The stage registries of the CPU and wgpu backends.
///
/// A program that adds variants adds them here (`registries.cpu.add_hasher(...)`,
/// `registries.wgpu...`) and hands the registries to the [`crate::Renderer`] or to the command
/// line (`crsh_cli::main_with`); every name lookup goes through them.
#[derive(Clone, Debug)]
pub struct Registries {
    /// The CPU backend's variants and presets.
    pub cpu: Registry<Cpu>,
    /// The wgpu backend's variants and presets.
    pub wgpu: Registry<Wgpu>,
}

impl Default for Registries {
    fn default() -> Self {
        Registries::builtin()
    }
}

impl Registries {
    /// The built-in variants and presets of both backends.
    pub fn builtin() -> Registries {
        Registries {
            cpu: Registry::builtin(),
            wgpu: Registry::builtin(),
        }
    }

    fn infos(&self, backend: BackendKind) -> &[StageVariantInfo] {
        match backend {
            BackendKind::Cpu => self.cpu.variants(),
            BackendKind::Wgpu => self.wgpu.variants(),
        }
    }

    /// The preset `name`, from the CPU registry or else the wgpu one (resolved against the
    /// registry that has it).
    pub fn preset(&self, name: &str) -> Option<PipelineConfig> {
        self.cpu.preset(name).or_else(|| self.wgpu.preset(name))
    }

    /// The names of every preset, the CPU registry's first, each once.
    pub fn preset_names(&self) -> Vec<String> {
        let mut names: Vec<String> = Vec::new();
        let all = self.cpu.presets().iter().chain(self.wgpu.presets());
        for p in all {
            if !names.contains(&p.name) {
                names.push(p.name.clone());
            }
        }
        names
    }

    /// The backends whose registry has variant `name` in `slot`.
    pub fn backends_of(&self, slot: StageKind, name: &str) -> Vec<BackendKind> {
        BackendKind::ALL
            .into_iter()
            .filter(|b| {
                self.infos(*b)
                    .iter()
                    .any(|v| v.stage == slot && v.name == name)
            })
            .collect()
    }

    /// `cfg` resolved against `backend`'s registry (defaults filled in, slots checked).
    ///
    /// When `backend` lacks a variant or a parameter value that the other backend's registry
    /// accepts, the error is [`CoreError::Unsupported`] naming the slot, the variant, what
    /// `backend` offers instead and the backend that runs it — so a command line can say "no
    /// wgpu twin" before any device work. Other failures are [`crsh_core::Registry::resolve`]'s.
    pub fn resolve(
        &self,
        cfg: &PipelineConfig,
        backend: BackendKind,
    ) -> Result<PipelineConfig, CoreError> {
        let mut out = cfg.clone();
        let err = match out.resolve(self.infos(backend)) {
            Ok(()) => return Ok(out),
            Err(e) => e,
        };
        let (here, other) = (self.infos(backend), self.infos(backend.other()));
        for slot in StageKind::ALL {
            let Some(spec) = cfg.slot(slot) else {
                continue;
            };
            let (mut a, mut b) = (spec.clone(), spec.clone());
            let (on_here, on_other) = (
                resolve_spec(slot, &mut a, here),
                resolve_spec(slot, &mut b, other),
            );
            if let (Err(e), Ok(())) = (on_here, on_other) {
                let offered: Vec<&str> = here
                    .iter()
                    .filter(|v| v.stage == slot)
                    .map(|v| v.name)
                    .collect();
                let what = if matches!(e, CoreError::UnknownVariant { .. }) {
                    format!(
                        "the {backend} backend (its {slot} variants: {}); run it with --backend {}",
                        if offered.is_empty() {
                            "none".to_string()
                        } else {
                            offered.join(", ")
                        },
                        backend.other()
                    )
                } else {
                    format!(
                        "these parameters on the {backend} backend ({e}); run it with --backend {}",
                        backend.other()
                    )
                };
                return Err(CoreError::Unsupported {
                    stage: slot.key(),
                    variant: spec.kind.clone(),
                    what,
                });
            }
        }
        Err(err)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg(preset: &str, sets: &[&str]) -> PipelineConfig {
        let mut c = Registries::builtin().preset(preset).unwrap();
        for s in sets {
            c.set(s).unwrap();
        }
        c
    }

    #[test]
    fn a_variant_the_gpu_lacks_is_unsupported_naming_the_backend_that_has_it() {
        let r = Registries::builtin();
        for preset in r.preset_names() {
            let c = cfg(&preset, &[]);
            if r.wgpu.preset(&preset).is_some() {
                r.resolve(&c, BackendKind::Wgpu).unwrap();
            } else {
                // A CPU-only preset (`grid` until its wgpu twin lands) names the CPU.
                let e = r.resolve(&c, BackendKind::Wgpu).unwrap_err();
                assert!(e.to_string().contains("--backend cpu"), "{preset}: {e}");
            }
        }
        assert_eq!(cfg("grid", &[]).intersect.kind, "grid");
        let e = r
            .resolve(&cfg("bvh", &["primary.kind=raycast"]), BackendKind::Wgpu)
            .unwrap_err();
        assert!(
            matches!(&e, CoreError::Unsupported { stage: "primary", variant, .. } if variant == "raycast"),
            "{e}"
        );
        assert!(e.to_string().contains("--backend cpu"), "{e}");
        assert!(
            e.to_string().contains("raster"),
            "names the GPU's variants: {e}"
        );
        let e = r
            .resolve(
                &cfg("bvh", &["intersect.test=watertight"]),
                BackendKind::Wgpu,
            )
            .unwrap_err();
        assert!(
            matches!(
                &e,
                CoreError::Unsupported {
                    stage: "intersect",
                    ..
                }
            ),
            "{e}"
        );
        assert!(e.to_string().contains("watertight"), "{e}");
        // Unknown everywhere stays unknown; slot mismatches stay what they are.
        let e = r
            .resolve(&cfg("bvh", &["intersect.kind=octree"]), BackendKind::Wgpu)
            .unwrap_err();
        assert!(matches!(e, CoreError::UnknownVariant { .. }), "{e}");
        let e = r
            .resolve(&cfg("crsh", &["sort=off"]), BackendKind::Cpu)
            .unwrap_err();
        assert!(matches!(e, CoreError::Incompatible { .. }), "{e}");
        assert_eq!(
            r.backends_of(StageKind::Intersect, "brute64"),
            vec![BackendKind::Cpu]
        );
        assert_eq!(
            r.backends_of(StageKind::Hash, "thesis"),
            vec![BackendKind::Cpu, BackendKind::Wgpu]
        );
    }
}
