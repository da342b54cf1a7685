use super::*;

fn small() -> LargeCatalogueConfig {
    LargeCatalogueConfig {
        items: 5_000,
        sessions_per_item: 2.0,
        mean_len: 8.0,
        items_per_category: 250,
        zipf: 1.0,
        seed: 5,
    }
}

#[test]
fn sessions_are_seeded_and_independent_of_generation_order() {
    let a = LargeCatalogue::new(&small()).expect("builds");
    let b = LargeCatalogue::new(&small()).expect("builds");
    assert_eq!(a.session(17), b.session(17));
    let _ = b.session(3);
    assert_eq!(
        a.session(42),
        b.session(42),
        "no state carried between sessions"
    );
    let c = LargeCatalogue::new(&LargeCatalogueConfig { seed: 6, ..small() }).expect("builds");
    assert_ne!(
        (0..20).map(|s| a.session(s)).collect::<Vec<_>>(),
        (0..20).map(|s| c.session(s)).collect::<Vec<_>>()
    );
}

#[test]
fn the_sessions_have_the_asked_shape() {
    let catalogue = LargeCatalogue::new(&small()).expect("builds");
    let stats = catalogue.stats();
    assert_eq!(stats.items, 5_000);
    assert_eq!(stats.sessions, 10_000);
    assert_eq!(stats.categories, 20);
    assert!(
        (6.5..9.5).contains(&stats.events_per_session),
        "mean length {}",
        stats.events_per_session
    );
    assert!(stats.median_session_len < stats.p90_session_len);
    // Zipf popularity: the top 1% of items take far more than 1% of purchases
    assert!(stats.top_1pct_share > 0.15, "{stats:?}");
    // sessions stay mostly inside their categories (20 categories: 5% by chance)
    assert!(stats.same_category_share > 0.4, "{stats:?}");
    for s in 0..200 {
        let items = catalogue.session(s);
        assert!(!items.is_empty() && items.len() <= MAX_LEN);
        assert!(items.iter().all(|&i| (i as usize) < catalogue.items()));
    }
}

#[test]
fn the_records_are_well_formed_sessions() {
    let catalogue = LargeCatalogue::new(&small()).expect("builds");
    for s in 0..50 {
        let record = catalogue.session_record(s);
        crate::recsys::sessions::check_session(&record).expect("well formed");
        assert_eq!(record.purchases.len(), catalogue.session(s).len());
    }
}

#[test]
fn bad_settings_are_refused_with_the_reason() {
    for (config, reason) in [
        (
            LargeCatalogueConfig {
                items: 1,
                ..small()
            },
            "items",
        ),
        (
            LargeCatalogueConfig {
                mean_len: f64::NAN,
                ..small()
            },
            "mean_len",
        ),
        (
            LargeCatalogueConfig {
                items_per_category: 0,
                ..small()
            },
            "items_per_category",
        ),
        (
            LargeCatalogueConfig {
                sessions_per_item: 0.0,
                ..small()
            },
            "sessions_per_item",
        ),
        (
            LargeCatalogueConfig {
                items: 2,
                sessions_per_item: 0.1,
                ..small()
            },
            "gives no session",
        ),
        (
            LargeCatalogueConfig {
                mean_len: 400.0,
                ..small()
            },
            "mean_len",
        ),
    ] {
        let err = LargeCatalogue::new(&config).expect_err("refused");
        assert!(err.contains(reason), "{err}");
    }
}

#[test]
fn the_recommender_environment_runs_on_a_generated_catalogue() {
    use crate::{ActionRef, Env, EnvConfig};
    use jsae_env_spec::SessionSource;
    let mut config = EnvConfig::default();
    let r = &mut config.recommender;
    r.source = SessionSource::Catalogue;
    r.catalogue = small();
    r.top_n = 5_000;
    let mut env = crate::recsys::RecommenderEnv::new(&config).expect("builds");
    assert!(
        env.model().catalogue().len() > 4_000,
        "most items are bought"
    );
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    env.reset(&mut rng);
    let (mut steps, mut reward) = (0, 0.0);
    for t in 0..200u32 {
        let step = env.step(ActionRef::Discrete(t * 7 % 5_000));
        reward += step.reward;
        steps += 1;
        if step.terminated || step.truncated {
            env.reset(&mut rng);
        }
    }
    assert_eq!(steps, 200);
    assert!(reward.is_finite());
    // bad settings of the source are refused with the key
    config.recommender.catalogue.items_per_category = 0;
    let err = crate::recsys::RecommenderEnv::new(&config).expect_err("refused");
    assert!(
        err.to_string()
            .contains("recommender.catalogue.items_per_category"),
        "{err}"
    );
}
