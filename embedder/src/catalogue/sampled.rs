//! The sampled softmax of catalogue-scale training: each row's cross-entropy over the value
//! it should predict and `K` values drawn for the whole minibatch from a known proposal `Q`,
//! every logit less `ln(K Q(v))` (the sampling-probability, or logQ, correction: with it the
//! sampled loss's gradient estimates the full softmax's, Jean et al. 2015 and Bengio and
//! Senecal 2008). A drawn value equal to a row's own target is masked in that row. Where
//! the values are no more than `K`, every one is a candidate and the loss is the exact
//! softmax's.
//!
//! Two heads score candidates: T's linear one, `h . w_v + b_v`, and the next-item head's
//! distance, `-s |h - z_v|^2`. The gradients are computed here (at `h`, at each candidate's
//! row, at the bias and the scale) and reach the tables as sparse rows.

use ndarray::{Array2, ArrayView2, Axis};
use rand::Rng;
use rand_chacha::ChaCha8Rng;

use crate::model::wide_softmax::{cross_entropy_grad, times};

/// Recent targets the proposal remembers.
const RECENT: usize = 1 << 16;
/// A masked logit: its softmax weight and gradient are exactly 0.
const MASKED: f32 = -1e30;

/// The distribution negatives are drawn from: half uniform over the values, half the most
/// recent targets (a ring of them), so an item is drawn about as often as it is bought and
/// every item now and then. Each value's probability is known exactly from the ring's
/// counts, as the correction needs.
#[derive(Debug, Clone)]
pub(crate) struct Proposal {
    values: usize,
    ring: Vec<u32>,
    at: usize,
    counts: Vec<u32>,
}

impl Proposal {
    /// A proposal over `0..values`, uniform until targets are observed.
    pub(crate) fn new(values: usize) -> Self {
        Self {
            values: values.max(1),
            ring: Vec::new(),
            at: 0,
            counts: vec![0; values.max(1)],
        }
    }

    /// Remembers `targets` (values past the range are ignored).
    pub(crate) fn observe(&mut self, targets: &[u32]) {
        for &t in targets.iter().filter(|&&t| (t as usize) < self.values) {
            if self.ring.len() < RECENT {
                self.ring.push(t);
            } else {
                self.counts[self.ring[self.at] as usize] -= 1;
                self.ring[self.at] = t;
                self.at = (self.at + 1) % RECENT;
            }
            self.counts[t as usize] += 1;
        }
    }

    /// `Q(v)`.
    pub(crate) fn probability(&self, v: u32) -> f64 {
        let uniform = 1.0 / self.values as f64;
        match self.ring.len() {
            0 => uniform,
            n => 0.5 * uniform + 0.5 * f64::from(self.counts[v as usize]) / n as f64,
        }
    }

    /// `k` values drawn from `Q`, with replacement.
    fn draw(&self, k: usize, rng: &mut ChaCha8Rng) -> Vec<u32> {
        (0..k)
            .map(|_| {
                if self.ring.is_empty() || rng.random_bool(0.5) {
                    rng.random_range(0..self.values as u32)
                } else {
                    self.ring[rng.random_range(0..self.ring.len())]
                }
            })
            .collect()
    }
}

/// What a minibatch's rows are scored against.
#[derive(Debug, Clone)]
pub(crate) struct Candidates {
    /// The values every row scores: all of them (exact), or the draws.
    pub(crate) shared: Vec<u32>,
    /// Each row's target value.
    pub(crate) targets: Vec<u32>,
    /// `ln(K Q(v))` of each shared value and of each target (empty when exact).
    shared_log_q: Vec<f32>,
    target_log_q: Vec<f32>,
    /// Whether the targets are scored among the draws (not every value).
    sampled: bool,
}

impl Candidates {
    /// `negatives` draws from `proposal` for the rows' `targets`; every value where there
    /// are no more than `negatives`.
    pub(crate) fn draw(
        proposal: &Proposal,
        negatives: usize,
        targets: Vec<u32>,
        rng: &mut ChaCha8Rng,
    ) -> Self {
        if proposal.values <= negatives {
            return Self {
                shared: (0..proposal.values as u32).collect(),
                targets,
                shared_log_q: Vec::new(),
                target_log_q: Vec::new(),
                sampled: false,
            };
        }
        let shared = proposal.draw(negatives, rng);
        let log_q = |v: u32| (negatives as f64 * proposal.probability(v)).ln() as f32;
        Self {
            shared_log_q: shared.iter().map(|&v| log_q(v)).collect(),
            target_log_q: targets.iter().map(|&v| log_q(v)).collect(),
            shared,
            targets,
            sampled: true,
        }
    }
}

/// How a head scores a row `h` against a candidate's row `z`.
#[derive(Debug, Clone, Copy)]
pub(crate) enum Score {
    /// `h . z + bias`.
    Linear,
    /// `-scale |h - z|^2`.
    Distance { scale: f32 },
}

/// The candidates' rows as a head scores them: the shared ones `[K, w]`, each row's target's
/// `[B, w]`, their biases (linear head), and which shared ones exist in the head's table
/// (the next-item head has no row for "no item").
pub(crate) struct Rows {
    pub(crate) shared: Array2<f32>,
    pub(crate) targets: Array2<f32>,
    pub(crate) shared_bias: Vec<f32>,
    pub(crate) target_bias: Vec<f32>,
    pub(crate) valid: Vec<bool>,
}

/// The loss and its gradients: at `h` (`[B, w]`), at the shared and the target rows as
/// scored, at their biases, and at the distance head's log-scale.
pub(crate) struct HeadGrad {
    pub(crate) loss: f32,
    pub(crate) d_h: Array2<f32>,
    pub(crate) d_shared: Array2<f32>,
    pub(crate) d_targets: Array2<f32>,
    pub(crate) d_shared_bias: Vec<f32>,
    pub(crate) d_target_bias: Vec<f32>,
    pub(crate) d_log_scale: f32,
}

/// The mean cross-entropy of the rows of `h` over `c` under `score`, and its gradients.
pub(crate) fn sampled_cross_entropy(
    h: ArrayView2<'_, f32>,
    rows: &Rows,
    score: Score,
    c: &Candidates,
) -> HeadGrad {
    let (b, k) = (h.nrows(), rows.shared.nrows());
    let sampled = c.sampled;
    let off = usize::from(sampled);
    // the shared part of every row's scores, [B, K]
    let mut raw = times(h, rows.shared.t());
    let h_sq = h.map_axis(Axis(1), |r| r.dot(&r));
    let z_sq = rows.shared.map_axis(Axis(1), |r| r.dot(&r));
    match score {
        Score::Linear => {
            for mut r in raw.rows_mut() {
                for (v, &bias) in r.iter_mut().zip(&rows.shared_bias) {
                    *v += bias;
                }
            }
        }
        Score::Distance { scale } => {
            for (i, mut r) in raw.rows_mut().into_iter().enumerate() {
                for (j, v) in r.iter_mut().enumerate() {
                    *v = -scale * (h_sq[i] + z_sq[j] - 2.0 * *v);
                }
            }
        }
    }
    let target_raw: Vec<f32> = (0..b)
        .map(|i| match (sampled, score) {
            (false, _) => 0.0,
            (true, Score::Linear) => h.row(i).dot(&rows.targets.row(i)) + rows.target_bias[i],
            (true, Score::Distance { scale }) => {
                let d = &h.row(i) - &rows.targets.row(i);
                -scale * d.dot(&d)
            }
        })
        .collect();
    let cols = k + off;
    let mut logits = Array2::<f32>::zeros((b, cols));
    let mut column = Vec::with_capacity(b);
    for i in 0..b {
        let mut out = logits.row_mut(i);
        if sampled {
            out[0] = target_raw[i] - c.target_log_q[i];
            column.push(0);
        } else {
            column.push(c.targets[i]);
        }
        for j in 0..k {
            let hit = sampled && c.shared[j] == c.targets[i];
            out[off + j] = if rows.valid[j] && !hit {
                raw[[i, j]] - c.shared_log_q.get(j).copied().unwrap_or(0.0)
            } else {
                MASKED
            };
        }
    }
    let slice = logits
        .as_slice_mut()
        .unwrap_or_else(|| unreachable!("a new array is contiguous"));
    let (loss, _) = cross_entropy_grad(slice, cols, &column);
    let g = logits; // the gradient at the logits, already divided by B
    let gs = g.slice_axis(Axis(1), ndarray::Slice::from(off..));
    let gt: Vec<f32> = (0..b)
        .map(|i| if sampled { g[[i, 0]] } else { 0.0 })
        .collect();
    let mut d_h = times(gs, rows.shared.view());
    let mut d_shared = times(gs.t(), h);
    let mut d_targets = Array2::zeros((b, h.ncols()));
    let mut out = HeadGrad {
        loss,
        d_h: Array2::zeros((0, 0)),
        d_shared: Array2::zeros((0, 0)),
        d_targets: Array2::zeros((0, 0)),
        d_shared_bias: Vec::new(),
        d_target_bias: Vec::new(),
        d_log_scale: 0.0,
    };
    match score {
        Score::Linear => {
            for (i, &g) in gt.iter().enumerate() {
                d_h.row_mut(i).scaled_add(g, &rows.targets.row(i));
                d_targets.row_mut(i).scaled_add(g, &h.row(i));
            }
            out.d_shared_bias = gs.sum_axis(Axis(0)).to_vec();
            out.d_target_bias = gt;
        }
        Score::Distance { scale } => {
            // d/dh of -s|h - z|^2 is 2s (z - h), d/dz is 2s (h - z), d/d(ln s) the score
            let two_s = 2.0 * scale;
            let row_sums = gs.sum_axis(Axis(1));
            let col_sums = gs.sum_axis(Axis(0));
            for i in 0..b {
                d_h.row_mut(i).scaled_add(-row_sums[i], &h.row(i));
                let d = &rows.targets.row(i) - &h.row(i);
                d_h.row_mut(i).scaled_add(gt[i], &d);
                d_targets.row_mut(i).scaled_add(-gt[i] * two_s, &d);
            }
            d_h *= two_s;
            for j in 0..k {
                d_shared
                    .row_mut(j)
                    .scaled_add(-col_sums[j], &rows.shared.row(j));
            }
            d_shared *= two_s;
            let shared_part: f32 = gs
                .iter()
                .zip(raw.iter())
                .map(|(&g, &r)| if g == 0.0 { 0.0 } else { g * r })
                .sum();
            let target_part: f32 = gt.iter().zip(&target_raw).map(|(g, r)| g * r).sum();
            out.d_log_scale = shared_part + target_part;
        }
    }
    out.d_h = d_h;
    out.d_shared = d_shared;
    out.d_targets = d_targets;
    out
}
