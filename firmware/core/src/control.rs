//! Carrying out control requests, shared by the firmware and the host simulation.

use crate::config::{PersistentConfig, MAX_CONFIG_BYTES};
use crate::servo::{Models, Servo};
use crate::wire::{ConfigSource, Rejection, Request, Response, Status};

/// Access to the [`Servo`], which in the firmware belongs to the servo interrupt: `with`
/// runs `f` in a short critical section there, and directly on the host.
pub trait ServoAccess {
    /// Runs `f` on the servo.
    fn with<R>(&mut self, f: impl FnOnce(&mut Servo) -> R) -> R;
}

impl ServoAccess for Servo {
    fn with<R>(&mut self, f: impl FnOnce(&mut Servo) -> R) -> R {
        f(self)
    }
}

/// Where [`Request::SaveConfig`] writes the config record.
pub trait ConfigWriter {
    /// Writes `record`; false if the store failed.
    fn write_config(&mut self, record: &[u8]) -> bool;
}

/// Carries out `request` and returns the answer. Program validation runs here, outside any
/// critical section; only the short updates of the servo run inside [`ServoAccess::with`].
pub fn handle_request(
    request: Request,
    models: &mut Models,
    servo: &mut impl ServoAccess,
    store: &mut impl ConfigWriter,
    config_source: ConfigSource,
) -> Response {
    match request {
        Request::Ping { nonce } => Response::Pong { nonce, protocol_version: crate::wire::PROTOCOL_VERSION },
        Request::GetStatus => Response::Status(status(models, servo, config_source)),
        Request::UploadProgram { program, activate } => match models.upload(program, activate) {
            Ok(()) => Response::Ack,
            Err(err) => {
                servo.with(|s| s.update_counters(|c| c.rejected_programs += 1));
                Response::Rejected(Rejection::Program(err))
            }
        },
        Request::ActivateStaged => {
            if models.activate_staged() {
                Response::Ack
            } else {
                Response::Rejected(Rejection::NoStagedProgram)
            }
        }
        Request::ClearProgram => {
            models.clear();
            Response::Ack
        }
        Request::SetParams(params) => match servo.with(|s| s.set_params(params)) {
            Ok(()) => Response::Ack,
            Err(err) => Response::Rejected(Rejection::Params(err)),
        },
        Request::SetEnabled(enabled) => {
            servo.with(|s| s.set_enabled(enabled));
            Response::Ack
        }
        Request::SaveConfig => {
            let (params, supervisor, feature_config) =
                servo.with(|s| (s.params(), s.supervisor_params(), *s.feature_config()));
            let config =
                PersistentConfig { params, supervisor, feature_config, program: models.active_program().cloned() };
            let mut record = [0u8; MAX_CONFIG_BYTES];
            let written = config.encode(&mut record).ok().is_some_and(|len| store.write_config(&record[..len]));
            if written {
                Response::Ack
            } else {
                servo.with(|s| s.update_counters(|c| c.config_store_errors += 1));
                Response::Rejected(Rejection::Store)
            }
        }
        Request::SetFeatureConfig(config) => match servo.with(|s| s.set_feature_config(config)) {
            Ok(()) => Response::Ack,
            Err(_) => Response::Rejected(Rejection::FeatureConfig),
        },
        Request::SetSupervisor(params) => match servo.with(|s| s.set_supervisor_params(params)) {
            Ok(()) => Response::Ack,
            Err(err) => Response::Rejected(Rejection::Supervisor(err)),
        },
        Request::ResetCounters => {
            servo.with(|s| s.update_counters(|c| *c = Default::default()));
            Response::Ack
        }
    }
}

/// The status report. Read in short critical sections: what the tick changes in one, the
/// settings in others (only the low-priority side, which runs this, changes them, so the
/// report is the same as from one section).
pub fn status(models: &Models, servo: &mut impl ServoAccess, config_source: ConfigSource) -> Status {
    let (counters, enabled, gain, degraded, amp_um, phase_deg, features) = servo.with(|s| {
        s.count_axis_resets();
        let output = s.last_output();
        (*s.counters(), s.enabled(), s.gain(), s.degraded(), output.amp_um(), output.phase_deg(), *s.last_features())
    });
    let params = servo.with(|s| s.params());
    let (feature_config, supervisor_params, supervisor) =
        servo.with(|s| (*s.feature_config(), s.supervisor_params(), s.supervisor_state()));
    Status {
        counters,
        enabled,
        gain,
        degraded,
        program_id: models.active_id(),
        staged_program_id: models.staged_id(),
        params,
        feature_config,
        config_source,
        amp_um,
        phase_deg,
        features,
        supervisor_params,
        supervisor,
    }
}
