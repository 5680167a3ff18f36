//! The service runtime: what every bdis-slam service does the same way around its own logic, so a service is
//! `main.rs` (its arguments) plus `node.rs` (its ports and what it does with a sample), the way dora splits a
//! node's `main` from its `run`.
//!
//! * [`serve`]: the WaitSet loop. It sleeps until a listener fires or a deadline passes (so the heartbeat goes
//!   out while nothing arrives), stops on SIGINT/SIGTERM, drains the wake-up events, sends the telemetry
//!   keepalive and hands over to the service, which receives everything waiting and says whether its stream
//!   ended. No polling, no sleeping.
//! * [`send_end_of_stream`] and [`copy_into`]: the zero-length last sample of a stream, and a payload copied
//!   into a loan.
//! * [`init_logging`] and [`finish`]: the start and the one-line fatal exit of every binary.

use std::time::Duration;

use bdis_ipc::TelemetryPublisher;
use iceoryx2::port::listener::Listener;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::prelude::*;
use iceoryx2::waitset::WaitSetRunResult;

pub use bdis_ipc::process::{finish, init_logging};

/// What a service holding frames does first: owner-only files (see [`bdis_ipc::process::private_files`]) and
/// no core dumps ([`bdis_ipc::process::no_core_dumps`]).
pub fn protect_patient_data() {
    bdis_ipc::process::private_files();
    bdis_ipc::process::no_core_dumps();
}

/// How long a service sleeps at most with nothing arriving: the telemetry keepalive goes out at least this often,
/// well inside the launcher's liveness deadlines.
pub const WAKE_DEADLINE: Duration = Duration::from_secs(1);

/// Everything the runtime itself can fail at. The iceoryx2 error is kept as the source.
#[derive(Debug, thiserror::Error)]
pub enum NodeError {
    #[error("create a WaitSet")]
    WaitSet(#[source] iceoryx2::waitset::WaitSetCreateError),
    #[error("attach a listener to the WaitSet")]
    Attach(#[source] iceoryx2::waitset::WaitSetAttachmentError),
    #[error("wait for samples")]
    Wait(#[source] iceoryx2::waitset::WaitSetRunError),
    #[error("loan the end-of-stream sample")]
    Loan(#[source] iceoryx2::port::LoanError),
    #[error("send the end-of-stream sample")]
    Send(#[source] iceoryx2::port::SendError),
}

/// What the service says after handling a wake-up.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Flow {
    /// Keep serving.
    Continue,
    /// The stream ended (the service received its end-of-stream sample, or finished otherwise).
    Finished,
}

/// How [`serve`] ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Ended {
    /// The service returned [`Flow::Finished`].
    Finished,
    /// SIGINT or SIGTERM arrived (the launcher's stop ladder, a user's Ctrl-C).
    StopRequested,
}

/// The service loop. `wake_on[0]` is the service's input and carries the [`WAKE_DEADLINE`]; the others (pose
/// corrections, snapshot requests, …) wake it too. After every wake-up — an event, or the deadline with nothing
/// new — the pending events are drained, the keepalive is sent and `on_wake` runs; it receives everything
/// waiting (events are only wake-ups: samples are counted by receiving them). A service error ends the loop
/// with that error; the caller decides what it still writes.
pub fn serve<E: From<NodeError>>(
    wake_on: &[&Listener<ipc::Service>],
    telemetry: &mut TelemetryPublisher,
    mut on_wake: impl FnMut(&mut TelemetryPublisher) -> Result<Flow, E>,
) -> Result<Ended, E> {
    let waitset = WaitSetBuilder::new().create::<ipc::Service>().map_err(NodeError::WaitSet)?;
    let mut guards = Vec::with_capacity(wake_on.len());
    for (i, listener) in wake_on.iter().enumerate() {
        let guard = if i == 0 {
            waitset.attach_deadline(*listener, WAKE_DEADLINE)
        } else {
            waitset.attach_notification(*listener)
        };
        guards.push(guard.map_err(NodeError::Attach)?);
    }
    loop {
        let result = waitset.wait_and_process_once(|_| CallbackProgression::Continue).map_err(NodeError::Wait)?;
        if matches!(result, WaitSetRunResult::TerminationRequest | WaitSetRunResult::Interrupt) {
            return Ok(Ended::StopRequested);
        }
        for listener in wake_on {
            // Only wake-ups: a failed read of them loses nothing (the samples are received below).
            let _ = bdis_ipc::drain_events(listener);
        }
        telemetry.keepalive();
        if on_wake(telemetry)? == Flow::Finished {
            return Ok(Ended::Finished);
        }
    }
}

/// Sends the zero-length sample that ends a stream of `[u8]` samples, with `header` (which carries the
/// topic's end-of-stream flag).
pub fn send_end_of_stream<H: std::fmt::Debug + Default + ZeroCopySend>(
    publisher: &Publisher<ipc::Service, [u8], H>,
    header: H,
) -> Result<(), NodeError> {
    let loan = publisher.loan_slice_uninit(0).map_err(NodeError::Loan)?;
    // SAFETY: a zero-length payload has nothing to initialise.
    let mut sample = unsafe { loan.assume_init() };
    *sample.user_header_mut() = header;
    sample.send().map_err(NodeError::Send)?;
    Ok(())
}

/// Copies `src` into the start of a loaned payload; returns how many bytes were written (the shorter length).
pub fn copy_into(dst: &mut [std::mem::MaybeUninit<u8>], src: &[u8]) -> usize {
    let n = dst.len().min(src.len());
    for (d, &b) in dst[..n].iter_mut().zip(&src[..n]) {
        d.write(b);
    }
    n
}

/// Writes `values` as native-endian bytes into a loaned payload; returns how many bytes were written.
pub fn copy_floats_into(dst: &mut [std::mem::MaybeUninit<u8>], values: &[f32]) -> usize {
    let mut n = 0;
    for (chunk, v) in dst.chunks_exact_mut(4).zip(values) {
        for (d, b) in chunk.iter_mut().zip(v.to_ne_bytes()) {
            d.write(b);
        }
        n += 4;
    }
    n
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::mem::MaybeUninit;

    #[test]
    fn copies_write_exactly_the_shorter_length() {
        let mut dst = [MaybeUninit::<u8>::uninit(); 4];
        assert_eq!(copy_into(&mut dst, &[1, 2, 3, 4, 5, 6]), 4);
        let mut dst = [MaybeUninit::<u8>::uninit(); 8];
        assert_eq!(copy_into(&mut dst[..], &[7, 8]), 2);
        // SAFETY: the first two bytes were written.
        assert_eq!(unsafe { [dst[0].assume_init(), dst[1].assume_init()] }, [7, 8]);
    }

    #[test]
    fn floats_are_written_as_native_bytes() {
        let mut dst = [MaybeUninit::<u8>::uninit(); 8];
        assert_eq!(copy_floats_into(&mut dst, &[1.5, -2.0, 9.0]), 8);
        // SAFETY: all eight bytes were written.
        let bytes: Vec<u8> = dst.iter().map(|b| unsafe { b.assume_init() }).collect();
        assert_eq!(f32::from_ne_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]), 1.5);
        assert_eq!(f32::from_ne_bytes([bytes[4], bytes[5], bytes[6], bytes[7]]), -2.0);
    }
}
