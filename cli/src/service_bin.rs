//! The per-service binaries (`jsae-embedder`, `jsae-learner`, `jsae-actor`): each is the
//! `jsae` subcommand of the same name, with the same flags (`--log-format` too) and run by
//! the same code ([`crate::commands::run`]), so `jsae-learner` reads a recommender run's
//! logged purchases exactly as `jsae learner` does.

use std::process::ExitCode;

use clap::{Args, FromArgMatches, Parser};

use crate::commands::Command;

/// `--log-format`, on `jsae` (for every subcommand) and on each service binary.
#[derive(Args, Debug, Clone, Copy)]
pub struct LogFormatFlag {
    /// Log lines as text (coloured only on a terminal) or JSON objects, one per line; the
    /// services `jsae train` starts log the same way [default: $JSAE_LOG_FORMAT, else text].
    #[arg(long, global = true, value_enum)]
    pub log_format: Option<jsae_net::logging::LogFormat>,
}

impl LogFormatFlag {
    /// Makes the chosen format the process's (before anything logs).
    pub fn apply(self) {
        if let Some(format) = self.log_format {
            jsae_net::logging::choose_log_format(format);
        }
    }
}

/// Runs the service binary `name`: parses its flags as `jsae <subcommand>` does and runs the
/// subcommand `into` makes of them.
pub fn main<A: Parser + Args>(name: &'static str, into: fn(A) -> Command) -> ExitCode {
    let command = LogFormatFlag::augment_args(A::command().name(name).bin_name(name));
    let parsed = command.try_get_matches().and_then(|matches| {
        let flag = LogFormatFlag::from_arg_matches(&matches)?;
        Ok((flag, A::from_arg_matches(&matches)?))
    });
    let (flag, args) = match parsed {
        Ok(parsed) => parsed,
        Err(e) if e.use_stderr() && asks_for_json() => {
            // a usage error in JSON mode is a JSON line too
            jsae_net::logging::choose_log_format(jsae_net::logging::LogFormat::Json);
            jsae_net::logging::report_failure(name, e.to_string().trim());
            return ExitCode::from(u8::try_from(e.exit_code()).unwrap_or(2));
        }
        Err(e) => e.exit(),
    };
    flag.apply();
    let command = into(args);
    crate::closed_pipe::run(|| crate::commands::run(command))
}

/// Whether the command line (`--log-format json`, `--log-format=json`) or the environment
/// asks for JSON logs, read before the flags parse.
fn asks_for_json() -> bool {
    let args: Vec<String> = std::env::args().collect();
    let flag = args
        .windows(2)
        .any(|w| w[0] == "--log-format" && w[1] == "json")
        || args.iter().any(|a| a == "--log-format=json");
    flag || std::env::var(jsae_net::logging::LOG_FORMAT_ENV).is_ok_and(|v| v == "json")
}
