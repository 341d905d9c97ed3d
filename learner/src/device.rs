//! Where the learner computes: [`LearnerDevice`], the `[learner] device` setting and the
//! `--device` option, and the burn device it stands for.
//!
//! `cpu` is burn's pure-Rust CPU backend (flex), the default. `wgpu` is the first GPU that
//! wgpu finds (Vulkan, Metal or DX12; `CUBECL_WGPU_DEFAULT_DEVICE` picks another), in a
//! build with the `wgpu` feature. Checkpoints hold plain values, so a run checkpointed on one
//! device resumes on the other.

use std::fmt;
use std::str::FromStr;

use burn::tensor::Device;
use serde::{Deserialize, Serialize};

/// The learner's device.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum LearnerDevice {
    /// burn's CPU backend (flex), on every core.
    #[default]
    Cpu,
    /// The default wgpu adapter (a GPU, or a software Vulkan driver such as lavapipe).
    Wgpu,
}

/// The device is not available in this build or on this machine.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum DeviceError {
    /// The build has no wgpu backend.
    #[error("device `wgpu`: this build has no wgpu backend (build with `--features wgpu`)")]
    NotBuilt,
    /// No adapter works (no driver, or the driver failed).
    #[error("device `wgpu`: no usable adapter ({0}); a GPU driver, or Mesa's lavapipe (Debian: mesa-vulkan-drivers), provides one")]
    NoAdapter(String),
}

impl LearnerDevice {
    /// Every device, in the order of the `--device` help.
    pub const ALL: [LearnerDevice; 2] = [LearnerDevice::Cpu, LearnerDevice::Wgpu];

    /// The name in configurations and options.
    pub fn name(self) -> &'static str {
        match self {
            LearnerDevice::Cpu => "cpu",
            LearnerDevice::Wgpu => "wgpu",
        }
    }

    /// Whether this build can run on it.
    pub fn is_built(self) -> bool {
        match self {
            LearnerDevice::Cpu => true,
            LearnerDevice::Wgpu => cfg!(feature = "wgpu"),
        }
    }

    /// The burn device, checked to work: a small computation runs on it and reads back. The
    /// CPU always works; wgpu fails with [`DeviceError`] when it is not built or no adapter
    /// comes up.
    pub fn open(self) -> Result<Device, DeviceError> {
        match self {
            LearnerDevice::Cpu => Ok(Device::flex()),
            LearnerDevice::Wgpu => open_wgpu(),
        }
    }
}

#[cfg(feature = "wgpu")]
fn open_wgpu() -> Result<Device, DeviceError> {
    use burn::tensor::{DeviceKind, Tensor};
    // wgpu panics when no adapter comes up; the learner reports it as an error instead.
    let probe = std::panic::catch_unwind(|| {
        let device = Device::wgpu(DeviceKind::DefaultDevice);
        let t = Tensor::<1>::from_floats([1.0f32, 2.0], &device);
        let back: Vec<f32> = (t.clone() + t)
            .into_data()
            .try_to_vec::<f32>()
            .map_err(|e| format!("{e:?}"))?;
        if back != [2.0, 4.0] {
            return Err(format!("1 + 1 gave {back:?}"));
        }
        Ok(device)
    });
    match probe {
        Ok(Ok(device)) => Ok(device),
        Ok(Err(why)) => Err(DeviceError::NoAdapter(why)),
        Err(panic) => Err(DeviceError::NoAdapter(
            panic
                .downcast_ref::<String>()
                .cloned()
                .or_else(|| panic.downcast_ref::<&str>().map(|s| s.to_string()))
                .unwrap_or_else(|| "it panicked".into()),
        )),
    }
}

#[cfg(not(feature = "wgpu"))]
fn open_wgpu() -> Result<Device, DeviceError> {
    Err(DeviceError::NotBuilt)
}

impl fmt::Display for LearnerDevice {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for LearnerDevice {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::ALL
            .into_iter()
            .find(|d| d.name() == s)
            .ok_or_else(|| format!("unknown device `{s}` (cpu or wgpu)"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_and_the_cpu_always_opens() {
        for d in LearnerDevice::ALL {
            assert_eq!(d.name().parse::<LearnerDevice>(), Ok(d));
        }
        assert_eq!(
            "cuda".parse::<LearnerDevice>(),
            Err("unknown device `cuda` (cpu or wgpu)".into())
        );
        assert!(LearnerDevice::Cpu.open().is_ok());
        if !LearnerDevice::Wgpu.is_built() {
            assert_eq!(LearnerDevice::Wgpu.open().err(), Some(DeviceError::NotBuilt));
        }
    }
}
