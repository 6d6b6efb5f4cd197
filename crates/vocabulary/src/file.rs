//! Opening vocabulary files: checked for type and size before a byte is read.

use std::fs::File;
use std::io::Take;
use std::path::Path;

/// Largest vocabulary file read, bytes. ORB-SLAM's DBoW2 text vocabulary (1M words) is
/// 139 MB and the shipped binary one 3.4 MiB; a cap keeps a wrong path from exhausting memory.
pub const MAX_FILE_BYTES: u64 = 1 << 30;

/// `path` opened for reading through [`ferroslam_files::open_regular`]: a regular file of at
/// most [`MAX_FILE_BYTES`] (a device such as `/dev/zero` would be read until memory runs
/// out, and opening a FIFO blocks until a writer comes).
///
/// # Errors
/// The operating system's error, or `InvalidInput` naming the path and what is wrong.
pub(crate) fn open_regular_file(path: &Path) -> std::io::Result<Take<File>> {
    ferroslam_files::open_regular(path, MAX_FILE_BYTES, "vocabulary file")
}
