//! Flat storage of many states or actions: one allocation per batch, none per step.

use serde::{Deserialize, Serialize};

/// States of one space, stored row after row.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum StateBatch {
    /// Category indices, `factors` per state: `[len, factors]`.
    Categorical {
        /// Number of factors per state.
        factors: usize,
        /// Indices, row-major.
        data: Vec<u32>,
    },
    /// Real vectors: `[len, dim]`.
    Real {
        /// Length of each vector.
        dim: usize,
        /// Values, row-major.
        data: Vec<f32>,
    },
}

impl StateBatch {
    /// An empty batch for states of `space`.
    pub fn empty(space: &crate::StateSpace) -> Self {
        match space {
            crate::StateSpace::Categorical { sizes } => Self::Categorical {
                factors: sizes.len(),
                data: Vec::new(),
            },
            crate::StateSpace::Real { dim } => Self::Real {
                dim: *dim,
                data: Vec::new(),
            },
        }
    }

    /// Number of states held.
    pub fn len(&self) -> usize {
        match self {
            Self::Categorical { factors, data } => data.len() / (*factors).max(1),
            Self::Real { dim, data } => data.len() / (*dim).max(1),
        }
    }

    /// Whether no state is held.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Removes every state, keeping the allocation.
    pub fn clear(&mut self) {
        match self {
            Self::Categorical { data, .. } => data.clear(),
            Self::Real { data, .. } => data.clear(),
        }
    }

    /// Appends every state of `other` (same kind and width).
    pub fn extend_from(&mut self, other: &StateBatch) {
        match (self, other) {
            (Self::Categorical { data, .. }, Self::Categorical { data: o, .. }) => {
                data.extend_from_slice(o)
            }
            (Self::Real { data, .. }, Self::Real { data: o, .. }) => data.extend_from_slice(o),
            _ => {}
        }
    }

    /// Appends the `i`-th state of `other`.
    pub fn push_row_of(&mut self, other: &StateBatch, i: usize) {
        match (self, other) {
            (Self::Categorical { data, factors }, Self::Categorical { data: o, .. }) => {
                data.extend_from_slice(&o[i * *factors..(i + 1) * *factors])
            }
            (Self::Real { data, dim }, Self::Real { data: o, .. }) => {
                data.extend_from_slice(&o[i * *dim..(i + 1) * *dim])
            }
            _ => {}
        }
    }

    /// Dense features of every state: one-hots concatenated per factor, or the vectors.
    /// `[len, space.feature_len()]`, row-major.
    pub fn features(&self, space: &crate::StateSpace) -> Vec<f32> {
        let mut out = Vec::new();
        self.write_features(space, &mut out);
        out
    }

    /// Like [`Self::features`], writing into `out` (cleared first).
    pub fn write_features(&self, space: &crate::StateSpace, out: &mut Vec<f32>) {
        out.clear();
        match (self, space) {
            (Self::Categorical { factors, data }, crate::StateSpace::Categorical { sizes }) => {
                let width: usize = sizes.iter().sum();
                let rows = data.len() / (*factors).max(1);
                out.resize(rows * width, 0.0);
                for (r, row) in data.chunks_exact((*factors).max(1)).enumerate() {
                    let mut offset = r * width;
                    for (&idx, &size) in row.iter().zip(sizes) {
                        out[offset + idx as usize] = 1.0;
                        offset += size;
                    }
                }
            }
            (Self::Real { data, .. }, _) => out.extend_from_slice(data),
            _ => {}
        }
    }
}

/// Actions, stored row after row.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum ActionBatch {
    /// Discrete action indices: `[len]`.
    Discrete(Vec<u32>),
    /// Continuous actions: `[len, dim]`.
    Continuous {
        /// Components per action.
        dim: usize,
        /// Values, row-major.
        data: Vec<f32>,
    },
}

impl ActionBatch {
    /// An empty batch for actions of `space`.
    pub fn empty(space: &crate::ActionSpace) -> Self {
        match space {
            crate::ActionSpace::Discrete { .. } => Self::Discrete(Vec::new()),
            crate::ActionSpace::Continuous { dim, .. } => Self::Continuous {
                dim: *dim,
                data: Vec::new(),
            },
        }
    }

    /// Number of actions held.
    pub fn len(&self) -> usize {
        match self {
            Self::Discrete(v) => v.len(),
            Self::Continuous { dim, data } => data.len() / (*dim).max(1),
        }
    }

    /// Whether no action is held.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Removes every action, keeping the allocation.
    pub fn clear(&mut self) {
        match self {
            Self::Discrete(v) => v.clear(),
            Self::Continuous { data, .. } => data.clear(),
        }
    }

    /// Appends every action of `other` (same kind).
    pub fn extend_from(&mut self, other: &ActionBatch) {
        match (self, other) {
            (Self::Discrete(v), Self::Discrete(o)) => v.extend_from_slice(o),
            (Self::Continuous { data, .. }, Self::Continuous { data: o, .. }) => {
                data.extend_from_slice(o)
            }
            _ => {}
        }
    }

    /// Appends the `i`-th action of `other`.
    pub fn push_row_of(&mut self, other: &ActionBatch, i: usize) {
        match (self, other) {
            (Self::Discrete(v), Self::Discrete(o)) => v.push(o[i]),
            (Self::Continuous { data, dim }, Self::Continuous { data: o, .. }) => {
                data.extend_from_slice(&o[i * *dim..(i + 1) * *dim])
            }
            _ => {}
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::StateSpace;

    #[test]
    fn factored_features_are_concatenated_one_hots() {
        let space = StateSpace::Categorical { sizes: vec![3, 2] };
        let batch = StateBatch::Categorical {
            factors: 2,
            data: vec![2, 0, 0, 1],
        };
        assert_eq!(batch.len(), 2);
        assert_eq!(
            batch.features(&space),
            vec![0., 0., 1., 1., 0., /* row 2 */ 1., 0., 0., 0., 1.]
        );
    }
}
