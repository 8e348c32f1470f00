//! The pipeline as data: which variant fills each stage slot, with what parameters.
//!
//! A [`PipelineConfig`] is plain serde data (TOML in plan files, JSON in stats), shared by the
//! CLI, tests and benchmarks. Each backend publishes a catalogue of [`StageVariantInfo`]s;
//! [`PipelineConfig::resolve`] checks a config against it and fills in defaults, and
//! [`PipelineConfig::set`] applies the CLI's `--set stage.param=value` overrides.

use std::collections::BTreeMap;
use std::fmt;

use serde::{Deserialize, Serialize};

use crate::error::{CoreError, Result};

/// The stage slots of a pipeline.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum StageKind {
    /// Primary visibility ([`crate::PrimaryVisibility`]).
    Primary,
    /// Secondary ray creation ([`crate::RayGen`]).
    Raygen,
    /// Ray indexing ([`crate::Hasher`]).
    Hash,
    /// Ray sorting ([`crate::Sorter`]).
    Sort,
    /// Ray-space hierarchy creation ([`crate::HierarchyBuilder`]).
    Hierarchy,
    /// Hierarchy traversal ([`crate::Traverser`]).
    Traverse,
    /// Ray-triangle tests ([`crate::Intersector`]).
    Intersect,
    /// Shading ([`crate::Shader`]).
    Shade,
}

impl StageKind {
    /// Every slot in pipeline order.
    pub const ALL: [StageKind; 8] = [
        StageKind::Primary,
        StageKind::Raygen,
        StageKind::Hash,
        StageKind::Sort,
        StageKind::Hierarchy,
        StageKind::Traverse,
        StageKind::Intersect,
        StageKind::Shade,
    ];

    /// The slot's key in configs and `--set` keys.
    pub fn key(self) -> &'static str {
        match self {
            StageKind::Primary => "primary",
            StageKind::Raygen => "raygen",
            StageKind::Hash => "hash",
            StageKind::Sort => "sort",
            StageKind::Hierarchy => "hierarchy",
            StageKind::Traverse => "traverse",
            StageKind::Intersect => "intersect",
            StageKind::Shade => "shade",
        }
    }

    /// The slot named `key`.
    pub fn from_key(key: &str) -> Option<StageKind> {
        StageKind::ALL.into_iter().find(|k| k.key() == key)
    }

    /// Whether a pipeline may leave this slot empty.
    pub fn optional(self) -> bool {
        matches!(
            self,
            StageKind::Hash | StageKind::Sort | StageKind::Hierarchy | StageKind::Traverse
        )
    }
}

impl fmt::Display for StageKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.key())
    }
}

/// A parameter value.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum ParamValue {
    /// `true` / `false`.
    Bool(bool),
    /// An integer.
    Int(i64),
    /// A real number.
    Float(f64),
    /// A name.
    Str(String),
}

impl ParamValue {
    /// Parses a `--set` value: `true`/`false`, an integer, a real number, else a string.
    pub fn parse(s: &str) -> ParamValue {
        let s = s.trim();
        if let Ok(b) = s.parse::<bool>() {
            ParamValue::Bool(b)
        } else if let Ok(i) = s.parse::<i64>() {
            ParamValue::Int(i)
        } else if let Ok(f) = s.parse::<f64>() {
            ParamValue::Float(f)
        } else {
            ParamValue::Str(s.to_string())
        }
    }

    fn type_name(&self) -> &'static str {
        match self {
            ParamValue::Bool(_) => "bool",
            ParamValue::Int(_) => "integer",
            ParamValue::Float(_) => "number",
            ParamValue::Str(_) => "string",
        }
    }

    /// This value converted to the type of `like` (integers widen to numbers), if possible.
    fn coerce_like(&self, like: &ParamValue) -> Option<ParamValue> {
        match (self, like) {
            (ParamValue::Bool(b), ParamValue::Bool(_)) => Some(ParamValue::Bool(*b)),
            (ParamValue::Int(i), ParamValue::Int(_)) => Some(ParamValue::Int(*i)),
            (ParamValue::Int(i), ParamValue::Float(_)) => Some(ParamValue::Float(*i as f64)),
            (ParamValue::Float(f), ParamValue::Float(_)) => Some(ParamValue::Float(*f)),
            (ParamValue::Str(s), ParamValue::Str(_)) => Some(ParamValue::Str(s.clone())),
            _ => None,
        }
    }
}

impl fmt::Display for ParamValue {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ParamValue::Bool(b) => write!(f, "{b}"),
            ParamValue::Int(i) => write!(f, "{i}"),
            ParamValue::Float(x) => write!(f, "{x}"),
            ParamValue::Str(s) => f.write_str(s),
        }
    }
}

/// One stage slot's choice: the variant name and its parameters.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StageSpec {
    /// Variant name (`brute`, `bvh`, `raster`, ...).
    pub kind: String,
    /// Parameters by name; after [`PipelineConfig::resolve`] every parameter the variant
    /// declares is present.
    #[serde(flatten)]
    pub params: BTreeMap<String, ParamValue>,
}

impl StageSpec {
    /// A spec with no parameters set.
    pub fn new(kind: &str) -> StageSpec {
        StageSpec {
            kind: kind.to_string(),
            params: BTreeMap::new(),
        }
    }

    fn missing(&self, key: &str) -> CoreError {
        CoreError::InvalidParam {
            key: format!("{}.{key}", self.kind),
            reason: "missing (was the config resolved?)".into(),
        }
    }

    /// A real-valued parameter.
    pub fn f64(&self, key: &str) -> Result<f64> {
        match self.params.get(key) {
            Some(ParamValue::Float(f)) => Ok(*f),
            Some(ParamValue::Int(i)) => Ok(*i as f64),
            Some(v) => Err(CoreError::InvalidParam {
                key: key.into(),
                reason: format!("expected a number, got {}", v.type_name()),
            }),
            None => Err(self.missing(key)),
        }
    }

    /// An integer parameter.
    pub fn i64(&self, key: &str) -> Result<i64> {
        match self.params.get(key) {
            Some(ParamValue::Int(i)) => Ok(*i),
            Some(v) => Err(CoreError::InvalidParam {
                key: key.into(),
                reason: format!("expected an integer, got {}", v.type_name()),
            }),
            None => Err(self.missing(key)),
        }
    }

    /// An integer parameter that must lie in `range`.
    pub fn u32_in(&self, key: &str, range: std::ops::RangeInclusive<u32>) -> Result<u32> {
        let v = self.i64(key)?;
        if v < *range.start() as i64 || v > *range.end() as i64 {
            return Err(CoreError::InvalidParam {
                key: key.into(),
                reason: format!("{v} is outside {}..={}", range.start(), range.end()),
            });
        }
        Ok(v as u32)
    }

    /// A boolean parameter.
    pub fn bool(&self, key: &str) -> Result<bool> {
        match self.params.get(key) {
            Some(ParamValue::Bool(b)) => Ok(*b),
            Some(v) => Err(CoreError::InvalidParam {
                key: key.into(),
                reason: format!("expected true/false, got {}", v.type_name()),
            }),
            None => Err(self.missing(key)),
        }
    }

    /// A string parameter.
    pub fn str(&self, key: &str) -> Result<&str> {
        match self.params.get(key) {
            Some(ParamValue::Str(s)) => Ok(s),
            Some(v) => Err(CoreError::InvalidParam {
                key: key.into(),
                reason: format!("expected a name, got {}", v.type_name()),
            }),
            None => Err(self.missing(key)),
        }
    }
}

/// A parameter a stage variant accepts.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ParamInfo {
    /// Name (the part after the dot in a `--set` key).
    pub name: &'static str,
    /// Default; also fixes the type.
    pub default: ParamValue,
    /// For string parameters, the accepted values (empty: any).
    pub choices: &'static [&'static str],
    /// One line of documentation.
    pub doc: &'static str,
}

/// A stage variant a backend offers.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct StageVariantInfo {
    /// Slot it fills.
    pub stage: StageKind,
    /// Variant name.
    pub name: &'static str,
    /// One line of documentation (cite the paper and equations).
    pub doc: &'static str,
    /// Parameters with defaults.
    pub params: Vec<ParamInfo>,
}

/// A whole pipeline: one [`StageSpec`] per slot; the optional slots (hash, sort, hierarchy,
/// traverse) may be absent, in which case rays go straight to the intersector.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PipelineConfig {
    /// Pipeline name as reported in stats (`brute`, `bvh`, or a user's own).
    pub name: String,
    /// Primary visibility.
    pub primary: StageSpec,
    /// Secondary ray creation.
    pub raygen: StageSpec,
    /// Ray hashing (optional).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub hash: Option<StageSpec>,
    /// Ray sorting (optional).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sort: Option<StageSpec>,
    /// Ray-space hierarchy (optional; needs `traverse`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub hierarchy: Option<StageSpec>,
    /// Hierarchy traversal (optional; needs `hierarchy`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub traverse: Option<StageSpec>,
    /// Ray-triangle tests.
    pub intersect: StageSpec,
    /// Shading.
    pub shade: StageSpec,
}

impl PipelineConfig {
    /// A Whitted pipeline (raster primaries, Phong) whose rays go to the intersector `intersect`.
    pub fn whitted(name: &str, intersect: &str) -> PipelineConfig {
        PipelineConfig {
            name: name.to_string(),
            primary: StageSpec::new("raster"),
            raygen: StageSpec::new("whitted"),
            hash: None,
            sort: None,
            hierarchy: None,
            traverse: None,
            intersect: StageSpec::new(intersect),
            shade: StageSpec::new("phong"),
        }
    }

    /// The spec in `slot`, if the slot is filled.
    pub fn slot(&self, slot: StageKind) -> Option<&StageSpec> {
        match slot {
            StageKind::Primary => Some(&self.primary),
            StageKind::Raygen => Some(&self.raygen),
            StageKind::Hash => self.hash.as_ref(),
            StageKind::Sort => self.sort.as_ref(),
            StageKind::Hierarchy => self.hierarchy.as_ref(),
            StageKind::Traverse => self.traverse.as_ref(),
            StageKind::Intersect => Some(&self.intersect),
            StageKind::Shade => Some(&self.shade),
        }
    }

    fn slot_mut(&mut self, slot: StageKind) -> SlotMut<'_> {
        match slot {
            StageKind::Primary => SlotMut::Required(&mut self.primary),
            StageKind::Raygen => SlotMut::Required(&mut self.raygen),
            StageKind::Hash => SlotMut::Optional(&mut self.hash),
            StageKind::Sort => SlotMut::Optional(&mut self.sort),
            StageKind::Hierarchy => SlotMut::Optional(&mut self.hierarchy),
            StageKind::Traverse => SlotMut::Optional(&mut self.traverse),
            StageKind::Intersect => SlotMut::Required(&mut self.intersect),
            StageKind::Shade => SlotMut::Required(&mut self.shade),
        }
    }

    /// Applies one `stage.param=value` override (the CLI's `--set`).
    ///
    /// `stage.kind=NAME` picks the variant (and drops parameters of the previous one);
    /// `stage=off` empties an optional slot; anything else sets a parameter. Call
    /// [`PipelineConfig::resolve`] afterwards to check the result.
    pub fn set(&mut self, assignment: &str) -> Result<()> {
        let (key, value) = assignment
            .split_once('=')
            .ok_or_else(|| CoreError::InvalidParam {
                key: assignment.into(),
                reason: "expected key=value".into(),
            })?;
        let key = key.trim();
        let value = value.trim();
        let (stage, param) = match key.split_once('.') {
            Some((s, p)) => (s, Some(p)),
            None => (key, None),
        };
        let slot = StageKind::from_key(stage).ok_or_else(|| CoreError::InvalidParam {
            key: key.into(),
            reason: format!(
                "unknown stage `{stage}` (stages: {})",
                StageKind::ALL.map(|k| k.key()).join(", ")
            ),
        })?;
        match (param, self.slot_mut(slot)) {
            (None, SlotMut::Optional(s)) if value == "off" || value == "none" => {
                *s = None;
                Ok(())
            }
            (None, _) => Err(CoreError::InvalidParam {
                key: key.into(),
                reason: format!("use `{stage}.kind=NAME` or `{stage}.PARAM=VALUE`"),
            }),
            (Some("kind"), SlotMut::Required(s)) => {
                *s = StageSpec::new(value);
                Ok(())
            }
            (Some("kind"), SlotMut::Optional(s)) => {
                *s = Some(StageSpec::new(value));
                Ok(())
            }
            (Some(p), SlotMut::Required(s)) => {
                s.params.insert(p.to_string(), ParamValue::parse(value));
                Ok(())
            }
            (Some(p), SlotMut::Optional(s)) => match s {
                Some(s) => {
                    s.params.insert(p.to_string(), ParamValue::parse(value));
                    Ok(())
                }
                None => Err(CoreError::InvalidParam {
                    key: key.into(),
                    reason: format!(
                        "stage `{stage}` is off in this pipeline; set `{stage}.kind` first"
                    ),
                }),
            },
        }
    }

    /// Checks every filled slot against `catalogue` (variant exists, parameters known and of
    /// the right type, string choices valid), fills in defaults, and checks that `hierarchy`
    /// and `traverse` are both present or both absent.
    pub fn resolve(&mut self, catalogue: &[StageVariantInfo]) -> Result<()> {
        for slot in StageKind::ALL {
            let spec = match self.slot_mut(slot) {
                SlotMut::Required(s) => s,
                SlotMut::Optional(Some(s)) => s,
                SlotMut::Optional(None) => continue,
            };
            let info = catalogue
                .iter()
                .find(|v| v.stage == slot && v.name == spec.kind)
                .ok_or_else(|| CoreError::UnknownVariant {
                    stage: slot.key().into(),
                    name: spec.kind.clone(),
                    known: catalogue
                        .iter()
                        .filter(|v| v.stage == slot)
                        .map(|v| v.name)
                        .collect::<Vec<_>>()
                        .join(", "),
                })?;
            for (k, v) in spec.params.iter_mut() {
                let p = info.params.iter().find(|p| p.name == k).ok_or_else(|| {
                    CoreError::InvalidParam {
                        key: format!("{slot}.{k}"),
                        reason: format!(
                            "`{}` has no such parameter (parameters: {})",
                            info.name,
                            if info.params.is_empty() {
                                "none".to_string()
                            } else {
                                info.params
                                    .iter()
                                    .map(|p| p.name)
                                    .collect::<Vec<_>>()
                                    .join(", ")
                            }
                        ),
                    }
                })?;
                *v = v
                    .coerce_like(&p.default)
                    .ok_or_else(|| CoreError::InvalidParam {
                        key: format!("{slot}.{k}"),
                        reason: format!(
                            "expected {}, got {} `{v}`",
                            p.default.type_name(),
                            v.type_name()
                        ),
                    })?;
                if let ParamValue::Str(s) = v {
                    if !p.choices.is_empty() && !p.choices.contains(&s.as_str()) {
                        return Err(CoreError::InvalidParam {
                            key: format!("{slot}.{k}"),
                            reason: format!("`{s}` is not one of {}", p.choices.join(", ")),
                        });
                    }
                }
            }
            for p in &info.params {
                spec.params
                    .entry(p.name.to_string())
                    .or_insert_with(|| p.default.clone());
            }
        }
        if self.hierarchy.is_some() != self.traverse.is_some() {
            return Err(CoreError::InvalidParam {
                key: "hierarchy/traverse".into(),
                reason: "a ray-space hierarchy needs a traverser and vice versa".into(),
            });
        }
        Ok(())
    }
}

enum SlotMut<'a> {
    Required(&'a mut StageSpec),
    Optional(&'a mut Option<StageSpec>),
}

#[cfg(test)]
mod tests {
    use super::*;

    fn catalogue() -> Vec<StageVariantInfo> {
        let mk = |stage, name, params| StageVariantInfo {
            stage,
            name,
            doc: "",
            params,
        };
        vec![
            mk(StageKind::Primary, "raster", vec![]),
            mk(
                StageKind::Raygen,
                "whitted",
                vec![ParamInfo {
                    name: "shadow_origin",
                    default: ParamValue::Str("light".into()),
                    choices: &["light", "surface"],
                    doc: "",
                }],
            ),
            mk(StageKind::Intersect, "brute", vec![]),
            mk(StageKind::Intersect, "bvh", vec![]),
            mk(
                StageKind::Shade,
                "phong",
                vec![ParamInfo {
                    name: "ambient",
                    default: ParamValue::Float(0.1),
                    choices: &[],
                    doc: "",
                }],
            ),
        ]
    }

    #[test]
    fn resolve_fills_defaults_and_coerces() {
        let mut c = PipelineConfig::whitted("bvh", "bvh");
        c.set("shade.ambient=0").unwrap();
        c.resolve(&catalogue()).unwrap();
        assert_eq!(c.shade.f64("ambient").unwrap(), 0.0);
        assert_eq!(c.raygen.str("shadow_origin").unwrap(), "light");
    }

    #[test]
    fn resolve_rejects_bad_input() {
        let mut c = PipelineConfig::whitted("x", "kdtree");
        assert!(matches!(
            c.resolve(&catalogue()),
            Err(CoreError::UnknownVariant { .. })
        ));
        let mut c = PipelineConfig::whitted("x", "brute");
        c.set("shade.ambiant=0").unwrap();
        assert!(c.resolve(&catalogue()).is_err());
        let mut c = PipelineConfig::whitted("x", "brute");
        c.set("raygen.shadow_origin=sideways").unwrap();
        assert!(c.resolve(&catalogue()).is_err());
        let mut c = PipelineConfig::whitted("x", "brute");
        c.set("shade.ambient=bright").unwrap();
        assert!(c.resolve(&catalogue()).is_err());
        assert!(c.set("nonsense").is_err());
        assert!(c.set("warp.speed=9").is_err());
        assert!(c.set("hash.bits=3").is_err());
    }

    #[test]
    fn config_roundtrips_through_json_and_toml_shapes() {
        let mut c = PipelineConfig::whitted("bvh", "bvh");
        c.resolve(&catalogue()).unwrap();
        let j = serde_json::to_string(&c).unwrap();
        let back: PipelineConfig = serde_json::from_str(&j).unwrap();
        assert_eq!(back, c);
    }
}
