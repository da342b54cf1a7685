//! Learning curves against env steps: one run's training return and success rate (separate
//! panels) with its final deterministic evaluation marked, and several runs in one figure
//! as the mean of each environment and algorithm with a band from the lowest to the
//! highest run.

use std::ops::Range;

use crate::figures::{self, Band, Drawing, Figure, reason, steps_label};
use crate::report::min_max_band;
use jsae_run_dir::{MetricsTable, Summary};
use plotters::coord::Shift;
use plotters::prelude::*;

/// Width of a curve figure; its height is [`PANEL_HEIGHT`] per panel and the title.
const WIDTH: u32 = 900;
const PANEL_HEIGHT: u32 = 380;
const TITLE_HEIGHT: u32 = 40;

/// Points of a combined curve on the common env-steps grid.
const COMBINED_POINTS: usize = 100;

/// (env steps, value) points, in increasing env steps.
pub type Curve = Vec<(f64, f64)>;

/// The training return and success rate of `metrics.csv` against env steps.
fn training_curves(metrics: &MetricsTable) -> (Curve, Curve) {
    (
        metrics.series("env_steps", "return_mean"),
        metrics.series("env_steps", "success_rate"),
    )
}

/// The final deterministic evaluation of a run (`summary.json`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Eval {
    /// Where it is drawn: the run's last env step.
    pub env_steps: f64,
    /// Mean return.
    pub return_mean: f64,
    /// The returns' standard deviation (the error bar).
    pub return_std: f64,
    /// Success rate, where the environment has one.
    pub success_rate: Option<f64>,
}

/// One run's learning curve: training return in one panel, success rate (0 to 1) in a
/// second where the environment has a success notion (a success column with values), each
/// with its evaluation point labelled "eval".
#[derive(Debug, Clone)]
pub struct LearningCurve {
    /// Title.
    pub title: String,
    /// (env steps, mean training episode return).
    pub returns: Curve,
    /// (env steps, training success rate); empty without a success notion.
    pub success: Curve,
    /// The final evaluation (none before the run has a summary).
    pub eval: Option<Eval>,
}

impl LearningCurve {
    /// The curve of a run's metrics and, once written, its summary.
    pub fn new(metrics: &MetricsTable, summary: Option<&Summary>, title: String) -> Self {
        let (returns, success) = training_curves(metrics);
        let last_step = returns.last().map_or(0.0, |p| p.0);
        let eval = summary.map(|s| Eval {
            env_steps: if s.env_steps > 0 {
                s.env_steps as f64
            } else {
                last_step
            },
            return_mean: s.eval_return_mean,
            return_std: s.eval_return_std,
            success_rate: s.eval_success_rate,
        });
        Self {
            title,
            returns,
            success,
            eval,
        }
    }

    fn panels(&self) -> u32 {
        if self.success.is_empty() { 1 } else { 2 }
    }
}

/// One panel of a learning curve: a training line and its evaluation point.
struct Panel<'a> {
    y_label: &'a str,
    line_label: &'a str,
    line: &'a [(f64, f64)],
    /// (env steps, value, error-bar half-width) and its legend label.
    eval: Option<((f64, f64, f64), &'a str)>,
    /// The y range when it is fixed (a rate's 0 to 1).
    fixed: Option<Range<f64>>,
}

impl Drawing for LearningCurve {
    fn size(&self) -> (u32, u32) {
        (WIDTH, TITLE_HEIGHT + PANEL_HEIGHT * self.panels())
    }

    fn draw_on<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<(), String>
    where
        DB::ErrorType: 'static,
    {
        let body = root
            .titled(&self.title, ("sans-serif", 20))
            .map_err(reason)?;
        let areas = body.split_evenly((self.panels() as usize, 1));
        let x_end = self
            .returns
            .iter()
            .chain(&self.success)
            .map(|p| p.0)
            .chain(self.eval.map(|e| e.env_steps))
            .fold(1.0, f64::max);
        let returns = Panel {
            y_label: "episode return",
            line_label: "training return (mean of the episodes)",
            line: &self.returns,
            eval: self.eval.map(|e| {
                let point = (e.env_steps, e.return_mean, e.return_std);
                (point, "eval: deterministic return, +/- 1 std")
            }),
            fixed: None,
        };
        draw_panel(&areas[0], &returns, x_end)?;
        if let Some(area) = areas.get(1) {
            let success = Panel {
                y_label: "success rate",
                line_label: "training success rate",
                line: &self.success,
                eval: self.eval.and_then(|e| {
                    Some((
                        (e.env_steps, e.success_rate?, 0.0),
                        "eval: deterministic success rate",
                    ))
                }),
                fixed: Some(-0.02..1.02),
            };
            draw_panel(area, &success, x_end)?;
        }
        Ok(())
    }
}

fn draw_panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    panel: &Panel<'_>,
    x_end: f64,
) -> Result<(), String>
where
    DB::ErrorType: 'static,
{
    let err = reason::<DB::ErrorType>;
    let y = panel.fixed.clone().unwrap_or_else(|| {
        let values = panel.line.iter().map(|p| (p.1, p.1));
        let eval = panel.eval.iter().map(|((_, v, e), _)| (v - e, v + e));
        let (lo, hi) = values
            .chain(eval)
            .filter(|(lo, hi)| lo.is_finite() && hi.is_finite())
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), (lo, hi)| {
                (a.min(lo), b.max(hi))
            });
        if lo <= hi {
            let pad = ((hi - lo) * 0.06).max(1e-3);
            (lo - pad)..(hi + pad)
        } else {
            0.0..1.0
        }
    });
    let mut chart = ChartBuilder::on(area)
        .margin(12)
        .x_label_area_size(45)
        .y_label_area_size(70)
        .build_cartesian_2d(0.0..x_end * 1.03, y)
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc("env steps")
        .y_desc(panel.y_label)
        .x_label_formatter(&steps_label)
        .label_style(("sans-serif", 14))
        .draw()
        .map_err(err)?;
    let line_colour = figures::colour(0);
    chart
        .draw_series(LineSeries::new(
            panel.line.iter().copied(),
            line_colour.stroke_width(2),
        ))
        .map_err(err)?
        .label(panel.line_label)
        .legend(move |(x, y)| {
            PathElement::new(vec![(x, y), (x + 24, y)], line_colour.stroke_width(3))
        });
    if let Some(((x, v, half), label)) = panel.eval {
        let eval_colour = figures::colour(3);
        if half > 0.0 {
            chart
                .draw_series(std::iter::once(ErrorBar::new_vertical(
                    x,
                    v - half,
                    v,
                    v + half,
                    eval_colour.stroke_width(2),
                    14,
                )))
                .map_err(err)?;
        }
        chart
            .draw_series(std::iter::once(Circle::new(
                (x, v),
                6,
                eval_colour.filled(),
            )))
            .map_err(err)?
            .label(label)
            .legend(move |(x, y)| Circle::new((x + 12, y), 6, eval_colour.filled()));
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::LowerRight)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font(("sans-serif", 14))
        .draw()
        .map_err(err)?;
    Ok(())
}

/// One run among several: the group it is averaged in (`env / algo`) and its curves.
#[derive(Debug, Clone)]
pub struct RunCurves {
    /// The group: runs with the same label are averaged together.
    pub group: String,
    /// (env steps, mean training episode return).
    pub returns: Curve,
    /// (env steps, training success rate); empty without a success notion.
    pub success: Curve,
}

impl RunCurves {
    /// The curves of a run's metrics, in `group`.
    pub fn new(group: String, metrics: &MetricsTable) -> Self {
        let (returns, success) = training_curves(metrics);
        Self {
            group,
            returns,
            success,
        }
    }
}

/// Several runs in one figure: per group, the mean over its runs of the training return
/// (and success rate, in a second panel, where any group has one) with a band from the
/// lowest to the highest run, on a common env-steps grid where each run's curve is
/// interpolated linearly (over the range all the group's runs cover).
#[derive(Debug, Clone)]
pub struct Combined {
    returns: Figure,
    success: Option<Figure>,
}

impl Combined {
    /// The figure of `runs` (groups in the order they first appear).
    pub fn new(runs: &[RunCurves]) -> Self {
        let mut groups: Vec<(&str, Vec<&RunCurves>)> = Vec::new();
        for run in runs {
            match groups.iter_mut().find(|(g, _)| *g == run.group) {
                Some((_, members)) => members.push(run),
                None => groups.push((&run.group, vec![run])),
            }
        }
        let series = |pick: fn(&RunCurves) -> &[(f64, f64)]| -> Vec<(String, Vec<Band>)> {
            groups
                .iter()
                .map(|(group, members)| {
                    let curves: Vec<&[(f64, f64)]> = members.iter().map(|r| pick(r)).collect();
                    let name = match members.len() {
                        1 => format!("{group} (1 run)"),
                        n => format!("{group}: mean of {n} runs, band min to max"),
                    };
                    (name, min_max_band(&curves, COMBINED_POINTS))
                })
                .filter(|(_, band)| !band.is_empty())
                .collect()
        };
        let figure = |what: &str, series: Vec<(String, Vec<Band>)>| Figure {
            title: format!("{what}, {} runs", runs.len()),
            x_label: "env steps".into(),
            y_label: what.into(),
            series,
        };
        let success = series(|r| &r.success);
        Self {
            returns: figure("training return", series(|r| &r.returns)),
            success: (!success.is_empty()).then(|| figure("training success rate", success)),
        }
    }

    /// Names of the drawn series, per panel.
    pub fn series_names(&self) -> Vec<&str> {
        let panels = std::iter::once(&self.returns).chain(&self.success);
        panels
            .flat_map(|f| f.series.iter().map(|(name, _)| name.as_str()))
            .collect()
    }
}

impl Drawing for Combined {
    fn size(&self) -> (u32, u32) {
        let panels = if self.success.is_some() { 2 } else { 1 };
        (WIDTH, (PANEL_HEIGHT + TITLE_HEIGHT / 2) * panels)
    }

    fn draw_on<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<(), String>
    where
        DB::ErrorType: 'static,
    {
        let Some(success) = &self.success else {
            return figures::draw_bands(root, &self.returns);
        };
        let areas = root.split_evenly((2, 1));
        figures::draw_bands(&areas[0], &self.returns)?;
        figures::draw_bands(&areas[1], success)
    }
}
