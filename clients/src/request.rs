//! One request, one answer: the client side of ussd's request-response services (`params`,
//! `command`), opened once per ussd generation and shared by a bus's threads.

use crate::ClientError;
use crate::link::{Link, Services};
use crate::open::{Ipc, layout_verifier, opened};
use core::fmt::Debug;
use core::time::Duration;
use iceoryx2::port::client::Client;
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::prelude::EventId;
use iceoryx2::prelude::{ServiceName, ZeroCopySend};
use std::sync::{Arc, Condvar, Mutex, OnceLock, PoisonError};
use std::time::Instant;
use uss_shm_types::Instance;
use uss_shm_types::names::{self, MAX_ACTIVE_REQUESTS};

/// The longest a waiting client sleeps before it looks at its request again.
const ANSWER_CHECK: Duration = Duration::from_millis(2);

/// A client port of a request-response service and its free request slots: iceoryx2 refuses
/// a port's request beyond [`MAX_ACTIVE_REQUESTS`] on their way, so a bus's threads take
/// turns here instead (a fifth thread waits until one of the four is answered).
#[derive(Debug)]
pub(crate) struct Requester<Req, Resp>
where
    Req: Debug + ZeroCopySend + Copy,
    Resp: Debug + ZeroCopySend + Copy,
{
    client: Client<Ipc, Req, (), Resp, ()>,
    in_flight: Mutex<usize>,
    freed: Condvar,
    /// The generation's request and answer events, shared by the bus's requesters.
    events: Arc<RequestEvents>,
}

/// A ussd instance's request and answer events, opened once per client process and
/// generation for both the parameter and the command requester.
#[derive(Debug)]
pub(crate) struct RequestEvents {
    /// Tells ussd a request was sent ([`names::REQUEST_SENT`]); `None`: ussd finds it within
    /// [`names::REQUEST_POLL_NS`] anyway.
    requests: Option<Notifier<Ipc>>,
    /// ussd's [`names::ANSWER_SENT`] events; `None`: the answer is polled for.
    answers: Option<Listener<Ipc>>,
}

impl RequestEvents {
    /// The events of `instance` where this process can have them (one beyond the events' port
    /// limits polls instead).
    fn open(link: &Link, instance: &Instance) -> Result<Self, ClientError> {
        let verifier = layout_verifier()?;
        let event = |name: ServiceName| {
            link.node
                .service_builder(&name)
                .event()
                .open_with_attributes(&verifier)
                .ok()
        };
        let requests = event(names::requests(instance)).and_then(|s| {
            s.notifier_builder()
                .default_event_id(EventId::new(names::REQUEST_SENT))
                .create()
                .ok()
        });
        let answers =
            event(names::answers(instance)).and_then(|s| s.listener_builder().create().ok());
        Ok(Self { requests, answers })
    }
}

/// One taken request slot, given back when dropped.
struct Slot<'a> {
    in_flight: &'a Mutex<usize>,
    freed: &'a Condvar,
}

impl Drop for Slot<'_> {
    fn drop(&mut self) {
        *self
            .in_flight
            .lock()
            .unwrap_or_else(PoisonError::into_inner) -= 1;
        self.freed.notify_one();
    }
}

impl<Req, Resp> Requester<Req, Resp>
where
    Req: Debug + ZeroCopySend + Copy,
    Resp: Debug + ZeroCopySend + Copy,
{
    /// Takes a request slot, waiting until `deadline` at most.
    fn slot(&self, deadline: Instant) -> Option<Slot<'_>> {
        let mut in_flight = self
            .in_flight
            .lock()
            .unwrap_or_else(PoisonError::into_inner);
        while *in_flight >= MAX_ACTIVE_REQUESTS {
            let left = deadline.checked_duration_since(Instant::now())?;
            in_flight = self
                .freed
                .wait_timeout(in_flight, left)
                .unwrap_or_else(PoisonError::into_inner)
                .0;
        }
        *in_flight += 1;
        Some(Slot {
            in_flight: &self.in_flight,
            freed: &self.freed,
        })
    }
}

/// How a round trip ended without an answer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum NoAnswer {
    /// No server: ussd does not run the bus.
    NotRunning,
    /// The server let go of the request without answering (ussd stopped or crashed).
    Dropped,
    /// Nothing within the timeout.
    Timeout,
}

/// The client of service `name` kept in `cell` (one of `services`'), opened on first use
/// (only then is its name made), with the generation's request and answer events.
pub(crate) fn client<'a, Req, Resp>(
    link: &Link,
    services: &'a Services,
    cell: &'a OnceLock<Requester<Req, Resp>>,
    name: impl FnOnce() -> ServiceName,
) -> Result<&'a Requester<Req, Resp>, ClientError>
where
    Req: Debug + ZeroCopySend + Copy,
    Resp: Debug + ZeroCopySend + Copy,
{
    if let Some(client) = cell.get() {
        return Ok(client);
    }
    let name = &name();
    let bus = link.name.as_str();
    let service = opened(
        link.node
            .service_builder(name)
            .request_response::<Req, Resp>()
            .open_with_attributes(&layout_verifier()?),
        bus,
        name,
        || ClientError::not_running(bus.to_owned()),
    )?;
    let client = service
        .client_builder()
        .create()
        .map_err(|e| ClientError::ipc(format!("a client of {}", name.as_str()), e))?;
    let events = if let Some(events) = services.events.get() {
        Arc::clone(events)
    } else {
        let events = Arc::new(RequestEvents::open(link, &services.instance)?);
        // Another thread may have won the race; its events serve as well as these.
        Arc::clone(services.events.get_or_init(|| events))
    };
    // Another thread may have won the race; its client serves as well as this one.
    let _ = cell.set(Requester {
        client,
        in_flight: Mutex::new(0),
        freed: Condvar::new(),
        events,
    });
    cell.get()
        .ok_or_else(|| ClientError::ipc(format!("the client of {}", name.as_str()), "not kept"))
}

/// Sends `request` and waits up to `timeout` for its one answer (the wait for a free request
/// slot included).
pub(crate) fn round_trip<Req, Resp>(
    requester: &Requester<Req, Resp>,
    request: Req,
    timeout: Duration,
) -> Result<Result<Resp, NoAnswer>, ClientError>
where
    Req: Debug + ZeroCopySend + Copy,
    Resp: Debug + ZeroCopySend + Copy,
{
    let deadline = Instant::now() + timeout;
    let Some(_slot) = requester.slot(deadline) else {
        return Ok(Err(NoAnswer::Timeout));
    };
    let pending = requester
        .client
        .send_copy(request)
        .map_err(|e| ClientError::ipc("sending a request to ussd", e))?;
    if pending.number_of_server_connections() == 0 {
        return Ok(Err(NoAnswer::NotRunning));
    }
    if let Some(requests) = &requester.events.requests {
        let _ = requests.notify();
    }
    let mut pause = Duration::from_micros(50);
    loop {
        // Looked at before `receive`, so an answer sent just before the server let go of the
        // request is still received.
        let connected = pending.is_connected();
        if let Some(response) = pending
            .receive()
            .map_err(|e| ClientError::ipc("receiving ussd's answer", e))?
        {
            return Ok(Ok(*response));
        }
        if !connected {
            return Ok(Err(NoAnswer::Dropped));
        }
        let Some(left) = deadline.checked_duration_since(Instant::now()) else {
            return Ok(Err(NoAnswer::Timeout));
        };
        // Woken by ussd's answer to any request (another thread's or process's too, then
        // looked again); at least every ANSWER_CHECK, for a ussd that let go of the request and
        // for threads that share the listener (one waits on it, the others take turns).
        let woken = requester
            .events
            .answers
            .as_ref()
            .is_some_and(|a| a.timed_wait(|_| {}, left.min(ANSWER_CHECK)).is_ok());
        if !woken {
            // No events: poll, backing off to 2 ms.
            std::thread::sleep(pause.min(left));
            pause = (pause * 2).min(ANSWER_CHECK);
        }
    }
}
