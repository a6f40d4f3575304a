//! The HIL harness looks for the firmware ELFs where `cargo xtask firmware` puts them.

use sts_hil::{FirmwareVariant, BRINGUP_ELF_ENV, FIRMWARE_ELF_ENV, FIRMWARE_TARGET};

#[test]
fn harness_defaults_are_the_xtask_outputs() {
    assert_eq!(FirmwareVariant::Twin.default_elf_relative(), xtask::QEMU_TWIN.elf);
    assert_eq!(FirmwareVariant::BringUp.default_elf_relative(), xtask::QEMU_BRINGUP.elf);
    assert_eq!(Some(FIRMWARE_ELF_ENV), xtask::QEMU_TWIN.env);
    assert_eq!(Some(BRINGUP_ELF_ENV), xtask::QEMU_BRINGUP.env);
    assert_eq!(FIRMWARE_TARGET, xtask::FIRMWARE_TARGET);
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap();
    assert_eq!(FirmwareVariant::Twin.default_elf(), root.join(xtask::QEMU_TWIN.elf));
}
