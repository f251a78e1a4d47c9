//! Wall files read from disk (see `deploy/walls/*.toml` for examples); the text itself is
//! parsed and checked by `tessera_model::window::WallFile::from_toml`.

use std::path::Path;
use tessera_model::wall::{WallError, WallLayout};
use tessera_model::window::WallFile;

/// Reads the wall file at `path`: the wall and where its displays put their windows.
///
/// # Errors
/// The file cannot be read, or its text is not a valid wall (the error names the file).
pub fn read(path: &Path) -> Result<WallFile, WallError> {
    let text = std::fs::read_to_string(path).map_err(|e| WallError::File {
        path: path.display().to_string(),
        message: e.to_string(),
    })?;
    WallFile::from_toml(&text, &path.display().to_string())
}

/// Reads the wall of the wall file at `path`, its windows checked but not kept.
///
/// # Errors
/// As [`read`].
pub fn read_layout(path: &Path) -> Result<WallLayout, WallError> {
    read(path).map(|f| f.layout)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_missing_wall_file_is_named_once() {
        let error = read_layout(Path::new("/nonexistent/wall.toml")).unwrap_err();
        let text = error.to_string();
        assert!(text.contains("/nonexistent/wall.toml"), "{text}");
    }
}
