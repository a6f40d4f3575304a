//! The twin application on the board seam: `sts_twin_core::servo` in the servo interrupt,
//! the model update and the control protocol in the background. Every board runs this.
//!
//! - [`TwinServo::tick`]: the core's [`Servo::tick`] inside the shared cell (the servo
//!   interrupt has the highest priority, so the critical section costs it nothing); a model
//!   request is parked in the shared state and the background is woken.
//! - [`TwinBackground::model_work`]: finishes the features, evaluates the twin program and
//!   prepares the synthesiser's update outside any critical section, then hands it over in
//!   a short one; the servo applies it at its due tick, so the outputs do not depend on how
//!   fast this ran (a late result, a few ticks after it arrived).
//! - [`TwinBackground::on_control_bytes`]: decodes COBS/CRC frames, carries out requests with
//!   [`handle_request`] and answers; bad frames are counted in the servo's `frame_errors`.

use sts_twin_core::bus::InputSlot;
use sts_twin_core::commands::DefaultCommandRing;
use sts_twin_core::config::{ConfigError as RecordError, PersistentConfig, MAX_CONFIG_BYTES};
use sts_twin_core::control::{handle_request, ConfigWriter, ServoAccess};
use sts_twin_core::features::{DefaultSpectralRings, FeatureConfig};
use sts_twin_core::feedforward::FeedforwardParams;
use sts_twin_core::servo::{Models, Servo, ServoConfig};
use sts_twin_core::wire::{encode_frame, ConfigSource, FrameDecoder, Request, MAX_ENCODED_FRAME};

use crate::servo::{BackgroundApp, BackgroundCtx, ServoApp, TickOutcome};
use crate::sync::SharedCell;
use crate::ConfigStore;

/// The feature rings, shared lock-free between the servo tick (writer) and the model update
/// (reader); all atomics.
pub static RINGS: DefaultSpectralRings = DefaultSpectralRings::new();

/// The recent ticks' commands, from the servo tick to the axis twin's compensator.
pub static COMMANDS: DefaultCommandRing = DefaultCommandRing::new();

/// Preparations of a model delivery outside the critical section before the last one inside
/// (a retry follows a tick that made the view out of date: one that applied an earlier
/// result, or passed this one's tick).
const DELIVERY_ATTEMPTS: usize = 8;

/// Ticks after the next one from which a late model result is applied: time to prepare it
/// outside the critical section before that tick (see `Servo::delivery_view`).
const LATE_MARGIN_TICKS: u32 = 4;

/// State shared by the two halves.
pub struct TwinShared {
    /// The core's servo pipeline (it also holds the model request waiting for the
    /// background).
    pub servo: Servo,
}

impl TwinShared {
    /// A servo with the default settings (the stored config is applied at boot by
    /// [`TwinBackground::on_boot`]).
    pub fn new() -> Self {
        let (servo, _) = Servo::new(FeatureConfig::DEFAULT, ServoConfig::default(), FeedforwardParams::default());
        Self { servo }
    }
}

impl Default for TwinShared {
    fn default() -> Self {
        Self::new()
    }
}

/// The servo-interrupt half.
#[derive(Debug, Default)]
pub struct TwinServo;

impl ServoApp for TwinServo {
    type Shared = TwinShared;

    #[inline]
    fn tick(&mut self, input: &InputSlot, shared: &SharedCell<TwinShared>) -> TickOutcome {
        shared.with(|s| {
            let (output, request_model_work) = s.servo.tick(&RINGS, &COMMANDS, input);
            TickOutcome { output, request_model_work }
        })
    }

    fn on_underrun(&mut self, shared: &SharedCell<TwinShared>) {
        shared.with(|s| {
            s.servo.underrun();
        });
    }
}

/// The background half: the twin programs, the frame decoder, where the config came from.
pub struct TwinBackground {
    models: Models,
    decoder: FrameDecoder<Request>,
    config_source: ConfigSource,
}

impl Default for TwinBackground {
    fn default() -> Self {
        Self::new()
    }
}

impl TwinBackground {
    /// No program, nothing decoded yet.
    pub const fn new() -> Self {
        Self { models: Models::new(), decoder: FrameDecoder::new(), config_source: ConfigSource::Defaults }
    }

    /// Where the boot configuration came from.
    pub fn config_source(&self) -> ConfigSource {
        self.config_source
    }
}

/// The servo inside the shared cell, as the control handler sees it.
struct SharedServo<'a>(&'a SharedCell<TwinShared>);

impl ServoAccess for SharedServo<'_> {
    fn with<R>(&mut self, f: impl FnOnce(&mut Servo) -> R) -> R {
        self.0.with(|s| f(&mut s.servo))
    }
}

/// The board's config store as the control handler's writer.
struct StoreWriter<'a>(&'a mut dyn ConfigStore);

impl ConfigWriter for StoreWriter<'_> {
    fn write_config(&mut self, record: &[u8]) -> bool {
        self.0.write(record).is_ok()
    }
}

impl BackgroundApp for TwinBackground {
    type Shared = TwinShared;

    fn on_boot(&mut self, ctx: &mut BackgroundCtx<'_, TwinShared>) {
        let mut record = [0u8; MAX_CONFIG_BYTES];
        let loaded = match ctx.config.read(&mut record) {
            Ok(len) => PersistentConfig::decode(&record[..len.min(MAX_CONFIG_BYTES)]),
            Err(crate::ConfigError::Empty) => Err(RecordError::Blank),
            // Stored but damaged, or unreadable: defaults, reported as corrupt.
            Err(_) => Err(RecordError::Crc),
        };
        self.config_source = match loaded {
            // All was validated with the record; the checks keep a failure visible anyway.
            // The same steps, in the same order, as the host's `sts_twin_core::twin::Twin::boot`.
            Ok(config) => {
                let settings = ctx.shared.with(|s| {
                    s.servo.set_params(config.params).is_ok()
                        && s.servo.set_supervisor_params(config.supervisor).is_ok()
                        && s.servo.set_feature_config(config.feature_config).is_ok()
                });
                let program = config.program.is_none_or(|program| self.models.upload(program, true).is_ok());
                if settings && program {
                    ConfigSource::Stored
                } else {
                    ConfigSource::DefaultsAfterCorrupt
                }
            }
            Err(RecordError::Blank) => ConfigSource::Defaults,
            Err(_) => ConfigSource::DefaultsAfterCorrupt,
        };
        if self.config_source == ConfigSource::DefaultsAfterCorrupt {
            ctx.shared.with(|s| s.servo.update_counters(|c| c.config_store_errors += 1));
        }
    }

    fn model_work(&mut self, ctx: &mut BackgroundCtx<'_, TwinShared>) {
        let Some((request, path)) = ctx.shared.with(|s| s.servo.take_request().map(|r| (r, *s.servo.analogue_path())))
        else {
            return;
        };
        let result = self.models.compute(&RINGS, &COMMANDS, &request, &path);
        // The delivery in short critical sections: the verdict and a view of the servo, the
        // synthesiser's update prepared from the view while the tick runs, then handed over.
        // A tick between them may apply an earlier result or pass the result's tick, and the
        // view is then out of date: another view, and at last all in one critical section.
        let (judgement, mut view) = ctx.shared.with(|s| {
            let judgement = s.servo.judge(&result);
            (judgement, s.servo.delivery_view(&result, &judgement, LATE_MARGIN_TICKS))
        });
        for _ in 0..DELIVERY_ATTEMPTS {
            let prepared = Servo::prepare_delivery(&view, &result, &judgement);
            let installed = ctx.shared.with(|s| {
                let installed = s.servo.install_delivery(&prepared, &result, &judgement);
                if !installed {
                    view = s.servo.delivery_view(&result, &judgement, LATE_MARGIN_TICKS);
                }
                installed
            });
            if installed {
                return;
            }
        }
        ctx.shared.with(|s| {
            let view = s.servo.delivery_view(&result, &judgement, LATE_MARGIN_TICKS);
            let prepared = Servo::prepare_delivery(&view, &result, &judgement);
            s.servo.install_delivery(&prepared, &result, &judgement)
        });
    }

    fn on_control_bytes(&mut self, rx: &[u8], ctx: &mut BackgroundCtx<'_, TwinShared>) {
        for &byte in rx {
            let Some(frame) = self.decoder.push(byte) else {
                continue;
            };
            let envelope = match frame {
                Ok(envelope) => envelope,
                Err(_) => {
                    ctx.shared.with(|s| s.servo.update_counters(|c| c.frame_errors += 1));
                    continue;
                }
            };
            let response = handle_request(
                envelope.body,
                &mut self.models,
                &mut SharedServo(ctx.shared),
                &mut StoreWriter(&mut *ctx.config),
                self.config_source,
            );
            let mut out = [0u8; MAX_ENCODED_FRAME];
            if let Ok(len) = encode_frame(envelope.seq, &response, &mut out) {
                let mut sent = 0;
                // The link's transmit queue holds several frames; a full queue drops the rest
                // and the host times out and retries.
                while sent < len {
                    let n = ctx.link.write(&out[sent..len]);
                    if n == 0 {
                        break;
                    }
                    sent += n;
                }
            }
        }
    }
}
