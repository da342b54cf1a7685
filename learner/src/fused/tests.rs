//! The host loss and gradient against burn's autodiff on the same weights and minibatch,
//! for each head, with and without the tanh mean and the value clip.

use super::*;
use crate::ppo::clipped_surrogate_loss;
use crate::{PolicyEval, PpoConfig};
use burn::tensor::Tensor;
use jsae_nn::{BurnDevice, DeviceKind};
use jsae_wire::ActionBatch;
use ndarray::Array2;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn close(a: &[f32], b: &[f32], what: &str) {
    assert_eq!(a.len(), b.len(), "{what}");
    let scale = b.iter().fold(0.0f32, |m, v| m.max(v.abs())).max(1e-6);
    for (i, (x, y)) in a.iter().zip(b).enumerate() {
        assert!(
            (x - y).abs() <= 1e-4 * scale + 1e-7,
            "{what}[{i}]: host {x}, burn {y} (scale {scale})"
        );
    }
}

fn check(head: PolicyHead, tanh_mean: bool, clip_value_loss: bool) {
    check_at(head, tanh_mean, clip_value_loss, -0.3);
}

fn check_at(head: PolicyHead, tanh_mean: bool, clip_value_loss: bool, init_log_std: f32) {
    check_with(head, tanh_mean, clip_value_loss, init_log_std, 0.0, false);
}

/// `next_purchase_coef` > 0 (categorical): a next purchase for most samples, none for some;
/// `wide_actor`: the actor's input-to-output path, set to non-zero weights.
fn check_with(
    head: PolicyHead,
    tanh_mean: bool,
    clip_value_loss: bool,
    init_log_std: f32,
    next_purchase_coef: f32,
    wide_actor: bool,
) {
    let device = DeviceKind::Flex.train_device();
    let mut config = PpoConfig {
        tanh_mean,
        clip_value_loss,
        init_log_std,
        wide_actor,
        ..PpoConfig::default()
    };
    config.normalize_obs = false;
    let input = 7;
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let mut policy = Policy::new(&config, input, head, &mut rng, &device);
    if wide_actor {
        let mut host = HostPolicy::from_policy(&policy, None);
        if let Some(skip) = host.params.actor.skip.as_mut() {
            skip.mapv_inplace(|_| rng.random_range(-0.3..0.3));
        }
        host.params.write_into(&mut policy);
    }
    let b = 48;
    let m = random_minibatch(&policy, b, next_purchase_coef, &mut rng);
    let Minibatch {
        x,
        actions,
        old_logp,
        adv,
        returns,
        old_values,
        next_purchase,
    } = &m;
    let cfg = LossConfig {
        clip: 0.2,
        clip_value_loss,
        ent_coef: 0.05,
        vf_coef: 0.5,
        next_purchase_coef,
    };

    let loss = burn_loss(&policy, &m, clip_value_loss, next_purchase_coef);
    let burn_loss = jsae_nn::to_vec(loss.clone())[0];
    let grads = loss.backward();

    let host = HostPolicy::from_policy(&policy, None);
    let x_host = Array2::from_shape_vec((b, input), x.clone()).expect("shape");
    let (continuous, discrete) = match actions {
        ActionBatch::Continuous { data, .. } => (data.as_slice(), &[][..]),
        ActionBatch::Discrete(a) => (&[][..], a.as_slice()),
    };
    // rows `r` of the minibatch
    let rows = |r: std::ops::Range<usize>| {
        // the values of rows `r` in `v`, whose rows are `v.len() / b` long (or empty)
        fn of<'a, T>(v: &'a [T], b: usize, r: &std::ops::Range<usize>) -> &'a [T] {
            let w = v.len() / b;
            &v[w * r.start..w * r.end]
        }
        HostMinibatch {
            x: HostInput::Dense(x_host.slice_axis(ndarray::Axis(0), r.clone().into())),
            continuous: of(continuous, b, &r),
            discrete: of(discrete, b, &r),
            old_logp: &old_logp[r.clone()],
            adv: &adv[r.clone()],
            returns: &returns[r.clone()],
            old_values: &old_values[r.clone()],
            next_purchase: of(next_purchase, b, &r),
        }
    };
    let mut work = FusedWork::new(&host);
    // a smaller minibatch first: the buffers are reshaped, and nothing of it is left over
    host.loss_and_grads(&[rows(0..b / 2)], cfg, &mut work);
    // the minibatch whole, and split into runs of rows (as threads share it): the same
    for split in [vec![0, b], vec![0, 20, b], vec![0, 7, 30, b]] {
        let parts: Vec<_> = split.windows(2).map(|w| rows(w[0]..w[1])).collect();
        let what = format!(
            "{head:?} tanh_mean {tanh_mean} clip_value {clip_value_loss} parts {}",
            parts.len()
        );
        let loss = host.loss_and_grads(&parts, cfg, &mut work);
        compare(&policy, &grads, &work, loss.total, burn_loss, &what);
    }
}

/// A random minibatch for `policy`, behaviour log-probabilities near its own (so some
/// ratios are clipped and some not); a next purchase for most samples where
/// `next_purchase_coef` > 0 (categorical), none for some.
struct Minibatch {
    x: Vec<f32>,
    actions: ActionBatch,
    old_logp: Vec<f32>,
    adv: Vec<f32>,
    returns: Vec<f32>,
    old_values: Vec<f32>,
    next_purchase: Vec<u32>,
}

fn random_minibatch(
    policy: &Policy,
    b: usize,
    next_purchase_coef: f32,
    rng: &mut ChaCha8Rng,
) -> Minibatch {
    let input = policy.input_dim();
    let x: Vec<f32> = (0..b * input)
        .map(|_| rng.random_range(-2.0..2.0))
        .collect();
    let actions = match policy.head() {
        PolicyHead::Gaussian { dim } => ActionBatch::Continuous {
            dim,
            data: (0..b * dim).map(|_| rng.random_range(-1.2..1.2)).collect(),
        },
        PolicyHead::Categorical { n } => {
            ActionBatch::Discrete((0..b).map(|_| rng.random_range(0..n as u32)).collect())
        }
    };
    let current = jsae_nn::to_vec(
        policy
            .evaluate(
                jsae_nn::tensor2(x.clone(), b, input, policy.device()),
                &actions,
            )
            .logp,
    );
    let old_logp: Vec<f32> = current
        .iter()
        .map(|l| l + rng.random_range(-0.4..0.4))
        .collect();
    let adv: Vec<f32> = (0..b).map(|_| rng.random_range(-1.5..1.5)).collect();
    let returns: Vec<f32> = (0..b).map(|_| rng.random_range(-1.0..1.0)).collect();
    let old_values: Vec<f32> = (0..b).map(|_| rng.random_range(-1.0..1.0)).collect();
    let next_purchase: Vec<u32> = match policy.head() {
        PolicyHead::Categorical { n } if next_purchase_coef > 0.0 => (0..b)
            .map(|i| {
                if i % 5 == 3 {
                    u32::MAX
                } else {
                    rng.random_range(0..n as u32)
                }
            })
            .collect(),
        _ => Vec::new(),
    };
    Minibatch {
        x,
        actions,
        old_logp,
        adv,
        returns,
        old_values,
        next_purchase,
    }
}

/// The loss exactly as `ppo::update`'s burn path builds it.
fn burn_loss(
    policy: &Policy,
    m: &Minibatch,
    clip_value_loss: bool,
    next_purchase_coef: f32,
) -> Tensor<1> {
    let (b, input) = (m.adv.len(), policy.input_dim());
    let eval = policy.evaluate(
        jsae_nn::tensor2(m.x.clone(), b, input, policy.device()),
        &m.actions,
    );
    let log_ratio = eval.logp - jsae_nn::tensor1(m.old_logp.clone(), policy.device());
    let pg = clipped_surrogate_loss(
        log_ratio,
        jsae_nn::tensor1(m.adv.clone(), policy.device()),
        0.2,
    );
    let ret = jsae_nn::tensor1(m.returns.clone(), policy.device());
    let v_loss = if clip_value_loss {
        let old = jsae_nn::tensor1(m.old_values.clone(), policy.device());
        let unclipped = (eval.value.clone() - ret.clone()).square();
        let clipped_v = old.clone() + (eval.value - old).clamp(-0.2, 0.2);
        let clipped = (clipped_v - ret).square();
        unclipped.max_pair(clipped).mean().mul_scalar(0.5)
    } else {
        (eval.value - ret).square().mean().mul_scalar(0.5)
    };
    let mut loss: Tensor<1> = pg - eval.entropy.mean().mul_scalar(0.05) + v_loss.mul_scalar(0.5);
    if !m.next_purchase.is_empty() {
        // -log pi(t | x) of the samples with a purchase, over all b samples
        let with: Vec<usize> = (0..b).filter(|&i| m.next_purchase[i] != u32::MAX).collect();
        let xs: Vec<f32> = with
            .iter()
            .flat_map(|&i| m.x[i * input..(i + 1) * input].to_vec())
            .collect();
        let targets = ActionBatch::Discrete(with.iter().map(|&i| m.next_purchase[i]).collect());
        let logp = policy
            .evaluate(
                jsae_nn::tensor2(xs, with.len(), input, policy.device()),
                &targets,
            )
            .logp;
        loss = loss + logp.sum().neg().mul_scalar(next_purchase_coef / b as f32);
    }
    loss
}

/// The host's loss and gradients in `work` against burn's.
fn compare(
    policy: &Policy,
    grads: &burn::tensor::Gradients,
    work: &FusedWork,
    host_loss: f32,
    burn_loss: f32,
    what: &str,
) {
    let g = work.grads();
    close(&[host_loss], &[burn_loss], &format!("{what}: loss"));
    let (actor, critic, log_std) = policy.parts();
    for (name, mlp, host_grads) in [("actor", actor, &g.actor), ("critic", critic, &g.critic)] {
        for (i, layer) in mlp.layers().iter().enumerate() {
            let gw = layer.weight.val().grad(grads).map(jsae_nn::to_vec);
            let gw = gw.unwrap_or_else(|| vec![0.0; host_grads.w[i].len()]);
            close(
                &host_grads.weight(i).iter().copied().collect::<Vec<_>>(),
                &gw,
                &format!("{what}: {name} weight {i}"),
            );
            let bias = layer.bias.as_ref().expect("biases");
            let gb = bias.val().grad(grads).map(jsae_nn::to_vec);
            let gb = gb.unwrap_or_else(|| vec![0.0; host_grads.b[i].len()]);
            close(
                &host_grads.b[i].to_vec(),
                &gb,
                &format!("{what}: {name} bias {i}"),
            );
        }
    }
    if let Some(skip) = actor.skip() {
        let gw = skip.weight.val().grad(grads).map(jsae_nn::to_vec);
        let host_skip = g.actor.skip.as_ref().expect("a skip gradient");
        close(
            &host_skip.iter().copied().collect::<Vec<_>>(),
            &gw.expect("burn's skip gradient"),
            &format!("{what}: actor skip"),
        );
    }
    if matches!(policy.head(), PolicyHead::Gaussian { .. }) {
        let gls = log_std
            .val()
            .grad(grads)
            .map(jsae_nn::to_vec)
            .expect("log-std gradient");
        close(
            g.log_std.as_slice().expect("contiguous"),
            &gls,
            &format!("{what}: log_std"),
        );
    }
}

#[test]
fn gaussian_loss_and_gradients_equal_burn_autodiff() {
    for tanh_mean in [true, false] {
        for clip_value_loss in [false, true] {
            check(PolicyHead::Gaussian { dim: 3 }, tanh_mean, clip_value_loss);
        }
        // a std beyond the entropy bonus's cap (with a tanh mean), and one just below it
        let cap = jsae_settings::EMBEDDED_ENTROPY_LOG_STD_MAX;
        check_at(PolicyHead::Gaussian { dim: 3 }, tanh_mean, false, cap + 0.3);
        check_at(PolicyHead::Gaussian { dim: 3 }, tanh_mean, false, cap - 0.1);
    }
}

#[test]
fn the_entropy_bonus_counts_the_std_up_to_its_cap() {
    let device = DeviceKind::Flex.train_device();
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let dim = 2;
    let x = jsae_nn::tensor2(vec![0.1; 4], 1, 4, &device);
    let actions = ActionBatch::Continuous {
        dim,
        data: vec![0.0; dim],
    };
    let at = |log_std: f32| (0.5 + jsae_agent::policy::HALF_LOG_2PI + log_std) * dim as f32;
    let cap = jsae_settings::EMBEDDED_ENTROPY_LOG_STD_MAX;
    // (tanh mean, the setting, initial log-std, the entropy the bonus sees)
    for (tanh_mean, setting, init_log_std, want) in [
        (true, None, cap + 0.4, at(cap)),
        (true, None, -0.3, at(-0.3)),
        (false, None, cap + 0.4, at(cap + 0.4)),
        (true, Some(0.0), 0.4, at(0.0)),
        (false, Some(-0.1), 0.4, at(-0.1)),
    ] {
        let config = PpoConfig {
            tanh_mean,
            init_log_std,
            entropy_log_std_max: setting,
            ..PpoConfig::default()
        };
        let head = PolicyHead::Gaussian { dim };
        let policy = Policy::new(&config, 4, head, &mut rng, &device);
        let entropy = jsae_nn::to_vec(policy.evaluate(x.clone(), &actions).entropy)[0];
        assert!(
            (entropy - want).abs() < 1e-5,
            "{tanh_mean} {setting:?} {init_log_std}: {entropy}"
        );
    }
}

#[test]
fn categorical_loss_and_gradients_equal_burn_autodiff() {
    for clip_value_loss in [false, true] {
        check(PolicyHead::Categorical { n: 11 }, false, clip_value_loss);
    }
    // 48 x 1,500 logits: the softmax rows and the output layer's products are split
    // between threads, two or, in a pool of three, three
    check(PolicyHead::Categorical { n: 1500 }, false, true);
    rayon::ThreadPoolBuilder::new()
        .num_threads(3)
        .build()
        .expect("a pool of three")
        .install(|| check(PolicyHead::Categorical { n: 2100 }, false, true));
}

#[test]
fn the_next_purchase_loss_and_its_gradients_equal_burn_autodiff() {
    for n in [11, 1500] {
        check_with(PolicyHead::Categorical { n }, false, true, -0.3, 0.7, false);
    }
}

#[test]
fn a_wide_actors_loss_and_gradients_equal_burn_autodiff() {
    for n in [11, 1500] {
        check_with(PolicyHead::Categorical { n }, false, true, -0.3, 0.7, true);
    }
    check_with(
        PolicyHead::Gaussian { dim: 3 },
        true,
        false,
        -0.3,
        0.0,
        true,
    );
}

#[test]
fn one_hot_inputs_split_into_parts_give_the_whole_dense_minibatchs_gradients() {
    for wide_actor in [false, true] {
        one_hot_parts(wide_actor);
    }
}

fn one_hot_parts(wide_actor: bool) {
    let device = DeviceKind::Flex.train_device();
    let config = PpoConfig {
        normalize_obs: false,
        wide_actor,
        ..PpoConfig::default()
    };
    let (input, b, n) = (40, 30, 9);
    let head = PolicyHead::Categorical { n };
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let policy = Policy::new(&config, input, head, &mut rng, &device);
    let host = HostPolicy::from_policy(&policy, None);
    let mut x = Array2::zeros((b, input));
    for r in 0..b {
        x[[r, rng.random_range(0..input)]] = 1.0;
    }
    let sparse = jsae_nn::SparseRows::from_dense(x.view()).expect("one-hot rows");
    let discrete: Vec<u32> = (0..b).map(|_| rng.random_range(0..n as u32)).collect();
    let values = |rng: &mut ChaCha8Rng| -> Vec<f32> {
        (0..b).map(|_| rng.random_range(-1.0..1.0)).collect()
    };
    let (old_logp, adv, returns, old_values) = (
        values(&mut rng).iter().map(|v| v - 2.2).collect::<Vec<_>>(),
        values(&mut rng),
        values(&mut rng),
        values(&mut rng),
    );
    let cfg = LossConfig {
        clip: 0.2,
        clip_value_loss: true,
        ent_coef: 0.05,
        vf_coef: 0.5,
        next_purchase_coef: 0.0,
    };
    let whole = HostMinibatch {
        x: HostInput::Dense(x.view()),
        continuous: &[],
        discrete: &discrete,
        old_logp: &old_logp,
        adv: &adv,
        returns: &returns,
        old_values: &old_values,
        next_purchase: &[],
    };
    let mut work = FusedWork::new(&host);
    let expected_loss = host
        .loss_and_grads(std::slice::from_ref(&whole), cfg, &mut work)
        .total;
    let expected = work.grads().clone();
    for split in [vec![0, 13, b], vec![0, 4, 21, b]] {
        let parts: Vec<jsae_nn::SparseRows> = split
            .windows(2)
            .map(|w| {
                let mut part = jsae_nn::SparseRows::default();
                part.gather(&sparse, &(w[0]..w[1]).collect::<Vec<_>>());
                part
            })
            .collect();
        let minibatches: Vec<_> = split
            .windows(2)
            .zip(&parts)
            .map(|(w, part)| HostMinibatch {
                x: HostInput::Sparse(part),
                discrete: &discrete[w[0]..w[1]],
                old_logp: &old_logp[w[0]..w[1]],
                adv: &adv[w[0]..w[1]],
                returns: &returns[w[0]..w[1]],
                old_values: &old_values[w[0]..w[1]],
                ..whole.clone()
            })
            .collect();
        // overwritten, or (for a lazy optimiser) added into buffers whose picked rows are
        // cleared after each step: twice, so the clearing is checked too
        let mut lazy = FusedWork::new(&host);
        lazy.accumulate_input_rows = true;
        for (work, what) in [(&mut work, "overwritten"), (&mut lazy, "accumulated")] {
            for round in 0..2 {
                let loss = host.loss_and_grads(&minibatches, cfg, work).total;
                let what = format!("{} parts, {what}, round {round}", parts.len());
                close(&[loss], &[expected_loss], &what);
                for (k, (g, e)) in work
                    .grads()
                    .slices()
                    .iter()
                    .zip(expected.slices())
                    .enumerate()
                {
                    close(g, e, &format!("{what}: parameter slice {k}"));
                }
                let mut touched = Vec::new();
                parts.iter().for_each(|p| p.columns_into(&mut touched));
                touched.sort_unstable();
                touched.dedup();
                if work.accumulate_input_rows {
                    work.clear_grad_rows(&host.params.input_rows(&touched));
                }
            }
        }
    }
}
