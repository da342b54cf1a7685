//! The remote environments' pool (`jsae-remote-envs`) with real Python workers (`python -m jsae.envs`, the project's venv): steps and
//! resets of Gymnasium's CartPole on two workers, a worker killed -9 between steps (its
//! environments' steps are lost and their next episodes start on the other), and workers
//! refused with the reason in their error: another environment's spaces, an observation with
//! NaN.

use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use jsae_envs::{EnvPool, GymConfig, Step};
use jsae_net::security::Security;
use jsae_remote_envs::{HostPlan, RemotePool, host_on_own_runtime};
use jsae_wire::{ActionBatch, StateBatch};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// The project's venv python, with the jsae package (scripts/setup-python.sh installs it).
fn python() -> PathBuf {
    jsae_tests::venv_python()
}

fn cartpole() -> GymConfig {
    let d = jsae_settings::parse_description(&String::from_utf8_lossy(
        &Command::new(python())
            .args(["-m", "jsae.envs", "--describe", "--env", "CartPole-v1"])
            .output()
            .expect("describes")
            .stdout,
    ))
    .expect("a description");
    GymConfig {
        id: "CartPole-v1".into(),
        observation: Some(d.observation),
        action: Some(d.action),
        max_steps: d.max_steps,
        workers: 0,
    }
}

/// A pool of `envs` CartPoles served on loopback, and `workers` workers started for it
/// (each logging to this test's output).
fn pool(envs: usize, workers: usize) -> (RemotePool, jsae_remote_envs::Hosting) {
    // the workers this process starts find the venv's python from the working directory
    // (jsae_settings::python); setting it up installs the package
    python();
    let plan = HostPlan {
        listen: "127.0.0.1:0".into(),
        workers,
        log_dir: None,
        name: String::new(),
        worker_env: Vec::new(),
    };
    host_on_own_runtime(&cartpole(), envs, &Security::default(), &plan).expect("a host")
}

fn step_all(pool: &mut RemotePool, action: u32) -> Vec<Step> {
    let k = pool.len();
    let mut out = vec![Step::default(); k];
    pool.step(&ActionBatch::Discrete(vec![action; k]), &mut out);
    out
}

#[test]
fn cartpole_steps_on_two_workers_and_survives_one_killed() {
    let (mut pool, hosting) = pool(4, 2);
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    for i in 0..4 {
        pool.reset(i, &mut rng);
    }
    assert_eq!(pool.workers(), 2);
    let mut ended = 0;
    for t in 0..60 {
        for (i, s) in step_all(&mut pool, (t % 2) as u32).iter().enumerate() {
            assert!(!s.lost, "nothing is lost while both workers live");
            assert!(s.reward == 1.0);
            if s.terminated || s.truncated {
                ended += 1;
                pool.reset(i, &mut rng);
            }
        }
    }
    // pushing one side for 60 steps drops the pole in CartPole
    let mut constant = 0;
    for _ in 0..40 {
        for (i, s) in step_all(&mut pool, 1).iter().enumerate() {
            if s.terminated {
                constant += 1;
                pool.reset(i, &mut rng);
            }
        }
    }
    assert!(constant > 0, "pushing right ends episodes ({ended} before)");
    let mut states = StateBatch::Real {
        dim: 4,
        data: Vec::new(),
    };
    pool.push_state(0, &mut states);
    assert_eq!(states.len(), 1);

    let killed = hosting.workers.lock().expect("workers").pids()[0];
    let status = Command::new("kill")
        .args(["-9", &killed.to_string()])
        .status()
        .expect("kill runs");
    assert!(status.success());
    std::thread::sleep(Duration::from_millis(300));
    let steps = step_all(&mut pool, 0);
    let lost: Vec<usize> = (0..4).filter(|&i| steps[i].lost).collect();
    assert_eq!(
        lost.len(),
        2,
        "the killed worker's two environments: {steps:?}"
    );
    for &i in &lost {
        pool.reset(i, &mut rng);
    }
    for _ in 0..10 {
        for (i, s) in step_all(&mut pool, 0).iter().enumerate() {
            assert!(
                !s.lost,
                "the lost environments step again, on the survivor or the restart"
            );
            if s.terminated || s.truncated {
                pool.reset(i, &mut rng);
            }
        }
    }
    // the killed worker is started again and joins
    let start = Instant::now();
    while pool.workers() < 2 {
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "the killed worker was not restarted"
        );
        step_all(&mut pool, 0);
        std::thread::sleep(Duration::from_millis(100));
    }
    assert_ne!(hosting.workers.lock().expect("workers").pids()[0], killed);
}

/// Starts `python -c SCRIPT URL` (or `python -m jsae.envs ARGS`) and waits for its exit:
/// (status code, stderr).
fn run_worker(args: &[String]) -> (Option<i32>, String) {
    let mut child = Command::new(python())
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("python starts");
    let start = Instant::now();
    loop {
        if let Some(status) = child.try_wait().expect("waits") {
            let mut err = String::new();
            use std::io::Read;
            let _ = child.stderr.take().map(|mut e| e.read_to_string(&mut err));
            return (status.code(), err);
        }
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "the worker did not exit"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
}

#[test]
fn a_worker_of_another_environment_is_refused_with_the_reason() {
    let (_pool, hosting) = pool(1, 0);
    let args: Vec<String> = ["-m", "jsae.envs", "--env", "Pendulum-v1", "--envs", "1"]
        .iter()
        .map(|s| s.to_string())
        .chain(["--actor".to_string(), hosting.url.clone()])
        .collect();
    let (code, err) = run_worker(&args);
    assert_eq!(code, Some(2), "{err}");
    assert!(err.contains("not \"Pendulum-v1\""), "{err}");
    // the same spaces under the run's name still differ in their spaces
    let script = format!(
        "import gymnasium, jsae.envs\n\
         jsae.envs.serve(lambda: gymnasium.make('Pendulum-v1'), actor='{}', envs=1, env_id='CartPole-v1')",
        hosting.url
    );
    let (code, err) = run_worker(&["-c".into(), script]);
    assert_ne!(code, Some(0));
    assert!(err.contains("observation space"), "{err}");
}

#[test]
fn an_observation_with_nan_is_refused_with_the_reason() {
    let (mut pool, hosting) = pool(1, 0);
    let script = format!(
        "import gymnasium, numpy as np, jsae.envs\n\
         class Nan(gymnasium.Wrapper):\n\
         \x20   def step(self, a):\n\
         \x20       o, r, t, u, i = self.env.step(a)\n\
         \x20       return np.full(4, np.nan, dtype=np.float32), r, t, u, i\n\
         try:\n\
         \x20   jsae.envs.serve(lambda: Nan(gymnasium.make('CartPole-v1')), actor='{}', envs=1)\n\
         except jsae.envs.RefusedByActor as e:\n\
         \x20   raise SystemExit(f'refused: {{e}}')\n",
        hosting.url
    );
    let worker = std::thread::spawn(move || run_worker(&["-c".into(), script]));
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    pool.reset(0, &mut rng);
    let steps = step_all(&mut pool, 0);
    assert!(steps[0].lost, "a NaN observation is not taken: {steps:?}");
    let (code, err) = worker.join().expect("the worker's thread");
    assert_ne!(code, Some(0));
    assert!(err.contains("refused") && err.contains("NaN"), "{err}");
}
