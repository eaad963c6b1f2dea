//! A job's image files beside the database: `<data>/jobs/<id>/{image,samples,distance,
//! classes,objects}.png` and `image.exr`, the last frame of a finished (or cancelled)
//! job, and in `iterations/` the frames of earlier iterations (`0003-distance.png`: the
//! iteration the job's progress counts, then the layer). File names derive from the job
//! id (a parsed UUID), an iteration number and [`super::Layer`] only, never from user
//! input, so no request can choose a path.

use super::fault::{self, Write};
use super::Layer;
use std::path::{Path, PathBuf};

/// The folder of a job's earlier iterations, inside its own folder (so deleting or
/// forgetting the job removes them with it).
pub const ITERATIONS_DIR: &str = "iterations";

/// The file of one layer of one kept iteration.
#[must_use]
pub fn iteration_path(job_dir: &Path, iteration: u32, layer: Layer) -> PathBuf {
    job_dir
        .join(ITERATIONS_DIR)
        .join(format!("{iteration:04}-{}", layer.file_name(false)))
}

/// Writes one iteration's layer PNGs into the job's `iterations/` folder (atomically and
/// synced, like the final files); returns their bytes.
pub fn write_iteration_blocking<B: AsRef<[u8]> + Sync>(
    job_dir: &Path,
    iteration: u32,
    layers: &[(Layer, B)],
) -> std::io::Result<u64> {
    let files: Vec<(String, &[u8])> = layers
        .iter()
        .map(|(l, b)| (format!("{iteration:04}-{}", l.file_name(false)), b.as_ref()))
        .collect();
    write_files_blocking(&job_dir.join(ITERATIONS_DIR), &files)?;
    Ok(files.iter().map(|(_, b)| b.len() as u64).sum())
}

/// Removes the files of one kept iteration (those already gone are not an error).
pub fn remove_iteration_blocking(job_dir: &Path, iteration: u32) -> std::io::Result<()> {
    for layer in Layer::ALL {
        match std::fs::remove_file(iteration_path(job_dir, iteration, layer)) {
            Ok(()) => {}
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => return Err(e),
        }
    }
    Ok(())
}

/// Removes every kept iteration (a job that runs again after a restart starts afresh).
pub fn clear_iterations_blocking(job_dir: &Path) -> std::io::Result<()> {
    match std::fs::remove_dir_all(job_dir.join(ITERATIONS_DIR)) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => Err(e),
        _ => Ok(()),
    }
}

/// The kept iterations and the layers stored for each, oldest first (empty when there
/// are none). Files whose names this module did not make are ignored.
pub fn kept_iterations_blocking(job_dir: &Path) -> std::io::Result<Vec<(u32, Vec<Layer>)>> {
    let rd = match std::fs::read_dir(job_dir.join(ITERATIONS_DIR)) {
        Ok(rd) => rd,
        Err(e) if is_gone(&e) => return Ok(Vec::new()),
        Err(e) => return Err(e),
    };
    let mut found = std::collections::BTreeMap::<u32, Vec<Layer>>::new();
    for entry in rd {
        let name = entry?.file_name();
        let Some((n, rest)) = name.to_str().and_then(|s| s.split_once('-')) else {
            continue;
        };
        let (Ok(n), Some(layer)) = (
            n.parse::<u32>(),
            rest.strip_suffix(".png").and_then(Layer::parse),
        ) else {
            continue;
        };
        found.entry(n).or_default().push(layer);
    }
    Ok(found
        .into_iter()
        .map(|(n, mut layers)| {
            layers.sort_by_key(|l| Layer::ALL.iter().position(|a| a == l));
            (n, layers)
        })
        .collect())
}

/// Whether `e` says a job's file is not there: missing, or a path through something that
/// is not a folder (a regular file put where the job's folder was). Either way the job's
/// files are gone; neither is the store failing.
#[must_use]
pub fn is_gone(e: &std::io::Error) -> bool {
    matches!(
        e.kind(),
        std::io::ErrorKind::NotFound | std::io::ErrorKind::NotADirectory
    )
}

/// Whether a job's file at `path` is there ([`is_gone`] answers no, not an error).
pub async fn file_present(path: &Path) -> std::io::Result<bool> {
    match tokio::fs::try_exists(path).await {
        Err(e) if is_gone(&e) => Ok(false),
        r => r,
    }
}

/// Removes a job's folder with everything in it, or whatever stands in its place (a
/// regular file or a link put there by hand): `DELETE` forgets what is there. Nothing
/// there is no error.
pub async fn remove_job_dir(dir: &Path) -> std::io::Result<()> {
    match tokio::fs::remove_dir_all(dir).await {
        Err(e) if e.kind() == std::io::ErrorKind::NotADirectory => {
            match tokio::fs::remove_file(dir).await {
                Err(e) if !is_gone(&e) => Err(e),
                _ => Ok(()),
            }
        }
        Err(e) if !is_gone(&e) => Err(e),
        _ => Ok(()),
    }
}

/// The file the final image goes to, created empty while the job renders (see
/// [`prepare_job_dir_blocking`]).
pub const FINAL_IMAGE_FILE: &str = "image.png";

/// Creates a job's (or an attempt's, `Store::attempt_dir`) folder and an empty
/// [`FINAL_IMAGE_FILE`] in it, and makes these names durable (the folder is synced for
/// the file, its parent for the folder, and the grandparent for the parent, which an
/// attempt's folder may just have created). Called while the
/// job renders, so that at its end storing the final image costs one write and one data
/// sync, not also a rename and the folder's sync (each sync ~4 ms on the test machine,
/// on the path between a render's end and its `done`). The empty file is never served:
/// the record says `has_frame` only after the image is written into it.
pub fn prepare_job_dir_blocking(dir: &Path) -> std::io::Result<()> {
    fault::check(Write::PrepareDir)?;
    std::fs::create_dir_all(dir)?;
    std::fs::File::create(dir.join(FINAL_IMAGE_FILE))?;
    std::fs::File::open(dir)?.sync_all()?;
    for ancestor in dir.ancestors().skip(1).take(2) {
        std::fs::File::open(ancestor)?.sync_all()?;
    }
    Ok(())
}

/// Writes the final image into the file [`prepare_job_dir_blocking`] made and syncs its
/// data (with its length): after this returns, the bytes survive a crash. Falls back to
/// [`write_files_blocking`] (temp file, rename, folder sync) if that file is missing.
///
/// Overwriting in place is safe here although it is not atomic: the file is written once
/// per run of a job, before the record says `has_frame`; a crash during the write leaves
/// a job that is not finished in the store, so it runs again and nobody reads the file.
pub fn write_final_image_blocking(dir: &Path, png: &[u8]) -> std::io::Result<()> {
    use std::io::Write as _;
    fault::check(Write::FinalImage)?;
    match std::fs::OpenOptions::new()
        .write(true)
        .truncate(true)
        .open(dir.join(FINAL_IMAGE_FILE))
    {
        Ok(mut f) => {
            f.write_all(png)?;
            f.sync_data()
        }
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            write_files_blocking(dir, &[(FINAL_IMAGE_FILE.to_owned(), png.to_vec())])
        }
        Err(e) => Err(e),
    }
}

/// Writes `files` (name, bytes) into `dir` atomically (temp file + rename), synchronously:
/// called from worker threads, never from the async runtime.
pub fn write_files_blocking<B: AsRef<[u8]> + Sync>(
    dir: &Path,
    files: &[(String, B)],
) -> std::io::Result<()> {
    use rayon::prelude::*;
    use std::io::Write as _;
    fault::check(Write::Layers)?;
    if !dir.exists() {
        std::fs::create_dir_all(dir)?;
        // The folder's own name must survive a crash too, not only the files in it.
        if let Some(parent) = dir.parent() {
            std::fs::File::open(parent)?.sync_all()?;
        }
    }
    // Each file is written to a temporary name and synced before it is renamed into place,
    // so a crash leaves either the old file or the whole new one. The files are written
    // and synced in parallel (the syncs wait on the disk, not the CPU: one at a time they
    // were most of the time between a render's end and its `done`), then the folder is
    // synced so the renames themselves survive a crash.
    files.par_iter().try_for_each(|(name, bytes)| {
        let tmp = dir.join(format!(".{name}.tmp"));
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes.as_ref())?;
        f.sync_all()
    })?;
    for (name, _) in files {
        std::fs::rename(dir.join(format!(".{name}.tmp")), dir.join(name))?;
    }
    std::fs::File::open(dir)?.sync_all()
}

#[cfg(test)]
mod tests {
    use super::Layer;

    #[test]
    fn kept_iterations_are_written_listed_and_removed() {
        let dir = tempfile::tempdir().unwrap();
        let job = dir.path().join("job");
        assert!(super::kept_iterations_blocking(&job).unwrap().is_empty());
        let bytes = super::write_iteration_blocking(
            &job,
            12,
            &[(Layer::Distance, b"dd".as_slice()), (Layer::Image, b"iii")],
        )
        .unwrap();
        assert_eq!(bytes, 5);
        super::write_iteration_blocking(&job, 3, &[(Layer::Image, b"i")]).unwrap();
        // Not ours: ignored.
        std::fs::write(job.join("iterations/notes.txt"), b"x").unwrap();
        std::fs::write(job.join("iterations/0001-unknown.png"), b"x").unwrap();
        assert_eq!(
            super::kept_iterations_blocking(&job).unwrap(),
            [
                (3, vec![Layer::Image]),
                (12, vec![Layer::Image, Layer::Distance])
            ]
        );
        assert_eq!(
            std::fs::read(super::iteration_path(&job, 12, Layer::Distance)).unwrap(),
            b"dd"
        );
        super::remove_iteration_blocking(&job, 12).unwrap();
        super::remove_iteration_blocking(&job, 12).unwrap();
        assert_eq!(
            super::kept_iterations_blocking(&job).unwrap(),
            [(3, vec![Layer::Image])]
        );
        super::clear_iterations_blocking(&job).unwrap();
        super::clear_iterations_blocking(&job).unwrap();
        assert!(super::kept_iterations_blocking(&job).unwrap().is_empty());
    }

    /// A regular file where a job's folder should be: its files are gone, not a fault,
    /// and removing the job removes the file.
    #[tokio::test]
    async fn a_file_in_place_of_a_jobs_folder_is_its_files_gone() {
        let dir = tempfile::tempdir().unwrap();
        let job = dir.path().join("job");
        std::fs::write(&job, b"not a folder").unwrap();
        assert!(!super::file_present(&job.join("image.png")).await.unwrap());
        assert!(super::kept_iterations_blocking(&job).unwrap().is_empty());
        super::remove_job_dir(&job).await.unwrap();
        assert!(!job.exists());
        super::remove_job_dir(&job).await.unwrap();
        // A folder goes with what is in it.
        super::write_iteration_blocking(&job, 1, &[(Layer::Image, b"i")]).unwrap();
        super::remove_job_dir(&job).await.unwrap();
        assert!(!job.exists());
    }

    #[test]
    fn the_final_image_overwrites_its_placeholder_or_is_written_without_one() {
        let dir = tempfile::tempdir().unwrap();
        // Prepared: the (empty) placeholder is overwritten; a longer earlier content (a
        // re-run after a crash) is truncated, not left as a tail.
        let job = dir.path().join("prepared");
        super::prepare_job_dir_blocking(&job).unwrap();
        let file = job.join(super::FINAL_IMAGE_FILE);
        assert_eq!(std::fs::read(&file).unwrap(), b"");
        std::fs::write(&file, b"an older and longer image").unwrap();
        super::write_final_image_blocking(&job, b"png").unwrap();
        assert_eq!(std::fs::read(&file).unwrap(), b"png");
        // Not prepared (the preparation failed): the folder is made and the file written
        // by temp file and rename, with no temp file left behind.
        let job = dir.path().join("unprepared");
        super::write_final_image_blocking(&job, b"png2").unwrap();
        assert_eq!(
            std::fs::read(job.join(super::FINAL_IMAGE_FILE)).unwrap(),
            b"png2"
        );
        let names: Vec<_> = std::fs::read_dir(&job)
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names, [super::FINAL_IMAGE_FILE]);
        // A folder that cannot be made is an error, not a panic.
        let blocked = dir.path().join("a-file");
        std::fs::write(&blocked, b"x").unwrap();
        assert!(super::write_final_image_blocking(&blocked.join("job"), b"png").is_err());
    }
}
