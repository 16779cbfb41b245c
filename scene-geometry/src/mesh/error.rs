use std::path::PathBuf;

/// Everything that can be wrong with a mesh, a node list or a mesh spec. Each variant names
/// the file and, where there is one, the line or element.
#[derive(Debug, thiserror::Error)]
pub enum MeshError {
    #[error("{}: cannot read: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{}:{line}: {problem}", path.display())]
    Parse {
        path: PathBuf,
        line: usize,
        problem: String,
    },
    #[error("{}: missing section {section}", path.display())]
    MissingSection {
        path: PathBuf,
        section: &'static str,
    },
    #[error("{}: unsupported format: {problem}", path.display())]
    Unsupported { path: PathBuf, problem: String },
    #[error("{}:{line}: node {node}: coordinate is not finite ({value})", path.display())]
    NonFiniteCoordinate {
        path: PathBuf,
        line: usize,
        node: usize,
        value: f64,
    },
    #[error("{}:{line}: element {element}: node tag {tag} is out of range (no such node)", path.display())]
    NodeOutOfRange {
        path: PathBuf,
        line: usize,
        element: usize,
        tag: i64,
    },
    #[error(
        "{}: element {element} (line {line}): zero-volume tetrahedron (volume {volume:.3e}, edge {edge:.3e})",
        path.display()
    )]
    ZeroVolume {
        path: PathBuf,
        line: usize,
        element: usize,
        volume: f64,
        edge: f64,
    },
    #[error("{}: {problem}", path.display())]
    Invalid { path: PathBuf, problem: String },
    #[error("{}:{line}: fixed node {index} is out of range (mesh has {nodes} nodes)", path.display())]
    FixedNodeOutOfRange {
        path: PathBuf,
        line: usize,
        index: usize,
        nodes: usize,
    },
    #[error("mesh spec `{spec}`: {problem}")]
    Spec { spec: String, problem: String },
}

impl MeshError {
    pub(crate) fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        MeshError::Io {
            path: path.into(),
            source,
        }
    }
    pub(crate) fn parse(path: impl Into<PathBuf>, line: usize, problem: impl Into<String>) -> Self {
        MeshError::Parse {
            path: path.into(),
            line,
            problem: problem.into(),
        }
    }
    pub(crate) fn invalid(path: impl Into<PathBuf>, problem: impl Into<String>) -> Self {
        MeshError::Invalid {
            path: path.into(),
            problem: problem.into(),
        }
    }
}
