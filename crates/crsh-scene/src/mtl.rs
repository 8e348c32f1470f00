//! MTL files: checked line by line before `tobj` parses them.
//!
//! `tobj` panics on a colour line with fewer than three numbers and drops a whole file on one
//! garbled line; it also accepts values that mean nothing (`d -1`, `d nan`, `Kd 1 1 1 1`). So
//! every line is checked first, and the first one outside its meaning is an error naming the
//! file, the line and the key: `m.mtl:4: Kd: needs three numbers (r g b), found 2`. A value's
//! trailing `# comment` is allowed (`Ka 0.6 0.1 0.1 # red`).
//!
//! The rules, one per key (case-sensitive, as `tobj` reads them):
//! - `newmtl NAME`: a name is required. Every other statement needs a `newmtl` before it
//!   (`tobj` would silently drop it).
//! - `Ka`, `Kd`, `Ks` (ambient, diffuse, specular reflectance): exactly three finite numbers
//!   in `[0, 1]` (a surface cannot reflect more light than it receives). `Ke` (emission):
//!   exactly three finite numbers `>= 0`, any size (an emitter's radiance). The spectral and
//!   CIE XYZ forms of the MTL specification are not supported.
//! - `Tf` (transmission filter): one or three finite numbers in `[0, 1]`.
//! - `d` (dissolve, opacity) and `Tr` (its complement): one finite number in `[0, 1]`.
//! - `Ns` (shininess): one finite number `>= 0`. `Ni` (index of refraction): one finite
//!   number `> 0`.
//! - `illum`: one integer in `0..=10`.
//! - `map_Ka`, `map_Kd`, `map_Ks`, `map_Ns`, `map_d`, `map_Bump`, `bump`: a file name is
//!   required (`tobj` reads them; textures are not used). Any other key (`Pe`, `disp`,
//!   `refl`, ...) is kept by `tobj` as an unknown parameter and ignored here.
//! - Every line must be valid UTF-8 (a binary file fails on its first bad line).

use std::path::Path;

use crate::error::SceneError;

/// Largest `illum` model of the MTL specification.
pub const MAX_ILLUM: u32 = 10;

/// Texture statements that `tobj` parses itself and refuses without a file name.
const TEXTURE_KEYS: [&str; 10] = [
    "map_Ka", "map_Kd", "map_Ks", "map_Ns", "map_ns", "map_NS", "map_d", "map_Bump", "map_bump",
    "bump",
];

/// Scans MTL text for the first line outside its meaning (see the module documentation) and
/// returns its 1-based number and `key: what is wrong`.
pub fn diagnose(bytes: &[u8]) -> Option<(usize, String)> {
    let mut in_material = false;
    for (i, line) in bytes.split(|&b| b == b'\n').enumerate() {
        let line = line.strip_suffix(b"\r").unwrap_or(line);
        if let Err(msg) = check_line(line, &mut in_material) {
            return Some((i + 1, msg));
        }
    }
    None
}

/// Checks one line; `in_material` says whether a `newmtl` came before (and is set by one).
fn check_line(line: &[u8], in_material: &mut bool) -> Result<(), String> {
    let Ok(line) = std::str::from_utf8(line) else {
        return Err("line is not valid UTF-8".into());
    };
    let mut words = line.split_whitespace();
    let Some(key) = words.next() else {
        return Ok(());
    };
    if key.starts_with('#') {
        return Ok(());
    }
    let args: Vec<&str> = words.take_while(|w| !w.starts_with('#')).collect();
    if key == "newmtl" {
        if args.is_empty() {
            return Err("newmtl: a material name is required".into());
        }
        *in_material = true;
        return Ok(());
    }
    if !*in_material {
        return Err(format!(
            "{key}: comes before the first newmtl (no material to apply it to)"
        ));
    }
    let bad = |what: String| Err(format!("{key}: {what}"));
    match key {
        "Ka" | "Kd" | "Ks" => numbers(&args, &[3], "three numbers (r g b)")
            .and_then(|v| in_range(&v, 0.0, Some(1.0), "in [0, 1]"))
            .or_else(bad),
        "Ke" => numbers(&args, &[3], "three numbers (r g b)")
            .and_then(|v| in_range(&v, 0.0, None, ">= 0"))
            .or_else(bad),
        "Tf" => numbers(&args, &[1, 3], "one or three numbers")
            .and_then(|v| in_range(&v, 0.0, Some(1.0), "in [0, 1]"))
            .or_else(bad),
        "d" | "Tr" => numbers(&args, &[1], "one number")
            .and_then(|v| in_range(&v, 0.0, Some(1.0), "in [0, 1]"))
            .or_else(bad),
        "Ns" => numbers(&args, &[1], "one number")
            .and_then(|v| in_range(&v, 0.0, None, ">= 0"))
            .or_else(bad),
        "Ni" => match numbers(&args, &[1], "one number") {
            Ok(v) if v[0] > 0.0 => Ok(()),
            Ok(v) => bad(format!("{} must be > 0 (an index of refraction)", v[0])),
            Err(e) => bad(e),
        },
        "illum" => match args[..] {
            [one] => match one.parse::<u32>() {
                Ok(n) if n <= MAX_ILLUM => Ok(()),
                _ => bad(format!(
                    "'{one}' is not an illumination model (an integer in 0..={MAX_ILLUM})"
                )),
            },
            _ => bad(format!(
                "needs one integer in 0..={MAX_ILLUM}, found {} values",
                args.len()
            )),
        },
        k if TEXTURE_KEYS.contains(&k) && args.is_empty() => bad("a file name is required".into()),
        _ => Ok(()),
    }
}

/// Parses `args` as finite numbers, their count one of `counts`.
fn numbers(args: &[&str], counts: &[usize], what: &str) -> Result<Vec<f32>, String> {
    if !counts.contains(&args.len()) {
        return Err(format!("needs {what}, found {}", args.len()));
    }
    args.iter()
        .map(|t| match t.parse::<f32>() {
            Ok(x) if x.is_finite() => Ok(x),
            Ok(x) => Err(format!("{x} is not a finite number")),
            Err(_) => Err(format!("'{t}' is not a number")),
        })
        .collect()
}

/// Checks that every value of `v` is `>= lo` and, with `hi`, `<= hi`.
fn in_range(v: &[f32], lo: f32, hi: Option<f32>, what: &str) -> Result<(), String> {
    match v.iter().find(|&&x| x < lo || hi.is_some_and(|h| x > h)) {
        Some(x) => Err(format!("{x} is outside its meaning (must be {what})")),
        None => Ok(()),
    }
}

/// Reads the MTL file at `path` and checks it ([`diagnose`]), returning its text (without a
/// UTF-8 byte-order mark) for `tobj::load_mtl_buf`. `Ok(None)` when the file does not exist
/// (the caller warns and uses a default material); any other problem is an error naming the
/// file (and line).
pub fn read_checked(path: &Path) -> Result<Option<Vec<u8>>, SceneError> {
    let mut bytes = match std::fs::read(path) {
        Ok(b) => b,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(e) => {
            return Err(SceneError::Io {
                path: path.to_path_buf(),
                source: e,
            })
        }
    };
    if bytes.starts_with(b"\xEF\xBB\xBF") {
        bytes.drain(..3);
    }
    match diagnose(&bytes) {
        Some((n, msg)) => Err(SceneError::invalid(format!("{}:{n}", path.display()), msg)),
        None => Ok(Some(bytes)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn first_error(text: &str) -> Option<(usize, String)> {
        diagnose(text.as_bytes())
    }

    #[test]
    fn valid_files_pass() {
        let text = "# comment\r\nnewmtl a\r\n  Ka 0.6 0.1 0.1 # red\r\nKd 0 0 0\nKs 1 1 1\n\
                    Ke 17 12 4\nNs 1000\nNi 1.5\nd 0.5\nTr 0\nTf 0.9\nTf 1 1 1\nillum 7\n\
                    Pe 10\nmap_Kd tex.png\nrefl -type sphere x.png\n\nnewmtl b\n";
        assert_eq!(first_error(text), None);
    }

    #[test]
    fn short_and_long_colours_are_errors() {
        for (line, want) in [
            ("Kd 0.5 0.5", "Kd: needs three numbers (r g b), found 2"),
            ("Kd 0.5", "Kd: needs three numbers (r g b), found 1"),
            ("Kd", "Kd: needs three numbers (r g b), found 0"),
            ("Ks 1 1", "Ks: needs three numbers (r g b), found 2"),
            ("Ka 1", "Ka: needs three numbers (r g b), found 1"),
            ("Ke 1 1", "Ke: needs three numbers (r g b), found 2"),
            ("Kd 1 1 1 1", "Kd: needs three numbers (r g b), found 4"),
        ] {
            let text = format!("newmtl m\n{line}\n");
            assert_eq!(first_error(&text), Some((2, want.to_string())), "{line}");
        }
    }

    #[test]
    fn values_outside_their_meaning_are_errors() {
        for (line, key) in [
            ("d -1", "d:"),
            ("d nan", "d:"),
            ("d 1.5", "d:"),
            ("Tf nan", "Tf:"),
            ("Tf 1 1", "Tf:"),
            ("Tr nan", "Tr:"),
            ("Ni nan", "Ni:"),
            ("Ni 0", "Ni:"),
            ("Ni -1.5", "Ni:"),
            ("Ns -1", "Ns:"),
            ("Ns inf", "Ns:"),
            ("Kd a b c", "Kd:"),
            ("Kd 0.5 1.5 0", "Kd:"),
            ("Ke -1 0 0", "Ke:"),
            ("illum x", "illum:"),
            ("illum 11", "illum:"),
            ("illum", "illum:"),
            ("map_Kd", "map_Kd:"),
            ("bump   ", "bump:"),
        ] {
            let text = format!("newmtl m\nNs 1\n{line}\n");
            let (n, msg) = first_error(&text).unwrap_or_else(|| panic!("{line} accepted"));
            assert_eq!(n, 3, "{line}: {msg}");
            assert!(msg.starts_with(key), "{line}: {msg}");
        }
    }

    #[test]
    fn structure_errors() {
        assert_eq!(
            first_error("Kd 1 1 1\nnewmtl a\n"),
            Some((
                1,
                "Kd: comes before the first newmtl (no material to apply it to)".into()
            ))
        );
        assert_eq!(
            first_error("newmtl a\nnewmtl\n"),
            Some((2, "newmtl: a material name is required".into()))
        );
        assert_eq!(
            diagnose(b"newmtl a\nKd 1 \xff 1\n"),
            Some((2, "line is not valid UTF-8".into()))
        );
    }
}
