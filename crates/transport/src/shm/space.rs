//! Start-up check that the shared-memory filesystem can hold the run.
//!
//! Containers default to a 64 MiB `/dev/shm`; iceoryx2 would fail much later with an
//! opaque allocation error. This names the size needed and the fix instead.

use std::path::Path;

use crate::error::TransportError;

/// Where POSIX shared memory lives on Linux.
pub const SHM_PATH: &str = "/dev/shm";

/// Free bytes available to unprivileged users on the filesystem at `path`.
pub fn available_bytes(path: &Path) -> Result<u64, TransportError> {
    let stat = nix::sys::statvfs::statvfs(path).map_err(|e| TransportError::ShmUnavailable {
        path: path.display().to_string(),
        source: std::io::Error::from(e),
    })?;
    Ok(stat.blocks_available() as u64 * stat.fragment_size() as u64)
}

/// Fails with [`TransportError::ShmTooSmall`] when `path` has less than `required` bytes free.
pub fn check_free_space(path: &Path, required: u64) -> Result<u64, TransportError> {
    let available = available_bytes(path)?;
    if available < required {
        return Err(TransportError::ShmTooSmall {
            available_mib: available >> 20,
            required_mib: required.div_ceil(1 << 20),
        });
    }
    Ok(available)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reports_size_and_fix_when_too_small() {
        let err = check_free_space(Path::new(SHM_PATH), u64::MAX / 2).unwrap_err();
        let msg = err.to_string();
        assert!(msg.contains("MiB of shared memory"), "{msg}");
        assert!(msg.contains("--shm-size"), "{msg}");
    }

    #[test]
    fn small_requirement_passes() {
        assert!(check_free_space(Path::new(SHM_PATH), 1).is_ok());
    }

    #[test]
    fn missing_path_is_a_clear_error() {
        let err = available_bytes(Path::new("/definitely/not/here")).unwrap_err();
        assert!(err.to_string().contains("/definitely/not/here"));
    }
}
