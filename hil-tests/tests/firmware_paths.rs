//! The HIL harness looks for the firmware ELFs where `cargo xtask firmware` puts them.

use sts_hil::board::qemu::QemuBoard;
use sts_hil::{FirmwareVariant, BRINGUP_ELF_ENV, FIRMWARE_ELF_ENV, FIRMWARE_TARGET, RISCV_FIRMWARE_ELF_ENV};

#[test]
fn harness_defaults_are_the_xtask_outputs() {
    let (twin, bringup) = (FirmwareVariant::Twin, FirmwareVariant::BringUp);
    for arm in [QemuBoard::An386, QemuBoard::An500] {
        assert_eq!(twin.default_elf_relative(arm), Some(xtask::QEMU_TWIN.elf));
        assert_eq!(bringup.default_elf_relative(arm), Some(xtask::QEMU_BRINGUP.elf));
        assert_eq!(twin.env(arm), xtask::QEMU_TWIN.env);
        assert_eq!(bringup.env(arm), xtask::QEMU_BRINGUP.env);
        assert_eq!(arm.rust_target(), xtask::QEMU_TWIN.target);
    }
    let virt = QemuBoard::RiscvVirt;
    assert_eq!(twin.default_elf_relative(virt), Some(xtask::RISCV_VIRT_TWIN.elf));
    assert_eq!(twin.env(virt), xtask::RISCV_VIRT_TWIN.env);
    assert_eq!(virt.rust_target(), xtask::RISCV_VIRT_TWIN.target);
    assert_eq!(bringup.default_elf_relative(virt), None);
    assert_eq!((Some(FIRMWARE_ELF_ENV), Some(BRINGUP_ELF_ENV)), (xtask::QEMU_TWIN.env, xtask::QEMU_BRINGUP.env));
    assert_eq!(Some(RISCV_FIRMWARE_ELF_ENV), xtask::RISCV_VIRT_TWIN.env);
    assert_eq!(FIRMWARE_TARGET, xtask::FIRMWARE_TARGET);
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap();
    assert_eq!(twin.default_elf(virt), Some(root.join(xtask::RISCV_VIRT_TWIN.elf)));
}
