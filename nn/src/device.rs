//! Which burn device the models run on, chosen at run time, and the burn devices behind it.

use burn::tensor::Device;
use serde::{Deserialize, Serialize};

/// The CPU backend to use.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum DeviceKind {
    /// burn's pure-Rust `flex` backend (the faster one here).
    #[default]
    Flex,
    /// burn's `ndarray` backend.
    Ndarray,
}

impl DeviceKind {
    /// Every kind, in the order the command line lists them.
    pub const ALL: [Self; 2] = [Self::Flex, Self::Ndarray];

    /// The name as written on the command line and in settings files.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Flex => "flex",
            Self::Ndarray => "ndarray",
        }
    }
}

impl std::str::FromStr for DeviceKind {
    type Err = String;

    fn from_str(name: &str) -> Result<Self, String> {
        Self::ALL
            .into_iter()
            .find(|kind| kind.as_str() == name)
            .ok_or_else(|| format!("unknown device {name:?}: flex or ndarray"))
    }
}

/// The burn devices of a [`DeviceKind`].
pub trait BurnDevice {
    /// The inference device.
    fn device(self) -> Device;
    /// The training device (the inference device with autodiff).
    fn train_device(self) -> Device;
}

impl BurnDevice for DeviceKind {
    fn device(self) -> Device {
        match self {
            Self::Flex => Device::flex(),
            #[allow(deprecated)] // still supported and measured against flex
            Self::Ndarray => Device::ndarray(),
        }
    }

    fn train_device(self) -> Device {
        self.device().autodiff()
    }
}
