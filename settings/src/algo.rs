//! The algorithms `--algo` names, and the representation each one's policy sees and acts
//! through.

use serde::{Deserialize, Serialize};

/// The algorithms `jsae train --algo` names.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Algo {
    /// PPO on jointly-learned state and action embeddings (the method).
    Jsae,
    /// PPO on raw states and actions (categorical for discrete actions).
    Ppo,
    /// PPO on auto-encoder embeddings of states and actions (baseline).
    Ae,
    /// PPO on raw states acting through Chandak et al.'s action representations (baseline).
    Ra,
}

impl Algo {
    /// The name as written on the command line.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Jsae => "jsae",
            Self::Ppo => "ppo",
            Self::Ae => "ae",
            Self::Ra => "ra",
        }
    }

    /// The representation the algorithm's policy sees and acts through.
    pub fn representation(self) -> Representation {
        match self {
            Self::Jsae => Representation::Jsae,
            Self::Ppo => Representation::Raw,
            Self::Ae => Representation::AutoEncoder,
            Self::Ra => Representation::ActionRepresentation,
        }
    }
}

/// What sits between the environment and PPO: raw states and actions, or a representation
/// model the embedder trains. Every component asks it its questions (does it embed states?
/// actions? is there an embedder to follow?) instead of testing algorithm names.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Representation {
    /// Raw states in, raw actions out (plain PPO).
    Raw,
    /// Jointly-learned state and action embeddings: phi, g, T, f (the method).
    Jsae,
    /// Auto-encoder embeddings of states and of actions (baseline).
    AutoEncoder,
    /// Chandak et al.'s action representations, raw states (baseline).
    ActionRepresentation,
}

impl Representation {
    /// An embedder service trains it from the actors' transitions (and must be followed).
    pub fn needs_embedder(self) -> bool {
        !matches!(self, Self::Raw)
    }

    /// The policy's input is `phi(s)` rather than the raw state's features.
    pub fn embeds_states(self) -> bool {
        matches!(self, Self::Jsae | Self::AutoEncoder)
    }

    /// The policy acts in an action-embedding space whose points f decodes to actions.
    pub fn decodes_actions(self) -> bool {
        !matches!(self, Self::Raw)
    }
}
