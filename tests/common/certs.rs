//! Certificates for the TLS tests, made by the `openssl` command (Debian package openssl).

use std::path::Path;
use std::process::Command;

/// Runs `openssl ARGS` in `dir`; panics with its stderr on failure.
pub fn openssl(dir: &Path, args: &[&str]) {
    let out = Command::new("openssl")
        .args(args)
        .current_dir(dir)
        .output()
        .expect("the `openssl` command is needed for this test (Debian package openssl)");
    assert!(
        out.status.success(),
        "openssl {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// `openssl req` options for a new P-256 key without a passphrase.
const NEW_EC_KEY: [&str; 5] = [
    "-newkey",
    "ec",
    "-pkeyopt",
    "ec_paramgen_curve:prime256v1",
    "-nodes",
];

/// A self-signed CA `name`.pem / `name`.key in `dir`.
pub fn make_ca(dir: &Path, name: &str) {
    let (key, pem, subject) = (
        format!("{name}.key"),
        format!("{name}.pem"),
        format!("/CN={name}"),
    );
    let out = ["-keyout", &key, "-out", &pem, "-days", "2", "-subj", &subject];
    openssl(dir, &[&["req", "-x509"][..], &NEW_EC_KEY, &out].concat());
}

/// A certificate `name`.pem / `name`.key signed by CA `ca`, with the extensions in `ext`.
pub fn make_leaf(dir: &Path, ca: &str, name: &str, ext: &str) {
    let (key, pem, csr, extfile, subject) = (
        format!("{name}.key"),
        format!("{name}.pem"),
        format!("{name}.csr"),
        format!("{name}.ext"),
        format!("/CN={name}"),
    );
    std::fs::write(dir.join(&extfile), ext).unwrap();
    let request = ["-keyout", &key, "-out", &csr, "-subj", &subject];
    openssl(dir, &[&["req"][..], &NEW_EC_KEY, &request].concat());
    let (ca_pem, ca_key) = (format!("{ca}.pem"), format!("{ca}.key"));
    openssl(
        dir,
        &[
            "x509",
            "-req",
            "-in",
            &csr,
            "-CA",
            &ca_pem,
            "-CAkey",
            &ca_key,
            "-CAcreateserial",
            "-out",
            &pem,
            "-days",
            "2",
            "-extfile",
            &extfile,
        ],
    );
}
