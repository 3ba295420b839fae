//! TLS for the MQTT client: the broker's certificate authority and an optional client
//! certificate, read from PEM files into a rustls configuration (the ring provider, so it
//! builds with cargo alone). Every error names the recipe key and the file.

use std::path::Path;
use std::sync::Arc;

use rustls::pki_types::pem::PemObject;
use rustls::pki_types::{CertificateDer, PrivateKeyDer};

/// Most bytes of a PEM file (CA, client certificate, key).
pub const MAX_PEM_BYTES: u64 = 1 << 20;

/// The PEM text of `path`, the recipe key `mqtt.<key>` named in an error.
fn read(key: &str, path: &Path) -> Result<String, String> {
    crate::limits::read_small(path, MAX_PEM_BYTES).map_err(|e| {
        format!(
            "mqtt.{key} = {:?}: cannot read: {e}",
            path.display().to_string()
        )
    })
}

/// The certificates of the PEM file `path` (at least one).
fn certificates(key: &str, path: &Path) -> Result<Vec<CertificateDer<'static>>, String> {
    let shown = path.display().to_string();
    let text = read(key, path)?;
    let certs: Vec<_> = CertificateDer::pem_slice_iter(text.as_bytes())
        .collect::<Result<_, _>>()
        .map_err(|e| format!("mqtt.{key} = {shown:?}: not PEM: {e}"))?;
    if certs.is_empty() {
        return Err(format!("mqtt.{key} = {shown:?}: no PEM certificate in it"));
    }
    Ok(certs)
}

/// A client configuration trusting the certificates of `ca` (`mqtt.ca_file`) and, given
/// `client` = (certificate, key) (`mqtt.client_cert_file`, `mqtt.client_key_file`),
/// presenting that certificate.
pub fn client_config(
    ca: &Path,
    client: Option<(&Path, &Path)>,
) -> Result<Arc<rustls::ClientConfig>, String> {
    let mut roots = rustls::RootCertStore::empty();
    for c in certificates("ca_file", ca)? {
        roots.add(c).map_err(|e| {
            format!(
                "mqtt.ca_file = {:?}: not a usable certificate: {e}",
                ca.display().to_string()
            )
        })?;
    }
    let provider = Arc::new(rustls::crypto::ring::default_provider());
    let builder = rustls::ClientConfig::builder_with_provider(provider)
        .with_safe_default_protocol_versions()
        .map_err(|e| format!("mqtt: TLS: {e}"))?
        .with_root_certificates(roots);
    let config = match client {
        Some((cert, key)) => {
            let chain = certificates("client_cert_file", cert)?;
            let shown = key.display().to_string();
            let text = read("client_key_file", key)?;
            let der = PrivateKeyDer::from_pem_slice(text.as_bytes()).map_err(|e| {
                format!("mqtt.client_key_file = {shown:?}: no PEM private key in it: {e}")
            })?;
            builder.with_client_auth_cert(chain, der).map_err(|e| {
                format!("mqtt.client_key_file = {shown:?}: does not fit mqtt.client_cert_file: {e}")
            })?
        }
        None => builder.with_no_client_auth(),
    };
    Ok(Arc::new(config))
}
