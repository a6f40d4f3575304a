//! Which CPU QEMU's threads run on.
//!
//! Under `-icount sleep=off` every servo tick hands the guest over between QEMU's vCPU
//! thread and its main thread twice (the clock warps through the main loop while the guest
//! idles in `WFI`). When the kernel spreads the two threads over two CPUs, each hand-off
//! wakes an idle CPU, which in a virtual machine is a trip through the hypervisor; on one
//! CPU it is a context switch, so lockstep ticks run a little faster and a stream of ticks
//! about twice as fast.

use std::sync::atomic::{AtomicBool, Ordering};

/// Where QEMU's threads run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
#[non_exhaustive]
pub enum QemuPlacement {
    /// All on one CPU (the last of the harness's set) while this QEMU is the only one of the
    /// process that is so placed and the set holds at least two CPUs; anywhere otherwise.
    /// Two QEMUs on the two CPUs of a 2-core machine would each share its CPU with a
    /// lockstep host thread, which then waits for time slices (too slow for the offset
    /// calibration's settling check), and one CPU for QEMU and its host is slower still.
    #[default]
    OneCpu,
    /// Wherever the kernel puts them.
    Anywhere,
    /// All on this CPU (it must be in the harness's set, or the start fails).
    Cpu(usize),
}

/// The CPU a QEMU is pinned to; for [`QemuPlacement::OneCpu`] it holds the process's one
/// pinned place until dropped (with the QEMU it belongs to).
#[derive(Debug)]
pub(crate) struct CpuPin {
    pub(crate) cpu: usize,
    claimed: bool,
}

static ONE_CPU_TAKEN: AtomicBool = AtomicBool::new(false);

impl Drop for CpuPin {
    fn drop(&mut self) {
        if self.claimed {
            ONE_CPU_TAKEN.store(false, Ordering::Release);
        }
    }
}

impl QemuPlacement {
    /// The CPU to pin a new QEMU to, if any.
    pub(crate) fn resolve(self) -> Option<CpuPin> {
        match self {
            Self::Anywhere => None,
            Self::Cpu(cpu) => Some(CpuPin { cpu, claimed: false }),
            Self::OneCpu => {
                let cpus = allowed_cpus();
                let &cpu = cpus.last()?;
                if cpus.len() < 2 || ONE_CPU_TAKEN.swap(true, Ordering::AcqRel) {
                    return None;
                }
                Some(CpuPin { cpu, claimed: true })
            }
        }
    }
}

/// The CPUs this thread may run on.
fn allowed_cpus() -> Vec<usize> {
    // SAFETY: a zeroed cpu_set_t is a valid empty set; sched_getaffinity fills it.
    let mut set: libc::cpu_set_t = unsafe { std::mem::zeroed() };
    let got = unsafe { libc::sched_getaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &mut set) };
    if got != 0 {
        return Vec::new();
    }
    (0..libc::CPU_SETSIZE as usize).filter(|&cpu| unsafe { libc::CPU_ISSET(cpu, &set) }).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_cpu_pins_one_qemu_at_a_time_to_an_allowed_cpu() {
        let cpus = allowed_cpus();
        assert!(!cpus.is_empty());
        let first = QemuPlacement::OneCpu.resolve();
        if cpus.len() == 1 {
            assert!(first.is_none());
            return;
        }
        let cpu = first.as_ref().expect("a CPU").cpu;
        assert!(cpus.contains(&cpu), "{cpu} not in {cpus:?}");
        assert!(QemuPlacement::OneCpu.resolve().is_none(), "a second QEMU meanwhile goes anywhere");
        drop(first);
        assert_eq!(QemuPlacement::OneCpu.resolve().map(|pin| pin.cpu), Some(cpu), "free again");
        assert!(QemuPlacement::Anywhere.resolve().is_none());
        assert_eq!(QemuPlacement::Cpu(3).resolve().map(|pin| pin.cpu), Some(3));
    }
}
