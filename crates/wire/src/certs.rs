//! TLS files for one run: a fresh certificate authority and one certificate it signs, usable
//! by the learner and selector as their gRPC server certificate (`[cluster] tls_cert`,
//! `tls_key`) and verified by every client with `tls_ca`.
//!
//! The CA's private key is used once and never written: nobody, this tool included, can sign
//! another certificate of the run, so a run's folder of certificates is the whole of its trust.
//! To add a host, make a new folder and hand it to every process. ECDSA P-256 keys (rcgen).

use std::path::{Path, PathBuf};

use rcgen::{
    BasicConstraints, CertificateParams, DistinguishedName, DnType, ExtendedKeyUsagePurpose, IsCa,
    Issuer, KeyPair, KeyUsagePurpose,
};

/// Why the certificates could not be made.
#[derive(Debug, thiserror::Error)]
pub enum CertError {
    /// No host names or addresses were given, or one is empty.
    #[error("certificates need at least one host name or IP address, none of them empty")]
    NoHosts,
    /// A host is neither an IP address nor a valid DNS name (RFC 1035 letters, digits and
    /// hyphens; labels of 1–63 characters; at most 253 in all), or the common name is longer
    /// than X.509's 64 characters.
    #[error("`{name}` is not usable in a certificate: {reason}")]
    BadName {
        /// The name as given.
        name: String,
        /// What is wrong with it.
        reason: String,
    },
    /// rcgen refused a name or failed to sign.
    #[error("cannot make the certificate: {0}")]
    Generate(#[from] rcgen::Error),
    /// A file could not be written.
    #[error("cannot write {path}: {source}")]
    Write {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
}

/// The three files [`write_run_certificates`] writes.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RunCertificates {
    /// `ca.pem`: the CA's certificate (`tls_ca`).
    pub ca: PathBuf,
    /// `cert.pem`: the run's certificate, signed by the CA (`tls_cert`).
    pub cert: PathBuf,
    /// `key.pem`: its private key (`tls_key`), written with mode 0600.
    pub key: PathBuf,
}

/// Makes a CA and a certificate it signs for `hosts` (DNS names and IP addresses, each a
/// subject alternative name, valid for server and client authentication) and writes
/// `ca.pem`, `cert.pem` and `key.pem` into `dir` (created if missing; existing files are
/// replaced). The common name of the certificate is `common_name`.
///
/// # Errors
/// [`CertError::NoHosts`] for an empty host list or an empty host; [`CertError::Generate`]
/// for a name rcgen cannot encode; [`CertError::Write`] when `dir` or a file cannot be written.
pub fn write_run_certificates(
    dir: &Path,
    common_name: &str,
    hosts: &[String],
) -> Result<RunCertificates, CertError> {
    if hosts.is_empty() || hosts.iter().any(|h| h.trim().is_empty()) {
        return Err(CertError::NoHosts);
    }
    for h in hosts {
        check_host(h)?;
    }
    if common_name.is_empty() || common_name.chars().count() > 64 {
        return Err(CertError::BadName {
            name: common_name.to_string(),
            reason: "a common name has 1 to 64 characters".into(),
        });
    }
    let mut ca_params = CertificateParams::new(Vec::<String>::new())?;
    ca_params.is_ca = IsCa::Ca(BasicConstraints::Constrained(0));
    ca_params.key_usages = vec![KeyUsagePurpose::KeyCertSign, KeyUsagePurpose::CrlSign];
    let mut ca_name = DistinguishedName::new();
    ca_name.push(DnType::CommonName, format!("{common_name} CA"));
    ca_params.distinguished_name = ca_name;
    let ca_key = KeyPair::generate()?;
    let ca_cert = ca_params.self_signed(&ca_key)?;
    let issuer = Issuer::new(ca_params, ca_key);

    let mut params = CertificateParams::new(hosts.to_vec())?;
    let mut name = DistinguishedName::new();
    name.push(DnType::CommonName, common_name);
    params.distinguished_name = name;
    params.key_usages = vec![KeyUsagePurpose::DigitalSignature];
    params.extended_key_usages = vec![
        ExtendedKeyUsagePurpose::ServerAuth,
        ExtendedKeyUsagePurpose::ClientAuth,
    ];
    let key = KeyPair::generate()?;
    let cert = params.signed_by(&key, &issuer)?;

    std::fs::create_dir_all(dir).map_err(|source| CertError::Write {
        path: dir.to_path_buf(),
        source,
    })?;
    let files = RunCertificates {
        ca: dir.join("ca.pem"),
        cert: dir.join("cert.pem"),
        key: dir.join("key.pem"),
    };
    // All three are written beside their names first and renamed only when all are there, the
    // key first: a failure leaves the folder's old set as it was and no temporary behind.
    let mut parts = Vec::new();
    for (path, text, mode) in [
        (&files.key, key.serialize_pem(), 0o600),
        (&files.cert, cert.pem(), 0o644),
        (&files.ca, ca_cert.pem(), 0o644),
    ] {
        match write_part(path, &text, mode) {
            Ok(part) => parts.push((part, path.clone())),
            Err(e) => {
                for (part, _) in &parts {
                    let _ = std::fs::remove_file(part);
                }
                return Err(e);
            }
        }
    }
    // The old files stay reachable under a second name until all three new ones are in place.
    let backup = |p: &Path| p.with_extension(format!("{}.old", std::process::id()));
    let mut kept = Vec::new();
    let undo = |parts: &[(PathBuf, PathBuf)], kept: &[PathBuf], replaced: &[PathBuf]| {
        for (part, _) in parts {
            let _ = std::fs::remove_file(part);
        }
        for path in replaced {
            if kept.contains(path) {
                let _ = std::fs::rename(backup(path), path);
            }
        }
        for path in kept {
            let _ = std::fs::remove_file(backup(path));
        }
    };
    for (_, path) in &parts {
        if std::fs::symlink_metadata(path).is_ok_and(|m| m.is_file()) {
            if let Err(source) = std::fs::hard_link(path, backup(path)) {
                undo(&parts, &kept, &[]);
                return Err(CertError::Write {
                    path: path.clone(),
                    source,
                });
            }
            kept.push(path.clone());
        }
    }
    let mut replaced = Vec::new();
    for (part, path) in &parts {
        if let Err(source) = std::fs::rename(part, path) {
            undo(&parts, &kept, &replaced);
            return Err(CertError::Write {
                path: path.clone(),
                source,
            });
        }
        replaced.push(path.clone());
    }
    for path in &kept {
        let _ = std::fs::remove_file(backup(path));
    }
    Ok(files)
}

/// An IP address, or a DNS name of RFC 1035 labels (a leading `*.` wildcard allowed).
fn check_host(h: &str) -> Result<(), CertError> {
    let bad = |reason: &str| {
        Err(CertError::BadName {
            name: h.to_string(),
            reason: reason.to_string(),
        })
    };
    if h.parse::<std::net::IpAddr>().is_ok() {
        return Ok(());
    }
    if h.len() > 253 {
        return bad("a DNS name has at most 253 characters");
    }
    let labels: Vec<&str> = h.strip_prefix("*.").unwrap_or(h).split('.').collect();
    if labels.iter().all(|l| l.chars().all(|c| c.is_ascii_digit())) {
        return bad("neither an IP address nor a DNS name (all-digit labels)");
    }
    for l in labels {
        if l.is_empty() || l.len() > 63 {
            return bad("every dot-separated label of a DNS name has 1 to 63 characters");
        }
        if !l.chars().all(|c| c.is_ascii_alphanumeric() || c == '-') {
            return bad(
                "a DNS name has letters, digits, hyphens and dots only (no port, scheme, \
                 brackets or spaces: give an address as 10.0.0.1 or ::1)",
            );
        }
        if l.starts_with('-') || l.ends_with('-') {
            return bad("a DNS label does not start or end with a hyphen");
        }
    }
    Ok(())
}

/// Writes `text` to `<path>.<pid>.part` with `mode` (synced) and returns that path; the caller
/// renames it to `path`, so a reader never sees half a file and a key is never readable by
/// others, even for a moment. On error no temporary is left.
fn write_part(path: &Path, text: &str, mode: u32) -> Result<PathBuf, CertError> {
    use std::io::Write;
    use std::os::unix::fs::OpenOptionsExt;
    let err = |source| CertError::Write {
        path: path.to_path_buf(),
        source,
    };
    let part = path.with_extension(format!("{}.part", std::process::id()));
    let mut file = std::fs::OpenOptions::new()
        .write(true)
        .create(true)
        .truncate(true)
        .mode(mode)
        .open(&part)
        .map_err(err)?;
    if let Err(e) = file
        .write_all(text.as_bytes())
        .and_then(|()| file.sync_all())
    {
        let _ = std::fs::remove_file(&part);
        return Err(err(e));
    }
    Ok(part)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::os::unix::fs::PermissionsExt;

    #[test]
    fn names_a_certificate_cannot_match_are_refused() {
        let dir = std::env::temp_dir().join(format!("terl-certs-bad-{}", std::process::id()));
        for bad in [
            "10.0.0.1:50051",
            "[::1]",
            "https://h",
            "a b",
            "a\nb",
            "999.1.1.1",
            "-x.example",
            "a..b",
            &"x".repeat(64),
            &format!("{}.example", "a.".repeat(130)),
        ] {
            let e = write_run_certificates(&dir, "terl run", &[bad.to_string()]).unwrap_err();
            assert!(matches!(e, CertError::BadName { .. }), "{bad}: {e}");
        }
        let e = write_run_certificates(&dir, &"c".repeat(65), &["h".to_string()]).unwrap_err();
        assert!(matches!(e, CertError::BadName { .. }), "{e}");
        assert!(!dir.exists(), "nothing is written for a refused name");
        for good in [
            "terl-learner",
            "*.svc.cluster.local",
            "::1",
            "10.0.0.1",
            "a-1.b2",
        ] {
            check_host(good).unwrap();
        }
    }

    #[test]
    fn a_failed_write_keeps_the_old_set_and_leaves_no_temporary() {
        let dir = std::env::temp_dir().join(format!("terl-certs-keep-{}", std::process::id()));
        let hosts = vec!["h".to_string()];
        let old = write_run_certificates(&dir, "terl run", &hosts).unwrap();
        let before: Vec<String> = [&old.ca, &old.cert, &old.key]
            .iter()
            .map(|p| std::fs::read_to_string(p).unwrap())
            .collect();
        // cert.pem's name taken by a non-empty folder: its rename fails.
        std::fs::remove_file(&old.cert).unwrap();
        std::fs::create_dir_all(old.cert.join("x")).unwrap();
        assert!(write_run_certificates(&dir, "terl run", &hosts).is_err());
        assert_eq!(std::fs::read_to_string(&old.ca).unwrap(), before[0]);
        assert_eq!(
            std::fs::read_to_string(&old.key).unwrap(),
            before[2],
            "the key is put back"
        );
        let names: Vec<String> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        assert!(
            names
                .iter()
                .all(|n| !n.ends_with(".part") && !n.ends_with(".old")),
            "{names:?}"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn writes_a_ca_a_certificate_and_a_private_key() {
        let dir = std::env::temp_dir().join(format!("terl-certs-{}", std::process::id()));
        let hosts = vec!["terl-learner".to_string(), "10.0.0.1".to_string()];
        let files = write_run_certificates(&dir, "terl run", &hosts).unwrap();
        for f in [&files.ca, &files.cert] {
            let text = std::fs::read_to_string(f).unwrap();
            assert!(text.starts_with("-----BEGIN CERTIFICATE-----"), "{text}");
        }
        let key = std::fs::read_to_string(&files.key).unwrap();
        assert!(key.starts_with("-----BEGIN PRIVATE KEY-----"));
        let mode = std::fs::metadata(&files.key).unwrap().permissions().mode();
        assert_eq!(mode & 0o777, 0o600);
        let again = write_run_certificates(&dir.join("again"), "terl run", &hosts).unwrap();
        assert_ne!(
            std::fs::read(&again.ca).unwrap(),
            std::fs::read(&files.ca).unwrap(),
            "every run gets its own CA"
        );
        assert_ne!(
            std::fs::read(&files.ca).unwrap(),
            std::fs::read(&files.cert).unwrap()
        );
        assert!(std::fs::read_dir(&dir).unwrap().all(|e| !e
            .unwrap()
            .file_name()
            .to_string_lossy()
            .ends_with(".part")));
        std::fs::remove_dir_all(&dir).unwrap();
        assert!(matches!(
            write_run_certificates(&dir, "x", &[]),
            Err(CertError::NoHosts)
        ));
        assert!(matches!(
            write_run_certificates(&dir, "x", &[" ".into()]),
            Err(CertError::NoHosts)
        ));
    }
}
