//! A job's image files beside the database: `<data>/jobs/<id>/{image,samples,distance,
//! classes,objects}.png` and `image.exr`, the last frame of a finished (or cancelled)
//! job. File names derive from the job id (a parsed UUID) and [`super::Layer`] only,
//! never from user input, so no request can choose a path.

use super::fault::{self, Write};
use std::path::Path;

/// The file the final image goes to, created empty while the job renders (see
/// [`prepare_job_dir_blocking`]).
pub const FINAL_IMAGE_FILE: &str = "image.png";

/// Creates a job's folder and an empty [`FINAL_IMAGE_FILE`] in it, and makes both names
/// durable (the folder is synced for the file, `jobs/` for the folder). Called while the
/// job renders, so that at its end storing the final image costs one write and one data
/// sync, not also a rename and the folder's sync (each sync ~4 ms on the test machine,
/// on the path between a render's end and its `done`). The empty file is never served:
/// the record says `has_frame` only after the image is written into it.
pub fn prepare_job_dir_blocking(dir: &Path) -> std::io::Result<()> {
    fault::check(Write::PrepareDir)?;
    std::fs::create_dir_all(dir)?;
    std::fs::File::create(dir.join(FINAL_IMAGE_FILE))?;
    std::fs::File::open(dir)?.sync_all()?;
    match dir.parent() {
        Some(parent) => std::fs::File::open(parent)?.sync_all(),
        None => Ok(()),
    }
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
