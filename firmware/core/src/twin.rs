//! The whole twin in one context: what the host runs to simulate the firmware bit for bit.

use crate::bus::{InputSlot, OutputSlot};
use crate::commands::DefaultCommandRing;
use crate::config::{ConfigError, PersistentConfig};
use crate::control::{handle_request, ConfigWriter};
use crate::features::{DefaultSpectralRings, FeatureConfig};
use crate::feedforward::FeedforwardParams;
use crate::servo::{Models, Servo, ServoConfig};
use crate::wire::{ConfigSource, Request, Response};

/// The firmware's processing in one struct: servo tick, model update and control requests,
/// run synchronously. Model results take effect at the same ticks as on the target, so a
/// `Twin` fed the same inputs writes the same DAC codes as the firmware.
pub struct Twin {
    servo: Servo,
    models: Models,
    rings: DefaultSpectralRings,
    commands: DefaultCommandRing,
    config_source: ConfigSource,
    store: MemoryStore,
}

/// An in-memory config store.
#[derive(Clone, Debug, Default)]
pub struct MemoryStore {
    /// The last record written.
    pub record: heapless::Vec<u8, { crate::config::MAX_CONFIG_BYTES }>,
}

impl ConfigWriter for MemoryStore {
    fn write_config(&mut self, record: &[u8]) -> bool {
        self.record.clear();
        self.record.extend_from_slice(record).is_ok()
    }
}

impl Twin {
    /// A twin booted like the firmware: the config comes from `stored` (a config record as
    /// the store holds it, or empty) and falls back to defaults when it is not valid.
    pub fn boot(feature_config: FeatureConfig, servo_config: ServoConfig, stored: &[u8]) -> Self {
        let (config, config_source) = match PersistentConfig::decode(stored) {
            Ok(config) => (Some(config), ConfigSource::Stored),
            Err(ConfigError::Blank) => (None, ConfigSource::Defaults),
            Err(_) => (None, ConfigSource::DefaultsAfterCorrupt),
        };
        let params = config.as_ref().map_or_else(FeedforwardParams::default, |c| c.params);
        let (mut servo, _) = Servo::new(feature_config, servo_config, params);
        let mut models = Models::new();
        if let Some(config) = config {
            // The same steps, in the same order, as the firmware's boot
            // (`sts_twin_board::twin::TwinBackground::on_boot`). Validated with the record.
            let _ = servo.set_supervisor_params(config.supervisor);
            let _ = servo.set_feature_config(config.feature_config);
            if let Some(program) = config.program {
                let _ = models.upload(program, true);
            }
        }
        let mut store = MemoryStore::default();
        let _ = store.record.extend_from_slice(stored);
        Self {
            servo,
            models,
            rings: DefaultSpectralRings::new(),
            commands: DefaultCommandRing::new(),
            config_source,
            store,
        }
    }

    /// One servo tick, with the model update done at once when one is requested; `None`
    /// is a tick period whose input did not arrive (see [`Servo::underrun`]).
    pub fn tick(&mut self, input: Option<&InputSlot>) -> OutputSlot {
        let Some(input) = input else {
            return self.servo.underrun();
        };
        let (output, requested) = self.servo.tick(&self.rings, &self.commands, input);
        if let Some(request) = self.servo.take_request().filter(|_| requested) {
            let path = *self.servo.analogue_path();
            let result = self.models.compute(&self.rings, &self.commands, &request, &path);
            self.servo.deliver(result);
        }
        output
    }

    /// Carries out a control request.
    pub fn handle(&mut self, request: Request) -> Response {
        handle_request(request, &mut self.models, &mut self.servo, &mut self.store, self.config_source)
    }

    /// The servo side, for inspection.
    pub fn servo(&self) -> &Servo {
        &self.servo
    }

    /// The config store's content.
    pub fn stored_config(&self) -> &[u8] {
        &self.store.record
    }
}
