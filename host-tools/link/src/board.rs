//! [`Board`]: a co-processor on the other end of a [`Transport`], spoken to with the control
//! protocol: the version handshake on connect, then requests, each sent with a new sequence
//! number and retried under a [`RetryPolicy`] until its answer comes.

use std::time::{Duration, Instant};

use sts_twin_core::wire::{
    encode_frame, FrameDecoder, FrameError, Request, Response, MAX_ENCODED_FRAME, PROTOCOL_VERSION,
};

use super::{FrameFate, FrameInjector, LinkError, LinkFaults, LinkStats, RetryPolicy, Transport};

/// The nonce of the handshake's `Ping` ("STS" and a 1).
const HANDSHAKE_NONCE: u32 = 0x5354_5301;

/// A co-processor reached through `T`, its protocol version checked.
pub struct Board<T: Transport> {
    transport: T,
    policy: RetryPolicy,
    seq: u16,
    stats: LinkStats,
    undecodable: u64,
    faults: Option<(FrameInjector, FrameInjector)>,
    rx: Vec<u8>,
}

impl<T: Transport> Board<T> {
    /// Connects: sends `Ping` and checks the `Pong`'s protocol version against this host's
    /// ([`PROTOCOL_VERSION`]). Fails with [`LinkError::Version`] or
    /// [`LinkError::Undecodable`] for a firmware of another version, [`LinkError::NoAnswer`]
    /// for a board that says nothing.
    pub fn connect(transport: T, policy: RetryPolicy) -> Result<Self, LinkError> {
        let mut board = Self {
            transport,
            policy,
            seq: 0,
            stats: LinkStats::default(),
            undecodable: 0,
            faults: None,
            rx: Vec::new(),
        };
        board.handshake()?;
        Ok(board)
    }

    /// Passes every frame from now on, in and out, through seeded [`LinkFaults`] (tests of a
    /// noisy line on a real port).
    pub fn with_faults(mut self, inbound: LinkFaults, outbound: LinkFaults, seed: u64) -> Self {
        self.faults = Some((FrameInjector::new(inbound, seed), FrameInjector::new(outbound, seed ^ 0x6F75_7462)));
        self
    }

    /// Sends `Ping` again and checks the version (after a board reset, for instance).
    pub fn handshake(&mut self) -> Result<u16, LinkError> {
        match self.request(Request::Ping { nonce: HANDSHAKE_NONCE })? {
            Response::Pong { nonce: HANDSHAKE_NONCE, protocol_version: PROTOCOL_VERSION } => Ok(PROTOCOL_VERSION),
            Response::Pong { nonce: HANDSHAKE_NONCE, protocol_version } => Err(LinkError::Version {
                port: self.transport.describe(),
                found: protocol_version,
                expected: PROTOCOL_VERSION,
            }),
            other => Err(self.unexpected("Ping", &other)),
        }
    }

    /// Sends `request` and returns its answer, retrying under the policy.
    pub fn request(&mut self, request: Request) -> Result<Response, LinkError> {
        let name = request_name(&request);
        let mut frame = [0u8; MAX_ENCODED_FRAME + 1];
        let started = Instant::now();
        let mut timeout = self.policy.first_timeout;
        for attempt in 1..=self.policy.attempts {
            self.seq = self.seq.wrapping_add(1);
            // A leading delimiter resynchronises the firmware's decoder after line noise.
            let len = encode_frame(self.seq, &request, &mut frame[1..]).map_err(|e| LinkError::Encode {
                port: self.transport.describe(),
                request: name,
                detail: e.to_string(),
            })?;
            self.stats.attempts += 1;
            self.send(&mut frame[..len + 1])?;
            // The line's own transfer time (the request, and an answer of up to a full
            // frame) on top of the policy's wait.
            let transfer = self
                .transport
                .bytes_per_second()
                .map_or(Duration::ZERO, |bps| Duration::from_secs_f64((len + 1 + MAX_ENCODED_FRAME) as f64 / bps));
            if let Some(answer) = self.await_answer(self.seq, timeout + transfer)? {
                self.stats.requests += 1;
                self.stats.max_attempts = self.stats.max_attempts.max(attempt);
                return Ok(answer);
            }
            timeout = (timeout * 2).min(self.policy.max_timeout);
        }
        let port = self.transport.describe();
        if self.undecodable > 0 {
            return Err(LinkError::Undecodable { port, frames: self.undecodable, expected: PROTOCOL_VERSION });
        }
        Err(LinkError::NoAnswer {
            port,
            request: name,
            attempts: self.policy.attempts,
            seconds: started.elapsed().as_secs_f64(),
        })
    }

    /// Sends `request` and fails unless it is acknowledged.
    pub fn expect_ack(&mut self, request: Request) -> Result<(), LinkError> {
        let name = request_name(&request);
        match self.request(request)? {
            Response::Ack => Ok(()),
            other => Err(self.unexpected(name, &other)),
        }
    }

    /// Retries from now on under `policy`.
    pub fn set_policy(&mut self, policy: RetryPolicy) {
        self.policy = policy;
    }

    /// What the host saw on the link so far.
    pub fn stats(&self) -> LinkStats {
        self.stats
    }

    /// What the transport is, for messages.
    pub fn describe(&self) -> String {
        self.transport.describe()
    }

    /// The transport, for tests that write raw bytes.
    pub fn transport(&mut self) -> &mut T {
        &mut self.transport
    }

    fn unexpected(&self, request: &'static str, answer: &Response) -> LinkError {
        LinkError::Unexpected { port: self.transport.describe(), request, answer: format!("{answer:?}") }
    }

    fn send(&mut self, frame: &mut [u8]) -> Result<(), LinkError> {
        let len = frame.len();
        let fate = match &mut self.faults {
            Some((inbound, _)) => inbound.pass(&mut frame[1..len - 1]),
            None => FrameFate::Delivered,
        };
        if fate == FrameFate::Dropped {
            return Ok(());
        }
        let port = self.transport.describe();
        self.transport.write_all(frame).map_err(|source| LinkError::Io { port, what: "sending", source })
    }

    /// Reads frames until the answer with `seq` arrives or `timeout` passes.
    fn await_answer(&mut self, seq: u16, timeout: Duration) -> Result<Option<Response>, LinkError> {
        let deadline = Instant::now() + timeout;
        let mut buf = [0u8; 1024];
        loop {
            while let Some(end) = self.rx.iter().position(|&b| b == 0) {
                let mut frame: Vec<u8> = self.rx.drain(..=end).collect();
                frame.pop();
                if frame.is_empty() {
                    continue;
                }
                if let Some((_, outbound)) = &mut self.faults
                    && outbound.pass(&mut frame) == FrameFate::Dropped
                {
                    continue;
                }
                if let Some(answer) = self.judge(&frame, seq) {
                    return Ok(Some(answer));
                }
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                // Whatever half-frame is left belongs to an abandoned attempt.
                self.rx.clear();
                return Ok(None);
            }
            let port = self.transport.describe();
            let n = self.transport.read(&mut buf, left).map_err(|source| LinkError::Io {
                port,
                what: "receiving",
                source,
            })?;
            self.rx.extend_from_slice(&buf[..n]);
        }
    }

    /// Decodes one frame (its bytes without the delimiter): the answer if it carries `seq`.
    fn judge(&mut self, frame: &[u8], seq: u16) -> Option<Response> {
        let mut decoder = FrameDecoder::<Response>::new();
        let mut result = None;
        for &b in frame.iter().chain(&[0]) {
            if let Some(r) = decoder.push(b) {
                result = Some(r);
            }
        }
        match result? {
            Ok(envelope) if envelope.seq == seq => Some(envelope.body),
            Ok(_) => {
                self.stats.stale_answers += 1;
                None
            }
            Err(FrameError::Decode) => {
                self.undecodable += 1;
                self.stats.bad_answers += 1;
                None
            }
            Err(_) => {
                self.stats.bad_answers += 1;
                None
            }
        }
    }
}

/// The request's name, for messages.
pub fn request_name(request: &Request) -> &'static str {
    match request {
        Request::Ping { .. } => "Ping",
        Request::GetStatus => "GetStatus",
        Request::UploadProgram { .. } => "UploadProgram",
        Request::ActivateStaged => "ActivateStaged",
        Request::ClearProgram => "ClearProgram",
        Request::SetParams(_) => "SetParams",
        Request::SetEnabled(_) => "SetEnabled",
        Request::SaveConfig => "SaveConfig",
        Request::ResetCounters => "ResetCounters",
        Request::SetFeatureConfig(_) => "SetFeatureConfig",
        Request::SetSupervisor(_) => "SetSupervisor",
    }
}

#[cfg(test)]
mod tests {
    use std::collections::VecDeque;

    use serde::Serialize;
    use sts_twin_core::wire::{Envelope, FrameDecoder};

    use super::*;

    /// A board in memory: answers each request frame with what `answer` makes of it.
    struct FakeBoard<F: FnMut(u16, &Request) -> Vec<u8>> {
        decoder: FrameDecoder<Request>,
        out: VecDeque<u8>,
        answer: F,
    }

    impl<F: FnMut(u16, &Request) -> Vec<u8>> Transport for FakeBoard<F> {
        fn describe(&self) -> String {
            "serial port /dev/fake at 115200 baud".into()
        }
        fn bytes_per_second(&self) -> Option<f64> {
            None
        }
        fn write_all(&mut self, bytes: &[u8]) -> std::io::Result<()> {
            for &b in bytes {
                if let Some(Ok(Envelope { seq, body })) = self.decoder.push(b) {
                    let reply = (self.answer)(seq, &body);
                    self.out.extend(reply);
                }
            }
            Ok(())
        }
        fn read(&mut self, buf: &mut [u8], _timeout: Duration) -> std::io::Result<usize> {
            let n = buf.len().min(self.out.len());
            for (slot, byte) in buf.iter_mut().zip(self.out.drain(..n)) {
                *slot = byte;
            }
            Ok(n)
        }
    }

    fn fake<F: FnMut(u16, &Request) -> Vec<u8>>(answer: F) -> FakeBoard<F> {
        FakeBoard { decoder: FrameDecoder::new(), out: VecDeque::new(), answer }
    }

    fn frame(seq: u16, body: &impl Serialize) -> Vec<u8> {
        let mut out = [0u8; MAX_ENCODED_FRAME];
        let len = encode_frame(seq, body, &mut out).unwrap();
        out[..len].to_vec()
    }

    fn quick() -> RetryPolicy {
        RetryPolicy { first_timeout: Duration::from_millis(1), max_timeout: Duration::from_millis(2), attempts: 3 }
    }

    #[test]
    fn the_handshake_accepts_this_version_and_names_another() {
        let this = fake(|seq, request| match request {
            Request::Ping { nonce } => {
                frame(seq, &Response::Pong { nonce: *nonce, protocol_version: PROTOCOL_VERSION })
            }
            _ => frame(seq, &Response::Ack),
        });
        let mut board = Board::connect(this, quick()).expect("same version");
        board.expect_ack(Request::SetEnabled(true)).unwrap();

        let newer = fake(|seq, request| match request {
            Request::Ping { nonce } => frame(seq, &Response::Pong { nonce: *nonce, protocol_version: 9 }),
            _ => frame(seq, &Response::Ack),
        });
        let err = Board::connect(newer, quick()).err().unwrap();
        assert!(matches!(err, LinkError::Version { found: 9, expected: PROTOCOL_VERSION, .. }), "{err}");
        assert!(err.to_string().contains("/dev/fake") && err.to_string().contains("version 9"), "{err}");
    }

    #[test]
    fn a_version_1_firmware_whose_pong_does_not_decode_is_named_as_another_version() {
        // Version 1's Pong: the nonce only.
        #[derive(Serialize)]
        enum PongV1 {
            Pong { nonce: u32 },
        }
        let old = fake(|seq, request| match request {
            Request::Ping { nonce } => frame(seq, &PongV1::Pong { nonce: *nonce }),
            _ => Vec::new(),
        });
        let err = Board::connect(old, quick()).err().unwrap();
        assert!(matches!(err, LinkError::Undecodable { frames: 3, .. }), "{err}");
    }

    #[test]
    fn a_silent_board_and_a_wrong_answer_are_errors_that_name_the_port() {
        let silent = fake(|_, _| Vec::new());
        let err = Board::connect(silent, quick()).err().unwrap();
        assert!(matches!(err, LinkError::NoAnswer { request: "Ping", attempts: 3, .. }), "{err}");
        assert!(err.to_string().contains("/dev/fake"), "{err}");

        let confused = fake(|seq, request| match request {
            Request::Ping { nonce } => {
                frame(seq, &Response::Pong { nonce: *nonce, protocol_version: PROTOCOL_VERSION })
            }
            _ => frame(seq, &Response::Pong { nonce: 0, protocol_version: PROTOCOL_VERSION }),
        });
        let mut board = Board::connect(confused, quick()).unwrap();
        let err = board.expect_ack(Request::SaveConfig).err().unwrap();
        assert!(matches!(err, LinkError::Unexpected { request: "SaveConfig", .. }), "{err}");
    }

    #[test]
    fn answers_to_earlier_attempts_are_ignored() {
        // The board answers each request twice: first with a stale sequence number.
        let echo = fake(|seq, request| {
            let body = match request {
                Request::Ping { nonce } => Response::Pong { nonce: *nonce, protocol_version: PROTOCOL_VERSION },
                _ => Response::Ack,
            };
            let mut bytes = frame(seq.wrapping_sub(1), &Response::Rejected(sts_twin_core::wire::Rejection::Store));
            bytes.extend(frame(seq, &body));
            bytes
        });
        let mut board = Board::connect(echo, quick()).unwrap();
        board.expect_ack(Request::ResetCounters).unwrap();
        assert_eq!(board.stats().stale_answers, 2);
    }
}
