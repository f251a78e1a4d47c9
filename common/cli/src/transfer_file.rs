//! `--transfer NAME|FILE.toml`: a preset, or a transfer function written as a TOML list of
//! points. The master reads the file; render nodes get the points in the frame's parameters.
//!
//! ```toml
//! domain = "data"          # or "normalized" (0..1 over the volume's range), the default
//! [[point]]
//! value = 150.0
//! color = [0.6, 0.3, 0.2]  # linear RGB
//! opacity = 0.0            # per step of the smallest voxel spacing
//! [[point]]
//! value = 600.0
//! color = [1.0, 0.95, 0.85]
//! opacity = 0.8
//! ```

use serde::Deserialize;
use std::path::Path;
use tessera_model::volume_params::{
    TransferDomain, TransferFunction, TransferPoint, VolumeParamsError,
};

/// Why `--transfer` was refused.
#[derive(Debug, thiserror::Error)]
pub enum TransferFileError {
    /// The argument is no preset's name and does not end in `.toml`; it holds the argument.
    #[error("`{0}` is neither a preset (ramp, ct-bone, ct-skin) nor a .toml file")]
    Unknown(String),
    /// The file could not be read.
    // `reason`, not `source` (here and below): an error chain would print a source again.
    #[error("{path}: {reason}")]
    Io {
        /// The file, as given to `--transfer`.
        path: String,
        /// Why reading it failed.
        reason: std::io::Error,
    },
    /// The file is not TOML of the expected shape.
    #[error("{path}: {message}")]
    Parse {
        /// The file, as given to `--transfer`.
        path: String,
        /// The TOML parser's message, with the line at fault.
        message: String,
    },
    /// The points do not make a transfer function (too few or too many, or a bad one).
    #[error("{path}: {reason}")]
    Invalid {
        /// The file, as given to `--transfer`.
        path: String,
        /// What is wrong with the points (a bad one by its index).
        reason: VolumeParamsError,
    },
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct TransferToml {
    #[serde(default)]
    domain: DomainToml,
    point: Vec<TransferPoint>,
}

#[derive(Deserialize, Default)]
#[serde(rename_all = "lowercase")]
enum DomainToml {
    #[default]
    Normalized,
    Data,
}

/// The transfer function `arg` names: a preset, or a `.toml` file.
///
/// # Errors
/// An unknown name, an unreadable file, bad TOML (with its line), or bad points (by index).
pub fn transfer_function(arg: &str) -> Result<TransferFunction, TransferFileError> {
    if let Some(tf) = TransferFunction::preset_named(arg) {
        return Ok(tf);
    }
    if !arg.to_ascii_lowercase().ends_with(".toml") {
        return Err(TransferFileError::Unknown(arg.to_string()));
    }
    let path = Path::new(arg);
    let text = std::fs::read_to_string(path).map_err(|reason| TransferFileError::Io {
        path: arg.to_string(),
        reason,
    })?;
    parse(&text, arg)
}

fn parse(text: &str, path: &str) -> Result<TransferFunction, TransferFileError> {
    let file: TransferToml = toml::from_str(text).map_err(|e| TransferFileError::Parse {
        path: path.to_string(),
        message: e.to_string(),
    })?;
    let domain = match file.domain {
        DomainToml::Normalized => TransferDomain::Normalized,
        DomainToml::Data => TransferDomain::Data,
    };
    TransferFunction::new(domain, &file.point).map_err(|reason| TransferFileError::Invalid {
        path: path.to_string(),
        reason,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_file_of_points_parses_and_bad_points_are_named() {
        let text = "domain = \"data\"\n[[point]]\nvalue = 0.0\ncolor = [1.0, 0.0, 0.0]\nopacity = 0.0\n[[point]]\nvalue = 10.0\ncolor = [1.0, 1.0, 1.0]\nopacity = 1.0\n";
        let tf = parse(text, "t.toml").unwrap();
        assert_eq!(tf.domain(), TransferDomain::Data);
        assert_eq!(tf.eval(5.0).1, 0.5);
        let bad = text.replace("opacity = 1.0", "opacity = 2.0");
        let err = parse(&bad, "t.toml").unwrap_err().to_string();
        assert!(
            err.contains("point 1") && err.contains("opacity 2"),
            "{err}"
        );
        let err = parse("point = 3", "t.toml").unwrap_err().to_string();
        assert!(err.contains("t.toml"), "{err}");
        assert!(matches!(
            transfer_function("nope"),
            Err(TransferFileError::Unknown(_))
        ));
        assert!(transfer_function("ct-bone").is_ok());
    }

    /// Every refusal as the master prints it, `--transfer: ` and the error's causes: the
    /// invalid points' reason used to be a `source` too, and came out twice.
    #[test]
    fn a_refused_transfer_function_says_its_reason_once() {
        let dir = std::env::temp_dir().join(format!("tessera-tf-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let point = "[[point]]\nvalue = 0.0\ncolor = [1.0, 0.0, 0.0]\nopacity = 0.0\n";
        let files = [
            (
                "points.toml",
                format!("{point}{}", point.replace("0.0\n", "2.0\n")),
            ),
            ("syntax.toml", "point = [".to_string()),
            ("shape.toml", "point = 3\n".to_string()),
        ];
        let mut args = vec![
            "nosuch".to_string(),
            dir.join("absent.toml").display().to_string(),
        ];
        for (name, text) in &files {
            std::fs::write(dir.join(name), text).unwrap();
            args.push(dir.join(name).display().to_string());
        }
        for arg in &args {
            let err = crate::ArgError::from(transfer_function(arg).unwrap_err());
            let mut chain = vec![err.to_string()];
            let mut cause = std::error::Error::source(&err);
            while let Some(c) = cause {
                chain.push(c.to_string());
                cause = c.source();
            }
            for pair in chain.windows(2) {
                assert!(!pair[0].contains(&pair[1]), "{arg}: said twice: {chain:?}");
            }
            let last = chain.last().unwrap();
            assert!(last.contains(arg.as_str()), "{arg}: {chain:?}");
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
