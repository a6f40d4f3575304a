//! The build tasks' library: where `cargo xtask firmware` puts the firmware ELFs, the
//! module-layering check of `cargo xtask layering` ([`layering`]), and the full suites of
//! `cargo xtask suites` ([`suites`], the table; [`recording`], running and recording them).
//!
//! The firmware apps (`firmware/qemu-app`, `firmware/stm32h7-app` for [`FIRMWARE_TARGET`],
//! `firmware/riscv-virt-app` for [`RISCV_TARGET`]) are workspaces of their own; each image lands in a fixed place under its
//! app's own `target` directory, given here relative to the repository root. The HIL harness
//! (`sts_hil`) looks for the QEMU images at the same places (the hil-tests check that
//! the two agree).

pub mod layering;
pub mod recording;
pub mod size;
pub mod suites;

/// The Arm firmware's Rust target (`rustup target add thumbv7em-none-eabihf`).
pub const FIRMWARE_TARGET: &str = "thumbv7em-none-eabihf";
/// The RISC-V firmware's Rust target (`rustup target add riscv32imac-unknown-none-elf`).
pub const RISCV_TARGET: &str = "riscv32imac-unknown-none-elf";
/// The cargo profile of the firmware images (defined in each app's Cargo.toml).
pub const FIRMWARE_PROFILE: &str = "firmware";
/// The command that builds every image, run at the repository root.
pub const BUILD_COMMAND: &str = "cargo xtask firmware";

/// One firmware image: an app crate built with some features into some target directory.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Image {
    /// The name `cargo xtask firmware --only` takes.
    pub name: &'static str,
    /// What it is, for people.
    pub what: &'static str,
    /// The app crate's directory.
    pub app_dir: &'static str,
    /// Its Rust target.
    pub target: &'static str,
    /// Its cargo features (`--features`), empty for none.
    pub features: &'static str,
    /// The target directory it is built in: one for every image (`firmware/target`, also the
    /// apps' own `.cargo/config.toml` `target-dir`), so that the images share every compiled
    /// dependency they have in common: the bring-up costs seconds, the second app a fraction.
    pub target_dir: &'static str,
    /// The binary's name.
    pub bin: &'static str,
    /// Where cargo leaves the ELF: `<target_dir>/<target>/firmware/<bin>`.
    pub built: &'static str,
    /// Where the ELF is kept: `built`, or a copy of it for an image whose `built` place
    /// another image of the same target directory takes next.
    pub elf: &'static str,
    /// The environment variable that points the HIL harness at another ELF of this kind.
    pub env: Option<&'static str>,
}

/// The twin on QEMU mps2-an386: the product, what the HIL tests and the demo run.
pub const QEMU_TWIN: Image = Image {
    name: "qemu",
    what: "twin firmware, QEMU mps2-an386",
    app_dir: "firmware/qemu-app",
    target: FIRMWARE_TARGET,
    features: "",
    target_dir: "firmware/target",
    bin: "sts-twin-firmware",
    built: "firmware/target/thumbv7em-none-eabihf/firmware/sts-twin-firmware",
    elf: "firmware/target/thumbv7em-none-eabihf/firmware/sts-twin-firmware",
    env: Some("STS_TWIN_FIRMWARE_ELF"),
};

/// The bring-up application on QEMU (feature `bringup`), for the platform tests. Built in the
/// twin's target directory and copied out of cargo's place before the twin takes it.
pub const QEMU_BRINGUP: Image = Image {
    name: "bringup",
    what: "bring-up firmware, QEMU mps2-an386",
    app_dir: "firmware/qemu-app",
    target: FIRMWARE_TARGET,
    features: "bringup",
    target_dir: "firmware/target",
    bin: "sts-twin-firmware",
    built: "firmware/target/thumbv7em-none-eabihf/firmware/sts-twin-firmware",
    elf: "firmware/target/bringup/thumbv7em-none-eabihf/firmware/sts-twin-firmware",
    env: Some("STS_TWIN_BRINGUP_ELF"),
};

/// The real board, STM32H743ZI through embassy-stm32 (build only; flash with probe-rs).
pub const STM32H7: Image = Image {
    name: "stm32h7",
    what: "firmware for the STM32H743ZI board",
    app_dir: "firmware/stm32h7-app",
    target: FIRMWARE_TARGET,
    features: "",
    target_dir: "firmware/target",
    bin: "sts-twin-board-stm32h7",
    built: "firmware/target/thumbv7em-none-eabihf/firmware/sts-twin-board-stm32h7",
    elf: "firmware/target/thumbv7em-none-eabihf/firmware/sts-twin-board-stm32h7",
    env: None,
};

/// The twin on QEMU RISC-V `virt` (RV32IMAC).
pub const RISCV_VIRT_TWIN: Image = Image {
    name: "riscv-virt",
    what: "twin firmware, QEMU RISC-V virt",
    app_dir: "firmware/riscv-virt-app",
    target: RISCV_TARGET,
    features: "",
    target_dir: "firmware/target",
    bin: "sts-twin-firmware-riscv",
    built: "firmware/target/riscv32imac-unknown-none-elf/firmware/sts-twin-firmware-riscv",
    elf: "firmware/target/riscv32imac-unknown-none-elf/firmware/sts-twin-firmware-riscv",
    env: Some("STS_TWIN_RISCV_FIRMWARE_ELF"),
};

/// Every image, in build order: the bring-up before the twin, so that cargo's place in their
/// shared target directory holds the twin at the end.
pub const IMAGES: [Image; 4] = [QEMU_BRINGUP, QEMU_TWIN, STM32H7, RISCV_VIRT_TWIN];

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn elf_paths_follow_cargo_layout() {
        for image in IMAGES {
            let expected = format!("{}/{}/{FIRMWARE_PROFILE}/{}", image.target_dir, image.target, image.bin);
            assert_eq!(image.built, expected, "{}", image.name);
            // `cargo build` in the app's directory builds into the same place.
            let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
            let config = std::fs::read_to_string(root.join(image.app_dir).join(".cargo/config.toml")).unwrap();
            let relative = config
                .lines()
                .find_map(|l| l.trim().strip_prefix("target-dir = \"")?.strip_suffix('"'))
                .expect("the app's .cargo/config.toml sets target-dir");
            let app_parent = std::path::Path::new(image.app_dir).parent().unwrap();
            let resolved = relative.strip_prefix("../").map(|r| app_parent.join(r)).expect("a sibling directory");
            assert_eq!(resolved, std::path::Path::new(image.target_dir), "{}", image.name);
        }
        // Where two images share cargo's place, the one kept there is built last.
        for (i, a) in IMAGES.iter().enumerate() {
            for b in &IMAGES[i + 1..] {
                if a.built == b.built {
                    assert!(a.elf != a.built && b.elf == b.built, "{} and {}", a.name, b.name);
                }
            }
        }
        let elfs: std::collections::BTreeSet<&str> = IMAGES.iter().map(|i| i.elf).collect();
        assert_eq!(elfs.len(), IMAGES.len(), "every image keeps its own ELF");
    }
}
