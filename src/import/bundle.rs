//! Zip bundles uploaded over HTTP: one scene file at the root and the files it names.
//! Our own reader of the zip central directory (stored and deflated entries), so that
//! every limit holds before anything is unpacked:
//! - the entry count and the total *declared* unpacked size are checked first (a zip bomb
//!   is refused from its directory, not inflated);
//! - an entry is inflated only when the import reads it, after its declared size has been
//!   checked against the file limit and the read budget, with that size as a hard cap (a
//!   directory that lies gets an error, not a big buffer); the import drops it once
//!   parsed, so an import holds the zip and the files it is reading, not everything the
//!   bundle unpacks to;
//! - every read counts against the bundle's read budget, twice what it holds plus
//!   [`READ_SLACK`]: a file read again (each `Include` of it, each material naming the
//!   same texture) counts every time;
//! - names are resolved inside the bundle only: absolute names, `..` that leaves the
//!   bundle, symbolic links and names not in the bundle are errors naming the entry.

use std::cell::Cell;
use std::collections::BTreeMap;

use super::{FileSource, ReadError};

/// The most entries an uploaded bundle may have.
pub const MAX_ENTRIES: usize = 10_000;
/// The most bytes an uploaded bundle may unpack to, all entries together (256 MiB).
pub const MAX_UNPACKED: u64 = 1 << 28;
/// The largest single file an upload's import reads (64 MiB): a scene, mesh, buffer or
/// texture is parsed from memory, so this bounds what one file costs to hold and to
/// parse. It leaves room for a mesh at the default triangle limit (a million triangles are
/// ~30 MB of binary PLY or glTF buffers).
pub const MAX_FILE: u64 = 1 << 26;
/// What an import may read beyond twice what its bundle holds (16 MiB). Public scenes
/// read some files more than once (veach-ajar names two of its PLY meshes three times
/// each, 7.3 MB more than its 7.8 MB bundle), while a file included over and over is
/// refused after a few readings, not parsed 200 times.
pub const READ_SLACK: u64 = 16 << 20;

/// Bounds on a bundle, checked from its directory.
#[derive(Clone, Copy, Debug)]
pub struct BundleLimits {
    pub max_entries: usize,
    pub max_unpacked: u64,
}

/// The bundle in an upload's bytes: its directory by normalised name, each entry inflated
/// when it is read.
#[derive(Debug, Default)]
pub struct Bundle<'z> {
    zip: &'z [u8],
    files: BTreeMap<String, Entry>,
    /// Bytes inflated so far and the most that may be.
    read: Cell<u64>,
    read_budget: u64,
}

/// Why a bundle was refused: `too_large` for a limit.
#[derive(Debug)]
pub struct BundleError {
    pub message: String,
    pub too_large: bool,
}

fn bad(m: impl Into<String>) -> BundleError {
    BundleError {
        message: m.into(),
        too_large: false,
    }
}

fn u16_at(b: &[u8], i: usize) -> Option<usize> {
    b.get(i..i + 2)
        .map(|s| usize::from(u16::from_le_bytes([s[0], s[1]])))
}

fn u32_at(b: &[u8], i: usize) -> Option<u64> {
    b.get(i..i + 4)
        .map(|s| u64::from(u32::from_le_bytes([s[0], s[1], s[2], s[3]])))
}

impl<'z> Bundle<'z> {
    /// Reads the directory of the bundle in `zip`; nothing is inflated.
    pub fn parse(zip: &'z [u8], limits: &BundleLimits) -> Result<Self, BundleError> {
        let entries = entries(zip, limits.max_entries)?;
        let total: u64 = entries.iter().map(|e| e.size).sum();
        if total > limits.max_unpacked {
            return Err(BundleError {
                message: format!(
                    "the bundle unpacks to {total} bytes, more than the limit of {} (refused before unpacking)",
                    limits.max_unpacked
                ),
                too_large: true,
            });
        }
        let mut files = BTreeMap::new();
        for e in entries {
            if e.name.ends_with('/') {
                continue;
            }
            let key = normalise(&e.name).map_err(|m| bad(format!("entry \"{}\": {m}", e.name)))?;
            insert_once(&mut files, key, e)?;
        }
        Ok(Self {
            zip,
            files,
            read: Cell::new(0),
            read_budget: total.saturating_mul(2).saturating_add(READ_SLACK),
        })
    }

    /// The one scene file at the bundle's root (`.json`, `.gltf`, `.glb`, `.pbrt`).
    pub fn scene_file(&self) -> Result<&str, BundleError> {
        let scenes: Vec<&str> = self
            .files
            .keys()
            .map(String::as_str)
            .filter(|n| !n.contains('/'))
            .filter(|n| super::Format::of(std::path::Path::new(n)).is_ok())
            .collect();
        match scenes.as_slice() {
            [one] => Ok(one),
            [] => Err(bad(
                "no scene file (.json, .gltf, .glb or .pbrt) at the bundle's root",
            )),
            many => Err(bad(format!(
                "more than one scene file at the bundle's root: {}",
                many.join(", ")
            ))),
        }
    }

    /// What the entry `name` (normalised) says it unpacks to.
    #[must_use]
    pub fn size_of(&self, name: &str) -> Option<u64> {
        self.files.get(name).map(|e| e.size)
    }

    /// The most bytes the import may inflate, all reads together: twice what the bundle
    /// holds plus [`READ_SLACK`].
    #[must_use]
    pub fn read_budget(&self) -> u64 {
        self.read_budget
    }

    /// Charges `e`'s declared size to the read budget, refused past it or past `max`
    /// (both before anything is inflated).
    fn charge(&self, name: &str, e: &Entry, max: u64) -> Result<(), ReadError> {
        if e.size > max {
            return Err(ReadError::limit(format!(
                "\"{name}\" unpacks to {} bytes, more than the limit of {max} bytes for one file (refused before unpacking)",
                e.size
            )));
        }
        let read = self.read.get().saturating_add(e.size);
        if read > self.read_budget {
            return Err(ReadError::limit(format!(
                "reading \"{name}\" ({} bytes) takes what the import reads past the limit of {} bytes, twice what the bundle holds plus {READ_SLACK} (a file read again, as each Include of it, counts every time)",
                e.size, self.read_budget
            )));
        }
        self.read.set(read);
        Ok(())
    }
}

impl FileSource for Bundle<'_> {
    fn read(&self, name: &str, max: u64) -> Result<Vec<u8>, ReadError> {
        let key = normalise(name).map_err(|m| ReadError::missing(format!("\"{name}\": {m}")))?;
        let e = self
            .files
            .get(&key)
            .ok_or_else(|| ReadError::missing(format!("\"{name}\" is not in the bundle")))?;
        self.charge(name, e, max)?;
        unpack(self.zip, e).map_err(|m| ReadError::missing(format!("entry \"{}\": {m}", e.name)))
    }
}

/// What the bundle in `zip` says it unpacks to, all entries together (from its central
/// directory, nothing inflated); `None` if it is not a zip Glimpse reads (its import will
/// say why). The service charges this against its validation budget before importing.
#[must_use]
pub fn unpacked_size(zip: &[u8]) -> Option<u64> {
    let entries = entries(zip, MAX_ENTRIES).ok()?;
    Some(entries.iter().map(|e| e.size).sum())
}

/// The entries of the central directory, at most `max_entries`.
fn entries(zip: &[u8], max_entries: usize) -> Result<Vec<Entry>, BundleError> {
    // End of central directory: 22 bytes plus a comment of up to 64 KiB, at the end.
    let from = zip.len().saturating_sub(22 + 65535);
    let eocd = (from..zip.len().saturating_sub(21))
        .rev()
        .find(|&i| zip[i..i + 4] == [0x50, 0x4b, 0x05, 0x06])
        .ok_or_else(|| bad("not a zip file (no end of central directory)"))?;
    let count = u16_at(zip, eocd + 10).unwrap_or(0);
    let dir_len = u32_at(zip, eocd + 12).unwrap_or(0);
    let dir_at = u32_at(zip, eocd + 16).unwrap_or(0);
    if count == 0xffff || dir_at == 0xffff_ffff {
        return Err(bad("zip64 bundles are not supported"));
    }
    if count > max_entries {
        return Err(BundleError {
            message: format!(
                "the bundle has {count} entries, more than the limit of {max_entries}"
            ),
            too_large: true,
        });
    }
    let dir = zip
        .get(dir_at as usize..(dir_at + dir_len) as usize)
        .ok_or_else(|| bad("the central directory lies outside the file (truncated?)"))?;
    directory(dir, count)
}

/// Adds `e` under its normalised name `key`, refusing a second entry of that name: which
/// of the two a reader would get is up to the reader, so the upload is ambiguous.
fn insert_once(
    files: &mut BTreeMap<String, Entry>,
    key: String,
    e: Entry,
) -> Result<(), BundleError> {
    match files.entry(key) {
        std::collections::btree_map::Entry::Occupied(o) => Err(bad(format!(
            "entry \"{}\" appears twice in the bundle (also as \"{}\")",
            o.key(),
            o.get().name
        ))),
        std::collections::btree_map::Entry::Vacant(v) => {
            v.insert(e);
            Ok(())
        }
    }
}

/// A name inside the bundle with `.` and `..` resolved; absolute names and names that
/// climb out of the bundle are refused.
fn normalise(name: &str) -> Result<String, String> {
    if name.starts_with('/') || name.starts_with('\\') || name.contains(':') {
        return Err("absolute names are not allowed in a bundle".into());
    }
    let mut parts: Vec<&str> = Vec::new();
    for p in name.split(['/', '\\']) {
        match p {
            "" | "." => {}
            ".." => {
                if parts.pop().is_none() {
                    return Err("`..` leaves the bundle".into());
                }
            }
            p => parts.push(p),
        }
    }
    if parts.is_empty() {
        return Err("empty name".into());
    }
    Ok(parts.join("/"))
}

#[derive(Debug)]
struct Entry {
    name: String,
    method: usize,
    packed: u64,
    size: u64,
    local: u64,
}

fn directory(dir: &[u8], count: usize) -> Result<Vec<Entry>, BundleError> {
    let mut out = Vec::with_capacity(count);
    let mut at = 0;
    for k in 0..count {
        let trunc = || bad(format!("central directory entry {k} is truncated"));
        if dir.get(at..at + 4) != Some(&[0x50, 0x4b, 0x01, 0x02]) {
            return Err(trunc());
        }
        let flags = u16_at(dir, at + 8).ok_or_else(trunc)?;
        let method = u16_at(dir, at + 10).ok_or_else(trunc)?;
        let packed = u32_at(dir, at + 20).ok_or_else(trunc)?;
        let size = u32_at(dir, at + 24).ok_or_else(trunc)?;
        let (n, x, c) = (
            u16_at(dir, at + 28).ok_or_else(trunc)?,
            u16_at(dir, at + 30).ok_or_else(trunc)?,
            u16_at(dir, at + 32).ok_or_else(trunc)?,
        );
        let external = u32_at(dir, at + 38).ok_or_else(trunc)?;
        let local = u32_at(dir, at + 42).ok_or_else(trunc)?;
        let name = dir.get(at + 46..at + 46 + n).ok_or_else(trunc)?;
        let name = String::from_utf8_lossy(name).into_owned();
        if flags & 1 != 0 {
            return Err(bad(format!("entry \"{name}\" is encrypted")));
        }
        // Unix mode in the high half of the external attributes: S_IFLNK.
        if (external >> 16) & 0o170_000 == 0o120_000 {
            return Err(bad(format!(
                "entry \"{name}\" is a symbolic link (links are not allowed)"
            )));
        }
        if method != 0 && method != 8 {
            return Err(bad(format!(
                "entry \"{name}\" uses compression method {method} (stored and deflate only)"
            )));
        }
        out.push(Entry {
            name,
            method,
            packed,
            size,
            local,
        });
        at += 46 + n + x + c;
    }
    Ok(out)
}

/// An entry's bytes, inflated with its declared size as the cap.
fn unpack(zip: &[u8], e: &Entry) -> Result<Vec<u8>, String> {
    let l = e.local as usize;
    if zip.get(l..l + 4) != Some(&[0x50, 0x4b, 0x03, 0x04]) {
        return Err("no local header where the directory says".into());
    }
    let n = u16_at(zip, l + 26).ok_or("truncated local header")?;
    let x = u16_at(zip, l + 28).ok_or("truncated local header")?;
    let start = l + 30 + n + x;
    let data = zip
        .get(start..start.saturating_add(e.packed as usize))
        .ok_or("its data lies outside the file (truncated?)")?;
    if e.method == 0 {
        if e.packed != e.size {
            return Err("a stored entry's sizes disagree".into());
        }
        return Ok(data.to_vec());
    }
    let out = miniz_oxide::inflate::decompress_to_vec_with_limit(data, e.size as usize).map_err(
        |err| {
            format!(
                "cannot inflate (more data than its declared {} bytes, or corrupt): {err:?}",
                e.size
            )
        },
    )?;
    if out.len() as u64 != e.size {
        return Err(format!(
            "inflates to {} bytes, not the declared {}",
            out.len(),
            e.size
        ));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A zip of stored entries (name, data, unix mode).
    pub fn stored_zip(entries: &[(&str, &[u8], u32)]) -> Vec<u8> {
        let (mut out, mut dir) = (Vec::new(), Vec::new());
        for (name, data, mode) in entries {
            let at = out.len() as u32;
            out.extend([0x50, 0x4b, 0x03, 0x04, 20, 0, 0, 0, 0, 0, 0, 0, 0, 0]);
            out.extend(0u32.to_le_bytes()); // crc (not checked)
            out.extend((data.len() as u32).to_le_bytes());
            out.extend((data.len() as u32).to_le_bytes());
            out.extend((name.len() as u16).to_le_bytes());
            out.extend(0u16.to_le_bytes());
            out.extend(name.as_bytes());
            out.extend(*data);
            dir.extend([0x50, 0x4b, 0x01, 0x02, 20, 3, 20, 0, 0, 0, 0, 0, 0, 0, 0, 0]);
            dir.extend(0u32.to_le_bytes());
            dir.extend((data.len() as u32).to_le_bytes());
            dir.extend((data.len() as u32).to_le_bytes());
            dir.extend((name.len() as u16).to_le_bytes());
            dir.extend([0, 0, 0, 0, 0, 0, 0, 0]);
            dir.extend((mode << 16).to_le_bytes());
            dir.extend(at.to_le_bytes());
            dir.extend(name.as_bytes());
        }
        let dir_at = out.len() as u32;
        out.extend(&dir);
        out.extend([0x50, 0x4b, 0x05, 0x06, 0, 0, 0, 0]);
        out.extend((entries.len() as u16).to_le_bytes());
        out.extend((entries.len() as u16).to_le_bytes());
        out.extend((dir.len() as u32).to_le_bytes());
        out.extend(dir_at.to_le_bytes());
        out.extend(0u16.to_le_bytes());
        out
    }

    fn limits() -> BundleLimits {
        BundleLimits {
            max_entries: 100,
            max_unpacked: 1 << 20,
        }
    }

    #[test]
    fn names_resolve_inside_the_bundle_only() {
        let z = stored_zip(&[
            ("scene.pbrt", b"WorldBegin", 0o100_644),
            ("models/a.ply", b"ply", 0o100_644),
        ]);
        let b = Bundle::parse(&z, &limits()).unwrap();
        assert_eq!(b.scene_file().unwrap(), "scene.pbrt");
        assert_eq!(b.read("./models/../models/a.ply", 10).unwrap(), b"ply");
        let err = |name: &str, max: u64| b.read(name, max).unwrap_err();
        assert!(err("../scene.pbrt", 10)
            .message
            .contains("leaves the bundle"));
        assert!(err("/etc/passwd", 10).message.contains("absolute"));
        let e = err("models/b.ply", 10);
        assert!(e.message.contains("\"models/b.ply\" is not in the bundle"));
        assert!(!e.too_large);
        let e = err("models/a.ply", 2);
        assert!(e.too_large && e.message.contains("limit of 2 bytes"), "{e}");
    }

    #[test]
    fn names_that_normalise_alike_are_refused() {
        for (first, second) in [
            ("a.ply", "a.ply"),
            ("a/../b.ply", "b.ply"),
            ("./c.ply", "c.ply"),
        ] {
            let z = stored_zip(&[
                ("scene.pbrt", b"x", 0o100_644),
                (first, b"1", 0o100_644),
                (second, b"2", 0o100_644),
            ]);
            let e = Bundle::parse(&z, &limits()).unwrap_err();
            let name = second.trim_start_matches("./");
            assert!(
                !e.too_large
                    && e.message
                        .contains(&format!("entry \"{name}\" appears twice in the bundle")),
                "{}",
                e.message
            );
        }
    }

    #[test]
    fn entries_inflate_when_read_within_the_read_budget() {
        let packed = miniz_oxide::deflate::compress_to_vec(&[7u8; 1000], 6);
        let mut z = stored_zip(&[
            ("scene.pbrt", b"x", 0o100_644),
            ("inc.pbrt", &packed, 0o100_644),
        ]);
        let dir = z
            .windows(4)
            .rposition(|w| w == [0x50, 0x4b, 0x01, 0x02])
            .unwrap();
        z[dir + 10] = 8; // deflate
        z[dir + 24..dir + 28].copy_from_slice(&1000u32.to_le_bytes());
        let b = Bundle::parse(&z, &limits()).unwrap();
        assert_eq!(b.size_of("inc.pbrt"), Some(1000));
        assert_eq!(b.read_budget(), 2 * 1001 + READ_SLACK);
        assert_eq!(b.read("inc.pbrt", 1000).unwrap(), vec![7u8; 1000]);
        // Read again and again, as a scene including it over and over: refused once the
        // reads pass the budget, before inflating.
        let times = ((2 * 1001 + READ_SLACK) / 1000 - 1) as usize;
        let refused = (0..times + 2).position(|_| b.read("inc.pbrt", 1000).is_err());
        assert_eq!(refused, Some(times));
        let e = b.read("inc.pbrt", 1000).unwrap_err();
        assert!(
            e.too_large && e.message.contains("counts every time"),
            "{e}"
        );
    }

    #[test]
    fn links_escapes_and_limits_are_refused_from_the_directory() {
        let link = stored_zip(&[
            ("scene.pbrt", b"x", 0o100_644),
            ("l.ply", b"/etc/passwd", 0o120_777),
        ]);
        assert!(Bundle::parse(&link, &limits())
            .unwrap_err()
            .message
            .contains("symbolic link"));
        let up = stored_zip(&[("../scene.pbrt", b"x", 0o100_644)]);
        assert!(Bundle::parse(&up, &limits())
            .unwrap_err()
            .message
            .contains("leaves the bundle"));
        let many: Vec<(String, &[u8], u32)> = (0..101)
            .map(|i| (format!("f{i}"), &b""[..], 0o100_644))
            .collect();
        let many: Vec<(&str, &[u8], u32)> =
            many.iter().map(|(n, d, m)| (n.as_str(), *d, *m)).collect();
        let e = Bundle::parse(&stored_zip(&many), &limits()).unwrap_err();
        assert!(
            e.too_large && e.message.contains("101 entries"),
            "{}",
            e.message
        );
        // A deflated entry whose directory claims 1 GiB: refused before inflating.
        let packed = miniz_oxide::deflate::compress_to_vec(&vec![0u8; 1 << 16], 6);
        let mut z = stored_zip(&[("zeros.bin", &packed, 0o100_644)]);
        let dir = z
            .windows(4)
            .position(|w| w == [0x50, 0x4b, 0x01, 0x02])
            .unwrap();
        z[dir + 10] = 8; // deflate
        z[dir + 24..dir + 28].copy_from_slice(&(1u32 << 30).to_le_bytes());
        let e = Bundle::parse(&z, &limits()).unwrap_err();
        assert!(
            e.too_large && e.message.contains("refused before unpacking"),
            "{}",
            e.message
        );
        // The same entry claiming 10 bytes: inflation, when it is read, stops at the cap.
        z[dir + 24..dir + 28].copy_from_slice(&10u32.to_le_bytes());
        let b = Bundle::parse(&z, &limits()).unwrap();
        let e = b.read("zeros.bin", 100).unwrap_err();
        assert!(e.message.contains("cannot inflate"), "{e}");
        assert!(Bundle::parse(b"PK not a zip", &limits()).is_err());
        assert!(Bundle::parse(&z[..z.len() - 30], &limits()).is_err());
    }
}
