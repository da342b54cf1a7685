//! How far pre-training has come, for people waiting on it: the epoch, the epochs, and the
//! time left at the pace so far. The trainer logs it at every tenth of the epochs (the
//! embedder service's log, which `jsae train` shows beside its progress bar) and hands it to
//! an observer where one is set (the one-process driver's progress bar).

use std::time::Duration;

/// Pre-training after `epoch` of `epochs` passes over `transitions` transitions.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PretrainProgress {
    /// Passes done.
    pub epoch: usize,
    /// Passes in all (`embedding.pretrain_epochs`).
    pub epochs: usize,
    /// Transitions it trains on.
    pub transitions: usize,
    /// Time since pre-training started.
    pub elapsed: Duration,
}

/// The words every report starts with (the launcher looks for them in the embedder's log).
pub const PRETRAIN_PHASE: &str = "pre-training the embedding";

impl PretrainProgress {
    /// Time left at the pace of the passes so far (None before the first one).
    pub fn eta(&self) -> Option<Duration> {
        (self.epoch > 0).then(|| {
            self.elapsed
                .mul_f64((self.epochs.saturating_sub(self.epoch)) as f64 / self.epoch as f64)
        })
    }

    /// Whether the trainer logs this pass: the first, each tenth of the epochs, the last.
    pub fn worth_logging(&self) -> bool {
        let tenth = (self.epochs / 10).max(1);
        self.epoch == 1 || self.epoch.is_multiple_of(tenth) || self.epoch == self.epochs
    }
}

impl std::fmt::Display for PretrainProgress {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{PRETRAIN_PHASE} on {} transitions: epoch {}/{}",
            self.transitions, self.epoch, self.epochs
        )?;
        match self.eta() {
            Some(left) => write!(f, ", about {:.0} s left", left.as_secs_f64().ceil()),
            None => Ok(()),
        }
    }
}

/// Where the trainer reports each pass of pre-training.
pub struct PretrainObserver(pub Box<dyn FnMut(&PretrainProgress) + Send>);

impl std::fmt::Debug for PretrainObserver {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("PretrainObserver")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_time_left_follows_the_pace_so_far() {
        let p = PretrainProgress {
            epoch: 12,
            epochs: 60,
            transitions: 32_768,
            elapsed: Duration::from_secs(10),
        };
        assert_eq!(p.eta(), Some(Duration::from_secs(40)));
        assert_eq!(
            p.to_string(),
            "pre-training the embedding on 32768 transitions: epoch 12/60, about 40 s left"
        );
        assert!(p.worth_logging() && !PretrainProgress { epoch: 7, ..p }.worth_logging());
    }
}
