//! What a connection trusts and what it proves, read from files: the coordinator's TLS
//! certificate and key (`ServerTls`), what a client verifies the coordinator against and
//! the certificate it shows for mutual TLS (`ClientTls`), and the bearer token a client
//! sends (`Token`).
//!
//! Secrets are read from files (or, for a token, the `TESSERA_TOKEN` environment
//! variable), never from the command line, where every user of the machine can read them
//! in `ps`. A key or token file that every user can read is refused: the secret is already
//! out. Nothing here prints a secret: `Token`'s `Debug` says only that there is one.

use std::path::{Path, PathBuf};

use tonic::transport::{Certificate, ClientTlsConfig, Identity, ServerTlsConfig};

/// The environment variable a client reads its token from when it is given no token file.
pub const TOKEN_ENV: &str = "TESSERA_TOKEN";

/// The longest token accepted: far above any generated one, far below a header's limit.
const MAX_TOKEN_BYTES: usize = 1024;
/// The largest PEM file read (a certificate chain is a few kilobytes).
const MAX_PEM_BYTES: u64 = 1 << 20;

/// Why a certificate, key or token cannot be used.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CredentialError {
    /// The file cannot be read.
    #[error("cannot read the {what} {path}: {reason}")]
    Read {
        /// What the file was to hold ("TLS certificate", "token file", …).
        what: &'static str,
        /// The file.
        path: PathBuf,
        /// Why.
        reason: String,
    },
    /// The file does not hold what it should.
    #[error("the {what} {path} {reason}")]
    Malformed {
        /// What the file was to hold.
        what: &'static str,
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        reason: String,
    },
    /// A secret every user of the machine can read.
    #[error("the {what} {path} can be read by every user (mode {mode:03o}); `chmod 600` it")]
    Exposed {
        /// What the file holds.
        what: &'static str,
        /// The file.
        path: PathBuf,
        /// Its permission bits.
        mode: u32,
    },
    /// A token that cannot travel in a header.
    #[error("the token from {from} {reason}")]
    BadToken {
        /// Where it came from (a file, the environment).
        from: String,
        /// What is wrong with it.
        reason: String,
    },
}

/// A PEM file's contents, with where it came from for error messages.
#[derive(Clone, PartialEq)]
struct Pem {
    path: PathBuf,
    bytes: Vec<u8>,
}

impl std::fmt::Debug for Pem {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        // Key files are PEM too: never their bytes.
        write!(f, "Pem({})", self.path.display())
    }
}

/// Reads a file of at most `limit` bytes; with `secret`, refuses one every user can read.
fn read_file(what: &'static str, path: &Path, limit: u64, secret: bool) -> Result<Vec<u8>, CredentialError> {
    use std::io::Read;
    let read = |reason: String| CredentialError::Read { what, path: path.to_owned(), reason };
    let file = std::fs::File::open(path).map_err(|e| read(e.to_string()))?;
    let meta = file.metadata().map_err(|e| read(e.to_string()))?;
    if !meta.is_file() {
        return Err(CredentialError::Malformed {
            what,
            path: path.to_owned(),
            reason: "is not a regular file".into(),
        });
    }
    #[cfg(unix)]
    if secret {
        use std::os::unix::fs::PermissionsExt;
        let mode = meta.permissions().mode() & 0o777;
        if mode & 0o004 != 0 {
            return Err(CredentialError::Exposed { what, path: path.to_owned(), mode });
        }
    }
    #[cfg(not(unix))]
    let _ = secret;
    if meta.len() > limit {
        return Err(CredentialError::Malformed {
            what,
            path: path.to_owned(),
            reason: format!("is {} bytes, more than the {limit} such a file can need", meta.len()),
        });
    }
    let mut bytes = Vec::new();
    file.take(limit + 1).read_to_end(&mut bytes).map_err(|e| read(e.to_string()))?;
    Ok(bytes)
}

impl Pem {
    /// Reads a PEM file that must hold a block whose label ends with `label`
    /// ("CERTIFICATE", "PRIVATE KEY").
    fn read(what: &'static str, path: &Path, label: &str, secret: bool) -> Result<Pem, CredentialError> {
        let bytes = read_file(what, path, MAX_PEM_BYTES, secret)?;
        let text = String::from_utf8_lossy(&bytes);
        let found = text
            .lines()
            .filter_map(|l| l.trim().strip_prefix("-----BEGIN ")?.strip_suffix("-----"))
            .any(|l| l.ends_with(label));
        if !found {
            return Err(CredentialError::Malformed {
                what,
                path: path.to_owned(),
                reason: format!("holds no PEM block `-----BEGIN …{label}-----`"),
            });
        }
        Ok(Pem { path: path.to_owned(), bytes })
    }
}

/// The coordinator's TLS: its certificate and key, and for mutual TLS the CA that client
/// certificates must be signed by (then every client must show one).
#[derive(Debug, Clone, PartialEq)]
pub struct ServerTls {
    cert: Pem,
    key: Pem,
    client_ca: Option<Pem>,
}

impl ServerTls {
    /// Reads the certificate (chain) and key PEM files, and the client CA if given.
    pub fn read(cert: &Path, key: &Path, client_ca: Option<&Path>) -> Result<ServerTls, CredentialError> {
        Ok(ServerTls {
            cert: Pem::read("TLS certificate", cert, "CERTIFICATE", false)?,
            key: Pem::read("TLS key", key, "PRIVATE KEY", true)?,
            client_ca: client_ca
                .map(|p| Pem::read("client CA certificate", p, "CERTIFICATE", false))
                .transpose()?,
        })
    }

    /// The certificate chain and the key, PEM (the web face serves HTTPS with them too).
    pub fn pem(&self) -> (&[u8], &[u8]) {
        (&self.cert.bytes, &self.key.bytes)
    }

    /// Whether clients must show a certificate signed by the client CA.
    pub fn mutual(&self) -> bool {
        self.client_ca.is_some()
    }

    /// tonic's server configuration. A handshake must finish within 10 s, so that
    /// connections that never finish one do not pile up.
    pub fn config(&self) -> ServerTlsConfig {
        let config = ServerTlsConfig::new()
            .identity(Identity::from_pem(&self.cert.bytes, &self.key.bytes))
            .timeout(std::time::Duration::from_secs(10));
        match &self.client_ca {
            Some(ca) => config.client_ca_root(Certificate::from_pem(&ca.bytes)).client_auth_optional(false),
            None => config,
        }
    }
}

/// What a client trusts and shows over `https://`: the CA the coordinator's certificate
/// must be signed by (the system's roots without one), and a certificate of its own for
/// mutual TLS.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ClientTls {
    ca: Option<Pem>,
    identity: Option<(Pem, Pem)>,
}

impl ClientTls {
    /// The system's roots, no client certificate.
    pub fn new() -> ClientTls {
        ClientTls::default()
    }

    /// Trusts only certificates signed by the CA in this PEM file.
    pub fn ca_file(mut self, path: &Path) -> Result<ClientTls, CredentialError> {
        self.ca = Some(Pem::read("CA certificate", path, "CERTIFICATE", false)?);
        Ok(self)
    }

    /// Shows this certificate and key (PEM files) to the coordinator.
    pub fn identity_files(mut self, cert: &Path, key: &Path) -> Result<ClientTls, CredentialError> {
        self.identity = Some((
            Pem::read("client certificate", cert, "CERTIFICATE", false)?,
            Pem::read("client key", key, "PRIVATE KEY", true)?,
        ));
        Ok(self)
    }

    /// Whether anything differs from the defaults (an `http://` URL cannot take it).
    pub fn is_default(&self) -> bool {
        self.ca.is_none() && self.identity.is_none()
    }

    /// tonic's client configuration.
    pub fn config(&self) -> ClientTlsConfig {
        let config = match &self.ca {
            Some(ca) => ClientTlsConfig::new().ca_certificate(Certificate::from_pem(&ca.bytes)),
            None => ClientTlsConfig::new().with_native_roots(),
        };
        match &self.identity {
            Some((cert, key)) => config.identity(Identity::from_pem(&cert.bytes, &key.bytes)),
            None => config,
        }
    }
}

/// A bearer token. Its `Debug` does not show it.
#[derive(Clone, PartialEq, Eq)]
pub struct Token(String);

impl std::fmt::Debug for Token {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Token(hidden)")
    }
}

impl Token {
    /// A token from its text (surrounding whitespace removed); `from` says where it came
    /// from for errors.
    pub fn new(text: &str, from: &str) -> Result<Token, CredentialError> {
        let bad =
            |reason: &str| CredentialError::BadToken { from: from.to_string(), reason: reason.to_string() };
        let t = text.trim();
        if t.is_empty() {
            return Err(bad("is empty"));
        }
        if t.len() > MAX_TOKEN_BYTES {
            return Err(bad(&format!("is longer than {MAX_TOKEN_BYTES} bytes")));
        }
        if !t.bytes().all(|b| b.is_ascii_graphic()) {
            return Err(bad("holds spaces, control or non-ASCII characters"));
        }
        Ok(Token(t.to_string()))
    }

    /// The token in `path` (one line; a file every user can read is refused).
    pub fn read_file(path: &Path) -> Result<Token, CredentialError> {
        let bytes = read_file("token file", path, MAX_TOKEN_BYTES as u64 + 2, true)?;
        let text = String::from_utf8(bytes).map_err(|_| CredentialError::BadToken {
            from: path.display().to_string(),
            reason: "is not UTF-8 text".into(),
        })?;
        Token::new(&text, &path.display().to_string())
    }

    /// The token in [`TOKEN_ENV`], if it is set.
    pub fn from_env() -> Result<Option<Token>, CredentialError> {
        match std::env::var(TOKEN_ENV) {
            Ok(v) => Token::new(&v, TOKEN_ENV).map(Some),
            Err(std::env::VarError::NotPresent) => Ok(None),
            Err(std::env::VarError::NotUnicode(_)) => {
                Err(CredentialError::BadToken { from: TOKEN_ENV.into(), reason: "is not UTF-8 text".into() })
            }
        }
    }

    /// The token from `file` if given, else from [`TOKEN_ENV`] if set.
    pub fn from_file_or_env(file: Option<&Path>) -> Result<Option<Token>, CredentialError> {
        match file {
            Some(path) => Token::read_file(path).map(Some),
            None => Token::from_env(),
        }
    }

    /// The secret itself, for the header that carries it.
    pub fn secret(&self) -> &str {
        &self.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(dir: &Path, name: &str, text: &str, mode: u32) -> PathBuf {
        let path = dir.join(name);
        std::fs::write(&path, text).unwrap();
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            std::fs::set_permissions(&path, std::fs::Permissions::from_mode(mode)).unwrap();
        }
        path
    }

    fn tempdir() -> PathBuf {
        let dir = std::env::temp_dir().join(format!(
            "tessera-credentials-{}-{:?}",
            std::process::id(),
            std::thread::current().id()
        ));
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    #[test]
    fn tokens_are_checked_and_never_shown() {
        let t = Token::new("  s3cret-token\n", "test").unwrap();
        assert_eq!(t.secret(), "s3cret-token");
        assert_eq!(format!("{t:?}"), "Token(hidden)");
        for bad in ["", "   ", "two words", "tab\there", "é"] {
            let e = Token::new(bad, "test").unwrap_err();
            assert!(e.to_string().starts_with("the token from test "), "{e}");
        }
        assert!(Token::new(&"x".repeat(MAX_TOKEN_BYTES + 1), "test").is_err());
    }

    #[cfg(unix)]
    #[test]
    fn secrets_every_user_can_read_are_refused() {
        let dir = tempdir();
        let open = write(&dir, "open.token", "abc\n", 0o644);
        let e = Token::read_file(&open).unwrap_err();
        assert!(matches!(e, CredentialError::Exposed { mode: 0o644, .. }), "{e:?}");
        assert!(e.to_string().contains("chmod 600"), "{e}");
        let closed = write(&dir, "closed.token", "abc\n", 0o600);
        assert_eq!(Token::read_file(&closed).unwrap().secret(), "abc");
        let cert =
            write(&dir, "c.pem", "-----BEGIN CERTIFICATE-----\nAA==\n-----END CERTIFICATE-----\n", 0o644);
        let key =
            write(&dir, "k.pem", "-----BEGIN PRIVATE KEY-----\nAA==\n-----END PRIVATE KEY-----\n", 0o644);
        let e = ServerTls::read(&cert, &key, None).unwrap_err();
        assert!(matches!(e, CredentialError::Exposed { what: "TLS key", .. }), "{e:?}");
        let _ = std::fs::remove_dir_all(dir);
    }

    #[test]
    fn files_that_are_not_pem_say_so() {
        let dir = tempdir();
        let junk = write(&dir, "junk.pem", "hello\n", 0o600);
        let e = ClientTls::new().ca_file(&junk).unwrap_err();
        assert!(e.to_string().contains("holds no PEM block `-----BEGIN …CERTIFICATE-----`"), "{e}");
        let e = ClientTls::new().ca_file(&dir.join("missing.pem")).unwrap_err();
        assert!(matches!(e, CredentialError::Read { what: "CA certificate", .. }), "{e:?}");
        let _ = std::fs::remove_dir_all(dir);
    }
}
