//! The lab's workflow on both foreign machines over many seeds: each seed draws the hidden
//! effects' parameters and the sensors' noise, measures each machine as a lab would (the
//! grid of `foreign_machine`), and runs `sts-twin explain` from nothing on each measurement,
//! as a lab that measures its machine once does. The tools are never told what a machine has.
//!
//! The machines: the two-mass slide under a cascaded servo (`foreign`) with LuGre friction, a
//! longer loop delay, a probe's scale, a tool-post mode inside the test band or a late
//! setpoint, alone and in sets of two and three (friction in half of them); the ball-screw
//! drive (`foreign::ball_screw`) with sharp Coulomb friction, a tick more of loop delay, and
//! both.
//!
//! Measured per seed, against the issue's targets (a rate below its target fails the test):
//! - **single effects**: the refit with the effect (`fit --effect`) against the clean
//!   machine's twin on the data (`compare`): falls at least 50% in 90% of draws;
//! - **every effect named or absorbed** in 90% of the cases (single and sets): absorbed only
//!   by `sts_assess::absorbed` (the final twin within 1.2x of the clean twin's error and a
//!   refit with the missed effect beside the named ones gaining less than 10%);
//! - **the final twin within 2x** of the clean twin's error (the clean machine's own ladder,
//!   same seed) in 90% of the sets;
//! - **false names**: on the clean machines, `none`, or names whose refit lowered the held-out
//!   error by 30% or more, in 95% of the draws; in the changed machines' ladders, a name of an
//!   effect the machine lacks in at most 10%. Both structures have a mode between encoder and
//!   tool by construction ([`INHERENT`]): `structural-mode` is never a false name on them.
//!
//! ```text
//! STS_FOREIGN_SEEDS=20 cargo test --release -p sts-twin --test tests foreign_suite:: -- --ignored --nocapture
//! ```
//!
//! `STS_FOREIGN_FIRST_SEED` starts at another seed (to split a run); `cargo xtask suites --only
//! foreign-seeds` runs it as BENCHMARKS.md quotes it.

use crate::foreign::ball_screw::{BallScrew, Coulomb};
use crate::foreign::{self, Foreign, Lugre, ToolMode};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::path::{Path, PathBuf};
use std::process::Command;

const FREQS_HZ: [f64; 7] = [2.0, 6.0, 12.0, 20.0, 28.0, 34.0, 40.0];
const AMPS_UM: [f64; 5] = [1.5, 3.0, 5.0, 7.5, 10.0];
const DURATION_S: f64 = 6.0;

/// The verdicts that name each effect a machine can hide (a LuGre or Coulomb law's reversals
/// are what the presliding term's saturation draws too).
const FRICTION: &[&str] = &["coulomb-friction", "presliding-hysteresis"];
const LOOP_DELAY: &[&str] = &["loop-delay"];
const SENSOR_GAIN: &[&str] = &["sensor-gain"];
const MODE: &[&str] = &["structural-mode"];
const SETPOINT: &[&str] = &["setpoint-delay"];

/// A machine of either structure.
#[derive(Clone, Copy)]
enum Machine {
    TwoMass(Foreign),
    BallScrew(BallScrew),
}

impl Machine {
    fn measure(&self, dir: &Path, seed: u64) {
        match self {
            Machine::TwoMass(m) => m.measure(dir, &FREQS_HZ, &AMPS_UM, DURATION_S, seed),
            Machine::BallScrew(m) => m.measure(dir, &FREQS_HZ, &AMPS_UM, DURATION_S, seed),
        }
    }
}

/// One measured machine: which structure (`two-mass`, `ball-screw`), its name, the machine,
/// and its hidden effects, each by the verdicts that name it (none: the clean machine).
struct Case {
    structure: &'static str,
    name: String,
    machine: Machine,
    effects: Vec<&'static [&'static str]>,
}

/// What both structures have by construction, clean or not, and so is no false name: a mode
/// between the encoder and the tool (the two-mass slide's carrier on its 240 Hz coupling, the
/// ball screw's tool holder at 220 Hz on a compliant screw).
const INHERENT: &[&str] = MODE;

/// The cases of one seed: each structure's clean machine first, then its changed machines.
fn cases(seed: u64) -> Vec<Case> {
    let mut rng = ChaCha8Rng::seed_from_u64(0xf0e1_0000 + seed);
    let clean = Foreign::default();
    let coulomb_n = rng.random_range(2.0..5.0);
    let lugre = Lugre {
        coulomb_n,
        static_n: coulomb_n * rng.random_range(1.2..1.5),
        stribeck_mps: rng.random_range(1e-4..5e-4),
        sigma0_n_per_m: rng.random_range(1e6..2e6),
        sigma1_ns_per_m: 300.0,
    };
    let delay_ticks = rng.random_range(3..=6);
    let probe_gain = 1.0 + rng.random_range(0.03..0.06) * if rng.random_bool(0.5) { 1.0 } else { -1.0 };
    let mode = ToolMode {
        freq_hz: rng.random_range(14.0..30.0),
        damping: rng.random_range(0.03..0.06),
        modal_kg: 0.05,
        share: rng.random_range(0.008..0.015),
    };
    let late_s = f64::from(rng.random_range(1..=3)) / foreign::RATE_HZ;
    // Each effect of the two-mass machine: its verdicts and how it changes the machine.
    type Change = fn(&mut Foreign, &Draw);
    struct Draw {
        lugre: Lugre,
        delay_ticks: usize,
        probe_gain: f64,
        mode: ToolMode,
        late_s: f64,
    }
    let draw = Draw { lugre, delay_ticks, probe_gain, mode, late_s };
    let effects: [(&str, &'static [&'static str], Change); 5] = [
        ("lugre-friction", FRICTION, |m, d| m.friction = Some(d.lugre)),
        ("loop-delay", LOOP_DELAY, |m, d| m.delay_ticks = d.delay_ticks),
        ("probe-gain", SENSOR_GAIN, |m, d| m.probe_gain = d.probe_gain),
        ("tool-mode", MODE, |m, d| m.tool_mode = Some(d.mode)),
        ("setpoint-delay", SETPOINT, |m, d| m.setpoint_delay_s = d.late_s),
    ];
    let two_mass = |chosen: &[usize]| {
        let mut machine = clean;
        for &i in chosen {
            (effects[i].2)(&mut machine, &draw);
        }
        Case {
            structure: "two-mass",
            name: chosen.iter().map(|&i| effects[i].0).collect::<Vec<_>>().join("+"),
            machine: Machine::TwoMass(machine),
            effects: chosen.iter().map(|&i| effects[i].1).collect(),
        }
    };
    let mut out =
        vec![Case { structure: "two-mass", name: "clean".into(), machine: Machine::TwoMass(clean), effects: vec![] }];
    out.extend((0..effects.len()).map(|i| two_mass(&[i])));
    // Sets: friction with one and with two others, and two and three of the others.
    let others: Vec<usize> = (1..effects.len()).collect();
    let pick = |rng: &mut ChaCha8Rng, n: usize| -> Vec<usize> {
        let mut pool = others.clone();
        let mut chosen = Vec::new();
        for _ in 0..n {
            chosen.push(pool.remove(rng.random_range(0..pool.len())));
        }
        chosen.sort_unstable();
        chosen
    };
    for (with_friction, n) in [(true, 1), (true, 2), (false, 2), (false, 3)] {
        let mut chosen = pick(&mut rng, n);
        if with_friction {
            chosen.insert(0, 0);
        }
        out.push(two_mass(&chosen));
    }
    let screw = BallScrew::default();
    let coulomb =
        Coulomb { guide_n: rng.random_range(3.0..8.0), bearing_n: rng.random_range(1.0..3.0), width_mps: 1e-6 };
    // One tick more: the ball screw's PID, tuned for one, is unstable from three.
    let screw_delay = 2;
    let ball_screw = |name: &str, machine: BallScrew, effects: Vec<&'static [&'static str]>| Case {
        structure: "ball-screw",
        name: name.into(),
        machine: Machine::BallScrew(machine),
        effects,
    };
    out.push(ball_screw("clean", screw, vec![]));
    out.push(ball_screw("coulomb-friction", BallScrew { friction: Some(coulomb), ..screw }, vec![FRICTION]));
    out.push(ball_screw("loop-delay", BallScrew { delay_ticks: screw_delay, ..screw }, vec![LOOP_DELAY]));
    out.push(ball_screw(
        "coulomb-friction+loop-delay",
        BallScrew { friction: Some(coulomb), delay_ticks: screw_delay, ..screw },
        vec![FRICTION, LOOP_DELAY],
    ));
    out
}

/// Runs `sts-twin ARGS`; its standard output as JSON (`--json` among the arguments), or its
/// error.
fn sts_twin(args: &[&str]) -> Result<serde_json::Value, String> {
    let out = Command::new(env!("CARGO_BIN_EXE_sts-twin")).args(args).output().map_err(|e| e.to_string())?;
    if !out.status.success() {
        return Err(format!("sts-twin {}: {}", args.join(" "), String::from_utf8_lossy(&out.stderr)));
    }
    Ok(if args.contains(&"--json") {
        serde_json::from_slice(&out.stdout).map_err(|e| e.to_string())?
    } else {
        serde_json::Value::Null
    })
}

fn path(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// The held-out waveform RMS of a model file, um.
fn held_out_um(model: &Path) -> f64 {
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(model).unwrap()).unwrap();
    v["validation"]["waveform_rms_um"].as_f64().unwrap()
}

/// `fit DATA --effect EFFECTS`'s held-out waveform RMS, um.
fn refit_um(data: &Path, effects: &[&str], out: &Path) -> Result<f64, String> {
    let list = effects.join(",");
    sts_twin(&["fit", path(data), "--effect", &list, "--out", path(out), "--quiet", "--force"])?;
    Ok(held_out_um(out))
}

/// One ladder: its named effects, each with the held-out error before and after its rung,
/// and its start and end.
struct Ladder {
    named: Vec<(String, f64, f64)>,
    start_um: f64,
    final_um: f64,
}

fn explain(data: &Path, out: &Path) -> Result<Ladder, String> {
    let ex = sts_twin(&["explain", path(data), "--out", path(out), "--force", "--json"])?;
    let named = ex["steps"]
        .as_array()
        .map(|steps| {
            steps
                .iter()
                .map(|s| {
                    (
                        s["effect"].as_str().unwrap_or("?").to_string(),
                        s["waveform_rms_um_before"].as_f64().unwrap_or(f64::NAN),
                        s["waveform_rms_um_after"].as_f64().unwrap_or(f64::NAN),
                    )
                })
                .collect()
        })
        .unwrap_or_default();
    Ok(Ladder {
        named,
        start_um: ex["start_waveform_rms_um"].as_f64().unwrap_or(f64::NAN),
        final_um: ex["waveform_rms_um"].as_f64().unwrap_or(f64::NAN),
    })
}

/// A rate: how many of how many met a target.
#[derive(Default, Clone, Copy)]
struct Rate {
    met: usize,
    of: usize,
}

impl Rate {
    fn add(&mut self, met: bool) {
        self.met += usize::from(met);
        self.of += 1;
    }
    fn fraction(&self) -> f64 {
        if self.of == 0 {
            1.0
        } else {
            self.met as f64 / self.of as f64
        }
    }
    fn show(&self) -> String {
        format!("{} of {} ({:.0}%)", self.met, self.of, 100.0 * self.fraction())
    }
}

/// The rates of one structure.
#[derive(Default)]
struct Rates {
    /// Per single effect (its case name): the refit fell at least 50%.
    refit_falls: Vec<(String, Rate)>,
    /// Every effect named or absorbed: single effects, and sets.
    named_single: Rate,
    named_sets: Rate,
    /// The final twin within 2x of the clean twin's error: single effects, and sets.
    within_2x_single: Rate,
    within_2x_sets: Rate,
    /// Clean machines: `none` or only names whose refit lowered the error 30% or more.
    clean_ok: Rate,
    /// Changed machines' ladders without a name of an effect the machine lacks.
    no_absent_name: Rate,
}

impl Rates {
    fn refit(&mut self, name: &str) -> &mut Rate {
        if !self.refit_falls.iter().any(|(n, _)| n == name) {
            self.refit_falls.push((name.to_string(), Rate::default()));
        }
        &mut self.refit_falls.iter_mut().find(|(n, _)| n == name).unwrap().1
    }
}

#[test]
#[ignore = "long: both foreign machines, 14 measurements and ladders a seed (about 5 minutes a seed on 2 cores)"]
fn the_lab_workflow_over_seeds_on_both_foreign_machines() {
    let env_u64 = |name: &str, default: u64| std::env::var(name).ok().and_then(|v| v.parse().ok()).unwrap_or(default);
    let first_seed = env_u64("STS_FOREIGN_FIRST_SEED", 1);
    let seeds = env_u64("STS_FOREIGN_SEEDS", 20);
    let root: PathBuf = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("foreign-suite-{}", std::process::id()));
    let mut rates: Vec<(&'static str, Rates)> = vec![("two-mass", Rates::default()), ("ball-screw", Rates::default())];
    let mut errors = Vec::new();
    for seed in first_seed..first_seed + seeds {
        let dir = root.join(format!("seed-{seed}"));
        let _ = std::fs::remove_dir_all(&dir);
        let cases = cases(seed);
        std::thread::scope(|s| {
            for (i, case) in cases.iter().enumerate() {
                let d = dir.join(case.structure).join(&case.name);
                s.spawn(move || case.machine.measure(&d, seed * 100 + i as u64));
            }
        });
        // Per structure: the clean machine's twin (a plain fit) and its ladder's end.
        let mut clean: Option<(PathBuf, f64)> = None;
        for case in &cases {
            let data = dir.join(case.structure).join(&case.name);
            let rates = &mut rates.iter_mut().find(|(s, _)| *s == case.structure).unwrap().1;
            let result = (|| -> Result<String, String> {
                let ladder = explain(&data, &data.with_extension("explained.json"))?;
                let names: Vec<&str> = ladder.named.iter().map(|(n, _, _)| n.as_str()).collect();
                let ladder_text = format!(
                    "{:.1} nm: {} -> {:.1} nm",
                    ladder.start_um * 1e3,
                    if names.is_empty() { "-".to_string() } else { names.join(", ") },
                    ladder.final_um * 1e3
                );
                if case.effects.is_empty() {
                    let twin = data.with_extension("twin.json");
                    sts_twin(&["fit", path(&data), "--out", path(&twin), "--quiet", "--force"])?;
                    // A name on the clean machine is no false name if its rung lowered the
                    // error by 30% or more, or it is of what the structure has.
                    let helps = ladder
                        .named
                        .iter()
                        .all(|(name, before, after)| INHERENT.contains(&name.as_str()) || *after <= 0.7 * before);
                    rates.clean_ok.add(helps);
                    clean = Some((twin, ladder.final_um));
                    return Ok(format!("{ladder_text}{}", if helps { "" } else { "; a name that does not help" }));
                }
                let (clean_twin, clean_um) = clean.clone().ok_or("no clean machine before")?;
                let absent: Vec<&str> = names
                    .iter()
                    .copied()
                    .filter(|n| !INHERENT.contains(n) && !case.effects.iter().any(|e| e.contains(n)))
                    .collect();
                rates.no_absent_name.add(absent.is_empty());
                // Each effect named, or absorbed where the data shows it.
                let (mut missed, mut all_named) = (Vec::new(), true);
                for effect in &case.effects {
                    if names.iter().any(|n| effect.contains(n)) {
                        continue;
                    }
                    let mut with: Vec<&str> = names.clone();
                    with.push(effect[0]);
                    let refit = refit_um(&data, &with, &data.with_extension("missed.json"))?;
                    let absorbed = sts_assess::absorbed::absorbed(ladder.final_um, clean_um, refit);
                    all_named &= absorbed;
                    missed.push(format!(
                        "{}{} (refit {:.1} nm)",
                        effect[0],
                        if absorbed { ", absorbed" } else { "" },
                        refit * 1e3
                    ));
                }
                let within_2x = ladder.final_um <= 2.0 * clean_um;
                let single = case.effects.len() == 1;
                if single {
                    rates.named_single.add(all_named);
                    rates.within_2x_single.add(within_2x);
                } else {
                    rates.named_sets.add(all_named);
                    rates.within_2x_sets.add(within_2x);
                }
                let mut line = format!("{ladder_text} ({:.2}x clean)", ladder.final_um / clean_um);
                if !missed.is_empty() {
                    line += &format!("; missed {}", missed.join(", "));
                }
                if !absent.is_empty() {
                    line += &format!("; named but not there: {}", absent.join(", "));
                }
                if single {
                    // The refit with the effect against the clean machine's twin on the data.
                    let effect =
                        names.iter().copied().find(|n| case.effects[0].contains(n)).unwrap_or(case.effects[0][0]);
                    let before = sts_twin(&["compare", path(&data), "--model", path(&clean_twin), "--json"])?
                        ["waveform_rms_um"]
                        .as_f64()
                        .unwrap_or(f64::NAN);
                    let after = refit_um(&data, &[effect], &data.with_extension("refit.json"))?;
                    let fall = 1.0 - after / before;
                    rates.refit(&case.name).add(fall >= 0.5);
                    line += &format!(
                        "; refit with {effect}: {:.1} -> {:.1} nm ({:.0}%)",
                        before * 1e3,
                        after * 1e3,
                        fall * 100.0
                    );
                }
                Ok(line)
            })();
            match result {
                Ok(line) => println!("seed {seed:>2} {:<10} {:<46} {line}", case.structure, case.name),
                Err(e) => {
                    println!("seed {seed:>2} {:<10} {:<46} error: {e}", case.structure, case.name);
                    errors.push(format!("seed {seed} {} {}: {e}", case.structure, case.name));
                }
            }
        }
        let _ = std::fs::remove_dir_all(&dir);
    }
    let _ = std::fs::remove_dir_all(&root);

    println!("\nseeds {first_seed}-{}, the lab's workflow (`explain` from nothing):", first_seed + seeds - 1);
    let mut short = Vec::new();
    let mut check = |what: String, rate: Rate, target: f64| {
        let ok = rate.fraction() >= target;
        println!("  {what:<72} {:<16} target {:.0}%{}", rate.show(), target * 100.0, if ok { "" } else { "  SHORT" });
        if !ok {
            short.push(what);
        }
    };
    for (structure, r) in &rates {
        println!("{structure}:");
        for (name, rate) in &r.refit_falls {
            check(format!("{structure}: the refit with {name} falls 50% or more"), *rate, 0.9);
        }
        check(format!("{structure}: single effects named or absorbed"), r.named_single, 0.9);
        check(format!("{structure}: sets, every effect named or absorbed"), r.named_sets, 0.9);
        check(format!("{structure}: single effects, final twin within 2x of clean"), r.within_2x_single, 0.9);
        check(format!("{structure}: sets, final twin within 2x of clean"), r.within_2x_sets, 0.9);
        check(format!("{structure}: clean, none or names that help 30%"), r.clean_ok, 0.95);
        check(format!("{structure}: ladders without a name the machine lacks"), r.no_absent_name, 0.9);
    }
    assert!(errors.is_empty(), "{errors:#?}");
    assert!(short.is_empty(), "short of the targets: {short:#?}");
}
