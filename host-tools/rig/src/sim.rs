//! The co-processor simulated on the host: the firmware's core ([`Twin`]) run synchronously,
//! bit-identical to the firmware on the same inputs.

use sts_twin_core::bus::{InputSlot, OutputSlot};
use sts_twin_core::features::FeatureConfig;
use sts_twin_core::servo::ServoConfig;
use sts_twin_core::twin::Twin;
use sts_twin_core::wire::{Request, Response};

use super::{Coprocessor, RigError};

/// The host simulation of the co-processor.
pub struct SimCoprocessor {
    twin: Box<Twin>,
}

impl SimCoprocessor {
    /// Boots like the firmware with the default settings and `stored_config` in its store.
    pub fn boot(stored_config: &[u8]) -> Self {
        Self { twin: Box::new(Twin::boot(FeatureConfig::DEFAULT, ServoConfig::default(), stored_config)) }
    }

    /// The simulated core.
    pub fn twin(&self) -> &Twin {
        &self.twin
    }
}

impl Coprocessor for SimCoprocessor {
    fn tick(&mut self, input: &InputSlot) -> Result<OutputSlot, RigError> {
        Ok(self.twin.tick(Some(input)))
    }

    fn request(&mut self, request: Request) -> Result<Response, RigError> {
        Ok(self.twin.handle(request))
    }

    fn kind(&self) -> &'static str {
        "sim"
    }
}
