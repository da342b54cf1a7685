//! How far the embedder's next-item head alone goes: for each recommender run directory
//! (JSAE with `embedding.recommender.next_item_coef`), the run's latest embedding played as
//! a policy, recommending the item nearest to `h(phi(s))` (the head's most likely next item,
//! which the JSAE policy's mean starts at), under `recommender-baseline`'s protocol; and the
//! share of logged purchases it predicts (top 1), beside the greedy rule's.
//!
//!   cargo run --release -p jsae-research --example embedding_greedy -- RUN_DIR [RUN_DIR ...]

use std::collections::HashSet;

use anyhow::{Context, Result, bail};
use jsae_envs::recsys::RecommenderEnv;
use jsae_recommender::baseline::{Reference, returns};
use jsae_report::plot::load_latest_embedding;
use jsae_run_dir::RunDir;
use jsae_settings::{EnvName, TrainConfig};
use jsae_wire::{ActionBatch, StateBatch};

fn main() -> Result<()> {
    let runs: Vec<String> = std::env::args().skip(1).collect();
    if runs.is_empty() {
        bail!("usage: embedding_greedy RUN_DIR [RUN_DIR ...]");
    }
    for run in runs {
        let dir = RunDir::new(&run);
        let config = TrainConfig::from_layers(None, None, Some(&dir.config_toml()))?;
        if config.env != EnvName::Recommender || !config.embedding.recommender.next_item() {
            bail!("{run}: not a recommender run with the next-item head");
        }
        let mut embedding =
            load_latest_embedding(&dir, &config).context("no embedding checkpoint")??;
        let (m, d) = (config.embedding.state_dim, config.embedding.action_dim);
        let mut env = RecommenderEnv::new(&config.environment)?;
        let mut x = Vec::new();
        let mut pick = |history: &[u32]| -> u32 {
            let states = StateBatch::Categorical {
                factors: history.len(),
                data: history.to_vec(),
            };
            embedding.embed_states(&states, &mut x);
            let h: Vec<f32> = x[m..m + d].iter().map(|v| v.tanh()).collect();
            let mut out = ActionBatch::Discrete(Vec::new());
            embedding.decode(&h, &mut out);
            match out {
                ActionBatch::Discrete(a) => a[0],
                ActionBatch::Continuous { .. } => 0,
            }
        };
        let (states, next) = env.logged_steps();
        let StateBatch::Categorical { factors, data } = &states else {
            bail!("categorical states expected");
        };
        let model = env.model().clone();
        let (mut head_hits, mut rule_hits) = (0usize, 0usize);
        for (row, &bought) in data.chunks_exact(*factors).zip(&next) {
            head_hits += usize::from(pick(row) == bought);
            rule_hits += usize::from(Reference::MostLikely.best(&model, row) == bought);
        }
        // where the head and the rule part, in the states the head's own play visits: pairs
        // the logs hold against pairs they do not (whose hashed pair row another pair may own)
        let logged: HashSet<(u32, u32)> = data
            .chunks_exact(*factors)
            .map(|r| (r[factors - 2], r[factors - 1]))
            .collect();
        let mut agree = [(0usize, 0usize); 2]; // (agreements, states): unlogged, logged
        let r = returns(&mut env, 2000, config.eval_seed(), "", |env, _| {
            let h = env.history();
            let a = pick(h);
            let seen = usize::from(logged.contains(&(h[h.len() - 2], h[h.len() - 1])));
            agree[seen].1 += 1;
            agree[seen].0 += usize::from(Reference::MostLikely.best(&model, h) == a);
            a
        });
        let share = |(a, n): (usize, usize)| a as f64 / n.max(1) as f64;
        println!(
            "{run}: the head's nearest item returns {:.3} (std {:.3}, 2,000 episodes); top-1 on \
             the {} logged purchases: head {:.3}, greedy rule {:.3}",
            r.return_mean,
            r.return_std,
            next.len(),
            head_hits as f64 / next.len() as f64,
            rule_hits as f64 / next.len() as f64
        );
        println!(
            "  in its play the head recommends the rule's item in {:.3} of the {} states whose \
             pair the logs hold, {:.3} of the {} others",
            share(agree[1]),
            agree[1].1,
            share(agree[0]),
            agree[0].1
        );
    }
    Ok(())
}
