//! The architecture as Cargo enforces it (see common/README.md): what each crate's dependency
//! tree may and may not hold, read from `cargo tree`, so that a dependency added in the wrong
//! layer fails here rather than in a review.

use std::path::Path;
use std::process::Command;

/// The crates in `package`'s normal (non-dev, non-build) dependency tree, names only.
fn dependency_tree(package: &str) -> Vec<String> {
    let workspace = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/.."));
    let out = Command::new(env!("CARGO"))
        .args([
            "tree", "-p", package, "-e", "normal", "--prefix", "none", "--format", "{p}",
        ])
        .current_dir(workspace)
        .output()
        .expect("cargo tree");
    assert!(
        out.status.success(),
        "cargo tree -p {package} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let mut crates: Vec<String> = String::from_utf8_lossy(&out.stdout)
        .lines()
        .filter_map(|l| l.split_whitespace().next())
        .map(str::to_string)
        .collect();
    crates.sort();
    crates.dedup();
    assert!(crates.iter().any(|c| c == package), "{crates:?}");
    crates
}

fn assert_none_of(package: &str, forbidden: &[&str]) {
    let tree = dependency_tree(package);
    let found: Vec<&String> = tree
        .iter()
        .filter(|c| forbidden.contains(&c.as_str()))
        .collect();
    assert!(
        found.is_empty(),
        "{package} must not depend on {found:?} (its tree: {tree:?})"
    );
}

/// I/O and command-line crates that the sans-IO layers must never see.
const IO: &[&str] = &[
    "tokio",
    "quinn",
    "quinn-proto",
    "quinn-udp",
    "socket2",
    "mio",
    "rustls",
    "clap",
];

#[test]
fn the_sans_io_core_has_no_runtime_socket_or_cli_in_its_tree() {
    assert_none_of("tessera-core", IO);
    // Nor the renderer: the simulator runs hundreds of nodes without tracing a ray.
    assert_none_of("tessera-core", &["tessera-render", "obvhs", "rayon"]);
}

#[test]
fn the_model_and_the_protocol_are_usable_by_every_layer() {
    for crate_name in ["tessera-model", "tessera-protocol"] {
        assert_none_of(crate_name, IO);
        assert_none_of(crate_name, &["tessera-render", "obvhs", "rayon"]);
    }
    // The model does no file I/O of its own: images and wall files are read and written at
    // the edge (tessera-cli).
    assert_none_of("tessera-model", &["image", "png", "tessera-protocol"]);
}

#[test]
fn the_renderer_does_no_io() {
    assert_none_of("tessera-render", IO);
}

#[test]
fn the_display_node_does_not_compile_the_renderer() {
    assert_none_of(
        "tessera-display-node",
        &[
            "tessera-render",
            "obvhs",
            "tobj",
            "gltf",
            "ply-rs-bw",
            "rayon",
        ],
    );
}

#[test]
fn the_check_sees_what_is_there() {
    // The test above must be able to fail: the render node does pull in what the display may
    // not, and the core's tree holds the model and the protocol.
    let render = dependency_tree("tessera-render-node");
    for expected in ["tessera-render", "obvhs", "tokio", "quinn"] {
        assert!(
            render.iter().any(|c| c == expected),
            "{expected} in {render:?}"
        );
    }
    let core = dependency_tree("tessera-core");
    for expected in ["tessera-model", "tessera-protocol"] {
        assert!(core.iter().any(|c| c == expected), "{expected} in {core:?}");
    }
}
