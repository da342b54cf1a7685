//! The recommender's PPO settings (`[ppo.recommender]`): what only the recommender's
//! categorical policy over the items of its state has a use for. Older settings files name
//! these keys in `[ppo]` itself; they are moved into `[ppo.recommender]` as they are read
//! ([`nest_legacy_keys`]), so a run directory of before reads as it did.

use serde::{Deserialize, Serialize};

/// Most buckets of the crossed pair feature (`ppo.recommender.pair_buckets`; 131,072 in use).
pub const MAX_PAIR_BUCKETS: usize = 1 << 22;

/// The recommender's PPO settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RecommenderPpoConfig {
    /// Weight of a self-supervised loss for the recommender's categorical policy (its
    /// actions are the items of the state's factors): the cross-entropy of the policy's
    /// softmax against the item bought next, read from the next state, added to the PPO loss
    /// (as in self-supervised RL for recommendation, Xin et al. 2020). 0: off.
    pub next_purchase_coef: f64,
    /// Passes of pre-training on logged purchases before the policy plays (0: none; the
    /// recommender's categorical policy, fused update): the next-purchase cross-entropy
    /// alone, over every step of the sessions the simulator's model is built from (never the
    /// held-out ones), at `logged_pretrain_lr`. A shop has its purchase logs before it has
    /// a policy.
    pub logged_pretrain_epochs: usize,
    /// Adam's learning rate at the start of `logged_pretrain_epochs`, annealed linearly to 0
    /// over them.
    pub logged_pretrain_lr: f64,
    /// Add to the categorical policy's logits the log of a next-purchase estimate counted
    /// from the same logged purchases (an interpolated n-gram: a pair's counts smoothed
    /// towards its last item's, those towards all purchases'), fixed, so the network learns
    /// only what the counts get wrong (the recommender's PPO, fused update, no input
    /// normalisation). The counts travel in the policy's bytes.
    pub logged_prior: bool,
    /// Buckets of a crossed feature of one-hot states (0: none): the last two factors'
    /// values (the recommender's item before the last and its last item) hashed together
    /// into one of this many columns, appended to the input of the actor and of the critic,
    /// whose weights start at zero. A pair's own row of the first layer lets the networks
    /// tell pairs apart that share an item, which a narrow layer over the items alone
    /// cannot. Trained with a lazy Adam on the first layers (only the rows a minibatch's
    /// inputs pick are stepped); the fused update only.
    pub pair_buckets: usize,
    /// The crossed feature's input value (1: a plain one-hot). Adam steps a weight by about
    /// the learning rate whatever its gradient's size, so this multiplies how fast a pair's
    /// own row changes the network's output: a pair seen a few times must count.
    pub pair_scale: f32,
    /// Buckets per pair (1 or more): with two, a pair's feature is the sum of two rows, which
    /// two pairs share only if both of their buckets collide.
    pub pair_hashes: usize,
    /// JSAE with the embedder's next-item head (`embedding.recommender.next_item_coef`): the
    /// Gaussian's mean starts at the item the head finds most likely next. A linear path
    /// from the head's part of the policy's input to the mean starts at the identity (the
    /// rest of the actor adds to it from near zero) and is trained with the rest: a warm
    /// start that PPO may move away from, not a fixed prior.
    pub mean_at_next_item: bool,
}

impl Default for RecommenderPpoConfig {
    fn default() -> Self {
        Self {
            next_purchase_coef: 0.0,
            logged_pretrain_epochs: 0,
            logged_pretrain_lr: 1e-3,
            logged_prior: false,
            pair_buckets: 0,
            pair_scale: 1.0,
            pair_hashes: 1,
            mean_at_next_item: false,
        }
    }
}

/// The keys of [`RecommenderPpoConfig`], which older settings files set in `[ppo]`.
pub const KEYS: [&str; 7] = [
    "next_purchase_coef",
    "logged_pretrain_epochs",
    "logged_pretrain_lr",
    "logged_prior",
    "pair_buckets",
    "pair_scale",
    "pair_hashes",
];

impl RecommenderPpoConfig {
    /// Whether a fresh policy learns from logged purchases (`logged_prior`,
    /// `logged_pretrain_epochs`).
    pub fn wants_logs(&self) -> bool {
        self.logged_prior || self.logged_pretrain_epochs > 0
    }

    /// Checks the settings (`fused`: `ppo.update` is the fused update; `normalize_obs`:
    /// `[ppo]`'s); the reason names the bad key.
    pub fn validate(&self, fused: bool, normalize_obs: bool) -> Result<(), String> {
        if self.pair_buckets > MAX_PAIR_BUCKETS {
            return Err(format!(
                "ppo.recommender.pair_buckets is {}, at most {MAX_PAIR_BUCKETS}",
                self.pair_buckets
            ));
        }
        if !(self.next_purchase_coef >= 0.0 && self.next_purchase_coef.is_finite()) {
            return Err("ppo.recommender.next_purchase_coef must be a finite number >= 0".into());
        }
        if self.pair_buckets > 0 && (!fused || normalize_obs) {
            return Err(
                "ppo.recommender.pair_buckets needs ppo.update = \"fused\" and ppo.normalize_obs = false \
                 (the crossed feature is built for the host update's one-hot inputs); set \
                 ppo.recommender.pair_buckets = 0 for the others"
                    .into(),
            );
        }
        if !(self.pair_scale > 0.0 && self.pair_scale.is_finite()) {
            return Err(format!(
                "ppo.recommender.pair_scale must be a positive number, got {}",
                self.pair_scale
            ));
        }
        if !(1..=8).contains(&self.pair_hashes) {
            return Err(format!(
                "ppo.recommender.pair_hashes must be between 1 and 8, got {}",
                self.pair_hashes
            ));
        }
        if self.pair_buckets > (1 << 24) {
            return Err(format!(
                "ppo.recommender.pair_buckets must be at most 16777216, got {}",
                self.pair_buckets
            ));
        }
        if self.logged_pretrain_epochs > 0 && !fused {
            return Err(
                "ppo.recommender.logged_pretrain_epochs needs ppo.update = \"fused\"; set \
                 ppo.recommender.logged_pretrain_epochs = 0 for the burn update"
                    .into(),
            );
        }
        if self.logged_prior && (!fused || normalize_obs) {
            return Err(
                "ppo.recommender.logged_prior needs ppo.update = \"fused\" and ppo.normalize_obs = false \
                 (the prior is keyed by the host update's one-hot inputs); set \
                 ppo.recommender.logged_prior = false for the others"
                    .into(),
            );
        }
        Ok(())
    }
}

/// A `[ppo]` table of an older settings file with these keys in `[ppo.recommender]`, where
/// they are now (a key given in both places: the sub-table's wins).
pub(crate) fn nest_legacy_keys(mut ppo: toml::Value) -> toml::Value {
    let Some(table) = ppo.as_table_mut() else {
        return ppo;
    };
    let moved: Vec<(String, toml::Value)> = KEYS
        .iter()
        .filter_map(|k| table.remove(*k).map(|v| (k.to_string(), v)))
        .collect();
    if moved.is_empty() {
        return ppo;
    }
    let sub = table
        .entry("recommender")
        .or_insert_with(|| toml::Value::Table(toml::Table::new()));
    if let Some(sub) = sub.as_table_mut() {
        for (k, v) in moved {
            sub.entry(k).or_insert(v);
        }
    }
    ppo
}
