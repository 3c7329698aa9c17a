//! The `tri3` gradient against its render with box bins (the box rows of `umbra bench
//! tri3-grad`, one scene alone: for profiling the adjoint kernel).
//! `cargo run --release --example tri3_grad_box [reps] [sheet|default|sphere]`
use umbra::scene::{KernelSpec, Model};

fn main() -> umbra::Result<()> {
    let mut args = std::env::args().skip(1);
    let reps = args.next().and_then(|a| a.parse().ok()).unwrap_or(5);
    let mut scene = match args.next().as_deref().unwrap_or("sheet") {
        "default" => umbra::scene::default::default_scene()?,
        "sphere" => umbra::bench::accuracy::scene("sphere")?,
        _ => umbra::bench::tri3_speed_scene()?,
    };
    scene.film.kernel = KernelSpec::Box;
    let t = umbra::bench::grad_timing(&scene, Model::Tri3, 1, reps)?;
    println!(
        "forward {:.4} s, adjoint {:.4} s, interior {:.4} s: {:.2}x (interior {:.2}x)",
        t.forward,
        t.adjoint,
        t.interior,
        t.adjoint / t.forward,
        t.interior / t.forward
    );
    Ok(())
}
