//! Typed errors of the recordings library. Every error names the file it is about.

use std::path::PathBuf;

/// What went wrong reading, writing or replaying a recording.
#[derive(Debug, thiserror::Error)]
pub enum RecordingError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: not an MCAP file (missing magic bytes)")]
    NotMcap { path: PathBuf },
    #[error("{path}: MCAP profile is {found:?}, expected \"ros2\"")]
    WrongProfile { path: PathBuf, found: String },
    #[error("{path}: truncated before any message could be read ({detail})")]
    Truncated { path: PathBuf, detail: String },
    #[error("{path}: corrupt MCAP at byte {offset}: {detail}")]
    Corrupt {
        path: PathBuf,
        offset: u64,
        detail: String,
    },
    #[error("{path}: channel {topic:?} has unknown schema {schema:?} (encoding {encoding:?})")]
    UnknownSchema {
        path: PathBuf,
        topic: String,
        schema: String,
        encoding: String,
    },
    #[error(
        "{path}: message on {topic:?} (sequence {sequence}) does not decode as {schema}: {detail}"
    )]
    Decode {
        path: PathBuf,
        topic: String,
        sequence: u64,
        schema: String,
        detail: String,
    },
    #[error("{path}: recording has no {topic:?} messages; {why}")]
    MissingTopic {
        path: PathBuf,
        topic: String,
        why: String,
    },
    #[error("{path}: cannot write MCAP: {detail}")]
    Write { path: PathBuf, detail: String },
    #[error("{path}: launch file: {detail}")]
    Launch { path: PathBuf, detail: String },
    #[error("{path}: physics: {detail}")]
    Physics { path: PathBuf, detail: String },
    #[error("{path}: shared memory: {detail}")]
    Link { path: PathBuf, detail: String },
}

impl RecordingError {
    pub(crate) fn io(path: &std::path::Path, source: std::io::Error) -> Self {
        RecordingError::Io {
            path: path.to_path_buf(),
            source,
        }
    }

    pub(crate) fn write(path: &std::path::Path, detail: impl std::fmt::Display) -> Self {
        RecordingError::Write {
            path: path.to_path_buf(),
            detail: detail.to_string(),
        }
    }
}
