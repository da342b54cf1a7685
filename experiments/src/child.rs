//! Child processes a launcher owns and must not leave behind: a flag that SIGTERM or SIGINT
//! to this process sets (instead of ending it at once), and a child stopped with SIGTERM,
//! then SIGKILL past a timeout. `jsae train` stops its services with them, `jsae sweep` its
//! runs.

use std::process::Child;
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};

/// A flag that SIGTERM or SIGINT to this process sets (instead of ending it at once).
pub fn stop_on_signal() -> std::io::Result<Arc<AtomicBool>> {
    let flag = Arc::new(AtomicBool::new(false));
    for signal in [signal_hook::consts::SIGTERM, signal_hook::consts::SIGINT] {
        signal_hook::flag::register(signal, flag.clone())?;
    }
    Ok(flag)
}

/// Stops `child` (unless it has ended): SIGTERM, then SIGKILL if it still runs after
/// `timeout`; false when it had to be killed.
pub fn terminate(child: &mut Child, timeout: Duration) -> bool {
    if !matches!(child.try_wait(), Ok(None)) {
        return true;
    }
    let pid = rustix::process::Pid::from_child(child);
    let _ = rustix::process::kill_process(pid, rustix::process::Signal::TERM);
    let deadline = Instant::now() + timeout;
    while Instant::now() < deadline {
        if !matches!(child.try_wait(), Ok(None)) {
            return true;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    let _ = child.kill();
    let _ = child.wait();
    false
}
