//! Tests of `settings::ppo`: defaults, bounds and the rules that read the settings.

use super::*;
use crate::{Algo, EnvName, TrainConfig};

#[test]
fn the_entropy_cap_falls_over_the_runs_last_quarter_only_where_a_bonus_holds_the_std() {
    let jsae = TrainConfig::defaults(EnvName::GridworldDiscrete, Algo::Jsae).ppo;
    assert_eq!(jsae.entropy_log_std_cap_at(0.0), None);
    assert_eq!(jsae.entropy_log_std_cap_at(0.75), None);
    assert_eq!(jsae.entropy_log_std_cap_at(0.875), Some(-0.25));
    assert_eq!(jsae.entropy_log_std_cap_at(1.0), Some(-1.0));
    // no bonus (MuJoCo, the slot machine) or no cap (plain PPO): nothing is held
    let cheetah = TrainConfig::defaults(EnvName::HalfCheetah, Algo::Jsae).ppo;
    assert_eq!(cheetah.entropy_log_std_cap_at(1.0), None);
    let ppo = TrainConfig::defaults(EnvName::GridworldDiscrete, Algo::Ppo).ppo;
    assert_eq!(ppo.entropy_log_std_cap_at(1.0), None);
    let set = PpoConfig {
        entropy_log_std_max: Some(0.0),
        entropy_log_std_final: Some(-2.0),
        entropy_cap_anneal_from: 0.0,
        ent_coef: 0.01,
        ..PpoConfig::default()
    };
    assert_eq!(set.entropy_log_std_cap_at(0.5), Some(-1.0));
    // a fall that ends before the run does holds the final cap from there on
    let early = PpoConfig {
        entropy_cap_anneal_to: 0.5,
        ..set.clone()
    };
    assert_eq!(early.entropy_log_std_cap_at(0.25), Some(-1.0));
    assert_eq!(early.entropy_log_std_cap_at(0.5), Some(-2.0));
    assert_eq!(early.entropy_log_std_cap_at(0.9), Some(-2.0));
    let bad = PpoConfig {
        entropy_cap_anneal_from: 1.0,
        ..set.clone()
    };
    let refused = bad
        .validate()
        .expect_err("the fall must start before the end");
    assert!(refused.contains("entropy_cap_anneal_from"), "{refused}");
    let backwards = PpoConfig {
        entropy_cap_anneal_from: 0.5,
        entropy_cap_anneal_to: 0.5,
        ..set
    };
    let refused = backwards
        .validate()
        .expect_err("the fall must end after it starts");
    assert!(refused.contains("entropy_cap_anneal_to"), "{refused}");
}

#[test]
fn a_count_of_minibatches_grows_the_minibatch_with_the_batch() {
    let sized = PpoConfig {
        minibatch_size: 64,
        ..PpoConfig::default()
    };
    assert_eq!(sized.minibatch_len(2048), 64);
    assert_eq!(sized.minibatch_len(16_384), 64);
    assert_eq!(sized.minibatch_len(40), 40);
    let counted = PpoConfig {
        minibatches: Some(32),
        ..sized
    };
    assert_eq!(counted.minibatch_len(2048), 64);
    assert_eq!(counted.minibatch_len(16_384), 512);
    assert_eq!(counted.minibatch_len(100), 4);
    assert_eq!(counted.minibatch_len(10), 1);
    counted.validate().expect("a count is valid");
    let zero = PpoConfig {
        minibatches: Some(0),
        ..counted
    };
    let refused = zero.validate().expect_err("no minibatches");
    assert!(refused.contains("ppo.minibatches"), "{refused}");
}

#[test]
fn the_logged_prior_is_the_recommenders_ppo_default_and_the_pair_feature_valid_there() {
    let mut ppo = TrainConfig::defaults(EnvName::Recommender, Algo::Ppo);
    assert!(ppo.ppo.recommender.logged_prior);
    assert_eq!(ppo.ppo.recommender.pair_buckets, 0);
    assert_eq!(ppo.ppo.recommender.logged_pretrain_epochs, 0);
    assert_eq!(ppo.ppo.gamma, 0.0);
    ppo.validate().expect("the defaults are valid");
    let jsae = TrainConfig::defaults(EnvName::Recommender, Algo::Jsae);
    assert!(!jsae.ppo.recommender.logged_prior);
    assert_eq!(jsae.ppo.recommender.pair_buckets, 0);
    ppo.ppo.recommender.pair_buckets = 131_072;
    ppo.validate()
        .expect("the pair feature is valid on the recommender");
    let mut c = TrainConfig::defaults(EnvName::GridworldDiscrete, Algo::Ppo);
    c.ppo.recommender.pair_buckets = 64;
    let reason = c.validate().expect_err("not the recommender").to_string();
    assert!(reason.contains("ppo.recommender.pair_buckets"), "{reason}");
    for change in [
        |c: &mut TrainConfig| c.ppo.update = UpdatePath::Burn,
        |c: &mut TrainConfig| c.ppo.normalize_obs = true,
        |c: &mut TrainConfig| c.ppo.recommender.pair_hashes = 0,
        |c: &mut TrainConfig| c.ppo.recommender.pair_scale = f32::NAN,
    ] {
        let mut c = ppo.clone();
        change(&mut c);
        let reason = c.validate().expect_err("refused").to_string();
        assert!(reason.contains("ppo.recommender.pair_"), "{reason}");
    }
}

#[test]
fn the_reward_bound_is_generous_and_must_be_positive() {
    for env in [
        EnvName::HalfCheetah,
        EnvName::Recommender,
        EnvName::Gridworld,
    ] {
        let c = TrainConfig::defaults(env, Algo::Jsae);
        assert_eq!(c.ppo.max_abs_reward, DEFAULT_MAX_ABS_REWARD);
    }
    for bad in [0.0, -1.0, f32::NAN] {
        let mut c = TrainConfig::defaults(EnvName::Gridworld, Algo::Ppo);
        c.ppo.max_abs_reward = bad;
        let reason = c.validate().expect_err("not positive").to_string();
        assert!(reason.contains("ppo.max_abs_reward"), "{reason}");
    }
}

#[test]
fn absurd_sizes_are_refused_before_anything_is_allocated() {
    let c = TrainConfig::defaults(EnvName::Gridworld, Algo::Jsae);
    c.validate().expect("the defaults pass");
    type Set = fn(&mut TrainConfig);
    let cases: [(&str, Set); 6] = [
        ("ppo.hidden", |c| c.ppo.hidden = vec![1 << 40; 2]),
        ("ppo.hidden", |c| c.ppo.hidden = vec![MAX_WIDTH; 6]),
        ("ppo.hidden", |c| c.ppo.hidden = vec![64; MAX_LAYERS + 1]),
        ("ppo.batch_steps", |c| {
            c.ppo.batch_steps = MAX_BATCH_STEPS + 1
        }),
        ("ppo.recommender.pair_buckets", |c| {
            c.ppo.recommender.pair_buckets = usize::MAX
        }),
        ("embedding.decoder_hidden", |c| {
            c.embedding.decoder_hidden = 1 << 30
        }),
    ];
    for (key, set) in cases {
        let mut bad = c.clone();
        set(&mut bad);
        let reason = bad.validate().expect_err("too large").to_string();
        assert!(reason.contains(key), "{key}: {reason}");
    }
}

#[test]
fn logged_pretraining_is_for_the_recommenders_ppo_on_the_fused_update() {
    let mut ppo = TrainConfig::defaults(EnvName::Recommender, Algo::Ppo);
    ppo.ppo.recommender.logged_pretrain_epochs = 5;
    ppo.validate().expect("valid");
    for (env, algo) in [
        (EnvName::Recommender, Algo::Jsae),
        (EnvName::Slotmachine, Algo::Ppo),
    ] {
        let mut c = TrainConfig::defaults(env, algo);
        c.ppo.recommender.logged_pretrain_epochs = 5;
        let reason = c.validate().expect_err("refused").to_string();
        assert!(
            reason.contains("ppo.recommender.logged_pretrain_epochs"),
            "{reason}"
        );
    }
    let mut burn = ppo.clone();
    (burn.ppo.update, burn.ppo.recommender.pair_buckets) = (UpdatePath::Burn, 0);
    let reason = burn.validate().expect_err("the burn update").to_string();
    assert!(
        reason.contains("ppo.recommender.logged_pretrain_epochs"),
        "{reason}"
    );
    for bad in [0.0, -1e-3, f64::NAN] {
        let mut c = ppo.clone();
        c.ppo.recommender.logged_pretrain_lr = bad;
        let reason = c.validate().expect_err("not positive").to_string();
        assert!(
            reason.contains("ppo.recommender.logged_pretrain_lr"),
            "{reason}"
        );
    }
}

#[test]
fn the_logged_prior_is_for_the_recommenders_ppo_on_the_fused_update_without_normalising() {
    let mut ppo = TrainConfig::defaults(EnvName::Recommender, Algo::Ppo);
    ppo.ppo.recommender.logged_prior = true;
    ppo.validate().expect("valid");
    for (env, algo) in [
        (EnvName::Recommender, Algo::Jsae),
        (EnvName::Slotmachine, Algo::Ppo),
    ] {
        let mut c = TrainConfig::defaults(env, algo);
        c.ppo.recommender.logged_prior = true;
        let reason = c.validate().expect_err("refused").to_string();
        assert!(reason.contains("ppo.recommender.logged_prior"), "{reason}");
    }
    for change in [
        |c: &mut TrainConfig| c.ppo.update = UpdatePath::Burn,
        |c: &mut TrainConfig| c.ppo.normalize_obs = true,
    ] {
        let mut c = ppo.clone();
        (
            c.ppo.recommender.pair_buckets,
            c.ppo.recommender.logged_pretrain_epochs,
        ) = (0, 0);
        change(&mut c);
        let reason = c.validate().expect_err("refused").to_string();
        assert!(reason.contains("ppo.recommender.logged_prior"), "{reason}");
    }
}

#[test]
fn the_recommenders_keys_read_from_their_sub_table_and_from_an_older_files_ppo_table() {
    let dir = std::env::temp_dir().join(format!("jsae-ppo-recommender-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("dir");
    let read = |name: &str, text: &str| {
        let file = dir.join(name);
        std::fs::write(&file, text).expect("write");
        TrainConfig::from_layers(Some(EnvName::Recommender), Some(Algo::Ppo), Some(&file))
    };
    // one key of the sub-table leaves the others at the pair's defaults (logged_prior: true)
    let new = read("new.toml", "[ppo.recommender]\npair_scale = 2.0\n").expect("reads");
    assert_eq!(new.ppo.recommender.pair_scale, 2.0);
    assert!(new.ppo.recommender.logged_prior);
    // a run directory's config.toml of before: the keys in [ppo] itself
    let old = read(
        "old.toml",
        "[ppo]\nlr = 1e-4\nlogged_prior = false\nnext_purchase_coef = 0.5\n",
    )
    .expect("an older file reads");
    assert_eq!(old.ppo.lr, 1e-4);
    assert!(!old.ppo.recommender.logged_prior);
    assert_eq!(old.ppo.recommender.next_purchase_coef, 0.5);
    // what a run writes now reads back the same
    let again = read("again.toml", &old.to_toml()).expect("reads back");
    assert_eq!(again.ppo, old.ppo);
    assert!(old.to_toml().contains("[ppo.recommender]"));
    let unknown = read("unknown.toml", "[ppo.recommender]\nlr = 1e-4\n");
    assert!(unknown.is_err(), "lr is [ppo]'s");
    let _ = std::fs::remove_dir_all(&dir);
}
