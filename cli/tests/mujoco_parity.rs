//! HalfCheetah and Ant against Gymnasium v5 itself: Gymnasium (in the venv that
//! scripts/setup-python.sh makes) records trajectories over several seeds with actions in
//! [-1.5, 1.5]; `jsae env-replay` replays the same initial states and actions; obs, reward and
//! terminated must agree to 1e-9 relative, step for step.

mod common;

use std::path::Path;
use std::process::Command;

use common::{repo_root, venv_python as reference_python};

fn read_lines(path: &Path) -> Vec<serde_json::Value> {
    std::fs::read_to_string(path)
        .expect("readable")
        .lines()
        .filter(|l| !l.trim().is_empty())
        .map(|l| serde_json::from_str(l).expect("a JSON line"))
        .collect()
}

fn close(a: f64, b: f64) -> bool {
    a == b || (a - b).abs() <= 1e-9 * a.abs().max(b.abs())
}

struct Case {
    gym_id: &'static str,
    env: &'static str,
    seed: u32,
    steps: u32,
    action_scale: f64,
    z_offset: f64,
}

/// Returns (steps compared, whether the last step terminated, actions outside [-1, 1]).
fn check(python: &Path, dir: &Path, case: &Case) -> (usize, bool, usize) {
    let tag = format!(
        "{}-{}-{}-{}",
        case.env, case.seed, case.action_scale, case.z_offset
    );
    let input = dir.join(format!("{tag}-in.jsonl"));
    let expected = dir.join(format!("{tag}-gymnasium.jsonl"));
    let ours = dir.join(format!("{tag}-jsae.jsonl"));
    let rec = Command::new(python)
        .arg(repo_root().join("scripts/python/gymnasium_record.py"))
        .args(["--env", case.gym_id, "--seed", &case.seed.to_string()])
        .args(["--steps", &case.steps.to_string()])
        .args(["--z-offset", &case.z_offset.to_string()])
        .args(["--action-scale", &case.action_scale.to_string()])
        .arg("--input")
        .arg(&input)
        .arg("--expected")
        .arg(&expected)
        .output()
        .expect("python runs");
    assert!(
        rec.status.success(),
        "gymnasium_record.py failed: {}",
        String::from_utf8_lossy(&rec.stderr)
    );
    let replay = Command::new(env!("CARGO_BIN_EXE_jsae"))
        .args(["env-replay", "--env", case.env, "--input"])
        .arg(&input)
        .arg("--output")
        .arg(&ours)
        .output()
        .expect("jsae runs");
    assert!(
        replay.status.success(),
        "jsae env-replay failed: {}",
        String::from_utf8_lossy(&replay.stderr)
    );
    // rough edge 11: MuJoCo's settotalmass deprecation warning (HalfCheetah's XML) is
    // silenced; other MuJoCo messages still reach the log
    let stderr = String::from_utf8_lossy(&replay.stderr);
    assert!(
        !stderr.contains("settotalmass"),
        "{tag}: MuJoCo's warning reached stderr: {stderr}"
    );
    let (want, got) = (read_lines(&expected), read_lines(&ours));
    assert_eq!(want.len(), got.len(), "{tag}: number of steps");
    let mut terminated = false;
    for (t, (w, g)) in want.iter().zip(&got).enumerate() {
        let values = |v: &serde_json::Value| -> Vec<f64> {
            v["obs"]
                .as_array()
                .expect("obs")
                .iter()
                .map(|x| x.as_f64().expect("number"))
                .collect()
        };
        let (wo, go) = (values(w), values(g));
        assert_eq!(wo.len(), go.len(), "{tag} step {t}: obs length");
        for (i, (a, b)) in wo.iter().zip(&go).enumerate() {
            assert!(
                close(*a, *b),
                "{tag} step {t}: obs[{i}] {a} (gymnasium) vs {b}"
            );
        }
        let (wr, gr) = (w["reward"].as_f64(), g["reward"].as_f64());
        let (wr, gr) = (wr.expect("reward"), gr.expect("reward"));
        assert!(
            close(wr, gr),
            "{tag} step {t}: reward {wr} (gymnasium) vs {gr}"
        );
        assert_eq!(
            w["terminated"], g["terminated"],
            "{tag} step {t}: terminated"
        );
        terminated = g["terminated"].as_bool().unwrap_or(false);
    }
    let outside = read_lines(&input)
        .iter()
        .skip(1)
        .flat_map(|l| l["action"].as_array().cloned().unwrap_or_default())
        .filter(|a| a.as_f64().is_some_and(|v| v.abs() > 1.0))
        .count();
    (got.len(), terminated, outside)
}

#[test]
fn half_cheetah_and_ant_match_gymnasium_v5() {
    let python = reference_python();
    let dir = std::env::temp_dir().join(format!("jsae-parity-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let mut cases = Vec::new();
    for seed in 1..=3 {
        cases.push(Case {
            gym_id: "HalfCheetah-v5",
            env: "half-cheetah",
            seed,
            steps: 300,
            action_scale: 1.5,
            z_offset: 0.0,
        });
        cases.push(Case {
            gym_id: "Ant-v5",
            env: "ant",
            seed,
            steps: 300,
            action_scale: 1.5,
            z_offset: 0.0,
        });
    }
    // Strong random actions make Ant jump out of its healthy range within tens of steps;
    // milder ones keep it walking for the whole trajectory (contacts all along).
    cases.push(Case {
        gym_id: "Ant-v5",
        env: "ant",
        seed: 4,
        steps: 300,
        action_scale: 0.5,
        z_offset: 0.0,
    });
    // An Ant dropped from above the healthy range: terminated on the first step.
    cases.push(Case {
        gym_id: "Ant-v5",
        env: "ant",
        seed: 5,
        steps: 300,
        action_scale: 1.5,
        z_offset: 0.5,
    });
    let (mut outside, mut terminations, mut long_ant) = (0, 0, false);
    for case in &cases {
        let (steps, terminated, out) = check(&python, &dir, case);
        outside += out;
        terminations += usize::from(terminated);
        assert!(
            terminated || steps == case.steps as usize,
            "{}: full length",
            case.env
        );
        if case.z_offset > 0.0 {
            assert!(terminated && steps < 5, "the lifted Ant terminates at once");
        }
        long_ant |= case.env == "ant" && steps == case.steps as usize;
    }
    assert!(outside > 0, "some actions lie outside [-1, 1]");
    assert!(terminations >= 2, "terminations are compared");
    assert!(long_ant, "one Ant trajectory runs its full length");
    let _ = std::fs::remove_dir_all(&dir);
}
