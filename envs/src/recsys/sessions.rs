//! Purchase sessions, the unit every source produces and the service accepts, and the
//! contract's rules for a well-formed one.

use jsae_proto::wire::pb;
use serde::{Deserialize, Serialize};

/// Most purchases one submitted session may hold.
pub const MAX_PURCHASES_PER_SESSION: usize = 10_000;
/// Longest `session_id` or `item_id`, in bytes.
pub const MAX_ID_BYTES: usize = 256;

/// One purchase.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Purchase {
    /// The shop's item id.
    pub item_id: String,
    /// The price paid (0 where the source has no prices; 0 when a JSON line leaves it out).
    #[serde(default)]
    pub price: f64,
    /// When, in milliseconds since the Unix epoch (or a relative time where the source has
    /// no dates); purchases of a session are in this order. 0 when a JSON line leaves it out.
    #[serde(default)]
    pub time_unix_ms: i64,
}

/// The purchases of one session (or one user), oldest first.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Session {
    /// The session's id.
    pub session_id: String,
    /// Its purchases, oldest first.
    pub purchases: Vec<Purchase>,
}

/// A stable 64-bit hash of bytes: FNV-1a, mixed by SplitMix64's finaliser (FNV alone leaves
/// the high bits of ids that differ in their last characters, `user-1`, `user-2`, ...,
/// nearly equal). The same bytes give the same hash on every machine and in every version,
/// so it may be written to disk.
pub fn bytes_hash(bytes: &[u8]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for &b in bytes {
        h ^= u64::from(b);
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    h = (h ^ (h >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    h = (h ^ (h >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    h ^ (h >> 31)
}

/// The [`bytes_hash`] of an id: the session store's index of stored sessions and the
/// held-out split are made of it.
pub fn id_hash(id: &str) -> u64 {
    bytes_hash(id.as_bytes())
}

/// Why a session is malformed (CONTRACT.md: empty id, no purchases, an empty item id, a
/// negative, NaN or infinite price), or over the documented limits.
pub fn check_session(session: &Session) -> Result<(), String> {
    if session.session_id.is_empty() {
        return Err("session_id is empty".into());
    }
    if session.session_id.len() > MAX_ID_BYTES {
        return Err(format!("session_id is longer than {MAX_ID_BYTES} bytes"));
    }
    if session.purchases.is_empty() {
        return Err("no purchases".into());
    }
    if session.purchases.len() > MAX_PURCHASES_PER_SESSION {
        return Err(format!(
            "{} purchases, more than {MAX_PURCHASES_PER_SESSION}",
            session.purchases.len()
        ));
    }
    for (i, p) in session.purchases.iter().enumerate() {
        if p.item_id.is_empty() {
            return Err(format!("purchase {i}: item_id is empty"));
        }
        if p.item_id.len() > MAX_ID_BYTES {
            return Err(format!(
                "purchase {i}: item_id is longer than {MAX_ID_BYTES} bytes"
            ));
        }
        if !(p.price.is_finite() && p.price >= 0.0) {
            return Err(format!(
                "purchase {i}: price {} is not a finite number >= 0",
                p.price
            ));
        }
    }
    Ok(())
}

impl From<pb::Session> for Session {
    fn from(s: pb::Session) -> Self {
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
}

impl From<Session> for pb::Session {
    fn from(s: Session) -> Self {
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
}

#[cfg(test)]
mod tests {
    use super::*;

    fn session(id: &str, items: &[(&str, f64)]) -> Session {
        Session {
            session_id: id.into(),
            purchases: items
                .iter()
                .map(|&(item, price)| Purchase {
                    item_id: item.into(),
                    price,
                    time_unix_ms: 0,
                })
                .collect(),
        }
    }

    #[test]
    fn the_contracts_malformed_sessions_are_refused_with_a_reason() {
        assert!(check_session(&session("s", &[("a", 1.0), ("b", 0.0)])).is_ok());
        for (bad, reason) in [
            (session("", &[("a", 1.0)]), "session_id"),
            (session("s", &[]), "no purchases"),
            (session("s", &[("", 1.0)]), "item_id"),
            (session("s", &[("a", -1.0)]), "price"),
            (session("s", &[("a", f64::NAN)]), "price"),
            (session("s", &[("a", f64::INFINITY)]), "price"),
            (
                session("s", &[("a", 1.0); MAX_PURCHASES_PER_SESSION + 1]),
                "purchases, more than",
            ),
        ] {
            let err = check_session(&bad).expect_err("malformed");
            assert!(err.contains(reason), "{err}");
        }
    }
}
