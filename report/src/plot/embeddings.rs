//! The gridworld's learned embeddings as scatters in a square frame (equal x and y scales),
//! each beside a colour key: the action embeddings g(a) coloured by the displacement each
//! action causes (the paper's Figure 2d), and the state embeddings phi(s) of every cell
//! centre coloured by position (Figure 2b). Embeddings wider than 2 are shown on their first
//! two principal components.

use std::ops::Range;
use std::path::PathBuf;

use crate::figures::{Drawing, reason};
use jsae_agent::Embedding;
use jsae_envs::EnvName;
use jsae_envs::gridworld::{Gridworld, action_motions};
use jsae_run_dir::RunDir;
use jsae_settings::TrainConfig;
use jsae_wire::StateBatch;
use plotters::coord::Shift;
use plotters::prelude::*;

/// Size of an embedding figure: a square chart and the key beside it.
const SIZE: (u32, u32) = (880, 640);

/// Cells per side of the colour key's square.
const KEY_CELLS: u32 = 24;

/// A 2-D scatter, one colour per point, in a square frame beside its colour key.
#[derive(Debug, Clone)]
pub struct Scatter {
    /// Title (names the embedding version drawn).
    pub title: String,
    /// x- and y-axis labels.
    pub axes: (String, String),
    /// The points.
    pub points: Vec<(f64, f64)>,
    /// Their colours: [`ColourKey::colour_of`] of each point's quantity.
    pub colours: Vec<RGBColor>,
    /// What the colours encode.
    pub key: ColourKey,
}

/// What a scatter's colours encode: a 2-D quantity over a box, drawn as a square of the
/// colours it takes, with the values the points have marked on it.
#[derive(Debug, Clone)]
pub struct ColourKey {
    /// Caption (`colour = displacement`).
    pub caption: String,
    /// Names of the quantity's two components.
    pub axes: (String, String),
    /// The box.
    pub x: Range<f64>,
    /// The box.
    pub y: Range<f64>,
    /// The colour of a value.
    pub colour_of: fn(f64, f64) -> RGBColor,
    /// Values marked on the key (each action's displacement).
    pub marks: Vec<(f64, f64)>,
    /// Lines of text under the key.
    pub notes: Vec<String>,
}

/// The radius of a scatter's dots: smaller the more there are.
fn dot_radius(n: usize) -> i32 {
    match n {
        0..=64 => 6,
        65..=400 => 4,
        _ => 3,
    }
}

/// The colour of a point of the unit square: red grows with the first coordinate, green
/// with the second.
fn unit_colour(u: f64, v: f64) -> RGBColor {
    let byte = |t: f64| (t.clamp(0.0, 1.0) * 255.0).round() as u8;
    RGBColor(byte(u), byte(v), 128)
}

/// The colour of a displacement in `[-1, 1]^2`.
fn displacement_colour(dx: f64, dy: f64) -> RGBColor {
    unit_colour((dx + 1.0) / 2.0, (dy + 1.0) / 2.0)
}

impl Drawing for Scatter {
    fn size(&self) -> (u32, u32) {
        SIZE
    }

    fn draw_on<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<(), String>
    where
        DB::ErrorType: 'static,
    {
        let err = reason::<DB::ErrorType>;
        let body = root.titled(&self.title, ("sans-serif", 20)).map_err(err)?;
        let side = body.dim_in_pixel().1;
        let (left, right) = body.split_horizontally(side);
        // Equal label areas and margins on a square area, and equal spans: a square frame
        // with one scale on both axes.
        let (x, y) = square_ranges(&self.points);
        let mut chart = ChartBuilder::on(&left)
            .margin(12)
            .x_label_area_size(45)
            .y_label_area_size(45)
            .build_cartesian_2d(x, y)
            .map_err(err)?;
        chart
            .configure_mesh()
            .x_desc(&self.axes.0)
            .y_desc(&self.axes.1)
            .label_style(("sans-serif", 13))
            .draw()
            .map_err(err)?;
        let r = dot_radius(self.points.len());
        chart
            .draw_series(self.points.iter().zip(&self.colours).map(|(&p, &c)| {
                EmptyElement::at(p)
                    + Circle::new((0, 0), r, c.filled())
                    + Circle::new((0, 0), r, BLACK.mix(0.5).stroke_width(1))
            }))
            .map_err(err)?;
        let key_side = right.dim_in_pixel().0;
        let (key_area, notes) = right.split_vertically(key_side);
        self.key.draw_on(&key_area.margin(30, 0, 10, 16))?;
        let style = TextStyle::from(("sans-serif", 14)).color(&BLACK);
        for (i, line) in self.key.notes.iter().enumerate() {
            let y = 8 + 20 * i as i32;
            notes.draw_text(line, &style, (16, y)).map_err(err)?;
        }
        Ok(())
    }
}

impl ColourKey {
    fn draw_on<DB: DrawingBackend>(&self, area: &DrawingArea<DB, Shift>) -> Result<(), String>
    where
        DB::ErrorType: 'static,
    {
        let err = reason::<DB::ErrorType>;
        let mut chart = ChartBuilder::on(area)
            .caption(&self.caption, ("sans-serif", 15))
            .x_label_area_size(35)
            .y_label_area_size(45)
            .build_cartesian_2d(self.x.clone(), self.y.clone())
            .map_err(err)?;
        let cell = |range: &Range<f64>, i: u32| {
            let w = (range.end - range.start) / f64::from(KEY_CELLS);
            (
                range.start + w * f64::from(i),
                range.start + w * f64::from(i + 1),
            )
        };
        chart
            .draw_series((0..KEY_CELLS * KEY_CELLS).map(|i| {
                let ((x0, x1), (y0, y1)) =
                    (cell(&self.x, i % KEY_CELLS), cell(&self.y, i / KEY_CELLS));
                let colour = (self.colour_of)((x0 + x1) / 2.0, (y0 + y1) / 2.0);
                Rectangle::new([(x0, y0), (x1, y1)], colour.filled())
            }))
            .map_err(err)?;
        chart
            .configure_mesh()
            .disable_mesh()
            .x_labels(3)
            .y_labels(3)
            .x_desc(&self.axes.0)
            .y_desc(&self.axes.1)
            .label_style(("sans-serif", 12))
            .draw()
            .map_err(err)?;
        let r = dot_radius(self.marks.len()) - 2;
        chart
            .draw_series(
                self.marks
                    .iter()
                    .map(|&m| Circle::new(m, r, BLACK.stroke_width(1))),
            )
            .map_err(err)?;
        Ok(())
    }
}

/// x and y ranges of equal span, centred on the points, holding them all with a margin.
fn square_ranges(points: &[(f64, f64)]) -> (Range<f64>, Range<f64>) {
    let bounds = |v: &mut dyn Iterator<Item = f64>| {
        v.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| {
            (a.min(x), b.max(x))
        })
    };
    let (x0, x1) = bounds(&mut points.iter().map(|p| p.0).filter(|v| v.is_finite()));
    let (y0, y1) = bounds(&mut points.iter().map(|p| p.1).filter(|v| v.is_finite()));
    if !(x0 <= x1 && y0 <= y1) {
        return (-1.0..1.0, -1.0..1.0);
    }
    let half = ((x1 - x0).max(y1 - y0) * 0.55).max(1e-3);
    let (cx, cy) = ((x0 + x1) / 2.0, (y0 + y1) / 2.0);
    ((cx - half)..(cx + half), (cy - half)..(cy + half))
}

/// Whether the run's environment has embedding plots (the gridworlds).
pub(super) fn plots_embeddings(config: &TrainConfig) -> bool {
    matches!(config.env, EnvName::Gridworld | EnvName::GridworldDiscrete)
}

/// The scatters of a gridworld run's embeddings and the SVG paths they go to in the run
/// directory (none for other environments, or without an embedding).
pub(super) fn embedding_scatters(
    dir: &RunDir,
    config: &TrainConfig,
    embedding: Option<&Embedding>,
) -> Vec<(Scatter, PathBuf)> {
    let Some(embedding) = embedding.filter(|_| plots_embeddings(config)) else {
        return Vec::new();
    };
    let mut scatters = Vec::new();
    if let Some(table) = embedding
        .action_table()
        .filter(|_| embedding.action_dim() >= 2)
    {
        let scatter = action_scatter(config, embedding, &table);
        scatters.push((scatter, dir.action_embeddings_svg()));
    }
    if config.algo.representation().embeds_states() {
        scatters.push((state_scatter(config, embedding), dir.state_embeddings_svg()));
    }
    scatters
}

/// g(a) of every action, coloured by the displacement the action causes.
fn action_scatter(config: &TrainConfig, embedding: &Embedding, table: &[f32]) -> Scatter {
    let motions: Vec<(f64, f64)> = action_motions(config.environment.gridworld.actuators)
        .iter()
        .map(|m| (m[0], m[1]))
        .collect();
    let (points, axes) = principal_plane(table, embedding.action_dim());
    Scatter {
        title: format!(
            "action embeddings g(a) of embedding version {}",
            embedding.version()
        ),
        axes: (format!("g(a): {}", axes.0), format!("g(a): {}", axes.1)),
        points,
        colours: motions
            .iter()
            .map(|&(dx, dy)| displacement_colour(dx, dy))
            .collect(),
        key: ColourKey {
            caption: "colour = the action's displacement".into(),
            axes: ("dx".into(), "dy".into()),
            x: -1.0..1.0,
            y: -1.0..1.0,
            colour_of: displacement_colour,
            marks: motions,
            notes: vec![
                "red grows with dx, green with dy".into(),
                "rings: the actions' displacements".into(),
            ],
        },
    }
}

/// phi(s) of every cell centre, coloured by the cell's position.
fn state_scatter(config: &TrainConfig, embedding: &Embedding) -> Scatter {
    let (states, positions) = gridworld_cells(config);
    let mut phi = Vec::new();
    embedding.embed_states(&states, &mut phi);
    let (points, axes) = principal_plane(&phi, embedding.state_dim());
    Scatter {
        title: format!(
            "state embeddings phi(s) of the cell centres, embedding version {}",
            embedding.version()
        ),
        axes: (format!("phi(s): {}", axes.0), format!("phi(s): {}", axes.1)),
        points,
        colours: positions.iter().map(|p| unit_colour(p[0], p[1])).collect(),
        key: ColourKey {
            caption: "colour = the cell's position".into(),
            axes: ("x".into(), "y".into()),
            x: 0.0..1.0,
            y: 0.0..1.0,
            colour_of: unit_colour,
            marks: Vec::new(),
            notes: vec!["red grows with x, green with y".into()],
        },
    }
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

    #[test]
    fn square_ranges_have_equal_spans_around_the_points() {
        let (x, y) = square_ranges(&[(0.0, 10.0), (2.0, 11.0), (1.0, 10.5)]);
        assert!((x.end - x.start - (y.end - y.start)).abs() < 1e-12);
        assert!(x.start < 0.0 && x.end > 2.0 && y.start < 10.0 && y.end > 11.0);
        assert!(((x.start + x.end) / 2.0 - 1.0).abs() < 1e-12);
        assert_eq!(square_ranges(&[]), (-1.0..1.0, -1.0..1.0));
    }
}
