//! Who is acting, and so how large a batch is. An actor announces itself when it opens its
//! policy stream (`WatchRequest.evaluates`, with `rollout_steps`: the env steps one rollout of
//! all its environments delivers), and leaves when its last stream closes, however it was
//! started (`jsae train`, by hand, compose, an orchestrator): no setting says how many actors
//! a run has. The learner's batch is one rollout of every actor present, so with
//! `rollouts_per_policy = 1` each update answers exactly the rollouts its actors sent and
//! the policy lag stays 0 as actors join and leave.
//!
//! An actor that is connected but sends nothing (a link cut while its connection still looks
//! open, an actor stuck or refused) must not hold every update back: a round whose first
//! fragment has waited longer than [`RoundClock::deadline`] is closed with what it has, and
//! each actor that delivered nothing to it is marked absent, out of the batch, until its next
//! fragment arrives. The deadline's floor is half the actors' own (`policy_wait_ms`), so the
//! learner closes such a round before the actors that did deliver give up waiting for its
//! update and send more under the same version; where they still do (a loaded machine) and
//! their extra rollouts fill the round past its deadline, the silent actors are left out the
//! same way (`training::round_completed`). With no actor present (none announced itself, or
//! all are absent) the batch is the settings' `actors x envs_per_actor x rollout_len`.

use std::collections::{BTreeMap, BTreeSet};
use std::time::{Duration, Instant};

/// The most env steps one actor may say its rollout delivers (a larger claim would hold
/// every round until its deadline).
pub const MAX_ROLLOUT_STEPS: u64 = 1 << 22;

/// A round's deadline is this many times the slowest recent round's spread (from its first
/// fragment to its last), never less than the floor.
pub const DEADLINE_FACTOR: u32 = 3;

#[derive(Debug, Clone, Copy)]
struct Member {
    /// Open policy streams (an actor reconnecting may have two for a moment).
    streams: usize,
    rollout_steps: u64,
    /// Left out of the batch: it delivered nothing to a round that closed at its deadline.
    absent: bool,
}

/// The actors whose policy streams are open, who delivered to the round being gathered, and
/// the round's clock.
#[derive(Debug)]
pub(super) struct Roster {
    members: BTreeMap<u64, Member>,
    /// The batch while no actor is present, and an actor's rollout when it does not say.
    fallback: (usize, u64),
    delivered: BTreeSet<u64>,
    clock: RoundClock,
}

impl Roster {
    /// `fallback_batch`: the batch with no actor present; `default_rollout`: the rollout of
    /// an actor that does not say (`rollout_steps` 0); `floor`: the least a round waits for
    /// its silent actors.
    pub(super) fn new(fallback_batch: usize, default_rollout: u64, floor: Duration) -> Self {
        Self {
            members: BTreeMap::new(),
            fallback: (fallback_batch.max(1), default_rollout.max(1)),
            delivered: BTreeSet::new(),
            clock: RoundClock::new(floor),
        }
    }

    /// How long the round being gathered may wait for its last fragment.
    pub(super) fn deadline(&self) -> Duration {
        self.clock.deadline()
    }

    /// A fragment of `actor` was buffered at `now`; `first`: it is the only one buffered (a
    /// new round, or the first of a newer embedding, which emptied the round).
    pub(super) fn buffered(&mut self, actor: u64, first: bool, now: Instant) {
        if first {
            self.new_round();
            self.clock.reset();
        }
        self.delivered(actor);
        self.clock.buffered(now);
    }

    /// The round reached its batch at `now`. Past its deadline (the actors that did deliver
    /// sent more rollouts while one stayed silent) the actors that delivered nothing to it
    /// are left out as at the deadline itself (their ids), and its spread is not measured.
    pub(super) fn completed(&mut self, now: Instant) -> Vec<u64> {
        if let Some(missing) = self.overdue(now) {
            return missing;
        }
        self.new_round();
        self.clock.completed(now);
        Vec::new()
    }

    /// At `now`, whether the round is past its deadline waiting on an actor present: then the
    /// actors that delivered nothing to it are left out until their next fragment (their ids)
    /// and a new round starts; the caller updates on what is buffered.
    pub(super) fn overdue(&mut self, now: Instant) -> Option<Vec<u64>> {
        if !(self.clock.overdue(now) && self.waits_on_someone()) {
            return None;
        }
        self.clock.reset();
        Some(self.close_overdue())
    }

    /// An actor's policy stream opened; `rollout_steps` as it announced them.
    pub(super) fn open(&mut self, actor: u64, rollout_steps: u64) {
        let steps = match rollout_steps {
            0 => self.fallback.1,
            n => n.min(MAX_ROLLOUT_STEPS),
        };
        let m = self.members.entry(actor).or_insert(Member {
            streams: 0,
            rollout_steps: steps,
            absent: false,
        });
        m.streams += 1;
        m.rollout_steps = steps;
        m.absent = false;
    }

    /// One of an actor's policy streams closed.
    pub(super) fn close(&mut self, actor: u64) {
        if let Some(m) = self.members.get_mut(&actor) {
            m.streams = m.streams.saturating_sub(1);
            if m.streams == 0 {
                self.members.remove(&actor);
            }
        }
    }

    /// Whether `actor` has a policy stream open.
    pub(super) fn is_open(&self, actor: u64) -> bool {
        self.members.contains_key(&actor)
    }

    /// An actor with an open stream, present ones first.
    pub(super) fn any_open(&self) -> Option<u64> {
        let present = self.members.iter().find(|(_, m)| !m.absent);
        present
            .or_else(|| self.members.iter().next())
            .map(|(&a, _)| a)
    }

    /// Actors with an open stream, and how many of them are present.
    pub(super) fn counts(&self) -> (usize, usize) {
        let present = self.members.values().filter(|m| !m.absent).count();
        (self.members.len(), present)
    }

    /// The batch: one rollout of every present actor (the fallback with none).
    pub(super) fn batch_steps(&self) -> usize {
        let steps: u64 = self
            .members
            .values()
            .filter(|m| !m.absent)
            .map(|m| m.rollout_steps)
            .sum();
        if steps == 0 {
            self.fallback.0
        } else {
            steps as usize
        }
    }

    /// A fragment of `actor` reached the round (buffered or dropped): the actor is present
    /// again.
    pub(super) fn delivered(&mut self, actor: u64) {
        self.delivered.insert(actor);
        if let Some(m) = self.members.get_mut(&actor) {
            m.absent = false;
        }
    }

    /// The round was closed complete, or emptied (a newer embedding): a new one starts.
    fn new_round(&mut self) {
        self.delivered.clear();
    }

    /// Whether the round waits on an actor present that has delivered nothing to it (with
    /// none present, a round is the settings' batch and has no one to wait for).
    fn waits_on_someone(&self) -> bool {
        self.members
            .iter()
            .any(|(a, m)| !m.absent && !self.delivered.contains(a))
    }

    /// The round closed at its deadline: the actors that delivered nothing to it are absent
    /// until their next fragment; their ids.
    fn close_overdue(&mut self) -> Vec<u64> {
        let mut missing = Vec::new();
        for (&actor, m) in &mut self.members {
            if !m.absent && !self.delivered.contains(&actor) {
                m.absent = true;
                missing.push(actor);
            }
        }
        self.delivered.clear();
        missing
    }
}

/// When the round being gathered started, and how long rounds take to fill.
#[derive(Debug, Clone)]
struct RoundClock {
    floor: Duration,
    /// The slowest recent spread, decayed by a tenth at each new one.
    slowest: Duration,
    first: Option<Instant>,
}

impl RoundClock {
    /// A clock whose deadline is never below `floor`.
    fn new(floor: Duration) -> Self {
        Self {
            floor,
            slowest: Duration::ZERO,
            first: None,
        }
    }

    /// How long a round may wait for its last fragment after its first.
    fn deadline(&self) -> Duration {
        self.floor.max(self.slowest * DEADLINE_FACTOR)
    }

    /// A fragment is buffered at `now` (the round's first starts the clock).
    fn buffered(&mut self, now: Instant) {
        self.first.get_or_insert(now);
    }

    /// The round was completed at `now`: its spread is measured.
    fn completed(&mut self, now: Instant) {
        if let Some(first) = self.first.take() {
            let spread = now.duration_since(first);
            self.slowest = spread.max(self.slowest.mul_f64(0.9));
        }
    }

    /// Nothing is buffered (the round closed overdue, or was emptied).
    fn reset(&mut self) {
        self.first = None;
    }

    /// Whether the round has waited past its deadline.
    fn overdue(&self, now: Instant) -> bool {
        self.first
            .is_some_and(|first| now.duration_since(first) >= self.deadline())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_batch_is_one_rollout_of_every_actor_present() {
        let mut r = Roster::new(2048, 512, Duration::ZERO);
        assert_eq!(r.batch_steps(), 2048, "nobody yet: the settings' batch");
        assert!(!r.waits_on_someone());
        r.open(1, 1000);
        r.open(2, 0);
        assert_eq!(
            r.batch_steps(),
            1512,
            "actor 2 did not say: the default rollout"
        );
        r.open(2, 0);
        r.close(2);
        assert_eq!(r.batch_steps(), 1512, "actor 2 still has a stream");
        r.close(2);
        assert_eq!(r.batch_steps(), 1000);
        r.open(3, u64::MAX);
        assert_eq!(r.batch_steps(), 1000 + MAX_ROLLOUT_STEPS as usize);
        assert_eq!(r.counts(), (2, 2));
    }

    #[test]
    fn an_actor_silent_through_an_overdue_round_is_absent_until_it_delivers() {
        let mut r = Roster::new(2048, 100, Duration::ZERO);
        r.open(1, 100);
        r.open(2, 100);
        r.delivered(1);
        assert!(r.waits_on_someone());
        assert_eq!(r.close_overdue(), vec![2]);
        r.delivered(1);
        assert!(
            !r.waits_on_someone(),
            "actor 2 is absent: a round of actor 1 waits on nobody"
        );
        assert_eq!(r.batch_steps(), 100);
        assert_eq!(r.counts(), (2, 1));
        assert_eq!(r.any_open(), Some(1));
        r.delivered(2);
        assert_eq!(r.batch_steps(), 200);
        // a round nobody delivered to: all absent, the settings' batch
        r.new_round();
        assert_eq!(r.close_overdue().len(), 2);
        assert_eq!(r.batch_steps(), 2048);
        assert!(r.is_open(2));
        assert_eq!(r.any_open(), Some(1));
    }

    #[test]
    fn the_deadline_follows_the_slowest_recent_round() {
        let ms = Duration::from_millis;
        let t0 = Instant::now();
        let mut c = RoundClock::new(ms(100));
        assert!(!c.overdue(t0 + ms(1000)), "nothing buffered");
        c.buffered(t0);
        c.buffered(t0 + ms(10));
        assert!(!c.overdue(t0 + ms(99)));
        c.completed(t0 + ms(60));
        assert_eq!(c.deadline(), ms(180));
        c.buffered(t0 + ms(100));
        assert!(!c.overdue(t0 + ms(279)));
        assert!(c.overdue(t0 + ms(280)));
        c.reset();
        assert!(!c.overdue(t0 + ms(1000)));
    }
}
