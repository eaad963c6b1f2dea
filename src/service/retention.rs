//! Retention: finished jobs are forgotten (record and files, as `DELETE` does) once there
//! are too many, they are too old, or their files take too many bytes, so the data folder
//! does not grow for ever. Queued and running jobs are never touched; the newest finished
//! jobs are kept first.
//!
//! [`to_forget`] is the policy (pure); [`run`] applies it every [`PERIOD`] and at start-up.

use super::jobs::{DeleteOutcome, Jobs};
use std::path::{Path, PathBuf};
use std::time::Duration;
use time::OffsetDateTime;
use uuid::Uuid;

/// How often the policy is applied.
pub const PERIOD: Duration = Duration::from_secs(60);

/// What is kept (`serve --keep-jobs N --keep-days D --keep-bytes B`); `None` = no limit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Retention {
    pub max_jobs: Option<usize>,
    pub max_age: Option<Duration>,
    pub max_bytes: Option<u64>,
}

impl Default for Retention {
    /// 1000 finished jobs, 30 days, 10 GB: at most ~540 finished 1600×1200 jobs (18.4 MB
    /// each on disk, README "Bytes on disk"), far more of the viewer's usual sizes.
    fn default() -> Self {
        Self {
            max_jobs: Some(1000),
            max_age: Some(Duration::from_secs(30 * 24 * 3600)),
            max_bytes: Some(10_000_000_000),
        }
    }
}

/// A finished job as the policy sees it.
#[derive(Clone, Debug, PartialEq)]
pub struct Finished {
    pub id: Uuid,
    pub finished_at: Option<OffsetDateTime>,
    pub bytes: u64,
}

/// The jobs to forget, given the finished jobs newest first: walking from the newest, a
/// job is kept while the count and the bytes so far stay within the limits and it is not
/// older than the age limit; every job after the first one that is not kept goes too (so
/// what remains is always the newest ones).
#[must_use]
pub fn to_forget(newest_first: &[Finished], policy: &Retention, now: OffsetDateTime) -> Vec<Uuid> {
    let mut bytes = 0u64;
    let cut = newest_first.iter().enumerate().position(|(k, j)| {
        bytes = bytes.saturating_add(j.bytes);
        let too_many = policy.max_jobs.is_some_and(|m| k >= m);
        let too_big = policy.max_bytes.is_some_and(|m| bytes > m);
        let too_old = match (policy.max_age, j.finished_at) {
            (Some(age), Some(at)) => (now - at).unsigned_abs() > age && now > at,
            _ => false,
        };
        too_many || too_big || too_old
    });
    cut.map_or_else(Vec::new, |c| {
        newest_first[c..].iter().map(|j| j.id).collect()
    })
}

/// Bytes of the files in a job's folder and its sub-folders (the kept iterations), 0
/// when it has none. Symbolic links are not followed.
fn folder_bytes(dir: &Path) -> u64 {
    std::fs::read_dir(dir).map_or(0, |rd| {
        rd.filter_map(Result::ok)
            .filter_map(|e| e.metadata().ok().map(|m| (e.path(), m)))
            .map(|(path, m)| {
                if m.is_dir() {
                    folder_bytes(&path)
                } else if m.is_file() {
                    m.len()
                } else {
                    0
                }
            })
            .sum()
    })
}

/// Applies the policy once; returns how many jobs were forgotten.
pub async fn apply(jobs: &Jobs, jobs_dir: &Path, policy: &Retention) -> usize {
    let finished = match jobs.finished_newest_first().await {
        Ok(f) => f,
        Err(e) => {
            tracing::warn!("retention: cannot list the finished jobs: {e}");
            return 0;
        }
    };
    let dir = jobs_dir.to_path_buf();
    let seen: Vec<Finished> = tokio::task::spawn_blocking(move || {
        finished
            .into_iter()
            .map(|(id, finished_at)| Finished {
                id,
                finished_at,
                bytes: folder_bytes(&dir.join(id.hyphenated().to_string())),
            })
            .collect()
    })
    .await
    .unwrap_or_default();
    let mut forgotten = 0;
    for id in to_forget(&seen, policy, OffsetDateTime::now_utc()) {
        match jobs.delete(id).await {
            Ok(DeleteOutcome::Deleted) => {
                forgotten += 1;
                tracing::info!(%id, "retention: job forgotten");
            }
            Ok(_) => {}
            Err(e) => tracing::warn!(%id, "retention: cannot forget the job: {e}"),
        }
    }
    forgotten
}

/// Applies the policy now and every [`PERIOD`] until `stop`.
pub async fn run(
    jobs: Jobs,
    jobs_dir: PathBuf,
    policy: Retention,
    stop: tokio_util::sync::CancellationToken,
) {
    if policy.max_jobs.is_none() && policy.max_age.is_none() && policy.max_bytes.is_none() {
        return;
    }
    loop {
        apply(&jobs, &jobs_dir, &policy).await;
        tokio::select! {
            () = stop.cancelled() => return,
            () = tokio::time::sleep(PERIOD) => {}
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn job(n: u128, days_ago: i64, bytes: u64, now: OffsetDateTime) -> Finished {
        Finished {
            id: Uuid::from_u128(n),
            finished_at: Some(now - time::Duration::days(days_ago)),
            bytes,
        }
    }

    const NONE: Retention = Retention {
        max_jobs: None,
        max_age: None,
        max_bytes: None,
    };

    #[test]
    fn a_jobs_bytes_include_its_kept_iterations() {
        let dir = tempfile::tempdir().unwrap();
        assert_eq!(super::folder_bytes(&dir.path().join("none")), 0);
        std::fs::write(dir.path().join("image.png"), [0u8; 10]).unwrap();
        std::fs::create_dir(dir.path().join("iterations")).unwrap();
        std::fs::write(dir.path().join("iterations/0001-image.png"), [0u8; 7]).unwrap();
        assert_eq!(super::folder_bytes(dir.path()), 17);
    }

    #[test]
    fn keeps_the_newest_within_each_limit() {
        let now = OffsetDateTime::now_utc();
        let jobs: Vec<Finished> = (0..5).map(|k| job(k, k as i64, 10, now)).collect();
        let ids = |v: &[u128]| v.iter().map(|&n| Uuid::from_u128(n)).collect::<Vec<_>>();
        assert!(to_forget(&jobs, &NONE, now).is_empty());
        let count = Retention {
            max_jobs: Some(3),
            ..NONE
        };
        assert_eq!(to_forget(&jobs, &count, now), ids(&[3, 4]));
        let bytes = Retention {
            max_bytes: Some(25),
            ..NONE
        };
        assert_eq!(to_forget(&jobs, &bytes, now), ids(&[2, 3, 4]));
        let age = Retention {
            max_age: Some(Duration::from_secs(36 * 3600)),
            ..NONE
        };
        assert_eq!(to_forget(&jobs, &age, now), ids(&[2, 3, 4]));
        // The tightest limit decides.
        let all = Retention {
            max_jobs: Some(4),
            max_bytes: Some(15),
            max_age: Some(Duration::from_secs(10 * 86_400)),
        };
        assert_eq!(to_forget(&jobs, &all, now), ids(&[1, 2, 3, 4]));
    }

    #[test]
    fn everything_after_the_first_forgotten_goes_and_no_limit_forgets_nothing() {
        let now = OffsetDateTime::now_utc();
        // A huge job in the middle: it and everything older go, the newer one stays.
        let jobs = vec![job(0, 0, 1, now), job(1, 1, 1000, now), job(2, 2, 1, now)];
        let bytes = Retention {
            max_bytes: Some(100),
            ..NONE
        };
        assert_eq!(
            to_forget(&jobs, &bytes, now),
            vec![Uuid::from_u128(1), Uuid::from_u128(2)]
        );
        let zero = Retention {
            max_jobs: Some(0),
            ..NONE
        };
        assert_eq!(to_forget(&jobs, &zero, now).len(), 3);
        assert!(to_forget(&[], &Retention::default(), now).is_empty());
        // A job without a finishing time is judged by count and bytes only.
        let undated = [Finished {
            id: Uuid::nil(),
            finished_at: None,
            bytes: 1,
        }];
        let age = Retention {
            max_age: Some(Duration::from_secs(1)),
            ..NONE
        };
        assert!(to_forget(&undated, &age, now).is_empty());
    }
}
