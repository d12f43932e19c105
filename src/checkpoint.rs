//! Checkpoint files: a run's whole state on disk, to resume it bit for bit.
//!
//! Layout (little-endian):
//!
//! ```text
//! 0   8 bytes   magic "CLEAVECK"
//! 8   u32       format version (FORMAT_VERSION)
//! 12  u64       payload length (bytes)
//! 20  u32       CRC-32 of the payload
//! 24  payload   postcard (serde) encoding of the state
//! ```
//!
//! A file of another version, a truncated file and a file whose payload
//! does not match its checksum are refused with an error naming the file
//! and the problem, before anything is decoded. A checkpoint is written to
//! a temporary file beside it, flushed to disk and renamed over the old
//! one, so a process killed at any moment leaves either the old checkpoint
//! or the new one, never a partial file. The format is versioned as a
//! whole: any change to a serialized type bumps [`FORMAT_VERSION`].
//! Checkpoints are trusted files (as a run's own output): the checksum
//! catches damage, not a crafted file.

use std::io::Write;
use std::path::{Path, PathBuf};

use thiserror::Error;

/// The file's first bytes.
pub const MAGIC: [u8; 8] = *b"CLEAVECK";

/// The version of the format and of every type it stores.
pub const FORMAT_VERSION: u32 = 8;

/// Bytes before the payload.
const HEADER: usize = 24;

/// A checkpoint that cannot be written or read.
#[derive(Debug, Error)]
pub enum CheckpointError {
    /// The file could not be read or written.
    #[error("{}: {source}", .path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// The file does not start with the checkpoint magic.
    #[error("{}: not a cleave checkpoint (no CLEAVECK header)", .path.display())]
    NotACheckpoint {
        /// The file.
        path: PathBuf,
    },
    /// The file was written by another version of the format.
    #[error("{}: checkpoint format version {found}, this cleave reads version {expected}", .path.display())]
    Version {
        /// The file.
        path: PathBuf,
        /// The file's version.
        found: u32,
        /// The version this build reads and writes.
        expected: u32,
    },
    /// The file is shorter than its header says.
    #[error("{}: truncated checkpoint: {found} payload bytes of {expected}", .path.display())]
    Truncated {
        /// The file.
        path: PathBuf,
        /// Payload bytes the header announces.
        expected: u64,
        /// Payload bytes present.
        found: u64,
    },
    /// The payload does not match its checksum, or carries trailing bytes.
    #[error("{}: damaged checkpoint: {problem}", .path.display())]
    Damaged {
        /// The file.
        path: PathBuf,
        /// What does not match.
        problem: String,
    },
    /// The state cannot be encoded or decoded.
    #[error("{}: checkpoint state: {message}", .path.display())]
    Encoding {
        /// The file.
        path: PathBuf,
        /// The encoder's message.
        message: String,
    },
}

/// Writes `state` to `path` atomically (temporary file, flush, rename).
pub fn write<T: serde::Serialize>(path: &Path, state: &T) -> Result<(), CheckpointError> {
    let encoding = |e: postcard::Error| CheckpointError::Encoding { path: path.to_path_buf(), message: e.to_string() };
    let payload = postcard::to_stdvec(state).map_err(encoding)?;
    let mut bytes = Vec::with_capacity(HEADER + payload.len());
    bytes.extend_from_slice(&MAGIC);
    bytes.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
    bytes.extend_from_slice(&(payload.len() as u64).to_le_bytes());
    bytes.extend_from_slice(&crc32fast::hash(&payload).to_le_bytes());
    bytes.extend_from_slice(&payload);
    let mut temporary = path.as_os_str().to_owned();
    temporary.push(".partial");
    let temporary = PathBuf::from(temporary);
    let io = |source| CheckpointError::Io { path: path.to_path_buf(), source };
    let mut file = std::fs::File::create(&temporary).map_err(io)?;
    file.write_all(&bytes).map_err(io)?;
    file.sync_all().map_err(io)?;
    drop(file);
    std::fs::rename(&temporary, path).map_err(io)
}

/// Reads a checkpoint written by [`write()`].
pub fn read<T: serde::de::DeserializeOwned>(path: &Path) -> Result<T, CheckpointError> {
    let bytes = std::fs::read(path).map_err(|source| CheckpointError::Io { path: path.to_path_buf(), source })?;
    decode(path, &bytes)
}

/// Decodes the bytes of a checkpoint file (`path` names it in errors).
pub fn decode<T: serde::de::DeserializeOwned>(path: &Path, bytes: &[u8]) -> Result<T, CheckpointError> {
    let path = path.to_path_buf();
    if bytes.len() < 12 || bytes[..8] != MAGIC {
        return Err(CheckpointError::NotACheckpoint { path });
    }
    let word = |at: usize| u32::from_le_bytes(bytes[at..at + 4].try_into().expect("4 bytes"));
    let found = word(8);
    if found != FORMAT_VERSION {
        return Err(CheckpointError::Version { path, found, expected: FORMAT_VERSION });
    }
    if bytes.len() < HEADER {
        return Err(CheckpointError::Truncated { path, expected: 0, found: 0 });
    }
    let expected = u64::from_le_bytes(bytes[12..20].try_into().expect("8 bytes"));
    let payload = &bytes[HEADER..];
    if (payload.len() as u64) < expected {
        return Err(CheckpointError::Truncated { path, expected, found: payload.len() as u64 });
    }
    if payload.len() as u64 > expected {
        let problem = format!("{} bytes after the payload", payload.len() as u64 - expected);
        return Err(CheckpointError::Damaged { path, problem });
    }
    let (stored, actual) = (word(20), crc32fast::hash(payload));
    if stored != actual {
        let problem = format!("payload checksum {actual:08x}, header says {stored:08x}");
        return Err(CheckpointError::Damaged { path, problem });
    }
    let (state, rest) = postcard::take_from_bytes(payload)
        .map_err(|e| CheckpointError::Encoding { path: path.clone(), message: e.to_string() })?;
    if !rest.is_empty() {
        let problem = format!("{} payload bytes left over after the state", rest.len());
        return Err(CheckpointError::Damaged { path, problem });
    }
    Ok(state)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_refusals() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("c.bin");
        let state = (vec![1.5f64, -0.0, f64::MIN_POSITIVE], String::from("scene"), 7usize);
        write(&path, &state).unwrap();
        let back: (Vec<f64>, String, usize) = read(&path).unwrap();
        assert_eq!(
            back.0.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
            state.0.iter().map(|v| v.to_bits()).collect::<Vec<_>>()
        );
        assert_eq!((back.1, back.2), (state.1, state.2));
        assert!(!dir.path().join("c.bin.partial").exists());
        let bytes = std::fs::read(&path).unwrap();
        let refuse = |b: &[u8]| decode::<(Vec<f64>, String, usize)>(&path, b).unwrap_err().to_string();
        assert!(refuse(&bytes[..bytes.len() - 3]).contains("truncated"), "{}", refuse(&bytes[..bytes.len() - 3]));
        assert!(refuse(&bytes[..10]).contains("not a cleave checkpoint"));
        let mut other = bytes.clone();
        other[8] = 99;
        assert!(refuse(&other).contains("version 99"));
        let mut flipped = bytes.clone();
        *flipped.last_mut().unwrap() ^= 1;
        assert!(refuse(&flipped).contains("checksum"));
        let mut longer = bytes.clone();
        longer.push(0);
        assert!(refuse(&longer).contains("after the payload"));
        assert!(refuse(b"").contains("not a cleave checkpoint"));
    }
}
