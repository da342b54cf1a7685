//! Random play before the first embedding. Each actor plays its share of the pre-training
//! budget at random, sending the transitions to the embedder and no fragment, then waits for
//! the first embedding rather than spend the budget on more. An embedder that goes away before
//! its first embedding (killed, then restarted with no checkpoint) starts again from an empty
//! buffer, and the transitions it had are lost with it: the actor, told by its embedding
//! stream that the embedder went away and is back, plays another share for the new one (and
//! `push` loses none of it while the embedder is away), so a restart during pre-training does
//! not leave the run waiting forever.

/// How far the actor plays at random; see the module's text.
#[derive(Debug, Clone)]
pub struct RandomPlay {
    share: u64,
    /// Random play goes on until this many env steps.
    until: u64,
    /// Losses of the embedder's stream seen so far.
    losses: u64,
}

impl RandomPlay {
    /// `share` env steps at random (`TrainConfig::random_play_share`).
    pub fn new(share: u64) -> Self {
        Self {
            share,
            until: share,
            losses: 0,
        }
    }

    /// The embedder's stream has come back after a loss `losses` times in all; when that is
    /// more than before, another share starts at `env_steps`: the env steps it goes on until.
    pub fn embedder_lost(&mut self, env_steps: u64, losses: u64) -> Option<u64> {
        if losses <= self.losses {
            return None;
        }
        self.losses = losses;
        self.until = env_steps + self.share;
        Some(self.until)
    }

    /// Whether an actor with no embedding yet that has played `env_steps` waits for it.
    pub fn waits(&self, env_steps: u64) -> bool {
        env_steps >= self.until
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_actor_plays_its_share_then_waits() {
        let play = RandomPlay::new(100);
        assert!(!play.waits(0));
        assert!(!play.waits(99));
        assert!(play.waits(128));
    }

    #[test]
    fn a_lost_embedder_gets_another_share_from_where_the_actor_is() {
        let mut play = RandomPlay::new(100);
        assert_eq!(play.embedder_lost(128, 0), None);
        assert!(play.waits(128));
        assert_eq!(play.embedder_lost(128, 1), Some(228));
        assert_eq!(
            play.embedder_lost(200, 1),
            None,
            "the same loss counts once"
        );
        assert!(!play.waits(200));
        assert!(play.waits(256));
        // lost while still playing: the share counts from the loss
        assert_eq!(play.embedder_lost(300, 3), Some(400));
        assert!(!play.waits(300));
    }
}
