//! `jsae report DIR`: the runs of a results folder, grouped by setting, environment and
//! algorithm, summarised over seeds (mean with a 95% bootstrap interval, interquartile
//! mean, steps to a threshold, wall time) into `report.md`, `report.json` and the figures.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use jsae_run_dir::MetricsTable;
use serde::Deserialize;

pub use crate::error::ReportError;
use crate::figures::{self, Band, Figure};
use crate::stats::{self, Interval, RESAMPLES};
use jsae_experiments::grid::{Grid, ReportSpec};

/// Points on the x axis of a curve with a band.
const CURVE_POINTS: usize = 60;
/// Bootstrap resamples per curve point (fewer than for the table: many points).
const CURVE_RESAMPLES: usize = 1000;

fn file_error(path: &Path) -> impl FnOnce(String) -> ReportError + '_ {
    move |message| ReportError::File {
        path: path.to_path_buf(),
        message,
    }
}

/// The fields of `summary.json` a report reads.
#[derive(Debug, Clone, Deserialize)]
struct SummaryFields {
    env: String,
    algo: String,
    env_steps: u64,
    wall_seconds: f64,
    eval_return_mean: f64,
    eval_success_rate: Option<f64>,
    #[serde(default)]
    eval_stochastic_return_mean: Option<f64>,
    #[serde(default)]
    eval_stochastic_success_rate: Option<f64>,
}

/// One finished run.
#[derive(Debug, Clone)]
pub struct RunResult {
    /// The setting (the folder under `runs/`).
    pub setting: String,
    summary: SummaryFields,
    /// The training curve of the report's column against env steps.
    pub curve: Vec<(f64, f64)>,
    /// The training return against env steps.
    pub returns: Vec<(f64, f64)>,
}

/// One algorithm's row of a table.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Row {
    /// The setting.
    pub setting: String,
    /// The environment.
    pub env: String,
    /// The algorithm.
    pub algo: String,
    /// Seeds (finished runs).
    pub seeds: usize,
    /// Env steps of a run (the largest among the seeds).
    pub env_steps: u64,
    /// Deterministic evaluation return over seeds.
    pub eval_return: Interval,
    /// Its interquartile mean.
    pub eval_return_iqm: f64,
    /// Deterministic evaluation success rate over seeds (None without a success notion).
    pub eval_success: Option<Interval>,
    /// Stochastic evaluation return over seeds (None for runs without it).
    pub stochastic_return: Option<Interval>,
    /// Stochastic evaluation success rate over seeds.
    pub stochastic_success: Option<Interval>,
    /// Seeds whose deterministic evaluation success is at least 0.9.
    pub eval_solved: Option<usize>,
    /// Seeds whose last training value of the report column reached the threshold while
    /// their deterministic evaluation success stayed below it (a greedy policy that loops
    /// where the sampled one solves the task); None without a threshold or a success notion.
    pub greedy_below_training: Option<usize>,
    /// Seeds whose training curve reached the threshold, and the mean env steps it took them.
    pub reached: Option<(usize, Option<f64>)>,
    /// The report column's last training value, over seeds.
    pub final_training: Option<Interval>,
    /// Mean wall seconds of a run.
    pub wall_seconds: f64,
}

/// A made report.
#[derive(Debug)]
pub struct Report {
    /// The rows, by setting, env and algorithm.
    pub rows: Vec<Row>,
    /// The markdown (also in `report.md`).
    pub markdown: String,
    /// Files written.
    pub written: Vec<PathBuf>,
}

/// The finished runs under `dir/runs/`.
pub fn collect(
    dir: &Path,
    spec: &ReportSpec,
    grid: Option<&Grid>,
) -> Result<Vec<RunResult>, ReportError> {
    let wanted: Option<std::collections::BTreeSet<PathBuf>> = grid.map(|g| {
        g.runs()
            .iter()
            .map(|r| dir.join(r.relative_dir()))
            .collect()
    });
    let runs = dir.join("runs");
    let mut found = Vec::new();
    let entries = |p: &Path| -> Result<Vec<PathBuf>, ReportError> {
        let mut v: Vec<PathBuf> = std::fs::read_dir(p)
            .map_err(|e| file_error(p)(e.to_string()))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.is_dir())
            .collect();
        v.sort();
        Ok(v)
    };
    if !runs.is_dir() {
        return Err(ReportError::Empty(dir.to_path_buf()));
    }
    for setting_dir in entries(&runs)? {
        let setting = setting_dir
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        for run_dir in entries(&setting_dir)? {
            if wanted.as_ref().is_some_and(|w| !w.contains(&run_dir)) {
                continue; // not in the sweep file (any more)
            }
            let summary_path = run_dir.join("summary.json");
            let Ok(text) = std::fs::read_to_string(&summary_path) else {
                continue; // unfinished
            };
            let summary: SummaryFields = serde_json::from_str(&text)
                .map_err(|e| file_error(&summary_path)(e.to_string()))?;
            let metrics_path = run_dir.join("metrics.csv");
            let metrics = MetricsTable::read(&metrics_path)
                .map_err(|e| file_error(&metrics_path)(e.to_string()))?;
            if !metrics.columns().contains(&spec.column) {
                return Err(file_error(&metrics_path)(format!(
                    "no column {:?} (the sweep file's [report] column)",
                    spec.column
                )));
            }
            found.push(RunResult {
                setting: setting.clone(),
                curve: metrics.series("env_steps", &spec.column),
                returns: metrics.series("env_steps", "return_mean"),
                summary,
            });
        }
    }
    if found.is_empty() {
        return Err(ReportError::Empty(dir.to_path_buf()));
    }
    Ok(found)
}

/// Group key: (setting, env), then algorithm.
type Groups<'a> = BTreeMap<(String, String), BTreeMap<String, Vec<&'a RunResult>>>;

fn group(runs: &[RunResult]) -> Groups<'_> {
    let mut groups: Groups<'_> = BTreeMap::new();
    for r in runs {
        groups
            .entry((r.setting.clone(), r.summary.env.clone()))
            .or_default()
            .entry(r.summary.algo.clone())
            .or_default()
            .push(r);
    }
    groups
}

fn interval(values: &[f64]) -> Option<Interval> {
    stats::bootstrap_mean(values, RESAMPLES, 0)
}

/// Summarises one algorithm's runs of one setting and environment.
pub fn row(runs: &[&RunResult], spec: &ReportSpec) -> Row {
    let first = &runs[0];
    let returns: Vec<f64> = runs.iter().map(|r| r.summary.eval_return_mean).collect();
    let all = |f: fn(&SummaryFields) -> Option<f64>| -> Option<Vec<f64>> {
        runs.iter().map(|r| f(&r.summary)).collect()
    };
    let success = all(|s| s.eval_success_rate);
    let reached = spec.threshold.map(|t| {
        let steps: Vec<f64> = runs
            .iter()
            .filter_map(|r| stats::first_reaching(&r.curve, t))
            .collect();
        let n = steps.len();
        (n, (n > 0).then(|| stats::mean(&steps)))
    });
    let finals: Option<Vec<f64>> = runs.iter().map(|r| r.curve.last().map(|p| p.1)).collect();
    let greedy_below_training = match (spec.threshold, &success) {
        (Some(t), Some(success)) if spec.column == "success_rate" => Some(
            runs.iter()
                .zip(success)
                .filter(|(r, s)| r.curve.last().is_some_and(|p| p.1 >= t) && **s < t)
                .count(),
        ),
        _ => None,
    };
    Row {
        setting: first.setting.clone(),
        env: first.summary.env.clone(),
        algo: first.summary.algo.clone(),
        seeds: runs.len(),
        env_steps: runs.iter().map(|r| r.summary.env_steps).max().unwrap_or(0),
        eval_return: interval(&returns).unwrap_or(Interval {
            mean: f64::NAN,
            lo: f64::NAN,
            hi: f64::NAN,
        }),
        eval_return_iqm: stats::iqm(&returns),
        eval_solved: success
            .as_ref()
            .map(|v| v.iter().filter(|&&s| s >= 0.9).count()),
        eval_success: success.as_deref().and_then(interval),
        greedy_below_training,
        stochastic_return: all(|s| s.eval_stochastic_return_mean)
            .as_deref()
            .and_then(interval),
        stochastic_success: all(|s| s.eval_stochastic_success_rate)
            .as_deref()
            .and_then(interval),
        reached,
        final_training: finals.as_deref().and_then(interval),
        wall_seconds: stats::mean(
            &runs
                .iter()
                .map(|r| r.summary.wall_seconds)
                .collect::<Vec<_>>(),
        ),
    }
}

fn ci(i: &Interval) -> String {
    let f = |v: f64| {
        if v.abs() >= 100.0 {
            format!("{v:.0}")
        } else {
            format!("{v:.2}")
        }
    };
    format!("{} [{}, {}]", f(i.mean), f(i.lo), f(i.hi))
}

fn opt_ci(i: Option<&Interval>) -> String {
    i.map_or_else(|| "-".into(), ci)
}

/// The markdown table of some rows.
pub fn markdown_table(rows: &[Row], spec: &ReportSpec) -> String {
    let threshold = spec.threshold.map_or_else(String::new, |t| {
        format!(
            " | steps to {c} >= {t} | final {c} >= {t}, det. eval success < {t}",
            c = spec.column
        )
    });
    let mut md = format!(
        "| setting | env | algo | seeds | eval return (det.) | IQM | eval success (det.) | \
         solved (det. >= 0.9) | eval return (stoch.) | eval success (stoch.) | final training {}{threshold} | wall s |\n",
        spec.column
    );
    md.push_str("|---|---|---|---|---|---|---|---|---|---|---|");
    md.push_str(if spec.threshold.is_some() {
        "---|---|---|\n"
    } else {
        "---|\n"
    });
    for r in rows {
        let reached = r.reached.map_or_else(String::new, |(n, steps)| {
            let steps = steps.map_or_else(|| "-".into(), |s| format!("{:.1}k", s / 1000.0));
            let below = r
                .greedy_below_training
                .map_or_else(|| "-".into(), |b| format!("{b}/{}", r.seeds));
            format!(" | {n}/{} ({steps}) | {below}", r.seeds)
        });
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} | {} | {:.2} | {} | {} | {} | {} | {}{reached} | {:.0} |",
            r.setting,
            r.env,
            r.algo,
            r.seeds,
            ci(&r.eval_return),
            r.eval_return_iqm,
            opt_ci(r.eval_success.as_ref()),
            r.eval_solved
                .map_or_else(|| "-".into(), |n| format!("{n}/{}", r.seeds)),
            opt_ci(r.stochastic_return.as_ref()),
            opt_ci(r.stochastic_success.as_ref()),
            opt_ci(r.final_training.as_ref()),
            r.wall_seconds
        );
    }
    md
}

/// The mean curve over seeds with a 95% bootstrap band, on an even grid of env steps; a
/// point is drawn only where every seed has a value.
pub fn band(curves: &[&[(f64, f64)]], points: usize) -> Vec<Band> {
    // Up to the shortest curve's end: no seed's last value is carried beyond its run.
    let end = curves
        .iter()
        .map(|c| c.last().map_or(0.0, |p| p.0))
        .fold(f64::INFINITY, f64::min);
    if !end.is_finite() {
        return Vec::new();
    }
    (1..=points)
        .filter_map(|i| {
            let x = end * i as f64 / points as f64;
            let ys: Option<Vec<f64>> = curves.iter().map(|c| stats::value_at(c, x)).collect();
            let ci = stats::bootstrap_mean(&ys?, CURVE_RESAMPLES, i as u64)?;
            Some(Band {
                x,
                mean: ci.mean,
                lo: ci.lo,
                hi: ci.hi,
            })
        })
        .collect()
}

/// The mean curve of several runs with a band from the lowest to the highest run, on `points`
/// evenly spaced env steps over the range every run covers (from the latest first point to
/// the earliest last point), each run's curve interpolated linearly onto them. Empty when
/// the runs share no range.
pub fn min_max_band(curves: &[&[(f64, f64)]], points: usize) -> Vec<Band> {
    let (mut start, mut end) = (f64::NEG_INFINITY, f64::INFINITY);
    for c in curves {
        let (Some(first), Some(last)) = (c.first(), c.last()) else {
            return Vec::new();
        };
        (start, end) = (start.max(first.0), end.min(last.0));
    }
    if curves.is_empty() || start.is_nan() || end.is_nan() || start > end {
        return Vec::new();
    }
    let steps = if start < end { points.max(2) - 1 } else { 0 };
    (0..=steps)
        .filter_map(|i| {
            let x = start + (end - start) * i as f64 / steps.max(1) as f64;
            let ys: Vec<f64> = curves
                .iter()
                .map(|c| stats::interpolate(c, x))
                .collect::<Option<_>>()?;
            Some(Band {
                x,
                mean: stats::mean(&ys),
                lo: ys.iter().copied().fold(f64::INFINITY, f64::min),
                hi: ys.iter().copied().fold(f64::NEG_INFINITY, f64::max),
            })
        })
        .collect()
}

/// Where a results folder's runs came from, for the report's first line.
fn sweep_source(dir: &Path) -> String {
    let name = dir.file_name().map_or_else(
        || dir.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    );
    if dir.join("sweep.toml").exists() {
        format!("the sweep `{name}`")
    } else {
        format!("`{name}`")
    }
}

/// Makes the report of the results folder `dir` into `out` (often `dir` itself): `report.md`,
/// `report.json` and `figures/SETTING-ENV-{return_mean,COLUMN}.{svg,png}`.
pub fn report(dir: &Path, out: &Path) -> Result<Report, ReportError> {
    let sweep_file = dir.join("sweep.toml");
    let grid = if sweep_file.exists() {
        Some(Grid::read(&sweep_file).map_err(|e| file_error(&sweep_file)(e.to_string()))?)
    } else {
        None
    };
    let spec = grid.as_ref().map(|g| g.report.clone()).unwrap_or_default();
    let runs = collect(dir, &spec, grid.as_ref())?;
    let groups = group(&runs);
    let mut rows = Vec::new();
    let mut written = Vec::new();
    let mut figure_links = String::new();
    let mut figures_skipped: Option<String> = None;
    let fig_dir = out.join("figures");
    std::fs::create_dir_all(&fig_dir).map_err(|e| file_error(&fig_dir)(e.to_string()))?;
    for ((setting, env), algos) in &groups {
        for runs in algos.values() {
            rows.push(row(runs, &spec));
        }
        let mut columns = vec![("return_mean", "training episode return")];
        if spec.column != "return_mean" {
            columns.push((spec.column.as_str(), spec.column.as_str()));
        }
        for (column, label) in columns {
            let series: Vec<(String, Vec<Band>)> = algos
                .iter()
                .map(|(algo, runs)| {
                    let curves: Vec<&[(f64, f64)]> = runs
                        .iter()
                        .map(|r| {
                            if column == "return_mean" {
                                r.returns.as_slice()
                            } else {
                                r.curve.as_slice()
                            }
                        })
                        .collect();
                    (algo.clone(), band(&curves, CURVE_POINTS))
                })
                .filter(|(_, b)| !b.is_empty())
                .collect();
            if series.is_empty() {
                continue;
            }
            let stem = format!("{setting}-{env}-{column}");
            let figure = Figure {
                title: format!("{env}, {setting}: {label} (mean, 95% CI over seeds)"),
                x_label: "env steps".into(),
                y_label: label.into(),
                series,
            };
            if let Err(reason) = figures::font() {
                // Tables without figures rather than no report (a machine with no font).
                if figures_skipped.is_none() {
                    figures_skipped = Some(reason);
                }
                continue;
            }
            for path in figures::draw(&figure, &fig_dir.join(&stem))? {
                written.push(path);
            }
            let _ = writeln!(figure_links, "![{stem}](figures/{stem}.svg)");
        }
    }
    let mut markdown = format!(
        "Made by `jsae report` from {} ({} runs).\n\n",
        sweep_source(dir),
        runs.len()
    );
    markdown.push_str(
        "Mean over seeds with a 95% percentile-bootstrap interval in brackets; IQM: \
         interquartile mean of the deterministic evaluation return. Deterministic evaluation: \
         the policy's mean action (then f); stochastic: sampled actions. Steps to the threshold: \
         the seeds whose training curve reached it, and the mean of their first env step \
         there (the others are not in that mean).\n\n",
    );
    markdown.push_str(&markdown_table(&rows, &spec));
    markdown.push('\n');
    markdown.push_str(&figure_links);
    if let Some(reason) = &figures_skipped {
        let _ = writeln!(markdown, "No figures: {reason}.");
    }
    let md_path = out.join("report.md");
    std::fs::write(&md_path, &markdown).map_err(|e| file_error(&md_path)(e.to_string()))?;
    written.push(md_path);
    let json_path = out.join("report.json");
    let json = serde_json::to_string_pretty(&rows).unwrap_or_default();
    std::fs::write(&json_path, json + "\n").map_err(|e| file_error(&json_path)(e.to_string()))?;
    written.push(json_path);
    Ok(Report {
        rows,
        markdown,
        written,
    })
}
