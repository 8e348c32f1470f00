//! A third-party ray hasher, registered in the CPU registry and selected like a built-in one
//! with `--set hash.kind=screen_tile`: the whole `crsh` command line runs with it.
//!
//! ```sh
//! cargo run --release --example custom_hasher      # renders crsh with the screen_tile hash
//! cargo run --release --example custom_hasher -- pipelines          # lists it
//! cargo run --release --example custom_hasher -- ablate --pipelines crsh \
//!     --set hash.kind=thesis,screen_tile --set hash.tile=4,8,16 --width 128 --out ablate-hash
//! ```
//!
//! Without arguments it runs `render --pipeline crsh --set hash.kind=screen_tile --width 256
//! --reference brute --out custom_hasher.png --stats custom_hasher.json`; the stats name the
//! hasher (`"stages": {"hash": "screen_tile", ...}`) and the hits equal brute force's.
//!
//! The key is the screen tile of the ray's pixel in Morton order, then its octahedral
//! direction: rays of nearby pixels going the same way sort together. The pixel index is
//! `y * width + x`, so the hasher needs the frame width, which its constructor reads from the
//! stage context.

use crsh::crsh_core::quantize::{interleave, octahedral, quantize};
use crsh::crsh_core::{Hasher, Ray, Result, Stats};
use crsh::{Cpu, ParamInfo, RayKind, Registries, StageKind, StageVariantInfo};
use rayon::prelude::*;

// ---- the stage: under 40 lines -----------------------------------------------------------

/// Screen tile (Morton order of the tile coordinates), then octahedral direction.
struct ScreenTile {
    width: u32,
    tile: u32,
    dir_bits: u32,
}

impl ScreenTile {
    fn key(&self, r: &Ray) -> u64 {
        let x = (r.pixel % self.width / self.tile) as u64;
        let y = (r.pixel / self.width / self.tile) as u64;
        let (ub, vb) = (self.dir_bits.div_ceil(2), self.dir_bits / 2);
        let o = octahedral(r.dir);
        let (u, v) = (quantize(o.x, -1.0, 1.0, ub), quantize(o.y, -1.0, 1.0, vb));
        interleave(&[(y, 14), (x, 14)]) << self.dir_bits | interleave(&[(u, ub), (v, vb)])
    }
}

impl Hasher<Cpu> for ScreenTile {
    fn name(&self) -> &str {
        "screen_tile"
    }
    fn key_bits(&self) -> u32 {
        28 + self.dir_bits
    }
    fn hash(&self, _: &Cpu, rays: &Vec<Ray>, _: RayKind, _: &mut Stats) -> Result<Vec<u64>> {
        Ok(rays.par_iter().map(|r| self.key(r)).collect())
    }
}

fn info() -> StageVariantInfo {
    let doc = "screen tile of the ray's pixel (Morton order), then its direction (example)";
    StageVariantInfo::new(StageKind::Hash, "screen_tile", doc)
        .param(ParamInfo::int("tile", 8, 1, 1024, "tile side in pixels"))
        .param(ParamInfo::int(
            "direction_bits",
            12,
            0,
            32,
            "octahedral direction bits",
        ))
}

// ---- registration and the command line --------------------------------------------------

fn main() {
    let mut registries = Registries::builtin();
    registries
        .cpu
        .add_hasher(info(), |ctx, spec| {
            Ok(Box::new(ScreenTile {
                width: ctx.frame.width,
                tile: spec.u32_in("tile", 1..=1024)?,
                dir_bits: spec.u32_in("direction_bits", 0..=32)?,
            }))
        })
        .expect("a well-formed catalogue entry with a new name");

    let mut args: Vec<String> = std::env::args().collect();
    if args.len() == 1 {
        args.extend(
            [
                "render",
                "--pipeline",
                "crsh",
                "--set",
                "hash.kind=screen_tile",
                "--width",
                "256",
                "--reference",
                "brute",
                "--out",
                "custom_hasher.png",
                "--stats",
                "custom_hasher.json",
            ]
            .map(String::from),
        );
    }
    crsh_cli::main_with_args(registries, args)
}
