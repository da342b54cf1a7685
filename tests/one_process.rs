//! End-to-end runs of the one-process trainer: determinism, both devices, every
//! environment with every algorithm, warm starts, and the run directory's files.

use jsae_nn::DeviceKind;
use jsae_settings::Algo;
use jsae_settings::EnvName;
use jsae_tests::{metrics_without_timing, small_config, summary_without_timing, temp_dir};
use jsae_train::progress::Progress;
use jsae_train::train_one_process;

#[test]
fn the_same_seed_gives_the_same_summary_twice() {
    let runs: Vec<_> = (0..2)
        .map(|i| {
            let dir = temp_dir(&format!("determinism-{i}"));
            let config = small_config(EnvName::GridworldDiscrete, Algo::Jsae, 3, dir.clone());
            train_one_process(&config, &mut Progress::new(0, true)).expect("run completes");
            dir
        })
        .collect();
    let (a, b) = (
        summary_without_timing(&runs[0]),
        summary_without_timing(&runs[1]),
    );
    assert_eq!(a, b);
    assert!(a["learner_updates"].as_u64().unwrap_or(0) > 0, "{a}");
    assert_eq!(
        metrics_without_timing(&runs[0]),
        metrics_without_timing(&runs[1])
    );
    // a different seed gives a different run
    let dir = temp_dir("determinism-other-seed");
    let config = small_config(EnvName::GridworldDiscrete, Algo::Jsae, 4, dir.clone());
    train_one_process(&config, &mut Progress::new(0, true)).expect("run completes");
    assert_ne!(
        metrics_without_timing(&runs[0]),
        metrics_without_timing(&dir)
    );
}

#[test]
fn the_run_directory_holds_config_metrics_summary_checkpoints_and_plots() {
    let dir = temp_dir("run-dir");
    let config = small_config(EnvName::GridworldDiscrete, Algo::Jsae, 1, dir.clone());
    let outcome = train_one_process(&config, &mut Progress::new(0, true)).expect("run completes");
    let summary = summary_without_timing(&dir);
    for key in [
        "env",
        "algo",
        "seed",
        "env_steps",
        "eval_episodes",
        "eval_return_mean",
        "eval_return_std",
        "eval_success_rate",
        "learner_updates",
        "policy_lag_mean",
        "policy_lag_max",
        "embedding_version",
    ] {
        assert!(summary.get(key).is_some(), "summary lacks {key}: {summary}");
    }
    assert_eq!(summary["env"], "gridworld-discrete");
    assert!(summary["env_steps"].as_u64().unwrap_or(0) >= 16_384);
    assert!(summary["embedding_version"].as_u64().unwrap_or(0) >= 1);
    let config_text = std::fs::read_to_string(dir.join("config.toml")).expect("config.toml");
    assert!(
        config_text.contains("seed = 1") && config_text.contains("[embedding]"),
        "{config_text}"
    );
    let metrics = std::fs::read_to_string(dir.join("metrics.csv")).expect("metrics.csv");
    let header = metrics.lines().next().unwrap_or("");
    for col in [
        "env_steps",
        "wall_seconds",
        "return_mean",
        "policy_lag_mean",
        "policy_loss",
        "value_loss",
        "embedding_loss",
        "embedding_structure",
    ] {
        assert!(
            header.split(',').any(|c| c == col),
            "metrics.csv lacks {col}"
        );
    }
    assert!(metrics.lines().count() > 2);
    // The gridworld's action embeddings are measured against the actions' displacements.
    let table = jsae_run_dir::MetricsTable::read(&dir.join("metrics.csv")).expect("reads");
    let structure = table.series("env_steps", "embedding_structure");
    assert!(
        structure.last().is_some_and(|p| p.1 > 0.0 && p.1 < 1.5),
        "{structure:?}"
    );
    // the final policy and embedding, and the latest of each with its version (to resume)
    let mut checkpoints: Vec<String> = std::fs::read_dir(dir.join("checkpoints"))
        .expect("checkpoints")
        .filter_map(|e| e.ok()?.file_name().into_string().ok())
        .collect();
    checkpoints.sort();
    let (p, e) = (
        outcome.summary.policy_version,
        outcome.summary.embedding_version,
    );
    let mut expected = vec![
        format!("embedding-v{e}.bpk"),
        "embedding-latest.ckpt".into(),
        format!("policy-v{p}.bpk"),
        "policy-latest.ckpt".into(),
        "policy-previous.ckpt".into(),
    ];
    // the latest file a newer one replaced
    if e > 1 {
        expected.push("embedding-previous.ckpt".into());
    }
    expected.sort();
    assert_eq!(checkpoints, expected);
    // the learning curve and, on the gridworld, the action and the state embeddings
    let names: Vec<_> = outcome.plots.iter().filter_map(|p| p.file_name()).collect();
    assert_eq!(
        names,
        [
            "learning_curve.svg",
            "learning_curve.png",
            "action_embeddings.svg",
            "action_embeddings.png",
            "state_embeddings.svg",
            "state_embeddings.png"
        ]
    );
    assert!(outcome.plots.iter().all(|p| p.exists()));
}

#[test]
fn every_algorithm_trains_on_every_environment_and_on_both_devices() {
    for (env, algo, device) in [
        (EnvName::Gridworld, Algo::Jsae, DeviceKind::Flex),
        (EnvName::Gridworld, Algo::Ppo, DeviceKind::Flex),
        (EnvName::Slotmachine, Algo::Jsae, DeviceKind::Flex),
        (EnvName::Slotmachine, Algo::Ppo, DeviceKind::Flex),
        (EnvName::GridworldDiscrete, Algo::Ppo, DeviceKind::Ndarray),
        (EnvName::GridworldDiscrete, Algo::Jsae, DeviceKind::Ndarray),
        (EnvName::HalfCheetah, Algo::Jsae, DeviceKind::Flex),
        (EnvName::HalfCheetah, Algo::Ppo, DeviceKind::Flex),
        (EnvName::Ant, Algo::Jsae, DeviceKind::Flex),
        // the baselines: discrete and continuous actions, categorical and real states
        (EnvName::GridworldDiscrete, Algo::Ae, DeviceKind::Flex),
        (EnvName::GridworldDiscrete, Algo::Ra, DeviceKind::Ndarray),
        (EnvName::Gridworld, Algo::Ra, DeviceKind::Flex),
        (EnvName::HalfCheetah, Algo::Ae, DeviceKind::Flex),
        (EnvName::HalfCheetah, Algo::Ra, DeviceKind::Flex),
        (EnvName::Slotmachine, Algo::Ae, DeviceKind::Flex),
        // the recommender on the real Instacart sample (fetched at build time)
        (EnvName::Recommender, Algo::Jsae, DeviceKind::Flex),
        (EnvName::Recommender, Algo::Ppo, DeviceKind::Ndarray),
    ] {
        let dir = temp_dir(&format!(
            "{}-{}-{}",
            env.as_str(),
            algo.as_str(),
            device.as_str()
        ));
        let mut config = small_config(env, algo, 2, dir.clone());
        config.device = device;
        let outcome = train_one_process(&config, &mut Progress::new(0, true))
            .unwrap_or_else(|e| panic!("{env:?} {algo:?} {device:?}: {e}"));
        let s = &outcome.summary;
        assert!(
            s.learner_updates > 0 && s.eval_return_mean.is_finite(),
            "{s:?}"
        );
        assert_eq!(s.device, device.as_str());
        let has_goal = matches!(env, EnvName::Gridworld | EnvName::GridworldDiscrete);
        assert_eq!(s.eval_success_rate.is_some(), has_goal);
    }
}

#[test]
fn a_run_warm_starts_from_another_with_more_actions_and_refuses_a_mismatch() {
    let source = temp_dir("init-source");
    let config = small_config(EnvName::GridworldDiscrete, Algo::Jsae, 5, source.clone());
    train_one_process(&config, &mut Progress::new(0, true)).expect("source run");

    let target = temp_dir("init-target");
    let mut warm = small_config(EnvName::GridworldDiscrete, Algo::Jsae, 5, target.clone());
    warm.environment.gridworld.actuators = 10;
    warm.init_from = Some(source.clone());
    let outcome = train_one_process(&warm, &mut Progress::new(0, true)).expect("warm run");
    assert!(outcome.summary.learner_updates > 0);
    let written = std::fs::read_to_string(target.join("config.toml")).expect("config.toml");
    assert!(written.contains("init_from"), "{written}");

    let mut other = small_config(
        EnvName::GridworldDiscrete,
        Algo::Ppo,
        5,
        temp_dir("init-bad"),
    );
    other.init_from = Some(source.clone());
    let err = train_one_process(&other, &mut Progress::new(0, true)).expect_err("jsae -> ppo");
    assert!(err.to_string().contains("--init-from"), "{err}");
    other.init_from = Some(temp_dir("init-missing"));
    let err = train_one_process(&other, &mut Progress::new(0, true)).expect_err("no run");
    assert!(err.to_string().contains("config.toml"), "{err}");
}
