//! Who may talk to the control plane: a shared bearer token checked on every RPC and optional
//! TLS (rustls, via tonic).
//!
//! Servers bind `127.0.0.1` by default. Any other address needs a token ([`ServerSecurity`]
//! refuses to serve without one, naming the settings that provide it: the [`TOKEN_ENV`]
//! environment variable or the run file's `cluster.token_file`). The token travels as
//! `authorization: Bearer <token>` metadata, is compared in constant time (for equal lengths),
//! marked sensitive in HTTP/2 (never HPACK-indexed, shown as `Sensitive` by `Debug`), and never
//! printed: [`Token`]'s `Debug` is redacted and there is no `Display`.
//!
//! TLS is optional and independent of the token: a server with [`ServerTls`] speaks only TLS; a
//! client with [`ClientTls`] verifies the server's certificate against the given CA (the system's
//! roots are not used) and refuses plaintext.

use std::fmt;
use std::future::{ready, Ready};
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::task::{Context, Poll};

use futures_util::future::Either;
use subtle::ConstantTimeEq;
use tonic::codegen::http;
use tonic::metadata::{Ascii, MetadataValue};
use tonic::Status;

/// Environment variable that holds the control-plane token (it wins over `cluster.token_file`).
pub const TOKEN_ENV: &str = "TERL_TOKEN";

/// Shortest token accepted, bytes: a guessable token is no protection.
pub const MIN_TOKEN_BYTES: usize = 16;
/// Longest token accepted, bytes (and the largest token file read).
pub const MAX_TOKEN_BYTES: usize = 1024;
/// Largest certificate, key or CA file read, bytes.
pub const MAX_PEM_BYTES: u64 = 1 << 20;

/// RPCs that `status_without_token` leaves open: both services' `GetStatus` and health.
const STATUS_PATHS: [&str; 4] = [
    "/terl.v1.Learner/GetStatus",
    "/terl.v1.Selector/GetStatus",
    "/grpc.health.v1.Health/Check",
    "/grpc.health.v1.Health/Watch",
];

/// Why a security setting could not be used.
#[derive(Debug, thiserror::Error)]
pub enum SecurityError {
    /// A server would listen on a non-loopback address without a token.
    #[error(
        "refusing to serve the control plane on {addr} without a token: anyone who can reach \
         that address could read status, take checkpoints and download the weights. Set the \
         {TOKEN_ENV} environment variable or `token_file` in the run file's [cluster] section \
         (cluster.token_file), or bind a loopback address (127.0.0.1)"
    )]
    TokenRequired {
        /// The listen address.
        addr: SocketAddr,
    },
    /// A token is shorter than [`MIN_TOKEN_BYTES`], longer than [`MAX_TOKEN_BYTES`], holds
    /// characters other than visible ASCII, or (read from a file) is not UTF-8.
    #[error("invalid token ({source_name}): {reason}")]
    InvalidToken {
        /// Where the token came from (e.g. [`TOKEN_ENV`] or the token file's path); never the
        /// value.
        source_name: String,
        /// Which rule it breaks.
        reason: &'static str,
    },
    /// A token, certificate or key file could not be read.
    #[error("cannot read {what} {path}: {source}")]
    Read {
        /// The file's role, e.g. `"TLS key"`.
        what: &'static str,
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// A token, certificate or key file is larger than such a file can be.
    #[error("{what} {path} is {len} bytes; at most {max} expected")]
    TooLarge {
        /// The file's role, e.g. `"TLS certificate"`.
        what: &'static str,
        /// The file.
        path: PathBuf,
        /// Its size, bytes.
        len: u64,
        /// The limit, bytes.
        max: u64,
    },
    /// A certificate or key file holds no `-----BEGIN ` line.
    #[error("{what} {path} holds no PEM block (-----BEGIN ...)")]
    NotPem {
        /// The file's role, e.g. `"TLS CA certificate"`.
        what: &'static str,
        /// The file.
        path: PathBuf,
    },
}

/// The shared secret of a cluster's control plane: 16 to 1024 visible ASCII characters (no
/// spaces). Cheap to clone; `Debug` prints `Token(<redacted>)` and nothing else prints it.
#[derive(Clone)]
pub struct Token(Arc<str>);

impl fmt::Debug for Token {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("Token(<redacted>)")
    }
}

impl Token {
    /// Checks `value` (taken as is: no trimming). `source_name` says where it came from in
    /// errors (e.g. `TERL_TOKEN`), never the value.
    pub fn new(value: impl Into<String>, source_name: &str) -> Result<Self, SecurityError> {
        let value: String = value.into();
        let invalid = |reason| SecurityError::InvalidToken {
            source_name: source_name.to_owned(),
            reason,
        };
        if value.len() < MIN_TOKEN_BYTES {
            return Err(invalid("shorter than 16 characters"));
        }
        if value.len() > MAX_TOKEN_BYTES {
            return Err(invalid("longer than 1024 characters"));
        }
        if !value.bytes().all(|b| b.is_ascii_graphic()) {
            return Err(invalid(
                "use visible ASCII characters only (no spaces or control characters), e.g. \
                 the output of `openssl rand -hex 32`",
            ));
        }
        Ok(Self(value.into()))
    }

    /// Reads a token file: its content without trailing whitespace (so a final newline is
    /// fine). Files over [`MAX_TOKEN_BYTES`] + 64 bytes are refused before reading.
    pub fn from_file(path: &Path) -> Result<Self, SecurityError> {
        let text = read_bounded(path, "token file", MAX_TOKEN_BYTES as u64 + 64)?;
        let text = String::from_utf8(text).map_err(|_| SecurityError::InvalidToken {
            source_name: path.display().to_string(),
            reason: "the file is not UTF-8 text",
        })?;
        Self::new(text.trim_end(), &path.display().to_string())
    }

    /// The token itself, to hand to another authenticator of the same run (the Zenoh
    /// sessions' user/password authentication); never to be logged.
    pub fn expose(&self) -> &str {
        &self.0
    }

    /// The `authorization` metadata value, marked sensitive.
    fn header(&self) -> MetadataValue<Ascii> {
        let mut value = MetadataValue::try_from(format!("Bearer {}", self.0))
            .expect("a token is visible ASCII, a valid header value");
        value.set_sensitive(true);
        value
    }
}

fn read_bounded(path: &Path, what: &'static str, max: u64) -> Result<Vec<u8>, SecurityError> {
    let read_err = |source| SecurityError::Read {
        what,
        path: path.to_owned(),
        source,
    };
    let meta = std::fs::metadata(path).map_err(read_err)?;
    if !meta.is_file() {
        // A directory, a FIFO (would block), a device (/dev/zero never ends).
        return Err(read_err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            "not a regular file",
        )));
    }
    let too_large = |len| SecurityError::TooLarge {
        what,
        path: path.to_owned(),
        len,
        max,
    };
    if meta.len() > max {
        return Err(too_large(meta.len()));
    }
    // The size read is bounded too: the file may grow after the check.
    let mut bytes = Vec::new();
    std::io::Read::read_to_end(
        &mut std::io::Read::take(std::fs::File::open(path).map_err(read_err)?, max + 1),
        &mut bytes,
    )
    .map_err(read_err)?;
    if bytes.len() as u64 > max {
        return Err(too_large(bytes.len() as u64));
    }
    Ok(bytes)
}

fn read_pem(path: &Path, what: &'static str) -> Result<Vec<u8>, SecurityError> {
    let pem = read_bounded(path, what, MAX_PEM_BYTES)?;
    if !pem.windows(11).any(|w| w == b"-----BEGIN ") {
        return Err(SecurityError::NotPem {
            what,
            path: path.to_owned(),
        });
    }
    Ok(pem)
}

/// A server's TLS identity: certificate chain and private key, PEM. `Debug` shows only sizes.
#[derive(Clone)]
pub struct ServerTls {
    cert_pem: Vec<u8>,
    key_pem: Vec<u8>,
}

impl fmt::Debug for ServerTls {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("ServerTls")
            .field("cert_pem_bytes", &self.cert_pem.len())
            .field("key", &"<redacted>")
            .finish()
    }
}

impl ServerTls {
    /// From PEM text already in memory.
    pub fn from_pem(cert_pem: impl Into<Vec<u8>>, key_pem: impl Into<Vec<u8>>) -> Self {
        Self {
            cert_pem: cert_pem.into(),
            key_pem: key_pem.into(),
        }
    }

    /// Reads the certificate (chain) and key files (PEM, at most 1 MiB each).
    pub fn from_files(cert: &Path, key: &Path) -> Result<Self, SecurityError> {
        Ok(Self::from_pem(
            read_pem(cert, "TLS certificate")?,
            read_pem(key, "TLS key")?,
        ))
    }

    pub(crate) fn config(&self) -> tonic::transport::ServerTlsConfig {
        tonic::transport::ServerTlsConfig::new().identity(tonic::transport::Identity::from_pem(
            &self.cert_pem,
            &self.key_pem,
        ))
    }
}

/// What a client trusts: the CA certificate(s) the server's certificate must chain to, and
/// optionally the name to expect in it (default: the host of the address dialled; an IP
/// address must then be in the certificate's subject alternative names).
#[derive(Clone, Debug)]
pub struct ClientTls {
    ca_pem: Vec<u8>,
    /// Name the server certificate must be valid for, instead of the dialled host.
    pub domain: Option<String>,
}

impl ClientTls {
    /// From PEM text already in memory.
    pub fn from_pem(ca_pem: impl Into<Vec<u8>>, domain: Option<String>) -> Self {
        Self {
            ca_pem: ca_pem.into(),
            domain,
        }
    }

    /// Reads the CA file (PEM, at most 1 MiB).
    pub fn from_file(ca: &Path, domain: Option<String>) -> Result<Self, SecurityError> {
        Ok(Self::from_pem(read_pem(ca, "TLS CA certificate")?, domain))
    }

    pub(crate) fn config(&self) -> tonic::transport::ClientTlsConfig {
        let config = tonic::transport::ClientTlsConfig::new()
            .ca_certificate(tonic::transport::Certificate::from_pem(&self.ca_pem));
        match &self.domain {
            Some(d) => config.domain_name(d.clone()),
            None => config,
        }
    }
}

/// A server's access control. Default: no token, no TLS (loopback only).
#[derive(Clone, Debug, Default)]
pub struct ServerSecurity {
    /// Required on every RPC when set (health and reflection included).
    pub token: Option<Token>,
    /// With a token: leave `GetStatus` of both services and `grpc.health.v1` open to callers
    /// without one (so monitoring needs no secret). Checkpoints, weights and reflection stay
    /// closed.
    pub status_without_token: bool,
    /// Serve TLS only.
    pub tls: Option<ServerTls>,
}

impl ServerSecurity {
    /// Refuses a non-loopback `addr` (including `0.0.0.0` and `::`) without a token.
    pub fn check_bind(&self, addr: SocketAddr) -> Result<(), SecurityError> {
        if self.token.is_none() && !addr.ip().to_canonical().is_loopback() {
            return Err(SecurityError::TokenRequired { addr });
        }
        Ok(())
    }

    pub(crate) fn layer(&self) -> AuthLayer {
        AuthLayer {
            expected: self
                .token
                .as_ref()
                .map(|t| Arc::from(format!("Bearer {}", t.0).into_bytes())),
            status_without_token: self.status_without_token,
        }
    }
}

/// A client's credentials. Default: no token, plaintext.
#[derive(Clone, Debug, Default)]
pub struct ClientSecurity {
    /// Sent as `authorization: Bearer <token>` on every call.
    pub token: Option<Token>,
    /// Connect with TLS and verify the server against this CA.
    pub tls: Option<ClientTls>,
}

/// Adds the token to every outgoing call (the interceptor of all wire clients).
#[derive(Clone, Default)]
pub struct TokenInterceptor(Option<MetadataValue<Ascii>>);

impl fmt::Debug for TokenInterceptor {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let shown = if self.0.is_some() {
            "<redacted>"
        } else {
            "none"
        };
        f.debug_tuple("TokenInterceptor").field(&shown).finish()
    }
}

impl TokenInterceptor {
    pub(crate) fn new(token: Option<&Token>) -> Self {
        Self(token.map(Token::header))
    }
}

impl tonic::service::Interceptor for TokenInterceptor {
    fn call(&mut self, mut request: tonic::Request<()>) -> Result<tonic::Request<()>, Status> {
        if let Some(value) = &self.0 {
            request
                .metadata_mut()
                .insert("authorization", value.clone());
        }
        Ok(request)
    }
}

/// The tower layer in front of every service of a server (service, health, reflection): with a
/// token configured, a call without `authorization: Bearer <token>` is answered
/// `UNAUTHENTICATED` before it reaches any service.
#[derive(Clone, Default)]
pub(crate) struct AuthLayer {
    /// `Bearer <token>` as bytes.
    expected: Option<Arc<[u8]>>,
    status_without_token: bool,
}

impl fmt::Debug for AuthLayer {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("AuthLayer")
            .field("token", &self.expected.as_ref().map(|_| "<redacted>"))
            .field("status_without_token", &self.status_without_token)
            .finish()
    }
}

impl<S> tower_layer::Layer<S> for AuthLayer {
    type Service = Auth<S>;
    fn layer(&self, inner: S) -> Auth<S> {
        Auth {
            inner,
            layer: self.clone(),
        }
    }
}

impl AuthLayer {
    fn check<B>(&self, request: &http::Request<B>) -> Result<(), Status> {
        let Some(expected) = &self.expected else {
            return Ok(());
        };
        if self.status_without_token && STATUS_PATHS.contains(&request.uri().path()) {
            return Ok(());
        }
        match request.headers().get(http::header::AUTHORIZATION) {
            None => Err(Status::unauthenticated(format!(
                "this server requires a token (`authorization: Bearer <token>` metadata; terl \
                 clients send the {TOKEN_ENV} environment variable or cluster.token_file)"
            ))),
            Some(given) if bool::from(given.as_bytes().ct_eq(expected)) => Ok(()),
            Some(_) => Err(Status::unauthenticated("invalid token")),
        }
    }
}

/// The service [`AuthLayer`] makes.
#[derive(Clone, Debug)]
pub(crate) struct Auth<S> {
    inner: S,
    layer: AuthLayer,
}

impl<S, B> tower_service::Service<http::Request<B>> for Auth<S>
where
    S: tower_service::Service<http::Request<B>, Response = http::Response<tonic::body::Body>>,
{
    type Response = http::Response<tonic::body::Body>;
    type Error = S::Error;
    type Future = Either<S::Future, Ready<Result<Self::Response, S::Error>>>;

    fn poll_ready(&mut self, cx: &mut Context<'_>) -> Poll<Result<(), Self::Error>> {
        self.inner.poll_ready(cx)
    }

    fn call(&mut self, request: http::Request<B>) -> Self::Future {
        match self.layer.check(&request) {
            Ok(()) => Either::Left(self.inner.call(request)),
            Err(status) => {
                tracing::debug!(path = request.uri().path(), %status, "call refused");
                Either::Right(ready(Ok(status.into_http())))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tokens_are_checked_and_never_printed() {
        assert!(Token::new("short", "t").is_err());
        assert!(Token::new("with a space in it!!", "t").is_err());
        assert!(Token::new("x".repeat(MAX_TOKEN_BYTES + 1), "t").is_err());
        let token = Token::new("s3cret-s3cret-s3cret", "t").unwrap();
        let security = ServerSecurity {
            token: Some(token.clone()),
            ..ServerSecurity::default()
        };
        let shown = format!(
            "{token:?} {security:?} {:?} {:?}",
            security.layer(),
            TokenInterceptor::new(Some(&token))
        );
        assert!(!shown.contains("s3cret"), "{shown}");
        assert!(shown.contains("redacted"), "{shown}");
    }

    #[test]
    fn token_file_is_trimmed_and_bounded() {
        let dir = std::env::temp_dir().join(format!("terl-token-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("token");
        std::fs::write(&path, "0123456789abcdef0123\n").unwrap();
        let token = Token::from_file(&path).unwrap();
        assert_eq!(&*token.0, "0123456789abcdef0123");
        std::fs::write(&path, vec![b'a'; 4096]).unwrap();
        assert!(matches!(
            Token::from_file(&path),
            Err(SecurityError::TooLarge { .. })
        ));
        // Not regular files: a directory, and a device that never ends (its reported size
        // is 0, so only the kind and a bounded read keep it out).
        for other in [dir.as_path(), Path::new("/dev/zero")] {
            let e = Token::from_file(other).unwrap_err().to_string();
            assert!(e.contains("not a regular file"), "{e}");
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn only_loopback_binds_go_without_a_token() {
        let open = ServerSecurity::default();
        for ok in [
            "127.0.0.1:0",
            "127.1.2.3:5",
            "[::1]:0",
            "[::ffff:127.0.0.1]:0",
        ] {
            open.check_bind(ok.parse().unwrap()).unwrap();
        }
        for refused in ["0.0.0.0:0", "[::]:0", "10.0.0.5:50051"] {
            let err = open.check_bind(refused.parse().unwrap()).unwrap_err();
            let message = err.to_string();
            assert!(message.contains(TOKEN_ENV), "{message}");
            assert!(message.contains("cluster.token_file"), "{message}");
        }
        let locked = ServerSecurity {
            token: Some(Token::new("0123456789abcdef", "t").unwrap()),
            ..ServerSecurity::default()
        };
        locked.check_bind("0.0.0.0:0".parse().unwrap()).unwrap();
    }
}
