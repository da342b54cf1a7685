//! A fixed prior over a categorical policy's actions, counted from logged purchases
//! (`ppo.recommender.logged_prior`): the policy's logits are its network's outputs plus the log of an
//! interpolated n-gram estimate of the item bought next, keyed by the input's one-hot
//! columns. Pair counts are smoothed towards the last item's, the last item's towards all
//! purchases, and those towards uniform (`SMOOTHING` pseudo-purchases at each level), so a
//! pair seen once still leans on its last item and an unseen pair is its last item's
//! estimate. The network then learns only what the counts get wrong; the counts are not
//! trained and travel inside the policy's bytes, so actors, evaluation and the Recommender
//! act with the same prior the learner trained beside.

use std::collections::HashMap;

/// Pseudo-purchases spread by the coarser level's estimate at each level.
pub const SMOOTHING: f32 = 1.0;

/// The counts and the tables derived from them.
#[derive(Debug, Clone, PartialEq)]
pub struct CountPrior {
    /// Input width (the one-hot columns keys are made of).
    x_dim: usize,
    /// Actions.
    n: usize,
    /// Purchases of each item.
    all: Vec<f32>,
    /// Per last column: the items bought after it, with their counts.
    last: HashMap<u32, Vec<(u32, f32)>>,
    /// Per pair of columns (the item before the last, the last): the same.
    pairs: HashMap<(u32, u32), Vec<(u32, f32)>>,
    /// Per column, the log-estimate after it as the last column (`[x_dim * n]`); columns
    /// never seen last hold the estimate over all purchases.
    last_log: Vec<f32>,
    /// Per column, the estimate itself (not logged), to smooth a pair's counts towards.
    last_p: Vec<f32>,
}

/// Why bytes are not a prior.
#[derive(Debug, thiserror::Error)]
#[error("the policy's count prior: {0}")]
pub struct PriorError(String);

impl CountPrior {
    /// Counts `rows`: each the non-zero columns of a logged state's input, ascending (the
    /// last two are the item before the last and the last item), and the item bought next.
    ///
    /// # Panics
    /// When an item is not below `n` or a column not below `x_dim`.
    pub fn count<'a>(
        x_dim: usize,
        n: usize,
        rows: impl IntoIterator<Item = (&'a [u32], u32)>,
    ) -> Self {
        let mut all = vec![0.0; n];
        let mut last: HashMap<u32, HashMap<u32, f32>> = HashMap::new();
        let mut pairs: HashMap<(u32, u32), HashMap<u32, f32>> = HashMap::new();
        for (cols, item) in rows {
            assert!((item as usize) < n, "item {item} of {n}");
            assert!(
                cols.iter().all(|&c| (c as usize) < x_dim),
                "a column past {x_dim}"
            );
            all[item as usize] += 1.0;
            if let Some((b, a)) = key(cols) {
                *last.entry(b).or_default().entry(item).or_default() += 1.0;
                if let Some(a) = a {
                    *pairs.entry((a, b)).or_default().entry(item).or_default() += 1.0;
                }
            }
        }
        let sorted = |m: HashMap<u32, f32>| {
            let mut v: Vec<(u32, f32)> = m.into_iter().collect();
            v.sort_unstable_by_key(|e| e.0);
            v
        };
        Self::derive(
            x_dim,
            n,
            all,
            last.into_iter().map(|(k, m)| (k, sorted(m))).collect(),
            pairs.into_iter().map(|(k, m)| (k, sorted(m))).collect(),
        )
    }

    fn derive(
        x_dim: usize,
        n: usize,
        all: Vec<f32>,
        last: HashMap<u32, Vec<(u32, f32)>>,
        pairs: HashMap<(u32, u32), Vec<(u32, f32)>>,
    ) -> Self {
        let total: f32 = all.iter().sum();
        // every level: (counts + SMOOTHING * coarser estimate) / (total + SMOOTHING)
        let base: Vec<f32> = all
            .iter()
            .map(|&c| (c + SMOOTHING / n as f32) / (total + SMOOTHING))
            .collect();
        let mut last_p = Vec::with_capacity(x_dim * n);
        for _ in 0..x_dim {
            last_p.extend_from_slice(&base);
        }
        for (&b, items) in &last {
            let mass: f32 = items.iter().map(|e| e.1).sum();
            let row = &mut last_p[b as usize * n..(b as usize + 1) * n];
            for (p, &q) in row.iter_mut().zip(&base) {
                *p = SMOOTHING * q / (mass + SMOOTHING);
            }
            for &(k, c) in items {
                row[k as usize] += c / (mass + SMOOTHING);
            }
        }
        let last_log = last_p.iter().map(|p| p.ln()).collect();
        Self {
            x_dim,
            n,
            all,
            last,
            pairs,
            last_log,
            last_p,
        }
    }

    /// Actions.
    pub fn actions(&self) -> usize {
        self.n
    }

    /// Item pairs counted.
    pub fn contexts(&self) -> usize {
        self.pairs.len()
    }

    /// Adds the prior's log-estimate after the input whose non-zero columns are `cols`
    /// (ascending among those below the input width; columns past it, a crossed feature's,
    /// are passed over) to `logits` (`[n]`).
    pub fn add_to(&self, cols: &[u32], logits: &mut [f32]) {
        let n = self.n;
        let cols = &cols[..cols.partition_point(|&c| (c as usize) < self.x_dim)];
        let Some((b, a)) = key(cols) else {
            let total: f32 = self.all.iter().sum();
            for (l, &c) in logits.iter_mut().zip(&self.all) {
                *l += ((c + SMOOTHING / n as f32) / (total + SMOOTHING)).ln();
            }
            return;
        };
        let row = b as usize * n..(b as usize + 1) * n;
        let pair = a.and_then(|a| self.pairs.get(&(a, b)));
        let Some(items) = pair else {
            for (l, &p) in logits.iter_mut().zip(&self.last_log[row]) {
                *l += p;
            }
            return;
        };
        // items the pair never led to keep the last item's estimate times a shared factor
        let mass: f32 = items.iter().map(|e| e.1).sum();
        let shift = (SMOOTHING / (mass + SMOOTHING)).ln();
        for (l, &p) in logits.iter_mut().zip(&self.last_log[row.clone()]) {
            *l += p + shift;
        }
        let last_p = &self.last_p[row];
        for &(k, c) in items {
            let k = k as usize;
            let smoothed = (c + SMOOTHING * last_p[k]) / (mass + SMOOTHING);
            logits[k] += smoothed.ln() - (last_p[k].ln() + shift);
        }
    }

    /// [`Self::add_to`] for a dense input row `x` (`[x_dim]`).
    pub fn add_to_dense(&self, x: &[f32], logits: &mut [f32], cols: &mut Vec<u32>) {
        cols.clear();
        cols.extend(
            x.iter()
                .enumerate()
                .filter(|(_, v)| **v != 0.0)
                .map(|(j, _)| j as u32),
        );
        self.add_to(cols, logits);
    }

    /// The counts as bytes (little-endian: the sizes, the item counts, then each last
    /// column's and each pair's entries); the tables are derived again on reading.
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = Vec::new();
        let put = |out: &mut Vec<u8>, v: u32| out.extend_from_slice(&v.to_le_bytes());
        let putf = |out: &mut Vec<u8>, v: f32| out.extend_from_slice(&v.to_le_bytes());
        put(&mut out, self.x_dim as u32);
        put(&mut out, self.n as u32);
        for &c in &self.all {
            putf(&mut out, c);
        }
        let mut last: Vec<_> = self.last.iter().collect();
        last.sort_unstable_by_key(|e| *e.0);
        put(&mut out, last.len() as u32);
        for (&b, items) in last {
            put(&mut out, b);
            put(&mut out, items.len() as u32);
            for &(k, c) in items {
                put(&mut out, k);
                putf(&mut out, c);
            }
        }
        let mut pairs: Vec<_> = self.pairs.iter().collect();
        pairs.sort_unstable_by_key(|e| *e.0);
        put(&mut out, pairs.len() as u32);
        for (&(a, b), items) in pairs {
            put(&mut out, a);
            put(&mut out, b);
            put(&mut out, items.len() as u32);
            for &(k, c) in items {
                put(&mut out, k);
                putf(&mut out, c);
            }
        }
        out
    }

    /// Reads [`Self::to_bytes`]'s counts for a policy of input width `x_dim` and `n` actions.
    ///
    /// # Errors
    /// When the bytes are cut short, hold more, or do not fit the shape (nothing read from
    /// them is trusted to size an allocation before it is checked against the bytes left).
    pub fn from_bytes(bytes: &[u8], x_dim: usize, n: usize) -> Result<Self, PriorError> {
        let mut r = Reader { bytes, at: 0 };
        let (dim, actions) = (r.u32()? as usize, r.u32()? as usize);
        if (dim, actions) != (x_dim, n) {
            return Err(PriorError(format!(
                "counted for {dim} inputs and {actions} actions, the policy has {x_dim} and {n}"
            )));
        }
        let mut all = Vec::with_capacity(n);
        for _ in 0..n {
            all.push(r.count()?);
        }
        let mut last = HashMap::new();
        for _ in 0..r.len(8)? {
            let b = r.column(x_dim)?;
            last.insert(b, r.items(n)?);
        }
        let mut pairs = HashMap::new();
        for _ in 0..r.len(12)? {
            let (a, b) = (r.column(x_dim)?, r.column(x_dim)?);
            pairs.insert((a, b), r.items(n)?);
        }
        if r.at != bytes.len() {
            return Err(PriorError(format!(
                "{} bytes past the counts",
                bytes.len() - r.at
            )));
        }
        Ok(Self::derive(x_dim, n, all, last, pairs))
    }
}

/// A policy's bytes with a prior: the weight record's length (8 bytes, little-endian), the
/// record, then the prior's counts (nothing before they are counted).
pub fn frame(record: &[u8], prior: Option<&CountPrior>) -> Vec<u8> {
    let mut out = (record.len() as u64).to_le_bytes().to_vec();
    out.extend_from_slice(record);
    if let Some(prior) = prior {
        out.extend_from_slice(&prior.to_bytes());
    }
    out
}

/// [`frame`]'s record and counts.
///
/// # Errors
/// When the bytes are shorter than the length they state.
pub fn unframe(bytes: &[u8]) -> Result<(&[u8], &[u8]), PriorError> {
    let len = bytes
        .first_chunk::<8>()
        .map(|b| u64::from_le_bytes(*b))
        .ok_or_else(|| PriorError("no record length before the counts".into()))?;
    let end = usize::try_from(len)
        .ok()
        .and_then(|l| l.checked_add(8))
        .filter(|&e| e <= bytes.len())
        .ok_or_else(|| PriorError(format!("a weight record of {len} bytes in fewer")))?;
    Ok((&bytes[8..end], &bytes[end..]))
}

/// The last non-zero column of a row and the one before it, if any.
fn key(cols: &[u32]) -> Option<(u32, Option<u32>)> {
    let (&b, rest) = cols.split_last()?;
    Some((b, rest.last().copied()))
}

struct Reader<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl Reader<'_> {
    fn u32(&mut self) -> Result<u32, PriorError> {
        let b = self
            .bytes
            .get(self.at..self.at + 4)
            .ok_or_else(|| PriorError("cut short".into()))?;
        self.at += 4;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }

    fn count(&mut self) -> Result<f32, PriorError> {
        let v = f32::from_bits(self.u32()?);
        if v.is_finite() && v >= 0.0 {
            Ok(v)
        } else {
            Err(PriorError(format!("a count of {v}")))
        }
    }

    /// A length of entries of at least `each` bytes, checked against the bytes left.
    fn len(&mut self, each: usize) -> Result<usize, PriorError> {
        let len = self.u32()? as usize;
        if len.saturating_mul(each) > self.bytes.len() - self.at {
            return Err(PriorError(format!("{len} entries in fewer bytes")));
        }
        Ok(len)
    }

    fn column(&mut self, x_dim: usize) -> Result<u32, PriorError> {
        let c = self.u32()?;
        if (c as usize) < x_dim {
            Ok(c)
        } else {
            Err(PriorError(format!("column {c} of {x_dim}")))
        }
    }

    fn items(&mut self, n: usize) -> Result<Vec<(u32, f32)>, PriorError> {
        let len = self.len(8)?;
        let mut out = Vec::with_capacity(len);
        for _ in 0..len {
            let k = self.u32()?;
            if k as usize >= n {
                return Err(PriorError(format!("item {k} of {n}")));
            }
            out.push((k, self.count()?));
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn softmax(logits: &[f32]) -> Vec<f32> {
        let max = logits.iter().copied().fold(f32::NEG_INFINITY, f32::max);
        let e: Vec<f32> = logits.iter().map(|l| (l - max).exp()).collect();
        let s: f32 = e.iter().sum();
        e.iter().map(|v| v / s).collect()
    }

    /// 4 items; columns 0..5 the item before the last (4: none), 5..10 the last.
    fn prior() -> CountPrior {
        let rows: Vec<(Vec<u32>, u32)> = vec![
            (vec![0, 6], 2),
            (vec![0, 6], 2),
            (vec![0, 6], 3),
            (vec![1, 6], 0),
            (vec![4, 7], 1),
        ];
        CountPrior::count(10, 4, rows.iter().map(|(c, k)| (c.as_slice(), *k)))
    }

    #[test]
    fn estimates_are_interpolated_counts_that_sum_to_one() {
        let p = prior();
        let probs = |cols: &[u32]| {
            let mut l = vec![0.0; 4];
            p.add_to(cols, &mut l);
            softmax(&l)
        };
        // all purchases: (counts + 1/4) / (5 + 1)
        let base = [1.25 / 6.0, 1.25 / 6.0, 2.25 / 6.0, 1.25 / 6.0];
        // after 6: counts 2:2, 3:1, 0:1 (mass 4), smoothed towards base
        let after6: Vec<f32> = (0..4)
            .map(|k| ([1.0, 0.0, 2.0, 1.0][k] + base[k]) / 5.0)
            .collect();
        // after (0, 6): 2:2, 3:1 (mass 3), smoothed towards after6
        let pair: Vec<f32> = (0..4)
            .map(|k| ([0.0, 0.0, 2.0, 1.0][k] + after6[k]) / 4.0)
            .collect();
        let close = |a: &[f32], b: &[f32]| a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-5);
        assert!(close(&probs(&[0, 6]), &pair), "{:?}", probs(&[0, 6]));
        // an unseen pair is its last item's estimate; an unseen last item, all purchases'
        assert!(close(&probs(&[3, 6]), &after6));
        assert!(close(&probs(&[3, 8]), &base));
        assert!(close(&probs(&[]), &base));
        let mut l = vec![0.0; 4];
        p.add_to(&[0, 6], &mut l);
        assert!((l.iter().map(|v| v.exp()).sum::<f32>() - 1.0).abs() < 1e-5);
        let mut dense = vec![0.0; 10];
        (dense[0], dense[6]) = (1.0, 1.0);
        let (mut from_dense, mut cols) = (vec![0.0; 4], Vec::new());
        p.add_to_dense(&dense, &mut from_dense, &mut cols);
        assert_eq!(from_dense, l);
    }

    #[test]
    fn bytes_round_trip_and_bad_bytes_are_refused() {
        let p = prior();
        let bytes = p.to_bytes();
        assert_eq!(CountPrior::from_bytes(&bytes, 10, 4).expect("reads"), p);
        assert!(CountPrior::from_bytes(&bytes, 10, 5).is_err());
        assert!(CountPrior::from_bytes(&bytes[..bytes.len() - 1], 10, 4).is_err());
        let mut longer = bytes.clone();
        longer.push(0);
        assert!(CountPrior::from_bytes(&longer, 10, 4).is_err());
        // a huge entry count is refused before anything is allocated for it
        let mut huge = bytes[..8 + 16].to_vec();
        huge.extend_from_slice(&u32::MAX.to_le_bytes());
        assert!(CountPrior::from_bytes(&huge, 10, 4).is_err());
        let mut nan = bytes.clone();
        nan[8..12].copy_from_slice(&f32::NAN.to_le_bytes());
        assert!(CountPrior::from_bytes(&nan, 10, 4).is_err());

        // framed with a weight record
        let framed = frame(b"weights", Some(&p));
        let (record, counts) = unframe(&framed).expect("unframes");
        assert_eq!(record, b"weights");
        assert_eq!(CountPrior::from_bytes(counts, 10, 4).expect("reads"), p);
        assert_eq!(unframe(&frame(b"weights", None)).expect("unframes").1, b"");
        assert!(unframe(&framed[..4]).is_err());
        assert!(unframe(&framed[..10]).is_err());
    }
}
