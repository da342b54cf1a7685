//! The Recommender's command-line clients (containers carry no grpcurl):
//! `jsae recommend` asks for recommendations once, `jsae submit-sessions` streams sessions
//! from a JSON-lines file. Both print the answer as one JSON line.

use std::io::BufRead;

use jsae_net::security::{Security, SecurityFlags};
use jsae_wire::pb;

use jsae_envs::recsys::Session;
use jsae_recommender::{MAX_CALL_BYTES, MAX_SESSIONS_PER_CALL};

/// The client's command line.
#[derive(Debug, Clone, clap::Args)]
#[command(mut_arg("tls_client_ca", |a| a.hide(true)))] // a server's flag
pub struct AskArgs {
    /// The Recommender's address (`http://host:port`, or `host:port`).
    #[arg(
        long,
        env = "JSAE_RECOMMENDER",
        default_value = "http://127.0.0.1:50060"
    )]
    pub addr: String,
    /// Items to recommend.
    #[arg(long, default_value_t = 5)]
    pub k: u32,
    /// The purchase history, item ids oldest first.
    #[arg(required = true)]
    pub history: Vec<String>,
    /// `--auth-token-file`, `--tls-*`.
    #[command(flatten)]
    pub security: SecurityFlags,
}

/// Asks once; the answer as JSON, or the status as an error.
pub async fn ask(args: &AskArgs) -> Result<serde_json::Value, String> {
    let security = args.security.load()?;
    let (channel, url) = crate::oneshot::connect(&args.addr, &security)?;
    let mut client = pb::recommender_client::RecommenderClient::new(channel);
    let r = client
        .recommend(pb::RecommendRequest {
            history: args.history.clone(),
            k: args.k,
        })
        .await
        .map_err(|s| crate::oneshot::reason(&url, &s))?
        .into_inner();
    Ok(serde_json::json!({
        "items": r.items.iter().map(|i| serde_json::json!({"item_id": i.item_id, "score": i.score})).collect::<Vec<_>>(),
        "policy_version": r.policy_version,
        "embedding_version": r.embedding_version,
        "unknown_items": r.unknown_items,
    }))
}

/// Runs the client: exit 0 with the answer on stdout, 1 with the reason on stderr.
pub fn main(args: AskArgs) -> std::process::ExitCode {
    crate::oneshot::run("jsae recommend", ask(&args))
}

/// `jsae submit-sessions`' command line.
#[derive(Debug, Clone, clap::Args)]
#[command(mut_arg("tls_client_ca", |a| a.hide(true)))] // a server's flag
pub struct SubmitArgs {
    /// The Recommender's address (`http://host:port`, or `host:port`).
    #[arg(
        long,
        env = "JSAE_RECOMMENDER",
        default_value = "http://127.0.0.1:50060"
    )]
    pub addr: String,
    /// Sessions, one JSON object per line, as the session store keeps them:
    /// `{"session_id": "s1", "purchases": [{"item_id": "24852", "price": 1.5,
    /// "time_unix_ms": 0}]}` (`price` and `time_unix_ms` may be left out: 0). `-` reads stdin.
    pub file: std::path::PathBuf,
    /// `--auth-token-file`, `--tls-*`.
    #[command(flatten)]
    pub security: SecurityFlags,
}

/// Reads a JSON-lines session file; blank lines are skipped, a line that is not a session
/// stops it with its line number (nothing is sent then).
pub fn read_sessions(reader: impl BufRead, name: &str) -> Result<Vec<Session>, String> {
    let mut sessions = Vec::new();
    for (i, line) in reader.lines().enumerate() {
        let line = line.map_err(|e| format!("{name}: {e}"))?;
        if line.trim().is_empty() {
            continue;
        }
        let session: Session =
            serde_json::from_str(&line).map_err(|e| format!("{name}:{}: {e}", i + 1))?;
        sessions.push(session);
    }
    Ok(sessions)
}

/// The sessions cut into calls of at most [`MAX_SESSIONS_PER_CALL`] sessions and
/// [`MAX_CALL_BYTES`] encoded bytes (a session over that alone goes in a call of its own,
/// for the service to refuse).
fn calls(sessions: Vec<Session>) -> Vec<Vec<pb::Session>> {
    let mut calls: Vec<Vec<pb::Session>> = Vec::new();
    let mut bytes = 0;
    for s in sessions.into_iter().map(jsae_recommender::session_to_wire) {
        let n = prost::Message::encoded_len(&s) as u64;
        match calls.last_mut() {
            Some(call)
                if (call.len() as u64) < MAX_SESSIONS_PER_CALL && bytes + n <= MAX_CALL_BYTES =>
            {
                bytes += n;
                call.push(s);
            }
            _ => {
                bytes = n;
                calls.push(vec![s]);
            }
        }
    }
    calls
}

/// Streams the sessions in calls within the service's limits ([`calls`]) and adds up the
/// service's summaries (the rejected ones, with the service's reasons, are in `errors`;
/// sessions stored already are counted in `sessions_duplicate`). A call the service refuses
/// stores nothing: the error says how many calls before it were stored, and sending the file
/// again stores only the sessions not stored yet.
pub async fn submit(
    addr: &str,
    security: &Security,
    sessions: Vec<Session>,
) -> Result<serde_json::Value, String> {
    let (channel, url) = crate::oneshot::connect(addr, security)?;
    let mut client = pb::recommender_client::RecommenderClient::new(channel)
        .max_decoding_message_size(jsae_wire::MAX_MESSAGE_BYTES)
        .max_encoding_message_size(jsae_wire::MAX_MESSAGE_BYTES);
    let mut total = pb::SubmitSummary::default();
    let mut offset = 0u64;
    for call in calls(sessions) {
        let sent = call.len() as u64;
        let summary = client
            .submit_sessions(tokio_stream::iter(call))
            .await
            .map_err(|s| {
                format!(
                    "{} (sessions {offset}.. of the file; the {} before were stored, {} \
                     were stored already)",
                    crate::oneshot::reason(&url, &s),
                    total.sessions_accepted,
                    total.sessions_duplicate
                )
            })?
            .into_inner();
        total.sessions_accepted += summary.sessions_accepted;
        total.sessions_rejected += summary.sessions_rejected;
        total.sessions_duplicate += summary.sessions_duplicate;
        total.purchases_accepted += summary.purchases_accepted;
        // the service numbers sessions within a call; renumber them within the file
        total
            .errors
            .extend(summary.errors.into_iter().map(|e| renumber(&e, offset)));
        offset += sent;
    }
    Ok(serde_json::json!({
        "sessions_accepted": total.sessions_accepted,
        "sessions_rejected": total.sessions_rejected,
        "sessions_duplicate": total.sessions_duplicate,
        "purchases_accepted": total.purchases_accepted,
        "errors": total.errors,
    }))
}

/// `session N (...)` of a later call becomes `session N+offset (...)`.
fn renumber(error: &str, offset: u64) -> String {
    if offset == 0 {
        return error.to_owned();
    }
    error
        .strip_prefix("session ")
        .and_then(|rest| {
            let (n, tail) = rest.split_once(' ')?;
            let n: u64 = n.parse().ok()?;
            Some(format!("session {} {tail}", n + offset))
        })
        .unwrap_or_else(|| error.to_owned())
}

/// Runs `jsae submit-sessions`: exit 0 when every session was accepted, 1 when the service
/// rejected some (the summary is printed all the same) or could not be reached, 2 when the
/// file is not a session file.
pub fn submit_main(args: SubmitArgs) -> std::process::ExitCode {
    let read = if args.file.as_os_str() == "-" {
        read_sessions(std::io::stdin().lock(), "stdin")
    } else {
        let name = args.file.display().to_string();
        std::fs::File::open(&args.file)
            .map_err(|e| format!("{name}: {e}"))
            .and_then(|f| read_sessions(std::io::BufReader::new(f), &name))
    };
    let read = read.and_then(|s| Ok((s, args.security.load()?)));
    let (sessions, security) = match read {
        Ok(s) => s,
        Err(e) => {
            eprintln!("jsae submit-sessions: {e}");
            return std::process::ExitCode::from(2);
        }
    };
    if sessions.is_empty() {
        eprintln!(
            "jsae submit-sessions: no sessions in {}",
            args.file.display()
        );
        return std::process::ExitCode::from(2);
    }
    crate::oneshot::run("jsae submit-sessions", async {
        let summary = submit(&args.addr, &security, sessions).await?;
        match summary["sessions_rejected"].as_u64() {
            Some(0) => Ok(summary),
            rejected => {
                // the summary still goes to stdout; the exit status says some were refused
                println!("{summary}");
                Err(format!(
                    "{} sessions rejected (their reasons are in `errors`)",
                    rejected.unwrap_or_default()
                ))
            }
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn session_lines_parse_with_defaults_and_bad_lines_name_their_number() {
        let text = "{\"session_id\":\"a\",\"purchases\":[{\"item_id\":\"1\"},{\"item_id\":\"2\",\"price\":2.5,\"time_unix_ms\":7}]}\n\n{\"session_id\":\"b\",\"purchases\":[]}\n";
        let sessions = read_sessions(text.as_bytes(), "f").expect("parses");
        assert_eq!(sessions.len(), 2);
        assert_eq!(sessions[0].purchases[0].price, 0.0);
        assert_eq!(sessions[0].purchases[1].time_unix_ms, 7);
        assert!(sessions[1].purchases.is_empty(), "the service judges it");
        let bad = read_sessions(
            "{\"session_id\":\"a\",\"purchases\":[]}\nnot json\n".as_bytes(),
            "f",
        )
        .expect_err("line 2 is no session");
        assert!(bad.starts_with("f:2:"), "{bad}");
    }

    #[test]
    fn sessions_are_cut_into_calls_within_the_services_byte_limit() {
        // about 2.6 MB each: 25 fit in MAX_CALL_BYTES (64 MiB)
        let big = |i: usize| Session {
            session_id: format!("s{i}"),
            purchases: (0..10_000)
                .map(|_| jsae_envs::recsys::Purchase {
                    item_id: "x".repeat(250),
                    price: 1.0,
                    time_unix_ms: 0,
                })
                .collect(),
        };
        let calls = calls((0..60).map(big).collect());
        let sizes: Vec<usize> = calls.iter().map(Vec::len).collect();
        assert_eq!(sizes, [25, 25, 10]);
        let bytes: u64 = calls[0]
            .iter()
            .map(|s| prost::Message::encoded_len(s) as u64)
            .sum();
        assert!(bytes <= MAX_CALL_BYTES);
    }

    #[test]
    fn errors_of_later_calls_are_numbered_within_the_file() {
        assert_eq!(
            renumber(
                "session 3 (session_id \"x\"): INVALID_ARGUMENT: no purchases",
                100_000
            ),
            "session 100003 (session_id \"x\"): INVALID_ARGUMENT: no purchases"
        );
        assert_eq!(renumber("other", 5), "other");
    }
}
