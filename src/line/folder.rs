//! A file of an `inspect --out` folder that cannot be read or written: one line naming it.

use std::path::{Path, PathBuf};

/// A file of the line's folder that cannot be read or written: `PATH: problem`.
#[derive(Debug, thiserror::Error)]
#[error("{}: {problem}", .path.display())]
pub struct FolderError {
    /// The file or folder.
    pub path: PathBuf,
    /// What is wrong with it.
    pub problem: FolderProblem,
}

/// What is wrong with a file of the line's folder.
#[derive(Debug, thiserror::Error)]
pub enum FolderProblem {
    /// It cannot be read or written.
    #[error(transparent)]
    Io(#[from] std::io::Error),
    /// It is not the JSON it should be.
    #[error(transparent)]
    Json(#[from] serde_json::Error),
    /// An ENVI file that cannot be read or written (boxed: keeps the error small).
    #[error(transparent)]
    Envi(Box<crate::io::EnviError>),
    /// The folder has no results log.
    #[error("no results log (is this an `inspect --out` folder?)")]
    NoResultsLog,
    /// The folder has neither a status snapshot nor a results log.
    #[error("no {0} nor results.jsonl (not a `filmscope inspect --out` folder)")]
    NotALineFolder(&'static str),
    /// A file larger than it can be.
    #[error("{len} bytes, more than a snapshot holds ({max})")]
    TooLarge {
        /// Its size, bytes.
        len: u64,
        /// The most it may hold, bytes.
        max: u64,
    },
}

impl From<crate::io::EnviError> for FolderProblem {
    fn from(e: crate::io::EnviError) -> Self {
        Self::Envi(Box::new(e))
    }
}

impl FolderError {
    /// `problem` of `path`.
    pub fn new(path: &Path, problem: impl Into<FolderProblem>) -> Self {
        Self {
            path: path.to_path_buf(),
            problem: problem.into(),
        }
    }
}

impl From<super::stream::StreamError> for FolderError {
    fn from(e: super::stream::StreamError) -> Self {
        match e {
            super::stream::StreamError::Io { path, cause } => Self::new(&path, cause),
        }
    }
}
