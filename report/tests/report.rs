//! `jsae report` on a small results folder written by hand, whose numbers are known.

use std::path::{Path, PathBuf};

use jsae_report::report;

fn folder(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("jsae-report-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

/// A finished run: `summary.json` and a `metrics.csv` whose success rate is `curve`
/// (every 1,000 env steps) and whose return is ten times it.
fn write_run(dir: &Path, setting: &str, algo: &str, seed: u64, eval: (f64, f64), curve: &[f64]) {
    let run = dir
        .join("runs")
        .join(setting)
        .join(format!("gridworld-discrete-{algo}-seed{seed}"));
    std::fs::create_dir_all(&run).expect("mkdir");
    let summary = serde_json::json!({
        "env": "gridworld-discrete", "algo": algo, "seed": seed, "env_steps": 1000 * curve.len(),
        "wall_seconds": 10.0 * seed as f64, "eval_return_mean": eval.0,
        "eval_success_rate": eval.1, "eval_stochastic_return_mean": eval.0 - 1.0,
        "eval_stochastic_success_rate": 1.0,
    });
    std::fs::write(run.join("summary.json"), summary.to_string()).expect("summary");
    let mut csv = String::from("update,env_steps,return_mean,success_rate\n");
    for (i, s) in curve.iter().enumerate() {
        csv.push_str(&format!("{},{},{},{s}\n", i + 1, 1000 * (i + 1), 10.0 * s));
    }
    std::fs::write(run.join("metrics.csv"), csv).expect("metrics");
}

#[test]
fn report_of_known_runs() {
    let dir = folder("known");
    std::fs::create_dir_all(&dir).expect("mkdir");
    std::fs::write(
        dir.join("sweep.toml"),
        "envs = [\"gridworld-discrete\"]\nalgos = [\"jsae\", \"ppo\"]\nseeds = [1, 2, 3, 4]\n\
         env_steps = 4000\n[report]\nthreshold = 0.9\n[settings.a9]\n",
    )
    .expect("sweep file");
    // jsae: eval returns 1, 2, 3, 10 (mean 4, IQM of the middle two: 2.5); success 1, 1, 1, 0;
    // the curve reaches 0.9 at 2,000, 3,000 and 4,000 steps on seeds 1-3 (mean 3,000).
    let jsae = [
        (1.0, 1.0, [0.0, 0.9, 1.0, 1.0]),
        (2.0, 1.0, [0.0, 0.5, 0.95, 1.0]),
        (3.0, 1.0, [0.0, 0.0, 0.0, 0.9]),
        (10.0, 0.0, [0.0, 0.0, 0.0, 0.2]),
    ];
    for (seed, (ret, success, curve)) in (1..).zip(jsae) {
        write_run(&dir, "a9", "jsae", seed, (ret, success), &curve);
    }
    // ppo: the same return 0.5 and success 0 on every seed; seed 4's training curve ends at
    // 0.95 (a greedy policy below its sampled one), the others never reach the threshold.
    for seed in 1..=4 {
        let last = if seed == 4 { 0.95 } else { 0.4 };
        write_run(&dir, "a9", "ppo", seed, (0.5, 0.0), &[0.1, 0.2, 0.3, last]);
    }
    // A finished run the sweep file does not name (seed 9) and an unfinished run (no
    // summary.json) are left out.
    write_run(&dir, "a9", "jsae", 9, (100.0, 1.0), &[1.0]);
    std::fs::create_dir_all(dir.join("runs/a9/gridworld-discrete-ppo-seed5")).expect("mkdir");

    let made = report::report(&dir, &dir).expect("report");
    assert_eq!(made.rows.len(), 2);
    let (j, p) = (&made.rows[0], &made.rows[1]);
    assert_eq!((j.algo.as_str(), p.algo.as_str()), ("jsae", "ppo"));
    assert_eq!(j.seeds, 4);
    assert_eq!(j.eval_return.mean, 4.0);
    assert_eq!(j.eval_return_iqm, 2.5);
    assert!(
        j.eval_return.lo >= 1.0 && j.eval_return.lo < 4.0,
        "{:?}",
        j.eval_return
    );
    assert!(
        j.eval_return.hi > 4.0 && j.eval_return.hi <= 10.0,
        "{:?}",
        j.eval_return
    );
    assert_eq!(j.eval_success.map(|s| s.mean), Some(0.75));
    assert_eq!(j.eval_solved, Some(3));
    assert_eq!(j.reached, Some((3, Some(3000.0))));
    assert_eq!(j.stochastic_return.map(|s| s.mean), Some(3.0));
    assert_eq!(j.wall_seconds, 25.0);
    // A constant sample has a point interval.
    assert_eq!((p.eval_return.lo, p.eval_return.hi), (0.5, 0.5));
    assert_eq!(p.reached, Some((1, Some(4000.0))));
    assert_eq!(j.greedy_below_training, Some(0));
    assert_eq!(p.greedy_below_training, Some(1));
    assert!(
        made.markdown
            .contains("| a9 | gridworld-discrete | jsae | 4 | 4.00 [")
    );
    assert!(made.markdown.contains("3/4 (3.0k) | 0/4"));
    assert!(made.markdown.contains("1/4 (4.0k) | 1/4"));
    assert!(std::fs::metadata(dir.join("report.json")).is_ok_and(|m| m.len() > 500));
    if let Err(reason) = jsae_report::figures::font() {
        // A machine without a TrueType font gets the tables and the reason.
        assert!(made.markdown.contains("No figures"), "{reason}");
        let _ = std::fs::remove_dir_all(&dir);
        return;
    }
    for f in [
        "report.md",
        "figures/a9-gridworld-discrete-return_mean.svg",
        "figures/a9-gridworld-discrete-return_mean.png",
        "figures/a9-gridworld-discrete-success_rate.png",
    ] {
        let len = std::fs::metadata(dir.join(f)).map(|m| m.len()).unwrap_or(0);
        assert!(len > 500, "{f}: {len} bytes");
    }
    let png =
        std::fs::read(dir.join("figures/a9-gridworld-discrete-success_rate.png")).expect("png");
    assert_eq!(&png[1..4], b"PNG");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn an_empty_folder_is_an_error() {
    let dir = folder("empty");
    std::fs::create_dir_all(dir.join("runs/x")).expect("mkdir");
    let err = report::report(&dir, &dir).expect_err("nothing to report");
    assert!(err.to_string().contains("no finished run"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn min_max_band_interpolates_over_the_range_every_run_covers() {
    let a = [(0.0, 0.0), (100.0, 10.0), (200.0, 20.0)];
    let b = [(50.0, 5.0), (150.0, 5.0)];
    let band = report::min_max_band(&[&a, &b], 3);
    let xs: Vec<f64> = band.iter().map(|p| p.x).collect();
    assert_eq!(xs, vec![50.0, 100.0, 150.0]);
    // At 100: a is 10, b is 5.
    assert_eq!((band[1].mean, band[1].lo, band[1].hi), (7.5, 5.0, 10.0));
    assert_eq!((band[2].lo, band[2].hi), (5.0, 15.0));
    assert!(report::min_max_band(&[&a, &[(300.0, 1.0)]], 3).is_empty());
    assert!(report::min_max_band(&[&a, &[]], 3).is_empty());
    assert!(report::min_max_band(&[], 3).is_empty());
    assert_eq!(report::min_max_band(&[&a], 5).len(), 5);
}
