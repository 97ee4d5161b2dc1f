//! Replay: re-running a recorded collection with no hardware.
//!
//! A [`ReplaySession`] holds a cursor on the recorded events: the event under it, and an
//! [`EventSource`] that reads the next from the recording file when the cursor moves on (a
//! look ahead, for the watchdog's message and the final check, reads on its own reader), so a
//! replay holds one event, whatever the recording's length. The client's three sockets are
//! [`ReplayStream`]s and the job's cameras are [`ReplayCamera`]s over that one session, so the
//! real [`Mg400Client`] and the real collection job run unchanged ([`ReplayRig`]). The
//! peripheral calls are read from the file by a reader of their own ([`ReplayPeripherals`]).
//!
//! Ordering, and why the replay does not depend on wall-clock timing: two tasks touch the
//! hardware. The job's task (commands, replies, frames) is sequential, so its events must come
//! in exactly the recorded order; the client's feedback reader runs beside it and only reads.
//! The session therefore serves the event under the cursor to whoever asks for it:
//!
//! - a feedback read is served when the next event is a feedback read, and waits otherwise, so
//!   the controller's 8 ms frames arrive in the same place relative to the client's requests
//!   and replies as they did (the frames that followed a `Sync()` reply still follow it);
//! - a write, a command-socket read or a frame request of the job is served when the next event
//!   is exactly that; when the next event is a feedback read it waits for the reader to take
//!   it; a write or a frame request facing anything else is a divergence, reported with the
//!   record number, what the recording has and what the replayed run did instead (a reply
//!   read waits, because the client may race it against an alarm in the feedback; the
//!   watchdog reports it if nothing else happens; and when the job goes on past replies it
//!   read in the recording but gave up on this time, those stay in their socket, as on the
//!   wire, and are read later);
//! - a reconnection (version 4) is served like the socket's reads: the feedback reader's when
//!   it is next, the job's when it is next or after the feedback recorded before it, and the
//!   job's facing anything else is a divergence. A lost connection (a socket record without
//!   bytes) is served as the end of the stream, or as a failed write;
//! - a decision of the client on the feedback (version 5: in alarm? arrived? enabled?) is served
//!   like a write: the recorded frame's number, when it is next or after the feedback recorded
//!   before it, and facing anything else it is a divergence; the client then decides by that
//!   frame, not by the newest it holds (a live reader logs a read before it publishes, so a frame
//!   logged before a decision need not be one it saw). An alarm racing a `Sync()` reply waits
//!   behind the reply instead. A reply the recorded client gave up on (version 5) times out
//!   when that record is next, while the reply read waits. Before version 5 the client decides
//!   on the frames it holds, and its reply timeouts run on the clock;
//! - after each chunk a stream yields once, so the job's task sees every feedback frame the
//!   way it did live (the client keeps only the newest frame).
//!
//! Time comes from a [`MockClock`] set to each event's recorded rig-clock time as it is
//! served, and the client's socket timeouts are set far out; a watchdog turns a replay that
//! stops moving into a divergence naming the record it waits for. Run it on a current-thread
//! runtime, where the two tasks interleave only at these points.

use std::future::poll_fn;
use std::pin::Pin;
use std::sync::{Arc, Mutex, MutexGuard};
use std::task::{Context, Poll, Waker};
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};

use super::format::{ConnectOutcome, Direction, Event, PeripheralOutcome, PeripheralPhase, SocketId};
use super::{REPLAY_CLIENT_TIMEOUT, RecordAt, RecordError, RecordReader, RecordingFile, Summary, decision_of, frame_image};
use crate::arm::ArmError;
use crate::arm::dobot::client::{Ask, ByteStream, Decision, Mg400Client, Mg400Config, Reopen, Witness};
use crate::camera::{Camera, CameraError, Frame};
use crate::clock::{Clock, MockClock};
use crate::collect::CollectError;
use crate::dataset::DatasetError;
use crate::io::modbus::{ModbusError, ModbusReading, Peripherals, parse_readings};

/// Where the replayed run left the recording.
#[derive(Debug, Clone, PartialEq)]
pub struct Divergence {
    /// Index of the recorded event (0 = first after the header).
    pub record: usize,
    /// Rig-clock time of that event, s; `None` past the end of the recording.
    pub t_s: Option<f64>,
    /// What the recording has at that point.
    pub expected: String,
    /// What the replayed run did instead.
    pub got: String,
}

impl std::fmt::Display for Divergence {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self.t_s {
            Some(t) => write!(f, "replay diverged at record {} (t = {t:.3} s on the recorded rig clock): ", self.record)?,
            None => write!(f, "replay diverged at record {} (past the end of the recording): ", self.record)?,
        }
        write!(f, "the recording has {}, but {}", self.expected, self.got)
    }
}

/// Errors of a replay.
#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    #[error("{0}")]
    Diverged(Divergence),
    /// The replayed job failed the way the recorded one did (or for a dataset reason).
    #[error("the replayed collection failed: {0}")]
    Collect(#[from] CollectError),
    #[error(transparent)]
    Dataset(#[from] DatasetError),
    #[error("the replayed collection finished with {remaining} recorded events not replayed; the next is {next}")]
    Leftover { remaining: usize, next: String },
    /// The replayed job called its peripherals where the recorded one did not.
    #[error("{0}")]
    PeripheralsDiverged(String),
    /// The recording could not be read on: damaged after it was checked, or a frame whose
    /// pixels do not decode.
    #[error(transparent)]
    Recording(#[from] RecordError),
}

/// Where a session's events come from, one at a time, each with its record number and offset.
pub enum EventSource {
    /// Events in memory (tests); their record numbers are their places in the list.
    Memory(std::iter::Enumerate<std::vec::IntoIter<Event>>),
    /// Read from the recording file as they are served.
    File(RecordReader),
}

impl EventSource {
    /// Events held in memory.
    pub fn memory(events: Vec<Event>) -> Self {
        EventSource::Memory(events.into_iter().enumerate())
    }

    /// The next record, whatever it is.
    fn next_record(&mut self) -> Result<Option<RecordAt>, RecordError> {
        match self {
            EventSource::Memory(events) => Ok(events.next().map(|(record, event)| RecordAt { record, offset: 0, event })),
            EventSource::File(reader) => reader.next_record(),
        }
    }

    /// The next event the session serves: not an interrupt (it says where the job stopped) nor
    /// a peripherals call (served apart, by [`ReplayPeripherals`]).
    fn next_served(&mut self) -> Result<Option<RecordAt>, RecordError> {
        loop {
            match self.next_record()? {
                Some(RecordAt { event: Event::Interrupt { .. } | Event::Peripherals { .. }, .. }) => continue,
                other => return Ok(other),
            }
        }
    }

    /// The file it reads, for messages (events in memory: none).
    fn path(&self) -> &std::path::Path {
        match self {
            EventSource::Memory(_) => std::path::Path::new("(in memory)"),
            EventSource::File(reader) => reader.path(),
        }
    }

    /// A source that reads on from here on its own (a look ahead).
    fn fork(&self) -> Self {
        match self {
            EventSource::Memory(events) => EventSource::Memory(events.clone()),
            EventSource::File(reader) => EventSource::File(reader.fork()),
        }
    }
}

/// Whether a session serves `e` (see [`EventSource::next_served`]).
fn is_served(e: &Event) -> bool {
    !matches!(e, Event::Interrupt { .. } | Event::Peripherals { .. })
}

struct SessionState {
    /// The events after `current`, read as they are needed.
    source: EventSource,
    /// The event under the cursor; `None` past the end of the recording.
    current: Option<RecordAt>,
    /// The record number past the last (for a divergence past the end).
    end_record: usize,
    /// Events served so far, and in all.
    served_events: usize,
    total_events: usize,
    cameras: Vec<String>,
    /// Bytes of `current` already served (socket events are served in pieces).
    offset: usize,
    divergence: Option<Divergence>,
    /// The recording could not be read on (then nothing more is served).
    damaged: Option<RecordError>,
    waiters: Vec<Waker>,
    /// Counts served pieces, for the watchdog.
    progress: u64,
    /// The command socket whose read waited last, for the watchdog's message.
    blocked_read: Option<SocketId>,
    /// Controller bytes the client has not read yet although it went on, per socket (what
    /// would sit in the socket's receive buffer), served before further recorded reads.
    unread: [Vec<u8>; 3],
}

/// Shortened, escaped text of protocol bytes for messages.
fn show_bytes(bytes: &[u8]) -> String {
    let text: String = String::from_utf8_lossy(bytes).escape_debug().collect();
    if text.chars().count() > 120 {
        format!("\"{}...\" ({} bytes)", text.chars().take(120).collect::<String>(), bytes.len())
    } else {
        format!("\"{text}\"")
    }
}

/// Whether an event is the feedback reader's (the only one that runs beside the job).
fn is_feedback_read(e: &Event) -> bool {
    matches!(
        e,
        Event::Socket { socket: SocketId::Feedback, direction: Direction::FromController, .. }
            | Event::Connect { socket: SocketId::Feedback, .. }
    )
}

impl SessionState {
    fn describe(&self, e: &Event, offset: usize) -> String {
        match e {
            Event::Socket { socket, direction: Direction::FromController, bytes, .. } if bytes.is_empty() => {
                format!("the {} socket's connection lost (the client's read finds it closed)", socket.name())
            }
            Event::Socket { socket, direction: Direction::ToController, bytes, .. } if bytes.is_empty() => {
                format!("the {} socket's connection lost (the client's write fails)", socket.name())
            }
            Event::Socket { socket, direction: Direction::ToController, bytes, .. } => {
                format!("the client writing {} on the {} socket", show_bytes(bytes.get(offset..).unwrap_or_default()), socket.name())
            }
            Event::Socket { socket: SocketId::Feedback, bytes, .. } => {
                format!("{} bytes of feedback for the client to read", bytes.len() - offset.min(bytes.len()))
            }
            Event::Socket { socket, bytes, .. } => {
                format!("the controller answering {} on the {} socket", show_bytes(bytes.get(offset..).unwrap_or_default()), socket.name())
            }
            Event::Frame(f) => format!(
                "a frame of camera {} (seq {}, captured at {:.3} s)",
                self.cameras.get(usize::from(f.camera)).map_or("?", String::as_str),
                f.seq,
                f.t_capture_s
            ),
            Event::Interrupt { captured, .. } => format!("the operator's interrupt after {captured} poses"),
            Event::Peripherals { phase, .. } => format!("the peripherals' {phase:?} capture call"),
            Event::Connect { socket, outcome, .. } => format!("the client reconnecting the {} socket ({outcome:?})", socket.name()),
            Event::FeedbackUsed { seq: Some(0), .. } => "the client deciding on the feedback before any frame arrived".to_string(),
            Event::FeedbackUsed { seq: Some(seq), .. } => format!("the client deciding on the feedback by frame {seq}"),
            Event::FeedbackUsed { seq: None, .. } => "the client's wait for a fitting feedback frame timing out".to_string(),
            Event::ReplyTimedOut { socket, .. } => format!("the client giving up on a reply on the {} socket", socket.name()),
        }
    }

    fn describe_next(&self) -> String {
        match self.current_event() {
            Some(e) => self.describe(e, self.offset),
            None => "the end of the recording".to_string(),
        }
    }

    /// The event under the cursor.
    fn current_event(&self) -> Option<&Event> {
        self.current.as_ref().map(|r| &r.event)
    }

    /// The record number of the event under the cursor (past the end: the count of records).
    fn record(&self) -> usize {
        self.current.as_ref().map_or(self.end_record, |r| r.record)
    }

    /// The record number of the next feedback read after the cursor, looked for on a look ahead
    /// (for the watchdog's message; it reads on to the end of the recording at worst).
    fn next_feedback_read(&self) -> Option<usize> {
        let mut ahead = self.source.fork();
        while let Ok(Some(r)) = ahead.next_served() {
            if is_feedback_read(&r.event) {
                return Some(r.record);
            }
        }
        None
    }

    /// Whether the replay stopped: it diverged, or the recording could not be read on.
    fn halted(&self) -> bool {
        self.divergence.is_some() || self.damaged.is_some()
    }

    /// Moves the cursor to the next event, read from the source.
    fn advance(&mut self) {
        self.served_events += 1;
        self.current = match self.source.next_served() {
            Ok(next) => next,
            Err(e) => {
                self.damaged.get_or_insert(e);
                None
            }
        };
    }

    fn wake_all(&mut self) {
        for w in self.waiters.drain(..) {
            w.wake();
        }
    }

    fn wait(&mut self, cx: &Context<'_>) {
        if !self.waiters.iter().any(|w| w.will_wake(cx.waker())) {
            self.waiters.push(cx.waker().clone());
        }
    }

    /// Records the first divergence and wakes everyone so that they see it.
    fn diverge(&mut self, got: String) -> std::io::Error {
        if self.divergence.is_none() {
            self.divergence =
                Some(Divergence { record: self.record(), t_s: self.current_event().map(Event::t_s), expected: self.describe_next(), got });
        }
        self.wake_all();
        self.failure()
    }

    fn failure(&self) -> std::io::Error {
        let text = match (&self.divergence, &self.damaged) {
            (Some(d), _) => d.to_string(),
            (None, Some(e)) => e.to_string(),
            (None, None) => "replay failed".to_string(),
        };
        std::io::Error::other(text)
    }

    /// The job went on (wrote, or asked for a frame) while replies it read in the recording
    /// are next: it gave up on those replies this time (the client's `Sync` races its reply
    /// against an alarm in the feedback, and either may win). They stay in the socket, as on
    /// the wire, and the client reads (and skips) them later.
    fn shelve_unread_replies(&mut self, clock: &MockClock) {
        while let Some(Event::Socket { socket, direction: Direction::FromController, bytes, t_s }) = self.current_event()
            && *socket != SocketId::Feedback
            // A lost connection is not shelved: the read it ended stays due.
            && !bytes.is_empty()
        {
            let (socket, t_s, len) = (*socket, *t_s, bytes.len());
            let rest = bytes.get(self.offset..).unwrap_or_default().to_vec();
            self.unread[socket.index()].extend_from_slice(&rest);
            self.served(rest.len(), len, t_s, clock);
            if self.offset != 0 {
                // Nothing was left to move (an empty tail cannot happen with recorded events).
                break;
            }
        }
    }

    /// A step of the job (a write, a frame request, a reconnection) that is not the event under
    /// the cursor: it waits while feedback recorded before the step is still unread; facing
    /// anything else, the replay diverged (`got`: what the job did).
    fn job_step_elsewhere(&mut self, cx: &Context<'_>, got: impl FnOnce() -> String) -> Poll<std::io::Error> {
        if self.current_event().is_some_and(is_feedback_read) {
            self.wait(cx);
            Poll::Pending
        } else {
            Poll::Ready(self.diverge(got()))
        }
    }

    /// Marks `n` more bytes of the current event (of `len`) served, at recorded time `t_s`.
    fn served(&mut self, n: usize, len: usize, t_s: f64, clock: &MockClock) {
        self.offset += n;
        if self.offset >= len {
            self.advance();
            self.offset = 0;
        }
        self.progress += 1;
        self.blocked_read = None;
        if t_s > clock.now_s() {
            clock.set_s(t_s);
        }
        self.wake_all();
    }
}

/// Serves the recorded events to the replayed client and cameras. Cloning shares it.
#[derive(Clone)]
pub struct ReplaySession {
    state: Arc<Mutex<SessionState>>,
    clock: MockClock,
}

impl ReplaySession {
    /// A session over `events` held in memory; `cameras` names the cameras by index (for
    /// messages).
    pub fn new(events: Vec<Event>, cameras: Vec<String>) -> Self {
        let (end_record, total) = (events.len(), events.iter().filter(|e| is_served(e)).count());
        let mut source = EventSource::memory(events);
        // Events in memory are read without fail.
        let current = source.next_served().unwrap_or_default();
        Self::with_source(source, current, end_record, total, cameras)
    }

    /// A session over the records `reader` reads, `summary` counted by a scan of the same file
    /// first: it holds the event being served, whatever the recording's length.
    pub fn from_file(reader: RecordReader, summary: &Summary, cameras: Vec<String>) -> Result<Self, RecordError> {
        let mut source = EventSource::File(reader);
        let current = source.next_served()?;
        Ok(Self::with_source(source, current, summary.events, summary.served_events(), cameras))
    }

    fn with_source(source: EventSource, current: Option<RecordAt>, end_record: usize, total_events: usize, cameras: Vec<String>) -> Self {
        let state = SessionState {
            source,
            current,
            end_record,
            served_events: 0,
            total_events,
            cameras,
            offset: 0,
            divergence: None,
            damaged: None,
            waiters: Vec::new(),
            progress: 0,
            blocked_read: None,
            unread: Default::default(),
        };
        Self { state: Arc::new(Mutex::new(state)), clock: MockClock::new() }
    }

    fn lock(&self) -> MutexGuard<'_, SessionState> {
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// The clock that follows the recorded times of the events served.
    pub fn clock(&self) -> MockClock {
        self.clock.clone()
    }

    /// The replay side of one MG400 socket.
    pub fn stream(&self, socket: SocketId) -> ReplayStream {
        ReplayStream { session: self.clone(), socket, yield_next: false }
    }

    /// Opens `socket` again where the recording has the client reconnecting it: a new
    /// [`ReplayStream`], or the recorded failure.
    pub fn reopen(&self, socket: SocketId) -> Reopen {
        let session = self.clone();
        Arc::new(move || {
            let session = session.clone();
            Box::pin(async move {
                let outcome = poll_fn(|cx| session.poll_connect(socket, cx)).await?;
                let what = || format!("reconnecting the {} socket (as in the recording)", socket.name());
                match outcome {
                    ConnectOutcome::Connected => Ok(Box::new(session.stream(socket)) as Box<dyn ByteStream>),
                    ConnectOutcome::Failed => Err(ArmError::Io { context: what(), source: std::io::ErrorKind::ConnectionRefused.into() }),
                    // The recording keeps the outcome, not the wait; the replay does not wait.
                    ConnectOutcome::TimedOut => Err(ArmError::Timeout {
                        what: format!("reconnecting the {} socket (it timed out in the recorded run)", socket.name()),
                        after: Duration::ZERO,
                    }),
                }
            })
        })
    }

    fn poll_connect(&self, socket: SocketId, cx: &mut Context<'_>) -> Poll<Result<ConnectOutcome, ArmError>> {
        let mut st = self.lock();
        let failed = |source| ArmError::Io { context: format!("reconnecting the {} socket", socket.name()), source };
        if st.halted() {
            return Poll::Ready(Err(failed(st.failure())));
        }
        if socket != SocketId::Feedback {
            st.shelve_unread_replies(&self.clock);
        }
        if let Some(Event::Connect { socket: s, t_s, outcome }) = st.current_event()
            && *s == socket
        {
            let (t_s, outcome) = (*t_s, *outcome);
            st.served(1, 1, t_s, &self.clock);
            return Poll::Ready(Ok(outcome));
        }
        // The feedback reader waits for its turn.
        if socket == SocketId::Feedback {
            st.wait(cx);
            return Poll::Pending;
        }
        st.job_step_elsewhere(cx, || format!("the client reconnected the {} socket", socket.name())).map(|e| Err(failed(e)))
    }

    /// Dictates the replayed client's decisions that timing settled (a recording of version 5
    /// on): each is served where the recording has it.
    pub fn witness(&self) -> Witness {
        let session = self.clone();
        Witness::Dictate(Arc::new(move |ask| {
            let session = session.clone();
            Box::pin(async move { poll_fn(|cx| session.poll_decision(ask, cx)).await })
        }))
    }

    fn poll_decision(&self, ask: Ask, cx: &mut Context<'_>) -> Poll<Result<Decision, ArmError>> {
        let mut st = self.lock();
        let failed = |source| ArmError::Io { context: "deciding what the MG400 client does next".into(), source };
        if st.halted() {
            return Poll::Ready(Err(failed(st.failure())));
        }
        // A decision on the feedback that is the client's next step: replies it gave up on stay
        // in their socket, as before a write. The others race a reply and wait while anything
        // else comes first.
        if ask == Ask::Feedback {
            st.shelve_unread_replies(&self.clock);
        }
        let next = st.current_event().and_then(|e| Some((e.t_s(), decision_of(e)?)));
        if let Some((t_s, decision)) = next
            && match (decision, ask) {
                (Decision::Feedback(_) | Decision::FeedbackTimedOut, Ask::Feedback | Ask::AlarmDuringSync) => true,
                (Decision::ReplyTimedOut(recorded), Ask::ReplyTimeout(asked)) => recorded == asked,
                _ => false,
            }
        {
            st.served(1, 1, t_s, &self.clock);
            return Poll::Ready(Ok(decision));
        }
        if ask != Ask::Feedback {
            st.wait(cx);
            return Poll::Pending;
        }
        st.job_step_elsewhere(cx, || "the client decided on the feedback".to_string()).map(|e| Err(failed(e)))
    }

    /// The replay of camera number `index` of the header's list.
    pub fn camera(&self, index: u8) -> ReplayCamera {
        let name = self.lock().cameras.get(usize::from(index)).cloned().unwrap_or_else(|| format!("camera{index}"));
        ReplayCamera { session: self.clone(), index, name }
    }

    /// The first divergence, if the replayed run left the recording.
    pub fn divergence(&self) -> Option<Divergence> {
        self.lock().divergence.clone()
    }

    /// The recording's damage that stopped the replay, if any (taken: reported once).
    pub fn take_damage(&self) -> Option<RecordError> {
        self.lock().damaged.take()
    }

    /// Events served so far and in all.
    pub fn position(&self) -> (usize, usize) {
        let st = self.lock();
        (st.served_events, st.total_events)
    }

    /// Succeeds when every recorded event of the job was replayed (feedback frames the client
    /// did not read before it was closed may remain). Reads the rest of the recording on a
    /// look ahead: the position stays.
    pub fn check_finished(&self) -> Result<(), ReplayError> {
        let st = self.lock();
        let Some(next) = st.current_event() else { return Ok(()) };
        let (mut remaining, mut only_feedback) = (1, is_feedback_read(next));
        let mut rest = st.source.fork();
        while let Some(r) = rest.next_served()? {
            remaining += 1;
            only_feedback &= is_feedback_read(&r.event);
        }
        if only_feedback {
            return Ok(());
        }
        Err(ReplayError::Leftover { remaining, next: st.describe_next() })
    }

    /// Turns a replay that serves nothing for `stall_after` into a divergence. Runs until the
    /// task is aborted.
    pub async fn watchdog(self, stall_after: Duration) {
        let tick = (stall_after / 4).max(Duration::from_millis(10));
        let mut last = (u64::MAX, tokio::time::Instant::now());
        loop {
            tokio::time::sleep(tick).await;
            let mut st = self.lock();
            if st.halted() {
                return;
            }
            if st.progress != last.0 {
                last = (st.progress, tokio::time::Instant::now());
            } else if last.1.elapsed() >= stall_after {
                let doing = match st.blocked_read {
                    Some(socket) => format!("the client waits for a reply on the {} socket", socket.name()),
                    // The job may wait for feedback the recording has only after its next step.
                    None => match st.current_event().filter(|e| !is_feedback_read(e)).and_then(|_| st.next_feedback_read()) {
                        Some(k) => format!(
                            "the replayed run waits for something else (if for a feedback frame, the recording has the next \
                             one only after this step, at record {k})"
                        ),
                        None => "the replayed run waits for something else".to_string(),
                    },
                };
                let _ = st.diverge(format!("{doing}, and nothing happened for {stall_after:?}"));
                return;
            }
        }
    }
}

/// One replayed MG400 socket: serves the recorded controller bytes, checks the client's.
pub struct ReplayStream {
    session: ReplaySession,
    socket: SocketId,
    /// Yield once before serving the next chunk (see the module docs).
    yield_next: bool,
}

impl AsyncRead for ReplayStream {
    fn poll_read(mut self: Pin<&mut Self>, cx: &mut Context<'_>, buf: &mut ReadBuf<'_>) -> Poll<std::io::Result<()>> {
        let this = &mut *self;
        let session = this.session.clone();
        let mut st = session.lock();
        if st.halted() {
            return Poll::Ready(Err(st.failure()));
        }
        if this.yield_next {
            this.yield_next = false;
            cx.waker().wake_by_ref();
            return Poll::Pending;
        }
        if buf.remaining() == 0 {
            return Poll::Ready(Ok(()));
        }
        let waiting = &mut st.unread[this.socket.index()];
        if !waiting.is_empty() {
            let n = waiting.len().min(buf.remaining());
            buf.put_slice(&waiting[..n]);
            waiting.drain(..n);
            st.progress += 1;
            this.yield_next = true;
            return Poll::Ready(Ok(()));
        }
        let offset = st.offset;
        let outcome = match st.current_event() {
            Some(Event::Socket { socket, direction: Direction::FromController, bytes, t_s }) if *socket == this.socket => {
                let rest = bytes.get(offset..).unwrap_or_default();
                let n = rest.len().min(buf.remaining());
                buf.put_slice(&rest[..n]);
                Some((n, bytes.len(), *t_s))
            }
            _ => None,
        };
        if let Some((n, len, t_s)) = outcome {
            st.served(n, len, t_s, &session.clock);
            this.yield_next = true;
            return Poll::Ready(Ok(()));
        }
        if this.socket == SocketId::Feedback || st.current.is_some() {
            // The feedback reader waits for its turn. A reply read waits too, also when the
            // job's next recorded step is something else: the client may be racing the read
            // against an alarm in the feedback (`Sync` does), and the other branch moves on.
            // If nothing does, the watchdog reports what this read waited for.
            if this.socket != SocketId::Feedback {
                st.blocked_read = Some(this.socket);
            }
            st.wait(cx);
            return Poll::Pending;
        }
        let got = format!("the client waits to read from the {} socket", this.socket.name());
        Poll::Ready(Err(st.diverge(got)))
    }
}

impl AsyncWrite for ReplayStream {
    fn poll_write(self: Pin<&mut Self>, cx: &mut Context<'_>, buf: &[u8]) -> Poll<std::io::Result<usize>> {
        let session = self.session.clone();
        let mut st = session.lock();
        if st.halted() {
            return Poll::Ready(Err(st.failure()));
        }
        if buf.is_empty() {
            return Poll::Ready(Ok(0));
        }
        st.shelve_unread_replies(&session.clock);
        let offset = st.offset;
        let matched = match st.current_event() {
            Some(Event::Socket { socket, direction: Direction::ToController, bytes, t_s }) if *socket == self.socket => {
                let rest = bytes.get(offset..).unwrap_or_default();
                let n = rest.len().min(buf.len());
                Some((rest.get(..n) == buf.get(..n), n, bytes.len(), *t_s))
            }
            _ => None,
        };
        match matched {
            Some((true, _, 0, t_s)) => {
                // The recorded write failed: the connection was lost there.
                st.served(0, 0, t_s, &session.clock);
                let what = format!("writing on the {} socket: the connection was lost here in the recording", self.socket.name());
                Poll::Ready(Err(std::io::Error::new(std::io::ErrorKind::BrokenPipe, what)))
            }
            Some((true, n, len, t_s)) => {
                st.served(n, len, t_s, &session.clock);
                Poll::Ready(Ok(n))
            }
            Some((false, ..)) => {
                let got = format!("the client wrote {} on the {} socket", show_bytes(buf), self.socket.name());
                Poll::Ready(Err(st.diverge(got)))
            }
            None => {
                st.job_step_elsewhere(cx, || format!("the client wrote {} on the {} socket", show_bytes(buf), self.socket.name())).map(Err)
            }
        }
    }
    fn poll_flush(self: Pin<&mut Self>, _cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Poll::Ready(Ok(()))
    }
    fn poll_shutdown(self: Pin<&mut Self>, _cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Poll::Ready(Ok(()))
    }
}

/// A replayed camera: hands out the recorded frames in recorded order. The recorded frame is
/// returned whatever `not_before_s` asks: the recording already honoured it. It has no stream
/// ([`Camera::stream_stats`] is `None`): a recording holds the frames the job took, not the
/// ones the camera delivered between them, so a replayed dataset records no frame counts.
pub struct ReplayCamera {
    session: ReplaySession,
    index: u8,
    name: String,
}

impl ReplayCamera {
    fn poll_frame(&self, cx: &mut Context<'_>) -> Poll<Result<Frame, CameraError>> {
        let mut st = self.session.lock();
        let device_error = |reason: String| CameraError::Device { camera: self.name.clone(), reason };
        if st.halted() {
            return Poll::Ready(Err(device_error(st.failure().to_string())));
        }
        st.shelve_unread_replies(&self.session.clock);
        if matches!(st.current_event(), Some(Event::Frame(f)) if f.camera == self.index)
            && let Some(RecordAt { record, offset, event: Event::Frame(f) }) = st.current.take()
        {
            // Served (and the cursor moved on) before the pixels are decoded: only this frame is
            // held while they are.
            st.served(1, 1, f.t_s, &self.session.clock);
            let (t_capture_s, seq) = (f.t_capture_s, f.seq);
            return match frame_image(f.width, f.height, f.pixels) {
                Ok(image) => Poll::Ready(Ok(Frame { image, t_capture_s, seq })),
                Err(reason) => {
                    let damage = RecordError::FrameDecode {
                        path: st.source.path().to_path_buf(),
                        record,
                        offset,
                        camera: self.name.clone(),
                        seq,
                        reason,
                    };
                    let text = damage.to_string();
                    st.damaged.get_or_insert(damage);
                    st.wake_all();
                    Poll::Ready(Err(CameraError::Decode { camera: self.name.clone(), reason: text }))
                }
            };
        }
        st.job_step_elsewhere(cx, || format!("the job asked camera {} for a frame", self.name)).map(|e| Err(device_error(e.to_string())))
    }
}

impl Camera for ReplayCamera {
    fn name(&self) -> &str {
        &self.name
    }
    async fn frame_after(&mut self, _not_before_s: f64) -> Result<Frame, CameraError> {
        poll_fn(|cx| self.poll_frame(cx)).await
    }
}

/// The recorded peripheral calls, handed back in recorded order. They are not served through
/// the session: the job calls them at fixed points between its own socket traffic, so their
/// order among themselves is all that matters. They are read from their own [`EventSource`]
/// (on the recording file: a reader of its own), one call at a time. Cloning shares the calls.
#[derive(Clone)]
pub struct ReplayPeripherals {
    state: Arc<Mutex<PeripheralCalls>>,
    /// Whether the recorded run had peripherals (it then logged at least one call).
    present: bool,
}

struct PeripheralCalls {
    /// The recording, read on to each next peripherals record.
    source: EventSource,
    /// Calls recorded and not made yet.
    left: usize,
    /// The first call that did not match the recording.
    mismatch: Option<String>,
    /// The recording could not be read on.
    damaged: Option<RecordError>,
}

impl ReplayPeripherals {
    /// The `calls` peripheral calls that `source` reads, in order.
    pub fn new(source: EventSource, calls: usize) -> Self {
        let state = PeripheralCalls { source, left: calls, mismatch: None, damaged: None };
        Self { state: Arc::new(Mutex::new(state)), present: calls > 0 }
    }

    /// The peripheral calls of `events`, in order.
    pub fn from_events(events: &[Event]) -> Self {
        let calls = events.iter().filter(|e| matches!(e, Event::Peripherals { .. })).count();
        Self::new(EventSource::memory(events.to_vec()), calls)
    }

    fn lock(&self) -> MutexGuard<'_, PeripheralCalls> {
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Calls recorded but not made by the replay.
    pub fn left(&self) -> usize {
        self.lock().left
    }

    /// The first call of the replay that the recording does not have.
    pub fn mismatch(&self) -> Option<String> {
        self.lock().mismatch.clone()
    }

    /// The recording's damage found while reading the calls, if any (taken: reported once).
    pub fn take_damage(&self) -> Option<RecordError> {
        self.lock().damaged.take()
    }

    fn next(&self, phase: PeripheralPhase) -> Result<(PeripheralOutcome, String), ModbusError> {
        let mut st = self.lock();
        let call = loop {
            match st.source.next_record() {
                Ok(Some(RecordAt { event: Event::Peripherals { phase, outcome, text, .. }, .. })) => break Some((phase, outcome, text)),
                Ok(Some(_)) => continue,
                Ok(None) => break None,
                Err(e) => {
                    let message = e.to_string();
                    st.damaged.get_or_insert(e);
                    return Err(ModbusError::Replayed { message, recoverable: false });
                }
            }
        };
        st.left = st.left.saturating_sub(usize::from(call.is_some()));
        match call {
            Some((p, outcome, text)) if p == phase => Ok((outcome, text)),
            other => {
                let recorded = other.map_or_else(|| "no further call".to_string(), |(p, ..)| format!("a {p:?}-capture call"));
                let message = format!("replay diverged: the job made a {phase:?}-capture peripherals call, the recording has {recorded}");
                st.mismatch.get_or_insert_with(|| message.clone());
                Err(ModbusError::Replayed { message, recoverable: false })
            }
        }
    }

    fn replayed<T>(outcome: PeripheralOutcome, text: String, ok: T) -> Result<T, ModbusError> {
        match outcome {
            PeripheralOutcome::Ok => Ok(ok),
            PeripheralOutcome::Recoverable => Err(ModbusError::Replayed { message: text, recoverable: true }),
            PeripheralOutcome::Fatal => Err(ModbusError::Replayed { message: text, recoverable: false }),
        }
    }
}

impl Peripherals for ReplayPeripherals {
    fn is_empty(&self) -> bool {
        !self.present
    }
    async fn before_capture(&mut self) -> Result<(), ModbusError> {
        if !self.present {
            return Ok(());
        }
        let (outcome, text) = self.next(PeripheralPhase::Before)?;
        Self::replayed(outcome, text, ())
    }
    async fn after_capture(&mut self) -> Result<Vec<ModbusReading>, ModbusError> {
        // As `NoPeripherals`: the job asks for readings even without peripherals.
        if !self.present {
            return Ok(Vec::new());
        }
        let (outcome, text) = self.next(PeripheralPhase::After)?;
        if outcome != PeripheralOutcome::Ok {
            return Self::replayed(outcome, text, Vec::new());
        }
        parse_readings(&text).ok_or_else(|| ModbusError::Replayed {
            message: format!("the recording's readings {text:?} are not a modbus column"),
            recoverable: false,
        })
    }
}

/// The hardware of a replayed collection: the real MG400 client over the recording's sockets,
/// the recorded cameras and peripherals, on the recorded clock, with a watchdog that turns a
/// replay that stops moving into a divergence. The job runs on it like on a live rig
/// (`jobs::replay`), then [`verdict`](Self::verdict) and [`finished`](Self::finished) judge
/// the run against the recording.
pub struct ReplayRig {
    session: ReplaySession,
    pub arm: Mg400Client,
    /// One camera per recorded sensor, in the header's order.
    pub cameras: Vec<ReplayCamera>,
    pub peripherals: ReplayPeripherals,
    pub clock: Arc<dyn Clock>,
    /// Poses after which the recorded run was interrupted: the replay stops there too.
    pub stop_after: Option<usize>,
    watchdog: tokio::task::JoinHandle<()>,
}

impl ReplayRig {
    /// Opens the replayed hardware of `recording`, whose records `summary` counted (a scan of
    /// the whole file, [`RecordingFile::scan`]): connects the client and waits for its first
    /// feedback, as the recorded run's connect did. `stall_after` is the watchdog's patience.
    /// The events and the peripheral calls are read from the file as they are served.
    pub async fn open(recording: &RecordingFile, summary: &Summary, stall_after: Duration) -> Result<ReplayRig, ReplayError> {
        let h = &recording.header;
        // An interrupt is not I/O to serve: it says where the job stopped.
        let stop_after = summary.interrupted_after.map(|captured| usize::try_from(captured).unwrap_or(usize::MAX));
        // Peripheral calls are served apart from the socket and camera events (see ReplayPeripherals).
        let peripherals = ReplayPeripherals::new(EventSource::File(recording.records()), summary.peripheral_calls);
        let session = ReplaySession::from_file(recording.records(), summary, h.sensors.iter().map(|s| s.camera.clone()).collect())?;
        let watchdog = tokio::spawn(session.clone().watchdog(stall_after));
        let mut cfg = Mg400Config::new("replay", h.profile.clone());
        cfg.speed_factor_pct = h.speed_factor_pct;
        cfg.connect_timeout = REPLAY_CLIENT_TIMEOUT;
        cfg.reply_timeout = REPLAY_CLIENT_TIMEOUT;
        cfg.enable_timeout = REPLAY_CLIENT_TIMEOUT;
        cfg.drain_timeout = REPLAY_CLIENT_TIMEOUT;
        let clock: Arc<dyn Clock> = Arc::new(session.clock());
        let replayed = |socket| (Box::new(session.stream(socket)) as Box<dyn ByteStream>, session.reopen(socket));
        let mut arm = Mg400Client::with_reopen(
            cfg,
            Arc::clone(&clock),
            [replayed(SocketId::Dashboard), replayed(SocketId::Motion), replayed(SocketId::Feedback)],
        );
        // Before version 5 the decisions on the feedback were not recorded: the client makes them
        // on the frames it holds, which is a matter of scheduling (the module docs).
        if recording.version >= 5 {
            arm.set_witness(session.witness());
        }
        // The header has at most 256 sensors: frame records name them with one byte.
        let cameras = (0..h.sensors.len()).map(|index| session.camera(u8::try_from(index).unwrap_or(u8::MAX))).collect();
        let mut rig = ReplayRig { session, arm, cameras, peripherals, clock, stop_after, watchdog };
        // As the recorded run's connect did.
        if let Err(e) = rig.arm.wait_first_feedback().await {
            rig.watchdog.abort();
            return Err(rig.verdict().err().unwrap_or(ReplayError::Collect(CollectError::from(e))));
        }
        Ok(rig)
    }

    /// After the job: the first divergence from the recording (it explains whatever the job
    /// made of it afterwards), else a peripherals call the recording does not have.
    pub fn verdict(&self) -> Result<(), ReplayError> {
        self.watchdog.abort();
        // A damaged recording explains whatever the replay did after it.
        if let Some(e) = self.session.take_damage().or_else(|| self.peripherals.take_damage()) {
            return Err(ReplayError::Recording(e));
        }
        if let Some(d) = self.session.divergence() {
            return Err(ReplayError::Diverged(d));
        }
        if let Some(m) = self.peripherals.mismatch() {
            return Err(ReplayError::PeripheralsDiverged(m));
        }
        Ok(())
    }

    /// After a job that succeeded: every recorded event was served; returns the events served
    /// and in all.
    pub fn finished(&self) -> Result<(usize, usize), ReplayError> {
        self.session.check_finished()?;
        if self.peripherals.left() > 0 {
            return Err(ReplayError::Leftover { remaining: self.peripherals.left(), next: "a recorded peripherals call".into() });
        }
        Ok(self.session.position())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::arm::dobot::proto::Port;
    use tokio::io::{AsyncReadExt, AsyncWriteExt};

    fn ev(socket: SocketId, direction: Direction, t_s: f64, bytes: &[u8]) -> Event {
        Event::Socket { socket, direction, t_s, bytes: bytes.to_vec() }
    }

    #[tokio::test(flavor = "current_thread")]
    async fn serves_replies_in_order_and_follows_the_recorded_clock() {
        let session = ReplaySession::new(
            vec![
                ev(SocketId::Dashboard, Direction::ToController, 1.0, b"RobotMode()"),
                ev(SocketId::Dashboard, Direction::FromController, 1.5, b"0,{5},RobotMode();"),
            ],
            vec![],
        );
        let mut d = session.stream(SocketId::Dashboard);
        d.write_all(b"Robot").await.unwrap();
        d.write_all(b"Mode()").await.unwrap();
        assert_eq!(session.clock().now_s(), 1.0);
        let mut buf = [0u8; 64];
        let n = d.read(&mut buf).await.unwrap();
        assert_eq!(&buf[..n], b"0,{5},RobotMode();");
        assert_eq!(session.clock().now_s(), 1.5);
        assert!(session.check_finished().is_ok());
    }

    #[tokio::test(flavor = "current_thread")]
    async fn reconnections_get_the_recorded_outcomes_in_order() {
        let connect = |t_s, outcome| Event::Connect { socket: SocketId::Motion, t_s, outcome };
        let session = ReplaySession::new(
            vec![
                ev(SocketId::Motion, Direction::FromController, 1.0, b""),
                connect(1.1, ConnectOutcome::Failed),
                connect(1.2, ConnectOutcome::TimedOut),
                connect(1.3, ConnectOutcome::Connected),
                ev(SocketId::Motion, Direction::ToController, 1.4, b"Sync()"),
            ],
            vec![],
        );
        let mut m = session.stream(SocketId::Motion);
        let mut buf = [0u8; 16];
        assert_eq!(m.read(&mut buf).await.unwrap(), 0, "the recorded loss is the end of the stream");
        let reopen = session.reopen(SocketId::Motion);
        assert!(matches!(reopen().await, Err(ArmError::Io { .. })));
        assert!(matches!(reopen().await, Err(ArmError::Timeout { .. })));
        assert!((session.clock().now_s() - 1.2).abs() < 1e-9, "the clock follows the served records");
        let mut again = reopen().await.expect("the third attempt connected");
        again.write_all(b"Sync()").await.unwrap();
        assert_eq!(session.position(), (5, 5));
        assert_eq!(session.divergence(), None);
    }

    #[tokio::test(flavor = "current_thread")]
    async fn a_reconnection_the_recording_lacks_is_a_divergence() {
        let session = ReplaySession::new(vec![ev(SocketId::Dashboard, Direction::ToController, 1.0, b"RobotMode()")], vec![]);
        let err = session.reopen(SocketId::Dashboard)().await.err().expect("no reconnection recorded");
        assert!(matches!(err, ArmError::Io { .. }), "{err:?}");
        let d = session.divergence().expect("a divergence");
        assert_eq!(d.record, 0);
        assert!(d.expected.contains("RobotMode()") && d.got.contains("reconnected the dashboard socket"), "{d}");
    }

    /// The decision the witness dictates, as the client asks for it.
    async fn decide(session: &ReplaySession, ask: Ask) -> Result<Decision, ArmError> {
        let Witness::Dictate(next) = session.witness() else { panic!("a replay dictates") };
        next(ask).await
    }

    #[tokio::test(flavor = "current_thread")]
    async fn decisions_get_the_recorded_frames_after_the_feedback_before_them() {
        let session = ReplaySession::new(
            vec![
                Event::FeedbackUsed { t_s: 0.5, seq: Some(0) },
                ev(SocketId::Feedback, Direction::FromController, 1.0, b"frame"),
                Event::FeedbackUsed { t_s: 1.5, seq: Some(1) },
                Event::FeedbackUsed { t_s: 2.0, seq: None },
            ],
            vec![],
        );
        assert_eq!(decide(&session, Ask::Feedback).await.unwrap(), Decision::Feedback(0));
        let s = session.clone();
        let second = tokio::spawn(async move { decide(&s, Ask::Feedback).await });
        tokio::task::yield_now().await;
        assert_eq!(session.position().0, 1, "the decision waits for the feedback recorded before it");
        let mut f = session.stream(SocketId::Feedback);
        let mut buf = [0u8; 8];
        assert_eq!(f.read(&mut buf).await.unwrap(), 5);
        assert_eq!(second.await.unwrap().unwrap(), Decision::Feedback(1));
        assert_eq!(decide(&session, Ask::Feedback).await.unwrap(), Decision::FeedbackTimedOut, "the recorded wait timed out");
        assert_eq!(session.clock().now_s(), 2.0);
        assert!(session.check_finished().is_ok());
    }

    #[tokio::test(flavor = "current_thread")]
    async fn a_decision_the_recording_lacks_is_a_divergence_and_one_racing_a_reply_waits() {
        let session = ReplaySession::new(
            vec![
                ev(SocketId::Motion, Direction::FromController, 1.0, b"0,{},Sync();"),
                ev(SocketId::Dashboard, Direction::ToController, 1.1, b"GetErrorID()"),
            ],
            vec![],
        );
        // Racing the Sync reply: it waits while the reply is next.
        let s = session.clone();
        let racing = tokio::spawn(async move { decide(&s, Ask::AlarmDuringSync).await });
        tokio::task::yield_now().await;
        assert!(!racing.is_finished() && session.divergence().is_none());
        racing.abort();
        let mut m = session.stream(SocketId::Motion);
        let mut buf = [0u8; 32];
        assert_eq!(m.read(&mut buf).await.unwrap(), 12);
        // Not racing anything, facing a write: a divergence naming both.
        let err = decide(&session, Ask::Feedback).await.unwrap_err();
        assert!(matches!(err, ArmError::Io { .. }), "{err:?}");
        let d = session.divergence().expect("a divergence");
        assert_eq!(d.record, 1);
        assert!(d.expected.contains("GetErrorID()") && d.got.contains("decided on the feedback"), "{d}");
    }

    #[tokio::test(flavor = "current_thread")]
    async fn a_reply_times_out_where_the_recording_gave_up_on_it() {
        let session = ReplaySession::new(
            vec![
                ev(SocketId::Motion, Direction::ToController, 1.0, b"Sync()"),
                Event::ReplyTimedOut { socket: SocketId::Motion, t_s: 2.0 },
            ],
            vec![],
        );
        // Before the write, and on the other socket, the timeout is not due: both wait.
        let (s1, s2) = (session.clone(), session.clone());
        let motion = tokio::spawn(async move { decide(&s1, Ask::ReplyTimeout(Port::Motion)).await });
        let dashboard = tokio::spawn(async move { decide(&s2, Ask::ReplyTimeout(Port::Dashboard)).await });
        tokio::task::yield_now().await;
        assert!(!motion.is_finished() && !dashboard.is_finished());
        session.stream(SocketId::Motion).write_all(b"Sync()").await.unwrap();
        assert_eq!(motion.await.unwrap().unwrap(), Decision::ReplyTimedOut(Port::Motion));
        tokio::task::yield_now().await;
        assert!(!dashboard.is_finished(), "the motion socket's timeout is not the dashboard's");
        dashboard.abort();
        assert_eq!(session.clock().now_s(), 2.0);
        assert!(session.check_finished().is_ok() && session.divergence().is_none());
    }

    #[tokio::test(flavor = "current_thread")]
    async fn a_different_request_is_a_divergence_naming_both() {
        let session = ReplaySession::new(vec![ev(SocketId::Motion, Direction::ToController, 2.0, b"MovJ(1,2,3,4)")], vec![]);
        let mut m = session.stream(SocketId::Motion);
        let err = m.write_all(b"MovJ(1,2,3,5)").await.unwrap_err();
        let d = session.divergence().unwrap();
        assert_eq!(d.record, 0);
        assert!(d.expected.contains("MovJ(1,2,3,4)") && d.got.contains("MovJ(1,2,3,5)"), "{d}");
        assert!(err.to_string().contains("record 0"), "{err}");
    }

    #[tokio::test(flavor = "current_thread")]
    async fn the_job_waits_for_feedback_recorded_before_its_request() {
        let session = ReplaySession::new(
            vec![
                ev(SocketId::Feedback, Direction::FromController, 0.1, b"frame"),
                ev(SocketId::Dashboard, Direction::ToController, 0.2, b"Sync()"),
            ],
            vec![],
        );
        let mut d = session.stream(SocketId::Dashboard);
        let mut f = session.stream(SocketId::Feedback);
        let writer = tokio::spawn(async move { d.write_all(b"Sync()").await });
        tokio::task::yield_now().await;
        assert_eq!(session.position().0, 0, "the write must wait for the feedback read");
        let mut buf = [0u8; 16];
        assert_eq!(f.read(&mut buf).await.unwrap(), 5);
        writer.await.unwrap().unwrap();
        assert_eq!(session.position(), (2, 2));
    }

    #[tokio::test(flavor = "current_thread")]
    async fn a_reply_that_never_comes_is_reported_by_the_watchdog() {
        let session = ReplaySession::new(vec![ev(SocketId::Dashboard, Direction::ToController, 1.0, b"ClearError()")], vec![]);
        let mut m = session.stream(SocketId::Motion);
        let watchdog = tokio::spawn(session.clone().watchdog(Duration::from_millis(40)));
        let mut buf = [0u8; 8];
        assert!(m.read(&mut buf).await.is_err());
        watchdog.await.unwrap();
        let d = session.divergence().unwrap();
        assert!(d.expected.contains("ClearError()") && d.got.contains("reply on the motion socket"), "{d}");
    }

    #[tokio::test(flavor = "current_thread")]
    async fn a_reply_the_client_gave_up_on_stays_in_the_socket() {
        let session = ReplaySession::new(
            vec![
                ev(SocketId::Motion, Direction::ToController, 1.0, b"Sync()"),
                ev(SocketId::Motion, Direction::FromController, 1.1, b"0,{},Sync();"),
                ev(SocketId::Dashboard, Direction::ToController, 1.2, b"GetErrorID()"),
                ev(SocketId::Motion, Direction::ToController, 1.3, b"MovJ(1,2,3,4)"),
                ev(SocketId::Motion, Direction::FromController, 1.4, b"0,{},MovJ(1,2,3,4);"),
            ],
            vec![],
        );
        let (mut d, mut m) = (session.stream(SocketId::Dashboard), session.stream(SocketId::Motion));
        m.write_all(b"Sync()").await.unwrap();
        // The client does not read the Sync reply now (an alarm won the race) and goes on.
        d.write_all(b"GetErrorID()").await.unwrap();
        m.write_all(b"MovJ(1,2,3,4)").await.unwrap();
        let mut text = Vec::new();
        let mut buf = [0u8; 64];
        while text.len() < 31 {
            let n = m.read(&mut buf).await.unwrap();
            text.extend_from_slice(&buf[..n]);
        }
        assert_eq!(text, b"0,{},Sync();0,{},MovJ(1,2,3,4);");
        assert_eq!(session.divergence(), None);
        assert!(session.check_finished().is_ok());
    }

    #[tokio::test(flavor = "current_thread")]
    async fn writing_past_the_end_is_a_divergence() {
        let session = ReplaySession::new(vec![], vec![]);
        let mut d = session.stream(SocketId::Dashboard);
        assert!(d.write_all(b"DisableRobot()").await.is_err());
        let d = session.divergence().unwrap();
        assert!(d.t_s.is_none() && d.expected.contains("end of the recording"), "{d}");
    }

    #[tokio::test(flavor = "current_thread")]
    async fn the_watchdog_reports_a_stall() {
        let session = ReplaySession::new(vec![ev(SocketId::Motion, Direction::ToController, 3.0, b"Sync()")], vec![]);
        session.clone().watchdog(Duration::from_millis(40)).await;
        let d = session.divergence().unwrap();
        assert!(d.expected.contains("Sync()") && d.got.contains("nothing happened"), "{d}");
        assert!(!d.got.contains("feedback frame"), "no feedback is recorded: {d}");
    }

    #[tokio::test(flavor = "current_thread")]
    async fn a_stall_before_recorded_feedback_names_where_the_feedback_is() {
        let session = ReplaySession::new(
            vec![
                ev(SocketId::Motion, Direction::ToController, 3.0, b"Sync()"),
                ev(SocketId::Feedback, Direction::FromController, 3.1, b"frame"),
            ],
            vec![],
        );
        session.clone().watchdog(Duration::from_millis(40)).await;
        let d = session.divergence().unwrap();
        assert!(d.expected.contains("Sync()") && d.got.contains("only after this step, at record 1"), "{d}");
    }
}
