//! Development experiment: fit the default letter T from a plane, report Chamfer.
use std::cell::RefCell;
use std::rc::Rc;
use umbra::fit::{default_schedule, fit, FitConfig, Init};
use umbra::geometry::SceneGeometry;
use umbra::scene::default::default_scene;
use umbra::scene::Model;
use umbra::transport::{RenderOptions, Renderer};

fn main() {
    let arg = |i: usize, d: &str| std::env::args().nth(i).unwrap_or(d.to_string());
    let scan: u32 = arg(1, "16").parse().unwrap();
    let target_model = arg(2, "tri3");
    let mut scene = default_scene().unwrap();
    scene.scan.nx = scan;
    scene.scan.ny = scan;
    scene.film.temporal_bins = 256;
    scene.film.bin_width_opl = 0.008;
    let geom = SceneGeometry::build(&scene);
    let opts = RenderOptions {
        model: Model::parse(&target_model).unwrap(),
        spp: 256,
        ..RenderOptions::from_scene(&scene)
    };
    let t0 = std::time::Instant::now();
    let target = Renderer::new(&scene, &geom, &opts)
        .unwrap()
        .render(None)
        .unwrap();
    eprintln!(
        "target ({target_model}) rendered in {:.1} s",
        t0.elapsed().as_secs_f64()
    );
    let truth = &scene.objects[0].mesh;
    let truth = optim::Mesh::new(
        truth
            .positions
            .iter()
            .map(|p| [p.x as f64, p.y as f64, p.z as f64])
            .collect(),
        truth.triangles.clone(),
    );
    let cfg = FitConfig {
        schedule: default_schedule(),
        init: Init::Plane,
        model: Model::Tri3,
        spp: 16,
        fit_scale: true,
        two_sided: true,
        albedo: 0.9,
        resume: false,
    };
    let out = std::path::PathBuf::from(arg(3, "/tmp/fitexp"));
    let _ = std::fs::remove_dir_all(&out);
    let progress: optim::fit::Progress =
        Rc::new(RefCell::new(|r: &optim::checkpoint::LossRecord| {
            if r.iteration % 10 == 0 {
                eprintln!(
                    "it {} stage {} loss {:.4e}",
                    r.iteration, r.stage, r.data_loss
                );
            }
            true
        }));
    let rep = fit(&scene, &target.data, &cfg, &out, progress).unwrap();
    let c = umbra::fit::metrics::chamfer(&rep.mesh, &truth, 4000);
    println!(
        "fit {:.1} s, final loss {:.4e}, scale {:.4}, chamfer {:?}",
        rep.seconds, rep.final_loss, rep.scale, c
    );
}
