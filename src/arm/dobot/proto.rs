//! MG400 wire format, sans-io: no sockets, no clock reads.
//!
//! Three pieces, each working on byte slices and owned buffers only:
//!
//! - Requests ([`Request`]): typed dashboard and motion commands, encoded as the ASCII text
//!   `Name(arg1,arg2,...)` (fact sheet section 2). The simulator goes the other way with
//!   [`RequestFramer`] (frames on the closing parenthesis) and [`Request::from_call`].
//! - Replies ([`Reply`]): `ErrorID,{values},Echo(args);`. [`ReplyFramer`] frames them on `;`
//!   across arbitrary read boundaries (one read may hold half a reply or several replies) and
//!   parses them; [`ErrorId`] types the error classes (-1, -10000, -20000, -3000N, -4000N).
//! - Feedback ([`FeedbackFrame`]): the 1440-byte little-endian frame pushed on 30004.
//!   [`FeedbackDecoder`] gathers stream bytes and resynchronises after garbage or a start
//!   mid-frame by scanning for the size field and the test value.
//!
//! Every decoder returns `Ok(None)` (or `None`) for a partial frame and never panics on any
//! input; the fuzz targets in `fuzz/` and the property tests below hold it to that.

use std::fmt;

use crate::pose::Pose;

/// Size of one feedback frame, bytes (fact sheet section 4).
pub const FEEDBACK_FRAME_LEN: usize = 1440;
/// The constant every valid feedback frame carries at byte 48.
pub const FEEDBACK_TEST_VALUE: u64 = 0x0123_4567_89AB_CDEF;
/// A reply longer than this without a `;` is treated as garbage: a real reply (even a
/// pretty-printed GetErrorID with every list full) stays far below it.
pub const MAX_REPLY_LEN: usize = 64 * 1024;
/// A request longer than this without a closing parenthesis is dropped by [`RequestFramer`].
pub const MAX_REQUEST_LEN: usize = 4 * 1024;

/// Errors of the codec. Each keeps the offending text (cut to a readable length).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ProtoError {
    #[error("reply {text:?} does not follow `ErrorID,{{values}},Echo;`: {problem}")]
    MalformedReply { text: String, problem: &'static str },
    #[error("{len} bytes arrived without a `;` ending a reply")]
    ReplyTooLong { len: usize },
    #[error("value list {{{text}}} is not {expected}")]
    BadValues { text: String, expected: &'static str },
    #[error("request {text:?} is not `Name(args)`: {problem}")]
    MalformedRequest { text: String, problem: &'static str },
    #[error("feedback frame has {got} bytes, expected {FEEDBACK_FRAME_LEN}")]
    FrameSize { got: usize },
    #[error("feedback frame size field reads {message_size}, expected {FEEDBACK_FRAME_LEN}")]
    FrameLengthField { message_size: u16 },
    #[error("feedback frame test value is {found:#018x}, expected {FEEDBACK_TEST_VALUE:#018x}")]
    FrameTestValue { found: u64 },
}

/// Cuts text kept in an error to a readable length (on a char boundary).
fn excerpt(text: &str) -> String {
    const MAX: usize = 120;
    if text.len() <= MAX {
        return text.to_string();
    }
    let mut end = MAX;
    while !text.is_char_boundary(end) {
        end -= 1;
    }
    format!("{}...", &text[..end])
}

// ---------------------------------------------------------------------------------------------
// Error ids
// ---------------------------------------------------------------------------------------------

/// The ErrorID field of a reply (fact sheet section 2, error code table).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ErrorId {
    /// 0: accepted.
    Accepted,
    /// -1: could not obtain or execute (also: not in TCP mode, uncalibrated User/Tool index).
    Failed,
    /// -10000: unknown command.
    UnknownCommand,
    /// -20000: wrong number of parameters.
    WrongParameterCount,
    /// -3000N: parameter N (1-based) has the wrong type.
    ParameterType { index: u32 },
    /// -4000N: parameter N (1-based) is out of range.
    ParameterRange { index: u32 },
    /// Any other code (V4 controllers add -2..-5 and more).
    Other(i64),
}

impl ErrorId {
    /// Classifies a numeric code.
    pub fn from_code(code: i64) -> Self {
        match code {
            0 => ErrorId::Accepted,
            -1 => ErrorId::Failed,
            -10000 => ErrorId::UnknownCommand,
            -20000 => ErrorId::WrongParameterCount,
            -39999..=-30001 => ErrorId::ParameterType { index: (-code - 30000) as u32 },
            -49999..=-40001 => ErrorId::ParameterRange { index: (-code - 40000) as u32 },
            other => ErrorId::Other(other),
        }
    }

    /// The numeric code on the wire.
    pub fn code(&self) -> i64 {
        match *self {
            ErrorId::Accepted => 0,
            ErrorId::Failed => -1,
            ErrorId::UnknownCommand => -10000,
            ErrorId::WrongParameterCount => -20000,
            ErrorId::ParameterType { index } => -30000 - i64::from(index),
            ErrorId::ParameterRange { index } => -40000 - i64::from(index),
            ErrorId::Other(code) => code,
        }
    }

    /// What the code means, for error messages.
    pub fn meaning(&self) -> String {
        match *self {
            ErrorId::Accepted => "accepted".into(),
            ErrorId::Failed => "could not execute (robot in alarm, not enabled, not in TCP mode, or bad index)".into(),
            ErrorId::UnknownCommand => "unknown command".into(),
            ErrorId::WrongParameterCount => "wrong number of parameters".into(),
            ErrorId::ParameterType { index } => format!("parameter {index} has the wrong type"),
            ErrorId::ParameterRange { index } => format!("parameter {index} is out of range"),
            ErrorId::Other(code) => format!("undocumented error code {code}"),
        }
    }
}

impl fmt::Display for ErrorId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.code())
    }
}

// ---------------------------------------------------------------------------------------------
// Requests
// ---------------------------------------------------------------------------------------------

/// Which TCP port a command belongs to (fact sheet section 2, command table).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Port {
    /// 29999: settings, queries, I/O.
    Dashboard,
    /// 30003: queued motion and Sync.
    Motion,
}

/// A command rig sends (and the simulator understands).
///
/// Numbers are written with Rust's shortest round-trip formatting, so what the controller
/// parses is exactly the `f64` rig holds.
#[derive(Debug, Clone, PartialEq)]
pub enum Request {
    /// `EnableRobot()`, `EnableRobot(load)` or `EnableRobot(load,cx,cy,cz)`.
    EnableRobot {
        load_kg: Option<f64>,
        centre_mm: Option<[f64; 3]>,
    },
    DisableRobot,
    ClearError,
    /// Stops the arm and empties the motion queue.
    ResetRobot,
    EmergencyStop,
    Pause,
    Continue,
    /// Global speed, 1..=100 %.
    SpeedFactor {
        percent: i64,
    },
    User {
        index: i64,
    },
    Tool {
        index: i64,
    },
    RobotMode,
    GetPose,
    GetAngle,
    GetErrorId,
    /// `DI(index)`: read a digital input.
    Di {
        index: i64,
    },
    /// `DO(index,status)` and its relatives: set a digital output.
    Do {
        output: DigitalOutput,
        index: i64,
        on: bool,
    },
    /// `SpeedJ(r)`, `AccL(r)`, ...: per-motion-kind speed and acceleration ratios, %.
    Ratio {
        setting: RatioSetting,
        percent: i64,
    },
    /// `SetCollisionLevel(level)`: 0 = off .. 5 = most sensitive.
    SetCollisionLevel {
        level: i64,
    },
    /// `MovJ(x,y,z,r)`: joint-interpolated move to a base-frame pose.
    MovJ {
        target: Pose,
    },
    /// `MovL(x,y,z,r)`: straight-line move to a base-frame pose.
    MovL {
        target: Pose,
    },
    /// `JointMovJ(j1,j2,j3,j4)`: joint move to joint angles, degrees.
    JointMovJ {
        joints_deg: [f64; 4],
    },
    /// Blocks until the motion queue has drained.
    Sync,
}

/// The digital-output commands (fact sheet section 2): queued or immediate, controller
/// outputs or the two tool outputs on the arm.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DigitalOutput {
    /// `DO`: controller output, queued.
    Queued,
    /// `DOExecute`: controller output, immediate.
    Immediate,
    /// `ToolDO`: arm-mounted output, queued.
    ToolQueued,
    /// `ToolDOExecute`: arm-mounted output, immediate.
    ToolImmediate,
}

impl DigitalOutput {
    fn name(&self) -> &'static str {
        match self {
            DigitalOutput::Queued => "DO",
            DigitalOutput::Immediate => "DOExecute",
            DigitalOutput::ToolQueued => "ToolDO",
            DigitalOutput::ToolImmediate => "ToolDOExecute",
        }
    }
}

/// The ratio setters (1..=100 %; CP takes 0..=100).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RatioSetting {
    /// Joint moves (MovJ, JointMovJ): acceleration.
    AccJ,
    /// Linear moves (MovL): acceleration.
    AccL,
    /// Joint moves: speed.
    SpeedJ,
    /// Linear moves: speed.
    SpeedL,
    /// Continuous-path blending ratio.
    Cp,
}

impl RatioSetting {
    fn name(&self) -> &'static str {
        match self {
            RatioSetting::AccJ => "AccJ",
            RatioSetting::AccL => "AccL",
            RatioSetting::SpeedJ => "SpeedJ",
            RatioSetting::SpeedL => "SpeedL",
            RatioSetting::Cp => "CP",
        }
    }
}

impl Request {
    /// The command name as written on the wire.
    pub fn name(&self) -> &'static str {
        match self {
            Request::EnableRobot { .. } => "EnableRobot",
            Request::DisableRobot => "DisableRobot",
            Request::ClearError => "ClearError",
            Request::ResetRobot => "ResetRobot",
            Request::EmergencyStop => "EmergencyStop",
            Request::Pause => "Pause",
            Request::Continue => "Continue",
            Request::SpeedFactor { .. } => "SpeedFactor",
            Request::User { .. } => "User",
            Request::Tool { .. } => "Tool",
            Request::RobotMode => "RobotMode",
            Request::GetPose => "GetPose",
            Request::GetAngle => "GetAngle",
            Request::GetErrorId => "GetErrorID",
            Request::Di { .. } => "DI",
            Request::Do { output, .. } => output.name(),
            Request::Ratio { setting, .. } => setting.name(),
            Request::SetCollisionLevel { .. } => "SetCollisionLevel",
            Request::MovJ { .. } => "MovJ",
            Request::MovL { .. } => "MovL",
            Request::JointMovJ { .. } => "JointMovJ",
            Request::Sync => "Sync",
        }
    }

    /// The port this command is sent on.
    pub fn port(&self) -> Port {
        match self {
            Request::MovJ { .. } | Request::MovL { .. } | Request::JointMovJ { .. } | Request::Sync => Port::Motion,
            _ => Port::Dashboard,
        }
    }

    /// Whether the command goes through the motion queue.
    pub fn is_queued_motion(&self) -> bool {
        matches!(self, Request::MovJ { .. } | Request::MovL { .. } | Request::JointMovJ { .. })
    }

    /// The command text, e.g. `MovL(300,0,-20,15)`. No terminator: the closing parenthesis
    /// ends a request.
    pub fn encode(&self) -> String {
        let args: Vec<String> = match self {
            Request::EnableRobot { load_kg, centre_mm } => {
                let mut a = Vec::new();
                if let Some(load) = load_kg {
                    a.push(num(*load));
                    if let Some(c) = centre_mm {
                        a.extend(c.iter().map(|v| num(*v)));
                    }
                }
                a
            }
            Request::SpeedFactor { percent } => vec![percent.to_string()],
            Request::User { index } | Request::Tool { index } | Request::Di { index } => {
                vec![index.to_string()]
            }
            Request::Ratio { percent, .. } => vec![percent.to_string()],
            Request::SetCollisionLevel { level } => vec![level.to_string()],
            Request::Do { index, on, .. } => vec![index.to_string(), u8::from(*on).to_string()],
            Request::MovJ { target } | Request::MovL { target } => {
                vec![num(target.x_mm), num(target.y_mm), num(target.z_mm), num(target.yaw_deg)]
            }
            Request::JointMovJ { joints_deg } => joints_deg.iter().map(|v| num(*v)).collect(),
            _ => Vec::new(),
        };
        format!("{}({})", self.name(), args.join(","))
    }

    /// Interprets a framed call the way the controller does. The error is the ErrorID the
    /// controller would answer with (unknown command, wrong count, wrong type).
    pub fn from_call(call: &RequestCall) -> Result<Request, ErrorId> {
        let name = call.name.to_ascii_lowercase();
        // Optional `Key=value` arguments (SpeedL=, User=, ...) follow the positional ones; the
        // simulated controller accepts and ignores them.
        let positional: Vec<&str> = call.args.iter().map(String::as_str).filter(|a| !a.contains('=')).collect();
        let count = |allowed: &[usize]| {
            if allowed.contains(&positional.len()) { Ok(()) } else { Err(ErrorId::WrongParameterCount) }
        };
        let float = |i: usize| -> Result<f64, ErrorId> {
            positional[i].trim().parse::<f64>().ok().filter(|v| v.is_finite()).ok_or(ErrorId::ParameterType { index: i as u32 + 1 })
        };
        let int = |i: usize| -> Result<i64, ErrorId> {
            positional[i].trim().parse::<i64>().map_err(|_| ErrorId::ParameterType { index: i as u32 + 1 })
        };
        let pose = || -> Result<Pose, ErrorId> { Ok(Pose::new(float(0)?, float(1)?, float(2)?, float(3)?)) };
        Ok(match name.as_str() {
            "enablerobot" => {
                count(&[0, 1, 4])?;
                match positional.len() {
                    0 => Request::EnableRobot { load_kg: None, centre_mm: None },
                    1 => Request::EnableRobot { load_kg: Some(float(0)?), centre_mm: None },
                    _ => Request::EnableRobot { load_kg: Some(float(0)?), centre_mm: Some([float(1)?, float(2)?, float(3)?]) },
                }
            }
            "disablerobot" => count(&[0]).map(|_| Request::DisableRobot)?,
            "clearerror" => count(&[0]).map(|_| Request::ClearError)?,
            "resetrobot" => count(&[0]).map(|_| Request::ResetRobot)?,
            "emergencystop" => count(&[0]).map(|_| Request::EmergencyStop)?,
            "pause" => count(&[0]).map(|_| Request::Pause)?,
            "continue" => count(&[0]).map(|_| Request::Continue)?,
            "robotmode" => count(&[0]).map(|_| Request::RobotMode)?,
            "getpose" => Request::GetPose,
            "getangle" => count(&[0]).map(|_| Request::GetAngle)?,
            "geterrorid" => count(&[0]).map(|_| Request::GetErrorId)?,
            "sync" => count(&[0]).map(|_| Request::Sync)?,
            "speedfactor" => {
                count(&[1])?;
                Request::SpeedFactor { percent: int(0)? }
            }
            "user" => {
                count(&[1])?;
                Request::User { index: int(0)? }
            }
            "tool" => {
                count(&[1])?;
                Request::Tool { index: int(0)? }
            }
            "di" => {
                count(&[1])?;
                Request::Di { index: int(0)? }
            }
            "do" | "doexecute" | "tooldo" | "tooldoexecute" => {
                count(&[2])?;
                let index = int(0)?;
                let on = match int(1)? {
                    0 => false,
                    1 => true,
                    _ => return Err(ErrorId::ParameterRange { index: 2 }),
                };
                let output = match name.as_str() {
                    "do" => DigitalOutput::Queued,
                    "doexecute" => DigitalOutput::Immediate,
                    "tooldo" => DigitalOutput::ToolQueued,
                    _ => DigitalOutput::ToolImmediate,
                };
                Request::Do { output, index, on }
            }
            "accj" | "accl" | "speedj" | "speedl" | "cp" => {
                count(&[1])?;
                let setting = match name.as_str() {
                    "accj" => RatioSetting::AccJ,
                    "accl" => RatioSetting::AccL,
                    "speedj" => RatioSetting::SpeedJ,
                    "speedl" => RatioSetting::SpeedL,
                    _ => RatioSetting::Cp,
                };
                Request::Ratio { setting, percent: int(0)? }
            }
            "setcollisionlevel" => {
                count(&[1])?;
                Request::SetCollisionLevel { level: int(0)? }
            }
            "movj" => {
                count(&[4])?;
                Request::MovJ { target: pose()? }
            }
            "movl" => {
                count(&[4])?;
                Request::MovL { target: pose()? }
            }
            "jointmovj" => {
                count(&[4])?;
                Request::JointMovJ { joints_deg: [float(0)?, float(1)?, float(2)?, float(3)?] }
            }
            _ => return Err(ErrorId::UnknownCommand),
        })
    }
}

/// Formats a number the way rig sends it: shortest text that parses back to the same `f64`
/// (Rust's `Display` for `f64` never uses exponent notation).
fn num(v: f64) -> String {
    format!("{v}")
}

/// One request as delivered: the name, the raw comma-separated arguments, and the text the
/// controller echoes back.
#[derive(Debug, Clone, PartialEq)]
pub struct RequestCall {
    pub name: String,
    pub args: Vec<String>,
    /// The request text without surrounding whitespace, echoed in the reply.
    pub text: String,
}

impl RequestCall {
    /// Parses `Name(arg,...)`. Commas inside `{...}` do not split arguments.
    pub fn parse(text: &str) -> Result<RequestCall, ProtoError> {
        let text = text.trim();
        let bad = |problem| ProtoError::MalformedRequest { text: excerpt(text), problem };
        let open = text.find('(').ok_or_else(|| bad("no opening parenthesis"))?;
        if !text.ends_with(')') {
            return Err(bad("no closing parenthesis"));
        }
        let name = text[..open].trim();
        if name.is_empty() || !name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') {
            return Err(bad("the command name is not a plain word"));
        }
        let inner = &text[open + 1..text.len() - 1];
        let args = split_top_level(inner).into_iter().map(|a| a.trim().to_string()).collect();
        Ok(RequestCall { name: name.to_string(), args, text: text.to_string() })
    }
}

/// Splits on commas outside braces; an empty input has no arguments.
fn split_top_level(inner: &str) -> Vec<&str> {
    if inner.trim().is_empty() {
        return Vec::new();
    }
    let mut parts = Vec::new();
    let mut depth = 0i32;
    let mut start = 0;
    for (i, c) in inner.char_indices() {
        match c {
            '{' | '[' => depth += 1,
            '}' | ']' => depth -= 1,
            ',' if depth == 0 => {
                parts.push(&inner[start..i]);
                start = i + 1;
            }
            _ => {}
        }
    }
    parts.push(&inner[start..]);
    parts
}

/// Frames requests out of a byte stream (simulator side). A request ends at its closing
/// parenthesis; whitespace, newlines and stray `;` between requests are skipped, so
/// `printf 'EnableRobot()' | nc` and line-oriented clients both work.
#[derive(Debug, Default)]
pub struct RequestFramer {
    buf: Vec<u8>,
}

impl RequestFramer {
    pub fn new() -> Self {
        Self::default()
    }

    /// Appends received bytes.
    pub fn push(&mut self, bytes: &[u8]) {
        self.buf.extend_from_slice(bytes);
    }

    /// The next complete request, `Ok(None)` when more bytes are needed. A malformed request
    /// is consumed and returned as an error; framing continues after it.
    pub fn next_call(&mut self) -> Result<Option<RequestCall>, ProtoError> {
        let skip = self.buf.iter().position(|b| !(b.is_ascii_whitespace() || *b == b';' || *b == 0)).unwrap_or(self.buf.len());
        self.buf.drain(..skip);
        let Some(end) = self.buf.iter().position(|b| *b == b')') else {
            if self.buf.len() > MAX_REQUEST_LEN {
                let len = self.buf.len();
                self.buf.clear();
                return Err(ProtoError::MalformedRequest {
                    text: format!("<{len} bytes>"),
                    problem: "too long without a closing parenthesis",
                });
            }
            return Ok(None);
        };
        let raw: Vec<u8> = self.buf.drain(..=end).collect();
        let text = String::from_utf8_lossy(&raw);
        RequestCall::parse(&text).map(Some)
    }
}

// ---------------------------------------------------------------------------------------------
// Replies
// ---------------------------------------------------------------------------------------------

/// One reply: `ErrorID,{values},Echo;`.
#[derive(Debug, Clone, PartialEq)]
pub struct Reply {
    pub error_id: ErrorId,
    /// The text between the outer braces, verbatim (may hold newlines and tabs).
    pub values: String,
    /// The echoed command, e.g. `MovL(300,0,-20,0)`.
    pub echo: String,
}

impl Reply {
    /// Builds a reply echoing `echo`.
    pub fn new(error_id: ErrorId, values: impl Into<String>, echo: impl Into<String>) -> Self {
        Self { error_id, values: values.into(), echo: echo.into() }
    }

    /// The wire text, `;` included.
    pub fn encode(&self) -> String {
        format!("{},{{{}}},{};", self.error_id.code(), self.values, self.echo)
    }

    /// Parses one reply; a trailing `;` and surrounding whitespace are allowed.
    pub fn parse(text: &str) -> Result<Reply, ProtoError> {
        let text = text.trim();
        let text = text.strip_suffix(';').unwrap_or(text).trim_end();
        let bad = |problem| ProtoError::MalformedReply { text: excerpt(text), problem };
        let comma = text.find(',').ok_or_else(|| bad("no comma after the ErrorID"))?;
        let code: i64 = text[..comma].trim().parse().map_err(|_| bad("the ErrorID is not an integer"))?;
        let rest = text[comma + 1..].trim_start();
        if !rest.starts_with('{') {
            return Err(bad("no `{` opening the values"));
        }
        // The value list may nest braces and brackets (GetErrorID); find its matching `}`.
        let mut depth = 0i32;
        let mut close = None;
        for (i, c) in rest.char_indices() {
            match c {
                '{' => depth += 1,
                '}' => {
                    depth -= 1;
                    if depth == 0 {
                        close = Some(i);
                        break;
                    }
                }
                _ => {}
            }
        }
        let close = close.ok_or_else(|| bad("the values have no closing `}`"))?;
        let values = &rest[1..close];
        let after = rest[close + 1..].trim_start();
        let echo = after.strip_prefix(',').ok_or_else(|| bad("no comma before the echo"))?.trim();
        Ok(Reply { error_id: ErrorId::from_code(code), values: values.to_string(), echo: echo.to_string() })
    }

    /// The name of the echoed command (`MovL` for `MovL(1,2,3,4)`).
    pub fn echo_name(&self) -> &str {
        self.echo.split('(').next().unwrap_or("").trim()
    }

    /// The values as numbers (`{}` gives an empty list).
    pub fn numbers(&self) -> Result<Vec<f64>, ProtoError> {
        parse_numbers(&self.values)
    }

    /// The values as a pose: `{x,y,z,r}` or the 6-value form `{x,y,z,r,0,0}`.
    pub fn pose(&self) -> Result<Pose, ProtoError> {
        let v = self.four_of_four_or_six("4 or 6 numbers (x,y,z,r[,0,0])")?;
        Ok(Pose::new(v[0], v[1], v[2], v[3]))
    }

    /// The values as joint angles in degrees: `{j1,j2,j3,j4}` or the 6-value form.
    pub fn joints_deg(&self) -> Result<[f64; 4], ProtoError> {
        self.four_of_four_or_six("4 or 6 numbers (j1..j4[,0,0])")
    }

    fn four_of_four_or_six(&self, expected: &'static str) -> Result<[f64; 4], ProtoError> {
        let v = self.numbers()?;
        if v.len() != 4 && v.len() != 6 {
            return Err(ProtoError::BadValues { text: excerpt(&self.values), expected });
        }
        Ok([v[0], v[1], v[2], v[3]])
    }

    /// A single integer value, e.g. the mode in `0,{5},RobotMode();`.
    pub fn integer(&self) -> Result<i64, ProtoError> {
        let bad = || ProtoError::BadValues { text: excerpt(&self.values), expected: "one integer" };
        let v = self.numbers()?;
        match v.as_slice() {
            [x] if x.fract() == 0.0 && x.abs() < 9.0e15 => Ok(*x as i64),
            _ => Err(bad()),
        }
    }

    /// The GetErrorID payload: list 0 holds controller alarms, the rest per-servo alarms.
    pub fn error_id_lists(&self) -> Result<Vec<Vec<i64>>, ProtoError> {
        parse_error_id_lists(&self.values)
    }
}

/// Parses a comma-separated list of finite numbers (whitespace allowed).
pub fn parse_numbers(values: &str) -> Result<Vec<f64>, ProtoError> {
    if values.trim().is_empty() {
        return Ok(Vec::new());
    }
    values
        .split(',')
        .map(|s| s.trim().parse::<f64>().ok().filter(|v| v.is_finite()))
        .collect::<Option<Vec<f64>>>()
        .ok_or_else(|| ProtoError::BadValues { text: excerpt(values), expected: "a list of numbers" })
}

/// Parses the GetErrorID value `[[ids],[ids],...]`, pretty-printed or not. Any number of inner
/// lists is accepted (6 and 7 both occur in the wild).
pub fn parse_error_id_lists(values: &str) -> Result<Vec<Vec<i64>>, ProtoError> {
    let compact: String = values.chars().filter(|c| !c.is_whitespace()).collect();
    let bad = || ProtoError::BadValues { text: excerpt(values), expected: "[[ids],[ids],...]" };
    let inner = compact.strip_prefix('[').and_then(|s| s.strip_suffix(']')).ok_or_else(bad)?;
    let mut lists = Vec::new();
    let mut rest = inner;
    while !rest.is_empty() {
        let body_start = rest.strip_prefix('[').ok_or_else(bad)?;
        let close = body_start.find(']').ok_or_else(bad)?;
        let body = &body_start[..close];
        let ids = if body.is_empty() {
            Vec::new()
        } else {
            body.split(',').map(|s| s.parse::<i64>().ok()).collect::<Option<Vec<i64>>>().ok_or_else(bad)?
        };
        lists.push(ids);
        rest = &body_start[close + 1..];
        if let Some(r) = rest.strip_prefix(',') {
            if r.is_empty() {
                return Err(bad());
            }
            rest = r;
        } else if !rest.is_empty() {
            return Err(bad());
        }
    }
    Ok(lists)
}

/// Formats GetErrorID lists the way the controller pretty-prints them (newlines and tabs).
pub fn format_error_id_lists(lists: &[Vec<i64>]) -> String {
    let mut s = String::from("[\n");
    for (i, list) in lists.iter().enumerate() {
        if list.is_empty() {
            s.push_str("\t[]");
        } else {
            s.push_str("\t[\n");
            let ids: Vec<String> = list.iter().map(|id| format!("\t\t{id}")).collect();
            s.push_str(&ids.join(",\n"));
            s.push_str("\n\t]");
        }
        if i + 1 < lists.len() {
            s.push(',');
        }
        s.push('\n');
    }
    s.push(']');
    s
}

/// Frames replies on `;` across arbitrary read boundaries (client side).
#[derive(Debug, Default)]
pub struct ReplyFramer {
    buf: Vec<u8>,
}

impl ReplyFramer {
    pub fn new() -> Self {
        Self::default()
    }

    /// Appends received bytes.
    pub fn push(&mut self, bytes: &[u8]) {
        self.buf.extend_from_slice(bytes);
    }

    /// Bytes held that do not yet form a reply.
    pub fn pending_len(&self) -> usize {
        self.buf.len()
    }

    /// Drops everything buffered (after a reconnect).
    pub fn clear(&mut self) {
        self.buf.clear();
    }

    /// The next complete reply, `Ok(None)` when more bytes are needed. A malformed reply is
    /// consumed and returned as an error; framing continues after it.
    pub fn next_reply(&mut self) -> Result<Option<Reply>, ProtoError> {
        let Some(end) = self.buf.iter().position(|b| *b == b';') else {
            if self.buf.len() > MAX_REPLY_LEN {
                let len = self.buf.len();
                self.buf.clear();
                return Err(ProtoError::ReplyTooLong { len });
            }
            return Ok(None);
        };
        let raw: Vec<u8> = self.buf.drain(..=end).collect();
        let text = String::from_utf8_lossy(&raw);
        Reply::parse(&text).map(Some)
    }
}

// ---------------------------------------------------------------------------------------------
// Feedback frame
// ---------------------------------------------------------------------------------------------

/// Robot modes reported by RobotMode() and the feedback frame (fact sheet section 3).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RobotMode {
    Init,
    BrakeOpen,
    PowerOff,
    Disabled,
    Enabled,
    Backdrive,
    Running,
    Recording,
    Error,
    Pause,
    Jog,
    /// A value outside the documented 1..=11.
    Unknown(u64),
}

impl RobotMode {
    pub fn from_code(code: u64) -> Self {
        match code {
            1 => RobotMode::Init,
            2 => RobotMode::BrakeOpen,
            3 => RobotMode::PowerOff,
            4 => RobotMode::Disabled,
            5 => RobotMode::Enabled,
            6 => RobotMode::Backdrive,
            7 => RobotMode::Running,
            8 => RobotMode::Recording,
            9 => RobotMode::Error,
            10 => RobotMode::Pause,
            11 => RobotMode::Jog,
            other => RobotMode::Unknown(other),
        }
    }

    pub fn code(&self) -> u64 {
        match *self {
            RobotMode::Init => 1,
            RobotMode::BrakeOpen => 2,
            RobotMode::PowerOff => 3,
            RobotMode::Disabled => 4,
            RobotMode::Enabled => 5,
            RobotMode::Backdrive => 6,
            RobotMode::Running => 7,
            RobotMode::Recording => 8,
            RobotMode::Error => 9,
            RobotMode::Pause => 10,
            RobotMode::Jog => 11,
            RobotMode::Unknown(c) => c,
        }
    }
}

/// The fields rig uses from one real-time feedback frame. Fields not listed are ignored on
/// decode and written as zero on encode.
///
/// Layout (fact sheet section 4; little-endian, packed; 6-element arrays carry MG400 data in
/// `[0..4]`):
///
/// | byte | type   | field                          | unit / meaning                      |
/// |------|--------|--------------------------------|-------------------------------------|
/// | 0    | u16    | MessageSize                    | must be 1440                        |
/// | 8    | u64    | DigitalInputs                  | bit k = DI(k+1)                     |
/// | 16   | u64    | DigitalOutputs                 | bit k = DO(k+1)                     |
/// | 24   | u64    | RobotMode                      | [`RobotMode`] code                  |
/// | 32   | u64    | TimeStamp                      | ms (Unix ms on the real controller) |
/// | 48   | u64    | TestValue                      | must be 0x0123456789ABCDEF          |
/// | 64   | f64    | SpeedScaling                   | fraction, 1.0 = 100 %               |
/// | 192  | f64×6  | QTarget                        | deg                                 |
/// | 432  | f64×6  | QActual                        | deg                                 |
/// | 480  | f64×6  | QDActual                       | deg/s                               |
/// | 624  | f64×6  | ToolVectorActual               | x,y,z mm, r deg                     |
/// | 672  | f64×6  | TCPSpeedActual                 | mm/s, deg/s                         |
/// | 768  | f64×6  | ToolVectorTarget               | x,y,z mm, r deg                     |
/// | 1012 | i8     | User                           | active user frame index             |
/// | 1013 | i8     | Tool                           | active tool index                   |
/// | 1014 | i8     | RunQueuedCmd                   | 1 = motion queue running            |
/// | 1015 | i8     | PauseCmdFlag                   | 1 = queue paused                    |
/// | 1025 | u8     | BrakeStatus                    | bit5 J1 .. bit2 J4                  |
/// | 1026 | i8     | EnableStatus                   | 1 = enabled                         |
/// | 1027 | i8     | DragStatus                     |                                     |
/// | 1028 | i8     | RunningStatus                  | 1 = moving                          |
/// | 1029 | i8     | ErrorStatus                    | 1 = alarm active                    |
/// | 1030 | i8     | JogStatus                      |                                     |
/// | 1031 | i8     | RobotType                      | 1 = MG400                           |
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct FeedbackFrame {
    pub digital_inputs: u64,
    pub digital_outputs: u64,
    /// Raw RobotMode code; see [`FeedbackFrame::mode`].
    pub robot_mode: u64,
    pub timestamp_ms: u64,
    pub speed_scaling: f64,
    pub q_target_deg: [f64; 6],
    pub q_actual_deg: [f64; 6],
    pub qd_actual_deg_s: [f64; 6],
    /// x, y, z (mm), r (deg), 0, 0.
    pub tool_vector_actual: [f64; 6],
    pub tcp_speed_actual: [f64; 6],
    pub tool_vector_target: [f64; 6],
    pub user: i8,
    pub tool: i8,
    pub run_queued_cmd: bool,
    pub pause_cmd_flag: bool,
    pub brake_status: u8,
    pub enable_status: bool,
    pub drag_status: bool,
    pub running_status: bool,
    pub error_status: bool,
    pub jog_status: bool,
    pub robot_type: i8,
}

mod offset {
    pub const MESSAGE_SIZE: usize = 0;
    pub const DIGITAL_INPUTS: usize = 8;
    pub const DIGITAL_OUTPUTS: usize = 16;
    pub const ROBOT_MODE: usize = 24;
    pub const TIMESTAMP: usize = 32;
    pub const TEST_VALUE: usize = 48;
    pub const SPEED_SCALING: usize = 64;
    pub const Q_TARGET: usize = 192;
    pub const Q_ACTUAL: usize = 432;
    pub const QD_ACTUAL: usize = 480;
    pub const TOOL_VECTOR_ACTUAL: usize = 624;
    pub const TCP_SPEED_ACTUAL: usize = 672;
    pub const TOOL_VECTOR_TARGET: usize = 768;
    pub const USER: usize = 1012;
    pub const TOOL: usize = 1013;
    pub const RUN_QUEUED_CMD: usize = 1014;
    pub const PAUSE_CMD_FLAG: usize = 1015;
    pub const BRAKE_STATUS: usize = 1025;
    pub const ENABLE_STATUS: usize = 1026;
    pub const DRAG_STATUS: usize = 1027;
    pub const RUNNING_STATUS: usize = 1028;
    pub const ERROR_STATUS: usize = 1029;
    pub const JOG_STATUS: usize = 1030;
    pub const ROBOT_TYPE: usize = 1031;
}

/// The size field and test value as they appear on the wire: what resynchronisation scans for.
const SIZE_BYTES: [u8; 2] = (FEEDBACK_FRAME_LEN as u16).to_le_bytes();
const TEST_BYTES: [u8; 8] = FEEDBACK_TEST_VALUE.to_le_bytes();

fn u64_at(b: &[u8; FEEDBACK_FRAME_LEN], at: usize) -> u64 {
    let mut a = [0u8; 8];
    a.copy_from_slice(&b[at..at + 8]);
    u64::from_le_bytes(a)
}

fn f64_at(b: &[u8; FEEDBACK_FRAME_LEN], at: usize) -> f64 {
    f64::from_bits(u64_at(b, at))
}

fn f64x6_at(b: &[u8; FEEDBACK_FRAME_LEN], at: usize) -> [f64; 6] {
    std::array::from_fn(|i| f64_at(b, at + 8 * i))
}

fn put_u64(b: &mut [u8; FEEDBACK_FRAME_LEN], at: usize, v: u64) {
    b[at..at + 8].copy_from_slice(&v.to_le_bytes());
}

fn put_f64x6(b: &mut [u8; FEEDBACK_FRAME_LEN], at: usize, v: &[f64; 6]) {
    for (i, x) in v.iter().enumerate() {
        put_u64(b, at + 8 * i, x.to_bits());
    }
}

impl FeedbackFrame {
    /// The robot mode.
    pub fn mode(&self) -> RobotMode {
        RobotMode::from_code(self.robot_mode)
    }

    /// The measured tool pose (ToolVectorActual[0..4]).
    pub fn actual_pose(&self) -> Pose {
        let v = &self.tool_vector_actual;
        Pose::new(v[0], v[1], v[2], v[3])
    }

    /// Whether the controller reports an alarm (mode 9 or ErrorStatus).
    pub fn in_alarm(&self) -> bool {
        self.error_status || self.mode() == RobotMode::Error
    }

    /// Decodes one frame. Checks the length, the size field and the test value.
    pub fn decode(bytes: &[u8]) -> Result<FeedbackFrame, ProtoError> {
        let b: &[u8; FEEDBACK_FRAME_LEN] = bytes.try_into().map_err(|_| ProtoError::FrameSize { got: bytes.len() })?;
        let message_size = u16::from_le_bytes([b[offset::MESSAGE_SIZE], b[offset::MESSAGE_SIZE + 1]]);
        if usize::from(message_size) != FEEDBACK_FRAME_LEN {
            return Err(ProtoError::FrameLengthField { message_size });
        }
        let test = u64_at(b, offset::TEST_VALUE);
        if test != FEEDBACK_TEST_VALUE {
            return Err(ProtoError::FrameTestValue { found: test });
        }
        Ok(FeedbackFrame {
            digital_inputs: u64_at(b, offset::DIGITAL_INPUTS),
            digital_outputs: u64_at(b, offset::DIGITAL_OUTPUTS),
            robot_mode: u64_at(b, offset::ROBOT_MODE),
            timestamp_ms: u64_at(b, offset::TIMESTAMP),
            speed_scaling: f64_at(b, offset::SPEED_SCALING),
            q_target_deg: f64x6_at(b, offset::Q_TARGET),
            q_actual_deg: f64x6_at(b, offset::Q_ACTUAL),
            qd_actual_deg_s: f64x6_at(b, offset::QD_ACTUAL),
            tool_vector_actual: f64x6_at(b, offset::TOOL_VECTOR_ACTUAL),
            tcp_speed_actual: f64x6_at(b, offset::TCP_SPEED_ACTUAL),
            tool_vector_target: f64x6_at(b, offset::TOOL_VECTOR_TARGET),
            user: b[offset::USER] as i8,
            tool: b[offset::TOOL] as i8,
            run_queued_cmd: b[offset::RUN_QUEUED_CMD] != 0,
            pause_cmd_flag: b[offset::PAUSE_CMD_FLAG] != 0,
            brake_status: b[offset::BRAKE_STATUS],
            enable_status: b[offset::ENABLE_STATUS] != 0,
            drag_status: b[offset::DRAG_STATUS] != 0,
            running_status: b[offset::RUNNING_STATUS] != 0,
            error_status: b[offset::ERROR_STATUS] != 0,
            jog_status: b[offset::JOG_STATUS] != 0,
            robot_type: b[offset::ROBOT_TYPE] as i8,
        })
    }

    /// Encodes the frame (size field and test value set, unused fields zero).
    pub fn encode(&self) -> [u8; FEEDBACK_FRAME_LEN] {
        let mut b = [0u8; FEEDBACK_FRAME_LEN];
        b[offset::MESSAGE_SIZE..offset::MESSAGE_SIZE + 2].copy_from_slice(&SIZE_BYTES);
        put_u64(&mut b, offset::DIGITAL_INPUTS, self.digital_inputs);
        put_u64(&mut b, offset::DIGITAL_OUTPUTS, self.digital_outputs);
        put_u64(&mut b, offset::ROBOT_MODE, self.robot_mode);
        put_u64(&mut b, offset::TIMESTAMP, self.timestamp_ms);
        put_u64(&mut b, offset::TEST_VALUE, FEEDBACK_TEST_VALUE);
        put_u64(&mut b, offset::SPEED_SCALING, self.speed_scaling.to_bits());
        put_f64x6(&mut b, offset::Q_TARGET, &self.q_target_deg);
        put_f64x6(&mut b, offset::Q_ACTUAL, &self.q_actual_deg);
        put_f64x6(&mut b, offset::QD_ACTUAL, &self.qd_actual_deg_s);
        put_f64x6(&mut b, offset::TOOL_VECTOR_ACTUAL, &self.tool_vector_actual);
        put_f64x6(&mut b, offset::TCP_SPEED_ACTUAL, &self.tcp_speed_actual);
        put_f64x6(&mut b, offset::TOOL_VECTOR_TARGET, &self.tool_vector_target);
        b[offset::USER] = self.user as u8;
        b[offset::TOOL] = self.tool as u8;
        b[offset::RUN_QUEUED_CMD] = u8::from(self.run_queued_cmd);
        b[offset::PAUSE_CMD_FLAG] = u8::from(self.pause_cmd_flag);
        b[offset::BRAKE_STATUS] = self.brake_status;
        b[offset::ENABLE_STATUS] = u8::from(self.enable_status);
        b[offset::DRAG_STATUS] = u8::from(self.drag_status);
        b[offset::RUNNING_STATUS] = u8::from(self.running_status);
        b[offset::ERROR_STATUS] = u8::from(self.error_status);
        b[offset::JOG_STATUS] = u8::from(self.jog_status);
        b[offset::ROBOT_TYPE] = self.robot_type as u8;
        b
    }
}

/// Gathers feedback stream bytes and yields whole, validated frames.
///
/// TCP delivers a byte stream: a connection may start mid-frame, reads split frames anywhere,
/// and a corrupted stretch must not shift every later frame. The decoder scans for a position
/// where the size field reads 1440 and the test value sits 48 bytes later, and counts the
/// bytes it had to skip.
#[derive(Debug, Default)]
pub struct FeedbackDecoder {
    buf: Vec<u8>,
    skipped_bytes: u64,
}

impl FeedbackDecoder {
    pub fn new() -> Self {
        Self::default()
    }

    /// Appends received bytes.
    pub fn push(&mut self, bytes: &[u8]) {
        self.buf.extend_from_slice(bytes);
    }

    /// Bytes discarded so far while resynchronising.
    pub fn skipped_bytes(&self) -> u64 {
        self.skipped_bytes
    }

    /// The next valid frame, `None` when more bytes are needed.
    pub fn next_frame(&mut self) -> Option<FeedbackFrame> {
        const HEADER: usize = offset::TEST_VALUE + 8;
        loop {
            let mut start = None;
            let mut p = 0;
            while p + HEADER <= self.buf.len() {
                if self.buf[p..p + 2] == SIZE_BYTES && self.buf[p + offset::TEST_VALUE..p + HEADER] == TEST_BYTES {
                    start = Some(p);
                    break;
                }
                p += 1;
            }
            // Without a candidate, everything before `p` is garbage; the tail may still hold
            // the beginning of a frame.
            let drop_to = start.unwrap_or(p);
            if drop_to > 0 {
                self.buf.drain(..drop_to);
                self.skipped_bytes += drop_to as u64;
            }
            start?;
            if self.buf.len() < FEEDBACK_FRAME_LEN {
                return None;
            }
            match FeedbackFrame::decode(&self.buf[..FEEDBACK_FRAME_LEN]) {
                Ok(frame) => {
                    self.buf.drain(..FEEDBACK_FRAME_LEN);
                    return Some(frame);
                }
                Err(_) => {
                    // Cannot happen after the checks above, but never loop on it: skip a byte.
                    self.buf.drain(..1);
                    self.skipped_bytes += 1;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn replies(framer: &mut ReplyFramer) -> Vec<Reply> {
        let mut out = Vec::new();
        while let Some(r) = framer.next_reply().unwrap() {
            out.push(r);
        }
        out
    }

    #[test]
    fn encodes_commands() {
        assert_eq!(Request::EnableRobot { load_kg: None, centre_mm: None }.encode(), "EnableRobot()");
        assert_eq!(Request::EnableRobot { load_kg: Some(0.5), centre_mm: Some([1.0, -2.0, 0.25]) }.encode(), "EnableRobot(0.5,1,-2,0.25)");
        assert_eq!(Request::SpeedFactor { percent: 50 }.encode(), "SpeedFactor(50)");
        assert_eq!(Request::MovL { target: Pose::new(350.0, 0.0, -20.5, 15.0) }.encode(), "MovL(350,0,-20.5,15)");
        assert_eq!(Request::Do { output: DigitalOutput::Queued, index: 1, on: true }.encode(), "DO(1,1)");
        assert_eq!(Request::Do { output: DigitalOutput::ToolImmediate, index: 2, on: false }.encode(), "ToolDOExecute(2,0)");
        assert_eq!(Request::Ratio { setting: RatioSetting::SpeedL, percent: 30 }.encode(), "SpeedL(30)");
        assert_eq!(Request::Sync.encode(), "Sync()");
        assert_eq!(Request::Sync.port(), Port::Motion);
        assert_eq!(Request::GetErrorId.port(), Port::Dashboard);
    }

    #[test]
    fn fragmented_reply_across_reads() {
        let mut f = ReplyFramer::new();
        f.push(b"0,{5}");
        assert_eq!(f.next_reply().unwrap(), None);
        f.push(b",RobotMo");
        assert_eq!(f.next_reply().unwrap(), None);
        f.push(b"de();");
        let r = f.next_reply().unwrap().unwrap();
        assert_eq!(r.error_id, ErrorId::Accepted);
        assert_eq!(r.integer().unwrap(), 5);
        assert_eq!(r.echo, "RobotMode()");
        assert_eq!(r.echo_name(), "RobotMode");
        assert_eq!(f.pending_len(), 0);
    }

    #[test]
    fn merged_replies_in_one_read() {
        let mut f = ReplyFramer::new();
        f.push(b"0,{},EnableRobot();0,{},SpeedFactor(50);-1,{},Us");
        let r = replies(&mut f);
        assert_eq!(r.len(), 2);
        assert_eq!(r[0].echo, "EnableRobot()");
        assert_eq!(r[1].echo, "SpeedFactor(50)");
        f.push(b"er(3);");
        let r = replies(&mut f);
        assert_eq!(r[0].error_id, ErrorId::Failed);
        assert_eq!(r[0].echo, "User(3)");
    }

    #[test]
    fn byte_by_byte_delivery() {
        let text = b"0,{},MovL(-500,100,200,150);0,{1},DI(2);";
        let mut f = ReplyFramer::new();
        let mut got = Vec::new();
        for b in text {
            f.push(&[*b]);
            got.extend(replies(&mut f));
        }
        assert_eq!(got.len(), 2);
        assert_eq!(got[1].integer().unwrap(), 1);
    }

    #[test]
    fn four_and_six_value_poses() {
        let r = Reply::parse("0,{350.000000,0.000000,0.000000,0.000000,0.000000,0.000000},GetPose();").unwrap();
        assert_eq!(r.pose().unwrap(), Pose::new(350.0, 0.0, 0.0, 0.0));
        let r = Reply::parse("0,{300.5,-12.25,-40,15},GetPose();").unwrap();
        assert_eq!(r.pose().unwrap(), Pose::new(300.5, -12.25, -40.0, 15.0));
        let r = Reply::parse("0,{1.5,32,32.6,-4},GetAngle();").unwrap();
        assert_eq!(r.joints_deg().unwrap(), [1.5, 32.0, 32.6, -4.0]);
        let r = Reply::parse("0,{1,2,3},GetPose();").unwrap();
        assert!(matches!(r.pose(), Err(ProtoError::BadValues { .. })));
        let r = Reply::parse("0,{1,x,3,4},GetPose();").unwrap();
        assert!(matches!(r.pose(), Err(ProtoError::BadValues { .. })));
    }

    #[test]
    fn pretty_printed_get_error_id() {
        let mut f = ReplyFramer::new();
        f.push(b"0,{[\n\t[\n\t\t69,\n\t\t72\n\t],\n\t[1],\n\t[],\n\t[],\n\t[],\n\t[]\n]\n},GetErrorID();");
        let r = f.next_reply().unwrap().unwrap();
        assert_eq!(r.echo, "GetErrorID()");
        assert_eq!(r.error_id_lists().unwrap(), vec![vec![69, 72], vec![1], vec![], vec![], vec![], vec![]]);
        let seven = "[[],[],[],[],[],[],[]]";
        assert_eq!(parse_error_id_lists(seven).unwrap().len(), 7);
        let lists = vec![vec![112], vec![], vec![8752, 33920], vec![]];
        assert_eq!(parse_error_id_lists(&format_error_id_lists(&lists)).unwrap(), lists);
        assert!(parse_error_id_lists("[[1,2],").is_err());
        assert!(parse_error_id_lists("[[a]]").is_err());
    }

    #[test]
    fn each_error_id_class() {
        let cases = [
            ("0,{},EnableRobot();", ErrorId::Accepted),
            ("-1,{},EnableRobot();", ErrorId::Failed),
            ("-10000,{},Mov(1,2,3,4);", ErrorId::UnknownCommand),
            ("-20000,{},MovJ(1,2,3);", ErrorId::WrongParameterCount),
            ("-30001,{},SpeedFactor(x);", ErrorId::ParameterType { index: 1 }),
            ("-30004,{},MovL(1,2,3,r);", ErrorId::ParameterType { index: 4 }),
            ("-40001,{},SpeedFactor(200);", ErrorId::ParameterRange { index: 1 }),
            ("-40002,{},DO(1,7);", ErrorId::ParameterRange { index: 2 }),
            ("-2,{},MovJ(1,2,3,4);", ErrorId::Other(-2)),
        ];
        for (text, id) in cases {
            let r = Reply::parse(text).unwrap();
            assert_eq!(r.error_id, id, "{text}");
            assert_eq!(ErrorId::from_code(id.code()), id);
        }
        assert!(ErrorId::ParameterRange { index: 3 }.meaning().contains("parameter 3"));
    }

    #[test]
    fn malformed_replies_are_errors_and_framing_continues() {
        let mut f = ReplyFramer::new();
        f.push(b"garbage;0,{},ClearError();x,{},A();0,{1,2,B();");
        assert!(matches!(f.next_reply(), Err(ProtoError::MalformedReply { .. })));
        assert_eq!(f.next_reply().unwrap().unwrap().echo, "ClearError()");
        assert!(f.next_reply().is_err());
        assert!(f.next_reply().is_err());
        assert_eq!(f.next_reply().unwrap(), None);
    }

    #[test]
    fn request_framing_and_parsing() {
        let mut f = RequestFramer::new();
        f.push(b"EnableRobot()\nMovL(350.0,0,-20, 15");
        let c = f.next_call().unwrap().unwrap();
        assert_eq!(c.name, "EnableRobot");
        assert_eq!(f.next_call().unwrap(), None);
        f.push(b")  movj(1,2,3,4,SpeedJ=50)");
        let c = f.next_call().unwrap().unwrap();
        assert_eq!(c.text, "MovL(350.0,0,-20, 15)");
        assert_eq!(Request::from_call(&c).unwrap(), Request::MovL { target: Pose::new(350.0, 0.0, -20.0, 15.0) });
        let c = f.next_call().unwrap().unwrap();
        assert_eq!(Request::from_call(&c).unwrap(), Request::MovJ { target: Pose::new(1.0, 2.0, 3.0, 4.0) });
        let call = |t: &str| Request::from_call(&RequestCall::parse(t).unwrap());
        assert_eq!(call("Mov(1,2,3,4)"), Err(ErrorId::UnknownCommand));
        assert_eq!(call("MovJ(1,2,3)"), Err(ErrorId::WrongParameterCount));
        assert_eq!(call("MovL(1,2,3,r)"), Err(ErrorId::ParameterType { index: 4 }));
        assert_eq!(call("DO(1,5)"), Err(ErrorId::ParameterRange { index: 2 }));
        assert_eq!(RequestCall::parse("SetUser(1,{1,2,3,4})").unwrap().args.len(), 2);
        assert!(RequestCall::parse("(1)").is_err());
    }

    fn sample_frame() -> FeedbackFrame {
        FeedbackFrame {
            digital_inputs: 0b101,
            digital_outputs: 1 << 3,
            robot_mode: 5,
            timestamp_ms: 1_700_000_000_123,
            speed_scaling: 0.5,
            q_actual_deg: [1.0, 32.0, 32.6, -4.0, 0.0, 0.0],
            tool_vector_actual: [350.0, 0.0, 0.0, -3.0, 0.0, 0.0],
            enable_status: true,
            run_queued_cmd: true,
            robot_type: 1,
            ..Default::default()
        }
    }

    #[test]
    fn feedback_literal_bytes() {
        let bytes = sample_frame().encode();
        assert_eq!(&bytes[0..2], &[0xA0, 0x05]);
        assert_eq!(&bytes[48..56], &[0xEF, 0xCD, 0xAB, 0x89, 0x67, 0x45, 0x23, 0x01]);
        assert_eq!(&bytes[24..32], &[5, 0, 0, 0, 0, 0, 0, 0]);
        assert_eq!(&bytes[624..632], &350.0f64.to_le_bytes());
        assert_eq!(bytes[1026], 1);
        assert_eq!(FeedbackFrame::decode(&bytes).unwrap(), sample_frame());

        let mut wrong_size = bytes;
        wrong_size[0] = 0x9F;
        assert!(matches!(FeedbackFrame::decode(&wrong_size), Err(ProtoError::FrameLengthField { .. })));
        let mut wrong_test = bytes;
        wrong_test[48] = 0;
        assert!(matches!(FeedbackFrame::decode(&wrong_test), Err(ProtoError::FrameTestValue { .. })));
        assert!(matches!(FeedbackFrame::decode(&bytes[..100]), Err(ProtoError::FrameSize { got: 100 })));
    }

    #[test]
    fn feedback_resync_after_start_mid_frame_and_garbage() {
        let a = sample_frame();
        let mut b = sample_frame();
        b.robot_mode = 7;
        let mut c = sample_frame();
        c.timestamp_ms += 8;
        let mut stream = Vec::new();
        stream.extend_from_slice(&a.encode()[700..]); // connection starts mid-frame
        stream.extend_from_slice(&b.encode());
        stream.extend_from_slice(&[0xA0, 0x05, 1, 2, 3, 0xEF, 0xCD]); // garbage that looks like a start
        stream.extend_from_slice(&c.encode());
        let mut d = FeedbackDecoder::new();
        let mut got = Vec::new();
        for chunk in stream.chunks(333) {
            d.push(chunk);
            while let Some(f) = d.next_frame() {
                got.push(f);
            }
        }
        assert_eq!(got, vec![b, c]);
        assert_eq!(d.skipped_bytes(), (1440 - 700 + 7) as u64);
    }

    fn finite() -> std::ops::Range<f64> {
        -1.0e6f64..1.0e6
    }

    fn arb_request() -> impl Strategy<Value = Request> {
        let pose = || (finite(), finite(), finite(), finite()).prop_map(|(x, y, z, r)| Pose::new(x, y, z, r));
        prop_oneof![
            Just(Request::EnableRobot { load_kg: None, centre_mm: None }),
            finite().prop_map(|l| Request::EnableRobot { load_kg: Some(l), centre_mm: None }),
            (finite(), finite(), finite(), finite())
                .prop_map(|(l, a, b, c)| Request::EnableRobot { load_kg: Some(l), centre_mm: Some([a, b, c]) }),
            Just(Request::ClearError),
            Just(Request::Continue),
            Just(Request::GetErrorId),
            Just(Request::Sync),
            any::<i64>().prop_map(|percent| Request::SpeedFactor { percent }),
            any::<i64>().prop_map(|index| Request::User { index }),
            (any::<i64>(), any::<bool>(), 0usize..4).prop_map(|(index, on, k)| Request::Do {
                output: [DigitalOutput::Queued, DigitalOutput::Immediate, DigitalOutput::ToolQueued, DigitalOutput::ToolImmediate][k],
                index,
                on,
            }),
            (any::<i64>(), 0usize..5).prop_map(|(percent, k)| Request::Ratio {
                setting: [RatioSetting::AccJ, RatioSetting::AccL, RatioSetting::SpeedJ, RatioSetting::SpeedL, RatioSetting::Cp][k],
                percent,
            }),
            any::<i64>().prop_map(|level| Request::SetCollisionLevel { level }),
            pose().prop_map(|target| Request::MovJ { target }),
            pose().prop_map(|target| Request::MovL { target }),
            (finite(), finite(), finite(), finite()).prop_map(|(a, b, c, d)| Request::JointMovJ { joints_deg: [a, b, c, d] }),
        ]
    }

    fn arb_frame() -> impl Strategy<Value = FeedbackFrame> {
        let arr = || proptest::array::uniform6(finite());
        (
            (any::<u64>(), any::<u64>(), 0u64..12, any::<u64>(), finite()),
            (arr(), arr(), arr(), arr()),
            (any::<i8>(), any::<i8>(), any::<[bool; 8]>(), any::<u8>(), any::<i8>()),
        )
            .prop_map(|((di, dout, mode, ts, speed), (qt, qa, tva, tvt), (user, tool, flags, brake, rt))| FeedbackFrame {
                digital_inputs: di,
                digital_outputs: dout,
                robot_mode: mode,
                timestamp_ms: ts,
                speed_scaling: speed,
                q_target_deg: qt,
                q_actual_deg: qa,
                qd_actual_deg_s: [0.0; 6],
                tool_vector_actual: tva,
                tcp_speed_actual: [0.0; 6],
                tool_vector_target: tvt,
                user,
                tool,
                run_queued_cmd: flags[0],
                pause_cmd_flag: flags[1],
                brake_status: brake,
                enable_status: flags[2],
                drag_status: flags[3],
                running_status: flags[4],
                error_status: flags[5],
                jog_status: flags[6],
                robot_type: rt,
            })
    }

    /// Pulls everything out of both framers, using every parsed value; each call consumes
    /// input or reports a partial frame, so `bound` iterations suffice.
    fn drain_framers(r: &mut ReplyFramer, q: &mut RequestFramer, bound: usize) {
        for _ in 0..=bound {
            match r.next_reply() {
                Ok(None) => break,
                Ok(Some(reply)) => {
                    let _ = (reply.numbers(), reply.pose(), reply.error_id_lists(), reply.integer());
                }
                Err(_) => {}
            }
        }
        for _ in 0..=bound {
            match q.next_call() {
                Ok(None) => break,
                Ok(Some(call)) => {
                    let _ = Request::from_call(&call).map(|req| req.encode());
                }
                Err(_) => {}
            }
        }
    }

    proptest! {
        #[test]
        fn request_encode_then_decode(req in arb_request()) {
            let mut f = RequestFramer::new();
            f.push(req.encode().as_bytes());
            let call = f.next_call().unwrap().unwrap();
            prop_assert_eq!(Request::from_call(&call), Ok(req));
        }

        #[test]
        fn reply_encode_then_decode(code in -50000i64..10, values in proptest::collection::vec(finite(), 0..7),
                                    lists in proptest::collection::vec(proptest::collection::vec(any::<i64>(), 0..4), 1..8),
                                    split in 0usize..200) {
            let nums = Reply::new(ErrorId::from_code(code), values.iter().map(|v| v.to_string()).collect::<Vec<_>>().join(","), "GetPose()");
            let errs = Reply::new(ErrorId::Accepted, format_error_id_lists(&lists), "GetErrorID()");
            let wire = format!("{}{}", nums.encode(), errs.encode());
            let split = split.min(wire.len());
            let mut f = ReplyFramer::new();
            f.push(&wire.as_bytes()[..split]);
            let mut got = replies(&mut f);
            f.push(&wire.as_bytes()[split..]);
            got.extend(replies(&mut f));
            prop_assert_eq!(got.len(), 2);
            prop_assert_eq!(got[0].numbers().unwrap(), values);
            prop_assert_eq!(&got[0], &nums);
            prop_assert_eq!(got[1].error_id_lists().unwrap(), lists);
        }

        #[test]
        fn feedback_encode_then_decode(frame in arb_frame(), cut in 0usize..1440, junk in proptest::collection::vec(any::<u8>(), 0..300)) {
            let bytes = frame.encode();
            prop_assert_eq!(FeedbackFrame::decode(&bytes).unwrap(), frame);
            // Junk, then a frame split at `cut`, then the same frame again: both come out.
            let mut d = FeedbackDecoder::new();
            d.push(&junk);
            d.push(&bytes[..cut]);
            let mut got: Vec<FeedbackFrame> = std::iter::from_fn(|| d.next_frame()).collect();
            d.push(&bytes[cut..]);
            d.push(&bytes);
            got.extend(std::iter::from_fn(|| d.next_frame()));
            prop_assert_eq!(got, vec![frame, frame]);
        }

        /// The stand-in for the cargo-fuzz targets where `cargo fuzz` cannot run: valid
        /// replies, requests and frames with random bytes overwritten.
        #[test]
        fn mutated_valid_input_never_panics(frame in arb_frame(),
                                            flips in proptest::collection::vec((any::<usize>(), any::<u8>()), 0..24),
                                            chunk in 1usize..700) {
            let mut bytes = Vec::new();
            bytes.extend_from_slice(b"0,{350.000000,0.000000,0.000000,0.000000,0.000000,0.000000},GetPose();");
            bytes.extend_from_slice(Reply::new(ErrorId::Accepted, format_error_id_lists(&[vec![69, 72], vec![1]]), "GetErrorID()").encode().as_bytes());
            bytes.extend_from_slice(b"MovL(300,0,-20,15)EnableRobot(0.5,1,2,3)DO(1,1)");
            bytes.extend_from_slice(&frame.encode());
            bytes.extend_from_slice(&frame.encode());
            let len = bytes.len();
            for (at, b) in flips {
                bytes[at % len] = b;
            }
            let mut r = ReplyFramer::new();
            let mut q = RequestFramer::new();
            let mut d = FeedbackDecoder::new();
            let mut frames = 0;
            for piece in bytes.chunks(chunk) {
                r.push(piece);
                q.push(piece);
                drain_framers(&mut r, &mut q, len);
                d.push(piece);
                while d.next_frame().is_some() {
                    frames += 1;
                }
            }
            prop_assert!(frames <= len / FEEDBACK_FRAME_LEN);
        }

        #[test]
        fn decoders_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..4000)) {
            let mut r = ReplyFramer::new();
            let mut q = RequestFramer::new();
            r.push(&bytes);
            q.push(&bytes);
            drain_framers(&mut r, &mut q, bytes.len());
            let mut d = FeedbackDecoder::new();
            d.push(&bytes);
            while d.next_frame().is_some() {}
            let _ = FeedbackFrame::decode(&bytes);
        }
    }
}
