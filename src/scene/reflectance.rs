//! How a hidden surface reflects: Lambertian, or retroreflective with an angular
//! falloff (DESIGN §2; `tri3` confocal only, `transport::gate`).

/// How a hidden surface reflects.
#[derive(serde::Serialize, serde::Deserialize, Clone, Copy, Debug, Default, PartialEq)]
pub enum Reflectance {
    /// Lambertian, `f = ρ/π`.
    #[default]
    Lambertian,
    /// Retroreflective, in the confocal idealisation of the LCT paper (O'Toole et al.
    /// 2018, eq. for retroreflective objects): light returns to the wall point it came
    /// from, so the return leg's `cos θ_x cos θ_wall / r²` becomes a constant (1/m²) and
    /// the signal falls as `1/r²` instead of `1/r⁴`. Confocal capture and `tri3` only (a
    /// perfect retroreflector sends nothing to a sensor point away from the laser spot).
    ///
    /// `falloff` is the sheeting's angular falloff: the returned light is scaled by
    /// `cos^m θ_x` (`m = falloff`, 0 to [`MAX_RETRO_FALLOFF`]; `θ_x` the entrance angle
    /// at the surface). Real retroreflective sheeting returns less light at oblique
    /// entrance (its retroreflection coefficient roughly halves by 30–40°: `m` ≈ 2–4;
    /// the Stanford captures' fits choose 8–16 for the sign and the resolution charts
    /// and 0–2 for the rest, docs/BASELINES.md); `m = 0` is the ideal retroreflector.
    Retroreflective { falloff: f32 },
}

/// The largest angular falloff exponent of [`Reflectance::Retroreflective`] (`cos^16` is
/// 0.5 at 16°: a narrower lobe than any sheeting's).
pub const MAX_RETRO_FALLOFF: f32 = 16.0;

impl Reflectance {
    /// The ideal retroreflector (no angular falloff).
    pub const RETRO: Reflectance = Reflectance::Retroreflective { falloff: 0.0 };

    pub fn parse(s: &str) -> Option<Reflectance> {
        match s {
            "lambertian" | "diffuse" => Some(Reflectance::Lambertian),
            "retroreflective" => Some(Reflectance::RETRO),
            _ => None,
        }
    }

    pub fn is_retro(self) -> bool {
        matches!(self, Reflectance::Retroreflective { .. })
    }

    /// The angular falloff exponent `m` (0 for Lambertian and the ideal retroreflector).
    pub fn falloff(self) -> f32 {
        match self {
            Reflectance::Retroreflective { falloff } => falloff,
            Reflectance::Lambertian => 0.0,
        }
    }

    /// This reflectance with the falloff exponent `m` ([`MAX_RETRO_FALLOFF`] at most),
    /// or why not: `what` names the field in the message.
    pub fn with_falloff(self, m: f32, what: &str) -> std::result::Result<Reflectance, String> {
        match self {
            _ if !(0.0..=MAX_RETRO_FALLOFF).contains(&m) => Err(format!(
                "{what} = {m}: the angular falloff exponent is a number from 0 to {MAX_RETRO_FALLOFF}"
            )),
            Reflectance::Retroreflective { .. } => Ok(Reflectance::Retroreflective { falloff: m }),
            Reflectance::Lambertian if m == 0.0 => Ok(self),
            Reflectance::Lambertian => Err(format!(
                "{what} = {m} is for a retroreflective surface, and this one is lambertian"
            )),
        }
    }
}
