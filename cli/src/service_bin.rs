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
    let matches = LogFormatFlag::augment_args(A::command().name(name).bin_name(name)).get_matches();
    let parsed = LogFormatFlag::from_arg_matches(&matches)
        .and_then(|flag| Ok((flag, A::from_arg_matches(&matches)?)));
    let (flag, args) = parsed.unwrap_or_else(|e| e.exit());
    flag.apply();
    let command = into(args);
    crate::closed_pipe::run(|| crate::commands::run(command))
}
