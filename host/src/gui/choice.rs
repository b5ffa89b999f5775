//! Which device the GUI talks to, and opening it: the built-in simulator or a device over
//! the wire protocol (the Phantom in this process is opened by
//! `crate::phantom::device::gui_device`, which falls back to the simulator).

use std::sync::Arc;

use crate::device::{
    BrushChoice, Device, DeviceError, Endpoint, HandInput, LinkDevice, LinkOptions, ModelKind,
    SimClock, SimDevice,
};

/// Which device the GUI talks to.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub enum DeviceChoice {
    /// The built-in simulator.
    #[default]
    Sim,
    /// A device over the wire protocol (`tcp:HOST:PORT`, `serial:PATH`).
    Link(Endpoint),
}

impl std::str::FromStr for DeviceChoice {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        if s == "sim" {
            Ok(DeviceChoice::Sim)
        } else {
            s.parse().map(DeviceChoice::Link)
        }
    }
}

impl std::fmt::Display for DeviceChoice {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            DeviceChoice::Sim => f.write_str("sim"),
            DeviceChoice::Link(e) => e.fmt(f),
        }
    }
}

/// The device for `choice` with the brush `preset`, not yet connected; `wake` is called
/// from its threads when frames arrive. The built-in simulator runs `model`; a device on a
/// link runs its own (a pen: Liang's).
pub fn make_device(
    choice: &DeviceChoice,
    preset: &str,
    model: ModelKind,
    wake: Option<Arc<dyn Fn() + Send + Sync>>,
) -> Result<Box<dyn Device>, DeviceError> {
    let length = BrushChoice::parse(preset)
        .map(|b| b.params.length_mm as f64)
        .unwrap_or(50.0);
    let hand = start_hand(length);
    Ok(match choice {
        DeviceChoice::Sim => {
            let mut d = SimDevice::with_model(SimClock::RealTime, model, preset, hand)?;
            if let Some(w) = wake {
                d.on_frames(w);
            }
            Box::new(d)
        }
        DeviceChoice::Link(e) => {
            let mut opts = LinkOptions::new(e.clone(), hand);
            opts.preset = preset.to_string();
            let mut d = LinkDevice::new(opts)?;
            if let Some(w) = wake {
                d.on_frames(w);
            }
            Box::new(d)
        }
    })
}

/// The hand's start: above the paper's centre, the brush hanging straight down.
pub fn start_hand(length_mm: f64) -> HandInput {
    HandInput {
        x: 0.0,
        y: 0.0,
        z: length_mm + 6.0,
        tilt_x_deg: 0.0,
        tilt_y_deg: 0.0,
    }
}
