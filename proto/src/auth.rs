//! The run's secret token and TLS settings for cross-node gRPC.
//!
//! The token lives in a file readable by its owner only (mode 0600); [`read_token_file`]
//! refuses a file that group or others may read. Clients send it as `authorization: Bearer
//! <token>` ([`ClientAuth`]); the server checks it on every call ([`ServerAuth`]) and counts
//! refusals.

use std::fs::OpenOptions;
use std::io::{Read, Write};
use std::os::unix::fs::{OpenOptionsExt, PermissionsExt};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use thiserror::Error;
use tonic::metadata::MetadataValue;
use tonic::service::Interceptor;
use tonic::transport::{Certificate, ClientTlsConfig, Identity, ServerTlsConfig};
use tonic::{Request, Status};

use crate::validate::{Refusal, RefusalCounts};

/// Why a token or TLS file could not be used. The message names the file.
#[derive(Debug, Error)]
pub enum AuthError {
    /// The file could not be read or written.
    #[error("token/TLS file {path}: cannot {op}: {err}")]
    Io {
        /// The file.
        path: PathBuf,
        /// What was attempted.
        op: &'static str,
        /// The I/O error (in the message, so it is not a separate `source`).
        err: std::io::Error,
    },
    /// The token file may be read by group or others.
    #[error("token file {path} has mode {mode:o}; it must be readable by its owner only (chmod 600)")]
    Permissions {
        /// The file.
        path: PathBuf,
        /// Its permission bits.
        mode: u32,
    },
    /// The token file is empty or not printable ASCII.
    #[error("token file {path}: {reason}")]
    BadToken {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        reason: &'static str,
    },
}

fn io_err<'a>(path: &'a Path, op: &'static str) -> impl FnOnce(std::io::Error) -> AuthError + 'a {
    move |err| AuthError::Io {
        path: path.to_owned(),
        op,
        err,
    }
}

/// Reads the token from `path`: one line of printable ASCII, from a file with no group or other
/// permissions.
pub fn read_token_file(path: &Path) -> Result<String, AuthError> {
    let meta = std::fs::metadata(path).map_err(io_err(path, "read"))?;
    let mode = meta.permissions().mode() & 0o777;
    if mode & 0o077 != 0 {
        return Err(AuthError::Permissions {
            path: path.to_owned(),
            mode,
        });
    }
    let text = std::fs::read_to_string(path).map_err(io_err(path, "read"))?;
    let token = text.trim();
    if token.is_empty() {
        return Err(AuthError::BadToken {
            path: path.to_owned(),
            reason: "it is empty",
        });
    }
    if !token.bytes().all(|b| b.is_ascii_graphic()) {
        return Err(AuthError::BadToken {
            path: path.to_owned(),
            reason: "the token must be printable ASCII without spaces",
        });
    }
    Ok(token.to_owned())
}

/// Writes a fresh random token (32 bytes from `/dev/urandom`, hex) to `path` with mode 0600,
/// replacing nothing: an existing file is an error. Returns the token.
pub fn create_token_file(path: &Path) -> Result<String, AuthError> {
    let mut raw = [0u8; 32];
    std::fs::File::open("/dev/urandom")
        .and_then(|mut f| f.read_exact(&mut raw))
        .map_err(io_err(Path::new("/dev/urandom"), "read"))?;
    let token: String = raw.iter().map(|b| format!("{b:02x}")).collect();
    let mut f = OpenOptions::new()
        .write(true)
        .create_new(true)
        .mode(0o600)
        .open(path)
        .map_err(io_err(path, "create"))?;
    f.write_all(format!("{token}\n").as_bytes())
        .and_then(|_| f.sync_all())
        .map_err(io_err(path, "write"))?;
    Ok(token)
}

/// The token in `path`, created (random, mode 0600) when the file does not exist yet.
pub fn read_or_create_token_file(path: &Path) -> Result<String, AuthError> {
    if path.exists() {
        read_token_file(path)
    } else {
        create_token_file(path)
    }
}

/// gRPC metadata key of the operator credential. `Shutdown` needs it besides the run token,
/// so an actor, which holds only the run token, cannot end the run.
pub const OPERATOR_METADATA: &str = "x-adp-operator";

/// Whether `metadata` carries the operator token `expected` under [`OPERATOR_METADATA`]
/// (compared in constant time).
pub fn carries_operator_token(metadata: &tonic::metadata::MetadataMap, expected: &str) -> bool {
    metadata
        .get(OPERATOR_METADATA)
        .is_some_and(|v| constant_time_eq(v.as_bytes(), expected.as_bytes()))
}

/// Client interceptor that adds `authorization: Bearer <token>` to every call. Cheap to clone.
#[derive(Debug, Clone)]
pub struct ClientAuth {
    header: Option<MetadataValue<tonic::metadata::Ascii>>,
}

impl ClientAuth {
    /// Sends `token` (or nothing when `None`: for tests of the refusal path).
    pub fn new(token: Option<&str>) -> Self {
        Self {
            header: token.map(|t| {
                format!("Bearer {t}")
                    .parse()
                    .expect("read_token_file admits printable ASCII only")
            }),
        }
    }
}

impl Interceptor for ClientAuth {
    fn call(&mut self, mut request: Request<()>) -> Result<Request<()>, Status> {
        if let Some(h) = &self.header {
            request.metadata_mut().insert("authorization", h.clone());
        }
        Ok(request)
    }
}

/// Server interceptor that refuses a call without the run's token (`UNAUTHENTICATED`) and
/// counts it. Cheap to clone; the counters are shared.
#[derive(Debug, Clone)]
pub struct ServerAuth {
    expected: Arc<[u8]>,
    refusals: Arc<RefusalCounts>,
}

impl ServerAuth {
    /// Accepts calls that carry `token`; counts refusals in `refusals`.
    pub fn new(token: &str, refusals: Arc<RefusalCounts>) -> Self {
        Self {
            expected: format!("Bearer {token}").into_bytes().into(),
            refusals,
        }
    }
}

/// A fresh actor credential: 16 bytes from the kernel's random source (`getrandom(2)`, which
/// needs no file descriptor, so registrations still work when the open-file limit is reached).
pub fn new_actor_secret() -> Result<crate::plane::ActorSecret, std::io::Error> {
    let mut raw = [0u8; 16];
    let mut filled = 0;
    while filled < raw.len() {
        // SAFETY: the pointer and length describe the unfilled tail of `raw`.
        let n = unsafe { libc::getrandom(raw[filled..].as_mut_ptr().cast(), raw.len() - filled, 0) };
        match n {
            n if n > 0 => filled += n as usize,
            _ => {
                let e = std::io::Error::last_os_error();
                if e.kind() != std::io::ErrorKind::Interrupted {
                    return Err(e);
                }
            }
        }
    }
    Ok(raw)
}

/// Whether `got` is the credential `expected` (compared in constant time).
pub fn secret_matches(expected: &crate::plane::ActorSecret, got: &[u8]) -> bool {
    constant_time_eq(expected, got)
}

/// Equality whose time does not depend on where the inputs differ.
fn constant_time_eq(a: &[u8], b: &[u8]) -> bool {
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

impl Interceptor for ServerAuth {
    fn call(&mut self, request: Request<()>) -> Result<Request<()>, Status> {
        let why = match request.metadata().get("authorization") {
            None => "no `authorization` token",
            Some(v) if constant_time_eq(v.as_bytes(), &self.expected) => return Ok(request),
            Some(_) => "wrong token",
        };
        let refusal = Refusal::Unauthenticated(why.into());
        self.refusals.record(&refusal, 1);
        Err(Status::unauthenticated(refusal.to_string()))
    }
}

/// TLS files of one side of a connection (PEM).
#[derive(Debug, Clone, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TlsFiles {
    /// This side's certificate chain.
    pub cert: Option<PathBuf>,
    /// This side's private key.
    pub key: Option<PathBuf>,
    /// The CA that signed the other side's certificate.
    pub ca: Option<PathBuf>,
    /// The server name to verify (client side; defaults to the host of the address).
    pub domain: Option<String>,
}

fn read_pem(path: &Path) -> Result<Vec<u8>, AuthError> {
    std::fs::read(path).map_err(io_err(path, "read"))
}

impl TlsFiles {
    /// The server's TLS configuration: `cert` and `key` are required; with `ca`, clients must
    /// present a certificate signed by it (mutual TLS).
    pub fn server_config(&self) -> Result<ServerTlsConfig, AuthError> {
        let (cert, key) = self.identity_paths("server")?;
        let mut cfg = ServerTlsConfig::new().identity(Identity::from_pem(read_pem(cert)?, read_pem(key)?));
        if let Some(ca) = &self.ca {
            cfg = cfg.client_ca_root(Certificate::from_pem(read_pem(ca)?));
        }
        Ok(cfg)
    }

    /// The client's TLS configuration for a server named `host`: `ca` is required; with `cert`
    /// and `key`, the client presents them (mutual TLS).
    pub fn client_config(&self, host: &str) -> Result<ClientTlsConfig, AuthError> {
        let ca = self.ca.as_deref().ok_or_else(|| AuthError::BadToken {
            path: PathBuf::from("<tls.ca>"),
            reason: "a TLS client needs the CA certificate (`ca`) that signed the learner's certificate",
        })?;
        let mut cfg = ClientTlsConfig::new()
            .ca_certificate(Certificate::from_pem(read_pem(ca)?))
            .domain_name(self.domain.clone().unwrap_or_else(|| host.to_owned()));
        if self.cert.is_some() || self.key.is_some() {
            let (cert, key) = self.identity_paths("client")?;
            cfg = cfg.identity(Identity::from_pem(read_pem(cert)?, read_pem(key)?));
        }
        Ok(cfg)
    }

    fn identity_paths(&self, side: &'static str) -> Result<(&Path, &Path), AuthError> {
        match (&self.cert, &self.key) {
            (Some(c), Some(k)) => Ok((c, k)),
            _ => Err(AuthError::BadToken {
                path: PathBuf::from(format!("<tls.{side}>")),
                reason: "TLS needs both `cert` and `key`",
            }),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dir(name: &str) -> PathBuf {
        testkit::fresh_dir(&format!("auth-{name}"))
    }

    #[test]
    fn token_file_round_trip_and_permission_check() {
        let d = dir("perm");
        let p = d.join("token");
        let t = create_token_file(&p).unwrap();
        assert_eq!(t.len(), 64);
        assert_eq!(read_token_file(&p).unwrap(), t);
        assert!(create_token_file(&p).is_err(), "never replaces a token");
        std::fs::set_permissions(&p, std::fs::Permissions::from_mode(0o644)).unwrap();
        let e = read_token_file(&p).unwrap_err().to_string();
        assert!(e.contains("mode 644") && e.contains("chmod 600"), "{e}");
        let e = read_token_file(&d.join("missing")).unwrap_err().to_string();
        assert!(e.contains("missing") && e.contains("cannot read"), "{e}");
        std::fs::write(d.join("empty"), "\n").unwrap();
        std::fs::set_permissions(d.join("empty"), std::fs::Permissions::from_mode(0o600)).unwrap();
        assert!(read_token_file(&d.join("empty"))
            .unwrap_err()
            .to_string()
            .contains("empty"));
    }

    #[test]
    fn server_refuses_missing_and_wrong_tokens_and_counts_them() {
        let counts = Arc::new(RefusalCounts::default());
        let mut server = ServerAuth::new("s3cret", counts.clone());
        let mut client = ClientAuth::new(Some("s3cret"));
        let ok = client.call(Request::new(())).unwrap();
        assert!(server.call(ok).is_ok());
        let missing = ClientAuth::new(None).call(Request::new(())).unwrap();
        assert_eq!(
            server.call(missing).unwrap_err().code(),
            tonic::Code::Unauthenticated
        );
        let wrong = ClientAuth::new(Some("guess")).call(Request::new(())).unwrap();
        let e = server.call(wrong).unwrap_err();
        assert!(e.message().contains("wrong token"), "{e}");
        assert_eq!(counts.total(), 2);
    }
}
