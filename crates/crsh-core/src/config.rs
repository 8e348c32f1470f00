//! The pipeline as data: which variant fills each stage slot, with what parameters.
//!
//! A [`PipelineConfig`] is plain serde data (TOML in plan files, JSON in stats), shared by the
//! CLI, tests and benchmarks. Each backend's [`crate::Registry`] holds the catalogue entries
//! ([`StageVariantInfo`]) of its variants; [`PipelineConfig::resolve`] checks a config against
//! them (variants, parameter types, choices and ranges, slots that fit together) and fills in
//! defaults, and [`PipelineConfig::set`] applies the CLI's `--set stage.param=value` overrides.

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
///
/// Build one with [`ParamInfo::int`], [`ParamInfo::float`], [`ParamInfo::bool`] or
/// [`ParamInfo::choice`]; [`PipelineConfig::resolve`] checks values against the type of the
/// default, the choices and the range.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ParamInfo {
    /// Name (the part after the dot in a `--set` key).
    pub name: &'static str,
    /// Default; also fixes the type.
    pub default: ParamValue,
    /// For string parameters, the accepted values (empty: any).
    pub choices: &'static [&'static str],
    /// For numeric parameters, the smallest accepted value (inclusive); NaN is never accepted
    /// where a bound is set.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub min: Option<f64>,
    /// For numeric parameters, the largest accepted value (inclusive).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max: Option<f64>,
    /// One line of documentation.
    pub doc: &'static str,
}

impl ParamInfo {
    /// An integer parameter accepted in `min ..= max`.
    pub fn int(name: &'static str, default: i64, min: i64, max: i64, doc: &'static str) -> Self {
        ParamInfo {
            name,
            default: ParamValue::Int(default),
            choices: &[],
            min: Some(min as f64),
            max: Some(max as f64),
            doc,
        }
    }

    /// A real-valued parameter (any finite value unless [`ParamInfo::range`] narrows it; NaN
    /// and infinities are rejected when a bound is set).
    pub fn float(name: &'static str, default: f64, doc: &'static str) -> Self {
        ParamInfo {
            name,
            default: ParamValue::Float(default),
            choices: &[],
            min: None,
            max: None,
            doc,
        }
    }

    /// A boolean parameter.
    pub fn bool(name: &'static str, default: bool, doc: &'static str) -> Self {
        ParamInfo {
            name,
            default: ParamValue::Bool(default),
            choices: &[],
            min: None,
            max: None,
            doc,
        }
    }

    /// A name chosen from `choices` (`default` must be one of them).
    pub fn choice(
        name: &'static str,
        default: &'static str,
        choices: &'static [&'static str],
        doc: &'static str,
    ) -> Self {
        ParamInfo {
            name,
            default: ParamValue::Str(default.to_string()),
            choices,
            min: None,
            max: None,
            doc,
        }
    }

    /// The same parameter accepted only in `min ..= max` (either bound may be infinite).
    pub fn range(self, min: f64, max: f64) -> Self {
        ParamInfo {
            min: Some(min),
            max: Some(max),
            ..self
        }
    }

    /// Checks `v` (already of the default's type) against the choices and the range.
    fn check(&self, slot: StageKind, v: &ParamValue) -> Result<()> {
        let bad = |reason: String| CoreError::InvalidParam {
            key: format!("{slot}.{}", self.name),
            reason,
        };
        match v {
            ParamValue::Str(s)
                if !self.choices.is_empty() && !self.choices.contains(&s.as_str()) =>
            {
                Err(bad(format!(
                    "`{s}` is not one of {}",
                    self.choices.join(", ")
                )))
            }
            ParamValue::Int(_) | ParamValue::Float(_) => {
                let x = match v {
                    ParamValue::Int(i) => *i as f64,
                    ParamValue::Float(f) => *f,
                    _ => unreachable!("matched numbers"),
                };
                let bounded = self.min.is_some() || self.max.is_some();
                if bounded && x.is_nan() {
                    return Err(bad("NaN is not a value".into()));
                }
                let lo = self.min.unwrap_or(f64::NEG_INFINITY);
                let hi = self.max.unwrap_or(f64::INFINITY);
                if bounded && !(lo..=hi).contains(&x) {
                    return Err(bad(format!("{v} is outside {}", self.range_text())));
                }
                Ok(())
            }
            _ => Ok(()),
        }
    }

    /// The accepted range as text (`0..=21`, `>= 0`, `any`), for errors and listings.
    pub fn range_text(&self) -> String {
        let fmt = |x: f64| {
            if matches!(self.default, ParamValue::Int(_)) && x.fract() == 0.0 && x.abs() < 1e18 {
                format!("{}", x as i64)
            } else {
                format!("{x}")
            }
        };
        match (self.min, self.max) {
            (Some(lo), Some(hi)) if lo.is_finite() && hi.is_finite() => {
                format!("{}..={}", fmt(lo), fmt(hi))
            }
            (Some(lo), _) if lo.is_finite() => format!(">= {}", fmt(lo)),
            (_, Some(hi)) if hi.is_finite() => format!("<= {}", fmt(hi)),
            (Some(_), _) | (_, Some(_)) => "finite".to_string(),
            (None, None) => "any".to_string(),
        }
    }
}

/// A stage variant a backend offers: its catalogue entry.
///
/// ```
/// use crsh_core::{ParamInfo, StageKind, StageVariantInfo};
/// let info = StageVariantInfo::new(StageKind::Hash, "screen_tile", "screen tile, then direction")
///     .param(ParamInfo::int("tile", 8, 1, 256, "tile side in pixels"));
/// assert_eq!(info.params[0].range_text(), "1..=256");
/// ```
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
    /// Intersectors only: answers whole-scene queries but not the candidate queries of a
    /// ray-space hierarchy ([`crate::Intersector::supports_candidates`] is `false`), so a
    /// pipeline with a `hierarchy` cannot use it. Checked by [`PipelineConfig::resolve`],
    /// before any stage is built.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub scene_only: bool,
    /// Listed but left out of this build (e.g. a cargo feature that links a system library
    /// was off): why, and how to get it. Constructing it fails; presets that use it are
    /// skipped by [`crate::Registry::available_presets`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub unavailable: Option<&'static str>,
}

impl StageVariantInfo {
    /// An entry with no parameters.
    pub fn new(stage: StageKind, name: &'static str, doc: &'static str) -> Self {
        StageVariantInfo {
            stage,
            name,
            doc,
            params: Vec::new(),
            scene_only: false,
            unavailable: None,
        }
    }

    /// The same entry, marked as left out of this build with `reason` unless `built`.
    pub fn built_if(self, built: bool, reason: &'static str) -> Self {
        StageVariantInfo {
            unavailable: (!built).then_some(reason),
            ..self
        }
    }

    /// The same entry with one more parameter.
    pub fn param(mut self, p: ParamInfo) -> Self {
        self.params.push(p);
        self
    }

    /// The same entry marked as answering whole-scene queries only (intersectors).
    pub fn scene_only(self) -> Self {
        StageVariantInfo {
            scene_only: true,
            ..self
        }
    }

    /// The spec of this variant with every parameter at its default.
    pub fn defaults(&self) -> StageSpec {
        let mut s = StageSpec::new(self.name);
        for p in &self.params {
            s.params.insert(p.name.to_string(), p.default.clone());
        }
        s
    }

    /// Checks that the entry is well formed: a usable name (not empty, only `a-z`, `0-9`,
    /// `_` and `-`, not `off` or `none`), a documentation line, distinct parameter names,
    /// string defaults among their choices, numeric defaults inside their range, and choices
    /// or ranges only on parameters of a fitting type. [`crate::Registry`] calls it for every
    /// variant it registers.
    pub fn validate(&self) -> Result<()> {
        let bad = |reason: String| {
            CoreError::InvalidInput(format!(
                "catalogue entry {} `{}`: {reason}",
                self.stage, self.name
            ))
        };
        check_name(self.name).map_err(|r| bad(format!("name: {r}")))?;
        if self.doc.trim().is_empty() {
            return Err(bad("no documentation line".into()));
        }
        for (i, p) in self.params.iter().enumerate() {
            check_name(p.name).map_err(|r| bad(format!("parameter `{}`: {r}", p.name)))?;
            if p.name == "kind" {
                return Err(bad(
                    "`kind` is the variant's own key, not a parameter name".into()
                ));
            }
            if self.params[..i].iter().any(|q| q.name == p.name) {
                return Err(bad(format!("parameter `{}` listed twice", p.name)));
            }
            if p.doc.trim().is_empty() {
                return Err(bad(format!("parameter `{}` has no documentation", p.name)));
            }
            let numeric = matches!(p.default, ParamValue::Int(_) | ParamValue::Float(_));
            if !p.choices.is_empty() && !matches!(p.default, ParamValue::Str(_)) {
                return Err(bad(format!(
                    "parameter `{}` has choices but is not a name",
                    p.name
                )));
            }
            if (p.min.is_some() || p.max.is_some()) && !numeric {
                return Err(bad(format!(
                    "parameter `{}` has a range but is not a number",
                    p.name
                )));
            }
            if let (Some(lo), Some(hi)) = (p.min, p.max) {
                if lo.is_nan() || hi.is_nan() || lo > hi {
                    return Err(bad(format!("parameter `{}` has an empty range", p.name)));
                }
            }
            p.check(self.stage, &p.default)
                .map_err(|e| bad(format!("default of `{}`: {e}", p.name)))?;
        }
        Ok(())
    }
}

/// Whether `name` can serve as a variant, preset or parameter name: the `--set` syntax and the
/// comma lists of the CLI must be able to carry it.
pub fn check_name(name: &str) -> std::result::Result<(), String> {
    if name.is_empty() {
        return Err("empty".into());
    }
    if let Some(c) = name
        .chars()
        .find(|c| !(c.is_ascii_lowercase() || c.is_ascii_digit() || *c == '_' || *c == '-'))
    {
        return Err(format!("`{name}` has `{c}` (use a-z, 0-9, `_` and `-`)"));
    }
    if name == "off" || name == "none" {
        return Err(format!(
            "`{name}` is reserved (it empties an optional slot)"
        ));
    }
    Ok(())
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

    /// Checks every filled slot against `catalogue` (variant exists, parameters known, of the
    /// right type, among the choices and inside the range), fills in defaults, and checks that
    /// the slots fit together ([`PipelineConfig::check_slots`]).
    pub fn resolve(&mut self, catalogue: &[StageVariantInfo]) -> Result<()> {
        for slot in StageKind::ALL {
            let spec = match self.slot_mut(slot) {
                SlotMut::Required(s) => s,
                SlotMut::Optional(Some(s)) => s,
                SlotMut::Optional(None) => continue,
            };
            resolve_spec(slot, spec, catalogue)?;
        }
        self.check_slots(catalogue)
    }

    /// Checks that the filled slots fit together, naming the slots when they do not
    /// ([`CoreError::Incompatible`]): `hash` and `sort` come together (without a `hierarchy`
    /// they put each batch in sorted order for the whole-scene intersector), a `hierarchy`
    /// comes with a `traverse` stage, and the intersector of a pipeline with a hierarchy
    /// answers candidate queries (its catalogue entry is not
    /// [`StageVariantInfo::scene_only`]).
    pub fn check_slots(&self, catalogue: &[StageVariantInfo]) -> Result<()> {
        fn kind(s: &Option<StageSpec>) -> Option<&str> {
            s.as_ref().map(|s| s.kind.as_str())
        }
        let incompatible = |slots: &str, reason: String| CoreError::Incompatible {
            slots: slots.to_string(),
            reason,
        };
        match (kind(&self.hash), kind(&self.sort)) {
            (Some(h), None) => {
                return Err(incompatible(
                    "hash, sort",
                    format!("hash `{h}` writes keys that only a sorter uses, and `sort` is off; add --set sort.kind=NAME or set hash=off"),
                ))
            }
            (None, Some(s)) => {
                return Err(incompatible(
                    "hash, sort",
                    format!("sort `{s}` orders rays by the keys of a hasher, and `hash` is off; add --set hash.kind=NAME or set sort=off"),
                ))
            }
            _ => {}
        }
        match (kind(&self.hierarchy), kind(&self.traverse)) {
            (Some(h), None) => {
                return Err(incompatible(
                    "hierarchy, traverse",
                    format!("hierarchy `{h}` needs a traverser, and `traverse` is off"),
                ))
            }
            (None, Some(t)) => {
                return Err(incompatible(
                    "hierarchy, traverse",
                    format!("traverse `{t}` walks a ray-space hierarchy, and `hierarchy` is off"),
                ))
            }
            _ => {}
        }
        if let Some(h) = kind(&self.hierarchy) {
            let scene_only = catalogue.iter().any(|v| {
                v.stage == StageKind::Intersect && v.name == self.intersect.kind && v.scene_only
            });
            if scene_only {
                return Err(incompatible(
                    "hierarchy, intersect",
                    format!(
                        "intersect `{}` answers whole-scene queries only and cannot run the final tests of hierarchy `{h}` (use it as --reference, or in a pipeline without a hierarchy)",
                        self.intersect.kind
                    ),
                ));
            }
        }
        Ok(())
    }

    /// The reference pipeline of `--reference NAME`: the same primary, ray generation and
    /// shading stages (with their parameters) as `self`, every ray traced against the whole
    /// scene by the intersector `intersect` (no hash, sort, hierarchy or traverse stage),
    /// named `NAME-reference-INTERSECT`. Unresolved.
    pub fn reference(&self, intersect: &str) -> PipelineConfig {
        PipelineConfig {
            name: format!("{}-reference-{intersect}", self.name),
            hash: None,
            sort: None,
            hierarchy: None,
            traverse: None,
            intersect: StageSpec::new(intersect),
            ..self.clone()
        }
    }
}

/// The error for variant `name` missing from `slot` of `catalogue`, listing the ones there.
pub(crate) fn unknown_variant(
    slot: StageKind,
    name: &str,
    catalogue: &[StageVariantInfo],
) -> CoreError {
    CoreError::UnknownVariant {
        stage: slot.key().into(),
        name: name.to_string(),
        known: catalogue
            .iter()
            .filter(|v| v.stage == slot)
            .map(|v| v.name)
            .collect::<Vec<_>>()
            .join(", "),
    }
}

/// Resolves one slot's spec against `catalogue` (see [`PipelineConfig::resolve`]).
pub fn resolve_spec(
    slot: StageKind,
    spec: &mut StageSpec,
    catalogue: &[StageVariantInfo],
) -> Result<()> {
    let info = catalogue
        .iter()
        .find(|v| v.stage == slot && v.name == spec.kind)
        .ok_or_else(|| unknown_variant(slot, &spec.kind, catalogue))?;
    for (k, v) in spec.params.iter_mut() {
        let p =
            info.params
                .iter()
                .find(|p| p.name == k)
                .ok_or_else(|| CoreError::InvalidParam {
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
        p.check(slot, v)?;
    }
    for p in &info.params {
        spec.params
            .entry(p.name.to_string())
            .or_insert_with(|| p.default.clone());
    }
    Ok(())
}

enum SlotMut<'a> {
    Required(&'a mut StageSpec),
    Optional(&'a mut Option<StageSpec>),
}

#[cfg(test)]
mod tests {
    use super::*;

    fn catalogue() -> Vec<StageVariantInfo> {
        vec![
            StageVariantInfo::new(StageKind::Primary, "raster", "r"),
            StageVariantInfo::new(StageKind::Raygen, "whitted", "w").param(ParamInfo::choice(
                "shadow_origin",
                "light",
                &["light", "surface"],
                "o",
            )),
            StageVariantInfo::new(StageKind::Intersect, "brute", "b"),
            StageVariantInfo::new(StageKind::Intersect, "bvh", "v").scene_only(),
            StageVariantInfo::new(StageKind::Hash, "h", "h")
                .param(ParamInfo::int("bits", 8, 1, 32, "b")),
            StageVariantInfo::new(StageKind::Sort, "s", "s"),
            StageVariantInfo::new(StageKind::Hierarchy, "t", "t"),
            StageVariantInfo::new(StageKind::Traverse, "u", "u"),
            StageVariantInfo::new(StageKind::Shade, "phong", "p")
                .param(ParamInfo::float("ambient", 0.1, "a").range(0.0, 1.0)),
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
        // Ranges: NaN and out-of-range numbers are refused before any stage is built.
        for bad in ["shade.ambient=nan", "shade.ambient=2", "shade.ambient=-0.5"] {
            let mut c = PipelineConfig::whitted("x", "brute");
            c.set(bad).unwrap();
            let e = c.resolve(&catalogue()).unwrap_err();
            assert!(matches!(e, CoreError::InvalidParam { .. }), "{bad}: {e}");
        }
    }

    fn hierarchy_pipeline(sets: &[&str]) -> PipelineConfig {
        let mut c = PipelineConfig::whitted("x", "brute");
        for s in [
            "hash.kind=h",
            "sort.kind=s",
            "hierarchy.kind=t",
            "traverse.kind=u",
        ]
        .iter()
        .chain(sets)
        {
            c.set(s).unwrap();
        }
        c
    }

    #[test]
    fn slots_that_do_not_fit_are_refused_naming_them() {
        hierarchy_pipeline(&[]).resolve(&catalogue()).unwrap();
        for (sets, slots) in [
            (&["sort=off"][..], "hash, sort"),
            (&["hash=off"], "hash, sort"),
            (&["traverse=off"], "hierarchy, traverse"),
            (&["hierarchy=off"], "hierarchy, traverse"),
            (&["intersect.kind=bvh"], "hierarchy, intersect"),
        ] {
            let e = hierarchy_pipeline(sets).resolve(&catalogue()).unwrap_err();
            match &e {
                CoreError::Incompatible { slots: s, .. } => assert_eq!(s, slots, "{sets:?}"),
                other => panic!("{sets:?}: {other}"),
            }
        }
        // Without a hierarchy a whole-scene intersector is fine, sorted or not.
        let mut plain = PipelineConfig::whitted("x", "bvh");
        plain.resolve(&catalogue()).unwrap();
        hierarchy_pipeline(&["hierarchy=off", "traverse=off", "intersect.kind=bvh"])
            .resolve(&catalogue())
            .unwrap();
    }

    #[test]
    fn catalogue_entries_are_validated() {
        for v in catalogue() {
            v.validate().unwrap();
        }
        let ok = || StageVariantInfo::new(StageKind::Hash, "fine", "doc");
        for bad in [
            StageVariantInfo::new(StageKind::Hash, "Bad.Name", "doc"),
            StageVariantInfo::new(StageKind::Hash, "off", "doc"),
            StageVariantInfo::new(StageKind::Hash, "x", " "),
            ok().param(ParamInfo::int("n", 40, 1, 32, "d")),
            ok().param(ParamInfo::choice("c", "z", &["a", "b"], "d")),
            ok().param(ParamInfo::bool("b", true, "d"))
                .param(ParamInfo::bool("b", false, "d")),
            ok().param(ParamInfo::bool("kind", true, "d")),
            ok().param(ParamInfo::bool("b", true, "d").range(0.0, 1.0)),
            ok().param(ParamInfo::float("f", 0.5, "d").range(1.0, 0.0)),
        ] {
            assert!(bad.validate().is_err(), "{bad:?}");
        }
        assert_eq!(
            ParamInfo::float("f", 0.0, "d")
                .range(0.0, f64::INFINITY)
                .range_text(),
            ">= 0"
        );
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
