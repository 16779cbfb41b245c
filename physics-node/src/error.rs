//! Errors of the simulation (scene, probe model, numerics). Mesh and FEM errors are wrapped
//! as text with the stage that failed, so this type does not depend on their shapes.

#[derive(Debug, thiserror::Error)]
pub enum PhysicsError {
    #[error("scene: {0}")]
    Config(String),
    #[error("{path}: cannot read: {detail}")]
    Io { path: String, detail: String },
    #[error("{path}:{line}: {detail}")]
    Parse {
        path: String,
        line: usize,
        detail: String,
    },
    #[error("mesh: {0}")]
    Mesh(String),
    #[error("fem: {0}")]
    Fem(String),
    /// A non-finite value appeared in the state; the step was not committed.
    #[error("numerical failure at t = {time:.4} s: {detail}")]
    Numerical { time: f64, detail: String },
}
