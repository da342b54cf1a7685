//! The `EnvHost` gRPC service an actor serves to its environment workers: a worker's hello
//! is checked against the run (its environment and spaces), then its commands are whatever
//! the pool sends and its replies go to the pool as events. A worker whose stream ends, or
//! that says its environment failed, is gone: the pool ends its episodes.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::time::Duration;

use jsae_envs::GymSpace;
use jsae_wire::{RpcError, pb};
use tokio::sync::mpsc;
use tokio_stream::wrappers::ReceiverStream;
use tonic::{Request, Response, Status, Streaming};

/// The protocol version workers speak (`EnvHello.protocol`).
pub const PROTOCOL: u32 = 1;
/// The most environments one worker may host.
pub const MAX_WORKER_ENVS: u32 = 4096;
/// How long a worker has to say hello once connected.
const HELLO_TIMEOUT: Duration = Duration::from_secs(30);

/// What a worker's stream told the pool.
#[derive(Debug)]
pub(crate) enum Event {
    /// A reply to a command.
    Reply(pb::EnvReply),
    /// The worker is gone, and why.
    Gone(String),
}

/// A worker that said hello and was accepted.
#[derive(Debug)]
pub(crate) struct Joined {
    pub(crate) id: u64,
    pub(crate) name: String,
    pub(crate) envs: u32,
    /// Its command stream (an error ends it with that status).
    pub(crate) commands: mpsc::Sender<Result<pb::EnvCommand, Status>>,
}

/// What the service and the pool share.
#[derive(Debug)]
pub(crate) struct Lobby {
    env_id: String,
    spaces: (GymSpace, GymSpace),
    /// Workers accepted and not yet taken in by the pool.
    pub(crate) joined: Mutex<Vec<Joined>>,
    pub(crate) arrived: Condvar,
    events: Mutex<std::sync::mpsc::Sender<(u64, Event)>>,
    next_id: AtomicU64,
}

impl Lobby {
    pub(crate) fn new(
        env_id: String,
        spaces: (GymSpace, GymSpace),
        events: std::sync::mpsc::Sender<(u64, Event)>,
    ) -> Self {
        Self {
            env_id,
            spaces,
            joined: Mutex::new(Vec::new()),
            arrived: Condvar::new(),
            events: Mutex::new(events),
            next_id: AtomicU64::new(1),
        }
    }

    fn send(&self, worker: u64, event: Event) {
        let events = self
            .events
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        let _ = events.send((worker, event));
    }

    /// Checks a hello against the run, with the reason a worker is refused.
    fn check(&self, hello: &pb::EnvHello) -> Result<(), String> {
        if hello.protocol != PROTOCOL {
            return Err(format!(
                "protocol {} is not this actor's ({PROTOCOL}): install the jsae package of \
                 this version (pip install ./python)",
                hello.protocol
            ));
        }
        if hello.env_id != self.env_id {
            return Err(format!(
                "this actor's run steps {:?}, not {:?}",
                self.env_id, hello.env_id
            ));
        }
        if hello.envs == 0 || hello.envs > MAX_WORKER_ENVS {
            return Err(format!(
                "a worker hosts 1 to {MAX_WORKER_ENVS} environments, not {}",
                hello.envs
            ));
        }
        let (obs, act) = &self.spaces;
        // a reply carries every environment's observation, and as many again where all end
        // at once (a time limit): it must fit a message
        let per_env = 8 * obs.state_space().stored_len() as u64 + 32;
        let most = jsae_wire::MAX_MESSAGE_BYTES as u64 / per_env;
        if u64::from(hello.envs) > most {
            return Err(format!(
                "{} environments of {} would not fit one message: at most {most} per worker",
                hello.envs,
                obs.describe()
            ));
        }
        for (what, said, want) in [
            ("observation", &hello.observation_space, obs),
            ("action", &hello.action_space, act),
        ] {
            let said = said
                .as_ref()
                .ok_or_else(|| format!("the hello has no {what} space"))
                .and_then(|s| gym_space(s).map_err(|e| format!("{what} space: {e}")))?;
            if &said != want {
                return Err(format!(
                    "the {what} space {} is not the run's {} (environment.gym.{what})",
                    said.describe(),
                    want.describe()
                ));
            }
        }
        Ok(())
    }
}

/// A space's wire form as the run's settings hold it.
pub fn gym_space(space: &pb::Space) -> Result<GymSpace, String> {
    use pb::space::Kind;
    let space = match &space.kind {
        Some(Kind::Discrete(d)) => GymSpace::Discrete {
            n: d.n,
            start: d.start,
        },
        Some(Kind::MultiDiscrete(m)) => GymSpace::MultiDiscrete {
            nvec: m.nvec.clone(),
        },
        Some(Kind::Box(b)) => GymSpace::Box {
            shape: b.shape.clone(),
            low: b.low.clone(),
            high: b.high.clone(),
        },
        None => return Err("no space".into()),
    };
    space.check("the space")?;
    Ok(space)
}

/// The service (cheap to clone: every clone serves the same lobby).
#[derive(Debug, Clone)]
pub struct EnvHost {
    lobby: Arc<Lobby>,
}

impl EnvHost {
    pub(crate) fn new(lobby: Arc<Lobby>) -> Self {
        Self { lobby }
    }

    /// The service to serve (`jsae_net::serve`).
    pub fn server(self) -> pb::env_host_server::EnvHostServer<Self> {
        pb::env_host_server::EnvHostServer::new(self)
            .max_decoding_message_size(jsae_wire::MAX_MESSAGE_BYTES)
            .max_encoding_message_size(jsae_wire::MAX_MESSAGE_BYTES)
    }
}

#[tonic::async_trait]
impl pb::env_host_server::EnvHost for EnvHost {
    type AttachStream = ReceiverStream<Result<pb::EnvCommand, Status>>;

    async fn attach(
        &self,
        request: Request<Streaming<pb::EnvUp>>,
    ) -> Result<Response<Self::AttachStream>, Status> {
        let peer = request
            .remote_addr()
            .map_or_else(|| "?".to_string(), |a| a.to_string());
        let mut inbound = request.into_inner();
        let first = tokio::time::timeout(HELLO_TIMEOUT, inbound.message())
            .await
            .map_err(|_| RpcError::InvalidArgument("no hello within 30 s".into()))??;
        let Some(pb::EnvUp {
            kind: Some(pb::env_up::Kind::Hello(hello)),
        }) = first
        else {
            return Err(RpcError::InvalidArgument(
                "a worker's first message must be its hello".into(),
            )
            .into());
        };
        if let Err(reason) = self.lobby.check(&hello) {
            tracing::warn!(
                "environment worker {} ({peer}) refused: {reason}",
                hello.worker
            );
            return Err(RpcError::InvalidArgument(reason).into());
        }
        let id = self.lobby.next_id.fetch_add(1, Ordering::Relaxed);
        let name = format!("{} ({peer})", hello.worker);
        let (commands, outbound) = mpsc::channel(4);
        tracing::info!(
            "environment worker {name} joined with {} environments",
            hello.envs
        );
        let lobby = self.lobby.clone();
        tokio::spawn(async move {
            let gone = loop {
                match inbound.message().await {
                    Ok(Some(pb::EnvUp {
                        kind: Some(pb::env_up::Kind::Reply(r)),
                    })) => lobby.send(id, Event::Reply(r)),
                    Ok(Some(pb::EnvUp {
                        kind: Some(pb::env_up::Kind::Error(e)),
                    })) => break format!("its environment failed: {e}"),
                    Ok(Some(_)) => break "it sent a second hello, or an empty message".into(),
                    Ok(None) => break "its stream ended".into(),
                    Err(s) => break format!("its stream broke: {}", s.message()),
                }
            };
            lobby.send(id, Event::Gone(gone));
        });
        let mut joined = self
            .lobby
            .joined
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        joined.push(Joined {
            id,
            name,
            envs: hello.envs,
            commands,
        });
        self.lobby.arrived.notify_all();
        Ok(Response::new(ReceiverStream::new(outbound)))
    }
}
