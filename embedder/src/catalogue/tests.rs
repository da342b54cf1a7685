//! The sampled softmax against the graph's full softmax where every value is a candidate,
//! the proposal's probabilities against its draws, and catalogue-scale training end to end
//! on a small catalogue: the loss falls, the snapshot loads into an acting model without T.

use super::sampled::{Candidates, Proposal, Rows, Score, sampled_cross_entropy};
use super::*;
use crate::model::cross_entropy;
use crate::replay::Minibatch;
use crate::representation::{RepresentationModel, TrainingModel};
use burn::tensor::{Device, Int, TensorData};
use jsae_settings::{EmbeddingConfig, Representation};
use jsae_wire::ActionSpace;

const B: usize = 6;
const N: usize = 23;
const W: usize = 4;

fn device() -> Device {
    Device::flex().autodiff()
}

fn random(rows: usize, cols: usize, rng: &mut ChaCha8Rng) -> Array2<f32> {
    Array2::from_shape_fn((rows, cols), |_| rng.random_range(-1.0..1.0))
}

fn close(a: &[f32], b: &[f32]) {
    assert_eq!(a.len(), b.len());
    for (x, y) in a.iter().zip(b) {
        assert!((x - y).abs() <= 1e-5 + 1e-4 * y.abs(), "{x} against {y}");
    }
}

fn tensor(a: &Array2<f32>) -> Tensor<2> {
    let (r, c) = a.dim();
    nn::tensor2(a.iter().copied().collect(), r, c, &device()).require_grad()
}

fn exact(targets: &[u32]) -> Candidates {
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    Candidates::draw(&Proposal::new(N), N, targets.to_vec(), &mut rng)
}

#[test]
fn with_every_value_a_candidate_the_linear_head_is_the_full_softmax() {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let (h, z) = (random(B, W, &mut rng), random(N, W, &mut rng));
    let bias: Vec<f32> = (0..N).map(|_| rng.random_range(-1.0..1.0)).collect();
    let targets: Vec<u32> = (0..B).map(|_| rng.random_range(0..N as u32)).collect();
    let c = exact(&targets);
    let rows = Rows {
        shared: z.clone(),
        targets: Array2::zeros((B, W)),
        shared_bias: bias.clone(),
        target_bias: vec![0.0; B],
        valid: vec![true; N],
    };
    let got = sampled_cross_entropy(h.view(), &rows, Score::Linear, &c);
    let (ht, zt) = (tensor(&h), tensor(&z));
    let bt = nn::tensor1(bias, &device()).require_grad();
    let logits = ht.clone().matmul(zt.clone().transpose()) + bt.clone().unsqueeze_dim(0);
    let idx = targets.iter().map(|&t| i64::from(t)).collect();
    let target = Tensor::<2, Int>::from_data(TensorData::new(idx, [B, 1]), &device());
    let loss = cross_entropy(logits, target);
    close(&[got.loss], &nn::to_vec(loss.clone()));
    let grads = loss.backward();
    let grad = |t: &Tensor<2>| nn::to_vec(t.grad(&grads).expect("a gradient"));
    close(got.d_h.as_slice().expect("contiguous"), &grad(&ht));
    close(got.d_shared.as_slice().expect("contiguous"), &grad(&zt));
    close(
        &got.d_shared_bias,
        &nn::to_vec(bt.grad(&grads).expect("a gradient")),
    );
}

#[test]
fn with_every_value_a_candidate_the_distance_head_is_the_full_softmax() {
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    let (h, z) = (random(B, W, &mut rng), random(N, W, &mut rng));
    let targets: Vec<u32> = (0..B).map(|_| rng.random_range(0..N as u32 - 1)).collect();
    let c = exact(&targets);
    // the last value has no row in the head (the recommender's "no item")
    let mut valid = vec![true; N];
    valid[N - 1] = false;
    let scale = 1.7f32;
    let rows = Rows {
        shared: z.clone(),
        targets: Array2::zeros((B, W)),
        shared_bias: Vec::new(),
        target_bias: Vec::new(),
        valid,
    };
    let got = sampled_cross_entropy(h.view(), &rows, Score::Distance { scale }, &c);
    let (ht, zt) = (
        tensor(&h),
        tensor(
            &z.slice_axis(Axis(0), ndarray::Slice::from(..N - 1))
                .to_owned(),
        ),
    );
    let log_scale = nn::tensor1(vec![scale.ln()], &device()).require_grad();
    let dist = ht.clone().square().sum_dim(1) + zt.clone().square().sum_dim(1).transpose()
        - ht.clone().matmul(zt.clone().transpose()) * 2.0;
    let logits = dist * log_scale.clone().exp().reshape([1, 1]).neg();
    let idx = targets.iter().map(|&t| i64::from(t)).collect();
    let target = Tensor::<2, Int>::from_data(TensorData::new(idx, [B, 1]), &device());
    let loss = cross_entropy(logits, target);
    close(&[got.loss], &nn::to_vec(loss.clone()));
    let grads = loss.backward();
    close(
        got.d_h.as_slice().expect("contiguous"),
        &nn::to_vec(ht.grad(&grads).expect("a gradient")),
    );
    let dz = got
        .d_shared
        .slice_axis(Axis(0), ndarray::Slice::from(..N - 1))
        .to_owned();
    close(
        dz.as_slice().expect("contiguous"),
        &nn::to_vec(zt.grad(&grads).expect("a gradient")),
    );
    assert!(
        got.d_shared.row(N - 1).iter().all(|&v| v.abs() < 1e-12),
        "{:?}",
        got.d_shared.row(N - 1)
    );
    close(
        &[got.d_log_scale],
        &nn::to_vec(log_scale.grad(&grads).expect("a gradient")),
    );
}

#[test]
fn the_proposal_draws_as_often_as_it_says() {
    let mut p = Proposal::new(10);
    p.observe(&[3, 3, 3, 7]);
    let total: f64 = (0..10).map(|v| p.probability(v)).sum();
    assert!((total - 1.0).abs() < 1e-12, "{total}");
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let c = Candidates::draw(&p, 9, vec![0], &mut rng);
    assert_eq!(c.shared.len(), 9, "fewer values than draws would be exact");
    let mut counts = [0usize; 10];
    for _ in 0..20_000 {
        for v in Candidates::draw(&p, 9, vec![0], &mut rng).shared {
            counts[v as usize] += 1;
        }
    }
    for (v, &n) in counts.iter().enumerate() {
        let share = n as f64 / (20_000.0 * 9.0);
        let q = p.probability(v as u32);
        assert!(
            (share - q).abs() < 0.01,
            "value {v}: drawn {share}, said {q}"
        );
    }
}

/// A recommender-like catalogue of `n` items: a state is the last two items (or "none",
/// value `n`), and after item `i` comes item `7 i + 3 mod n`.
fn successor_batch(n: u32, rows: usize, rng: &mut ChaCha8Rng) -> Minibatch {
    let next = |i: u32| (7 * i + 3) % n;
    let (mut states, mut actions, mut nexts) = (Vec::new(), Vec::new(), Vec::new());
    for _ in 0..rows {
        let (a, b) = (rng.random_range(0..n), rng.random_range(0..n));
        states.extend([a, b]);
        actions.push(rng.random_range(0..n));
        nexts.extend([b, next(b)]);
    }
    let cat = |data| StateBatch::Categorical { factors: 2, data };
    Minibatch {
        states: cat(states),
        actions: ActionBatch::Discrete(actions),
        next_states: cat(nexts),
    }
}

#[test]
fn a_catalogue_scale_model_learns_what_follows_and_snapshots_without_t() {
    let n = 3000u32;
    let mut config = EmbeddingConfig {
        state_dim: 16,
        action_dim: 16,
        sampled_softmax_from: 1000,
        negatives: 128,
        lr: 0.01,
        ..EmbeddingConfig::default()
    };
    config.recommender.next_item_coef = 1.0;
    let states = StateSpace::Categorical {
        sizes: vec![n as usize + 1; 2],
    };
    let actions = ActionSpace::Discrete { n: n as usize };
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let model = EmbeddingModel::new(
        &config,
        Representation::Jsae,
        &states,
        &actions,
        &mut rng,
        &device(),
    );
    assert!(
        model.net().transition.is_none(),
        "T is the embedder's alone"
    );
    let mut m = TrainingModel::new(model, 5);
    assert!(m.at_catalogue_scale());
    let mut optim = burn::optim::AdamConfig::new().init();
    let fixed = successor_batch(n, 512, &mut rng);
    let before = m.evaluate(&fixed).0;
    for _ in 0..300 {
        let mb = successor_batch(n, 256, &mut rng);
        m.train_step(&mut optim, &mb, 0.01);
    }
    let after = m.evaluate(&fixed).0;
    assert!(after < 0.5 * before, "loss {before} -> {after}");
    // the snapshot loads into a model built for acting, and holds the host tables
    let bytes = m.snapshot_bytes().expect("serialises");
    let mut acting = EmbeddingModel::new(
        &config,
        Representation::Jsae,
        &states,
        &actions,
        &mut ChaCha8Rng::seed_from_u64(9),
        &Device::flex(),
    );
    acting.load_bytes(&bytes).expect("the same structure");
    let table = nn::to_vec(acting.action_table().expect("a g-table"));
    let (host, d) = m.action_embeddings().expect("discrete actions");
    assert_eq!(d, 16);
    close(&table, &host);
}

/// The sampled loss computed the plain way, in f64: each row's target (less its
/// `ln(K Q)`) against every draw that is not the target (less theirs).
fn plain_sampled_loss(
    h: &Array2<f32>,
    rows: &Rows,
    score: Score,
    c: &Candidates,
    log_kq: &dyn Fn(u32) -> f64,
) -> f64 {
    let s = |i: usize, z: ndarray::ArrayView1<'_, f32>, bias: f32| -> f64 {
        let (h, z) = (h.row(i), z);
        match score {
            Score::Linear => {
                h.iter().zip(z).map(|(a, b)| f64::from(a * b)).sum::<f64>() + f64::from(bias)
            }
            Score::Distance { scale } => {
                -f64::from(scale)
                    * h.iter()
                        .zip(z)
                        .map(|(a, b)| f64::from(a - b).powi(2))
                        .sum::<f64>()
            }
        }
    };
    let mut total = 0.0;
    for i in 0..h.nrows() {
        let t = c.targets[i];
        let bias = rows.target_bias.get(i).copied().unwrap_or(0.0);
        let picked = s(i, rows.targets.row(i), bias) - log_kq(t);
        let mut logits = vec![picked];
        for (j, &v) in c.shared.iter().enumerate() {
            if v != t && rows.valid[j] {
                let bias = rows.shared_bias.get(j).copied().unwrap_or(0.0);
                logits.push(s(i, rows.shared.row(j), bias) - log_kq(v));
            }
        }
        let max = logits.iter().copied().fold(f64::MIN, f64::max);
        let lse = max + logits.iter().map(|l| (l - max).exp()).sum::<f64>().ln();
        total += lse - picked;
    }
    total / h.nrows() as f64
}

#[test]
fn the_sampled_loss_and_its_gradients_are_the_plain_ones() {
    let mut rng = ChaCha8Rng::seed_from_u64(6);
    let values = 30;
    let mut proposal = Proposal::new(values);
    proposal.observe(&[1, 1, 1, 2, 5, 5, 9]);
    let targets: Vec<u32> = (0..B).map(|_| rng.random_range(0..values as u32)).collect();
    let k = 20;
    let c = Candidates::draw(&proposal, k, targets.clone(), &mut rng);
    assert!(
        targets.iter().any(|t| c.shared.contains(t)),
        "a draw equal to a target (masked in its row): {:?} {targets:?}",
        c.shared
    );
    let log_kq = |v: u32| (k as f64 * proposal.probability(v)).ln();
    for score in [Score::Linear, Score::Distance { scale: 1.3 }] {
        let linear = matches!(score, Score::Linear);
        let mut valid = vec![true; k];
        if !linear {
            valid[0] = false; // a draw without a row in the head
        }
        let rows = Rows {
            shared: random(k, W, &mut rng),
            targets: random(B, W, &mut rng),
            shared_bias: if linear {
                (0..k).map(|_| rng.random_range(-1.0..1.0)).collect()
            } else {
                Vec::new()
            },
            target_bias: if linear {
                (0..B).map(|_| rng.random_range(-1.0..1.0)).collect()
            } else {
                Vec::new()
            },
            valid,
        };
        let h = random(B, W, &mut rng);
        let got = sampled_cross_entropy(h.view(), &rows, score, &c);
        let plain = plain_sampled_loss(&h, &rows, score, &c, &log_kq);
        assert!(
            (f64::from(got.loss) - plain).abs() < 1e-4,
            "{} against {plain}",
            got.loss
        );
        // central differences of the plain loss at h, at the rows and at the scale
        let eps = 1e-2f32;
        let numeric = |bump: &Bump<'_>| {
            let (mut h1, mut r1, mut s1) = (h.clone(), clone_rows(&rows), score);
            bump(&mut h1, &mut r1, &mut s1, eps);
            let (mut h2, mut r2, mut s2) = (h.clone(), clone_rows(&rows), score);
            bump(&mut h2, &mut r2, &mut s2, -eps);
            (plain_sampled_loss(&h1, &r1, s1, &c, &log_kq)
                - plain_sampled_loss(&h2, &r2, s2, &c, &log_kq))
                / (2.0 * f64::from(eps))
        };
        let near = |analytic: f32, numeric: f64| {
            assert!(
                (f64::from(analytic) - numeric).abs() < 2e-3 + 1e-2 * numeric.abs(),
                "{analytic} against {numeric}"
            )
        };
        for (i, j) in [(0, 0), (B - 1, W - 1)] {
            near(got.d_h[[i, j]], numeric(&|h, _, _, e| h[[i, j]] += e));
            near(
                got.d_targets[[i, j]],
                numeric(&|_, r, _, e| r.targets[[i, j]] += e),
            );
        }
        for j in 0..k {
            near(
                got.d_shared[[j, 1]],
                numeric(&|_, r, _, e| r.shared[[j, 1]] += e),
            );
        }
        if linear {
            near(
                got.d_shared_bias[3],
                numeric(&|_, r, _, e| r.shared_bias[3] += e),
            );
            near(
                got.d_target_bias[2],
                numeric(&|_, r, _, e| r.target_bias[2] += e),
            );
        } else {
            let bump = |_: &mut Array2<f32>, _: &mut Rows, s: &mut Score, e: f32| {
                if let Score::Distance { scale } = s {
                    *scale *= e.exp();
                }
            };
            near(got.d_log_scale, numeric(&bump));
        }
    }
}

/// A change of size `eps` to one input of the plain loss.
type Bump<'a> = dyn Fn(&mut Array2<f32>, &mut Rows, &mut Score, f32) + 'a;

fn clone_rows(r: &Rows) -> Rows {
    Rows {
        shared: r.shared.clone(),
        targets: r.targets.clone(),
        shared_bias: r.shared_bias.clone(),
        target_bias: r.target_bias.clone(),
        valid: r.valid.clone(),
    }
}

/// Continuous updates at catalogue scale: after pre-training, new transitions make a new
/// version through the same sampled step.
#[test]
fn a_catalogue_scale_trainer_keeps_updating_after_pretraining() {
    let n = 500u32;
    let mut config = EmbeddingConfig {
        state_dim: 8,
        action_dim: 8,
        sampled_softmax_from: 100,
        negatives: 64,
        batch_size: 128,
        pretrain_transitions: 256,
        pretrain_epochs: 2,
        update_every: 256,
        update_steps: 3,
        ..EmbeddingConfig::default()
    };
    config.recommender.next_item_coef = 1.0;
    let states = StateSpace::Categorical {
        sizes: vec![n as usize + 1; 2],
    };
    let actions = ActionSpace::Discrete { n: n as usize };
    let mut t = crate::EmbedderTrainer::new(
        config,
        Representation::Jsae,
        &states,
        &actions,
        1,
        jsae_nn::DeviceKind::Flex,
    );
    assert!(t.model().at_catalogue_scale());
    let mut rng = ChaCha8Rng::seed_from_u64(8);
    let transitions = |rng: &mut ChaCha8Rng| {
        let mb = successor_batch(n, 256, rng);
        jsae_wire::TransitionBatch {
            actor_id: 1,
            states: mb.states,
            actions: mb.actions,
            rewards: vec![0.0; 256],
            next_states: mb.next_states,
            terminated: vec![false; 256],
        }
    };
    t.ingest(&transitions(&mut rng)).expect("valid");
    let first = t.poll().expect("serialises").expect("pre-trained");
    t.ingest(&transitions(&mut rng)).expect("valid");
    let next = t.poll().expect("serialises").expect("an update is due");
    assert_eq!((first.version, next.version), (1, 2));
    assert_ne!(first.bytes, next.bytes, "the update moved the tables");
}
