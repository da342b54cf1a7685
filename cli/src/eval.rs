//! `jsae eval --run DIR`: evaluates a finished (or running) run's newest checkpoints, or a
//! given policy checkpoint, with the deterministic and the sampled policy; prints JSON.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Args;
use jsae_agent::greedy::GreedyDecode;
use jsae_run_dir::EvalStats;
use jsae_run_dir::{RunDir, Weights};
use jsae_settings::TrainConfig;
use jsae_wire::PolicySnapshot;

/// How the deterministic policy picks a discrete action through f.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum DecodeArg {
    /// f of the mean embedding (the default everywhere).
    Mean,
    /// The policy's most likely action, from fixed draws (slower; docs/src/experiments/greedy-loops.md).
    Mode,
}

/// `jsae eval` flags.
#[derive(Args, Debug)]
pub struct EvalArgs {
    /// The run directory (config.toml and checkpoints/).
    #[arg(long)]
    pub run: PathBuf,
    /// Episodes of each policy [default: the run's eval_episodes].
    #[arg(long)]
    pub episodes: Option<usize>,
    /// Environment seed of the evaluation [default: the run's evaluation seed, as at the
    /// end of training].
    #[arg(long)]
    pub seed: Option<u64>,
    /// A policy checkpoint file (`checkpoints/policy-vN.bpk`) [default: the version
    /// summary.json names, else the newest]. It is evaluated with the run's settings and,
    /// where the algorithm has an embedder, the embedding summary.json names (else the
    /// newest), not the embedding of the policy's own time.
    #[arg(long)]
    pub checkpoint: Option<PathBuf>,
    /// Deterministic discrete actions of JSAE: f of the mean, or the most likely action.
    #[arg(long, value_enum, default_value = "mean")]
    pub decode: DecodeArg,
}

#[derive(Debug, serde::Serialize)]
struct EvalOutput {
    run: PathBuf,
    policy_version: u64,
    embedding_version: u64,
    decode: &'static str,
    seed: u64,
    eval_episodes: usize,
    eval_return_mean: f64,
    eval_return_std: f64,
    eval_success_rate: Option<f64>,
    eval_length_mean: f64,
    eval_stochastic_return_mean: f64,
    eval_stochastic_success_rate: Option<f64>,
}

fn evaluate(a: &EvalArgs) -> Result<EvalOutput, (u8, String)> {
    let dir = RunDir::new(&a.run);
    let mut config = TrainConfig::from_layers(None, None, Some(&dir.config_toml()))
        .map_err(|e| (2, e.to_string()))?;
    // a run's config.toml does not name its folder; a gym run's workers log into it
    config.out = a.run.clone();
    let ckpt = dir.checkpoints();
    let (version, policy_path) = match &a.checkpoint {
        // The version only labels the output: `policy-vN.bpk` names it, else 0.
        Some(p) => (
            p.file_stem()
                .and_then(|s| s.to_str()?.strip_prefix("policy-v")?.parse().ok())
                .unwrap_or(0),
            p.clone(),
        ),
        // the version summary.json names where it is there (the newest otherwise)
        None => {
            let summary = jsae_report::plot::read_summary(&dir).map_err(|e| (2, e.to_string()))?;
            let named = summary
                .map(|s| {
                    (
                        s.policy_version,
                        ckpt.versioned(Weights::Policy, s.policy_version),
                    )
                })
                .filter(|(_, path)| path.is_file());
            named
                .or_else(|| ckpt.newest(Weights::Policy))
                .ok_or_else(|| {
                    (
                        2,
                        format!("{}: no policy checkpoint", ckpt.path().display()),
                    )
                })?
        }
    };
    let bytes = jsae_run_dir::read_weights(&policy_path)
        .map_err(|e| (2, format!("{}: {e}", policy_path.display())))?;
    // a gym run's evaluation steps its environment in a worker this process starts
    let (mut worker, _hosting) =
        jsae_train::actor_worker(&config, 0).map_err(|e| (1, e.to_string()))?;
    if config.algo.representation().needs_embedder() {
        // the version summary.json names (the newest where the run has no summary yet)
        let emb = jsae_report::plot::run_embedding(&dir)
            .map_err(|e| (2, format!("{}: {e}", dir.path().display())))?
            .ok_or_else(|| {
                (
                    2,
                    format!("{}: no embedding checkpoint", ckpt.path().display()),
                )
            })?;
        worker.set_embedding(&emb).map_err(|e| (2, e.to_string()))?;
    }
    worker
        .set_policy(&PolicySnapshot { version, bytes })
        .map_err(|e| (2, format!("{}: {e}", policy_path.display())))?;
    worker.set_greedy_decode(match a.decode {
        DecodeArg::Mode => GreedyDecode::Mode,
        DecodeArg::Mean => GreedyDecode::Mean,
    });
    let episodes = a.episodes.unwrap_or(config.eval_episodes);
    if episodes == 0 {
        return Err((2, "--episodes must be positive".into()));
    }
    let seed = a.seed.unwrap_or_else(|| config.eval_seed());
    let report = worker.evaluate(episodes, seed);
    let (det, stoch) = (
        EvalStats::of(&report.episodes),
        EvalStats::of(&report.stochastic),
    );
    Ok(EvalOutput {
        run: a.run.clone(),
        policy_version: report.policy_version,
        embedding_version: report.embedding_version,
        decode: match a.decode {
            DecodeArg::Mode => "mode",
            DecodeArg::Mean => "mean",
        },
        seed,
        eval_episodes: det.episodes,
        eval_return_mean: det.return_mean,
        eval_return_std: det.return_std,
        eval_success_rate: det.success_rate,
        eval_length_mean: det.length_mean,
        eval_stochastic_return_mean: stoch.return_mean,
        eval_stochastic_success_rate: stoch.success_rate,
    })
}

/// The mean return of a run's newest checkpoints, deterministic policy, under the run's
/// evaluation seed (as at the end of training), over `episodes` episodes.
pub(crate) fn simulated_return(
    run: &std::path::Path,
    episodes: usize,
) -> Result<f64, (u8, String)> {
    let out = evaluate(&EvalArgs {
        run: run.to_owned(),
        episodes: Some(episodes),
        seed: None,
        checkpoint: None,
        decode: DecodeArg::Mean,
    })?;
    Ok(out.eval_return_mean)
}

/// Runs `jsae eval`: the JSON on stdout; exit 2 for a bad run directory or flag.
pub fn main(a: &EvalArgs) -> ExitCode {
    match evaluate(a) {
        Ok(out) => {
            println!("{}", serde_json::to_string_pretty(&out).unwrap_or_default());
            ExitCode::SUCCESS
        }
        Err((code, reason)) => {
            eprintln!("jsae eval: {reason}");
            ExitCode::from(code)
        }
    }
}
