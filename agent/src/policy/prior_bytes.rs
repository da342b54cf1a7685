//! The count prior beside the policy ([`PolicyPrior`]) and how the two travel as one
//! snapshot's or checkpoint's bytes.

use std::sync::Arc;

use jsae_nn::RecordError;
use jsae_settings::PpoConfig;

use super::{Policy, PolicyHead};
use crate::prior::{CountPrior, frame, unframe};

/// The prior a categorical policy's logits add (`ppo.recommender.logged_prior`), held beside the policy
/// and passed to [`Policy::act`]. With the setting on, a policy's bytes are [`frame`]d: the
/// weight record, then the counts once they are counted; with it off, the record alone.
#[derive(Debug, Clone, Default)]
pub struct PolicyPrior {
    framed: bool,
    counts: Option<Arc<CountPrior>>,
}

impl PolicyPrior {
    /// No counts yet; framed bytes where the settings ask for a prior.
    pub fn new(config: &PpoConfig) -> Self {
        Self {
            framed: config.recommender.logged_prior,
            counts: None,
        }
    }

    /// Whether the settings ask for a prior (`ppo.recommender.logged_prior`).
    pub fn in_use(&self) -> bool {
        self.framed
    }

    /// The counts, once they are counted (or read with the weights).
    pub fn get(&self) -> Option<&CountPrior> {
        self.counts.as_deref()
    }

    /// The counts, shared (for a host copy of the policy).
    pub fn shared(&self) -> Option<Arc<CountPrior>> {
        self.counts.clone()
    }

    /// Sets the counts for `policy`.
    ///
    /// # Panics
    /// When the settings ask for no prior, or it is not over `policy`'s actions.
    pub fn set(&mut self, prior: CountPrior, policy: &Policy) {
        assert!(self.framed, "ppo.recommender.logged_prior is off");
        assert_eq!(
            Some(prior.actions()),
            match policy.head() {
                PolicyHead::Categorical { n } => Some(n),
                PolicyHead::Gaussian { .. } => None,
            }
        );
        self.counts = Some(Arc::new(prior));
    }

    /// `policy`'s weights as bytes, framed with the counts where the settings ask.
    pub fn encode(&self, policy: &Policy) -> Result<Vec<u8>, RecordError> {
        let record = policy.record_bytes()?;
        Ok(if self.framed {
            frame(&record, self.get())
        } else {
            record
        })
    }

    /// Loads [`Self::encode`]'s bytes into `policy` and the counts they carry into `self`
    /// (counts already held stay when the bytes carry none); nothing changes on an error.
    pub fn decode(&mut self, policy: &mut Policy, bytes: &[u8]) -> Result<(), RecordError> {
        let (record, counts) = if self.framed {
            unframe(bytes).map_err(|e| RecordError(e.to_string()))?
        } else {
            (bytes, &[][..])
        };
        let counts = match (counts.is_empty(), policy.head()) {
            (true, _) => None,
            (false, PolicyHead::Categorical { n }) => Some(Arc::new(
                CountPrior::from_bytes(counts, policy.input_dim(), n)
                    .map_err(|e| RecordError(e.to_string()))?,
            )),
            (false, PolicyHead::Gaussian { .. }) => {
                return Err(RecordError("a count prior for a Gaussian policy".into()));
            }
        };
        policy.load_record(record)?;
        if counts.is_some() {
            self.counts = counts;
        }
        Ok(())
    }
}
