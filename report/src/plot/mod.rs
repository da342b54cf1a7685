//! The plots of a run, drawn by plotters as SVG and PNG twins (`learning_curve.svg` and
//! `learning_curve.png`, ...; the font, the colours and the double drawing are
//! `crate::figures`'), and `jsae plot`.
//!
//! Layout: `curves` (the learning curve of a run with its final evaluation, and several runs
//! in one figure as a mean with a band), `embeddings` (for the gridworld, the learned action
//! embeddings coloured by the displacement each action causes and the learned state
//! embeddings coloured by position, the paper's Figures 2d and 2b, each with a colour key),
//! `weights` (`summary.json` and which embedding checkpoint the plots are drawn from).

mod curves;
mod embeddings;
#[cfg(test)]
mod tests;
mod weights;

use std::io;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use crate::figures::{self, Drawing};
use clap::Args;
use jsae_agent::Embedding;
use jsae_run_dir::MetricsTable;
use jsae_run_dir::RunDir;
use jsae_settings::TrainConfig;

pub use curves::{Combined, Curve, Eval, LearningCurve, RunCurves};
pub use embeddings::{ColourKey, Scatter};
pub use weights::{
    latest_embedding, load_embedding, load_latest_embedding, read_summary, run_embedding,
};

/// `jsae plot`: the plots of one or more run directories, and with several runs (or
/// `--to`) one figure of them all.
#[derive(Args, Debug, Clone, Default)]
pub struct PlotArgs {
    /// Run directories (each holding config.toml and metrics.csv).
    #[arg(value_name = "RUN")]
    pub runs: Vec<PathBuf>,
    /// A run directory, the same as RUN (repeatable; `--out` is read as this too, the name
    /// `jsae train --out` gave the run).
    #[arg(long = "run", alias = "out", value_name = "DIR")]
    pub out: Vec<PathBuf>,
    /// Where the figure of all the runs goes: FILE_STEM.svg and FILE_STEM.png (per
    /// environment and algorithm, the mean over its runs with a band from the lowest to the
    /// highest run). Drawn for several runs, and for one when this is given [default:
    /// learning_curves in the first run's parent folder].
    #[arg(long, value_name = "FILE_STEM")]
    pub to: Option<PathBuf>,
}

/// Runs `jsae plot`: prints each file written; exits 2 with a one-line reason for a
/// missing run directory, one without metrics.csv or with unreadable settings, 1 when
/// drawing fails.
pub fn main(args: &PlotArgs) -> ExitCode {
    match plot(args) {
        Ok(paths) => {
            for p in paths {
                println!("plot: {}", p.display());
            }
            ExitCode::SUCCESS
        }
        Err((code, reason)) => {
            eprintln!("jsae plot: {reason}");
            ExitCode::from(code)
        }
    }
}

/// What `jsae plot` does: the files written, or the exit code and the reason.
fn plot(args: &PlotArgs) -> Result<Vec<PathBuf>, (u8, String)> {
    let dirs: Vec<&PathBuf> = args.runs.iter().chain(&args.out).collect();
    if dirs.is_empty() {
        return Err((
            2,
            "no run directory given (jsae plot RUN... or --out DIR)".into(),
        ));
    }
    let mut runs = Vec::new();
    for d in dirs {
        let run = RunDir::new(d);
        if !d.is_dir() {
            return Err((2, format!("{}: no such directory", d.display())));
        }
        if !run.metrics_csv().is_file() {
            return Err((
                2,
                format!("{}: no metrics.csv (not a run directory)", d.display()),
            ));
        }
        let config = TrainConfig::from_layers(None, None, Some(&run.config_toml()))
            .map_err(|e| (2, e.to_string()))?;
        runs.push((run, config));
    }
    figures::font().map_err(|reason| (1, reason))?;
    let failed = |run: &RunDir| {
        let dir = run.path().display().to_string();
        move |e: io::Error| (1, format!("{dir}: {e}"))
    };
    let mut written = Vec::new();
    for (run, config) in &runs {
        written.extend(plot_run_dir(run, config).map_err(failed(run))?);
    }
    if runs.len() > 1 || args.to.is_some() {
        let mut curves = Vec::new();
        for (run, config) in &runs {
            let metrics = MetricsTable::read(&run.metrics_csv())
                .map_err(|e| failed(run)(io::Error::other(e)))?;
            let group = format!("{} / {}", config.env.as_str(), config.algo.as_str());
            curves.push(RunCurves::new(group, &metrics));
        }
        let stem = args
            .to
            .clone()
            .unwrap_or_else(|| default_combined_stem(runs[0].0.path()));
        let paths =
            figures::draw_twice(&Combined::new(&curves), &stem).map_err(|e| (1, e.to_string()))?;
        written.extend(paths);
    }
    Ok(written)
}

/// `learning_curves` beside the run directory `run` (in its parent folder).
fn default_combined_stem(run: &Path) -> PathBuf {
    run.parent()
        .unwrap_or(Path::new(""))
        .join("learning_curves")
}

/// Draws `drawing` as `svg` and as its PNG twin (the same name ending in `.png`).
fn draw_beside(drawing: &impl Drawing, svg: &Path) -> io::Result<Vec<PathBuf>> {
    figures::draw_twice(drawing, &svg.with_extension("")).map_err(io::Error::other)
}

/// Writes the plots of a run into its directory, each as SVG and PNG; returns their paths.
/// The learning curve (with the final evaluation of `summary.json`, once it is there) and,
/// for the gridworlds, the scatters of `embedding` (titled with its version). On a machine
/// without a TrueType font nothing is drawn (a warning, not an error: a finished run is not
/// lost to a missing font).
pub fn write_run_plots(
    dir: &RunDir,
    config: &TrainConfig,
    embedding: Option<&Embedding>,
) -> io::Result<Vec<PathBuf>> {
    if let Err(reason) = figures::font() {
        tracing::warn!("{}: no plots drawn: {reason}", dir.path().display());
        return Ok(Vec::new());
    }
    let metrics = MetricsTable::read(&dir.metrics_csv()).map_err(io::Error::other)?;
    let summary = read_summary(dir)?;
    let title = format!(
        "{} / {} / seed {}",
        config.env.as_str(),
        config.algo.as_str(),
        config.seed
    );
    let curve = LearningCurve::new(&metrics, summary.as_ref(), title);
    let mut written = draw_beside(&curve, &dir.learning_curve_svg())?;
    for (scatter, svg) in embeddings::embedding_scatters(dir, config, embedding) {
        written.extend(draw_beside(&scatter, &svg)?);
    }
    Ok(written)
}

/// Draws the plots of a run directory written by separate services (or by hand): the
/// learning curve from `metrics.csv` and `summary.json`, and the embedding scatters of the
/// embedding version the summary names ([`run_embedding`]: the newest checkpoint only while
/// there is no summary yet), so an older run's checkpoints left in the directory are not
/// drawn.
pub fn plot_run_dir(dir: &RunDir, config: &TrainConfig) -> io::Result<Vec<PathBuf>> {
    // only the gridworlds' embeddings are drawn: another run's is not read (at a million
    // items that is 801 MB, and f's index built for nothing)
    if !embeddings::plots_embeddings(config) {
        return write_run_plots(dir, config, None);
    }
    let embedding = match run_embedding(dir)? {
        Some(snapshot) => match load_embedding(&snapshot, config) {
            Ok(embedding) => Some(embedding),
            Err(e) => {
                tracing::warn!(
                    "{}: embedding version {} does not load with the run's settings ({e}); \
                     no embedding plots",
                    dir.path().display(),
                    snapshot.version
                );
                None
            }
        },
        None => {
            if embeddings::plots_embeddings(config) && config.algo.representation().needs_embedder()
            {
                let wanted = match read_summary(dir)? {
                    Some(s) => format!("version {} (summary.json)", s.embedding_version),
                    None => "checkpoint".into(),
                };
                tracing::warn!(
                    "{}: no embedding plots: checkpoints/ holds no embedding {wanted}",
                    dir.path().display()
                );
            }
            None
        }
    };
    write_run_plots(dir, config, embedding.as_ref())
}
