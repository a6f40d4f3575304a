//! `sts-twin regress`.

/// Arguments of `sts-twin regress`.
#[derive(Debug, clap::Args)]
pub struct Args {}

/// Runs `sts-twin regress`.
pub fn run(_args: &Args) -> anyhow::Result<()> {
    anyhow::bail!("`sts-twin regress` is not built yet")
}
