//! Several effects at once, as real machines have them: emulator data with two or three
//! randomly drawn effects (effects and parameters from a seed; the tools are never told
//! which), and `explain` run on it as a lab runs it (a twin fitted on the data itself, then
//! diagnose, add the named effect, refit, until `none`).
//!
//! Measured per set: which of its effects the ladder named, why it stopped, and the final
//! twin's held-out waveform RMS against a twin of the clean machine fitted on the same grid.
//! An effect the ladder did not name counts as absorbed only where the data shows the twin
//! carries it: the final twin within 1.2x of the clean twin's error, and a refit with the
//! missed effect beside the named ones lowering that error by less than 10%. Names of effects
//! the set does not hold are counted and asserted (none in CI's sets, at most 10% of the
//! ladders in a full run). Where the
//! machine hunts (a friction's limit cycle: a slow group's reading depends on the emulator's
//! integration step), the final diagnosis must find groups that do not repeat, and the 2x is
//! taken over the groups where it does not hunt, against the clean twin's error over the same
//! groups (no twin driven by the command predicts a hunting axis).
//!
//! CI runs `ci_sets` (two sets on 5.5 s groups). The full run, every pair of the eight
//! effects with `STS_SETS_SEEDS` seeds each and `STS_SETS_TRIPLES` random triples:
//!
//! ```text
//! STS_SETS_SEEDS=5 STS_SETS_TRIPLES=10 STS_SETS_GRID=paper \
//!   cargo test --release -p sts-assess --test tests explain_several_effects::full_sets -- --ignored --nocapture
//! ```
//!
//! `cargo xtask suites --only sets,sets-60kg` runs the configurations BENCHMARKS.md quotes at
//! one commit and keeps their tables in `target/suites/<commit>/SUMMARY.md`.
//!
//! `STS_SETS_FIRST_SEED` starts at another seed (to split a run); `STS_SETS_ONLY=a+b,c+d+e`
//! runs only those sets, `STS_SETS_WITH=a,b` only the sets holding `a` or `b`,
//! `STS_SETS_WITHOUT=a,b` only those holding neither; `STS_PLANT=FILE` measures another machine
//! (a plant file as `sts-twin measure --plant` takes it) instead of the default.

use rand::seq::IndexedRandom;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use sts_analysis::repeat::rms_without;
use sts_assess::explain::{explain, ExplainConfig, Stop};
use sts_emulator::{EffectSpec, PlantParams};
use sts_fit::effects::fit_with;
use sts_fit::FitConfig;
use sts_model::Effect;
use sts_model::Validation;

use sts_assess::absorbed::{refit_gains_nothing, ABSORBED_WITHIN};

use crate::support::{clean_twin, hunting_groups, measure, plant_from_env};

struct Sets {
    /// The sets, each with its draw index (its position in the full list, so that a set run
    /// alone with `STS_SETS_ONLY` draws the same parameters as in the full run).
    sets: Vec<(usize, Vec<&'static str>)>,
    first_seed: u64,
    seeds: u64,
    paper_grid: bool,
    epochs: usize,
    /// The machine measured (the clean twin's data too).
    plant: PlantParams,
}

fn env_u64(name: &str, default: u64) -> u64 {
    std::env::var(name).ok().and_then(|v| v.parse().ok()).unwrap_or(default)
}

/// The comma-separated list in the environment variable `name`, when it is set.
fn env_list(name: &str) -> Option<Vec<String>> {
    std::env::var(name).ok().map(|v| v.split(',').map(str::to_string).collect())
}

/// Every pair of the effects, then `triples` distinct triples drawn with a fixed seed.
fn pairs_and_triples(triples: usize) -> Vec<Vec<&'static str>> {
    let mut sets = Vec::new();
    let names = Effect::ALL.map(Effect::name);
    for (i, a) in names.iter().enumerate() {
        for b in &names[i + 1..] {
            sets.push(vec![*a, *b]);
        }
    }
    let mut rng = ChaCha8Rng::seed_from_u64(0x0721_91e5);
    let mut drawn: Vec<Vec<&'static str>> = Vec::new();
    while drawn.len() < triples {
        let mut t: Vec<&'static str> = names.sample(&mut rng, 3).copied().collect();
        t.sort_by_key(|n| names.iter().position(|e| e == n));
        if !drawn.contains(&t) {
            drawn.push(t);
        }
    }
    sets.extend(drawn);
    sets
}

struct Outcome {
    /// The drawn effects as `sts-twin measure --effect` takes them.
    specs: Vec<String>,
    named: Vec<String>,
    stop: Stop,
    start_rms_um: f64,
    final_rms_um: f64,
    /// The groups where the machine hunts (their reading depends on the emulator's
    /// integration step by more than the probe's noise: a limit cycle that no twin driven by
    /// the command predicts), as files.
    hunting: Vec<String>,
    /// The files of the groups whose error the final diagnosis found not repeating.
    not_repeating: Vec<String>,
    /// The final twin's held-out validation.
    final_validation: Validation,
    /// Per effect of the set the ladder missed: the held-out RMS of a refit with it beside the
    /// named ones, um, where the final twin ends within [`ABSORBED_WITHIN`] of clean.
    missed_refits_um: Vec<(String, f64)>,
}

/// A twin's held-out waveform RMS over the groups not in `skip` (at least one of them left
/// out), um.
fn rms_over_others(validation: &Validation, skip: &[String]) -> f64 {
    rms_without(validation.groups.iter().map(|g| (g.file.as_str(), g.waveform_rms_um)), skip)
        .expect("some groups left out and some kept")
}

fn run_set(s: &Sets, set: &[&str], set_index: usize, seed: u64, clean_rms_um: f64) -> Outcome {
    let mut rng = ChaCha8Rng::seed_from_u64(0x5e75_0000 + seed * 256 + set_index as u64);
    let effects: Vec<EffectSpec> =
        set.iter().map(|n| EffectSpec::random(n.parse().expect("an effect"), &mut rng).expect("a draw")).collect();
    let data = measure(&s.plant, s.paper_grid, effects.clone(), 500 + seed);
    let hunting =
        if set.contains(&"coulomb-friction") { hunting_groups(&s.plant, &effects, 500 + seed) } else { Vec::new() };
    let config = ExplainConfig { fit: FitConfig { max_epochs: s.epochs, ..FitConfig::default() }, max_effects: 4 };
    let e = explain(&data, "several effects", None, &config, &mut |_| {}).expect("explain");
    let named: Vec<String> = e.steps.iter().map(|st| st.effect.clone()).collect();
    let missed_refits_um = if e.waveform_rms_um <= ABSORBED_WITHIN * clean_rms_um {
        set.iter()
            .filter(|m| !named.iter().any(|n| n == *m))
            .map(|m| {
                let mut with = named.clone();
                with.push(m.to_string());
                let rms_um = fit_with(&data, &with, "several effects", &config.fit, &mut |_| {})
                    .map_or(f64::INFINITY, |(model, _)| model.validation.waveform_rms_um);
                (m.to_string(), rms_um)
            })
            .collect()
    } else {
        Vec::new()
    };
    Outcome {
        specs: effects.iter().map(ToString::to_string).collect(),
        named,
        missed_refits_um,
        stop: e.stop,
        start_rms_um: e.start_waveform_rms_um,
        final_rms_um: e.waveform_rms_um,
        hunting: e
            .model
            .validation
            .groups
            .iter()
            .filter(|g| hunting.iter().any(|&(f, a)| g.freq_hz == f && g.amp_um == a))
            .map(|g| g.file.clone())
            .collect(),
        not_repeating: e.last.not_repeating_files(),
        final_validation: e.model.validation,
    }
}

fn run_sets(s: &Sets) {
    let clean_twin = clean_twin(&s.plant, s.paper_grid, s.epochs);
    let clean_rms_um = clean_twin.validation.waveform_rms_um;
    println!("clean twin: held-out waveform RMS {:.2} nm", clean_rms_um * 1e3);

    let (mut cases, mut all_named, mut named_or_absorbed, mut within_2x) = (0usize, 0usize, 0usize, 0usize);
    let mut with_wrong_name = 0usize;
    // Per effect: in how many sets it was hidden, and named.
    let mut per_effect = vec![(0usize, 0usize); Effect::ALL.len()];
    for seed in s.first_seed..s.first_seed + s.seeds {
        for (index, set) in &s.sets {
            let o = run_set(s, set, *index, seed, clean_rms_um);
            // A hunting machine's error where it hunts is no test of the twin: the
            // ratio is taken over the other groups, against the clean twin's over the same
            // groups, and the diagnosis must have found groups that do not repeat.
            let hunts = !o.hunting.is_empty();
            let told = !hunts || !o.not_repeating.is_empty();
            let ratio = if hunts && told {
                rms_over_others(&o.final_validation, &o.hunting) / rms_over_others(&clean_twin.validation, &o.hunting)
            } else if told {
                o.final_rms_um / clean_rms_um
            } else {
                f64::INFINITY
            };
            let missed: Vec<&str> = set.iter().copied().filter(|e| !o.named.iter().any(|n| n == e)).collect();
            let wrong: Vec<&String> = o.named.iter().filter(|n| !set.contains(&n.as_str())).collect();
            let absorbed = !missed.is_empty()
                && missed
                    .iter()
                    .all(|m| o.missed_refits_um.iter().any(|(e, r)| e == m && refit_gains_nothing(*r, o.final_rms_um)));
            cases += 1;
            with_wrong_name += usize::from(!wrong.is_empty());
            all_named += usize::from(missed.is_empty());
            named_or_absorbed += usize::from(missed.is_empty() || absorbed);
            within_2x += usize::from(ratio <= 2.0);
            for e in set.iter() {
                let i = Effect::ALL.iter().position(|n| n.name() == *e).unwrap_or(0);
                per_effect[i].0 += 1;
                per_effect[i].1 += usize::from(o.named.iter().any(|n| n == e));
            }
            println!(
                "{:<60} seed {seed:>2}: named {:<50} {:>6.1} -> {:>5.1} nm ({}), stop {}{}{}",
                set.join("+"),
                if o.named.is_empty() { "-".to_string() } else { o.named.join(", ") },
                o.start_rms_um * 1e3,
                o.final_rms_um * 1e3,
                match (hunts, told) {
                    (false, _) => format!("{ratio:.2}x clean"),
                    (true, true) => format!(
                        "the machine hunts in {} groups: {ratio:.2}x clean without them; {} found not repeating",
                        o.hunting.len(),
                        o.not_repeating.len()
                    ),
                    (true, false) => "the machine hunts and the diagnosis did not find it".into(),
                },
                o.stop.describe(),
                if missed.is_empty() {
                    String::new()
                } else {
                    format!(
                        "; missed {}{}{}",
                        missed.join(", "),
                        if absorbed { " (absorbed)" } else { "" },
                        o.missed_refits_um
                            .iter()
                            .map(|(e, r)| format!(", refit with {e} {:.1} nm", r * 1e3))
                            .collect::<String>()
                    )
                },
                if wrong.is_empty() {
                    String::new()
                } else {
                    format!(
                        "; named but not hidden: {}",
                        wrong.iter().map(|w| w.as_str()).collect::<Vec<_>>().join(", ")
                    )
                }
            );
            if !(missed.is_empty() || absorbed) || ratio > 2.0 {
                // The same machine through the CLI, to look at a failure by hand (the CLI
                // records the paper's groups; CI's shorter ones only differ in length).
                let effects: String = o.specs.iter().map(|spec| format!(" --effect {spec}")).collect();
                println!("    sts-twin measure{effects} --seed {} --out DATA", 500 + seed);
            }
        }
    }
    println!("\nper effect: named in how many of the sets that hid it");
    for (name, (hidden, named)) in Effect::ALL.map(Effect::name).iter().zip(&per_effect) {
        if *hidden > 0 {
            println!("  {name:<22} {named:>3} of {hidden:>3}");
        }
    }
    let pct = |n: usize| 100.0 * n as f64 / cases.max(1) as f64;
    println!(
        "\n{cases} sets: every effect named in {all_named} ({:.0}%); named or absorbed by the formulas in {named_or_absorbed} ({:.0}%, target 80%); final twin within 2x of the clean twin's error in {within_2x} ({:.0}%)",
        pct(all_named),
        pct(named_or_absorbed),
        pct(within_2x)
    );
    assert!(
        named_or_absorbed as f64 >= 0.8 * cases as f64,
        "effects named in only {named_or_absorbed} of {cases} sets"
    );
    assert!(within_2x as f64 >= 0.8 * cases as f64, "final twin within 2x clean in only {within_2x} of {cases} sets");
    println!("a name of an effect the set does not hold in {with_wrong_name} of {cases} ladders (at most 10%)");
    assert!(
        with_wrong_name as f64 <= 0.1 * cases as f64,
        "{with_wrong_name} of {cases} ladders name an effect the set does not hold"
    );
}

/// CI's share: two sets on 5.5 s groups, one of them the axis twin with two effects.
#[test]
fn ci_sets() {
    run_sets(&Sets {
        sets: vec![(0, vec!["coulomb-friction", "presliding-hysteresis"]), (1, vec!["thermal-drift", "force-ripple"])],
        first_seed: 0,
        seeds: 1,
        paper_grid: false,
        epochs: 10,
        plant: PlantParams::default(),
    });
}

/// The full run (see the module docs for the command).
#[test]
#[ignore = "long: every pair and random triples, several seeds each (about 20 minutes per seed)"]
fn full_sets() {
    let mut sets: Vec<(usize, Vec<&'static str>)> =
        pairs_and_triples(env_u64("STS_SETS_TRIPLES", 10) as usize).into_iter().enumerate().collect();
    if let Some(only) = env_list("STS_SETS_ONLY") {
        sets.retain(|(_, s)| only.contains(&s.join("+")));
    }
    // Only the sets that hold one of these effects (the rest unchanged by a change to them),
    // and none of those (the sets such a change leaves alone, rerun on their own).
    if let Some(with) = env_list("STS_SETS_WITH") {
        sets.retain(|(_, s)| s.iter().any(|e| with.iter().any(|w| w == e)));
    }
    if let Some(without) = env_list("STS_SETS_WITHOUT") {
        sets.retain(|(_, s)| !s.iter().any(|e| without.iter().any(|w| w == e)));
    }
    run_sets(&Sets {
        sets,
        first_seed: env_u64("STS_SETS_FIRST_SEED", 0),
        seeds: env_u64("STS_SETS_SEEDS", 5),
        paper_grid: std::env::var("STS_SETS_GRID").map_or(true, |g| g == "paper"),
        epochs: env_u64("STS_SETS_EPOCHS", 40) as usize,
        plant: plant_from_env(),
    });
}
