//! The typed records of the store: what a job is, as the API shows it, and how a row of
//! either backend becomes one.

use super::{clip, StoreError};
use crate::progressive::RenderStats;
use crate::service::error_code::ErrorCode;
use serde::{Deserialize, Serialize};
use uuid::Uuid;

/// The five states of service-api.md.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum JobState {
    Queued,
    Running,
    Succeeded,
    Failed,
    Cancelled,
}

impl JobState {
    pub const ALL: [JobState; 5] = [
        JobState::Queued,
        JobState::Running,
        JobState::Succeeded,
        JobState::Failed,
        JobState::Cancelled,
    ];

    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            JobState::Queued => "queued",
            JobState::Running => "running",
            JobState::Succeeded => "succeeded",
            JobState::Failed => "failed",
            JobState::Cancelled => "cancelled",
        }
    }

    #[must_use]
    pub fn parse(s: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|st| st.as_str() == s)
    }

    /// Succeeded, failed or cancelled: nothing will change any more.
    #[must_use]
    pub fn is_finished(self) -> bool {
        matches!(
            self,
            JobState::Succeeded | JobState::Failed | JobState::Cancelled
        )
    }
}

/// The layers of a frame (service-api.md `GET .../frame?layer=`), in the order the
/// stream lists them.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Layer {
    Image,
    Samples,
    Distance,
    Classes,
    Objects,
}

impl Layer {
    pub const ALL: [Layer; 5] = [
        Layer::Image,
        Layer::Samples,
        Layer::Distance,
        Layer::Classes,
        Layer::Objects,
    ];

    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Layer::Image => "image",
            Layer::Samples => "samples",
            Layer::Distance => "distance",
            Layer::Classes => "classes",
            Layer::Objects => "objects",
        }
    }

    #[must_use]
    pub fn parse(s: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|l| l.as_str() == s)
    }

    /// The stored file of this layer: its PNG, or for the image with `exr` the linear EXR.
    /// Names come from this enum only, never from a request.
    #[must_use]
    pub fn file_name(self, exr: bool) -> String {
        format!("{}.{}", self.as_str(), if exr { "exr" } else { "png" })
    }
}

/// A running (or finished) render's progress, as the job object and the stream show it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Progress {
    pub iteration: u32,
    pub pixels_traced: u64,
    pub pixel_fraction: f64,
    pub elapsed_ms: u64,
    /// The latest mean perceptual distance between successive frames (null when not finite).
    pub mean_distance: Option<f64>,
    /// Estimated time left (`progressive::eta`): a central value and a range, null when
    /// unknown, and how much to trust it.
    pub eta_ms: Option<u64>,
    pub eta_low_ms: Option<u64>,
    pub eta_high_ms: Option<u64>,
    pub eta_confidence: Option<f64>,
    /// Close enough to the end that no time is given ("finishing"). Absent in progress
    /// stored before it existed.
    #[serde(default)]
    pub finishing: bool,
    /// Whether this frame's picture went through the denoiser.
    #[serde(default)]
    pub denoised: bool,
}

/// Why a job failed: a code of service-api.md "Errors" and a sentence.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct JobError {
    pub code: ErrorCode,
    pub message: String,
}

impl JobError {
    #[must_use]
    pub fn new(code: ErrorCode, message: impl Into<String>) -> Self {
        Self {
            code,
            message: message.into(),
        }
    }
}

/// One job as the API shows it (the scene document is kept in the store but not echoed).
#[derive(Clone, Debug, Serialize)]
pub struct JobRecord {
    pub id: Uuid,
    pub state: JobState,
    pub name: String,
    pub created_at: String,
    pub started_at: Option<String>,
    pub finished_at: Option<String>,
    pub progress: Option<Progress>,
    pub stats: Option<RenderStats>,
    pub error: Option<JobError>,
    /// Starts of the job so far: 1 on its first run, 2 once a worker running it was
    /// lost and another took it over (cluster.md).
    pub attempt: u32,
    /// The worker node that runs (or last ran) the job, on a shared database.
    pub worker: Option<String>,
    /// What its submission was warned of (the 201 answer's `warnings`), kept with the job
    /// so that every later reader sees it; bounded by [`bounded_warnings`]. Absent when
    /// there is nothing, as in the 201.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub warnings: Vec<String>,
    /// True once a frame was stored (`GET .../frame` can answer after a restart).
    #[serde(skip)]
    pub has_frame: bool,
    /// The token of the attempt that runs the job, or once it is finished the one whose
    /// end was recorded: on a shared database its files are that attempt's
    /// ([`super::Store::files_dir`]). Never shown.
    #[serde(skip)]
    pub attempt_token: Option<super::LeaseToken>,
}

/// A `jobs` row as both backends return it (every column is text or a 64-bit integer).
#[derive(sqlx::FromRow)]
pub(super) struct Row {
    id: String,
    name: String,
    state: String,
    created_at: String,
    started_at: Option<String>,
    finished_at: Option<String>,
    progress: Option<String>,
    stats: Option<String>,
    error: Option<String>,
    attempts: i64,
    worker: Option<String>,
    has_frame: i64,
    lease_token: Option<String>,
    warnings: Option<String>,
}

pub(super) const COLUMNS: &str =
    "id, name, state, created_at, started_at, finished_at, progress, stats, error, attempts, worker, has_frame, lease_token, warnings";

impl Row {
    pub(super) fn into_record(self) -> Result<JobRecord, StoreError> {
        let id = Uuid::parse_str(&self.id).map_err(|e| {
            StoreError::Corrupt(format!("job id {:?} is not a UUID: {e}", clip(&self.id)))
        })?;
        let state = JobState::parse(&self.state).ok_or_else(|| {
            StoreError::Corrupt(format!(
                "job {id} has the unknown state {:?}",
                clip(&self.state)
            ))
        })?;
        Ok(JobRecord {
            id,
            state,
            progress: parse_column(id, "progress", self.progress),
            stats: parse_column(id, "stats", self.stats),
            error: parse_column(id, "error", self.error),
            name: self.name,
            created_at: self.created_at,
            started_at: self.started_at,
            finished_at: self.finished_at,
            attempt: u32::try_from(self.attempts).unwrap_or(0),
            worker: self.worker,
            warnings: parse_column(id, "warnings", self.warnings).unwrap_or_default(),
            has_frame: self.has_frame != 0,
            // A damaged token reads as none: the files are then looked for in the job's
            // own folder, and the job's frames answer 404 rather than the list failing.
            attempt_token: self
                .lease_token
                .and_then(|t| Uuid::parse_str(&t).ok())
                .map(super::LeaseToken),
        })
    }
}

/// Warnings a job keeps at most: a scene with thousands of lamps facing away, or an
/// import of thousands of unsupported materials, warns once per item, and the list is
/// repeated in every answer and stream message about the job.
pub const MAX_WARNINGS: usize = 32;

/// Longest warning kept (characters): a warning may quote an imported file's own names.
pub const MAX_WARNING_CHARS: usize = 1000;

/// `warnings` as a job keeps them: at most [`MAX_WARNINGS`] lines (the last one saying how
/// many more there were), each cut to [`MAX_WARNING_CHARS`].
#[must_use]
pub fn bounded_warnings(warnings: &[String]) -> Vec<String> {
    let cut = |w: &String| super::clip_to(w, MAX_WARNING_CHARS);
    if warnings.len() <= MAX_WARNINGS {
        return warnings.iter().map(cut).collect();
    }
    let shown = MAX_WARNINGS - 1;
    let mut out: Vec<String> = warnings[..shown].iter().map(cut).collect();
    out.push(format!(
        "… and {} more warnings like these, not shown",
        warnings.len() - shown
    ));
    out
}

/// A JSON column read into its type. A damaged one loses that field (logged), not the
/// job, nor every list that includes it.
fn parse_column<T: serde::de::DeserializeOwned>(
    id: Uuid,
    column: &str,
    text: Option<String>,
) -> Option<T> {
    serde_json::from_str(&text?)
        .map_err(|e| tracing::warn!(%id, "the stored {column} cannot be read ({e}); shown as null"))
        .ok()
}

/// The text a JSON column stores (`None` stays SQL `NULL`).
pub(super) fn column_text<T: Serialize>(value: Option<&T>) -> Option<String> {
    value.and_then(|v| serde_json::to_string(v).ok())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layers_and_states_round_trip_their_names() {
        for l in Layer::ALL {
            assert_eq!(Layer::parse(l.as_str()), Some(l));
        }
        assert_eq!(Layer::parse("../image"), None);
        assert_eq!(Layer::Image.file_name(true), "image.exr");
        assert_eq!(Layer::Classes.file_name(false), "classes.png");
        for s in JobState::ALL {
            assert_eq!(JobState::parse(s.as_str()), Some(s));
        }
    }

    #[test]
    fn a_job_error_has_the_api_error_shape() {
        let e = JobError::new(ErrorCode::Poison, "gone twice");
        assert_eq!(
            serde_json::to_value(&e).unwrap(),
            serde_json::json!({"code": "poison", "message": "gone twice"})
        );
        let back: JobError = serde_json::from_str(r#"{"code":"timeout","message":"m"}"#).unwrap();
        assert_eq!(back.code, ErrorCode::Timeout);
    }

    #[test]
    fn warnings_are_bounded_in_count_and_length() {
        let few = vec!["a: b".to_owned(), "c: d".to_owned()];
        assert_eq!(bounded_warnings(&few), few);
        let long = "é".repeat(MAX_WARNING_CHARS + 5);
        let kept = bounded_warnings(std::slice::from_ref(&long));
        assert_eq!(kept[0].chars().count(), MAX_WARNING_CHARS + 1);
        assert!(kept[0].ends_with('…'));
        let many: Vec<String> = (0..100)
            .map(|k| format!("objects[{k}]: faces away"))
            .collect();
        let kept = bounded_warnings(&many);
        assert_eq!(kept.len(), MAX_WARNINGS);
        assert_eq!(kept[MAX_WARNINGS - 2], many[MAX_WARNINGS - 2]);
        assert!(kept[MAX_WARNINGS - 1].contains("69 more"), "{kept:?}");
        assert_eq!(bounded_warnings(&many[..MAX_WARNINGS]).len(), MAX_WARNINGS);
    }

    #[test]
    fn a_damaged_column_is_null_not_an_error() {
        let id = Uuid::nil();
        let p: Option<Progress> = parse_column(id, "progress", Some("{".into()));
        assert!(p.is_none());
        let e: Option<JobError> =
            parse_column(id, "error", Some(r#"{"code":"nope","message":""}"#.into()));
        assert!(e.is_none());
    }
}
