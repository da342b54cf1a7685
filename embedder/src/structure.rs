//! How much of the environment's action geometry an action embedding holds: the mean true
//! displacement distance from an action to its `k` nearest neighbours in E, over the mean
//! distance to all other actions. 1 is no structure (neighbours in E are random actions), 0
//! is perfect (neighbours in E move the same way). Measured on every published snapshot where
//! the environment gives each action's displacement (the gridworlds); metrics.csv's
//! `embedding_structure`.

/// Neighbours per action.
const K: usize = 5;
/// At most this many actions are measured (evenly strided), each against all actions, so a
/// measurement at 4,096 actions costs a few milliseconds per snapshot.
const MAX_ANCHORS: usize = 1024;

/// The true displacement of every action, and the all-pairs term computed once.
#[derive(Debug, Clone)]
pub struct ActionStructure {
    motions: Vec<[f64; 2]>,
    anchors: Vec<usize>,
    /// Per anchor: mean displacement distance to every other action.
    random: f64,
}

impl ActionStructure {
    /// The measure against these displacements (None for fewer than `K + 1` actions).
    pub fn new(motions: Vec<[f64; 2]>) -> Option<Self> {
        let n = motions.len();
        if n <= K {
            return None;
        }
        let stride = n.div_ceil(MAX_ANCHORS);
        let anchors: Vec<usize> = (0..n).step_by(stride).collect();
        let mut structure = Self {
            motions,
            anchors,
            random: 0.0,
        };
        let random: f64 = structure
            .anchors
            .iter()
            .map(|&a| {
                (0..n)
                    .filter(|&b| b != a)
                    .map(|b| structure.motion_distance(a, b))
                    .sum::<f64>()
                    / (n - 1) as f64
            })
            .sum();
        structure.random = random / structure.anchors.len() as f64;
        Some(structure)
    }

    fn motion_distance(&self, a: usize, b: usize) -> f64 {
        let (p, q) = (self.motions[a], self.motions[b]);
        (p[0] - q[0]).hypot(p[1] - q[1])
    }

    /// The ratio for an action table `[n, d]` row-major (None if its row count differs from
    /// the motions', or the actions do not move at all).
    pub fn measure(&self, table: &[f32], d: usize) -> Option<f32> {
        let n = self.motions.len();
        if d == 0 || table.len() != n * d || self.random <= 0.0 {
            return None;
        }
        let mut by_e: Vec<(f32, usize)> = Vec::with_capacity(n);
        let mut near = 0.0;
        for &a in &self.anchors {
            let row = &table[a * d..(a + 1) * d];
            by_e.clear();
            by_e.extend((0..n).filter(|&b| b != a).map(|b| {
                let other = &table[b * d..(b + 1) * d];
                let dist: f32 = row.iter().zip(other).map(|(x, y)| (x - y) * (x - y)).sum();
                (dist, b)
            }));
            // ties broken by action index, so the measure is deterministic
            by_e.select_nth_unstable_by(K - 1, |x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)));
            near += by_e[..K]
                .iter()
                .map(|&(_, b)| self.motion_distance(a, b))
                .sum::<f64>()
                / K as f64;
        }
        Some((near / self.anchors.len() as f64 / self.random) as f32)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn line(n: usize) -> Vec<[f64; 2]> {
        (0..n).map(|i| [i as f64, 0.0]).collect()
    }

    #[test]
    fn an_embedding_that_copies_the_motions_scores_low_and_a_shuffled_one_near_one() {
        let n = 200;
        let s = ActionStructure::new(line(n)).expect("enough actions");
        let same: Vec<f32> = (0..n).map(|i| i as f32).collect();
        let ordered = s.measure(&same, 1).expect("measured");
        assert!(ordered < 0.1, "{ordered}");
        // a fixed scramble of the order: neighbours in E are unrelated actions
        let scrambled: Vec<f32> = (0..n).map(|i| ((i * 7919) % n) as f32).collect();
        let random = s.measure(&scrambled, 1).expect("measured");
        assert!(random > 0.6, "{random}");
        assert_eq!(s.measure(&same[..10], 1), None, "wrong row count");
        assert!(ActionStructure::new(line(K)).is_none());
    }
}
