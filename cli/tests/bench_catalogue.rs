//! `jsae bench --catalogue --json` end to end at a small size: every key the contract names,
//! measured (the Recommender is the real process, started by the bench).

use std::process::Command;

#[test]
fn the_catalogue_bench_prints_every_key_of_a_row() {
    let out = Command::new(env!("CARGO_BIN_EXE_jsae"))
        .args([
            "bench",
            "--quick",
            "--catalogue",
            "--items",
            "3000",
            "--json",
        ])
        .output()
        .expect("jsae runs");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let row: serde_json::Value = serde_json::from_str(stdout.lines().last().expect("a row"))
        .unwrap_or_else(|e| panic!("{e}: {stdout}"));
    assert_eq!(row["items"], 3000, "{row}");
    for key in [
        "embedder_step_ms",
        "ann_build_s",
        "recall_at_10",
        "recommend_p50_ms",
        "recommend_p99_ms",
        "offered_rps",
        "rss_mib",
        "train_env_steps_per_s",
    ] {
        let v = row[key].as_f64().unwrap_or_else(|| panic!("{key}: {row}"));
        assert!(v.is_finite() && v > 0.0, "{key}: {row}");
    }
    assert_eq!(row["refused_other_catalogue"], true, "{row}");
}
