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
    write_file(&files.ca, &ca_cert.pem(), 0o644)?;
    write_file(&files.cert, &cert.pem(), 0o644)?;
    write_file(&files.key, &key.serialize_pem(), 0o600)?;
    Ok(files)
}

/// Writes `text` to `<path>.<pid>.part` with `mode`, then renames it to `path`, so a reader
/// never sees half a file and a key is never readable by others, even for a moment.
fn write_file(path: &Path, text: &str, mode: u32) -> Result<(), CertError> {
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
    file.write_all(text.as_bytes())
        .and_then(|()| file.sync_all())
        .map_err(err)?;
    std::fs::rename(&part, path).map_err(err)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::os::unix::fs::PermissionsExt;

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
