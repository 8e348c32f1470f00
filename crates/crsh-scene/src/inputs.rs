//! The files loading a scene reads, found without loading it: a program that writes files
//! (`crsh render --stats`, `crsh ablate --out`) checks that it will not write over one of
//! them.

use std::io::BufRead;
use std::path::{Path, PathBuf};

use crate::manifest::{Manifest, MAX_EXTENDS_DEPTH};

/// The files loading `spec` (as [`crate::load`] takes it) reads: a manifest, the manifests it
/// extends, the OBJ files it and its instances name, and the MTL files those name (each
/// `mtllib` line, read both whole and word by word, so the list errs on the side of too many).
/// A built-in scene reads none. Files that do not exist are listed all the same (as the
/// loader would name them); what cannot be read or parsed ends the search there, since loading
/// it fails too.
pub fn input_files(spec: &str) -> Vec<PathBuf> {
    let mut out = Vec::new();
    if crate::builtin::is_name(spec) {
        return out;
    }
    let path = Path::new(spec);
    match path.extension().and_then(|e| e.to_str()) {
        Some(e) if e.eq_ignore_ascii_case("toml") => manifest_files(path, 0, &mut out),
        Some(e) if e.eq_ignore_ascii_case("obj") => obj_files(path, &mut out),
        _ => out.push(path.to_path_buf()),
    }
    let mut seen = std::collections::HashSet::new();
    out.retain(|p| seen.insert(p.clone()));
    out
}

fn beside(file: &Path, name: &Path) -> PathBuf {
    file.parent().unwrap_or(Path::new(".")).join(name)
}

fn manifest_files(path: &Path, depth: usize, out: &mut Vec<PathBuf>) {
    out.push(path.to_path_buf());
    let Ok(manifest) = Manifest::read(path) else {
        return;
    };
    if let Some(base) = &manifest.extends {
        if depth < MAX_EXTENDS_DEPTH && !crate::builtin::is_static(base) {
            manifest_files(&beside(path, Path::new(base)), depth + 1, out);
        }
    }
    let meshes = manifest
        .mesh
        .iter()
        .chain(manifest.instances.iter().filter_map(|i| i.mesh.as_ref()));
    for mesh in meshes {
        obj_files(&beside(path, mesh), out);
    }
}

fn obj_files(path: &Path, out: &mut Vec<PathBuf>) {
    out.push(path.to_path_buf());
    let Ok(file) = std::fs::File::open(path) else {
        return;
    };
    let mut reader = std::io::BufReader::new(file);
    let mut line = Vec::new();
    loop {
        line.clear();
        match reader.read_until(b'\n', &mut line) {
            Ok(0) | Err(_) => break,
            Ok(_) => {}
        }
        let text = String::from_utf8_lossy(&line);
        let text = text.trim().trim_start_matches('\u{feff}');
        let Some(rest) = text.strip_prefix("mtllib") else {
            continue;
        };
        if !rest.starts_with(char::is_whitespace) {
            continue;
        }
        let rest = rest.trim();
        out.push(beside(path, Path::new(rest)));
        if rest.contains(char::is_whitespace) {
            for word in rest.split_whitespace() {
                out.push(beside(path, Path::new(word)));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn manifests_objs_and_mtls() {
        let d = std::env::temp_dir().join(format!("crsh-scene-inputs-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(d.join("m")).unwrap();
        std::fs::write(
            d.join("m/a.obj"),
            "mtllib a.mtl\nmtllib  b c.mtl \nv 0 0 0\n",
        )
        .unwrap();
        std::fs::write(d.join("m/i.obj"), "v 0 0 0\n").unwrap();
        std::fs::write(d.join("base.toml"), "mesh = \"m/a.obj\"\n").unwrap();
        std::fs::write(
            d.join("s.toml"),
            "extends = \"base.toml\"\n[[instances]]\nmesh = \"m/i.obj\"\n",
        )
        .unwrap();
        let s = d.join("s.toml");
        let got = input_files(s.to_str().unwrap());
        let want: Vec<PathBuf> = [
            "s.toml",
            "base.toml",
            "m/a.obj",
            "m/a.mtl",
            "m/b c.mtl",
            "m/b",
            "m/c.mtl",
            "m/i.obj",
        ]
        .iter()
        .map(|n| match n.split_once('/') {
            Some((dir, f)) => d.join(dir).join(f),
            None => d.join(n),
        })
        .collect();
        assert_eq!(got, want);
        assert!(input_files("cornell-mirrors").is_empty());
        let missing = d.join("none.obj");
        assert_eq!(input_files(missing.to_str().unwrap()), vec![missing]);
    }
}
