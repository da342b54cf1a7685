//! MovieLens-100K as shipped in the PyPI package `recbole==1.2.1`
//! (`recbole/dataset_example/ml-100k/ml-100k.inter`: tab-separated `user_id:token`,
//! `item_id:token`, `rating:float`, `timestamp:float`, one row per rating).
//! `scripts/setup-data.sh` fetches it into `third_party/movielens/`; it is never committed.
//! A user's ratings in time order (ties: by item id) form one session, each rating counted
//! as a purchase without a price, so the held-out split (by session id) is by user.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use super::RecsysError;
use super::sessions::{Purchase, Session, per_user};

/// Where `scripts/setup-data.sh` puts the file, in this checkout (or
/// `$JSAE_DATA_DIR/movielens/` where that is set, as in the container image).
pub fn default_path() -> PathBuf {
    match std::env::var_os("JSAE_DATA_DIR") {
        Some(dir) => Path::new(&dir).join("movielens/ml-100k.inter"),
        None => {
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../third_party/movielens/ml-100k.inter")
        }
    }
}

/// Reads the ratings file: one session per user, sessions in order of user id.
pub fn read(path: &Path) -> Result<Vec<Session>, RecsysError> {
    let text = std::fs::read_to_string(path).map_err(|source| RecsysError::Io {
        path: path.into(),
        source,
    })?;
    parse(&text, path)
}

/// As [`read`], from the file's text (`path` names it in errors).
pub fn parse(text: &str, path: &Path) -> Result<Vec<Session>, RecsysError> {
    let bad = |line: usize, reason: String| RecsysError::Parse {
        path: path.into(),
        line: line as u64,
        reason,
    };
    let mut lines = text.lines().enumerate();
    let header = lines
        .next()
        .map(|(_, h)| h)
        .ok_or_else(|| bad(1, "empty file".into()))?;
    let names: Vec<&str> = header.split('\t').map(|h| h.trim()).collect();
    let column = |name: &str| {
        names
            .iter()
            .position(|h| h.split(':').next() == Some(name))
            .ok_or_else(|| {
                bad(
                    1,
                    format!("no column {name:?} (RecBole .inter format: user_id:token, item_id:token, timestamp:float)"),
                )
            })
    };
    let (user_col, item_col, time_col) =
        (column("user_id")?, column("item_id")?, column("timestamp")?);
    let mut users: HashMap<u64, Vec<(i64, u64, String)>> = HashMap::new();
    for (i, line) in lines {
        if line.trim().is_empty() {
            continue;
        }
        let fields: Vec<&str> = line.split('\t').map(str::trim).collect();
        let get = |c: usize| fields.get(c).copied().unwrap_or("");
        let user: u64 = get(user_col).parse().map_err(|_| {
            bad(
                i + 1,
                format!("user_id: not an integer: {:?}", get(user_col)),
            )
        })?;
        let item = get(item_col);
        if item.is_empty() {
            return Err(bad(i + 1, "empty item_id".into()));
        }
        let time: f64 = get(time_col)
            .parse()
            .ok()
            .filter(|t: &f64| t.is_finite() && *t >= 0.0)
            .ok_or_else(|| bad(i + 1, format!("timestamp: not a time: {:?}", get(time_col))))?;
        let order = item.parse::<u64>().unwrap_or(u64::MAX);
        users
            .entry(user)
            .or_default()
            .push(((time * 1000.0) as i64, order, item.to_owned()));
    }
    if users.is_empty() {
        return Err(bad(1, "no ratings".into()));
    }
    Ok(per_user(users, |mut rows| {
        rows.sort();
        rows.into_iter()
            .map(|(time_unix_ms, _, item_id)| Purchase {
                item_id,
                price: 0.0,
                time_unix_ms,
            })
            .collect()
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_users_ratings_in_time_order_are_one_session() {
        let text = "user_id:token\titem_id:token\trating:float\ttimestamp:float\n\
                    7\t50\t5\t300\n2\t9\t3\t100\n7\t10\t4\t200\n7\t3\t1\t300\n";
        let s = parse(text, Path::new("x.inter")).expect("parses");
        assert_eq!(s.len(), 2);
        assert_eq!(s[0].session_id, "user-2");
        let items: Vec<&str> = s[1].purchases.iter().map(|p| p.item_id.as_str()).collect();
        // time first, then the item id as a number (3 before 50 at the same second)
        assert_eq!(items, ["10", "3", "50"]);
        assert_eq!(s[1].purchases[0].time_unix_ms, 200_000);
    }

    #[test]
    fn a_file_of_another_format_is_refused_with_the_line() {
        let e = parse("a,b,c\n1,2,3\n", Path::new("x")).expect_err("not .inter");
        assert!(e.to_string().contains("no column \"user_id\""), "{e}");
        let e = parse(
            "user_id:token\titem_id:token\ttimestamp:float\nu\t1\t2\n",
            Path::new("x"),
        )
        .expect_err("bad user");
        assert!(e.to_string().contains("line 2"), "{e}");
        let e = parse(
            "user_id:token\titem_id:token\ttimestamp:float\n",
            Path::new("x"),
        )
        .expect_err("empty");
        assert!(e.to_string().contains("no ratings"), "{e}");
    }
}
