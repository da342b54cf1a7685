//! A streaming reader for the REES46 "eCommerce behavior data from multi category store"
//! CSV format (`event_time,event_type,product_id,category_id,category_code,brand,price,
//! user_id,user_session`), plain or gzip-compressed. The files run to gigabytes: rows are
//! read one at a time and only purchases are kept.

use std::collections::{HashMap, HashSet};
use std::io::Read;
use std::path::Path;

use jsae_env_spec::GroupBy;

use super::RecsysError;
use super::sessions::{Purchase, Session};

/// What a read kept and skipped.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct ReadStats {
    /// Rows read (all event types).
    pub rows: u64,
    /// Purchase rows kept.
    pub purchases: u64,
    /// Purchase rows identical to an earlier one of the same session (time, item, price).
    pub duplicates: u64,
    /// Purchase rows skipped: no session or user, no product, or a bad time or price.
    pub malformed: u64,
}

/// Opens `path`, decompressing it when its name ends in `.gz`.
pub fn open(path: &Path) -> Result<Box<dyn Read>, RecsysError> {
    let file = std::fs::File::open(path).map_err(|source| RecsysError::Io {
        path: path.into(),
        source,
    })?;
    let reader = std::io::BufReader::with_capacity(1 << 20, file);
    Ok(if path.extension().is_some_and(|e| e == "gz") {
        Box::new(flate2::read::MultiGzDecoder::new(reader))
    } else {
        Box::new(reader)
    })
}

/// Reads the purchases of a REES46 file into sessions (grouped by `user_session` or
/// `user_id`), each in time order, sessions in the order they first appear.
pub fn read(path: &Path, group_by: GroupBy) -> Result<(Vec<Session>, ReadStats), RecsysError> {
    read_from(open(path)?, group_by, path)
}

/// As [`read`], from any reader (`path` names it in errors).
pub fn read_from(
    input: impl Read,
    group_by: GroupBy,
    path: &Path,
) -> Result<(Vec<Session>, ReadStats), RecsysError> {
    let mut csv = csv::ReaderBuilder::new()
        .has_headers(true)
        .flexible(true)
        .from_reader(input);
    let bad = |line: u64, reason: String| RecsysError::Parse {
        path: path.into(),
        line,
        reason,
    };
    let header = csv
        .byte_headers()
        .map_err(|e| bad(1, e.to_string()))?
        .clone();
    let column = |name: &str| {
        header
            .iter()
            .position(|h| h == name.as_bytes())
            .ok_or_else(|| {
                bad(
                    1,
                    format!("no column {name:?} in the header (REES46 format)"),
                )
            })
    };
    let time_col = column("event_time")?;
    let type_col = column("event_type")?;
    let product_col = column("product_id")?;
    let price_col = column("price")?;
    let key_col = column(match group_by {
        GroupBy::Session => "user_session",
        GroupBy::User => "user_id",
    })?;
    let mut stats = ReadStats::default();
    let mut index: HashMap<Vec<u8>, usize> = HashMap::new();
    let mut sessions: Vec<Session> = Vec::new();
    let mut seen: HashSet<(usize, i64, Vec<u8>, u64)> = HashSet::new();
    let mut row = csv::ByteRecord::new();
    loop {
        match csv.read_byte_record(&mut row) {
            Ok(true) => {}
            Ok(false) => break,
            Err(e) => {
                let line = e.position().map_or(0, |p| p.line());
                return Err(bad(line, e.to_string()));
            }
        }
        stats.rows += 1;
        if row.get(type_col) != Some(b"purchase") {
            continue;
        }
        let field = |c: usize| std::str::from_utf8(row.get(c).unwrap_or_default()).ok();
        let parsed = (|| {
            let key = row.get(key_col).filter(|k| !k.is_empty())?;
            let item = field(product_col).filter(|p| !p.is_empty())?;
            let time = parse_time(field(time_col)?)?;
            let price: f64 = field(price_col)?.trim().parse().ok()?;
            (price.is_finite() && price >= 0.0).then_some((key, item, time, price))
        })();
        let Some((key, item, time, price)) = parsed else {
            stats.malformed += 1;
            continue;
        };
        let next = sessions.len();
        let s = *index.entry(key.to_vec()).or_insert(next);
        if s == next {
            sessions.push(Session {
                session_id: String::from_utf8_lossy(key).into_owned(),
                purchases: Vec::new(),
            });
        }
        if !seen.insert((s, time, item.as_bytes().to_vec(), price.to_bits())) {
            stats.duplicates += 1;
            continue;
        }
        stats.purchases += 1;
        sessions[s].purchases.push(Purchase {
            item_id: item.to_owned(),
            price,
            time_unix_ms: time,
        });
    }
    for s in &mut sessions {
        // stable: purchases at the same second keep the file's order
        s.purchases.sort_by_key(|p| p.time_unix_ms);
    }
    Ok((sessions, stats))
}

/// `2019-10-01 00:00:04 UTC` (the suffix optional) as milliseconds since the Unix epoch.
pub fn parse_time(text: &str) -> Option<i64> {
    let text = text.trim();
    let text = text.strip_suffix("UTC").map_or(text, str::trim_end);
    let (date, time) = text.split_once([' ', 'T'])?;
    let mut d = date.splitn(3, '-').map(|v| v.parse::<i64>().ok());
    let (y, m, day) = (d.next()??, d.next()??, d.next()??);
    let mut t = time.splitn(3, ':').map(|v| v.parse::<f64>().ok());
    let (hh, mm, ss) = (t.next()??, t.next()??, t.next().flatten().unwrap_or(0.0));
    if !(1..=12).contains(&m) || !(1..=31).contains(&day) || !(0.0..24.0).contains(&hh) {
        return None;
    }
    let days = days_from_civil(y, m, day);
    Some(days * 86_400_000 + ((hh * 3600.0 + mm * 60.0 + ss) * 1000.0) as i64)
}

/// Days since 1970-01-01 of a proleptic Gregorian date (Howard Hinnant's algorithm).
fn days_from_civil(y: i64, m: i64, d: i64) -> i64 {
    let y = if m <= 2 { y - 1 } else { y };
    let era = y.div_euclid(400);
    let yoe = y - era * 400;
    let mp = (m + 9) % 12;
    let doy = (153 * mp + 2) / 5 + d - 1;
    let doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
    era * 146_097 + doe - 719_468
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn times_parse_with_and_without_the_utc_suffix() {
        assert_eq!(parse_time("1970-01-01 00:00:00 UTC"), Some(0));
        assert_eq!(
            parse_time("2019-10-01 00:00:04 UTC"),
            Some(1_569_888_004_000)
        );
        assert_eq!(parse_time("2019-10-01 00:00:04"), Some(1_569_888_004_000));
        assert_eq!(
            parse_time("2020-02-29 12:00:00 UTC"),
            Some(1_582_977_600_000)
        );
        assert_eq!(parse_time("yesterday"), None);
    }
}
