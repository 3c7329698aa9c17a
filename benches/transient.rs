//! Criterion benchmarks: the time side of the speed-against-accuracy study (`umbra bench
//! accuracy` gives the error side, BENCHMARKS.md both), measured by criterion's
//! statistics instead of single timings.
//!
//! - `forward/<scene>/<method>`: one transient of each accuracy scene
//!   (`umbra::bench::accuracy::scenes`: letter, sphere, bunny-like, concave corner;
//!   confocal 16 x 16, 256 bins) by `tri3` (default subdivision, sub-triangle visibility),
//!   `mc3` at 256 spp and the multi-bounce path tracer (MIS) at 256 spp.
//! - `gradient/<scene>/<method>`: the adjoint pass for a fixed `dLoss/dH`
//!   (`umbra::bench::grad_accuracy`: tilted square, corner) by `tri3`, `mc3` and `path`
//!   replay at 256 spp.
//!
//! Run: `cargo bench --bench transient` (about 3 minutes on 2 cores). Compare methods
//! within one run; absolute times on a shared machine are noise.

use criterion::{criterion_group, criterion_main, Criterion};
use std::time::Duration;
use umbra::bench::{accuracy, grad_accuracy, with_techniques};
use umbra::geometry::SceneGeometry;
use umbra::scene::{Model, Visibility};
use umbra::transport::{RenderOptions, Renderer};

fn methods(scene: &umbra::Scene) -> Vec<(&'static str, umbra::Scene, RenderOptions)> {
    let all = with_techniques(scene, true, true, true);
    let tri3 = RenderOptions {
        model: Model::Tri3,
        visibility: Visibility::Subtriangle,
        ..RenderOptions::from_scene(scene)
    };
    let mc = |model| RenderOptions {
        model,
        spp: 256,
        ..RenderOptions::from_scene(&all)
    };
    vec![
        ("tri3", scene.clone(), tri3),
        ("mc3 256 spp", all.clone(), mc(Model::Mc3)),
        ("path 256 spp", all.clone(), mc(Model::Path)),
    ]
}

fn forward(c: &mut Criterion) {
    let mut g = c.benchmark_group("forward");
    g.sample_size(10)
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(3));
    for (name, scene) in accuracy::scenes().expect("accuracy scenes") {
        for (label, s, opts) in methods(&scene) {
            let geom = SceneGeometry::build(&s);
            let r = Renderer::new(&s, &geom, &opts).expect("renderer");
            g.bench_function(format!("{name}/{label}"), |b| {
                b.iter(|| r.render(None).expect("render"))
            });
        }
    }
    g.finish();
}

fn gradient(c: &mut Criterion) {
    let mut g = c.benchmark_group("gradient");
    g.sample_size(10)
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(3));
    for (name, scene) in grad_accuracy::scenes().expect("gradient scenes") {
        let adj = grad_accuracy::adjoint_histogram(&scene).expect("adjoint histogram");
        for (label, s, opts) in methods(&scene) {
            let geom = SceneGeometry::build(&s);
            g.bench_function(format!("{name}/{label}"), |b| {
                b.iter(|| umbra::adjoint::gradient(&s, &geom, &opts, &adj, None).expect("gradient"))
            });
        }
    }
    g.finish();
}

criterion_group!(benches, forward, gradient);
criterion_main!(benches);
