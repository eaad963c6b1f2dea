//! The frames of a job's earlier iterations, kept beside its final frame for the viewer's
//! iteration slider and `GET /v1/jobs/{id}/frame?iteration=N`. At the end of a render every
//! triangle is final, so the final frame's `distance` and `classes` layers are one flat
//! colour: the iterations before it are where those layers show what the method did.
//!
//! A [`Keeper`] per running job encodes each frame's [`KEPT_LAYERS`] on its own thread
//! (sharing the encodings with the stream, `LiveFrame::encoded_blocking`) and writes them
//! through the job files API, so deleting or forgetting a job removes them with it. What
//! is kept is bounded per job by [`MAX_KEPT`] iterations and [`MAX_KEPT_BYTES`]; past that,
//! [`to_forget`] thins the kept iterations evenly, always keeping the first (where the
//! distance layer carries the most) and the newest.

use super::live::LiveFrame;
use super::store::{self, Layer};
use std::path::PathBuf;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::mpsc::{channel, Sender};
use std::sync::Arc;

/// At most this many earlier iterations are kept per job.
pub const MAX_KEPT: usize = 64;

/// At most this many bytes of earlier iterations are kept per job (a 1600×1200 iteration
/// is about 2 MB, most of it the image and the samples layer).
pub const MAX_KEPT_BYTES: u64 = 128 << 20;

/// The layers kept per iteration; `objects` is the same at every iteration, so only the
/// final frame's is stored.
pub const KEPT_LAYERS: [Layer; 4] = [
    Layer::Image,
    Layer::Samples,
    Layer::Distance,
    Layer::Classes,
];

/// One kept iteration: its number (as the job's progress counts) and its bytes on disk.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Kept {
    pub iteration: u32,
    pub bytes: u64,
}

/// The iterations to remove (oldest first in `kept`) so that at most `max_count` remain
/// and their bytes are at most `max_bytes`. Each removal takes the inner iteration whose
/// neighbours are closest (the densest spot), so what remains spans the run evenly; the
/// first and the newest go only when nothing else is left to remove. Pure.
#[must_use]
pub fn to_forget(kept: &[Kept], max_count: usize, max_bytes: u64) -> Vec<u32> {
    let mut left = kept.to_vec();
    let mut gone = Vec::new();
    let over =
        |l: &[Kept]| l.len() > max_count || l.iter().map(|k| k.bytes).sum::<u64>() > max_bytes;
    while !left.is_empty() && over(&left) {
        let k = if left.len() <= 2 {
            0
        } else {
            (1..left.len() - 1)
                .min_by_key(|&i| left[i + 1].iteration - left[i - 1].iteration)
                .unwrap_or(0)
        };
        gone.push(left.remove(k).iteration);
    }
    gone
}

/// Keeps the earlier iterations of one running job (see the module's comment). Dropping
/// it waits until every frame it accepted is written.
pub struct Keeper {
    tx: Option<Sender<Arc<LiveFrame>>>,
    /// Pixels of the frames waiting for the writer.
    waiting: Arc<AtomicUsize>,
    thread: Option<std::thread::JoinHandle<()>>,
}

/// Pixels of frames that may wait for the writer (a waiting frame is a copy of the image
/// and its layers, ~18 bytes a pixel: 72 MB here). A frame that would go beyond it is not
/// kept, unless nothing waits: the render never waits for the disk, memory stays bounded,
/// and small images, whose iterations come faster than their files are synced, keep
/// every iteration.
const WAITING_PIXELS: usize = 4 << 20;

impl Keeper {
    /// Starts the writer for the job whose folder is `job_dir`, first removing what an
    /// earlier run of the same job kept (a job run again after a restart starts afresh).
    #[must_use]
    pub fn start(job_dir: PathBuf) -> Self {
        let (tx, rx) = channel::<Arc<LiveFrame>>();
        let waiting = Arc::new(AtomicUsize::new(0));
        let done = Arc::clone(&waiting);
        let thread = std::thread::Builder::new()
            .name("keep-iterations".into())
            .spawn(move || {
                if let Err(e) = store::clear_iterations_blocking(&job_dir) {
                    tracing::warn!("cannot clear earlier iterations: {e}");
                }
                let mut kept = Vec::new();
                for lf in rx {
                    if let Err(e) = keep(&job_dir, &lf, &mut kept) {
                        tracing::warn!(iteration = lf.iteration, "not kept: {e}");
                    }
                    done.fetch_sub(pixels(&lf), Ordering::SeqCst);
                }
            });
        match thread {
            Ok(t) => Self {
                tx: Some(tx),
                waiting,
                thread: Some(t),
            },
            Err(e) => {
                tracing::warn!("earlier iterations will not be kept: {e}");
                Self {
                    tx: None,
                    waiting,
                    thread: None,
                }
            }
        }
    }

    /// Hands a frame to the writer, unless it is the final one (stored as the job's own
    /// files), a preview (no iteration: the first iteration's frame follows it), or the
    /// frames waiting already hold [`WAITING_PIXELS`].
    pub fn offer(&self, lf: &Arc<LiveFrame>) {
        let Some(tx) = &self.tx else { return };
        if lf.is_last() || lf.preview {
            return;
        }
        let px = pixels(lf);
        let admitted = self
            .waiting
            .fetch_update(Ordering::SeqCst, Ordering::SeqCst, |w| {
                (w == 0 || w + px <= WAITING_PIXELS).then_some(w + px)
            })
            .is_ok();
        if !admitted {
            tracing::debug!(iteration = lf.iteration, "writer behind: not kept");
        } else if tx.send(Arc::clone(lf)).is_err() {
            self.waiting.fetch_sub(px, Ordering::SeqCst);
        }
    }
}

impl Drop for Keeper {
    fn drop(&mut self) {
        self.tx = None;
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

fn pixels(lf: &LiveFrame) -> usize {
    lf.pixel_count()
}

/// Writes one frame's kept layers, then removes what the bounds no longer allow.
fn keep(job_dir: &std::path::Path, lf: &LiveFrame, kept: &mut Vec<Kept>) -> Result<(), String> {
    let mut layers = Vec::new();
    for layer in KEPT_LAYERS {
        if let Some(png) = lf.encoded_blocking(layer, false)? {
            layers.push((layer, png));
        }
    }
    let iteration = lf.iteration;
    let bytes =
        store::write_iteration_blocking(job_dir, iteration, &layers).map_err(|e| e.to_string())?;
    kept.retain(|k| k.iteration != iteration);
    kept.push(Kept { iteration, bytes });
    for n in to_forget(kept, MAX_KEPT, MAX_KEPT_BYTES) {
        store::remove_iteration_blocking(job_dir, n).map_err(|e| e.to_string())?;
        kept.retain(|k| k.iteration != n);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::{to_forget, Kept};

    fn kept(iterations: &[u32], bytes: u64) -> Vec<Kept> {
        iterations
            .iter()
            .map(|&iteration| Kept { iteration, bytes })
            .collect()
    }

    #[test]
    fn within_bounds_nothing_is_forgotten() {
        assert!(to_forget(&[], 0, 0).is_empty());
        assert!(to_forget(&kept(&[0, 1, 2], 10), 3, 30).is_empty());
    }

    #[test]
    fn over_the_count_the_densest_inner_iteration_goes() {
        // 0 1 2 3 4, at most 4: the first inner iteration whose neighbours are closest
        // (1: its neighbours 0 and 2 are 2 apart) goes.
        assert_eq!(to_forget(&kept(&[0, 1, 2, 3, 4], 1), 4, 100), [1]);
        // Gaps already uneven: 5 sits between 4 and 6, the densest spot.
        assert_eq!(to_forget(&kept(&[0, 2, 4, 5, 6, 9], 1), 5, 100), [5]);
        // Thinning a long run keeps its ends and spreads what remains.
        let all: Vec<u32> = (0..100).collect();
        let gone = to_forget(&kept(&all, 1), 10, u64::MAX);
        assert_eq!(gone.len(), 90);
        let left: Vec<u32> = all.iter().copied().filter(|n| !gone.contains(n)).collect();
        assert_eq!((left[0], left[9]), (0, 99));
        let widest = left.windows(2).map(|w| w[1] - w[0]).max().unwrap();
        assert!(widest <= 16, "{left:?}");
    }

    #[test]
    fn over_the_bytes_iterations_go_until_they_fit() {
        assert_eq!(to_forget(&kept(&[0, 1, 2, 3], 10), 64, 25), [1, 2]);
        // One iteration larger than the whole budget is not kept either.
        assert_eq!(to_forget(&kept(&[7], 50), 64, 25), [7]);
        // With two left the older goes first.
        assert_eq!(to_forget(&kept(&[3, 8], 20), 64, 25), [3]);
    }
}
