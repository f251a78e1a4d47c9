//! How a run ended, as `report.json`'s `outcome` and the exit status say it: every run writes
//! its report, a failed one too (with the failure in it and whatever figures it had), and the
//! exit status tells a completed run (0, even if nodes were lost and recovered from on the
//! way: the report names them) from an interrupted one (130) and a failed one (1).

use crate::report::Report;
use crate::server::RunEnd;
use anyhow::{Context, Result};
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

/// Exit status of a run ended by Ctrl-C or SIGTERM: 128 + SIGINT, as shells report it.
pub const INTERRUPTED: u8 = 130;

/// Exit status of a run that did not complete, or whose report could not be written.
pub const FAILED: u8 = 1;

/// How a run ended: its figures (if the master ever ran) and whatever went wrong.
pub struct Ended {
    /// What the run measured; `None` if it ended before the master started.
    pub report: Option<Report>,
    /// Why the run did not complete; `None` if it did.
    pub error: Option<anyhow::Error>,
    /// Whether Ctrl-C or SIGTERM ended it.
    pub interrupted: bool,
    /// Node processes that exited with an error or had to be killed, as the launcher's log
    /// lines name them (empty for `serve`, whose nodes are not its children).
    pub processes_failed: Vec<String>,
}

impl Ended {
    /// How a run that [`crate::server::run_wall`] ran (or could not start) ended.
    pub fn of(end: Result<RunEnd>, interrupted: bool) -> Ended {
        match end {
            Ok(end) => Ended {
                report: Some(end.report),
                error: end.error,
                interrupted,
                processes_failed: Vec::new(),
            },
            Err(e) => Ended::before_start(e, interrupted),
        }
    }

    /// A run that ended with `error` before its master started.
    pub fn before_start(error: anyhow::Error, interrupted: bool) -> Ended {
        Ended {
            report: None,
            error: Some(error),
            interrupted,
            processes_failed: Vec::new(),
        }
    }

    /// The report of a run that completed.
    ///
    /// # Errors
    /// The run's error, or a run without figures.
    pub fn into_report(self) -> Result<Report> {
        if let Some(e) = self.error {
            return Err(e);
        }
        self.report.context("the run ended without figures")
    }

    /// What `report.json` says of the end.
    pub fn outcome(&self) -> Outcome {
        let exit_status = match (&self.error, self.interrupted) {
            (_, true) => INTERRUPTED,
            (Some(_), false) => FAILED,
            (None, false) => 0,
        };
        Outcome {
            completed: exit_status == 0,
            interrupted: self.interrupted,
            error: self.error.as_ref().map(|e| format!("{e:#}")),
            processes_failed: self.processes_failed.clone(),
            exit_status,
        }
    }
}

/// How the run ended, first in `report.json`.
#[derive(Serialize, Debug, Clone, PartialEq, Eq)]
pub struct Outcome {
    /// Whether the run did what it was asked: every frame presented. Nodes may have been lost
    /// and recovered from on the way (`nodes_lost` names them).
    pub completed: bool,
    /// Whether Ctrl-C or SIGTERM ended it (a run of `--frames 0` ends no other way).
    pub interrupted: bool,
    /// Why it did not complete, if it failed.
    pub error: Option<String>,
    /// Node processes that exited with an error or had to be killed (`local`, `launch`).
    pub processes_failed: Vec<String>,
    /// The master's exit status: 0 completed, 130 interrupted, 1 failed.
    pub exit_status: u8,
}

/// `report.json`: the outcome, then the figures at the top level as before.
#[derive(Serialize)]
struct ReportFile<'a> {
    outcome: &'a Outcome,
    #[serde(flatten)]
    figures: Option<&'a Report>,
}

/// The text of `report.json`.
pub fn report_json(outcome: &Outcome, report: Option<&Report>) -> Result<String> {
    let file = ReportFile {
        outcome,
        figures: report,
    };
    Ok(serde_json::to_string_pretty(&file)?)
}

/// Writes `dir/report.json`; if that fails (a full disk), prints the report on stderr instead,
/// so that the run's figures are never lost silently, and returns the error naming the path.
pub fn write_report(dir: &Path, outcome: &Outcome, report: Option<&Report>) -> Result<PathBuf> {
    let path = dir.join("report.json");
    let json = report_json(outcome, report)?;
    match std::fs::write(&path, &json) {
        Ok(()) => Ok(path),
        Err(e) => {
            eprintln!(
                "tessera-master: cannot write {}: {e}; the report follows here instead:\n{json}",
                path.display()
            );
            Err(e).with_context(|| format!("cannot write {}", path.display()))
        }
    }
}

/// The exit code of a run that ended as `outcome` says, once its report is written (or
/// `written` says why not): a report that could not be written fails the run.
///
/// # Errors
/// The run's error, or the report's; `main` prints it and exits with [`FAILED`].
pub fn exit_code(
    outcome: &Outcome,
    error: Option<anyhow::Error>,
    written: Result<()>,
) -> Result<ExitCode> {
    if let Some(error) = error {
        if outcome.interrupted {
            eprintln!("tessera-master: interrupted: {error:#}");
            written?;
            return Ok(ExitCode::from(INTERRUPTED));
        }
        if let Err(report) = written {
            eprintln!("tessera-master: error: {report:#}");
        }
        return Err(error);
    }
    written?;
    if outcome.interrupted {
        eprintln!("tessera-master: interrupted");
        return Ok(ExitCode::from(INTERRUPTED));
    }
    Ok(ExitCode::SUCCESS)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ended(error: Option<&str>, interrupted: bool) -> Ended {
        Ended {
            report: None,
            error: error.map(|e| anyhow::anyhow!("{e}")),
            interrupted,
            processes_failed: vec!["render node 2 (pid 7) exited with signal 9".into()],
        }
    }

    #[test]
    fn the_exit_status_says_whether_the_run_completed_not_whether_nodes_were_lost() {
        let completed = ended(None, false).outcome();
        assert!(completed.completed);
        assert_eq!(completed.exit_status, 0, "a node lost on the way");
        let failed = ended(Some("display 1 was not back"), false).outcome();
        assert!(!failed.completed);
        assert_eq!(failed.exit_status, FAILED);
        assert_eq!(failed.error.as_deref(), Some("display 1 was not back"));
        let interrupted = ended(None, true).outcome();
        assert_eq!(
            (interrupted.completed, interrupted.exit_status),
            (false, 130)
        );
    }

    #[test]
    fn a_failed_run_writes_its_outcome_first_in_the_report() {
        let dir = tempfile::tempdir().unwrap();
        let run = ended(Some("every render node or every display is gone"), false);
        let path = write_report(dir.path(), &run.outcome(), None).unwrap();
        let json: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
        assert_eq!(json["outcome"]["completed"], false);
        assert_eq!(json["outcome"]["exit_status"], 1);
        assert!(json["outcome"]["error"]
            .as_str()
            .unwrap()
            .contains("every render node"));
        assert_eq!(
            json["outcome"]["processes_failed"][0],
            "render node 2 (pid 7) exited with signal 9"
        );
    }

    #[test]
    fn a_report_that_cannot_be_written_fails_the_run_naming_its_path() {
        let dir = tempfile::tempdir().unwrap();
        // A directory where the file should go: the write fails as on a full disk.
        std::fs::create_dir(dir.path().join("report.json")).unwrap();
        let run = ended(None, false);
        let outcome = run.outcome();
        let written = write_report(dir.path(), &outcome, None).map(|_| ());
        let e = exit_code(&outcome, None, written).unwrap_err();
        assert!(format!("{e:#}").contains("report.json"), "{e:#}");
    }
}
