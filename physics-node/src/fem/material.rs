//! Tissue materials: the study's meniscus presets, degeneration grades and the two
//! constitutive models (linear corotational, stable neo-Hookean).

use launch_config::scene::MaterialConfig;

use super::FemError;

/// Lateral meniscus (study): E = 3.50 MPa, ν = 0.29.
pub const LATERAL_YOUNGS_MODULUS: f64 = 3.50e6;
pub const LATERAL_POISSON_RATIO: f64 = 0.29;
/// Medial meniscus (study): E = 3.84 MPa, ν = 0.26.
pub const MEDIAL_YOUNGS_MODULUS: f64 = 3.84e6;
pub const MEDIAL_POISSON_RATIO: f64 = 0.26;
/// Meniscus density, kg/m³.
pub const MENISCUS_DENSITY: f64 = 1090.0;
/// Modulus loss per degeneration grade: grade 2 = −41% (Fischenich et al. 2015), linear in grade.
pub const MODULUS_LOSS_PER_GRADE: f64 = 0.205;

/// Constitutive model of the tetrahedra: the launch file's choice, parsed once with it.
/// `Corotational` is linear elasticity in a per-element rotated frame (small strain, large
/// rotation); `StableNeoHookean` (Smith et al. 2018, in the Kim & Eberle form without the log
/// term) is hyperelastic, stiffens in large compression, rest-stable and defined for inverted
/// elements.
pub use launch_config::scene::MaterialModel;
use launch_config::scene::MaterialPreset;

/// An isotropic elastic material. SI units.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Material {
    /// Young's modulus, Pa.
    pub youngs_modulus: f64,
    /// Poisson's ratio, in (−1, 0.5).
    pub poisson_ratio: f64,
    /// Density, kg/m³.
    pub density: f64,
    pub model: MaterialModel,
}

impl Material {
    /// Lateral meniscus preset (corotational).
    pub fn lateral() -> Self {
        Material {
            youngs_modulus: LATERAL_YOUNGS_MODULUS,
            poisson_ratio: LATERAL_POISSON_RATIO,
            density: MENISCUS_DENSITY,
            model: MaterialModel::Corotational,
        }
    }

    /// Medial meniscus preset (corotational).
    pub fn medial() -> Self {
        Material {
            youngs_modulus: MEDIAL_YOUNGS_MODULUS,
            poisson_ratio: MEDIAL_POISSON_RATIO,
            density: MENISCUS_DENSITY,
            model: MaterialModel::Corotational,
        }
    }

    /// Preset by name: `lateral` or `medial`.
    pub fn preset(preset: MaterialPreset) -> Result<Self, FemError> {
        match preset {
            MaterialPreset::Lateral => Ok(Self::lateral()),
            MaterialPreset::Medial => Ok(Self::medial()),
            MaterialPreset::Custom => Err(FemError::Material(
                "preset `custom` has no parameters of its own (give youngs_modulus and \
                 poisson_ratio)"
                    .into(),
            )),
        }
    }

    pub fn with_model(mut self, model: MaterialModel) -> Self {
        self.model = model;
        self
    }

    /// Modulus factor of a degeneration grade in 0..=2: 1 − 0.205·grade (grade 2 = −41%).
    pub fn degeneration_factor(grade: f64) -> Result<f64, FemError> {
        if !grade.is_finite() || !(0.0..=2.0).contains(&grade) {
            return Err(FemError::Material(format!(
                "degeneration grade {grade} outside 0..=2"
            )));
        }
        Ok(1.0 - MODULUS_LOSS_PER_GRADE * grade)
    }

    /// This material with its modulus scaled for a degeneration grade (0, 1, 2 or between).
    pub fn degenerated(mut self, grade: f64) -> Result<Self, FemError> {
        self.youngs_modulus *= Self::degeneration_factor(grade)?;
        Ok(self)
    }

    /// Builds the material of a scene's `[scene.material]` section: preset, then by-hand
    /// overrides of E and ν, then degeneration grade and modulus scale.
    pub fn from_config(cfg: &MaterialConfig) -> Result<Self, FemError> {
        let model = cfg.model;
        let mut m = if cfg.preset == MaterialPreset::Custom {
            let (Some(e), Some(nu)) = (cfg.youngs_modulus, cfg.poisson_ratio) else {
                return Err(FemError::Material(
                    "preset `custom` needs both youngs_modulus and poisson_ratio".into(),
                ));
            };
            Material {
                youngs_modulus: e,
                poisson_ratio: nu,
                density: cfg.density,
                model,
            }
        } else {
            Self::preset(cfg.preset)?
        };
        if let Some(e) = cfg.youngs_modulus {
            m.youngs_modulus = e;
        }
        if let Some(nu) = cfg.poisson_ratio {
            m.poisson_ratio = nu;
        }
        m.density = cfg.density;
        m.model = model;
        if !cfg.modulus_scale.is_finite() || cfg.modulus_scale <= 0.0 {
            return Err(FemError::Material(format!(
                "modulus_scale must be > 0, got {}",
                cfg.modulus_scale
            )));
        }
        m.youngs_modulus *= cfg.modulus_scale;
        let m = m.degenerated(cfg.degeneration_grade)?;
        m.validate()?;
        Ok(m)
    }

    /// Checks E > 0, −1 < ν < 0.5, density > 0, all finite.
    pub fn validate(&self) -> Result<(), FemError> {
        if !self.youngs_modulus.is_finite() || self.youngs_modulus <= 0.0 {
            return Err(FemError::Material(format!(
                "Young's modulus must be > 0 Pa, got {}",
                self.youngs_modulus
            )));
        }
        if !self.poisson_ratio.is_finite()
            || self.poisson_ratio >= 0.5
            || self.poisson_ratio <= -1.0
        {
            return Err(FemError::Material(format!(
                "Poisson's ratio must be in (-1, 0.5), got {}",
                self.poisson_ratio
            )));
        }
        if !self.density.is_finite() || self.density <= 0.0 {
            return Err(FemError::Material(format!(
                "density must be > 0 kg/m³, got {}",
                self.density
            )));
        }
        Ok(())
    }

    /// Lamé parameters (μ, λ).
    pub fn lame(&self) -> (f64, f64) {
        let e = self.youngs_modulus;
        let nu = self.poisson_ratio;
        let mu = e / (2.0 * (1.0 + nu));
        let lambda = e * nu / ((1.0 + nu) * (1.0 - 2.0 * nu));
        (mu, lambda)
    }
}

/// Largest modulus factor the strain-stiffening law gives (bounds the stiffness a few
/// crushed elements under the probe tip can reach, which keeps the implicit step and the
/// warped compliance well conditioned).
pub const MAX_STIFFENING_FACTOR: f64 = 50.0;

/// Strain stiffening of the tissue (Fung-type exponential secant modulus): an element's
/// modulus is E · exp(rate · ε_eq), with ε_eq its von Mises equivalent small strain in the
/// corotated frame, capped at [`MAX_STIFFENING_FACTOR`]. Collagenous tissue stiffens as its
/// fibres straighten under load (Fung 1967); the rate is fitted to measured probing (the
/// cadaver force–displacement table), see `launch/default.toml`. rate = 0: linear.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StrainStiffening {
    /// Exponential rate per unit equivalent strain, ≥ 0.
    pub rate: f64,
}

impl StrainStiffening {
    pub const NONE: StrainStiffening = StrainStiffening { rate: 0.0 };

    pub fn new(rate: f64) -> Result<Self, FemError> {
        if !(rate.is_finite() && rate >= 0.0) {
            return Err(FemError::Material(format!(
                "strain_stiffening must be finite and ≥ 0, got {rate}"
            )));
        }
        Ok(StrainStiffening { rate })
    }

    pub fn is_active(&self) -> bool {
        self.rate > 0.0
    }

    /// Modulus factor at equivalent strain `eps_eq` (≥ 1).
    #[inline]
    pub fn factor(&self, eps_eq: f64) -> f64 {
        if self.rate <= 0.0 || !eps_eq.is_finite() {
            return 1.0;
        }
        (self.rate * eps_eq.max(0.0))
            .exp()
            .min(MAX_STIFFENING_FACTOR)
    }

    /// von Mises equivalent strain of the small strain ε = sym(RᵀF) − I:
    /// √(2/3 · dev ε : dev ε).
    #[inline]
    pub fn equivalent_strain(f: &nalgebra::Matrix3<f64>, rot: &nalgebra::Matrix3<f64>) -> f64 {
        let rf = rot.transpose() * f;
        let mut eps = (rf + rf.transpose()) * 0.5 - nalgebra::Matrix3::identity();
        let mean = eps.trace() / 3.0;
        for i in 0..3 {
            eps[(i, i)] -= mean;
        }
        (2.0 / 3.0 * eps.norm_squared()).sqrt()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_and_grades() {
        let l = Material::lateral();
        assert_eq!(l.youngs_modulus, 3.50e6);
        assert_eq!(l.poisson_ratio, 0.29);
        assert_eq!(l.density, 1090.0);
        let m = Material::medial();
        assert_eq!((m.youngs_modulus, m.poisson_ratio), (3.84e6, 0.26));
        let g2 = l.degenerated(2.0).unwrap();
        assert!((g2.youngs_modulus - 3.50e6 * 0.59).abs() < 1e-6);
        let g1 = l.degenerated(1.0).unwrap();
        assert!((g1.youngs_modulus - 3.50e6 * 0.795).abs() < 1e-6);
        assert!(l.degenerated(3.0).is_err());
    }

    #[test]
    fn config_errors_are_clear() {
        let mut cfg = MaterialConfig::default();
        assert_eq!(Material::from_config(&cfg).unwrap(), Material::lateral());
        // Unknown presets and models cannot reach here: they are launch-file parse errors.
        cfg.preset = MaterialPreset::Medial;
        cfg.model = MaterialModel::StableNeoHookean;
        cfg.poisson_ratio = Some(0.5);
        let e = Material::from_config(&cfg).unwrap_err().to_string();
        assert!(e.contains("Poisson"), "{e}");
        cfg.poisson_ratio = None;
        cfg.youngs_modulus = Some(0.0);
        let e = Material::from_config(&cfg).unwrap_err().to_string();
        assert!(e.contains("Young"), "{e}");
        cfg.youngs_modulus = Some(1e6);
        cfg.degeneration_grade = 2.0;
        let m = Material::from_config(&cfg).unwrap();
        assert_eq!(m.model, MaterialModel::StableNeoHookean);
        assert!((m.youngs_modulus - 0.59e6).abs() < 1e-6);
        assert_eq!(m.poisson_ratio, 0.26);
        cfg.preset = MaterialPreset::Custom;
        assert!(Material::from_config(&cfg).is_err());
    }
}
