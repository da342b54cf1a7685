//! On-policy pacing of a separate actor process. Each rollout round of all actors is one
//! learner update, so one policy version; an actor may have at most `rollouts_per_policy`
//! rollouts out that no newer version has answered yet (1: wait for the update each rollout
//! feeds, lag 0 with one actor; 2: collect the next rollout while the learner updates, lag
//! at most 1). It counts the rollouts it sent and the versions that came since a baseline.
//!
//! The wait is not forever: an actor whose round the learner cannot complete (another actor
//! died) goes on after a while. The rollouts still out stay counted for one more wait: where
//! the learner was only late (a round held to its deadline on a loaded machine), their
//! answer brings the actor back in step, where counting afresh at once left it one rollout
//! ahead, at lag 1, for the rest of the run; where they were dropped, the next wait ends the
//! same way and the actor counts afresh. How long adapts to the run: the actor
//! measures how long each newer version took to arrive once it started waiting (the
//! learner's update plus the wait for the other actors' rollouts), keeps the largest recent
//! one (the older ones decaying by a tenth at each new measurement), and waits `WAIT_FACTOR`
//! times that, never less than the configured `policy_wait_ms`. So a healthy run never moves
//! on early, whatever the batch size, actor count and update time.
//!
//! A new embedding starts a new count, but the rollouts still out under the old one stay in
//! it: the learner goes on taking the old embedding's fragments until the first of the new
//! one reaches it, so with one actor they are always answered, and counting them as answered
//! (as this module once did) let the actor run one rollout ahead, at lag 1, for the rest of
//! the run. With several actors another's fragment of the new embedding may get there first
//! and the learner drops them, so the actor waits for them only `WAIT_FACTOR` times the
//! slowest recent update, without the configured floor.

use std::time::{Duration, Instant};

/// The wait is this many times the slowest recent arrival of a newer version.
pub const WAIT_FACTOR: u32 = 3;

/// What the actor should do before its next rollout.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Pace {
    /// Collect a rollout now.
    Collect,
    /// Wait a little and ask again.
    Wait,
}

/// Rollouts sent and versions seen since a baseline.
#[derive(Debug, Clone, Copy)]
struct Count {
    /// (policy, embedding) versions at the baseline.
    base: (u64, u64),
    /// Rollouts sent since the baseline.
    sent: u64,
    /// The newest policy version seen.
    seen: u64,
    /// Since when the actor waits (if it does).
    waiting: Option<Instant>,
    /// Rollouts of an earlier embedding are among `sent` and no newer version has come yet.
    carried: bool,
    /// The actor went on after a wait with rollouts still out, which stay in `sent` until
    /// answered or until the next wait also ends.
    late: bool,
}

/// One actor's pacing state.
#[derive(Debug, Clone)]
pub struct Pacing {
    rollouts_per_policy: u64,
    floor: Duration,
    /// The slowest recent arrival of a newer version, decayed.
    slowest: Duration,
    count: Option<Count>,
}

impl Pacing {
    /// Pacing of `rollouts_per_policy` unanswered rollouts at most, waiting at least `floor`.
    pub fn new(rollouts_per_policy: usize, floor: Duration) -> Self {
        Self {
            rollouts_per_policy: rollouts_per_policy.max(1) as u64,
            floor,
            slowest: Duration::ZERO,
            count: None,
        }
    }

    /// How long the actor waits for a newer version now.
    pub fn wait(&self) -> Duration {
        self.floor.max(self.slowest * WAIT_FACTOR)
    }

    /// Whether to collect now, the actor's current (policy, embedding) versions being
    /// `version`.
    pub fn pace(&mut self, version: (u64, u64), now: Instant) -> Pace {
        let wait = self.wait();
        let fresh = Count {
            base: version,
            sent: 0,
            seen: version.0,
            waiting: None,
            carried: false,
            late: false,
        };
        let c = match &mut self.count {
            // an older policy: a learner restarted from a checkpoint
            Some(c) if version.0 < c.base.0 => {
                *c = fresh;
                c
            }
            // a new embedding: the rollouts still out under the old one stay counted
            Some(c) if c.base.1 != version.1 => {
                let out = c.sent.saturating_sub(version.0 - c.base.0);
                *c = Count {
                    sent: out,
                    carried: out > 0,
                    ..fresh
                };
                c
            }
            Some(c) => c,
            None => self.count.insert(fresh),
        };
        if version.0 > c.seen {
            c.carried = false;
            if let Some(since) = c.waiting.take() {
                let took = now.duration_since(since);
                self.slowest = took.max(self.slowest.mul_f64(0.9));
            }
            c.seen = version.0;
        }
        let answered = version.0 - c.base.0;
        if c.sent < answered + self.rollouts_per_policy {
            c.late = false;
            return Pace::Collect;
        }
        let since = *c.waiting.get_or_insert(now);
        let wait = if c.carried {
            self.slowest * WAIT_FACTOR
        } else {
            wait
        };
        if now.duration_since(since) < wait {
            return Pace::Wait;
        }
        // overdue: go on under this version, the rollouts still out counted once more (the
        // learner may only be late); a second wait in a row (or one for an old embedding's
        // rollouts, which the learner drops) counts afresh
        if c.late || c.carried {
            *c = fresh;
        } else {
            c.late = true;
            c.waiting = None;
        }
        Pace::Collect
    }

    /// A rollout was sent.
    pub fn sent(&mut self) {
        if let Some(c) = &mut self.count {
            c.sent += 1;
        }
    }

    /// Forgets the count (while the actor is not yet acting on a policy).
    pub fn reset(&mut self) {
        self.count = None;
    }

    /// Restarts the clock of a wait in progress (after the actor spent time on something
    /// else, such as an evaluation, which must not count as update time).
    pub fn restart_wait(&mut self, now: Instant) {
        if let Some(Count {
            waiting: Some(since),
            ..
        }) = &mut self.count
        {
            *since = now;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: Duration = Duration::from_millis(1);

    #[test]
    fn waits_for_the_next_version_and_learns_how_long_updates_take() {
        let t0 = Instant::now();
        let mut p = Pacing::new(1, 100 * MS);
        assert_eq!(p.pace((0, 1), t0), Pace::Collect);
        p.sent();
        assert_eq!(p.pace((0, 1), t0), Pace::Wait);
        assert_eq!(p.pace((0, 1), t0 + 99 * MS), Pace::Wait);
        // v1 arrives 80 ms into the wait: from now on the actor waits 3 x 80 ms
        assert_eq!(p.pace((1, 1), t0 + 80 * MS), Pace::Collect);
        assert_eq!(p.wait(), 240 * MS);
        p.sent();
        let t1 = t0 + 200 * MS;
        assert_eq!(p.pace((1, 1), t1), Pace::Wait);
        // an update of 200 ms now does not make the actor go on early (wait 240 ms)
        assert_eq!(p.pace((1, 1), t1 + 200 * MS), Pace::Wait);
        assert_eq!(p.pace((2, 1), t1 + 230 * MS), Pace::Collect);
        assert_eq!(p.wait(), 690 * MS);
    }

    #[test]
    fn two_rollouts_out_keep_the_lag_at_one_however_versions_arrive() {
        let t0 = Instant::now();
        let mut p = Pacing::new(2, 50 * MS);
        for _ in 0..2 {
            assert_eq!(p.pace((3, 1), t0), Pace::Collect);
            p.sent();
        }
        assert_eq!(p.pace((3, 1), t0), Pace::Wait);
        // the first rollout's version: one more may go out
        assert_eq!(p.pace((4, 1), t0 + 10 * MS), Pace::Collect);
        p.sent();
        assert_eq!(p.pace((4, 1), t0 + 10 * MS), Pace::Wait);
        // two versions at once (the actor was slow to look): two more may go out
        assert_eq!(p.pace((6, 1), t0 + 20 * MS), Pace::Collect);
        p.sent();
        assert_eq!(p.pace((6, 1), t0 + 20 * MS), Pace::Collect);
        p.sent();
        assert_eq!(p.pace((6, 1), t0 + 20 * MS), Pace::Wait);
        // no version comes (another actor died): go on after the wait with one more out,
        // and after a second wait count afresh
        assert_eq!(p.pace((6, 1), t0 + 69 * MS), Pace::Wait);
        assert_eq!(p.pace((6, 1), t0 + 70 * MS), Pace::Collect);
        p.sent();
        assert_eq!(p.pace((6, 1), t0 + 70 * MS), Pace::Wait);
        assert_eq!(p.pace((6, 1), t0 + 119 * MS), Pace::Wait);
        assert_eq!(p.pace((6, 1), t0 + 120 * MS), Pace::Collect);
        p.sent();
        assert_eq!(p.pace((6, 1), t0 + 120 * MS), Pace::Collect);
        p.sent();
        assert_eq!(p.pace((6, 1), t0 + 121 * MS), Pace::Wait);
    }

    #[test]
    fn a_late_answer_after_the_wait_brings_the_actor_back_to_lag_zero() {
        let t0 = Instant::now();
        let mut p = Pacing::new(1, 100 * MS);
        assert_eq!(p.pace((4, 1), t0), Pace::Collect);
        p.sent();
        assert_eq!(p.pace((4, 1), t0), Pace::Wait);
        // the learner holds its round past the actor's wait: the actor goes on
        assert_eq!(p.pace((4, 1), t0 + 100 * MS), Pace::Collect);
        p.sent();
        // the first rollout's answer comes late: the second is still out, so wait for it
        assert_eq!(p.pace((5, 1), t0 + 110 * MS), Pace::Wait, "not one ahead");
        assert_eq!(p.pace((6, 1), t0 + 120 * MS), Pace::Collect);
        p.sent();
        assert_eq!(p.pace((6, 1), t0 + 120 * MS), Pace::Wait, "in step again");
    }

    #[test]
    fn a_rollout_out_under_the_old_embedding_keeps_the_lag_at_zero() {
        let t0 = Instant::now();
        let mut p = Pacing::new(1, 3000 * MS);
        assert_eq!(p.pace((0, 1), t0), Pace::Collect);
        p.sent();
        assert_eq!(p.pace((0, 1), t0), Pace::Wait);
        // updates take 20 ms
        assert_eq!(p.pace((1, 1), t0 + 20 * MS), Pace::Collect);
        p.sent();
        // embedding 2 arrives while the rollout of embedding 1 is out: wait for its answer
        assert_eq!(p.pace((1, 2), t0 + 25 * MS), Pace::Wait);
        assert_eq!(p.pace((2, 2), t0 + 40 * MS), Pace::Collect);
        p.sent();
        assert_eq!(p.pace((2, 2), t0 + 40 * MS), Pace::Wait, "lag 0, not 1");
        assert_eq!(p.pace((3, 2), t0 + 60 * MS), Pace::Collect);
        p.sent();
        // embedding 3, and the learner dropped the last rollout of embedding 2 (another
        // actor's fragment of embedding 3 came first): go on after 3 x 20 ms, not 3 s
        assert_eq!(p.pace((3, 3), t0 + 70 * MS), Pace::Wait);
        assert_eq!(p.pace((3, 3), t0 + 129 * MS), Pace::Wait);
        assert_eq!(p.pace((3, 3), t0 + 130 * MS), Pace::Collect);
        p.sent();
        assert_eq!(p.pace((3, 3), t0 + 130 * MS), Pace::Wait);
    }

    #[test]
    fn a_new_embedding_before_any_timed_update_goes_on_at_once_and_evaluations_do_not_wait() {
        let t0 = Instant::now();
        let mut p = Pacing::new(1, 100 * MS);
        assert_eq!(p.pace((5, 1), t0), Pace::Collect);
        p.sent();
        assert_eq!(p.pace((5, 1), t0), Pace::Wait);
        assert_eq!(p.pace((5, 2), t0 + 90 * MS), Pace::Collect);
        assert_eq!(
            p.wait(),
            100 * MS,
            "an embedding's arrival is not an update"
        );
        p.sent();
        assert_eq!(p.pace((5, 2), t0 + 90 * MS), Pace::Wait);
        p.restart_wait(t0 + 500 * MS);
        assert_eq!(p.pace((5, 2), t0 + 550 * MS), Pace::Wait);
        assert_eq!(p.pace((6, 2), t0 + 560 * MS), Pace::Collect);
        assert_eq!(p.wait(), 180 * MS);
    }
}
