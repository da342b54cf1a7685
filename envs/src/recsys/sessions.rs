//! Purchase sessions, the unit every source produces and the service accepts, and the
//! contract's rules for a well-formed one.

use serde::{Deserialize, Serialize};

/// Most purchases one submitted session may hold.
pub const MAX_PURCHASES_PER_SESSION: usize = 10_000;
/// Longest `session_id` or `item_id`, in bytes.
pub const MAX_ID_BYTES: usize = 256;
/// Highest price of one purchase: a reward of one purchase stays within the learner's
/// default reward bound (`ppo.max_abs_reward`, 10^6), and sums of many stay finite.
pub const MAX_PRICE: f64 = 1e6;

/// Whether a price is one the service stores and the model counts: finite, in
/// `[0, MAX_PRICE]`.
pub fn valid_price(price: f64) -> bool {
    (0.0..=MAX_PRICE).contains(&price)
}

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

/// One session per user, in order of user id, each named `user-N`, for the sources whose
/// sessions are users: `purchases` turns one user's rows into their purchases, oldest first.
pub(super) fn per_user<R>(
    mut users: std::collections::HashMap<u64, Vec<R>>,
    mut purchases: impl FnMut(Vec<R>) -> Vec<Purchase>,
) -> Vec<Session> {
    let mut ids: Vec<u64> = users.keys().copied().collect();
    ids.sort_unstable();
    ids.into_iter()
        .map(|user| Session {
            session_id: format!("user-{user}"),
            purchases: purchases(users.remove(&user).unwrap_or_default()),
        })
        .collect()
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

/// The [`bytes_hash`] of an id: the held-out split is made of it. Anyone can compute it, so
/// it never decides whether a session is stored ([`IdKey`] does).
pub fn id_hash(id: &str) -> u64 {
    bytes_hash(id.as_bytes())
}

/// A session store's secret key for the hash of session ids in its index (SipHash-1-3): a
/// client who does not know it cannot make an id of its own collide with another client's
/// and have that session counted as a duplicate and dropped. Drawn at random when a store is
/// created (from the operating system's entropy), kept in the store (`id_key`).
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct IdKey(pub [u64; 2]);

impl std::fmt::Debug for IdKey {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("IdKey(..)")
    }
}

impl IdKey {
    /// A fresh random key.
    pub fn random() -> Self {
        Self([rand::random(), rand::random()])
    }

    /// The keyed hash of a session id.
    pub fn hash(&self, id: &str) -> u64 {
        use std::hash::Hasher;
        let mut h = siphasher::sip::SipHasher13::new_with_keys(self.0[0], self.0[1]);
        h.write(id.as_bytes());
        h.finish()
    }

    /// As the key file holds it: 32 hex digits and a newline.
    pub fn to_text(self) -> String {
        format!("{:016x}{:016x}\n", self.0[0], self.0[1])
    }

    /// From [`Self::to_text`]'s text.
    pub fn from_text(text: &str) -> Option<Self> {
        let t = text.trim_end();
        if t.len() != 32 || !t.is_ascii() {
            return None;
        }
        let k0 = u64::from_str_radix(&t[..16], 16).ok()?;
        let k1 = u64::from_str_radix(&t[16..], 16).ok()?;
        Some(Self([k0, k1]))
    }
}

/// Why a session is malformed (docs/src/recommender.md: empty id, no purchases, an empty item id, a
/// negative, NaN or infinite price), or over the documented limits (a price over
/// [`MAX_PRICE`] included).
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
        if !valid_price(p.price) {
            return Err(format!(
                "purchase {i}: price {} is not a number in [0, {MAX_PRICE}]",
                p.price
            ));
        }
    }
    Ok(())
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
        assert!(check_session(&session("s", &[("a", 1.0), ("b", 0.0), ("c", MAX_PRICE)])).is_ok());
        for (bad, reason) in [
            (session("", &[("a", 1.0)]), "session_id"),
            (session("s", &[]), "no purchases"),
            (session("s", &[("", 1.0)]), "item_id"),
            (session("s", &[("a", -1.0)]), "price"),
            (session("s", &[("a", f64::NAN)]), "price"),
            (session("s", &[("a", f64::INFINITY)]), "price"),
            (session("s", &[("a", 1.7e308)]), "price 170000000"),
            (session("s", &[("a", MAX_PRICE * 1.01)]), "price"),
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
