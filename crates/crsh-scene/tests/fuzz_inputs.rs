//! A deterministic fuzz test of the scene loaders (issue 18): valid OBJ, MTL and manifest
//! texts are mutated (tokens swapped, deleted or duplicated, numbers replaced by `nan`,
//! `inf`, `-1`, `1e30` or garbage, lines truncated, deleted or repeated, random bytes
//! inserted) and loaded through the public API from files in a scratch directory. For every
//! case: no panic, the input files are unchanged afterwards, an error names one of the
//! files, and an accepted scene passes the structural invariants of `support`.
//!
//! The number of cases is `CRSH_FUZZ_CASES` (default [`DEFAULT_CASES`]), the seed
//! `CRSH_FUZZ_SEED` (default 0) and the first case `CRSH_FUZZ_FIRST` (default 0): a failure
//! is reproduced alone by its seed and case number (`CRSH_FUZZ_FIRST=N CRSH_FUZZ_CASES=1`).

mod support;

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::{Path, PathBuf};

/// Cases run by default: about a second in a debug build.
const DEFAULT_CASES: usize = 10_000;

const OBJ: &str = "# a small scene
mtllib m.mtl
o quad
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0 1
vt 0 0
vt 1 0
vt 1 1
vn 0 0 1
usemtl red
f 1/1/1 2/2/1 3/3/1 4//1
o tri
g part
v 0 0 1
v 1 0 1
v 0 1 1
usemtl glass
f -3 -2 -1
s off
usemtl lamp
f 5 6 7
l 1 2 3
p 4
";

const MTL: &str = "# materials
newmtl red
Ka 0.1 0.1 0.1 # ambient
Kd 0.8 0.1 0.1
Ks 0.2 0.2 0.2
Ns 32
illum 2
map_Kd red.png

newmtl glass
Ks 0.1 0.1 0.1
Ni 1.5
Tf 0.9 0.9 0.9
Tr 0.1
d 0.9
illum 7

newmtl lamp
Ke 5 4 3
Pe 10
bump b.png
";

const MANIFEST: &str = "name = \"fuzz\"
mesh = \"s.obj\"

[camera]
eye = [0.5, 0.5, 4.0]
target = [0.5, 0.5, 0.0]
up = [0.0, 1.0, 0.0]
vfov_deg = 40.0
aspect = 1.5

[[lights]]
position = [0.0, 3.0, 3.0]
color = [1.0, 1.0, 1.0]
intensity = 1.0
attenuation = [1.0, 0.0, 0.0]
radius = 0.1

[materials.red]
diffuse = [0.5, 0.5, 0.5]
reflectivity = 0.2

[animation]
fps = 24.0

[[instances]]
shape = \"box\"
subdivisions = 1
translate = [2.0, 0.0, 0.0]
rotate = [0.0, 1.0, 0.0, 30.0]
scale = [1.0, 2.0, 1.0]
material = { diffuse = [0.8, 0.7, 0.6], transparency = 0.5, ior = 1.3 }

[[instances.motion]]
kind = \"rotate\"
axis = [0.0, 1.0, 0.0]
degrees_per_second = 45.0
pivot = [0.0, 0.0, 0.0]

[[instances]]
mesh = \"s.obj\"
translate = [0.0, 0.0, -2.0]
scale = 0.5
";

/// SplitMix64 (the generator of `crsh_scene`'s own `rng` module, which is private).
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in `0..n` (`n > 0`).
    fn below(&mut self, n: usize) -> usize {
        ((self.next() as u128 * n as u128) >> 64) as usize
    }

    fn pick<'a, T>(&mut self, items: &'a [T]) -> &'a T {
        &items[self.below(items.len())]
    }
}

/// What a number may be replaced by.
const NUMBERS: [&str; 22] = [
    "nan",
    "NaN",
    "inf",
    "-inf",
    "-1",
    "0",
    "-0",
    "1",
    "2",
    "1e30",
    "-1e30",
    "1e19",
    "1e39",
    "1e-45",
    "0.5",
    "x",
    "",
    "1/2",
    "//",
    "#",
    "99999999999",
    "-3",
];

/// Byte ranges of the whitespace-separated tokens of `text`.
fn tokens(text: &[u8]) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut start = None;
    for (i, b) in text.iter().enumerate() {
        match (b.is_ascii_whitespace(), start) {
            (true, Some(s)) => {
                out.push((s, i));
                start = None;
            }
            (false, None) => start = Some(i),
            _ => {}
        }
    }
    if let Some(s) = start {
        out.push((s, text.len()));
    }
    out
}

/// Byte ranges of the lines of `text`, each with its `\n`.
fn lines(text: &[u8]) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut start = 0;
    for (i, &b) in text.iter().enumerate() {
        if b == b'\n' {
            out.push((start, i + 1));
            start = i + 1;
        }
    }
    if start < text.len() {
        out.push((start, text.len()));
    }
    out
}

fn splice(text: &[u8], (a, b): (usize, usize), with: &[u8]) -> Vec<u8> {
    [&text[..a], with, &text[b..]].concat()
}

/// One random mutation of `text`.
fn mutate(text: &[u8], rng: &mut Rng) -> Vec<u8> {
    let toks = tokens(text);
    let lns = lines(text);
    if toks.is_empty() || lns.is_empty() {
        let len = rng.below(16);
        return (0..len).map(|_| rng.next() as u8).collect();
    }
    match rng.below(10) {
        // Swap two tokens.
        0 => {
            let (mut x, mut y) = (*rng.pick(&toks), *rng.pick(&toks));
            if x.0 > y.0 {
                std::mem::swap(&mut x, &mut y);
            }
            if x == y {
                return text.to_vec();
            }
            [
                &text[..x.0],
                &text[y.0..y.1],
                &text[x.1..y.0],
                &text[x.0..x.1],
                &text[y.1..],
            ]
            .concat()
        }
        // Delete a token.
        1 => splice(text, *rng.pick(&toks), b""),
        // Duplicate a token.
        2 => {
            let t = *rng.pick(&toks);
            let copy = [&text[t.0..t.1], b" "].concat();
            splice(text, (t.0, t.0), &copy)
        }
        // Replace a number (or any token) by a bad value.
        3 | 4 => {
            let numeric: Vec<_> = toks
                .iter()
                .copied()
                .filter(|&(a, _)| matches!(text[a], b'0'..=b'9' | b'-' | b'.'))
                .collect();
            let t = if numeric.is_empty() || rng.below(4) == 0 {
                *rng.pick(&toks)
            } else {
                *rng.pick(&numeric)
            };
            splice(text, t, rng.pick(&NUMBERS).as_bytes())
        }
        // Truncate a line.
        5 => {
            let (a, b) = *rng.pick(&lns);
            let cut = a + rng.below(b - a);
            splice(text, (cut, b), b"\n")
        }
        // Delete or duplicate a line.
        6 => splice(text, *rng.pick(&lns), b""),
        7 => {
            let (a, b) = *rng.pick(&lns);
            let copy = text[a..b].to_vec();
            splice(text, (a, a), &copy)
        }
        // Random bytes.
        8 => {
            let at = rng.below(text.len() + 1);
            let len = 1 + rng.below(8);
            let bytes: Vec<u8> = (0..len).map(|_| rng.next() as u8).collect();
            splice(text, (at, at), &bytes)
        }
        // Truncate the file.
        _ => text[..rng.below(text.len() + 1)].to_vec(),
    }
}

/// The scratch directory of this test run.
fn scratch() -> PathBuf {
    let d = std::env::temp_dir().join(format!("crsh-scene-fuzz-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Writes `text` to a new file at `path`: rewriting a file in place makes ext4 flush it to
/// disk on close, which costs milliseconds per case.
fn write_new(path: &Path, text: &[u8]) {
    let _ = std::fs::remove_file(path);
    std::fs::write(path, text).unwrap();
}

fn env_usize(name: &str, default: usize) -> usize {
    match std::env::var(name) {
        Ok(v) => v
            .parse()
            .unwrap_or_else(|_| panic!("{name}={v} is not a number")),
        Err(_) => default,
    }
}

/// What went wrong in one case.
struct Failure {
    case: usize,
    what: String,
    files: [(String, Vec<u8>); 3],
}

/// Loads the files in `dir`: the manifest (animated, then frame 1) or the bare OBJ, checking
/// what loads. `Err` is the load error's text; a panic propagates.
fn load(dir: &Path, manifest: bool) -> Result<(), String> {
    if manifest {
        let spec = dir.join("s.toml");
        let (anim, _) =
            crsh_scene::load_animated(spec.to_str().unwrap()).map_err(|e| e.to_string())?;
        support::check_invariants(anim.scene());
        // A later frame may fail (a motion can carry vertices too far), naming the scene and
        // the instance rather than a file; only a panic counts there.
        let mut scene = anim.scene().clone();
        if anim.update(&mut scene, 1, true).is_ok() {
            support::check_invariants(&scene);
        }
    } else {
        let (scene, _) =
            crsh_scene::load_path_with_report(&dir.join("s.obj")).map_err(|e| e.to_string())?;
        support::check_invariants(&scene);
    }
    Ok(())
}

#[test]
fn mutated_scene_files_never_panic_nor_change() {
    // The loaders use rayon: from inside a one-thread pool its jobs run inline, instead of
    // waiting for a worker to wake up thousands of times on a busy machine.
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    pool.install(fuzz);
}

fn fuzz() {
    let cases = env_usize("CRSH_FUZZ_CASES", DEFAULT_CASES);
    let seed = env_usize("CRSH_FUZZ_SEED", 0) as u64;
    let first = env_usize("CRSH_FUZZ_FIRST", 0);
    let dir = scratch();
    let dir_text = dir.to_str().unwrap();
    let names = ["s.obj", "m.mtl", "s.toml"];
    let seeds = [OBJ, MTL, MANIFEST];

    // The seeds themselves load.
    for (name, text) in names.iter().zip(seeds) {
        std::fs::write(dir.join(name), text).unwrap();
    }
    load(&dir, true).expect("the manifest seed loads");
    load(&dir, false).expect("the OBJ seed loads");

    let quiet = std::panic::take_hook();
    std::panic::set_hook(Box::new(|_| {}));
    let mut failures = Vec::new();
    let (mut accepted, mut refused) = (0usize, 0usize);
    for case in first..first + cases {
        let mut rng = Rng(seed ^ (case as u64).wrapping_mul(0xA24B_AED4_963E_E407));
        let mut texts: Vec<Vec<u8>> = seeds.iter().map(|s| s.as_bytes().to_vec()).collect();
        let target = rng.below(3);
        for _ in 0..1 + rng.below(4) {
            texts[target] = mutate(&texts[target], &mut rng);
        }
        // Now and then a second file is damaged too.
        if rng.below(8) == 0 {
            let other = (target + 1 + rng.below(2)) % 3;
            texts[other] = mutate(&texts[other], &mut rng);
        }
        for (name, text) in names.iter().zip(&texts) {
            write_new(&dir.join(name), text);
        }
        let manifest = target != 0 || rng.below(2) == 0;
        let files = || {
            let t = texts.clone();
            [
                (names[0].to_string(), t[0].clone()),
                (names[1].to_string(), t[1].clone()),
                (names[2].to_string(), t[2].clone()),
            ]
        };
        match catch_unwind(AssertUnwindSafe(|| load(&dir, manifest))) {
            Ok(Ok(())) => accepted += 1,
            Ok(Err(e)) => {
                refused += 1;
                if !e.contains(dir_text) {
                    failures.push(Failure {
                        case,
                        what: format!("the error names no file: {e}"),
                        files: files(),
                    });
                }
            }
            Err(p) => {
                let msg = p
                    .downcast_ref::<String>()
                    .cloned()
                    .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
                    .unwrap_or_default();
                failures.push(Failure {
                    case,
                    what: format!("panic: {msg}"),
                    files: files(),
                });
            }
        }
        for (name, text) in names.iter().zip(&texts) {
            let now = std::fs::read(dir.join(name)).unwrap_or_default();
            if &now != text {
                failures.push(Failure {
                    case,
                    what: format!("{name} changed while loading"),
                    files: files(),
                });
            }
        }
    }
    std::panic::set_hook(quiet);
    let _ = std::fs::remove_dir_all(&dir);

    if let Some(f) = failures.first() {
        let mut report = format!(
            "{} of {cases} cases failed (seed {seed}); the first, case {}: {}\n",
            failures.len(),
            f.case,
            f.what
        );
        for (name, text) in &f.files {
            report.push_str(&format!("--- {name}\n{}\n", String::from_utf8_lossy(text)));
        }
        for f in failures.iter().skip(1).take(9) {
            report.push_str(&format!("case {}: {}\n", f.case, f.what));
        }
        panic!("{report}");
    }
    // The mutations must leave both outcomes common, or the test checks little.
    assert!(
        cases < 100 || accepted * 20 > cases && refused * 4 > cases,
        "{accepted} accepted, {refused} refused of {cases}"
    );
}
