//! SVG plots of a run: the learning curve (return and success rate against env steps) and,
//! for the gridworld, the learned action embeddings coloured by the displacement each
//! action causes and the learned state embeddings coloured by position (the paper's
//! Figure 2d and 2b).

use std::fmt::Write as _;
use std::path::PathBuf;

use jsae_embedder::Embedding;
use jsae_learner::MetricsTable;
use jsae_nn::{BurnDevice, RecordError};
use jsae_proto::run_dir::{RunDir, Weights};
use jsae_proto::{EmbeddingSnapshot, StateBatch};

use jsae_envs::EnvName;
use jsae_envs::gridworld::{Gridworld, action_motions};
use jsae_proto::settings::TrainConfig;

const W: f64 = 640.0;
const H: f64 = 400.0;
const PAD: f64 = 50.0;

struct Frame {
    x0: f64,
    x1: f64,
    y0: f64,
    y1: f64,
}

impl Frame {
    fn fit(xs: impl Iterator<Item = f64> + Clone, ys: impl Iterator<Item = f64> + Clone) -> Self {
        let lo_hi = |v: &mut dyn Iterator<Item = f64>| {
            v.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| {
                (a.min(x), b.max(x))
            })
        };
        let (x0, x1) = lo_hi(&mut xs.clone());
        let (y0, y1) = lo_hi(&mut ys.clone());
        let widen = |a: f64, b: f64| {
            if (b - a).abs() < 1e-12 {
                (a - 0.5, b + 0.5)
            } else {
                (a, b)
            }
        };
        let (x0, x1) = widen(x0, x1);
        let (y0, y1) = widen(y0, y1);
        Self { x0, x1, y0, y1 }
    }

    fn px(&self, x: f64) -> f64 {
        PAD + (x - self.x0) / (self.x1 - self.x0) * (W - 2.0 * PAD)
    }

    fn py(&self, y: f64) -> f64 {
        H - PAD - (y - self.y0) / (self.y1 - self.y0) * (H - 2.0 * PAD)
    }

    fn axes(&self, svg: &mut String, title: &str, xlabel: &str, ylabel: &str) {
        let _ = write!(
            svg,
            r#"<rect x="{PAD}" y="{PAD}" width="{}" height="{}" fill="none" stroke="black"/>"#,
            W - 2.0 * PAD,
            H - 2.0 * PAD
        );
        let _ = write!(
            svg,
            r#"<text x="{}" y="25" text-anchor="middle" font-size="16">{title}</text>"#,
            W / 2.0
        );
        let _ = write!(
            svg,
            r#"<text x="{}" y="{}" text-anchor="middle" font-size="12">{xlabel}</text>"#,
            W / 2.0,
            H - 12.0
        );
        let _ = write!(
            svg,
            r#"<text x="14" y="{}" text-anchor="middle" font-size="12" transform="rotate(-90 14 {})">{ylabel}</text>"#,
            H / 2.0,
            H / 2.0
        );
        for (v, anchor, x, y) in [
            (self.x0, "start", PAD, H - PAD + 15.0),
            (self.x1, "end", W - PAD, H - PAD + 15.0),
            (self.y0, "end", PAD - 4.0, H - PAD),
            (self.y1, "end", PAD - 4.0, PAD + 10.0),
        ] {
            let _ = write!(
                svg,
                r#"<text x="{x}" y="{y}" text-anchor="{anchor}" font-size="11">{}</text>"#,
                fmt_num(v)
            );
        }
    }
}

fn fmt_num(v: f64) -> String {
    if v.abs() >= 1000.0 {
        format!("{v:.0}")
    } else {
        format!("{v:.2}")
    }
}

fn svg_open() -> String {
    format!(
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{W}" height="{H}" viewBox="0 0 {W} {H}"><rect width="100%" height="100%" fill="white"/>"#
    )
}

fn polyline(svg: &mut String, frame: &Frame, pts: &[(f64, f64)], colour: &str) {
    let path: Vec<String> = pts
        .iter()
        .map(|(x, y)| format!("{:.1},{:.1}", frame.px(*x), frame.py(*y)))
        .collect();
    let _ = write!(
        svg,
        r#"<polyline fill="none" stroke="{colour}" stroke-width="1.5" points="{}"/>"#,
        path.join(" ")
    );
}

/// The learning curve of a run directory's `metrics.csv`.
pub fn learning_curve(metrics: &MetricsTable, title: &str) -> String {
    let ret = metrics.series("env_steps", "return_mean");
    let success = metrics.series("env_steps", "success_rate");
    let mut svg = svg_open();
    let frame = Frame::fit(
        ret.iter().map(|p| p.0).chain(std::iter::once(0.0)),
        ret.iter().chain(&success).map(|p| p.1),
    );
    frame.axes(
        &mut svg,
        title,
        "env steps",
        "training episode return (blue), success rate (green)",
    );
    polyline(&mut svg, &frame, &ret, "#1f77b4");
    polyline(&mut svg, &frame, &success, "#2ca02c");
    svg.push_str("</svg>\n");
    svg
}

/// Scatter of 2-D points with one colour each.
pub fn scatter(
    points: &[(f64, f64)],
    colours: &[(f64, f64, f64)],
    title: &str,
    xl: &str,
    yl: &str,
) -> String {
    let mut svg = svg_open();
    let frame = Frame::fit(points.iter().map(|p| p.0), points.iter().map(|p| p.1));
    frame.axes(&mut svg, title, xl, yl);
    for (p, c) in points.iter().zip(colours) {
        let to = |v: f64| (v.clamp(0.0, 1.0) * 255.0).round() as u8;
        let _ = write!(
            svg,
            r##"<circle cx="{:.1}" cy="{:.1}" r="3" fill="#{:02x}{:02x}{:02x}"/>"##,
            frame.px(p.0),
            frame.py(p.1),
            to(c.0),
            to(c.1),
            to(c.2)
        );
    }
    svg.push_str("</svg>\n");
    svg
}

/// Writes the plots of a finished run into its directory; returns their paths.
pub fn write_run_plots(
    dir: &RunDir,
    config: &TrainConfig,
    embedding: Option<&Embedding>,
) -> std::io::Result<Vec<PathBuf>> {
    let mut written = Vec::new();
    let metrics = MetricsTable::read(&dir.metrics_csv()).map_err(std::io::Error::other)?;
    let title = format!(
        "{} / {} / seed {}",
        config.env.as_str(),
        config.algo.as_str(),
        config.seed
    );
    let path = dir.learning_curve_svg();
    std::fs::write(&path, learning_curve(&metrics, &title))?;
    written.push(path);
    let gridworld = matches!(config.env, EnvName::Gridworld | EnvName::GridworldDiscrete);
    let table = embedding
        .filter(|e| gridworld && e.action_dim() >= 2)
        .and_then(|e| Some((e.action_table()?, e.action_dim())));
    if let Some((table, d)) = table {
        let motions = action_motions(config.environment.gridworld.actuators);
        let points: Vec<(f64, f64)> = table
            .chunks_exact(d)
            .map(|r| (f64::from(r[0]), f64::from(r[1])))
            .collect();
        let colours: Vec<(f64, f64, f64)> = motions
            .iter()
            .map(|m| ((m[0] + 1.0) / 2.0, (m[1] + 1.0) / 2.0, 0.5))
            .collect();
        let path = dir.action_embeddings_svg();
        let title = "action embeddings g(a), coloured by displacement";
        std::fs::write(&path, scatter(&points, &colours, title, "e1", "e2"))?;
        written.push(path);
    }
    let embeds_states = config.algo.representation().embeds_states();
    if let Some(embedding) = embedding.filter(|_| gridworld && embeds_states) {
        let (states, positions) = gridworld_cells(config);
        let mut phi = Vec::new();
        embedding.embed_states(&states, &mut phi);
        let (points, axes) = principal_plane(&phi, embedding.state_dim());
        let colours: Vec<(f64, f64, f64)> = positions.iter().map(|p| (p[0], p[1], 0.5)).collect();
        let path = dir.state_embeddings_svg();
        let title = "state embeddings phi(s) of the cell centres, coloured by position";
        std::fs::write(&path, scatter(&points, &colours, title, axes.0, axes.1))?;
        written.push(path);
    }
    Ok(written)
}

/// Every cell centre of the gridworld's `bins x bins` lattice, as the run's environment
/// encodes it (a one-hot cell for gridworld-discrete, the position otherwise), and its
/// position.
fn gridworld_cells(config: &TrainConfig) -> (StateBatch, Vec<[f64; 2]>) {
    let g = &config.environment.gridworld;
    let bins = g.bins.max(1);
    let positions: Vec<[f64; 2]> = (0..bins * bins)
        .map(|i| {
            let centre = |b: u32| (f64::from(b) + 0.5) / f64::from(bins);
            [centre(i / bins), centre(i % bins)]
        })
        .collect();
    let states = if config.env == EnvName::GridworldDiscrete {
        let world = Gridworld::new(g.clone(), true);
        StateBatch::Categorical {
            factors: 1,
            data: positions.iter().map(|&p| world.state_index(p)).collect(),
        }
    } else {
        StateBatch::Real {
            dim: 2,
            data: positions.iter().flatten().map(|&v| v as f32).collect(),
        }
    };
    (states, positions)
}

/// Rows of `data` (`[n, m]`) as 2-D points: the first two coordinates when `m <= 2`, else
/// the projections on the two leading principal components (power iteration on the
/// covariance, the second after deflating the first); also the axes' labels.
fn principal_plane(data: &[f32], m: usize) -> (Vec<(f64, f64)>, (&'static str, &'static str)) {
    let rows: Vec<Vec<f64>> = data
        .chunks_exact(m.max(1))
        .map(|r| r.iter().map(|&v| f64::from(v)).collect())
        .collect();
    if m <= 2 {
        let at = |r: &Vec<f64>, i: usize| r.get(i).copied().unwrap_or(0.0);
        let points = rows.iter().map(|r| (at(r, 0), at(r, 1))).collect();
        return (points, ("x1", "x2"));
    }
    let n = rows.len().max(1) as f64;
    let mean: Vec<f64> = (0..m)
        .map(|j| rows.iter().map(|r| r[j]).sum::<f64>() / n)
        .collect();
    let mut cov = vec![0.0; m * m];
    for r in &rows {
        for i in 0..m {
            for j in 0..m {
                cov[i * m + j] += (r[i] - mean[i]) * (r[j] - mean[j]) / n;
            }
        }
    }
    let first = leading_eigenvector(&cov, m);
    let lambda: f64 = (0..m)
        .map(|i| first[i] * (0..m).map(|j| cov[i * m + j] * first[j]).sum::<f64>())
        .sum();
    for i in 0..m {
        for j in 0..m {
            cov[i * m + j] -= lambda * first[i] * first[j];
        }
    }
    let second = leading_eigenvector(&cov, m);
    let project = |r: &Vec<f64>, v: &[f64]| (0..m).map(|j| (r[j] - mean[j]) * v[j]).sum::<f64>();
    let points = rows
        .iter()
        .map(|r| (project(r, &first), project(r, &second)))
        .collect();
    (points, ("PC 1", "PC 2"))
}

/// The unit eigenvector of the largest eigenvalue of a symmetric `m x m` matrix, by power
/// iteration from a fixed start.
fn leading_eigenvector(a: &[f64], m: usize) -> Vec<f64> {
    let mut v: Vec<f64> = (0..m).map(|i| 1.0 + i as f64 / m as f64).collect();
    for _ in 0..500 {
        let w: Vec<f64> = (0..m)
            .map(|i| (0..m).map(|j| a[i * m + j] * v[j]).sum())
            .collect();
        let norm = w.iter().map(|x| x * x).sum::<f64>().sqrt();
        if norm < 1e-12 {
            break;
        }
        v = w.into_iter().map(|x| x / norm).collect();
    }
    v
}

/// The newest embedding checkpoint of a run, if any.
pub fn latest_embedding(dir: &RunDir) -> Option<EmbeddingSnapshot> {
    let (version, path) = dir.checkpoints().newest(Weights::Embedding)?;
    Some(EmbeddingSnapshot {
        version,
        bytes: std::fs::read(path).ok()?,
        model_loss: 0.0,
        decoder_loss: 0.0,
        action_structure: None,
    })
}

/// The newest embedding checkpoint of a run, loaded with the run's settings (None: the run
/// has no embedding checkpoint).
pub fn load_latest_embedding(
    dir: &RunDir,
    config: &TrainConfig,
) -> Option<Result<Embedding, RecordError>> {
    let snapshot = latest_embedding(dir)?;
    let (states, actions) = config.spaces();
    Some(Embedding::from_snapshot(
        &config.embedding,
        config.algo.representation(),
        &states,
        &actions,
        &snapshot,
        &config.device.device(),
    ))
}

/// Draws the plots of a run directory written by separate services (or by hand): the learning
/// curve from `metrics.csv`, and the action embeddings of the newest embedding checkpoint.
pub fn plot_run_dir(dir: &RunDir, config: &TrainConfig) -> std::io::Result<Vec<PathBuf>> {
    let embedding = load_latest_embedding(dir, config).and_then(Result::ok);
    write_run_plots(dir, config, embedding.as_ref())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn principal_plane_finds_the_directions_of_spread() {
        // Points on a line in 3-D plus a smaller spread along a second, orthogonal direction.
        let mut data = Vec::new();
        for t in 0..10 {
            let (t, u) = (f64::from(t), if t % 2 == 0 { 0.5 } else { -0.5 });
            data.extend([t + u, 2.0 * t, -t + u].map(|v| v as f32));
        }
        let (points, labels) = principal_plane(&data, 3);
        assert_eq!(labels, ("PC 1", "PC 2"));
        let spread = |i: usize| {
            let v: Vec<f64> = points
                .iter()
                .map(|p| if i == 0 { p.0 } else { p.1 })
                .collect();
            let mean = v.iter().sum::<f64>() / v.len() as f64;
            v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / v.len() as f64
        };
        // The line's direction (1, 2, -1)/sqrt(6) carries 6 * var(t) = 49.5; the rest 0.5.
        assert!((spread(0) - 49.5).abs() < 0.1, "{}", spread(0));
        assert!((spread(1) - 0.5).abs() < 0.05, "{}", spread(1));
        let (flat, labels) = principal_plane(&[1.0, 2.0, 3.0, 4.0], 2);
        assert_eq!((flat, labels), (vec![(1.0, 2.0), (3.0, 4.0)], ("x1", "x2")));
    }
}
