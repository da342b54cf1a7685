//! `jsae sweep` and `jsae report`: the command-line ends of the jsae-experiments crate.

use std::path::Path;
use std::process::ExitCode;

use jsae_experiments::{Grid, SweepOptions};

/// `jsae sweep FILE --out DIR [--jobs N]`: exit 0 when every run finished, 1 when some
/// failed (their logs are listed), 2 for a bad sweep file.
pub fn sweep(file: &Path, jobs: Option<usize>, out: &Path) -> ExitCode {
    let text = match std::fs::read_to_string(file) {
        Ok(t) => t,
        Err(e) => {
            eprintln!("jsae sweep: {}: {e}", file.display());
            return ExitCode::from(2);
        }
    };
    let grid = match Grid::parse(&text) {
        Ok(g) => g,
        Err(reason) => {
            eprintln!("jsae sweep: {}: {reason}", file.display());
            return ExitCode::from(2);
        }
    };
    if jobs == Some(0) {
        eprintln!("jsae sweep: --jobs must be positive");
        return ExitCode::from(2);
    }
    let exe = match jsae_train::launch::current_exe() {
        Ok(exe) => exe,
        Err(e) => {
            eprintln!("jsae sweep: {e}");
            return ExitCode::FAILURE;
        }
    };
    let options = SweepOptions {
        exe,
        jobs: jobs.unwrap_or_else(|| std::thread::available_parallelism().map_or(1, usize::from)),
        out: out.to_path_buf(),
    };
    let note = |line: &str| eprintln!("jsae sweep: {line}");
    match jsae_experiments::run_sweep(&grid, &text, &options, &note) {
        Ok(outcome) if outcome.failed.is_empty() => {
            println!(
                "{} runs trained, {} finished before; results in {} (next: jsae report {})",
                outcome.trained,
                outcome.skipped,
                out.display(),
                out.display()
            );
            ExitCode::SUCCESS
        }
        Ok(outcome) => {
            for (run, log) in &outcome.failed {
                eprintln!(
                    "jsae sweep: {} failed; see {}",
                    run.relative_dir().display(),
                    log.display()
                );
            }
            ExitCode::FAILURE
        }
        Err(e @ jsae_experiments::SweepError::Settings { .. }) => {
            eprintln!("jsae sweep: {e}");
            ExitCode::from(2)
        }
        Err(e) => {
            eprintln!("jsae sweep: {e}");
            ExitCode::FAILURE
        }
    }
}

/// `jsae report DIR [--out OUT]`: prints the markdown table and the files written.
pub fn report(dir: &Path, out: &Path) -> ExitCode {
    match jsae_report::report(dir, out) {
        Ok(made) => {
            println!("{}", made.markdown);
            for p in &made.written {
                println!("wrote: {}", p.display());
            }
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("jsae report: {e}");
            ExitCode::FAILURE
        }
    }
}
