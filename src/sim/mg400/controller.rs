//! The simulated MG400 controller without sockets: modes, alarms, the motion queue and
//! kinematic motion ([`Controller`], advanced by [`Controller::tick`] with the time passed
//! in), and one dashboard or motion connection's request stream ([`CommandSession`]: request
//! bytes in, answers out). The TCP server ([`super::server`]) moves bytes between sockets and
//! these.

use std::collections::VecDeque;

use crate::arm::dobot::alarms;
use crate::arm::dobot::proto::{
    DigitalOutput, ErrorId, FeedbackFrame, Port, RatioSetting, Reply, Request, RequestCall, RequestFramer, RobotMode, format_error_id_lists,
};
use crate::arm::kinematics::Joints;
use crate::arm::profile::{FirmwareProfile, ReachError, trapezoid_accel_fraction, trapezoid_fraction, trapezoid_time_s};
use crate::pose::Pose;

/// Number of lists in a GetErrorID reply (controller + servos), as in the [HX] fixture.
const ERROR_LISTS: usize = 6;

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
    /// `EnableRobot` requests received, accepted or not (a dry run must send none).
    pub enable_requests: u64,
    /// Motion requests received (MovJ, MovL, JointMovJ), accepted or not.
    pub motion_requests: u64,
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

    /// The same controller with its clock starting at `t_s` (the first [`Self::tick`] advances
    /// from there).
    pub fn starting_at(mut self, t_s: f64) -> Self {
        self.last_t_s = t_s;
        self
    }

    /// Moves that end halfway in a collision alarm (1-based, counted since start): the fault
    /// injection of [`super::SimFaults`].
    pub fn set_collisions(&mut self, at_move: Option<u64>, at_moves: Vec<u64>) {
        self.collision_at_move = at_move;
        self.collision_at_moves = at_moves;
    }

    /// The firmware profile it moves under.
    pub fn profile(&self) -> &FirmwareProfile {
        &self.profile
    }

    /// Tool speed over the last tick, mm/s.
    pub fn speed_mm_s(&self) -> f64 {
        self.speed_mm_s
    }

    /// Counters since start (`dashboard_connections` is the server's: 0 here).
    pub fn stats(&self) -> SimStats {
        self.stats
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
                self.stats.enable_requests += 1;
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
        self.stats.motion_requests += 1;
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

/// One dashboard or motion connection without the socket: the bytes that arrive go in
/// ([`Self::push`]), and each complete request comes out answered by the controller, in order
/// ([`Self::next`]).
#[derive(Debug)]
pub struct CommandSession {
    port: Port,
    framer: RequestFramer,
    requests: u64,
}

/// What the next request of a [`CommandSession`] came to.
#[derive(Debug, Clone, PartialEq)]
pub enum SessionStep {
    /// A request the controller answered.
    Answered(Answer),
    /// Bytes that do not frame a request: the reply the controller sends for them.
    Malformed(Reply),
    /// The request past the session's limit: it was not handed to the controller (the fault
    /// that closes a dashboard connection after n commands).
    LimitReached,
}

impl CommandSession {
    /// A session on `port` with nothing received yet.
    pub fn new(port: Port) -> Self {
        Self { port, framer: RequestFramer::new(), requests: 0 }
    }

    /// Bytes received on the connection.
    pub fn push(&mut self, bytes: &[u8]) {
        self.framer.push(bytes);
    }

    /// Requests handed to the controller so far.
    pub fn requests(&self) -> u64 {
        self.requests
    }

    /// Answers the next complete request with `controller`; `None` when more bytes are needed.
    /// With `max_requests = Some(n)` the request after the n-th is not handled
    /// ([`SessionStep::LimitReached`]).
    pub fn next(&mut self, controller: &mut Controller, max_requests: Option<u64>) -> Option<SessionStep> {
        let call = match self.framer.next_call() {
            Ok(Some(call)) => call,
            Ok(None) => return None,
            Err(e) => {
                tracing::debug!(error = %e, "simulated MG400: malformed request");
                return Some(SessionStep::Malformed(Reply::new(ErrorId::UnknownCommand, "", "")));
            }
        };
        self.requests += 1;
        if max_requests.is_some_and(|n| self.requests > n) {
            return Some(SessionStep::LimitReached);
        }
        Some(SessionStep::Answered(controller.handle(&call, self.port)))
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

    #[test]
    fn a_session_frames_bytes_into_answers() {
        let mut c = Controller::new(FirmwareProfile::default_mg400(), Pose::new(300.0, 0.0, 0.0, 0.0), 50).unwrap();
        let mut session = CommandSession::new(Port::Dashboard);
        assert_eq!(session.next(&mut c, None), None);
        // A request split across reads, then two in one.
        session.push(b"Enable");
        assert_eq!(session.next(&mut c, None), None);
        session.push(b"Robot()RobotMode()GetPose()");
        let text = |step: Option<SessionStep>| match step {
            Some(SessionStep::Answered(Answer::Reply(r))) => r.encode(),
            other => panic!("{other:?}"),
        };
        assert_eq!(text(session.next(&mut c, None)), "0,{},EnableRobot();");
        assert_eq!(text(session.next(&mut c, None)), "0,{5},RobotMode();");
        // The third request is past a limit of two: not handled.
        assert_eq!(session.next(&mut c, Some(2)), Some(SessionStep::LimitReached));
        assert_eq!(session.requests(), 3);
        session.push(b"()");
        assert!(matches!(session.next(&mut c, None), Some(SessionStep::Malformed(r)) if r.error_id == ErrorId::UnknownCommand));
    }
}
