//! Empty: it exists so that cargo takes the `[build-dependencies]` of Cargo.toml into
//! account, which unify the host-side crates' features with the workspace's (see there).
fn main() {}
