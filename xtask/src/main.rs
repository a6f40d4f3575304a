//! `cargo xtask`: the build tasks of sts-twin (the alias is in `.cargo/config.toml`).

use std::path::{Path, PathBuf};
use std::process::{Command, ExitCode};

use clap::{Parser, Subcommand, ValueEnum};
use xtask::{Image, BUILD_COMMAND, FIRMWARE_PROFILE, IMAGES, QEMU_BRINGUP, QEMU_TWIN, RISCV_VIRT_TWIN, STM32H7};

/// Build tasks of sts-twin that plain cargo at the root cannot do.
#[derive(Debug, Parser)]
#[command(name = "cargo xtask", bin_name = "cargo xtask")]
struct Cli {
    #[command(subcommand)]
    task: Task,
}

#[derive(Debug, Subcommand)]
enum Task {
    /// Build the firmware ELFs: the QEMU twin, the QEMU bring-up app, the STM32H7 app and the
    /// RISC-V twin.
    #[command(long_about = FIRMWARE_ABOUT)]
    Firmware(FirmwareArgs),
    /// Check that no crate of the root workspace has an import cycle between its top-level
    /// modules, and print each crate's module graph.
    Layering,
    /// Print the flash and RAM use of each built firmware image (from its ELF's load
    /// segments; the stack is not counted).
    Size,
    /// Run the full suites whose tables BENCHMARKS.md quotes, at HEAD, one after another, and
    /// record their output and a summary in target/suites/<commit> (hours).
    #[command(long_about = SUITES_ABOUT)]
    Suites(SuitesArgs),
}

const SUITES_ABOUT: &str = "\
Run the full suites whose tables BENCHMARKS.md quotes, at the checked-out commit, one after
another (hours on 2 cores), and record them: every figure from one commit.

Refuses a work tree with changes (it names them) unless --allow-dirty, which marks every output
dirty. Builds the test binaries once (cargo test --locked --release --no-run, per package),
then runs each suite in the configuration BENCHMARKS.md quotes (`--list` shows each with its
command and the section it feeds), its whole output shown and kept in
target/suites/<commit>/<name>.txt. At the end, target/suites/<commit>/SUMMARY.md gives the
commit, the date, the machine and, per run, its command (environment included), wall time,
pass or fail and the table lines it printed, as printed. A suite that fails (a target not
met) does not stop the others; the task exits non-zero at the end, naming the failures.

With --seeds N (a quick try) the output goes to target/suites/<commit>-seeds<N>, a dirty run's
to <commit>-dirty. Ctrl-C stops the runs with the task and leaves no SUMMARY.md.";

#[derive(Debug, clap::Args)]
struct SuitesArgs {
    /// Run only these suites (comma-separated or repeated; `--list` names them).
    #[arg(long, value_name = "NAME", value_delimiter = ',')]
    only: Vec<String>,
    /// List the suites, their commands and the BENCHMARKS.md sections they feed; run nothing.
    #[arg(long)]
    list: bool,
    /// Run N seeds instead of each suite's own count (refits at most N), for a quick try.
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u64).range(1..))]
    seeds: Option<u64>,
    /// Run on a work tree with changes, marking every output dirty.
    #[arg(long)]
    allow_dirty: bool,
}

const FIRMWARE_ABOUT: &str = "\
Build the firmware ELFs (thumbv7em-none-eabihf and riscv32imac-unknown-none-elf, profile
`firmware`) and print where they are.

The firmware apps are workspaces of their own (each with its Cargo.lock and a
.cargo/config.toml that sets the target and the runner), so a plain `cargo build` at the root
does not build them. This task runs, in each app's directory:

  bringup  firmware/qemu-app     cargo build --profile firmware --features bringup
                                 (then its ELF is copied to target/bringup/..., below)
  qemu     firmware/qemu-app     cargo build --profile firmware
  stm32h7  firmware/stm32h7-app  cargo build --profile firmware
  riscv-virt firmware/riscv-virt-app cargo build --profile firmware

All share one target directory (firmware/target), and with it every dependency they
have in common; the twin is built after the bring-up (also with --only bringup) so that
cargo's place holds it.

The ELFs land at fixed places (paths from the repository root):

  firmware/target/thumbv7em-none-eabihf/firmware/sts-twin-firmware
  firmware/target/bringup/thumbv7em-none-eabihf/firmware/sts-twin-firmware
  firmware/target/thumbv7em-none-eabihf/firmware/sts-twin-board-stm32h7
  firmware/target/riscv32imac-unknown-none-elf/firmware/sts-twin-firmware-riscv

The HIL harness (sts-twin hil, the hil-tests, the demo) takes the QEMU ELFs from there unless
STS_TWIN_FIRMWARE_ELF / STS_TWIN_BRINGUP_ELF / STS_TWIN_RISCV_FIRMWARE_ELF point elsewhere. It
never builds them: run this again after changing the firmware. Needs the Rust targets:
`rustup target add thumbv7em-none-eabihf riscv32imac-unknown-none-elf`.";

#[derive(Debug, clap::Args)]
struct FirmwareArgs {
    /// Build only this image (repeat for several); all by default.
    #[arg(long, value_enum, value_name = "IMAGE")]
    only: Vec<ImageName>,
    /// Pass `--locked` to cargo: fail instead of changing an app's Cargo.lock.
    #[arg(long)]
    locked: bool,
    /// Print the ELF paths, build nothing.
    #[arg(long)]
    paths: bool,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
enum ImageName {
    /// The twin on QEMU mps2-an386 (firmware/qemu-app).
    Qemu,
    /// The bring-up app on QEMU mps2-an386 (firmware/qemu-app, feature `bringup`).
    Bringup,
    /// The STM32H743ZI board (firmware/stm32h7-app).
    Stm32h7,
    /// The twin on QEMU RISC-V virt (firmware/riscv-virt-app).
    RiscvVirt,
}

impl ImageName {
    fn image(self) -> Image {
        match self {
            Self::Qemu => QEMU_TWIN,
            Self::Bringup => QEMU_BRINGUP,
            Self::Stm32h7 => STM32H7,
            Self::RiscvVirt => RISCV_VIRT_TWIN,
        }
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.task {
        Task::Firmware(args) => firmware(&args),
        Task::Layering => layering(),
        Task::Size => size(),
        Task::Suites(args) => suites(&args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(message) => {
            eprintln!("error: {message}");
            ExitCode::FAILURE
        }
    }
}

/// The repository root (this crate lives in `<root>/xtask`).
fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("xtask sits in the repository root").to_path_buf()
}

/// The root workspace's target directory: `CARGO_TARGET_DIR` where set, else `target`.
fn target_dir(root: &Path) -> PathBuf {
    match std::env::var_os("CARGO_TARGET_DIR") {
        Some(dir) if !dir.is_empty() => std::env::current_dir().unwrap_or_default().join(dir),
        _ => root.join("target"),
    }
}

fn suites(args: &SuitesArgs) -> Result<(), String> {
    let root = repo_root();
    let target = target_dir(&root);
    // Checked before anything else, also for --list.
    xtask::suites::select(&args.only)?;
    if args.list {
        if !args.only.is_empty() || args.allow_dirty {
            return Err("--list runs nothing: give it alone (or with --seeds, to see the changed commands)".into());
        }
        print!("{}", xtask::suites::listing(args.seeds, "target/release/sts-twin"));
        return Ok(());
    }
    let options =
        xtask::recording::Options { only: args.only.clone(), seeds: args.seeds, allow_dirty: args.allow_dirty };
    xtask::recording::run_suites(&root, &target, &options)
}

fn firmware(args: &FirmwareArgs) -> Result<(), String> {
    let root = repo_root();
    let images: Vec<Image> = if args.only.is_empty() {
        IMAGES.to_vec()
    } else {
        // An image built in another's place (the bring-up in the twin's) puts that one back.
        let chosen: Vec<Image> = args.only.iter().map(|n| n.image()).collect();
        IMAGES
            .into_iter()
            .filter(|i| chosen.contains(i) || chosen.iter().any(|c| c.elf != c.built && c.built == i.elf))
            .collect()
    };
    if !args.paths {
        for image in &images {
            check_target_installed(image.target)?;
        }
        for image in &images {
            build(&root, image, args.locked)?;
        }
    }
    println!("firmware ELFs (profile `{FIRMWARE_PROFILE}`):");
    for image in &images {
        let elf = root.join(image.elf);
        let note = match (elf.is_file(), image.env) {
            (false, _) => format!("  (not built: {BUILD_COMMAND} --only {})", image.name),
            (true, Some(env)) => format!("  (HIL default; {env} overrides)"),
            (true, None) => String::new(),
        };
        println!("  {:<10} {}{note}", image.name, elf.display());
    }
    Ok(())
}

fn size() -> Result<(), String> {
    let root = repo_root();
    println!("{:<10} {:>12} {:>12}  ELF", "image", "flash bytes", "RAM bytes");
    for image in IMAGES {
        let elf = root.join(image.elf);
        if !elf.is_file() {
            println!("{:<10} (not built: {BUILD_COMMAND} --only {})", image.name, image.name);
            continue;
        }
        let use_ = xtask::size::memory_use(&elf)?;
        println!("{:<10} {:>12} {:>12}  {}", image.name, use_.flash_bytes, use_.ram_bytes, image.elf);
    }
    Ok(())
}

/// The root workspace's members, from the `members = [...]` list of the root Cargo.toml.
fn workspace_members(root: &Path) -> Result<Vec<PathBuf>, String> {
    let manifest = root.join("Cargo.toml");
    let text = std::fs::read_to_string(&manifest).map_err(|e| format!("{}: {e}", manifest.display()))?;
    let start = text.find("members = [").ok_or_else(|| format!("{}: no `members = [`", manifest.display()))?;
    let list = &text[start..];
    let list = &list[..list.find(']').unwrap_or(list.len())];
    Ok(list
        .lines()
        .filter_map(|l| l.trim().strip_prefix('"').and_then(|l| l.split('"').next()))
        .map(|m| root.join(m))
        .collect())
}

fn layering() -> Result<(), String> {
    let root = repo_root();
    let mut cycles = Vec::new();
    for member in workspace_members(&root)? {
        let name = member.strip_prefix(&root).unwrap_or(&member).display().to_string();
        for root_file in ["src/lib.rs", "src/main.rs"].map(|f| member.join(f)).into_iter().filter(|f| f.is_file()) {
            let graph = xtask::layering::module_graph(&root_file);
            let file = root_file.file_name().unwrap_or_default().to_string_lossy();
            println!("{name} ({file}):");
            for (module, uses) in &graph.edges {
                let uses: Vec<&str> = uses.iter().map(String::as_str).collect();
                println!("  {module} -> {}", if uses.is_empty() { "-".to_string() } else { uses.join(", ") });
            }
            for group in graph.cycles() {
                cycles.push(format!("{name}: {}", group.join(" <-> ")));
            }
        }
    }
    if cycles.is_empty() {
        println!("no import cycle between the top-level modules of any crate");
        Ok(())
    } else {
        Err(format!("import cycles between top-level modules:\n  {}", cycles.join("\n  ")))
    }
}

/// Builds one image in its app's directory, where the app's `.cargo/config.toml` applies.
fn build(root: &Path, image: &Image, locked: bool) -> Result<(), String> {
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    let app_dir = root.join(image.app_dir);
    let target_dir = root.join(image.target_dir);
    let mut args = vec!["build", "--profile", FIRMWARE_PROFILE, "--target", image.target];
    if !image.features.is_empty() {
        args.extend(["--features", image.features]);
    }
    if locked {
        args.push("--locked");
    }
    let shown = format!("cargo {} --target-dir {}", args.join(" "), target_dir.display());
    eprintln!("xtask: {} ({}): {shown}", image.name, image.what);
    let status = Command::new(&cargo)
        .args(&args)
        .arg("--target-dir")
        .arg(&target_dir)
        .current_dir(&app_dir)
        // The image's place is fixed: no target or target directory from the environment.
        .env_remove("CARGO_BUILD_TARGET")
        .env_remove("CARGO_TARGET_DIR")
        .env_remove("CARGO_BUILD_TARGET_DIR")
        .status()
        .map_err(|e| format!("cannot run {}: {e}", Path::new(&cargo).display()))?;
    if !status.success() {
        return Err(format!("building {} failed ({status}) in {}: {shown}", image.name, app_dir.display()));
    }
    let built = root.join(image.built);
    if !built.is_file() {
        return Err(format!("{} built, but its ELF is not at {}", image.name, built.display()));
    }
    if image.elf != image.built {
        let elf = root.join(image.elf);
        let copied = elf.parent().map_or(Ok(()), std::fs::create_dir_all).and_then(|()| std::fs::copy(&built, &elf));
        copied.map_err(|e| format!("cannot copy {} to {}: {e}", built.display(), elf.display()))?;
    }
    Ok(())
}

/// Fails early, with the command to fix it, when the standard library of `target` is
/// missing from the toolchain's sysroot.
fn check_target_installed(target: &str) -> Result<(), String> {
    let rustc = std::env::var_os("RUSTC").unwrap_or_else(|| "rustc".into());
    let output = Command::new(&rustc)
        .args(["--print", "sysroot"])
        .output()
        .map_err(|e| format!("cannot run {}: {e}", Path::new(&rustc).display()))?;
    if !output.status.success() {
        // Leave the diagnosis to cargo.
        return Ok(());
    }
    let sysroot = PathBuf::from(String::from_utf8_lossy(&output.stdout).trim());
    let lib = sysroot.join("lib").join("rustlib").join(target).join("lib");
    if lib.is_dir() {
        Ok(())
    } else {
        Err(format!(
            "the Rust target {target} is not installed (no {}): run `rustup target add {target}`",
            lib.display()
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn suites_args(args: &[&str]) -> Result<SuitesArgs, String> {
        let cli = Cli::try_parse_from(["cargo xtask", "suites"].iter().chain(args)).map_err(|e| e.to_string())?;
        match cli.task {
            Task::Suites(a) => Ok(a),
            other => Err(format!("parsed as {other:?}")),
        }
    }

    #[test]
    fn suites_arguments() {
        let a = suites_args(&[]).unwrap();
        assert!(a.only.is_empty() && !a.list && a.seeds.is_none() && !a.allow_dirty);
        let a = suites_args(&["--only", "lab,sets", "--only", "reference", "--seeds", "2", "--allow-dirty"]).unwrap();
        assert_eq!(a.only, ["lab", "sets", "reference"]);
        assert_eq!(a.seeds, Some(2));
        assert!(a.allow_dirty);
        assert!(suites_args(&["--list"]).unwrap().list);
        for bad in [&["--seeds", "0"][..], &["--seeds", "x"], &["--seeds", "-1"], &["--only"], &["--bogus"]] {
            assert!(suites_args(bad).is_err(), "{bad:?} accepted");
        }
    }

    #[test]
    fn unknown_names_are_refused_before_anything_runs() {
        let a = suites_args(&["--only", "lab,nope"]).unwrap();
        let err = suites(&a).unwrap_err();
        assert!(err.starts_with("unknown suite `nope` (known: "), "{err}");
        let a = suites_args(&["--list", "--only", "lab"]).unwrap();
        assert!(suites(&a).unwrap_err().starts_with("--list runs nothing"));
    }
}
