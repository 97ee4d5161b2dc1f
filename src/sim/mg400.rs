//! A simulated MG400 controller that speaks the real protocol over TCP.
//!
//! [`SimMg400::start`] binds the three ports (dashboard, motion, feedback; port 0 picks a free
//! one) and runs:
//!
//! - a motion task that advances the [`Controller`] state machine every feedback period on
//!   the passed [`Clock`] (so `MonotonicClock::scaled(10.0)` runs ten times faster than real
//!   time) and publishes [`ArmTruth`] for the simulated sensors;
//! - per connection on the dashboard and motion ports: requests framed with
//!   [`RequestFramer`], answered `ErrorID,{values},Echo;` as the real controller does, `Sync()`
//!   held back until the motion queue has drained;
//! - per connection on the feedback port: a valid 1440-byte [`FeedbackFrame`] every 8 ms of
//!   simulated time.
//!
//! The controller starts DISABLED (mode 4). Moves run in queue order with trapezoidal
//! profiles scaled by SpeedFactor (MovJ in joint space, MovL in a straight line) and end
//! exactly on the commanded target. Mode is 7 while moving, 5 when idle, 9 with alarm ids for
//! unreachable targets, injected collisions and emergency stops. An alarm stops the arm,
//! empties the queue and stops the queue runner: further motion is refused (-1) until
//! ClearError, and queued motion waits for Continue. Pause holds the arm mid-move until
//! Continue. A collision or emergency stop also
//! disables the arm, so EnableRobot is needed again (as \[WS\] reports for the real arm).
//!
//! Fault injection ([`SimFaults`], changeable at run time with [`SimMg400::set_faults`]):
//! reply delays, replies split across writes, garbage in the feedback stream, feedback that
//! starts mid-frame, a collision at the k-th move, dashboard connections closed after n
//! commands; [`SimMg400::drop_connections`] closes every open connection of one port.

use std::collections::VecDeque;
use std::net::{IpAddr, Ipv4Addr, SocketAddr};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::watch;
use tokio::task::JoinHandle;

use crate::arm::dobot::alarms;
use crate::arm::dobot::client::Mg400Config;
use crate::arm::dobot::proto::{
    DigitalOutput, ErrorId, FeedbackFrame, Port, RatioSetting, Reply, Request, RequestCall, RequestFramer, RobotMode, format_error_id_lists,
};
use crate::arm::kinematics::Joints;
use crate::arm::profile::{FirmwareProfile, ReachError, trapezoid_accel_fraction, trapezoid_fraction, trapezoid_time_s};
use crate::clock::Clock;
use crate::pose::Pose;
use crate::sim::ArmTruth;

/// Feedback and motion step period in simulated time (the real controller's 30004 period).
pub const FEEDBACK_PERIOD: Duration = Duration::from_millis(8);
/// The shortest real-time period the simulator waits between steps, so a fast clock does not
/// turn the motion and feedback tasks into busy loops.
const MIN_REAL_PERIOD: Duration = Duration::from_millis(1);
/// Number of lists in a GetErrorID reply (controller + servos), as in the [HX] fixture.
const ERROR_LISTS: usize = 6;

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

/// Counters for tests and the `rig sim` status line.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SimStats {
    /// Moves that started executing.
    pub moves_started: u64,
    /// Motion commands accepted into the queue.
    pub motion_commands: u64,
    /// Most motion commands ever held at once (queued plus executing).
    pub max_queue_depth: usize,
    /// Whether the controller froze from an over-full queue.
    pub frozen: bool,
    /// Connections accepted on the dashboard port.
    pub dashboard_connections: u64,
}

/// A queued motion command.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Motion {
    Joint(Pose),
    Linear(Pose),
    Joints(Joints),
}

/// The move being executed.
#[derive(Debug, Clone, Copy)]
struct Segment {
    start_t_s: f64,
    duration_s: f64,
    accel_fraction: f64,
    linear: bool,
    from_joints: Joints,
    to_joints: Joints,
    from_pose: Pose,
    to_pose: Pose,
    collides: bool,
}

/// SpeedJ/AccJ/SpeedL/AccL ratios, % (defaults 100).
#[derive(Debug, Clone, Copy)]
struct Ratios {
    speed_j: i64,
    acc_j: i64,
    speed_l: i64,
    acc_l: i64,
}

/// The simulated controller: modes, alarms, queue and kinematic motion. Pure state, advanced
/// by [`Controller::tick`] with the time passed in.
#[derive(Debug)]
pub struct Controller {
    profile: FirmwareProfile,
    joints: Joints,
    pose: Pose,
    enabled: bool,
    alarms: Vec<i64>,
    queue_running: bool,
    paused: bool,
    speed_factor_pct: i64,
    ratios_pct: Ratios,
    user: i64,
    tool: i64,
    digital_outputs: u64,
    queue: VecDeque<Motion>,
    active: Option<Segment>,
    last_t_s: f64,
    speed_mm_s: f64,
    freeze_queue_depth: usize,
    stats: SimStats,
    collision_at_move: Option<u64>,
    collision_at_moves: Vec<u64>,
}

/// What a request asks of the connection handler.
#[derive(Debug, Clone, PartialEq)]
pub enum Answer {
    /// Send this reply now.
    Reply(Reply),
    /// Send `Reply` once the motion queue has drained (Sync).
    WhenIdle(Reply),
}

impl Controller {
    /// A controller at `start_pose`, disabled.
    pub fn new(profile: FirmwareProfile, start_pose: Pose, freeze_queue_depth: usize) -> Result<Self, ReachError> {
        let joints = profile.reach(&start_pose)?;
        Ok(Self {
            profile,
            joints,
            pose: start_pose,
            enabled: false,
            alarms: Vec::new(),
            queue_running: true,
            paused: false,
            speed_factor_pct: 100,
            ratios_pct: Ratios { speed_j: 100, acc_j: 100, speed_l: 100, acc_l: 100 },
            user: 0,
            tool: 0,
            digital_outputs: 0,
            queue: VecDeque::new(),
            active: None,
            last_t_s: 0.0,
            speed_mm_s: 0.0,
            freeze_queue_depth,
            stats: SimStats::default(),
            collision_at_move: None,
            collision_at_moves: Vec::new(),
        })
    }

    /// The robot mode now.
    pub fn mode(&self) -> RobotMode {
        if !self.alarms.is_empty() {
            RobotMode::Error
        } else if !self.enabled {
            RobotMode::Disabled
        } else if self.paused {
            RobotMode::Pause
        } else if self.active.is_some() {
            RobotMode::Running
        } else {
            RobotMode::Enabled
        }
    }

    /// The tool pose now.
    pub fn pose(&self) -> Pose {
        self.pose
    }

    /// Whether the queue has drained and nothing moves (what Sync waits for).
    pub fn idle(&self) -> bool {
        self.queue.is_empty() && self.active.is_none()
    }

    fn raise_alarm(&mut self, id: i64, disable: bool) {
        if !self.alarms.contains(&id) {
            self.alarms.push(id);
        }
        self.queue.clear();
        self.active = None;
        self.queue_running = false;
        self.speed_mm_s = 0.0;
        if disable {
            self.enabled = false;
        }
        tracing::info!(alarm = id, "simulated MG400 raised an alarm");
    }

    /// Answers one request arriving on `port`.
    pub fn handle(&mut self, call: &RequestCall, port: Port) -> Answer {
        let reply = |id: ErrorId, values: String| Answer::Reply(Reply::new(id, values, call.text.clone()));
        let ok = || reply(ErrorId::Accepted, String::new());
        let request = match Request::from_call(call) {
            Ok(r) => r,
            Err(id) => return reply(id, String::new()),
        };
        // Continue is accepted on both ports: Dobot's C++ SDK sends it on 30003.
        if request.port() != port && request != Request::Continue {
            return reply(ErrorId::UnknownCommand, String::new());
        }
        match request {
            Request::EnableRobot { load_kg, centre_mm } => {
                if load_kg.is_some_and(|l| !(0.0..=0.75).contains(&l)) {
                    return reply(ErrorId::ParameterRange { index: 1 }, String::new());
                }
                if let Some(c) = centre_mm
                    && let Some(i) = c.iter().position(|v| !(-500.0..=500.0).contains(v))
                {
                    return reply(ErrorId::ParameterRange { index: i as u32 + 2 }, String::new());
                }
                if !self.alarms.is_empty() {
                    return reply(ErrorId::Failed, String::new());
                }
                self.enabled = true;
                ok()
            }
            Request::DisableRobot => {
                self.enabled = false;
                self.stop_motion();
                ok()
            }
            Request::ClearError => {
                self.alarms.clear();
                ok()
            }
            Request::ResetRobot => {
                self.stop_motion();
                ok()
            }
            Request::EmergencyStop => {
                self.raise_alarm(alarms::EMERGENCY_STOP, true);
                ok()
            }
            Request::Pause => {
                self.paused = true;
                ok()
            }
            Request::Continue => {
                self.paused = false;
                self.queue_running = true;
                ok()
            }
            Request::SpeedFactor { percent } => {
                if !(1..=100).contains(&percent) {
                    return reply(ErrorId::ParameterRange { index: 1 }, String::new());
                }
                self.speed_factor_pct = percent;
                ok()
            }
            Request::User { index } | Request::Tool { index } => {
                if !(0..=9).contains(&index) {
                    return reply(ErrorId::ParameterRange { index: 1 }, String::new());
                }
                // Only index 0 (the base frame / bare flange) is calibrated on the simulator.
                if index != 0 {
                    return reply(ErrorId::Failed, String::new());
                }
                if call.name.eq_ignore_ascii_case("user") {
                    self.user = index;
                } else {
                    self.tool = index;
                }
                ok()
            }
            Request::RobotMode => reply(ErrorId::Accepted, self.mode().code().to_string()),
            Request::GetPose => {
                let p = self.pose;
                reply(ErrorId::Accepted, format!("{:.6},{:.6},{:.6},{:.6}", p.x_mm, p.y_mm, p.z_mm, p.yaw_deg))
            }
            Request::GetAngle => {
                let j = self.joints;
                reply(ErrorId::Accepted, format!("{:.6},{:.6},{:.6},{:.6}", j.j1_deg, j.j2_deg, j.j3_deg, j.j4_deg))
            }
            Request::GetErrorId => {
                let mut lists = vec![Vec::new(); ERROR_LISTS];
                lists[0] = self.alarms.clone();
                reply(ErrorId::Accepted, format_error_id_lists(&lists))
            }
            Request::Di { index } => {
                if !(1..=16).contains(&index) {
                    return reply(ErrorId::ParameterRange { index: 1 }, String::new());
                }
                reply(ErrorId::Accepted, "0".into())
            }
            Request::Do { output, index, on } => {
                let tool = matches!(output, DigitalOutput::ToolQueued | DigitalOutput::ToolImmediate);
                // 16 controller outputs; the arm carries two tool outputs (fact sheet section 2).
                let count = if tool { 2 } else { 16 };
                if !(1..=count).contains(&index) {
                    return reply(ErrorId::ParameterRange { index: 1 }, String::new());
                }
                if !tool {
                    let bit = 1u64 << (index - 1);
                    if on {
                        self.digital_outputs |= bit;
                    } else {
                        self.digital_outputs &= !bit;
                    }
                }
                ok()
            }
            Request::Ratio { setting, percent } => {
                let min = if setting == RatioSetting::Cp { 0 } else { 1 };
                if !(min..=100).contains(&percent) {
                    return reply(ErrorId::ParameterRange { index: 1 }, String::new());
                }
                match setting {
                    RatioSetting::AccJ => self.ratios_pct.acc_j = percent,
                    RatioSetting::AccL => self.ratios_pct.acc_l = percent,
                    RatioSetting::SpeedJ => self.ratios_pct.speed_j = percent,
                    RatioSetting::SpeedL => self.ratios_pct.speed_l = percent,
                    // Blending is not simulated: every move comes to rest on its target.
                    RatioSetting::Cp => {}
                }
                ok()
            }
            Request::SetCollisionLevel { level } => {
                if !(0..=5).contains(&level) {
                    return reply(ErrorId::ParameterRange { index: 1 }, String::new());
                }
                ok()
            }
            Request::MovJ { target } => self.enqueue(Motion::Joint(target), call),
            Request::MovL { target } => self.enqueue(Motion::Linear(target), call),
            Request::JointMovJ { joints_deg } => self.enqueue(Motion::Joints(Joints::from_array(joints_deg)), call),
            Request::Sync => Answer::WhenIdle(Reply::new(ErrorId::Accepted, String::new(), call.text.clone())),
        }
    }

    fn enqueue(&mut self, motion: Motion, call: &RequestCall) -> Answer {
        if !self.alarms.is_empty() || !self.enabled {
            return Answer::Reply(Reply::new(ErrorId::Failed, String::new(), call.text.clone()));
        }
        self.queue.push_back(motion);
        self.stats.motion_commands += 1;
        let depth = self.queue.len() + usize::from(self.active.is_some());
        self.stats.max_queue_depth = self.stats.max_queue_depth.max(depth);
        if depth > self.freeze_queue_depth && !self.stats.frozen {
            tracing::warn!(depth, "simulated MG400 froze: too many queued commands");
            self.stats.frozen = true;
        }
        Answer::Reply(Reply::new(ErrorId::Accepted, String::new(), call.text.clone()))
    }

    fn stop_motion(&mut self) {
        self.queue.clear();
        self.active = None;
        self.speed_mm_s = 0.0;
        // Clearing the queue also thaws a frozen controller (what a reset does on the real one).
        self.stats.frozen = false;
    }

    /// Advances motion to `now_s`.
    pub fn tick(&mut self, now_s: f64) {
        let before = self.pose;
        let dt = now_s - self.last_t_s;
        if self.paused {
            // Pause holds the arm where it is: the move in progress resumes on Continue from
            // the same point of its profile.
            if let Some(seg) = self.active.as_mut() {
                seg.start_t_s += dt;
            }
            self.speed_mm_s = 0.0;
            self.last_t_s = now_s;
            return;
        }
        let mut chain_from = now_s;
        // Each pass either finishes a segment or leaves it running; bounded by the queue.
        for _ in 0..=self.queue.len() + 1 {
            if let Some(seg) = self.active {
                let tau = if seg.duration_s > 0.0 { (now_s - seg.start_t_s) / seg.duration_s } else { 1.0 };
                if seg.collides && tau >= 0.5 {
                    self.place(&seg, 0.5);
                    self.raise_alarm(alarms::COLLISION, true);
                    break;
                }
                if tau >= 1.0 {
                    self.joints = seg.to_joints;
                    self.pose = seg.to_pose;
                    self.active = None;
                    chain_from = seg.start_t_s + seg.duration_s;
                } else {
                    self.place(&seg, tau);
                    break;
                }
            }
            if !self.start_next(chain_from.min(now_s)) {
                break;
            }
        }
        self.speed_mm_s = if dt > 0.0 { self.pose.distance_mm(&before) / dt } else { 0.0 };
        self.last_t_s = now_s;
    }

    /// Puts the arm at fraction `tau` of the segment's time.
    fn place(&mut self, seg: &Segment, tau: f64) {
        let s = trapezoid_fraction(tau, seg.accel_fraction);
        if seg.linear {
            let (a, b) = (seg.from_pose, seg.to_pose);
            let pose = Pose::new(
                a.x_mm + (b.x_mm - a.x_mm) * s,
                a.y_mm + (b.y_mm - a.y_mm) * s,
                a.z_mm + (b.z_mm - a.z_mm) * s,
                a.yaw_deg + (b.yaw_deg - a.yaw_deg) * s,
            );
            match self.profile.kinematics.inverse(&pose) {
                Ok(j) => {
                    self.joints = j;
                    self.pose = pose;
                }
                Err(_) => self.raise_alarm(33, false),
            }
        } else {
            let (a, b) = (seg.from_joints.to_array(), seg.to_joints.to_array());
            self.joints = Joints::from_array(std::array::from_fn(|i| a[i] + (b[i] - a[i]) * s));
            self.pose = self.profile.kinematics.forward(&self.joints);
        }
    }

    /// Starts the next queued move at `t_s`; false when nothing was started.
    fn start_next(&mut self, t_s: f64) -> bool {
        if self.active.is_some() || !self.enabled || !self.alarms.is_empty() || !self.queue_running || self.paused || self.stats.frozen {
            return false;
        }
        let Some(motion) = self.queue.pop_front() else { return false };
        self.stats.moves_started += 1;
        let collides =
            self.collision_at_move == Some(self.stats.moves_started) || self.collision_at_moves.contains(&self.stats.moves_started);
        let linear = matches!(motion, Motion::Linear(_));
        let target = match motion {
            Motion::Joint(p) | Motion::Linear(p) => self.profile.reach(&p).map(|j| (j, p)),
            Motion::Joints(j) => self.profile.check_joints(&j).map(|()| (j, self.profile.kinematics.forward(&j))),
        };
        let (to_joints, to_pose) = match target {
            Ok(t) => t,
            Err(e) => {
                let id = match e {
                    ReachError::Kinematics(_) => alarms::IK_NO_SOLUTION,
                    ReachError::Height { .. } | ReachError::Radius { .. } if linear => 23,
                    ReachError::Height { .. } | ReachError::Radius { .. } => 34,
                    _ => alarms::JOINT_LIMIT,
                };
                tracing::info!(error = %e, "simulated MG400: target out of reach");
                self.raise_alarm(id, false);
                return false;
            }
        };
        // Effective speed = global SpeedFactor x the per-kind ratio ([G4]).
        let sf = self.speed_factor_pct as f64 / 100.0;
        let r = self.ratios_pct;
        let sp = &self.profile.speed;
        let (duration_s, accel_fraction) = if linear {
            let (v, a) = (sf * r.speed_l as f64 / 100.0, sf * r.acc_l as f64 / 100.0);
            let d = self.pose.distance_mm(&to_pose);
            let yaw = (to_pose.yaw_deg - self.pose.yaw_deg).abs();
            let t_lin = trapezoid_time_s(d, sp.linear_speed_mm_s * v, sp.linear_acc_mm_s2 * a);
            let t_yaw = trapezoid_time_s(yaw, sp.yaw_speed_deg_s * v, sp.yaw_acc_deg_s2 * a);
            if t_lin >= t_yaw {
                (t_lin, trapezoid_accel_fraction(d, sp.linear_speed_mm_s * v, sp.linear_acc_mm_s2 * a))
            } else {
                (t_yaw, trapezoid_accel_fraction(yaw, sp.yaw_speed_deg_s * v, sp.yaw_acc_deg_s2 * a))
            }
        } else {
            let (v, acc_ratio) = (sf * r.speed_j as f64 / 100.0, sf * r.acc_j as f64 / 100.0);
            let (a, b) = (self.joints.to_array(), to_joints.to_array());
            let mut slowest = (0.0, 0.5);
            for i in 0..4 {
                let (d, v, acc) = ((b[i] - a[i]).abs(), sp.joint_speed_deg_s[i] * v, sp.joint_acc_deg_s2[i] * acc_ratio);
                let t = trapezoid_time_s(d, v, acc);
                if t > slowest.0 {
                    slowest = (t, trapezoid_accel_fraction(d, v, acc));
                }
            }
            slowest
        };
        self.active = Some(Segment {
            start_t_s: t_s,
            duration_s,
            accel_fraction,
            linear,
            from_joints: self.joints,
            to_joints,
            from_pose: self.pose,
            to_pose,
            collides,
        });
        true
    }

    /// The feedback frame describing the controller now.
    pub fn feedback_frame(&self, timestamp_ms: u64) -> FeedbackFrame {
        let six = |a: [f64; 4]| [a[0], a[1], a[2], a[3], 0.0, 0.0];
        let pose = |p: Pose| six([p.x_mm, p.y_mm, p.z_mm, p.yaw_deg]);
        let (q_target, tool_target) = match self.active {
            Some(seg) => (six(seg.to_joints.to_array()), pose(seg.to_pose)),
            None => (six(self.joints.to_array()), pose(self.pose)),
        };
        FeedbackFrame {
            digital_inputs: 0,
            digital_outputs: self.digital_outputs,
            robot_mode: self.mode().code(),
            timestamp_ms,
            speed_scaling: self.speed_factor_pct as f64 / 100.0,
            q_target_deg: q_target,
            q_actual_deg: six(self.joints.to_array()),
            qd_actual_deg_s: [0.0; 6],
            tool_vector_actual: pose(self.pose),
            tcp_speed_actual: [self.speed_mm_s, 0.0, 0.0, 0.0, 0.0, 0.0],
            tool_vector_target: tool_target,
            user: self.user as i8,
            tool: self.tool as i8,
            run_queued_cmd: self.queue_running,
            pause_cmd_flag: self.paused,
            // All four brakes released while enabled (bits 5..2).
            brake_status: if self.enabled { 0b0011_1100 } else { 0 },
            enable_status: self.enabled,
            drag_status: false,
            running_status: self.active.is_some(),
            error_status: !self.alarms.is_empty(),
            jog_status: false,
            robot_type: 1,
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
        let mut controller = Controller::new(cfg.profile.clone(), start_pose, cfg.freeze_queue_depth).map_err(unreachable)?;
        controller.collision_at_move = cfg.faults.collision_at_move;
        controller.collision_at_moves = cfg.faults.collision_at_moves.clone();
        controller.last_t_s = clock.now_s();
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

    /// Client settings for this simulator: its address and ports, the profile it runs.
    pub fn client_config(&self) -> Mg400Config {
        let profile = self.shared.controller().profile.clone();
        Mg400Config::new(self.dashboard_addr.ip().to_string(), profile).with_ports(
            self.dashboard_addr.port(),
            self.motion_addr.port(),
            self.feedback_addr.port(),
        )
    }

    /// The arm's true state, published at every motion step (`t_s` on the simulator's clock).
    pub fn truth(&self) -> watch::Receiver<ArmTruth> {
        self.shared.truth_tx.subscribe()
    }

    /// Replaces the fault-injection switches; takes effect on the next request, frame or move.
    pub fn set_faults(&self, faults: SimFaults) {
        {
            let mut controller = self.shared.controller();
            controller.collision_at_move = faults.collision_at_move;
            controller.collision_at_moves = faults.collision_at_moves.clone();
        }
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
        let mut s = self.shared.controller().stats;
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
        shared.truth_tx.send_replace(ArmTruth { t_s: now_s, pose: c.pose, speed_mm_s: c.speed_mm_s });
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
    let mut framer = RequestFramer::new();
    let mut buf = [0u8; 2048];
    let mut commands = 0u64;
    loop {
        loop {
            let call = match framer.next_call() {
                Ok(Some(call)) => call,
                Ok(None) => break,
                Err(e) => {
                    tracing::debug!(error = %e, "simulated MG400: malformed request");
                    let reply = Reply::new(ErrorId::UnknownCommand, "", "");
                    if stream.write_all(reply.encode().as_bytes()).await.is_err() {
                        return;
                    }
                    continue;
                }
            };
            commands += 1;
            let faults = shared.faults();
            if port == Port::Dashboard && faults.drop_dashboard_after.is_some_and(|n| commands > n) {
                tracing::info!("simulated MG400: dropping the dashboard connection (fault injection)");
                return;
            }
            let answer = shared.controller().handle(&call, port);
            let reply = match answer {
                Answer::Reply(r) => r,
                Answer::WhenIdle(r) => {
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
                Ok(n) => framer.push(&buf[..n]),
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

#[cfg(test)]
mod tests {
    use super::*;

    fn call(text: &str) -> RequestCall {
        RequestCall::parse(text).unwrap()
    }

    fn reply(c: &mut Controller, text: &str, port: Port) -> Reply {
        match c.handle(&call(text), port) {
            Answer::Reply(r) | Answer::WhenIdle(r) => r,
        }
    }

    #[test]
    fn starts_disabled_and_moves_to_exact_target() {
        let mut c = Controller::new(FirmwareProfile::default_mg400(), Pose::new(300.0, 0.0, 0.0, 0.0), 50).unwrap();
        assert_eq!(c.mode(), RobotMode::Disabled);
        assert_eq!(reply(&mut c, "MovJ(310,5,-10,3)", Port::Motion).error_id, ErrorId::Failed);
        assert_eq!(reply(&mut c, "EnableRobot()", Port::Dashboard).error_id, ErrorId::Accepted);
        assert_eq!(reply(&mut c, "MovJ(310,5,-10,3)", Port::Dashboard).error_id, ErrorId::UnknownCommand);
        assert_eq!(reply(&mut c, "MovJ(310,5,-10,3)", Port::Motion).error_id, ErrorId::Accepted);
        assert!(matches!(c.handle(&call("Sync()"), Port::Motion), Answer::WhenIdle(_)));
        c.tick(0.01);
        assert_eq!(c.mode(), RobotMode::Running);
        assert!(!c.idle());
        let mut t = 0.01;
        while !c.idle() && t < 10.0 {
            t += 0.008;
            c.tick(t);
        }
        assert_eq!(c.mode(), RobotMode::Enabled);
        assert_eq!(c.pose(), Pose::new(310.0, 5.0, -10.0, 3.0));
        assert_eq!(reply(&mut c, "RobotMode()", Port::Dashboard).values, "5");
    }

    #[test]
    fn unreachable_target_alarms_until_cleared() {
        let mut c = Controller::new(FirmwareProfile::default_mg400(), Pose::new(300.0, 0.0, 0.0, 0.0), 50).unwrap();
        reply(&mut c, "EnableRobot()", Port::Dashboard);
        reply(&mut c, "MovJ(600,0,0,0)", Port::Motion);
        c.tick(0.01);
        assert_eq!(c.mode(), RobotMode::Error);
        assert!(c.idle());
        let errs = reply(&mut c, "GetErrorID()", Port::Dashboard).error_id_lists().unwrap();
        assert_eq!(errs[0], vec![34]);
        assert_eq!(reply(&mut c, "MovJ(310,0,0,0)", Port::Motion).error_id, ErrorId::Failed);
        reply(&mut c, "ClearError()", Port::Dashboard);
        assert_eq!(c.mode(), RobotMode::Enabled);
        // Queued but held until Continue.
        assert_eq!(reply(&mut c, "MovJ(310,0,0,0)", Port::Motion).error_id, ErrorId::Accepted);
        c.tick(0.02);
        assert!(!c.idle() && c.mode() == RobotMode::Enabled);
        reply(&mut c, "Continue()", Port::Dashboard);
        c.tick(0.03);
        assert_eq!(c.mode(), RobotMode::Running);
    }

    #[test]
    fn speed_ratios_slow_moves_down() {
        let duration = |setup: &[&str], motion: &str| {
            let mut c = Controller::new(FirmwareProfile::default_mg400(), Pose::new(300.0, 0.0, 0.0, 0.0), 50).unwrap();
            reply(&mut c, "EnableRobot()", Port::Dashboard);
            for cmd in setup {
                assert_eq!(reply(&mut c, cmd, Port::Dashboard).error_id, ErrorId::Accepted, "{cmd}");
            }
            reply(&mut c, motion, Port::Motion);
            c.tick(0.001);
            c.active.map(|seg| seg.duration_s).unwrap_or(0.0)
        };
        let full = duration(&[], "MovJ(250,80,-30,20)");
        assert!(full > 0.0);
        assert!(duration(&["SpeedJ(10)"], "MovJ(250,80,-30,20)") > full);
        assert!(duration(&["SpeedFactor(20)"], "MovJ(250,80,-30,20)") > full);
        // SpeedJ affects joint moves only.
        let linear = duration(&[], "MovL(250,80,-30,20)");
        assert_eq!(duration(&["SpeedJ(10)", "AccJ(10)"], "MovL(250,80,-30,20)"), linear);
        assert!(duration(&["SpeedL(10)", "AccL(10)"], "MovL(250,80,-30,20)") > linear);
    }

    #[test]
    fn pause_holds_the_arm_and_continue_resumes() {
        let mut c = Controller::new(FirmwareProfile::default_mg400(), Pose::new(300.0, 0.0, 0.0, 0.0), 50).unwrap();
        reply(&mut c, "EnableRobot()", Port::Dashboard);
        reply(&mut c, "MovL(260,0,0,0)", Port::Motion);
        c.tick(0.0);
        c.tick(0.02);
        reply(&mut c, "Pause()", Port::Dashboard);
        assert_eq!(c.mode(), RobotMode::Pause);
        let held = c.pose();
        c.tick(5.0);
        assert_eq!(c.pose(), held);
        reply(&mut c, "Continue()", Port::Dashboard);
        c.tick(5.01);
        assert!(c.pose().x_mm < held.x_mm, "moves on after Continue");
        let mut t = 5.01;
        while !c.idle() && t < 20.0 {
            t += 0.008;
            c.tick(t);
        }
        assert_eq!(c.pose(), Pose::new(260.0, 0.0, 0.0, 0.0));
    }

    #[test]
    fn parameter_errors() {
        let mut c = Controller::new(FirmwareProfile::default_mg400(), Pose::new(300.0, 0.0, 0.0, 0.0), 50).unwrap();
        assert_eq!(reply(&mut c, "SpeedFactor(0)", Port::Dashboard).error_id, ErrorId::ParameterRange { index: 1 });
        assert_eq!(reply(&mut c, "SpeedFactor(a)", Port::Dashboard).error_id, ErrorId::ParameterType { index: 1 });
        assert_eq!(reply(&mut c, "Fly()", Port::Dashboard).error_id, ErrorId::UnknownCommand);
        assert_eq!(reply(&mut c, "User(3)", Port::Dashboard).error_id, ErrorId::Failed);
        assert_eq!(reply(&mut c, "ToolDO(3,1)", Port::Dashboard).error_id, ErrorId::ParameterRange { index: 1 });
        assert_eq!(reply(&mut c, "ToolDO(2,1)", Port::Dashboard).error_id, ErrorId::Accepted);
        assert_eq!(reply(&mut c, "CP(0)", Port::Dashboard).error_id, ErrorId::Accepted);
        assert_eq!(reply(&mut c, "AccJ(0)", Port::Dashboard).error_id, ErrorId::ParameterRange { index: 1 });
        assert_eq!(reply(&mut c, "SetCollisionLevel(6)", Port::Dashboard).error_id, ErrorId::ParameterRange { index: 1 });
        assert_eq!(reply(&mut c, "EnableRobot(1,2)", Port::Dashboard).error_id, ErrorId::WrongParameterCount);
        assert_eq!(reply(&mut c, "getpose()", Port::Dashboard).values, "300.000000,0.000000,0.000000,0.000000");
    }
}
