//! The simulated MG400's TCP server: the three ports, a motion task that ticks the
//! [`Controller`] on the passed [`Clock`] and publishes [`ArmTruth`], the connection handlers
//! (each a [`CommandSession`] over a socket, or a feedback stream), and fault injection.

use std::net::{IpAddr, Ipv4Addr, SocketAddr};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::watch;
use tokio::task::JoinHandle;

use super::FEEDBACK_PERIOD;
use super::controller::{Answer, CommandSession, Controller, SessionStep, SimStats};
use crate::arm::dobot::proto::{Port, RobotMode};
use crate::arm::kinematics::Joints;
use crate::arm::profile::{FirmwareProfile, ReachError};
use crate::clock::Clock;
use crate::pose::Pose;
use crate::sim::ArmTruth;

/// The shortest real-time period the simulator waits between steps, so a fast clock does not
/// turn the motion and feedback tasks into busy loops.
const MIN_REAL_PERIOD: Duration = Duration::from_millis(1);

/// Fault-injection switches.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SimFaults {
    /// Real time to wait before sending each dashboard/motion reply.
    pub reply_delay: Duration,
    /// Send each reply in two writes (the split falls inside the reply).
    pub split_replies: bool,
    /// Precede every n-th feedback frame with garbage bytes (n ≥ 1).
    pub feedback_garbage_every: Option<u32>,
    /// Begin each new feedback connection with the tail of a frame.
    pub feedback_start_mid_frame: bool,
    /// The k-th move executed (1-based, counted since start) ends halfway in a collision alarm.
    pub collision_at_move: Option<u64>,
    /// More moves (1-based, counted since start) that end halfway in a collision alarm, so a
    /// fault matrix can place alarms at several (seeded random) moves of one run.
    pub collision_at_moves: Vec<u64>,
    /// Close each dashboard connection, unanswered, when it delivers command n + 1.
    pub drop_dashboard_after: Option<u64>,
}

/// Which port of the simulator.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SimPort {
    Dashboard,
    Motion,
    Feedback,
}

/// Configuration of a simulated MG400.
#[derive(Debug, Clone)]
pub struct SimMg400Config {
    pub bind: IpAddr,
    /// 0 = any free port.
    pub dashboard_port: u16,
    pub motion_port: u16,
    pub feedback_port: u16,
    /// Base-frame pose the arm starts at; must be reachable under `profile`.
    pub start_pose: Pose,
    /// Joint angles the arm starts at; when set, they replace `start_pose`.
    pub start_joints: Option<Joints>,
    pub profile: FirmwareProfile,
    pub faults: SimFaults,
    /// Queue depth past which the controller freezes (the real one freezes past about 50).
    pub freeze_queue_depth: usize,
}

impl Default for SimMg400Config {
    fn default() -> Self {
        Self {
            bind: IpAddr::V4(Ipv4Addr::LOCALHOST),
            dashboard_port: 0,
            motion_port: 0,
            feedback_port: 0,
            start_pose: Pose::new(300.0, 0.0, 0.0, 0.0),
            start_joints: None,
            profile: FirmwareProfile::default_mg400(),
            faults: SimFaults::default(),
            freeze_queue_depth: 50,
        }
    }
}

impl SimMg400Config {
    /// Ports from one base, as `rig sim --port-base N` documents them: dashboard on `base`,
    /// motion on `base + 3`, feedback on `base + 4`.
    pub fn with_port_base(mut self, base: u16) -> Result<Self, std::io::Error> {
        let motion = base.checked_add(3);
        let feedback = base.checked_add(4);
        match (motion, feedback) {
            (Some(m), Some(f)) => {
                self.dashboard_port = base;
                self.motion_port = m;
                self.feedback_port = f;
                Ok(self)
            }
            _ => Err(std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                format!("port base {base} leaves no room for the motion and feedback ports"),
            )),
        }
    }
}

/// State shared by the simulator's tasks.
struct Shared {
    controller: Mutex<Controller>,
    faults: Mutex<SimFaults>,
    clock: Arc<dyn Clock>,
    truth_tx: watch::Sender<ArmTruth>,
    /// Bumped to close every open connection of a port (dashboard, motion, feedback).
    drop_tx: [watch::Sender<u64>; 3],
    shutdown_tx: watch::Sender<bool>,
    epoch_unix_ms: u64,
    stats_connections: Mutex<u64>,
    /// Connections open now, per port.
    open: [AtomicUsize; 3],
}

/// Counts a connection as open for as long as its handler runs.
struct OpenGuard<'a>(&'a AtomicUsize);

impl<'a> OpenGuard<'a> {
    fn new(counter: &'a AtomicUsize) -> Self {
        counter.fetch_add(1, Ordering::SeqCst);
        Self(counter)
    }
}

impl Drop for OpenGuard<'_> {
    fn drop(&mut self) {
        self.0.fetch_sub(1, Ordering::SeqCst);
    }
}

impl Shared {
    fn controller(&self) -> MutexGuard<'_, Controller> {
        // A panic while holding the lock would be a simulator bug; keep serving regardless.
        self.controller.lock().unwrap_or_else(|e| e.into_inner())
    }
    fn faults(&self) -> SimFaults {
        self.faults.lock().unwrap_or_else(|e| e.into_inner()).clone()
    }
    fn period_real(&self) -> Duration {
        self.clock.real_duration(FEEDBACK_PERIOD).max(MIN_REAL_PERIOD)
    }
    fn timestamp_ms(&self) -> u64 {
        self.epoch_unix_ms + (self.clock.now_s().max(0.0) * 1000.0) as u64
    }
}

fn port_index(p: SimPort) -> usize {
    match p {
        SimPort::Dashboard => 0,
        SimPort::Motion => 1,
        SimPort::Feedback => 2,
    }
}

/// A running simulated MG400. Dropping it stops its tasks.
pub struct SimMg400 {
    shared: Arc<Shared>,
    dashboard_addr: SocketAddr,
    motion_addr: SocketAddr,
    feedback_addr: SocketAddr,
    tasks: Vec<JoinHandle<()>>,
}

impl SimMg400 {
    /// Binds the ports and starts serving.
    pub async fn start(cfg: SimMg400Config, clock: Arc<dyn Clock>) -> Result<SimMg400, std::io::Error> {
        let unreachable =
            |e: ReachError| std::io::Error::new(std::io::ErrorKind::InvalidInput, format!("simulated MG400 start is unreachable: {e}"));
        let start_pose = match cfg.start_joints {
            Some(j) => {
                cfg.profile.check_joints(&j).map_err(unreachable)?;
                cfg.profile.kinematics.forward(&j)
            }
            None => cfg.start_pose,
        };
        let mut controller =
            Controller::new(cfg.profile.clone(), start_pose, cfg.freeze_queue_depth).map_err(unreachable)?.starting_at(clock.now_s());
        controller.set_collisions(cfg.faults.collision_at_move, cfg.faults.collision_at_moves.clone());
        let dashboard = TcpListener::bind((cfg.bind, cfg.dashboard_port)).await?;
        let motion = TcpListener::bind((cfg.bind, cfg.motion_port)).await?;
        let feedback = TcpListener::bind((cfg.bind, cfg.feedback_port)).await?;
        let truth = ArmTruth { t_s: clock.now_s(), pose: start_pose, speed_mm_s: 0.0 };
        let epoch_unix_ms = SystemTime::now().duration_since(UNIX_EPOCH).map(|d| d.as_millis() as u64).unwrap_or(0);
        let shared = Arc::new(Shared {
            controller: Mutex::new(controller),
            faults: Mutex::new(cfg.faults.clone()),
            clock,
            truth_tx: watch::Sender::new(truth),
            drop_tx: std::array::from_fn(|_| watch::Sender::new(0)),
            shutdown_tx: watch::Sender::new(false),
            epoch_unix_ms,
            stats_connections: Mutex::new(0),
            open: std::array::from_fn(|_| AtomicUsize::new(0)),
        });
        let sim = SimMg400 {
            dashboard_addr: dashboard.local_addr()?,
            motion_addr: motion.local_addr()?,
            feedback_addr: feedback.local_addr()?,
            tasks: vec![
                tokio::spawn(motion_task(shared.clone())),
                tokio::spawn(accept_loop(shared.clone(), dashboard, SimPort::Dashboard)),
                tokio::spawn(accept_loop(shared.clone(), motion, SimPort::Motion)),
                tokio::spawn(accept_loop(shared.clone(), feedback, SimPort::Feedback)),
            ],
            shared,
        };
        Ok(sim)
    }

    pub fn dashboard_addr(&self) -> SocketAddr {
        self.dashboard_addr
    }
    pub fn motion_addr(&self) -> SocketAddr {
        self.motion_addr
    }
    pub fn feedback_addr(&self) -> SocketAddr {
        self.feedback_addr
    }

    /// The firmware profile the simulated controller runs (the one a client should check
    /// against).
    pub fn profile(&self) -> FirmwareProfile {
        self.shared.controller().profile().clone()
    }

    /// The arm's true state, published at every motion step (`t_s` on the simulator's clock).
    pub fn truth(&self) -> watch::Receiver<ArmTruth> {
        self.shared.truth_tx.subscribe()
    }

    /// Replaces the fault-injection switches; takes effect on the next request, frame or move.
    pub fn set_faults(&self, faults: SimFaults) {
        self.shared.controller().set_collisions(faults.collision_at_move, faults.collision_at_moves.clone());
        *self.shared.faults.lock().unwrap_or_else(|e| e.into_inner()) = faults;
    }

    /// The fault-injection switches in force.
    pub fn faults(&self) -> SimFaults {
        self.shared.faults()
    }

    /// Closes every open connection of `port` (new connections are still accepted).
    pub fn drop_connections(&self, port: SimPort) {
        self.shared.drop_tx[port_index(port)].send_modify(|g| *g += 1);
    }

    /// A handle that does [`drop_connections`](Self::drop_connections) from another task
    /// while the simulator itself is owned elsewhere (the rig's socket-dropping fault).
    pub fn connection_dropper(&self) -> ConnectionDropper {
        ConnectionDropper(Arc::clone(&self.shared))
    }

    /// The robot mode now.
    pub fn mode(&self) -> RobotMode {
        self.shared.controller().mode()
    }

    /// The tool pose now.
    pub fn pose(&self) -> Pose {
        self.shared.controller().pose()
    }

    /// Connections open now on `port`.
    pub fn open_connections(&self, port: SimPort) -> usize {
        self.shared.open[port_index(port)].load(Ordering::SeqCst)
    }

    /// Counters since start.
    pub fn stats(&self) -> SimStats {
        let mut s = self.shared.controller().stats();
        s.dashboard_connections = *self.shared.stats_connections.lock().unwrap_or_else(|e| e.into_inner());
        s
    }

    /// Stops serving and closes every connection.
    pub async fn shutdown(mut self) {
        self.shared.shutdown_tx.send_replace(true);
        for t in self.tasks.drain(..) {
            t.abort();
            let _ = t.await;
        }
    }
}

/// Closes the simulator's connections on request; see [`SimMg400::connection_dropper`].
pub struct ConnectionDropper(Arc<Shared>);

impl ConnectionDropper {
    /// Closes every open connection of `port` (new connections are still accepted).
    pub fn drop_connections(&self, port: SimPort) {
        self.0.drop_tx[port_index(port)].send_modify(|g| *g += 1);
    }
}

impl Drop for SimMg400 {
    fn drop(&mut self) {
        self.shared.shutdown_tx.send_replace(true);
        for t in &self.tasks {
            t.abort();
        }
    }
}

async fn motion_task(shared: Arc<Shared>) {
    let mut shutdown = shared.shutdown_tx.subscribe();
    loop {
        tokio::select! {
            _ = tokio::time::sleep(shared.period_real()) => {}
            _ = shutdown.changed() => return,
        }
        let now_s = shared.clock.now_s();
        let mut c = shared.controller();
        c.tick(now_s);
        // Published under the lock, so no feedback frame or reply can show a state the truth
        // does not yet hold.
        shared.truth_tx.send_replace(ArmTruth { t_s: now_s, pose: c.pose(), speed_mm_s: c.speed_mm_s() });
        drop(c);
    }
}

async fn accept_loop(shared: Arc<Shared>, listener: TcpListener, port: SimPort) {
    let mut shutdown = shared.shutdown_tx.subscribe();
    loop {
        let accepted = tokio::select! {
            a = listener.accept() => a,
            _ = shutdown.changed() => return,
        };
        let stream = match accepted {
            Ok((stream, _)) => stream,
            Err(e) => {
                tracing::warn!(error = %e, ?port, "simulated MG400: accept failed");
                tokio::time::sleep(Duration::from_millis(10)).await;
                continue;
            }
        };
        let _ = stream.set_nodelay(true);
        let shared = shared.clone();
        match port {
            SimPort::Dashboard => {
                *shared.stats_connections.lock().unwrap_or_else(|e| e.into_inner()) += 1;
                tokio::spawn(serve_commands(shared, stream, Port::Dashboard));
            }
            SimPort::Motion => {
                tokio::spawn(serve_commands(shared, stream, Port::Motion));
            }
            SimPort::Feedback => {
                tokio::spawn(serve_feedback(shared, stream));
            }
        }
    }
}

/// Serves one dashboard or motion connection until it closes, is dropped, or the sim stops.
async fn serve_commands(shared: Arc<Shared>, mut stream: TcpStream, port: Port) {
    let sim_port = if port == Port::Dashboard { SimPort::Dashboard } else { SimPort::Motion };
    let _open = OpenGuard::new(&shared.open[port_index(sim_port)]);
    let mut drop_rx = shared.drop_tx[port_index(sim_port)].subscribe();
    let mut shutdown = shared.shutdown_tx.subscribe();
    let mut session = CommandSession::new(port);
    let mut buf = [0u8; 2048];
    loop {
        loop {
            let faults = shared.faults();
            let limit = if port == Port::Dashboard { faults.drop_dashboard_after } else { None };
            let step = session.next(&mut shared.controller(), limit);
            let reply = match step {
                None => break,
                Some(SessionStep::Malformed(reply)) => {
                    if stream.write_all(reply.encode().as_bytes()).await.is_err() {
                        return;
                    }
                    continue;
                }
                Some(SessionStep::LimitReached) => {
                    tracing::info!("simulated MG400: dropping the dashboard connection (fault injection)");
                    return;
                }
                Some(SessionStep::Answered(Answer::Reply(r))) => r,
                Some(SessionStep::Answered(Answer::WhenIdle(r))) => {
                    loop {
                        if shared.controller().idle() {
                            break;
                        }
                        tokio::select! {
                            _ = tokio::time::sleep(shared.period_real()) => {}
                            _ = drop_rx.changed() => return,
                            _ = shutdown.changed() => return,
                        }
                    }
                    r
                }
            };
            if !faults.reply_delay.is_zero() {
                tokio::time::sleep(faults.reply_delay).await;
            }
            let bytes = reply.encode().into_bytes();
            let written = if faults.split_replies && bytes.len() > 1 {
                let mid = bytes.len() / 2;
                let first = stream.write_all(&bytes[..mid]).await;
                let _ = stream.flush().await;
                tokio::time::sleep(Duration::from_millis(2)).await;
                first.and(stream.write_all(&bytes[mid..]).await)
            } else {
                stream.write_all(&bytes).await
            };
            if written.is_err() {
                return;
            }
        }
        tokio::select! {
            n = stream.read(&mut buf) => match n {
                Ok(0) | Err(_) => return,
                Ok(n) => session.push(&buf[..n]),
            },
            _ = drop_rx.changed() => return,
            _ = shutdown.changed() => return,
        }
    }
}

/// Streams feedback frames on one connection.
async fn serve_feedback(shared: Arc<Shared>, mut stream: TcpStream) {
    let _open = OpenGuard::new(&shared.open[port_index(SimPort::Feedback)]);
    let mut drop_rx = shared.drop_tx[port_index(SimPort::Feedback)].subscribe();
    let mut shutdown = shared.shutdown_tx.subscribe();
    let mut sent = 0u64;
    // Garbage that starts like a frame (size field) so it exercises the resync scan.
    const GARBAGE: [u8; 21] = [0xA0, 0x05, 0, 0, 0x13, 0x37, 0xEF, 0xCD, 0xAB, 0x89, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11];
    loop {
        let faults = shared.faults();
        let frame = shared.controller().feedback_frame(shared.timestamp_ms()).encode();
        let mut out = Vec::with_capacity(frame.len() * 2);
        if sent == 0 && faults.feedback_start_mid_frame {
            out.extend_from_slice(&frame[frame.len() / 2..]);
        }
        if let Some(n) = faults.feedback_garbage_every
            && n > 0
            && sent % u64::from(n) == u64::from(n) - 1
        {
            out.extend_from_slice(&GARBAGE);
        }
        out.extend_from_slice(&frame);
        if stream.write_all(&out).await.is_err() {
            return;
        }
        sent += 1;
        tokio::select! {
            _ = tokio::time::sleep(shared.period_real()) => {}
            _ = drop_rx.changed() => return,
            _ = shutdown.changed() => return,
        }
    }
}
