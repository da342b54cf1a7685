//! How a continuous-action run's embedding space E relates to the torque box [-1, 1]^n:
//! the spread of g over the box, f's reconstruction error on g(a), f's gain near g(box) (how
//! far the torques move per unit step in E: a std s in E acts as about gain x s in torques),
//! and where f sends points spread uniformly over E (where the internal policy's Gaussian
//! samples).
//!
//!   cargo run --release -p jsae-research --example action_box_coverage -- RUN_DIR [RUN_DIR ...]
//!
//! Reads each run's config.toml and newest embedding checkpoint; 20,000 samples, fixed seed.

use anyhow::{Context, Result, bail};
use jsae_agent::Embedding;
use jsae_report::plot::load_latest_embedding;
use jsae_run_dir::RunDir;
use jsae_settings::TrainConfig;
use jsae_wire::{ActionBatch, ActionSpace};
use rand::{Rng, SeedableRng};

const SAMPLES: usize = 20_000;
const SEED: u64 = 7;
const NUDGE: f32 = 0.01;

fn main() -> Result<()> {
    let runs: Vec<String> = std::env::args().skip(1).collect();
    if runs.is_empty() {
        bail!("usage: action_box_coverage RUN_DIR [RUN_DIR ...]");
    }
    for run in runs {
        println!("{run}: {}", coverage(&run)?);
    }
    Ok(())
}

fn coverage(run: &str) -> Result<String> {
    let dir = RunDir::new(run);
    let config = TrainConfig::from_layers(None, None, Some(&dir.config_toml()))?;
    let ActionSpace::Continuous { dim, .. } = config.spaces().1 else {
        bail!("{run}: not a continuous-action run");
    };
    let mut embedding = load_latest_embedding(&dir, &config)
        .with_context(|| format!("{run}: no embedding checkpoint"))??;
    let e_dim = embedding.action_dim();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(SEED);
    let mut uniform =
        |n: usize| -> Vec<f32> { (0..n).map(|_| rng.random_range(-1.0f32..=1.0)).collect() };

    let box_actions = uniform(SAMPLES * dim);
    let batch = ActionBatch::Continuous {
        dim,
        data: box_actions.clone(),
    };
    let embedded = jsae_nn::to_vec(embedding.model().embed_actions(&batch));
    let spread: Vec<String> = (0..e_dim)
        .map(|k| {
            format!(
                "{:.2}",
                std_dev((0..SAMPLES).map(|i| embedded[i * e_dim + k]))
            )
        })
        .collect();
    let max_abs = embedded.iter().fold(0f32, |m, x| m.max(x.abs()));

    let rebuilt = decode(&mut embedding, &embedded, dim);
    let mse = box_actions
        .iter()
        .zip(&rebuilt)
        .map(|(a, b)| (a - b).powi(2))
        .sum::<f32>()
        / rebuilt.len() as f32;

    // f's gain near g(box): RMS torque change per RMS step in E, for steps of 0.01 per dim.
    let nudged: Vec<f32> = embedded
        .iter()
        .zip(uniform(embedded.len()))
        .map(|(e, u)| e + NUDGE * u.signum())
        .collect();
    let moved = decode(&mut embedding, &nudged, dim);
    let gain = rms(moved.iter().zip(&rebuilt).map(|(a, b)| a - b)) / NUDGE;

    let decoded = decode(&mut embedding, &uniform(SAMPLES * e_dim), dim);
    let outside = decoded.iter().filter(|x| x.abs() > 1.0).count() as f32 / decoded.len() as f32;
    Ok(format!(
        "std of g over the box per dim [{}] (uniform box: 0.58), max |g| {max_abs:.2}; \
         f(g(a)) mse {mse:.4}; gain of f near g(box) {gain:.2}; f(uniform E): {:.0}% of torques outside the box",
        spread.join(", "),
        outside * 100.0
    ))
}

fn decode(embedding: &mut Embedding, points: &[f32], dim: usize) -> Vec<f32> {
    let mut out = ActionBatch::Continuous {
        dim,
        data: Vec::new(),
    };
    embedding.decode(points, &mut out);
    match out {
        ActionBatch::Continuous { data, .. } => data,
        ActionBatch::Discrete(_) => unreachable!("a continuous action space decodes to torques"),
    }
}

fn rms(xs: impl Iterator<Item = f32>) -> f32 {
    let (sum, n) = xs.fold((0.0, 0usize), |(s, n), x| (s + x * x, n + 1));
    (sum / n as f32).sqrt()
}

fn std_dev(xs: impl Iterator<Item = f32> + Clone) -> f32 {
    let n = xs.clone().count() as f32;
    let mean = xs.clone().sum::<f32>() / n;
    (xs.map(|x| (x - mean).powi(2)).sum::<f32>() / n).sqrt()
}
