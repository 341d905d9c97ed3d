//! TLS between actors and a real `adp learner` (issue 16, item 7): the learner serves with
//! `[service.tls]` and verifies client certificates (mutual TLS); an actor with the right CA
//! and a client certificate registers; one that trusts another CA, one without a client
//! certificate and one speaking plain HTTP/2 are all turned away, and the learner keeps
//! serving. The certificates are made for the test by the `openssl` command.

use std::path::PathBuf;
use std::process::{Child, Stdio};
use std::time::Duration;

use learner_service::read_addr;
use proto::auth::TlsFiles;
use proto::grpc::LearnerAddress;
use proto::pb;

mod common;
use common::certs::{make_ca, make_leaf};
use common::{adp, fresh_dir};

/// Polls of a watchdog that should never fire (about five minutes at 100 ms).
const PATIENCE: u32 = 3000;

/// Kills the learner when the test ends, passing or not.
struct Guard(Child);

impl Drop for Guard {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Registers rank 0 at `addr` with `tls`; the error text when the learner cannot be reached
/// or refuses.
async fn register(addr: &str, token: &str, tls: Option<TlsFiles>) -> Result<pb::RegisterReply, String> {
    let address = LearnerAddress {
        addr: addr.to_owned(),
        token: Some(token.to_owned()),
        tls,
    };
    let (mut control, _) = address.connect().await.map_err(|e| format!("connect: {e}"))?;
    control
        .register(pb::RegisterRequest {
            rank: 0,
            host: "test".into(),
            pid: 1,
            ..Default::default()
        })
        .await
        .map(tonic::Response::into_inner)
        .map_err(|s| format!("register: {s}"))
}

#[test]
fn mutual_tls_admits_the_right_certificates_only() {
    let dir = fresh_dir("tls");
    let certs = dir.join("certs");
    std::fs::create_dir_all(&certs).unwrap();
    make_ca(&certs, "ca");
    make_ca(&certs, "other-ca");
    make_leaf(
        &certs,
        "ca",
        "learner",
        "subjectAltName=DNS:localhost,IP:127.0.0.1\nextendedKeyUsage=serverAuth\n",
    );
    make_leaf(&certs, "ca", "actor", "extendedKeyUsage=clientAuth\n");
    make_leaf(&certs, "other-ca", "intruder", "extendedKeyUsage=clientAuth\n");
    let file = |name: &str| -> PathBuf { certs.join(name) };

    let cfg = dir.join("tls.toml");
    std::fs::write(
        &cfg,
        format!(
            "[td3]\nwarmup_steps = 128\nactor_hidden = [64, 64]\ncritic_hidden = [64, 64]\n\n\
             [service]\nshared_memory = false\n\n[service.tls]\ncert = {:?}\nkey = {:?}\nca = {:?}\n",
            file("learner.pem"),
            file("learner.key"),
            file("ca.pem")
        ),
    )
    .unwrap();
    let run = dir.join("run");
    let log = std::fs::File::create(dir.join("learner.log")).unwrap();
    let learner = Guard(
        adp()
            .args(["learner", "--config"])
            .arg(&cfg)
            .args(["--steps", "100000", "--listen", "127.0.0.1:0", "--out"])
            .arg(&run)
            .stdout(Stdio::null())
            .stderr(log)
            .spawn()
            .unwrap(),
    );
    let mut addr = None;
    for _ in 0..PATIENCE {
        if let Ok(a) = read_addr(&run) {
            addr = Some(a);
            break;
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    let addr = addr.unwrap_or_else(|| {
        panic!(
            "watchdog: no learner.addr; learner stderr:\n{}",
            std::fs::read_to_string(dir.join("learner.log")).unwrap_or_default()
        )
    });
    let port = addr.rsplit(':').next().unwrap();
    let addr = format!("localhost:{port}");
    let token = proto::auth::read_token_file(&run.join("token")).unwrap();
    let tls = |ca: &str, client: Option<&str>| TlsFiles {
        ca: Some(file(&format!("{ca}.pem"))),
        cert: client.map(|c| file(&format!("{c}.pem"))),
        key: client.map(|c| file(&format!("{c}.key"))),
        domain: Some("localhost".into()),
    };

    let rt = tokio::runtime::Runtime::new().unwrap();
    rt.block_on(async {
        let ok = register(&addr, &token, Some(tls("ca", Some("actor")))).await;
        assert!(ok.is_ok(), "the right CA and client certificate: {ok:?}");
        let wrong_ca = register(&addr, &token, Some(tls("other-ca", Some("actor")))).await;
        assert!(wrong_ca.is_err(), "trusting another CA must fail: {wrong_ca:?}");
        let no_client_cert = register(&addr, &token, Some(tls("ca", None))).await;
        assert!(
            no_client_cert.is_err(),
            "the learner verifies clients: {no_client_cert:?}"
        );
        let intruder = register(&addr, &token, Some(tls("ca", Some("intruder")))).await;
        assert!(
            intruder.is_err(),
            "a client certificate from another CA: {intruder:?}"
        );
        let plain = register(&addr, &token, None).await;
        assert!(plain.is_err(), "plain HTTP/2 to a TLS learner: {plain:?}");
        // Still serving after every refusal.
        let again = register(&addr, &token, Some(tls("ca", Some("actor")))).await;
        assert!(again.is_ok(), "after the refusals: {again:?}");
    });
    drop(learner);
}
