//! The run's env-step count, built from what the actors' fragments claim but never more than
//! they deliver.
//!
//! Each fragment claims its actor's total env steps so far (`actor_env_steps`), counted within
//! one incarnation of the actor process (`actor_incarnation`, drawn at random when it
//! starts). The learner keeps one account per (actor id, incarnation): the highest claim, the
//! steps credited, and the steps its fragments held. A fragment raises its account's credit
//! towards its claim, but an account is never credited more than its fragments' steps plus
//! what it drew from a run-wide allowance for random play (the steps an actor plays before it
//! sends fragments: the pre-training budget and one rollout of all environments of every
//! actor, `TrainConfig::random_play_allowance`; 0 for a run without pre-training). What an account
//! drew goes back to the allowance as its fragments catch up with its credit, so a round of
//! fragments that all claim the round's total is counted whole and only the random steps
//! stay drawn.
//!
//! So a forged claim of 10^12 steps credits its fragment's length (and at most the allowance
//! once), never the run's budget; a claim that goes back within an incarnation is refused; a
//! restarted actor reusing its id has an account of its own, counted from zero. The run's env
//! steps are the steps of earlier processes (`--resume` of a run whose checkpoint predates
//! the accounts) plus every account's credit.

use std::collections::HashMap;

/// A claim that went back within one incarnation.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error(
    "actor {actor_id} (incarnation {incarnation:016x}) claims {claimed} env steps after \
     claiming {before}: its count cannot go back"
)]
pub struct ClaimWentBack {
    /// The actor.
    pub actor_id: u64,
    /// Its incarnation.
    pub incarnation: u64,
    /// The claim refused.
    pub claimed: u64,
    /// The highest claim before it.
    pub before: u64,
}

/// One actor incarnation's account.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Account {
    /// The highest `actor_env_steps` claimed.
    pub claimed: u64,
    /// Env steps credited to the run.
    pub credited: u64,
    /// Steps its fragments held (and steps vouched for by a trusted caller).
    pub delivered: u64,
}

impl Account {
    /// What this account holds of the random-play allowance.
    fn drawn(&self) -> u64 {
        self.credited.saturating_sub(self.delivered)
    }
}

/// Every account of a run and the allowance they share.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct StepCredits {
    /// Env steps of earlier processes not kept in accounts.
    before: u64,
    /// The run's random-play allowance.
    allowance: u64,
    accounts: HashMap<(u64, u64), Account>,
}

impl StepCredits {
    /// No account yet; `allowance` random-play steps to share.
    pub fn new(allowance: u64) -> Self {
        Self {
            allowance,
            ..Self::default()
        }
    }

    /// The run's env steps: the earlier processes' and every account's credit.
    pub fn total(&self) -> u64 {
        self.before + self.accounts.values().map(|a| a.credited).sum::<u64>()
    }

    /// Counts on from `steps` taken by earlier processes.
    pub fn count_from(&mut self, steps: u64) {
        self.before = steps;
    }

    /// What is left of the random-play allowance.
    pub fn allowance_left(&self) -> u64 {
        let drawn: u64 = self.accounts.values().map(Account::drawn).sum();
        self.allowance.saturating_sub(drawn)
    }

    /// Credits a fragment of `len` steps whose actor claims `claimed` env steps in
    /// `incarnation`; returns the steps credited.
    pub fn credit(
        &mut self,
        actor_id: u64,
        incarnation: u64,
        claimed: u64,
        len: u64,
    ) -> Result<u64, ClaimWentBack> {
        let left = self.allowance_left();
        let account = self.accounts.entry((actor_id, incarnation)).or_default();
        if claimed < account.claimed {
            return Err(ClaimWentBack {
                actor_id,
                incarnation,
                claimed,
                before: account.claimed,
            });
        }
        account.claimed = claimed;
        account.delivered = account.delivered.saturating_add(len);
        let ceiling = account
            .delivered
            .saturating_add(account.drawn())
            .saturating_add(left);
        let target = claimed.min(ceiling);
        let credit = target.saturating_sub(account.credited);
        account.credited += credit;
        Ok(credit)
    }

    /// Records steps a trusted caller vouches for (the one-process driver, which steps its
    /// actors itself): the account's claim, credit and delivered steps become at least
    /// `steps`.
    pub fn trust(&mut self, actor_id: u64, incarnation: u64, steps: u64) {
        let account = self.accounts.entry((actor_id, incarnation)).or_default();
        account.claimed = account.claimed.max(steps);
        account.delivered = account.delivered.max(steps);
        account.credited = account.credited.max(steps);
    }

    /// Every account, for a checkpoint.
    pub fn accounts(&self) -> impl Iterator<Item = ((u64, u64), Account)> + '_ {
        self.accounts.iter().map(|(&k, &a)| (k, a))
    }

    /// The earlier processes' steps, for a checkpoint.
    pub fn before(&self) -> u64 {
        self.before
    }

    /// Puts back a checkpoint's accounts and earlier steps (the allowance stays this run's).
    pub fn restore(
        &mut self,
        before: u64,
        accounts: impl IntoIterator<Item = ((u64, u64), Account)>,
    ) {
        self.before = before;
        self.accounts = accounts.into_iter().collect();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_forged_claim_credits_only_its_fragments_length() {
        let mut c = StepCredits::new(0);
        assert_eq!(c.credit(7, 1, 1_000_000_000_000, 64), Ok(64));
        assert_eq!(c.total(), 64);
        // going on claiming the same: each fragment its length
        assert_eq!(c.credit(7, 1, 1_000_000_000_000, 64), Ok(64));
        assert_eq!(c.total(), 128);
    }

    #[test]
    fn a_round_of_fragments_claiming_the_rounds_total_is_counted_whole() {
        // 4 environments x 32 steps; each fragment claims the actor's 128
        let mut c = StepCredits::new(0);
        for _ in 0..4 {
            c.credit(1, 5, 128, 32).expect("credited");
        }
        assert_eq!(c.total(), 128);
        for _ in 0..4 {
            c.credit(1, 5, 256, 32).expect("credited");
        }
        assert_eq!(c.total(), 256);
    }

    #[test]
    fn random_play_before_the_first_fragment_draws_on_the_allowance_and_only_it() {
        // 1000 random steps, then a round of 4 x 32
        let mut c = StepCredits::new(1_200);
        c.credit(1, 5, 1_128, 32).expect("credited");
        assert_eq!(
            c.total(),
            1_128,
            "the claim in full while the allowance lasts"
        );
        assert_eq!(c.allowance_left(), 1_200 - 1_096);
        for _ in 0..3 {
            c.credit(1, 5, 1_128, 32).expect("credited");
        }
        assert_eq!(c.total(), 1_128);
        assert_eq!(c.allowance_left(), 200, "the round's own steps went back");
        // a second actor's random play finds what is left
        c.credit(2, 9, 1_032, 32).expect("credited");
        assert_eq!(c.total(), 1_128 + 32 + 200);
        assert_eq!(c.allowance_left(), 0);
    }

    #[test]
    fn a_claim_going_back_is_refused_and_a_new_incarnation_counts_from_zero() {
        let mut c = StepCredits::new(0);
        c.credit(0, 1, 64, 64).expect("credited");
        let back = c.credit(0, 1, 32, 32).expect_err("went back");
        assert_eq!((back.claimed, back.before), (32, 64));
        assert_eq!(c.total(), 64);
        // the actor restarted with the same id: its own account
        assert_eq!(c.credit(0, 2, 64, 64), Ok(64));
        assert_eq!(c.total(), 128);
    }

    #[test]
    fn trusted_steps_are_credited_and_the_fragments_that_follow_add_nothing_twice() {
        let mut c = StepCredits::new(0);
        c.trust(0, 3, 512);
        assert_eq!(c.total(), 512);
        assert_eq!(c.credit(0, 3, 512, 128), Ok(0));
        c.trust(0, 3, 640);
        assert_eq!(c.credit(0, 3, 640, 128), Ok(0));
        assert_eq!(c.total(), 640);
        c.count_from(1_000);
        assert_eq!(c.total(), 1_640);
    }
}
