//! Two ways a lab gives the calibration its readings ([`super::LabInstruments`]): the
//! operator types them ([`PromptInstruments`]), or the lab's own commands print them
//! ([`CommandInstruments`]: a script that queries the motion controller, a probe's driver).

use std::io::{BufRead, Write};
use std::process::Command;

use super::lab::LabInstruments;
use crate::RigError;

/// Asks the operator on `output` and reads each answer, a number, from a line of `input`.
pub struct PromptInstruments<R: BufRead, W: Write> {
    input: R,
    output: W,
}

impl<R: BufRead, W: Write> PromptInstruments<R, W> {
    /// Prompts on `output`, answers from `input` (stderr and stdin, for the command line).
    pub fn new(input: R, output: W) -> Self {
        Self { input, output }
    }

    fn ask(&mut self, instrument: &str, question: &str) -> Result<String, RigError> {
        let failed = |detail: String| RigError::Instrument { instrument: instrument.to_string(), detail };
        write!(self.output, "{question} ").and_then(|()| self.output.flush()).map_err(|e| failed(e.to_string()))?;
        let mut line = String::new();
        match self.input.read_line(&mut line) {
            Ok(0) => Err(failed("no answer (end of input)".into())),
            Ok(_) => Ok(line.trim().to_string()),
            Err(e) => Err(failed(e.to_string())),
        }
    }

    fn number(&mut self, instrument: &str, question: &str) -> Result<f64, RigError> {
        for _ in 0..3 {
            let answer = self.ask(instrument, question)?;
            match answer.parse::<f64>() {
                Ok(value) if value.is_finite() => return Ok(value),
                _ => {
                    let _ = writeln!(self.output, "`{answer}` is not a number; type the reading as a decimal number");
                }
            }
        }
        Err(RigError::Instrument { instrument: instrument.to_string(), detail: "no number in three answers".into() })
    }
}

impl<R: BufRead, W: Write> LabInstruments for PromptInstruments<R, W> {
    fn controller_reading_v(&mut self, dac_v: f64) -> Result<f64, RigError> {
        self.number(
            "the controller's analogue-input reading",
            &format!("The board outputs {dac_v:+.4} V. The motion controller's reading of its analogue input, V:"),
        )
    }

    fn feedforward_on(&mut self) -> Result<(), RigError> {
        self.ask(
            "switching the controller's analogue feedforward on",
            "Switch the motion controller's analogue feedforward input on (the axis will follow the board's output), then press Enter:",
        )
        .map(drop)
    }

    fn tool_position_um(&mut self, dac_v: f64) -> Result<f64, RigError> {
        self.number(
            "the probe at the tool",
            &format!("The board outputs {dac_v:+.4} V. The probe's reading at the tool, um:"),
        )
    }
}

/// Runs the lab's commands (with `sh -c`) and reads each reading, a number, from the first
/// word the command prints. The board's output voltage is in the environment as
/// `STS_TWIN_DAC_V`, for a command that wants to log it.
pub struct CommandInstruments {
    /// Prints the controller's reading of its analogue input, V.
    pub controller_reading: String,
    /// Switches the controller's analogue feedforward on (`None`: ask the operator).
    pub feedforward_on: Option<String>,
    /// Prints the probe's reading at the tool, um.
    pub tool_position: String,
}

fn run(instrument: &str, command: &str, dac_v: Option<f64>) -> Result<String, RigError> {
    let failed = |detail: String| RigError::Instrument { instrument: format!("{instrument} (`{command}`)"), detail };
    let mut cmd = Command::new("sh");
    cmd.args(["-c", command]);
    if let Some(v) = dac_v {
        cmd.env("STS_TWIN_DAC_V", format!("{v}"));
    }
    let out = cmd.output().map_err(|e| failed(format!("cannot run it: {e}")))?;
    if !out.status.success() {
        return Err(failed(format!("{}: {}", out.status, String::from_utf8_lossy(&out.stderr).trim())));
    }
    Ok(String::from_utf8_lossy(&out.stdout).to_string())
}

fn number(instrument: &str, command: &str, dac_v: f64) -> Result<f64, RigError> {
    let text = run(instrument, command, Some(dac_v))?;
    let word = text.split_whitespace().next().unwrap_or("");
    word.parse::<f64>().ok().filter(|v| v.is_finite()).ok_or_else(|| RigError::Instrument {
        instrument: format!("{instrument} (`{command}`)"),
        detail: format!("printed `{}`, not a number", text.trim()),
    })
}

impl LabInstruments for CommandInstruments {
    fn controller_reading_v(&mut self, dac_v: f64) -> Result<f64, RigError> {
        number("the controller's analogue-input reading", &self.controller_reading, dac_v)
    }

    fn feedforward_on(&mut self) -> Result<(), RigError> {
        match &self.feedforward_on {
            Some(command) => run("switching the controller's analogue feedforward on", command, None).map(drop),
            None => PromptInstruments::new(std::io::stdin().lock(), std::io::stderr()).feedforward_on(),
        }
    }

    fn tool_position_um(&mut self, dac_v: f64) -> Result<f64, RigError> {
        number("the probe at the tool", &self.tool_position, dac_v)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_operator_is_asked_again_after_a_typo_and_the_end_of_input_is_an_error() {
        let mut out = Vec::new();
        let mut prompt = PromptInstruments::new(&b"0.2x\n0.25\n\n"[..], &mut out);
        assert_eq!(prompt.controller_reading_v(0.2).unwrap(), 0.25);
        prompt.feedforward_on().unwrap();
        let err = prompt.tool_position_um(0.1).unwrap_err();
        assert!(err.to_string().contains("the probe at the tool: no answer"), "{err}");
        let shown = String::from_utf8(out).unwrap();
        assert!(shown.contains("+0.2000 V") && shown.contains("`0.2x` is not a number"), "{shown}");
    }

    #[test]
    fn a_command_gives_its_first_word_and_a_failing_or_wordy_one_is_named() {
        let mut commands = CommandInstruments {
            controller_reading: "echo \"$STS_TWIN_DAC_V\" volts".into(),
            feedforward_on: Some("true".into()),
            tool_position: "echo about 3 um".into(),
        };
        assert_eq!(commands.controller_reading_v(0.125).unwrap(), 0.125);
        commands.feedforward_on().unwrap();
        let err = commands.tool_position_um(0.0).unwrap_err();
        assert!(err.to_string().contains("`echo about 3 um`") && err.to_string().contains("not a number"), "{err}");
        commands.controller_reading = "echo broken >&2; exit 3".into();
        let err = commands.controller_reading_v(0.0).unwrap_err();
        assert!(err.to_string().contains("exit status: 3") && err.to_string().contains("broken"), "{err}");
    }
}
