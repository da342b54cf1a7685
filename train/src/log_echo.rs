//! The services' warnings and errors on `jsae train`'s own output: while a run goes on as
//! separate processes, each service's log (`logs/NAME.log`) is read as it grows and its WARN
//! and ERROR lines are shown, prefixed with the service's name, at most
//! [`MAX_ECHOED_LINES`] per service (then one line saying where the rest are), so a refused
//! certificate or token is seen where the user looks, not only in a file.

use std::io::{Read, Seek, SeekFrom};
use std::path::PathBuf;

use crate::progress::Progress;

/// Most lines shown per service; the rest stay in its log.
pub const MAX_ECHOED_LINES: usize = 20;

/// One service's log, read from where the last look stopped.
#[derive(Debug)]
pub struct LogEcho {
    name: String,
    path: PathBuf,
    offset: u64,
    /// A line not yet ended by a newline.
    partial: String,
    shown: usize,
}

impl LogEcho {
    /// Follows the log of the service `name` at `path` from its start.
    pub fn new(name: &str, path: PathBuf) -> Self {
        Self {
            name: name.to_string(),
            path,
            offset: 0,
            partial: String::new(),
            shown: 0,
        }
    }

    /// Shows the warnings and errors written since the last look.
    pub fn show_new(&mut self, progress: &Progress) {
        if self.shown > MAX_ECHOED_LINES {
            return;
        }
        let Ok(mut file) = std::fs::File::open(&self.path) else {
            return;
        };
        if file.seek(SeekFrom::Start(self.offset)).is_err() {
            return;
        }
        // at most 1 MiB a look: a log that floods is caught up with over several looks
        let mut bytes = Vec::new();
        let Ok(read) = file.take(1 << 20).read_to_end(&mut bytes) else {
            return;
        };
        self.offset += read as u64;
        self.partial.push_str(&String::from_utf8_lossy(&bytes));
        let Some(end) = self.partial.rfind('\n') else {
            return;
        };
        let complete: String = self.partial.drain(..=end).collect();
        for line in complete.lines().filter(|l| is_warning(l)) {
            self.shown += 1;
            if self.shown > MAX_ECHOED_LINES {
                progress.warn(&format!(
                    "[{}] more warnings in {}",
                    self.name,
                    self.path.display()
                ));
                return;
            }
            progress.warn(&format!("[{}] {}", self.name, line.trim()));
        }
    }
}

/// Whether a log line (text or JSON) is a warning or an error.
fn is_warning(line: &str) -> bool {
    [
        " WARN ",
        " ERROR ",
        "\"level\":\"WARN\"",
        "\"level\":\"ERROR\"",
    ]
    .iter()
    .any(|mark| line.contains(mark))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_warnings_and_errors_are_shown_each_once_and_at_most_the_cap() {
        let dir = std::env::temp_dir().join(format!("jsae-log-echo-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("dir");
        let path = dir.join("actor-0.log");
        std::fs::write(
            &path,
            "t  INFO a: fine\nt  WARN a: refused\nt ERROR a: gave",
        )
        .expect("w");
        let mut echo = LogEcho::new("actor-0", path.clone());
        let progress = Progress::new(0, true);
        echo.show_new(&progress);
        assert_eq!(echo.shown, 1, "the unfinished line waits for its end");
        std::fs::write(
            &path,
            format!(
                "t  INFO a: fine\nt  WARN a: refused\nt ERROR a: gave up\n{}",
                "t  WARN x\n".repeat(40)
            ),
        )
        .expect("w");
        echo.show_new(&progress);
        assert_eq!(echo.shown, MAX_ECHOED_LINES + 1, "capped");
        assert!(is_warning(r#"{"level":"ERROR","fields":{}}"#));
        assert!(!is_warning("t  INFO a: WARNING in a message"));
        let _ = std::fs::remove_dir_all(&dir);
    }
}
