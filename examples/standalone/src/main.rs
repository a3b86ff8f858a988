//! `cvd-embed-example SPIRV_DIR`: the clipped Voronoi cells of a small
//! built-in input, computed on the first Vulkan device from the modules and
//! `manifest.json` that `cargo xtask spirv --out SPIRV_DIR` writes. Prints
//! `site,x,y,z,volume` per site.

use std::process::ExitCode;

fn main() -> ExitCode {
    let Some(dir) = std::env::args_os().nth(1) else {
        eprintln!("usage: cvd-embed-example SPIRV_DIR   (write it with: cargo xtask spirv --out SPIRV_DIR)");
        return ExitCode::from(2);
    };
    let (verts, tets) = cvd_embed_example::cube_mesh(2);
    let sites = cvd_embed_example::sites(40, 7);
    match cvd_embed_example::run(std::path::Path::new(&dir), &verts, &tets, &sites) {
        Ok(out) => {
            eprintln!(
                "{} on {}: {} tets, {} sites, volume sum {:.9}; unfinished after the first pass {}, after the second {}",
                out.device,
                dir.to_string_lossy(),
                tets.len(),
                sites.len(),
                out.volumes.iter().sum::<f64>(),
                out.unfinished_first,
                out.unfinished_after
            );
            println!("site,x,y,z,volume");
            for (i, (s, v)) in sites.iter().zip(&out.volumes).enumerate() {
                println!("{i},{},{},{},{v:e}", s[0], s[1], s[2]);
            }
            if out.unfinished_after > 0 {
                eprintln!("{} entries were left unfinished: their volume is missing", out.unfinished_after);
                return ExitCode::FAILURE;
            }
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("cvd-embed-example: {e}");
            ExitCode::FAILURE
        }
    }
}
