//! A complete batch of fragments flattened for minibatching: advantages by GAE (terminated
//! and truncated kept apart), returns, old values and log-probabilities; and one minibatch,
//! as tensors (the burn update) or in reused host buffers (the fused update).

use burn::tensor::{Device, Tensor};
use jsae_nn as nn;
use jsae_nn::{HostInput, SparseRows};
use jsae_wire::{ActionBatch, RolloutFragment};
use ndarray::{Array2, ArrayView2};

use crate::PpoConfig;
use crate::fused::{HostMinibatch, HostPolicy};
use crate::gae::{GaeStep, gae};
use crate::normalise::RewardScaler;
use jsae_agent::Policy;

/// A batch flattened for minibatching: `[n]` rows of x, actions, old log-probs, advantages,
/// returns and old values.
pub(super) struct Batch {
    pub(super) x_dim: usize,
    pub(super) x: Vec<f32>,
    /// `x` as the network reads it ([`NetworkInput::new`]): picked from the inputs of the
    /// critic's bootstrap pass (the steps' rows with the truncation and tail rows), so
    /// whether it is kept sparse is decided over those.
    pub(super) input: NetworkInput,
    pub(super) actions: ActionBatch,
    pub(super) logp: Vec<f32>,
    pub(super) adv: Vec<f32>,
    pub(super) returns: Vec<f32>,
    pub(super) values: Vec<f32>,
    /// The item bought after each step ([`next_purchases`]; [`NO_TARGET`] where there is
    /// none), or empty when `ppo.recommender.next_purchase_coef` is 0.
    pub(super) next_purchase: Vec<u32>,
}

/// A step with no next purchase (an episode that terminated there, or an input that holds no
/// item).
pub(crate) const NO_TARGET: u32 = u32::MAX;

/// The item bought after each step of a fragment, for the self-supervised next-purchase loss:
/// the newest factor of the next state (its last one-hot block of `n + 1` values: the `n`
/// items, then "none"), read from the next step's input, the truncation's bootstrap input, or
/// the fragment's tail input.
fn next_purchases(f: &RolloutFragment, x_dim: usize, n: usize, out: &mut Vec<u32>) {
    let item = |x: &[f32]| -> u32 {
        let block = &x[x.len().saturating_sub(n + 1)..];
        block
            .iter()
            .position(|&v| v > 0.5)
            .filter(|&k| k < n)
            .map_or(NO_TARGET, |k| k as u32)
    };
    let t_len = f.len();
    let mut cut = 0;
    for t in 0..t_len {
        let next = if f.truncated[t] {
            cut += 1;
            Some(&f.truncated_next_x[(cut - 1) * x_dim..cut * x_dim])
        } else if f.terminated[t] {
            None
        } else if t + 1 < t_len {
            Some(&f.x[(t + 1) * x_dim..(t + 2) * x_dim])
        } else {
            Some(&f.last_next_x[..x_dim])
        };
        out.push(next.map_or(NO_TARGET, item));
    }
}

pub(super) struct Minibatch {
    pub(super) x: Tensor<2>,
    pub(super) actions: ActionBatch,
    pub(super) old_logp: Tensor<1>,
    pub(super) adv: Tensor<1>,
    pub(super) returns: Tensor<1>,
    pub(super) old_values: Tensor<1>,
    /// The next purchases ([`NO_TARGET`]: none), empty when the loss is off.
    pub(super) next_purchase: Vec<u32>,
}

/// The batch's raw input rows, kept between updates: they are megabytes (2,048 one-hot rows
/// of 1,600 are 13 MB), and memory freshly mapped for each update cost more in page faults
/// than the copies into it. (The network's view of them, sparse rows or normalised dense
/// ones, is built anew: a few KB for one-hot rows.)
#[derive(Debug, Default)]
pub(super) struct BatchBuffers {
    /// Every input of the fragments (steps, truncation bootstraps, tails).
    all_x: Vec<f32>,
    /// The batch's `x`, back from the last batch.
    x: Vec<f32>,
}

impl BatchBuffers {
    /// Takes back the buffers of a batch that is done with.
    pub(super) fn recycle(&mut self, batch: Batch) {
        self.x = batch.x;
    }
}

/// A fragment's steps for GAE: each step's reward and value, and the value after it: the
/// next step's, a truncated episode's bootstrap (`cut_v`, in order), or the value after the
/// fragment (`tail_v`).
fn gae_steps(
    f: &RolloutFragment,
    v: &[f32],
    cut_v: &[f32],
    tail_v: f32,
    ends: &[bool],
) -> Vec<GaeStep> {
    let t_len = f.len();
    let mut cut = 0;
    (0..t_len)
        .map(|t| {
            let next_value = if f.truncated[t] {
                cut += 1;
                cut_v[cut - 1]
            } else if t + 1 < t_len {
                v[t + 1]
            } else {
                tail_v
            };
            GaeStep {
                reward: f.rewards[t],
                value: v[t],
                next_value,
                terminated: f.terminated[t],
                episode_end: ends[t],
            }
        })
        .collect()
}

impl Batch {
    pub(super) fn build(
        policy: &Policy,
        fragments: Vec<RolloutFragment>,
        config: &PpoConfig,
        mut scaler: Option<&mut RewardScaler>,
        buffers: &mut BatchBuffers,
    ) -> Self {
        let x_dim = policy.input_dim();
        // One critic pass over every x, truncation bootstrap x and tail x.
        let all_x = &mut buffers.all_x;
        all_x.clear();
        for f in &fragments {
            all_x.extend_from_slice(&f.x);
            all_x.extend_from_slice(&f.truncated_next_x);
            all_x.extend_from_slice(&f.last_next_x);
        }
        let inputs = NetworkInput::new(
            all_x,
            x_dim,
            obs_stats(policy).as_ref(),
            policy.pair_feature(),
        );
        let values = HostPolicy::values(policy, inputs.host());

        let mut x = std::mem::take(&mut buffers.x);
        x.clear();
        // the batch's rows among all the inputs
        let mut rows = Vec::new();
        let mut out = Batch {
            x_dim,
            x,
            input: NetworkInput::Dense(Array2::zeros((0, x_dim))),
            actions: match &fragments.first().map(|f| &f.actions) {
                Some(ActionBatch::Continuous { dim, .. }) => ActionBatch::Continuous {
                    dim: *dim,
                    data: Vec::new(),
                },
                _ => ActionBatch::Discrete(Vec::new()),
            },
            logp: Vec::new(),
            adv: Vec::new(),
            returns: Vec::new(),
            values: Vec::new(),
            next_purchase: Vec::new(),
        };
        let purchase_items = match policy.head() {
            jsae_agent::PolicyHead::Categorical { n }
                if config.recommender.next_purchase_coef > 0.0 && x_dim > n =>
            {
                Some(n)
            }
            _ => None,
        };
        let mut offset = 0;
        for mut f in fragments {
            let t_len = f.len();
            let cuts = f.truncated.iter().filter(|&&t| t).count();
            let v = &values[offset..offset + t_len];
            let cut_v = &values[offset + t_len..offset + t_len + cuts];
            let tail_v = values[offset + t_len + cuts];
            rows.extend(offset..offset + t_len);
            offset += t_len + cuts + 1;
            let ends: Vec<bool> = f
                .terminated
                .iter()
                .zip(&f.truncated)
                .map(|(a, b)| *a || *b)
                .collect();
            if let Some(s) = scaler.as_deref_mut() {
                s.scale((f.actor_id, f.env_index), &mut f.rewards, &ends);
            }
            let steps = gae_steps(&f, v, cut_v, tail_v, &ends);
            let (adv, ret) = gae(&steps, config.gamma as f32, config.gae_lambda as f32);
            if let Some(n) = purchase_items {
                next_purchases(&f, x_dim, n, &mut out.next_purchase);
            }
            out.x.extend_from_slice(&f.x);
            out.actions.extend_from(&f.actions);
            out.logp.extend_from_slice(&f.logp);
            out.adv.extend(adv);
            out.returns.extend(ret);
            out.values.extend_from_slice(v);
        }
        out.input = inputs.select(&rows);
        out
    }

    pub(super) fn len(&self) -> usize {
        self.logp.len()
    }

    pub(super) fn explained_variance(&self) -> f64 {
        let n = self.returns.len().max(1) as f64;
        let mean = |v: &[f32]| v.iter().map(|&a| f64::from(a)).sum::<f64>() / n;
        let var =
            |v: &[f32], m: f64| v.iter().map(|&a| (f64::from(a) - m).powi(2)).sum::<f64>() / n;
        let diff: Vec<f32> = self
            .returns
            .iter()
            .zip(&self.values)
            .map(|(r, v)| r - v)
            .collect();
        let var_ret = var(&self.returns, mean(&self.returns));
        if var_ret <= 0.0 {
            return 0.0;
        }
        1.0 - var(&diff, mean(&diff)) / var_ret
    }

    pub(super) fn minibatch(&self, rows: &[usize], norm_adv: bool, device: &Device) -> Minibatch {
        let d = self.x_dim;
        let mut x = Vec::with_capacity(rows.len() * d);
        let mut actions = match &self.actions {
            ActionBatch::Discrete(_) => ActionBatch::Discrete(Vec::with_capacity(rows.len())),
            ActionBatch::Continuous { dim, .. } => ActionBatch::Continuous {
                dim: *dim,
                data: Vec::with_capacity(rows.len() * dim),
            },
        };
        let pick = |v: &[f32]| rows.iter().map(|&r| v[r]).collect::<Vec<f32>>();
        for &r in rows {
            x.extend_from_slice(&self.x[r * d..(r + 1) * d]);
            actions.push_row_of(&self.actions, r);
        }
        let mut adv = pick(&self.adv);
        if norm_adv {
            normalise_advantages(&mut adv);
        }
        Minibatch {
            x: nn::tensor2(x, rows.len(), d, device),
            actions,
            old_logp: nn::tensor1(pick(&self.logp), device),
            adv: nn::tensor1(adv, device),
            returns: nn::tensor1(pick(&self.returns), device),
            old_values: nn::tensor1(pick(&self.values), device),
            next_purchase: if self.next_purchase.is_empty() {
                Vec::new()
            } else {
                rows.iter().map(|&r| self.next_purchase[r]).collect()
            },
        }
    }
}

/// Per-minibatch advantage normalisation: zero mean, unit (sample) standard deviation.
fn normalise_advantages(adv: &mut [f32]) {
    if let Some(stats) = advantage_stats(adv) {
        normalise_with(adv, stats);
    }
}

/// The mean and the sample standard deviation of `adv` (none below two values).
fn advantage_stats(adv: &[f32]) -> Option<(f32, f32)> {
    if adv.len() < 2 {
        return None;
    }
    let n = adv.len() as f32;
    let mean = adv.iter().sum::<f32>() / n;
    let std = (adv.iter().map(|a| (a - mean).powi(2)).sum::<f32>() / (n - 1.0)).sqrt();
    Some((mean, std))
}

/// `(a - mean) / (std + 1e-8)` for every advantage.
fn normalise_with(adv: &mut [f32], (mean, std): (f32, f32)) {
    adv.iter_mut().for_each(|a| *a = (*a - mean) / (std + 1e-8));
}

/// Rows of `x` (`[rows, d]` row-major) normalised by `stats` (mean, variance) as
/// `jsae_nn::ObsNorm::apply` does.
fn normalised(x: &[f32], d: usize, (mean, var): &(Vec<f32>, Vec<f32>)) -> Array2<f32> {
    let rows = x.len() / d.max(1);
    let mut x = Array2::from_shape_vec((rows, d), x[..rows * d].to_vec())
        .unwrap_or_else(|_| Array2::zeros((rows, d)));
    let clip = jsae_nn::ObsNorm::CLIP;
    let std: Vec<f32> = var
        .iter()
        .map(|v| (v + jsae_nn::ObsNorm::EPS).sqrt())
        .collect();
    for mut row in x.rows_mut() {
        for ((v, m), s) in row.iter_mut().zip(mean).zip(&std) {
            *v = ((*v - m) / s).clamp(-clip, clip);
        }
    }
    x
}

/// Network inputs: dense rows, or (one-hot states) their non-zero entries.
#[derive(Debug)]
pub(super) enum NetworkInput {
    Dense(Array2<f32>),
    Sparse(SparseRows),
}

impl NetworkInput {
    /// Rows of `x` (`[rows, d]` row-major) as the network sees them: normalised by the
    /// policy's statistics if it normalises, and as their non-zero entries where at most an
    /// eighth of them are non-zero; with a pair feature (one-hot rows, no normalisation) as
    /// their entries and their crossed pair feature ([`SparseRows::crossed`]).
    pub(super) fn new(
        x: &[f32],
        d: usize,
        stats: Option<&(Vec<f32>, Vec<f32>)>,
        pair: Option<jsae_nn::PairCross>,
    ) -> Self {
        if let Some(stats) = stats {
            return Self::Dense(normalised(x, d, stats));
        }
        let rows = x.len() / d.max(1);
        let Ok(view) = ArrayView2::from_shape((rows, d), &x[..rows * d]) else {
            return Self::Dense(Array2::zeros((rows, d)));
        };
        if let Some(cross) = pair {
            return Self::Sparse(SparseRows::crossed(view, cross));
        }
        SparseRows::from_dense(view).map_or_else(|| Self::Dense(view.to_owned()), Self::Sparse)
    }

    /// Appends `other`'s rows (the same kind and width).
    ///
    /// # Panics
    /// When one is dense and the other sparse.
    pub(super) fn append(&mut self, other: Self) {
        match (self, other) {
            (Self::Dense(x), Self::Dense(o)) => {
                x.append(ndarray::Axis(0), o.view())
                    .expect("rows of one width");
            }
            (Self::Sparse(x), Self::Sparse(o)) => x.append(&o),
            _ => panic!("dense and sparse inputs appended together"),
        }
    }

    /// Rows `rows` of these inputs.
    fn select(&self, rows: &[usize]) -> Self {
        match self {
            Self::Dense(x) => Self::Dense(x.select(ndarray::Axis(0), rows)),
            Self::Sparse(x) => {
                let mut picked = SparseRows::default();
                picked.gather(x, rows);
                Self::Sparse(picked)
            }
        }
    }

    /// The inputs as the host MLP reads them.
    pub(super) fn host(&self) -> HostInput<'_> {
        match self {
            Self::Dense(x) => HostInput::Dense(x.view()),
            Self::Sparse(x) => HostInput::Sparse(x),
        }
    }
}

/// The policy's observation statistics (mean, variance), if it normalises.
fn obs_stats(policy: &Policy) -> Option<(Vec<f32>, Vec<f32>)> {
    policy.obs_stats().map(|(mean, var, _)| (mean, var))
}

/// One minibatch's rows in buffers reused between minibatches (the fused update), in parts:
/// runs of rows that [`crate::fused::HostPolicy::loss_and_grads`] shares between threads.
#[derive(Debug, Default)]
pub(super) struct HostRows {
    /// The parts' buffers; the first `used` hold the last minibatch (the others are kept for
    /// later minibatches of more parts).
    parts: Vec<PartRows>,
    used: usize,
    /// Advantages of the whole minibatch, for their normalisation.
    adv: Vec<f32>,
}

impl HostRows {
    /// Gathers `rows` of `batch` in `parts` runs, with `x` the batch's
    /// [`Batch::input`]; advantages are normalised over all the rows.
    pub(super) fn fill(
        &mut self,
        batch: &Batch,
        x: &NetworkInput,
        rows: &[usize],
        norm_adv: bool,
        parts: usize,
    ) {
        self.adv.clear();
        self.adv.extend(rows.iter().map(|&r| batch.adv[r]));
        let stats = if norm_adv {
            advantage_stats(&self.adv)
        } else {
            None
        };
        let per = rows.len().div_ceil(parts.max(1)).max(1);
        self.used = rows.chunks(per).len().max(1);
        if self.parts.len() < self.used {
            self.parts.resize_with(self.used, PartRows::default);
        }
        for (part, rows) in self.parts.iter_mut().zip(rows.chunks(per)) {
            part.fill(batch, x, rows, stats);
        }
    }

    /// The columns the last minibatch's sparse inputs use, ascending and each once, into
    /// `out` (cleared first; nothing for dense inputs).
    pub(super) fn sparse_columns(&self, out: &mut Vec<u32>) {
        out.clear();
        for part in &self.parts[..self.used] {
            if part.sparse_input {
                part.sparse.columns_into(out);
            }
        }
        out.sort_unstable();
        out.dedup();
    }

    /// The parts as the fused loss reads them.
    pub(super) fn views(&self) -> Vec<HostMinibatch<'_>> {
        self.parts[..self.used].iter().map(PartRows::view).collect()
    }
}

/// A run of a minibatch's rows.
#[derive(Debug, Default)]
struct PartRows {
    x: Array2<f32>,
    sparse: SparseRows,
    sparse_input: bool,
    continuous: Vec<f32>,
    discrete: Vec<u32>,
    old_logp: Vec<f32>,
    adv: Vec<f32>,
    returns: Vec<f32>,
    old_values: Vec<f32>,
    next_purchase: Vec<u32>,
}

impl PartRows {
    /// Gathers `rows`; advantages normalised with `adv_stats` (mean, std) where given.
    fn fill(
        &mut self,
        batch: &Batch,
        x: &NetworkInput,
        rows: &[usize],
        adv_stats: Option<(f32, f32)>,
    ) {
        match x {
            NetworkInput::Dense(x) => {
                self.sparse_input = false;
                if self.x.dim() != (rows.len(), x.ncols()) {
                    self.x = Array2::zeros((rows.len(), x.ncols()));
                }
                for (mut dst, &r) in self.x.rows_mut().into_iter().zip(rows) {
                    dst.assign(&x.row(r));
                }
            }
            NetworkInput::Sparse(x) => {
                self.sparse_input = true;
                self.sparse.gather(x, rows);
            }
        }
        self.continuous.clear();
        self.discrete.clear();
        match &batch.actions {
            ActionBatch::Continuous { dim, data } => {
                for &r in rows {
                    self.continuous
                        .extend_from_slice(&data[r * dim..(r + 1) * dim]);
                }
            }
            ActionBatch::Discrete(a) => self.discrete.extend(rows.iter().map(|&r| a[r])),
        }
        let pick = |dst: &mut Vec<f32>, src: &[f32]| {
            dst.clear();
            dst.extend(rows.iter().map(|&r| src[r]));
        };
        pick(&mut self.old_logp, &batch.logp);
        pick(&mut self.adv, &batch.adv);
        pick(&mut self.returns, &batch.returns);
        pick(&mut self.old_values, &batch.values);
        self.next_purchase.clear();
        if !batch.next_purchase.is_empty() {
            self.next_purchase
                .extend(rows.iter().map(|&r| batch.next_purchase[r]));
        }
        if let Some(stats) = adv_stats {
            normalise_with(&mut self.adv, stats);
        }
    }

    /// The rows as the fused loss reads them.
    fn view(&self) -> HostMinibatch<'_> {
        HostMinibatch {
            x: if self.sparse_input {
                HostInput::Sparse(&self.sparse)
            } else {
                HostInput::Dense(self.x.view())
            },
            continuous: &self.continuous,
            discrete: &self.discrete,
            old_logp: &self.old_logp,
            adv: &self.adv,
            returns: &self.returns,
            old_values: &self.old_values,
            next_purchase: &self.next_purchase,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_next_purchase_is_the_next_states_newest_item() {
        // 3 items: two one-hot blocks of 4 (items 0..3, then "none")
        let (n, x_dim) = (3, 8);
        let state = |before: usize, last: usize| {
            let mut x = vec![0.0; x_dim];
            x[before] = 1.0;
            x[4 + last] = 1.0;
            x
        };
        // steps: (none, 2) -> 1, (2, 1) -> truncated, next (1, 0); then a new episode at
        // (none, 3 = "none" is not an item) ... the tail's next state (0, 1)
        let x: Vec<f32> = [state(3, 2), state(2, 1), state(3, 0)].concat();
        let f = RolloutFragment {
            actor_id: 0,
            env_index: 0,
            policy_version: 1,
            embedding_version: 0,
            actor_env_steps: 3,
            x_dim,
            x,
            actions: ActionBatch::Discrete(vec![0, 0, 0]),
            logp: vec![0.0; 3],
            rewards: vec![0.0; 3],
            terminated: vec![false; 3],
            truncated: vec![false, true, false],
            truncated_next_x: state(1, 0),
            last_next_x: state(0, 3),
            episodes: Vec::new(),
            actor_incarnation: 1,
            visit_keys: Vec::new(),
        };
        let mut out = Vec::new();
        next_purchases(&f, x_dim, n, &mut out);
        assert_eq!(out, [1, 0, NO_TARGET]);
        let ended = RolloutFragment {
            terminated: vec![false, false, true],
            truncated: vec![false; 3],
            truncated_next_x: Vec::new(),
            ..f
        };
        out.clear();
        next_purchases(&ended, x_dim, n, &mut out);
        assert_eq!(out, [1, 0, NO_TARGET], "no next state after a termination");
    }
}
