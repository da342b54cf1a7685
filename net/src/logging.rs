//! Logging of every process: tracing events on stderr, as text (coloured only on a terminal,
//! so redirected output and `logs/*.log` hold no escape codes) or as JSON lines for log
//! collectors (`--log-format json`, env `JSAE_LOG_FORMAT`). The level is `RUST_LOG`'s
//! (default `info`).

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
