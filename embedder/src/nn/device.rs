//! Which burn device the models run on, chosen at run time.

use burn::tensor::Device;
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
    /// The inference device.
    pub fn device(self) -> Device {
        match self {
            Self::Flex => Device::flex(),
            #[allow(deprecated)] // still supported and measured against flex
            Self::Ndarray => Device::ndarray(),
        }
    }

    /// The training device (the inference device with autodiff).
    pub fn train_device(self) -> Device {
        self.device().autodiff()
    }

    /// The name as written on the command line.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Flex => "flex",
            Self::Ndarray => "ndarray",
        }
    }
}
