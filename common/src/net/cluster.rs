//! The cluster's certificate authority and the nodes' identities.
//!
//! The master generates a CA on first start and keeps it in its cluster directory; every node
//! (the master included) presents a certificate signed by that CA and accepts only peers that do
//! the same, so a machine without a certificate from this CA cannot join or feed a display.
//! `tessera-master issue-cert` writes a node's directory: `node.pem`, `node.key`, `ca.pem`.

use anyhow::{bail, Context, Result};
use rcgen::{
    BasicConstraints, CertificateParams, DistinguishedName, DnType, ExtendedKeyUsagePurpose, IsCa,
    Issuer, KeyPair, KeyUsagePurpose,
};
use rustls_pki_types::pem::PemObject;
use rustls_pki_types::{CertificateDer, PrivateKeyDer};
use std::path::{Path, PathBuf};

/// The name every node certificate carries and every client checks. Nodes are identified by the
/// CA, not by host names, so a wall works the same on IPs, names or loopback.
pub const CLUSTER_SERVER_NAME: &str = "tessera.cluster";

const CA_CERT: &str = "ca.pem";
const CA_KEY: &str = "ca.key";
const NODE_CERT: &str = "node.pem";
const NODE_KEY: &str = "node.key";

/// The cluster CA, as kept in the master's cluster directory.
pub struct ClusterCa {
    dir: PathBuf,
    key: KeyPair,
    cert_pem: String,
}

fn ca_params() -> Result<CertificateParams> {
    let mut params = CertificateParams::new(Vec::<String>::new())?;
    let mut dn = DistinguishedName::new();
    dn.push(DnType::CommonName, "Tessera cluster CA");
    params.distinguished_name = dn;
    params.is_ca = IsCa::Ca(BasicConstraints::Unconstrained);
    params.key_usages = vec![KeyUsagePurpose::KeyCertSign, KeyUsagePurpose::CrlSign];
    Ok(params)
}

fn write_private(path: &Path, text: &str) -> Result<()> {
    use std::io::Write;
    let mut options = std::fs::OpenOptions::new();
    options.write(true).create(true).truncate(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        options.mode(0o600);
    }
    let mut file = options
        .open(path)
        .with_context(|| format!("cannot write {}", path.display()))?;
    file.write_all(text.as_bytes())?;
    Ok(())
}

impl ClusterCa {
    /// Opens the CA in `dir`, creating the directory and a new CA on first use.
    pub fn open_or_create(dir: &Path) -> Result<ClusterCa> {
        let (cert_path, key_path) = (dir.join(CA_CERT), dir.join(CA_KEY));
        if cert_path.exists() != key_path.exists() {
            bail!(
                "cluster directory {} has only one of {CA_CERT} and {CA_KEY}; restore the other or remove both to start a new cluster",
                dir.display()
            );
        }
        if !cert_path.exists() {
            std::fs::create_dir_all(dir)
                .with_context(|| format!("cannot create cluster directory {}", dir.display()))?;
            let key = KeyPair::generate()?;
            let cert = ca_params()?.self_signed(&key)?;
            std::fs::write(&cert_path, cert.pem())?;
            write_private(&key_path, &key.serialize_pem())?;
            tracing::info!("created a new cluster CA in {}", dir.display());
        }
        let key_pem = std::fs::read_to_string(&key_path)
            .with_context(|| format!("cannot read {}", key_path.display()))?;
        let key = KeyPair::from_pem(&key_pem)
            .with_context(|| format!("{} is not a private key", key_path.display()))?;
        let cert_pem = std::fs::read_to_string(&cert_path)
            .with_context(|| format!("cannot read {}", cert_path.display()))?;
        Ok(ClusterCa {
            dir: dir.to_path_buf(),
            key,
            cert_pem,
        })
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Writes a node identity (`node.pem`, `node.key`, `ca.pem`) signed by this CA into `out`.
    pub fn issue(&self, name: &str, out: &Path) -> Result<()> {
        let issuer = Issuer::new(ca_params()?, &self.key);
        let mut params = CertificateParams::new(vec![CLUSTER_SERVER_NAME.to_string()])?;
        let mut dn = DistinguishedName::new();
        dn.push(DnType::CommonName, name);
        params.distinguished_name = dn;
        params.extended_key_usages = vec![
            ExtendedKeyUsagePurpose::ServerAuth,
            ExtendedKeyUsagePurpose::ClientAuth,
        ];
        params.key_usages = vec![KeyUsagePurpose::DigitalSignature];
        let key = KeyPair::generate()?;
        let cert = params.signed_by(&key, &issuer)?;
        std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
        std::fs::write(out.join(NODE_CERT), cert.pem())?;
        write_private(&out.join(NODE_KEY), &key.serialize_pem())?;
        std::fs::write(out.join(CA_CERT), &self.cert_pem)?;
        Ok(())
    }
}

/// A node's certificate, key and the CA it trusts, loaded from a node directory.
#[derive(Debug)]
pub struct NodeIdentity {
    pub cert: CertificateDer<'static>,
    pub key: PrivateKeyDer<'static>,
    pub ca: CertificateDer<'static>,
}

impl NodeIdentity {
    pub fn load(dir: &Path) -> Result<NodeIdentity> {
        if !dir.is_dir() {
            bail!(
                "certificate directory {} does not exist (create it with `tessera-master issue-cert --name NODE --out {}`)",
                dir.display(),
                dir.display()
            );
        }
        let read_cert = |name: &str| {
            let path = dir.join(name);
            CertificateDer::from_pem_file(&path).with_context(|| {
                format!(
                    "cannot read certificate {} (create node certificates with `tessera-master issue-cert`)",
                    path.display()
                )
            })
        };
        let key_path = dir.join(NODE_KEY);
        let key = PrivateKeyDer::from_pem_file(&key_path)
            .with_context(|| format!("cannot read private key {}", key_path.display()))?;
        Ok(NodeIdentity {
            cert: read_cert(NODE_CERT)?,
            key,
            ca: read_cert(CA_CERT)?,
        })
    }
}
