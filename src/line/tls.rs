//! TLS for the MQTT client: the broker's certificate authority and an optional client
//! certificate, read from PEM files into a rustls configuration (the ring provider, so it
//! builds with cargo alone). Every error names the recipe key and the file.

use std::path::Path;
use std::sync::Arc;

use rustls::pki_types::pem::PemObject;
use rustls::pki_types::{CertificateDer, PrivateKeyDer};

/// Most bytes of a PEM file (CA, client certificate, key).
pub const MAX_PEM_BYTES: u64 = 1 << 20;

/// A TLS setting that cannot be used, one line naming the recipe key and the file.
#[derive(Debug, thiserror::Error)]
pub enum TlsError {
    /// A file's problem.
    #[error("mqtt.{key} = {file:?}: {problem}")]
    File {
        /// The recipe key, after `mqtt.`.
        key: &'static str,
        /// The file as given.
        file: String,
        /// Its problem.
        problem: TlsProblem,
    },
    /// No protocol version the provider and rustls share.
    #[error("mqtt: TLS: {0}")]
    Protocol(rustls::Error),
}

/// What is wrong with a PEM file.
#[derive(Debug, thiserror::Error)]
pub enum TlsProblem {
    /// It cannot be read.
    #[error("cannot read: {0}")]
    Read(std::io::Error),
    /// It is not PEM.
    #[error("not PEM: {0}")]
    NotPem(rustls::pki_types::pem::Error),
    /// It holds no certificate.
    #[error("no PEM certificate in it")]
    NoCertificate,
    /// Its certificate is not one a trust store takes.
    #[error("not a usable certificate: {0}")]
    Unusable(rustls::Error),
    /// It holds no private key.
    #[error("no PEM private key in it: {0}")]
    NoKey(rustls::pki_types::pem::Error),
    /// The key is not the client certificate's.
    #[error("does not fit mqtt.client_cert_file: {0}")]
    Mismatch(rustls::Error),
}

impl TlsError {
    fn file(key: &'static str, path: &Path, problem: TlsProblem) -> Self {
        Self::File {
            key,
            file: path.display().to_string(),
            problem,
        }
    }
}

/// The PEM text of `path`, the recipe key `mqtt.<key>` named in an error.
fn read(key: &'static str, path: &Path) -> Result<String, TlsError> {
    crate::limits::read_small(path, MAX_PEM_BYTES)
        .map_err(|e| TlsError::file(key, path, TlsProblem::Read(e)))
}

/// The certificates of the PEM file `path` (at least one).
fn certificates(key: &'static str, path: &Path) -> Result<Vec<CertificateDer<'static>>, TlsError> {
    let text = read(key, path)?;
    let certs: Vec<_> = CertificateDer::pem_slice_iter(text.as_bytes())
        .collect::<Result<_, _>>()
        .map_err(|e| TlsError::file(key, path, TlsProblem::NotPem(e)))?;
    if certs.is_empty() {
        return Err(TlsError::file(key, path, TlsProblem::NoCertificate));
    }
    Ok(certs)
}

/// A client configuration trusting the certificates of `ca` (`mqtt.ca_file`) and, given
/// `client` = (certificate, key) (`mqtt.client_cert_file`, `mqtt.client_key_file`),
/// presenting that certificate.
pub fn client_config(
    ca: &Path,
    client: Option<(&Path, &Path)>,
) -> Result<Arc<rustls::ClientConfig>, TlsError> {
    let mut roots = rustls::RootCertStore::empty();
    for c in certificates("ca_file", ca)? {
        roots
            .add(c)
            .map_err(|e| TlsError::file("ca_file", ca, TlsProblem::Unusable(e)))?;
    }
    let provider = Arc::new(rustls::crypto::ring::default_provider());
    let builder = rustls::ClientConfig::builder_with_provider(provider)
        .with_safe_default_protocol_versions()
        .map_err(TlsError::Protocol)?
        .with_root_certificates(roots);
    let config = match client {
        Some((cert, key)) => {
            let chain = certificates("client_cert_file", cert)?;
            let text = read("client_key_file", key)?;
            let der = PrivateKeyDer::from_pem_slice(text.as_bytes())
                .map_err(|e| TlsError::file("client_key_file", key, TlsProblem::NoKey(e)))?;
            builder
                .with_client_auth_cert(chain, der)
                .map_err(|e| TlsError::file("client_key_file", key, TlsProblem::Mismatch(e)))?
        }
        None => builder.with_no_client_auth(),
    };
    Ok(Arc::new(config))
}
