//! The REES46 loader on generated files in the exact format of the public data set: its
//! header, empty `category_code` and `brand`, times with the " UTC" suffix, duplicated rows,
//! views and carts mixed in, and the same rows gzip-compressed (also as several gzip
//! members, as concatenated monthly files are).

use std::io::Write;
use std::path::{Path, PathBuf};

use jsae_env_spec::{GroupBy, RecommenderConfig, SessionSource};
use jsae_envs::recsys::rees46::{self, ReadStats};
use jsae_envs::recsys::{NgramModel, Purchase, Session};

const HEADER: &str =
    "event_time,event_type,product_id,category_id,category_code,brand,price,user_id,user_session";

/// Rows as they appear in the data set (copied in form, not content: ids are made up).
const ROWS: &str = "\
2019-10-01 00:00:00 UTC,view,44600062,2103807459595387724,,shiseido,35.79,541312140,72d76fde-8bb3-4e00-8c23-a032dfed738c
2019-10-01 00:00:04 UTC,purchase,3900821,2053013552326770905,appliances.environment.water_heater,aqua,33.20,554748717,9333dfbd-b87a-4708-9857-6336556b0fcc
2019-10-01 00:00:05 UTC,cart,1307067,2053013558920217191,computers.notebook,lenovo,251.74,550050854,7c90fc70-0e80-4590-96f3-13c02c18c713
2019-10-01 00:01:10 UTC,purchase,1004856,2053013555631882655,,,130.76,554748717,9333dfbd-b87a-4708-9857-6336556b0fcc
2019-10-01 00:01:10 UTC,purchase,1004856,2053013555631882655,,,130.76,554748717,9333dfbd-b87a-4708-9857-6336556b0fcc
2019-10-01 00:00:50 UTC,purchase,5100816,2053013553375346967,,xiaomi,29.51,554748717,9333dfbd-b87a-4708-9857-6336556b0fcc
2019-10-01 00:02:14 UTC,purchase,1004856,2053013555631882655,electronics.smartphone,samsung,130.76,513351129,e6b7ce9b-1938-4e20-976c-8b4163aea11d
2019-10-02 10:15:00 UTC,purchase,3900821,2053013552326770905,,aqua,33.20,554748717,0a1b2c3d-0000-4000-8000-000000000001
2019-10-02 10:16:00 UTC,purchase,,2053013552326770905,,aqua,33.20,554748717,0a1b2c3d-0000-4000-8000-000000000001
2019-10-02 10:17:00 UTC,purchase,4804056,2053013554658804075,electronics.audio.headphone,apple,-1,554748717,0a1b2c3d-0000-4000-8000-000000000001
2019-10-02 10:18:00 UTC,remove_from_cart,4804056,2053013554658804075,electronics.audio.headphone,apple,160.57,554748717,0a1b2c3d-0000-4000-8000-000000000001
";

fn dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("jsae-rees46-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&d).expect("temp dir");
    d
}

fn write_csv(path: &Path, text: &str) {
    std::fs::write(path, text).expect("write csv");
}

fn write_gz(path: &Path, parts: &[&str]) {
    let mut file = std::fs::File::create(path).expect("create gz");
    for part in parts {
        let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
        gz.write_all(part.as_bytes()).expect("compress");
        file.write_all(&gz.finish().expect("finish"))
            .expect("write gz");
    }
}

fn purchase(item: &str, price: f64, time: &str) -> Purchase {
    Purchase {
        item_id: item.into(),
        price,
        time_unix_ms: rees46::parse_time(time).expect("time"),
    }
}

fn expected_by_session() -> Vec<Session> {
    vec![
        Session {
            session_id: "9333dfbd-b87a-4708-9857-6336556b0fcc".into(),
            // sorted by time: the 00:00:50 row comes before the 00:01:10 one; the duplicate
            // 00:01:10 row is dropped
            purchases: vec![
                purchase("3900821", 33.20, "2019-10-01 00:00:04"),
                purchase("5100816", 29.51, "2019-10-01 00:00:50"),
                purchase("1004856", 130.76, "2019-10-01 00:01:10"),
            ],
        },
        Session {
            session_id: "e6b7ce9b-1938-4e20-976c-8b4163aea11d".into(),
            purchases: vec![purchase("1004856", 130.76, "2019-10-01 00:02:14")],
        },
        Session {
            session_id: "0a1b2c3d-0000-4000-8000-000000000001".into(),
            purchases: vec![purchase("3900821", 33.20, "2019-10-02 10:15:00")],
        },
    ]
}

const STATS: ReadStats = ReadStats {
    rows: 11,
    purchases: 5,
    duplicates: 1,
    malformed: 2,
};

#[test]
fn plain_and_gzip_files_give_the_same_sessions_with_quirks_handled() {
    let d = dir("formats");
    let text = format!("{HEADER}\n{ROWS}");
    let plain = d.join("2019-Oct.csv");
    write_csv(&plain, &text);
    let gz = d.join("2019-Oct.csv.gz");
    write_gz(&gz, &[&text]);
    // a file split across gzip members (the header in the first)
    let multi = d.join("2019-Oct-multi.csv.gz");
    let (a, b) = text.split_at(text.len() / 2);
    write_gz(&multi, &[a, b]);

    for path in [&plain, &gz, &multi] {
        let (sessions, stats) = rees46::read(path, GroupBy::Session).expect("reads");
        assert_eq!(sessions, expected_by_session(), "{}", path.display());
        assert_eq!(stats, STATS, "{}", path.display());
    }

    // by user: the two sessions of user 554748717 form one sequence, in time order
    let (by_user, _) = rees46::read(&gz, GroupBy::User).expect("reads");
    assert_eq!(by_user.len(), 2);
    assert_eq!(by_user[0].session_id, "554748717");
    let items: Vec<&str> = by_user[0]
        .purchases
        .iter()
        .map(|p| p.item_id.as_str())
        .collect();
    assert_eq!(items, ["3900821", "5100816", "1004856", "3900821"]);
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn a_file_in_another_format_is_refused_with_the_missing_column() {
    let d = dir("other");
    let path = d.join("orders.csv");
    write_csv(&path, "order_id,product_id,price\n1,2,3.0\n");
    let err = rees46::read(&path, GroupBy::Session).expect_err("refused");
    let text = err.to_string();
    assert!(
        text.contains("event_time") && text.contains("line 1"),
        "{text}"
    );
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn a_large_compressed_file_streams_into_the_ngram_model_with_prices_as_rewards() {
    // 200k rows (about 3% purchases, as in the real data), in a .csv.gz
    let d = dir("large");
    let path = d.join("2019-Nov.csv.gz");
    let mut text = String::with_capacity(200_000 * 120);
    text.push_str(HEADER);
    text.push('\n');
    let mut purchases = 0;
    for i in 0..200_000u64 {
        let kind = if i % 33 == 0 { "purchase" } else { "view" };
        purchases += u64::from(kind == "purchase");
        let item = 1_000_000 + (i * 7919) % 50;
        let price = 10.0 + (item % 50) as f64;
        let session = i / 330;
        let brand = if i % 2 == 0 { "" } else { "samsung" };
        text.push_str(&format!(
            "2019-11-{:02} {:02}:{:02}:{:02} UTC,{kind},{item},2053013555631882655,,{brand},{price:.2},{},s-{session}\n",
            1 + (i / 86_400) % 28,
            (i / 3600) % 24,
            (i / 60) % 60,
            i % 60,
            500_000_000 + session,
        ));
    }
    write_gz(&path, &[&text]);
    let (sessions, stats) = rees46::read(&path, GroupBy::Session).expect("reads");
    assert_eq!(stats.rows, 200_000);
    assert_eq!(stats.purchases, purchases);
    assert_eq!(
        sessions
            .iter()
            .map(|s| s.purchases.len() as u64)
            .sum::<u64>(),
        purchases
    );

    let config = RecommenderConfig {
        source: SessionSource::Rees46,
        path: path.clone(),
        top_n: 20,
        ..RecommenderConfig::default()
    };
    let loaded = jsae_envs::recsys::data::load_sessions(&config).expect("loads");
    assert_eq!(loaded, sessions);
    let catalogue = jsae_envs::recsys::Catalogue::most_purchased(loaded.iter(), 20);
    assert_eq!(catalogue.len(), 20);
    let model = NgramModel::build(catalogue, loaded.iter(), &config).expect("builds");
    for slot in 0..20u32 {
        let id: u64 = model
            .catalogue()
            .id(slot)
            .expect("filled")
            .parse()
            .expect("numeric id");
        let price = 10.0 + (id % 50) as f64;
        assert!(
            (model.value(slot) - price).abs() < 1e-9,
            "item {id}: value {} != price {price}",
            model.value(slot)
        );
    }
    let _ = std::fs::remove_dir_all(&d);
}
