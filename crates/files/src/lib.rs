//! The one way the core reads and writes files (map files, vocabularies), the same rules as
//! the Python package's `ferroslam._files`:
//!
//! - [`open_regular`] opens a regular file (links followed) for reading and refuses
//!   folders, FIFOs, devices and sockets *before* reading: opening a FIFO would block until
//!   a writer came, and a device such as `/dev/zero` would be read until memory ran out. It
//!   opens non-blocking and checks the open file again, so a FIFO swapped in between the
//!   check and the open cannot block either.
//! - [`write_atomically`] writes a new file beside the target (created exclusively: a file
//!   or link planted under its name is never written through), flushes it to disk and
//!   renames it over the target, so an interrupted write leaves any previous file intact. A
//!   target that exists and is not a regular file is refused (a FIFO never becomes a
//!   regular file, `/dev/null` is never replaced); a symlink at the target is replaced by
//!   the file, never written through. Missing parent folders are created.
//!
//! Errors are `std::io::Error`s: `InvalidInput` for a special file, `IsADirectory` for a
//! folder, else the operating system's. As the standard library's, their messages say what
//! is wrong and leave naming the file to the caller (the map and vocabulary errors do).
#![warn(missing_docs)]

use std::fs::{File, Metadata};
use std::io::{BufWriter, Error, ErrorKind, Read, Take, Write};
use std::path::{Path, PathBuf};

/// `path` opened for reading if it is a regular file of at most `max_bytes` bytes; reads
/// stop after `max_bytes + 1` bytes even if the file grows meanwhile (`what` names the
/// kind of file in messages, e.g. "map file").
///
/// # Errors
/// `NotFound`, `IsADirectory`, or `InvalidInput` for a special file or one too large.
pub fn open_regular(path: &Path, max_bytes: u64, what: &str) -> std::io::Result<Take<File>> {
    check_regular(&std::fs::metadata(path)?, what)?;
    let file = open_nonblocking(path)?;
    let meta = file.metadata()?;
    check_regular(&meta, what)?;
    if meta.len() > max_bytes {
        return Err(Error::new(
            ErrorKind::InvalidInput,
            format!(
                "holds {} bytes, more than a {what}'s {max_bytes}",
                meta.len()
            ),
        ));
    }
    Ok(file.take(max_bytes.saturating_add(1)))
}

#[cfg(unix)]
fn open_nonblocking(path: &Path) -> std::io::Result<File> {
    use std::os::unix::fs::OpenOptionsExt;
    // Non-blocking matters only for FIFOs, which are refused once opened; regular files
    // ignore the flag.
    std::fs::OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NONBLOCK)
        .open(path)
}

#[cfg(not(unix))]
fn open_nonblocking(path: &Path) -> std::io::Result<File> {
    File::open(path)
}

fn check_regular(meta: &Metadata, what: &str) -> std::io::Result<()> {
    if meta.is_file() {
        return Ok(());
    }
    if meta.is_dir() {
        return Err(Error::new(
            ErrorKind::IsADirectory,
            format!("is a directory, expected a {what}"),
        ));
    }
    Err(Error::new(
        ErrorKind::InvalidInput,
        format!(
            "is {}, expected a regular {what}; refusing to read it",
            kind(meta)
        ),
    ))
}

/// Writes `path` through `write` (given a buffered writer to a temporary file beside it)
/// and renames the temporary file over `path` once `write` and the flush to disk succeed;
/// on any failure the temporary file is removed and `path` is left as it was.
///
/// # Errors
/// `write`'s error, or an `io::Error` (converted into `E`): `IsADirectory` or
/// `InvalidInput` when `path` exists and is a folder or a special file (checked before
/// anything is written and again before the rename), else the operating system's.
pub fn write_atomically<E: From<Error>>(
    path: &Path,
    write: impl FnOnce(&mut BufWriter<File>) -> Result<(), E>,
) -> Result<(), E> {
    check_target(path)?;
    if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent).map_err(|e| {
            Error::new(
                e.kind(),
                format!("cannot create folder {}: {e}", parent.display()),
            )
        })?;
    }
    let (file, temporary) = create_temporary_beside(path)?;
    let result = (|| {
        let mut w = BufWriter::new(file);
        write(&mut w)?;
        w.flush()?;
        w.into_inner().map_err(|e| e.into_error())?.sync_all()?;
        check_target(path)?; // again: it may have changed while the data was written
        Ok(std::fs::rename(&temporary, path)?)
    })();
    if result.is_err() {
        // Best effort: the error being reported matters more than a leftover file.
        let _ = std::fs::remove_file(&temporary);
    }
    result
}

/// Refuses a target that exists and is neither a regular file nor a symlink (which is
/// replaced, not followed).
fn check_target(path: &Path) -> std::io::Result<()> {
    let meta = match std::fs::symlink_metadata(path) {
        Ok(meta) => meta,
        // A parent that is a file: reported when the parents are created, naming it.
        Err(e) if matches!(e.kind(), ErrorKind::NotFound | ErrorKind::NotADirectory) => {
            return Ok(())
        }
        Err(e) => return Err(e),
    };
    if meta.is_file() || meta.file_type().is_symlink() {
        return Ok(());
    }
    if meta.is_dir() {
        return Err(Error::new(
            ErrorKind::IsADirectory,
            "is a directory, not a file to write",
        ));
    }
    Err(Error::new(
        ErrorKind::InvalidInput,
        format!(
            "is {}, not a regular file; refusing to replace it",
            kind(&meta)
        ),
    ))
}

#[cfg(unix)]
fn kind(meta: &Metadata) -> &'static str {
    use std::os::unix::fs::FileTypeExt;
    let t = meta.file_type();
    if t.is_fifo() {
        "a FIFO"
    } else if t.is_char_device() {
        "a character device"
    } else if t.is_block_device() {
        "a block device"
    } else if t.is_socket() {
        "a socket"
    } else {
        "not a regular file"
    }
}

#[cfg(not(unix))]
fn kind(_meta: &Metadata) -> &'static str {
    "not a regular file"
}

/// A new file beside `path`, named `.<name>.<random>.tmp` and created exclusively (never an
/// existing file or a link), with its name.
fn create_temporary_beside(path: &Path) -> std::io::Result<(File, PathBuf)> {
    let name = path
        .file_name()
        .ok_or_else(|| Error::new(ErrorKind::InvalidInput, "names no file"))?
        .to_string_lossy()
        .into_owned();
    let mut last_error = None;
    // A name taken by chance (or planted) is skipped; a few draws find a free one.
    for _ in 0..8 {
        let temporary = path.with_file_name(format!(".{name}.{:016x}.tmp", random_u64()));
        match std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&temporary)
        {
            Ok(file) => return Ok((file, temporary)),
            Err(e) if e.kind() == ErrorKind::AlreadyExists => last_error = Some(e),
            Err(e) => return Err(e),
        }
    }
    Err(last_error.expect("at least one attempt"))
}

/// 64 random bits from the standard library: each `RandomState` draws new keys, seeded
/// from the operating system's randomness.
fn random_u64() -> u64 {
    use std::hash::{BuildHasher, Hasher};
    std::collections::hash_map::RandomState::new()
        .build_hasher()
        .finish()
}

#[cfg(test)]
mod tests;
