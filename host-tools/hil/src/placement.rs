//! Which CPU QEMU's threads run on.
//!
//! Under `-icount sleep=off` every servo tick hands the guest over between QEMU's vCPU
//! thread and its main thread twice (the clock warps through the main loop while the guest
//! idles in `WFI`). When the kernel spreads the two threads over two CPUs, each hand-off
//! wakes an idle CPU, which in a virtual machine is a trip through the hypervisor; on one
//! CPU it is a context switch. On the 2-core VM the project is tested on (BENCHMARKS.md,
//! "HIL: QEMU on one CPU"), QEMU on one CPU ran 14.7-14.9 thousand lockstep ticks a second
//! against 13.1-13.2 thousand spread, and a stream of ticks 15.8-17.0 thousand against
//! 5.6-8.7 thousand.

use std::sync::atomic::{AtomicUsize, Ordering};

/// Where QEMU's threads run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
#[non_exhaustive]
pub enum QemuPlacement {
    /// All on one CPU of the harness's own set, a different one for each QEMU this process
    /// starts in turn; anywhere when the set holds a single CPU (one CPU for QEMU and the
    /// host would make each lockstep tick wait for a time slice).
    #[default]
    OneCpu,
    /// Wherever the kernel puts them.
    Anywhere,
    /// All on this CPU (it must be in the harness's set, or the start fails).
    Cpu(usize),
}

impl QemuPlacement {
    /// The CPU to pin a new QEMU to, if any.
    pub(crate) fn resolve(self) -> Option<usize> {
        match self {
            Self::Anywhere => None,
            Self::Cpu(cpu) => Some(cpu),
            Self::OneCpu => {
                static STARTED: AtomicUsize = AtomicUsize::new(0);
                let cpus = allowed_cpus();
                if cpus.len() < 2 {
                    return None;
                }
                // From the last CPU down: the kernel tends to fill CPUs from the first.
                let turn = STARTED.fetch_add(1, Ordering::Relaxed) % cpus.len();
                Some(cpus[cpus.len() - 1 - turn])
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
    fn one_cpu_takes_an_allowed_cpu_and_leaves_a_single_cpu_alone() {
        let cpus = allowed_cpus();
        assert!(!cpus.is_empty());
        let picked = QemuPlacement::OneCpu.resolve();
        match cpus.len() {
            1 => assert_eq!(picked, None),
            _ => assert!(cpus.contains(&picked.expect("a CPU")), "{picked:?} not in {cpus:?}"),
        }
        assert_eq!(QemuPlacement::Anywhere.resolve(), None);
        assert_eq!(QemuPlacement::Cpu(3).resolve(), Some(3));
    }
}
