//! Load-time transform x' = R · (s · x) + t, matching `launch_config::scene::TransformConfig`.

use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};

use super::{MeshError, SurfaceMesh, TetMesh};

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Transform {
    pub scale: f64,
    pub rotation: Rotation3<f64>,
    pub translation: Vector3<f64>,
}

impl Transform {
    pub fn identity() -> Self {
        Transform {
            scale: 1.0,
            rotation: Rotation3::identity(),
            translation: Vector3::zeros(),
        }
    }

    /// Rotation in degrees, extrinsic x then y then z: R = Rz · Ry · Rx.
    pub fn from_config(cfg: &launch_config::scene::TransformConfig) -> Result<Self, MeshError> {
        let bad = |what: &str| MeshError::Spec {
            spec: format!("{cfg:?}"),
            problem: what.into(),
        };
        if !cfg.scale.is_finite() || cfg.scale == 0.0 {
            return Err(bad("scale must be finite and non-zero"));
        }
        if cfg
            .rotation_deg
            .iter()
            .chain(&cfg.translation)
            .any(|v| !v.is_finite())
        {
            return Err(bad("rotation and translation must be finite"));
        }
        let [rx, ry, rz] = cfg.rotation_deg.map(f64::to_radians);
        let rotation = Rotation3::from_axis_angle(&Vector3::z_axis(), rz)
            * Rotation3::from_axis_angle(&Vector3::y_axis(), ry)
            * Rotation3::from_axis_angle(&Vector3::x_axis(), rx);
        Ok(Transform {
            scale: cfg.scale,
            rotation,
            translation: Vector3::from(cfg.translation),
        })
    }

    /// The launch-file form: rotation as extrinsic x, y, z degrees (R = Rz · Ry · Rx).
    pub fn to_config(&self) -> launch_config::scene::TransformConfig {
        let (rx, ry, rz) = self.rotation.euler_angles();
        launch_config::scene::TransformConfig {
            scale: self.scale,
            rotation_deg: [rx.to_degrees(), ry.to_degrees(), rz.to_degrees()],
            translation: self.translation.into(),
        }
    }

    /// `other` after `self`: x ↦ other(self(x)).
    pub fn then(&self, other: &Transform) -> Transform {
        Transform {
            scale: self.scale * other.scale,
            rotation: other.rotation * self.rotation,
            translation: other.rotation * self.translation * other.scale + other.translation,
        }
    }

    pub fn from_isometry(iso: &Isometry3<f64>) -> Self {
        Transform {
            scale: 1.0,
            rotation: iso.rotation.to_rotation_matrix(),
            translation: iso.translation.vector,
        }
    }

    pub fn isometry(&self) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::from(self.translation),
            UnitQuaternion::from_rotation_matrix(&self.rotation),
        )
    }

    pub fn apply(&self, p: &Point3<f64>) -> Point3<f64> {
        self.rotation * Point3::from(p.coords * self.scale) + self.translation
    }

    pub fn linear(&self) -> Matrix3<f64> {
        self.rotation.matrix() * self.scale
    }

    /// Transforms a tet mesh; a mirroring transform (negative scale) reorders the tets so
    /// they stay positive.
    pub fn apply_tets(&self, mesh: &mut TetMesh) {
        for p in &mut mesh.nodes {
            *p = self.apply(p);
        }
        if self.scale < 0.0 {
            mesh.orient_positive();
        }
    }

    /// Transforms a surface; a mirroring transform flips the triangles so they stay
    /// counter-clockwise seen from outside.
    pub fn apply_surface(&self, surface: &mut SurfaceMesh) {
        for p in &mut surface.vertices {
            *p = self.apply(p);
        }
        if self.scale < 0.0 {
            for t in &mut surface.triangles {
                t.swap(1, 2);
            }
        }
    }
}
