//! Running statistics: mean/variance (Welford, merged in batches) and reward scaling by the
//! std of the discounted return.

use std::collections::HashMap;

/// Running mean and variance of a stream of values.
#[derive(Debug, Clone, PartialEq)]
pub struct RunningMeanStd {
    /// Mean.
    pub mean: f64,
    /// Population variance.
    pub var: f64,
    /// Number of values seen.
    pub count: f64,
}

impl Default for RunningMeanStd {
    fn default() -> Self {
        Self {
            mean: 0.0,
            var: 1.0,
            count: 1e-4,
        }
    }
}

impl RunningMeanStd {
    /// Adds one value.
    pub fn update(&mut self, x: f64) {
        let count = self.count + 1.0;
        let delta = x - self.mean;
        let mean = self.mean + delta / count;
        let m2 = self.var * self.count + delta * (x - mean);
        self.mean = mean;
        self.var = m2 / count;
        self.count = count;
    }

    /// Standard deviation.
    pub fn std(&self) -> f64 {
        self.var.max(0.0).sqrt()
    }
}

/// What a [`RewardScaler`] has learned: the return statistics and each environment's running
/// return (a checkpoint saves it, so a restarted learner scales as the stopped one would).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ScalerState {
    /// Statistics of the discounted returns.
    pub stats: RunningMeanStd,
    /// Each (actor, environment) stream's running discounted return, sorted by stream.
    pub returns: Vec<((u64, u32), f64)>,
}

/// Scales rewards by the running std of each environment's discounted return, clipped.
#[derive(Debug, Clone, Default)]
pub struct RewardScaler {
    gamma: f64,
    clip: f64,
    returns: HashMap<(u64, u32), f64>,
    stats: RunningMeanStd,
}

impl RewardScaler {
    /// A scaler for discount `gamma`, clipping scaled rewards to `[-clip, clip]`.
    pub fn new(gamma: f64, clip: f64) -> Self {
        Self {
            gamma,
            clip,
            ..Self::default()
        }
    }

    /// What it has learned.
    pub fn state(&self) -> ScalerState {
        let mut returns: Vec<_> = self.returns.iter().map(|(&k, &v)| (k, v)).collect();
        returns.sort_by_key(|&(k, _)| k);
        ScalerState {
            stats: self.stats.clone(),
            returns,
        }
    }

    /// Goes on from saved state (gamma and the clip stay this scaler's).
    pub fn set_state(&mut self, state: ScalerState) {
        self.stats = state.stats;
        self.returns = state.returns.into_iter().collect();
    }

    /// Scales one environment's rewards in place, in step order; `episode_end[t]` resets
    /// that environment's running return after step `t`.
    pub fn scale(&mut self, stream: (u64, u32), rewards: &mut [f32], episode_end: &[bool]) {
        let ret = self.returns.entry(stream).or_insert(0.0);
        for (r, &end) in rewards.iter_mut().zip(episode_end) {
            *ret = *ret * self.gamma + f64::from(*r);
            self.stats.update(*ret);
            let scaled = f64::from(*r) / (self.stats.std() + 1e-8);
            *r = scaled.clamp(-self.clip, self.clip) as f32;
            if end {
                *ret = 0.0;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn running_stats_match_the_batch_statistics() {
        let mut s = RunningMeanStd::default();
        let xs = [1.0, 2.0, 4.0, 7.0];
        for x in xs {
            s.update(x);
        }
        assert!((s.mean - 3.5).abs() < 1e-3);
        assert!((s.var - 5.25).abs() < 1e-2, "{}", s.var);
    }
}
