//! `--help` explains every subcommand. (Also makes `cargo test` build the binary that the
//! end-to-end tests in `tests/` start.)

use std::process::Command;

#[test]
fn help_lists_subcommands_and_wall_flags() {
    let bin = env!("CARGO_BIN_EXE_tessera-master");
    let out = Command::new(bin).arg("--help").output().unwrap();
    let text = String::from_utf8(out.stdout).unwrap();
    for word in [
        "local",
        "serve",
        "render",
        "issue-cert",
        "render-node",
        "display-node",
    ] {
        assert!(text.contains(word), "{text}");
    }
    let out = Command::new(bin)
        .args(["local", "--help"])
        .output()
        .unwrap();
    let text = String::from_utf8(out.stdout).unwrap();
    for flag in [
        "--wall",
        "--screen",
        "--bezel",
        "--wall-file",
        "--render-nodes",
        "--frames",
        "--scene",
        "--eye",
        "--target",
        "--up",
        "--fov",
        "--out",
        "--save-frame",
        "--window",
    ] {
        assert!(text.contains(flag), "local --help lacks {flag}:\n{text}");
    }
}

#[test]
fn unknown_flags_are_refused() {
    let out = Command::new(env!("CARGO_BIN_EXE_tessera-master"))
        .args(["local", "--wal", "2x2"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--wal"));
}
