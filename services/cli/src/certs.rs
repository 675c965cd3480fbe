//! `terl certs`: the TLS files of one run's gRPC control plane (a fresh CA, one certificate it
//! signs for the given hosts, its key: [`terl_wire::certs::write_run_certificates`]).

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result};
use clap::Args;

#[derive(Debug, Args)]
pub struct CertsArgs {
    /// Folder for ca.pem, cert.pem and key.pem (created; existing files are replaced).
    #[arg(long, value_name = "DIR")]
    out: PathBuf,
    /// A host name or IP address the learner and selector are reached by (repeatable), e.g.
    /// their host's address or the Kubernetes Service terl-learner. localhost and 127.0.0.1
    /// are always included.
    #[arg(long = "host", value_name = "NAME_OR_IP")]
    hosts: Vec<String>,
    /// The certificate's common name.
    #[arg(long, default_value = "terl run")]
    common_name: String,
}

pub fn run(args: CertsArgs) -> Result<ExitCode> {
    let mut hosts = vec!["localhost".to_string(), "127.0.0.1".to_string()];
    for h in args.hosts {
        if !hosts.contains(&h) {
            hosts.push(h);
        }
    }
    let files = terl_wire::certs::write_run_certificates(&args.out, &args.common_name, &hosts)
        .with_context(|| format!("cannot make the certificates in {}", args.out.display()))?;
    // Absolute paths: a run file is read by processes started from other folders.
    let absolute = |p: PathBuf| std::fs::canonicalize(&p).unwrap_or(p);
    let files = terl_wire::certs::RunCertificates {
        ca: absolute(files.ca),
        cert: absolute(files.cert),
        key: absolute(files.key),
    };
    eprintln!(
        "wrote {}, {} and {} (certificate for {}); the learner and selector need all three, \
         every other process of the run the CA",
        files.ca.display(),
        files.cert.display(),
        files.key.display(),
        hosts.join(", ")
    );
    println!(
        "[cluster]\ntls_ca = \"{}\"\ntls_cert = \"{}\"\ntls_key = \"{}\"",
        files.ca.display(),
        files.cert.display(),
        files.key.display()
    );
    Ok(ExitCode::SUCCESS)
}
