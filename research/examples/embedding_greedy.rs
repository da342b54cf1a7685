//! How far the embedder's next-item head alone goes: for each recommender run directory
//! (JSAE with `embedding.recommender.next_item_coef`), the run's latest embedding played as
//! a policy, recommending the item nearest to `h(phi(s))` (the head's most likely next item,
//! which the JSAE policy's mean starts at), under `recommender-baseline`'s protocol; and the
//! share of logged purchases it predicts (top 1), beside the greedy rule's. In the states its
//! play visits, it also names how often the head's item is the most likely item of the
//! estimate counted from the logs (`logged_targets = "counted-best"`'s target) and how often
//! that item is the rule's, and how often the head's item is the `lookahead` target (planned
//! at the simulator's lift).
//!
//!   cargo run --release -p jsae-research --example embedding_greedy -- RUN_DIR [RUN_DIR ...]

use std::collections::{HashMap, HashSet};

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
        // the counted estimate, as the embedder's logged pre-training counts it
        let logs = jsae_embedder::LoggedItems {
            states: states.clone(),
            items: next.clone(),
            catalogue: None,
        };
        let estimate = jsae_embedder::CountedEstimate::count(&logs, model.catalogue().len())
            .context("the counted estimate needs two-item states")?;
        let mut plan =
            jsae_embedder::LookaheadEstimate::count(&states, &next, model.catalogue().len())
                .context("the lookahead needs two-item states")?;
        plan.set_boost(config.environment.recommender.boost);
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
        // an unlogged pair's hashed row is zero unless a logged pair owns its bucket
        let buckets = config.embedding.recommender.pair_buckets.max(1);
        let items = model.catalogue().len() as u32 + 1; // each factor's slots, "none" included
        let bucket = |b: u32, l: u32| jsae_nn::pair_bucket(b, l + items, 0, buckets);
        let mut owners: HashMap<usize, usize> = HashMap::new();
        for &(b, l) in &logged {
            *owners.entry(bucket(b, l)).or_default() += 1;
        }
        // per kind of state (unlogged pairs whose bucket no logged pair owns, unlogged pairs
        // whose bucket one does, logged pairs alone in their bucket, logged pairs sharing it):
        // (agreements with the rule, states, expected reward lost to the rule's item)
        let mut agree = [(0usize, 0usize, 0.0f64); 4];
        // per kind: (the head's item is the counted best, the counted best is the rule's,
        // expected reward the counted best loses to the rule)
        let mut counted = [(0usize, 0usize, 0.0f64); 4];
        // per kind: the head's item is the lookahead target
        let mut planned = [0usize; 4];
        let r = returns(&mut env, 2000, config.eval_seed(), "", |env, _| {
            let h = env.history();
            let a = pick(h);
            let (b, l) = (h[h.len() - 2], h[h.len() - 1]);
            let sharing = owners.get(&bucket(b, l)).copied().unwrap_or(0);
            let kind = match (logged.contains(&(b, l)), sharing) {
                (true, 1) => 2,
                (true, _) => 3,
                (false, 0) => 0,
                (false, _) => 1,
            };
            let rule = Reference::MostLikely.best(&model, h);
            let expected = model.expected_rewards(b, l);
            agree[kind].0 += usize::from(rule == a);
            agree[kind].1 += 1;
            agree[kind].2 += expected[rule as usize] - expected[a as usize];
            let best = estimate.best_item(h);
            counted[kind].0 += usize::from(best == a);
            counted[kind].1 += usize::from(best == rule);
            counted[kind].2 += expected[rule as usize] - expected[best as usize];
            planned[kind] += usize::from(plan.target(h) == a);
            a
        });
        let share = |(a, n, _): (usize, usize, f64)| a as f64 / n.max(1) as f64;
        println!(
            "{run}: the head's nearest item returns {:.3} (std {:.3}, 2,000 episodes); top-1 on \
             the {} logged purchases: head {:.3}, greedy rule {:.3}",
            r.return_mean,
            r.return_std,
            next.len(),
            head_hits as f64 / next.len() as f64,
            rule_hits as f64 / next.len() as f64
        );
        for (kind, name) in [
            (2, "whose pair the logs hold, its row its own"),
            (
                3,
                "whose pair the logs hold, its row shared with another logged pair",
            ),
            (0, "whose pair they do not, its row zero"),
            (1, "whose pair they do not, its row another pair's"),
        ] {
            println!(
                "  states {name}: {} ({:.3} of its play), the rule's item in {:.3}, expected \
                 reward lost to the rule {:.3} an episode",
                agree[kind].1,
                agree[kind].1 as f64 / agree.iter().map(|k| k.1).sum::<usize>().max(1) as f64,
                share(agree[kind]),
                agree[kind].2 / 2000.0
            );
            let states = agree[kind].1.max(1) as f64;
            println!(
                "    the counted estimate's best item: the head's in {:.3}, the rule's in {:.3}, \
                 expected reward it loses to the rule {:.3} an episode; the lookahead target: \
                 the head's in {:.3}",
                counted[kind].0 as f64 / states,
                counted[kind].1 as f64 / states,
                counted[kind].2 / 2000.0,
                planned[kind] as f64 / states
            );
        }
    }
    Ok(())
}
