//! Whether a recommender run's action embedding g places items bought in similar contexts
//! close together. An item's context is the distribution of the purchases right before it in
//! the training sessions (the held-out ones excluded, as the model excludes them); two items'
//! context similarity is the cosine of those count vectors. For every item bought at least
//! `MIN_COUNT` times: the context similarity with its nearest item in g, against the mean
//! over all pairs of such items (what an embedding without that structure gives). Also g's
//! spread per dimension.
//!
//!   cargo run --release -p jsae-research --example recommender_structure -- RUN_DIR [RUN_DIR ...]

use anyhow::{Context, Result, bail};
use jsae_envs::recsys::data::{load_sessions, split_sessions};
use jsae_envs::recsys::model_handle;
use jsae_report::plot::load_latest_embedding;
use jsae_run_dir::RunDir;
use jsae_settings::{EnvName, TrainConfig};
use jsae_wire::ActionBatch;
use std::collections::HashMap;

const MIN_COUNT: u32 = 5;

fn main() -> Result<()> {
    let runs: Vec<String> = std::env::args().skip(1).collect();
    if runs.is_empty() {
        bail!("usage: recommender_structure RUN_DIR [RUN_DIR ...]");
    }
    for run in runs {
        println!("{run}: {}", structure(&run)?);
    }
    Ok(())
}

fn structure(run: &str) -> Result<String> {
    let dir = RunDir::new(run);
    let config = TrainConfig::from_layers(None, None, Some(&dir.config_toml()))?;
    if config.env != EnvName::Recommender {
        bail!("{run}: not a recommender run");
    }
    let mut r = config.environment.recommender.clone();
    r.store_dir = Default::default();
    let model = model_handle(&r)?.current();
    let catalogue = model.catalogue();
    let n = catalogue.len();

    // predecessor counts of every catalogue item in the training sessions
    let (train, _) = split_sessions(load_sessions(&r)?, &r);
    let mut before: Vec<HashMap<u32, f64>> = vec![HashMap::new(); n];
    let mut count = vec![0u32; n];
    for s in &train {
        let slots: Vec<u32> = s
            .purchases
            .iter()
            .filter_map(|p| catalogue.slot(&p.item_id))
            .collect();
        for w in slots.windows(2) {
            *before[w[1] as usize].entry(w[0]).or_insert(0.0) += 1.0;
            count[w[1] as usize] += 1;
        }
    }
    let norm: Vec<f64> = before
        .iter()
        .map(|m| m.values().map(|c| c * c).sum::<f64>().sqrt())
        .collect();
    let cosine = |i: usize, j: usize| -> f64 {
        if norm[i] == 0.0 || norm[j] == 0.0 {
            return 0.0;
        }
        let dot: f64 = before[i]
            .iter()
            .map(|(k, c)| c * before[j].get(k).copied().unwrap_or(0.0))
            .sum();
        dot / (norm[i] * norm[j])
    };
    let kept: Vec<usize> = (0..n).filter(|&i| count[i] >= MIN_COUNT).collect();

    let embedding = load_latest_embedding(&dir, &config)
        .with_context(|| format!("{run}: no embedding checkpoint"))??;
    let batch = ActionBatch::Discrete((0..n as u32).collect());
    let g = jsae_nn::to_vec(embedding.model().embed_actions(&batch));
    let d = g.len() / n.max(1);
    let dist = |i: usize, j: usize| -> f32 {
        (0..d)
            .map(|k| (g[i * d + k] - g[j * d + k]).powi(2))
            .sum::<f32>()
    };
    let (mut near, mut all, mut pairs) = (0.0, 0.0, 0usize);
    for &i in &kept {
        let nearest = kept
            .iter()
            .copied()
            .filter(|&j| j != i)
            .min_by(|&a, &b| dist(i, a).total_cmp(&dist(i, b)))
            .unwrap_or(i);
        near += cosine(i, nearest);
        for &j in &kept {
            if j != i {
                all += cosine(i, j);
                pairs += 1;
            }
        }
    }
    let near = near / kept.len().max(1) as f64;
    let all = all / pairs.max(1) as f64;
    let spread: Vec<String> = (0..d)
        .map(|k| {
            let v: Vec<f64> = (0..n).map(|i| f64::from(g[i * d + k])).collect();
            let mean = v.iter().sum::<f64>() / n as f64;
            let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n as f64;
            format!("{:.3}", var.sqrt())
        })
        .collect();
    Ok(format!(
        "{} items bought >= {MIN_COUNT} times; context similarity with the nearest item in g \
         {near:.4}, over all pairs {all:.4} (ratio {:.2}); g's std per dimension [{}]",
        kept.len(),
        near / all.max(1e-12),
        spread.join(", ")
    ))
}
