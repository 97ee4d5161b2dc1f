//! A simulated Dobot Magician speaking the real serial protocol.
//!
//! [`SimMagician::handle`] is sans-io: a decoded [`Command`] in, a [`Reply`] out. Queued
//! commands (PTP moves, homing) get increasing queue indices; while the queue runs, each
//! `GetQueuedCmdCurrentIndex` poll completes one queued command, so a client that polls for
//! arrival sees the arm move in steps it can follow. [`SimMagician::serve_in_thread`] runs it
//! on the device end of a byte stream (a pseudo-terminal master in tests).

use std::collections::VecDeque;
use std::io::{Read, Write};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;

use crate::arm::magician::proto::{Command, DeviceVersion, MagicianPose, PacketFramer, Reply};

/// The firmware version the simulated Magician reports unless told otherwise (a made-up
/// version, not one a real controller is known to run).
pub const SIM_FIRMWARE: DeviceVersion = DeviceVersion { major: 3, minor: 7, revision: 0 };

/// The simulated Magician's state.
#[derive(Debug, Clone)]
pub struct SimMagician {
    pub pose: MagicianPose,
    /// Where homing takes the arm.
    pub home: MagicianPose,
    pub alarms: Vec<u16>,
    pub executing: bool,
    /// What GetDeviceVersion answers.
    pub firmware: DeviceVersion,
    queue: VecDeque<(u64, Command)>,
    next_index: u64,
    current_index: u64,
    /// Every command received, in order (tests check the sequence a client sends).
    pub log: Vec<Command>,
}

impl SimMagician {
    pub fn new(pose: MagicianPose) -> Self {
        Self {
            pose,
            home: pose,
            alarms: Vec::new(),
            executing: false,
            firmware: SIM_FIRMWARE,
            queue: VecDeque::new(),
            next_index: 1,
            current_index: 0,
            log: Vec::new(),
        }
    }

    /// Applies one command and returns the controller's reply.
    pub fn handle(&mut self, command: Command) -> Reply {
        self.log.push(command);
        match command {
            Command::GetDeviceVersion => Reply::DeviceVersion(self.firmware),
            Command::GetPose => Reply::Pose(self.pose),
            Command::GetAlarmsState => Reply::Alarms(self.alarms.clone()),
            Command::ClearAllAlarmsState => {
                self.alarms.clear();
                Reply::Ack
            }
            Command::Home | Command::SetPtp { .. } => {
                let index = self.next_index;
                self.next_index += 1;
                self.queue.push_back((index, command));
                Reply::QueuedIndex(index)
            }
            Command::SetPtpCommonParams { .. } => Reply::Ack,
            Command::QueuedStartExec => {
                self.executing = true;
                Reply::Ack
            }
            Command::QueuedStopExec => {
                self.executing = false;
                Reply::Ack
            }
            Command::QueuedForceStopExec => {
                self.executing = false;
                self.queue.clear();
                Reply::Ack
            }
            Command::QueuedClear => {
                self.queue.clear();
                Reply::Ack
            }
            Command::GetQueuedCurrentIndex => {
                if self.executing && self.alarms.is_empty() {
                    self.step();
                }
                Reply::CurrentIndex(self.current_index)
            }
        }
    }

    /// Completes the next queued command.
    fn step(&mut self) {
        let Some((index, command)) = self.queue.pop_front() else { return };
        match command {
            Command::SetPtp { x_mm, y_mm, z_mm, r_deg, .. } => {
                self.pose.x_mm = x_mm;
                self.pose.y_mm = y_mm;
                self.pose.z_mm = z_mm;
                self.pose.r_deg = r_deg;
            }
            Command::Home => self.pose = self.home,
            _ => {}
        }
        self.current_index = index;
    }

    /// Serves the protocol on `io` (the device end) in a thread until [`SimServer::stop`] or
    /// the stream closes. Undecodable requests get no reply, like the real controller.
    pub fn serve_in_thread<T: Read + Write + Send + 'static>(self, mut io: T) -> SimServer {
        let stop = Arc::new(AtomicBool::new(false));
        let stop_flag = Arc::clone(&stop);
        let handle = std::thread::spawn(move || {
            let mut sim = self;
            let mut framer = PacketFramer::new();
            let mut buf = [0u8; 256];
            while !stop_flag.load(Ordering::Relaxed) {
                let n = match io.read(&mut buf) {
                    Ok(0) | Err(_) => break,
                    Ok(n) => n,
                };
                framer.push(&buf[..n]);
                while let Some(packet) = framer.next_packet() {
                    let Ok(command) = Command::from_packet(&packet) else { continue };
                    let reply = sim.handle(command);
                    let Ok(bytes) = reply.packet_for(&command).encode() else { continue };
                    if io.write_all(&bytes).and_then(|_| io.flush()).is_err() {
                        return sim;
                    }
                }
            }
            sim
        });
        SimServer { stop, handle }
    }
}

/// A running simulated Magician.
pub struct SimServer {
    stop: Arc<AtomicBool>,
    handle: JoinHandle<SimMagician>,
}

impl SimServer {
    /// Asks the thread to stop after its current read and returns without waiting (a blocked
    /// read ends when the stream closes).
    pub fn stop(self) {
        self.stop.store(true, Ordering::Relaxed);
        drop(self.handle);
    }
    /// Waits for the stream to close and returns the final state.
    pub fn join(self) -> Option<SimMagician> {
        self.handle.join().ok()
    }
}
