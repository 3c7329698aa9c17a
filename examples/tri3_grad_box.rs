//! The `tri3` gradient against its render on the 10k-triangle sheet with box bins (the
//! box row of `umbra bench tri3-grad`, alone: for profiling the adjoint kernel).
//! `cargo run --release --example tri3_grad_box [reps]`
use umbra::scene::{KernelSpec, Model};

fn main() -> umbra::Result<()> {
    let reps = std::env::args()
        .nth(1)
        .and_then(|a| a.parse().ok())
        .unwrap_or(5);
    let mut scene = umbra::bench::tri3_speed_scene()?;
    scene.film.kernel = KernelSpec::Box;
    let t = umbra::bench::grad_timing(&scene, Model::Tri3, 1, reps)?;
    println!(
        "forward {:.4} s, adjoint {:.4} s, interior {:.4} s: {:.2}x",
        t.forward,
        t.adjoint,
        t.interior,
        t.adjoint / t.forward
    );
    Ok(())
}
