//! The launch file's choices: each is an enum parsed once, by serde, when the file is read
//! (an unknown value is reported like every other issue, with file, line, key and the
//! allowed values: see [`crate::load`]); the nodes match on the enums and never see the
//! strings. The written spelling of each variant is its `as_str`.

/// Defines a choice enum: serde spelling, `as_str`, `Display`, `FromStr` (for command-line
/// flags; its error lists the allowed values like a launch-file issue) and `ALL`.
macro_rules! choice {
    (
        $(#[$meta:meta])*
        pub enum $name:ident {
            $( $(#[$vmeta:meta])* $variant:ident = $text:literal, )+
        }
    ) => {
        $(#[$meta])*
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
        pub enum $name {
            $( $(#[$vmeta])* #[serde(rename = $text)] $variant, )+
        }

        impl $name {
            /// Every value, in the order the allowed values are listed.
            pub const ALL: &'static [$name] = &[$($name::$variant),+];

            /// The spelling in a launch file.
            pub fn as_str(self) -> &'static str {
                match self {
                    $($name::$variant => $text,)+
                }
            }
        }

        impl std::fmt::Display for $name {
            fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str(self.as_str())
            }
        }

        impl std::str::FromStr for $name {
            type Err = String;
            fn from_str(s: &str) -> Result<Self, String> {
                Self::ALL
                    .iter()
                    .copied()
                    .find(|v| v.as_str() == s)
                    .ok_or_else(|| not_allowed(s, Self::ALL.iter().map(|v| v.as_str())))
            }
        }
    };
}

/// The message of a value outside a choice's allowed values (launch-file issues and flags).
pub fn not_allowed<'a>(value: &str, allowed: impl IntoIterator<Item = &'a str>) -> String {
    let list: Vec<String> = allowed.into_iter().map(|a| format!("`{a}`")).collect();
    format!("{value:?} is not allowed; allowed: {}", list.join(", "))
}

choice! {
    /// `[scene.material] preset`: the study's material parameters.
    pub enum MaterialPreset {
        /// Lateral meniscus: E 3.50 MPa, ν 0.29.
        Lateral = "lateral",
        /// Medial meniscus: E 3.84 MPa, ν 0.26.
        Medial = "medial",
        /// `youngs_modulus` and `poisson_ratio` given in the file.
        Custom = "custom",
    }
}

choice! {
    /// `[scene.material] model`: the constitutive model of the FEM.
    pub enum MaterialModel {
        /// Linear corotational (SOFA's TetrahedronFEMForceField "large").
        Corotational = "corotational",
        /// Stable neo-Hookean (Smith et al. 2018).
        StableNeoHookean = "neo-hookean",
    }
}

choice! {
    /// `[scene.solver] kind`: the linear solver of the implicit step.
    pub enum SolverKind {
        /// SOFA's CG, no preconditioner.
        Cg = "cg",
        /// CG with the inverse 3×3 diagonal blocks.
        CgJacobi = "cg-jacobi",
        /// CG preconditioned by the rest factor.
        CgCholesky = "cg-cholesky",
        /// CG preconditioned by the rest factor, rotation-warped (SOFA's WarpPreconditioner).
        CgWarpedCholesky = "cg-warped-cholesky",
        /// CG preconditioned by a factor of the step's own system, refactored when a solve
        /// needs more than a few iterations (converged solves for offline replays).
        CgLaggedFactor = "cg-lagged-factor",
        /// faer sparse Cholesky every step.
        Direct = "direct",
    }
}

choice! {
    /// `[scene.solver] offline`: how offline replays (the gap diagnosis, `arthrosim reality`,
    /// `arthrosim replay --converged`) solve the implicit step. The live physics node ignores
    /// it and keeps `kind` (SOFA's 25-iteration CG, sized for the 1 ms budget).
    pub enum OfflineSolver {
        /// faer sparse Cholesky of the step's matrix every step: exact to round-off.
        Direct = "direct",
        /// CG preconditioned by a lagged factor of the step's own system (`cg-lagged-factor`),
        /// in double precision, every element re-rotated every step, to the relative residual
        /// `offline_tolerance`.
        Cg = "cg",
        /// The scene's own `kind` and CG settings, as the live node steps them.
        Scene = "scene",
    }
}

choice! {
    /// `[scene.solver] rotation`: how the corotational element finds its rotation.
    pub enum RotationMethod {
        /// SOFA's "large": Q of the QR decomposition of F (closed form, SOFA's default).
        Qr = "qr",
        /// Polar decomposition (nearest rotation, iterative, warm-started; rotation-invariant
        /// under shear).
        Polar = "polar",
    }
}

choice! {
    /// `[scene.solver] cg_matrix`: precision of the system matrix the CG products read.
    pub enum CgMatrix {
        /// Upper triangle packed in f32 (products accumulate in f64): half the memory the 26
        /// products of a step stream, so they run from L2 on the default meshes. Entries keep
        /// 7 digits: right for SOFA's truncated CG, not for a CG asked to converge below
        /// ~1e-6.
        F32 = "f32",
        /// Upper triangle in f64, for CG solves that must converge tightly.
        F64 = "f64",
    }
}

choice! {
    /// `[device] backend`: what the haptic node drives.
    pub enum DeviceBackend {
        /// 3D Systems Touch through OpenHaptics libHD.
        Touch = "touch",
        /// Touch emulator driven by an operator model.
        Emulated = "emulated",
        /// Proxy pose trajectory from a CSV file or a session recording.
        Replay = "replay",
    }
}

choice! {
    /// `[device] displacement_reference`: the reference pose of the displacement Δx in
    /// δ = δ_free + H·Δx.
    pub enum DisplacementReference {
        /// The proxy pose the physics step was driven toward (reproduces the physics force
        /// exactly at the same proxy position).
        Proxy = "proxy",
        /// The probe's free pose.
        ProbeFree = "probe_free",
    }
}

choice! {
    /// `[device.emulated] sites`: where the emulated operator probes.
    pub enum SiteSource {
        /// The scene mesh's probing sites.
        Scene = "scene",
        /// A flat plane's sites (no mesh loaded).
        Plane = "plane",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spellings_round_trip_and_unknown_values_list_the_allowed_ones() {
        for v in SolverKind::ALL {
            assert_eq!(v.as_str().parse::<SolverKind>(), Ok(*v));
        }
        for v in OfflineSolver::ALL {
            assert_eq!(v.as_str().parse::<OfflineSolver>(), Ok(*v));
        }
        assert_eq!(
            "joystick".parse::<DeviceBackend>().unwrap_err(),
            "\"joystick\" is not allowed; allowed: `touch`, `emulated`, `replay`"
        );
        assert_eq!(MaterialModel::StableNeoHookean.to_string(), "neo-hookean");
    }
}
