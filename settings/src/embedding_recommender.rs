//! The recommender's embedding settings (`[embedding.recommender]`): what lets JSAE learn the
//! items' structure from what every transition carries, the item bought next, rather than
//! from the rare transitions where a recommendation was bought
//! (docs/src/experiments/recommender-jsae.md). All off by default, which is the paper's JSAE.

use serde::{Deserialize, Serialize};

use super::ppo_recommender::MAX_PAIR_BUCKETS;
use crate::TrainConfig;

/// Most floats in phi's pair rows (`pair_buckets x state_dim`): 64 MiB, well inside a
/// snapshot (262,144 x 64 in the recommender's JSAE defaults).
pub const MAX_PAIR_FLOATS: usize = 1 << 24;

/// The recommender's embedding settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RecommenderEmbeddingConfig {
    /// Weight of the next-item loss (0: off, the paper's JSAE): a head `h(x) = tanh(W x + b)`
    /// in the action-embedding space scores every item `i` by `-s |h(x) - g(i)|^2` (`s` a
    /// learned scale), and the cross-entropy against the item bought next is added to T's
    /// loss. g is tied to the items' output embedding, so the item nearest to `h(x)`, which f
    /// decodes, is the one the head finds most likely. The policy's input becomes
    /// `concat(phi(s), W x + b)`.
    pub next_item_coef: f64,
    /// Buckets of a pair row in phi (0: none): phi's pre-activation also adds a row picked by
    /// a hash of the state's last two items (starting at zero), so states that share an item
    /// can differ in what follows them.
    pub pair_buckets: usize,
    /// Passes over the logged purchases (the sessions the simulator is built from, never the
    /// held-out ones) before the random-play pre-training, with the next-item loss alone, at
    /// `embedding.lr` (0: none; needs `next_item_coef > 0`).
    pub logged_pretrain_epochs: usize,
    /// The logged pre-training's learning rate at its first pass, annealed linearly to 0 by
    /// its last (0: `embedding.lr`, constant).
    pub logged_pretrain_lr: f64,
    /// The most minibatch steps the logged passes take (the last pass cut short): a
    /// million items' logs are 20M purchases, 4,883 minibatches a pass. Instacart's 100
    /// passes take 4,000.
    pub logged_pretrain_max_steps: usize,
    /// What the logged passes teach the head after each logged state: the item bought there
    /// (`bought`), the next-purchase estimate counted from the logs (`counted`: the items
    /// bought after the state's two-item context, smoothed towards those after its last
    /// item, towards all purchases and towards uniform, as PPO's count prior), or that
    /// estimate's most likely item (`counted-best`: the logs' count-greedy choice, a warm
    /// start of the head), or the item a one-purchase lookahead on the logs' interpolated
    /// estimate finds best (`lookahead`: the recommendation with the most expected purchases
    /// of recommended items over this step and the next, the next one count-greedy; the
    /// lift a recommendation gives is `lookahead_boost`). At catalogue scale (`embedding.sampled_softmax_from`) the item
    /// bought, whatever this says: a distribution over every item per state does not fit.
    pub logged_targets: LoggedTargets,
    /// With counted targets, states one purchase ahead of the logged ones, as many as this
    /// share of each minibatch: a logged state's last item followed by an item drawn from
    /// its estimate, with the estimate after that state as the target. They reach two-item
    /// contexts the logs never hold, as play does (0: none; at most 4).
    pub logged_ahead_share: f64,
    /// With `lookahead` targets, the lift a recommendation gives its item's purchase
    /// probability `p` (to `boost p / (1 + (boost - 1) p)`), which the logs cannot show (0:
    /// measured on the random-play pre-training transitions, bought recommendations against
    /// the estimate's expectation of them; else at least 1).
    pub lookahead_boost: f64,
}

/// The logged pre-training's targets (`embedding.recommender.logged_targets`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum LoggedTargets {
    /// The item bought after each logged state.
    #[default]
    Bought,
    /// The next-purchase estimate counted from the logs, a distribution over the items.
    Counted,
    /// The item the counted estimate finds most likely after each state.
    CountedBest,
    /// The item a one-purchase lookahead on the logs' interpolated estimate finds best.
    Lookahead,
}

impl Default for RecommenderEmbeddingConfig {
    fn default() -> Self {
        Self {
            next_item_coef: 0.0,
            pair_buckets: 0,
            logged_pretrain_epochs: 0,
            logged_pretrain_lr: 0.0,
            logged_pretrain_max_steps: 5_000,
            logged_targets: LoggedTargets::Bought,
            logged_ahead_share: 0.0,
            lookahead_boost: 0.0,
        }
    }
}

impl RecommenderEmbeddingConfig {
    /// Whether any of them is on (only the recommender's JSAE may set them).
    pub fn any(&self) -> bool {
        self.next_item_coef > 0.0 || self.pair_buckets > 0 || self.logged_pretrain_epochs > 0
    }

    /// Whether the model has the next-item head (and the policy reads its output).
    pub fn next_item(&self) -> bool {
        self.next_item_coef > 0.0
    }

    /// Checks the settings (`state_dim`: `[embedding]`'s); the reason names the bad key.
    pub fn validate(&self, state_dim: usize) -> Result<(), String> {
        if self.pair_buckets.saturating_mul(state_dim) > MAX_PAIR_FLOATS {
            return Err(format!(
                "embedding.recommender.pair_buckets x embedding.state_dim is {} x {state_dim}, \
                 at most {MAX_PAIR_FLOATS} floats",
                self.pair_buckets
            ));
        }
        if !(self.next_item_coef >= 0.0 && self.next_item_coef.is_finite()) {
            return Err(format!(
                "embedding.recommender.next_item_coef must be finite and >= 0, got {}",
                self.next_item_coef
            ));
        }
        if self.pair_buckets > MAX_PAIR_BUCKETS {
            return Err(format!(
                "embedding.recommender.pair_buckets is {}, at most {MAX_PAIR_BUCKETS}",
                self.pair_buckets
            ));
        }
        if !(self.logged_pretrain_lr >= 0.0 && self.logged_pretrain_lr.is_finite()) {
            return Err(format!(
                "embedding.recommender.logged_pretrain_lr must be finite and >= 0, got {}",
                self.logged_pretrain_lr
            ));
        }
        if !((0.0..=4.0).contains(&self.logged_ahead_share)) {
            return Err(format!(
                "embedding.recommender.logged_ahead_share must be between 0 and 4, got {}",
                self.logged_ahead_share
            ));
        }
        if self.logged_ahead_share > 0.0 && self.logged_targets == LoggedTargets::Bought {
            return Err(
                "embedding.recommender.logged_ahead_share needs logged_targets = \"counted\", \
                 \"counted-best\" or \"lookahead\" (the states ahead are drawn from the \
                 counted estimate, their targets too)"
                    .into(),
            );
        }
        let b = self.lookahead_boost;
        if !(b == 0.0 || (b >= 1.0 && b.is_finite())) {
            return Err(format!(
                "embedding.recommender.lookahead_boost must be 0 (measured) or a finite lift \
                 >= 1, got {b}"
            ));
        }
        if self.logged_pretrain_epochs > 0 && !self.next_item() {
            return Err(
                "embedding.recommender.logged_pretrain_epochs needs next_item_coef > 0 (the \
                 logs hold states and the items bought, which only the next-item loss reads)"
                    .into(),
            );
        }
        Ok(())
    }
}

/// The recommender's JSAE defaults: under the paper's loss g learns only from bought
/// recommendations (0.34% of random play, 0.001 nats of the next state) and stays at random
/// play; the item bought next, in every transition and in the logs, teaches phi, g and the
/// next-item head instead, and the policy's mean starts at the head's item
/// (docs/src/experiments/recommender-jsae.md). The paper's JSAE: `[embedding.recommender]`
/// and `ppo.recommender.mean_at_next_item` off.
pub(crate) fn jsae_recommender_defaults(c: &mut TrainConfig) {
    let e = &mut c.embedding;
    (e.state_dim, e.action_dim) = (64, 64);
    e.batch_size = 4096;
    e.pretrain_transitions = 20_000;
    e.pretrain_epochs = 1;
    e.update_every = 0;
    e.recommender.next_item_coef = 1.0;
    // the most rows the settings allow at this width (MAX_PAIR_FLOATS): at 131,072 the 3% of
    // play whose unlogged pair hashes onto a logged pair's row cost 0.04 an episode
    e.recommender.pair_buckets = MAX_PAIR_FLOATS / e.state_dim;
    e.recommender.logged_pretrain_epochs = 100;
    // the logs learnt to their conditional entropy (0.69 nats, annealed from 1e-2), then a
    // gentle random-play pass: at 1e-2 it moved the fitted g enough to cost the head's item
    // 1.2 of its 7.7 (docs/src/experiments/recommender-jsae.md)
    e.recommender.logged_pretrain_lr = 0.01;
    // after each logged state and after states one purchase ahead, the item a one-purchase
    // lookahead on the logs' estimate finds best, its lift measured on random play: the
    // count-greedy item (`counted-best`, +0.36 a seed over the item bought) left the head
    // 0.07 below the greedy rule on Instacart, planning adds what the rule leaves out
    // (docs/src/experiments/recommender-jsae.md#planning-on-the-logs)
    e.recommender.logged_targets = LoggedTargets::Lookahead;
    e.recommender.logged_ahead_share = 0.5;
    // the random-play pass at 1e-6 leaves the head's fit of the counted targets as the logged
    // passes left it: at 1e-3 its five minibatches of random-play purchases moved the head
    // off the count-greedy item in 1-3% of the logged contexts its play visits, 0.06-0.07 of
    // its return (docs/src/experiments/recommender-jsae.md#the-random-play-pass-after-the-counted-targets)
    e.lr = 1e-6;
    let p = &mut c.ppo;
    p.gamma = 0.0;
    p.lr = 1e-4;
    p.ent_coef = 0.0;
    p.init_log_std = -2.0;
    p.recommender.mean_at_next_item = true;
}

/// The item settings against the rest of a run's: only the recommender's JSAE may set them,
/// and the mean starts at the head only where there is a head, the mean is a tanh and the
/// policy reads the head's output unnormalised.
pub(crate) fn validate_for_run(c: &TrainConfig) -> Result<(), String> {
    let recommender_jsae = c.env == crate::EnvName::Recommender && c.algo == crate::Algo::Jsae;
    if c.embedding.recommender.any() && !recommender_jsae {
        return Err(
            "embedding.recommender.* is for --env recommender --algo jsae (the items \
                    bought next, in the state's last factor, are its actions)"
                .into(),
        );
    }
    if c.ppo.recommender.mean_at_next_item
        && !(recommender_jsae
            && c.embedding.recommender.next_item()
            && c.ppo.tanh_mean
            && !c.ppo.normalize_obs)
    {
        return Err(
            "ppo.recommender.mean_at_next_item is for --env recommender --algo jsae with \
             embedding.recommender.next_item_coef > 0 (the head whose output the mean starts \
             at), ppo.tanh_mean = true (the head's tanh) and ppo.normalize_obs = false (the \
             head's output as it is)"
                .into(),
        );
    }
    Ok(())
}

/// `[embedding]` keys every run directory's config.toml holds (a whole dump of the settings).
const DUMPED: [&str; 8] = [
    "state_dim",
    "action_dim",
    "lr",
    "batch_size",
    "pretrain_transitions",
    "pretrain_epochs",
    "replay_capacity",
    "update_lr",
];

/// A run directory's config.toml from before `logged_targets` existed ran with the item
/// bought as the logged passes' target: it is set so. One from before
/// `[embedding.recommender]` existed (a whole `[embedding]` table without it) ran with the
/// item settings off: they are set so, in
/// `embedding` and in `ppo`'s `[ppo.recommender]`, so that the run reads (and its checkpoints
/// load) as it did. A settings file of a user's names only some keys and is left as it is.
pub(crate) fn items_off_in_older_dumps(
    embedding: &mut Option<toml::Value>,
    ppo: &mut Option<toml::Value>,
) {
    let Some(table) = embedding.as_mut().and_then(toml::Value::as_table_mut) else {
        return;
    };
    if !DUMPED.iter().all(|k| table.contains_key(*k)) {
        return;
    }
    if let Some(items) = table
        .get_mut("recommender")
        .and_then(toml::Value::as_table_mut)
    {
        // a dump from before `logged_targets` taught the head the item bought
        if !items.contains_key("logged_targets") {
            items.insert(
                "logged_targets".into(),
                toml::Value::String("bought".into()),
            );
            items.insert("logged_ahead_share".into(), toml::Value::Float(0.0));
        }
        return;
    }
    let mut off = toml::Table::new();
    off.insert("next_item_coef".into(), toml::Value::Float(0.0));
    off.insert("pair_buckets".into(), toml::Value::Integer(0));
    off.insert("logged_pretrain_epochs".into(), toml::Value::Integer(0));
    table.insert("recommender".into(), toml::Value::Table(off));
    let ppo = ppo.get_or_insert_with(|| toml::Value::Table(toml::Table::new()));
    if let Some(ppo) = ppo.as_table_mut() {
        let sub = ppo
            .entry("recommender")
            .or_insert_with(|| toml::Value::Table(toml::Table::new()));
        if let Some(sub) = sub.as_table_mut() {
            sub.entry("mean_at_next_item")
                .or_insert(toml::Value::Boolean(false));
        }
    }
}

#[cfg(test)]
mod tests {
    use crate::{Algo, EnvName, TrainConfig};

    fn items_on(env: EnvName, algo: Algo) -> TrainConfig {
        let mut c = TrainConfig::defaults(env, algo);
        c.embedding.recommender.next_item_coef = 1.0;
        c.embedding.recommender.pair_buckets = 1024;
        c.embedding.recommender.logged_pretrain_epochs = 2;
        c.ppo.recommender.mean_at_next_item = true;
        c
    }

    #[test]
    fn the_item_settings_are_the_recommenders_jsae_only() {
        let c = items_on(EnvName::Recommender, Algo::Jsae);
        c.validate().expect("the recommender's JSAE takes them");
        assert_eq!(
            c.embedding.policy_input_dim(),
            c.embedding.state_dim + c.embedding.action_dim
        );
        for (env, algo) in [
            (EnvName::Recommender, Algo::Ae),
            (EnvName::Gridworld, Algo::Jsae),
        ] {
            let reason = items_on(env, algo)
                .validate()
                .expect_err("refused")
                .to_string();
            assert!(reason.contains("embedding.recommender"), "{reason}");
        }
        let mut c = items_on(EnvName::Recommender, Algo::Jsae);
        c.embedding.recommender.logged_pretrain_epochs = 0;
        c.embedding.recommender.next_item_coef = 0.0;
        let reason = c.validate().expect_err("no head to start at").to_string();
        assert!(reason.contains("mean_at_next_item"), "{reason}");
        c.ppo.recommender.mean_at_next_item = false;
        c.validate().expect("pair rows alone");
        assert_eq!(c.embedding.policy_input_dim(), c.embedding.state_dim);
        c.embedding.recommender.logged_pretrain_epochs = 3;
        let reason = c.validate().expect_err("logs need the head").to_string();
        assert!(reason.contains("logged_pretrain_epochs"), "{reason}");
        c.embedding.recommender.logged_pretrain_epochs = 0;
        c.embedding.recommender.next_item_coef = f64::NAN;
        assert!(c.validate().is_err());
    }

    #[test]
    fn states_ahead_need_a_counted_target_and_a_sane_share() {
        let mut c = items_on(EnvName::Recommender, Algo::Jsae);
        c.embedding.recommender.logged_targets = super::LoggedTargets::Bought;
        c.embedding.recommender.logged_ahead_share = 0.5;
        let reason = c.validate().expect_err("bought targets").to_string();
        assert!(reason.contains("logged_ahead_share"), "{reason}");
        for targets in [
            super::LoggedTargets::Counted,
            super::LoggedTargets::CountedBest,
            super::LoggedTargets::Lookahead,
        ] {
            c.embedding.recommender.logged_targets = targets;
            c.validate().expect("counted targets take states ahead");
        }
        for share in [-0.1, 4.5, f64::NAN] {
            c.embedding.recommender.logged_ahead_share = share;
            let reason = c.validate().expect_err("out of range").to_string();
            assert!(reason.contains("between 0 and 4"), "{reason}");
        }
        let parsed: super::RecommenderEmbeddingConfig =
            toml::from_str("logged_targets = \"counted-best\"").expect("parses");
        assert_eq!(parsed.logged_targets, super::LoggedTargets::CountedBest);
        let parsed: super::RecommenderEmbeddingConfig =
            toml::from_str("logged_targets = \"lookahead\"").expect("parses");
        assert_eq!(parsed.logged_targets, super::LoggedTargets::Lookahead);
        c.embedding.recommender.logged_ahead_share = 0.5;
        for boost in [0.5, -1.0, f64::INFINITY, f64::NAN] {
            c.embedding.recommender.lookahead_boost = boost;
            let reason = c.validate().expect_err("no lift").to_string();
            assert!(reason.contains("lookahead_boost"), "{reason}");
        }
        for boost in [0.0, 1.0, 3.0] {
            c.embedding.recommender.lookahead_boost = boost;
            c.validate().expect("measured or a lift");
        }
    }

    #[test]
    fn a_dump_from_before_logged_targets_reads_as_it_ran() {
        let dumped: String = super::DUMPED.iter().map(|k| format!("{k} = 1\n")).collect();
        let text = format!("{dumped}[recommender]\nnext_item_coef = 1.0\n");
        let mut embedding = Some(toml::Value::Table(toml::from_str(&text).expect("toml")));
        let mut ppo = None;
        super::items_off_in_older_dumps(&mut embedding, &mut ppo);
        let items = &embedding.expect("kept")["recommender"];
        assert_eq!(items["logged_targets"].as_str(), Some("bought"));
        assert_eq!(items["logged_ahead_share"].as_float(), Some(0.0));
        // a user's file of some keys is left as it is
        let mut partial = Some(toml::Value::Table(
            toml::from_str("[recommender]\nnext_item_coef = 1.0\n").expect("toml"),
        ));
        super::items_off_in_older_dumps(&mut partial, &mut ppo);
        assert!(
            partial.expect("kept")["recommender"]
                .get("logged_targets")
                .is_none()
        );
    }
}
