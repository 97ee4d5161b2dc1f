//! The MG400 TCP client: a thin tokio shell around the sans-io codec in `proto`.
//!
//! [`Mg400Client`] owns three connections:
//!
//! - dashboard (29999) and motion (30003): each a `CommandLink` that writes one request,
//!   feeds the bytes it reads into a [`ReplyFramer`] and returns the reply whose echo names
//!   the request (a late reply to an abandoned request is recognised and skipped). A dropped
//!   socket is reconnected and the request sent again; a timed-out link is closed so the next
//!   request starts clean.
//! - feedback (30004): a background task decodes frames with [`FeedbackDecoder`] and
//!   publishes the newest one on a `watch` channel, reconnecting when the stream drops.
//!
//! Arrival ([`Arm::wait_arrived`]) combines both completion signals of the fact sheet
//! (section 5): `Sync()` returns once the queue has drained, then the newest feedback frame
//! (or a later one) must show mode 5 and the tool within the arrival tolerance of the target.
//! A move to the current pose therefore returns as soon as Sync answers. The newest frame may
//! have been read just before the reply: the reader runs on its own task, so whether a frame
//! read around the reply is published before the job looks is a matter of scheduling. Waiting
//! for a frame newer than the one held would make the outcome depend on that race, and a
//! recording could then not be replayed (`record::replay` publishes each frame as soon as it
//! is next). A frame showing mode 5 at the target cannot predate the move, except when the
//! arm was already there. An alarm (mode 9 or
//! ErrorStatus in the feedback, or a refused command while in alarm) becomes
//! [`ArmError::Fault`] with the named alarm ids from GetErrorID, kept apart from I/O errors
//! and timeouts; [`Arm::clear_error`] runs the recovery flow (GetErrorID, ClearError,
//! Continue, EnableRobot when the arm dropped to mode 4).
//!
//! Decisions on the feedback: whether the arm is in alarm before a move or a `Sync()`, which
//! frame ends a wait (arrival, enable, a cleared alarm), whether the queue runner is stopped,
//! whether the arm dropped to disabled, and the pose it reports. Each goes by the newest frame
//! the client holds, and which frame that is depends on scheduling: the reader may have read a
//! frame and not yet published it. So every such decision goes through a [`Witness`]: a
//! recording logs the number of the frame it went by (or that a wait timed out), and a replay
//! makes it by that frame, kept in a short history, whatever the reader has decoded since. A
//! `Sync()` racing an alarm takes the reply when both are ready, live and replayed alike. A
//! reply that does not come in time is such a decision too: a recording logs it, and a replay
//! gives up on the reply where the recording did, not on its clock.
//!
//! The client never keeps more than `max_queued_commands` moves queued on the controller:
//! past that it waits for Sync before sending more (the real controller freezes past ~50).
//! Socket timeouts run on real time; [`Arrival::t_s`] is stamped from the [`Clock`] passed in.

use std::collections::VecDeque;
use std::future::Future;
use std::net::SocketAddr;
use std::pin::Pin;
use std::sync::Arc;
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio::sync::watch;
use tokio::task::JoinHandle;
use tokio::time::Instant;

use crate::arm::dobot::alarms;
use crate::arm::dobot::proto::{ErrorId, FeedbackDecoder, FeedbackFrame, Port, Reply, ReplyFramer, Request, RobotMode};
use crate::arm::profile::FirmwareProfile;
use crate::arm::{Alarm, Arm, ArmError, Arrival, MoveKind};
use crate::clock::Clock;
use crate::pose::Pose;

/// A byte stream the client can run a link over (a `TcpStream`, a duplex pipe in tests).
pub trait ByteStream: AsyncRead + AsyncWrite + Unpin + Send + 'static {}
impl<T: AsyncRead + AsyncWrite + Unpin + Send + 'static> ByteStream for T {}

/// Settings of an [`Mg400Client`].
#[derive(Debug, Clone)]
pub struct Mg400Config {
    /// Controller address (LAN1 of a real MG400 is 192.168.1.6).
    pub host: String,
    pub dashboard_port: u16,
    pub motion_port: u16,
    pub feedback_port: u16,
    /// Limit on establishing each TCP connection and on the first feedback frame.
    pub connect_timeout: Duration,
    /// Limit on a reply to an immediate command.
    pub reply_timeout: Duration,
    /// Limit on EnableRobot and the wait for mode 5 afterwards (\[CPP\] allows 20 s).
    pub enable_timeout: Duration,
    /// Limit on draining the queue when the queued-command bound is reached.
    pub drain_timeout: Duration,
    /// Global speed, 1..=100 %.
    pub speed_factor_pct: u8,
    /// Arrival tolerance on position, mm.
    pub arrival_tolerance_mm: f64,
    /// Arrival tolerance on yaw, degrees.
    pub arrival_tolerance_deg: f64,
    /// Most moves kept queued on the controller at once.
    pub max_queued_commands: usize,
    /// User frame and tool indices selected on enable.
    pub user_index: u8,
    pub tool_index: u8,
    /// Reconnection attempts after a dropped socket, per request.
    pub reconnect_attempts: u32,
    pub profile: FirmwareProfile,
}

impl Mg400Config {
    /// Settings for the controller at `host`, ports and queue bound from `profile`.
    pub fn new(host: impl Into<String>, profile: FirmwareProfile) -> Self {
        Self {
            host: host.into(),
            dashboard_port: profile.transport.dashboard_port,
            motion_port: profile.transport.motion_port,
            feedback_port: profile.transport.feedback_port,
            connect_timeout: Duration::from_secs(3),
            reply_timeout: Duration::from_secs(5),
            enable_timeout: Duration::from_secs(20),
            drain_timeout: Duration::from_secs(120),
            speed_factor_pct: 50,
            arrival_tolerance_mm: 0.1,
            arrival_tolerance_deg: 0.1,
            max_queued_commands: profile.transport.max_queued_commands,
            user_index: 0,
            tool_index: 0,
            reconnect_attempts: 3,
            profile,
        }
    }

    /// Same settings with explicit ports (e.g. a simulator on ephemeral ports).
    pub fn with_ports(mut self, dashboard: u16, motion: u16, feedback: u16) -> Self {
        self.dashboard_port = dashboard;
        self.motion_port = motion;
        self.feedback_port = feedback;
        self
    }

    /// Settings for a controller whose three ports listen at these addresses (a simulator on
    /// ephemeral ports), moving under `profile`; the host is the dashboard's.
    pub fn at_addresses(dashboard: SocketAddr, motion: SocketAddr, feedback: SocketAddr, profile: FirmwareProfile) -> Self {
        Self::new(dashboard.ip().to_string(), profile).with_ports(dashboard.port(), motion.port(), feedback.port())
    }
}

impl Default for Mg400Config {
    /// A real MG400 on LAN1 with the default profile.
    fn default() -> Self {
        Self::new("192.168.1.6", FirmwareProfile::default_mg400())
    }
}

fn io_err(context: String, source: std::io::Error) -> ArmError {
    ArmError::Io { context, source }
}

/// Opens a new connection to one of the arm's ports, when the old one was lost.
pub type Reopen = Arc<dyn Fn() -> Pin<Box<dyn Future<Output = Result<Box<dyn ByteStream>, ArmError>> + Send>> + Send + Sync>;

/// A decision of the client that timing settles, not bytes (see "Decisions on the feedback"
/// in the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Decision {
    /// Made by the feedback frame numbered so ([`FeedbackSample::seq`]; 0: none had arrived).
    Feedback(u64),
    /// A wait for a fitting feedback frame timed out.
    FeedbackTimedOut,
    /// The reply awaited on this port did not come in time.
    ReplyTimedOut(Port),
}

/// What the client asks a replay's [`Witness::Dictate`] for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Ask {
    /// A decision on the feedback, next of the client's steps.
    Feedback,
    /// An alarm in the feedback racing the `Sync()` reply: it may wait behind the reply.
    AlarmDuringSync,
    /// Whether the reply awaited on this port timed out: it waits behind the reply, which may
    /// come instead.
    ReplyTimeout(Port),
}

/// A dictated decision, when the recording gives it: see [`Witness`].
pub type Dictated = Pin<Box<dyn Future<Output = Result<Decision, ArmError>> + Send>>;

/// Who learns of the client's decisions that timing settles.
#[derive(Clone, Default)]
pub enum Witness {
    /// Nobody (an unrecorded run).
    #[default]
    Unwatched,
    /// Each decision is reported as it is made (a recording).
    Report(Arc<dyn Fn(Decision) + Send + Sync>),
    /// Each decision is dictated (a replay): the future gives what the recorded one was.
    Dictate(Arc<dyn Fn(Ask) -> Dictated + Send + Sync>),
}

impl Witness {
    /// Tells a reporting witness of `decision`; the others need not hear it.
    fn report(&self, decision: Decision) {
        if let Witness::Report(report) = self {
            report(decision);
        }
    }
}

/// How many of the newest feedback samples the client keeps, so that a replayed decision can
/// go by the recorded frame although the reader has decoded later ones.
const HISTORY: usize = 64;

/// A [`Reopen`] that connects over TCP.
fn tcp_reopen(host: &str, port: u16, timeout: Duration, role: &'static str) -> Reopen {
    let host = host.to_string();
    Arc::new(move || {
        let host = host.clone();
        Box::pin(async move { connect_tcp(&host, port, timeout, role).await.map(|s| Box::new(s) as Box<dyn ByteStream>) })
    })
}

/// Sends one dashboard command on a connection of its own and returns the controller's reply,
/// whatever its ErrorID (`rig arm send`): the motion and feedback ports stay closed, and the
/// arm is not enabled or moved by rig around it.
pub async fn dashboard_once(cfg: &Mg400Config, req: &Request) -> Result<Reply, ArmError> {
    let port = cfg.dashboard_port;
    let mut link = CommandLink {
        role: "dashboard",
        where_: format!("dashboard port {}:{port}", cfg.host),
        reopen: Some(tcp_reopen(&cfg.host, port, cfg.connect_timeout, "dashboard")),
        reset_on_abandon: true,
        stream: None,
        framer: ReplyFramer::new(),
        abandoned: VecDeque::new(),
        port: Port::Dashboard,
        witness: Witness::Unwatched,
    };
    let timeout = match req {
        Request::EnableRobot { .. } | Request::DisableRobot | Request::ClearError | Request::ResetRobot => cfg.enable_timeout,
        _ => cfg.reply_timeout,
    };
    // Sent once: a command typed by hand is not resent behind the user's back.
    link.request(req, timeout, 0).await
}

/// One request/reply connection (dashboard or motion).
struct CommandLink {
    /// "dashboard" or "motion", for messages.
    role: &'static str,
    /// Names the connection in messages ("dashboard port 192.168.1.6:29999").
    where_: String,
    /// How to reconnect; `None` for an attached stream, which cannot be reopened.
    reopen: Option<Reopen>,
    /// Whether a request abandoned (timed out, or lost a race) closes the connection so the
    /// next request opens a fresh one. Only for TCP: a recorded or replayed link keeps its
    /// stream, so the replay does not depend on which way such a race went.
    reset_on_abandon: bool,
    stream: Option<Box<dyn ByteStream>>,
    framer: ReplyFramer,
    /// Names of requests abandoned on this stream whose replies are still due, oldest first.
    abandoned: VecDeque<&'static str>,
    port: Port,
    /// Learns of a reply that timed out, or (a replay) says whether it did.
    witness: Witness,
}

impl CommandLink {
    fn where_(&self) -> String {
        self.where_.clone()
    }

    async fn open(&mut self) -> Result<(), ArmError> {
        if self.stream.is_some() {
            return Ok(());
        }
        let Some(reopen) = self.reopen.clone() else {
            return Err(io_err(
                format!("using the {} (attached stream closed, cannot reconnect)", self.where_()),
                std::io::ErrorKind::NotConnected.into(),
            ));
        };
        self.stream = Some(reopen().await?);
        self.framer.clear();
        self.abandoned.clear();
        Ok(())
    }

    /// Forgets the stream after trouble, so the next request reconnects (when it can) instead
    /// of reading replies meant for requests nobody waits for any more.
    fn reset(&mut self) {
        if self.reopen.is_some() {
            self.stream = None;
            self.framer.clear();
            self.abandoned.clear();
        }
    }

    /// Marks `name` as abandoned after its reply was not awaited to the end: a fresh connection
    /// when `reset_on_abandon`, else its late reply is skipped on this one.
    fn abandon(&mut self, name: &'static str) {
        if self.reset_on_abandon {
            self.reset();
        } else {
            self.abandoned.push_back(name);
        }
    }

    /// One attempt: write the request, read until its reply arrives or the deadline passes.
    async fn exchange(&mut self, req: &Request, timeout: Duration) -> Result<Reply, ArmError> {
        self.open().await?;
        let text = req.encode();
        let where_ = self.where_();
        let Some(stream) = self.stream.as_mut() else {
            return Err(io_err(format!("sending {text} on the {where_}"), std::io::ErrorKind::NotConnected.into()));
        };
        if let Err(e) = stream.write_all(text.as_bytes()).await {
            self.reset();
            return Err(io_err(format!("sending {text} on the {where_}"), e));
        }
        let deadline = Instant::now() + timeout;
        let mut buf = [0u8; 4096];
        loop {
            loop {
                let reply = match self.framer.next_reply() {
                    Ok(Some(r)) => r,
                    Ok(None) => break,
                    Err(e) => return Err(ArmError::Protocol(format!("{where_} answered {text}: {e}"))),
                };
                let name = reply.echo_name();
                if self.abandoned.front().is_some_and(|a| a.eq_ignore_ascii_case(name)) {
                    self.abandoned.pop_front();
                    continue;
                }
                if name.eq_ignore_ascii_case(req.name()) {
                    return Ok(reply);
                }
                tracing::debug!(reply = %reply.encode(), waiting_for = %text, "skipping an unexpected reply");
            }
            let Some(stream) = self.stream.as_mut() else {
                return Err(io_err(format!("reading the reply to {text}"), std::io::ErrorKind::NotConnected.into()));
            };
            // A replay times out where the recording did, not on the clock.
            let read = match &self.witness {
                Witness::Dictate(next) => {
                    let timed_out = next(Ask::ReplyTimeout(self.port));
                    tokio::select! {
                        biased;
                        r = stream.read(&mut buf) => Some(r),
                        d = timed_out => {
                            d?;
                            None
                        }
                    }
                }
                _ => tokio::time::timeout_at(deadline, stream.read(&mut buf)).await.ok(),
            };
            match read {
                Some(Ok(0)) => {
                    self.reset();
                    return Err(io_err(format!("reading the reply to {text} on the {where_}"), std::io::ErrorKind::UnexpectedEof.into()));
                }
                Some(Ok(n)) => self.framer.push(&buf[..n]),
                Some(Err(e)) => {
                    self.reset();
                    return Err(io_err(format!("reading the reply to {text} on the {where_}"), e));
                }
                None => {
                    self.witness.report(Decision::ReplyTimedOut(self.port));
                    self.abandon(req.name());
                    return Err(ArmError::Timeout { what: format!("waiting for the reply to {text} on the {where_}"), after: timeout });
                }
            }
        }
    }

    /// Sends `req` and returns its reply, reconnecting and resending after a dropped socket.
    /// Resending is safe for what rig sends: queries, setters, and moves to absolute targets.
    async fn request(&mut self, req: &Request, timeout: Duration, attempts: u32) -> Result<Reply, ArmError> {
        let mut tries = 0;
        loop {
            match self.exchange(req, timeout).await {
                Err(ArmError::Io { context, source }) if self.reopen.is_some() && tries < attempts => {
                    tries += 1;
                    tracing::warn!(%context, error = %source, attempt = tries, "reconnecting the MG400 {}", self.role);
                    tokio::time::sleep(Duration::from_millis(20 << tries.min(5))).await;
                }
                other => return other,
            }
        }
    }
}

/// Opens one of the arm's TCP ports within `timeout` (no Nagle delay: commands are small).
pub(crate) async fn connect_tcp(host: &str, port: u16, timeout: Duration, role: &str) -> Result<TcpStream, ArmError> {
    match tokio::time::timeout(timeout, TcpStream::connect((host, port))).await {
        Ok(Ok(s)) => {
            // Commands are small and latency matters more than throughput.
            let _ = s.set_nodelay(true);
            Ok(s)
        }
        Ok(Err(e)) => Err(io_err(format!("connecting to the MG400 {role} port at {host}:{port}"), e)),
        Err(_) => Err(ArmError::Timeout { what: format!("connecting to the MG400 {role} port at {host}:{port}"), after: timeout }),
    }
}

/// How many consecutive feedback frames must agree before a state seen right after a command
/// is believed (earlier frames may have been sent before the command took effect).
const STALE_FRAMES: u32 = 5;

/// One decoded feedback frame and when it arrived.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FeedbackSample {
    pub frame: FeedbackFrame,
    /// Counts frames received since the client started (1 = first).
    pub seq: u64,
    /// Arrival time on the client's clock, s.
    pub t_s: f64,
}

/// Reads the feedback stream, publishing each frame; reconnects with `reopen` when given.
async fn feedback_task(
    first: Option<Box<dyn ByteStream>>,
    reopen: Option<Reopen>,
    clock: Arc<dyn Clock>,
    tx: watch::Sender<Option<FeedbackSample>>,
    history: Arc<std::sync::Mutex<VecDeque<FeedbackSample>>>,
) {
    let mut stream = first;
    let mut seq = 0u64;
    let mut buf = vec![0u8; 16 * 1024];
    loop {
        let mut s = match stream.take() {
            Some(s) => s,
            None => {
                let Some(reopen) = reopen.as_ref() else { return };
                match reopen().await {
                    Ok(s) => s,
                    Err(e) => {
                        tracing::warn!(error = %e, "MG400 feedback reconnect failed; retrying");
                        tokio::time::sleep(Duration::from_millis(200)).await;
                        continue;
                    }
                }
            }
        };
        let mut decoder = FeedbackDecoder::new();
        loop {
            match s.read(&mut buf).await {
                Ok(0) | Err(_) => break,
                Ok(n) => {
                    decoder.push(&buf[..n]);
                    while let Some(frame) = decoder.next_frame() {
                        seq += 1;
                        let sample = FeedbackSample { frame, seq, t_s: clock.now_s() };
                        {
                            let mut held = history.lock().unwrap_or_else(|p| p.into_inner());
                            if held.len() == HISTORY {
                                held.pop_front();
                            }
                            held.push_back(sample);
                        }
                        tx.send_replace(Some(sample));
                    }
                }
            }
            if tx.is_closed() {
                return;
            }
        }
        if decoder.skipped_bytes() > 0 {
            tracing::debug!(skipped = decoder.skipped_bytes(), "feedback resynchronised");
        }
        tracing::warn!("MG400 feedback stream closed");
    }
}

/// The MG400 client. See the module docs.
pub struct Mg400Client {
    cfg: Mg400Config,
    clock: Arc<dyn Clock>,
    dashboard: CommandLink,
    motion: CommandLink,
    feedback: watch::Receiver<Option<FeedbackSample>>,
    /// The newest [`HISTORY`] samples, oldest first.
    history: Arc<std::sync::Mutex<VecDeque<FeedbackSample>>>,
    witness: Witness,
    feedback_task: JoinHandle<()>,
    /// Moves sent since the queue was last known to be empty.
    queued_moves: usize,
}

impl Drop for Mg400Client {
    fn drop(&mut self) {
        self.feedback_task.abort();
    }
}

impl Mg400Client {
    /// Connects the three sockets and waits for the first valid feedback frame.
    pub async fn connect(cfg: Mg400Config, clock: Arc<dyn Clock>) -> Result<Mg400Client, ArmError> {
        let link = |port, role| (tcp_reopen(&cfg.host, port, cfg.connect_timeout, role), format!("{role} port {}:{port}", cfg.host));
        let links = [link(cfg.dashboard_port, "dashboard"), link(cfg.motion_port, "motion"), link(cfg.feedback_port, "feedback")];
        // The first connections are opened the way lost ones are reopened.
        let [(d, _), (m, _), (f, _)] = &links;
        let streams = [d().await?, m().await?, f().await?];
        let links = links.map(|(open, where_)| (Some(open), where_));
        let mut client = Self::build(cfg, clock, streams, links, true);
        client.first_feedback().await?;
        Ok(client)
    }

    /// Runs the client over already-open streams (duplex pipes, sockets set up elsewhere).
    /// Attached streams are not reconnected when they drop.
    pub fn attach(
        cfg: Mg400Config,
        clock: Arc<dyn Clock>,
        dashboard: impl ByteStream,
        motion: impl ByteStream,
        feedback: impl ByteStream,
    ) -> Mg400Client {
        let links = ["dashboard", "motion", "feedback"].map(|role| (None, format!("{role} stream")));
        Self::build(cfg, clock, [Box::new(dashboard), Box::new(motion), Box::new(feedback)], links, false)
    }

    /// Runs the client over already-open streams (dashboard, motion, feedback), each with how
    /// to open it again when it is lost: a recorded run's sockets, a replay's streams. Only a
    /// lost connection is reopened; an abandoned request's late reply is skipped on the same
    /// connection, as with attached streams.
    pub fn with_reopen(cfg: Mg400Config, clock: Arc<dyn Clock>, streams: [(Box<dyn ByteStream>, Reopen); 3]) -> Mg400Client {
        let [(dashboard, d), (motion, m), (feedback, f)] = streams;
        let links =
            [(Some(d), "dashboard stream".to_string()), (Some(m), "motion stream".to_string()), (Some(f), "feedback stream".to_string())];
        Self::build(cfg, clock, [dashboard, motion, feedback], links, false)
    }

    /// `streams` and `links` (how to reopen each, and its name in messages): dashboard, motion,
    /// feedback.
    fn build(
        cfg: Mg400Config,
        clock: Arc<dyn Clock>,
        streams: [Box<dyn ByteStream>; 3],
        links: [(Option<Reopen>, String); 3],
        reset_on_abandon: bool,
    ) -> Mg400Client {
        let [dashboard, motion, feedback] = streams;
        let [(d_reopen, d_where), (m_reopen, m_where), (f_reopen, _)] = links;
        let link = |role, port, reopen, where_, stream| CommandLink {
            role,
            port,
            witness: Witness::Unwatched,
            where_,
            reopen,
            reset_on_abandon,
            stream: Some(stream),
            framer: ReplyFramer::new(),
            abandoned: VecDeque::new(),
        };
        let (tx, rx) = watch::channel(None);
        let history = Arc::new(std::sync::Mutex::new(VecDeque::with_capacity(HISTORY)));
        let feedback_task = tokio::spawn(feedback_task(Some(feedback), f_reopen, clock.clone(), tx, Arc::clone(&history)));
        Mg400Client {
            dashboard: link("dashboard", Port::Dashboard, d_reopen, d_where, dashboard),
            motion: link("motion", Port::Motion, m_reopen, m_where, motion),
            feedback: rx,
            history,
            witness: Witness::Unwatched,
            feedback_task,
            queued_moves: 0,
            clock,
            cfg,
        }
    }

    /// The settings in use.
    pub fn config(&self) -> &Mg400Config {
        &self.cfg
    }

    /// Moves sent and not yet known to be finished.
    pub fn queued_moves(&self) -> usize {
        self.queued_moves
    }

    /// The newest feedback frame, if any arrived. For display: the client's own decisions go
    /// through the [`Witness`].
    pub fn latest_feedback(&self) -> Option<FeedbackSample> {
        *self.feedback.borrow()
    }

    /// Sets who learns of the client's decisions on the feedback (before the first one: a
    /// recording before [`wait_first_feedback`](Self::wait_first_feedback)).
    pub fn set_witness(&mut self, witness: Witness) {
        self.dashboard.witness = witness.clone();
        self.motion.witness = witness.clone();
        self.witness = witness;
    }

    /// The newest feedback sample, for a decision: reported to the witness, or in a replay, the
    /// sample the recorded decision went by.
    async fn observe(&mut self) -> Result<Option<FeedbackSample>, ArmError> {
        let Witness::Dictate(next) = &self.witness else {
            let sample = self.latest_feedback();
            self.witness.report(Decision::Feedback(sample.map_or(0, |s| s.seq)));
            return Ok(sample);
        };
        match next(Ask::Feedback).await? {
            Decision::Feedback(seq) => self.sample_numbered(seq).await,
            other => {
                Err(ArmError::Protocol(format!("the recording has {other:?} where the replayed client looked at the newest feedback")))
            }
        }
    }

    /// The sample numbered `seq` (0: none), once the feedback reader has decoded it.
    async fn sample_numbered(&mut self, seq: u64) -> Result<Option<FeedbackSample>, ArmError> {
        if seq == 0 {
            return Ok(None);
        }
        loop {
            {
                let held = self.history.lock().unwrap_or_else(|p| p.into_inner());
                if let Some(s) = held.iter().find(|s| s.seq == seq) {
                    return Ok(Some(*s));
                }
                if held.back().is_some_and(|s| s.seq > seq) {
                    return Err(ArmError::Protocol(format!(
                        "the recorded decision went by feedback frame {seq}, older than the {HISTORY} frames the client keeps"
                    )));
                }
            }
            if self.feedback.changed().await.is_err() {
                return Err(io_err(format!("waiting for feedback frame {seq}"), std::io::Error::other("the feedback reader stopped")));
            }
        }
    }

    /// Waits (up to the connect timeout) for the first feedback frame, as [`connect`](Self::connect)
    /// does; for clients built with [`attach`](Self::attach) over freshly opened sockets.
    pub async fn wait_first_feedback(&mut self) -> Result<FeedbackSample, ArmError> {
        self.first_feedback().await
    }

    async fn first_feedback(&mut self) -> Result<FeedbackSample, ArmError> {
        let deadline = Instant::now() + self.cfg.connect_timeout;
        self.wait_feedback(deadline, "waiting for the first MG400 feedback frame", |_| true).await
    }

    /// Waits until the newest feedback sample satisfies `pred`: the one held now, or a later
    /// one (never a frame newer than some snapshot: see the module docs on arrival). A decision:
    /// the sample, or the timeout, goes to the witness; a replay returns the recorded one.
    async fn wait_feedback(
        &mut self,
        deadline: Instant,
        what: &str,
        pred: impl FnMut(&FeedbackSample) -> bool,
    ) -> Result<FeedbackSample, ArmError> {
        if let Witness::Dictate(next) = &self.witness {
            return match next(Ask::Feedback).await? {
                Decision::Feedback(seq) => self
                    .sample_numbered(seq)
                    .await?
                    .ok_or_else(|| ArmError::Protocol(format!("{what}: the recording has the wait end before any feedback frame arrived"))),
                // The recording keeps that the wait timed out, not how long it waited.
                Decision::FeedbackTimedOut => {
                    Err(ArmError::Timeout { what: format!("{what} (it timed out in the recorded run)"), after: Duration::ZERO })
                }
                other => Err(ArmError::Protocol(format!("{what}: the recording has {other:?} here"))),
            };
        }
        let waited = self.wait_feedback_live(deadline, what, pred).await;
        match &waited {
            Ok(s) => self.witness.report(Decision::Feedback(s.seq)),
            Err(ArmError::Timeout { .. }) => self.witness.report(Decision::FeedbackTimedOut),
            Err(_) => {}
        }
        waited
    }

    async fn wait_feedback_live(
        &mut self,
        deadline: Instant,
        what: &str,
        mut pred: impl FnMut(&FeedbackSample) -> bool,
    ) -> Result<FeedbackSample, ArmError> {
        let start = Instant::now();
        loop {
            if let Some(s) = *self.feedback.borrow_and_update()
                && pred(&s)
            {
                return Ok(s);
            }
            match tokio::time::timeout_at(deadline, self.feedback.changed()).await {
                Ok(Ok(())) => {}
                Ok(Err(_)) => {
                    return Err(io_err(what.to_string(), std::io::Error::other("the feedback reader stopped")));
                }
                Err(_) => {
                    return Err(ArmError::Timeout { what: what.to_string(), after: deadline.saturating_duration_since(start) });
                }
            }
        }
    }

    /// Sends a dashboard command; a non-zero ErrorID becomes [`ArmError::Refused`].
    pub async fn dashboard(&mut self, req: &Request) -> Result<Reply, ArmError> {
        let timeout = match req {
            Request::EnableRobot { .. } | Request::DisableRobot | Request::ClearError | Request::ResetRobot => self.cfg.enable_timeout,
            _ => self.cfg.reply_timeout,
        };
        let reply = self.dashboard.request(req, timeout, self.cfg.reconnect_attempts).await?;
        accepted(req, reply)
    }

    /// Sends any command on its own port (dashboard or motion); a non-zero ErrorID becomes
    /// [`ArmError::Refused`]. Motion sent this way is not counted against the queue bound.
    pub async fn command(&mut self, req: &Request) -> Result<Reply, ArmError> {
        match req.port() {
            Port::Dashboard => self.dashboard(req).await,
            Port::Motion => {
                let reply = self.motion.request(req, self.cfg.reply_timeout, self.cfg.reconnect_attempts).await?;
                accepted(req, reply)
            }
        }
    }

    /// The robot mode, asked on the dashboard.
    pub async fn robot_mode(&mut self) -> Result<RobotMode, ArmError> {
        let reply = self.dashboard(&Request::RobotMode).await?;
        let code = reply.integer().map_err(|e| ArmError::Protocol(e.to_string()))?;
        Ok(RobotMode::from_code(u64::try_from(code).unwrap_or(0)))
    }

    /// The active alarms (GetErrorID), named.
    pub async fn read_alarms(&mut self) -> Result<Vec<Alarm>, ArmError> {
        let reply = self.dashboard(&Request::GetErrorId).await?;
        let lists = reply.error_id_lists().map_err(|e| ArmError::Protocol(e.to_string()))?;
        Ok(alarms::from_lists(&lists))
    }

    /// The fault the robot is in, as an error value.
    async fn fault(&mut self) -> ArmError {
        match self.read_alarms().await {
            Ok(alarms) => ArmError::Fault { alarms },
            Err(e) => e,
        }
    }

    /// Whether the newest feedback shows an alarm (a decision, see [`observe`](Self::observe)).
    async fn feedback_in_alarm(&mut self) -> Result<bool, ArmError> {
        Ok(self.observe().await?.is_some_and(|s| s.frame.in_alarm()))
    }

    /// Resolves once the feedback shows an alarm (never, if the feedback stops): a decision
    /// that races a reply; reported when it resolves.
    fn alarm_in_feedback(&self) -> impl Future<Output = Result<(), ArmError>> + Send + 'static {
        let mut feedback = self.feedback.clone();
        let witness = self.witness.clone();
        async move {
            match witness {
                Witness::Dictate(next) => next(Ask::AlarmDuringSync).await.map(drop),
                live => {
                    live.report(Decision::Feedback(wait_for_alarm(&mut feedback).await));
                    Ok(())
                }
            }
        }
    }

    /// Blocks until the motion queue has drained (Sync), failing early with
    /// [`ArmError::Fault`] when the feedback shows an alarm meanwhile.
    pub async fn sync(&mut self, timeout: Duration) -> Result<(), ArmError> {
        if self.feedback_in_alarm().await? {
            return Err(self.fault().await);
        }
        let alarm = self.alarm_in_feedback();
        let attempts = self.cfg.reconnect_attempts;
        // The reply first: when both are ready, the reply wins, live and in a replay alike.
        let outcome = tokio::select! {
            biased;
            r = self.motion.request(&Request::Sync, timeout, attempts) => Some(r),
            seen = alarm => {
                seen?;
                None
            }
        };
        match outcome {
            Some(reply) => {
                accepted(&Request::Sync, reply?)?;
                self.queued_moves = 0;
                Ok(())
            }
            None => {
                // The Sync reply will still come (the controller empties its queue on an
                // alarm); it must not be taken for the reply to a later Sync.
                self.motion.abandon(Request::Sync.name());
                self.queued_moves = 0;
                Err(self.fault().await)
            }
        }
    }

    async fn enable_inner(&mut self) -> Result<(), ArmError> {
        self.dashboard(&Request::ClearError).await?;
        if let Err(e) = self.dashboard(&Request::EnableRobot { load_kg: None, centre_mm: None }).await {
            // An alarm ClearError could not clear makes EnableRobot fail with -1: report the
            // alarm rather than the bare refusal.
            if matches!(e, ArmError::Refused { .. }) && matches!(self.robot_mode().await, Ok(RobotMode::Error)) {
                return Err(self.fault().await);
            }
            return Err(e);
        }
        let deadline = Instant::now() + self.cfg.enable_timeout;
        // Frames already in flight may still show the state from before ClearError, so an
        // alarm counts only when several frames in a row report it.
        let mut alarm_frames = 0;
        let sample = self
            .wait_feedback(deadline, "waiting for the MG400 to report enabled (mode 5)", |s| {
                alarm_frames = if s.frame.in_alarm() { alarm_frames + 1 } else { 0 };
                alarm_frames >= STALE_FRAMES || matches!(s.frame.mode(), RobotMode::Enabled | RobotMode::Running)
            })
            .await?;
        if sample.frame.in_alarm() {
            return Err(self.fault().await);
        }
        self.dashboard(&Request::SpeedFactor { percent: i64::from(self.cfg.speed_factor_pct) }).await?;
        self.dashboard(&Request::User { index: i64::from(self.cfg.user_index) }).await?;
        self.dashboard(&Request::Tool { index: i64::from(self.cfg.tool_index) }).await?;
        // The official demos restart a stopped queue runner the same way.
        if self.observe().await?.is_some_and(|s| !s.frame.run_queued_cmd) {
            self.dashboard(&Request::Continue).await?;
        }
        self.queued_moves = 0;
        Ok(())
    }
}

/// Resolves once a feedback frame shows an alarm, with its number (never, if the feedback
/// stops).
async fn wait_for_alarm(feedback: &mut watch::Receiver<Option<FeedbackSample>>) -> u64 {
    loop {
        if let Some(s) = *feedback.borrow_and_update()
            && s.frame.in_alarm()
        {
            return s.seq;
        }
        if feedback.changed().await.is_err() {
            std::future::pending::<()>().await;
        }
    }
}

/// Turns a non-zero ErrorID into [`ArmError::Refused`].
fn accepted(req: &Request, reply: Reply) -> Result<Reply, ArmError> {
    if reply.error_id == ErrorId::Accepted {
        Ok(reply)
    } else {
        Err(ArmError::Refused { command: req.encode(), error_id: reply.error_id.code(), meaning: reply.error_id.meaning() })
    }
}

impl Arm for Mg400Client {
    async fn enable(&mut self) -> Result<(), ArmError> {
        self.enable_inner().await
    }

    async fn move_to(&mut self, target: Pose, kind: MoveKind) -> Result<(), ArmError> {
        // The fence comes first: nothing is sent for a target outside the profile.
        self.cfg.profile.check_reachable(&target)?;
        if self.feedback_in_alarm().await? {
            return Err(self.fault().await);
        }
        if self.queued_moves >= self.cfg.max_queued_commands {
            self.sync(self.cfg.drain_timeout).await?;
        }
        let req = match kind {
            MoveKind::Joint => Request::MovJ { target },
            MoveKind::Linear => Request::MovL { target },
        };
        let reply = self.motion.request(&req, self.cfg.reply_timeout, self.cfg.reconnect_attempts).await?;
        if let Err(refused) = accepted(&req, reply) {
            // A controller in alarm refuses motion with -1: report the alarm, not the refusal.
            if self.feedback_in_alarm().await? || matches!(self.robot_mode().await, Ok(RobotMode::Error)) {
                return Err(self.fault().await);
            }
            return Err(refused);
        }
        self.queued_moves += 1;
        Ok(())
    }

    async fn wait_arrived(&mut self, target: Pose, timeout: Duration) -> Result<Arrival, ArmError> {
        let deadline = Instant::now() + timeout;
        self.sync(timeout).await?;
        let (tol_mm, tol_deg) = (self.cfg.arrival_tolerance_mm, self.cfg.arrival_tolerance_deg);
        let what = format!("waiting for the feedback to show the arm at rest at {target}");
        let sample = self
            .wait_feedback(deadline, &what, |s| {
                let p = s.frame.actual_pose();
                s.frame.in_alarm()
                    || (s.frame.mode() == RobotMode::Enabled && p.distance_mm(&target) <= tol_mm && p.yaw_error_deg(&target) <= tol_deg)
            })
            .await;
        let sample = match sample {
            Ok(s) => s,
            Err(ArmError::Timeout { what, after }) => {
                let last = self.latest_feedback().map(|s| (s.frame.actual_pose(), s.frame.mode()));
                let what = match last {
                    Some((pose, mode)) => format!("{what} (last feedback: {pose}, mode {mode:?})"),
                    None => format!("{what} (no feedback)"),
                };
                return Err(ArmError::Timeout { what, after });
            }
            Err(e) => return Err(e),
        };
        if sample.frame.in_alarm() {
            return Err(self.fault().await);
        }
        let measured = sample.frame.actual_pose();
        Ok(Arrival { measured, error_mm: measured.distance_mm(&target), t_s: self.clock.now_s() })
    }

    async fn pose(&mut self) -> Result<Pose, ArmError> {
        if let Some(s) = self.observe().await? {
            return Ok(s.frame.actual_pose());
        }
        let reply = self.dashboard(&Request::GetPose).await?;
        reply.pose().map_err(|e| ArmError::Protocol(e.to_string()))
    }

    async fn stop(&mut self) -> Result<(), ArmError> {
        self.dashboard(&Request::ResetRobot).await?;
        self.queued_moves = 0;
        Ok(())
    }

    async fn clear_error(&mut self) -> Result<Vec<Alarm>, ArmError> {
        let alarms = self.read_alarms().await?;
        // Some alarms need more than one ClearError ([WS] retries 2-3 times).
        let mut cleared = false;
        for _ in 0..3 {
            self.dashboard(&Request::ClearError).await?;
            self.dashboard(&Request::Continue).await?;
            let deadline = Instant::now() + self.cfg.reply_timeout;
            if self.wait_feedback(deadline, "waiting for the alarm to clear", |s| !s.frame.in_alarm()).await.is_ok() {
                cleared = true;
                break;
            }
        }
        if !cleared {
            return Err(self.fault().await);
        }
        self.queued_moves = 0;
        // After a collision or emergency stop the arm sits disabled (mode 4).
        let disabled = self.observe().await?.is_some_and(|s| !s.frame.enable_status);
        if disabled {
            self.enable_inner().await?;
        }
        Ok(alarms)
    }

    async fn disable(&mut self) -> Result<(), ArmError> {
        self.dashboard(&Request::DisableRobot).await?;
        self.queued_moves = 0;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::clock::MockClock;
    use tokio::io::duplex;

    fn attached() -> (Mg400Client, tokio::io::DuplexStream, tokio::io::DuplexStream, tokio::io::DuplexStream) {
        let (d, d_robot) = duplex(4096);
        let (m, m_robot) = duplex(4096);
        let (f, f_robot) = duplex(1 << 16);
        let mut cfg = Mg400Config::new("attached", FirmwareProfile::default_mg400());
        cfg.reply_timeout = Duration::from_millis(50);
        let client = Mg400Client::attach(cfg, Arc::new(MockClock::new()), d, m, f);
        (client, d_robot, m_robot, f_robot)
    }

    async fn expect_request(robot: &mut tokio::io::DuplexStream, text: &str) {
        let mut buf = vec![0u8; text.len()];
        robot.read_exact(&mut buf).await.unwrap();
        assert_eq!(String::from_utf8_lossy(&buf), text);
    }

    #[tokio::test]
    async fn replies_are_matched_by_echo_across_split_writes() {
        let (mut client, mut robot, _m, _f) = attached();
        let robot_side = tokio::spawn(async move {
            expect_request(&mut robot, "RobotMode()").await;
            // A stray reply first, then the answer split inside its echo.
            robot.write_all(b"0,{},ClearError();0,{5},Robot").await.unwrap();
            tokio::task::yield_now().await;
            robot.write_all(b"Mode();").await.unwrap();
            expect_request(&mut robot, "SpeedFactor(101)").await;
            robot.write_all(b"-40001,{},SpeedFactor(101);").await.unwrap();
            robot
        });
        assert_eq!(client.robot_mode().await.unwrap(), RobotMode::Enabled);
        let err = client.command(&Request::SpeedFactor { percent: 101 }).await.unwrap_err();
        assert!(matches!(&err, ArmError::Refused { error_id: -40001, command, .. } if command == "SpeedFactor(101)"), "{err:?}");
        robot_side.await.unwrap();
    }

    #[tokio::test]
    async fn a_late_reply_to_an_abandoned_request_is_skipped() {
        let (mut client, mut robot, _m, _f) = attached();
        let robot_side = tokio::spawn(async move {
            expect_request(&mut robot, "RobotMode()").await;
            // No answer in time; it comes after the next request.
            expect_request(&mut robot, "GetErrorID()").await;
            robot.write_all(b"0,{5},RobotMode();0,{[[],[],[]]},GetErrorID();").await.unwrap();
            expect_request(&mut robot, "RobotMode()").await;
            robot.write_all(b"0,{4},RobotMode();").await.unwrap();
            robot
        });
        let err = client.robot_mode().await.unwrap_err();
        assert!(matches!(err, ArmError::Timeout { .. }), "{err:?}");
        assert!(client.read_alarms().await.unwrap().is_empty());
        // The late "5" was the abandoned request's; this request's answer is "4".
        assert_eq!(client.robot_mode().await.unwrap(), RobotMode::Disabled);
        robot_side.await.unwrap();
    }

    #[tokio::test]
    async fn a_closed_attached_stream_is_an_io_error() {
        let (mut client, robot, _m, _f) = attached();
        drop(robot);
        let err = client.robot_mode().await.unwrap_err();
        assert!(matches!(err, ArmError::Io { .. }), "{err:?}");
        assert!(err.is_recoverable());
    }

    #[tokio::test]
    async fn feedback_frames_reach_the_client_through_garbage() {
        let (mut client, _d, _m, mut feedback) = attached();
        let frame = FeedbackFrame { robot_mode: 5, tool_vector_actual: [310.0, 1.0, 2.0, 3.0, 0.0, 0.0], ..Default::default() };
        let bytes = frame.encode();
        feedback.write_all(&bytes[900..]).await.unwrap();
        feedback.write_all(b"\xA0\x05garbage").await.unwrap();
        feedback.write_all(&bytes).await.unwrap();
        let sample = client.first_feedback().await.unwrap();
        assert_eq!(sample.frame, frame);
        assert_eq!(client.pose().await.unwrap(), Pose::new(310.0, 1.0, 2.0, 3.0));
    }

    /// A frame at rest at `x` mm, or (`alarm`) one in mode 9.
    fn frame_at(x: f64, alarm: bool) -> Vec<u8> {
        let mode = if alarm { 9 } else { 5 };
        FeedbackFrame { robot_mode: mode, tool_vector_actual: [x, 0.0, 0.0, 0.0, 0.0, 0.0], ..Default::default() }.encode().to_vec()
    }

    async fn until_seq(client: &mut Mg400Client, seq: u64) {
        while client.latest_feedback().is_none_or(|s| s.seq < seq) {
            client.feedback.changed().await.unwrap();
        }
    }

    #[tokio::test]
    async fn decisions_on_the_feedback_are_reported_with_their_frame() {
        let (mut client, _d, _m, mut feedback) = attached();
        let reported = Arc::new(std::sync::Mutex::new(Vec::new()));
        let log = Arc::clone(&reported);
        client.set_witness(Witness::Report(Arc::new(move |used| log.lock().unwrap().push(used))));
        assert!(!client.feedback_in_alarm().await.unwrap(), "no frame yet");
        feedback.write_all(&frame_at(300.0, false)).await.unwrap();
        client.wait_first_feedback().await.unwrap();
        feedback.write_all(&frame_at(301.0, false)).await.unwrap();
        until_seq(&mut client, 2).await;
        assert_eq!(client.pose().await.unwrap().x_mm, 301.0);
        let deadline = Instant::now() + Duration::from_millis(30);
        let err = client.wait_feedback(deadline, "waiting for an alarm", |s| s.frame.in_alarm()).await.unwrap_err();
        assert!(matches!(err, ArmError::Timeout { .. }), "{err:?}");
        // Each decision once: the alarm check before any frame, the first frame, the pose, the
        // timeout.
        use Decision::{Feedback, FeedbackTimedOut};
        assert_eq!(*reported.lock().unwrap(), vec![Feedback(0), Feedback(1), Feedback(2), FeedbackTimedOut]);
    }

    #[tokio::test]
    async fn a_dictated_decision_goes_by_the_recorded_frame_not_the_newest() {
        let (mut client, _d, _m, mut feedback) = attached();
        let script = Arc::new(std::sync::Mutex::new(VecDeque::from(
            [1, 1, 0, u64::MAX, 1].map(|seq| if seq == u64::MAX { Decision::FeedbackTimedOut } else { Decision::Feedback(seq) }),
        )));
        let next = Arc::clone(&script);
        client.set_witness(Witness::Dictate(Arc::new(move |_| {
            let used = next.lock().unwrap().pop_front().expect("a scripted decision");
            Box::pin(async move { Ok(used) })
        })));
        feedback.write_all(&frame_at(300.0, false)).await.unwrap();
        feedback.write_all(&frame_at(301.0, true)).await.unwrap();
        until_seq(&mut client, 2).await;
        // The newest frame shows an alarm at 301 mm; the recorded decisions went by frame 1.
        assert_eq!(client.pose().await.unwrap().x_mm, 300.0);
        assert!(!client.feedback_in_alarm().await.unwrap());
        assert_eq!(client.observe().await.unwrap(), None, "frame 0: none had arrived");
        let err = client.wait_feedback(Instant::now(), "waiting", |_| true).await.unwrap_err();
        assert!(matches!(&err, ArmError::Timeout { what, .. } if what.contains("timed out in the recorded run")), "{err:?}");
        // A frame the client no longer keeps is an error, not another frame.
        for k in 0..HISTORY {
            feedback.write_all(&frame_at(302.0 + k as f64, false)).await.unwrap();
        }
        until_seq(&mut client, 2 + HISTORY as u64).await;
        let err = client.pose().await.unwrap_err();
        assert!(matches!(&err, ArmError::Protocol(m) if m.contains("older than the 64 frames")), "{err:?}");
        // A frame not decoded yet is waited for.
        let late = tokio::spawn(async move {
            tokio::time::sleep(Duration::from_millis(20)).await;
            feedback.write_all(&frame_at(400.0, false)).await.unwrap();
            feedback
        });
        script.lock().unwrap().push_back(Decision::Feedback(3 + HISTORY as u64));
        assert_eq!(client.pose().await.unwrap().x_mm, 400.0);
        late.await.unwrap();
    }
}
