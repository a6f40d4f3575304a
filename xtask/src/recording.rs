//! Running the [`crate::suites`] at one commit and recording them: `cargo xtask suites`.
//!
//! At the repository's HEAD (a work tree with changes is refused unless `--allow-dirty`, which
//! marks every output dirty) it builds the test binaries once, then runs each suite in turn,
//! its whole output (standard output and error, as printed) both on the terminal and in
//! `<target>/suites/<commit>/<name>.txt`, headed by the commit, the date, the machine and the
//! command. At the end `SUMMARY.md` there gives, per run, its command, wall time, pass or fail
//! and the table lines it printed, copied as printed. A run that fails does not stop the
//! others; the task fails at the end, naming them.
//!
//! The summary is written to a temporary file and renamed into place, and a summary left by an
//! earlier invocation in the same directory is removed first: a `SUMMARY.md` is always whole
//! and always describes the logs beside it. The children run in the task's process group, so
//! Ctrl-C at the terminal stops them with it, and no summary is written.
//!
//! Runs with `--seeds N` record in `<commit>-seeds<N>` and dirty ones in `<commit>-dirty`, so
//! that neither overwrites the logs of a full run at that commit.

use std::fmt::Write as _;
use std::fs::File;
use std::io::{Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::process::{Command, ExitStatus, Stdio};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use crate::suites::{self, Invocation, Run, Tables};

/// The summary's file name in the output directory.
pub const SUMMARY: &str = "SUMMARY.md";

/// What `cargo xtask suites` was asked.
#[derive(Clone, Debug, Default)]
pub struct Options {
    /// The runs to make (`--only`); every run when empty.
    pub only: Vec<String>,
    /// The seed count for a quick try (`--seeds`), instead of each run's own.
    pub seeds: Option<u64>,
    /// Run on a work tree with changes (`--allow-dirty`), marking every output dirty.
    pub allow_dirty: bool,
}

/// The commit the runs are at.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Commit {
    /// `git rev-parse HEAD`.
    pub full: String,
    /// `git rev-parse --short HEAD`.
    pub short: String,
    /// The work tree's changes, as `git status --porcelain` gives them (empty: clean).
    pub changes: Vec<String>,
}

impl Commit {
    pub fn dirty(&self) -> bool {
        !self.changes.is_empty()
    }

    /// `abc1234`, or `abc1234 (dirty: uncommitted changes)`.
    pub fn shown(&self) -> String {
        if self.dirty() {
            format!("{} (dirty: uncommitted changes)", self.short)
        } else {
            self.short.clone()
        }
    }
}

fn git(root: &Path, args: &[&str]) -> Result<String, String> {
    let out = Command::new("git")
        .args(args)
        .current_dir(root)
        .output()
        .map_err(|e| format!("cannot run git {}: {e}", args.join(" ")))?;
    if !out.status.success() {
        return Err(format!("git {} failed: {}", args.join(" "), String::from_utf8_lossy(&out.stderr).trim()));
    }
    Ok(String::from_utf8_lossy(&out.stdout).into_owned())
}

/// The commit checked out at `root` and the work tree's changes (untracked files included: a
/// new plant file changes what a run measures as much as an edit does).
pub fn commit_at(root: &Path) -> Result<Commit, String> {
    let full = git(root, &["rev-parse", "HEAD"])?.trim().to_string();
    let short = git(root, &["rev-parse", "--short", "HEAD"])?.trim().to_string();
    let changes = changed_files(&git(root, &["status", "--porcelain"])?);
    Ok(Commit { full, short, changes })
}

/// The lines of `git status --porcelain`, trimmed (`M path`, `?? path`).
pub fn changed_files(porcelain: &str) -> Vec<String> {
    porcelain.lines().map(str::trim).filter(|l| !l.is_empty()).map(str::to_string).collect()
}

/// The directory of one invocation's logs and summary, under `<target>/suites`.
pub fn output_dir_name(commit: &Commit, seeds: Option<u64>) -> String {
    let mut name = commit.short.clone();
    if commit.dirty() {
        name.push_str("-dirty");
    }
    if let Some(n) = seeds {
        let _ = write!(name, "-seeds{n}");
    }
    name
}

/// The machine, from the number of CPUs and `/proc/meminfo` and `/proc/cpuinfo` (empty where
/// there are none): `2 CPUs (model), 23.4 GiB RAM`.
pub fn describe_machine(cpus: usize, meminfo: &str, cpuinfo: &str) -> String {
    let ram = meminfo
        .lines()
        .find_map(|l| l.strip_prefix("MemTotal:"))
        .and_then(|v| v.trim().strip_suffix("kB"))
        .and_then(|kb| kb.trim().parse::<f64>().ok())
        .map_or("RAM unknown".to_string(), |kb| format!("{:.1} GiB RAM", kb / (1024.0 * 1024.0)));
    let model = cpuinfo
        .lines()
        .find_map(|l| l.strip_prefix("model name").and_then(|r| r.trim_start().strip_prefix(':')))
        .map(str::trim)
        .filter(|m| !m.is_empty());
    let cpus = format!("{cpus} CPU{}", if cpus == 1 { "" } else { "s" });
    match model {
        Some(m) => format!("{cpus} ({m}), {ram}"),
        None => format!("{cpus}, {ram}"),
    }
}

/// This machine, as [`describe_machine`] gives it.
pub fn this_machine() -> String {
    let cpus = std::thread::available_parallelism().map_or(0, |n| n.get());
    let read = |p: &str| std::fs::read_to_string(p).unwrap_or_default();
    describe_machine(cpus, &read("/proc/meminfo"), &read("/proc/cpuinfo"))
}

/// A time as `2026-12-08T11:14Z` (UTC, to the minute).
pub fn utc_minute(time: SystemTime) -> String {
    let secs = time.duration_since(UNIX_EPOCH).map_or(0, |d| d.as_secs());
    let (days, rest) = (secs / 86_400, secs % 86_400);
    // Days since 1970-01-01 to the civil date (H. Hinnant's algorithm).
    let z = days as i64 + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + i64::from(month <= 2);
    format!("{year:04}-{month:02}-{day:02}T{:02}:{:02}Z", rest / 3600, rest % 3600 / 60)
}

/// `1249 s (20.8 min)`.
pub fn wall(d: Duration) -> String {
    let s = d.as_secs_f64();
    if s >= 60.0 {
        format!("{s:.0} s ({:.1} min)", s / 60.0)
    } else {
        format!("{s:.1} s")
    }
}

/// What a run printed, read from libtest's output (or a script's, which is all its own).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Printed {
    /// The lines the tests (or the script) printed, without cargo's and libtest's own and
    /// without panic messages.
    pub lines: Vec<String>,
    /// Each panic's message, its lines joined.
    pub panics: Vec<String>,
    /// Tests passed and failed, from libtest's `test result:` lines (`None`: no such line).
    pub passed: Option<u64>,
    pub failed: Option<u64>,
}

/// Whether a libtest line (or what follows `test NAME ... `) is a test's end.
fn is_test_status(s: &str) -> bool {
    s == "ok" || s == "FAILED" || s == "ignored" || s.starts_with("ignored, ")
}

/// Ends the panic message being read, if any.
fn finish_panic(panic: &mut Option<Vec<String>>, panics: &mut Vec<String>) {
    if let Some(lines) = panic.take() {
        panics.push(lines.join(" ").trim().to_string());
    }
}

/// The count before `what` in libtest's `test result: ok. 2 passed; 0 failed; ...`.
fn count(result: &str, what: &str) -> Option<u64> {
    result.split(';').find_map(|part| {
        part.trim().trim_start_matches("ok. ").trim_start_matches("FAILED. ").strip_suffix(what)?.trim().parse().ok()
    })
}

/// The tests' own lines in the output of `cargo test -- --nocapture --test-threads=1`:
/// libtest prints `test NAME ... ` before a test runs, then the test's output follows on that
/// line, then `ok` or `FAILED` on a line of its own. Lines outside a test (cargo's, libtest's
/// `running N tests`, the failures' list) are left out, and so is a panic's message and
/// backtrace (collected into [`Printed::panics`]), and what the test prints after it.
pub fn read_test_output(text: &str) -> Printed {
    let mut printed = Printed::default();
    let mut in_test = false;
    // After a panic: `Some(message lines)` while its message is read, then the test's output
    // is over.
    let mut panic: Option<Vec<String>> = None;
    let mut after_panic = false;
    for line in text.lines() {
        let line = line.trim_end_matches('\r');
        if let Some(result) = line.strip_prefix("test result: ") {
            finish_panic(&mut panic, &mut printed.panics);
            in_test = false;
            for (total, what) in [(&mut printed.passed, " passed"), (&mut printed.failed, " failed")] {
                if let Some(n) = count(result, what) {
                    *total = Some(total.unwrap_or(0) + n);
                }
            }
            continue;
        }
        let line = if in_test {
            if is_test_status(line) {
                finish_panic(&mut panic, &mut printed.panics);
                in_test = false;
                continue;
            }
            line
        } else {
            match line.strip_prefix("test ").and_then(|rest| rest.split_once(" ... ")) {
                Some((_, after)) if is_test_status(after) => continue,
                Some((_, after)) => {
                    in_test = true;
                    after_panic = false;
                    after
                }
                None => continue,
            }
        };
        if line.starts_with("thread '") && line.contains(" panicked at ") {
            finish_panic(&mut panic, &mut printed.panics);
            panic = Some(Vec::new());
            after_panic = true;
            continue;
        }
        if let Some(message) = panic.as_mut() {
            if line.is_empty() || line.starts_with("stack backtrace:") || line.starts_with("note: ") {
                finish_panic(&mut panic, &mut printed.panics);
            } else {
                message.push(line.trim().to_string());
            }
            continue;
        }
        if !after_panic {
            printed.lines.push(line.to_string());
        }
    }
    finish_panic(&mut panic, &mut printed.panics);
    printed
}

/// A script's output: every line is its own.
pub fn read_script_output(text: &str) -> Printed {
    Printed { lines: text.lines().map(|l| l.trim_end_matches('\r').to_string()).collect(), ..Printed::default() }
}

/// The table lines among `lines`, as [`Tables`] picks them, without blank lines at either
/// end.
pub fn table_lines(lines: &[String], tables: &Tables) -> Vec<String> {
    let start = tables.from.and_then(|p| lines.iter().position(|l| l.starts_with(p)));
    let mut kept: Vec<String> = lines
        .iter()
        .enumerate()
        .filter(|(i, l)| start.is_some_and(|s| *i >= s) || tables.lines.iter().any(|p| l.starts_with(p)))
        .map(|(_, l)| l.clone())
        .collect();
    while kept.last().is_some_and(|l| l.trim().is_empty()) {
        kept.pop();
    }
    let lead = kept.iter().take_while(|l| l.trim().is_empty()).count();
    kept.drain(..lead);
    kept
}

/// How a run ended.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Outcome {
    Passed,
    /// Why, in a line.
    Failed(String),
}

/// A run's outcome from its exit status (`None`: killed by a signal) and what it printed. A
/// test run in which no test ran fails: its filter matched nothing.
pub fn outcome(run: &Run, code: Option<i32>, printed: &Printed) -> Outcome {
    let panics = || {
        if printed.panics.is_empty() {
            String::new()
        } else {
            format!(": {}", printed.panics.join("; "))
        }
    };
    match (code, run) {
        (Some(0), Run::Test { filter, .. }) if printed.passed.unwrap_or(0) + printed.failed.unwrap_or(0) == 0 => {
            Outcome::Failed(format!("no test ran: the filter `{filter}` matched none"))
        }
        (Some(0), _) => Outcome::Passed,
        (Some(c), Run::Test { .. }) if printed.failed.unwrap_or(0) > 0 => {
            Outcome::Failed(format!("{} test(s) failed (exit status {c}){}", printed.failed.unwrap_or(0), panics()))
        }
        (Some(c), _) => Outcome::Failed(format!("exit status {c}{}", panics())),
        (None, _) => Outcome::Failed(format!("killed by a signal{}", panics())),
    }
}

/// One run's record in the summary.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RunRecord {
    pub name: String,
    /// The section it feeds, as [`suites::Suite::feeds_shown`] gives it.
    pub feeds: String,
    /// The command as a shell line, environment included.
    pub command: String,
    pub wall: Duration,
    pub outcome: Outcome,
    /// The table lines it printed.
    pub tables: Vec<String>,
    /// The log's file name, beside the summary.
    pub log: String,
}

/// The summary's head: what every run shares.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SummaryHead {
    pub commit: Commit,
    pub started: String,
    pub finished: String,
    pub machine: String,
    pub seeds: Option<u64>,
    /// The runs not made (`--only`).
    pub left_out: Vec<String>,
    /// The builds: command and wall time.
    pub builds: Vec<(String, Duration)>,
}

/// The whole `SUMMARY.md`.
pub fn summary_markdown(head: &SummaryHead, runs: &[RunRecord]) -> String {
    let mut md = String::new();
    let c = &head.commit;
    let _ = writeln!(md, "# The suites at {}\n", c.shown());
    let _ = writeln!(md, "Written by `cargo xtask suites`; each run's whole output is in the log named below.\n");
    let _ = writeln!(md, "- commit: {}", c.full);
    if c.dirty() {
        let _ = writeln!(md, "- **dirty**: the work tree had changes, so no figure here is the commit's alone:");
        for change in &c.changes {
            let _ = writeln!(md, "  - `{change}`");
        }
    }
    let _ = writeln!(md, "- date: {} to {} (UTC)", head.started, head.finished);
    let _ = writeln!(md, "- machine: {}", head.machine);
    match head.seeds {
        Some(n) => {
            let _ = writeln!(
                md,
                "- seeds: **{n}** (`--seeds {n}`, a quick try: not the configurations BENCHMARKS.md quotes)"
            );
        }
        None => {
            let _ = writeln!(md, "- seeds: as BENCHMARKS.md quotes them");
        }
    }
    let failed: Vec<&str> =
        runs.iter().filter(|r| matches!(r.outcome, Outcome::Failed(_))).map(|r| r.name.as_str()).collect();
    let _ = writeln!(
        md,
        "- runs: {} passed, {} failed{}",
        runs.len() - failed.len(),
        failed.len(),
        if failed.is_empty() { String::new() } else { format!(" ({})", failed.join(", ")) }
    );
    if !head.left_out.is_empty() {
        let _ = writeln!(md, "- not run (`--only`): {}", head.left_out.join(", "));
    }
    for (command, took) in &head.builds {
        let _ = writeln!(md, "- build: `{command}`, {}", wall(*took));
    }
    let _ = writeln!(md, "\n| run | feeds | result | wall |\n|---|---|---|---:|");
    for r in runs {
        let result = match &r.outcome {
            Outcome::Passed => "passed",
            Outcome::Failed(_) => "**FAILED**",
        };
        let _ = writeln!(md, "| {} | {} | {result} | {} |", r.name, r.feeds.replace('|', "\\|"), wall(r.wall));
    }
    for r in runs {
        let _ = writeln!(md, "\n## {}\n", r.name);
        let _ = writeln!(md, "Feeds BENCHMARKS.md {}.\n", r.feeds);
        let _ = writeln!(md, "```text\n{}\n```\n", r.command);
        let _ = match &r.outcome {
            Outcome::Passed => writeln!(md, "Passed, {} wall; log `{}`.", wall(r.wall), r.log),
            Outcome::Failed(why) => writeln!(md, "**FAILED** ({why}), {} wall; log `{}`.", wall(r.wall), r.log),
        };
        if r.tables.is_empty() {
            let _ = writeln!(md, "\nNo table lines printed.");
        } else {
            let _ = writeln!(md, "\n```text\n{}\n```", r.tables.join("\n"));
        }
    }
    md
}

/// Writes `text` to `path` whole or not at all: into `<path>.tmp`, synced, then renamed.
pub fn write_whole(path: &Path, text: &str) -> Result<(), String> {
    let tmp = path.with_extension("md.tmp");
    let written = File::create(&tmp).and_then(|mut f| {
        f.write_all(text.as_bytes())?;
        f.sync_all()
    });
    written.map_err(|e| format!("cannot write {}: {e}", tmp.display()))?;
    std::fs::rename(&tmp, path).map_err(|e| format!("cannot rename {} to {}: {e}", tmp.display(), path.display()))
}

fn remove_if_there(path: &Path) -> Result<(), String> {
    match std::fs::remove_file(path) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => Err(format!("cannot remove {}: {e}", path.display())),
        _ => Ok(()),
    }
}

/// Runs `inv` in `root`, its standard output and error going (in the order printed) to the
/// log at `log` after `header`, and from there to this process's standard output as they
/// come. `append`: add to the log instead of starting it. Returns the exit status, what the
/// command printed and its wall time.
pub fn run_logged(
    inv: &Invocation,
    root: &Path,
    log: &Path,
    header: &str,
    append: bool,
) -> Result<(ExitStatus, String, Duration), String> {
    let shown = || format!("{} (log {})", inv.shown(), log.display());
    let mut file = std::fs::OpenOptions::new()
        .create(true)
        .append(append)
        .write(true)
        .truncate(!append)
        .open(log)
        .map_err(|e| format!("cannot open {}: {e}", log.display()))?;
    file.write_all(header.as_bytes()).map_err(|e| format!("cannot write {}: {e}", log.display()))?;
    let start = file.stream_position().map_err(|e| format!("{}: {e}", log.display()))?;
    let clone = || file.try_clone().map_err(|e| format!("{}: {e}", log.display()));
    let (out, err) = (clone()?, clone()?);
    let mut command = Command::new(&inv.program);
    command.args(&inv.args).current_dir(root).stdin(Stdio::null()).stdout(out).stderr(err);
    // The runs' own variables only: none left over from the shell (see suites::CLEARED_ENV).
    for (name, _) in std::env::vars_os() {
        if name.to_str().is_some_and(suites::is_cleared) {
            command.env_remove(&name);
        }
    }
    command.envs(inv.env.iter().map(|(k, v)| (k, v)));
    let began = Instant::now();
    // The child stays in this process group: Ctrl-C at the terminal stops it with the task.
    let mut child = command.spawn().map_err(|e| format!("cannot run {}: {e}", shown()))?;
    let mut reader = File::open(log).map_err(|e| format!("cannot read {}: {e}", log.display()))?;
    reader.seek(SeekFrom::Start(start)).map_err(|e| format!("{}: {e}", log.display()))?;
    let mut printed = Vec::new();
    let mut buf = vec![0u8; 1 << 16];
    let mut terminal = std::io::stdout();
    let status = loop {
        // Whether it has ended, then everything it wrote until then.
        let ended = child.try_wait().map_err(|e| format!("waiting for {}: {e}", shown()))?;
        loop {
            let n = reader.read(&mut buf).map_err(|e| format!("cannot read {}: {e}", log.display()))?;
            if n == 0 {
                break;
            }
            // The terminal may be gone (a closed pipe); the log is what counts.
            let _ = terminal.write_all(&buf[..n]).and_then(|()| terminal.flush());
            printed.extend_from_slice(&buf[..n]);
        }
        if let Some(status) = ended {
            break status;
        }
        std::thread::sleep(Duration::from_millis(200));
    };
    Ok((status, String::from_utf8_lossy(&printed).into_owned(), began.elapsed()))
}

/// Where the release binary `name` of the root workspace is built.
fn release_bin(target_dir: &Path, name: &str) -> PathBuf {
    target_dir.join("release").join(format!("{name}{}", std::env::consts::EXE_SUFFIX))
}

/// Puts the file `built` at `kept` too: a hard link, or a copy where there can be none.
fn keep(built: &Path, kept: &Path) -> Result<(), String> {
    remove_if_there(kept)?;
    std::fs::hard_link(built, kept)
        .or_else(|_| std::fs::copy(built, kept).map(drop))
        .map_err(|e| format!("cannot copy {} to {}: {e}", built.display(), kept.display()))
}

/// `path` relative to `root` when under it (the children run in `root`).
fn shown_path(root: &Path, path: &Path) -> String {
    path.strip_prefix(root).unwrap_or(path).display().to_string()
}

/// `cargo xtask suites`: the runs `options` selects at `root`'s HEAD, built in and recorded
/// under `target_dir`.
pub fn run_suites(root: &Path, target_dir: &Path, options: &Options) -> Result<(), String> {
    let selected = suites::select(&options.only)?;
    let commit = commit_at(root)?;
    if commit.dirty() && !options.allow_dirty {
        return Err(format!(
            "the work tree has changes, so the figures would not be the commit's ({}); commit or stash them, or pass \
             --allow-dirty to run anyway with every output marked dirty. Changed:\n  {}",
            commit.short,
            commit.changes.join("\n  ")
        ));
    }
    let dir = target_dir.join("suites").join(output_dir_name(&commit, options.seeds));
    std::fs::create_dir_all(&dir).map_err(|e| format!("cannot create {}: {e}", dir.display()))?;
    // A summary in this directory describes logs that this invocation replaces.
    let summary = dir.join(SUMMARY);
    remove_if_there(&summary)?;
    remove_if_there(&summary.with_extension("md.tmp"))?;
    let started = utc_minute(SystemTime::now());
    let machine = this_machine();
    let head_line = |what: &str| format!("# {what} at {}, {started}, {machine}\n", commit.shown());
    eprintln!("xtask: suites at {} ({}), {machine}; logs in {}", commit.shown(), commit.full, dir.display());

    let mut builds = Vec::new();
    let build_log = dir.join("build.txt");
    for (i, inv) in suites::builds(&selected).iter().enumerate() {
        eprintln!("xtask: build: {}", inv.shown());
        let header = format!("{}# {}\n", if i == 0 { head_line("build") } else { String::new() }, inv.shown());
        let (status, _, took) = run_logged(inv, root, &build_log, &header, i > 0)?;
        if !status.success() {
            return Err(format!("the build failed ({status}): {}; see {}", inv.shown(), build_log.display()));
        }
        builds.push((inv.shown(), took));
    }
    // A script's binary, kept beside the logs: a later `cargo test` of its package may put a
    // build with its tests' features in its place (cargo replaces the file, so a hard link
    // keeps this build).
    let mut bins = Vec::new();
    for suite in &selected {
        if let Run::Script { bin_name, .. } = suite.run
            && !bins.iter().any(|(n, _)| *n == bin_name)
        {
            let kept = dir.join(format!("{bin_name}{}", std::env::consts::EXE_SUFFIX));
            keep(&release_bin(target_dir, bin_name), &kept)?;
            bins.push((bin_name, shown_path(root, &kept)));
        }
    }

    let mut records = Vec::new();
    for (i, suite) in selected.iter().enumerate() {
        let bin = match suite.run {
            Run::Script { bin_name, .. } => bins.iter().find(|(n, _)| *n == bin_name).map_or("", |(_, p)| p.as_str()),
            Run::Test { .. } => "",
        };
        let inv = suite.invocation(options.seeds, bin);
        let log_name = format!("{}.txt", suite.name);
        eprintln!(
            "xtask: suite {} ({} of {}), for {}: {}",
            suite.name,
            i + 1,
            selected.len(),
            suite.feeds_shown(),
            inv.shown()
        );
        let header = format!("{}# {}\n", head_line(suite.name), inv.shown());
        let (status, text, took) = run_logged(&inv, root, &dir.join(&log_name), &header, false)?;
        let printed = match suite.run {
            Run::Test { .. } => read_test_output(&text),
            Run::Script { .. } => read_script_output(&text),
        };
        let outcome = outcome(&suite.run, status.code(), &printed);
        match &outcome {
            Outcome::Passed => eprintln!("xtask: suite {}: passed, {}", suite.name, wall(took)),
            Outcome::Failed(why) => eprintln!("xtask: suite {}: FAILED ({why}), {}", suite.name, wall(took)),
        }
        records.push(RunRecord {
            name: suite.name.to_string(),
            feeds: suite.feeds_shown(),
            command: inv.shown(),
            wall: took,
            outcome,
            tables: table_lines(&printed.lines, &suite.tables),
            log: log_name,
        });
    }

    let head = SummaryHead {
        commit: commit.clone(),
        started,
        finished: utc_minute(SystemTime::now()),
        machine,
        seeds: options.seeds,
        left_out: suites::SUITES
            .iter()
            .filter(|s| !selected.iter().any(|t| t.name == s.name))
            .map(|s| s.name.to_string())
            .collect(),
        builds,
    };
    write_whole(&summary, &summary_markdown(&head, &records))?;
    eprintln!("xtask: summary in {}", summary.display());
    for r in &records {
        let result = if r.outcome == Outcome::Passed { "passed" } else { "FAILED" };
        eprintln!("  {:<19} {result:<7} {}", r.name, wall(r.wall));
    }
    let failed: Vec<String> = records
        .iter()
        .filter_map(|r| match &r.outcome {
            Outcome::Failed(why) => Some(format!("{} ({why})", r.name)),
            Outcome::Passed => None,
        })
        .collect();
    if failed.is_empty() {
        Ok(())
    } else {
        Err(format!("{} of {} suites failed: {}", failed.len(), records.len(), failed.join("; ")))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::suites::{Suite, SUITES};

    /// Output as `cargo test -- --ignored --nocapture --test-threads=1` prints it for the
    /// hidden-effect suite (shortened), a target missed.
    const FAILED_SUITE: &str = "\
    Finished `release` profile [optimized] target(s) in 0.31s
     Running tests/tests.rs (target/release/deps/tests-0123456789abcdef)

running 1 test
test diagnose_hidden_effects::full_suite ... reference model: held-out waveform RMS on clean data 8.60 nm
workflow: lab (a twin fitted on each case's own data)
  hidden: setpoint-delay:delay_us=312
setpoint-delay           seed  0: verdict setpoint-delay         twin's RMS 20.1 nm, refit held-out RMS 5.4 nm
none                     seed  0: verdict none                   twin's RMS 8.4 nm

confusion matrix (rows: hidden effect, columns: verdict; 1 seeds each)
                         coulomb- presslid
setpoint-delay                   0        1
none                             0        0
setpoint-delay         correct 100.0% (target 90%)
none                   correct   0.0% (target 95%)

refit with --effect <verdict>: the diagnosed twin's RMS -> held-out RMS (fall; ratio to the clean held-out RMS 8.6 nm)
  setpoint-delay         seed 0: 20.1 -> 5.4 nm, fall 73%, 0.63x clean
names of effects the machine does not have: 0 of 2 verdicts

overall: 1/2 correct; every refit's error fell by at least 50% and ended within 1.5x clean (0 of 1 hunting, 1.5x not asserted): true

thread 'diagnose_hidden_effects::full_suite' (4242) panicked at host-tools/assess/tests/diagnose_hidden_effects.rs:340:9:
only 1 of 2 verdicts right
stack backtrace:
   0: std::panicking::begin_panic
note: Some details are omitted, run with `RUST_BACKTRACE=full` for a verbose backtrace.
FAILED

failures:

failures:
    diagnose_hidden_effects::full_suite

test result: FAILED. 0 passed; 1 failed; 0 ignored; 0 measured; 40 filtered out; finished in 61.20s

error: test failed, to rerun pass `-p sts-assess --test tests`
";

    /// Two tests of one filter, both passing; the second printed nothing.
    const TWO_TESTS: &str = "\
running 2 tests
test foreign_machine::an_in_band_mode ... clean machine: twin's held-out RMS 32.1 nm
mode 17 Hz        clean twin 78.8 nm; structural-mode
ok
test foreign_machine::the_loop_works ... ok

test result: ok. 2 passed; 0 failed; 0 ignored; 0 measured; 120 filtered out; finished in 95.00s

";

    fn suite(name: &str) -> &'static Suite {
        SUITES.iter().find(|s| s.name == name).unwrap()
    }

    #[test]
    fn the_tests_lines_and_the_panic() {
        let p = read_test_output(FAILED_SUITE);
        assert_eq!(p.lines.first().unwrap(), "reference model: held-out waveform RMS on clean data 8.60 nm");
        assert_eq!(p.lines.last().unwrap(), "");
        assert!(p.lines.iter().any(|l| l.starts_with("overall: 1/2 correct")));
        assert!(!p.lines.iter().any(|l| l.contains("panicked") || l.contains("backtrace") || l.contains("Running")));
        assert_eq!(p.panics, ["only 1 of 2 verdicts right"]);
        assert_eq!((p.passed, p.failed), (Some(0), Some(1)));
        let o = outcome(&suite("lab").run, Some(101), &p);
        assert_eq!(o, Outcome::Failed("1 test(s) failed (exit status 101): only 1 of 2 verdicts right".into()));

        let p = read_test_output(TWO_TESTS);
        assert_eq!(
            p.lines,
            ["clean machine: twin's held-out RMS 32.1 nm", "mode 17 Hz        clean twin 78.8 nm; structural-mode"]
        );
        assert_eq!((p.passed, p.failed), (Some(2), Some(0)));
        assert_eq!(outcome(&suite("foreign-machine").run, Some(0), &p), Outcome::Passed);
    }

    #[test]
    fn a_filter_matching_nothing_fails() {
        let p = read_test_output(
            "running 0 tests\n\ntest result: ok. 0 passed; 0 failed; 0 ignored; 0 measured; 9 filtered out\n",
        );
        assert_eq!(p.lines, Vec::<String>::new());
        let Outcome::Failed(why) = outcome(&suite("reference").run, Some(0), &p) else { panic!("passed") };
        assert!(why.contains("diagnose_hidden_effects::full_suite"), "{why}");
        assert_eq!(outcome(&suite("reference").run, None, &p), Outcome::Failed("killed by a signal".into()));
        // A script has no test count.
        let s = read_script_output("default    paper  seed 1:  12.0 s,    8.1 nm: nothing named; stop none\n");
        assert_eq!(outcome(&suite("false-names").run, Some(0), &s), Outcome::Passed);
        assert_eq!(outcome(&suite("false-names").run, Some(1), &s), Outcome::Failed("exit status 1".into()));
    }

    #[test]
    fn the_hidden_effect_tables_are_copied_as_printed() {
        let p = read_test_output(FAILED_SUITE);
        let t = table_lines(&p.lines, &suite("lab").tables);
        assert_eq!(t[0], "reference model: held-out waveform RMS on clean data 8.60 nm");
        assert_eq!(t[1], "workflow: lab (a twin fitted on each case's own data)");
        assert_eq!(t[2], "confusion matrix (rows: hidden effect, columns: verdict; 1 seeds each)");
        assert_eq!(t[4], "setpoint-delay                   0        1");
        assert!(!t.iter().any(|l| l.contains("seed  0: verdict") || l.contains("hidden:")), "{t:#?}");
        assert_eq!(t.last().unwrap(), "overall: 1/2 correct; every refit's error fell by at least 50% and ended within 1.5x clean (0 of 1 hunting, 1.5x not asserted): true");
        // Every line: the whole output, blank ends trimmed.
        let every =
            table_lines(&["".into(), "a".into(), "".into(), "b".into(), "".into()], &suite("false-names").tables);
        assert_eq!(every, ["a", "", "b"]);
        // A marker never printed: only the lines kept wherever they are.
        assert_eq!(table_lines(&["workflow: x".into(), "y".into()], &suite("lab").tables), ["workflow: x"]);
    }

    #[test]
    fn the_summary_holds_every_run_and_is_written_whole() {
        let commit = Commit {
            full: "0123456789abcdef".into(),
            short: "0123456".into(),
            changes: vec!["M xtask/src/main.rs".into()],
        };
        let head = SummaryHead {
            commit,
            started: "2026-12-08T11:14Z".into(),
            finished: "2026-12-08T12:00Z".into(),
            machine: "2 CPUs, 23.4 GiB RAM".into(),
            seeds: Some(1),
            left_out: vec!["sets".into()],
            builds: vec![("cargo test --no-run".into(), Duration::from_secs(90))],
        };
        let runs = [
            RunRecord {
                name: "lab".into(),
                feeds: suite("lab").feeds_shown(),
                command: "STS_SUITE_SEEDS=1 cargo test".into(),
                wall: Duration::from_secs(1249),
                outcome: Outcome::Failed("only 1 of 2 verdicts right".into()),
                tables: vec!["confusion matrix".into(), "none  1".into()],
                log: "lab.txt".into(),
            },
            RunRecord {
                name: "false-names".into(),
                feeds: suite("false-names").feeds_shown(),
                command: "bash bench/false-names.sh".into(),
                wall: Duration::from_millis(2500),
                outcome: Outcome::Passed,
                tables: vec![],
                log: "false-names.txt".into(),
            },
        ];
        let md = summary_markdown(&head, &runs);
        assert!(md.starts_with("# The suites at 0123456 (dirty: uncommitted changes)\n"), "{md}");
        for part in [
            "- commit: 0123456789abcdef\n",
            "  - `M xtask/src/main.rs`\n",
            "- date: 2026-12-08T11:14Z to 2026-12-08T12:00Z (UTC)\n",
            "- machine: 2 CPUs, 23.4 GiB RAM\n",
            "- seeds: **1** (`--seeds 1`",
            "- runs: 1 passed, 1 failed (lab)\n",
            "- not run (`--only`): sets\n",
            "- build: `cargo test --no-run`, 90 s (1.5 min)\n",
            "| lab | \"The hidden-effect suite\" (the lab's workflow, 20 seeds) | **FAILED** | 1249 s (20.8 min) |\n",
            "| false-names | \"No false names on clean machines\" | passed | 2.5 s |\n",
            "## lab\n\nFeeds BENCHMARKS.md \"The hidden-effect suite\" (the lab's workflow, 20 seeds).\n\n```text\nSTS_SUITE_SEEDS=1 cargo test\n```\n\n**FAILED** (only 1 of 2 verdicts right), 1249 s (20.8 min) wall; log `lab.txt`.\n\n```text\nconfusion matrix\nnone  1\n```\n",
            "## false-names\n",
            "No table lines printed.",
        ] {
            assert!(md.contains(part), "missing {part:?} in\n{md}");
        }

        let dir = std::env::temp_dir().join(format!("xtask-summary-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join(SUMMARY);
        write_whole(&path, &md).unwrap();
        assert_eq!(std::fs::read_to_string(&path).unwrap(), md);
        assert!(!path.with_extension("md.tmp").exists());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn dates_machines_and_directories() {
        assert_eq!(utc_minute(UNIX_EPOCH), "1970-01-01T00:00Z");
        assert_eq!(utc_minute(UNIX_EPOCH + Duration::from_secs(1_700_000_000)), "2023-11-14T22:13Z");
        assert_eq!(utc_minute(UNIX_EPOCH + Duration::from_secs(951_782_400)), "2000-02-29T00:00Z");
        let meminfo = "MemTotal:       24522092 kB\nMemFree:        1 kB\n";
        let cpuinfo = "processor\t: 0\nmodel name\t: AMD EPYC 7B13\n";
        assert_eq!(describe_machine(2, meminfo, cpuinfo), "2 CPUs (AMD EPYC 7B13), 23.4 GiB RAM");
        assert_eq!(describe_machine(1, "", ""), "1 CPU, RAM unknown");
        let clean = Commit { full: "f".repeat(40), short: "fffffff".into(), changes: changed_files("\n") };
        assert!(!clean.dirty());
        assert_eq!(output_dir_name(&clean, None), "fffffff");
        let dirty = Commit { changes: changed_files(" M a.rs\n?? b.toml\n"), ..clean };
        assert_eq!(dirty.changes, ["M a.rs", "?? b.toml"]);
        assert_eq!(output_dir_name(&dirty, Some(2)), "fffffff-dirty-seeds2");
        assert_eq!(wall(Duration::from_millis(61_500)), "62 s (1.0 min)");
    }
}
