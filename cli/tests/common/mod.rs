//! Helpers shared by the cli crate's integration tests.

use std::path::{Path, PathBuf};
use std::process::Command;

/// The workspace root.
pub fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("the cli crate lives in the workspace")
        .to_path_buf()
}

/// The test venv's python (scripts/setup-python.sh creates it on first use).
pub fn venv_python() -> PathBuf {
    let out = Command::new(repo_root().join("scripts/setup-python.sh"))
        .output()
        .expect("scripts/setup-python.sh runs");
    assert!(
        out.status.success(),
        "scripts/setup-python.sh failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    PathBuf::from(String::from_utf8_lossy(&out.stdout).trim())
}

/// What `scripts/python/SCRIPT ARGS...` prints, one JSON value, run with the venv's Python;
/// the script must succeed (its stderr is the failure message).
#[allow(dead_code, reason = "not every test crate runs a Python script")]
pub fn python_json<S: AsRef<std::ffi::OsStr>>(script: &str, args: &[S]) -> serde_json::Value {
    let out = Command::new(venv_python())
        .arg(repo_root().join("scripts/python").join(script))
        .args(args)
        .output()
        .expect("python runs");
    assert!(
        out.status.success(),
        "{script}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("one JSON value")
}

/// GET `http://ADDR/metrics` (Prometheus text), the body after a 200 answer's headers.
#[allow(dead_code, reason = "not every test crate scrapes metrics")]
pub fn scrape_metrics(addr: &str) -> String {
    use std::io::{Read, Write};
    let mut stream = std::net::TcpStream::connect(addr).expect("connects");
    stream
        .set_read_timeout(Some(std::time::Duration::from_secs(10)))
        .ok();
    write!(
        stream,
        "GET /metrics HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n"
    )
    .expect("asks");
    let mut answer = String::new();
    stream.read_to_string(&mut answer).expect("answer");
    assert!(answer.starts_with("HTTP/1.1 200"), "{answer}");
    answer
}

/// The value of the sample `name` (with its labels, if any) in Prometheus text.
#[allow(dead_code, reason = "not every test crate scrapes metrics")]
pub fn metric_value(text: &str, name: &str) -> Option<f64> {
    text.lines()
        .find_map(|l| l.strip_prefix(name)?.strip_prefix(' ')?.trim().parse().ok())
}

/// A free loopback port (bound and released: another process may take it in between, which
/// a test run makes unlikely).
#[allow(dead_code, reason = "not every test crate needs a port")]
pub fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .expect("a free port")
}

/// Every scalar of metrics.csv is in `run/tensorboard/` as TensorBoard's own reader sees it
/// (tag = column, step = env_steps, one point per non-empty cell, the same value), and the
/// final evaluation under `eval/`.
#[allow(dead_code, reason = "not every test crate reads TensorBoard files")]
pub fn assert_tensorboard_holds_the_metrics(run: &Path) {
    let tags = python_json("tensorboard_scalars.py", &[run.join("tensorboard")]);
    let text = std::fs::read_to_string(run.join("metrics.csv")).expect("metrics.csv");
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap_or_default().split(',').collect();
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    assert!(!rows.is_empty(), "no update in metrics.csv");
    let steps = header
        .iter()
        .position(|h| *h == "env_steps")
        .expect("env_steps");
    for (c, name) in header.iter().enumerate() {
        let expected: Vec<(u64, f32)> = rows
            .iter()
            .filter_map(|r| {
                let v: f64 = r[c].parse().ok()?;
                Some((r[steps].parse().ok()?, v as f32))
            })
            .collect();
        let got: Vec<(u64, f32)> = tags[*name]
            .as_array()
            .map(|points| {
                points
                    .iter()
                    .map(|p| {
                        (
                            p[0].as_u64().unwrap_or(0),
                            p[1].as_f64().unwrap_or(f64::NAN) as f32,
                        )
                    })
                    .collect()
            })
            .unwrap_or_default();
        assert_eq!(got, expected, "tag {name}");
    }
    for tag in ["eval/return_mean", "eval/length_mean"] {
        assert_eq!(tags[tag].as_array().map(Vec::len), Some(1), "{tag}");
    }
}

/// A `jsae recommender` process, killed when dropped.
#[allow(dead_code, reason = "not every test crate starts a recommender")]
pub struct Server(pub std::process::Child);

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Starts `jsae recommender --listen 127.0.0.1:0 ARGS`; returns it and its address.
#[allow(dead_code, reason = "not every test crate starts a recommender")]
pub fn start_recommender<S: AsRef<std::ffi::OsStr>>(args: &[S]) -> (Server, String) {
    use std::io::{BufRead, BufReader};
    let mut child = Command::new(env!("CARGO_BIN_EXE_jsae"))
        .args(["recommender", "--listen", "127.0.0.1:0"])
        .args(args)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null())
        .spawn()
        .expect("jsae recommender starts");
    let mut first = String::new();
    BufReader::new(child.stdout.take().expect("stdout"))
        .read_line(&mut first)
        .expect("the address line");
    let server = Server(child);
    assert!(first.contains("listening on"), "{first}");
    let addr = first.trim().rsplit(' ').next().expect("an address");
    (server, addr.to_owned())
}

/// A process as /proc shows it.
#[allow(dead_code, reason = "not every test crate looks at processes")]
#[derive(Debug, Clone)]
pub struct ProcessInfo {
    /// Its id.
    pub pid: u32,
    /// Its parent's id.
    pub ppid: u32,
    /// Its command line, the arguments joined by NUL bytes.
    pub cmdline: String,
    /// Whether it runs (not gone, not a zombie waiting to be reaped).
    pub running: bool,
}

/// Every process now (from /proc).
#[allow(dead_code, reason = "not every test crate looks at processes")]
pub fn processes() -> Vec<ProcessInfo> {
    let Ok(entries) = std::fs::read_dir("/proc") else {
        return Vec::new();
    };
    entries
        .filter_map(|e| e.ok()?.file_name().to_str()?.parse::<u32>().ok())
        .filter_map(|pid| {
            let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
            // "pid (comm) state ppid ...": the fields after the last ')'
            let mut after = stat.rsplit(')').next()?.split_whitespace();
            let state = after.next()?;
            let ppid = after.next()?.parse().ok()?;
            let cmdline = std::fs::read(format!("/proc/{pid}/cmdline")).unwrap_or_default();
            Some(ProcessInfo {
                pid,
                ppid,
                cmdline: String::from_utf8_lossy(&cmdline).into_owned(),
                running: state != "Z" && state != "X",
            })
        })
        .collect()
}

/// The output of `command` (stdout discarded, stderr kept), which must end within `secs`
/// seconds: past them it is killed and the test fails saying `what`.
#[allow(dead_code, reason = "not every test crate waits on a process")]
pub fn stderr_within(command: &mut Command, secs: u64, what: &str) -> std::process::Output {
    let mut child = command
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("the process starts");
    let started = std::time::Instant::now();
    while child.try_wait().expect("waits").is_none() {
        if started.elapsed().as_secs() > secs {
            let _ = child.kill();
            panic!("{what} after {secs} s");
        }
        std::thread::sleep(std::time::Duration::from_millis(200));
    }
    child.wait_with_output().expect("its output")
}
