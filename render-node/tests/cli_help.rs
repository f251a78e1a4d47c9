//! `--help` explains how to join a master. (Also makes `cargo test` build the binary that the
//! end-to-end tests in `tests/` start.)

use std::process::Command;

#[test]
fn help_names_master_and_certificates() {
    let out = Command::new(env!("CARGO_BIN_EXE_tessera-render-node"))
        .arg("--help")
        .output()
        .unwrap();
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(
        text.contains("--master") && text.contains("--cert-dir") && text.contains("--threads"),
        "{text}"
    );
}

#[test]
fn missing_certificates_are_explained() {
    let out = Command::new(env!("CARGO_BIN_EXE_tessera-render-node"))
        .args([
            "--master",
            "127.0.0.1:9",
            "--cert-dir",
            "/nonexistent/certs",
        ])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("/nonexistent/certs") && err.contains("issue-cert"),
        "{err}"
    );
}
