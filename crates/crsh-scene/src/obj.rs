//! Wavefront OBJ + MTL loading through `tobj`.
//!
//! The file's `v` and `f` lines are first counted while streaming it (so an absurdly large
//! file is rejected before anything is allocated for it); it is then read into memory, every
//! line is checked by [`diagnose`], and it is parsed by `tobj` with
//! [`tobj::GPU_LOAD_OPTIONS`] (one index per vertex, polygons triangulated as fans). Each
//! `tobj` model (a new one starts at every `o`, `g` or material change) becomes one mesh, a
//! contiguous triangle range.
//!
//! `tobj` reports errors without a line number and silently drops some data, so the first
//! line [`diagnose`] finds wrong is an error naming it (`file.obj:123: ...`): a line that does
//! not parse, a non-finite coordinate or one beyond [`MAX_COORDINATE`], a face with fewer
//! than three vertices, a vertex, texture-coordinate or normal index that is zero, malformed
//! or out of range. Line (`l`) and point (`p`) elements are checked the same way, then
//! ignored with a warning: only faces are rendered. Normals (`vn`) that are not finite or
//! zero are replaced by computed ones, with a warning ([`SceneBuilder`]); texture coordinates
//! are not used.
//!
//! Materials: a missing MTL file never fails the geometry: the meshes get a default material
//! and a warning goes to the load report. An MTL file that exists must be valid
//! ([`crate::mtl`]): its first bad line is an error (`m.mtl:4: Kd: ...`). The mapping from
//! MTL values follows `../shared/scenes/README.md`; see [`material_from_mtl`].

use std::cell::RefCell;
use std::collections::BTreeMap;
use std::path::Path;

use glam::Vec3;

use crate::error::SceneError;
use crate::model::{
    Camera, Light, Material, SceneBuilder, MAX_COORDINATE, MAX_TRIANGLES, MAX_VERTICES,
};

/// Largest OBJ file accepted (16 GiB); anything larger is rejected before it is read (files
/// below are counted, streaming, before they are loaded: see [`MAX_TRIANGLES`]).
pub const MAX_FILE_BYTES: u64 = 16 << 30;

/// Vertical field of view of the camera framed for a bare OBJ, in degrees.
pub const BARE_VFOV_DEG: f32 = 45.0;

/// What [`read`] found besides the geometry it added to the builder.
#[derive(Clone, Debug, Default)]
pub struct ObjInfo {
    /// Material ids in the builder, by MTL material name (a name may occur more than once
    /// when several MTL files define it).
    pub materials_by_name: BTreeMap<String, Vec<u32>>,
    /// Number of meshes added.
    pub meshes: usize,
    /// Number of triangles added.
    pub triangles: usize,
}

/// Counts of the OBJ elements, from a quick scan of the text.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct Counts {
    positions: usize,
    texcoords: usize,
    normals: usize,
    /// Triangles after fan triangulation of `f` lines.
    triangles: usize,
    /// Line (`l`) and point (`p`) elements, which are ignored.
    ignored: usize,
    /// Vertices given with a colour (`v x y z r g b`).
    coloured: usize,
}

/// Calls `f(line_number, line_bytes)` for every line (1-based, without `\r\n`).
fn for_each_line(bytes: &[u8], mut f: impl FnMut(usize, &[u8]) -> bool) {
    for (i, line) in bytes.split(|&b| b == b'\n').enumerate() {
        let line = line.strip_suffix(b"\r").unwrap_or(line);
        if !f(i + 1, line) {
            return;
        }
    }
}

/// The keyword and the rest of a line, split on ASCII whitespace.
fn words(line: &[u8]) -> impl Iterator<Item = &[u8]> {
    line.split(|b| b.is_ascii_whitespace())
        .filter(|w| !w.is_empty())
}

impl Counts {
    fn add_line(&mut self, line: &[u8]) {
        let mut w = words(line);
        match w.next() {
            Some(b"v") => self.positions += 1,
            Some(b"vt") => self.texcoords += 1,
            Some(b"vn") => self.normals += 1,
            Some(b"f") => self.triangles += w.count().saturating_sub(2),
            Some(b"l") | Some(b"p") => self.ignored += 1,
            _ => {}
        }
    }
}

fn count_elements(bytes: &[u8]) -> Counts {
    let mut c = Counts::default();
    for_each_line(bytes, |_, line| {
        c.add_line(line);
        true
    });
    c
}

/// [`count_elements`] over a file, streaming line by line.
fn count_file(path: &Path) -> std::io::Result<Counts> {
    use std::io::BufRead;
    let mut reader = std::io::BufReader::with_capacity(1 << 20, std::fs::File::open(path)?);
    let mut c = Counts::default();
    let mut line = Vec::new();
    loop {
        line.clear();
        if reader.read_until(b'\n', &mut line)? == 0 {
            return Ok(c);
        }
        c.add_line(&line);
    }
}

fn parse_f32(w: &[u8]) -> Option<f32> {
    std::str::from_utf8(w).ok()?.parse::<f32>().ok()
}

/// Resolves one 1-based (or negative, relative) OBJ index against `so_far` elements defined
/// before the line and `total` in the file. `Err` says what is wrong.
fn check_index(
    raw: &[u8],
    what: &str,
    so_far: usize,
    total: usize,
    strict: bool,
) -> Result<(), String> {
    let text = String::from_utf8_lossy(raw);
    let x: i64 = text
        .parse()
        .map_err(|_| format!("{what} index '{text}' is not an integer"))?;
    if x == 0 {
        return Err(format!(
            "{what} index 0 is invalid (OBJ indices start at 1)"
        ));
    }
    if x < 0 {
        if x.unsigned_abs() as usize > so_far {
            return Err(format!(
                "relative {what} index {x} reaches before the first {what} ({so_far} defined so far)"
            ));
        }
        return Ok(());
    }
    let limit = if strict { so_far } else { total };
    if x as usize > limit {
        return Err(if strict {
            format!("{what} index {x} refers to a {what} defined later ({so_far} defined so far)")
        } else {
            format!("{what} index {x} is out of range ({total} in the file)")
        });
    }
    Ok(())
}

/// Scans OBJ text for the first line `tobj` would reject or that holds a non-finite
/// coordinate, and returns its 1-based number and what is wrong with it. With `strict`,
/// forward references to vertices defined later count as errors too.
pub fn diagnose(bytes: &[u8], strict: bool) -> Option<(usize, String)> {
    let totals = count_elements(bytes);
    let mut seen = Counts::default();
    let mut found = None;
    for_each_line(bytes, |n, line| {
        if let Err(msg) = check_line(line, &mut seen, &totals, strict) {
            found = Some((n, msg));
            return false;
        }
        true
    });
    found
}

fn check_line(line: &[u8], seen: &mut Counts, totals: &Counts, strict: bool) -> Result<(), String> {
    if std::str::from_utf8(line).is_err() {
        return Err("line is not valid UTF-8".into());
    }
    let mut w = words(line);
    let Some(key) = w.next() else { return Ok(()) };
    let rest: Vec<&[u8]> = w.collect();
    let floats = |n: usize, what: &str| -> Result<Vec<f32>, String> {
        if rest.len() < n {
            return Err(format!("{what} needs {n} numbers, found {}", rest.len()));
        }
        rest[..n]
            .iter()
            .map(|t| {
                parse_f32(t)
                    .ok_or_else(|| format!("'{}' is not a number", String::from_utf8_lossy(t)))
            })
            .collect()
    };
    match key {
        b"v" => {
            let xyz = floats(3, "vertex")?;
            let mut w = 1.0;
            match rest.len() {
                3 => {}
                4 => match parse_f32(rest[3]) {
                    Some(0.0) => return Err("vertex weight w is zero".into()),
                    Some(x) => w = x,
                    None => return Err("vertex weight w is not a number".into()),
                },
                6 => {
                    if rest[3..].iter().any(|t| parse_f32(t).is_none()) {
                        return Err("vertex colour is not three numbers".into());
                    }
                }
                n => return Err(format!("vertex has {n} values (3, 4 or 6 expected)")),
            }
            // `tobj` keeps colours in a list of their own, indexed like the vertices.
            let coloured = rest.len() == 6;
            if seen.coloured != if coloured { seen.positions } else { 0 } {
                return Err(format!(
                    "vertex {} {} a colour but the vertices before it {}: give every vertex a \
                     colour, or none",
                    seen.positions + 1,
                    if coloured { "has" } else { "lacks" },
                    if coloured { "have none" } else { "have one" },
                ));
            }
            seen.coloured += usize::from(coloured);
            // `tobj` divides by the weight: check what it will store.
            let p = Vec3::from_array([xyz[0], xyz[1], xyz[2]]) / w;
            if !p.is_finite() {
                return Err(format!(
                    "vertex {} has a non-finite coordinate ({} {} {})",
                    seen.positions + 1,
                    p.x,
                    p.y,
                    p.z
                ));
            }
            if p.abs().max_element() > MAX_COORDINATE {
                return Err(format!(
                    "vertex {} has a coordinate beyond the supported magnitude {MAX_COORDINATE:e} \
                     ({} {} {})",
                    seen.positions + 1,
                    p.x,
                    p.y,
                    p.z
                ));
            }
            seen.positions += 1;
        }
        b"vt" => {
            floats(2, "texture coordinate")?;
            seen.texcoords += 1;
        }
        b"vn" => {
            floats(3, "normal")?;
            seen.normals += 1;
        }
        b"f" | b"l" | b"p" => {
            let (least, what) = match key {
                b"f" => (3, "face"),
                b"l" => (2, "line element"),
                _ => (1, "point element"),
            };
            if rest.len() < least {
                return Err(format!(
                    "{what} has {} vertices ({least} or more needed)",
                    rest.len()
                ));
            }
            for corner in &rest {
                let parts: Vec<&[u8]> = corner.split(|&b| b == b'/').collect();
                if parts.len() > 3 {
                    return Err(format!(
                        "face corner '{}' has more than three '/'-separated indices \
                         (v, v/vt, v//vn or v/vt/vn expected)",
                        String::from_utf8_lossy(corner)
                    ));
                }
                let kinds = [
                    ("vertex", seen.positions, totals.positions),
                    ("texture coordinate", seen.texcoords, totals.texcoords),
                    ("normal", seen.normals, totals.normals),
                ];
                for (part, (what, so_far, total)) in parts.iter().zip(kinds) {
                    if part.is_empty() && what != "vertex" {
                        continue;
                    }
                    check_index(part, what, so_far, total, strict)?;
                }
            }
        }
        b"usemtl" if rest.is_empty() => return Err("usemtl without a material name".into()),
        b"mtllib" if rest.is_empty() => return Err("mtllib without a file name".into()),
        _ => {}
    }
    Ok(())
}

fn first_number(s: &str) -> Option<f32> {
    s.split_whitespace().next()?.parse().ok()
}

/// Maps an MTL material to a crsh [`Material`] (`../shared/scenes/README.md`), returning
/// notes about interpretations for the load report.
///
/// - `Kd` diffuse; when absent, black if the material is described by `Ks`, `Tf` or `Ke`
///   instead (e.g. the Cornell spheres), else the default grey 0.8.
/// - `Ks` specular (default black), `Ns` shininess (default 1), `Ke` emission (marks an
///   emitter's surface; not a light).
/// - Mirror: `illum 3` or `illum 5` give reflectivity `max(Ks)` (clamped to `[0, 1]`).
/// - Transparency, first rule that applies: `d < 1` gives `1 - d` (dissolve is opacity;
///   `Tr`, its complement written by some exporters, counts as `d = 1 - Tr`);
///   else `Tf` with `max(Tf) < 1` gives `max(Tf)` (the transmission filter is the fraction
///   transmitted; `Tf 1 1 1` is ignored because exporters write it for opaque materials);
///   else `illum 4`, `6` or `7` give 1 (fully transparent glass, weighted by `max(Tf)` when
///   `Tf` is given).
/// - `ior` is `Ni` when given, else 1.0, or 1.5 for a transparent material without `Ni`.
pub fn material_from_mtl(m: &tobj::Material) -> (Material, Vec<String>) {
    let mut notes = Vec::new();
    let v3 = |a: Option<[f32; 3]>| a.map(Vec3::from_array);
    let tf: Option<Vec3> = m.unknown_param.get("Tf").and_then(|s| {
        let n: Vec<f32> = s
            .split_whitespace()
            .filter_map(|t| t.parse().ok())
            .collect();
        match n.len() {
            1 => Some(Vec3::splat(n[0])),
            3.. => Some(Vec3::new(n[0], n[1], n[2])),
            _ => None,
        }
    });
    let specular = v3(m.specular).unwrap_or(Vec3::ZERO);
    let emission = v3(m.emissive).unwrap_or(Vec3::ZERO);
    let described_otherwise = m.specular.is_some() || tf.is_some() || m.emissive.is_some();
    let diffuse = v3(m.diffuse).unwrap_or(if described_otherwise {
        Vec3::ZERO
    } else {
        Material::default().diffuse
    });
    let illum = m.illumination_model;
    let reflectivity = if matches!(illum, Some(3) | Some(5)) {
        let r = specular.max_element().clamp(0.0, 1.0);
        if r == 0.0 {
            notes.push(format!(
                "material '{}': illum {} without Ks: not a mirror",
                m.name,
                illum.unwrap_or(0)
            ));
        }
        r
    } else {
        0.0
    };
    let dissolve = m.dissolve.or_else(|| {
        m.unknown_param
            .get("Tr")
            .and_then(|s| first_number(s))
            .map(|tr| 1.0 - tr)
    });
    let transparency = match (dissolve, tf) {
        (Some(d), _) if d < 1.0 => (1.0 - d).clamp(0.0, 1.0),
        (_, Some(t)) if t.max_element() < 1.0 => t.max_element().clamp(0.0, 1.0),
        _ if matches!(illum, Some(4) | Some(6) | Some(7)) => {
            tf.map_or(1.0, |t| t.max_element().clamp(0.0, 1.0))
        }
        _ => 0.0,
    };
    let ior = match m.optical_density {
        Some(n) if n.is_finite() && n > 0.0 => n,
        Some(n) => {
            notes.push(format!(
                "material '{}': Ni {n} is not a positive number; using 1",
                m.name
            ));
            1.0
        }
        None if transparency > 0.0 => 1.5,
        None => 1.0,
    };
    let material = Material {
        name: m.name.clone(),
        diffuse,
        specular,
        shininess: m.shininess.unwrap_or(1.0),
        reflectivity,
        transparency,
        ior,
        emission,
    };
    (material, notes)
}

/// Turns every `l` statement into a comment: `tobj` parses it like a face, so a polyline of
/// three or more vertices would be rendered as a polygon. Line numbers stay the same.
fn comment_out_line_elements(bytes: &mut [u8]) {
    let mut start = 0;
    while start < bytes.len() {
        let end = bytes[start..]
            .iter()
            .position(|&b| b == b'\n')
            .map_or(bytes.len(), |i| start + i);
        if let Some(k) = bytes[start..end]
            .iter()
            .position(|b| !b.is_ascii_whitespace())
        {
            let at = start + k;
            if bytes[at] == b'l' && bytes.get(at + 1).is_none_or(|b| b.is_ascii_whitespace()) {
                bytes[at] = b'#';
            }
        }
        start = end + 1;
    }
}

fn load_error(path: &Path, line: Option<(usize, String)>, fallback: String) -> SceneError {
    match line {
        Some((n, msg)) => SceneError::invalid(format!("{}:{n}", path.display()), msg),
        None => SceneError::invalid(path.display().to_string(), fallback),
    }
}

/// Reads the OBJ at `path` (and the MTL files it names, relative to it) into `builder`:
/// its materials, then one mesh per `tobj` model. Problems with MTL files become warnings in
/// the builder; problems with the geometry are errors naming `file:line` (or the file).
pub fn read(path: &Path, builder: &mut SceneBuilder) -> Result<ObjInfo, SceneError> {
    let io = |e: std::io::Error| SceneError::Io {
        path: path.to_path_buf(),
        source: e,
    };
    let meta = std::fs::metadata(path).map_err(io)?;
    if !meta.is_file() {
        return Err(SceneError::invalid(
            path.display().to_string(),
            "not a regular file",
        ));
    }
    if meta.len() > MAX_FILE_BYTES {
        return Err(SceneError::invalid(
            path.display().to_string(),
            format!(
                "file of {} bytes exceeds the limit of {MAX_FILE_BYTES}",
                meta.len()
            ),
        ));
    }
    // Count first, streaming, so that an absurd file is rejected before it is held in memory.
    let counts = count_file(path).map_err(io)?;
    if counts.triangles > MAX_TRIANGLES {
        return Err(SceneError::invalid(
            path.display().to_string(),
            format!(
                "{} triangles exceed the limit of {MAX_TRIANGLES}",
                counts.triangles
            ),
        ));
    }
    if counts.positions > MAX_VERTICES {
        return Err(SceneError::invalid(
            path.display().to_string(),
            format!(
                "{} vertices exceed the limit of {MAX_VERTICES}",
                counts.positions
            ),
        ));
    }
    let mut bytes = std::fs::read(path).map_err(io)?;
    if bytes.starts_with(b"\xEF\xBB\xBF") {
        bytes.drain(..3); // a UTF-8 byte-order mark would hide the first keyword from tobj
    }

    // Every line is checked first: `tobj` accepts faces with fewer than three vertices and
    // texture or normal indices out of range, and drops them without a word.
    if let Some(line) = diagnose(&bytes, false) {
        return Err(load_error(path, Some(line), String::new()));
    }
    if counts.ignored > 0 {
        comment_out_line_elements(&mut bytes);
        builder.warn(format!(
            "{}: {} line (l) and point (p) elements ignored: only faces are rendered",
            path.display(),
            counts.ignored
        ));
    }

    let dir = path.parent().unwrap_or(Path::new(".")).to_path_buf();
    let mtl_warnings = RefCell::new(Vec::new());
    let mtl_error = RefCell::new(None);
    let loaded = tobj::load_obj_buf(
        &mut std::io::Cursor::new(&bytes[..]),
        &tobj::GPU_LOAD_OPTIONS,
        |mtl: &Path| {
            let full = dir.join(mtl);
            let fail = |e: SceneError| {
                mtl_error.borrow_mut().get_or_insert(e);
                Err(tobj::LoadError::MaterialParseError)
            };
            match crate::mtl::read_checked(&full) {
                Ok(Some(text)) => {
                    tobj::load_mtl_buf(&mut std::io::Cursor::new(text)).or_else(|e| {
                        fail(SceneError::invalid(
                            full.display().to_string(),
                            format!("malformed MTL ({e})"),
                        ))
                    })
                }
                Ok(None) => {
                    mtl_warnings.borrow_mut().push(format!(
                        "{}: mtllib {}: file not found; its materials fall back to the default",
                        path.display(),
                        full.display()
                    ));
                    Err(tobj::LoadError::OpenFileFailed)
                }
                // An unreadable file (a directory, no permission): say which mtllib it is.
                Err(SceneError::Io { source, .. }) => fail(SceneError::invalid(
                    format!("{}: mtllib {}", path.display(), full.display()),
                    source.to_string(),
                )),
                Err(e) => fail(e),
            }
        },
    );
    if let Some(e) = mtl_error.into_inner() {
        return Err(e);
    }
    for w in mtl_warnings.into_inner() {
        builder.warn(w);
    }
    let (models, materials) = match loaded {
        Ok(x) => x,
        Err(e) => {
            let line = diagnose(&bytes, true);
            return Err(load_error(path, line, format!("malformed OBJ ({e})")));
        }
    };
    // An error here is a missing MTL file, already reported per mtllib above.
    let materials = materials.unwrap_or_default();

    let mut info = ObjInfo::default();
    let mut ids = Vec::with_capacity(materials.len());
    for m in &materials {
        let (mat, notes) = material_from_mtl(m);
        for n in notes {
            builder.warn(format!("{}: {n}", path.display()));
        }
        let id = builder.material(mat);
        info.materials_by_name
            .entry(m.name.clone())
            .or_default()
            .push(id);
        ids.push(id);
    }

    let mut default_id = None;
    let mut without_material = 0usize;
    for model in &models {
        let mesh = &model.mesh;
        if mesh.indices.is_empty() {
            continue;
        }
        let positions: Vec<Vec3> = mesh
            .positions
            .chunks_exact(3)
            .map(|c| Vec3::new(c[0], c[1], c[2]))
            .collect();
        if positions.iter().any(|p| !p.is_finite()) {
            let line = diagnose(&bytes, false);
            return Err(load_error(
                path,
                line,
                format!("object '{}' has a non-finite coordinate", model.name),
            ));
        }
        let normals: Option<Vec<Vec3>> = (mesh.normals.len() == mesh.positions.len()).then(|| {
            mesh.normals
                .chunks_exact(3)
                .map(|c| Vec3::new(c[0], c[1], c[2]))
                .collect()
        });
        let indices: Vec<[u32; 3]> = mesh
            .indices
            .chunks_exact(3)
            .map(|c| [c[0], c[1], c[2]])
            .collect();
        let material = match mesh.material_id.and_then(|i| ids.get(i).copied()) {
            Some(id) => id,
            None => {
                without_material += 1;
                *default_id.get_or_insert_with(|| builder.material(Material::default()))
            }
        };
        builder.mesh(
            model.name.clone(),
            &positions,
            normals.as_deref(),
            &indices,
            material,
        );
        info.meshes += 1;
        info.triangles += indices.len();
    }
    if without_material > 0 && !materials.is_empty() {
        builder.warn(format!(
            "{}: {without_material} meshes name no known material (usemtl missing or unknown); \
             they use the default material",
            path.display()
        ));
    }
    Ok(info)
}

/// Loads a bare OBJ (no manifest): the camera looks at the centre of the bounds from the `+z`
/// side, at the distance where the bounding sphere fits a vertical field of view of
/// [`BARE_VFOV_DEG`]; one white light sits above the camera (by one bounding radius).
pub fn load(path: &Path) -> Result<(crate::Scene, Vec<String>), SceneError> {
    let name = path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "obj".into());
    let mut builder = SceneBuilder::new(name);
    read(path, &mut builder)?;
    let bounds = crsh_core::Aabb::from_points(builder.positions().iter().copied());
    let center = bounds.center();
    let radius = builder
        .positions()
        .iter()
        .fold(0.0f32, |r, p| r.max(p.distance(center)));
    let camera = Camera::framing(crsh_core::Sphere::new(center, radius), BARE_VFOV_DEG);
    let lift = if radius > 0.0 { radius } else { 1.0 };
    builder.light(Light {
        position: camera.eye + Vec3::Y * lift,
        color: Vec3::ONE,
        intensity: 1.0,
        attenuation: [1.0, 0.0, 0.0],
        radius: 0.0,
    });
    builder.camera(camera);
    builder.build_with_warnings(&path.display().to_string())
}
