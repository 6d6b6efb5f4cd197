//! Opening vocabulary files: checked for type and size before a byte is read.

use std::fs::File;
use std::io::{Error, ErrorKind, Read, Take};
use std::path::Path;

/// Largest vocabulary file read, bytes. ORB-SLAM's DBoW2 text vocabulary (1M words) is
/// 139 MB and the shipped binary one 3.4 MiB; a cap keeps a wrong path from exhausting memory.
pub const MAX_FILE_BYTES: u64 = 1 << 30;

/// `path` opened for reading if it is a regular file (after links) of at most
/// [`MAX_FILE_BYTES`]: a device such as `/dev/zero` would be read until memory runs out, and
/// opening a FIFO blocks until a writer comes.
///
/// # Errors
/// The operating system's error, or `InvalidInput` naming the path and what is wrong.
pub(crate) fn open_regular_file(path: &Path) -> std::io::Result<Take<File>> {
    let meta = std::fs::metadata(path)?;
    if !meta.is_file() {
        return Err(Error::new(
            ErrorKind::InvalidInput,
            format!("{} is not a regular file", path.display()),
        ));
    }
    if meta.len() > MAX_FILE_BYTES {
        return Err(Error::new(
            ErrorKind::InvalidInput,
            format!(
                "{} holds {} bytes, more than a vocabulary file's {MAX_FILE_BYTES}",
                path.display(),
                meta.len()
            ),
        ));
    }
    // Read no more than the cap even if the file grows meanwhile.
    Ok(File::open(path)?.take(MAX_FILE_BYTES + 1))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[cfg(unix)]
    #[test]
    fn devices_and_folders_are_refused_before_reading() {
        for path in ["/dev/zero", "/dev/null", "/"] {
            let err = open_regular_file(Path::new(path)).unwrap_err();
            assert_eq!(err.kind(), ErrorKind::InvalidInput, "{path}");
            assert!(err.to_string().contains("not a regular file"), "{err}");
        }
    }
}
