//! The cluster's certificate authority and the nodes' identities.
//!
//! The master generates a CA on first start and keeps it in its cluster directory; every node
//! (the master included) presents a certificate signed by that CA and accepts only peers that do
//! the same, so a machine without a certificate from this CA cannot join or feed a display.
//! `tessera-master issue-cert` writes a node's directory: `node.pem`, `node.key`, `ca.pem`.

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

/// What a certificate lets its holder be in the cluster. The role is a second subject name of
/// the certificate (`control.role.tessera.cluster`), so it is signed by the CA like the rest:
/// a holder cannot claim a role its certificate does not name.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum CertRole {
    /// The master: the certificate its endpoint presents to the nodes.
    Master,
    /// A render node.
    Render,
    /// A display node; its certificate may also name the one display it may show.
    Display,
    /// An operator's or a script's control client.
    Control,
}

impl CertRole {
    /// Every role, for going through them.
    pub const ALL: [CertRole; 4] = [
        CertRole::Master,
        CertRole::Render,
        CertRole::Display,
        CertRole::Control,
    ];

    /// The role's word, as its subject name carries it: `render` in `render.role.tessera.cluster`.
    pub fn name(self) -> &'static str {
        match self {
            CertRole::Master => "master",
            CertRole::Render => "render",
            CertRole::Display => "display",
            CertRole::Control => "control",
        }
    }

    fn subject_name(self) -> String {
        format!("{}.role.{CLUSTER_SERVER_NAME}", self.name())
    }
}

/// The name a display certificate carries for its display id: the master lets a display
/// certificate join as that display only.
fn display_subject_name(display: u32) -> String {
    format!("{display}.display.{CLUSTER_SERVER_NAME}")
}

/// Whether a (verified) certificate was issued for display `display`.
pub fn cert_is_for_display(cert: &CertificateDer<'_>, display: u32) -> bool {
    let Ok(parsed) = webpki::EndEntityCert::try_from(cert) else {
        return false;
    };
    rustls_pki_types::ServerName::try_from(display_subject_name(display))
        .is_ok_and(|name| parsed.verify_is_valid_for_subject_name(&name).is_ok())
}

/// The roles a (verified) certificate names; empty for a certificate from before roles, which
/// the master refuses.
pub fn cert_roles(cert: &CertificateDer<'_>) -> Vec<CertRole> {
    let Ok(parsed) = webpki::EndEntityCert::try_from(cert) else {
        return Vec::new();
    };
    CertRole::ALL
        .into_iter()
        .filter(|role| {
            rustls_pki_types::ServerName::try_from(role.subject_name())
                .is_ok_and(|name| parsed.verify_is_valid_for_subject_name(&name).is_ok())
        })
        .collect()
}

const CA_CERT: &str = "ca.pem";
const CA_KEY: &str = "ca.key";
const NODE_CERT: &str = "node.pem";
const NODE_KEY: &str = "node.key";

/// The cluster CA, as kept in the master's cluster directory.
pub struct ClusterCa {
    dir: PathBuf,
    key: KeyPair,
    cert_pem: String,
    /// Days a certificate issued from now on is valid for.
    valid_days: i64,
}

/// How long a node certificate is valid unless told otherwise: ten years.
pub const DEFAULT_VALID_DAYS: i64 = 3650;

/// Why a certificate or key could not be made, read or written.
#[derive(Debug, thiserror::Error)]
pub enum CertError {
    /// The cluster directory holds the CA's certificate or its key, not both.
    #[error(
        "cluster directory {dir} has only one of {CA_CERT} and {CA_KEY}; restore the other or remove both to start a new cluster"
    )]
    HalfCa {
        /// The master's cluster directory.
        dir: PathBuf,
    },
    /// A node's certificate directory does not exist.
    #[error(
        "certificate directory {dir} does not exist (create it with `tessera-master issue-cert --name NODE --out {dir}`)"
    )]
    NoCertDir {
        /// The node's certificate directory (`--cert-dir`).
        dir: PathBuf,
    },
    /// A file or directory could not be read, written or created.
    #[error("cannot {what} {path}")]
    Io {
        /// What was being done: `read`, `write`, `create cluster directory`.
        what: &'static str,
        /// The file or directory.
        path: PathBuf,
        /// The operating system's reason.
        source: std::io::Error,
    },
    /// A certificate or key file is missing or holds no PEM item of its kind.
    #[error(
        "cannot read {what} {path} (create node certificates with `tessera-master issue-cert`)"
    )]
    Pem {
        /// `certificate` or `private key`.
        what: &'static str,
        /// The file.
        path: PathBuf,
        /// Why it is not what was expected (missing, not PEM, no such item in it).
        source: rustls_pki_types::pem::Error,
    },
    /// The CA's key file holds no key rcgen can sign with.
    #[error("{path} is not a private key")]
    BadKey {
        /// The CA's `ca.key`.
        path: PathBuf,
        /// rcgen's reason.
        source: rcgen::Error,
    },
    /// rcgen could not make a key or a certificate.
    #[error("cannot make a certificate")]
    Make(#[from] rcgen::Error),
}

fn io<'a>(what: &'static str, path: &'a Path) -> impl FnOnce(std::io::Error) -> CertError + 'a {
    move |source| CertError::Io {
        what,
        path: path.to_path_buf(),
        source,
    }
}

fn ca_params() -> Result<CertificateParams, CertError> {
    let mut params = CertificateParams::new(Vec::<String>::new())?;
    let mut dn = DistinguishedName::new();
    dn.push(DnType::CommonName, "Tessera cluster CA");
    params.distinguished_name = dn;
    params.is_ca = IsCa::Ca(BasicConstraints::Unconstrained);
    params.key_usages = vec![KeyUsagePurpose::KeyCertSign, KeyUsagePurpose::CrlSign];
    Ok(params)
}

fn write_private(path: &Path, text: &str) -> Result<(), CertError> {
    use std::io::Write;
    let mut options = std::fs::OpenOptions::new();
    options.write(true).create(true).truncate(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        options.mode(0o600);
    }
    let mut file = options.open(path).map_err(io("write", path))?;
    file.write_all(text.as_bytes()).map_err(io("write", path))?;
    Ok(())
}

impl ClusterCa {
    /// Opens the CA in `dir`, creating the directory and a new CA on first use.
    pub fn open_or_create(dir: &Path) -> Result<ClusterCa, CertError> {
        let (cert_path, key_path) = (dir.join(CA_CERT), dir.join(CA_KEY));
        if cert_path.exists() != key_path.exists() {
            return Err(CertError::HalfCa {
                dir: dir.to_path_buf(),
            });
        }
        if !cert_path.exists() {
            std::fs::create_dir_all(dir).map_err(io("create cluster directory", dir))?;
            let key = KeyPair::generate()?;
            let cert = ca_params()?.self_signed(&key)?;
            std::fs::write(&cert_path, cert.pem()).map_err(io("write", &cert_path))?;
            write_private(&key_path, &key.serialize_pem())?;
            tracing::info!("created a new cluster CA in {}", dir.display());
        }
        let key_pem = std::fs::read_to_string(&key_path).map_err(io("read", &key_path))?;
        let key = KeyPair::from_pem(&key_pem).map_err(|source| CertError::BadKey {
            path: key_path.clone(),
            source,
        })?;
        let cert_pem = std::fs::read_to_string(&cert_path).map_err(io("read", &cert_path))?;
        Ok(ClusterCa {
            dir: dir.to_path_buf(),
            key,
            cert_pem,
            valid_days: DEFAULT_VALID_DAYS,
        })
    }

    /// The cluster directory the CA was opened from.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Writes a node identity (`node.pem`, `node.key`, `ca.pem`) signed by this CA into `out`,
    /// for the role `role` (`None`: a render or display node, as before roles existed).
    pub fn issue(&self, name: &str, out: &Path, role: Option<CertRole>) -> Result<(), CertError> {
        self.issue_names(
            name,
            out,
            role.map(CertRole::subject_name).into_iter().collect(),
        )
    }

    /// Issues a display node's certificate, for display `display` only.
    pub fn issue_display(&self, name: &str, out: &Path, display: u32) -> Result<(), CertError> {
        let names = vec![
            CertRole::Display.subject_name(),
            display_subject_name(display),
        ];
        self.issue_names(name, out, names)
    }

    /// Certificates issued from now on are valid for `days` from now (a negative number
    /// issues one that has already expired, for testing that it is refused).
    pub fn valid_for(mut self, days: i64) -> Self {
        self.valid_days = days;
        self
    }

    fn issue_names(&self, name: &str, out: &Path, grants: Vec<String>) -> Result<(), CertError> {
        let issuer = Issuer::new(ca_params()?, &self.key);
        let mut names = vec![CLUSTER_SERVER_NAME.to_string()];
        names.extend(grants);
        let mut params = CertificateParams::new(names)?;
        let now = time::OffsetDateTime::now_utc();
        params.not_after = now + time::Duration::days(self.valid_days);
        // An hour back, against clocks a little behind the master's.
        params.not_before =
            (now - time::Duration::hours(1)).min(params.not_after - time::Duration::days(1));
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
        std::fs::create_dir_all(out).map_err(io("create", out))?;
        let (cert_path, ca_path) = (out.join(NODE_CERT), out.join(CA_CERT));
        std::fs::write(&cert_path, cert.pem()).map_err(io("write", &cert_path))?;
        write_private(&out.join(NODE_KEY), &key.serialize_pem())?;
        std::fs::write(&ca_path, &self.cert_pem).map_err(io("write", &ca_path))?;
        Ok(())
    }
}

/// A node's certificate, key and the CA it trusts, loaded from a node directory.
#[derive(Debug)]
pub struct NodeIdentity {
    /// The node's certificate (`node.pem`), signed by the cluster CA.
    pub cert: CertificateDer<'static>,
    /// The certificate's private key (`node.key`).
    pub key: PrivateKeyDer<'static>,
    /// The cluster CA's certificate (`ca.pem`), the only one the node trusts.
    pub ca: CertificateDer<'static>,
}

impl NodeIdentity {
    /// Reads `node.pem`, `node.key` and `ca.pem` from the node directory `dir` (what
    /// `tessera-master issue-cert` wrote).
    ///
    /// # Errors
    /// [`CertError::NoCertDir`] if `dir` is no directory, [`CertError::Pem`] for a file that is
    /// missing or holds no certificate or key.
    pub fn load(dir: &Path) -> Result<NodeIdentity, CertError> {
        if !dir.is_dir() {
            return Err(CertError::NoCertDir {
                dir: dir.to_path_buf(),
            });
        }
        let read_cert = |name: &str| {
            let path = dir.join(name);
            CertificateDer::from_pem_file(&path).map_err(|source| CertError::Pem {
                what: "certificate",
                path,
                source,
            })
        };
        let key_path = dir.join(NODE_KEY);
        let key = PrivateKeyDer::from_pem_file(&key_path).map_err(|source| CertError::Pem {
            what: "private key",
            path: key_path.clone(),
            source,
        })?;
        Ok(NodeIdentity {
            cert: read_cert(NODE_CERT)?,
            key,
            ca: read_cert(CA_CERT)?,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_certificate_names_the_role_it_was_issued_for_and_no_other() {
        let dir = tempfile::tempdir().unwrap();
        let ca = ClusterCa::open_or_create(&dir.path().join("ca")).unwrap();
        for role in CertRole::ALL {
            let out = dir.path().join(role.name());
            ca.issue(role.name(), &out, Some(role)).unwrap();
            let id = NodeIdentity::load(&out).unwrap();
            assert_eq!(cert_roles(&id.cert), vec![role]);
        }
        ca.issue("old", &dir.path().join("old"), None).unwrap();
        let id = NodeIdentity::load(&dir.path().join("old")).unwrap();
        assert!(cert_roles(&id.cert).is_empty());
    }

    #[test]
    fn a_display_certificate_names_its_display_and_no_other() {
        let dir = tempfile::tempdir().unwrap();
        let ca = ClusterCa::open_or_create(&dir.path().join("ca")).unwrap();
        let out = dir.path().join("d3");
        ca.issue_display("d3", &out, 3).unwrap();
        let id = NodeIdentity::load(&out).unwrap();
        assert_eq!(cert_roles(&id.cert), vec![CertRole::Display]);
        assert!(cert_is_for_display(&id.cert, 3));
        assert!(!cert_is_for_display(&id.cert, 0));
        assert!(!cert_is_for_display(&id.cert, 30));
        // A role certificate without an id is for no display.
        ca.issue("any", &dir.path().join("any"), Some(CertRole::Display))
            .unwrap();
        let any = NodeIdentity::load(&dir.path().join("any")).unwrap();
        assert!(!cert_is_for_display(&any.cert, 0));
    }
}
