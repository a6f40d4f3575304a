//! [`Hil`]: one QEMU running the firmware, its bus, control link and logs.

use std::net::{SocketAddr, TcpListener};
use std::path::PathBuf;
use std::process::{Command, ExitStatus, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use sts_twin_board::qemu::QemuBoard;
use sts_twin_core::bus::{InputSlot, OutputSlot, RING_SLOTS};

use super::bus::{BusCounters, BusFile, Diagnostics};
use super::link::ControlPort;
use super::log::{self, LogLine, LogSink, SharedLog};
use super::placement::QemuPlacement;
use super::process::{self, QemuProcess};
use super::{firmware, HilError};

/// How to start the firmware under QEMU.
#[derive(Clone, Debug)]
pub struct HilConfig {
    /// The firmware ELF; `None`: the ELF of `variant` (env override or build).
    pub elf: Option<PathBuf>,
    /// Which application, when `elf` is `None`.
    pub variant: firmware::FirmwareVariant,
    /// The emulated board: AN386 (Cortex-M4F), AN500 (Cortex-M7, the STM32H7's core; the
    /// same image as the AN386's) or RISC-V `virt` (its own image).
    pub board: QemuBoard,
    /// Keep the bus paused whenever no tick call ([`Hil::step`], the streams) is under way,
    /// so that the host's own work between ticks (the plant, control requests) is never
    /// counted as an underrun. Off: a host that stops feeding is seen as one.
    pub idle_paused: bool,
    /// `-icount shift=N`: one guest instruction takes 2^N ns of guest time. 2 (250 MIPS,
    /// 31,250 instructions per 125 us tick) resembles a mid-range Cortex-M.
    pub icount_shift: u32,
    /// How long to wait for the firmware to announce the bus after QEMU starts.
    pub boot_timeout: Duration,
    /// How long one tick (or one stall of a stream) may take before the harness gives up.
    pub tick_timeout: Duration,
    /// Install the SIGINT/SIGTERM/SIGHUP handler that kills QEMU ([`process::install_signal_cleanup`]).
    pub handle_signals: bool,
    /// Print decoded firmware logs to stderr as they arrive.
    pub echo_logs: bool,
    /// Use this named bus file (kept, with its config store) instead of an anonymous one.
    pub bus_path: Option<PathBuf>,
    /// Put the control link on a pseudo-terminal (`-serial pty`) instead of a loopback TCP
    /// socket: the host then talks to the firmware with the serial-port code a lab uses
    /// (`sts_link`), through [`Hil::control_pty`]; [`Hil::link`] and [`Hil::transact`] are
    /// not available.
    pub control_pty: bool,
    /// Which CPU QEMU's threads run on ([`QemuPlacement`]; by default all on one).
    pub placement: QemuPlacement,
}

impl Default for HilConfig {
    fn default() -> Self {
        Self {
            elf: None,
            variant: firmware::FirmwareVariant::Twin,
            board: QemuBoard::An386,
            idle_paused: true,
            icount_shift: 2,
            boot_timeout: Duration::from_secs(20),
            tick_timeout: Duration::from_secs(10),
            handle_signals: true,
            echo_logs: std::env::var_os("STS_TWIN_HIL_ECHO").is_some(),
            bus_path: None,
            control_pty: false,
            placement: QemuPlacement::default(),
        }
    }
}

/// The firmware running under QEMU, attached.
///
/// Ticks go through [`Hil::step`] (lockstep: one input, wait for its output) or
/// [`Hil::run_open_loop`] (pipelined through the bus ring). The control link is
/// [`Hil::link`]; while exchanging control bytes the bus should be paused
/// ([`Hil::pause`] / [`Hil::resume`], or [`Hil::transact`]), because the servo tick, at the
/// highest priority, would otherwise spin waiting for the next input while the control
/// bytes wait behind it.
#[derive(Debug)]
pub struct Hil {
    config: HilConfig,
    elf: PathBuf,
    bus: Arc<BusFile>,
    qemu: QemuProcess,
    link: Option<ControlPort>,
    logs: SharedLog,
    next_tick: u32,
    serial_addr: Option<SocketAddr>,
    pty: Option<PathBuf>,
}

impl Hil {
    /// Starts QEMU with the firmware on a fresh bus and waits until it serves the bus.
    pub fn start(config: HilConfig) -> Result<Self, HilError> {
        let bus = match &config.bus_path {
            Some(p) => BusFile::persistent(p, config.board)?,
            None => BusFile::anonymous(config.board)?,
        };
        Self::start_on(config, Arc::new(bus))
    }

    /// Starts QEMU on an existing bus file (e.g. to reboot with the same config store).
    pub fn start_on(config: HilConfig, bus: Arc<BusFile>) -> Result<Self, HilError> {
        if bus.board() != config.board {
            return Err(HilError::BoardMismatch { file: bus.board().name(), board: config.board.name() });
        }
        let program = process::qemu_program(config.board)?;
        let elf = match &config.elf {
            Some(p) if p.is_file() => p.clone(),
            Some(p) => return Err(HilError::ElfMissing(p.clone())),
            None => firmware::firmware_elf_of(config.board, config.variant)?,
        };
        log::check_table(&elf)?;
        if config.handle_signals {
            process::install_signal_cleanup()?;
        }
        // The port comes from the OS; in the rare race where another process takes it
        // first, QEMU fails to listen and the start is retried on a new port.
        let mut last_err = None;
        for _ in 0..3 {
            match Self::try_start(&config, &program, &elf, &bus) {
                Ok(mut hil) => {
                    hil.idle();
                    return Ok(hil);
                }
                Err(e @ HilError::QemuExited { .. }) => last_err = Some(e),
                Err(e) => return Err(e),
            }
        }
        Err(last_err.expect("three attempts"))
    }

    fn try_start(
        config: &HilConfig,
        program: &str,
        elf: &std::path::Path,
        bus: &Arc<BusFile>,
    ) -> Result<Self, HilError> {
        let port = {
            let l = TcpListener::bind("127.0.0.1:0").map_err(|e| HilError::io("finding a free port", e))?;
            l.local_addr().map_err(|e| HilError::io("finding a free port", e))?.port()
        };
        let serial_addr = SocketAddr::from(([127, 0, 0, 1], port));
        let serial = if config.control_pty {
            "pty".to_string()
        } else {
            format!("tcp:127.0.0.1:{port},server=on,wait=off,nodelay=on")
        };
        bus.reset_for_boot();
        let mut cmd = Command::new(program);
        cmd.args(qemu_args(config.board, config.icount_shift, &bus.qemu_mem_path(), &serial, elf))
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped());
        let pin = config.placement.resolve();
        let cpu = pin.as_ref().map(|pin| pin.cpu);
        let mut qemu = QemuProcess::spawn(cmd, bus.inherited_fds(), pin).map_err(|e| match cpu {
            Some(cpu) => HilError::io(format!("starting {program} on CPU {cpu}"), e),
            None => HilError::io(format!("starting {program}"), e),
        })?;
        let logs: SharedLog = Arc::new(Mutex::new(LogSink::default()));
        if let Some(out) = qemu.take_stdout() {
            log::spawn_decoder(elf.to_path_buf(), out, logs.clone(), config.echo_logs, config.control_pty);
        }
        if let Some(err) = qemu.take_stderr() {
            log::spawn_stderr_reader(err, logs.clone());
        }
        let (link, pty) = if config.control_pty {
            (None, Some(wait_for_pty(&mut qemu, &logs, config.boot_timeout)?))
        } else {
            let mut alive = || check_alive(&mut qemu, &logs, "connecting the control link");
            (Some(ControlPort::connect(serial_addr, config.boot_timeout, &mut alive)?), None)
        };
        let mut hil = Self {
            config: config.clone(),
            elf: elf.to_path_buf(),
            bus: bus.clone(),
            qemu,
            link,
            logs,
            next_tick: 0,
            serial_addr: (!config.control_pty).then_some(serial_addr),
            pty,
        };
        let deadline = Instant::now() + hil.config.boot_timeout;
        while !hil.bus.firmware_ready() {
            hil.alive("waiting for the firmware to serve the bus")?;
            if Instant::now() >= deadline {
                return Err(HilError::Timeout {
                    what: "the firmware to serve the bus (FW_READY)".into(),
                    seconds: hil.config.boot_timeout.as_secs_f64(),
                });
            }
            std::thread::sleep(Duration::from_millis(1));
        }
        Ok(hil)
    }

    /// Kills this QEMU and boots the firmware again on the same bus file (the config store
    /// is kept; the tick count restarts at 0).
    pub fn reboot(mut self) -> Result<Self, HilError> {
        self.qemu.kill();
        let config = self.config.clone();
        let bus = self.bus.clone();
        drop(self);
        Self::start_on(config, bus)
    }

    /// The ELF being run.
    pub fn elf(&self) -> &std::path::Path {
        &self.elf
    }

    /// QEMU's process id.
    pub fn qemu_pid(&self) -> u32 {
        self.qemu.pid()
    }

    /// The loopback address of the control link (`None` with [`HilConfig::control_pty`]).
    pub fn serial_addr(&self) -> Option<SocketAddr> {
        self.serial_addr
    }

    /// The pseudo-terminal QEMU put the control link on (with [`HilConfig::control_pty`]).
    pub fn control_pty(&self) -> Option<&std::path::Path> {
        self.pty.as_deref()
    }

    /// The bus file (shared, e.g. for a reboot).
    pub fn bus(&self) -> &Arc<BusFile> {
        &self.bus
    }

    /// The next tick to be served (= outputs read so far).
    pub fn next_tick(&self) -> u32 {
        self.next_tick
    }

    /// The bus counters.
    pub fn counters(&self) -> BusCounters {
        self.bus.counters()
    }

    /// The firmware's diagnostics block.
    pub fn diagnostics(&self) -> Diagnostics {
        self.bus.diagnostics()
    }

    /// The `-icount` shift in use.
    pub fn icount_shift(&self) -> u32 {
        self.config.icount_shift
    }

    /// Errors out if QEMU has ended.
    pub fn alive(&mut self, during: &str) -> Result<(), HilError> {
        check_alive(&mut self.qemu, &self.logs, during)
    }

    /// One lockstep tick: writes input `k` (its `tick` field is set to `k`), waits for
    /// output `k`.
    pub fn step(&mut self, mut input: InputSlot) -> Result<OutputSlot, HilError> {
        let k = self.next_tick;
        input.tick = k;
        self.bus.write_input(&input);
        self.active();
        let waited = self.wait_fw_seq(k.wrapping_add(1), "the output of a lockstep tick");
        self.idle();
        waited?;
        self.next_tick = k.wrapping_add(1);
        Ok(self.bus.read_output(k))
    }

    /// Lets the firmware take inputs (ends an idle pause).
    fn active(&mut self) {
        if self.config.idle_paused {
            self.bus.set_host_stop(false);
        }
    }

    /// Between tick calls: pauses the bus if [`HilConfig::idle_paused`].
    fn idle(&mut self) {
        if self.config.idle_paused {
            self.bus.set_host_stop(true);
        }
    }

    /// Streams `inputs` through the bus ring without waiting for each output (open loop:
    /// no input depends on an output), keeping up to a ring's worth in flight. Returns the
    /// outputs in tick order.
    pub fn run_open_loop(&mut self, inputs: &[InputSlot]) -> Result<Vec<OutputSlot>, HilError> {
        let mut outputs = Vec::with_capacity(inputs.len());
        self.stream_open_loop(inputs.iter().copied(), |o| outputs.push(o))?;
        Ok(outputs)
    }

    /// Like [`Hil::run_open_loop`] but hands each output to `sink` as it comes, for long
    /// runs.
    pub fn stream_open_loop(
        &mut self,
        inputs: impl IntoIterator<Item = InputSlot>,
        sink: impl FnMut(OutputSlot),
    ) -> Result<u32, HilError> {
        self.active();
        let result = self.stream_inner(inputs, sink);
        self.idle();
        result
    }

    fn stream_inner(
        &mut self,
        inputs: impl IntoIterator<Item = InputSlot>,
        mut sink: impl FnMut(OutputSlot),
    ) -> Result<u32, HilError> {
        let mut inputs = inputs.into_iter().peekable();
        let first = self.next_tick;
        let mut written = first;
        let mut read = first;
        let mut waiter = Waiter::new(self.config.tick_timeout);
        loop {
            let fw = self.bus.fw_seq();
            let mut progressed = false;
            // Bounded by what the host has *read*, not by FW_SEQ: input k makes the firmware
            // write output slot k % RING, so more than a ring beyond `read` would overwrite
            // outputs not yet read (seen when the host lagged a whole ring behind the
            // firmware). One slot of slack as on the input side.
            while inputs.peek().is_some() && in_flight_allowed(written, read) {
                let mut input = inputs.next().expect("peeked");
                input.tick = written;
                self.bus.write_input(&input);
                written = written.wrapping_add(1);
                progressed = true;
            }
            while read != fw && (fw.wrapping_sub(read) as i32) > 0 {
                sink(self.bus.read_output(read));
                read = read.wrapping_add(1);
                progressed = true;
            }
            self.next_tick = read;
            if read == written && inputs.peek().is_none() {
                return Ok(read.wrapping_sub(first));
            }
            if progressed {
                waiter.reset();
            } else if written.wrapping_sub(read) >= STREAM_SLEEP_IN_FLIGHT {
                // Plenty in flight: one long sleep instead of a wake-up per tick, which
                // would take a host core's worth of system time from QEMU.
                waiter.sleep(&mut self.qemu, &self.logs, STREAM_SLEEP, "the firmware to consume a stream of ticks")?;
            } else {
                waiter.wait(&mut self.qemu, &self.logs, "the firmware to consume a stream of ticks")?;
            }
        }
    }

    fn wait_fw_seq(&mut self, target: u32, what: &str) -> Result<(), HilError> {
        let mut waiter = Waiter::new(self.config.tick_timeout);
        while (self.bus.fw_seq().wrapping_sub(target) as i32) < 0 {
            waiter.wait(&mut self.qemu, &self.logs, what)?;
        }
        Ok(())
    }

    /// Asks the firmware to stop waiting for inputs (it keeps ticking, serves nothing and
    /// counts no underruns) until [`Hil::resume`].
    pub fn pause(&mut self) {
        self.bus.set_host_stop(true);
    }

    /// Ends a [`Hil::pause`].
    pub fn resume(&mut self) {
        self.bus.set_host_stop(false);
    }

    /// The control link (a loopback TCP socket).
    ///
    /// # Panics
    /// With [`HilConfig::control_pty`], where the link is the pseudo-terminal instead.
    pub fn link(&mut self) -> &mut ControlPort {
        self.link.as_mut().expect("the control link is on a pseudo-terminal (HilConfig::control_pty)")
    }

    /// With the bus paused: sends `request`, receives until `done(reply so far)`, resumes.
    pub fn transact(
        &mut self,
        request: &[u8],
        timeout: Duration,
        done: impl FnMut(&[u8]) -> bool,
    ) -> Result<Vec<u8>, HilError> {
        let Some(link) = self.link.as_mut() else {
            return Err(HilError::Protocol(
                "the control link is on a pseudo-terminal (HilConfig::control_pty): talk to it with sts_link".into(),
            ));
        };
        self.bus.set_host_stop(true);
        let result = link.send(request).and_then(|()| link.recv_until(timeout, done));
        if !self.config.idle_paused {
            self.resume();
        }
        match result {
            Err(HilError::Timeout { .. }) | Err(HilError::Protocol(_)) => {
                self.alive("a control-link exchange")?;
                result
            }
            other => other,
        }
    }

    /// The decoded firmware log lines so far.
    pub fn logs(&self) -> Vec<LogLine> {
        self.logs.lock().unwrap_or_else(|e| e.into_inner()).lines.clone()
    }

    /// QEMU's own stderr so far.
    pub fn qemu_stderr(&self) -> String {
        self.logs.lock().unwrap_or_else(|e| e.into_inner()).stderr.clone()
    }

    /// Waits until a log line satisfies `pred`, up to `timeout`.
    pub fn wait_for_log(&mut self, timeout: Duration, pred: impl Fn(&LogLine) -> bool) -> Result<LogLine, HilError> {
        let deadline = Instant::now() + timeout;
        loop {
            if let Some(line) = self.logs.lock().unwrap_or_else(|e| e.into_inner()).lines.iter().find(|l| pred(l)) {
                return Ok(line.clone());
            }
            if Instant::now() >= deadline {
                return Err(HilError::Timeout {
                    what: "a matching firmware log line".into(),
                    seconds: timeout.as_secs_f64(),
                });
            }
            if let Some(status) = self.qemu.try_status() {
                // One last look: the line may have been decoded just before the exit.
                std::thread::sleep(Duration::from_millis(50));
                if let Some(line) = self.logs.lock().unwrap_or_else(|e| e.into_inner()).lines.iter().find(|l| pred(l)) {
                    return Ok(line.clone());
                }
                return Err(exited(status, &self.logs, "waiting for a log line"));
            }
            std::thread::sleep(Duration::from_millis(2));
        }
    }

    /// Waits up to `timeout` for QEMU to end by itself (e.g. after a firmware panic);
    /// `None` if it is still running.
    pub fn wait_exit(&mut self, timeout: Duration) -> Option<ExitStatus> {
        let status = self.qemu.wait_timeout(timeout);
        if status.is_some() {
            // Let the decoder drain the last frames.
            std::thread::sleep(Duration::from_millis(50));
        }
        status
    }

    /// Kills QEMU and reaps it (also done on drop).
    pub fn shutdown(mut self) -> Result<ExitStatus, HilError> {
        Ok(self.qemu.kill())
    }
}

/// The QEMU command line (without the program): the board with its memory from the bus
/// file, no display or monitor, the control link, semihosting for the logs and the exit
/// status, guest time from the instruction count.
pub(crate) fn qemu_args(
    board: QemuBoard,
    icount_shift: u32,
    mem_path: &str,
    serial: &str,
    elf: &std::path::Path,
) -> Vec<String> {
    let memory = format!(
        "memory-backend-file,id=shared,size={}M,mem-path={mem_path},share=on",
        board.backing_file_bytes() >> 20
    );
    let mut args = vec![
        "-machine".to_string(),
        format!("{},memory-backend=shared", board.qemu_machine()),
        "-object".into(),
        memory,
    ];
    if board == QemuBoard::RiscvVirt {
        // No firmware before ours (the reset vector jumps to the RAM's start), and the RTC,
        // the servo tick, on guest time: QEMU's default is the host's clock.
        args.extend(["-bios", "none", "-rtc", "clock=vm"].map(String::from));
    }
    args.extend(
        [
            "-display",
            "none",
            "-monitor",
            "none",
            "-serial",
            serial,
            "-semihosting-config",
            "enable=on,target=native",
            "-icount",
            &format!("shift={icount_shift},sleep=off"),
            "-no-reboot",
            "-kernel",
            &elf.display().to_string(),
        ]
        .map(String::from),
    );
    args
}

fn exited(status: ExitStatus, logs: &SharedLog, during: &str) -> HilError {
    let sink = logs.lock().unwrap_or_else(|e| e.into_inner());
    let mut tail: Vec<String> = sink.lines.iter().rev().take(20).map(|l| l.to_string()).collect();
    tail.reverse();
    if !sink.stderr.trim().is_empty() {
        tail.push(format!("qemu stderr: {}", sink.stderr.trim()));
    }
    HilError::QemuExited { status, during: during.into(), log_tail: tail.join("\n") }
}

/// Waits for QEMU's "char device redirected to /dev/pts/N (label serial0)", its first line
/// on stdout.
fn wait_for_pty(qemu: &mut QemuProcess, logs: &SharedLog, timeout: Duration) -> Result<PathBuf, HilError> {
    const MARK: &str = "char device redirected to ";
    let deadline = Instant::now() + timeout;
    loop {
        {
            let sink = logs.lock().unwrap_or_else(|e| e.into_inner());
            if let Some(banner) = &sink.banner {
                return match banner.strip_prefix(MARK).and_then(|rest| rest.split_whitespace().next()) {
                    Some(path) => Ok(PathBuf::from(path)),
                    None => Err(HilError::Protocol(format!(
                        "QEMU did not name the control link's pseudo-terminal (its first line: {banner:?})"
                    ))),
                };
            }
        }
        check_alive(qemu, logs, "waiting for QEMU's pseudo-terminal")?;
        if Instant::now() >= deadline {
            return Err(HilError::Timeout {
                what: "QEMU to name the pseudo-terminal of the control link".into(),
                seconds: timeout.as_secs_f64(),
            });
        }
        std::thread::sleep(Duration::from_millis(2));
    }
}

fn check_alive(qemu: &mut QemuProcess, logs: &SharedLog, during: &str) -> Result<(), HilError> {
    match qemu.try_status() {
        Some(status) => {
            std::thread::sleep(Duration::from_millis(50));
            Err(exited(status, logs, during))
        }
        None => Ok(()),
    }
}

/// Waiting for the firmware: spin briefly (a tick round trip is some 20 us), then sleep in
/// short steps (QEMU needs both of a small machine's cores); check QEMU is alive and enforce
/// the timeout. No `sched_yield` between the two: beside any other runnable task, even one at
/// idle priority, a yield hands it the core for a whole time slice (a HIL cut takes several
/// times as long), where a sleep's wake-up preempts it at once.
const SPIN_BEFORE_SLEEP: u32 = 64;
/// A stream with at least this many ticks in flight (half the ring) sleeps [`STREAM_SLEEP`]
/// at a time: at the guest's 20-40 thousand ticks a second the other half lasts 3-6 ms.
const STREAM_SLEEP_IN_FLIGHT: u32 = (RING_SLOTS / 2) as u32;
const STREAM_SLEEP: Duration = Duration::from_millis(1);

/// Asks Linux to wake this thread's short sleeps on time: the default 50 us of timer slack
/// turns each 5 us sleep into some 55 us, longer than a lockstep tick's round trip. Once per
/// thread.
fn fine_timer_slack() {
    thread_local!(static DONE: std::cell::Cell<bool> = const { std::cell::Cell::new(false) });
    DONE.with(|done| {
        if !done.replace(true) {
            // SAFETY: PR_SET_TIMERSLACK takes a value and changes only this thread's slack.
            unsafe { libc::prctl(libc::PR_SET_TIMERSLACK, 1 as libc::c_ulong, 0, 0, 0) };
        }
    });
}

struct Waiter {
    start: Instant,
    spins: u32,
    timeout: Duration,
}

impl Waiter {
    fn new(timeout: Duration) -> Self {
        fine_timer_slack();
        Self { start: Instant::now(), spins: 0, timeout }
    }

    fn reset(&mut self) {
        self.spins = 0;
        self.start = Instant::now();
    }

    /// Sleeps `nap`, then checks QEMU is alive and the timeout.
    fn sleep(&mut self, qemu: &mut QemuProcess, logs: &SharedLog, nap: Duration, what: &str) -> Result<(), HilError> {
        std::thread::sleep(nap);
        check_alive(qemu, logs, what)?;
        let waited = self.start.elapsed();
        if waited >= self.timeout {
            return Err(HilError::Timeout { what: what.into(), seconds: waited.as_secs_f64() });
        }
        Ok(())
    }

    fn wait(&mut self, qemu: &mut QemuProcess, logs: &SharedLog, what: &str) -> Result<(), HilError> {
        self.spins += 1;
        // Spinning longer than this only steals the core QEMU needs (a long-spinning host
        // halves the lockstep rate on a 2-core machine).
        if self.spins < SPIN_BEFORE_SLEEP {
            std::hint::spin_loop();
            return Ok(());
        }
        if self.spins.is_multiple_of(256) {
            check_alive(qemu, logs, what)?;
            let waited = self.start.elapsed();
            if waited >= self.timeout {
                return Err(HilError::Timeout { what: what.into(), seconds: waited.as_secs_f64() });
            }
        }
        // Then block in short sleeps: a host that stays runnable takes CPU share from QEMU's
        // threads, which on a shared machine costs milliseconds per tick.
        std::thread::sleep(Duration::from_micros(5));
        Ok(())
    }
}

/// True when input `written` may be sent while outputs from `read` on are still unread:
/// both rings then hold every slot in flight (`read <= FW_SEQ <= written`).
fn in_flight_allowed(written: u32, read: u32) -> bool {
    written.wrapping_sub(read) < (RING_SLOTS - 1) as u32
}
