//! `tessera certs`: a private certificate authority for a farm, and the certificates it
//! signs: one for the coordinator (the DNS names and IP addresses clients reach it by) and
//! one per client for mutual TLS (its common name is the client's name, its OU its role).
//! Keys are written with mode 0600, and no file is ever overwritten.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{bail, Context, Result};
use rcgen::{
    BasicConstraints, CertificateParams, DistinguishedName, DnType, ExtendedKeyUsagePurpose, IsCa, Issuer,
    KeyPair, KeyUsagePurpose,
};
use tessera_coordinator::Role;

/// `tessera certs …`.
#[derive(Debug, clap::Subcommand)]
#[deny(missing_docs)]
pub enum CertsCommand {
    /// Make a CA: DIR/ca.pem (every client's --ca, and the coordinator's --tls-client-ca
    /// for mutual TLS) and DIR/ca.key (signs the others; keep it off the farm).
    Ca {
        /// The directory to write into (made if missing).
        #[arg(long)]
        dir: PathBuf,
        /// The CA's common name.
        #[arg(long, default_value = "tessera farm CA")]
        name: String,
        /// Days it is valid.
        #[arg(long, default_value_t = 3650)]
        days: u32,
    },
    /// Make the coordinator's certificate, signed by the CA in DIR: DIR/server.pem and
    /// DIR/server.key (its --tls-cert and --tls-key).
    Server {
        /// The directory holding ca.pem and ca.key, and where to write.
        #[arg(long)]
        dir: PathBuf,
        /// A DNS name or IP address clients reach the coordinator by (repeat for several).
        #[arg(long = "host", required = true)]
        hosts: Vec<String>,
        /// Days it is valid.
        #[arg(long, default_value_t = 825)]
        days: u32,
    },
    /// Make a client certificate for mutual TLS, signed by the CA in DIR: DIR/NAME.pem and
    /// DIR/NAME.key (the client's --tls-cert and --tls-key).
    Client {
        /// The directory holding ca.pem and ca.key, and where to write.
        #[arg(long)]
        dir: PathBuf,
        /// The client's name (the certificate's common name): a job's owner, a worker's identity.
        #[arg(long)]
        name: String,
        /// Its role: admin, submitter, worker or viewer (the certificate's OU).
        #[arg(long)]
        role: String,
        /// Days it is valid.
        #[arg(long, default_value_t = 825)]
        days: u32,
    },
}

/// Runs `tessera certs …`.
pub fn run(cmd: CertsCommand) -> Result<ExitCode> {
    match cmd {
        CertsCommand::Ca { dir, name, days } => {
            std::fs::create_dir_all(&dir).with_context(|| format!("making {}", dir.display()))?;
            let mut params = CertificateParams::new(Vec::<String>::new())?;
            params.distinguished_name = name_of(&name, None);
            params.is_ca = IsCa::Ca(BasicConstraints::Constrained(0));
            params.key_usages = vec![
                KeyUsagePurpose::KeyCertSign,
                KeyUsagePurpose::CrlSign,
                KeyUsagePurpose::DigitalSignature,
            ];
            validity(&mut params, days)?;
            let key = KeyPair::generate()?;
            let cert = params.self_signed(&key)?;
            write_pair(&dir, "ca", &cert.pem(), &key.serialize_pem())?;
        }
        CertsCommand::Server { dir, hosts, days } => {
            let issuer = load_ca(&dir)?;
            for h in &hosts {
                if h.is_empty() || h.contains(['/', ' ', ':']) && h.parse::<std::net::IpAddr>().is_err() {
                    bail!("--host {h:?} is neither a DNS name nor an IP address");
                }
            }
            // IP addresses become IP SANs, the rest DNS names.
            let mut params = CertificateParams::new(hosts.clone())?;
            params.distinguished_name = name_of(&hosts[0], None);
            params.key_usages = vec![KeyUsagePurpose::DigitalSignature];
            params.extended_key_usages = vec![ExtendedKeyUsagePurpose::ServerAuth];
            validity(&mut params, days)?;
            let key = KeyPair::generate()?;
            let cert = params.signed_by(&key, &issuer)?;
            write_pair(&dir, "server", &cert.pem(), &key.serialize_pem())?;
        }
        CertsCommand::Client { dir, name, role, days } => {
            let role = Role::parse(&role)
                .with_context(|| format!("--role {role:?}: expected admin, submitter, worker or viewer"))?;
            if name.is_empty()
                || name.len() > 64
                || !name.chars().all(|c| c.is_ascii_alphanumeric() || "._-@:+".contains(c))
            {
                bail!("--name {name:?} must be 1 to 64 letters, digits or ._-@:+");
            }
            if name == "ca" || name == "server" {
                bail!("--name {name:?} would overwrite the CA's or the server's files; choose another");
            }
            let issuer = load_ca(&dir)?;
            let mut params = CertificateParams::new(Vec::<String>::new())?;
            params.distinguished_name = name_of(&name, Some(role));
            params.key_usages = vec![KeyUsagePurpose::DigitalSignature];
            params.extended_key_usages = vec![ExtendedKeyUsagePurpose::ClientAuth];
            validity(&mut params, days)?;
            let key = KeyPair::generate()?;
            let cert = params.signed_by(&key, &issuer)?;
            write_pair(&dir, &name, &cert.pem(), &key.serialize_pem())?;
        }
    }
    Ok(ExitCode::SUCCESS)
}

fn name_of(common_name: &str, role: Option<Role>) -> DistinguishedName {
    let mut dn = DistinguishedName::new();
    dn.push(DnType::CommonName, common_name);
    if let Some(role) = role {
        dn.push(DnType::OrganizationalUnitName, role.name());
    }
    dn
}

/// Valid from an hour ago (clocks differ a little) for `days`.
fn validity(params: &mut CertificateParams, days: u32) -> Result<()> {
    if days == 0 || days > 36500 {
        bail!("--days must be 1..=36500, got {days}");
    }
    let now = time::OffsetDateTime::now_utc();
    params.not_before = now - time::Duration::hours(1);
    params.not_after = now + time::Duration::days(i64::from(days));
    Ok(())
}

/// The CA in `dir`, to sign with.
fn load_ca(dir: &Path) -> Result<Issuer<'static, KeyPair>> {
    let (cert, key) = (dir.join("ca.pem"), dir.join("ca.key"));
    let read = |p: &Path| {
        std::fs::read_to_string(p).with_context(|| {
            format!("reading {} (make a CA first with `tessera certs ca --dir`)", p.display())
        })
    };
    let key =
        KeyPair::from_pem(&read(&key)?).with_context(|| format!("{} is not a PEM key", key.display()))?;
    Issuer::from_ca_cert_pem(&read(&cert)?, key)
        .with_context(|| format!("{} is not a PEM CA certificate", cert.display()))
}

/// Writes `dir/stem.pem` and `dir/stem.key` (mode 0600), refusing to overwrite either.
fn write_pair(dir: &Path, stem: &str, cert: &str, key: &str) -> Result<()> {
    let (cert_path, key_path) = (dir.join(format!("{stem}.pem")), dir.join(format!("{stem}.key")));
    for p in [&cert_path, &key_path] {
        if p.exists() {
            bail!("{} exists; remove it first to make a new one", p.display());
        }
    }
    write_new(&key_path, key, 0o600)?;
    write_new(&cert_path, cert, 0o644)?;
    eprintln!("wrote {} and {}", cert_path.display(), key_path.display());
    Ok(())
}

fn write_new(path: &Path, text: &str, mode: u32) -> Result<()> {
    let mut options = std::fs::OpenOptions::new();
    options.write(true).create_new(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        // The mode is set at creation, so the key is never readable by others, even briefly.
        options.mode(mode);
    }
    #[cfg(not(unix))]
    let _ = mode;
    let mut f = options.open(path).with_context(|| format!("creating {}", path.display()))?;
    f.write_all(text.as_bytes())
        .and_then(|_| f.sync_all())
        .with_context(|| format!("writing {}", path.display()))
}
