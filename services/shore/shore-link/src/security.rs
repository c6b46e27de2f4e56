//! Who may be on the other end of the link: zenoh's TLS with mutual authentication against the
//! vehicle's own certificate authority, made by [`generate`] (`shore-link keys`). Plain TCP only when
//! asked for by name (`--insecure`).
//!
//! - The vehicle listens with its certificate and asks every connecting peer for one; only a
//!   certificate signed by the vehicle's CA is accepted (zenoh's listener trusts only the configured
//!   root, never the system's).
//! - The shore connects with its own certificate and checks the vehicle's, the name included (the
//!   address it connects to must be one of the vehicle certificate's names). Zenoh's connecting side
//!   also trusts the public web authorities; those never sign a private address (10.x, 192.168.x) or
//!   a name without a public domain (`vehicle`, `*.internal`), which is what a vehicle is reached by.
//! - Each certificate carries one role (extended key usage): the vehicle's serves, the shore's is a
//!   client's. A copy of the vehicle's key cannot act as a shore, nor the shore's as a vehicle.
//! - Only the chosen protocol is accepted at all (`transport/link/protocols`): a TLS link refuses a
//!   plain TCP peer before any zenoh message.

use rcgen::{
    BasicConstraints, CertificateParams, DistinguishedName, DnType, ExtendedKeyUsagePurpose, IsCa,
    Issuer, KeyPair, KeyUsagePurpose, SanType,
};
use std::fmt;
use std::path::{Path, PathBuf};
use time::{Duration as TimeSpan, OffsetDateTime};

/// The vehicle's port when an endpoint names none.
pub const DEFAULT_PORT: u16 = 7447;

/// The files of one side, in its key directory (`DIR/vehicle` or `DIR/shore` of `keys DIR`).
pub const CA_FILE: &str = "ca.pem";
pub const CERT_FILE: &str = "cert.pem";
pub const KEY_FILE: &str = "key.pem";

/// How this end proves itself and checks the other.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Security {
    /// Mutual TLS with the key directory's CA, certificate and private key.
    Tls(KeyFiles),
    /// Plain TCP: anyone who reaches the port may join. Only with `--insecure`.
    Insecure,
}

impl Security {
    /// The zenoh scheme of this security's endpoints.
    pub fn scheme(&self) -> &'static str {
        match self {
            Security::Tls(_) => "tls",
            Security::Insecure => "tcp",
        }
    }
}

/// One side's files.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct KeyFiles {
    pub ca: PathBuf,
    pub cert: PathBuf,
    pub key: PathBuf,
}

impl KeyFiles {
    /// The files of the key directory `dir`.
    pub fn in_dir(dir: &Path) -> KeyFiles {
        KeyFiles {
            ca: dir.join(CA_FILE),
            cert: dir.join(CERT_FILE),
            key: dir.join(KEY_FILE),
        }
    }
}

/// A bad endpoint or key file, said with the value at fault.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Refused(pub String);

impl fmt::Display for Refused {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for Refused {}

/// The zenoh endpoint for `given` (`HOST:PORT`, `HOST`, or with its scheme): `tls/...` unless
/// insecure. A scheme that does not match the security is refused rather than silently changed: a
/// `tcp/` endpoint without `--insecure` would otherwise open the unauthenticated link it names.
pub fn endpoint(given: &str, security: &Security) -> Result<String, Refused> {
    let want = security.scheme();
    let address = match given.split_once('/') {
        Some((scheme, rest)) if scheme == want => rest,
        Some(("tcp", _)) => {
            return Err(Refused(format!(
                "endpoint `{given}`: plain TCP is unauthenticated; use tls/ (the default) or pass --insecure"
            )));
        }
        Some(("tls", _)) => {
            return Err(Refused(format!(
                "endpoint `{given}`: --insecure links are plain TCP (tcp/...), not TLS"
            )));
        }
        Some((scheme, _)) => {
            return Err(Refused(format!(
                "endpoint `{given}`: unknown scheme `{scheme}` (tls/HOST:PORT, or tcp/HOST:PORT with --insecure)"
            )));
        }
        None => given,
    };
    if address.is_empty() {
        return Err(Refused(format!("endpoint `{given}`: no host")));
    }
    // A port is the part after the last colon, unless that colon is inside an IPv6 address.
    let with_port = match address.rsplit_once(':') {
        Some((host, port)) if !host.is_empty() && (!host.contains(':') || host.ends_with(']')) => {
            port.parse::<u16>().map_err(|_| {
                Refused(format!("endpoint `{given}`: port `{port}` is not a number"))
            })?;
            address.to_owned()
        }
        _ if address.contains(':') && !address.starts_with('[') => {
            return Err(Refused(format!(
                "endpoint `{given}`: write an IPv6 address in brackets, e.g. [::1]:{DEFAULT_PORT}"
            )));
        }
        _ => format!("{address}:{DEFAULT_PORT}"),
    };
    Ok(format!("{want}/{with_port}"))
}

/// The zenoh settings of `security` for one side, as (key, JSON5 value): which protocol alone is
/// accepted and, for TLS, the files and the checks (mutual authentication, the vehicle's name, the
/// link closed when a certificate expires).
pub fn tls_settings(vehicle: bool, security: &Security) -> Vec<(&'static str, String)> {
    let text = |p: &Path| serde_json::Value::from(p.to_string_lossy().into_owned()).to_string();
    let mut settings = vec![(
        "transport/link/protocols",
        format!("[\"{}\"]", security.scheme()),
    )];
    if let Security::Tls(files) = security {
        let (cert, key) = match vehicle {
            true => (
                "transport/link/tls/listen_certificate",
                "transport/link/tls/listen_private_key",
            ),
            false => (
                "transport/link/tls/connect_certificate",
                "transport/link/tls/connect_private_key",
            ),
        };
        settings.extend([
            ("transport/link/tls/root_ca_certificate", text(&files.ca)),
            (cert, text(&files.cert)),
            (key, text(&files.key)),
            ("transport/link/tls/enable_mtls", "true".to_owned()),
            (
                "transport/link/tls/verify_name_on_connect",
                "true".to_owned(),
            ),
            (
                "transport/link/tls/close_link_on_expiration",
                "true".to_owned(),
            ),
        ]);
    }
    settings
}

/// A private key readable by anyone but its owner is refused, as ssh refuses one: whoever reads it
/// can be this end of the link. `mode` is the file's permission bits.
pub fn check_key_mode(path: &Path, mode: u32) -> Result<(), Refused> {
    if mode & 0o077 != 0 {
        return Err(Refused(format!(
            "{}: the private key is readable by others (mode {:04o}); `chmod 600 {}`",
            path.display(),
            mode & 0o7777,
            path.display()
        )));
    }
    Ok(())
}

/// A certificate and its private key, PEM.
#[derive(Clone, Debug)]
pub struct Pair {
    pub cert_pem: String,
    pub key_pem: String,
}

/// What `shore-link keys` writes: the vehicle's CA certificate (its private key is not kept: new
/// pairs come from a new run, which replaces both sides' directories) and the two signed pairs.
#[derive(Clone, Debug)]
pub struct Bundle {
    pub ca_pem: String,
    pub vehicle: Pair,
    pub shore: Pair,
    pub vehicle_names: Vec<String>,
    pub not_after: OffsetDateTime,
}

/// The common names of the two certificates.
pub const VEHICLE_CN: &str = "cabletrack-vehicle";
pub const SHORE_CN: &str = "cabletrack-shore";

/// A CA valid from `now` for `days`, and the vehicle's (server) and the shore's (client) pairs it
/// signs. `vehicle_names` are the names and addresses the shore may reach the vehicle by.
pub fn generate(
    vehicle_names: &[String],
    days: u32,
    now: OffsetDateTime,
) -> Result<Bundle, Refused> {
    if vehicle_names.is_empty() {
        return Err(Refused(
            "the vehicle's certificate needs at least one name or address".into(),
        ));
    }
    if days == 0 {
        return Err(Refused("--days must be at least 1".into()));
    }
    fn err(what: &str) -> impl FnOnce(rcgen::Error) -> Refused + '_ {
        move |e| Refused(format!("{what}: {e}"))
    }
    // A clock a little behind on the other side must not make a fresh certificate "not yet valid".
    let not_before = now - TimeSpan::hours(1);
    let not_after = now + TimeSpan::days(days.into());
    let name = |cn: &str| {
        let mut dn = DistinguishedName::new();
        dn.push(DnType::OrganizationName, "cabletrack");
        dn.push(DnType::CommonName, cn);
        dn
    };

    let mut ca = CertificateParams::default();
    ca.distinguished_name = name("cabletrack vehicle CA");
    ca.is_ca = IsCa::Ca(BasicConstraints::Constrained(0));
    ca.key_usages = vec![KeyUsagePurpose::KeyCertSign, KeyUsagePurpose::CrlSign];
    ca.not_before = not_before;
    ca.not_after = not_after;
    let ca_key = KeyPair::generate().map_err(err("the CA's key"))?;
    let ca_cert = ca
        .self_signed(&ca_key)
        .map_err(err("the CA's certificate"))?;
    let issuer = Issuer::new(ca, ca_key);

    let leaf =
        |cn: &str, sans: Vec<SanType>, role: ExtendedKeyUsagePurpose| -> Result<Pair, Refused> {
            let mut p = CertificateParams::default();
            p.distinguished_name = name(cn);
            p.subject_alt_names = sans;
            p.is_ca = IsCa::ExplicitNoCa;
            p.key_usages = vec![KeyUsagePurpose::DigitalSignature];
            p.extended_key_usages = vec![role];
            p.use_authority_key_identifier_extension = true;
            p.not_before = not_before;
            p.not_after = not_after;
            let key = KeyPair::generate().map_err(err(cn))?;
            let cert = p.signed_by(&key, &issuer).map_err(err(cn))?;
            Ok(Pair {
                cert_pem: cert.pem(),
                key_pem: key.serialize_pem(),
            })
        };
    let sans = vehicle_names
        .iter()
        .map(|n| match n.trim_matches(['[', ']']).parse::<std::net::IpAddr>() {
            Ok(ip) => Ok(SanType::IpAddress(ip)),
            Err(_) if is_host_name(n) => n
                .clone()
                .try_into()
                .map(SanType::DnsName)
                .map_err(|e| Refused(format!("vehicle name `{n}`: {e}"))),
            Err(_) => Err(Refused(format!(
                "vehicle name `{n}`: neither an IP address nor a host name (letters, digits, hyphens, dots)"
            ))),
        })
        .collect::<Result<Vec<_>, _>>()?;
    let vehicle = leaf(VEHICLE_CN, sans, ExtendedKeyUsagePurpose::ServerAuth)?;
    let shore_name = SHORE_CN
        .to_owned()
        .try_into()
        .map_err(|e| Refused(format!("{SHORE_CN}: {e}")))?;
    let shore = leaf(
        SHORE_CN,
        vec![SanType::DnsName(shore_name)],
        ExtendedKeyUsagePurpose::ClientAuth,
    )?;
    Ok(Bundle {
        ca_pem: ca_cert.pem(),
        vehicle,
        shore,
        vehicle_names: vehicle_names.to_vec(),
        not_after,
    })
}

/// A DNS host name: dot-separated labels of 1 to 63 letters, digits and hyphens, no label starting
/// or ending with a hyphen.
fn is_host_name(name: &str) -> bool {
    name.len() <= 253
        && name.split('.').all(|label| {
            (1..=63).contains(&label.len())
                && label
                    .bytes()
                    .all(|b| b.is_ascii_alphanumeric() || b == b'-')
                && !label.starts_with('-')
                && !label.ends_with('-')
        })
}

/// Writes `bundle` under `dir`: `vehicle/` (stays on the vehicle) and `shore/` (copied to the
/// shore computer), each with `ca.pem`, `cert.pem` and `key.pem`; directories 0700, private keys
/// 0600, created anew (an existing side directory is refused, never overwritten: replacing keys is
/// a decision, taken by removing it). Returns the files written.
pub fn write_bundle(dir: &Path, bundle: &Bundle) -> Result<Vec<PathBuf>, Refused> {
    use std::io::Write;
    use std::os::unix::fs::{DirBuilderExt, OpenOptionsExt};
    fn io(p: &Path) -> impl FnOnce(std::io::Error) -> Refused + '_ {
        move |e| Refused(format!("{}: {e}", p.display()))
    }
    std::fs::create_dir_all(dir).map_err(io(dir))?;
    let mut written = Vec::new();
    for (side, pair) in [("vehicle", &bundle.vehicle), ("shore", &bundle.shore)] {
        let sub = dir.join(side);
        std::fs::DirBuilder::new()
            .mode(0o700)
            .create(&sub)
            .map_err(|e| match e.kind() {
                std::io::ErrorKind::AlreadyExists => Refused(format!(
                    "{}: already exists; remove it to make new keys (both sides' directories go together)",
                    sub.display()
                )),
                _ => Refused(format!("{}: {e}", sub.display())),
            })?;
        for (name, text, mode) in [
            (CA_FILE, &bundle.ca_pem, 0o644),
            (CERT_FILE, &pair.cert_pem, 0o644),
            (KEY_FILE, &pair.key_pem, 0o600),
        ] {
            let path = sub.join(name);
            let mut f = std::fs::OpenOptions::new()
                .write(true)
                .create_new(true)
                .mode(mode)
                .open(&path)
                .map_err(io(&path))?;
            f.write_all(text.as_bytes())
                .and_then(|()| f.sync_all())
                .map_err(io(&path))?;
            written.push(path);
        }
    }
    Ok(written)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tls() -> Security {
        Security::Tls(KeyFiles::in_dir(Path::new("/keys/vehicle")))
    }

    #[test]
    fn endpoints_are_tls_by_default_and_plain_tcp_only_when_insecure() {
        assert_eq!(
            endpoint("10.0.0.1:7447", &tls()).unwrap(),
            "tls/10.0.0.1:7447"
        );
        assert_eq!(endpoint("vehicle", &tls()).unwrap(), "tls/vehicle:7447");
        assert_eq!(
            endpoint("tls/vehicle:9000", &tls()).unwrap(),
            "tls/vehicle:9000"
        );
        assert_eq!(endpoint("[::1]", &tls()).unwrap(), "tls/[::1]:7447");
        assert_eq!(endpoint("[::1]:8000", &tls()).unwrap(), "tls/[::1]:8000");
        assert_eq!(
            endpoint("10.0.0.1:7447", &Security::Insecure).unwrap(),
            "tcp/10.0.0.1:7447"
        );
        assert_eq!(
            endpoint("tcp/10.0.0.1:7447", &Security::Insecure).unwrap(),
            "tcp/10.0.0.1:7447"
        );
        let refused = |given: &str, security: &Security, says: &str| {
            let e = endpoint(given, security).unwrap_err().0;
            assert!(e.contains(given) && e.contains(says), "{e}");
        };
        refused("tcp/10.0.0.1:7447", &tls(), "--insecure");
        refused("tls/10.0.0.1:7447", &Security::Insecure, "plain TCP");
        refused("udp/10.0.0.1:7447", &tls(), "unknown scheme `udp`");
        refused("10.0.0.1:port", &tls(), "`port` is not a number");
        refused("::1", &tls(), "brackets");
        refused("tls/", &tls(), "no host");
    }

    #[test]
    fn tls_settings_name_the_files_and_turn_every_check_on() {
        let files = KeyFiles::in_dir(Path::new("/k/shore"));
        let get = |s: &[(&str, String)], k: &str| {
            s.iter().find(|(key, _)| *key == k).map(|(_, v)| v.clone())
        };
        let shore = tls_settings(false, &Security::Tls(files));
        assert_eq!(
            get(&shore, "transport/link/protocols").unwrap(),
            r#"["tls"]"#
        );
        assert_eq!(
            get(&shore, "transport/link/tls/root_ca_certificate").unwrap(),
            r#""/k/shore/ca.pem""#
        );
        assert_eq!(
            get(&shore, "transport/link/tls/connect_certificate").unwrap(),
            r#""/k/shore/cert.pem""#
        );
        assert_eq!(
            get(&shore, "transport/link/tls/connect_private_key").unwrap(),
            r#""/k/shore/key.pem""#
        );
        assert_eq!(get(&shore, "transport/link/tls/listen_private_key"), None);
        for check in [
            "enable_mtls",
            "verify_name_on_connect",
            "close_link_on_expiration",
        ] {
            assert_eq!(
                get(&shore, &format!("transport/link/tls/{check}")).as_deref(),
                Some("true"),
                "{check}"
            );
        }
        let vehicle = tls_settings(true, &tls());
        assert_eq!(
            get(&vehicle, "transport/link/tls/listen_certificate").unwrap(),
            r#""/keys/vehicle/cert.pem""#
        );
        assert_eq!(
            get(&vehicle, "transport/link/tls/connect_certificate"),
            None
        );
        let plain = tls_settings(true, &Security::Insecure);
        assert_eq!(
            plain,
            vec![("transport/link/protocols", r#"["tcp"]"#.to_owned())]
        );
    }

    #[test]
    fn a_private_key_readable_by_others_is_refused() {
        let p = Path::new("/k/shore/key.pem");
        assert!(check_key_mode(p, 0o100600).is_ok());
        assert!(check_key_mode(p, 0o100400).is_ok());
        for mode in [0o100640, 0o100604, 0o100644] {
            let e = check_key_mode(p, mode).unwrap_err().0;
            assert!(
                e.contains("/k/shore/key.pem") && e.contains("chmod 600"),
                "{e}"
            );
        }
    }

    #[test]
    fn a_bundle_needs_a_vehicle_name_and_a_validity() {
        let now = OffsetDateTime::UNIX_EPOCH + TimeSpan::days(20_000);
        assert!(generate(&[], 30, now).is_err());
        assert!(generate(&["vehicle".into()], 0, now).is_err());
        for bad in [
            "not a name!",
            "-vehicle",
            "vehicle..internal",
            "10.0.0.1:7447",
        ] {
            let e = generate(&[bad.into()], 30, now).unwrap_err().0;
            assert!(e.contains(bad), "{e}");
        }
        let b = generate(&["vehicle".into(), "10.0.0.1".into()], 30, now).unwrap();
        assert_eq!(b.not_after, now + TimeSpan::days(30));
        for pem in [&b.ca_pem, &b.vehicle.cert_pem, &b.shore.cert_pem] {
            assert!(pem.starts_with("-----BEGIN CERTIFICATE-----"), "{pem}");
        }
        for pem in [&b.vehicle.key_pem, &b.shore.key_pem] {
            assert!(pem.starts_with("-----BEGIN PRIVATE KEY-----"), "{pem}");
        }
        assert_ne!(b.vehicle.key_pem, b.shore.key_pem);
    }

    #[test]
    fn keys_are_written_private_and_never_over_old_ones() {
        use std::os::unix::fs::PermissionsExt;
        let dir = tempfile::tempdir().unwrap();
        let b = generate(&["vehicle".into()], 30, OffsetDateTime::now_utc()).unwrap();
        let written = write_bundle(dir.path(), &b).unwrap();
        assert_eq!(written.len(), 6);
        let mode = |p: &Path| std::fs::metadata(p).unwrap().permissions().mode() & 0o777;
        for side in ["vehicle", "shore"] {
            let files = KeyFiles::in_dir(&dir.path().join(side));
            assert_eq!(mode(&dir.path().join(side)), 0o700, "{side}");
            assert_eq!(mode(&files.key), 0o600, "{side}");
            assert_eq!(mode(&files.cert), 0o644, "{side}");
            assert_eq!(std::fs::read_to_string(&files.ca).unwrap(), b.ca_pem);
        }
        assert_eq!(
            std::fs::read_to_string(dir.path().join("shore/key.pem")).unwrap(),
            b.shore.key_pem
        );
        let again = write_bundle(dir.path(), &b).unwrap_err().0;
        assert!(
            again.contains("vehicle") && again.contains("already exists"),
            "{again}"
        );
    }
}
