//! The QEMU child process and the guarantees that it never outlives the harness.
//!
//! - [`QemuProcess`] kills (SIGKILL) and reaps QEMU on drop, so every exit path that
//!   unwinds or returns ends it.
//! - QEMU gets `PR_SET_PDEATHSIG(SIGKILL)`: the kernel kills it when the process that
//!   spawned it dies, even by SIGKILL. The signal follows the spawning *thread*, so every
//!   QEMU is spawned by one keeper thread that lives as long as the process.
//! - [`install_signal_cleanup`] kills every live QEMU on SIGINT, SIGTERM and SIGHUP and
//!   then exits the process with status 128 + signal.

use std::io;
use std::process::{Child, Command, ExitStatus};
use std::sync::mpsc;
use std::sync::{Mutex, OnceLock};
use std::time::{Duration, Instant};

use sts_twin_board::qemu::QemuBoard;

use super::placement::CpuPin;
use super::HilError;

/// Environment variable naming the QEMU binary of the Arm boards (default `qemu-system-arm`).
pub const QEMU_ENV: &str = "STS_TWIN_QEMU";
/// Environment variable naming the QEMU binary of the RISC-V board (default
/// `qemu-system-riscv32`).
pub const QEMU_RISCV32_ENV: &str = "STS_TWIN_QEMU_RISCV32";

static LIVE: Mutex<Vec<u32>> = Mutex::new(Vec::new());

/// Process ids of the QEMU instances this process currently runs.
pub fn live_qemu_pids() -> Vec<u32> {
    LIVE.lock().unwrap_or_else(|e| e.into_inner()).clone()
}

fn kill_pid(pid: u32) {
    // SAFETY: plain syscall; a stale pid at worst gets ESRCH.
    unsafe {
        libc::kill(pid as libc::pid_t, libc::SIGKILL);
    }
}

/// Installs (once) a handler that kills every live QEMU on SIGINT, SIGTERM and SIGHUP,
/// then exits with status 128 + signal. [`super::Hil::start`] calls it unless
/// [`super::HilConfig::handle_signals`] is off.
pub fn install_signal_cleanup() -> Result<(), HilError> {
    static INSTALLED: OnceLock<Result<(), String>> = OnceLock::new();
    let result = INSTALLED.get_or_init(|| {
        use signal_hook::consts::{SIGHUP, SIGINT, SIGTERM};
        let mut signals = signal_hook::iterator::Signals::new([SIGINT, SIGTERM, SIGHUP]).map_err(|e| e.to_string())?;
        std::thread::Builder::new()
            .name("sts-hil-signals".into())
            .spawn(move || {
                if let Some(signal) = signals.forever().next() {
                    for pid in live_qemu_pids() {
                        kill_pid(pid);
                    }
                    std::process::exit(128 + signal);
                }
            })
            .map_err(|e| e.to_string())?;
        Ok(())
    });
    result.clone().map_err(|e| HilError::io("installing the signal handler", io::Error::other(e)))
}

type SpawnRequest = (Command, mpsc::Sender<io::Result<Child>>);

/// Spawns `command` from the keeper thread (see the module docs).
fn spawn_from_keeper(command: Command) -> io::Result<Child> {
    static KEEPER: OnceLock<Mutex<mpsc::Sender<SpawnRequest>>> = OnceLock::new();
    let keeper = KEEPER.get_or_init(|| {
        let (tx, rx) = mpsc::channel::<SpawnRequest>();
        std::thread::Builder::new()
            .name("sts-hil-spawner".into())
            .spawn(move || {
                // Lives until the process ends: the QEMU children's death signal is tied to it.
                for (mut command, reply) in rx {
                    let _ = reply.send(command.spawn());
                }
            })
            .expect("spawning the QEMU keeper thread");
        Mutex::new(tx)
    });
    let (reply_tx, reply_rx) = mpsc::channel();
    keeper
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .send((command, reply_tx))
        .map_err(|_| io::Error::other("QEMU keeper thread is gone"))?;
    reply_rx.recv().map_err(|_| io::Error::other("QEMU keeper thread is gone"))?
}

/// A running QEMU, killed and reaped on drop.
#[derive(Debug)]
pub(crate) struct QemuProcess {
    child: Child,
    status: Option<ExitStatus>,
    /// Held as long as QEMU is (its place is free again when it ends).
    pin: Option<CpuPin>,
}

impl QemuProcess {
    /// Spawns `command` with the death signal set and `keep_fds` inherited (the bus file).
    pub(crate) fn spawn(mut command: Command, keep_fds: Vec<i32>, pin: Option<CpuPin>) -> io::Result<Self> {
        use std::os::unix::process::CommandExt;
        // SAFETY: the closure runs between fork and exec and only makes async-signal-safe
        // syscalls (prctl, getppid, sched_setaffinity, fcntl, _exit).
        let parent = unsafe { libc::getpid() };
        let cpu = pin.as_ref().map(|pin| pin.cpu);
        unsafe {
            command.pre_exec(move || {
                // Before exec, so that every thread QEMU starts inherits the CPU.
                if let Some(cpu) = cpu {
                    let mut set: libc::cpu_set_t = std::mem::zeroed();
                    libc::CPU_SET(cpu, &mut set);
                    if libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set) != 0 {
                        return Err(io::Error::last_os_error());
                    }
                }
                if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGKILL, 0, 0, 0) != 0 {
                    return Err(io::Error::last_os_error());
                }
                // The parent may have died before the death signal was armed.
                if libc::getppid() != parent {
                    libc::_exit(1);
                }
                for &fd in &keep_fds {
                    if libc::fcntl(fd, libc::F_SETFD, 0) != 0 {
                        return Err(io::Error::last_os_error());
                    }
                }
                Ok(())
            });
        }
        // Its own process group: a terminal's Ctrl-C reaches the harness, which cleans up.
        command.process_group(0);
        let child = spawn_from_keeper(command)?;
        LIVE.lock().unwrap_or_else(|e| e.into_inner()).push(child.id());
        Ok(Self { child, status: None, pin })
    }

    /// The process id.
    pub(crate) fn pid(&self) -> u32 {
        self.child.id()
    }

    pub(crate) fn take_stdout(&mut self) -> Option<std::process::ChildStdout> {
        self.child.stdout.take()
    }

    pub(crate) fn take_stderr(&mut self) -> Option<std::process::ChildStderr> {
        self.child.stderr.take()
    }

    /// The exit status if QEMU has ended.
    pub(crate) fn try_status(&mut self) -> Option<ExitStatus> {
        if self.status.is_none()
            && let Ok(Some(status)) = self.child.try_wait()
        {
            self.forget();
            self.status = Some(status);
        }
        self.status
    }

    /// Waits up to `timeout` for QEMU to end by itself.
    pub(crate) fn wait_timeout(&mut self, timeout: Duration) -> Option<ExitStatus> {
        let deadline = Instant::now() + timeout;
        loop {
            if let Some(status) = self.try_status() {
                return Some(status);
            }
            if Instant::now() >= deadline {
                return None;
            }
            std::thread::sleep(Duration::from_millis(2));
        }
    }

    /// Kills QEMU (if still running) and reaps it.
    pub(crate) fn kill(&mut self) -> ExitStatus {
        if let Some(status) = self.status {
            return status;
        }
        let _ = self.child.kill();
        let status = self.child.wait().unwrap_or_else(|_| {
            // Only if the child was reaped elsewhere: report it as killed.
            use std::os::unix::process::ExitStatusExt;
            ExitStatus::from_raw(libc::SIGKILL)
        });
        self.forget();
        self.pin = None;
        self.status = Some(status);
        status
    }

    fn forget(&self) {
        let pid = self.child.id();
        LIVE.lock().unwrap_or_else(|e| e.into_inner()).retain(|&p| p != pid);
    }
}

impl Drop for QemuProcess {
    fn drop(&mut self) {
        self.kill();
    }
}

/// The QEMU program that runs `board` ([`QemuBoard::qemu_program`], or its environment
/// variable's), checked to exist.
pub(crate) fn qemu_program(board: QemuBoard) -> Result<String, HilError> {
    let (env, arch, package) = match board {
        QemuBoard::An386 | QemuBoard::An500 => (QEMU_ENV, "Arm", "qemu-system-arm"),
        QemuBoard::RiscvVirt => (QEMU_RISCV32_ENV, "RISC-V", "qemu-system-misc"),
    };
    let program = std::env::var(env).unwrap_or_else(|_| board.qemu_program().into());
    match Command::new(&program).arg("--version").output() {
        Ok(out) if out.status.success() => Ok(program),
        _ => Err(HilError::QemuMissing { program, arch, package, env }),
    }
}
