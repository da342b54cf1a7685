//! Logging of every process: tracing events on stderr, as text (coloured only on a terminal,
//! so redirected output and `logs/*.log` hold no escape codes) or as JSON lines for log
//! collectors (`--log-format json`, env `JSAE_LOG_FORMAT`). The level is `RUST_LOG`'s
//! (default `info`). A service's lines on stdout (the address it listens on, its result) and
//! its refusals before it runs follow the same format, so that in JSON mode every line it
//! writes is a JSON object.

use std::sync::OnceLock;

/// The environment variable the format is read from where no flag chose it.
pub const LOG_FORMAT_ENV: &str = "JSAE_LOG_FORMAT";

/// How log events are written.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum LogFormat {
    /// One line of text per event.
    #[default]
    Text,
    /// One JSON object per line (timestamp, level, target, fields).
    Json,
}

impl LogFormat {
    /// The flag's value.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Text => "text",
            Self::Json => "json",
        }
    }
}

static CHOSEN: OnceLock<LogFormat> = OnceLock::new();

/// Fixes the format for this process (the `jsae` program's `--log-format`, before any
/// command runs); later calls change nothing.
pub fn choose_log_format(format: LogFormat) {
    let _ = CHOSEN.set(format);
}

/// The format chosen by a flag, if any (the launcher passes it on to its services).
pub fn chosen_log_format() -> Option<LogFormat> {
    CHOSEN.get().copied()
}

/// The format in effect: the flag's, else `JSAE_LOG_FORMAT`'s (an unknown value is text,
/// with a warning), else text.
fn log_format() -> (LogFormat, Option<String>) {
    if let Some(f) = chosen_log_format() {
        return (f, None);
    }
    match std::env::var(LOG_FORMAT_ENV).as_deref() {
        Err(_) | Ok("" | "text") => (LogFormat::Text, None),
        Ok("json") => (LogFormat::Json, None),
        Ok(other) => (
            LogFormat::Text,
            Some(format!(
                "{LOG_FORMAT_ENV}={other:?} is neither text nor json; logging text"
            )),
        ),
    }
}

/// Installs the process's log subscriber (once; later calls change nothing).
pub fn init_logging() {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    let (format, warning) = log_format();
    let builder = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr);
    let installed = match format {
        LogFormat::Json => builder.json().with_ansi(false).try_init(),
        // colour only for a person at a terminal: not in redirected output or logs/*.log
        LogFormat::Text => builder
            .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
            .try_init(),
    };
    if let (Ok(()), Some(w)) = (installed, warning) {
        tracing::warn!("{w}");
    }
}

/// Whether this process logs JSON lines.
pub fn logs_json() -> bool {
    log_format().0 == LogFormat::Json
}

/// One event on stdout, in the JSON shape of the log lines on stderr.
fn json_on_stdout(event: impl FnOnce()) {
    let stdout = tracing_subscriber::fmt()
        .json()
        .with_ansi(false)
        .with_writer(std::io::stdout)
        .finish();
    tracing::subscriber::with_default(stdout, event);
}

/// Says on stdout where service `name` listens, as the first line launchers wait for:
/// `NAME listening on ADDR`, or that message as a JSON log line with the address in its
/// `address` field ([`announced_address`] reads either).
pub fn announce_listening(name: &str, addr: std::net::SocketAddr) {
    let line = format!("{name} listening on {addr}");
    if logs_json() {
        json_on_stdout(|| tracing::info!(address = %addr, "{line}"));
    } else {
        println!("{line}");
    }
}

/// The address in a service's announcement line ([`announce_listening`]), text or JSON.
pub fn announced_address(line: &str) -> Option<String> {
    if line.trim_start().starts_with('{') {
        let event: serde_json::Value = serde_json::from_str(line).ok()?;
        return event["fields"]["address"].as_str().map(str::to_string);
    }
    line.rsplit(' ')
        .next()
        .filter(|a| a.contains(':'))
        .map(str::to_string)
}

/// Prints a service's result on stdout: pretty JSON as text, or one JSON log line whose
/// `result` field holds it (compact) in JSON mode.
pub fn print_result(what: &str, result: &impl serde::Serialize) {
    if logs_json() {
        let compact = serde_json::to_string(result).unwrap_or_default();
        json_on_stdout(|| tracing::info!(result = %compact, "{what}"));
    } else {
        println!(
            "{}",
            serde_json::to_string_pretty(result).unwrap_or_default()
        );
    }
}

/// Reports why service `name` stopped or would not start on stderr: `NAME: REASON` as text,
/// an error event in JSON mode.
pub fn report_failure(name: &str, reason: &str) {
    if logs_json() {
        init_logging();
        tracing::error!("{name}: {reason}");
    } else {
        eprintln!("{name}: {reason}");
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_address_is_read_from_a_text_or_a_json_announcement() {
        assert_eq!(
            announced_address("jsae-learner listening on 127.0.0.1:5000").as_deref(),
            Some("127.0.0.1:5000")
        );
        let json = r#"{"timestamp":"2026-11-28T13:00:00.000000Z","level":"INFO","fields":{"message":"jsae-learner listening on 127.0.0.1:5000","address":"127.0.0.1:5000"},"target":"jsae_net::logging"}"#;
        assert_eq!(announced_address(json).as_deref(), Some("127.0.0.1:5000"));
        assert_eq!(announced_address("starting"), None);
    }
}
