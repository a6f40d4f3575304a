//! A firmware image's flash and RAM use, read from its ELF's load segments: what
//! `cargo size` (cargo-binutils) shows per section, without installing it.

use std::path::Path;

use object::elf::{PF_W, PT_LOAD};
use object::read::elf::{ElfFile32, ProgramHeader};
use object::Endianness;

/// Bytes an image takes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MemoryUse {
    /// Bytes written to flash: every load segment's file contents (code, constants, the
    /// vector table and the initial values of `.data`).
    pub flash_bytes: u64,
    /// Bytes of RAM the program reserves: every writable load segment's memory size
    /// (`.data`, `.bss`, `.uninit`). The stack, which grows down from the top of RAM into
    /// what is left, is not counted.
    pub ram_bytes: u64,
}

/// The memory use of the 32-bit ELF at `elf`.
pub fn memory_use(elf: &Path) -> Result<MemoryUse, String> {
    let data = std::fs::read(elf).map_err(|e| format!("{}: {e}", elf.display()))?;
    let file =
        ElfFile32::<Endianness>::parse(&*data).map_err(|e| format!("{}: not a 32-bit ELF: {e}", elf.display()))?;
    let endian = file.endian();
    let mut use_ = MemoryUse { flash_bytes: 0, ram_bytes: 0 };
    for segment in file.elf_program_headers() {
        if segment.p_type(endian) != PT_LOAD {
            continue;
        }
        use_.flash_bytes += u64::from(segment.p_filesz(endian));
        if segment.p_flags(endian) & PF_W != 0 {
            use_.ram_bytes += u64::from(segment.p_memsz(endian));
        }
    }
    Ok(use_)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_file_that_is_not_an_elf_is_an_error_naming_it() {
        let path = std::env::temp_dir().join(format!("xtask-size-{}.elf", std::process::id()));
        std::fs::write(&path, b"not an elf").unwrap();
        let err = memory_use(&path).unwrap_err();
        let _ = std::fs::remove_file(&path);
        assert!(err.contains("xtask-size-") && err.contains("not a 32-bit ELF"), "{err}");
    }
}
