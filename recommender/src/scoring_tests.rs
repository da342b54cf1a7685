//! The Recommender core's tests: the softmax of the filled slots; an embedding of another
//! catalogue refused with the reason, one of a catalogue that grew since accepted.

use super::*;

#[test]
fn most_likely_is_the_softmax_of_the_filled_slots() {
    let got = most_likely(&[0.0, (2.0f32).ln(), 10.0], 2, 2);
    assert_eq!(got[0].0, 1);
    assert_eq!(got[1].0, 0);
    assert!((got[0].1 / got[1].1 - 2.0).abs() < 1e-5);
}

#[test]
fn an_embedding_of_another_catalogue_is_refused_with_the_reason() {
    use jsae_agent::EmbeddingModel;
    use jsae_settings::{Algo, SessionSource};
    use rand::SeedableRng;

    let mut config = TrainConfig::defaults(EnvName::Recommender, jsae_settings::Algo::Jsae);
    let r = &mut config.environment.recommender;
    r.source = SessionSource::Synthetic;
    r.top_n = 60;
    r.synthetic.items = 40;
    r.synthetic.sessions = 300;
    let rec =
        Recommender::new(&config, PolicyChoice::Learned, DeviceKind::Flex).expect("a recommender");
    assert!(
        rec.model().is_none(),
        "a learned policy reads the catalogue alone"
    );
    let catalogue = rec.current().catalogue().clone();
    assert_eq!(catalogue.len(), 40);
    let (states, actions) = EnvName::Recommender.spaces(&config.environment);
    let model = EmbeddingModel::new(
        &config.embedding,
        Algo::Jsae.representation(),
        &states,
        &actions,
        &mut rand_chacha::ChaCha8Rng::seed_from_u64(1),
        &DeviceKind::Flex.device(),
    );
    let ours = CatalogueTag {
        items: 40,
        capacity: 60,
        prefix_hash: catalogue.prefix_hash(40).expect("40 held"),
    };
    let snapshot = |version, tag: Option<CatalogueTag>| {
        let mut bytes = model.to_bytes().expect("bytes");
        if let Some(tag) = tag {
            tag.append_to(&mut bytes);
        }
        EmbeddingSnapshot::from_bytes(version, bytes)
    };
    let refusals = [
        CatalogueTag {
            prefix_hash: ours.prefix_hash ^ 1,
            ..ours
        },
        CatalogueTag {
            capacity: 61,
            ..ours
        },
        CatalogueTag { items: 41, ..ours },
    ];
    for (version, tag) in (1..).zip(refusals) {
        let why = rec
            .set_embedding(snapshot(version, Some(tag)))
            .expect_err("another catalogue");
        assert!(
            why.contains(&format!("embedding version {version} refused")),
            "{why}"
        );
        assert_eq!(rec.refused_embedding(), Some(version));
        assert_eq!(rec.embedding_version(), 0);
    }
    let (input, head) = jsae_agent::policy_shape(&config, &states, &actions);
    let policy = jsae_agent::Policy::new(
        &config.ppo,
        input,
        head,
        &mut rand_chacha::ChaCha8Rng::seed_from_u64(2),
        &DeviceKind::Flex.device(),
    );
    let bytes = jsae_agent::PolicyPrior::new(&config.ppo)
        .encode(&policy)
        .expect("policy bytes");
    rec.set_policy(&PolicySnapshot { version: 1, bytes })
        .expect("a policy");
    let history = vec![catalogue.id(0).expect("slot 0").to_owned()];
    let unavailable = rec.recommend(&history, 5).expect_err("no embedding");
    assert!(
        matches!(&unavailable, RpcError::Unavailable(m) if m.contains("refused")),
        "{unavailable:?}"
    );
    // a catalogue that grew since the snapshot's still matches it; so do untagged bytes
    let shorter = CatalogueTag {
        items: 30,
        prefix_hash: catalogue.prefix_hash(30).expect("30 held"),
        ..ours
    };
    rec.set_embedding(snapshot(4, Some(shorter)))
        .expect("the first 30 items agree");
    assert_eq!(
        (rec.embedding_version(), rec.refused_embedding()),
        (4, None)
    );
    rec.set_embedding(snapshot(5, None)).expect("untagged");
    assert_eq!(rec.embedding_version(), 5);
    let answer = rec.recommend(&history, 5).expect("answers");
    assert_eq!((answer.items.len(), answer.embedding_version), (5, 5));
}
