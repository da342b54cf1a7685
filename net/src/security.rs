//! Who may talk to a run: the deployment's shared bearer token and TLS, read the same way by
//! every service and client.
//!
//! - `--auth-token-file FILE` (env `JSAE_AUTH_TOKEN_FILE`): clients send the token as
//!   `authorization: Bearer TOKEN`; servers answer every RPC without it (or with another)
//!   `UNAUTHENTICATED`, except `grpc.health.v1.Health`, which probes must reach. Reflection
//!   needs the token too. The comparison takes the same time wherever the tokens differ, and
//!   the token is never logged (`Debug` prints `<redacted>`).
//! - `--tls-cert FILE --tls-key FILE`: a server serves TLS with this identity (and a client
//!   presents it where the server asks for one, mutual TLS).
//! - `--tls-ca FILE`: a client trusts servers whose certificate this CA signed; `https://`
//!   URLs need it, and with it an `http://` URL is refused (nothing falls back to plain text).
//! - `--tls-client-ca FILE`: a server accepts only clients with a certificate this CA signed.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use subtle::ConstantTimeEq;
use tonic::metadata::{Ascii, MetadataValue};
use tonic::service::Interceptor;
use tonic::service::interceptor::InterceptedService;
use tonic::transport::{
    Certificate, Channel, ClientTlsConfig, Endpoint, Identity, ServerTlsConfig,
};

/// The metadata key the token travels in.
const AUTHORIZATION: &str = "authorization";
/// The shortest token accepted, in bytes.
pub const MIN_TOKEN_BYTES: usize = 16;

/// The security flags of every service and client.
#[derive(Debug, Clone, Default, PartialEq, Eq, clap::Args)]
pub struct SecurityFlags {
    /// File holding the deployment's shared token (one line, at least 16 visible ASCII
    /// characters): sent by clients, required by servers on every RPC but health.
    #[arg(long, env = "JSAE_AUTH_TOKEN_FILE", value_name = "FILE")]
    pub auth_token_file: Option<PathBuf>,
    /// PEM certificate: a server serves TLS with it; a client presents it to a server that
    /// asks (mutual TLS). Needs --tls-key.
    #[arg(long, env = "JSAE_TLS_CERT", value_name = "FILE", requires = "tls_key")]
    pub tls_cert: Option<PathBuf>,
    /// PEM private key of --tls-cert.
    #[arg(long, env = "JSAE_TLS_KEY", value_name = "FILE", requires = "tls_cert")]
    pub tls_key: Option<PathBuf>,
    /// PEM CA certificate a client trusts servers by (`https://` URLs need it).
    #[arg(long, env = "JSAE_TLS_CA", value_name = "FILE")]
    pub tls_ca: Option<PathBuf>,
    /// PEM CA certificate a server requires clients' certificates to be signed by (mutual
    /// TLS). Needs --tls-cert and --tls-key.
    #[arg(
        long,
        env = "JSAE_TLS_CLIENT_CA",
        value_name = "FILE",
        requires = "tls_cert"
    )]
    pub tls_client_ca: Option<PathBuf>,
}

impl SecurityFlags {
    /// Reads the files the flags name; the reason (naming the flag and file) when one cannot
    /// be read or is not what it should be.
    pub fn load(&self) -> Result<Security, String> {
        let read = |flag: &str, path: &Path| {
            std::fs::read(path).map_err(|e| format!("{flag} {}: {e}", path.display()))
        };
        let mut security = Security::default();
        if let Some(path) = &self.auth_token_file {
            let text = read("--auth-token-file", path)?;
            let token = Token::parse(&text)
                .map_err(|e| format!("--auth-token-file {}: {e}", path.display()))?;
            security.token = Some(token);
        }
        if let (Some(cert), Some(key)) = (&self.tls_cert, &self.tls_key) {
            let cert = pem(read("--tls-cert", cert)?, "--tls-cert", cert, "CERTIFICATE")?;
            let key = pem(read("--tls-key", key)?, "--tls-key", key, "PRIVATE KEY")?;
            security.identity = Some(Identity::from_pem(cert, key));
        }
        if let Some(path) = &self.tls_ca {
            let ca = pem(read("--tls-ca", path)?, "--tls-ca", path, "CERTIFICATE")?;
            security.ca = Some(Certificate::from_pem(ca));
        }
        if let Some(path) = &self.tls_client_ca {
            let ca = pem(
                read("--tls-client-ca", path)?,
                "--tls-client-ca",
                path,
                "CERTIFICATE",
            )?;
            security.client_ca = Some(Certificate::from_pem(ca));
        }
        Ok(security)
    }

    /// The same settings as environment variables (absolute paths), for the processes
    /// `jsae train` starts.
    pub fn to_env(&self) -> Vec<(&'static str, PathBuf)> {
        let absolute = |p: &PathBuf| std::path::absolute(p).unwrap_or_else(|_| p.clone());
        [
            ("JSAE_AUTH_TOKEN_FILE", &self.auth_token_file),
            ("JSAE_TLS_CERT", &self.tls_cert),
            ("JSAE_TLS_KEY", &self.tls_key),
            ("JSAE_TLS_CA", &self.tls_ca),
            ("JSAE_TLS_CLIENT_CA", &self.tls_client_ca),
        ]
        .into_iter()
        .filter_map(|(name, path)| path.as_ref().map(|p| (name, absolute(p))))
        .collect()
    }
}

/// Checks that `bytes` (the file behind `flag`) hold a PEM block whose label contains
/// `label`, so that a swapped or empty file is named at start, not at the first handshake.
fn pem(bytes: Vec<u8>, flag: &str, path: &Path, label: &str) -> Result<Vec<u8>, String> {
    let text = String::from_utf8_lossy(&bytes);
    let found = text
        .lines()
        .any(|l| l.starts_with("-----BEGIN ") && l.contains(label));
    if found {
        Ok(bytes)
    } else {
        Err(format!(
            "{flag} {}: no PEM block with \"{label}\" in it",
            path.display()
        ))
    }
}

/// The shared secret, as the header value clients send and servers compare against.
#[derive(Clone)]
pub struct Token {
    header: MetadataValue<Ascii>,
    /// SHA-256 of the header's bytes, what a given header's digest is compared with.
    digest: [u8; 32],
}

impl std::fmt::Debug for Token {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Token(<redacted>)")
    }
}

impl Token {
    /// The token in a file's contents: one line (surrounding whitespace ignored) of at least
    /// [`MIN_TOKEN_BYTES`] visible ASCII characters.
    pub fn parse(contents: &[u8]) -> Result<Self, String> {
        let text = std::str::from_utf8(contents)
            .map_err(|_| "the token is not text".to_string())?
            .trim();
        if text.len() < MIN_TOKEN_BYTES {
            return Err(format!(
                "the token has {} characters, at least {MIN_TOKEN_BYTES} are needed \
                 (e.g. `head -c 32 /dev/urandom | od -An -tx1 | tr -d ' \\n' > FILE`)",
                text.len()
            ));
        }
        if !text.bytes().all(|b| b.is_ascii_graphic()) {
            return Err("the token must be visible ASCII without spaces".into());
        }
        let header: MetadataValue<Ascii> = format!("Bearer {text}")
            .parse()
            .map_err(|_| "the token cannot travel as gRPC metadata".to_string())?;
        let digest = sha256(header.as_bytes());
        Ok(Self { header, digest })
    }

    /// Whether `given` (an `authorization` value) is this token, in time independent of
    /// where they differ and of the token's length: the digests compared have one length
    /// (a slice comparison returns at once on a length mismatch).
    fn matches(&self, given: &[u8]) -> bool {
        self.digest.ct_eq(&sha256(given)).into()
    }
}

fn sha256(bytes: &[u8]) -> [u8; 32] {
    use sha2::Digest;
    sha2::Sha256::digest(bytes).into()
}

/// What a process knows about the deployment's security; the default is none (plain text,
/// no token), as on a developer's machine.
#[derive(Debug, Clone, Default)]
pub struct Security {
    token: Option<Token>,
    identity: Option<Identity>,
    ca: Option<Certificate>,
    client_ca: Option<Certificate>,
}

/// A client connection: a channel that attaches the token to every call.
pub type Connection = InterceptedService<Channel, AttachToken>;

/// A service behind the token check.
pub type Guarded<S> = InterceptedService<S, RequireToken>;

/// Why a client connection could not be made.
#[derive(Debug, thiserror::Error)]
pub enum ConnectError {
    /// The URL and the TLS settings disagree.
    #[error("{0}")]
    Scheme(String),
    /// The URL or the TLS settings were refused by the transport.
    #[error("{url}: {source}")]
    Transport {
        /// The URL.
        url: String,
        /// Why.
        #[source]
        source: tonic::transport::Error,
    },
}

impl Security {
    /// Only a token (tests, and clients built in code).
    pub fn with_token(token: Token) -> Self {
        Self {
            token: Some(token),
            ..Self::default()
        }
    }

    /// Whether servers serve TLS (and so clients should dial `https://`).
    pub fn serves_tls(&self) -> bool {
        self.identity.is_some()
    }

    /// The URL scheme clients use: `https` with a CA to trust, else `http`.
    pub fn scheme(&self) -> &'static str {
        if self.ca.is_some() { "https" } else { "http" }
    }

    /// The token check in front of a service (a pass-through without a token).
    pub fn guard<S>(&self, service: S) -> Guarded<S> {
        InterceptedService::new(
            service,
            RequireToken {
                token: self.token.clone().map(Arc::new),
            },
        )
    }

    /// The server's TLS settings, where it has an identity.
    pub fn server_tls(&self) -> Option<ServerTlsConfig> {
        let identity = self.identity.clone()?;
        let mut tls = ServerTlsConfig::new()
            .identity(identity)
            .timeout(Duration::from_secs(10));
        if let Some(ca) = &self.client_ca {
            tls = tls.client_ca_root(ca.clone());
        }
        Some(tls)
    }

    /// Checks that `url` (given as `flag`) fits these settings before anything connects:
    /// `https://` needs a CA to trust, and with one `http://` is refused.
    pub fn check_url(&self, flag: &str, url: &str) -> Result<(), String> {
        crate::check_url(flag, url)?;
        match (url.starts_with("https://"), self.ca.is_some()) {
            (true, false) => Err(format!("{flag} {url}: an https:// URL needs --tls-ca")),
            (false, true) => Err(format!(
                "{flag} {url}: --tls-ca is set, so the URL must be https:// (no plain-text \
                 fallback)"
            )),
            _ => Ok(()),
        }
    }

    /// A lazily connecting channel to `url` with TCP_NODELAY on, TLS where the URL is
    /// `https://`, and the token on every call; calls fail with UNAVAILABLE while the server
    /// is away and succeed again once it is back.
    pub fn channel(&self, url: &str) -> Result<Connection, ConnectError> {
        self.check_url("URL", url).map_err(ConnectError::Scheme)?;
        let transport = |source| ConnectError::Transport {
            url: url.to_string(),
            source,
        };
        let mut endpoint = Endpoint::from_shared(url.to_string())
            .map_err(transport)?
            .tcp_nodelay(true)
            .connect_timeout(Duration::from_secs(2))
            .http2_keep_alive_interval(Duration::from_secs(10))
            .keep_alive_timeout(Duration::from_secs(10));
        if let Some(ca) = &self.ca {
            let mut tls = ClientTlsConfig::new().ca_certificate(ca.clone());
            if let Some(identity) = &self.identity {
                tls = tls.identity(identity.clone());
            }
            endpoint = endpoint.tls_config(tls).map_err(transport)?;
        }
        Ok(InterceptedService::new(
            endpoint.connect_lazy(),
            AttachToken {
                header: self.token.as_ref().map(|t| t.header.clone()),
            },
        ))
    }
}

/// The client side: puts the token on every outgoing call.
#[derive(Debug, Clone)]
pub struct AttachToken {
    header: Option<MetadataValue<Ascii>>,
}

impl Interceptor for AttachToken {
    fn call(
        &mut self,
        mut request: tonic::Request<()>,
    ) -> Result<tonic::Request<()>, tonic::Status> {
        if let Some(header) = &self.header {
            request.metadata_mut().insert(AUTHORIZATION, header.clone());
        }
        Ok(request)
    }
}

/// The server side: refuses a call without the token.
#[derive(Debug, Clone)]
pub struct RequireToken {
    token: Option<Arc<Token>>,
}

impl Interceptor for RequireToken {
    fn call(&mut self, request: tonic::Request<()>) -> Result<tonic::Request<()>, tonic::Status> {
        let Some(token) = &self.token else {
            return Ok(request);
        };
        let given = request
            .metadata()
            .get(AUTHORIZATION)
            .map_or(&[][..], |v| v.as_bytes());
        if token.matches(given) {
            Ok(request)
        } else {
            Err(tonic::Status::unauthenticated(
                "missing or wrong bearer token (the deployment's --auth-token-file)",
            ))
        }
    }
}

/// Throw-away certificate authorities for tests: never part of a release build.
#[cfg(feature = "test-certs")]
pub mod test_certs {
    use std::path::{Path, PathBuf};

    use rcgen::{BasicConstraints, CertificateParams, CertifiedIssuer, DnType, IsCa, KeyPair};

    /// A CA and one certificate it signed for `localhost` and `127.0.0.1`, as PEM files.
    #[derive(Debug, Clone)]
    pub struct TestPki {
        /// The CA's certificate.
        pub ca: PathBuf,
        /// The leaf certificate (server and client identity).
        pub cert: PathBuf,
        /// The leaf's private key.
        pub key: PathBuf,
    }

    impl TestPki {
        /// Generates a fresh CA and leaf into `dir` (files `NAME-ca.pem`, `NAME-cert.pem`,
        /// `NAME-key.pem`).
        pub fn generate(dir: &Path, name: &str) -> Result<Self, rcgen::Error> {
            Self::generate_for(dir, name, &["localhost", "127.0.0.1"])
        }

        /// As [`TestPki::generate`], the leaf naming `hosts` only.
        pub fn generate_for(dir: &Path, name: &str, hosts: &[&str]) -> Result<Self, rcgen::Error> {
            std::fs::create_dir_all(dir).map_err(|_| rcgen::Error::CouldNotParseCertificate)?;
            let mut ca_params = CertificateParams::new(Vec::<String>::new())?;
            ca_params.is_ca = IsCa::Ca(BasicConstraints::Unconstrained);
            ca_params
                .distinguished_name
                .push(DnType::CommonName, format!("jsae test CA {name}"));
            let ca = CertifiedIssuer::self_signed(ca_params, KeyPair::generate()?)?;
            let key = KeyPair::generate()?;
            let mut params =
                CertificateParams::new(hosts.iter().map(|h| (*h).to_string()).collect::<Vec<_>>())?;
            params
                .distinguished_name
                .push(DnType::CommonName, format!("jsae test service {name}"));
            let cert = params.signed_by(&key, &ca)?;
            let pki = Self {
                ca: dir.join(format!("{name}-ca.pem")),
                cert: dir.join(format!("{name}-cert.pem")),
                key: dir.join(format!("{name}-key.pem")),
            };
            let write = |path: &Path, text: String| {
                std::fs::write(path, text).map_err(|_| rcgen::Error::CouldNotParseCertificate)
            };
            write(&pki.ca, ca.pem())?;
            write(&pki.cert, cert.pem())?;
            write(&pki.key, key.serialize_pem())?;
            Ok(pki)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tokens_are_checked_for_length_and_characters_and_never_printed() {
        assert!(Token::parse(b"short").is_err());
        assert!(Token::parse(b"sixteen chars !!").is_err());
        assert!(Token::parse(&[0xff; 20]).is_err());
        let token = Token::parse(b"  0123456789abcdef0123\n").expect("a good token");
        assert!(token.matches(b"Bearer 0123456789abcdef0123"));
        assert!(!token.matches(b"Bearer 0123456789abcdef0124"));
        assert!(!token.matches(b"0123456789abcdef0123"));
        assert!(!token.matches(b""));
        assert!(!format!("{token:?}").contains("0123"));
        let security = Security::with_token(token);
        assert!(!format!("{security:?}").contains("0123"));
    }

    #[test]
    fn the_token_check_refuses_missing_and_wrong_tokens() {
        let token = Token::parse(b"0123456789abcdef0123").expect("token");
        let mut check = RequireToken {
            token: Some(Arc::new(token.clone())),
        };
        assert_eq!(
            check
                .call(tonic::Request::new(()))
                .map_err(|s| s.code())
                .err(),
            Some(tonic::Code::Unauthenticated)
        );
        let mut attach = AttachToken {
            header: Some(token.header.clone()),
        };
        let request = attach.call(tonic::Request::new(())).expect("attached");
        assert!(check.call(request).is_ok());
        let mut open = RequireToken { token: None };
        assert!(open.call(tonic::Request::new(())).is_ok());
    }

    #[test]
    fn urls_must_match_the_tls_settings() {
        let plain = Security::default();
        assert!(plain.check_url("--learner", "http://127.0.0.1:1").is_ok());
        assert!(plain.check_url("--learner", "https://127.0.0.1:1").is_err());
        let tls = Security {
            ca: Some(Certificate::from_pem("x")),
            ..Security::default()
        };
        assert!(tls.check_url("--learner", "https://127.0.0.1:1").is_ok());
        let err = tls
            .check_url("--learner", "http://127.0.0.1:1")
            .expect_err("refused");
        assert!(err.contains("https://"), "{err}");
    }

    #[test]
    fn bad_files_are_named_with_their_flag() {
        let dir = std::env::temp_dir().join(format!("jsae-security-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("dir");
        let token = dir.join("token");
        std::fs::write(&token, "tiny").expect("write");
        let flags = SecurityFlags {
            auth_token_file: Some(token.clone()),
            ..SecurityFlags::default()
        };
        let err = flags.load().expect_err("refused");
        assert!(
            err.contains("--auth-token-file") && err.contains("at least 16"),
            "{err}"
        );
        let flags = SecurityFlags {
            tls_ca: Some(token),
            ..SecurityFlags::default()
        };
        assert!(flags.load().expect_err("refused").contains("--tls-ca"));
        let missing = SecurityFlags {
            tls_ca: Some(dir.join("absent.pem")),
            ..SecurityFlags::default()
        };
        assert!(missing.load().expect_err("refused").contains("absent.pem"));
        let _ = std::fs::remove_dir_all(&dir);
    }
}
