//! Who is acting, and so how large a batch is. An actor announces itself when it opens its
//! policy stream (`WatchRequest.evaluates`, with `rollout_steps`: the env steps one rollout of
//! all its environments delivers), and leaves when its last stream closes, however it was
//! started (`jsae train`, by hand, compose, an orchestrator): no setting says how many actors
//! a run has. The learner's batch is one rollout of every actor present, so with
//! `rollouts_per_policy = 1` each update answers exactly the rollouts its actors sent and
//! the policy lag stays 0 as actors join and leave. Where the batch is shared
//! (`batch_envs`), each present actor that said how many environments it has is given its
//! share of them ([`share_envs`]), and its rollout counts with its share only: the batch
//! stays `batch_envs` environments' rollouts whoever is present.
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
//! all are absent) the batch is the settings' one round (`TrainConfig::round_steps`).
//!
//! An actor that leaves mid-round may have delivered part of its rollout to the round, and
//! its last fragments may still reach the learner after its stream closed: what it delivered
//! counts on top of the batch of those present (`departed`), so the round still ends with
//! the survivors' last fragments; ended early, every later batch would straddle two policies.

use std::collections::{BTreeMap, VecDeque};
use std::time::{Duration, Instant};

use jsae_settings::share_envs;

/// The most env steps one actor may say its rollout delivers (a larger claim would hold
/// every round until its deadline).
pub const MAX_ROLLOUT_STEPS: u64 = 1 << 22;
/// An actor's rollout counts at most this many times the run's own (its `envs_per_actor` x
/// `rollout_len`), whatever it says.
pub const MAX_ROLLOUT_FACTOR: u64 = 16;
/// The batch grows with the actors up to this many of the run's rollouts (or the settings'
/// batch, where larger); beyond it the batch stays, and the rollouts past it go to the next
/// update. This bounds what the learner holds pending, however many actors connect and
/// whatever they say.
pub const MAX_BATCH_ROLLOUTS: u64 = 64;

/// A round's deadline is this many times the slowest recent round's spread (from its first
/// fragment to its last), never less than the floor.
pub const DEADLINE_FACTOR: u32 = 3;

/// Actors that left which the roster remembers (their late fragments count on top).
const LEFT_KEPT: usize = 64;

#[derive(Debug, Clone, Copy)]
struct Member {
    /// Open policy streams (an actor reconnecting may have two for a moment).
    streams: usize,
    rollout_steps: u64,
    /// Its environments (0: not said; it steps all of them, whatever the batch).
    envs: u32,
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
    /// The most one actor's rollout counts for, and the largest batch.
    max: (u64, u64),
    /// The env steps each actor delivered to the round (0: only dropped fragments).
    delivered: BTreeMap<u64, u64>,
    /// Env steps in the round from actors whose streams have closed: they count on top of
    /// the batch.
    departed: u64,
    /// The last actors whose streams all closed (at most [`LEFT_KEPT`]): their fragments are
    /// late. One that never opened a stream (a client that only pushes) counts as before.
    left: VecDeque<u64>,
    clock: RoundClock,
    /// `batch_envs` where the batch is shared among the actors present.
    shared: Option<usize>,
    /// Each present sharing actor's environments to step from the next round on (kept as
    /// members come, go, fall silent or are back: [`Roster::reshare`]).
    next_shares: BTreeMap<u64, u32>,
    /// The shares the round being gathered was collected with: they change only when a round
    /// ends (an actor that joins gets its own at once), so every actor's rollout counts with
    /// the share it stepped.
    shares: BTreeMap<u64, u32>,
}

impl Roster {
    /// `fallback_batch`: the batch with no actor present; `default_rollout`: the rollout of
    /// an actor that does not say (`rollout_steps` 0); `floor`: the least a round waits for
    /// its silent actors.
    pub(super) fn new(fallback_batch: usize, default_rollout: u64, floor: Duration) -> Self {
        Self {
            members: BTreeMap::new(),
            fallback: (fallback_batch.max(1), default_rollout.max(1)),
            max: (
                (default_rollout.max(1) * MAX_ROLLOUT_FACTOR).min(MAX_ROLLOUT_STEPS),
                (default_rollout.max(1) * MAX_BATCH_ROLLOUTS).max(fallback_batch as u64),
            ),
            delivered: BTreeMap::new(),
            departed: 0,
            left: VecDeque::new(),
            clock: RoundClock::new(floor),
            shared: None,
            next_shares: BTreeMap::new(),
            shares: BTreeMap::new(),
        }
    }

    /// The batch shared among the actors present: `batch_envs` environments' rollouts.
    pub(super) fn sharing(mut self, batch_envs: Option<usize>) -> Self {
        self.shared = batch_envs;
        self
    }

    /// How long the round being gathered may wait for its last fragment.
    pub(super) fn deadline(&self) -> Duration {
        self.clock.deadline()
    }

    /// A fragment of `actor`, `steps` long, was buffered at `now`; `first`: it is the only
    /// one buffered (a new round, or the first of a newer embedding, which emptied the
    /// round). One of an actor whose streams closed was counted before it was buffered
    /// ([`Roster::late`]).
    pub(super) fn buffered(&mut self, actor: u64, steps: u64, first: bool, now: Instant) {
        let late = self.has_left(actor);
        if first {
            self.new_round();
            self.clock.reset();
            if late {
                self.departed = steps;
            }
        }
        self.delivered(actor);
        if self.is_open(actor) {
            *self.delivered.entry(actor).or_default() += steps;
        }
        self.clock.buffered(now);
    }

    /// A fragment of `actor`, `steps` long, is about to be buffered: where its streams have
    /// closed (it was sent before the actor left) it counts on top of the batch, so that it
    /// does not end the round in place of a survivor's fragment; whether it did.
    pub(super) fn late(&mut self, actor: u64, steps: u64) -> bool {
        if !self.has_left(actor) {
            return false;
        }
        self.departed += steps;
        true
    }

    /// A late fragment counted by [`Roster::late`] was not buffered (dropped or refused).
    pub(super) fn not_buffered(&mut self, steps: u64) {
        self.departed = self.departed.saturating_sub(steps);
    }

    /// The round reached its batch at `now`. Past its deadline (the actors that did deliver
    /// sent more rollouts while one stayed silent) the actors that delivered nothing to it
    /// are left out as at the deadline itself (their ids), and its spread is not measured.
    pub(super) fn completed(&mut self, now: Instant) -> Vec<u64> {
        if let Some(missing) = self.overdue(now) {
            return missing;
        }
        self.new_round();
        self.round_ended();
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

    /// An actor's policy stream opened; `rollout_steps` and `envs` as it announced them (from
    /// the wire: environments that do not divide its own stated rollout count as not said,
    /// and the actor then steps all of them).
    pub(super) fn open(&mut self, actor: u64, rollout_steps: u64, envs: u32) {
        let steps = match rollout_steps {
            0 => self.fallback.1,
            n => n.min(self.max.0),
        };
        let divides = envs > 0 && rollout_steps == steps && steps % u64::from(envs) == 0;
        let envs = if divides { envs } else { 0 };
        let m = self.members.entry(actor).or_insert(Member {
            streams: 0,
            rollout_steps: steps,
            envs,
            absent: false,
        });
        m.streams += 1;
        m.rollout_steps = steps;
        m.envs = envs;
        m.absent = false;
        self.reshare();
        // a new actor steps its share from its first rollout, in this round
        match self.next_shares.get(&actor) {
            Some(&share) => {
                self.shares.entry(actor).or_insert(share);
            }
            None => {
                self.shares.remove(&actor);
            }
        }
    }

    /// One of an actor's policy streams closed.
    pub(super) fn close(&mut self, actor: u64) {
        if let Some(m) = self.members.get_mut(&actor) {
            m.streams = m.streams.saturating_sub(1);
            if m.streams == 0 {
                self.members.remove(&actor);
                self.shares.remove(&actor);
                self.departed += self.delivered.remove(&actor).unwrap_or(0);
                self.left.push_back(actor);
                if self.left.len() > LEFT_KEPT {
                    self.left.pop_front();
                }
            }
        }
        self.reshare();
    }

    /// Whether `actor`'s streams have all closed lately (`left`).
    fn has_left(&self, actor: u64) -> bool {
        !self.is_open(actor) && self.left.contains(&actor)
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

    /// The environments each actor steps in the round being gathered where the batch is
    /// shared (those that did not say how many they have step all of them and are not named).
    pub(super) fn shares(&self) -> &BTreeMap<u64, u32> {
        &self.shares
    }

    /// Shares the batch again among the actors present, for the next round.
    fn reshare(&mut self) {
        let Some(total) = self.shared else {
            return;
        };
        let sharing: Vec<(u64, usize)> = self
            .members
            .iter()
            .filter(|(_, m)| !m.absent && m.envs > 0)
            .map(|(&a, m)| (a, m.envs as usize))
            .collect();
        let capacities: Vec<usize> = sharing.iter().map(|&(_, envs)| envs).collect();
        let shares = share_envs(total, &capacities);
        self.next_shares = sharing
            .iter()
            .zip(shares)
            .map(|(&(a, _), share)| (a, share as u32))
            .collect();
    }

    /// The batch: one rollout of every present actor, of its share of the environments where
    /// the batch is shared, and what actors that left delivered to the round (the fallback
    /// with none present).
    pub(super) fn batch_steps(&self) -> usize {
        let shares = &self.shares;
        let steps: u64 = self
            .members
            .iter()
            .filter(|(_, m)| !m.absent)
            .map(|(a, m)| match shares.get(a) {
                Some(&share) => {
                    let len = (m.rollout_steps / u64::from(m.envs)).max(1);
                    u64::from(share) * len
                }
                None => m.rollout_steps,
            })
            .sum();
        if steps == 0 {
            self.fallback.0
        } else {
            (steps + self.departed).min(self.max.1) as usize
        }
    }

    /// A fragment of `actor` reached the round (buffered or dropped): the actor is present
    /// again.
    pub(super) fn delivered(&mut self, actor: u64) {
        if self.is_open(actor) {
            self.delivered.entry(actor).or_default();
        }
        if let Some(m) = self.members.get_mut(&actor)
            && m.absent
        {
            m.absent = false;
            self.reshare();
        }
    }

    /// The round was closed complete, or emptied (a newer embedding): a new one starts.
    fn new_round(&mut self) {
        self.delivered.clear();
        self.departed = 0;
    }

    /// Whether the round waits on an actor present that has delivered nothing to it (with
    /// none present, a round is the settings' batch and has no one to wait for).
    pub(super) fn waits_on_someone(&self) -> bool {
        self.members
            .iter()
            .any(|(a, m)| !m.absent && !self.delivered.contains_key(a))
    }

    /// The round closed at its deadline: the actors that delivered nothing to it are absent
    /// until their next fragment; their ids.
    fn close_overdue(&mut self) -> Vec<u64> {
        let mut missing = Vec::new();
        for (&actor, m) in &mut self.members {
            if !m.absent && !self.delivered.contains_key(&actor) {
                m.absent = true;
                missing.push(actor);
            }
        }
        self.new_round();
        self.reshare();
        self.round_ended();
        missing
    }

    /// A round ended: the next one is collected with the new shares (an absent actor keeps
    /// its last, which it steps until it is told another).
    fn round_ended(&mut self) {
        let mut shares = self.next_shares.clone();
        for (a, m) in &self.members {
            if let Some(&last) = self.shares.get(a)
                && m.absent
            {
                shares.insert(*a, last);
            }
        }
        self.shares = shares;
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
        r.open(1, 1000, 0);
        r.open(2, 0, 0);
        assert_eq!(
            r.batch_steps(),
            1512,
            "actor 2 did not say: the default rollout"
        );
        r.open(2, 0, 0);
        r.close(2);
        assert_eq!(r.batch_steps(), 1512, "actor 2 still has a stream");
        r.close(2);
        assert_eq!(r.batch_steps(), 1000);
        r.open(3, u64::MAX, 0);
        assert_eq!(
            r.batch_steps(),
            1000 + 512 * MAX_ROLLOUT_FACTOR as usize,
            "a rollout counts at most 16 of the run's own"
        );
        assert_eq!(r.counts(), (2, 2));
    }

    #[test]
    fn the_batch_stops_growing_at_64_of_the_runs_rollouts() {
        let mut r = Roster::new(2048, 512, Duration::ZERO);
        for actor in 0..200 {
            r.open(actor, 512 * MAX_ROLLOUT_FACTOR, 0);
        }
        assert_eq!(r.batch_steps(), 512 * MAX_BATCH_ROLLOUTS as usize);
        // a settings' batch larger than that stays the floor of the cap
        let mut r = Roster::new(1 << 20, 512, Duration::ZERO);
        for actor in 0..200 {
            r.open(actor, 512 * MAX_ROLLOUT_FACTOR, 0);
        }
        assert_eq!(r.batch_steps(), 1 << 20);
    }

    #[test]
    fn a_shared_batch_is_split_among_the_actors_present_from_round_to_round() {
        let now = Instant::now();
        let shares = |r: &Roster| r.shares().clone().into_iter().collect::<Vec<_>>();
        let mut r = Roster::new(2048, 2048, Duration::ZERO).sharing(Some(16));
        r.open(1, 16 * 128, 16);
        assert_eq!((shares(&r), r.batch_steps()), (vec![(1, 16)], 2048));
        // joining mid-round: each steps its own share at once, the others keep theirs until
        // the round ends, so every rollout counts with the share it was stepped with
        r.open(2, 16 * 128, 16);
        r.open(3, 16 * 128, 16);
        assert_eq!(shares(&r), vec![(1, 16), (2, 8), (3, 5)]);
        assert_eq!(r.batch_steps(), (16 + 8 + 5) * 128);
        assert!(r.completed(now).is_empty());
        assert_eq!(shares(&r), vec![(1, 6), (2, 5), (3, 5)]);
        assert_eq!(r.batch_steps(), 2048);
        // one that did not say its environments steps them all, on top; so does one whose
        // environments do not divide its rollout
        r.open(4, 1000, 0);
        assert_eq!(r.batch_steps(), 3048);
        r.close(4);
        r.open(4, 1000, 3);
        assert_eq!(r.batch_steps(), 3048);
        assert!(!r.shares().contains_key(&4));
        r.close(4);
        // one absent: the others take its share from the next round; it keeps its last
        r.delivered(1);
        r.delivered(2);
        assert_eq!(r.close_overdue(), vec![3]);
        assert_eq!(shares(&r), vec![(1, 8), (2, 8), (3, 5)]);
        assert_eq!(r.batch_steps(), 2048);
        // back mid-round with a rollout of its last share
        r.delivered(3);
        assert_eq!(r.batch_steps(), (8 + 8 + 5) * 128);
        assert!(r.completed(now).is_empty());
        assert_eq!(shares(&r), vec![(1, 6), (2, 5), (3, 5)]);
        // leaving mid-round: out of this round's batch at once
        r.close(1);
        assert_eq!(r.batch_steps(), 10 * 128);
        // an actor of 4 environments: the others take the rest
        r.open(5, 4 * 128, 4);
        assert!(r.completed(now).is_empty());
        assert_eq!(shares(&r), vec![(2, 6), (3, 6), (5, 4)]);
        assert_eq!(r.batch_steps(), 2048);
        // not shared: whole rollouts
        let mut r = Roster::new(2048, 2048, Duration::ZERO);
        r.open(1, 2048, 16);
        r.open(2, 2048, 16);
        assert!(r.shares().is_empty());
        assert_eq!(r.batch_steps(), 4096);
    }

    #[test]
    fn what_an_actor_that_left_delivered_counts_on_top_of_the_survivors_batch() {
        let now = Instant::now();
        let mut r = Roster::new(2048, 16 * 128, Duration::ZERO).sharing(Some(16));
        r.open(1, 16 * 128, 16);
        r.open(2, 16 * 128, 16);
        assert!(r.completed(now).is_empty());
        assert_eq!(r.batch_steps(), 2048, "8 environments each");
        r.buffered(1, 128, true, now);
        r.buffered(1, 128, false, now);
        r.buffered(2, 128, false, now);
        r.close(1);
        assert_eq!(
            r.batch_steps(),
            (8 + 2) * 128,
            "actor 2's share and actor 1's two"
        );
        // one more of actor 1, sent before it left, reaches the learner after
        assert!(r.late(1, 128));
        r.buffered(1, 128, false, now);
        assert_eq!(r.batch_steps(), (8 + 3) * 128);
        assert!(!r.late(2, 128), "actor 2 is open");
        // a late one dropped does not count
        assert!(r.late(1, 128));
        r.not_buffered(128);
        assert_eq!(r.batch_steps(), (8 + 3) * 128);
        assert!(r.completed(now).is_empty());
        assert_eq!(r.batch_steps(), 2048, "actor 2 steps all 16 now");
        // a late one that starts a round
        assert!(r.late(1, 128));
        r.buffered(1, 128, true, now);
        assert_eq!(r.batch_steps(), 2048 + 128);
        // an actor that never opened a stream (a client that only pushes) is not late
        assert!(!r.late(9, 128));
        // not shared: the same on top of whole rollouts
        let mut r = Roster::new(2048, 1024, Duration::ZERO);
        r.open(1, 1024, 0);
        r.open(2, 1024, 0);
        r.buffered(1, 100, true, now);
        r.close(1);
        assert_eq!(r.batch_steps(), 1124);
    }

    #[test]
    fn an_actor_silent_through_an_overdue_round_is_absent_until_it_delivers() {
        let mut r = Roster::new(2048, 100, Duration::ZERO);
        r.open(1, 100, 0);
        r.open(2, 100, 0);
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
