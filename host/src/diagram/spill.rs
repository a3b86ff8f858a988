//! Bytes kept until they are read back: in memory, or in a file of the
//! process's own ([`Spill::to_file`]) whose pages the system may write
//! out and drop, so that what a rank of a distributed run must keep until
//! it writes its rows does not stay in its memory.
//!
//! The file is made in the directory the caller names and unlinked at
//! once where the system allows (it lives while it is open: nothing is
//! left behind, even by a process that is killed), else removed when the
//! store is dropped.

use crate::error::{Error, Result};
use std::path::{Path, PathBuf};

/// An append-only store of bytes, read back at the offsets
/// [`Spill::append`] returned.
pub(crate) enum Spill {
    /// Each appended run of bytes, with the offset it starts at.
    Memory { runs: Vec<(u64, Vec<u8>)>, len: u64 },
    /// A file of this process's own.
    File { file: std::fs::File, path: PathBuf, unlinked: bool, len: u64 },
}

impl Default for Spill {
    fn default() -> Self {
        Self::Memory { runs: Vec::new(), len: 0 }
    }
}

impl Spill {
    /// A store in a new file in `dir`, named for this process and `tag`.
    pub(crate) fn to_file(dir: &Path, tag: &str) -> Result<Self> {
        static MADE: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
        let made = MADE.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let path = dir.join(format!(".cvd-spill-{}-{tag}-{made}", std::process::id()));
        let file = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .create_new(true)
            .open(&path)
            .map_err(|source| Error::Write { path: path.display().to_string(), source })?;
        let unlinked = std::fs::remove_file(&path).is_ok();
        Ok(Self::File { file, path, unlinked, len: 0 })
    }

    /// Where the bytes are kept, for the messages: a file's path, or
    /// "memory".
    pub(crate) fn place(&self) -> String {
        match self {
            Self::Memory { .. } => "memory".into(),
            Self::File { path, .. } => path.display().to_string(),
        }
    }

    /// Appends `bytes`; returns the offset they start at.
    pub(crate) fn append(&mut self, bytes: Vec<u8>) -> Result<u64> {
        match self {
            Self::Memory { runs, len } => {
                let at = *len;
                *len += bytes.len() as u64;
                if !bytes.is_empty() {
                    runs.push((at, bytes));
                }
                Ok(at)
            }
            Self::File { file, path, len, .. } => {
                let at = *len;
                write_at(file, &bytes, at)
                    .map_err(|source| Error::Write { path: path.display().to_string(), source })?;
                *len += bytes.len() as u64;
                Ok(at)
            }
        }
    }

    /// The `len` bytes at `at`, into `buf` (cleared first).
    pub(crate) fn read(&self, at: u64, len: usize, buf: &mut Vec<u8>) -> Result<()> {
        buf.clear();
        match self {
            Self::Memory { runs, .. } => {
                let r = runs.partition_point(|(start, _)| *start <= at).checked_sub(1);
                let bytes = r.map(|r| &runs[r]).and_then(|(start, run)| run.get((at - start) as usize..)?.get(..len));
                let bytes = bytes.ok_or_else(|| Error::Internal(format!("no {len} bytes kept at {at}")))?;
                buf.extend_from_slice(bytes);
                Ok(())
            }
            Self::File { file, path, .. } => {
                buf.resize(len, 0);
                read_at(file, buf, at).map_err(|source| Error::Io { path: path.display().to_string(), source })
            }
        }
    }
}

#[cfg(unix)]
fn write_at(file: &std::fs::File, bytes: &[u8], at: u64) -> std::io::Result<()> {
    std::os::unix::fs::FileExt::write_all_at(file, bytes, at)
}

#[cfg(unix)]
fn read_at(file: &std::fs::File, buf: &mut [u8], at: u64) -> std::io::Result<()> {
    std::os::unix::fs::FileExt::read_exact_at(file, buf, at)
}

// Elsewhere through the file's one position (a store is read by one
// thread at a time).
#[cfg(not(unix))]
fn write_at(mut file: &std::fs::File, bytes: &[u8], at: u64) -> std::io::Result<()> {
    use std::io::{Seek, Write};
    file.seek(std::io::SeekFrom::Start(at))?;
    file.write_all(bytes)
}

#[cfg(not(unix))]
fn read_at(mut file: &std::fs::File, buf: &mut [u8], at: u64) -> std::io::Result<()> {
    use std::io::{Read, Seek};
    file.seek(std::io::SeekFrom::Start(at))?;
    file.read_exact(buf)
}

impl Drop for Spill {
    fn drop(&mut self) {
        if let Self::File { path, unlinked: false, .. } = self {
            let _ = std::fs::remove_file(path);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Runs of bytes come back the same from memory and from a file, and
    /// the file leaves nothing behind.
    #[test]
    fn bytes_come_back_from_memory_and_from_a_file() {
        let dir = std::env::temp_dir().join(format!("cvd-spill-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let runs: Vec<Vec<u8>> = (0..5u8).map(|r| (0..(r as usize * 37 + 3)).map(|i| i as u8 ^ r).collect()).collect();
        for mut store in [Spill::default(), Spill::to_file(&dir, "test").unwrap()] {
            let mut at = Vec::new();
            for run in &runs {
                at.push(store.append(run.clone()).unwrap());
            }
            assert_eq!(store.append(Vec::new()).unwrap(), runs.iter().map(|r| r.len() as u64).sum::<u64>());
            let mut buf = Vec::new();
            for (run, &at) in runs.iter().zip(&at).rev() {
                store.read(at, run.len(), &mut buf).unwrap();
                assert_eq!(&buf, run, "{}", store.place());
                store.read(at + 1, run.len() - 2, &mut buf).unwrap();
                assert_eq!(&buf[..], &run[1..run.len() - 1]);
            }
            assert!(store.read(at[4], runs[4].len() + 1, &mut buf).is_err(), "past the end");
        }
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 0, "the spill file is gone");
        std::fs::remove_dir(&dir).unwrap();
    }
}
