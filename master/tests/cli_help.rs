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

fn help(args: &[&str]) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_tessera-master"))
        .args(args)
        .output()
        .unwrap();
    assert!(out.status.success(), "{args:?}: {out:?}");
    String::from_utf8(out.stdout).unwrap()
}

/// The text of `flag`'s entry in a long `--help`: from its line to the next flag's.
fn entry<'a>(help: &'a str, flag: &str) -> &'a str {
    let starts_flag = |line: &str| {
        let t = line.trim_start();
        t.starts_with("--") || (t.len() > 1 && t.starts_with('-') && t.as_bytes()[1] != b' ')
    };
    let mut lines = help.split_inclusive('\n');
    let mut start = 0;
    for line in lines.by_ref() {
        let t = line.trim_start();
        if starts_flag(line) && t.split([' ', ',', '\n']).any(|word| word == flag) {
            break;
        }
        start += line.len();
    }
    assert!(start < help.len(), "{flag} is not in:\n{help}");
    let mut end = start;
    for (i, line) in help[start..].split_inclusive('\n').enumerate() {
        if i > 0 && starts_flag(line) {
            break;
        }
        end += line.len();
    }
    &help[start..end]
}

/// The `[default: X]` that `--help` shows for `flag`.
fn default_of(help: &str, flag: &str) -> String {
    let entry = entry(help, flag);
    let shown = entry
        .split("[default: ")
        .nth(1)
        .and_then(|d| d.split(']').next());
    shown
        .unwrap_or_else(|| panic!("{flag} shows no default:\n{entry}"))
        .to_string()
}

#[test]
fn defaults_in_help_are_the_ones_the_code_uses() {
    use tessera_model::stereo::DEFAULT_EYE_SEPARATION;
    use tessera_model::wall::DEFAULT_TILE_SIZE;
    let tile = DEFAULT_TILE_SIZE.to_string();
    for command in ["local", "serve", "render", "simulate"] {
        let text = help(&[command, "--help"]);
        assert_eq!(default_of(&text, "--tile-size"), tile, "{command}");
    }
    let local = help(&["local", "--help"]);
    assert_eq!(
        default_of(&local, "--eye-separation"),
        DEFAULT_EYE_SEPARATION.to_string()
    );
    let fov = tessera_model::camera::DEFAULT_FOV_DEG;
    assert_eq!(default_of(&local, "--fov").parse::<f32>(), Ok(fov));
    let deadline = tessera_core::balance::DEFAULT_NODE_DEADLINE.as_millis();
    assert_eq!(
        default_of(&local, "--node-deadline-ms"),
        deadline.to_string()
    );
    let beat = tessera_protocol::HEARTBEAT_INTERVAL.as_millis();
    let said = entry(&local, "--node-deadline-ms");
    assert!(said.contains(&format!("beat every {beat} ms")), "{said}");
    let pause = tessera_core::balance::DEFAULT_ACCEPTABLE_PAUSE.as_millis();
    let said = entry(&local, "--acceptable-pause-ms");
    assert!(
        said.contains(&format!("default {pause} for a served wall")),
        "{said}"
    );
    let loss = format!("{:?}", tessera_core::master::DisplayLoss::default());
    assert_eq!(loss, "GoOn");
    assert_eq!(default_of(&local, "--display-loss"), "go-on");
    // `local` says what the render node's own default is.
    let node = help(&["render-node", "--help"]);
    let cache = default_of(&node, "--volume-cache-mb");
    let said = entry(&local, "--volume-cache-mb");
    assert!(
        said.contains(&format!("render node's own, {cache})")),
        "{said}"
    );
}

#[test]
fn bench_names_every_experiment_in_its_summary() {
    // The summary named 4 of the experiments after a fifth, sixth and seventh were added.
    let short = help(&["bench", "-h"]);
    let values = short
        .split("[possible values: ")
        .nth(1)
        .and_then(|v| v.split(']').next())
        .unwrap_or_else(|| panic!("no experiments listed:\n{short}"));
    let experiments: Vec<&str> = values.split(", ").collect();
    assert!(experiments.len() >= 7, "{experiments:?}");
    let summary = short.lines().next().unwrap();
    let top = help(&["--help"]);
    let listed = top
        .lines()
        .find(|l| l.trim_start().starts_with("bench "))
        .unwrap();
    for name in experiments {
        for text in [summary, listed] {
            let named = text.split([' ', ',', ':', ';']).any(|word| word == name);
            assert!(named, "`{name}` is missing from: {text}");
        }
    }
}

#[test]
fn tile_size_is_one_flag_on_local_and_simulate_and_tile_still_works() {
    for command in ["local", "simulate"] {
        let text = help(&[command, "--help"]);
        assert!(
            text.contains("--tile-size <TILE_SIZE>"),
            "{command}:\n{text}"
        );
    }
    let out = Command::new(env!("CARGO_BIN_EXE_tessera-master"))
        .args(["simulate", "--displays", "4", "--screen", "128x128"])
        .args(["--render-nodes", "2", "--frames", "2", "--tile", "32"])
        .output()
        .unwrap();
    assert!(out.status.success(), "{out:?}");
}
