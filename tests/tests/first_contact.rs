//! What a newcomer does first: the README's first command, on a clone where nothing else has
//! been built. `cargo run --release -p tessera-master` builds the master's binary and nothing
//! else, so the demo wall must run from that one executable: here it is copied alone into an
//! empty folder and given the README's arguments, and the README's command is checked to be
//! the one that builds that binary. (Before the master ran the node roles itself, this failed
//! with "cannot find tessera-display-node next to ...".)

use std::path::Path;
use std::time::Duration;
use tessera_tests::*;

fn workspace() -> &'static Path {
    Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/.."))
}

/// The README's first command, split into words: the first indented line that runs cargo.
fn readme_demo_command() -> Vec<String> {
    let readme = std::fs::read_to_string(workspace().join("README.md")).expect("README.md");
    let line = readme
        .lines()
        .find(|l| l.starts_with("    cargo run"))
        .expect("the README shows a `cargo run` command, indented as a code block");
    line.split_whitespace().map(str::to_string).collect()
}

#[test]
fn readme_demo_command_builds_the_master_binary_alone() {
    let words = readme_demo_command();
    let dashes = words
        .iter()
        .position(|w| w == "--")
        .expect("arguments after --");
    assert_eq!(
        words[..dashes],
        ["cargo", "run", "--release", "-p", "tessera-master"],
        "the README's first command must build (only) the master package"
    );
    // `cargo run -p P` runs P's only binary: the master package must have exactly one, and it
    // must be the tessera-master that the next test runs.
    let metadata = std::process::Command::new(env!("CARGO"))
        .args(["metadata", "--format-version", "1", "--no-deps"])
        .current_dir(workspace())
        .output()
        .expect("cargo metadata");
    assert!(metadata.status.success(), "{metadata:?}");
    let metadata: serde_json::Value = serde_json::from_slice(&metadata.stdout).unwrap();
    let master = metadata["packages"]
        .as_array()
        .unwrap()
        .iter()
        .find(|p| p["name"] == "tessera-master")
        .expect("a tessera-master package");
    let bins: Vec<&str> = master["targets"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|t| t["kind"].as_array().unwrap().iter().any(|k| k == "bin"))
        .map(|t| t["name"].as_str().unwrap())
        .collect();
    assert_eq!(bins, ["tessera-master"]);
}

#[test]
fn the_master_binary_alone_runs_the_readme_demo_wall() {
    let words = readme_demo_command();
    let dashes = words.iter().position(|w| w == "--").unwrap();
    let args: Vec<&str> = words[dashes + 1..].iter().map(String::as_str).collect();
    let out_dir = args
        .iter()
        .position(|a| *a == "--out")
        .map(|i| args[i + 1])
        .expect("the demo writes --out DIR");

    // An empty folder holding one file: the master, as `cargo run` would have built it.
    let alone = tempfile::tempdir().unwrap();
    let master = alone.path().join("tessera-master");
    std::fs::copy(bin("tessera-master"), &master).unwrap();
    assert_eq!(std::fs::read_dir(alone.path()).unwrap().count(), 1);

    let o = Proc::start_in(&master, alone.path(), &args).wait(Duration::from_secs(300));
    o.assert_success("the README's demo wall from the master binary alone");
    let out = alone.path().join(out_dir);
    let report = read_json(&out.join("report.json"));
    let frames: u64 = args[args.iter().position(|a| *a == "--frames").unwrap() + 1]
        .parse()
        .unwrap();
    assert_eq!(report["frames"], frames);
    for d in report["displays"].as_array().unwrap() {
        assert_eq!(d["frames_presented"], frames, "{d}");
    }
    // The README says 2×2 screens of 480×270 with 16-pixel bezels.
    let (w, h, _) = load_rgb(&out.join("wall.png"));
    assert_eq!((w, h), (2 * 480 + 16, 2 * 270 + 16));
}
