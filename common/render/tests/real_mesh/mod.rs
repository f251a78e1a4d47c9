//! The real mesh the numerical tests use, from Debian's assimp-testmodels, which `.ci/run`
//! installs: under CI its absence fails the test, elsewhere the test is skipped, saying why.

use std::path::Path;

pub const REAL_MESH: &str = "/usr/share/assimp/models/OBJ/WusonOBJ.obj";

/// The mesh's path, or `None` (after saying so) where it is not installed and not under CI.
pub fn real_mesh() -> Option<&'static Path> {
    let path = Path::new(REAL_MESH);
    if path.exists() {
        return Some(path);
    }
    assert!(
        std::env::var_os("CI").is_none(),
        "{REAL_MESH} is missing: .ci/run installs assimp-testmodels"
    );
    eprintln!("skipping: {REAL_MESH} not installed (apt-get install assimp-testmodels)");
    None
}
