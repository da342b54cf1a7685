//! The plots of run directories written by hand: which embedding version is drawn, the
//! evaluation point of a run's curve, the figure of several runs, and `jsae plot`'s refusals.

use std::path::{Path, PathBuf};

use jsae_agent::EmbeddingModel;
use jsae_nn::BurnDevice;
use jsae_run_dir::Summary;
use jsae_run_dir::{RunDir, Weights};
use jsae_settings::{Algo, EnvName, TrainConfig};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::*;

fn temp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("jsae-plot-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).expect("mkdir");
    d
}

/// Whether a TrueType font is there to draw with (a machine without one draws nothing).
fn can_draw() -> bool {
    match figures::font() {
        Ok(()) => true,
        Err(reason) => {
            eprintln!("no figures drawn: {reason}");
            false
        }
    }
}

/// A run directory with `config.toml` and a `metrics.csv` of `rows` updates, 1,000 env steps
/// apart; `success` leaves the success column empty when false.
fn write_run(root: &Path, config: &TrainConfig, rows: u32, offset: f64, success: bool) -> RunDir {
    let run = RunDir::new(root);
    std::fs::write(run.config_toml(), config.to_toml()).expect("config.toml");
    let mut csv = String::from("update,env_steps,return_mean,success_rate\n");
    for i in 1..=rows {
        let s = if success {
            format!("{}", f64::from(i) / f64::from(rows))
        } else {
            String::new()
        };
        csv.push_str(&format!("{i},{},{},{s}\n", 1000 * i, offset + f64::from(i)));
    }
    std::fs::write(run.metrics_csv(), csv).expect("metrics.csv");
    run
}

/// A `summary.json` naming `embedding_version`, after `env_steps`.
fn write_summary(run: &RunDir, embedding_version: u64, env_steps: u64) {
    let summary = Summary {
        env: "gridworld-discrete".into(),
        algo: "jsae".into(),
        seed: 1,
        env_steps,
        wall_seconds: 1.0,
        steps_per_second: env_steps as f64,
        eval_episodes: 5,
        eval_return_mean: 7.5,
        eval_return_std: 1.5,
        eval_success_rate: Some(0.8),
        eval_length_mean: 20.0,
        eval_stochastic_return_mean: None,
        eval_stochastic_success_rate: None,
        learner_updates: 4,
        policy_lag_mean: 0.0,
        policy_lag_max: 0,
        dropped_lag: 0,
        dropped_embedding: 0,
        policy_version: 4,
        embedding_version,
        device: "flex".into(),
        git_commit: String::new(),
        started_unix_s: 0,
        command_line: Vec::new(),
    };
    summary.write(run).expect("summary.json");
}

/// A fresh embedding model's weights for `config`, initialised from `seed`.
fn model_bytes(config: &TrainConfig, seed: u64) -> Vec<u8> {
    let (states, actions) = config.spaces();
    let model = EmbeddingModel::new(
        &config.embedding,
        config.algo.representation(),
        &states,
        &actions,
        &mut ChaCha8Rng::seed_from_u64(seed),
        &config.device.device(),
    );
    model.to_bytes().expect("weights as bytes")
}

fn text(path: &Path) -> String {
    std::fs::read_to_string(path).unwrap_or_default()
}

fn assert_png(path: &Path) {
    let bytes = std::fs::read(path).unwrap_or_default();
    assert!(
        bytes.len() > 1000,
        "{}: {} bytes",
        path.display(),
        bytes.len()
    );
    assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n", "{}", path.display());
}

#[test]
fn the_embedding_plots_draw_the_version_the_summary_names_not_a_newer_stray_one() {
    let root = temp("version");
    let config = TrainConfig::defaults(EnvName::GridworldDiscrete, Algo::Jsae);
    let run = write_run(&root, &config, 4, 0.0, true);
    let (ours, stray) = (model_bytes(&config, 1), model_bytes(&config, 2));
    let checkpoints = run.checkpoints();
    let write = |version, bytes: &[u8]| {
        checkpoints
            .write_versioned(Weights::Embedding, version, bytes)
            .expect("checkpoint");
    };
    write(3, &ours);
    // An older run's checkpoints in the same directory, with more updates than this one.
    write(9, &stray);
    checkpoints
        .write_latest(Weights::Embedding, 9, &stray)
        .expect("checkpoint");

    // No summary yet: the newest there is.
    let newest = run_embedding(&run).expect("read").expect("a checkpoint");
    assert_eq!((newest.version, &newest.bytes), (9, &stray));

    write_summary(&run, 3, 4000);
    let named = run_embedding(&run).expect("read").expect("version 3");
    assert_eq!((named.version, &named.bytes), (3, &ours));
    assert_eq!(load_embedding(&named, &config).expect("loads").version(), 3);

    if can_draw() {
        let written = plot_run_dir(&run, &config).expect("plots");
        for svg in [
            run.learning_curve_svg(),
            run.action_embeddings_svg(),
            run.state_embeddings_svg(),
        ] {
            assert!(written.contains(&svg), "{written:?}");
            assert_png(&svg.with_extension("png"));
        }
        let actions = text(&run.action_embeddings_svg());
        assert!(actions.contains("embedding version 3"), "{actions}");
        assert!(actions.contains("displacement"), "the colour key");
        assert!(text(&run.state_embeddings_svg()).contains("embedding version 3"));
    }

    // The named version gone: nothing rather than the stray one, unless the latest file
    // holds that version.
    std::fs::remove_file(checkpoints.versioned(Weights::Embedding, 3)).expect("rm");
    assert!(run_embedding(&run).expect("read").is_none());
    checkpoints
        .write_latest(Weights::Embedding, 3, &ours)
        .expect("checkpoint");
    let latest = run_embedding(&run).expect("read").expect("version 3");
    assert_eq!((latest.version, latest.bytes), (3, ours));
    // A run without embeddings names version 0: none.
    write_summary(&run, 0, 4000);
    assert!(run_embedding(&run).expect("read").is_none());
    let _ = std::fs::remove_dir_all(&root);
}

#[test]
fn a_runs_curve_marks_its_evaluation_and_drops_the_success_panel_without_success() {
    let root = temp("eval");
    let config = TrainConfig::defaults(EnvName::GridworldDiscrete, Algo::Ppo);
    let run = write_run(&root, &config, 5, 0.0, true);
    write_summary(&run, 0, 5000);
    let metrics = MetricsTable::read(&run.metrics_csv()).expect("metrics");
    let summary = read_summary(&run).expect("read");
    let curve = LearningCurve::new(&metrics, summary.as_ref(), "t".into());
    let eval = curve.eval.expect("an evaluation");
    assert_eq!((eval.env_steps, eval.return_mean), (5000.0, 7.5));
    assert_eq!((eval.return_std, eval.success_rate), (1.5, Some(0.8)));
    let without = write_run(&temp("no-success"), &config, 5, 0.0, false);
    let flat = MetricsTable::read(&without.metrics_csv()).expect("metrics");
    let one_panel = LearningCurve::new(&flat, None, "t".into());
    assert!(one_panel.success.is_empty() && one_panel.eval.is_none());
    assert!(one_panel.size().1 < curve.size().1);
    if can_draw() {
        let written = write_run_plots(&run, &config, None).expect("plots");
        assert_eq!(
            written,
            vec![
                run.learning_curve_svg(),
                run.learning_curve_svg().with_extension("png")
            ]
        );
        let svg = text(&run.learning_curve_svg());
        for label in ["eval", "training return", "success rate", "env steps"] {
            assert!(svg.contains(label), "{label}");
        }
        assert_png(&run.learning_curve_svg().with_extension("png"));
        let written = write_run_plots(&without, &config, None).expect("plots");
        assert_eq!(written.len(), 2);
        assert!(!text(&without.learning_curve_svg()).contains("success rate"));
    }
    let _ = std::fs::remove_dir_all(&root);
    let _ = std::fs::remove_dir_all(without.path());
}

#[test]
fn several_runs_make_one_figure_with_a_mean_and_band_per_env_and_algo() {
    let root = temp("several");
    let jsae = TrainConfig::defaults(EnvName::GridworldDiscrete, Algo::Jsae);
    let ppo = TrainConfig::defaults(EnvName::GridworldDiscrete, Algo::Ppo);
    let dirs: Vec<PathBuf> = [("a", &jsae, 0.0), ("b", &jsae, 2.0), ("c", &ppo, 4.0)]
        .iter()
        .map(|(name, config, offset)| {
            let dir = root.join(name);
            std::fs::create_dir_all(&dir).expect("mkdir");
            write_run(&dir, config, 6, *offset, true);
            dir
        })
        .collect();
    let curves: Vec<RunCurves> = dirs
        .iter()
        .zip(["g / jsae", "g / jsae", "g / ppo"])
        .map(|(d, group)| {
            let metrics = MetricsTable::read(&RunDir::new(d).metrics_csv()).expect("metrics");
            RunCurves::new(group.into(), &metrics)
        })
        .collect();
    let combined = Combined::new(&curves);
    assert_eq!(
        combined.series_names(),
        vec![
            "g / jsae: mean of 2 runs, band min to max",
            "g / ppo (1 run)",
            "g / jsae: mean of 2 runs, band min to max",
            "g / ppo (1 run)",
        ]
    );
    if !can_draw() {
        let _ = std::fs::remove_dir_all(&root);
        return;
    }
    // Positional runs and --out together; the figure where --to says.
    let stem = root.join("all");
    let args = PlotArgs {
        runs: dirs[..2].to_vec(),
        out: dirs[2..].to_vec(),
        to: Some(stem.clone()),
    };
    let written = plot(&args).expect("plots");
    let (svg, png) = figures::svg_and_png(&stem);
    assert!(
        written.contains(&svg) && written.contains(&png),
        "{written:?}"
    );
    assert!(written.contains(&dirs[2].join("learning_curve.png")));
    let figure = text(&svg);
    assert!(figure.contains("mean of 2 runs"), "{figure}");
    assert!(figure.contains("gridworld-discrete / ppo"), "{figure}");
    assert_png(&png);
    // Without --to: beside the runs.
    let args = PlotArgs {
        runs: dirs.clone(),
        ..PlotArgs::default()
    };
    plot(&args).expect("plots");
    assert_png(&root.join("learning_curves.png"));
    let _ = std::fs::remove_dir_all(&root);
}

#[test]
fn a_missing_directory_or_one_without_metrics_exits_2() {
    let root = temp("refused");
    let refused = |runs: Vec<PathBuf>| {
        let args = PlotArgs {
            runs,
            ..PlotArgs::default()
        };
        plot(&args).expect_err("refused")
    };
    let (code, reason) = refused(vec![root.join("nowhere")]);
    assert_eq!(code, 2);
    assert!(
        reason.contains("no such directory") && !reason.contains('\n'),
        "{reason}"
    );
    let (code, reason) = refused(vec![root.clone()]);
    assert_eq!(code, 2);
    assert!(reason.contains("no metrics.csv"), "{reason}");
    assert_eq!(refused(Vec::new()).0, 2);
    let _ = std::fs::remove_dir_all(&root);
}
