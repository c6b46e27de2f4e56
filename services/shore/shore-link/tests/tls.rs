//! Who the link lets in, on loopback: zenoh sessions opened with the link's own settings
//! (`shore_link::zenoh_settings`) and keys made by `shore-link keys`. The vehicle refuses a shore
//! without a certificate of its CA, the shore refuses a vehicle without one, and the certificates'
//! roles and names are checked; the real pair joins and a sample crosses. The certificates and the
//! vehicle's TLS port are also checked with OpenSSL (an implementation other than zenoh's rustls).

use shore_link::security::{KeyFiles, Security};
use shore_link::{Side, zenoh_settings};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;
use zenoh::Wait;

/// How long a refused shore keeps trying before its session gives up. A handshake on loopback
/// takes milliseconds: this bounds how long a refusal takes to show, not whether it shows.
const CONNECT_FOR: Duration = Duration::from_secs(3);

/// `shore-link keys DIR --vehicle-name NAME...`.
fn keys(dir: &Path, names: &[&str]) {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_shore-link"));
    cmd.arg("keys").arg(dir);
    for n in names {
        cmd.args(["--vehicle-name", n]);
    }
    let out = cmd.output().unwrap();
    assert!(out.status.success(), "{out:?}");
}

fn tls(dir: &Path, side: &str) -> Security {
    Security::Tls(KeyFiles::in_dir(&dir.join(side)))
}

fn config(side: Side, endpoint: &str, security: &Security) -> zenoh::Config {
    let mut z = zenoh::Config::default();
    for (k, v) in zenoh_settings(side, endpoint, security) {
        z.insert_json5(k, &v).unwrap();
    }
    z
}

/// The vehicle's end, listening on a free loopback port; returns it and its endpoint.
fn vehicle(security: &Security) -> (zenoh::Session, String) {
    let scheme = security.scheme();
    let z = config(Side::Vehicle, &format!("{scheme}/127.0.0.1:0"), security);
    let session = zenoh::open(z).wait().expect("the vehicle listens");
    let locator = session
        .info()
        .locators()
        .wait()
        .into_iter()
        .map(|l| l.to_string())
        .find(|l| l.starts_with(&format!("{scheme}/127.0.0.1:")))
        .expect("a loopback locator");
    (session, locator)
}

/// A shore end connecting to `endpoint` with `security` plus `extra` settings; fails when no
/// session with the vehicle can be established within [`CONNECT_FOR`].
fn shore(
    endpoint: &str,
    security: &Security,
    extra: &[(&str, &str)],
) -> zenoh::Result<zenoh::Session> {
    let mut z = config(Side::Shore, endpoint, security);
    z.insert_json5("connect/timeout_ms", &CONNECT_FOR.as_millis().to_string())
        .unwrap();
    z.insert_json5("connect/exit_on_failure", "true").unwrap();
    for (k, v) in extra {
        z.insert_json5(k, v).unwrap();
    }
    zenoh::open(z).wait()
}

fn two_key_sets() -> (tempfile::TempDir, PathBuf, PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let (ours, other) = (dir.path().join("ours"), dir.path().join("other"));
    keys(&ours, &["127.0.0.1"]);
    keys(&other, &["127.0.0.1"]);
    (dir, ours, other)
}

#[test]
fn the_real_shore_joins_and_a_sample_crosses() {
    let (_d, ours, _) = two_key_sets();
    let (v, endpoint) = vehicle(&tls(&ours, "vehicle"));
    assert!(endpoint.starts_with("tls/"), "{endpoint}");
    let s = shore(&endpoint, &tls(&ours, "shore"), &[]).expect("the real shore is admitted");
    assert_eq!(
        v.info().peers_zid().wait().collect::<Vec<_>>(),
        vec![s.zid()]
    );
    let sub = v.declare_subscriber("cabletrack/test").wait().unwrap();
    // The subscription reaches the shore over the link before a put is routed to it.
    let deadline = std::time::Instant::now() + Duration::from_secs(10);
    loop {
        s.put("cabletrack/test", "stop").wait().unwrap();
        if let Ok(Some(sample)) = sub.recv_timeout(Duration::from_millis(100)) {
            assert_eq!(sample.payload().try_to_string().unwrap(), "stop");
            break;
        }
        assert!(std::time::Instant::now() < deadline, "no sample crossed");
    }
}

#[test]
fn the_vehicle_refuses_a_shore_of_another_ca() {
    let (_d, ours, other) = two_key_sets();
    let (v, endpoint) = vehicle(&tls(&ours, "vehicle"));
    // The rogue trusts our CA (it has the public certificate) but its own pair is another CA's.
    let mut rogue = KeyFiles::in_dir(&other.join("shore"));
    rogue.ca = ours.join("vehicle/ca.pem");
    assert!(shore(&endpoint, &Security::Tls(rogue), &[]).is_err());
    assert_eq!(v.info().peers_zid().wait().count(), 0);
}

#[test]
fn the_vehicle_refuses_a_shore_without_a_certificate() {
    let (_d, ours, _) = two_key_sets();
    let (v, endpoint) = vehicle(&tls(&ours, "vehicle"));
    // TLS that checks the vehicle but presents nothing itself.
    let no_cert = [("transport/link/tls/enable_mtls", "false")];
    assert!(shore(&endpoint, &tls(&ours, "shore"), &no_cert).is_err());
    // Plain TCP on the TLS port.
    let plain = endpoint.replacen("tls/", "tcp/", 1);
    assert!(shore(&plain, &Security::Insecure, &[]).is_err());
    assert_eq!(v.info().peers_zid().wait().count(), 0);
}

#[test]
fn the_vehicles_own_pair_cannot_act_as_a_shore() {
    let (_d, ours, _) = two_key_sets();
    let (v, endpoint) = vehicle(&tls(&ours, "vehicle"));
    // Signed by the right CA, but a server's certificate: a copy of the vehicle's key is no shore.
    assert!(shore(&endpoint, &tls(&ours, "vehicle"), &[]).is_err());
    assert_eq!(v.info().peers_zid().wait().count(), 0);
}

#[test]
fn the_shore_refuses_a_vehicle_of_another_ca() {
    let (_d, ours, other) = two_key_sets();
    // A rogue vehicle that trusts our CA, so it would admit our shore; its own pair is another CA's.
    let mut rogue = KeyFiles::in_dir(&other.join("vehicle"));
    rogue.ca = ours.join("vehicle/ca.pem");
    let (v, endpoint) = vehicle(&Security::Tls(rogue));
    assert!(shore(&endpoint, &tls(&ours, "shore"), &[]).is_err());
    assert_eq!(v.info().peers_zid().wait().count(), 0);
}

#[test]
fn the_shore_refuses_a_vehicle_certified_for_another_name() {
    let dir = tempfile::tempdir().unwrap();
    keys(dir.path(), &["vehicle.cabletrack.internal"]);
    let (_v, endpoint) = vehicle(&tls(dir.path(), "vehicle"));
    // Dialled by its address, which its certificate does not name.
    assert!(shore(&endpoint, &tls(dir.path(), "shore"), &[]).is_err());
}

/// `openssl` with `args`, its output.
fn openssl(args: &[&str], input: &str) -> (bool, String) {
    let mut child = Command::new("openssl")
        .args(args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("openssl runs");
    use std::io::Write;
    child
        .stdin
        .take()
        .unwrap()
        .write_all(input.as_bytes())
        .unwrap();
    let (done, waited) = std::sync::mpsc::channel();
    let pid = child.id();
    std::thread::spawn(move || {
        let _ = done.send(child.wait_with_output());
    });
    let out = match waited.recv_timeout(Duration::from_secs(20)) {
        Ok(out) => out.unwrap(),
        Err(_) => {
            // SAFETY: kill(2) on the child this test started.
            unsafe { libc::kill(pid as libc::pid_t, libc::SIGKILL) };
            panic!("openssl {args:?} did not finish");
        }
    };
    let text =
        String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr);
    (out.status.success(), text)
}

#[test]
fn openssl_agrees_on_the_certificates_roles_and_names() {
    let (_d, ours, other) = two_key_sets();
    let p = |d: &Path, f: &str| d.join(f).to_string_lossy().into_owned();
    let ca = p(&ours, "vehicle/ca.pem");
    let verify = |purpose: &str, cert: &str, extra: &[&str]| {
        let mut args = vec!["verify", "-CAfile", &ca, "-purpose", purpose];
        args.extend_from_slice(extra);
        args.push(cert);
        openssl(&args, "").0
    };
    let (vehicle, shore_cert) = (p(&ours, "vehicle/cert.pem"), p(&ours, "shore/cert.pem"));
    assert!(verify("sslserver", &vehicle, &["-verify_ip", "127.0.0.1"]));
    assert!(!verify("sslserver", &vehicle, &["-verify_ip", "10.9.9.9"]));
    assert!(!verify("sslclient", &vehicle, &[]));
    assert!(verify("sslclient", &shore_cert, &[]));
    assert!(!verify("sslserver", &shore_cert, &[]));
    assert!(!verify("sslclient", &p(&other, "shore/cert.pem"), &[]));
    // The CA is a CA that signs end entities only.
    let (_, text) = openssl(&["x509", "-noout", "-text", "-in", &ca], "");
    assert!(text.contains("CA:TRUE, pathlen:0"), "{text}");
}

#[test]
fn openssl_meets_the_vehicles_port_with_tls_1_3_and_a_demand_for_a_certificate() {
    let (_d, ours, _) = two_key_sets();
    let (_v, endpoint) = vehicle(&tls(&ours, "vehicle"));
    let address = endpoint.trim_start_matches("tls/").to_owned();
    let p = |f: &str| ours.join(f).to_string_lossy().into_owned();
    let base = [
        "s_client",
        "-connect",
        &address,
        "-CAfile",
        &p("shore/ca.pem"),
        "-verify_return_error",
        "-verify_ip",
        "127.0.0.1",
    ];
    // With the shore's pair: the vehicle's certificate verifies (OpenSSL leaves when its input
    // ends).
    let (cert, key) = (p("shore/cert.pem"), p("shore/key.pem"));
    let mut with = base.to_vec();
    with.extend(["-cert", cert.as_str(), "-key", key.as_str()]);
    let (_, text) = openssl(&with, "");
    assert!(text.contains("Verify return code: 0 (ok)"), "{text}");
    assert!(text.contains("TLSv1.3"), "{text}");
    assert!(!text.contains("certificate required"), "{text}");
    // Without one: the vehicle answers with TLS 1.3's "certificate required" alert and closes
    // (OpenSSL stays until then).
    let mut without = base.to_vec();
    without.push("-ign_eof");
    let (_, text) = openssl(&without, "x\n");
    assert!(text.contains("certificate required"), "{text}");
}
