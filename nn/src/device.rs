//! The burn devices behind a [`DeviceKind`].

use burn::tensor::Device;

pub use jsae_proto::settings::DeviceKind;

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
