//! Atomic file writes: a file is either absent, the old one or complete, never half-written.

use crate::error::{io_err, Error, Result};
use std::fs::File;
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};

/// `path` with `.tmp` appended: the temporary name [`write_atomic`] writes first.
pub fn tmp_beside(path: &Path) -> PathBuf {
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".tmp");
    PathBuf::from(tmp)
}

/// Writes `path` atomically: `body` writes into `tmp`, which is flushed (and with `durable` fsynced),
/// then renamed to `path` (and with `durable` the folder is fsynced, so the rename survives a crash). On
/// failure `tmp` is removed and the error carries the file that failed: `tmp` for the write, `path` for
/// the rename, the folder for its fsync.
pub fn write_atomic_to(
    path: &Path,
    tmp: &Path,
    durable: bool,
    body: impl FnOnce(&mut BufWriter<File>) -> io::Result<()>,
) -> std::result::Result<(), (PathBuf, io::Error)> {
    let written = File::create(tmp).and_then(|f| {
        let mut w = BufWriter::new(f);
        body(&mut w)?;
        w.flush()?;
        if durable {
            w.get_ref().sync_all()?;
        }
        Ok(())
    });
    if let Err(e) = written {
        let _ = std::fs::remove_file(tmp);
        return Err((tmp.to_path_buf(), e));
    }
    if let Err(e) = std::fs::rename(tmp, path) {
        let _ = std::fs::remove_file(tmp);
        return Err((path.to_path_buf(), e));
    }
    if durable {
        let dir = path
            .parent()
            .filter(|d| !d.as_os_str().is_empty())
            .unwrap_or(Path::new("."));
        File::open(dir)
            .and_then(|d| d.sync_all())
            .map_err(|e| (dir.to_path_buf(), e))?;
    }
    Ok(())
}

/// Writes `bytes` to `path` through `path.tmp` and a rename (not fsynced); the error names the file.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    write_atomic_to(path, &tmp_beside(path), false, |w| w.write_all(bytes)).map_err(|(p, e)| io_err(&p, e))
}

/// Creates the folder `dir` and checks that a file can be written in it (before a run writes anything).
pub fn ensure_writable(dir: &Path) -> Result<()> {
    std::fs::create_dir_all(dir)
        .map_err(|e| Error::Io(format!("output folder {}: cannot be created: {e}", dir.display())))?;
    let probe = dir.join(format!(".blockflow-write-check-{}", std::process::id()));
    std::fs::write(&probe, b"blockflow")
        .and_then(|_| std::fs::remove_file(&probe))
        .map_err(|e| Error::Io(format!("output folder {} is not writable: {e}", dir.display())))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_failed_write_leaves_the_old_file_and_no_tmp() {
        let dir = std::env::temp_dir().join(format!("blockflow-util-fs-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("a.txt");
        write_atomic(&p, b"old").unwrap();
        let r = write_atomic_to(&p, &tmp_beside(&p), true, |_| Err(io::Error::other("disk full")));
        assert_eq!(r.unwrap_err().0, tmp_beside(&p));
        assert_eq!(std::fs::read(&p).unwrap(), b"old");
        assert!(!tmp_beside(&p).exists());
        write_atomic_to(&p, &dir.join(".x.tmp"), true, |w| w.write_all(b"new")).unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"new");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
