//! Chaos: one run of separate service processes (embedder, learner, one actor) in which the
//! embedder is killed with SIGKILL while it pre-trains (before any checkpoint: the actor must
//! play again for the restarted one), then the learner and the embedder at random moments,
//! several times each, each restarted with the same command line on the same ports. The run must still finish by
//! itself (the actor and the learner exit 0, summary.json written for the whole budget), and
//! nothing acknowledged may be lost or repeated: metrics.csv's updates strictly increase and
//! its env steps never go back, the policy and embedding versions go on from their
//! checkpoints (the final policy version is at least the last update), and every restarted
//! process came back from its checkpoint: a learner frozen, its checkpoint read, then killed,
//! says on restart that it took up that checkpoint's version and training state (Adam's
//! moments, the reward scaler, the step accounts: their size and CRC-32).

mod common;

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use common::free_port;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Kills of each of the learner and the embedder.
const KILLS: usize = 3;
const SEED: u64 = 7;
const ENV_STEPS: u64 = 150_000;

/// A service process and the command line it is restarted with.
struct Process {
    args: Vec<String>,
    log: PathBuf,
    child: Child,
    starts: usize,
}

impl Process {
    fn start(dir: &Path, name: &str, args: Vec<String>) -> Self {
        let log = dir.join(format!("{name}.log"));
        let child = spawn(&args, &log, 0);
        Self {
            args,
            log,
            child,
            starts: 1,
        }
    }

    fn kill_and_restart(&mut self) {
        let _ = self.child.kill(); // SIGKILL
        let _ = self.child.wait();
        self.child = spawn(&self.args, &self.log, self.starts);
        self.starts += 1;
    }

    /// Freezes the process (SIGSTOP), so that its files stay as they are until it is killed.
    /// The signal is delivered asynchronously (a thread in a system call, a rename for one,
    /// finishes it first), so this returns only once every thread of the process is stopped.
    fn freeze(&self) {
        let pid = rustix::process::Pid::from_child(&self.child);
        let _ = rustix::process::kill_process(pid, rustix::process::Signal::STOP);
        let tasks = PathBuf::from(format!("/proc/{}/task", self.child.id()));
        let deadline = Instant::now() + Duration::from_secs(10);
        while !all_stopped(&tasks) {
            assert!(Instant::now() < deadline, "the process did not stop");
            std::thread::sleep(Duration::from_millis(5));
        }
    }

    /// The log from byte `from` on.
    fn log_since(&self, from: usize) -> String {
        let text = std::fs::read_to_string(&self.log).unwrap_or_default();
        text.get(from..).unwrap_or_default().to_string()
    }

    fn log_len(&self) -> usize {
        std::fs::metadata(&self.log).map_or(0, |m| m.len() as usize)
    }
}

/// Whether every thread under `/proc/PID/task` is stopped (state `T`, `t` when traced) or
/// gone (`Z`, `X`); a process that is gone counts as stopped.
fn all_stopped(tasks: &Path) -> bool {
    let Ok(entries) = std::fs::read_dir(tasks) else {
        return true;
    };
    entries.flatten().all(|task| {
        let stat = std::fs::read_to_string(task.path().join("stat")).unwrap_or_default();
        // the state follows the command name, which is in parentheses and may hold spaces
        stat.rsplit_once(") ")
            .and_then(|(_, rest)| rest.chars().next())
            .is_none_or(|state| matches!(state, 'T' | 't' | 'Z' | 'X'))
    })
}

/// The version and training state of the policy checkpoint, as a restarted learner logs them.
fn saved_state(checkpoints: &Path) -> Option<String> {
    let bytes = std::fs::read(checkpoints.join("policy-latest.ckpt")).ok()?;
    let saved = jsae_run_dir::LatestCheckpoint::decode(&bytes).ok()?;
    Some(format!(
        "version {}, training state {} bytes (crc32 {:08x})",
        saved.version,
        saved.state.len(),
        saved.state_checksum()
    ))
}

impl Process {
    fn exited(&mut self) -> Option<std::process::ExitStatus> {
        self.child.try_wait().expect("try_wait")
    }
}

impl Drop for Process {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn spawn(args: &[String], log: &Path, start: usize) -> Child {
    let file = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(log)
        .expect("log file");
    let err = file.try_clone().expect("log file");
    Command::new(env!("CARGO_BIN_EXE_jsae"))
        .args(args)
        .env("JSAE_CHAOS_START", start.to_string())
        .stdin(Stdio::null())
        .stdout(file)
        .stderr(err)
        .spawn()
        .expect("jsae starts")
}

fn strings(parts: &[&str]) -> Vec<String> {
    parts.iter().map(|s| (*s).to_string()).collect()
}

/// (update, env_steps) of every complete metrics.csv row.
fn rows(run: &Path) -> Vec<(u64, u64)> {
    let text = std::fs::read_to_string(run.join("metrics.csv")).unwrap_or_default();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap_or_default().split(',').collect();
    let (Some(u), Some(s)) = (
        header.iter().position(|h| *h == "update"),
        header.iter().position(|h| *h == "env_steps"),
    ) else {
        return Vec::new();
    };
    lines
        .filter(|l| l.split(',').count() == header.len())
        .filter_map(|l| {
            let cells: Vec<&str> = l.split(',').collect();
            Some((cells[u].parse().ok()?, cells[s].parse().ok()?))
        })
        .collect()
}

/// The embedder, the learner and one actor of a small gridworld JSAE run in `dir/run`, each
/// a `jsae` process on its own port.
fn start_services(dir: &Path, run: &Path) -> (Process, Process, Process) {
    std::fs::write(
        dir.join("small.toml"),
        "envs_per_actor = 4\nrollout_len = 32\neval_episodes = 2\npolicy_wait_ms = 500\n\
         [embedding]\npretrain_transitions = 1000\npretrain_per_action = 0\npretrain_epochs = 40\n\
         update_every = 2048\nupdate_steps = 5\n[ppo]\nepochs = 1\n",
    )
    .expect("settings");
    let p = |s: &Path| s.display().to_string();
    let common = [
        "--env",
        "gridworld-discrete",
        "--algo",
        "jsae",
        "--seed",
        "5",
        "--config",
    ];
    let mut common = strings(&common);
    common.push(p(&dir.join("small.toml")));
    let (embedder_port, learner_port) = (free_port(), free_port());
    let embedder_url = format!("http://127.0.0.1:{embedder_port}");
    let learner_url = format!("http://127.0.0.1:{learner_port}");
    let with = |mut head: Vec<String>, tail: &[String]| {
        head.extend(common.iter().cloned());
        head.extend(tail.iter().cloned());
        head
    };
    let embedder_listen = format!("127.0.0.1:{embedder_port}");
    let embedder = Process::start(
        dir,
        "embedder",
        with(
            strings(&["embedder", "--listen", &embedder_listen]),
            &["--checkpoint-dir".into(), p(&run.join("checkpoints"))],
        ),
    );
    let learner_listen = format!("127.0.0.1:{learner_port}");
    let learner_tail = strings(&[
        "--embedder",
        &embedder_url,
        "--env-steps",
        &ENV_STEPS.to_string(),
        "--out",
        &p(run),
    ]);
    let learner = Process::start(
        dir,
        "learner",
        with(
            strings(&["learner", "--listen", &learner_listen]),
            &learner_tail,
        ),
    );
    let actor_head = strings(&[
        "actor",
        "--learner",
        &learner_url,
        "--embedder",
        &embedder_url,
    ]);
    let actor = Process::start(
        dir,
        "actor",
        with(actor_head, &strings(&["--id", "0", "--envs", "4"])),
    );
    (embedder, learner, actor)
}

/// Whether the embedder has checkpointed an embedding.
fn embedding_saved(checkpoints: &Path) -> bool {
    std::fs::read_dir(checkpoints).is_ok_and(|entries| {
        entries
            .flatten()
            .any(|e| e.file_name().to_string_lossy().starts_with("embedding-"))
    })
}

/// Kills the learner and the embedder `KILLS` times each, in a seeded random order at random
/// moments, until the run ends; returns how many learner restarts were seen to take up
/// exactly the state it saved last.
fn kill_at_random(learner: &mut Process, embedder: &mut Process, checkpoints: &Path) -> usize {
    let mut rng = ChaCha8Rng::seed_from_u64(SEED);
    let mut plan: Vec<bool> = (0..2 * KILLS).map(|i| i % 2 == 0).collect();
    for i in (1..plan.len()).rev() {
        plan.swap(i, rng.random_range(0..=i));
    }
    let mut compared = 0;
    for kill_learner in plan {
        std::thread::sleep(Duration::from_millis(rng.random_range(300..1500)));
        if learner.exited().is_some() {
            break; // the run ended before the plan did
        }
        if !kill_learner {
            embedder.kill_and_restart();
            continue;
        }
        // the state it saved last, read while it cannot write a newer one; the restarted
        // learner must take up exactly that state
        learner.freeze();
        let saved = saved_state(checkpoints);
        let from = learner.log_len();
        learner.kill_and_restart();
        if let Some(saved) = saved {
            let wait = Instant::now() + Duration::from_secs(30);
            while !learner.log_since(from).contains("resuming from") {
                assert!(Instant::now() < wait, "the learner did not resume");
                std::thread::sleep(Duration::from_millis(20));
            }
            let log = learner.log_since(from);
            assert!(
                log.contains(&saved),
                "saved {saved}; the restart said:\n{log}"
            );
            compared += 1;
        }
    }
    compared
}

/// What the finished run left: summary.json past the budget, metrics rows without repeats or
/// steps back, versions that follow them.
fn check_finished_run(run: &Path) {
    let summary: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(run.join("summary.json")).expect("summary.json"),
    )
    .expect("JSON");
    assert!(
        summary["env_steps"].as_u64().unwrap_or(0) >= ENV_STEPS,
        "{summary}"
    );
    let rows = rows(run);
    assert!(!rows.is_empty());
    for w in rows.windows(2) {
        assert!(
            w[0].0 < w[1].0,
            "update {} then {}: repeated or back",
            w[0].0,
            w[1].0
        );
        assert!(w[0].1 <= w[1].1, "env steps went back: {w:?}");
    }
    let last_update = rows.last().map_or(0, |r| r.0);
    assert!(
        summary["policy_version"].as_u64().unwrap_or(0) >= last_update,
        "{summary}"
    );
    assert!(
        summary["embedding_version"].as_u64().unwrap_or(0) >= 1,
        "{summary}"
    );
}

#[test]
fn killed_learners_and_embedders_rejoin_and_the_run_finishes_with_nothing_lost() {
    let dir = std::env::temp_dir().join(format!("jsae-chaos-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("dir");
    let run = dir.join("run");
    let checkpoints = run.join("checkpoints");
    let (mut embedder, mut learner, mut actor) = start_services(&dir, &run);

    let deadline = Instant::now() + Duration::from_secs(300);
    // the embedder killed while it pre-trains (the actor's random play in its buffer, no
    // embedding yet): the restarted one starts empty, and the actor plays for it again
    while !embedder.log_since(0).contains("pre-training the embedding") {
        assert!(Instant::now() < deadline, "no pre-training in time");
        std::thread::sleep(Duration::from_millis(20));
    }
    embedder.freeze();
    assert!(
        !embedding_saved(&checkpoints),
        "pre-training ended before the kill"
    );
    embedder.kill_and_restart();

    // kills at random moments once the run is under way (the first embedding published: a
    // restarted embedder resumes from its checkpoint)
    while !embedding_saved(&checkpoints) {
        assert!(Instant::now() < deadline, "no embedding in time");
        std::thread::sleep(Duration::from_millis(100));
    }
    let compared = kill_at_random(&mut learner, &mut embedder, &checkpoints);
    let (mut learner_exit, mut actor_exit) = (None, None);
    while learner_exit.is_none() || actor_exit.is_none() {
        assert!(
            Instant::now() < deadline,
            "the run did not finish; learner log:\n{}",
            std::fs::read_to_string(&learner.log).unwrap_or_default()
        );
        learner_exit = learner_exit.or_else(|| learner.exited());
        actor_exit = actor_exit.or_else(|| actor.exited());
        std::thread::sleep(Duration::from_millis(100));
    }
    let logs = || std::fs::read_to_string(&learner.log).unwrap_or_default();
    assert!(learner_exit.is_some_and(|s| s.success()), "{}", logs());
    assert!(actor_exit.is_some_and(|s| s.success()));
    println!(
        "started: learner {} times, embedder {} times; {} metrics rows; {compared} restarts \
         took up exactly the saved state",
        learner.starts,
        embedder.starts,
        rows(&run).len()
    );
    assert!(
        compared >= 1,
        "no learner restart was compared with its saved state"
    );
    assert!(learner.starts + embedder.starts > 2, "nothing was killed");
    check_finished_run(&run);
    if learner.starts > 1 {
        assert!(logs().contains("resuming"), "{}", logs());
    }
    let actor_log = std::fs::read_to_string(&actor.log).unwrap_or_default();
    assert!(
        actor_log.contains("random play for its pre-training again"),
        "the actor did not play again for the restarted embedder:\n{actor_log}"
    );
    embedder.child.kill().ok();
    let _ = std::fs::remove_dir_all(&dir);
}
