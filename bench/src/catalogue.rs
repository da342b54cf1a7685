//! `jsae bench --catalogue [--items LIST] [--json]`: the recommender at catalogue scale, one
//! row per size: the generated catalogue's sessions (`jsae_envs::recsys::large_catalogue`),
//! the `jsae recommender` process serving it at a fixed load (`catalogue_serving`), f over
//! its items, the approximate index (build time, recall@10 against the exact scan, search
//! latency) beside the exact scan measured in the same run, one thread each, PPO's
//! categorical head and the embedder's step (`catalogue_embedder`).
//!
//! The item embeddings are a stand-in until the embedder trains at these sizes: each item at
//! its category's centre plus noise (a trained g groups items bought together, which the
//! generator keeps mostly within categories). The rows say so (`embeddings`).

use std::time::Instant;

use jsae_action_index::{
    ApproxNearest, ApproxSettings, NearestAction, calibration_queries, recall,
};
use jsae_envs::recsys::large_catalogue::{
    LargeCatalogue, LargeCatalogueConfig, OTTO_EVENTS, OTTO_ITEMS, OTTO_SESSIONS,
};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use serde::Serialize;

use crate::recommender::percentile;

/// Width of the action embedding (the recommender JSAE's default `action_dim`).
pub const EMBEDDING_DIM: usize = 64;
/// Items asked for per recommendation.
const K: usize = 10;

/// One catalogue size's measurements.
#[derive(Debug, Clone, Serialize)]
pub struct CatalogueRow {
    /// Items in the catalogue.
    pub items: u64,
    /// Sessions generated.
    pub sessions: u64,
    /// Purchases over all sessions.
    pub events: u64,
    /// Mean purchases per session.
    pub events_per_session: f64,
    /// Share of consecutive purchases within one category.
    pub same_category_share: f64,
    /// Share of purchases going to the top 1% of items.
    pub top_1pct_share: f64,
    /// Seconds to generate and count every session.
    pub generate_s: f64,
    /// Where the item embeddings came from.
    pub embeddings: &'static str,
    /// Seconds to build the approximate index (threads: the machine's cores), calibration
    /// included.
    pub ann_build_s: f64,
    /// Search width the calibration chose.
    pub ann_expansion_search: usize,
    /// Recall@10 against the exact scan, on queries the calibration did not see.
    pub recall_at_10: f64,
    /// Top-10 search in the index, one thread: median and 99th percentile, milliseconds.
    pub ann_p50_ms: f64,
    /// See `ann_p50_ms`.
    pub ann_p99_ms: f64,
    /// The exact top-10 scan, one thread, the same queries: median, milliseconds.
    pub exact_p50_ms: f64,
    /// See `exact_p50_ms`.
    pub exact_p99_ms: f64,
    /// Bytes the index holds, MiB.
    pub ann_mib: f64,
    /// This bench's resident memory with the index, the exact scan's table and the
    /// embeddings held, MiB.
    pub bench_rss_mib: f64,
    /// The `jsae recommender` process serving a JSAE policy over the catalogue
    /// (`catalogue_serving`): seconds from its start to its first answer.
    pub recommender_load_s: f64,
    /// Requests a second offered to it, open loop, over loopback gRPC.
    pub offered_rps: f64,
    /// Requests answered, of those offered.
    pub recommend_answered: usize,
    /// See `recommend_answered`.
    pub recommend_sent: usize,
    /// `Recommend` latency at that load: median, milliseconds.
    pub recommend_p50_ms: f64,
    /// See `recommend_p50_ms`: 99th percentile.
    pub recommend_p99_ms: f64,
    /// The Recommender process's peak resident memory through its start and the load, MiB.
    pub rss_mib: f64,
    /// Its resident memory at the end of the load (serving, nothing being loaded), MiB.
    pub serving_rss_mib: f64,
    /// Seconds until a new embedding written to its run directory answered, under the load.
    pub swap_s: f64,
    /// `Recommend` latency meanwhile: median and 99th percentile, milliseconds.
    pub swap_p50_ms: f64,
    /// See `swap_p50_ms`.
    pub swap_p99_ms: f64,
    /// The Recommender's peak resident memory through the swap (two embeddings held), MiB.
    pub swap_rss_mib: f64,
    /// Whether it refused an embedding of another catalogue and kept the one in use.
    pub refused_other_catalogue: bool,
    /// JSAE's environment steps a second in training at this size, on the acting side: one
    /// actor's environments stepped by one thread, each step phi, the policy and f through
    /// the index (`catalogue_acting`; `docs/src/recommender/catalogue-scale.md` has whole
    /// runs).
    pub train_env_steps_per_s: f64,
    /// PPO with a categorical head over every item (64-wide input, the default hidden
    /// layers, fused update): milliseconds per update of 2,048 samples.
    pub ppo_categorical_update_ms: f64,
    /// Resident memory that PPO learner added, MiB.
    pub ppo_categorical_mib: f64,
    /// The recommender JSAE embedder's minibatch step (4,096 transitions from the
    /// sessions), milliseconds.
    pub embedder_step_ms: f64,
    /// Which step: `sampled` (catalogue scale, `embedding.sampled_softmax_from`) or `dense`.
    pub embedder_step: &'static str,
    /// Resident memory the embedder's trainer added, MiB.
    pub embedder_mib: f64,
    /// Its model loss at the first step and the last timed one (nats).
    pub embedder_loss_first: f32,
    /// See `embedder_loss_first`.
    pub embedder_loss_last: f32,
}

/// Samples per PPO update measured (one actor's rollout).
const PPO_BATCH: usize = 2_048;

/// Times one PPO update (after an untimed one, except from a million items, where one
/// takes minutes) of a categorical head over `items` actions on a 64-wide input: the
/// head alone (plain PPO on the recommender reads a one-hot input of `2 (items + 1)` more).
/// Returns milliseconds per update and the resident memory added, MiB.
pub fn ppo_categorical(items: usize) -> (f64, f64) {
    let ppo = jsae_settings::PpoConfig {
        batch_steps: PPO_BATCH,
        ..jsae_settings::PpoConfig::default()
    };
    let before = crate::recommender::rss_mib();
    let (s, _) = crate::learner::time_updates(
        &ppo,
        EMBEDDING_DIM,
        jsae_agent::PolicyHead::Categorical { n: items },
        None,
        PPO_BATCH,
        1,
        items < 1_000_000,
    );
    (s * 1e3, crate::recommender::rss_mib() - before)
}

/// Item embeddings standing in for a trained g: category centres `N(0, 1)`, items around
/// them with noise `N(0, 0.35^2)` per component.
pub fn stand_in_embeddings(catalogue: &LargeCatalogue, d: usize, seed: u64) -> Vec<f32> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let unit = Normal::new(0.0f32, 1.0).expect("a valid normal");
    let centres: Vec<f32> = (0..catalogue.categories() * d)
        .map(|_| unit.sample(&mut rng))
        .collect();
    let mut table = Vec::with_capacity(catalogue.items() * d);
    for item in 0..catalogue.items() as u32 {
        let c = catalogue.category(item) as usize;
        for j in 0..d {
            table.push(centres[c * d + j] + 0.35 * unit.sample(&mut rng));
        }
    }
    table
}

/// Median and 99th percentile of `f` over `queries`, milliseconds.
fn time_each(queries: &[f32], d: usize, mut f: impl FnMut(&[f32])) -> (f64, f64) {
    let mut ms: Vec<f64> = queries
        .chunks_exact(d)
        .map(|q| {
            let t = Instant::now();
            f(q);
            t.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    ms.sort_by(f64::total_cmp);
    (percentile(&ms, 0.5), percentile(&ms, 0.99))
}

/// Measures one catalogue size.
pub fn measure(items: u32, quick: bool) -> anyhow::Result<CatalogueRow> {
    let config = LargeCatalogueConfig {
        items,
        ..LargeCatalogueConfig::default()
    };
    let serving = crate::catalogue_serving::measure(items, if quick { 2.0 } else { 10.0 })?;
    let t = Instant::now();
    let catalogue = LargeCatalogue::new(&config).map_err(anyhow::Error::msg)?;
    let stats = catalogue.stats();
    let generate_s = t.elapsed().as_secs_f64();
    let table = stand_in_embeddings(&catalogue, EMBEDDING_DIM, config.seed);
    let settings = ApproxSettings::default();
    let t = Instant::now();
    let approx = ApproxNearest::build(&table, EMBEDDING_DIM, &settings)?;
    let ann_build_s = t.elapsed().as_secs_f64();
    let exact = NearestAction::new(&table, EMBEDDING_DIM);
    let queries = calibration_queries(
        &table,
        EMBEDDING_DIM,
        &ApproxSettings {
            seed: 2,
            calibration_queries: if quick { 100 } else { 1_000 },
            ..settings
        },
    );
    let n = catalogue.items();
    let (mut wanted, mut got) = (Vec::new(), Vec::new());
    let (exact_p50_ms, exact_p99_ms) = time_each(&queries, EMBEDDING_DIM, |q| {
        wanted.push(exact.k_nearest(q, K, n));
    });
    let (ann_p50_ms, ann_p99_ms) = time_each(&queries, EMBEDDING_DIM, |q| {
        got.push(approx.k_nearest(q, K, n));
    });
    let (ann_expansion_search, ann_mib, bench_rss_mib) = (
        approx.expansion_search(),
        approx.memory_bytes() as f64 / 1_048_576.0,
        crate::recommender::rss_mib(),
    );
    drop((approx, exact, table));
    let (ppo_categorical_update_ms, ppo_categorical_mib) = ppo_categorical(n);
    let embedder = crate::catalogue_embedder::embedder_steps(&catalogue);
    // last: the n-gram model the environments need stays in this process's memory
    let train_env_steps_per_s =
        crate::catalogue_acting::env_steps_per_s(items, if quick { 1.0 } else { 10.0 })?;
    let recall_at_10 = got
        .iter()
        .zip(&wanted)
        .map(|(g, w)| recall(g, w))
        .sum::<f64>()
        / wanted.len() as f64;
    Ok(CatalogueRow {
        items: stats.items,
        sessions: stats.sessions,
        events: stats.events,
        events_per_session: stats.events_per_session,
        same_category_share: stats.same_category_share,
        top_1pct_share: stats.top_1pct_share,
        generate_s,
        embeddings: "category stand-in",
        ann_build_s,
        ann_expansion_search,
        recall_at_10,
        ann_p50_ms,
        ann_p99_ms,
        exact_p50_ms,
        exact_p99_ms,
        ann_mib,
        bench_rss_mib,
        recommender_load_s: serving.load_s,
        offered_rps: serving.offered_rps,
        recommend_answered: serving.answered,
        recommend_sent: serving.sent,
        recommend_p50_ms: serving.p50_ms,
        recommend_p99_ms: serving.p99_ms,
        rss_mib: serving.rss_mib,
        serving_rss_mib: serving.serving_rss_mib,
        swap_s: serving.swap_s,
        swap_p50_ms: serving.swap_p50_ms,
        swap_p99_ms: serving.swap_p99_ms,
        swap_rss_mib: serving.swap_rss_mib,
        refused_other_catalogue: serving.refused_other_catalogue,
        train_env_steps_per_s,
        ppo_categorical_update_ms,
        ppo_categorical_mib,
        embedder_step_ms: embedder.step_ms,
        embedder_step: if embedder.sampled { "sampled" } else { "dense" },
        embedder_mib: embedder.mib,
        embedder_loss_first: embedder.loss.0,
        embedder_loss_last: embedder.loss.1,
    })
}

/// The default sizes.
pub const DEFAULT_ITEMS: [u32; 3] = [10_000, 100_000, 1_000_000];

/// Runs the sizes, printing a row as each is measured: a table, or with `json` one object
/// per line.
pub fn run(items: &[u32], json: bool, quick: bool) -> anyhow::Result<()> {
    if !json {
        println!(
            "OTTO (train, as published): {OTTO_ITEMS} items, {OTTO_SESSIONS} sessions, {:.1} events a session, {:.2} sessions an item",
            OTTO_EVENTS as f64 / OTTO_SESSIONS as f64,
            OTTO_SESSIONS as f64 / OTTO_ITEMS as f64
        );
        println!(
            "{:>9} {:>9} {:>10} {:>7} {:>6} {:>6} {:>7} {:>8} {:>5} {:>7} {:>8} {:>8} {:>8} {:>8} {:>7} {:>9} {:>7} {:>8} {:>8}",
            "items",
            "sessions",
            "events",
            "ev/ses",
            "same",
            "top1%",
            "gen s",
            "ann s",
            "ef",
            "recall",
            "ann p50",
            "ann p99",
            "scan p50",
            "scan p99",
            "bnch MiB",
            "ppo ms",
            "ppo MiB",
            "emb ms",
            "emb MiB"
        );
    }
    for &n in items {
        let row = measure(n, quick)?;
        if json {
            println!("{}", serde_json::to_string(&row)?);
        } else {
            println!(
                "{:>9} {:>9} {:>10} {:>7.2} {:>6.3} {:>6.3} {:>7.1} {:>8.1} {:>5} {:>7.3} {:>8.3} {:>8.3} {:>8.3} {:>8.3} {:>7.0} {:>9.0} {:>7.0} {:>8.0} {:>8.0}",
                row.items,
                row.sessions,
                row.events,
                row.events_per_session,
                row.same_category_share,
                row.top_1pct_share,
                row.generate_s,
                row.ann_build_s,
                row.ann_expansion_search,
                row.recall_at_10,
                row.ann_p50_ms,
                row.ann_p99_ms,
                row.exact_p50_ms,
                row.exact_p99_ms,
                row.bench_rss_mib,
                row.ppo_categorical_update_ms,
                row.ppo_categorical_mib,
                row.embedder_step_ms,
                row.embedder_mib
            );
            println!(
                "{:>9} jsae recommender: first answer after {:.1} s; {:.0} requests/s offered, {} of {} answered, p50 {:.3} ms, p99 {:.3} ms, peak RSS {:.0} MiB ({:.0} MiB serving); a new embedding answered after {:.1} s under the load, p50 {:.3} ms, p99 {:.3} ms meanwhile, peak RSS {:.0} MiB; another catalogue's embedding refused: {}; JSAE's acting: {:.0} env steps/s",
                "",
                row.recommender_load_s,
                row.offered_rps,
                row.recommend_answered,
                row.recommend_sent,
                row.recommend_p50_ms,
                row.recommend_p99_ms,
                row.rss_mib,
                row.serving_rss_mib,
                row.swap_s,
                row.swap_p50_ms,
                row.swap_p99_ms,
                row.swap_rss_mib,
                row.refused_other_catalogue,
                row.train_env_steps_per_s
            );
        }
    }
    Ok(())
}
