//! State and action spaces of an environment.

use serde::{Deserialize, Serialize};

/// The state space of an environment.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum StateSpace {
    /// One categorical per factor; a plain discrete space is one factor
    /// (`sizes = [n]`, the state is the index of its one-hot vector).
    Categorical {
        /// Number of categories of each factor.
        sizes: Vec<usize>,
    },
    /// A real vector of `dim` values.
    Real {
        /// Length of the vector.
        dim: usize,
    },
}

impl StateSpace {
    /// A discrete space of `n` states (one factor).
    pub fn discrete(n: usize) -> Self {
        Self::Categorical { sizes: vec![n] }
    }

    /// Values stored per state: the number of factors, or the vector length.
    pub fn stored_len(&self) -> usize {
        match self {
            Self::Categorical { sizes } => sizes.len(),
            Self::Real { dim } => *dim,
        }
    }

    /// Length of the dense feature vector of a state (one-hots concatenated, or the vector).
    pub fn feature_len(&self) -> usize {
        match self {
            Self::Categorical { sizes } => sizes.iter().sum(),
            Self::Real { dim } => *dim,
        }
    }
}

/// The action space of an environment.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum ActionSpace {
    /// `n` discrete actions.
    Discrete {
        /// Number of actions.
        n: usize,
    },
    /// A box `[low, high]^dim`.
    Continuous {
        /// Number of action components.
        dim: usize,
        /// Lower bound of each component.
        low: Vec<f32>,
        /// Upper bound of each component.
        high: Vec<f32>,
    },
}

impl ActionSpace {
    /// Values stored per action: 1 for a discrete action, `dim` for a continuous one.
    pub fn stored_len(&self) -> usize {
        match self {
            Self::Discrete { .. } => 1,
            Self::Continuous { dim, .. } => *dim,
        }
    }

    /// Number of discrete actions, if the space is discrete.
    pub fn num_discrete(&self) -> Option<usize> {
        match self {
            Self::Discrete { n } => Some(*n),
            Self::Continuous { .. } => None,
        }
    }
}
