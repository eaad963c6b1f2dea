//! Validation of a [`super::doc`] document into a [`super::Scene`]: collects every problem
//! with its JSON path. Owned by issue #2's scene work.

use super::Scene;

/// Where a document came from: decides whether `obj` paths may be read.
#[derive(Clone, Debug)]
pub enum SceneOrigin {
    /// A file on the command line; `obj` paths resolve inside this folder only.
    File { dir: std::path::PathBuf },
    /// A network request: `obj` objects are refused (no request reads server files).
    Request,
}

/// Size limits checked before any work starts (a server sets its own).
#[derive(Clone, Copy, Debug)]
pub struct Limits {
    pub max_width: u32,
    pub max_height: u32,
    pub max_pixels: u64,
    /// `samples_per_pixel × width × height` upper bound.
    pub max_sample_budget: u64,
    pub max_objects: usize,
    pub max_triangles: usize,
    pub max_samples_per_pixel: u32,
    pub max_bounces: u32,
}

impl Limits {
    /// What the command line accepts: large but still bounded.
    #[must_use]
    pub fn command_line() -> Self {
        Self {
            max_width: 16384,
            max_height: 16384,
            max_pixels: 64 << 20,
            max_sample_budget: 1 << 40,
            max_objects: 1_000_000,
            max_triangles: 20_000_000,
            max_samples_per_pixel: 1 << 20,
            max_bounces: 1024,
        }
    }
}

/// One problem in a document, named by its JSON path (`objects[3].radius`).
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct Problem {
    pub path: String,
    pub message: String,
}

impl std::fmt::Display for Problem {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if self.path.is_empty() {
            write!(f, "{}", self.message)
        } else {
            write!(f, "{}: {}", self.path, self.message)
        }
    }
}

/// Why a document was refused; decides the HTTP status in the service.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SceneErrorKind {
    /// Not JSON at all (HTTP 400 `invalid_json`).
    InvalidJson,
    /// JSON, but not a valid scene (HTTP 422 `invalid_scene`).
    InvalidScene,
    /// Valid, but above a limit (HTTP 413/422 `too_large`); the message names the limit.
    TooLarge,
}

/// Every problem of a refused document; the first is the headline.
#[derive(Clone, Debug, thiserror::Error)]
#[error("{}", .problems.first().map(ToString::to_string).unwrap_or_default())]
pub struct SceneError {
    pub kind: SceneErrorKind,
    pub problems: Vec<Problem>,
}

/// Parses and validates a scene document.
pub fn parse_scene(json: &str, origin: &SceneOrigin, limits: &Limits) -> Result<Scene, SceneError> {
    let _ = (json, origin, limits);
    todo!("issue #2: scene validation")
}
