//! Which burn device the models run on, chosen at run time (the burn side is in
//! `jsae_nn`).

use serde::{Deserialize, Serialize};

/// The CPU backend to use.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum DeviceKind {
    /// burn's pure-Rust `flex` backend (the faster one here).
    #[default]
    Flex,
    /// burn's `ndarray` backend.
    Ndarray,
}

impl DeviceKind {
    /// The name as written on the command line.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Flex => "flex",
            Self::Ndarray => "ndarray",
        }
    }
}
