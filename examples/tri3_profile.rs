//! The `tri3` speed case, for profiling: `tri3_profile [scan] [reps]` renders the wavy
//! sheet on a `scan x scan` confocal grid `reps` times and prints the fastest render.
use glam::Vec3;
use std::time::Instant;
use umbra::bench::mesh_scene;
use umbra::geometry::shapes::wavy_sheet;
use umbra::geometry::SceneGeometry;
use umbra::scene::{Model, Visibility};
use umbra::transport::{RenderOptions, Renderer};
fn main() {
    let arg = |i: usize, d: u32| std::env::args().nth(i).map_or(d, |s| s.parse().unwrap());
    let (scan, reps) = (arg(1, 8), arg(2, 1));
    let sheet = wavy_sheet(Vec3::new(0.0, 0.1, 0.8), 0.6, 71, 0.02, 0.3);
    let scene = mesh_scene(sheet, scan, 512, 0.004, 1.5).unwrap();
    let geom = SceneGeometry::build(&scene);
    let opts = RenderOptions {
        model: Model::Tri3,
        visibility: Visibility::None,
        subdivision: 0.15,
        ..RenderOptions::from_scene(&scene)
    };
    let r = Renderer::new(&scene, &geom, &opts).unwrap();
    let mut best = f64::INFINITY;
    let mut sum = 0.0;
    for _ in 0..reps {
        let t = Instant::now();
        let out = r.render(None).unwrap();
        best = best.min(t.elapsed().as_secs_f64());
        sum = out.data.iter().map(|&v| v as f64).sum::<f64>();
    }
    println!("best {best:.4} s  sum {sum:e}");
}
