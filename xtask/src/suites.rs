//! The table of `cargo xtask suites`: every run whose printed tables BENCHMARKS.md quotes, with
//! the configuration it quotes them for (environment included), in the order of BENCHMARKS.md.
//! What runs them and records their output is [`crate::recording`].
//!
//! A run is a test binary's test (most of them `#[ignore]`d: hours in all on 2 cores) or a
//! script of `bench/`. Each names the BENCHMARKS.md section its figures feed and which of its
//! printed lines are the tables ([`Tables`]); `--seeds N` turns a run's seed count down for a
//! quick try ([`Seeds`]).

use std::fmt::Write as _;

/// One run of `cargo xtask suites`.
#[derive(Clone, Copy, Debug)]
pub struct Suite {
    /// The name `--only` takes; also the log's file name (`<name>.txt`).
    pub name: &'static str,
    /// The BENCHMARKS.md section (its heading) whose tables this run's figures are.
    pub feeds: &'static str,
    /// The part of the section, for people (empty: the whole section).
    pub part: &'static str,
    /// The source file of the test or script, from the repository root.
    pub source: &'static str,
    /// What runs.
    pub run: Run,
    /// The configuration, as BENCHMARKS.md gives it.
    pub env: &'static [(&'static str, &'static str)],
    /// How `--seeds N` changes `env`.
    pub seeds: Seeds,
    /// Which printed lines are the tables.
    pub tables: Tables,
}

/// What a [`Suite`] runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Run {
    /// `cargo test --locked --release -p PACKAGE --test TEST FILTER -- [--ignored] --nocapture
    /// --test-threads=1`: one test at a time, its output as it prints it.
    Test { package: &'static str, test: &'static str, filter: &'static str, ignored: bool },
    /// `bash SCRIPT BIN`, where BIN is the release build of `PACKAGE`'s binary `BIN_NAME`
    /// (`cargo build --locked --release -p PACKAGE --bin BIN_NAME`).
    Script { script: &'static str, package: &'static str, bin_name: &'static str },
}

/// How `--seeds N` changes a [`Suite`]'s environment.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Seeds {
    /// The run has no seed count (`--seeds` leaves it alone).
    Fixed,
    /// `var` is the seed count, set to N; `fit_var`, the count of seeds refitted, to at most N.
    Count { var: &'static str, fit_var: Option<&'static str> },
    /// `var` is a space-separated list of seeds, set to N seeds from `first`.
    List { var: &'static str, first: u64 },
}

/// Which of a run's printed lines are its tables: the suites print their tables, and these
/// lines are copied as printed (no figure is recomputed).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Tables {
    /// Lines kept wherever they are printed: those starting with one of these.
    pub lines: &'static [&'static str],
    /// Every line from the first that starts with this on (`""`: every line printed).
    pub from: Option<&'static str>,
}

/// Every printed line.
const EVERY_LINE: Tables = Tables { lines: &[], from: Some("") };
/// The hidden-effect suite's tables: the clean twin's error and the workflow, then the
/// confusion matrix, the rates, the refits and the total (not the per-case lines above them).
const HIDDEN_EFFECT_TABLES: Tables =
    Tables { lines: &["reference model:", "workflow:"], from: Some("confusion matrix") };

const HIDDEN_EFFECTS: Run =
    Run::Test { package: "sts-assess", test: "tests", filter: "diagnose_hidden_effects::full_suite", ignored: true };
const HIDDEN_EFFECTS_SOURCE: &str = "host-tools/assess/tests/diagnose_hidden_effects.rs";
const HIDDEN_EFFECTS_SEEDS: Seeds = Seeds::Count { var: "STS_SUITE_SEEDS", fit_var: Some("STS_SUITE_FIT_SEEDS") };
const SETS: Run =
    Run::Test { package: "sts-assess", test: "tests", filter: "explain_several_effects::full_sets", ignored: true };
const SETS_SOURCE: &str = "host-tools/assess/tests/explain_several_effects.rs";
const SETS_SEEDS: Seeds = Seeds::Count { var: "STS_SETS_SEEDS", fit_var: None };
/// The effects the refit tables of "The hidden-effect suite" have rows for.
const REFIT_EFFECTS: &str = "coulomb-friction,presliding-hysteresis,force-ripple,thermal-drift,axis-coupling,\
loop-delay,structural-mode,sensor-gain";
/// The other plant of "Tried as a lab would: another plant".
const PLANT_60KG: &str = "host-tools/assess/tests/plants/slide-60kg.toml";

/// Every run, in the order of BENCHMARKS.md.
pub const SUITES: [Suite; 14] = [
    Suite {
        name: "foreign-machine",
        feeds: "The loop on a foreign machine",
        part: "the changed machines, the co-processor in the machine's loop, the tool-post mode and the late setpoint",
        source: "host-tools/cli/tests/foreign_machine.rs",
        run: Run::Test { package: "sts-twin", test: "tests", filter: "foreign_machine::", ignored: false },
        env: &[],
        seeds: Seeds::Fixed,
        tables: EVERY_LINE,
    },
    Suite {
        name: "foreign-ball-screw",
        feeds: "The loop on a foreign machine",
        part: "the second foreign machine, a ball-screw drive",
        source: "host-tools/cli/tests/foreign_ball_screw.rs",
        run: Run::Test { package: "sts-twin", test: "tests", filter: "foreign_ball_screw::", ignored: false },
        env: &[],
        seeds: Seeds::Fixed,
        tables: EVERY_LINE,
    },
    Suite {
        name: "foreign-seeds",
        feeds: "The loop on a foreign machine",
        part: "the lab's workflow on both foreign machines, 20 seeds",
        source: "host-tools/cli/tests/foreign_suite.rs",
        run: Run::Test { package: "sts-twin", test: "tests", filter: "foreign_suite::", ignored: true },
        env: &[("STS_FOREIGN_SEEDS", "20")],
        seeds: Seeds::Count { var: "STS_FOREIGN_SEEDS", fit_var: None },
        // The rates; each case's line stays in the run's log.
        tables: Tables { lines: &[], from: Some("seeds ") },
    },
    Suite {
        name: "reference",
        feeds: "The hidden-effect suite",
        part: "reference workflow, 20 seeds",
        source: HIDDEN_EFFECTS_SOURCE,
        run: HIDDEN_EFFECTS,
        env: &[("STS_SUITE_SEEDS", "20"), ("STS_SUITE_FIT_SEEDS", "0"), ("STS_SUITE_GRID", "paper")],
        seeds: HIDDEN_EFFECTS_SEEDS,
        tables: HIDDEN_EFFECT_TABLES,
    },
    Suite {
        name: "lab",
        feeds: "The hidden-effect suite",
        part: "the lab's workflow, 20 seeds",
        source: HIDDEN_EFFECTS_SOURCE,
        run: HIDDEN_EFFECTS,
        env: &[
            ("STS_SUITE_WORKFLOW", "lab"),
            ("STS_SUITE_SEEDS", "20"),
            ("STS_SUITE_FIT_SEEDS", "0"),
            ("STS_SUITE_GRID", "paper"),
        ],
        seeds: HIDDEN_EFFECTS_SEEDS,
        tables: HIDDEN_EFFECT_TABLES,
    },
    Suite {
        name: "lab-refits",
        feeds: "The hidden-effect suite",
        part: "refits in the lab's workflow, 20 seeds per effect",
        source: HIDDEN_EFFECTS_SOURCE,
        run: HIDDEN_EFFECTS,
        env: &[
            ("STS_SUITE_WORKFLOW", "lab"),
            ("STS_SUITE_SEEDS", "20"),
            ("STS_SUITE_FIT_SEEDS", "20"),
            ("STS_SUITE_GRID", "paper"),
            ("STS_SUITE_EFFECTS", REFIT_EFFECTS),
        ],
        seeds: HIDDEN_EFFECTS_SEEDS,
        tables: HIDDEN_EFFECT_TABLES,
    },
    Suite {
        name: "reference-refits",
        feeds: "The hidden-effect suite",
        part: "refits in the reference workflow, 20 seeds per effect",
        source: HIDDEN_EFFECTS_SOURCE,
        run: HIDDEN_EFFECTS,
        env: &[
            ("STS_SUITE_SEEDS", "20"),
            ("STS_SUITE_FIT_SEEDS", "20"),
            ("STS_SUITE_GRID", "paper"),
            ("STS_SUITE_EFFECTS", REFIT_EFFECTS),
        ],
        seeds: HIDDEN_EFFECTS_SEEDS,
        tables: HIDDEN_EFFECT_TABLES,
    },
    Suite {
        name: "modes-delays",
        feeds: "Modes and delays told apart",
        part: "reference workflow, 6 seeds, every case refitted",
        source: HIDDEN_EFFECTS_SOURCE,
        run: HIDDEN_EFFECTS,
        env: &[
            ("STS_SUITE_EFFECTS", "structural-mode,structural-mode-in-band,loop-delay,setpoint-delay"),
            ("STS_SUITE_SEEDS", "6"),
            ("STS_SUITE_FIT_SEEDS", "6"),
            ("STS_SUITE_GRID", "paper"),
        ],
        seeds: HIDDEN_EFFECTS_SEEDS,
        tables: HIDDEN_EFFECT_TABLES,
    },
    Suite {
        name: "lab-in-band",
        feeds: "Modes and delays told apart",
        part: "the in-band mode in the lab's workflow, 20 seeds",
        source: HIDDEN_EFFECTS_SOURCE,
        run: HIDDEN_EFFECTS,
        env: &[
            ("STS_SUITE_WORKFLOW", "lab"),
            ("STS_SUITE_EFFECTS", "structural-mode-in-band,none"),
            ("STS_SUITE_SEEDS", "20"),
            ("STS_SUITE_FIT_SEEDS", "20"),
            ("STS_SUITE_GRID", "paper"),
        ],
        seeds: HIDDEN_EFFECTS_SEEDS,
        tables: HIDDEN_EFFECT_TABLES,
    },
    Suite {
        name: "lab-setpoint",
        feeds: "The late setpoint in the lab's workflow",
        part: "",
        source: HIDDEN_EFFECTS_SOURCE,
        run: HIDDEN_EFFECTS,
        env: &[
            ("STS_SUITE_WORKFLOW", "lab"),
            ("STS_SUITE_EFFECTS", "setpoint-delay,none"),
            ("STS_SUITE_SEEDS", "20"),
            ("STS_SUITE_FIT_SEEDS", "20"),
            ("STS_SUITE_GRID", "paper"),
        ],
        seeds: HIDDEN_EFFECTS_SEEDS,
        tables: HIDDEN_EFFECT_TABLES,
    },
    Suite {
        name: "false-names",
        feeds: "No false names on clean machines",
        part: "",
        source: "bench/false-names.sh",
        run: Run::Script { script: "bench/false-names.sh", package: "sts-twin", bin_name: "sts-twin" },
        env: &[("SEEDS", "1 2")],
        seeds: Seeds::List { var: "SEEDS", first: 1 },
        tables: EVERY_LINE,
    },
    Suite {
        name: "sets",
        feeds: "Several effects at once",
        part: "every pair and 10 triples, seeds 0-4",
        source: SETS_SOURCE,
        run: SETS,
        env: &[("STS_SETS_SEEDS", "5"), ("STS_SETS_TRIPLES", "10"), ("STS_SETS_GRID", "paper")],
        seeds: SETS_SEEDS,
        // The per-set lines are the rows the section's counts and quotes come from.
        tables: Tables { lines: &[], from: Some("clean twin:") },
    },
    Suite {
        name: "lab-60kg",
        feeds: "Tried as a lab would: another plant",
        part: "the lab's workflow on the 60 kg slide, 20 seeds",
        source: HIDDEN_EFFECTS_SOURCE,
        run: HIDDEN_EFFECTS,
        env: &[
            ("STS_PLANT", PLANT_60KG),
            ("STS_SUITE_WORKFLOW", "lab"),
            ("STS_SUITE_SEEDS", "20"),
            ("STS_SUITE_FIT_SEEDS", "0"),
            ("STS_SUITE_GRID", "paper"),
        ],
        seeds: HIDDEN_EFFECTS_SEEDS,
        tables: HIDDEN_EFFECT_TABLES,
    },
    Suite {
        name: "sets-60kg",
        feeds: "Tried as a lab would: another plant",
        part: "the several-effects sets on the 60 kg slide, seed 0",
        source: SETS_SOURCE,
        run: SETS,
        env: &[
            ("STS_PLANT", PLANT_60KG),
            ("STS_SETS_SEEDS", "1"),
            ("STS_SETS_TRIPLES", "10"),
            ("STS_SETS_GRID", "paper"),
        ],
        seeds: SETS_SEEDS,
        tables: Tables { lines: &[], from: Some("clean twin:") },
    },
];

/// Environment variables the runs read: cleared for every run, so that what is set in the
/// shell (a `STS_SUITE_EFFECTS` left from a try) cannot narrow a run without its record saying
/// so. Each run then sets its own.
pub const CLEARED_ENV: [&str; 4] = ["STS_PLANT", "PLANTS", "GRIDS", "SEEDS"];
/// Prefixes of the variables cleared likewise.
pub const CLEARED_ENV_PREFIXES: [&str; 3] = ["STS_SUITE_", "STS_SETS_", "STS_FOREIGN_"];

/// Whether the run leaves `name` out of its children's environment.
pub fn is_cleared(name: &str) -> bool {
    CLEARED_ENV.contains(&name) || CLEARED_ENV_PREFIXES.iter().any(|p| name.starts_with(p))
}

/// The names `--only` takes, comma-separated.
pub fn known_names() -> String {
    SUITES.iter().map(|s| s.name).collect::<Vec<_>>().join(", ")
}

/// The runs `--only` names (each once, in the table's order), or every run when `only` is
/// empty. An unknown name is an error that lists the known ones.
pub fn select(only: &[String]) -> Result<Vec<&'static Suite>, String> {
    let named: Vec<&str> = only.iter().map(|n| n.trim()).filter(|n| !n.is_empty()).collect();
    if named.is_empty() && !only.is_empty() {
        return Err(format!("--only names no suite (known: {})", known_names()));
    }
    let only = named;
    let unknown: Vec<&str> = only.iter().copied().filter(|n| !SUITES.iter().any(|s| s.name == *n)).collect();
    if !unknown.is_empty() {
        return Err(format!(
            "unknown suite{} {} (known: {}; `cargo xtask suites --list` describes them)",
            if unknown.len() > 1 { "s" } else { "" },
            unknown.iter().map(|n| format!("`{n}`")).collect::<Vec<_>>().join(", "),
            known_names()
        ));
    }
    Ok(SUITES.iter().filter(|s| only.is_empty() || only.contains(&s.name)).collect())
}

/// A command to run: the program, its arguments, and the environment it sets.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Invocation {
    pub program: String,
    pub args: Vec<String>,
    pub env: Vec<(String, String)>,
}

impl Invocation {
    /// As a shell line: `VAR=value ... program args`, quoted where a shell needs it.
    pub fn shown(&self) -> String {
        let mut line = String::new();
        for (k, v) in &self.env {
            let _ = write!(line, "{k}={} ", shell_quote(v));
        }
        line.push_str(&shell_quote(&self.program));
        for a in &self.args {
            line.push(' ');
            line.push_str(&shell_quote(a));
        }
        line
    }
}

/// `s` as one shell word.
pub fn shell_quote(s: &str) -> String {
    let plain = |c: char| c.is_ascii_alphanumeric() || "_-./,:+=@%".contains(c);
    if !s.is_empty() && s.chars().all(plain) {
        s.to_string()
    } else {
        format!("'{}'", s.replace('\'', r"'\''"))
    }
}

fn strings(args: &[&str]) -> Vec<String> {
    args.iter().map(|a| a.to_string()).collect()
}

impl Suite {
    /// The environment this run sets: its own, with `--seeds N` applied.
    pub fn env(&self, seeds: Option<u64>) -> Vec<(String, String)> {
        let mut env: Vec<(String, String)> = self.env.iter().map(|(k, v)| (k.to_string(), v.to_string())).collect();
        let Some(n) = seeds else { return env };
        let mut set = |var: &str, value: String| match env.iter_mut().find(|(k, _)| k == var) {
            Some(entry) => entry.1 = value,
            None => env.push((var.to_string(), value)),
        };
        match self.seeds {
            Seeds::Fixed => {}
            Seeds::Count { var, fit_var } => {
                set(var, n.to_string());
                if let Some(fit_var) = fit_var {
                    let fit = self.env.iter().find(|(k, _)| *k == fit_var).and_then(|(_, v)| v.parse::<u64>().ok());
                    set(fit_var, fit.map_or(n, |f| f.min(n)).to_string());
                }
            }
            Seeds::List { var, first } => {
                let list: Vec<String> = (first..first.saturating_add(n)).map(|s| s.to_string()).collect();
                set(var, list.join(" "));
            }
        }
        env
    }

    /// The command of this run; `bin_dir` is where the release binaries are (a script's
    /// `BIN` argument).
    pub fn invocation(&self, seeds: Option<u64>, bin: &str) -> Invocation {
        let args = match self.run {
            Run::Test { package, test, filter, ignored } => {
                let mut args = strings(&["test", "--locked", "--release", "-p", package, "--test", test, filter, "--"]);
                if ignored {
                    args.push("--ignored".into());
                }
                args.extend(strings(&["--nocapture", "--test-threads=1"]));
                args
            }
            Run::Script { script, .. } => strings(&[script, bin]),
        };
        let program = match self.run {
            Run::Test { .. } => "cargo",
            Run::Script { .. } => "bash",
        };
        Invocation { program: program.into(), args, env: self.env(seeds) }
    }

    /// The section this run feeds, with its part: `"Section" (part)`.
    pub fn feeds_shown(&self) -> String {
        if self.part.is_empty() {
            format!("\"{}\"", self.feeds)
        } else {
            format!("\"{}\" ({})", self.feeds, self.part)
        }
    }
}

/// The builds the runs need, each once, before any runs: per package, its test binaries as
/// the runs build them (the same flags, so that a run finds them fresh), then the binaries the
/// scripts run (built last: `cargo test` of the same package may leave a build of the binary
/// with its tests' features in the same place).
pub fn builds(suites: &[&Suite]) -> Vec<Invocation> {
    let mut tests: Vec<(&str, Vec<&str>)> = Vec::new();
    let mut bins: Vec<(&str, &str)> = Vec::new();
    for suite in suites {
        match suite.run {
            Run::Test { package, test, .. } => match tests.iter_mut().find(|(p, _)| *p == package) {
                Some((_, names)) if names.contains(&test) => {}
                Some((_, names)) => names.push(test),
                None => tests.push((package, vec![test])),
            },
            Run::Script { package, bin_name, .. } => {
                if !bins.contains(&(package, bin_name)) {
                    bins.push((package, bin_name));
                }
            }
        }
    }
    let mut out = Vec::new();
    for (package, names) in tests {
        let mut args = strings(&["test", "--locked", "--release", "--no-run", "-p", package]);
        for name in names {
            args.extend(strings(&["--test", name]));
        }
        out.push(Invocation { program: "cargo".into(), args, env: Vec::new() });
    }
    for (package, bin_name) in bins {
        let args = strings(&["build", "--locked", "--release", "-p", package, "--bin", bin_name]);
        out.push(Invocation { program: "cargo".into(), args, env: Vec::new() });
    }
    out
}

/// The `--list` text: each run's name, the section it feeds, and its command.
pub fn listing(seeds: Option<u64>, bin: &str) -> String {
    let mut text = String::new();
    for s in &SUITES {
        let _ = writeln!(text, "{:<19} {}", s.name, s.feeds_shown());
        let _ = writeln!(text, "{:<19} {}", "", s.invocation(seeds, bin).shown());
    }
    text
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    fn root() -> &'static Path {
        Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap()
    }

    #[test]
    fn names_are_unique_and_plain() {
        for (i, s) in SUITES.iter().enumerate() {
            assert!(SUITES[i + 1..].iter().all(|o| o.name != s.name), "{} twice", s.name);
            assert!(s.name.chars().all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '-'), "{}", s.name);
        }
    }

    #[test]
    fn select_keeps_the_tables_order_and_names_unknown_ones() {
        let names = |only: &[&str]| -> Result<Vec<&str>, String> {
            let only: Vec<String> = only.iter().map(|s| s.to_string()).collect();
            select(&only).map(|v| v.iter().map(|s| s.name).collect())
        };
        assert_eq!(names(&[]).unwrap().len(), SUITES.len());
        assert_eq!(names(&["sets", "lab", "sets"]).unwrap(), ["lab", "sets"]);
        assert_eq!(names(&[" lab ", ""]).unwrap(), ["lab"]);
        let err = names(&["lab", "labb", "nope"]).unwrap_err();
        assert!(err.starts_with("unknown suites `labb`, `nope` (known: foreign-machine, "), "{err}");
        assert!(err.contains("reference-refits"), "{err}");
        assert!(names(&["Lab"]).unwrap_err().starts_with("unknown suite `Lab` "));
        // `--only ""` or `--only ,` is no way to run everything.
        assert!(names(&[""]).unwrap_err().starts_with("--only names no suite (known: foreign-machine, "));
    }

    #[test]
    fn the_commands_are_those_benchmarks_gives() {
        let reference = SUITES.iter().find(|s| s.name == "reference").unwrap();
        assert_eq!(
            reference.invocation(None, "target/release/sts-twin").shown(),
            "STS_SUITE_SEEDS=20 STS_SUITE_FIT_SEEDS=0 STS_SUITE_GRID=paper cargo test --locked --release -p sts-assess \
             --test tests diagnose_hidden_effects::full_suite -- --ignored --nocapture --test-threads=1"
        );
        let foreign = SUITES.iter().find(|s| s.name == "foreign-machine").unwrap();
        assert_eq!(
            foreign.invocation(Some(1), "x").shown(),
            "cargo test --locked --release -p sts-twin --test tests foreign_machine:: -- --nocapture --test-threads=1"
        );
        let names = SUITES.iter().find(|s| s.name == "false-names").unwrap();
        assert_eq!(
            names.invocation(None, "target/release/sts-twin").shown(),
            "SEEDS='1 2' bash bench/false-names.sh target/release/sts-twin"
        );
    }

    #[test]
    fn seeds_override_the_count_and_cap_the_refits() {
        let get = |name: &str, seeds| SUITES.iter().find(|s| s.name == name).unwrap().env(seeds);
        let value = |env: &[(String, String)], k: &str| env.iter().find(|(n, _)| n == k).map(|(_, v)| v.clone());
        let lab = get("lab-in-band", Some(2));
        assert_eq!(value(&lab, "STS_SUITE_SEEDS").as_deref(), Some("2"));
        assert_eq!(value(&lab, "STS_SUITE_FIT_SEEDS").as_deref(), Some("2"));
        assert_eq!(value(&lab, "STS_SUITE_EFFECTS").as_deref(), Some("structural-mode-in-band,none"));
        let reference = get("reference", Some(3));
        assert_eq!(value(&reference, "STS_SUITE_FIT_SEEDS").as_deref(), Some("0"));
        assert_eq!(value(&get("sets", Some(1)), "STS_SETS_SEEDS").as_deref(), Some("1"));
        assert_eq!(value(&get("false-names", Some(3)), "SEEDS").as_deref(), Some("1 2 3"));
        assert_eq!(get("foreign-machine", Some(3)), get("foreign-machine", None));
        // Without --seeds, the table's own.
        assert_eq!(value(&get("sets", None), "STS_SETS_SEEDS").as_deref(), Some("5"));
    }

    #[test]
    fn builds_once_per_package_and_the_scripts_binary_last() {
        let all: Vec<&Suite> = SUITES.iter().collect();
        let shown: Vec<String> = builds(&all).iter().map(Invocation::shown).collect();
        assert_eq!(
            shown,
            [
                "cargo test --locked --release --no-run -p sts-twin --test tests",
                "cargo test --locked --release --no-run -p sts-assess --test tests",
                "cargo build --locked --release -p sts-twin --bin sts-twin",
            ]
        );
        let lab = select(&["lab".to_string()]).unwrap();
        assert_eq!(builds(&lab).len(), 1);
    }

    #[test]
    fn quoting() {
        assert_eq!(shell_quote("a,b+c"), "a,b+c");
        assert_eq!(shell_quote("1 2"), "'1 2'");
        assert_eq!(shell_quote("it's"), r"'it'\''s'");
        assert_eq!(shell_quote(""), "''");
    }

    #[test]
    fn cleared_environment() {
        assert!(is_cleared("STS_SUITE_EFFECTS") && is_cleared("STS_SETS_ONLY") && is_cleared("STS_PLANT"));
        assert!(is_cleared("SEEDS") && !is_cleared("STS_TWIN_FIRMWARE_ELF") && !is_cleared("PATH"));
        for s in &SUITES {
            for (k, _) in s.env {
                assert!(is_cleared(k), "{}: {k} is set but not cleared first", s.name);
            }
        }
    }

    /// The table against the repository: each source exists, names the test or is the
    /// script, and reads every variable the run sets; each section is a heading of
    /// BENCHMARKS.md; each plant file exists.
    #[test]
    fn the_table_matches_the_repository() {
        let benchmarks = std::fs::read_to_string(root().join("BENCHMARKS.md")).unwrap();
        for s in &SUITES {
            let source = std::fs::read_to_string(root().join(s.source)).unwrap_or_else(|e| panic!("{}: {e}", s.source));
            assert!(
                benchmarks.lines().any(|l| l.trim_start_matches('#').trim() == s.feeds),
                "{}: no heading `{}` in BENCHMARKS.md",
                s.name,
                s.feeds
            );
            // The variables may be read in a shared module of the same tests directory.
            let dir = root().join(s.source).parent().unwrap().to_path_buf();
            let mut texts = vec![source.clone()];
            for entry in walk(&dir) {
                texts.push(std::fs::read_to_string(entry).unwrap_or_default());
            }
            for (k, v) in s.env {
                assert!(
                    texts.iter().any(|t| t.contains(&format!("\"{k}\"")) || t.contains(&format!("${{{k}"))),
                    "{}: nothing reads {k}",
                    s.name
                );
                if *k == "STS_PLANT" {
                    assert!(root().join(v).is_file(), "{}: no plant file {v}", s.name);
                }
            }
            match s.run {
                Run::Test { filter, .. } => {
                    let (module, test) = filter.split_once("::").unwrap();
                    assert!(
                        s.source.ends_with(&format!("/{module}.rs")),
                        "{}: {filter} is not in {}",
                        s.name,
                        s.source
                    );
                    if !test.is_empty() {
                        assert!(source.contains(&format!("fn {test}()")), "{}: no test {test} in {}", s.name, s.source);
                    }
                }
                Run::Script { script, .. } => assert_eq!(script, s.source),
            }
        }
    }

    fn walk(dir: &Path) -> Vec<std::path::PathBuf> {
        let mut out = Vec::new();
        for entry in std::fs::read_dir(dir).unwrap().flatten() {
            let path = entry.path();
            if path.is_dir() {
                out.extend(walk(&path));
            } else if path.extension().is_some_and(|e| e == "rs") {
                out.push(path);
            }
        }
        out
    }
}
