//! Property tests of the Recommender's session decoder and validator: any bytes decode to an
//! answer (never a panic), and a session passes `check_session` exactly when its id and every
//! item id are 1 to 256 bytes long, it has 1 to 10,000 purchases, and every price is a number
//! in [0, MAX_PRICE] (the contract's definition of a malformed session, and its bound).

use jsae_envs::recsys::sessions::{MAX_ID_BYTES, MAX_PRICE, check_session};
use jsae_recommender::session_from_wire;
use jsae_wire::pb;
use proptest::prelude::*;
use prost::Message;

fn price() -> impl Strategy<Value = f64> {
    prop_oneof![
        0.0..1e6,
        Just(MAX_PRICE),
        Just(MAX_PRICE * (1.0 + 1e-12)),
        Just(1.7e308),
        Just(-0.01),
        Just(f64::NAN),
        Just(f64::INFINITY),
        any::<f64>(),
    ]
}

fn id() -> impl Strategy<Value = String> {
    prop_oneof![
        Just(String::new()),
        "[a-z0-9-]{1,12}",
        Just("x".repeat(MAX_ID_BYTES)),
        Just("y".repeat(MAX_ID_BYTES + 1)),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2_000))]

    #[test]
    fn arbitrary_bytes_never_panic_the_session_decoder(bytes in prop::collection::vec(any::<u8>(), 0..400)) {
        if let Ok(m) = pb::Session::decode(bytes.as_slice()) {
            let _ = check_session(&session_from_wire(m));
        }
    }

    #[test]
    fn check_session_accepts_exactly_the_well_formed_sessions(
        session_id in id(),
        purchases in prop::collection::vec((id(), price()), 0..6),
    ) {
        let wire = pb::Session {
            session_id: session_id.clone(),
            purchases: purchases
                .iter()
                .map(|(item, price)| pb::Purchase { item_id: item.clone(), price: *price, time_unix_ms: 0 })
                .collect(),
        };
        let good_id = |s: &str| !s.is_empty() && s.len() <= MAX_ID_BYTES;
        let well_formed = good_id(&session_id)
            && !purchases.is_empty()
            && purchases.iter().all(|(item, p)| good_id(item) && p.is_finite() && (0.0..=MAX_PRICE).contains(p));
        prop_assert_eq!(check_session(&session_from_wire(wire)).is_ok(), well_formed);
    }
}
