//! Dobot MG400: wire protocol ([`proto`], sans-io) and the tokio TCP client ([`client`]).
//!
//! The client is a thin shell around the codec: it owns the three sockets (dashboard 29999,
//! motion 30003, feedback 30004), feeds received bytes into the framers of `proto`, and turns
//! the decoded replies and feedback frames into the [`Arm`](crate::arm::Arm) contract.
//! [`send`] checks one dashboard command typed by hand (`rig arm send`).

pub mod alarms;
pub mod client;
pub mod proto;
pub mod send;
