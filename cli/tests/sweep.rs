//! `jsae sweep` and `jsae report` end to end: a small grid trained as `jsae train` processes
//! two at a time, started again (finished runs skipped, a lost one redone), then reported;
//! SIGTERM to a sweep stops its runs and their services.

mod common;

use std::path::Path;
use std::process::Command;

fn jsae(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_jsae"))
        .args(args)
        .output()
        .expect("jsae runs")
}

const SWEEP: &str = r#"
envs = ["gridworld-discrete"]
algos = ["ppo", "jsae"]
seeds = [3, 4]
env_steps = 3000
eval_episodes = 2
[report]
threshold = 0.5
[settings.small]
envs_per_actor = 4
rollout_len = 32
[settings.small.embedding]
pretrain_transitions = 1000
pretrain_per_action = 0
pretrain_epochs = 2
[settings.small.ppo]
epochs = 1
"#;

fn text(out: &std::process::Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    )
}

#[test]
fn a_sweep_runs_resumes_and_reports() {
    let dir = std::env::temp_dir().join(format!("jsae-sweep-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("mkdir");
    let file = dir.join("grid.toml");
    std::fs::write(&file, SWEEP).expect("sweep file");
    let results = dir.join("results");
    let (f, r) = (
        file.to_str().unwrap_or("."),
        results.to_str().unwrap_or("."),
    );

    let first = jsae(&["sweep", f, "--out", r, "--jobs", "2"]);
    assert!(first.status.success(), "{}", text(&first));
    assert!(
        text(&first).contains("4 runs trained, 0 finished before"),
        "{}",
        text(&first)
    );
    let run = |algo: &str, seed: u64| {
        results.join(format!("runs/small/gridworld-discrete-{algo}-seed{seed}"))
    };
    for (algo, seed) in [("ppo", 3), ("ppo", 4), ("jsae", 3), ("jsae", 4)] {
        let summary =
            std::fs::read_to_string(run(algo, seed).join("summary.json")).expect("a finished run");
        assert!(summary.contains(&format!("\"seed\": {seed}")), "{summary}");
        assert!(summary.contains("eval_stochastic_return_mean"), "{summary}");
    }

    // Started again: nothing to do; a run whose summary is lost is trained again.
    std::fs::remove_file(run("jsae", 4).join("summary.json")).expect("remove");
    let again = jsae(&["sweep", f, "--out", r]);
    assert!(again.status.success(), "{}", text(&again));
    assert!(
        text(&again).contains("1 runs trained, 3 finished before"),
        "{}",
        text(&again)
    );

    let report_dir = dir.join("report");
    let report = jsae(&["report", r, "--out", report_dir.to_str().unwrap_or(".")]);
    assert!(report.status.success(), "{}", text(&report));
    let md = std::fs::read_to_string(report_dir.join("report.md")).expect("report.md");
    for algo in ["jsae", "ppo"] {
        assert!(
            md.contains(&format!("| small | gridworld-discrete | {algo} | 2 |")),
            "{md}"
        );
    }
    assert!(
        Path::new(&report_dir.join("figures/small-gridworld-discrete-return_mean.png")).exists()
            || md.contains("No figures")
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_bad_sweep_file_exits_2_with_a_reason() {
    let file = std::env::temp_dir().join(format!("jsae-bad-sweep-{}.toml", std::process::id()));
    std::fs::write(
        &file,
        "envs = [\"gridworld\"]\nalgos = [\"ppo\"]\nseeds = [1, 1]\nenv_steps = 10\n",
    )
    .expect("file");
    let out = jsae(&[
        "sweep",
        file.to_str().unwrap_or("."),
        "--out",
        "/nonexistent/x",
    ]);
    assert_eq!(out.status.code(), Some(2));
    assert!(text(&out).contains("repeat"), "{}", text(&out));
    // A setting the runs would refuse stops the sweep before any run starts.
    std::fs::write(
        &file,
        "envs = [\"gridworld\"]\nalgos = [\"ppo\"]\nseeds = [1]\nenv_steps = 10\n\
         [settings.typo.ppo]\nepochz = 3\n",
    )
    .expect("file");
    let out_dir = file.with_extension("d");
    let out = jsae(&[
        "sweep",
        file.to_str().unwrap_or("."),
        "--out",
        out_dir.to_str().unwrap_or("."),
    ]);
    assert_eq!(out.status.code(), Some(2));
    assert!(text(&out).contains("epochz"), "{}", text(&out));
    assert!(!out_dir.join("runs").exists());
    let _ = std::fs::remove_dir_all(&out_dir);
    let _ = std::fs::remove_file(&file);
}

/// The running processes whose command line mentions `needle`.
fn processes_mentioning(needle: &str) -> Vec<u32> {
    common::processes()
        .into_iter()
        .filter(|p| p.running && p.cmdline.contains(needle))
        .map(|p| p.pid)
        .collect()
}

#[test]
fn sigterm_to_a_sweep_stops_its_runs_and_their_services() {
    // one process per run (the sweep's default), then the services as processes: the sweep
    // and the first two runs' `jsae train` (PPO, seeds 3 and 4), each with a learner and an
    // actor under it
    sigterm_stops(true, 3);
    sigterm_stops(false, 3 + 4);
}

fn sigterm_stops(one_process: bool, processes: usize) {
    let dir = std::env::temp_dir().join(format!(
        "jsae-sweep-term-{one_process}-{}",
        std::process::id()
    ));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("mkdir");
    let file = dir.join("grid.toml");
    // runs far too long to end by themselves in this test
    let long = SWEEP.replace(
        "env_steps = 3000",
        &format!("env_steps = 100000000\none_process = {one_process}"),
    );
    std::fs::write(&file, long).expect("sweep file");
    let results = dir.join("results");
    let r = results.to_str().unwrap_or(".");
    let mut sweep = Command::new(env!("CARGO_BIN_EXE_jsae"))
        .args([
            "sweep",
            file.to_str().unwrap_or("."),
            "--out",
            r,
            "--jobs",
            "2",
        ])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("jsae sweep starts");
    // until both runs are under way
    let started = std::time::Instant::now();
    while processes_mentioning(r).len() < processes {
        if started.elapsed().as_secs() > 120 {
            let pid = rustix::process::Pid::from_child(&sweep);
            let _ = rustix::process::kill_process(pid, rustix::process::Signal::TERM);
            let _ = sweep.wait();
            panic!("the runs did not start: {:?}", processes_mentioning(r));
        }
        std::thread::sleep(std::time::Duration::from_millis(200));
    }
    std::thread::sleep(std::time::Duration::from_secs(2));
    let pid = rustix::process::Pid::from_child(&sweep);
    rustix::process::kill_process(pid, rustix::process::Signal::TERM).expect("SIGTERM");
    let out = sweep.wait_with_output().expect("jsae sweep ends");
    assert!(!out.status.success(), "{}", text(&out));
    assert!(text(&out).contains("stopped by a signal"), "{}", text(&out));
    let left = processes_mentioning(r);
    assert!(left.is_empty(), "still running: {left:?}");
    let _ = std::fs::remove_dir_all(&dir);
}
