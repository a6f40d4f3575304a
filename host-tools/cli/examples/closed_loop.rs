//! Closed loop at one frequency, simulated co-processor, with and without a model:
//! `cargo run --release -p sts-twin --example closed_loop -- MODEL FREQ_HZ AMP_UM`.
use sts_analysis::sine::fit_sine;
use sts_emulator::{Machine, PlantParams};
use sts_model::ModelFile;
use sts_rig::{expect_ack, run_loop, Coprocessor, SimCoprocessor, Sinusoid};
use sts_twin_core::feedforward::FeedforwardParams;
use sts_twin_core::wire::Request;
use sts_twin_core::SERVO_RATE_HZ;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let model = ModelFile::read(std::path::Path::new(&args[1]))?;
    let freq_hz: f64 = args[2].parse()?;
    let amp_um: f64 = args[3].parse()?;
    let plant = PlantParams::default();
    for with_twin in [false, true] {
        let mut machine = Machine::new(&plant, &[], 1)?;
        let mut cop = SimCoprocessor::boot(&[]);
        let params = FeedforwardParams {
            k_dv_um_per_v: 2.0,
            k_vc_pulses_per_v: 2000.0,
            offset_v: 0.012,
            slew_v_per_tick: 1.0,
            ..Default::default()
        };
        expect_ack("params", cop.request(Request::SetParams(params))?)?;
        expect_ack("features", cop.request(Request::SetFeatureConfig(model.feature_config))?)?;
        if with_twin {
            expect_ack(
                "program",
                cop.request(Request::UploadProgram { program: model.firmware_program()?, activate: true })?,
            )?;
            expect_ack("enable", cop.request(Request::SetEnabled(true))?)?;
        }
        let traj = Sinusoid { freq_hz, amp_um, duration_s: 10.0, sample_rate_hz: f64::from(SERVO_RATE_HZ) };
        let (mut t, mut de, mut pred) = (Vec::new(), Vec::new(), Vec::new());
        run_loop(&mut machine, &mut cop, &traj, 0..80_000, 10.0, true, |s| {
            if s.machine.time_s >= 9.0 {
                t.push(s.machine.time_s);
                de.push(s.machine.z_tcp_true_um - s.point.z_cmd_um);
                pred.push(f64::from(s.output.de_pred_pm) * 1e-6);
            }
        })?;
        let fit = fit_sine(&t, &de, freq_hz).unwrap();
        let pf = fit_sine(&t, &pred, freq_hz).unwrap();
        let pv = de.iter().cloned().fold(f64::MIN, f64::max) - de.iter().cloned().fold(f64::MAX, f64::min);
        println!(
            "twin {with_twin}: DE amp {:.4} um phase {:.2} deg, PV {:.4} um | predicted amp {:.4} phase {:.2}",
            fit.amp,
            fit.phase_rad.to_degrees(),
            pv,
            pf.amp,
            pf.phase_rad.to_degrees()
        );
    }
    Ok(())
}
