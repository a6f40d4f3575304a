//! `sts-twin measure`.

/// Arguments of `sts-twin measure`.
#[derive(Debug, clap::Args)]
pub struct Args {}

/// Runs `sts-twin measure`.
pub fn run(_args: &Args) -> anyhow::Result<()> {
    anyhow::bail!("`sts-twin measure` is not built yet")
}
