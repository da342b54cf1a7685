//! Who runs the end-of-run evaluation. The learner asks the actor whose fragment reached the
//! run's env steps; it knows which actors are alive by their open policy streams (the
//! [`Roster`]), so when the asked actor's last stream closes (the actor died, or its
//! connection did) it asks another actor whose stream is open, or the next one to connect.
//! Each request has a fresh random id; only the open one is answered. An actor id is held by
//! the connection that opened its stream ([`ActorIds`]).

use std::collections::HashMap;
use std::net::SocketAddr;
use std::sync::{Arc, Mutex};

use jsae_wire::RpcError;
use jsae_wire::pb;
use tokio::sync::mpsc;

use super::input::{Announced, Input};
use super::roster::Roster;

/// The open evaluation request and the actors that could take it over.
#[derive(Debug)]
pub(super) struct Evaluation {
    episodes: u32,
    seed: u64,
    /// The embedding version the final policy was trained on.
    embedding_version: u64,
    asked: Option<pb::EvalRequest>,
}

impl Evaluation {
    pub(super) fn new(episodes: u32, seed: u64) -> Self {
        Self {
            episodes,
            seed,
            embedding_version: 0,
            asked: None,
        }
    }

    /// The open request, once the run's env steps are reached.
    pub(super) fn open(&self) -> Option<pb::EvalRequest> {
        self.asked
    }

    /// The request to publish: to `actor` when its stream is open (or none is), else to an
    /// actor whose stream is; evaluated on `embedding_version`, the one the final policy was
    /// trained on.
    pub(super) fn ask(
        &mut self,
        actor: u64,
        roster: &Roster,
        embedding_version: u64,
    ) -> pb::EvalRequest {
        self.embedding_version = embedding_version;
        let actor = if roster.is_open(actor) {
            actor
        } else {
            roster.any_open().unwrap_or(actor)
        };
        self.request(actor)
    }

    /// The roster changed (a policy stream opened or closed); a new request to publish when
    /// the asked actor has no stream left and another actor has one.
    pub(super) fn roster_changed(&mut self, roster: &Roster) -> Option<pb::EvalRequest> {
        let asked = self.asked?;
        if roster.is_open(asked.actor_id) {
            return None;
        }
        let other = roster.any_open()?;
        tracing::warn!(
            "the policy stream of actor {} closed before it reported its evaluation: asking \
             actor {other}",
            asked.actor_id
        );
        Some(self.request(other))
    }

    fn request(&mut self, actor_id: u64) -> pb::EvalRequest {
        let request = pb::EvalRequest {
            request_id: jsae_wire::random_id(),
            episodes: self.episodes,
            seed: self.seed,
            actor_id,
            embedding_version: self.embedding_version,
        };
        self.asked = Some(request);
        request
    }
}

/// An actor's open policy stream: announced to the training thread when made, and its end when
/// dropped (with the stream's task, when the actor disconnects).
#[derive(Debug)]
pub(super) struct OpenStream {
    actor: u64,
    queue: mpsc::Sender<Input>,
}

impl OpenStream {
    /// Announces the stream of an actor, with what it said of itself; None when the training
    /// thread is gone.
    pub(super) async fn announce(
        actor: u64,
        announced: Announced,
        queue: &mpsc::Sender<Input>,
    ) -> Option<Self> {
        queue
            .send(Input::Stream {
                actor,
                opened: Some(announced),
            })
            .await
            .ok()?;
        Some(Self {
            actor,
            queue: queue.clone(),
        })
    }

    pub(super) fn actor(&self) -> u64 {
        self.actor
    }
}

impl Drop for OpenStream {
    fn drop(&mut self) {
        let (queue, actor) = (self.queue.clone(), self.actor);
        if let Ok(runtime) = tokio::runtime::Handle::try_current() {
            runtime.spawn(async move {
                let closed = Input::Stream {
                    actor,
                    opened: None,
                };
                let _ = queue.send(closed).await;
            });
        }
    }
}

/// Which connection holds each actor id. An id belongs to the connection whose policy stream
/// named it first, while any of its streams is open; another connection naming it is refused
/// (ALREADY_EXISTS, and its client tries again later), so nobody can take another actor's
/// place in the batch or its evaluation request, which only the named actor's streams carry.
/// An actor that reconnects gets its id back once its old connection's stream has closed
/// (at once when its process died; within the keepalive when its host vanished).
#[derive(Debug, Clone, Default)]
pub(super) struct ActorIds(Arc<Mutex<HashMap<u64, Holder>>>);

/// The connection holding an actor id, and its open streams naming it.
type Holder = (Option<SocketAddr>, usize);

impl ActorIds {
    /// Claims `actor` for `peer`'s connection while the claim lives.
    pub(super) fn claim(&self, actor: u64, peer: Option<SocketAddr>) -> Result<IdClaim, RpcError> {
        let mut held = self.0.lock().unwrap_or_else(|e| e.into_inner());
        let (holder, streams) = held.entry(actor).or_insert((peer, 0));
        if *holder != peer {
            return Err(RpcError::AlreadyExists(format!(
                "actor id {actor} is held by another connection's open policy stream: two \
                 actors were given one id, or this actor's earlier connection is not closed yet"
            )));
        }
        *streams += 1;
        Ok(IdClaim {
            ids: self.clone(),
            actor,
        })
    }
}

/// An actor id held by one connection while this lives.
#[derive(Debug)]
pub(super) struct IdClaim {
    ids: ActorIds,
    actor: u64,
}

impl Drop for IdClaim {
    fn drop(&mut self) {
        let mut held = self.ids.0.lock().unwrap_or_else(|e| e.into_inner());
        if let Some((_, streams)) = held.get_mut(&self.actor) {
            *streams -= 1;
            if *streams == 0 {
                held.remove(&self.actor);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_actor_id_belongs_to_one_connection_while_its_streams_are_open() {
        let ids = ActorIds::default();
        let (a, b) = (
            Some(SocketAddr::from(([127, 0, 0, 1], 1))),
            Some(SocketAddr::from(([127, 0, 0, 1], 2))),
        );
        let first = ids.claim(7, a).expect("first claim");
        let second = ids.claim(7, a).expect("the same connection again");
        let e = ids.claim(7, b).expect_err("another connection");
        assert!(matches!(e, RpcError::AlreadyExists(_)), "{e:?}");
        let _other = ids.claim(8, b).expect("another id");
        drop(first);
        assert!(ids.claim(7, b).is_err(), "a stream of a is still open");
        drop(second);
        let _taken_over = ids.claim(7, b).expect("a's streams closed");
    }

    /// Opens (`Some(steps)`) or closes a stream, then tells the evaluation.
    fn stream(
        e: &mut Evaluation,
        r: &mut Roster,
        actor: u64,
        open: bool,
    ) -> Option<pb::EvalRequest> {
        if open {
            r.open(actor, 1, 0);
        } else {
            r.close(actor);
        }
        e.roster_changed(r)
    }

    #[test]
    fn the_asked_actor_is_replaced_only_when_its_last_stream_closes() {
        let (mut e, mut r) = (
            Evaluation::new(3, 7),
            Roster::new(1, 1, std::time::Duration::ZERO),
        );
        assert_eq!(stream(&mut e, &mut r, 4, true), None);
        assert_eq!(stream(&mut e, &mut r, 9, true), None);
        assert_eq!(stream(&mut e, &mut r, 9, true), None);
        let first = e.ask(9, &r, 0);
        assert_eq!((first.actor_id, first.episodes, first.seed), (9, 3, 7));
        assert_eq!(
            stream(&mut e, &mut r, 9, false),
            None,
            "actor 9 has another stream"
        );
        let second = stream(&mut e, &mut r, 9, false).expect("actor 4 asked");
        assert_eq!(second.actor_id, 4);
        assert_ne!(second.request_id, first.request_id);
        assert_eq!(e.open(), Some(second));
        // an actor coming back does not take the request from one that is alive
        assert_eq!(stream(&mut e, &mut r, 9, true), None);
    }

    #[test]
    fn with_no_actor_alive_the_next_one_to_connect_is_asked() {
        let (mut e, mut r) = (
            Evaluation::new(1, 0),
            Roster::new(1, 1, std::time::Duration::ZERO),
        );
        let first = e.ask(2, &r, 0);
        assert_eq!(first.actor_id, 2, "no stream open: the fragment's actor");
        let second = stream(&mut e, &mut r, 5, true).expect("actor 5 asked");
        assert_eq!(second.actor_id, 5);
        // the asked actor reconnecting (same id) keeps its request
        let (mut e, mut r) = (
            Evaluation::new(1, 0),
            Roster::new(1, 1, std::time::Duration::ZERO),
        );
        let first = e.ask(2, &r, 0);
        assert_eq!(stream(&mut e, &mut r, 2, true), None);
        assert_eq!(e.open(), Some(first));
    }

    #[test]
    fn a_dead_actor_whose_fragment_reached_the_end_is_not_asked() {
        let (mut e, mut r) = (
            Evaluation::new(1, 0),
            Roster::new(1, 1, std::time::Duration::ZERO),
        );
        assert_eq!(stream(&mut e, &mut r, 1, true), None);
        assert_eq!(stream(&mut e, &mut r, 3, true), None);
        assert_eq!(stream(&mut e, &mut r, 3, false), None);
        assert_eq!(e.ask(3, &r, 0).actor_id, 1);
    }
}
