//! Purchase sessions to and from their gRPC form (`SubmitSessions`, `jsae recommend
//! --submit`); the rules of a well-formed session are `jsae_envs::recsys::sessions`'.

use jsae_envs::recsys::sessions::{Purchase, Session};
use jsae_wire::pb;

/// A session as received, unchecked (see `check_session`).
pub fn session_from_wire(s: pb::Session) -> Session {
    Session {
        session_id: s.session_id,
        purchases: s
            .purchases
            .into_iter()
            .map(|p| Purchase {
                item_id: p.item_id,
                price: p.price,
                time_unix_ms: p.time_unix_ms,
            })
            .collect(),
    }
}

/// A session as sent.
pub fn session_to_wire(s: Session) -> pb::Session {
    pb::Session {
        session_id: s.session_id,
        purchases: s
            .purchases
            .into_iter()
            .map(|p| pb::Purchase {
                item_id: p.item_id,
                price: p.price,
                time_unix_ms: p.time_unix_ms,
            })
            .collect(),
    }
}
