//! One request, one answer: the client side of ussd's request-response services (`params`,
//! `command`), opened once per ussd generation and shared by a bus's threads.

use crate::ClientError;
use crate::link::Link;
use crate::open::{Ipc, layout_verifier, opened};
use core::fmt::Debug;
use core::time::Duration;
use iceoryx2::port::client::Client;
use iceoryx2::prelude::{ServiceName, ZeroCopySend};
use std::sync::OnceLock;
use std::time::Instant;

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

/// The client of service `name` kept in `cell`, opened on first use.
pub(crate) fn client<'a, Req, Resp>(
    link: &Link,
    cell: &'a OnceLock<Client<Ipc, Req, (), Resp, ()>>,
    name: &ServiceName,
) -> Result<&'a Client<Ipc, Req, (), Resp, ()>, ClientError>
where
    Req: Debug + ZeroCopySend + Copy,
    Resp: Debug + ZeroCopySend + Copy,
{
    if let Some(client) = cell.get() {
        return Ok(client);
    }
    let bus = link.name.as_str();
    let service = opened(
        link.node
            .service_builder(name)
            .request_response::<Req, Resp>()
            .open_with_attributes(&layout_verifier()?),
        bus,
        name,
        || ClientError::NotRunning {
            bus: bus.to_owned(),
        },
    )?;
    let client = service
        .client_builder()
        .create()
        .map_err(|e| ClientError::ipc(format!("a client of {}", name.as_str()), e))?;
    // Another thread may have won the race; its client serves as well as this one.
    let _ = cell.set(client);
    cell.get()
        .ok_or_else(|| ClientError::ipc(format!("the client of {}", name.as_str()), "not kept"))
}

/// Sends `request` and waits up to `timeout` for its one answer.
pub(crate) fn round_trip<Req, Resp>(
    client: &Client<Ipc, Req, (), Resp, ()>,
    request: Req,
    timeout: Duration,
) -> Result<Result<Resp, NoAnswer>, ClientError>
where
    Req: Debug + ZeroCopySend + Copy,
    Resp: Debug + ZeroCopySend + Copy,
{
    let pending = client
        .send_copy(request)
        .map_err(|e| ClientError::ipc("sending a request to ussd", e))?;
    if pending.number_of_server_connections() == 0 {
        return Ok(Err(NoAnswer::NotRunning));
    }
    let deadline = Instant::now() + timeout;
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
        if Instant::now() >= deadline {
            return Ok(Err(NoAnswer::Timeout));
        }
        // A response has no file descriptor to wait on: poll, backing off to 2 ms.
        std::thread::sleep(pause);
        pause = (pause * 2).min(Duration::from_millis(2));
    }
}
