//! `jsae recommend`: a one-shot Recommender client for the command line and for checks
//! (containers carry no grpcurl). Prints the answer as one JSON line.

use jsae_proto::wire::pb;

/// The client's command line.
#[derive(Debug, Clone, clap::Args)]
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
}

/// Asks once; the answer as JSON, or the status as an error.
pub async fn ask(args: &AskArgs) -> Result<serde_json::Value, String> {
    let url = if args.addr.contains("://") {
        args.addr.clone()
    } else {
        format!("http://{}", args.addr)
    };
    let mut client = pb::recommender_client::RecommenderClient::connect(url.clone())
        .await
        .map_err(|e| format!("{url}: {e}"))?;
    let r = client
        .recommend(pb::RecommendRequest {
            history: args.history.clone(),
            k: args.k,
        })
        .await
        .map_err(|s| format!("{url}: {:?}: {}", s.code(), s.message()))?
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
    let runtime = match tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
    {
        Ok(r) => r,
        Err(e) => {
            eprintln!("jsae recommend: {e}");
            return std::process::ExitCode::FAILURE;
        }
    };
    match runtime.block_on(ask(&args)) {
        Ok(v) => {
            println!("{v}");
            std::process::ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("jsae recommend: {e}");
            std::process::ExitCode::FAILURE
        }
    }
}
