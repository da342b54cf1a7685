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
