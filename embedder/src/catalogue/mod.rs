//! Catalogue-scale training of JSAE's model (`embedding.sampled_softmax_from`): at a
//! million items a dense softmax over the items is 16 GB of logits per minibatch of 4,096,
//! and a dense Adam step moves every row of tables no minibatch touched. Here the item-sized
//! tables, phi's (`[factors x values, m]`), g's (`[items, d]`) and T's output rows over the
//! next state's last factor (`[values, width]` and a bias), live on the host; a minibatch
//! gathers the rows it reads, the two heads (T's and the next-item head's) score the item
//! that follows and `negatives` drawn items ([`sampled`]), and lazy Adam steps only the rows
//! that took a gradient (with weight decay on those rows). The rest of the model
//! (phi's pair rows, T's hidden layer, the next-item head and its scale) stays in burn and
//! its optimiser, reached through the tables' rows as leaves of the graph.
//!
//! T predicts the next state's last factor only: in the recommender the other factors are
//! the state's own items, shifted, and a prediction of them would cost a softmax over the
//! catalogue each for nothing to learn. T's output rows live only here: snapshots carry
//! phi, g and the heads the policy reads (the tables written from the host), and an embedder
//! restarted from a snapshot draws T's rows afresh.

mod sampled;

use burn::module::Param;
use burn::optim::{GradientsParams, ModuleOptimizer};
use burn::tensor::Tensor;
use jsae_agent::EmbeddingModel;
use jsae_nn::host::{HostAdam, Rows as AdamRows, zero_rows};
use jsae_nn::{self as nn};
use jsae_wire::{ActionBatch, StateBatch, StateSpace};
use ndarray::{Array2, ArrayView2, Axis};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::model::last_factor;
use crate::model::wide_softmax::{attach, host2};
use sampled::{Candidates, HeadGrad, Proposal, Rows, Score, sampled_cross_entropy};

/// The seed of the negatives an evaluation draws (the same each time, and never the
/// training's).
const EVALUATION_SEED: u64 = 0x6576_616c;

/// A host table `[rows, width]` row-major, its gradient (zero outside the rows a step
/// touches) and those rows.
#[derive(Debug, Clone)]
struct Table {
    values: Vec<f32>,
    grad: Vec<f32>,
    width: usize,
    touched: Vec<u32>,
}

impl Table {
    fn new(values: Vec<f32>, width: usize) -> Self {
        Self {
            grad: vec![0.0; values.len()],
            values,
            width,
            touched: Vec::new(),
        }
    }

    fn rows(&self) -> usize {
        self.values.len() / self.width.max(1)
    }

    fn row(&self, r: u32) -> &[f32] {
        let w = self.width;
        &self.values[r as usize * w..(r as usize + 1) * w]
    }

    /// The rows `ids` as a `[ids, width]` array, each through `map`.
    fn gather(&self, ids: &[u32], map: impl Fn(f32) -> f32) -> Array2<f32> {
        let mut out = Array2::zeros((ids.len(), self.width));
        for (mut o, &r) in out.rows_mut().into_iter().zip(ids) {
            if (r as usize) < self.rows() {
                for (o, &v) in o.iter_mut().zip(self.row(r)) {
                    *o = map(v);
                }
            }
        }
        out
    }

    /// The values of a width-1 table at `ids` (0 past the table).
    fn column(&self, ids: &[u32]) -> Vec<f32> {
        ids.iter()
            .map(|&r| self.values.get(r as usize).copied().unwrap_or(0.0))
            .collect()
    }

    /// Adds `grads` (`[ids, width]`, or one value per id for a width of 1) into the
    /// gradient at rows `ids` (ids past the table skipped).
    fn accumulate(&mut self, ids: &[u32], grads: ArrayView2<'_, f32>) {
        let w = self.width;
        for (&r, g) in ids.iter().zip(grads.rows()) {
            if (r as usize) < self.rows() {
                let at = r as usize * w;
                for (t, &v) in self.grad[at..at + w].iter_mut().zip(g) {
                    *t += v;
                }
                self.touched.push(r);
            }
        }
    }

    /// The rows touched since the last step, ascending, once each.
    fn touched_rows(&mut self) -> Vec<u32> {
        let mut rows = std::mem::take(&mut self.touched);
        rows.sort_unstable();
        rows.dedup();
        rows
    }
}

/// The item-sized tables on the host, their lazy Adam, and the negatives' proposal.
#[derive(Debug, Clone)]
pub(crate) struct CatalogueTables {
    phi: Table,
    g: Table,
    t_weight: Table,
    t_bias: Table,
    adam: HostAdam,
    proposal: Proposal,
    rng: ChaCha8Rng,
    negatives: usize,
    /// `embedding.weight_decay`, and whether it is decoupled (AdamW's) or L2 (Adam's).
    weight_decay: (f32, bool),
}

/// One minibatch as the catalogue path reads it.
struct Batch<'a> {
    states: &'a StateBatch,
    /// The actions taken (T's input); None for logged purchases (the next-item head alone).
    actions: Option<&'a [u32]>,
    /// The next state's last factor: the item bought next.
    targets: Vec<u32>,
}

impl<'a> Batch<'a> {
    fn transitions(
        states: &'a StateBatch,
        actions: &'a ActionBatch,
        next_states: &StateBatch,
    ) -> Self {
        let ActionBatch::Discrete(actions) = actions else {
            unreachable!("a catalogue-scale model has discrete actions")
        };
        Self {
            states,
            actions: Some(actions),
            targets: last_factor(next_states).unwrap_or_default(),
        }
    }
}

/// A forward pass: the loss, the graph to differentiate (the heads' losses attached at
/// their inputs), the leaves that stand for the tables' rows, and the heads' gradients at
/// the rows they scored.
struct Forward {
    loss: f32,
    total: Option<Tensor<1>>,
    phi_sum: Tensor<2>,
    phi_rows: Vec<u32>,
    factors: usize,
    g_leaf: Option<Tensor<2>>,
    transition: Option<HeadGrad>,
    next_item: Option<(HeadGrad, Rows)>,
    /// The next-item loss's weight.
    coef: f32,
}

impl Forward {
    fn add(&mut self, t: Tensor<1>) {
        self.total = Some(match self.total.take() {
            None => t,
            Some(s) => s + t,
        });
    }
}

impl CatalogueTables {
    /// The tables of `model` (built for catalogue scale: categorical states, discrete
    /// actions, no T of its own), T's output rows drawn as a linear layer's, seeded.
    ///
    /// # Errors
    /// When the model is not of that kind.
    pub(crate) fn new(model: &EmbeddingModel, seed: u64) -> Result<Self, String> {
        let net = model.net();
        let (Some(phi), Some(g), StateSpace::Categorical { sizes }) =
            (&net.phi_table, &net.g_table, model.state_space())
        else {
            return Err(
                "catalogue-scale training needs categorical states and discrete \
                        actions (a phi table and a g table)"
                    .into(),
            );
        };
        let config = model.config();
        let (m, d) = (config.state_dim, config.action_dim);
        let values = sizes.last().copied().unwrap_or(1);
        let width = match config.transition_hidden {
            0 => m + d,
            h => h,
        };
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x6361_7461_6c6f_6775);
        let k = 1.0 / (width as f32).sqrt();
        let weights = (0..values * width)
            .map(|_| rng.random_range(-k..k))
            .collect();
        let bias = (0..values).map(|_| rng.random_range(-k..k)).collect();
        Ok(Self {
            phi: Table::new(nn::to_vec(phi.val()), m),
            g: Table::new(nn::to_vec(g.val()), d),
            t_weight: Table::new(weights, width),
            t_bias: Table::new(bias, 1),
            adam: HostAdam::new(1e-8),
            proposal: Proposal::new(values),
            rng,
            negatives: config.negatives,
            weight_decay: (config.weight_decay, config.decoupled_weight_decay),
        })
    }

    /// One step on a minibatch of transitions (T's loss and the next-item head's); the
    /// model loss before it.
    pub(crate) fn train_step(
        &mut self,
        model: &mut EmbeddingModel,
        optim: &mut ModuleOptimizer,
        states: &StateBatch,
        actions: &ActionBatch,
        next_states: &StateBatch,
        lr: f64,
    ) -> f32 {
        let batch = Batch::transitions(states, actions, next_states);
        self.step(model, optim, &batch, lr)
    }

    /// One step on logged purchases (`items[i]` bought after row `i`), the next-item loss
    /// alone; the loss before it.
    pub(crate) fn next_item_step(
        &mut self,
        model: &mut EmbeddingModel,
        optim: &mut ModuleOptimizer,
        states: &StateBatch,
        items: &[u32],
        lr: f64,
    ) -> f32 {
        let batch = Batch {
            states,
            actions: None,
            targets: items.to_vec(),
        };
        self.step(model, optim, &batch, lr)
    }

    /// The model loss on a minibatch without training (negatives drawn from a fixed seed).
    pub(crate) fn evaluate(
        &self,
        model: &EmbeddingModel,
        states: &StateBatch,
        actions: &ActionBatch,
        next_states: &StateBatch,
    ) -> f32 {
        let batch = Batch::transitions(states, actions, next_states);
        let mut rng = ChaCha8Rng::seed_from_u64(EVALUATION_SEED);
        let candidates = Candidates::draw(
            &self.proposal,
            self.negatives,
            batch.targets.clone(),
            &mut rng,
        );
        self.forward(model, &batch, &candidates).loss
    }

    /// The forward pass, the backward pass, the dense parts' step and the tables'.
    fn step(
        &mut self,
        model: &mut EmbeddingModel,
        optim: &mut ModuleOptimizer,
        batch: &Batch<'_>,
        lr: f64,
    ) -> f32 {
        self.proposal.observe(&batch.targets);
        let candidates = Candidates::draw(
            &self.proposal,
            self.negatives,
            batch.targets.clone(),
            &mut self.rng,
        );
        let f = self.forward(model, batch, &candidates);
        let Some(total) = f.total else {
            return f.loss;
        };
        if let Some(t) = &f.transition {
            self.t_weight
                .accumulate(&candidates.shared, t.d_shared.view());
            self.t_weight
                .accumulate(&candidates.targets, t.d_targets.view());
            self.t_bias
                .accumulate(&candidates.shared, column(&t.d_shared_bias).view());
            self.t_bias
                .accumulate(&candidates.targets, column(&t.d_target_bias).view());
        }
        if let Some((n, rows)) = &f.next_item {
            // through g's tanh: (1 - z^2) at each row as scored
            let through = |d: &Array2<f32>, z: &Array2<f32>| f.coef * d * &z.mapv(|z| 1.0 - z * z);
            self.g.accumulate(
                &candidates.shared,
                through(&n.d_shared, &rows.shared).view(),
            );
            self.g.accumulate(
                &candidates.targets,
                through(&n.d_targets, &rows.targets).view(),
            );
        }
        let grads = total.backward();
        let m = self.phi.width;
        if let Some(d) = f.phi_sum.grad(&grads) {
            let d = host_rows(nn::to_vec(d), m);
            let each: Vec<usize> = (0..f.phi_rows.len()).map(|i| i / f.factors).collect();
            self.phi
                .accumulate(&f.phi_rows, d.select(Axis(0), &each).view());
        }
        if let (Some(leaf), Some(actions)) = (&f.g_leaf, batch.actions)
            && let Some(d) = leaf.grad(&grads)
        {
            let d = host_rows(nn::to_vec(d), self.g.width);
            self.g.accumulate(actions, d.view());
        }
        let dense = GradientsParams::from_grads(grads, model.net());
        let net = optim.step(lr, model.net().clone(), dense);
        model.set_net(net);
        self.step_tables(lr as f32);
        f.loss
    }

    /// The model loss of `batch` against `candidates`, and what its backward pass needs.
    fn forward(
        &self,
        model: &EmbeddingModel,
        batch: &Batch<'_>,
        candidates: &Candidates,
    ) -> Forward {
        let device = model.device().clone();
        let b = batch.targets.len();
        let factors = match batch.states {
            StateBatch::Categorical { factors, .. } => (*factors).max(1),
            StateBatch::Real { .. } => unreachable!("a catalogue-scale model's states"),
        };
        // phi: each state's rows summed, a leaf of the graph
        let phi_rows = model.phi_rows(batch.states);
        let m = self.phi.width;
        let mut summed = vec![0.0f32; b * m];
        for (i, &r) in phi_rows.iter().enumerate() {
            let out = &mut summed[(i / factors) * m..(i / factors + 1) * m];
            for (o, &v) in out.iter_mut().zip(self.phi.row(r)) {
                *o += v;
            }
        }
        let phi_sum = nn::tensor2(summed, b, m, &device).require_grad();
        let x = model.phi_of_row_sums(phi_sum.clone(), &phi_rows, factors);
        let mut f = Forward {
            loss: 0.0,
            total: None,
            phi_sum,
            phi_rows,
            factors,
            g_leaf: None,
            transition: None,
            next_item: None,
            coef: 1.0,
        };
        // T: the next state's last factor from concat(x, g(a))
        if let Some(actions) = batch.actions {
            let d = self.g.width;
            let pre = self.g.gather(actions, |v| v).into_raw_vec_and_offset().0;
            let leaf = nn::tensor2(pre, b, d, &device).require_grad();
            let input = Tensor::cat(vec![x.clone(), leaf.clone().tanh()], 1);
            let h = match &model.net().transition_in {
                Some(hidden) => hidden.forward(input).tanh(),
                None => input,
            };
            let rows = Rows {
                shared: self.t_weight.gather(&candidates.shared, |v| v),
                targets: self.t_weight.gather(&candidates.targets, |v| v),
                shared_bias: self.t_bias.column(&candidates.shared),
                target_bias: self.t_bias.column(&candidates.targets),
                valid: vec![true; candidates.shared.len()],
            };
            let grad = sampled_cross_entropy(host2(&h).view(), &rows, Score::Linear, candidates);
            f.loss += grad.loss;
            f.add(attach(grad.loss, vec![(h, grad.d_h.clone())]));
            f.g_leaf = Some(leaf);
            f.transition = Some(grad);
            f.coef = model.config().recommender.next_item_coef as f32;
        }
        // the next-item head: -s |h(x) - g(i)|^2 over the item bought and the draws
        if let (Some(head), Some(log_scale)) =
            (&model.net().next_item, &model.net().next_item_log_scale)
        {
            let h = head.forward(x).tanh();
            let scale = nn::to_vec(log_scale.val())[0].exp();
            let items = self.g.rows();
            let rows = Rows {
                shared: self.g.gather(&candidates.shared, f32::tanh),
                targets: self.g.gather(&candidates.targets, f32::tanh),
                shared_bias: Vec::new(),
                target_bias: Vec::new(),
                valid: candidates
                    .shared
                    .iter()
                    .map(|&v| (v as usize) < items)
                    .collect(),
            };
            let grad = sampled_cross_entropy(
                host2(&h).view(),
                &rows,
                Score::Distance { scale },
                candidates,
            );
            let coef = f.coef;
            f.loss += coef * grad.loss;
            f.add(attach(
                coef * grad.loss,
                vec![
                    (h, coef * &grad.d_h),
                    (
                        log_scale.val().unsqueeze_dim(0),
                        Array2::from_elem((1, 1), coef * grad.d_log_scale),
                    ),
                ],
            ));
            f.next_item = Some((grad, rows));
        }
        f
    }

    /// Lazy Adam on the rows that took a gradient (after weight decay on them);
    /// their gradients zeroed.
    fn step_tables(&mut self, lr: f32) {
        let tables = [
            &mut self.phi,
            &mut self.g,
            &mut self.t_weight,
            &mut self.t_bias,
        ];
        let touched: Vec<Vec<u32>> = tables.map(|t| t.touched_rows()).into_iter().collect();
        let mut tables = [
            &mut self.phi,
            &mut self.g,
            &mut self.t_weight,
            &mut self.t_bias,
        ];
        // weight decay on those rows: decoupled (`p -= lr wd p`) or L2 (`g += wd p`)
        let (wd, decoupled) = self.weight_decay;
        for (t, rows) in tables.iter_mut().zip(&touched) {
            let w = t.width;
            for &r in rows {
                let at = r as usize * w..(r as usize + 1) * w;
                let (values, grad) = (&mut t.values[at.clone()], &mut t.grad[at]);
                for (v, g) in values.iter_mut().zip(grad) {
                    if decoupled {
                        *v *= 1.0 - lr * wd;
                    } else {
                        *g += wd * *v;
                    }
                }
            }
        }
        let widths: Vec<usize> = tables.iter().map(|t| t.width).collect();
        let rows: Vec<Option<AdamRows<'_>>> = touched
            .iter()
            .zip(&widths)
            .map(|(rows, &width)| Some(AdamRows { width, rows }))
            .collect();
        let (mut params, mut grads): (Vec<&mut [f32]>, Vec<&mut [f32]>) = tables
            .iter_mut()
            .map(|t| (t.values.as_mut_slice(), t.grad.as_mut_slice()))
            .unzip();
        let read: Vec<&[f32]> = grads.iter().map(|g| &**g).collect();
        self.adam.step_rows(lr, 1.0, &mut params, &read, &rows);
        for (g, r) in grads.iter_mut().zip(rows.iter().flatten()) {
            zero_rows(g, *r);
        }
    }

    /// `model` with phi's and g's tables as trained here (what a snapshot carries).
    pub(crate) fn write_into(&self, model: &EmbeddingModel) -> EmbeddingModel {
        let mut out = model.clone();
        let device = model.device().clone();
        let net = out.net_mut();
        let table = |t: &Table| {
            Param::from_tensor(nn::tensor2(t.values.clone(), t.rows(), t.width, &device))
        };
        net.phi_table = Some(table(&self.phi));
        net.g_table = Some(table(&self.g));
        out
    }

    /// Takes phi's and g's tables from `model` (a restored snapshot or a warm start; T's
    /// rows stay as they were drawn, the moments start afresh).
    pub(crate) fn read_from(&mut self, model: &EmbeddingModel) {
        if let Some(phi) = &model.net().phi_table {
            self.phi = Table::new(nn::to_vec(phi.val()), self.phi.width);
        }
        if let Some(g) = &model.net().g_table {
            self.g = Table::new(nn::to_vec(g.val()), self.g.width);
        }
        self.adam = HostAdam::new(1e-8);
    }

    /// Every item's embedding `tanh(g)`, `[n, d]` row-major.
    pub(crate) fn action_embeddings(&self) -> (Vec<f32>, usize) {
        (
            self.g.values.iter().map(|v| v.tanh()).collect(),
            self.g.width,
        )
    }
}

/// Row-major values as `[len / width, width]`.
fn host_rows(values: Vec<f32>, width: usize) -> Array2<f32> {
    let rows = values.len() / width.max(1);
    Array2::from_shape_vec((rows, width), values).unwrap_or_else(|_| unreachable!("whole rows"))
}

/// Values as a `[len, 1]` column.
fn column(values: &[f32]) -> Array2<f32> {
    host_rows(values.to_vec(), 1)
}

#[cfg(test)]
mod tests;
