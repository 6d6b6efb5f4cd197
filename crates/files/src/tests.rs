use super::*;
use proptest::prelude::*;

/// A fresh empty folder under the system's temporary folder, removed on drop.
struct Scratch(PathBuf);

impl Scratch {
    fn new(name: &str) -> Self {
        let dir = std::env::temp_dir().join(format!(
            "ferroslam-files-{name}-{}-{:x}",
            std::process::id(),
            random_u64()
        ));
        std::fs::create_dir_all(&dir).unwrap();
        Scratch(dir)
    }

    fn entries(&self) -> Vec<String> {
        let mut names: Vec<String> = std::fs::read_dir(&self.0)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        names
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

#[cfg(unix)]
fn mkfifo(path: &Path) {
    use std::os::unix::ffi::OsStrExt;
    let c = std::ffi::CString::new(path.as_os_str().as_bytes()).unwrap();
    // SAFETY: a valid NUL-terminated path.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
}

#[cfg(unix)]
fn is_fifo(path: &Path) -> bool {
    use std::os::unix::fs::FileTypeExt;
    std::fs::symlink_metadata(path)
        .unwrap()
        .file_type()
        .is_fifo()
}

fn write_bytes(path: &Path, data: &[u8]) -> std::io::Result<()> {
    write_atomically(path, |w| w.write_all(data))
}

fn read_all(path: &Path) -> std::io::Result<Vec<u8>> {
    let mut bytes = Vec::new();
    open_regular(path, 1 << 20, "test file")?.read_to_end(&mut bytes)?;
    Ok(bytes)
}

#[cfg(unix)]
#[test]
fn special_files_and_folders_are_refused_before_reading() {
    let scratch = Scratch::new("read");
    let fifo = scratch.0.join("pipe");
    mkfifo(&fifo);
    for (path, kind, says) in [
        (
            Path::new("/dev/zero"),
            ErrorKind::InvalidInput,
            "a character device",
        ),
        (
            Path::new("/dev/null"),
            ErrorKind::InvalidInput,
            "a character device",
        ),
        (&fifo, ErrorKind::InvalidInput, "a FIFO"),
        (&scratch.0, ErrorKind::IsADirectory, "is a directory"),
    ] {
        let err = read_all(path).unwrap_err();
        assert_eq!(err.kind(), kind, "{}: {err}", path.display());
        assert!(err.to_string().contains(says), "{}: {err}", path.display());
    }
    let missing = read_all(&scratch.0.join("nothing")).unwrap_err();
    assert_eq!(missing.kind(), ErrorKind::NotFound);
}

#[test]
fn reading_is_bounded() {
    let scratch = Scratch::new("bound");
    let path = scratch.0.join("big");
    std::fs::write(&path, [7u8; 101]).unwrap();
    let err = open_regular(&path, 100, "vocabulary file").unwrap_err();
    assert_eq!(err.kind(), ErrorKind::InvalidInput);
    assert!(
        err.to_string()
            .contains("more than a vocabulary file's 100"),
        "{err}"
    );
    assert_eq!(read_all(&path).unwrap(), vec![7u8; 101]);
}

#[test]
fn writing_creates_parents_and_replaces_the_file() {
    let scratch = Scratch::new("write");
    let path = scratch.0.join("a").join("b").join("map.fslam");
    write_bytes(&path, b"first").unwrap();
    write_bytes(&path, b"second").unwrap();
    assert_eq!(std::fs::read(&path).unwrap(), b"second");
    assert_eq!(scratch.entries(), ["a"]);
    // The parent is a file: the error names the folder that cannot be created.
    let blocked = write_bytes(&path.join("under-a-file"), b"x").unwrap_err();
    assert!(
        blocked.to_string().contains("cannot create folder"),
        "{blocked}"
    );
    assert!(blocked.to_string().contains("map.fslam"), "{blocked}");
}

#[test]
fn a_failed_write_leaves_the_previous_file_and_no_temporary() {
    let scratch = Scratch::new("fail");
    let path = scratch.0.join("voc.bin");
    write_bytes(&path, b"complete").unwrap();
    let failed: Result<(), Error> = write_atomically(&path, |w| {
        w.write_all(b"half")?;
        Err(Error::other("disk full"))
    });
    assert_eq!(failed.unwrap_err().to_string(), "disk full");
    assert_eq!(std::fs::read(&path).unwrap(), b"complete");
    assert_eq!(scratch.entries(), ["voc.bin"]);
}

#[cfg(unix)]
#[test]
fn special_targets_are_refused_and_left_as_they_are() {
    let scratch = Scratch::new("special");
    let fifo = scratch.0.join("map.fslam");
    mkfifo(&fifo);
    let err = write_bytes(&fifo, b"x").unwrap_err();
    assert_eq!(err.kind(), ErrorKind::InvalidInput);
    assert!(
        err.to_string()
            .contains("is a FIFO, not a regular file; refusing"),
        "{err}"
    );
    assert!(is_fifo(&fifo));
    let folder = scratch.0.join("folder");
    std::fs::create_dir(&folder).unwrap();
    assert_eq!(
        write_bytes(&folder, b"x").unwrap_err().kind(),
        ErrorKind::IsADirectory
    );
    assert_eq!(scratch.entries(), ["folder", "map.fslam"]);
}

#[cfg(unix)]
#[test]
fn a_link_at_the_target_is_replaced_not_written_through() {
    let scratch = Scratch::new("link");
    let victim = scratch.0.join("victim.txt");
    std::fs::write(&victim, b"keep me").unwrap();
    let path = scratch.0.join("map.fslam");
    std::os::unix::fs::symlink(&victim, &path).unwrap();
    write_bytes(&path, b"map").unwrap();
    assert_eq!(std::fs::read(&victim).unwrap(), b"keep me");
    assert!(!std::fs::symlink_metadata(&path)
        .unwrap()
        .file_type()
        .is_symlink());
    assert_eq!(std::fs::read(&path).unwrap(), b"map");
}

proptest! {
    /// Whatever sequence of writes succeeds or fails, the file holds the last successful
    /// one and nothing else is left beside it.
    #[test]
    fn the_file_is_always_the_last_complete_write(
        writes in proptest::collection::vec((proptest::collection::vec(any::<u8>(), 0..64), any::<bool>()), 1..8)
    ) {
        let scratch = Scratch::new("prop");
        let path = scratch.0.join("out.bin");
        let mut expected: Option<Vec<u8>> = None;
        for (data, fails) in &writes {
            let result: Result<(), Error> = write_atomically(&path, |w| {
                w.write_all(data)?;
                if *fails { Err(Error::other("failed")) } else { Ok(()) }
            });
            prop_assert_eq!(result.is_ok(), !fails);
            if !fails {
                expected = Some(data.clone());
            }
        }
        match expected {
            Some(data) => {
                prop_assert_eq!(std::fs::read(&path).unwrap(), data);
                prop_assert_eq!(scratch.entries(), vec!["out.bin".to_string()]);
            }
            None => prop_assert!(scratch.entries().is_empty()),
        }
    }
}
