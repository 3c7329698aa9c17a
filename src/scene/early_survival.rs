//! `render.rr_early_survival`: `path`'s Russian roulette before `rr_bounces`, chosen per
//! render by a pilot (`transport::roulette`) or fixed.

/// [`RenderSettings::rr_early_survival`]: chosen per render, or fixed.
#[derive(serde::Serialize, serde::Deserialize, Clone, Copy, Debug, PartialEq, Default)]
pub enum EarlySurvival {
    /// A pilot picks it (`transport::roulette`).
    #[default]
    Auto,
    /// This survival, in `(0, 1]` (1: no roulette before `rr_bounces`).
    Fixed(f32),
}

impl EarlySurvival {
    /// `"auto"` or a number in `(0, 1]`.
    pub fn parse(text: &str) -> std::result::Result<Self, String> {
        if text.trim().eq_ignore_ascii_case("auto") {
            return Ok(EarlySurvival::Auto);
        }
        match text.trim().parse::<f32>() {
            Ok(q) => Self::fixed(q),
            Err(_) => Err(format!("'{text}' is not auto or a number in (0, 1]")),
        }
    }

    /// A fixed survival `q`, checked to lie in `(0, 1]`.
    pub fn fixed(q: f32) -> std::result::Result<Self, String> {
        if q > 0.0 && q <= 1.0 {
            Ok(EarlySurvival::Fixed(q))
        } else {
            Err(format!("must be auto or in (0, 1], got {q}"))
        }
    }
}
