//! Storage faults on demand, so tests can drive the real server binary through a full or
//! unwritable disk at every write it makes, one write at a time, and clear the fault
//! again without a restart.
//!
//! `GLIMPSE_FAULTS=PATH` (read once, at the first write) names a rules file that is read
//! again before every write of the store and of the job files. Each line names the
//! writes that fail: a [`Write`] name (`store.finish`), a family (`store.*`, `files.*`)
//! or `*`; a line `!NAME` (same forms) exempts writes from the lines before. A matching
//! write fails with `ENOSPC`, as on a full disk, before it touches anything. No file, an
//! empty one or the variable unset (production) means no fault; unset, a write costs one
//! atomic load here.
//!
//! Only the service's own writes are listed: the store's reads never fail here. The
//! claim is `store.start`, its end `store.finish`, a release `store.requeue`. On SQLite
//! the claim's fault strikes inside its transaction and fails it as `SQLITE_FULL` does
//! (the transaction already rolled back when the error comes: `lease::claim_sqlite`).

use std::path::PathBuf;
use std::sync::OnceLock;

/// Every write of the store and of the job files, by the name a rules file uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Write {
    /// A new job's record (`POST /v1/jobs`).
    Insert,
    /// queued → running, counting the attempt.
    Start,
    /// A cancel request recorded before its `202`.
    RequestCancel,
    /// queued → cancelled.
    CancelQueued,
    /// running → a finished state.
    Finish,
    /// running → queued on a graceful shutdown.
    Requeue,
    /// Start-up recovery.
    Recover,
    /// A finished job's record removed (`DELETE`).
    Delete,
    /// A job's folder and its empty final image made durable while it renders.
    PrepareDir,
    /// The final image written and synced before `done`.
    FinalImage,
    /// The other layers and the EXR, written after `done`.
    Layers,
    /// A finished job's folder removed (`DELETE`, retention).
    RemoveDir,
    /// A running job's lease renewed (with its progress) by its worker's heartbeat.
    Heartbeat,
    /// Expired leases taken back by the reaper.
    Reap,
}

impl Write {
    pub const ALL: [Self; 14] = [
        Self::Insert,
        Self::Start,
        Self::RequestCancel,
        Self::CancelQueued,
        Self::Finish,
        Self::Requeue,
        Self::Recover,
        Self::Delete,
        Self::PrepareDir,
        Self::FinalImage,
        Self::Layers,
        Self::RemoveDir,
        Self::Heartbeat,
        Self::Reap,
    ];

    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Insert => "store.insert",
            Self::Start => "store.start",
            Self::RequestCancel => "store.request_cancel",
            Self::CancelQueued => "store.cancel_queued",
            Self::Finish => "store.finish",
            Self::Requeue => "store.requeue",
            Self::Recover => "store.recover",
            Self::Delete => "store.delete",
            Self::PrepareDir => "files.prepare_dir",
            Self::FinalImage => "files.final_image",
            Self::Layers => "files.layers",
            Self::RemoveDir => "files.remove_dir",
            Self::Heartbeat => "store.heartbeat",
            Self::Reap => "store.reap",
        }
    }
}

/// Does `pattern` (a name, `family.*` or `*`) name `write`?
fn matches(pattern: &str, write: Write) -> bool {
    let name = write.name();
    match pattern.strip_suffix('*') {
        Some(prefix) => name.starts_with(prefix),
        None => name == pattern,
    }
}

/// Whether `rules` (the file's text) make `write` fail: the last line that names it
/// decides (`!` exempts); blank lines and `#` comments are skipped.
#[must_use]
pub fn fails(rules: &str, write: Write) -> bool {
    let mut fail = false;
    for line in rules.lines().map(str::trim) {
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        match line.strip_prefix('!') {
            Some(p) if matches(p.trim(), write) => fail = false,
            Some(_) => {}
            None if matches(line, write) => fail = true,
            None => {}
        }
    }
    fail
}

fn rules_file() -> Option<&'static PathBuf> {
    static FILE: OnceLock<Option<PathBuf>> = OnceLock::new();
    FILE.get_or_init(|| std::env::var_os("GLIMPSE_FAULTS").map(PathBuf::from))
        .as_ref()
}

/// `Err(ENOSPC)` if the rules file currently makes `write` fail; called first thing by
/// every write of the store and the job files.
pub fn check(write: Write) -> std::io::Result<()> {
    match rules_file() {
        Some(path) => check_against(path, write),
        None => Ok(()),
    }
}

/// [`check`] against the rules file at `path`.
fn check_against(path: &std::path::Path, write: Write) -> std::io::Result<()> {
    let rules = std::fs::read_to_string(path).unwrap_or_default();
    if fails(&rules, write) {
        const ENOSPC: i32 = 28;
        let e = std::io::Error::from_raw_os_error(ENOSPC);
        return Err(std::io::Error::new(
            e.kind(),
            format!("{e} (injected at {})", write.name()),
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::{fails, Write};

    #[test]
    fn rules_name_writes_families_and_exemptions() {
        assert!(!fails("", Write::Insert));
        assert!(fails("store.insert", Write::Insert));
        assert!(!fails("store.insert", Write::Finish));
        assert!(fails("# a full disk\nstore.*", Write::Finish));
        assert!(!fails("store.*", Write::FinalImage));
        assert!(fails("files.*", Write::FinalImage));
        // A full disk on which deletions still free space.
        let full = "*\n!store.delete\n!files.remove_dir";
        assert!(fails(full, Write::Insert));
        assert!(fails(full, Write::Layers));
        assert!(!fails(full, Write::Delete));
        assert!(!fails(full, Write::RemoveDir));
        // The last line naming a write decides.
        assert!(fails("!store.insert\nstore.insert", Write::Insert));
        // Every name is unique and in its family.
        for w in Write::ALL {
            assert_eq!(
                Write::ALL.iter().filter(|v| v.name() == w.name()).count(),
                1
            );
            assert!(w.name().starts_with("store.") || w.name().starts_with("files."));
        }
    }

    #[test]
    fn an_injected_fault_is_enospc_and_names_its_write() {
        let dir = tempfile::tempdir().unwrap();
        let rules = dir.path().join("faults");
        std::fs::write(&rules, "files.final_image").unwrap();
        let e = super::check_against(&rules, Write::FinalImage).unwrap_err();
        assert_eq!(e.kind(), std::io::ErrorKind::StorageFull);
        assert!(e.to_string().contains("files.final_image"), "{e}");
        assert!(super::check_against(&rules, Write::Insert).is_ok());
        std::fs::remove_file(&rules).unwrap();
        assert!(super::check_against(&rules, Write::FinalImage).is_ok());
    }
}
