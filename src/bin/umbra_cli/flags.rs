//! The render options shared by `umbra render`, `grad` and `gradcheck`: one set of flags,
//! applied through the library's one gate ([`umbra::transport::gate::Overrides`]), so
//! the three commands (and Python, which fills the same struct) accept and refuse the
//! same values with the same messages.

use umbra::transport::gate::Overrides;

#[derive(clap::Args, Clone, Debug, Default)]
pub struct RenderFlags {
    /// Light-transport model: tri3 (deterministic per-triangle three-bounce), mc3 (Monte
    /// Carlo three-bounce), path (multi-bounce) or auto (the cheapest accurate enough).
    /// Default: the scene's.
    #[arg(long)]
    pub model: Option<String>,
    /// Samples per measurement (overrides the scene).
    #[arg(long, allow_negative_numbers = true)]
    pub spp: Option<i64>,
    /// Random seed (overrides the scene).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Longest path in bounces, laser spot and sensor point included (3 = one hidden
    /// bounce); -1 for unbounded. Overrides the scene.
    #[arg(long, allow_negative_numbers = true)]
    pub max_depth: Option<i64>,
    /// Override the scene's laser sampling (NEE to the laser spot): true or false.
    #[arg(long)]
    pub laser_sampling: Option<bool>,
    /// Override hidden-geometry (area) sampling: true or false.
    #[arg(long)]
    pub hidden_geometry_sampling: Option<bool>,
    /// Override BSDF (cosine) sampling: true or false. With hidden-geometry sampling
    /// also on, the two are combined by multiple importance sampling.
    #[arg(long)]
    pub bsdf_sampling: Option<bool>,
    /// tri3: shadow rays: none, centroid or subtriangle.
    #[arg(long)]
    pub visibility: Option<String>,
    /// tri3: subdivision threshold: largest h²/(r·w) of a sub-triangle (edge h, height
    /// above the wall r, bin width w), i.e. the OPL curvature across it in bins.
    #[arg(long)]
    pub subdivision: Option<f32>,
    /// auto: the relative error the chosen model may leave (e.g. 0.01).
    #[arg(long)]
    pub max_error: Option<f32>,
    /// Test the laser -> laser spot and sensor point -> detector lines for occlusion by
    /// hidden objects (default true, as mitransient): false skips the two rays per
    /// measurement when you know they are clear.
    #[arg(long)]
    pub visible_legs: Option<bool>,
    /// Gradients (grad, gradcheck, fit): add the visibility boundary terms, the part of
    /// a vertex gradient carried by shadows moving across hidden surfaces (default
    /// true); false gives the interior derivative alone (faster where nothing occludes).
    #[arg(long)]
    pub boundary_terms: Option<bool>,
    /// path: the probability that a path goes on past each vertex before rr_bounces
    /// (Russian roulette from the first hidden vertex on): auto (default, the scene's
    /// render.rr_early_survival) lets a pilot pick it per render; 1 = every path goes on.
    #[arg(long)]
    pub rr_early_survival: Option<String>,
}

impl RenderFlags {
    pub fn overrides(&self) -> Overrides {
        Overrides {
            model: self.model.clone(),
            spp: self.spp,
            seed: self.seed,
            max_depth: self.max_depth,
            laser_sampling: self.laser_sampling,
            hidden_geometry_sampling: self.hidden_geometry_sampling,
            bsdf_sampling: self.bsdf_sampling,
            visibility: self.visibility.clone(),
            subdivision: self.subdivision,
            max_error: self.max_error,
            visible_legs: self.visible_legs,
            boundary_terms: self.boundary_terms,
            rr_early_survival: self.rr_early_survival.clone(),
        }
    }
}

/// A count of 1 or more (`--time-bin 0` used to run as 1 without a word).
pub fn at_least_one(s: &str) -> Result<usize, String> {
    match s.parse::<usize>() {
        Ok(0) => Err("must be at least 1".into()),
        Ok(k) => Ok(k),
        Err(e) => Err(format!("'{s}' is not a whole number: {e}")),
    }
}
