//! Property tests of every wire decoder and validator of `jsae-wire`: whatever bytes arrive,
//! decoding and checking return an answer (never a panic), what passes the checks is
//! consistent, valid messages survive the wire unchanged, and the reward bound holds exactly.

use jsae_wire::{self as wire, Reassembler, pb};
use jsae_wire::{
    ActionBatch, ActionSpace, EvalReport, FragmentBounds, RolloutFragment, StateBatch, StateSpace,
    TransitionBatch,
};
use proptest::prelude::*;
use prost::Message;

const BOUND: f32 = 1e6;

/// What a learner of policy inputs `x_dim` wide over `actions` accepts.
fn bounds(x_dim: usize, actions: ActionSpace) -> FragmentBounds {
    FragmentBounds {
        x_dim,
        actions,
        max_abs_reward: BOUND,
        logp: (-200.0, 5.0),
        max_episode_steps: u32::MAX,
    }
}

/// A fragment of one step with input `x`, log-probability `logp` and reward `reward`.
fn one_step(x: f32, logp: f32, reward: f32) -> RolloutFragment {
    RolloutFragment {
        actor_id: 0,
        env_index: 0,
        policy_version: 0,
        embedding_version: 0,
        actor_env_steps: 1,
        x_dim: 1,
        x: vec![x],
        actions: ActionBatch::Discrete(vec![0]),
        logp: vec![logp],
        rewards: vec![reward],
        terminated: vec![false],
        truncated: vec![false],
        truncated_next_x: vec![],
        last_next_x: vec![0.0],
        episodes: vec![],
        actor_incarnation: 1,
        visit_keys: Vec::new(),
    }
}

fn continuous() -> ActionSpace {
    ActionSpace::Continuous {
        dim: 2,
        low: vec![-1.0; 2],
        high: vec![1.0; 2],
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2_000))]

    #[test]
    fn arbitrary_bytes_never_panic_a_decoder_or_validator(bytes in prop::collection::vec(any::<u8>(), 0..400)) {
        if let Ok(m) = pb::RolloutFragment::decode(bytes.as_slice())
            && let Ok(f) = RolloutFragment::try_from(m)
        {
            for (x_dim, space) in [(f.x_dim, ActionSpace::Discrete { n: 8 }), (2, continuous())] {
                if f.validate(&bounds(x_dim, space)).is_ok() {
                    let n = f.rewards.len();
                    prop_assert_eq!(f.x.len(), n * x_dim);
                    prop_assert!(f.rewards.iter().all(|r| r.is_finite() && r.abs() <= BOUND));
                    prop_assert_eq!((f.logp.len(), f.terminated.len(), f.truncated.len()), (n, n, n));
                    prop_assert!(n > 0 && f.logp.iter().all(|l| (-200.0..=5.0).contains(l)));
                    prop_assert!(f.episodes.len() <= n);
                }
            }
        }
        if let Ok(m) = pb::TransitionBatch::decode(bytes.as_slice())
            && let Ok(t) = TransitionBatch::try_from(m)
        {
            for states in [StateSpace::discrete(16), StateSpace::Real { dim: 2 }] {
                let _ = t.validate(&states, &ActionSpace::Discrete { n: 8 }, BOUND);
            }
        }
        if let Ok(m) = pb::EvalReport::decode(bytes.as_slice()) {
            let _ = EvalReport::from_wire(m);
        }
        if let Ok(m) = pb::SnapshotChunk::decode(bytes.as_slice()) {
            let mut chunks = Reassembler::default();
            let _ = chunks.push(m.clone());
            let _ = chunks.push(m);
        }
        for m in [
            pb::PolicyEvent::decode(bytes.as_slice()).map(|_| ()),
            pb::WatchRequest::decode(bytes.as_slice()).map(|_| ()),
            pb::Session::decode(bytes.as_slice()).map(|_| ()),
            pb::RecommendRequest::decode(bytes.as_slice()).map(|_| ()),
        ] {
            let _ = m;
        }
    }

    #[test]
    fn valid_fragments_pass_and_survive_the_wire(
        n in 1usize..24,
        x_dim in 1usize..4,
        seed in any::<u64>(),
        reward in -BOUND..=BOUND,
    ) {
        let value = |i: usize| ((seed.wrapping_add(i as u64) % 1000) as f32) / 100.0 - 5.0;
        let cuts = (0..n).filter(|i| i % 5 == 4).count();
        let f = RolloutFragment {
            actor_id: seed % 7,
            env_index: (seed % 3) as u32,
            policy_version: seed % 11,
            embedding_version: seed % 13,
            actor_env_steps: seed % 1_000,
            x_dim,
            x: (0..n * x_dim).map(value).collect(),
            actions: ActionBatch::Discrete((0..n).map(|i| (i % 8) as u32).collect()),
            logp: (0..n).map(|i| -value(i).abs()).collect(),
            rewards: (0..n).map(|i| if i == 0 { reward } else { value(i) }).collect(),
            terminated: (0..n).map(|i| i % 7 == 6).collect(),
            truncated: (0..n).map(|i| i % 5 == 4).collect(),
            truncated_next_x: (0..cuts * x_dim).map(value).collect(),
            last_next_x: (0..x_dim).map(value).collect(),
            episodes: vec![],
            actor_incarnation: seed | 1,
            visit_keys: Vec::new(),
        };
        prop_assert_eq!(f.validate(&bounds(x_dim, ActionSpace::Discrete { n: 8 })), Ok(()));
        let wire = pb::RolloutFragment::from(f.clone()).encode_to_vec();
        let back = RolloutFragment::try_from(pb::RolloutFragment::decode(wire.as_slice()).expect("decodes"))
            .expect("converts");
        prop_assert_eq!(back, f);
    }

    #[test]
    fn the_reward_bound_holds_exactly(reward in any::<f32>()) {
        let f = one_step(0.0, -1.0, reward);
        let ok = f.validate(&bounds(1, ActionSpace::Discrete { n: 2 })).is_ok();
        prop_assert_eq!(ok, reward.is_finite() && reward.abs() <= BOUND);
    }

    #[test]
    fn the_log_prob_range_and_the_input_bound_hold_exactly(logp in any::<f32>(), x in any::<f32>()) {
        let f = one_step(x, logp, 0.0);
        let ok = f.validate(&bounds(1, ActionSpace::Discrete { n: 2 })).is_ok();
        let x_ok = x.is_finite() && x.abs() <= jsae_wire::MAX_ABS_POLICY_INPUT;
        prop_assert_eq!(ok, (-200.0..=5.0).contains(&logp) && x_ok);
    }

    #[test]
    fn transition_batches_survive_the_wire(n in 0usize..16, seed in any::<u64>()) {
        let t = TransitionBatch {
            actor_id: seed,
            states: StateBatch::Categorical { factors: 1, data: (0..n as u32).map(|i| i % 16).collect() },
            actions: ActionBatch::Discrete((0..n as u32).map(|i| i % 8).collect()),
            rewards: (0..n).map(|i| i as f32 - 3.0).collect(),
            next_states: StateBatch::Categorical { factors: 1, data: (0..n as u32).map(|i| (i + 1) % 16).collect() },
            terminated: (0..n).map(|i| i % 4 == 3).collect(),
        };
        prop_assert_eq!(t.validate(&StateSpace::discrete(16), &ActionSpace::Discrete { n: 8 }, BOUND), Ok(()));
        let wire = pb::TransitionBatch::from(t.clone()).encode_to_vec();
        let back = TransitionBatch::try_from(pb::TransitionBatch::decode(wire.as_slice()).expect("decodes"))
            .expect("converts");
        prop_assert_eq!(back, t);
    }

    #[test]
    fn snapshots_reassemble_from_their_chunks(bytes in prop::collection::vec(any::<u8>(), 0..4_000), version in 1u64..1_000) {
        let mut chunks = Reassembler::default();
        let mut done = None;
        for c in wire::chunk_snapshot(version, &bytes, 0.5, 0.25, None) {
            done = chunks.push(c).expect("in order");
        }
        let done = done.expect("complete");
        prop_assert_eq!((done.version, done.bytes), (version, bytes));
    }
}
