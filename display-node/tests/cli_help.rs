//! `--help` explains the display's options. (Also makes `cargo test` build the binary that the
//! end-to-end tests in `tests/` start.)

use std::process::Command;

#[test]
fn help_names_display_window_and_master() {
    let out = Command::new(env!("CARGO_BIN_EXE_tessera-display-node"))
        .arg("--help")
        .output()
        .unwrap();
    let text = String::from_utf8(out.stdout).unwrap();
    for flag in [
        "--master",
        "--display",
        "--cert-dir",
        "--window",
        "--listen",
        "--out",
    ] {
        assert!(text.contains(flag), "{text}");
    }
}

#[test]
fn unreachable_master_is_an_error_not_a_hang() {
    let dir = std::env::temp_dir().join(format!("tessera-display-cli-{}", std::process::id()));
    let ca = tessera_net::cluster::ClusterCa::open_or_create(&dir.join("ca")).unwrap();
    ca.issue("d", &dir.join("d"), None).unwrap();
    let start = std::time::Instant::now();
    let out = Command::new(env!("CARGO_BIN_EXE_tessera-display-node"))
        .args([
            "--master",
            "127.0.0.1:9",
            "--display",
            "0",
            "--cert-dir",
            dir.join("d").to_str().unwrap(),
        ])
        .output()
        .unwrap();
    let _ = std::fs::remove_dir_all(&dir);
    assert!(!out.status.success());
    assert!(start.elapsed() < std::time::Duration::from_secs(30));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("master"), "{err}");
}
