//! `jsae recommender-eval --run DIR`: a recommender run judged the way recommender systems
//! are, beside the reference policies (popular, item-kNN, the greedy rule, random): hit
//! rate@k, NDCG@k and MRR@k on the held-out sessions
//! (`jsae_recommender::offline`), and each policy's simulated return under the run's
//! evaluation protocol (the learned one as `jsae eval` computes it). Prints JSON.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Args;
use jsae_envs::recsys::held_out_sessions;
use jsae_recommender::baseline::{PolicyChoice, Reference, baselines};
use jsae_recommender::offline::{self, RankingMetrics};
use jsae_recommender::{Recommender, load_run};
use jsae_run_dir::RunDir;
use jsae_settings::{EnvName, TrainConfig};
use serde::Serialize;

/// `jsae recommender-eval` flags.
#[derive(Args, Debug)]
pub struct RecommenderEvalArgs {
    /// The run directory (config.toml and checkpoints/).
    #[arg(long)]
    pub run: PathBuf,
    /// Items recommended per query.
    #[arg(long, default_value_t = 10)]
    pub k: usize,
    /// Episodes of each policy's simulated return [default: the run's eval_episodes].
    #[arg(long)]
    pub episodes: Option<usize>,
    /// Score at most this many of the held-out queries, evenly spread [default: all]: the
    /// reference policies score every item per query, hours at 100,000 items.
    #[arg(long)]
    pub queries: Option<usize>,
}

#[derive(Debug, Serialize)]
struct PolicyRow {
    #[serde(flatten)]
    ranking: RankingMetrics,
    /// Mean simulated return under the run's evaluation seed.
    return_mean: f64,
}

#[derive(Debug, Serialize)]
struct Output {
    run: PathBuf,
    algo: &'static str,
    k: usize,
    holdout: f64,
    #[serde(flatten)]
    queries: offline::Queries,
    eval_episodes: usize,
    policies: Vec<PolicyRow>,
}

fn evaluate(a: &RecommenderEvalArgs) -> Result<Output, (u8, String)> {
    let dir = RunDir::new(&a.run);
    let mut config = TrainConfig::from_layers(None, None, Some(&dir.config_toml()))
        .map_err(|e| (2, e.to_string()))?;
    if config.env != EnvName::Recommender {
        return Err((2, format!("{}: not a recommender run", a.run.display())));
    }
    if a.k == 0 {
        return Err((2, "--k must be positive".into()));
    }
    // the data's model alone: a session store's later sessions would move the simulator
    config.environment.recommender.store_dir = PathBuf::new();
    let r = &config.environment.recommender;
    if r.holdout <= 0.0 {
        return Err((
            2,
            "the run's environment.recommender.holdout is 0: no sessions were held out".into(),
        ));
    }
    let held = held_out_sessions(r).map_err(|e| (1, e.to_string()))?;
    let episodes = a.episodes.unwrap_or(config.eval_episodes).max(1);

    let learned = Recommender::new(&config, PolicyChoice::Learned, config.device)
        .map_err(|e| (1, e.to_string()))?;
    load_run(&learned, &a.run).map_err(|e| (2, format!("{e:#}")))?;
    // the simulator's model (the learned policy reads the catalogue alone); the handle is
    // held to the end, so the reference policies and their returns share this one
    let handle = jsae_envs::recsys::model_handle(r).map_err(|e| (1, e.to_string()))?;
    let model = handle.current();
    let mut queries = offline::queries(&learned, &model, &held);
    if let Some(most) = a.queries {
        if most == 0 {
            return Err((2, "--queries must be positive".into()));
        }
        queries.thin_to(most);
    }
    let simulated = crate::eval::simulated_return(&a.run, episodes)?;
    let references =
        baselines(&config, episodes, config.eval_seed()).map_err(|e| (1, e.to_string()))?;
    let reference_return = |name: &str| {
        references
            .iter()
            .find(|b| b.policy == name)
            .map_or(f64::NAN, |b| b.return_mean)
    };
    let rank_err = |e: jsae_wire::RpcError| (1, e.to_string());
    let mut policies = vec![PolicyRow {
        ranking: offline::score(&learned, &model, &queries, a.k, "learned").map_err(rank_err)?,
        return_mean: simulated,
    }];
    for reference in Reference::ALL {
        let rec = Recommender::new(&config, reference.choice(), config.device)
            .map_err(|e| (1, e.to_string()))?;
        policies.push(PolicyRow {
            ranking: offline::score(&rec, &model, &queries, a.k, reference.name())
                .map_err(rank_err)?,
            return_mean: reference_return(reference.name()),
        });
    }
    policies.push(PolicyRow {
        ranking: offline::random_expectation(model.catalogue().len(), a.k),
        return_mean: reference_return("random"),
    });
    Ok(Output {
        run: a.run.clone(),
        algo: config.algo.as_str(),
        k: a.k,
        holdout: config.environment.recommender.holdout,
        queries,
        eval_episodes: episodes,
        policies,
    })
}

/// Runs `jsae recommender-eval`: the JSON on stdout; exit 2 for a bad run directory or flag.
pub fn main(a: &RecommenderEvalArgs) -> ExitCode {
    match evaluate(a) {
        Ok(out) => {
            println!("{}", serde_json::to_string_pretty(&out).unwrap_or_default());
            ExitCode::SUCCESS
        }
        Err((code, reason)) => {
            eprintln!("jsae recommender-eval: {reason}");
            ExitCode::from(code)
        }
    }
}
