//! The request bridge thread's side: [`ParamServer`] serves the request-response services,
//! which allocate per request and so stay out of the bus thread (ARCHITECTURE.md, "Data
//! flow"). Parameters: each multi-parameter request becomes one job per item, executed one PKW
//! task at a time by the drive's mailbox, and every accepted request is answered exactly once;
//! writes to a drive another process controls are refused unless forced. Operator commands:
//! OFF1/OFF2/OFF3 for a drive or the whole bus from any process, handed to the bus thread
//! through atomics (`EngineHandle::stop_drive`).

use super::bridge::OutService;
use super::{IpcError, IpcNode, MAX_CLIENTS, MAX_NODES, Svc, as_ns, fail, pid_of, text};
use core::time::Duration;
use iceoryx2::active_request::ActiveRequest;
use iceoryx2::identifiers::UniqueNodeId;
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::server::Server;
use iceoryx2::prelude::*;
use iceoryx2::service::port_factory::request_response::PortFactory as RequestResponseFactory;
use std::time::Instant;
use uss_catalogue::Catalogue;
use uss_engine::EngineHandle;
use uss_engine::jobs::{JobResult, Requester};
use uss_protocol::{Address, ParamRef, ParamTask};
use uss_shm_types::PathError;
use uss_shm_types::names;
use uss_shm_types::{Instance, Outcome, ParamRequest, ParamResponse, ParamResult, RequestError};

/// Creates the parameter service of `bus` and its server; `outs` are the drives' output
/// services, asked who controls a drive. Operator stops take a path of their own
/// (`crate::daemon::stops`).
pub(super) fn create(
    node: &IpcNode,
    bus: &Instance,
    attributes: &AttributeSpecifier,
    (outs, requests): (Vec<(Address, OutService)>, Listener<Svc>),
    setups: &[uss_engine::DriveSetup],
    requesters: std::sync::Arc<super::requesters::Requesters>,
) -> Result<ParamServer, IpcError> {
    let guards = setups
        .iter()
        .map(|d| {
            let rules = WriteRules {
                catalogue: Catalogue::of(d.family),
                writable: None,
            };
            (d.address, rules)
        })
        .collect();
    let (params, server) = serve(node, bus, &names::params(bus), attributes, "parameter")?;
    let answers = node
        .service_builder(&names::answers(bus))
        .event()
        .max_listeners(MAX_CLIENTS)
        .max_notifiers(1)
        .max_nodes(MAX_NODES)
        .create_with_attributes(attributes)
        .map_err(|e| fail(bus, "the answer event service")(text(e)))?
        .notifier_builder()
        .default_event_id(EventId::new(names::ANSWER_SENT))
        .create()
        .map_err(|e| fail(bus, "the answer notifier")(text(e)))?;
    Ok(ParamServer {
        server,
        requests,
        answers,
        answered: false,
        identities: Identities {
            config: node.config().clone(),
            params,
            outs,
        },
        pending: Vec::new(),
        put_backs: Vec::new(),
        bus: bus.bus.as_str().to_owned(),
        next_id: 1,
        next_dead_check: Instant::now(),
        watches: super::watches::Watches::new(requesters),
        guards,
    })
}

type Factory<Req, Resp> = RequestResponseFactory<Svc, Req, (), Resp, ()>;
/// A request-response service and ussd's server on it.
type Served<Req, Resp> = (Factory<Req, Resp>, Server<Svc, Req, (), Resp, ()>);

/// A request-response service (`what`: "parameter", "command") with ussd as its one server.
fn serve<Req, Resp>(
    node: &IpcNode,
    bus: &Instance,
    name: &ServiceName,
    attributes: &AttributeSpecifier,
    what: &str,
) -> Result<Served<Req, Resp>, IpcError>
where
    Req: core::fmt::Debug + ZeroCopySend + Copy,
    Resp: core::fmt::Debug + ZeroCopySend + Copy,
{
    let service = node
        .service_builder(name)
        .request_response::<Req, Resp>()
        .max_clients(MAX_CLIENTS)
        .max_servers(1)
        .max_active_requests_per_client(names::MAX_ACTIVE_REQUESTS)
        // As many loans as active requests: a client's threads may loan all at once (the
        // default, 2, refuses a third thread's loan while two are between loan and send).
        .max_loaned_requests(names::MAX_ACTIVE_REQUESTS)
        .max_nodes(MAX_NODES)
        .create_with_attributes(attributes)
        .map_err(|e| fail(bus, format!("the {what} service"))(text(e)))?;
    let server = service
        .server_builder()
        .create()
        .map_err(|e| fail(bus, format!("the {what} server"))(text(e)))?;
    Ok((service, server))
}

type Active = ActiveRequest<Svc, ParamRequest, (), ParamResponse, ()>;

/// A request whose items are on their way.
struct Pending {
    active: Active,
    response: ParamResponse,
    /// Job id of item 0; item i is `first_id + i`.
    first_id: u64,
    count: u64,
    remaining: usize,
    /// The asking client's node, if iceoryx2 lists it: when it dies, its jobs die too.
    client: Option<UniqueNodeId>,
    /// Its process id, once looked up (0: not yet).
    pid: u32,
    /// The jobs not yet on the wire were cancelled (the client died).
    cancelled: bool,
}

/// What a client raised on the way ([`uss_shm_types::REQUEST_PUT_BACK`]) and the write that
/// puts it back, which ussd runs should the client die before it writes that element again.
struct PutBack {
    client: UniqueNodeId,
    /// Its process id, once looked up (0: not yet).
    pid: u32,
    address: Address,
    task: ParamTask,
    /// The write as its family writes it (`P0010 := 0`), for the log.
    shown: String,
    /// The job of the client's own later write of the element: when it succeeds the put-back
    /// is the client's, and this one is dropped; when it fails or is cancelled, it stands.
    superseded_by: Option<u64>,
    /// The job ussd put it back with (the client died).
    running: Option<u64>,
    /// When ussd first tried to put it back: a drive that does not answer (offline, the line
    /// down) is tried again until [`PUT_BACK_WITHIN`] after it, as the client would have.
    first_try: Option<std::time::Instant>,
}

/// How long ussd goes on putting back a dead client's raise on a drive that does not answer:
/// as long as the client itself would have (its restore's `put_back_within`, 30 s).
const PUT_BACK_WITHIN: Duration = Duration::from_secs(30);

impl PutBack {
    /// Whether `task` writes the element this puts back.
    fn is_of(&self, address: Address, task: &ParamTask) -> bool {
        let key = |t: &ParamTask| match *t {
            ParamTask::Write { pnu, .. } => Some((pnu, None)),
            ParamTask::WriteArray { pnu, index, .. } => Some((pnu, Some(index))),
            _ => None,
        };
        self.address == address && key(task).is_some() && key(task) == key(&self.task)
    }
}

/// `task` (a write) as its family writes it: `P0010 := 0`, `P2014[0] := 500`.
fn shown_write(task: &ParamTask, rules: Option<&WriteRules>) -> String {
    let Some((pnu, index, value)) = written(task) else {
        return String::new();
    };
    let element = index.map(|i| format!("[{i}]")).unwrap_or_default();
    match rules.and_then(|r| r.catalogue).and_then(|c| c.param(pnu)) {
        Some(p) => format!("{}{element} := {}", p.id, p.show(value)),
        None => format!("P{pnu:04}{element} := {:#x}", value.as_u32()),
    }
}

/// A node iceoryx2 lists: its id, whether it is dead, its process (0: not known).
type Node = (UniqueNodeId, bool, u32);

/// Whether `client` died by iceoryx2's `nodes` (marked dead, or no longer listed); its process
/// id is noted in `pid` while it is listed with one.
fn died(nodes: &[Node], client: UniqueNodeId, pid: &mut u32) -> bool {
    match nodes.iter().find(|(node, _, _)| *node == client) {
        Some(&(_, dead, listed)) => {
            if listed != 0 {
                *pid = listed;
            }
            dead
        }
        None => true,
    }
}

/// How often pending requests are checked for dead clients: within this of a client's death
/// its jobs that have not reached the wire are cancelled.
const DEAD_CLIENT_CHECK: Duration = Duration::from_millis(100);

/// Requests sent without a [`names::REQUEST_SENT`] event are taken within this.
const REQUEST_POLL: Duration = Duration::from_nanos(names::REQUEST_POLL_NS);

/// The parameter bridge's servers. See the module documentation.
pub struct ParamServer {
    server: Server<Svc, ParamRequest, (), ParamResponse, ()>,
    /// Clients' "request sent" and the bus thread's "result ready" events.
    requests: Listener<Svc>,
    /// "Answer sent", for waiting clients.
    answers: Notifier<Svc>,
    /// Something was answered since the last notification.
    answered: bool,
    identities: Identities,
    pending: Vec<Pending>,
    /// What clients raised on the way, to put back should they die first.
    put_backs: Vec<PutBack>,
    /// The bus, for log events.
    bus: String,
    next_id: u64,
    next_dead_check: Instant,
    /// The requesting processes, watched by the bus thread before each job leaves a mailbox.
    watches: super::watches::Watches,
    /// What each drive takes without `--unsafe`.
    guards: Vec<(Address, WriteRules)>,
}

/// What a drive takes without `--unsafe`: what its family's catalogue does not guard (a family
/// uss-rt has no catalogue of takes nothing), narrowed to its `writable` list where it has one.
#[derive(Debug, Clone)]
struct WriteRules {
    catalogue: Option<&'static Catalogue>,
    writable: Option<Vec<ParamRef>>,
}

/// Why a write is refused before the bus.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Refused<'a> {
    /// No value the parameter can hold (NaN, an infinity): refused, `--unsafe` or not.
    Impossible,
    /// Neither a catalogue nor the drive's `writable` list says it is safe.
    Unlisted,
    /// Its catalogue guards it, for this reason.
    Guarded(&'a str),
}

impl WriteRules {
    /// Why writing `value` (the raw word or double word) to `pnu` (element `index`) is refused
    /// without `--unsafe`, if it is, with the catalogue's entry for the parameter (found once).
    fn refuse(
        &self,
        pnu: u16,
        index: Option<u8>,
        value: uss_protocol::Value,
    ) -> (
        Option<Refused<'static>>,
        Option<&'static uss_catalogue::Param>,
    ) {
        let judged = self.catalogue.map(|c| c.judge_write(pnu, value));
        let entry = judged.and_then(|j| j.entry);
        match judged {
            Some(j) if j.impossible => return (Some(Refused::Impossible), entry),
            Some(uss_catalogue::WriteJudgement {
                guard: Some(why), ..
            }) => return (Some(Refused::Guarded(why)), entry),
            _ => {}
        }
        let listed = |list: &[ParamRef]| {
            list.iter()
                .any(|p| p.pnu.get() == pnu && p.index.is_none_or(|i| Some(i.get()) == index))
        };
        let refused = match (&self.writable, self.catalogue) {
            (Some(list), _) if !listed(list) => Some(Refused::Unlisted),
            (None, None) => Some(Refused::Unlisted),
            _ => None,
        };
        (refused, entry)
    }
}

/// Who is behind a request and who controls a drive, from iceoryx2's own records (the node
/// of each port and the process of each node), not from what a client says of itself.
struct Identities {
    config: iceoryx2::config::Config,
    params: RequestResponseFactory<Svc, ParamRequest, (), ParamResponse, ()>,
    outs: Vec<(Address, OutService)>,
}

impl Identities {
    /// The process of a live node.
    fn pid(&self, node: &iceoryx2::identifiers::UniqueNodeId) -> Option<u32> {
        pid_of(&self.config, node)
    }

    /// The process that sent a parameter request.
    fn param_client(&self, origin: iceoryx2::identifiers::UniqueClientId) -> Option<u32> {
        self.param_client_node(origin).and_then(|n| self.pid(&n))
    }

    /// The node that sent a parameter request.
    fn param_client_node(
        &self,
        origin: iceoryx2::identifiers::UniqueClientId,
    ) -> Option<UniqueNodeId> {
        let mut node = None;
        self.params.dynamic_config().list_clients(|c| {
            if c.client_id == origin {
                node = Some(c.node_id);
                return CallbackProgression::Stop;
            }
            CallbackProgression::Continue
        });
        node
    }

    /// Every node iceoryx2 lists ([`super::listed_nodes`]).
    fn nodes(&self) -> Option<Vec<(UniqueNodeId, bool, u32)>> {
        super::listed_nodes(&self.config)
    }

    /// The live process that holds the drive's `out` publisher (its controller), if any.
    fn controller(&self, address: Address) -> Option<u32> {
        let (_, out) = self.outs.iter().find(|(a, _)| *a == address)?;
        let mut node = None;
        out.dynamic_config().list_publishers(|p| {
            node = Some(p.node_id);
            CallbackProgression::Stop
        });
        node.and_then(|n| self.pid(&n))
    }
}

impl core::fmt::Debug for ParamServer {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("ParamServer")
            .field("pending", &self.pending.len())
            .finish_non_exhaustive()
    }
}

impl ParamServer {
    /// Serves requests until the engine stops, then answers what is still pending (the
    /// engine ends every job it holds with "shutdown"; jobs it never took get that here).
    ///
    /// The thread sleeps until a client's [`names::REQUEST_SENT`] or the bus thread's
    /// [`names::RESULT_READY`] wakes it, or [`names::REQUEST_POLL_NS`] passes (for requests
    /// sent without the event).
    pub fn run(mut self, handle: &EngineHandle) {
        while !handle.is_stopped() {
            self.serve_once(handle, REQUEST_POLL);
        }
        let deadline = Instant::now() + Duration::from_secs(2);
        while !self.pending.is_empty() && Instant::now() < deadline {
            self.serve_once(handle, Duration::from_millis(5));
        }
        for mut p in self.pending.drain(..) {
            for r in &mut p.response.results[..p.count as usize] {
                if r.outcome == Outcome::NotRun.code() {
                    *r = ParamResult {
                        outcome: Outcome::Shutdown.code(),
                        ..ParamResult::NOT_RUN
                    };
                }
            }
            let _ = p.active.send_copy(p.response);
            self.answered = true;
        }
        self.notify_answered();
    }

    /// Takes new requests and finished jobs and routes them, tells waiting clients when
    /// something was answered, then sleeps until woken or `wait` passes.
    pub fn serve_once(&mut self, handle: &EngineHandle, wait: Duration) {
        // Results and new requests first: the rest can wait a moment.
        while let Some(r) = handle.recv_result(Duration::ZERO) {
            self.route(&r);
        }
        while let Ok(Some(active)) = self.server.receive() {
            self.accept(active, handle);
        }
        self.notify_answered();
        self.check_dead_clients(handle);
        if self.requests.timed_wait(|_| {}, wait).is_err() {
            // The event is broken (it never is in practice): keep serving by polling.
            std::thread::sleep(wait.min(Duration::from_millis(1)));
        }
    }

    fn notify_answered(&mut self) {
        if core::mem::take(&mut self.answered) {
            let _ = self.answers.notify();
        }
    }

    fn accept(&mut self, active: Active, handle: &EngineHandle) {
        let request = *active.payload();
        // Checked once, first: the rules below read the tasks, never the raw items.
        let (address, mut items) = match request.validate() {
            Ok(ok) => ok,
            Err(refusal) => {
                // A client that died meanwhile cannot be answered; nothing else to do.
                let _ = active.send_copy(ParamResponse::refused(request.address, refusal));
                self.answered = true;
                return;
            }
        };
        let checked = Checked {
            request: &request,
            address,
            tasks: &items,
            rules: self.rules(address),
        };
        if let Some(refusal) = checked
            .refuse_unindexed()
            .or_else(|| checked.refuse_eeprom_task())
            .or_else(|| self.refuse_controlled(&active, &checked))
            .or_else(|| self.refuse_guarded(&active, &checked))
        {
            let _ = active.send_copy(refusal);
            self.answered = true;
            return;
        }
        // Checked with the rest (its guards, its drive's controller), run only should the client
        // die first.
        let put_back = (request.flags & uss_shm_types::REQUEST_PUT_BACK != 0)
            .then(|| items.pop())
            .flatten();
        let first_id = self.next_id;
        self.next_id += items.len() as u64;
        // The node is cheap to find; its process (a walk over every node) only at its first
        // request: the bus thread checks that process before each job leaves the mailbox.
        let client = self.identities.param_client_node(active.origin());
        let requester = client.map_or(Requester::NONE, |node| {
            let identities = &self.identities;
            self.watches.request(node, || identities.pid(&node))
        });
        // All or nothing: a request is never run in part (its drive's queue too full for all
        // of it, an item the drive cannot take).
        if let Err((item, e)) = handle.submit_all_for(address, first_id, &items, requester) {
            tracing::debug!(
                bus = self.bus,
                drive = address.get(),
                "drive {address}: parameter request of {} item(s) refused: {e}",
                items.len()
            );
            let _ = active.send_copy(ParamResponse::refused(
                request.address,
                uss_shm_types::Refusal {
                    error: RequestError::from(&e),
                    item: item.and_then(|i| u8::try_from(i).ok()),
                },
            ));
            self.answered = true;
            if let Some(node) = client {
                self.watches.answered(node);
            }
            return;
        }
        tracing::debug!(
            bus = self.bus,
            drive = address.get(),
            first_job = first_id,
            "drive {address}: parameter request of {} item(s) accepted as jobs {first_id}..{}",
            items.len(),
            first_id + items.len() as u64,
        );
        if let Some(node) = client {
            self.keep_put_back(node, address, first_id, &items, put_back);
        }
        let mut response = ParamResponse::new(request.address);
        response.count = items.len() as u8;
        self.pending.push(Pending {
            active,
            response,
            first_id,
            count: items.len() as u64,
            remaining: items.len(),
            client,
            pid: 0,
            cancelled: false,
        });
    }

    /// Every [`DEAD_CLIENT_CHECK`] while requests are pending or raises are kept, one look at
    /// iceoryx2's nodes: the jobs of dead clients are cancelled, then their raises put back.
    fn check_dead_clients(&mut self, handle: &EngineHandle) {
        let idle = self.pending.iter().all(|p| p.cancelled)
            && self.put_backs.iter().all(|p| p.running.is_some());
        if idle || Instant::now() < self.next_dead_check {
            return;
        }
        self.next_dead_check = Instant::now() + DEAD_CLIENT_CHECK;
        let Some(nodes) = self.identities.nodes() else {
            return;
        };
        self.cancel_for_dead_clients(&nodes, handle);
        self.put_back_for_dead_clients(&nodes, handle);
    }

    /// Cancels the jobs of requests whose client died that have not reached the wire. The one
    /// on the wire completes; every job still ends in exactly one result, which nobody
    /// receives.
    fn cancel_for_dead_clients(&mut self, nodes: &[Node], handle: &EngineHandle) {
        for p in self.pending.iter_mut().filter(|p| !p.cancelled) {
            let Some(client) = p.client else {
                continue;
            };
            if !died(nodes, client, &mut p.pid) {
                continue;
            }
            let pid = p.pid;
            if handle.cancel(p.first_id..p.first_id + p.count) {
                p.cancelled = true;
                tracing::info!(
                    pid,
                    jobs = p.remaining,
                    "client process {pid} died: its parameter jobs that have not reached the wire are cancelled"
                );
            }
        }
    }

    /// Keeps `put_back` (the write that undoes what this request of `client` raises), or marks
    /// what the request's writes (jobs from `first_id`) put back themselves. A client that
    /// raises an element twice keeps the first put-back: the value before either.
    fn keep_put_back(
        &mut self,
        client: UniqueNodeId,
        address: Address,
        first_id: u64,
        items: &[ParamTask],
        put_back: Option<ParamTask>,
    ) {
        let Some(task) = put_back else {
            for p in self.put_backs.iter_mut().filter(|p| p.client == client) {
                if let Some(i) = items.iter().position(|t| p.is_of(address, t)) {
                    p.superseded_by = Some(first_id + i as u64);
                }
            }
            return;
        };
        let kept = PutBack {
            client,
            pid: 0,
            address,
            task,
            shown: shown_write(&task, self.rules(address)),
            superseded_by: None,
            running: None,
            first_try: None,
        };
        if !self
            .put_backs
            .iter()
            .any(|p| p.client == client && p.is_of(address, &task))
        {
            self.put_backs.push(kept);
        }
    }

    /// A finished job that puts back a raise: the client's own (its put-back is done, unless
    /// the write failed) or ussd's for a dead client (logged).
    fn put_back_ended(&mut self, r: &JobResult) {
        let id = r.job.id;
        let ok = matches!(r.outcome, Ok(Ok(_)));
        let bus = self.bus.as_str();
        self.put_backs.retain_mut(|p| {
            if p.running == Some(id) {
                let (what, drive, pid) = (&p.shown, p.address.get(), p.pid);
                // The drive did not answer: tried again (by the next check) while there is
                // time; a drive's refusal is its answer.
                let unanswered = matches!(
                    r.outcome,
                    Err(PathError::DriveOffline | PathError::Timeout | PathError::LineDown)
                );
                if unanswered && p.first_try.is_some_and(|t| t.elapsed() < PUT_BACK_WITHIN) {
                    p.running = None;
                    return true;
                }
                let died = format!(
                    "drive {drive}: client process {pid} died with a parameter raised on the way (a restore or commissioning cut short)"
                );
                if ok {
                    tracing::warn!(bus, drive, pid, "{died}: ussd put it back, {what}");
                } else {
                    let outcome = r.outcome;
                    tracing::error!(
                        bus,
                        drive,
                        pid,
                        "{died}: putting it back, {what}, failed ({outcome:?}); set it by hand"
                    );
                }
                return false;
            }
            if p.superseded_by == Some(id) {
                p.superseded_by = None;
                return !ok;
            }
            true
        });
    }

    /// Runs the put-backs of clients that died, each as ussd's own job, after the dead
    /// client's pending jobs were cancelled.
    fn put_back_for_dead_clients(&mut self, nodes: &[Node], handle: &EngineHandle) {
        // Last raised first: the access level goes back after quick commissioning ends.
        for p in self
            .put_backs
            .iter_mut()
            .rev()
            .filter(|p| p.running.is_none())
        {
            if !died(nodes, p.client, &mut p.pid) {
                continue;
            }
            // Tried at each check until the drive takes it (or the time is up).
            p.first_try.get_or_insert_with(std::time::Instant::now);
            let id = self.next_id;
            if handle
                .submit_all_for(p.address, id, &[p.task], Requester::NONE)
                .is_ok()
            {
                self.next_id += 1;
                p.running = Some(id);
            }
        }
    }

    /// A write to a drive that another process controls is refused unless the request says it
    /// is deliberate ([`uss_shm_types::REQUEST_FORCE`]); reads are never restricted, and the
    /// controlling process may write through its own handles.
    fn refuse_controlled(&self, active: &Active, checked: &Checked<'_>) -> Option<ParamResponse> {
        let Checked {
            request,
            address,
            tasks,
            ..
        } = *checked;
        if !tasks.iter().any(ParamTask::is_write) || request.is_forced() {
            return None;
        }
        let controller = self.identities.controller(address)?;
        let requester = self.identities.param_client(active.origin());
        if requester == Some(controller) {
            return None;
        }
        let mut response = ParamResponse::refused(
            request.address,
            uss_shm_types::Refusal {
                error: RequestError::Controlled,
                item: None,
            },
        );
        response.controller_pid = controller;
        Some(response)
    }

    /// The rules of drive `address`.
    fn rules(&self, address: Address) -> Option<&WriteRules> {
        self.guards
            .iter()
            .find(|(a, _)| *a == address)
            .map(|(_, r)| r)
    }

    /// A write the drive's rules do not take without `--unsafe` ([`WriteRules`]) is refused
    /// unless the request is marked unsafe ([`uss_shm_types::REQUEST_UNSAFE`]); an unsafe one
    /// is logged with its process. A value no parameter of its type holds (NaN) is refused
    /// either way.
    fn refuse_guarded(&self, active: &Active, checked: &Checked<'_>) -> Option<ParamResponse> {
        let Checked {
            request,
            address,
            tasks,
            rules,
        } = *checked;
        let rules = rules?;
        for (i, task) in tasks.iter().enumerate() {
            let Some((pnu, index, asked)) = written(task) else {
                continue;
            };
            let (Some(refused), entry) = rules.refuse(pnu, index, asked) else {
                continue;
            };
            let error = match refused {
                Refused::Impossible => RequestError::ImpossibleValue,
                _ if request.is_unsafe() => {
                    let pid = self.identities.param_client(active.origin()).unwrap_or(0);
                    let why = match refused {
                        Refused::Guarded(why) => why,
                        _ => "not listed as writable (no catalogue, or the drive's writable list)",
                    };
                    // Logged as asked, before the drive answers: the parameter as its family
                    // writes it, the element, the value in the parameter's own type where the
                    // catalogue knows it, and the word or double word sent (the type may read
                    // a value other than the one a client meant: a double word to a word).
                    let element = index.map(|i| format!("[{i}]")).unwrap_or_default();
                    let (id, shown) = entry.map_or_else(
                        || (format!("P{pnu:04}"), format!("{:#x}", asked.as_u32())),
                        |p| (p.id.to_string(), p.show(asked)),
                    );
                    let width = if asked.is_dword() {
                        "double word"
                    } else {
                        "word"
                    };
                    tracing::warn!(
                        bus = self.bus,
                        drive = address.get(),
                        pid,
                        "drive {address}: {id}{element} := {shown} asked with --unsafe by process {pid} (guarded: {why}; sent as the {width} {:#x})",
                        asked.as_u32()
                    );
                    continue;
                }
                Refused::Unlisted => RequestError::Unlisted,
                Refused::Guarded(_) => RequestError::Guarded,
            };
            return Some(ParamResponse::refused(
                request.address,
                uss_shm_types::Refusal {
                    error,
                    item: u8::try_from(i).ok(),
                },
            ));
        }
        None
    }

    /// Narrows what drive `address` takes without `--unsafe` to `writable` (its configuration's
    /// `writable` list).
    pub fn limit_writes(&mut self, address: Address, writable: Vec<ParamRef>) {
        if let Some((_, rules)) = self.guards.iter_mut().find(|(a, _)| *a == address) {
            rules.writable = Some(writable);
        }
    }

    fn route(&mut self, r: &JobResult) {
        let id = r.job.id;
        self.put_back_ended(r);
        let Some(at) = self
            .pending
            .iter()
            .position(|p| (p.first_id..p.first_id + p.count).contains(&id))
        else {
            return;
        };
        tracing::trace!(
            bus = self.bus,
            drive = r.job.address.get(),
            job = id,
            telegrams = r.telegrams,
            on_wire_us = r.on_wire.as_micros() as u64,
            "job {id} ended: {:?}",
            r.outcome
        );
        let p = &mut self.pending[at];
        p.response.results[(id - p.first_id) as usize] =
            ParamResult::of(&r.outcome, r.telegrams, as_ns(r.on_wire));
        p.remaining -= 1;
        if p.remaining == 0 {
            tracing::debug!(
                bus = self.bus,
                drive = r.job.address.get(),
                first_job = p.first_id,
                "jobs {}..{} answered",
                p.first_id,
                p.first_id + p.count
            );
            let p = self.pending.swap_remove(at);
            let cancelled = p.response.results[..p.count as usize]
                .iter()
                .filter(|r| r.outcome == Outcome::Cancelled.code())
                .count();
            if cancelled > 0 {
                let pid = p.client.and_then(|n| self.watches.pid(n)).unwrap_or(p.pid);
                tracing::info!(
                    bus = self.bus,
                    pid,
                    jobs = cancelled,
                    "client process {pid} died: {cancelled} of its parameter jobs were cancelled before they reached the wire"
                );
            }
            let _ = p.active.send_copy(p.response);
            self.answered = true;
            if let Some(node) = p.client {
                self.watches.answered(node);
            }
        }
    }
}

/// A request ussd has checked: its drive, the tasks its items ask for, and the drive's write
/// rules (found once for the request).
#[derive(Clone, Copy)]
struct Checked<'a> {
    request: &'a ParamRequest,
    address: Address,
    tasks: &'a [ParamTask],
    rules: Option<&'a WriteRules>,
}

impl Checked<'_> {
    /// An array parameter (its family's catalogue says so) named without its element is
    /// refused, read or write, from every front-end: a drive would take element 0, which may not
    /// be the element the user meant (`P1000`'s data sets, `P2014`'s two links).
    fn refuse_unindexed(&self) -> Option<ParamResponse> {
        let catalogue = self.rules?.catalogue?;
        let item = self.tasks.iter().position(|task| {
            let unindexed = match *task {
                ParamTask::Read { pnu } | ParamTask::Write { pnu, .. } => Some(pnu),
                _ => None,
            };
            unindexed
                .and_then(|pnu| catalogue.param(pnu.get()))
                .is_some_and(uss_catalogue::Param::is_array)
        })?;
        Some(ParamResponse::refused(
            self.request.address,
            uss_shm_types::Refusal {
                error: RequestError::IndexRequired,
                item: u8::try_from(item).ok(),
            },
        ))
    }
}

impl Checked<'_> {
    /// A write that stores one value in EEPROM (task codes 11..14) to a drive whose family has
    /// no such tasks (a G120's CU2x0-2: its settings become permanent only by its "copy RAM to
    /// ROM", p0971) is refused before the bus, from every front-end: the drive would refuse it
    /// (error 106), and a user who asked for a permanent value must learn how to get one.
    fn refuse_eeprom_task(&self) -> Option<ParamResponse> {
        let catalogue = self.rules?.catalogue?;
        if catalogue.eeprom_tasks {
            return None;
        }
        let item = self.tasks.iter().position(|task| {
            matches!(
                *task,
                ParamTask::Write {
                    storage: uss_protocol::Storage::RamAndEeprom,
                    ..
                } | ParamTask::WriteArray {
                    storage: uss_protocol::Storage::RamAndEeprom,
                    ..
                }
            )
        })?;
        Some(ParamResponse::refused(
            self.request.address,
            uss_shm_types::Refusal {
                error: RequestError::NoEepromTask,
                item: u8::try_from(item).ok(),
            },
        ))
    }
}

/// The parameter, element and raw value a task writes, if it writes.
fn written(task: &ParamTask) -> Option<(u16, Option<u8>, uss_protocol::Value)> {
    match *task {
        ParamTask::Write { pnu, value, .. } => Some((pnu.get(), None, value)),
        ParamTask::WriteArray {
            pnu, index, value, ..
        } => Some((pnu.get(), Some(index.get()), value)),
        _ => None,
    }
}
