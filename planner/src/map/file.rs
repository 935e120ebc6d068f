//! Bounded reading of input files (maps, scenarios, manifests): a size limit checked before
//! and while reading, and nothing but regular files.
//!
//! A path the user gives may be `/dev/zero` (reads forever), a FIFO (an `open` for reading
//! blocks until a writer appears, forever if none does), a device or a huge file. Each of them
//! must be a clear error, not a hang or an out-of-memory kill: the file is opened with
//! `O_NONBLOCK` (so opening a FIFO returns at once), checked with `fstat` on the open
//! descriptor (no race between the check and the read), refused unless it is a regular file,
//! refused if its size is over the limit, and read through a `take(limit + 1)` so a file that
//! grows while it is read still cannot exceed the limit.

use std::fs::File;
use std::io::{self, Read};
use std::path::Path;

/// Largest map file read: a 4096 × 4096 map (the grid's limit) with CRLF line ends and a
/// header fits with room to spare.
pub const MAX_MAP_BYTES: u64 =
    2 * (crate::grid::MAX_CELLS as u64 + 2 * crate::grid::MAX_SIDE as u64) + 64 * 1024;

/// Largest scenario file read (MovingAI's biggest `.scen` files are a few MB).
pub const MAX_SCEN_BYTES: u64 = 64 * 1024 * 1024;

/// Reads all of `path` if it is a regular file of at most `limit` bytes.
///
/// Errors (all `io::Error`s, kind in brackets): a directory
/// [`IsADirectory`](io::ErrorKind::IsADirectory), a FIFO, socket or device
/// [`InvalidInput`](io::ErrorKind::InvalidInput), larger than `limit`
/// [`FileTooLarge`](io::ErrorKind::FileTooLarge), and whatever `open`/`read` report. Never
/// blocks on a FIFO and never reads more than `limit + 1` bytes.
pub fn read_bounded(path: &Path, limit: u64) -> io::Result<Vec<u8>> {
    let file = open_nonblocking(path)?;
    let meta = file.metadata()?;
    let kind = meta.file_type();
    if kind.is_dir() {
        return Err(io::Error::new(
            io::ErrorKind::IsADirectory,
            "is a directory, not a file",
        ));
    }
    if !kind.is_file() {
        let what = if is_fifo(&kind) {
            "a FIFO (named pipe)"
        } else {
            "a device, socket or other special file"
        };
        return Err(io::Error::new(
            io::ErrorKind::InvalidInput,
            format!("is {what}, not a regular file"),
        ));
    }
    let too_large = |size: u64| {
        io::Error::new(
            io::ErrorKind::FileTooLarge,
            format!("is {size} bytes or more, larger than the limit of {limit} bytes"),
        )
    };
    if meta.len() > limit {
        return Err(too_large(meta.len()));
    }
    let mut bytes = Vec::with_capacity(meta.len() as usize);
    file.take(limit.saturating_add(1)).read_to_end(&mut bytes)?;
    if bytes.len() as u64 > limit {
        return Err(too_large(bytes.len() as u64));
    }
    Ok(bytes)
}

#[cfg(unix)]
fn open_nonblocking(path: &Path) -> io::Result<File> {
    use std::os::unix::fs::OpenOptionsExt;
    std::fs::OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NONBLOCK | libc::O_NOCTTY)
        .open(path)
}

#[cfg(not(unix))]
fn open_nonblocking(path: &Path) -> io::Result<File> {
    File::open(path)
}

#[cfg(unix)]
fn is_fifo(kind: &std::fs::FileType) -> bool {
    use std::os::unix::fs::FileTypeExt;
    kind.is_fifo()
}

#[cfg(not(unix))]
fn is_fifo(_: &std::fs::FileType) -> bool {
    false
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dir(tag: &str) -> std::path::PathBuf {
        let d = std::env::temp_dir().join(format!("qfleet-read-{tag}-{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn dev_zero_is_refused_without_reading() {
        let e = read_bounded(Path::new("/dev/zero"), 1024).unwrap_err();
        assert_eq!(e.kind(), io::ErrorKind::InvalidInput, "{e}");
        assert!(e.to_string().contains("not a regular file"), "{e}");
    }

    #[cfg(unix)]
    #[test]
    fn a_fifo_is_refused_at_once_instead_of_blocking() {
        let d = dir("fifo");
        let fifo = d.join("pipe");
        let c = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
        // SAFETY: a valid NUL-terminated path.
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
        // no writer exists: a blocking open would never return
        let e = read_bounded(&fifo, 1024).unwrap_err();
        assert!(e.to_string().contains("FIFO"), "{e}");
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn a_file_over_the_limit_is_refused_and_one_at_it_is_read() {
        let d = dir("limit");
        let f = d.join("big");
        std::fs::write(&f, vec![b'.'; 100]).unwrap();
        let e = read_bounded(&f, 99).unwrap_err();
        assert_eq!(e.kind(), io::ErrorKind::FileTooLarge, "{e}");
        assert_eq!(read_bounded(&f, 100).unwrap().len(), 100);
        let e = read_bounded(&d, 100).unwrap_err();
        assert!(e.to_string().contains("a directory"), "{e}");
        std::fs::remove_dir_all(&d).unwrap();
    }
}
