//! A recording reads back transition for transition, a file cut by a crash reads up to its
//! last closed chunk, and what is not a recording is refused with a reason.

use std::path::PathBuf;

use jsae_record::{RecordedSteps, Recorder, RecordingInfo, read, summarize};
use jsae_wire::{ActionBatch, ActionSpace, StateBatch, StateSpace, TransitionBatch};

fn temp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("jsae-record-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap_or_default();
    dir.join("rec.mcap")
}

fn info(states: StateSpace, actions: ActionSpace) -> RecordingInfo {
    RecordingInfo {
        run_id: "test-run".into(),
        env: "gridworld-discrete".into(),
        algo: "jsae".into(),
        seed: 7,
        states,
        actions,
    }
}

/// `n` steps of two environments: categorical states, discrete actions.
fn discrete_batch(n: usize) -> (TransitionBatch, RecordedSteps) {
    let t = TransitionBatch {
        actor_id: 3,
        states: StateBatch::Categorical {
            factors: 2,
            data: (0..2 * n as u32).map(|v| v % 5).collect(),
        },
        actions: ActionBatch::Discrete((0..n as u32).map(|v| v % 4).collect()),
        rewards: (0..n).map(|i| i as f32 * 0.5).collect(),
        next_states: StateBatch::Categorical {
            factors: 2,
            data: (0..2 * n as u32).map(|v| (v + 1) % 5).collect(),
        },
        terminated: (0..n).map(|i| i % 7 == 6).collect(),
    };
    let s = RecordedSteps {
        policy_version: 4,
        embedding_version: 2,
        env_index: (0..n as u32).map(|i| i % 2).collect(),
        episode: (0..n as u64).map(|i| i / 14).collect(),
        step: (0..n as u32).map(|i| (i / 2) % 7).collect(),
        truncated: vec![false; n],
    };
    (t, s)
}

#[test]
fn a_recording_reads_back_transition_for_transition() {
    let path = temp("roundtrip");
    let info = info(
        StateSpace::Categorical { sizes: vec![5, 5] },
        ActionSpace::Discrete { n: 4 },
    );
    let (t, s) = discrete_batch(100);
    let mut rec = Recorder::create(&path, &info).expect("create");
    rec.write(&t, &s).expect("write");
    rec.write(&t, &s).expect("write");
    assert_eq!(rec.finish().expect("finish"), 200);

    let back = read(&path, None).expect("read");
    assert!(back.finished && back.cut_short.is_none());
    assert_eq!(back.info, info);
    assert_eq!(back.transitions.len(), 200);
    let batch = back.transition_batch(&path).expect("batch");
    let mut twice = t.clone();
    twice.actor_id = 0;
    twice.states.extend_from(&t.states);
    twice.next_states.extend_from(&t.next_states);
    twice.actions.extend_from(&t.actions);
    twice.rewards.extend_from_slice(&t.rewards);
    twice.terminated.extend_from_slice(&t.terminated);
    assert_eq!(batch, twice);
    let m = &back.transitions[13];
    assert_eq!(
        (m.actor_id, m.env_index, m.episode, m.step, m.policy_version),
        (3, 1, 0, 6, 4)
    );
    assert_eq!(read(&path, Some(30)).expect("limit").transitions.len(), 30);

    let summary = summarize(&path).expect("summary");
    assert_eq!(summary.transitions, 200);
    assert_eq!(summary.per_actor.get(&3), Some(&200));
    assert_eq!(summary.environments, 2);
    assert_eq!(summary.random_play, 0);
    assert_eq!(summary.policy_versions, Some((4, 4)));
}

#[test]
fn continuous_actions_and_real_states_keep_their_values() {
    let path = temp("continuous");
    let info = info(
        StateSpace::Real { dim: 3 },
        ActionSpace::Continuous {
            dim: 2,
            low: vec![-1.0; 2],
            high: vec![1.0; 2],
        },
    );
    let t = TransitionBatch {
        actor_id: 1,
        states: StateBatch::Real {
            dim: 3,
            data: vec![0.1, 0.2, 0.3, 1.1, 1.2, 1.3],
        },
        actions: ActionBatch::Continuous {
            dim: 2,
            data: vec![-0.5, 0.25, 1.0, -1.0],
        },
        rewards: vec![1.5, -2.0],
        next_states: StateBatch::Real {
            dim: 3,
            data: vec![1.1, 1.2, 1.3, 2.1, 2.2, 2.3],
        },
        terminated: vec![false, true],
    };
    let s = RecordedSteps {
        policy_version: 0,
        embedding_version: 0,
        env_index: vec![0, 0],
        episode: vec![0, 0],
        step: vec![0, 1],
        truncated: vec![false, false],
    };
    let mut rec = Recorder::create(&path, &info).expect("create");
    rec.write(&t, &s).expect("write");
    rec.finish().expect("finish");
    let back = read(&path, None).expect("read");
    let mut expected = t.clone();
    expected.actor_id = 0;
    assert_eq!(back.transition_batch(&path).expect("batch"), expected);
    let summary = summarize(&path).expect("summary");
    assert_eq!(
        (
            summary.random_play,
            summary.terminated,
            summary.episodes_ended
        ),
        (2, 1, 1)
    );
    assert_eq!(summary.episode_return_mean, Some(-0.5));
}

#[test]
fn a_file_cut_by_a_crash_reads_up_to_its_last_closed_chunk() {
    let path = temp("crash");
    let info = info(
        StateSpace::Categorical { sizes: vec![5, 5] },
        ActionSpace::Discrete { n: 4 },
    );
    let (t, s) = discrete_batch(50);
    let mut rec = Recorder::create(&path, &info).expect("create");
    rec.write(&t, &s).expect("write");
    rec.flush().expect("flush");
    let first = std::fs::metadata(&path).expect("size").len() as usize;
    rec.write(&t, &s).expect("write");
    rec.flush().expect("flush");
    let closed = std::fs::metadata(&path).expect("size").len();
    rec.write(&t, &s).expect("write");
    // the process dies: the open chunk is never written, nor the summary
    std::mem::forget(rec);
    let bytes = std::fs::read(&path).expect("bytes");
    // (the open chunk's header may be there; its messages are not)
    assert!(bytes.len() as u64 >= closed);
    let back = read(&path, None).expect("read");
    assert!(!back.finished);
    assert_eq!(back.transitions.len(), 100);
    // cut inside the second chunk: the first still reads
    std::fs::write(&path, &bytes[..first + 10]).expect("cut");
    let back = read(&path, None).expect("read");
    assert_eq!(back.transitions.len(), 50);
    assert!(back.cut_short.is_some());
}

#[test]
fn what_is_not_a_recording_is_refused_with_a_reason() {
    let path = temp("garbage");
    std::fs::write(&path, b"not an mcap file at all").expect("write");
    let err = read(&path, None).expect_err("garbage");
    assert!(err.to_string().contains("rec.mcap"), "{err}");
    let missing = read(&temp("missing").with_file_name("nope.mcap"), None).expect_err("missing");
    assert!(missing.to_string().contains("nope.mcap"), "{missing}");
}
