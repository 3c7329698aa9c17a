//! The seed paper's ablation (Royo et al. 2022, "Non-line-of-sight transient rendering",
//! the comparison of sampling techniques at equal sample counts): the time-resolved
//! radiance at one scan point, rendered by the multi-bounce path tracer with each
//! combination of laser sampling (next-event estimation to the laser spot) and
//! hidden-geometry sampling (area sampling of the hidden surfaces), BSDF sampling always
//! on as their MIS partner, against a converged reference.
//!
//! Scene: a concave corner (a plate facing the wall and a side plate at right angles,
//! 0.8 m away, so paths with interreflections arrive), one confocal scan point, a laser
//! spot of 5 cm radius (so BSDF-only paths can reach it and every variant estimates the
//! same quantity), up to 6 bounces. Error: relative L2 over the bins against the
//! reference (all techniques at `reference_factor` times the samples, other seeds).

use super::with_techniques;
use crate::error::Result;
use crate::geometry::mesh::TriMesh;
use crate::geometry::SceneGeometry;
use crate::scene::{toml_format, Model, Scene};
use crate::transport::{render, RenderOptions};
use std::path::Path;
use std::time::Instant;

/// The corner: a 0.55 x 0.3 m plate at 0.8 m facing the wall, and a side plate from it
/// back to 0.5 m.
const CORNER: &str = "v -0.15 -0.15 0.8\nv 0.4 -0.15 0.8\nv 0.4 0.15 0.8\nv -0.15 0.15 0.8\n\
                      v 0.4 -0.15 0.5\nv 0.4 0.15 0.5\n\
                      f 1 4 3 2\nf 2 3 6 5\n";

/// The ablation scene (module doc).
pub fn ablation_scene() -> Result<Scene> {
    let toml = r#"
capture_type = "confocal"
[wall]
size = [2.0, 2.0]
albedo = 0.8
[laser]
origin = [0.3, -0.4, 1.0]
spot_radius = 0.05
[scan]
resolution = [1, 1]
size = [0.05, 0.05]
center = [0.1, 0.0, 0.0]
[film]
temporal_bins = 160
bin_width_opl = 0.01
start_opl = 1.4
kernel = "gaussian"
sigma_opl = 0.01
[[objects]]
file = "corner"
albedo = 0.8
two_sided = true
[render]
model = "path"
max_bounces = 6
"#;
    toml_format::parse(toml, Path::new("<ablation scene>"), &|_| {
        TriMesh::parse_obj(CORNER, Path::new("corner.obj"))
    })
}

/// One variant of the ablation.
#[derive(Clone, Debug)]
pub struct Variant {
    pub label: &'static str,
    pub laser_sampling: bool,
    pub hidden_geometry_sampling: bool,
    /// The transient at the scan point (one value per bin).
    pub transient: Vec<f32>,
    pub seconds: f64,
    /// Relative L2 against the reference.
    pub error: f64,
}

/// The ablation's result: the reference and the four variants at `spp`.
pub struct Ablation {
    pub scene: Scene,
    pub spp: u32,
    pub reference_spp: u64,
    pub reference: Vec<f32>,
    pub variants: Vec<Variant>,
}

fn render_mean(scene: &Scene, spp: u32, seeds: std::ops::Range<u64>) -> Result<Vec<f32>> {
    let geom = SceneGeometry::build(scene);
    let n = seeds.end - seeds.start;
    let mut sum: Vec<f64> = Vec::new();
    for seed in seeds {
        let opts = RenderOptions {
            model: Model::Path,
            spp,
            seed,
            ..RenderOptions::from_scene(scene)
        };
        let t = render(scene, &geom, &opts, None)?;
        if sum.is_empty() {
            sum = vec![0.0; t.data.len()];
        }
        sum.iter_mut()
            .zip(&t.data)
            .for_each(|(s, &v)| *s += v as f64);
    }
    Ok(sum.iter().map(|s| (s / n as f64) as f32).collect())
}

/// Runs the ablation at `spp` per variant, the reference at `reference_factor` x `spp`
/// (all techniques, seeds disjoint from the variants').
pub fn run(scene: &Scene, spp: u32, reference_factor: u32) -> Result<Ablation> {
    let all = with_techniques(scene, true, true, true);
    let factor = reference_factor.max(1) as u64;
    let reference = render_mean(&all, spp, 1000..1000 + factor)?;
    let variants = [
        ("BSDF sampling only", false, false),
        ("+ laser sampling", true, false),
        ("+ hidden-geometry sampling", false, true),
        ("+ laser and hidden-geometry sampling", true, true),
    ]
    .into_iter()
    .map(|(label, laser, hidden)| {
        let s = with_techniques(scene, laser, hidden, true);
        let start = Instant::now();
        let transient = render_mean(&s, spp, 0..1)?;
        let seconds = start.elapsed().as_secs_f64();
        let error = super::rel_l2(&transient, &reference);
        Ok(Variant {
            label,
            laser_sampling: laser,
            hidden_geometry_sampling: hidden,
            transient,
            seconds,
            error,
        })
    })
    .collect::<Result<Vec<_>>>()?;
    Ok(Ablation {
        scene: scene.clone(),
        spp,
        reference_spp: factor * spp as u64,
        reference,
        variants,
    })
}

impl Ablation {
    /// OPL (m) at the centre of bin `b`.
    pub fn opl(&self, b: usize) -> f64 {
        let f = &self.scene.film;
        (f.start_opl + (b as f32 + 0.5) * f.bin_width_opl) as f64
    }

    /// CSV: OPL, the reference, then each variant.
    pub fn csv(&self) -> String {
        let mut s = String::from("opl_m,reference");
        for v in &self.variants {
            s += &format!(",{}", v.label.replace(',', ";"));
        }
        s.push('\n');
        for b in 0..self.reference.len() {
            s += &format!("{:.4},{:e}", self.opl(b), self.reference[b]);
            for v in &self.variants {
                s += &format!(",{:e}", v.transient[b]);
            }
            s.push('\n');
        }
        s
    }

    /// The chart: one panel per variant, the reference in black under it.
    pub fn write_png(&self, path: &Path) -> Result<()> {
        let series = |label: &'static str, t: &[f32]| crate::io::plot::Series {
            label,
            points: t
                .iter()
                .enumerate()
                .map(|(b, &v)| (self.opl(b), v as f64))
                .collect(),
        };
        let panels: Vec<(String, Vec<crate::io::plot::Series>)> = self
            .variants
            .iter()
            .map(|v| {
                (
                    format!("{} (rel. L2 {:.1} %)", v.label, 100.0 * v.error),
                    vec![
                        series("reference", &self.reference),
                        series("this variant", &v.transient),
                    ],
                )
            })
            .collect();
        crate::io::plot::panel_chart(
            path,
            &format!(
                "Time-resolved radiance at one scan point, {} spp each (reference: {} spp)",
                self.spp, self.reference_spp
            ),
            "optical path length (m)",
            2,
            &panels,
        )
    }
}
