//! One row of `umbra bench grad` / `umbra bench tri3-grad` alone (gradient against render,
//! interleaved repetitions), for profiling an adjoint.
//! `cargo run --release --example grad_ratio [reps] [scene] [model] [spp] [box|gaussian]`;
//! scenes: `grad` (bench grad's letter), `plate` (its letter before a plate), `default`,
//! `sphere` (the accuracy sphere), `sheet` (the 10k-triangle sheet).
use umbra::scene::{KernelSpec, Model};

fn main() -> umbra::Result<()> {
    let mut args = std::env::args().skip(1);
    let reps = args.next().and_then(|a| a.parse().ok()).unwrap_or(5);
    let mut scene = match args.next().as_deref().unwrap_or("sheet") {
        "grad" => umbra::bench::grad_scene()?,
        "plate" => umbra::bench::grad_scene_occluded()?,
        "default" => umbra::scene::default::default_scene()?,
        "sphere" => umbra::bench::accuracy::scene("sphere")?,
        _ => umbra::bench::tri3_speed_scene()?,
    };
    let model = Model::parse(args.next().as_deref().unwrap_or("tri3"))
        .ok_or_else(|| umbra::Error::Invalid("model: tri3, mc3 or path".into()))?;
    let spp = args.next().and_then(|a| a.parse().ok()).unwrap_or(1);
    match args.next().as_deref() {
        Some("box") => scene.film.kernel = KernelSpec::Box,
        Some("gaussian") => {
            scene.film.kernel = KernelSpec::Gaussian {
                sigma_opl: 1.5 * scene.film.bin_width_opl,
            }
        }
        _ if model == Model::Tri3 => scene.film.kernel = KernelSpec::Box,
        _ => {}
    }
    let t = umbra::bench::grad_timing(&scene, model, spp, reps)?;
    println!("forward s | adjoint s | interior s | adjoint / forward | interior / forward");
    println!("{}", t.ratio_cells());
    Ok(())
}
