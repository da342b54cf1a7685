//! Why the paper's JSAE stays at random play on the recommender: what the embedder's data
//! can teach g under random play (the pre-training it gets), measured.
//!
//! Without a run: `STEPS` random-play steps of the default recommender (seed `SEED`), as the
//! embedder's pre-training collects them:
//! - accepted transitions (the recommended item bought), in all and per action, and the
//!   actions never seen accepted;
//! - the information the action carries about the next state, exactly from the model: at
//!   every 100th visited state `s`, `I(A; S' | s) = mean_a KL(P(.|s,a) || mean_a' P(.|s,a'))`
//!   over uniformly random actions (the next state differs from `s` only in the item
//!   bought), beside the entropy `H(S' | s)` that T's loss is made of.
//!
//! With runs: for each run directory, T's model loss on fresh random-play transitions with
//! the run's latest g, with g's rows permuted (three permutations: which action is which is
//! forgotten), and with every action given the mean of g (no action at all); then the
//! policy's log-std and entropy over the run (metrics.csv).
//!
//!   cargo run --release -p jsae-research --example recommender_cause -- [SEED] [STEPS] [RUN_DIR ...]

use anyhow::{Context, Result, bail};
use burn::module::Param;
use jsae_agent::EmbeddingModel;
use jsae_embedder::EmbeddingTraining;
use jsae_envs::recsys::RecommenderEnv;
use jsae_envs::{ActionRef, Env};
use jsae_nn as nn;
use jsae_report::plot::load_latest_embedding;
use jsae_run_dir::RunDir;
use jsae_settings::{Algo, EnvName, TrainConfig};
use jsae_wire::{ActionBatch, StateBatch};
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Random-play transitions: states, the recommended items, next states (history 2).
struct Transitions {
    states: Vec<u32>,
    actions: Vec<u32>,
    next: Vec<u32>,
}

fn main() -> Result<()> {
    let mut args = std::env::args().skip(1);
    let seed: u64 = args.next().map_or(Ok(2001), |s| s.parse())?;
    let steps: usize = args.next().map_or(Ok(100_000), |s| s.parse())?;
    let runs: Vec<String> = args.collect();
    let mut config = TrainConfig::defaults(EnvName::Recommender, Algo::Jsae);
    config.seed = seed;
    let boost = config.environment.recommender.boost;
    let mut env = RecommenderEnv::new(&config.environment)?;
    let n = env.model().catalogue().len();
    let (t, info) = random_play(&mut env, n, steps, seed, boost);
    let mut accepted = vec![0u32; n];
    for (a, s1) in t.actions.iter().zip(t.next.chunks_exact(2)) {
        if *a == s1[1] {
            accepted[*a as usize] += 1;
        }
    }
    let total: u32 = accepted.iter().sum();
    let never = accepted.iter().filter(|&&c| c == 0).count();
    let mut sorted = accepted.clone();
    sorted.sort_unstable();
    println!(
        "random play, {steps} steps (seed {seed}): {total} accepted recommendations ({:.2}% of \
         steps), {:.2} per action (median {}, max {}); {never} of {n} actions never seen accepted",
        100.0 * f64::from(total) / steps as f64,
        f64::from(total) / n as f64,
        sorted[n / 2],
        sorted[n - 1],
    );
    println!(
        "information the action carries about the next state: {:.5} nats per transition \
         (mean over {} visited states; H(S'|s) = {:.3} nats, so {:.3}% of it)",
        info.0,
        info.2,
        info.1,
        100.0 * info.0 / info.1
    );
    for run in runs {
        t_against_permuted(&run, &t, seed)?;
        policy_over_run(&run)?;
    }
    Ok(())
}

/// Plays `steps` uniformly random recommendations; returns the transitions and (mean
/// I(A; S'|s), mean H(S'|s), states measured).
fn random_play(
    env: &mut RecommenderEnv,
    n: usize,
    steps: usize,
    seed: u64,
    boost: f64,
) -> (Transitions, (f64, f64, usize)) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut t = Transitions {
        states: Vec::with_capacity(2 * steps),
        actions: Vec::with_capacity(steps),
        next: Vec::with_capacity(2 * steps),
    };
    let (mut info, mut entropy, mut measured) = (0.0, 0.0, 0usize);
    env.reset(&mut rng);
    for step in 0..steps {
        let h = env.history().to_vec();
        if step % 100 == 0 {
            let (i, e) = action_information(env, &h, n, boost);
            info += i;
            entropy += e;
            measured += 1;
        }
        let a = rng.random_range(0..n as u32);
        let out = env.step(ActionRef::Discrete(a));
        t.states.extend_from_slice(&h);
        t.actions.push(a);
        t.next.extend_from_slice(env.history());
        if out.terminated || out.truncated {
            env.reset(&mut rng);
        }
    }
    let m = measured.max(1) as f64;
    (t, (info / m, entropy / m, measured))
}

/// `I(A; S' | s)` for a uniformly random recommendation and `H(S' | s)`, exactly from the
/// model (nats).
fn action_information(env: &RecommenderEnv, h: &[u32], n: usize, boost: f64) -> (f64, f64) {
    let model = env.model();
    let (before, last) = (h[h.len() - 2], h[h.len() - 1]);
    let p: Vec<f64> = (0..n as u32)
        .map(|b| model.probability(before, last, b))
        .collect();
    let z: Vec<f64> = p.iter().map(|&pa| 1.0 + (boost - 1.0) * pa).collect();
    let mean_inv_z = z.iter().map(|z| 1.0 / z).sum::<f64>() / n as f64;
    // the mixture over actions: P(b) = p_b mean_a(1/z_a) + (boost - 1) p_b / (n z_b)
    let mix: Vec<f64> = (0..n)
        .map(|b| p[b] * mean_inv_z + (boost - 1.0) * p[b] / (n as f64 * z[b]))
        .collect();
    let mut info = 0.0;
    for (a, za) in z.iter().enumerate() {
        for b in 0..n {
            let q = if a == b { boost * p[b] } else { p[b] } / za;
            if q > 0.0 {
                info += q * (q / mix[b]).ln();
            }
        }
    }
    let entropy = -mix
        .iter()
        .filter(|&&q| q > 0.0)
        .map(|&q| q * q.ln())
        .sum::<f64>();
    (info / n as f64, entropy)
}

/// T's model loss on `t` with the run's g, with g's rows permuted and with the mean g.
fn t_against_permuted(run: &str, t: &Transitions, seed: u64) -> Result<()> {
    let dir = RunDir::new(run);
    let config = TrainConfig::from_layers(None, None, Some(&dir.config_toml()))?;
    if config.env != EnvName::Recommender || config.algo != Algo::Jsae {
        bail!("{run}: not a JSAE recommender run");
    }
    let embedding = load_latest_embedding(&dir, &config)
        .context("no embedding checkpoint")?
        .with_context(|| format!("{run}: the embedding checkpoint does not load"))?;
    let model = embedding.model().clone();
    let loss = |m: &EmbeddingModel| -> f64 {
        // minibatches of 4,096 (the loss is a mean)
        let (mut sum, mut count) = (0.0, 0usize);
        for start in (0..t.actions.len()).step_by(4096) {
            let end = (start + 4096).min(t.actions.len());
            let states = StateBatch::Categorical {
                factors: 2,
                data: t.states[2 * start..2 * end].to_vec(),
            };
            let next = StateBatch::Categorical {
                factors: 2,
                data: t.next[2 * start..2 * end].to_vec(),
            };
            let actions = ActionBatch::Discrete(t.actions[start..end].to_vec());
            let (l, _) = m.losses(&states, &actions, &next);
            sum += f64::from(nn::to_vec(l)[0]) * (end - start) as f64;
            count += end - start;
        }
        sum / count as f64
    };
    let table = model.net().g_table.as_ref().context("no g table")?.val();
    let [rows, d] = table.dims();
    let raw = nn::to_vec(table);
    let with_table = |values: Vec<f32>| {
        let mut m = model.clone();
        m.net_mut().g_table = Some(Param::from_tensor(nn::tensor2(
            values,
            rows,
            d,
            model.device(),
        )));
        m
    };
    let learned = loss(&model);
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x9e37);
    let permuted: Vec<f64> = (0..3)
        .map(|_| {
            let mut order: Vec<usize> = (0..rows).collect();
            order.shuffle(&mut rng);
            let values = order
                .iter()
                .flat_map(|&r| raw[r * d..(r + 1) * d].iter().copied())
                .collect();
            loss(&with_table(values))
        })
        .collect();
    let mean: Vec<f32> = (0..d)
        .map(|j| raw.iter().skip(j).step_by(d).sum::<f32>() / rows as f32)
        .collect();
    let blind = loss(&with_table(mean.repeat(rows)));
    println!(
        "{run}: T's loss on {} random-play transitions: learned g {learned:.4}, g's rows \
         permuted {} (differences {}), the mean g for every action {blind:.4} (+{:.4}) nats",
        t.actions.len(),
        permuted
            .iter()
            .map(|l| format!("{l:.4}"))
            .collect::<Vec<_>>()
            .join(", "),
        permuted
            .iter()
            .map(|l| format!("{:+.4}", l - learned))
            .collect::<Vec<_>>()
            .join(", "),
        blind - learned
    );
    Ok(())
}

/// The policy's log-std and entropy at six points of the run (metrics.csv).
fn policy_over_run(run: &str) -> Result<()> {
    let path = RunDir::new(run).metrics_csv();
    let text = std::fs::read_to_string(&path).with_context(|| format!("{}", path.display()))?;
    let mut lines = text.lines();
    let header: Vec<&str> = lines
        .next()
        .context("empty metrics.csv")?
        .split(',')
        .collect();
    let col = |name: &str| header.iter().position(|h| *h == name);
    let (Some(steps), Some(ls), Some(ent)) =
        (col("env_steps"), col("log_std_mean"), col("entropy"))
    else {
        bail!(
            "{}: no env_steps, log_std_mean or entropy column",
            path.display()
        );
    };
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    if rows.is_empty() {
        bail!("{}: no updates", path.display());
    }
    let points: Vec<String> = (0..6)
        .map(|i| {
            let r = &rows[(i * (rows.len() - 1)) / 5];
            format!(
                "{} steps: log-std {}, entropy {}",
                r[steps],
                short(r[ls]),
                short(r[ent])
            )
        })
        .collect();
    println!("{run}: the policy over the run: {}", points.join("; "));
    Ok(())
}

fn short(v: &str) -> String {
    v.parse::<f64>()
        .map_or(v.to_string(), |x| format!("{x:.2}"))
}
